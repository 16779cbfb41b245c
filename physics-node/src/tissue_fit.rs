//! Fit of a scene's tissue response to a measured force–displacement table (issue 13,
//! points 1–2): the elastic support (`[scene.meniscus] support_stiffness`) and the
//! stiffening rate (`[scene.material] strain_stiffening`) that make the scene's quasi-static
//! probe curve at a region's site reproduce the table. The curve is the FEM's response at each
//! trial; nothing reshapes the output force.
//!
//! Why these two: under a probe the table is soft at first (≈ 0.3 N/mm over the first 2 mm)
//! and ten times stiffer by 7.6 mm. The body under the probe is a 3.6 mm layer, so 7.6 mm of
//! probe travel is mostly the meniscus moving on what holds it (the support's compliance);
//! the stiffening law turns that into the table's hardening. The modulus stays the study's
//! (a support-dominated press cannot separate it from the support).
//!
//! Method: for a stiffening rate r the support stiffness k(r) is the one whose curve meets
//! the table's peak (secant iterations on ln k; the peak force grows about in proportion to
//! k); the rate is then chosen by golden-section search for the smallest largest error over
//! the table's points. A trial with a rolled-back (faulty) physics step counts as failed.

use crate::probe_curve::{self, ForceTable, ProbeCurveError, ProbeCurveOptions, Region};
use launch_config::SceneConfig;
use serde::Serialize;
use std::path::Path;

/// Range of the stiffening rate searched (per unit strain).
pub const RATE_RANGE: [f64; 2] = [0.0, 2.0];
/// The rate search stops when its bracket is narrower than this.
pub const RATE_TOLERANCE: f64 = 0.01;
/// Support stiffness the search starts from, N/m per supported node.
pub const START_SUPPORT_N_PER_M: f64 = 5.0;
/// The support matches the peak once within this relative error.
const PEAK_TOLERANCE: f64 = 0.005;
const SECANT_ITERATIONS: usize = 8;

/// The fitted tissue.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TissueFit {
    /// N/m per supported node.
    pub support_stiffness: f64,
    /// Per unit strain.
    pub strain_stiffening: f64,
    /// Largest |simulated − table| over the table's points, N and % of the table's peak.
    pub max_error_n: f64,
    pub max_error_percent_of_peak: f64,
    /// Probe curves simulated.
    pub evaluations: usize,
}

/// Errors of a fit.
#[derive(Debug, thiserror::Error)]
pub enum TissueFitError {
    #[error(transparent)]
    Curve(#[from] ProbeCurveError),
    #[error("the scene's inferior surface is held rigidly (`fixed = \"none\"`?): a support stiffness needs supported nodes")]
    NoSupport,
    #[error("no stiffening rate in {lo}..={hi} gives a press that meets the table's peak without physics faults and with the tip still pressing at the table's last point")]
    NoFit { lo: f64, hi: f64 },
}

/// One simulated trial.
#[derive(Debug, Clone, Copy)]
struct Trial {
    k: f64,
    rate: f64,
    /// Simulated force at the table's last point over the table's force there.
    peak_ratio: f64,
    max_error_n: f64,
}

struct Fitter<'a> {
    base: &'a SceneConfig,
    data_dir: &'a Path,
    table: &'a ForceTable,
    region: Region,
    evaluations: usize,
}

impl Fitter<'_> {
    /// The probe curve with support `k` and rate `rate`; None when the press had a fault.
    fn trial(&mut self, k: f64, rate: f64) -> Result<Option<Trial>, TissueFitError> {
        let mut scene = self.base.clone();
        scene.meniscus.support_stiffness = k;
        scene.material.strain_stiffening = rate;
        let opts = ProbeCurveOptions::new(self.region, self.table.max_displacement_m());
        self.evaluations += 1;
        let curve = probe_curve::run(&scene, self.data_dir, &opts)?;
        if curve.faulty_steps() > 0 {
            return Ok(None);
        }
        let cmp = probe_curve::compare(&curve, self.table)?;
        let last = cmp.points.last().expect("a table has rows");
        Ok(Some(Trial {
            k,
            rate,
            peak_ratio: last.simulated_n / last.table_n,
            max_error_n: cmp.max_error_n,
        }))
    }

    /// The support that meets the table's peak at `rate`, starting from `k0`.
    fn matched(&mut self, rate: f64, k0: f64) -> Result<Option<Trial>, TissueFitError> {
        let Some(mut a) = self.trial(k0, rate)? else {
            return Ok(None);
        };
        if !(a.peak_ratio > 0.0) {
            return Ok(None);
        }
        if (a.peak_ratio - 1.0).abs() <= PEAK_TOLERANCE {
            return Ok(Some(a));
        }
        // First guess: force in proportion to the support.
        let Some(mut b) = self.trial(k0 / a.peak_ratio, rate)? else {
            return Ok(None);
        };
        for _ in 0..SECANT_ITERATIONS {
            if (b.peak_ratio - 1.0).abs() <= PEAK_TOLERANCE || !(b.peak_ratio > 0.0) {
                break;
            }
            let (ga, gb) = (a.peak_ratio.ln(), b.peak_ratio.ln());
            let (la, lb) = (a.k.ln(), b.k.ln());
            let next = if (gb - ga).abs() > 1e-12 {
                lb - gb * (lb - la) / (gb - ga)
            } else {
                lb - gb
            };
            // At most a factor 4 per iteration: the response is not linear in ln k far away.
            let next = next.clamp(lb - 4f64.ln(), lb + 4f64.ln());
            a = b;
            b = match self.trial(next.exp(), rate)? {
                Some(t) => t,
                None => return Ok(None),
            };
        }
        Ok((b.peak_ratio > 0.0).then_some(b))
    }
}

/// Fits the support stiffness and stiffening rate of `base` (its mesh, material, solver and
/// probe kept) to `table` at the middle site of `region`.
pub fn fit_table(
    base: &SceneConfig,
    data_dir: &Path,
    table: &ForceTable,
    region: Region,
) -> Result<TissueFit, TissueFitError> {
    if base.meniscus.fixed.trim() == "none" {
        return Err(TissueFitError::NoSupport);
    }
    let mut f = Fitter {
        base,
        data_dir,
        table,
        region,
        evaluations: 0,
    };
    let [lo, hi] = RATE_RANGE;
    let mut k_guess = if base.meniscus.support_stiffness > 0.0 {
        base.meniscus.support_stiffness
    } else {
        START_SUPPORT_N_PER_M
    };
    // Golden section over the rate; each point's support meets the peak. A failed point
    // scores infinitely bad, so the search moves away from it.
    let eval =
        |f: &mut Fitter, rate: f64, k: &mut f64| -> Result<(f64, Option<Trial>), TissueFitError> {
            let t = f.matched(rate, *k)?;
            if let Some(t) = t {
                *k = t.k;
                Ok((t.max_error_n, Some(t)))
            } else {
                Ok((f64::INFINITY, None))
            }
        };
    let phi = (5f64.sqrt() - 1.0) / 2.0;
    let (mut a, mut b) = (lo, hi);
    let mut c = b - phi * (b - a);
    let mut d = a + phi * (b - a);
    let (mut fc, mut tc) = eval(&mut f, c, &mut k_guess)?;
    let (mut fd, mut td) = eval(&mut f, d, &mut k_guess)?;
    while b - a > RATE_TOLERANCE {
        if fc <= fd {
            b = d;
            d = c;
            (fd, td) = (fc, tc);
            c = b - phi * (b - a);
            (fc, tc) = eval(&mut f, c, &mut k_guess)?;
        } else {
            a = c;
            c = d;
            (fc, tc) = (fd, td);
            d = a + phi * (b - a);
            (fd, td) = eval(&mut f, d, &mut k_guess)?;
        }
    }
    let best = match (tc, td) {
        (Some(x), Some(y)) => Some(if x.max_error_n <= y.max_error_n { x } else { y }),
        (x, y) => x.or(y),
    };
    let best = best.ok_or(TissueFitError::NoFit { lo, hi })?;
    let peak = table.peak_n();
    Ok(TissueFit {
        support_stiffness: best.k,
        strain_stiffening: best.rate,
        max_error_n: best.max_error_n,
        max_error_percent_of_peak: 100.0 * best.max_error_n / peak,
        evaluations: f.evaluations,
    })
}
