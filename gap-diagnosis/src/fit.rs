//! Fitting candidates on calibration trials, scoring them on held-out trials, ranking.
use super::dataset::{TrialData, VarGroup};
use super::effects::{predict_scaled, Candidate, Effect, ParamSpec};
use super::experiment::Region;
use super::signal::{dot, sub};
use serde::{Deserialize, Serialize};

/// Which samples calibrate and which are held out, per trial.
#[derive(Debug, Clone)]
pub struct Fold {
    pub label: String,
    pub calib: Vec<Vec<bool>>,
    pub held: Vec<Vec<bool>>,
}

/// Leave-one-region-out when trials carry ≥ 2 regions, else k-fold over trials (k ≤ 5),
/// else (a single trial) interleaved 3-fold over its samples.
pub fn make_folds(data: &[TrialData]) -> (String, Vec<Fold>) {
    let all = |v: bool| -> Vec<Vec<bool>> { data.iter().map(|d| vec![v; d.t.len()]).collect() };
    let mut regions: Vec<Region> = data.iter().filter_map(|d| d.region).collect();
    regions.sort();
    regions.dedup();
    let labelled = data.iter().all(|d| d.region.is_some());
    let mut folds = Vec::new();
    let scheme;
    if labelled && regions.len() >= 2 {
        scheme = "leave-one-region-out".to_string();
        for r in regions {
            let mut calib = all(false);
            let mut held = all(false);
            for (i, d) in data.iter().enumerate() {
                let h = d.region == Some(r);
                held[i].iter_mut().for_each(|v| *v = h);
                calib[i].iter_mut().for_each(|v| *v = !h);
            }
            folds.push(Fold {
                label: r.name().into(),
                calib,
                held,
            });
        }
    } else if data.len() >= 3 {
        let k = data.len().min(5);
        scheme = format!("{k}-fold over trials");
        for f in 0..k {
            let mut calib = all(false);
            let mut held = all(false);
            for i in 0..data.len() {
                let h = i % k == f;
                held[i].iter_mut().for_each(|v| *v = h);
                calib[i].iter_mut().for_each(|v| *v = !h);
            }
            folds.push(Fold {
                label: format!("fold {}", f + 1),
                calib,
                held,
            });
        }
    } else {
        let k = 3;
        scheme = format!("{k}-fold over samples (interleaved)");
        for f in 0..k {
            let held: Vec<Vec<bool>> = data
                .iter()
                .map(|d| (0..d.t.len()).map(|j| j % k == f).collect())
                .collect();
            let calib = held
                .iter()
                .map(|v| v.iter().map(|b| !b).collect())
                .collect();
            folds.push(Fold {
                label: format!("fold {}", f + 1),
                calib,
                held,
            });
        }
    }
    (scheme, folds)
}

fn to_theta(specs: &[ParamSpec], u: &[f64]) -> Vec<f64> {
    specs
        .iter()
        .zip(u)
        .map(|(p, &x)| {
            let x = x.clamp(0.0, 1.0);
            if p.log {
                (p.lo.ln() + x * (p.hi.ln() - p.lo.ln())).exp()
            } else {
                p.lo + x * (p.hi - p.lo)
            }
        })
        .collect()
}
fn to_unit(specs: &[ParamSpec], th: &[f64]) -> Vec<f64> {
    specs
        .iter()
        .zip(th)
        .map(|(p, &v)| {
            if p.log {
                (v.ln() - p.lo.ln()) / (p.hi.ln() - p.lo.ln())
            } else {
                (v - p.lo) / (p.hi - p.lo)
            }
        })
        .collect()
}

/// Fewest residual values a phase needs to get its own variance; smaller phases share one.
const MIN_GROUP_VALUES: usize = 30;
/// Smallest mean square a phase is credited with, N² (noise-free synthetic data).
const MSE_FLOOR: f64 = 1e-10;

/// Squared residuals summed per variance group ([`VarGroup`]: out of contact, near a
/// contact, and the four contact phases).
///
/// The residual variance is far from uniform: out of contact it is the sensor noise alone
/// (hundredths of a newton), in contact the model's own error (tenths to newtons, growing with
/// the force). A single variance lets the contact phases decide everything, so an effect that
/// shows where the model is exact (a sensor bias before the tip touches) is fitted to, and
/// judged by, the contact error instead. Every fit and score here is the Gaussian likelihood
/// with one variance per phase, profiled out: Σ_g n_g ln(SSE_g / n_g).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PhaseSse {
    pub sse: [f64; VarGroup::COUNT],
    pub n: [usize; VarGroup::COUNT],
}

impl PhaseSse {
    pub fn push(&mut self, group: VarGroup, r: [f64; 3]) {
        let g = group as usize;
        self.sse[g] += dot(r, r);
        self.n[g] += 3;
    }
    pub fn total(&self) -> (f64, usize) {
        (self.sse.iter().sum(), self.n.iter().sum())
    }
    pub fn rmse(&self) -> f64 {
        let (s, n) = self.total();
        (s / n.max(1) as f64).sqrt()
    }
    /// (SSE, values) per variance group: each phase with enough values, the rest pooled.
    fn groups(&self) -> Vec<(f64, usize)> {
        let mut out = Vec::with_capacity(VarGroup::COUNT);
        let (mut rs, mut rn) = (0.0, 0usize);
        for g in 0..VarGroup::COUNT {
            if self.n[g] >= MIN_GROUP_VALUES {
                out.push((self.sse[g], self.n[g]));
            } else {
                rs += self.sse[g];
                rn += self.n[g];
            }
        }
        if rn > 0 {
            out.push((rs, rn));
        }
        out
    }
    /// Σ_g w_g ln(MSE_g) with w_g = n_g · (`effective` / n): −2 log-likelihood up to a
    /// constant when `effective` = n.
    pub fn log_mse_sum(&self, effective: f64) -> f64 {
        let (_, n) = self.total();
        if n == 0 {
            return 0.0;
        }
        self.groups()
            .iter()
            .map(|&(s, m)| m as f64 * effective / n as f64 * (s / m as f64).max(MSE_FLOOR).ln())
            .sum()
    }
    /// The phase-weighted RMSE: exp of the value-weighted mean of ln RMSE_g (what the plain
    /// RMSE is for one variance).
    pub fn weighted_rmse(&self) -> f64 {
        let (_, n) = self.total();
        if n == 0 {
            return 0.0;
        }
        (0.5 * self.log_mse_sum(n as f64) / n as f64).exp()
    }
}

/// How the model's own stiffness error is carried by a candidate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Nuisance {
    /// As the candidate says (a global stiffness scale where it has `modulus`).
    #[default]
    Global,
    /// Each trial's tissue force scaled by its own least-squares factor, profiled on the
    /// samples that are fitted or scored. A model's stiffness error differs from site to
    /// site (the discretisation locks differently where the specimen is thinner; a ball
    /// rolls over facets): against a coarse replay tens of percent, far more than a small
    /// tangential, onset or hold effect changes the normal force. Profiled per trial, that
    /// error no longer decides whether friction, a tilt, a sensor, a relaxation or a device
    /// bias is there; a scale cannot create a tangential force, a lag or a relaxation.
    PerTrial,
}

/// Bounds of a per-trial scale (the refined study meshes are ~5× softer than coarse ones).
const SITE_SCALE_RANGE: (f64, f64) = (0.05, 20.0);

/// The prediction of `c` for one trial under `nuisance`; returns the tissue scale used.
/// `mask` selects the samples the per-trial scale is profiled on.
pub fn predict_in(
    c: &Candidate,
    theta: &[f64],
    d: &TrialData,
    mask: &[bool],
    nuisance: Nuisance,
    grid: &mut Vec<[f64; 3]>,
    out: &mut Vec<[f64; 3]>,
) -> f64 {
    match nuisance {
        Nuisance::Global => {
            predict_scaled(c, theta, d, 1.0, grid, out);
            1.0
        }
        Nuisance::PerTrial => {
            // affine in the scale: out(s) = B + s·A (see `predict_scaled`)
            predict_scaled(c, theta, d, 0.0, grid, out);
            let b = out.clone();
            predict_scaled(c, theta, d, 1.0, grid, out);
            let (mut num, mut den) = (0.0, 0.0);
            for j in 0..out.len() {
                if mask[j] {
                    let a = sub(out[j], b[j]);
                    num += dot(a, sub(d.f[j], b[j]));
                    den += dot(a, a);
                }
            }
            let sc = if den > 0.0 {
                (num / den).clamp(SITE_SCALE_RANGE.0, SITE_SCALE_RANGE.1)
            } else {
                1.0
            };
            for (o, bj) in out.iter_mut().zip(&b) {
                let a = sub(*o, *bj);
                *o = [bj[0] + sc * a[0], bj[1] + sc * a[1], bj[2] + sc * a[2]];
            }
            sc
        }
    }
}

/// Residual sums of `c` at `theta` over the masked samples, per phase.
pub fn phase_sse(c: &Candidate, theta: &[f64], data: &[TrialData], mask: &[Vec<bool>]) -> PhaseSse {
    phase_sse_in(c, theta, data, mask, Nuisance::Global)
}

/// [`phase_sse`] under a given [`Nuisance`].
pub fn phase_sse_in(
    c: &Candidate,
    theta: &[f64],
    data: &[TrialData],
    mask: &[Vec<bool>],
    nuisance: Nuisance,
) -> PhaseSse {
    let (mut grid, mut out) = (Vec::new(), Vec::new());
    let mut acc = PhaseSse::default();
    for (d, m) in data.iter().zip(mask) {
        if !m.iter().any(|&b| b) {
            continue;
        }
        predict_in(c, theta, d, m, nuisance, &mut grid, &mut out);
        for (j, (p, f)) in out.iter().zip(&d.f).enumerate() {
            if m[j] {
                acc.push(d.var_group[j], sub(*p, *f));
            }
        }
    }
    acc
}

/// The baseline's residual: what every candidate is compared with.
#[derive(Debug, Clone, Copy)]
pub struct Baseline {
    pub rmse: f64,
    /// Phase-weighted RMSE ([`PhaseSse::weighted_rmse`]).
    pub weighted_rmse: f64,
    /// Σ_g n_g ln(MSE_g) (the BIC of a model without parameters).
    pub bic: f64,
}

impl Baseline {
    pub fn of(data: &[TrialData]) -> Baseline {
        let mut acc = PhaseSse::default();
        for d in data {
            for (j, (p, f)) in d.base_at_t.iter().zip(&d.f).enumerate() {
                acc.push(d.var_group[j], sub(*p, *f));
            }
        }
        let n = acc.total().1 as f64;
        Baseline {
            rmse: acc.rmse(),
            weighted_rmse: acc.weighted_rmse(),
            bic: acc.log_mse_sum(n),
        }
    }
}

/// Sum of squared residuals over the masked samples.
pub fn sse(c: &Candidate, theta: &[f64], data: &[TrialData], mask: &[Vec<bool>]) -> (f64, usize) {
    sse_in(c, theta, data, mask, Nuisance::Global)
}

fn sse_in(
    c: &Candidate,
    theta: &[f64],
    data: &[TrialData],
    mask: &[Vec<bool>],
    nuisance: Nuisance,
) -> (f64, usize) {
    let (mut grid, mut out) = (Vec::new(), Vec::new());
    let (mut s, mut n) = (0.0, 0usize);
    for (d, m) in data.iter().zip(mask) {
        if !m.iter().any(|&b| b) {
            continue;
        }
        predict_in(c, theta, d, m, nuisance, &mut grid, &mut out);
        for ((p, f), &b) in out.iter().zip(&d.f).zip(m) {
            if b {
                let r = sub(*p, *f);
                s += dot(r, r);
                n += 3;
            }
        }
    }
    (s, n)
}

/// Nelder–Mead on the unit cube (coordinates clamped), from `x0`.
pub fn nelder_mead(
    f: &dyn Fn(&[f64]) -> f64,
    x0: &[f64],
    step: f64,
    max_eval: usize,
) -> (Vec<f64>, f64) {
    let k = x0.len();
    if k == 0 {
        return (vec![], f(&[]));
    }
    let clamp = |x: &mut Vec<f64>| x.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
    let mut simplex: Vec<Vec<f64>> = vec![x0.to_vec()];
    for i in 0..k {
        let mut x = x0.to_vec();
        x[i] = if x[i] + step <= 1.0 {
            x[i] + step
        } else {
            x[i] - step
        };
        simplex.push(x);
    }
    let mut fv: Vec<f64> = simplex.iter().map(|x| f(x)).collect();
    let mut evals = k + 1;
    while evals < max_eval {
        let mut idx: Vec<usize> = (0..=k).collect();
        idx.sort_by(|&a, &b| fv[a].total_cmp(&fv[b]));
        simplex = idx.iter().map(|&i| simplex[i].clone()).collect();
        fv = idx.iter().map(|&i| fv[i]).collect();
        let spread = simplex
            .iter()
            .skip(1)
            .map(|x| {
                x.iter()
                    .zip(&simplex[0])
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max)
            })
            .fold(0.0, f64::max);
        if (fv[k] - fv[0]).abs() <= 1e-10 * fv[0].abs().max(1e-12) && spread < 1e-6 || spread < 1e-7
        {
            break;
        }
        let mut c = vec![0.0; k];
        for x in &simplex[..k] {
            for j in 0..k {
                c[j] += x[j] / k as f64;
            }
        }
        let pt = |a: f64| -> Vec<f64> {
            let mut x: Vec<f64> = (0..k).map(|j| c[j] + a * (simplex[k][j] - c[j])).collect();
            clamp(&mut x);
            x
        };
        let xr = pt(-1.0);
        let fr = f(&xr);
        evals += 1;
        if fr < fv[0] {
            let xe = pt(-2.0);
            let fe = f(&xe);
            evals += 1;
            if fe < fr {
                simplex[k] = xe;
                fv[k] = fe;
            } else {
                simplex[k] = xr;
                fv[k] = fr;
            }
        } else if fr < fv[k - 1] {
            simplex[k] = xr;
            fv[k] = fr;
        } else {
            let xc = if fr < fv[k] { pt(-0.5) } else { pt(0.5) };
            let fc = f(&xc);
            evals += 1;
            if fc < fv[k].min(fr) {
                simplex[k] = xc;
                fv[k] = fc;
            } else {
                for i in 1..=k {
                    let x: Vec<f64> = (0..k)
                        .map(|j| simplex[0][j] + 0.5 * (simplex[i][j] - simplex[0][j]))
                        .collect();
                    fv[i] = f(&x);
                    simplex[i] = x;
                    evals += 1;
                }
            }
        }
    }
    let best = (0..=k).min_by(|&a, &b| fv[a].total_cmp(&fv[b])).unwrap();
    (simplex[best].clone(), fv[best])
}

/// Which parameters of `c` are fitted by default: all but the optional ones.
pub fn default_free(c: &Candidate) -> Vec<bool> {
    c.params().iter().map(|(_, p)| !p.optional).collect()
}

/// Grid intervals per parameter of the hardening start search.
const HARDENING_GRID: usize = 24;

/// Maximum-likelihood fit of `c` on the masked samples (one residual variance per phase,
/// see [`PhaseSse`]); multi-start Nelder–Mead in unit space over the `free` parameters (the
/// others stay at their neutral value). Returns the parameters and their plain sum of
/// squared residuals.
pub fn fit(
    c: &Candidate,
    data: &[TrialData],
    mask: &[Vec<bool>],
    inits: &[Vec<f64>],
    free: &[bool],
) -> (Vec<f64>, f64) {
    fit_in(c, data, mask, inits, free, Nuisance::Global)
}

/// [`fit`] under a given [`Nuisance`].
pub fn fit_in(
    c: &Candidate,
    data: &[TrialData],
    mask: &[Vec<bool>],
    inits: &[Vec<f64>],
    free: &[bool],
    nuisance: Nuisance,
) -> (Vec<f64>, f64) {
    let specs: Vec<ParamSpec> = c.params().into_iter().map(|(_, p)| p).collect();
    let idx: Vec<usize> = (0..specs.len()).filter(|&i| free[i]).collect();
    let k = idx.len();
    let neutral = to_unit(&specs, &c.neutral());
    let full = |u: &[f64]| -> Vec<f64> {
        let mut x = neutral.clone();
        for (&i, &v) in idx.iter().zip(u) {
            x[i] = v;
        }
        to_theta(&specs, &x)
    };
    // the phase-variance likelihood (see `PhaseSse`)
    let obj = |u: &[f64]| {
        let acc = phase_sse_in(c, &full(u), data, mask, nuisance);
        acc.log_mse_sum(acc.total().1 as f64)
    };
    if k == 0 {
        let theta = full(&[]);
        let plain = sse_in(c, &theta, data, mask, nuisance).0;
        return (theta, plain);
    }
    let sub_unit = |th: &[f64]| -> Vec<f64> {
        let u = to_unit(&specs, th);
        idx.iter().map(|&i| u[i].clamp(0.0, 1.0)).collect()
    };
    let mut starts: Vec<Vec<f64>> = vec![sub_unit(&c.neutral())];
    for th in inits {
        starts.push(sub_unit(th));
    }
    // spread starts: hereditary and delay parameters have local minima
    starts.push(vec![0.3; k]);
    starts.push(vec![0.7; k]);
    // Hardening's scale · exp(rate · depth) has a narrow curved valley (a stiffer curve
    // needs a much smaller small-strain scale) that no start above reaches: on the cadaver
    // table every start ended at rate 0 with 20× the error of the valley. Its prediction is
    // analytic (no re-simulation), so a coarse grid over both parameters is cheap.
    if k == 2 && c.0.len() == 1 && c.0[0] == Effect::Hardening {
        let mut grid_best = (vec![0.0; 2], f64::INFINITY);
        for i in 0..=HARDENING_GRID {
            for j in 0..=HARDENING_GRID {
                let u = vec![
                    i as f64 / HARDENING_GRID as f64,
                    j as f64 / HARDENING_GRID as f64,
                ];
                let v = obj(&u);
                if v < grid_best.1 {
                    grid_best = (u, v);
                }
            }
        }
        starts.push(grid_best.0);
    }
    let mut best: (Vec<f64>, f64) = (starts[0].clone(), f64::INFINITY);
    for s in starts {
        let (u, v) = nelder_mead(&obj, &s, 0.15, 150 * k + 100);
        if v < best.1 {
            best = (u, v);
        }
    }
    // polish from the best
    let (u, v) = nelder_mead(&obj, &best.0, 0.03, 100 * k + 50);
    if v < best.1 {
        best = (u, v);
    }
    let theta = full(&best.0);
    let plain = sse_in(c, &theta, data, mask, nuisance).0;
    (theta, plain)
}

/// Standard errors from the Gauss–Newton covariance s²(JᵀJ)⁻¹ at the optimum, for the
/// `free` parameters (the others are held: 0).
pub fn uncertainty(
    c: &Candidate,
    theta: &[f64],
    data: &[TrialData],
    free: &[bool],
    nuisance: Nuisance,
) -> Vec<f64> {
    let specs: Vec<ParamSpec> = c.params().into_iter().map(|(_, p)| p).collect();
    let idx: Vec<usize> = (0..specs.len()).filter(|&i| free[i]).collect();
    let k = idx.len();
    if k == 0 {
        return vec![0.0; specs.len()];
    }
    let resid = |th: &[f64]| -> Vec<f64> {
        let (mut grid, mut out) = (Vec::new(), Vec::new());
        let mut r = Vec::new();
        for d in data {
            let all = vec![true; d.t.len()];
            predict_in(c, th, d, &all, nuisance, &mut grid, &mut out);
            for (p, f) in out.iter().zip(&d.f) {
                r.extend_from_slice(&sub(*p, *f));
            }
        }
        r
    };
    let r0 = resid(theta);
    let m = r0.len();
    let mut jac = nalgebra::DMatrix::<f64>::zeros(m, k);
    for (j, &pi) in idx.iter().enumerate() {
        let h = 1e-4 * (specs[pi].hi - specs[pi].lo).max(1e-9) + 1e-6 * theta[pi].abs();
        let (mut tp, mut tm) = (theta.to_vec(), theta.to_vec());
        tp[pi] += h;
        tm[pi] -= h;
        let (rp, rm) = (resid(&tp), resid(&tm));
        for i in 0..m {
            jac[(i, j)] = (rp[i] - rm[i]) / (2.0 * h);
        }
    }
    let s2 = r0.iter().map(|v| v * v).sum::<f64>() / (m.saturating_sub(k).max(1)) as f64;
    let jtj = jac.transpose() * &jac;
    let mut out = vec![0.0; specs.len()];
    let inv = jtj.try_inverse();
    for (j, &pi) in idx.iter().enumerate() {
        out[pi] = match &inv {
            Some(inv) => (s2 * inv[(j, j)]).max(0.0).sqrt(),
            None => f64::NAN,
        };
    }
    out
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FittedParam {
    pub effect: String,
    pub name: String,
    pub unit: String,
    pub value: f64,
    /// One standard error (Gauss–Newton), same unit.
    pub std: f64,
}

/// A candidate fitted, cross-validated and scored.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CandidateScore {
    pub effect: String,
    pub n_params: usize,
    pub params: Vec<FittedParam>,
    /// Fit on all trials.
    pub fit_rmse: f64,
    pub bic: f64,
    /// BIC minus the baseline's (negative = better).
    pub delta_bic: f64,
    /// Pooled over held-out folds.
    pub heldout_rmse: f64,
    pub heldout_shrink: f64,
    /// Held-out phase-weighted RMSE ([`PhaseSse::weighted_rmse`]) and its shrink against
    /// the baseline's: what the verdict weighs (a sensor bias out of contact counts against
    /// the noise there, not against the model error in contact).
    #[serde(default)]
    pub heldout_weighted_rmse: f64,
    #[serde(default)]
    pub heldout_weighted_shrink: f64,
    /// Study metric (mean normal force in contact): mean |simulated − measured| over trials,
    /// held-out, N.
    pub heldout_study_error: f64,
    /// Ranking score: held-out phase-variance log-likelihood (effective values) with a
    /// BIC-style parameter penalty.
    pub score: f64,
    #[serde(skip)]
    pub theta: Vec<f64>,
    /// Held-out squared residuals per variance group (phase), pooled over trials, and per
    /// trial: the verdict weighs an effect on the phases that carry it and asks that its gain
    /// hold trial by trial.
    #[serde(skip)]
    pub heldout_groups: PhaseSse,
    #[serde(skip)]
    pub heldout_trials: Vec<PhaseSse>,
    /// Parameters fitted per fold (calibration trials only): their spread is the jackknife
    /// uncertainty of a fit across independent trials.
    #[serde(skip)]
    pub fold_theta: Vec<Vec<f64>>,
    /// The global stiffness scale fitted with this candidate (the nuisance every candidate
    /// carries; for `hardening` its small-strain scale).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stiffness_scale: Option<f64>,
    /// The stiffness scale fitted per fold.
    #[serde(skip)]
    pub stiffness_folds: Vec<f64>,
    /// Held-out prediction at every measurement time, per trial.
    #[serde(skip)]
    pub heldout_pred: Vec<Vec<[f64; 3]>>,
}

/// Effective number of independent residual values (samples are correlated in time).
pub fn effective_n(n_values: usize) -> f64 {
    (n_values as f64 / 10.0).max(30.0)
}

pub fn study_metric(d: &TrialData, pred: &[[f64; 3]]) -> (f64, f64) {
    let idx: Vec<usize> = (0..d.t.len())
        .filter(|&i| d.phase[i] != super::metrics::Phase::Approach)
        .collect();
    if idx.is_empty() {
        return (0.0, 0.0);
    }
    let m = idx.iter().map(|&i| dot(d.f[i], d.normal)).sum::<f64>() / idx.len() as f64;
    let p = idx.iter().map(|&i| dot(pred[i], d.normal)).sum::<f64>() / idx.len() as f64;
    (m, p)
}

/// Fit `c` per fold (held-out score) and on everything (parameters, BIC).
pub fn score_candidate(
    c: &Candidate,
    data: &[TrialData],
    folds: &[Fold],
    baseline: &Baseline,
    inits: &[Vec<f64>],
) -> CandidateScore {
    score_candidate_in(c, data, folds, baseline, inits, Nuisance::Global)
}

/// [`score_candidate`] under a given [`Nuisance`]: in `PerTrial` every trial, calibration
/// or held out, gets its own tissue scale, profiled on its own samples.
pub fn score_candidate_in(
    c: &Candidate,
    data: &[TrialData],
    folds: &[Fold],
    baseline: &Baseline,
    inits: &[Vec<f64>],
    nuisance: Nuisance,
) -> CandidateScore {
    let all: Vec<Vec<bool>> = data.iter().map(|d| vec![true; d.t.len()]).collect();
    let n_all = data.iter().map(|d| 3 * d.t.len()).sum::<usize>();
    let ne_all = effective_n(n_all);
    // BIC of the phase-variance likelihood; the same judged on effective values only
    // (samples are correlated in time: the plain BIC lets extra terms soak up model error)
    let bic_of =
        |acc: &PhaseSse, k: usize| acc.log_mse_sum(n_all as f64) + k as f64 * (n_all as f64).ln();
    let crit = |acc: &PhaseSse, k: usize| acc.log_mse_sum(ne_all) + k as f64 * ne_all.ln();
    let mut free = default_free(c);
    let (mut theta, mut sse_all) = fit_in(c, data, &all, inits, &free, nuisance);
    let mut k = free.iter().filter(|&&f| f).count();
    let mut acc_all = phase_sse_in(c, &theta, data, &all, nuisance);
    let mut bic = bic_of(&acc_all, k);
    if free.iter().any(|f| !f) {
        // the optional parameters (second Prony term) are kept only when they lower the
        // penalised fit clearly: nested models, so the richer fit starts from the simpler
        // one's optimum
        let all_free = vec![true; free.len()];
        let specs: Vec<ParamSpec> = c.params().into_iter().map(|(_, p)| p).collect();
        let mut seeded = theta.clone();
        for (i, p) in specs.iter().enumerate() {
            if p.optional && !p.log {
                seeded[i] = p.lo + 0.1 * (p.hi - p.lo);
            }
        }
        let mut fi = inits.to_vec();
        fi.push(theta.clone());
        fi.push(seeded);
        let (theta2, sse2) = fit_in(c, data, &all, &fi, &all_free, nuisance);
        let k2 = all_free.len();
        let acc2 = phase_sse_in(c, &theta2, data, &all, nuisance);
        // and the extra term must remove a quarter of what the simpler fit leaves: a few
        // percent is what it absorbs of other effects' model error (a tilt, a coarse mesh)
        if crit(&acc2, k2) < crit(&acc_all, k) - 10.0
            && acc2.weighted_rmse().powi(2) < 0.75 * acc_all.weighted_rmse().powi(2)
        {
            bic = bic_of(&acc2, k2);
            (theta, sse_all, k, acc_all, free) = (theta2, sse2, k2, acc2, all_free);
        }
    }
    let _ = acc_all;
    let mut held_pred: Vec<Vec<[f64; 3]>> =
        data.iter().map(|d| vec![[0.0; 3]; d.t.len()]).collect();
    let mut held = PhaseSse::default();
    let mut held_trials = vec![PhaseSse::default(); data.len()];
    let (mut grid, mut out) = (Vec::new(), Vec::new());
    let mut fold_theta = Vec::with_capacity(folds.len());
    for f in folds {
        let mut fi = inits.to_vec();
        fi.push(theta.clone());
        let (th, _) = fit_in(c, data, &f.calib, &fi, &free, nuisance);
        fold_theta.push(th.clone());
        for (i, d) in data.iter().enumerate() {
            if !f.held[i].iter().any(|&b| b) {
                continue;
            }
            predict_in(c, &th, d, &f.held[i], nuisance, &mut grid, &mut out);
            for j in 0..d.t.len() {
                if f.held[i][j] {
                    held_pred[i][j] = out[j];
                    held.push(d.var_group[j], sub(out[j], d.f[j]));
                    held_trials[i].push(d.var_group[j], sub(out[j], d.f[j]));
                }
            }
        }
    }
    let heldout_rmse = held.rmse();
    let heldout_weighted_rmse = held.weighted_rmse();
    let se = uncertainty(c, &theta, data, &free, nuisance);
    let params = c
        .params()
        .into_iter()
        .zip(theta.iter().zip(&se))
        .zip(&free)
        .filter(|(_, &f)| f)
        .map(|(((e, p), (&v, &s)), _)| FittedParam {
            effect: e.name().into(),
            name: p.name.into(),
            unit: p.unit.into(),
            value: v,
            std: s,
        })
        .collect();
    let study: f64 = data
        .iter()
        .zip(&held_pred)
        .map(|(d, p)| {
            let (m, s) = study_metric(d, p);
            (s - m).abs()
        })
        .sum::<f64>()
        / data.len().max(1) as f64;
    let ne = effective_n(held.total().1);
    let score = held.log_mse_sum(ne) + k as f64 * ne.ln();
    let shrink = |x: f64, x0: f64| if x0 > 0.0 { 1.0 - x / x0 } else { 0.0 };
    CandidateScore {
        effect: c.name(),
        n_params: k,
        params,
        fit_rmse: (sse_all / n_all.max(1) as f64).sqrt(),
        bic,
        delta_bic: bic - baseline.bic,
        heldout_rmse,
        heldout_shrink: shrink(heldout_rmse, baseline.rmse),
        heldout_weighted_rmse,
        heldout_weighted_shrink: shrink(heldout_weighted_rmse, baseline.weighted_rmse),
        heldout_study_error: study,
        score,
        theta,
        heldout_groups: held,
        heldout_trials: held_trials,
        fold_theta,
        stiffness_scale: None,
        stiffness_folds: vec![],
        heldout_pred: held_pred,
    }
}

/// Which effects can be assessed on these data.
pub fn applicable(e: Effect, quasi_static: bool) -> bool {
    // a quasi-static table has no time history and no sliding
    !(quasi_static && (e.time_dependent() || e.needs_tangential()))
}

/// Pairs that are not redundant (one nested in the other).
pub fn pair_allowed(a: Effect, b: Effect) -> bool {
    let redundant = |x: Effect, y: Effect| {
        matches!(
            (x, y),
            (Effect::Modulus, Effect::Hardening) | (Effect::Hardening, Effect::Modulus)
        )
    };
    a != b && !redundant(a, b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nelder_mead_finds_quadratic_minimum() {
        let f = |x: &[f64]| (x[0] - 0.3).powi(2) + 10.0 * (x[1] - 0.8).powi(2) + 0.1;
        let (x, v) = nelder_mead(&f, &[0.5, 0.5], 0.1, 2000);
        assert!(
            (x[0] - 0.3).abs() < 1e-4 && (x[1] - 0.8).abs() < 1e-4,
            "{x:?}"
        );
        assert!((v - 0.1).abs() < 1e-8);
        // bound-constrained: minimum outside the cube lands on the face
        let g = |x: &[f64]| (x[0] + 0.5).powi(2);
        let (x, _) = nelder_mead(&g, &[0.5], 0.1, 500);
        assert!(x[0] < 1e-6);
    }
}
