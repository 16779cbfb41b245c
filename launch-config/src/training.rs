//! `[training]`: blinded degeneration-grade training (`arthrosim train`, owned by the
//! `training` crate). Each specimen gets a hidden modulus scale; the trainee probes and
//! answers a grade (its index in `modulus_scales`).
use serde::{Deserialize, Serialize};

/// Modulus factor per Fischenich grade step (grade 2 = −41%), as the physics' presets.
pub const FISCHENICH_LOSS_PER_GRADE: f64 = 0.205;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainingConfig {
    /// Modulus scale of each grade, grade 0 first (healthy = 1). Empty: the Fischenich
    /// grades 0/1/2 (1, 0.795, 0.59). Each must lie in [0.59, 1] (what the physics node can
    /// switch to between probings).
    pub modulus_scales: Vec<f64>,
    /// Start with an unscored healthy reference specimen (grade 0, announced as such).
    pub reference_case: bool,
    /// Wait after a specimen is loaded before probings count, s.
    pub settle_s: f64,
    /// The emulated operator answers after this many completed probings of a specimen.
    pub operator_probings: u32,
    /// The emulated operator answers at the latest after this long, s.
    pub case_timeout_s: f64,
    /// With the emulated device, its protocol's probings per region during training (1:
    /// posterior, mid, anterior in about 4 s, so each specimen is probed in every region).
    pub emulated_probings_per_region: u32,
}

impl Default for TrainingConfig {
    fn default() -> Self {
        TrainingConfig {
            modulus_scales: Vec::new(),
            reference_case: true,
            settle_s: 0.5,
            operator_probings: 3,
            case_timeout_s: 30.0,
            emulated_probings_per_region: 1,
        }
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TrainingConfigError {
    #[error("training.modulus_scales: {0}")]
    Scales(String),
    #[error("training.{key} = {value}: {what}")]
    Value {
        key: &'static str,
        value: f64,
        what: &'static str,
    },
}

impl TrainingConfig {
    /// The grades' modulus scales (the Fischenich ones when none are given).
    pub fn scales(&self) -> Vec<f64> {
        if self.modulus_scales.is_empty() {
            (0..3)
                .map(|g| 1.0 - FISCHENICH_LOSS_PER_GRADE * g as f64)
                .collect()
        } else {
            self.modulus_scales.clone()
        }
    }

    /// The physics' degeneration grade (0..=2, fractional) that gives modulus scale `s`.
    pub fn physics_grade(scale: f64) -> f64 {
        ((1.0 - scale) / FISCHENICH_LOSS_PER_GRADE).clamp(0.0, 2.0)
    }

    pub fn validate(&self) -> Result<(), TrainingConfigError> {
        let scales = self.scales();
        if scales.len() < 2 || scales.len() > 8 {
            return Err(TrainingConfigError::Scales(format!(
                "{} grades given; 2 to 8 are allowed",
                scales.len()
            )));
        }
        let lo = 1.0 - 2.0 * FISCHENICH_LOSS_PER_GRADE;
        for (g, s) in scales.iter().enumerate() {
            if !(s.is_finite() && (lo - 1e-9..=1.0 + 1e-9).contains(s)) {
                return Err(TrainingConfigError::Scales(format!(
                    "grade {g} has scale {s}; each must lie in [{lo}, 1]"
                )));
            }
        }
        for w in scales.windows(2) {
            if (w[0] - w[1]).abs() < 0.01 {
                return Err(TrainingConfigError::Scales(format!(
                    "scales {} and {} are too close to tell apart (differ by at least 0.01)",
                    w[0], w[1]
                )));
            }
        }
        for (key, value, what) in [
            ("settle_s", self.settle_s, "must be in [0, 10] s"),
            (
                "case_timeout_s",
                self.case_timeout_s,
                "must be in (0, 3600] s",
            ),
        ] {
            let ok = value.is_finite()
                && value >= 0.0
                && if key == "settle_s" {
                    value <= 10.0
                } else {
                    value > 0.0 && value <= 3600.0
                };
            if !ok {
                return Err(TrainingConfigError::Value { key, value, what });
            }
        }
        if self.operator_probings == 0 {
            return Err(TrainingConfigError::Value {
                key: "operator_probings",
                value: 0.0,
                what: "must be at least 1",
            });
        }
        if self.emulated_probings_per_region == 0 {
            return Err(TrainingConfigError::Value {
                key: "emulated_probings_per_region",
                value: 0.0,
                what: "must be at least 1",
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fischenich_defaults_and_physics_grades() {
        let c = TrainingConfig::default();
        c.validate().unwrap();
        let s = c.scales();
        assert_eq!(s.len(), 3);
        assert!((s[2] - 0.59).abs() < 1e-12);
        assert!((TrainingConfig::physics_grade(0.59) - 2.0).abs() < 1e-12);
        assert_eq!(TrainingConfig::physics_grade(1.0), 0.0);
    }

    #[test]
    fn scales_outside_the_physics_range_are_refused() {
        let c = TrainingConfig {
            modulus_scales: vec![1.0, 0.3],
            ..Default::default()
        };
        assert!(c.validate().unwrap_err().to_string().contains("grade 1"));
        let c = TrainingConfig {
            modulus_scales: vec![1.0],
            ..Default::default()
        };
        assert!(c.validate().is_err());
    }
}
