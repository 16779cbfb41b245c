//! The smallest strength of each effect worth naming.
//!
//! A candidate's fit can lower the held-out error with a strength no researcher would act on
//! and the protocol does not resolve: on the study-mesh proxy set a `hardening` case read
//! `hardening+viscoelastic` through a Prony term of g1 = 0.017 relaxing in 50 ms (the lower
//! bound of τ1, two samples at 38 Hz), which took up a transient of the truth's other contact
//! formulation; on the refined truth a `hardening+friction` case read `modulus+friction`
//! with a modulus scale of 1.23, inside the band an unrelated stiffness offset can take
//! ([`crate::fit::NUISANCE_MAX`]). Neither names an effect of the specimen. A verdict names an
//! effect only at a strength above these; below them the effect is what the model error,
//! the noise and the nuisances already leave room for.
//!
//! Each bound is a small fraction of the strengths an effect has when it matters (the study's
//! and the hidden cases' ranges, `reality::draw`) and above what the study's protocol
//! resolves: 0.5–1.2 mm presses, ~38 Hz sampling, ~0.02 N of sensor noise.

use crate::effects::{Effect, SUPPORT_KNOTS};
use crate::fit::{FittedParam, Nuisance};
use crate::recovery;

/// Stiffening rate, 1/mm: 6% more force at the study's deepest 1.2 mm press (drawn: 0.25–0.45).
pub const MIN_STIFFENING_RATE: f64 = 0.05;
/// Prony g1: 5% of the force relaxes (drawn: 0.3–0.5).
pub const MIN_PRONY_G1: f64 = 0.05;
/// Coulomb μ (drawn: 0.2–0.5; a hidden case 0.18).
pub const MIN_FRICTION: f64 = 0.05;
/// Tilt, degrees, both axes together (drawn: 4–8°).
pub const MIN_TILT_DEG: f64 = 1.0;
/// Device force bias, N: two and a half times the sensor noise (drawn: 0.2–0.5 N).
pub const MIN_BIAS_N: f64 = 0.05;
/// Support compliance, m/N per node: a tenth of the stiffest knot's (40,000 N/m per node, as
/// good as rigid under a meniscus; drawn: 700–2,000 N/m).
pub const MIN_SUPPORT_COMPLIANCE: f64 = 0.1 * SUPPORT_KNOTS[0];
/// Sensor delay or low-pass time constant, s: a fifth of a sample at 38 Hz (drawn: 20–120 ms).
pub const MIN_SENSOR_S: f64 = 0.005;

/// Whether a fitted strength ([`crate::recovery`]'s names and values: a vector by its length,
/// the support as a stiffness) is below what is worth naming; None where the strength has no
/// such bound (τ1: a time constant is no amount; the modulus: see [`negligible`]).
fn below_minimum(strength: &str, value: f64) -> Option<bool> {
    let below = |min: f64| Some(value.abs() < min);
    match strength {
        "stiffening_rate" => below(MIN_STIFFENING_RATE),
        "prony_g1" => below(MIN_PRONY_G1),
        "mu" => below(MIN_FRICTION),
        "tilt" => below(MIN_TILT_DEG),
        "bias" => below(MIN_BIAS_N),
        "support_stiffness" => Some(value > 1.0 / MIN_SUPPORT_COMPLIANCE),
        "delay" | "lowpass_tau" => below(MIN_SENSOR_S),
        _ => None,
    }
}

/// `effect`'s fitted strength in `params` is below what is worth naming (see the module), the
/// diagnosis fitting the nuisances of `band`: a modulus scale is negligible inside the band
/// the stiffness nuisance takes (with the nuisance off, only at exactly 1) while the
/// candidate's response `level` ([`crate::fit::CandidateScore::level`], where known) stays
/// inside the level's band too. An effect with several bounded strengths (the sensor's delay
/// and low-pass) is negligible when all are. `mesh` has no strength and is never negligible;
/// an effect whose bounded strengths are not all in `params` is not judged (false).
pub fn negligible(
    effect: Effect,
    params: &[FittedParam],
    band: Nuisance,
    level: Option<f64>,
) -> bool {
    let name = effect.name();
    if effect == Effect::Modulus {
        // a scale inside the band is what the stiffness nuisance is for, unless the contact
        // and material terms beside it take the response below what the floor may reach (a
        // modulus ×0.81 beside a 10 µm/N layer is a level of ×0.57)
        return recovery::fitted_strength(params, name, "modulus_scale")
            .is_some_and(|s| (band.lo..=band.hi).contains(&s))
            && level.is_none_or(|l| band.level_inside(l));
    }
    let mut judged = false;
    for &(strength, _) in recovery::strengths(name) {
        let fitted = recovery::fitted_strength(params, name, strength);
        match fitted.map(|v| below_minimum(strength, v)) {
            Some(Some(false)) => return false,
            Some(Some(true)) => judged = true,
            // fitted but unbounded (τ1): no say
            Some(None) => {}
            // a bounded strength not fitted here: not judged
            None if below_minimum(strength, 0.0).is_some() => return false,
            None => {}
        }
    }
    judged
}

/// Some effect of the `+`-joined `candidate` has a negligible fitted strength in `params`
/// at the response `level` ([`negligible`]).
pub fn any_negligible(
    candidate: &str,
    params: &[FittedParam],
    band: Nuisance,
    level: Option<f64>,
) -> bool {
    Effect::of_candidate(candidate).any(|e| negligible(e, params, band, level))
}

#[cfg(test)]
mod tests {
    use super::*;

    const ALL: Nuisance = Nuisance::ALL;

    fn given(effect: &str, pairs: &[(&str, f64)]) -> Vec<FittedParam> {
        pairs
            .iter()
            .map(|&(n, v)| FittedParam::given(effect, n, v))
            .collect()
    }

    #[test]
    fn a_fast_small_relaxation_beside_hardening_is_negligible() {
        // the study-mesh proxy's hardening case: g1 0.017 at τ1's lower bound
        let mut p = given(
            "hardening",
            &[("small_strain_scale", 0.965), ("stiffening_rate", 0.244)],
        );
        p.extend(given(
            "viscoelastic",
            &[("prony_g1", 0.0169), ("prony_tau1", 0.05)],
        ));
        assert!(!negligible(Effect::Hardening, &p, ALL, None));
        assert!(negligible(Effect::Viscoelastic, &p, ALL, None));
        assert!(any_negligible("hardening+viscoelastic", &p, ALL, None));
        assert!(!any_negligible("hardening", &p, ALL, None));
    }

    #[test]
    fn a_modulus_inside_the_nuisance_band_is_negligible_outside_it_is_not() {
        let modulus = |s: f64| given("modulus", &[("modulus_scale", s)]);
        assert!(negligible(Effect::Modulus, &modulus(1.2276), ALL, None));
        assert!(negligible(Effect::Modulus, &modulus(0.81), ALL, None));
        assert!(!negligible(Effect::Modulus, &modulus(1.3), ALL, None));
        assert!(!negligible(Effect::Modulus, &modulus(0.7), ALL, None));
        // inside the scale's band behind a layer that takes the level out of its own: not
        // negligible (the independent code's modulus ×0.55 at ×0.81 beside 10 µm/N)
        assert!(!negligible(
            Effect::Modulus,
            &modulus(0.81),
            ALL,
            Some(0.57)
        ));
        assert!(negligible(Effect::Modulus, &modulus(0.81), ALL, Some(0.75)));
    }

    /// Regression: with the nuisance off, a stiffness offset of ×1.14 read `none`: its modulus
    /// was judged against a band no fit had taken up (`gap_stats`).
    #[test]
    fn without_the_nuisance_any_modulus_change_counts() {
        let modulus = |s: f64| given("modulus", &[("modulus_scale", s)]);
        assert!(!negligible(
            Effect::Modulus,
            &modulus(1.14),
            Nuisance::OFF,
            None
        ));
        assert!(negligible(
            Effect::Modulus,
            &modulus(1.0),
            Nuisance::OFF,
            None
        ));
    }

    #[test]
    fn vectors_are_judged_by_their_length() {
        let tilt = given("tilt", &[("tilt_x", 0.8), ("tilt_y", 0.7)]);
        assert!(
            !negligible(Effect::Tilt, &tilt, ALL, None),
            "1.06° together"
        );
        let tilt = given("tilt", &[("tilt_x", 0.6), ("tilt_y", 0.7)]);
        assert!(negligible(Effect::Tilt, &tilt, ALL, None));
        let bias = given(
            "device",
            &[("bias_x", 0.03), ("bias_y", -0.03), ("bias_z", 0.03)],
        );
        assert!(
            !negligible(Effect::Device, &bias, ALL, None),
            "0.052 N together"
        );
        let bias = given(
            "device",
            &[("bias_x", 0.001), ("bias_y", 0.0), ("bias_z", -0.001)],
        );
        assert!(negligible(Effect::Device, &bias, ALL, None));
    }

    #[test]
    fn a_sensor_counts_by_its_larger_time_and_a_mesh_never_is_negligible() {
        let s = given("sensor", &[("delay", 0.0), ("lowpass_tau", 0.0007)]);
        assert!(negligible(Effect::Sensor, &s, ALL, None));
        let s = given("sensor", &[("delay", 0.0), ("lowpass_tau", 0.02)]);
        assert!(!negligible(Effect::Sensor, &s, ALL, None));
        assert!(!negligible(Effect::Mesh, &[], ALL, None));
        // not fitted here: not judged
        assert!(!negligible(Effect::Friction, &s, ALL, None));
    }

    #[test]
    fn a_stiff_support_and_small_friction_are_negligible() {
        let p = given("support", &[("support_compliance", 5.2e-6)]);
        assert!(negligible(Effect::Support, &p, ALL, None));
        let p = given("support", &[("support_compliance", 7.5e-4)]);
        assert!(!negligible(Effect::Support, &p, ALL, None));
        let mu = |m: f64| given("friction", &[("mu", m)]);
        assert!(negligible(Effect::Friction, &mu(0.0017), ALL, None));
        assert!(!negligible(Effect::Friction, &mu(0.18), ALL, None));
    }
}
