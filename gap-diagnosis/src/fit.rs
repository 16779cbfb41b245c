//! Fitting candidates on calibration trials, scoring them on held-out trials, ranking.
use super::dataset::{TrialData, VarGroup};
use super::effects::{predict, Candidate, Effect, ParamSpec};
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
#[derive(Debug, Clone, Copy, Default)]
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
    /// (SSE, values) of the phases with fewer than [`MIN_GROUP_VALUES`] values, pooled into
    /// one variance group: the one place that rule is written.
    fn pooled_small(&self) -> (f64, usize) {
        (0..VarGroup::COUNT)
            .filter(|&g| self.n[g] < MIN_GROUP_VALUES)
            .fold((0.0, 0), |(s, n), g| (s + self.sse[g], n + self.n[g]))
    }
    /// (SSE, values) per variance group: each phase with enough values, the rest pooled.
    fn groups(&self) -> Vec<(f64, usize)> {
        let mut out: Vec<(f64, usize)> = (0..VarGroup::COUNT)
            .filter(|&g| self.n[g] >= MIN_GROUP_VALUES)
            .map(|g| (self.sse[g], self.n[g]))
            .collect();
        let (rs, rn) = self.pooled_small();
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
    /// Mean square per variance group as the likelihood sees it: a phase with too few values
    /// gets the pooled mean square of all such phases ([`MIN_GROUP_VALUES`]); never below
    /// [`MSE_FLOOR`]; 0 for a group without values.
    pub fn group_mse(&self) -> [f64; VarGroup::COUNT] {
        let (rs, rn) = self.pooled_small();
        let pooled = (rs / rn.max(1) as f64).max(MSE_FLOOR);
        std::array::from_fn(|g| match self.n[g] {
            0 => 0.0,
            n if n >= MIN_GROUP_VALUES => (self.sse[g] / n as f64).max(MSE_FLOOR),
            _ => pooled,
        })
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

/// Residual sums of `c` at `theta` and stiffness scale `stiffness` over the masked samples,
/// per phase.
pub fn phase_sse(
    c: &Candidate,
    theta: &[f64],
    stiffness: f64,
    data: &[TrialData],
    mask: &[Vec<bool>],
) -> PhaseSse {
    let (mut grid, mut out) = (Vec::new(), Vec::new());
    let mut acc = PhaseSse::default();
    for (d, m) in data.iter().zip(mask) {
        if !m.iter().any(|&b| b) {
            continue;
        }
        predict(c, theta, d, stiffness, &mut grid, &mut out);
        for (j, (p, f)) in out.iter().zip(&d.f).enumerate() {
            if m[j] {
                acc.push(d.var_group[j], sub(*p, *f));
            }
        }
    }
    acc
}

/// Largest factor of the global stiffness nuisance either way: the band is
/// [1/`NUISANCE_MAX`, `NUISANCE_MAX`] (0.8…1.25), about the ±15% by which an independent
/// discretisation of the same specimen differs from the replay (issue 15), with room to fit it.
pub const NUISANCE_MAX: f64 = 1.25;

/// The global stiffness nuisance: one scale of the tissue's whole force, fitted jointly with
/// the baseline and with every candidate, in every fit (calibration folds and all trials).
///
/// No model is the specimen: another discretisation, contact formulation or a specimen a
/// little stiffer than its nominal modulus gives a persistent offset of the whole response.
/// Without a term for it, that offset is the largest residual there is, and it is read as
/// whichever effect can scale the force (`support`, `modulus`), or it hides a small effect
/// (friction in sliding) under its own error. Fitted in every model, it is explained by none
/// of them: an effect must explain what remains after it.
///
/// How `modulus` coexists with it: `modulus` (and `hardening`, whose small-strain scale is
/// the same parameter) is a global stiffness scale itself, so beside it the nuisance would be
/// the same parameter twice. Those candidates do not fit the nuisance; their scale is the
/// total (what they report, and what calibration writes). The baseline with the nuisance is
/// then exactly `modulus` restricted to the band, and `modulus` can only gain on it where its
/// fitted scale lies outside the band: `modulus` wins only when the data need a stiffness
/// change beyond what an unrelated offset can be, by a significant held-out gain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Nuisance {
    pub lo: f64,
    pub hi: f64,
}

impl Nuisance {
    /// No nuisance: the scale is held at 1 (the diagnosis before issue 15).
    pub const OFF: Nuisance = Nuisance { lo: 1.0, hi: 1.0 };
    /// The band [1/[`NUISANCE_MAX`], [`NUISANCE_MAX`]].
    pub const STIFFNESS: Nuisance = Nuisance {
        lo: 1.0 / NUISANCE_MAX,
        hi: NUISANCE_MAX,
    };
    /// The nuisance as fitted beside `c` (held at 1 where `c` carries its own scale).
    pub fn for_candidate(self, c: &Candidate) -> Nuisance {
        if c.absorbs_stiffness() {
            Nuisance::OFF
        } else {
            self
        }
    }
    /// The scale is a free parameter (it counts in the parameter penalties).
    pub fn fitted(self) -> bool {
        self.lo < self.hi
    }
}

/// Per variance group, the residual sums of a prediction affine in the stiffness scale s:
/// residual r(s) = s·a + b, so SSE_g(s) = s² Σa·a + 2s Σa·b + Σb·b.
///
/// The prediction is affine in s ([`predict`]), so one prediction (two with a device term)
/// gives the residual sums at every s: the nuisance is profiled out exactly in each objective
/// evaluation without adding a dimension to the Nelder–Mead search.
#[derive(Debug, Clone, Copy, Default)]
pub struct PhaseQuad {
    aa: [f64; VarGroup::COUNT],
    ab: [f64; VarGroup::COUNT],
    bb: [f64; VarGroup::COUNT],
    n: [usize; VarGroup::COUNT],
}

/// Golden-section iterations of the nuisance profile: the bracket shrinks to 0.618^40 of the
/// band's log width (1e-9), far below what moves a likelihood.
const PROFILE_ITERS: usize = 40;
/// Grid points over the band before the golden section (the profile of a sum of logarithms of
/// quadratics can have more than one minimum).
const PROFILE_GRID: usize = 12;

impl PhaseQuad {
    fn push(&mut self, group: VarGroup, a: [f64; 3], b: [f64; 3]) {
        let g = group as usize;
        self.aa[g] += dot(a, a);
        self.ab[g] += dot(a, b);
        self.bb[g] += dot(b, b);
        self.n[g] += 3;
    }
    /// Residual sums at stiffness scale `s`.
    pub fn at(&self, s: f64) -> PhaseSse {
        let mut acc = PhaseSse::default();
        for g in 0..VarGroup::COUNT {
            acc.sse[g] = (s * s * self.aa[g] + 2.0 * s * self.ab[g] + self.bb[g]).max(0.0);
            acc.n[g] = self.n[g];
        }
        acc
    }
    /// The scale in `band` of largest likelihood (the phase-variance one, [`PhaseSse`]) and
    /// the residual sums there.
    pub fn profile(&self, band: Nuisance) -> (f64, PhaseSse) {
        if !band.fitted() {
            return (band.lo, self.at(band.lo));
        }
        let n = self.n.iter().sum::<usize>() as f64;
        let obj = |x: f64| self.at(x.exp()).log_mse_sum(n);
        let (a, b) = (band.lo.ln(), band.hi.ln());
        let step = (b - a) / PROFILE_GRID as f64;
        let best = (0..=PROFILE_GRID)
            .map(|i| a + i as f64 * step)
            .min_by(|x, y| obj(*x).total_cmp(&obj(*y)))
            .unwrap_or(0.0);
        let (mut lo, mut hi) = ((best - step).max(a), (best + step).min(b));
        let r = 0.5 * (5f64.sqrt() - 1.0);
        let (mut x1, mut x2) = (hi - r * (hi - lo), lo + r * (hi - lo));
        let (mut f1, mut f2) = (obj(x1), obj(x2));
        for _ in 0..PROFILE_ITERS {
            if f1 <= f2 {
                hi = x2;
                (x2, f2) = (x1, f1);
                x1 = hi - r * (hi - lo);
                f1 = obj(x1);
            } else {
                lo = x1;
                (x1, f1) = (x2, f2);
                x2 = lo + r * (hi - lo);
                f2 = obj(x2);
            }
        }
        // the grid point itself when the section found nothing better (a minimum on the edge)
        let x = [(best, obj(best)), (x1, f1), (x2, f2)]
            .into_iter()
            .min_by(|p, q| p.1.total_cmp(&q.1))
            .map(|p| p.0)
            .unwrap_or(0.0);
        let s = x.exp().clamp(band.lo, band.hi);
        (s, self.at(s))
    }
}

/// [`PhaseQuad`] of `c` at `theta` over the masked samples.
pub fn phase_quad(
    c: &Candidate,
    theta: &[f64],
    data: &[TrialData],
    mask: &[Vec<bool>],
) -> PhaseQuad {
    let (mut grid, mut one, mut zero) = (Vec::new(), Vec::new(), Vec::new());
    // without a device term the prediction is linear in the scale: the part at 0 is 0
    let affine = c.0.contains(&Effect::Device);
    let mut acc = PhaseQuad::default();
    for (d, m) in data.iter().zip(mask) {
        if !m.iter().any(|&b| b) {
            continue;
        }
        predict(c, theta, d, 1.0, &mut grid, &mut one);
        if affine {
            predict(c, theta, d, 0.0, &mut grid, &mut zero);
        }
        for j in 0..d.t.len() {
            if m[j] {
                let z = if affine { zero[j] } else { [0.0; 3] };
                acc.push(d.var_group[j], sub(one[j], z), sub(z, d.f[j]));
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

/// Sum of squared residuals over the masked samples at stiffness scale `stiffness`.
pub fn sse(
    c: &Candidate,
    theta: &[f64],
    stiffness: f64,
    data: &[TrialData],
    mask: &[Vec<bool>],
) -> (f64, usize) {
    let (mut grid, mut out) = (Vec::new(), Vec::new());
    let (mut s, mut n) = (0.0, 0usize);
    for (d, m) in data.iter().zip(mask) {
        if !m.iter().any(|&b| b) {
            continue;
        }
        predict(c, theta, d, stiffness, &mut grid, &mut out);
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

/// A fit: the candidate's parameters, the stiffness scale fitted with them (1 when the
/// nuisance is off), and their plain sum of squared residuals.
#[derive(Debug, Clone)]
pub struct Fitted {
    pub theta: Vec<f64>,
    pub stiffness: f64,
    pub sse: f64,
}

/// Maximum-likelihood fit of `c` on the masked samples (one residual variance per phase,
/// see [`PhaseSse`]); multi-start Nelder–Mead in unit space over the `free` parameters (the
/// others stay at their neutral value), the stiffness nuisance profiled out at every
/// evaluation within `nuisance` ([`PhaseQuad::profile`]).
pub fn fit(
    c: &Candidate,
    data: &[TrialData],
    mask: &[Vec<bool>],
    inits: &[Vec<f64>],
    free: &[bool],
    nuisance: Nuisance,
) -> Fitted {
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
    // the phase-variance likelihood (see `PhaseSse`), the nuisance profiled out
    let profiled = |th: &[f64]| -> (f64, PhaseSse) {
        if nuisance.fitted() {
            phase_quad(c, th, data, mask).profile(nuisance)
        } else {
            (nuisance.lo, phase_sse(c, th, nuisance.lo, data, mask))
        }
    };
    let obj = |u: &[f64]| {
        let acc = profiled(&full(u)).1;
        acc.log_mse_sum(acc.total().1 as f64)
    };
    let done = |theta: Vec<f64>| -> Fitted {
        let stiffness = profiled(&theta).0;
        let plain = sse(c, &theta, stiffness, data, mask).0;
        Fitted {
            theta,
            stiffness,
            sse: plain,
        }
    };
    if k == 0 {
        return done(full(&[]));
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
    done(full(&best.0))
}

/// Standard errors from the Gauss–Newton covariance s²(JᵀJ)⁻¹ at the optimum, for the
/// `free` parameters (the others are held: 0), with the stiffness scale held at its fitted
/// value (conditional on it: an effect's parameter that trades against the scale reads a
/// little more certain than it is).
pub fn uncertainty(
    c: &Candidate,
    theta: &[f64],
    stiffness: f64,
    data: &[TrialData],
    free: &[bool],
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
            predict(c, th, d, stiffness, &mut grid, &mut out);
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
    /// BIC-style parameter penalty (the stiffness nuisance counts as a parameter where fitted).
    pub score: f64,
    /// The stiffness nuisance fitted with the candidate on all trials ([`Nuisance`]); absent
    /// where the candidate's own scale is the total (`modulus`, `hardening`) or the nuisance
    /// is off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nuisance_scale: Option<f64>,
    /// Held-out shrink against the nuisance floor (the baseline with the stiffness nuisance
    /// fitted per fold): the larger of the phase-weighted and plain shrinks. What the verdict
    /// requires of an effect, beside its significance ([`CandidateScore::floor_gain_z`]).
    #[serde(default)]
    pub floor_shrink: f64,
    /// Paired held-out gain over the nuisance floor, trial by trial, in standard errors of
    /// its mean over trials ([`crate::separability::gain_over`]); 0 with too few trials.
    #[serde(default)]
    pub floor_gain_z: f64,
    #[serde(skip)]
    pub theta: Vec<f64>,
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

/// Fit `c` per fold (held-out score) and on everything (parameters, BIC), with the stiffness
/// nuisance `nuisance` fitted jointly wherever `c` does not carry its own scale
/// ([`Nuisance::for_candidate`]). The empty candidate is the nuisance floor (named `none`).
pub fn score_candidate(
    c: &Candidate,
    data: &[TrialData],
    folds: &[Fold],
    baseline: &Baseline,
    inits: &[Vec<f64>],
    nuisance: Nuisance,
) -> CandidateScore {
    let nuisance = nuisance.for_candidate(c);
    let extra = usize::from(nuisance.fitted());
    let all: Vec<Vec<bool>> = data.iter().map(|d| vec![true; d.t.len()]).collect();
    let n_all = data.iter().map(|d| 3 * d.t.len()).sum::<usize>();
    let ne_all = effective_n(n_all);
    // BIC of the phase-variance likelihood; the same judged on effective values only
    // (samples are correlated in time: the plain BIC lets extra terms soak up model error)
    let bic_of =
        |acc: &PhaseSse, k: usize| acc.log_mse_sum(n_all as f64) + k as f64 * (n_all as f64).ln();
    let crit = |acc: &PhaseSse, k: usize| acc.log_mse_sum(ne_all) + k as f64 * ne_all.ln();
    let mut free = default_free(c);
    let Fitted {
        mut theta,
        mut stiffness,
        sse: mut sse_all,
    } = fit(c, data, &all, inits, &free, nuisance);
    let mut k = free.iter().filter(|&&f| f).count();
    let mut acc_all = phase_sse(c, &theta, stiffness, data, &all);
    let mut bic = bic_of(&acc_all, k + extra);
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
        let f2 = fit(c, data, &all, &fi, &all_free, nuisance);
        let k2 = all_free.len();
        let acc2 = phase_sse(c, &f2.theta, f2.stiffness, data, &all);
        // and the extra term must remove a quarter of what the simpler fit leaves: a few
        // percent is what it absorbs of other effects' model error (a tilt, a coarse mesh)
        if crit(&acc2, k2) < crit(&acc_all, k) - 10.0
            && acc2.weighted_rmse().powi(2) < 0.75 * acc_all.weighted_rmse().powi(2)
        {
            bic = bic_of(&acc2, k2 + extra);
            (theta, stiffness, sse_all, k, acc_all, free) =
                (f2.theta, f2.stiffness, f2.sse, k2, acc2, all_free);
        }
    }
    let _ = acc_all;
    let mut held_pred: Vec<Vec<[f64; 3]>> =
        data.iter().map(|d| vec![[0.0; 3]; d.t.len()]).collect();
    let mut held = PhaseSse::default();
    let (mut grid, mut out) = (Vec::new(), Vec::new());
    for f in folds {
        let mut fi = inits.to_vec();
        fi.push(theta.clone());
        let ff = fit(c, data, &f.calib, &fi, &free, nuisance);
        for (i, d) in data.iter().enumerate() {
            if !f.held[i].iter().any(|&b| b) {
                continue;
            }
            predict(c, &ff.theta, d, ff.stiffness, &mut grid, &mut out);
            for j in 0..d.t.len() {
                if f.held[i][j] {
                    held_pred[i][j] = out[j];
                    held.push(d.var_group[j], sub(out[j], d.f[j]));
                }
            }
        }
    }
    let heldout_rmse = held.rmse();
    let heldout_weighted_rmse = held.weighted_rmse();
    let se = uncertainty(c, &theta, stiffness, data, &free);
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
    let score = held.log_mse_sum(ne) + (k + extra) as f64 * ne.ln();
    CandidateScore {
        effect: if c.0.is_empty() {
            "none".into()
        } else {
            c.name()
        },
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
        nuisance_scale: nuisance.fitted().then_some(stiffness),
        floor_shrink: 0.0,
        floor_gain_z: 0.0,
        theta,
        heldout_pred: held_pred,
    }
}

/// Held-out shrink of `x` against `x0` (fraction; 0 when `x0` is 0).
pub fn shrink(x: f64, x0: f64) -> f64 {
    if x0 > 0.0 {
        1.0 - x / x0
    } else {
        0.0
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

    /// The profiled nuisance is the scale that fits: exactly inside the band, the band's edge
    /// outside it, and 1 when the nuisance is off.
    #[test]
    fn the_stiffness_nuisance_profile_finds_the_scale_within_its_band() {
        let model = [
            [0.0, 0.0, 2.0],
            [0.1, 0.0, 5.0],
            [0.0, -0.2, 9.0],
            [0.0, 0.0, 0.0],
        ];
        let quad_for = |truth: f64| {
            let mut q = PhaseQuad::default();
            for (i, m) in model.iter().enumerate() {
                let group = if i == 3 {
                    VarGroup::Free
                } else {
                    VarGroup::Hold
                };
                // residual s·m − truth·m: a = m, b = −truth·m
                q.push(group, *m, m.map(|v| -truth * v));
            }
            q
        };
        // noise-free: the likelihood is flat once a phase's mean square is under MSE_FLOOR
        // (here within ~3e-6 of the scale)
        let (s, acc) = quad_for(1.13).profile(Nuisance::STIFFNESS);
        assert!((s - 1.13).abs() < 1e-4, "fitted {s}");
        assert!(acc.total().0 < 1e-6);
        let (s, _) = quad_for(1.6).profile(Nuisance::STIFFNESS);
        assert!((s - NUISANCE_MAX).abs() < 1e-9, "fitted {s}");
        let (s, _) = quad_for(0.5).profile(Nuisance::STIFFNESS);
        assert!((s - 1.0 / NUISANCE_MAX).abs() < 1e-9, "fitted {s}");
        let (s, acc) = quad_for(1.13).profile(Nuisance::OFF);
        assert_eq!(s, 1.0);
        assert!(acc.total().0 > 0.1);
    }

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
