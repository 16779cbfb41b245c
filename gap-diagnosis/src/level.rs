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
use crate::experiment::Region;
use crate::fit::Nuisance;
use crate::separability::SEPARATION_SE;
use crate::signal::dot;
use std::collections::BTreeMap;

/// The measured normal force over the replay's where the replay presses, pooled over the
/// trials, with its between-trial standard error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DataLevel {
    /// Σ f·n / Σ f_replay·n over every trial's samples in the replay's contact.
    pub ratio: f64,
    /// Delete-one jackknife over the trials, within each probing region (`strata`).
    pub se: f64,
    pub trials: usize,
    /// How many regions the jackknife was taken within (1: over every trial together).
    pub strata: usize,
}

/// Which side of the level band a level lies beyond.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Beyond {
    Below,
    Above,
}

/// Fewest trials with a contact for a between-trial error.
pub const MIN_LEVEL_TRIALS: usize = 3;

/// Fewest trials in contact in every region for the error to be taken within the regions.
/// Two would leave one degree of freedom a region: the refined truth's CI-size cases (two
/// trials a region) read their modulus ×1.975 ± 0.162 within the regions against ± 0.132
/// over the six trials together, an error no better known than the one it replaces.
pub const MIN_STRATUM_TRIALS: usize = 3;

/// The measured level of `data` ([`DataLevel`]); None with fewer than [`MIN_LEVEL_TRIALS`]
/// trials in contact. Samples where the replay does not press are left out: a device's bias
/// there is no level, and the replay's force is what the ratio is of.
///
/// The error is taken within the probing regions when every region present (unlabelled
/// trials one of them) has [`MIN_STRATUM_TRIALS`] trials in contact: the study's protocol
/// probes each region as often, so how one region's level differs from another's is fixed
/// by the design and not a sampling error of the pooled level. On the independent P2 code
/// the mid-body presses read ×1.3–2.2 of the replay's and the others ×0.8–1.5; taken within
/// the regions, the error rule (g) of `decide` weighs a level by fell 3–18% on twelve of its
/// cases (README, "Friction on the independent code, and a level's error within regions").
pub fn data_level(data: &[TrialData]) -> Option<DataLevel> {
    let sums: Vec<(Option<Region>, f64, f64)> = data
        .iter()
        .map(|d| {
            let (m, r) =
                d.f.iter()
                    .zip(&d.base_at_t)
                    .map(|(&f, &b)| (dot(f, d.normal), dot(b, d.normal)))
                    .filter(|&(_, b)| b != 0.0)
                    .fold((0.0, 0.0), |(m, r), (f, b)| (m + f, r + b));
            (d.region, m, r)
        })
        .filter(|&(_, _, r)| r != 0.0)
        .collect();
    let n = sums.len();
    if n < MIN_LEVEL_TRIALS {
        return None;
    }
    let mut by_region: BTreeMap<Option<Region>, Vec<(f64, f64)>> = BTreeMap::new();
    for &(region, a, b) in &sums {
        by_region.entry(region).or_default().push((a, b));
    }
    let stratified =
        by_region.len() > 1 && by_region.values().all(|t| t.len() >= MIN_STRATUM_TRIALS);
    let strata: Vec<Vec<(f64, f64)>> = if stratified {
        by_region.into_values().collect()
    } else {
        vec![sums.iter().map(|&(_, a, b)| (a, b)).collect()]
    };
    let total = |v: &[(f64, f64)]| v.iter().fold((0.0, 0.0), |(m, r), &(a, b)| (m + a, r + b));
    let (measured, replayed) = sums
        .iter()
        .fold((0.0, 0.0), |(m, r), &(_, a, b)| (m + a, r + b));
    let ratio = measured / replayed;
    // Stratified delete-one jackknife (JKn): a trial left out of its region, the region's
    // others weighted up to keep its share, and the spread of those ratios taken within
    // each region. With one region it is the plain delete-one jackknife.
    let var: f64 = strata
        .iter()
        .map(|stratum| {
            let k = stratum.len() as f64;
            let (sm, sr) = total(stratum);
            let up = k / (k - 1.0);
            let without: Vec<f64> = stratum
                .iter()
                .map(|&(a, b)| (measured - sm + up * (sm - a)) / (replayed - sr + up * (sr - b)))
                .collect();
            let mean = without.iter().sum::<f64>() / k;
            without.iter().map(|r| (r - mean).powi(2)).sum::<f64>() * (k - 1.0) / k
        })
        .sum();
    let se = var.sqrt();
    (ratio.is_finite() && se.is_finite()).then_some(DataLevel {
        ratio,
        se,
        trials: n,
        strata: strata.len(),
    })
}

impl DataLevel {
    /// How the error was taken, for a verdict's reason: empty over every trial together.
    pub fn error_basis(&self) -> String {
        if self.strata > 1 {
            format!(" (its error within {} regions)", self.strata)
        } else {
            String::new()
        }
    }
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

    /// A trial pressed along z: the replay's force `replayed` N while it presses (the first
    /// and last samples free), the measured force `measured` N there and `bias` N where it
    /// does not.
    fn pressed(replayed: f64, measured: f64, bias: f64) -> TrialData {
        in_region(None, replayed, measured, bias)
    }

    /// [`pressed`], probed in `region`.
    fn in_region(region: Option<Region>, replayed: f64, measured: f64, bias: f64) -> TrialData {
        crate::dataset::pressed_at_rest(region, 20, 0.02, [replayed, measured, bias])
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
    fn a_level_that_differs_by_region_is_weighed_by_its_spread_within_the_regions() {
        use crate::experiment::Region::{Anterior, Mid, Posterior};
        // the mid-body reads ×1.6 ± 0.1 and the others ×1.0 ± 0.1: over the nine trials
        // together the spread is mostly between the regions, which the design fixes
        let levels = [
            (Posterior, [0.9, 1.0, 1.1]),
            (Mid, [1.5, 1.6, 1.7]),
            (Anterior, [0.9, 1.0, 1.1]),
        ];
        let data: Vec<TrialData> = levels
            .iter()
            .flat_map(|&(r, ls)| ls.map(|l| in_region(Some(r), 10.0, 10.0 * l, 0.0)))
            .collect();
        let l = data_level(&data).expect("nine trials in contact");
        assert_eq!((l.trials, l.strata), (9, 3));
        assert!((l.ratio - 1.2).abs() < 1e-12, "{l:?}");
        // equal forces: a region's trial left out and its others weighted ×3/2 moves the
        // pooled ratio by ∓0.05/3, so each region adds (2/3)·2·(0.05/3)² to the variance
        let within = (3.0 * 2.0 / 3.0 * 2.0 * (0.05_f64 / 3.0).powi(2)).sqrt();
        assert!((l.se - within).abs() < 1e-12, "{l:?} against {within}");
        // the same trials without their regions: the plain jackknife, 0.104 (×3.1)
        let pooled: Vec<TrialData> = levels
            .iter()
            .flat_map(|&(_, ls)| ls.map(|l| in_region(None, 10.0, 10.0 * l, 0.0)))
            .collect();
        let p = data_level(&pooled).expect("nine trials in contact");
        assert_eq!((p.ratio, p.strata), (l.ratio, 1));
        assert!((p.se - 0.104).abs() < 1e-3, "{p:?} against {l:?}");
        // a region probed twice has too little spread of its own: every trial is weighed
        // together
        let o = data_level(&data[..8]).expect("eight trials in contact");
        assert_eq!(o.strata, 1, "{o:?}");
    }

    #[test]
    fn a_level_is_beyond_the_band_only_by_two_of_its_errors() {
        let band = Nuisance::ALL;
        let (lo, hi) = band.level_band();
        let at = |ratio: f64, se: f64| DataLevel {
            ratio,
            se,
            trials: 15,
            strata: 1,
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
