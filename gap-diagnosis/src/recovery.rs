//! Parameter recovery: an injected effect's strength against what the diagnosis fitted for it.
//!
//! Issue 15 grades a diagnosis on more than its verdict: where an effect has a scale, the
//! fitted parameters must lie within 15% of the truth. The self-test knows the truth
//! ([`crate::reality::Injected`]), so it can say how far each fitted strength is from it.
//! One number per strength, relative to the truth's magnitude:
//! - a scalar (modulus scale, stiffening rate, Prony g1 and τ1, μ, the sensor's delay and
//!   low-pass) by |fitted − true| / |true|;
//! - a direction-bearing pair or triple (the tilt's two angles, the device's force bias) by the
//!   length of the error vector over the length of the true one, since a small component alone
//!   has no meaningful relative error;
//! - the support by its stiffness, the inverse of the compliance the diagnosis fits.
//!
//! The device's tool mass is left out: it is not identifiable from probings whose tool barely
//! accelerates (its fit sits at a bound, `FittedParam::at_bound`). The truth's systematic
//! stiffness offset is not taken out of the modulus: like the hidden cases, the comparison is
//! with the injected scale, and the offset is part of what the diagnosis must see through.

use crate::fit::FittedParam;
use crate::reality::Injected;
use serde::{Deserialize, Serialize};

/// The tolerance on a fitted strength, relative to the truth.
pub const RECOVERY_TOLERANCE: f64 = 0.15;

/// One injected strength and its fit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Recovery {
    pub effect: String,
    /// The strength's name (a parameter, or `tilt`, `bias`, `support_stiffness`).
    pub name: String,
    /// The truth's value (a vector's length for `tilt` and `bias`).
    pub truth: f64,
    /// The fitted value (for a vector: its length).
    pub fitted: f64,
    /// |fitted − truth| / |truth| (for a vector: the error vector's length over the truth's).
    pub relative_error: f64,
}

impl Recovery {
    pub fn within_tolerance(&self) -> bool {
        self.relative_error <= RECOVERY_TOLERANCE
    }
}

/// One line: `friction mu: fitted 0.2429 for 0.2881 (error 15.7%)`; the alternate form
/// (`{:#}`) adds `, outside 15%` inside the parentheses where it is.
impl std::fmt::Display for Recovery {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let outside = if f.alternate() && !self.within_tolerance() {
            ", outside 15%"
        } else {
            ""
        };
        write!(
            f,
            "{} {}: fitted {:.4} for {:.4} (error {:.1}%{outside})",
            self.effect,
            self.name,
            self.fitted,
            self.truth,
            100.0 * self.relative_error
        )
    }
}

/// The strengths each effect is graded on: (name, its parameters, named alike in the truth
/// and the fit). A vector's components are listed together; the support's fit is inverted
/// ([`fitted_value`]). [`crate::strength`] judges the same strengths.
pub(crate) fn strengths(effect: &str) -> &'static [(&'static str, &'static [&'static str])] {
    match effect {
        "modulus" => &[("modulus_scale", &["modulus_scale"])],
        "hardening" => &[("stiffening_rate", &["stiffening_rate"])],
        "viscoelastic" => &[("prony_g1", &["prony_g1"]), ("prony_tau1", &["prony_tau1"])],
        "friction" => &[("mu", &["mu"])],
        "tilt" => &[("tilt", &["tilt_x", "tilt_y"])],
        "device" => &[("bias", &["bias_x", "bias_y", "bias_z"])],
        "support" => &[("support_stiffness", &["support_stiffness"])],
        "sensor" => &[("delay", &["delay"]), ("lowpass_tau", &["lowpass_tau"])],
        _ => &[],
    }
}

/// The effect has a strength to grade (`mesh` has none).
pub fn grades(effect: &str) -> bool {
    !strengths(effect).is_empty()
}

/// The fitted value of truth parameter `name` of `effect` (the support: 1 / its compliance).
fn fitted_value(params: &[FittedParam], effect: &str, name: &str) -> Option<f64> {
    let find = |n: &str| {
        params
            .iter()
            .find(|p| p.effect == effect && p.name == n)
            .map(|p| p.value)
    };
    if name == "support_stiffness" {
        return find("support_compliance").map(|c| if c > 0.0 { 1.0 / c } else { f64::INFINITY });
    }
    find(name)
}

/// The length of a vector's components, or a scalar as it is (sign kept).
fn signed(v: &[f64]) -> f64 {
    if v.len() == 1 {
        v[0]
    } else {
        v.iter().map(|x| x * x).sum::<f64>().sqrt()
    }
}

/// The fitted value of strength `name` of `effect` ([`strengths`]): a scalar as fitted, a
/// vector by its length, the support as a stiffness. None where a component is not in
/// `params`.
pub(crate) fn fitted_strength(params: &[FittedParam], effect: &str, name: &str) -> Option<f64> {
    let (_, components) = strengths(effect).iter().find(|(n, _)| *n == name)?;
    let fitted: Option<Vec<f64>> = components
        .iter()
        .map(|c| fitted_value(params, effect, c))
        .collect();
    fitted.map(|v| signed(&v))
}

/// Each strength of the injected effects that the verdict names, against its fit. An effect
/// the verdict does not name has no fit to compare, and is not listed (the verdict is already
/// wrong about it). A strength that is zero in the truth is skipped: no relative error exists.
pub fn recovery(injected: &[Injected], params: &[FittedParam]) -> Vec<Recovery> {
    let mut out = Vec::new();
    for inj in injected {
        for &(name, components) in strengths(&inj.effect) {
            let truth: Option<Vec<f64>> = components
                .iter()
                .map(|c| inj.params.get(*c).copied())
                .collect();
            let fitted: Option<Vec<f64>> = components
                .iter()
                .map(|c| fitted_value(params, &inj.effect, c))
                .collect();
            let (Some(truth), Some(fitted)) = (truth, fitted) else {
                continue;
            };
            let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
            let error: Vec<f64> = fitted.iter().zip(&truth).map(|(f, t)| f - t).collect();
            let scale = norm(&truth);
            if !(scale > 0.0 && scale.is_finite()) {
                continue;
            }
            out.push(Recovery {
                effect: inj.effect.clone(),
                name: name.to_string(),
                truth: signed(&truth),
                fitted: signed(&fitted),
                relative_error: norm(&error) / scale,
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    fn injected(effect: &str, params: &[(&str, f64)]) -> Injected {
        Injected {
            effect: effect.into(),
            params: params
                .iter()
                .map(|(k, v)| (k.to_string(), *v))
                .collect::<BTreeMap<_, _>>(),
        }
    }

    fn fitted(effect: &str, name: &str, value: f64) -> FittedParam {
        FittedParam::given(effect, name, value)
    }

    #[test]
    fn a_scalar_is_graded_relative_to_the_truth() {
        // The first hidden set's modulus case: 1.27 fitted for a true 1.42 (−10.6%).
        let r = recovery(
            &[injected("modulus", &[("modulus_scale", 1.42)])],
            &[fitted("modulus", "modulus_scale", 1.27)],
        );
        assert_eq!(r.len(), 1);
        assert!((r[0].relative_error - 0.15 / 1.42).abs() < 1e-12);
        assert!(r[0].within_tolerance());
        let r = recovery(
            &[injected("friction", &[("mu", 0.29)])],
            &[fitted("friction", "mu", 0.07)],
        );
        assert!(!r[0].within_tolerance(), "{r:?}");
    }

    #[test]
    fn the_support_is_graded_by_its_stiffness_and_a_tilt_by_its_vector() {
        let r = recovery(
            &[
                injected("support", &[("support_stiffness", 2000.0)]),
                injected("tilt", &[("tilt_x", -5.25), ("tilt_y", -1.80)]),
            ],
            &[
                fitted("support", "support_compliance", 1.0 / 2200.0),
                fitted("tilt", "tilt_x", -4.50),
                fitted("tilt", "tilt_y", -0.67),
            ],
        );
        assert_eq!(r.len(), 2);
        assert!((r[0].fitted - 2200.0).abs() < 1e-9);
        assert!((r[0].relative_error - 0.1).abs() < 1e-12);
        // |(0.75, 1.13)| / |(5.25, 1.80)| = 1.356 / 5.55 = 24%: the small angle's 63% error
        // counts by its size, not alone.
        let expect = (0.75f64.hypot(1.13)) / 5.25f64.hypot(1.80);
        assert!((r[1].relative_error - expect).abs() < 1e-12, "{r:?}");
        assert!(!r[1].within_tolerance());
    }

    #[test]
    fn an_effect_the_verdict_does_not_name_and_the_tool_mass_are_not_graded() {
        let r = recovery(
            &[
                injected("friction", &[("mu", 0.3)]),
                injected(
                    "device",
                    &[
                        ("bias_x", 0.1),
                        ("bias_y", 0.0),
                        ("bias_z", 0.2),
                        ("tool_mass", 0.03),
                    ],
                ),
            ],
            &[
                fitted("device", "bias_x", 0.1),
                fitted("device", "bias_y", 0.0),
                fitted("device", "bias_z", 0.2),
                fitted("device", "tool_mass", 0.2),
            ],
        );
        assert_eq!(r.len(), 1, "{r:?}");
        assert_eq!(r[0].name, "bias");
        assert_eq!(r[0].relative_error, 0.0);
    }
}
