//! The measured response's level against the replay's, trial by trial: the evidence that a
//! stiffness lies beyond what the nuisances may take.
//!
//! The nuisances' level band ([`crate::fit::LEVEL_MAX`]) lets the floor take a persistent
//! offset of the response. Where the measured level lies beyond it, the floor stops at the
//! band's bound, and what is left of the level is small beside the model error of a replay
//! that is not the specimen: on the independent P2 code's modulus ×1.7 case the floor stopped
//! at ×1.44, and the modulus (×1.71 in level) removed 36% more of the held-out residual at
//! only 1.8 SE trial by trial, so the case read `none`. Every trial reads the level, and there
//! they agree: ×1.769 ± 0.113, 2.9 SE beyond the band (rule (g) of `decide`). Where they do
//! not agree, no level is beyond: the grade-2 case (×0.59) measures ×0.580 ± 0.065.
use crate::dataset::TrialData;
use crate::fit::Nuisance;
use crate::separability::SEPARATION_SE;
use crate::signal::dot;

/// The measured normal force over the replay's where the replay presses, pooled over the
/// trials, with its between-trial standard error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DataLevel {
    /// Σ f·n / Σ f_replay·n over every trial's samples in the replay's contact.
    pub ratio: f64,
    /// Delete-one jackknife over the trials.
    pub se: f64,
    pub trials: usize,
}

/// Which side of the level band a level lies beyond.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Beyond {
    Below,
    Above,
}

/// Fewest trials with a contact for a between-trial error.
pub const MIN_LEVEL_TRIALS: usize = 3;

/// The measured level of `data` ([`DataLevel`]); None with fewer than [`MIN_LEVEL_TRIALS`]
/// trials in contact. Samples where the replay does not press are left out: a device's bias
/// there is no level, and the replay's force is what the ratio is of.
pub fn data_level(data: &[TrialData]) -> Option<DataLevel> {
    let sums: Vec<(f64, f64)> = data
        .iter()
        .map(|d| {
            d.f.iter()
                .zip(&d.base_at_t)
                .map(|(&f, &b)| (dot(f, d.normal), dot(b, d.normal)))
                .filter(|&(_, b)| b != 0.0)
                .fold((0.0, 0.0), |(m, r), (f, b)| (m + f, r + b))
        })
        .filter(|&(_, r)| r != 0.0)
        .collect();
    let n = sums.len();
    if n < MIN_LEVEL_TRIALS {
        return None;
    }
    let (measured, replayed) = sums
        .iter()
        .fold((0.0, 0.0), |(m, r), &(a, b)| (m + a, r + b));
    let ratio = measured / replayed;
    let without: Vec<f64> = sums
        .iter()
        .map(|&(a, b)| (measured - a) / (replayed - b))
        .collect();
    let mean = without.iter().sum::<f64>() / n as f64;
    let var = without.iter().map(|r| (r - mean).powi(2)).sum::<f64>() * (n - 1) as f64 / n as f64;
    let se = var.sqrt();
    (ratio.is_finite() && se.is_finite()).then_some(DataLevel {
        ratio,
        se,
        trials: n,
    })
}

impl DataLevel {
    /// The side of `band`'s level band ([`Nuisance::level_inside`]) this level lies beyond
    /// by at least [`SEPARATION_SE`] of its error; None where it may lie inside.
    pub fn beyond(&self, band: Nuisance) -> Option<Beyond> {
        let (lo, hi) = band.level_band();
        let margin = SEPARATION_SE * self.se;
        if self.ratio + margin <= lo {
            Some(Beyond::Below)
        } else if self.ratio - margin >= hi {
            Some(Beyond::Above)
        } else {
            None
        }
    }
    /// How many of its errors this level lies beyond `band`'s level band (0 inside).
    pub fn beyond_se(&self, band: Nuisance) -> f64 {
        let (lo, hi) = band.level_band();
        let out = (lo - self.ratio).max(self.ratio - hi).max(0.0);
        if self.se > 0.0 {
            out / self.se
        } else if out > 0.0 {
            f64::INFINITY
        } else {
            0.0
        }
    }
}

impl Beyond {
    /// `level` lies beyond `band`'s level band on this side.
    pub fn holds(self, level: f64, band: Nuisance) -> bool {
        match self {
            Beyond::Below => level < band.level_band().0,
            Beyond::Above => level > band.level_band().1,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::prepare;
    use crate::experiment::Trial;
    use crate::model::ProbePath;

    /// A trial pressed along z: the replay's force `replayed` N while it presses (the first
    /// and last samples free), the measured force `measured` N there and `bias` N where it
    /// does not.
    fn pressed(replayed: f64, measured: f64, bias: f64) -> TrialData {
        let (n, dt) = (20, 0.02);
        let t: Vec<f64> = (0..n).map(|i| i as f64 * dt).collect();
        let poses: Vec<msgs::Pose> = (0..n)
            .map(|_| msgs::Pose {
                position: [0.0; 3],
                orientation: [0.0, 0.0, 0.0, 1.0],
            })
            .collect();
        let pressing = |i: usize| (2..n - 2).contains(&i);
        let force: Vec<[f64; 3]> = (0..n)
            .map(|i| [0.0, 0.0, if pressing(i) { measured } else { bias }])
            .collect();
        let base: Vec<[f64; 3]> = (0..n)
            .map(|i| [0.0, 0.0, if pressing(i) { replayed } else { 0.0 }])
            .collect();
        let trial = Trial {
            name: "press".into(),
            file: Default::default(),
            region: None,
            t,
            force,
            pose: poses.clone(),
            lead_in: 0.0,
        };
        let path = ProbePath { t0: 0.0, dt, poses };
        let mut td = prepare(&trial, path, base.clone(), Default::default());
        // the grid is the measurement's own times here
        td.base_at_t = base;
        td
    }

    #[test]
    fn the_measured_level_pools_the_trials_and_leaves_out_where_the_replay_is_free() {
        // ×0.5, ×0.6 and ×0.7 on equal forces; a 0.4 N bias off contact changes nothing
        let data = [
            pressed(10.0, 5.0, 0.4),
            pressed(10.0, 6.0, 0.4),
            pressed(10.0, 7.0, -0.4),
        ];
        let l = data_level(&data).expect("three trials in contact");
        assert!((l.ratio - 0.6).abs() < 1e-12, "{l:?}");
        assert_eq!(l.trials, 3);
        // delete-one ratios 0.65, 0.6, 0.55: (n−1)/n Σ (r − 0.6)² = 2/3 · 0.005
        assert!(
            (l.se - (2.0 / 3.0 * 0.005_f64).sqrt()).abs() < 1e-12,
            "{l:?}"
        );
        // a trial the replay never presses carries no level
        let with_free = [
            pressed(10.0, 5.0, 0.0),
            pressed(10.0, 6.0, 0.0),
            pressed(0.0, 3.0, 0.0),
        ];
        assert_eq!(data_level(&with_free), None);
    }

    #[test]
    fn a_level_is_beyond_the_band_only_by_two_of_its_errors() {
        let band = Nuisance::ALL;
        let (lo, hi) = band.level_band();
        let at = |ratio: f64, se: f64| DataLevel {
            ratio,
            se,
            trials: 15,
        };
        assert_eq!(at(lo - 0.21, 0.1).beyond(band), Some(Beyond::Below));
        assert_eq!(at(lo - 0.19, 0.1).beyond(band), None);
        assert_eq!(at(hi + 0.21, 0.1).beyond(band), Some(Beyond::Above));
        assert_eq!(at(1.0, 0.0).beyond(band), None);
        assert!((at(lo - 0.18, 0.1).beyond_se(band) - 1.8).abs() < 1e-9);
        assert_eq!(at(1.0, 0.1).beyond_se(band), 0.0);
        assert!(Beyond::Below.holds(lo - 0.01, band) && !Beyond::Below.holds(lo + 0.01, band));
        assert!(Beyond::Above.holds(hi + 0.01, band) && !Beyond::Above.holds(hi - 0.01, band));
    }
}
