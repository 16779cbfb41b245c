//! Where the gap lies: per-sample geometry (normal, depth, phase) and the residual metrics.
use super::experiment::Region;
use super::signal::{dot, norm, scale, sub};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, PartialOrd, Ord)]
#[serde(rename_all = "lowercase")]
pub enum Phase {
    Approach,
    Loading,
    Hold,
    Unloading,
    Sliding,
}
impl Phase {
    pub const ALL: [Phase; 5] = [
        Phase::Approach,
        Phase::Loading,
        Phase::Hold,
        Phase::Unloading,
        Phase::Sliding,
    ];
    pub fn name(self) -> &'static str {
        match self {
            Phase::Approach => "approach",
            Phase::Loading => "loading",
            Phase::Hold => "hold",
            Phase::Unloading => "unloading",
            Phase::Sliding => "sliding",
        }
    }
}

/// Indentation depth bands, mm (lower edges); the last is open.
pub const DEPTH_BANDS_MM: [f64; 5] = [0.0, 1.0, 2.0, 3.0, 5.0];
pub fn band_label(i: usize) -> String {
    if i + 1 < DEPTH_BANDS_MM.len() {
        format!("{}-{} mm", DEPTH_BANDS_MM[i], DEPTH_BANDS_MM[i + 1])
    } else {
        format!(">{} mm", DEPTH_BANDS_MM[i])
    }
}
pub fn band_of(depth_mm: f64) -> Option<usize> {
    if depth_mm < 0.0 {
        return None;
    }
    Some(
        DEPTH_BANDS_MM
            .iter()
            .rposition(|&e| depth_mm >= e)
            .unwrap_or(0),
    )
}

/// Contact normal of a trial: direction of the simulated (else measured) force at its peak.
pub fn trial_normal(base: &[[f64; 3]], measured: &[[f64; 3]]) -> [f64; 3] {
    let peak = |f: &[[f64; 3]]| {
        f.iter()
            .copied()
            .max_by(|a, b| norm(*a).total_cmp(&norm(*b)))
    };
    for f in [base, measured] {
        if let Some(p) = peak(f) {
            let n = norm(p);
            if n > 0.05 {
                return scale(p, 1.0 / n);
            }
        }
    }
    [0.0, 0.0, 1.0]
}

/// Indentation depth (mm) along −normal from the point where the simulated contact starts.
/// `positions` and `base` on the same grid. Before any contact the depth is negative.
pub fn depth_series(positions: &[[f64; 3]], base: &[[f64; 3]], normal: [f64; 3]) -> Vec<f64> {
    let peak = base.iter().map(|f| norm(*f)).fold(0.0, f64::max);
    let thr = (0.03 * peak).max(0.01);
    let onset = base.iter().position(|f| norm(*f) > thr);
    let p_on = match onset {
        Some(i) => positions[i],
        // no simulated contact: deepest point along −n is the reference
        None => positions
            .iter()
            .copied()
            .min_by(|a, b| dot(*a, normal).total_cmp(&dot(*b, normal)))
            .unwrap_or([0.0; 3]),
    };
    positions
        .iter()
        .map(|p| 1e3 * dot(sub(p_on, *p), normal))
        .collect()
}

/// Phase of each grid point from the depth rate and the tangential speed.
pub fn phases(
    positions: &[[f64; 3]],
    depth_mm: &[f64],
    normal: [f64; 3],
    dt: f64,
    in_contact: &[bool],
) -> Vec<Phase> {
    let n = positions.len();
    let mut out = vec![Phase::Approach; n];
    // rates over a ±w window so 38 Hz jitter does not flip phases
    let w = ((0.06 / dt).round() as usize).max(1);
    for i in 0..n {
        if !in_contact[i] {
            continue;
        }
        let (a, b) = (i.saturating_sub(w), (i + w).min(n - 1));
        if b == a {
            out[i] = Phase::Hold;
            continue;
        }
        let h = (b - a) as f64 * dt;
        let vn = (depth_mm[b] - depth_mm[a]) / h; // mm/s
        let d = sub(positions[b], positions[a]);
        let dn = dot(d, normal);
        let vt = 1e3 * norm(sub(d, scale(normal, dn))) / h; // mm/s
        out[i] = if vt > 0.3 && vt > vn.abs() {
            Phase::Sliding
        } else if vn > 0.1 {
            Phase::Loading
        } else if vn < -0.1 {
            Phase::Unloading
        } else {
            Phase::Hold
        };
    }
    out
}

/// Study-style metrics of one trial (normal = the trial's contact normal).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct TrialMetrics {
    pub rmse: f64,
    pub nrmse: f64,
    pub rmse_normal: f64,
    pub rmse_tangential: f64,
    /// Peak normal force, predicted − measured, N.
    pub peak_error: f64,
    /// Mean normal force during contact (the study's metric), N.
    pub mean_normal_measured: f64,
    pub mean_normal_simulated: f64,
    /// Force–displacement slope during loading, N/mm.
    pub slope_measured: Option<f64>,
    pub slope_simulated: Option<f64>,
    /// Hysteresis area ∮ F·n dδ over the contact, N·mm (= mJ).
    pub hysteresis_measured: f64,
    pub hysteresis_simulated: f64,
}

pub fn trial_metrics(
    meas: &[[f64; 3]],
    pred: &[[f64; 3]],
    normal: [f64; 3],
    depth_mm: &[f64],
    phase: &[Phase],
) -> TrialMetrics {
    let n = meas.len().max(1) as f64;
    let (mut se, mut sen, mut set) = (0.0, 0.0, 0.0);
    for (m, p) in meas.iter().zip(pred) {
        let r = sub(*p, *m);
        let rn = dot(r, normal);
        se += dot(r, r);
        sen += rn * rn;
        set += dot(r, r) - rn * rn;
    }
    let fnm: Vec<f64> = meas.iter().map(|f| dot(*f, normal)).collect();
    let fnp: Vec<f64> = pred.iter().map(|f| dot(*f, normal)).collect();
    let range =
        fnm.iter().cloned().fold(f64::MIN, f64::max) - fnm.iter().cloned().fold(f64::MAX, f64::min);
    let rmse = (se / (3.0 * n)).sqrt();
    let contact: Vec<usize> = (0..meas.len())
        .filter(|&i| phase[i] != Phase::Approach)
        .collect();
    let mean_on = |v: &[f64]| {
        if contact.is_empty() {
            0.0
        } else {
            contact.iter().map(|&i| v[i]).sum::<f64>() / contact.len() as f64
        }
    };
    let loading: Vec<usize> = (0..meas.len())
        .filter(|&i| phase[i] == Phase::Loading)
        .collect();
    let slope = |v: &[f64]| -> Option<f64> {
        if loading.len() < 3 {
            return None;
        }
        let k = loading.len() as f64;
        let mx = loading.iter().map(|&i| depth_mm[i]).sum::<f64>() / k;
        let my = loading.iter().map(|&i| v[i]).sum::<f64>() / k;
        let sxx: f64 = loading.iter().map(|&i| (depth_mm[i] - mx).powi(2)).sum();
        let sxy: f64 = loading
            .iter()
            .map(|&i| (depth_mm[i] - mx) * (v[i] - my))
            .sum();
        (sxx > 1e-12).then(|| sxy / sxx)
    };
    let hyst = |v: &[f64]| -> f64 {
        let mut a = 0.0;
        for w in contact.windows(2) {
            let (i, j) = (w[0], w[1]);
            a += 0.5 * (v[i] + v[j]) * (depth_mm[j] - depth_mm[i]);
        }
        a
    };
    TrialMetrics {
        rmse,
        nrmse: if range > 1e-9 { rmse / range } else { f64::NAN },
        rmse_normal: (sen / n).sqrt(),
        rmse_tangential: (set / (2.0 * n)).sqrt(),
        peak_error: fnp.iter().cloned().fold(f64::MIN, f64::max)
            - fnm.iter().cloned().fold(f64::MIN, f64::max),
        mean_normal_measured: mean_on(&fnm),
        mean_normal_simulated: mean_on(&fnp),
        slope_measured: slope(&fnm),
        slope_simulated: slope(&fnp),
        hysteresis_measured: hyst(&fnm),
        hysteresis_simulated: hyst(&fnp),
    }
}

/// Residual summary of one group of samples (a phase, region, band, axis...).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct GroupResidual {
    pub group: String,
    pub samples: usize,
    /// RMS of the residual per component, N.
    pub rmse: f64,
    /// Mean normal residual (simulated − measured), N.
    pub bias_normal: f64,
    pub rmse_normal: f64,
    pub rmse_tangential: f64,
}

/// Accumulator for grouped residuals.
#[derive(Debug, Clone, Default)]
pub struct Acc {
    pub n: usize,
    pub se: f64,
    pub sen: f64,
    pub sn: f64,
}
impl Acc {
    pub fn push(&mut self, r: [f64; 3], normal: [f64; 3]) {
        let rn = dot(r, normal);
        self.n += 1;
        self.se += dot(r, r);
        self.sen += rn * rn;
        self.sn += rn;
    }
    pub fn rmse(&self) -> f64 {
        if self.n == 0 {
            f64::NAN
        } else {
            (self.se / (3.0 * self.n as f64)).sqrt()
        }
    }
    pub fn summary(&self, group: String) -> GroupResidual {
        let n = self.n.max(1) as f64;
        GroupResidual {
            group,
            samples: self.n,
            rmse: self.rmse(),
            bias_normal: self.sn / n,
            rmse_normal: (self.sen / n).sqrt(),
            rmse_tangential: ((self.se - self.sen).max(0.0) / (2.0 * n)).sqrt(),
        }
    }
}

pub fn region_label(r: Option<Region>) -> &'static str {
    r.map(|r| r.name()).unwrap_or(msgs::protocol::UNLABELLED)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metrics_on_known_signals() {
        // loading 0→2 mm then unloading, measured F = 1 N/mm δ, predicted 2 N/mm δ + 0.1 N lateral
        let n = [0.0, 0.0, 1.0];
        let mut depth = Vec::new();
        for i in 0..=20 {
            depth.push(i as f64 * 0.1);
        }
        for i in (0..20).rev() {
            depth.push(i as f64 * 0.1);
        }
        let meas: Vec<[f64; 3]> = depth.iter().map(|d| [0.0, 0.0, *d]).collect();
        let pred: Vec<[f64; 3]> = depth.iter().map(|d| [0.1, 0.0, 2.0 * d]).collect();
        let phase: Vec<Phase> = (0..depth.len())
            .map(|i| {
                if i <= 20 {
                    Phase::Loading
                } else {
                    Phase::Unloading
                }
            })
            .collect();
        let m = trial_metrics(&meas, &pred, n, &depth, &phase);
        assert!((m.slope_measured.unwrap() - 1.0).abs() < 1e-9);
        assert!((m.slope_simulated.unwrap() - 2.0).abs() < 1e-9);
        assert!((m.peak_error - 2.0).abs() < 1e-9);
        assert!(
            m.hysteresis_measured.abs() < 1e-9,
            "no hysteresis for an elastic loop"
        );
        assert!((m.rmse_tangential - (0.01f64 / 2.0).sqrt()).abs() < 1e-9);
        let se: f64 = depth.iter().map(|d| d * d + 0.01).sum();
        assert!((m.rmse - (se / (3.0 * depth.len() as f64)).sqrt()).abs() < 1e-9);
        // a loop that carries more force on loading than on unloading has positive area
        let meas2: Vec<[f64; 3]> = depth
            .iter()
            .enumerate()
            .map(|(i, d)| [0.0, 0.0, if i <= 20 { 1.5 * d } else { 0.5 * d }])
            .collect();
        let m2 = trial_metrics(&meas2, &pred, n, &depth, &phase);
        assert!(
            (m2.hysteresis_measured - 0.5 * 2.0 * 2.0).abs() < 0.15,
            "{}",
            m2.hysteresis_measured
        );
        assert_eq!(band_of(2.5), Some(2));
        assert_eq!(band_of(7.0), Some(4));
        assert_eq!(band_of(-0.1), None);
    }

    #[test]
    fn phases_of_press_hold_slide_release() {
        let dt = 0.01;
        let n = [0.0, 0.0, 1.0];
        let mut pos = Vec::new();
        for i in 0..100 {
            pos.push([0.0, 0.0, 0.002 - i as f64 * 1e-5]); // approach then load at 1 mm/s
        }
        for _ in 0..100 {
            pos.push(*pos.last().unwrap());
        }
        for i in 0..100 {
            let p = *pos.last().unwrap();
            pos.push([p[0] + if i > 0 { 2e-5 } else { 0.0 }, p[1], p[2]]);
        }
        for _ in 0..100 {
            let p = *pos.last().unwrap();
            pos.push([p[0], p[1], p[2] + 1e-5]);
        }
        let depth: Vec<f64> = pos.iter().map(|p| 1e3 * (0.0015 - p[2])).collect();
        let contact: Vec<bool> = depth.iter().map(|d| *d > 0.0).collect();
        let ph = phases(&pos, &depth, n, dt, &contact);
        assert_eq!(ph[10], Phase::Approach);
        assert_eq!(ph[90], Phase::Loading);
        assert_eq!(ph[150], Phase::Hold);
        assert_eq!(ph[250], Phase::Sliding);
        assert_eq!(ph[320], Phase::Unloading);
        assert_eq!(ph[380], Phase::Approach);
    }
}
