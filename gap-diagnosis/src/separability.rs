//! Which candidates the held-out data cannot tell apart from the verdict (issue 15 point 2).
//!
//! Every candidate predicts each trial from a fit on the other folds. The evidence between the
//! verdict and a rival is the statistic the verdict's own significance uses ([`gain_over`]):
//! per trial, the log ratio of their phase-weighted held-out losses where their predictions
//! differ, with its mean and standard error over the trials. A rival over which the verdict's
//! gain is not at least two standard errors above zero explains the held-out data as well as
//! the verdict within the data's own between-trial scatter: the report names it beside the
//! verdict (`verdict.indistinguishable`) with what kind of trial would separate the two. The
//! verdict's effect itself is not changed here.
//!
//! Until 2026-11-28 this compared plain per-trial held-out MSE instead, a second measure of the
//! same evidence: unweighted, the deepest probings' model error set its scatter, and the
//! report listed 8–22 rivals, some of them better than the verdict on it by 4 standard errors
//! while worse on the measure that chose the verdict.

use crate::dataset::TrialData;
use crate::effects::Effect;
use crate::fit::CandidateScore;
use crate::signal::{dot, sub};
use serde::{Deserialize, Serialize};

/// Standard errors by which a rival's held-out error must exceed the verdict's to count as
/// told apart (a one-sided ~97.5% paired test over trials).
pub const SEPARATION_SE: f64 = 2.0;
/// Fewest trials with a held-out prediction for the paired test to mean anything.
pub const MIN_TRIALS: usize = 4;
/// Smallest variance-weighted loss of a trial in [`gain_over`] (the loss is 1 where a
/// prediction is as good as the floor's phase variances): 10⁻⁶ of that.
const LOSS_FLOOR: f64 = 1e-6;
/// Two held-out predictions differ at a sample, for [`gain_over`], by more than this fraction
/// of the phase's residual scale (the floor's held-out RMSE there).
const DIFFER: f64 = 0.1;

/// A set of candidates the held-out data cannot separate, and what would.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct Indistinguishable {
    /// The verdict first, then each rival within [`SEPARATION_SE`] standard errors, best
    /// first (e.g. `["support", "modulus"]`, reported as `support ~ modulus`).
    pub candidates: Vec<String>,
    /// Per rival: the verdict's held-out gain over it ([`gain_over`], mean log loss ratio per
    /// trial) and the standard error of that gain over trials.
    pub gain: Vec<f64>,
    pub gain_se: Vec<f64>,
    /// What kind of experiment would tell each rival from the verdict.
    pub separate_by: Vec<String>,
}

impl Indistinguishable {
    /// `a ~ b ~ c`.
    pub fn label(&self) -> String {
        self.candidates.join(" ~ ")
    }
}

/// Rivals of `verdict` (a candidate of `ranking`) the held-out data cannot separate from it.
/// `None` when the verdict is not a ranked candidate (e.g. `none`), when there are too few
/// trials, or when every rival is told apart.
pub fn indistinguishable(
    verdict: &str,
    ranking: &[CandidateScore],
    data: &[TrialData],
) -> Option<Indistinguishable> {
    if data.len() < MIN_TRIALS {
        return None;
    }
    let win = ranking.iter().find(|c| c.effect == verdict)?;
    let mut rivals: Vec<(f64, f64, &CandidateScore)> = ranking
        .iter()
        .filter(|c| c.effect != verdict)
        // a rival that contains the verdict (its pair) or is contained in it adds or drops an
        // effect; that choice is the verdict's own parsimony rule, not a confusion
        .filter(|c| !shares_effect(&c.effect, verdict))
        // a rival with more effects that fits no better loses on parsimony, as in the verdict
        .filter(|c| effects_of(&c.effect).len() <= effects_of(verdict).len())
        .filter_map(|c| {
            // the rival as the null model, as the floor is for the verdict's own gain
            let (mean, se) = gain_over(c, win, data)?;
            (!told_apart(mean, se)).then_some((mean, se, c))
        })
        .collect();
    if rivals.is_empty() {
        return None;
    }
    rivals.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut out = Indistinguishable {
        candidates: vec![verdict.to_string()],
        ..Default::default()
    };
    for (mean, se, c) in rivals {
        out.candidates.push(c.effect.clone());
        out.gain.push(mean);
        out.gain_se.push(se);
        out.separate_by
            .push(separating_experiment(verdict, &c.effect));
    }
    Some(out)
}

/// Held-out gain of `c` over `floor` (the nuisance floor, [`crate::fit::Nuisance`]), trial by
/// trial, and its standard error over trials: per trial, ln(L_floor / L_c), with L the sum of
/// |r|² / σ²_g over the trial's samples where the two held-out predictions differ, σ²_g the
/// floor's held-out mean square in the sample's variance group
/// ([`crate::fit::PhaseSse::group_mse`]).
///
/// Weighting by the phase variances is what the fits and scores do (a sensor bias out of
/// contact is judged against the noise there, not against the model's error in contact);
/// pairing by trial is what makes the gain significant only when it holds across trials,
/// not when a few trials' model error happens to fall its way. The evidence between two
/// models lies where their predictions differ (by more than a tenth of the phase's residual
/// scale, [`DIFFER`]): the samples are chosen from the two held-out predictions alone, not
/// from the measurement, so the choice does not favour either. Trials where they nowhere
/// differ are ties and left out (no contact; no slide, for friction). The logarithm makes
/// each trial count alike. Tried first: the difference of the trial's mean losses over all
/// its samples, then their log ratio; the deepest probings set the scatter of the one, the
/// phases an effect does not act on diluted the other, and effects that removed 80% of the
/// held-out error stood 1.2–1.9 standard errors above zero. `None` with fewer than
/// [`MIN_TRIALS`] trials or predictions that do not match the data; (0, 0) with fewer than
/// two trials that are not ties.
pub fn gain_over(
    floor: &CandidateScore,
    c: &CandidateScore,
    data: &[TrialData],
) -> Option<(f64, f64)> {
    if data.len() < MIN_TRIALS
        || floor.heldout_pred.len() != data.len()
        || c.heldout_pred.len() != data.len()
    {
        return None;
    }
    let mut acc = crate::fit::PhaseSse::default();
    for (d, pred) in data.iter().zip(&floor.heldout_pred) {
        for ((m, p), g) in d.f.iter().zip(pred).zip(&d.var_group) {
            acc.push(*g, sub(*p, *m));
        }
    }
    let var = acc.group_mse();
    let (mut floor_loss, mut c_loss) = (Vec::new(), Vec::new());
    for ((d, pf), pc) in data.iter().zip(&floor.heldout_pred).zip(&c.heldout_pred) {
        if pf.len() != d.f.len() || pc.len() != d.f.len() {
            return None;
        }
        let (mut lf, mut lc, mut n) = (0.0, 0.0, 0usize);
        for j in 0..d.f.len() {
            let w = var[d.var_group[j] as usize];
            let gap = sub(pc[j], pf[j]);
            if w <= 0.0 || dot(gap, gap) <= DIFFER * DIFFER * w {
                continue;
            }
            let (rf, rc) = (sub(pf[j], d.f[j]), sub(pc[j], d.f[j]));
            lf += dot(rf, rf) / w;
            lc += dot(rc, rc) / w;
            n += 1;
        }
        if n > 0 {
            // the loss floor keeps an exact fit's logarithm finite
            floor_loss.push((lf / n as f64).max(LOSS_FLOOR).ln());
            c_loss.push((lc / n as f64).max(LOSS_FLOOR).ln());
        }
    }
    if c_loss.len() < 2 {
        return Some((0.0, 0.0));
    }
    // the floor is the "rival" here: its excess over `c` is `c`'s gain
    Some(paired_excess(&c_loss, &floor_loss))
}

/// Mean and standard error over trials of `other − reference` (per-trial held-out losses):
/// `other`'s excess loss over `reference`.
fn paired_excess(reference: &[f64], other: &[f64]) -> (f64, f64) {
    let n = reference.len().min(other.len()) as f64;
    let diff: Vec<f64> = other.iter().zip(reference).map(|(o, r)| o - r).collect();
    let mean = diff.iter().sum::<f64>() / n;
    let var = diff.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (mean, (var / n).sqrt())
}

/// The verdict's gain over the rival is more than the trials' scatter explains.
fn told_apart(mean: f64, se: f64) -> bool {
    mean >= SEPARATION_SE * se && mean > 0.0
}

fn effects_of(name: &str) -> Vec<Effect> {
    Effect::of_candidate(name).collect()
}

fn shares_effect(a: &str, b: &str) -> bool {
    let b = effects_of(b);
    effects_of(a).iter().any(|e| b.contains(e))
}

/// Where two effects' predictions part, from how each acts on the probe force.
fn separating_experiment(a: &str, b: &str) -> String {
    let (ea, eb) = (effects_of(a), effects_of(b));
    let mut hints: Vec<&str> = Vec::new();
    for x in &ea {
        for y in &eb {
            if let Some(h) = hint(*x, *y).or_else(|| hint(*y, *x)) {
                if !hints.contains(&h) {
                    hints.push(h);
                }
            }
        }
    }
    if hints.is_empty() {
        format!("trials whose phases {a} and {b} act on differently (more probings, more sites)")
    } else {
        hints.join("; ")
    }
}

fn hint(x: Effect, y: Effect) -> Option<&'static str> {
    use Effect::*;
    Some(match (x, y) {
        (Support, Modulus) => {
            "a deeper press, and a probing near the fixed edge: the support moves the whole \
             body (it dominates far from the attachments), the modulus stiffens only the tissue \
             under the tip"
        }
        (Support, Hardening) | (Modulus, Hardening) => {
            "presses over a wider depth range: hardening grows with depth, a constant stiffness \
             scale does not"
        }
        (Support, Tilt) | (Modulus, Tilt) => {
            "forces on the tangential axes while pressing: a tilt turns part of the normal force \
             sideways, a stiffness change does not"
        }
        (Friction, Tilt) => {
            "slides in opposite directions: friction opposes each slide, a tilt pushes one way"
        }
        (Friction, Support) | (Friction, Modulus) | (Friction, Hardening) => {
            "longer tangential slides at constant depth: friction acts only while sliding"
        }
        (Viscoelastic, Sensor) => {
            "longer holds at constant depth: relaxation decays over the hold, a sensor delay or \
             low-pass only shifts and rounds the onsets"
        }
        (Viscoelastic, Support) | (Viscoelastic, Modulus) | (Viscoelastic, Hardening) => {
            "presses at two speeds and holds: viscoelasticity depends on the rate and relaxes, \
             a stiffness does not"
        }
        (Device, Sensor) => {
            "samples with the probe out of contact: a device bias is there at rest, a sensor \
             delay is not"
        }
        (Device, Support) | (Device, Modulus) | (Device, Hardening) | (Device, Tilt) => {
            "samples with the probe out of contact: a device bias or tool inertia shows without \
             tissue"
        }
        (Sensor, Support) | (Sensor, Modulus) | (Sensor, Hardening) => {
            "faster presses: a sensor delay grows with the loading rate, a stiffness does not"
        }
        (Mesh, _) => "a refined specimen mesh near the probing sites",
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rival whose per-trial held-out error scatters around the verdict's is not told
    /// apart; one that is worse on every trial by more than the scatter is.
    #[test]
    fn a_rival_is_told_apart_only_beyond_the_between_trial_scatter() {
        let verdict = [1.0, 1.2, 0.9, 1.1, 1.0, 1.3, 0.8, 1.0];
        let close = [1.05, 1.1, 1.0, 1.05, 0.95, 1.35, 0.85, 1.0];
        let (m, se) = paired_excess(&verdict, &close);
        assert!(!told_apart(m, se), "mean {m} se {se}");
        let worse: Vec<f64> = verdict.iter().map(|v| v + 0.3).collect();
        let (m, se) = paired_excess(&verdict, &worse);
        assert!(
            (m - 0.3).abs() < 1e-12 && told_apart(m, se),
            "mean {m} se {se}"
        );
        // better than the verdict (the verdict's own rule chose it anyway): not told apart
        let better: Vec<f64> = verdict.iter().map(|v| v - 0.1).collect();
        let (m, se) = paired_excess(&verdict, &better);
        assert!(!told_apart(m, se));
    }

    #[test]
    fn separating_experiments_are_symmetric_and_name_pairs() {
        assert_eq!(
            separating_experiment("support", "modulus"),
            separating_experiment("modulus", "support")
        );
        assert!(separating_experiment("support", "modulus").contains("fixed edge"));
        let pair = separating_experiment("friction+device", "tilt");
        assert!(pair.contains("opposite directions") && pair.contains("out of contact"));
        assert!(shares_effect("modulus+sensor", "sensor"));
        assert!(!shares_effect("modulus", "support"));
    }
}
