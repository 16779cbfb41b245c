//! The verdict under a systematic model error (issue 15, points 2 and 3).
//!
//! No model is the specimen: its stiffness is off by some tens of percent, and its
//! discretisation leaves an error that differs from site to site. The candidates are
//! therefore judged in two groups ([`Scored`]):
//! - global (`hardening`, `support`, `mesh`): each fitted with one stiffness scale for the
//!   specimen; the stiffness-only fit (`modulus`) is the reference they must beat, by more
//!   than the model-error floor ([`Floor::min_gain`]: the trial-to-trial scatter of the
//!   stiffness, estimated from the data). A scale beyond `Options::stiffness_tolerance` and
//!   its own jackknife error is `modulus`; a persistent offset within it is nobody's effect.
//! - local (`friction`, `tilt`, `sensor`, `viscoelastic`, `device`, and their pairs): each
//!   trial with its own stiffness (`fit::Nuisance::PerTrial`), so the site-to-site stiffness
//!   error is carried by the nuisance and not handed to whichever effect bends towards it.
//!   The reference is the per-trial stiffness alone.
//!
//! In both, an effect is named only when its held-out gain over the reference, on the phases
//! that carry it (friction: sliding; a sensor: the contact onsets and ramps; ...), is larger
//! than the floor and holds trial by trial (a paired t over the trials' held-out errors, or the
//! floor beaten in every trial), with ΔBIC ≤ −10. The two groups' choices are joined (at most
//! two names). Candidates whose held-out errors cannot be told apart trial by trial are
//! reported together.
use super::dataset::{TrialData, VarGroup};
use super::effects::Effect;
use super::fit::{CandidateScore, PhaseSse};
use super::metrics::Phase;
use super::signal::dot;
use super::{Options, Verdict};
use serde::{Deserialize, Serialize};

/// Paired t over trials an effect's held-out gain must reach (≈ p < 0.01 one-sided for 5–15
/// trials).
pub const MIN_T: f64 = 3.0;
/// Fewest trials for the trial-by-trial test; fewer (a single table) fall back to the
/// pooled shrink and ΔBIC.
pub const MIN_TRIALS: usize = 3;

/// The model-error floor of an experiment, estimated from the data.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Floor {
    /// Global stiffness scale (measured / simulated) fitted with no effect, and its
    /// jackknife standard error over the held-out folds.
    pub stiffness_scale: f64,
    pub stiffness_scale_std: f64,
    /// Standard deviation of ln(scale) fitted trial by trial: how much the model's stiffness
    /// error differs from site to site (what no global effect can remove).
    pub between_trial_scale_sd: f64,
    /// Held-out RMSE with the stiffness scale alone, N, and its part above the noise.
    pub heldout_rmse: f64,
    pub model_error_rmse: f64,
    /// Smallest held-out gain (fraction of the reference's RMSE on the phases that carry an
    /// effect) an effect must show: the trial-to-trial stiffness scatter, at least
    /// `Options::min_shrink`.
    pub min_gain: f64,
    /// The same for the effects judged with a per-trial stiffness (`Options::min_shrink`):
    /// the site-to-site stiffness error is then carried by the nuisance, not by the floor.
    #[serde(default)]
    pub local_min_gain: f64,
    /// A stiffness offset up to this (fraction, plus two standard errors) is model error,
    /// not `modulus` (`Options::stiffness_tolerance`).
    pub stiffness_tolerance: f64,
    pub summary: String,
}

/// The scored candidates, in two groups by how the model's stiffness error is carried.
///
/// Global: the stiffness-only reference (`modulus`: one scale for the specimen) and the
/// effects whose signature *is* a pattern of stiffness over sites and depths (`hardening`,
/// `support`, `mesh`), each with the global scale. Local: the per-trial-stiffness reference (each trial
/// its own scale, see `fit::Nuisance::PerTrial`) and the effects that show where a stiffness
/// cannot reach (friction and tilt on the tangential axes and in sliding, a sensor at the
/// onsets, a relaxation in the hold, a device bias out of contact), singles and pairs.
pub struct Scored<'a> {
    pub reference: &'a CandidateScore,
    pub singles: &'a [CandidateScore],
    pub local_reference: &'a CandidateScore,
    pub local_singles: &'a [CandidateScore],
    pub local_pairs: &'a [CandidateScore],
}

/// The variance groups (phases) an effect shows in.
pub fn carrying_groups(e: Effect) -> Vec<VarGroup> {
    use VarGroup::*;
    match e {
        Effect::Friction => vec![Sliding],
        Effect::Sensor => vec![NearContact, Loading, Unloading],
        Effect::Viscoelastic => vec![Loading, Hold, Unloading],
        Effect::Device => vec![Free, NearContact, Loading, Hold, Unloading, Sliding],
        Effect::Tilt | Effect::Support | Effect::Mesh | Effect::Modulus | Effect::Hardening => {
            vec![Loading, Hold, Unloading, Sliding]
        }
    }
}

fn groups_of(name: &str) -> Vec<VarGroup> {
    let mut g: Vec<VarGroup> = name
        .split('+')
        .filter_map(Effect::parse)
        .flat_map(carrying_groups)
        .collect();
    g.sort_by_key(|v| *v as usize);
    g.dedup();
    g
}

fn sse_in(acc: &PhaseSse, groups: &[VarGroup]) -> (f64, usize) {
    groups.iter().fold((0.0, 0), |(s, n), &g| {
        (s + acc.sse[g as usize], n + acc.n[g as usize])
    })
}

/// What a candidate gains over another on held-out data, on the given phases.
#[derive(Debug, Clone, Copy)]
pub struct Evidence {
    /// 1 − RMSE ratio on the phases, pooled over trials.
    pub gain: f64,
    /// 1 − phase-weighted RMSE ratio over everything (must not be negative).
    pub gain_weighted: f64,
    /// Paired t of ln(SSE_other / SSE_this) over trials, and how many trials had such samples.
    pub t: f64,
    /// The lower quartile of those per-trial gains (fraction, 1 − RMSE ratio): what three
    /// trials in four reach.
    pub quartile_trial_gain: f64,
    pub trials: usize,
    /// BIC difference (negative: this one is better).
    pub delta_bic: f64,
}

pub fn evidence(this: &CandidateScore, other: &CandidateScore, groups: &[VarGroup]) -> Evidence {
    let (s1, n1) = sse_in(&this.heldout_groups, groups);
    let (s0, _) = sse_in(&other.heldout_groups, groups);
    let gain = if n1 > 0 && s0 > 0.0 {
        1.0 - (s1 / s0).sqrt()
    } else {
        0.0
    };
    let gain_weighted = if other.heldout_weighted_rmse > 0.0 {
        1.0 - this.heldout_weighted_rmse / other.heldout_weighted_rmse
    } else {
        0.0
    };
    let d: Vec<f64> = this
        .heldout_trials
        .iter()
        .zip(&other.heldout_trials)
        .filter_map(|(a, b)| {
            let (sa, na) = sse_in(a, groups);
            let (sb, _) = sse_in(b, groups);
            (na > 0 && sa > 0.0 && sb > 0.0).then(|| (sb / sa).ln())
        })
        .collect();
    let mut sorted = d.clone();
    sorted.sort_by(f64::total_cmp);
    Evidence {
        gain,
        gain_weighted,
        quartile_trial_gain: match sorted.len() {
            0 => 0.0,
            n => 1.0 - (-0.5 * sorted[(n - 1) / 4]).exp(),
        },
        t: paired_t(&d),
        trials: d.len(),
        delta_bic: this.bic - other.bic,
    }
}

/// t statistic of the mean of `d` (∞ for a consistent non-zero mean without spread).
fn paired_t(d: &[f64]) -> f64 {
    let n = d.len();
    if n < 2 {
        return 0.0;
    }
    let m = d.iter().sum::<f64>() / n as f64;
    let var = d.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1) as f64;
    let se = (var / n as f64).sqrt();
    if se > 0.0 {
        m / se
    } else if m > 0.0 {
        f64::INFINITY
    } else {
        0.0
    }
}

/// Jackknife standard error of ln(scale) from the per-fold fits.
fn jackknife_ln_std(folds: &[f64]) -> f64 {
    let k = folds.len();
    if k < 2 {
        return 0.0;
    }
    let l: Vec<f64> = folds.iter().map(|s| s.max(1e-9).ln()).collect();
    let m = l.iter().sum::<f64>() / k as f64;
    ((k - 1) as f64 / k as f64 * l.iter().map(|x| (x - m).powi(2)).sum::<f64>()).sqrt()
}

/// Least-squares stiffness scale of each trial's contact samples (measured against the
/// baseline along the contact normal).
fn trial_scales(data: &[TrialData]) -> Vec<f64> {
    let base: Vec<&[[f64; 3]]> = data.iter().map(|d| d.base_at_t.as_slice()).collect();
    trial_scales_of(data, &base)
}

/// The same against a prediction per trial.
fn trial_scales_of(data: &[TrialData], pred: &[&[[f64; 3]]]) -> Vec<f64> {
    data.iter()
        .zip(pred)
        .filter_map(|(d, p)| {
            let (mut fb, mut bb) = (0.0, 0.0);
            for j in 0..d.t.len().min(p.len()) {
                if d.phase[j] == Phase::Approach {
                    continue;
                }
                let (f, b) = (dot(d.f[j], d.normal), dot(p[j], d.normal));
                fb += f * b;
                bb += b * b;
            }
            (bb > 0.0 && fb > 0.0).then(|| fb / bb)
        })
        .collect()
}

/// The trial-to-trial stiffness scatter a global candidate leaves (sd of ln of each trial's
/// scale against its held-out prediction): the floor it must beat. The scatter against the
/// baseline alone would count a true global effect twice (a hardening makes the deeper
/// presses stiffer, a support the sites far from the fixed edge softer: both are scatter
/// until they are modelled), while a false one leaves the model's own site-to-site error.
pub fn residual_scatter(c: &CandidateScore, data: &[TrialData]) -> f64 {
    let pred: Vec<&[[f64; 3]]> = c.heldout_pred.iter().map(|p| p.as_slice()).collect();
    let l: Vec<f64> = trial_scales_of(data, &pred)
        .iter()
        .map(|x| x.ln())
        .collect();
    sd(&l)
}

fn sd(v: &[f64]) -> f64 {
    if v.len() < 2 {
        return 0.0;
    }
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
}

/// The model-error floor from the stiffness-only reference and the trials.
pub fn floor(reference: &CandidateScore, data: &[TrialData], noise: f64, opts: &Options) -> Floor {
    let s = reference.stiffness_scale.unwrap_or(1.0);
    let ln_sd = jackknife_ln_std(&reference.stiffness_folds);
    let per_trial: Vec<f64> = trial_scales(data).iter().map(|x| x.ln()).collect();
    let between = sd(&per_trial);
    let model_error = (reference.heldout_rmse.powi(2) - noise * noise)
        .max(0.0)
        .sqrt();
    let min_gain = between.max(opts.min_shrink);
    Floor {
        stiffness_scale: s,
        stiffness_scale_std: s * ln_sd,
        between_trial_scale_sd: between,
        heldout_rmse: reference.heldout_rmse,
        model_error_rmse: model_error,
        min_gain,
        local_min_gain: opts.min_shrink,
        stiffness_tolerance: opts.stiffness_tolerance,
        summary: format!(
            "stiffness scale {s:.3} ± {:.3} (between trials ±{:.1}%); held-out RMSE with it \
             {:.4} N ({model_error:.4} N above the noise); an effect needs a held-out gain \
             ≥ {:.1}% on its phases, trial by trial (t ≥ {MIN_T}), or {:.1}% with a per-trial \
             stiffness (friction, tilt, sensor, viscoelastic, device)",
            s * ln_sd,
            100.0 * between,
            reference.heldout_rmse,
            100.0 * min_gain,
            100.0 * opts.min_shrink
        ),
    }
}

/// Whether `this` beats `other` on `groups` beyond the floor, trial by trial.
fn beats(
    this: &CandidateScore,
    other: &CandidateScore,
    groups: &[VarGroup],
    min_gain: f64,
    n_trials: usize,
    opts: &Options,
) -> (bool, Evidence) {
    let mut ev = evidence(this, other, groups);
    if ev.trials == 0 {
        // the phases that carry it are absent (no slides): judged on every contact phase
        use VarGroup::*;
        ev = evidence(this, other, &[Loading, Hold, Unloading, Sliding]);
    }
    let ok = if n_trials >= MIN_TRIALS {
        // trial by trial: significant on average, or beyond the floor in three trials of
        // four (a large gain can miss t ≥ 3 on the spread of ln ratios, one trial without
        // the effect's phase inflating it: viscoelastic at 90% with t = 3.0 on the stand-in)
        (ev.t >= MIN_T || ev.quartile_trial_gain >= min_gain)
            && ev.trials >= MIN_TRIALS
            && ev.gain >= min_gain
            && ev.gain_weighted > 0.0
            && ev.delta_bic <= -10.0
    } else {
        ev.gain.max(ev.gain_weighted) >= opts.min_shrink && ev.delta_bic <= -10.0
    };
    (ok, ev)
}

/// What would separate two candidates that the data cannot tell apart.
pub fn separate_by(a: &str, b: &str) -> &'static str {
    let has = |x: &str| a.split('+').any(|e| e == x) || b.split('+').any(|e| e == x);
    if has("support") && (has("modulus") || has("hardening")) {
        "deeper presses (an elastic support softens the force as it grows, a modulus scales \
         it) and probings near the fixed edge (where the support matters least)"
    } else if has("hardening") && has("modulus") {
        "presses spanning a wider range of depths"
    } else if has("friction") && has("tilt") {
        "slides in opposite directions at the same site (friction opposes the motion, a \
         tilt does not change sign)"
    } else if has("sensor") && has("viscoelastic") {
        "a faster ramp and a longer hold (a sensor lags by a fixed time, a relaxation \
         continues through the hold)"
    } else if has("mesh") {
        "a refined replay mesh at the probed sites"
    } else {
        "more trials in the phases that carry them"
    }
}

/// A choice within one group: the winner (None: its reference) and the significant rivals.
struct Choice<'a> {
    win: Option<&'a CandidateScore>,
    /// Its evidence over the group's reference on its phases.
    ev: Option<Evidence>,
    rivals: Vec<&'a CandidateScore>,
}

/// The best candidate of a group that beats the reference beyond `min_gain`; pairs only when
/// each effect adds to the other (its own phases, against the other alone) beyond it.
fn choose<'a>(
    reference: &'a CandidateScore,
    singles: &'a [CandidateScore],
    pairs: &'a [CandidateScore],
    min_gain_of: &dyn Fn(&CandidateScore) -> f64,
    n_trials: usize,
    opts: &Options,
) -> Choice<'a> {
    let mut sig: Vec<(&CandidateScore, Evidence)> = singles
        .iter()
        .filter_map(|c| {
            let (ok, ev) = beats(
                c,
                reference,
                &groups_of(&c.effect),
                min_gain_of(c),
                n_trials,
                opts,
            );
            ok.then_some((c, ev))
        })
        .collect();
    sig.sort_by(|a, b| a.0.score.total_cmp(&b.0.score));
    let single_of = |name: &str| singles.iter().find(|c| c.effect == name);
    let mut sig_pairs: Vec<&CandidateScore> = if n_trials >= MIN_TRIALS && opts.pairs {
        pairs
            .iter()
            .filter(|p| {
                let parts: Vec<&str> = p.effect.split('+').collect();
                parts.len() == 2
                    && (0..2).all(|k| match single_of(parts[1 - k]) {
                        Some(o) => {
                            beats(p, o, &groups_of(parts[k]), min_gain_of(p), n_trials, opts).0
                        }
                        None => false,
                    })
                    && beats(
                        p,
                        reference,
                        &groups_of(&p.effect),
                        min_gain_of(p),
                        n_trials,
                        opts,
                    )
                    .0
            })
            .collect()
    } else {
        vec![]
    };
    sig_pairs.sort_by(|a, b| a.score.total_cmp(&b.score));
    match (sig.first(), sig_pairs.first()) {
        (_, Some(&p)) if sig.first().map(|s| p.score < s.0.score).unwrap_or(true) => Choice {
            win: Some(p),
            ev: Some(evidence(p, reference, &groups_of(&p.effect))),
            rivals: sig_pairs,
        },
        (Some(&(c, ev)), _) => Choice {
            win: Some(c),
            ev: Some(ev),
            rivals: sig.iter().map(|x| x.0).collect(),
        },
        _ => Choice {
            win: None,
            ev: None,
            rivals: vec![],
        },
    }
}

/// The effects the local group names on its own (empty: none): what the global group is
/// then fitted with, so a tilt's or a relaxation's change of the normal force is not read as
/// a stiffness offset.
pub fn local_effects(
    reference: &CandidateScore,
    singles: &[CandidateScore],
    pairs: &[CandidateScore],
    n_trials: usize,
    opts: &Options,
) -> Vec<Effect> {
    choose(
        reference,
        singles,
        pairs,
        &|_| opts.min_shrink,
        n_trials,
        opts,
    )
    .win
    .map(|c| c.effect.split('+').filter_map(Effect::parse).collect())
    .unwrap_or_default()
}

/// Rivals the data cannot tell from `win`: not worse trial by trial on any phase (t < 2).
fn indistinguishable_from(
    win: &CandidateScore,
    rivals: &[&CandidateScore],
    n_trials: usize,
) -> Vec<String> {
    use VarGroup::*;
    let all = [Free, NearContact, Loading, Hold, Unloading, Sliding];
    if n_trials < MIN_TRIALS {
        return vec![];
    }
    rivals
        .iter()
        .filter(|r| !std::ptr::eq(**r, win))
        .filter(|r| evidence(win, r, &all).t < 2.0)
        .map(|r| r.effect.clone())
        .collect()
}

/// The verdict (params and shrink are the caller's: it scores the named effects together);
/// the floor; the effects named (empty: `none`).
///
/// The two groups are decided apart and joined: a global one (`modulus` from the stiffness
/// scale beyond its tolerance and uncertainty, `support`, `mesh`) and a local one. So a
/// site-to-site stiffness error of tens of percent, which no global effect can remove,
/// neither hides a friction nor is read as `support`: it is the global group's floor
/// ([`Floor::min_gain`]) and the local group's nuisance.
pub fn decide(
    s: &Scored,
    data: &[TrialData],
    r0: f64,
    noise: f64,
    opts: &Options,
) -> (Verdict, Floor, Vec<Effect>) {
    let n_trials = data.len();
    let fl = floor(s.reference, data, noise, opts);
    let mk = |effect: String, reason: String| Verdict {
        effect,
        heldout_shrink: 0.0,
        params: vec![],
        reason,
        indistinguishable: vec![],
        separate_by: String::new(),
    };
    if r0 <= 1.15 * noise {
        let v = mk(
            "none".into(),
            format!("baseline residual {r0:.4} N is within noise ({noise:.4} N)"),
        );
        return (v, fl, vec![]);
    }
    // a stiffness offset beyond the tolerance and beyond its own uncertainty is `modulus`
    let stiffness_off = |c: &CandidateScore| {
        let sc = c.stiffness_scale.unwrap_or(1.0).max(1e-9);
        let se = jackknife_ln_std(&c.stiffness_folds);
        opts.effects.contains(&Effect::Modulus)
            && sc.ln().abs() > (1.0 + opts.stiffness_tolerance).ln() + 2.0 * se
    };
    let local = choose(
        s.local_reference,
        s.local_singles,
        s.local_pairs,
        &|_| fl.local_min_gain,
        n_trials,
        opts,
    );
    let global_floor = |c: &CandidateScore| residual_scatter(c, data).max(opts.min_shrink);
    let global = choose(s.reference, s.singles, &[], &global_floor, n_trials, opts);
    let mut names: Vec<Effect> = vec![];
    let mut reasons: Vec<String> = vec![];
    let mut same: Vec<String> = vec![];
    match (global.win, global.ev) {
        (Some(c), Some(ev)) => {
            // hardening carries its own small-strain scale (modulus+hardening is nested)
            if c.effect != "hardening" && stiffness_off(c) {
                names.push(Effect::Modulus);
            }
            names.extend(c.effect.split('+').filter_map(Effect::parse));
            reasons.push(format!(
                "{} (global stiffness scale {:.3}) gains {:.1}% on its phases over the \
                 stiffness-only fit, t = {:.1} over {} trials (floor {:.1}%: the trial-to-trial \
                 stiffness scatter it leaves; {:.1}% without it)",
                c.effect,
                c.stiffness_scale.unwrap_or(1.0),
                100.0 * ev.gain,
                ev.t,
                ev.trials,
                100.0 * global_floor(c),
                100.0 * fl.min_gain
            ));
            same.extend(indistinguishable_from(c, &global.rivals, n_trials));
        }
        _ if stiffness_off(s.reference) => {
            names.push(Effect::Modulus);
            reasons.push(format!(
                "the stiffness is off by more than the tolerated model error: scale {:.3} ± \
                 {:.3} (tolerance ±{:.0}%)",
                fl.stiffness_scale,
                fl.stiffness_scale_std,
                100.0 * opts.stiffness_tolerance
            ));
        }
        _ => {
            let best = s
                .singles
                .iter()
                .map(|c| (c, evidence(c, s.reference, &groups_of(&c.effect))))
                .max_by(|a, b| a.1.gain.total_cmp(&b.1.gain));
            reasons.push(format!(
                "the stiffness scale {:.3} ± {:.3} is within the tolerated ±{:.0}% and no \
                 global effect beats the floor{}",
                fl.stiffness_scale,
                fl.stiffness_scale_std,
                100.0 * opts.stiffness_tolerance,
                match best {
                    Some((c, ev)) => format!(
                        ": best {} gains {:.1}% on its phases (t = {:.1}; floor {:.1}%)",
                        c.effect,
                        100.0 * ev.gain,
                        ev.t,
                        100.0 * global_floor(c)
                    ),
                    None => String::new(),
                }
            ))
        }
    }
    match (local.win, local.ev) {
        (Some(c), Some(ev)) => {
            let mut ln: Vec<Effect> = c.effect.split('+').filter_map(Effect::parse).collect();
            // a verdict names at most two effects: with a global one, the local pair's
            // member that gains most alone
            if !names.is_empty() && ln.len() > 1 {
                let best = ln
                    .iter()
                    .copied()
                    .filter_map(|e| {
                        let c1 = s.local_singles.iter().find(|x| x.effect == e.name())?;
                        Some((
                            e,
                            evidence(c1, s.local_reference, &groups_of(e.name())).gain,
                        ))
                    })
                    .max_by(|a, b| a.1.total_cmp(&b.1));
                ln = best.map(|b| vec![b.0]).unwrap_or_default();
            }
            for e in ln {
                if !names.contains(&e) {
                    names.push(e);
                }
            }
            reasons.push(format!(
                "with each trial's own stiffness, {} shrinks the held-out RMSE {:.4} → {:.4} N, \
                 {:.1}% on its phases, t = {:.1} over {} trials (floor {:.1}%)",
                c.effect,
                s.local_reference.heldout_rmse,
                c.heldout_rmse,
                100.0 * ev.gain,
                ev.t,
                ev.trials,
                100.0 * fl.local_min_gain
            ));
            same.extend(indistinguishable_from(c, &local.rivals, n_trials));
        }
        _ => {
            let best = s
                .local_singles
                .iter()
                .map(|c| (c, evidence(c, s.local_reference, &groups_of(&c.effect))))
                .max_by(|a, b| a.1.gain.total_cmp(&b.1.gain));
            if let Some((c, ev)) = best {
                reasons.push(format!(
                    "with each trial's own stiffness no effect beats the floor: best {} gains \
                     {:.1}% on its phases (t = {:.1}; floor {:.1}%, t ≥ {MIN_T})",
                    c.effect,
                    100.0 * ev.gain,
                    ev.t,
                    100.0 * fl.local_min_gain
                ));
            }
        }
    }
    names.truncate(2);
    let effect = if names.is_empty() {
        "none".to_string()
    } else {
        super::effects::Candidate(names.clone()).name()
    };
    let mut verdict = mk(effect, reasons.join("; "));
    if !same.is_empty() && !names.is_empty() {
        let mut all = vec![verdict.effect.clone()];
        all.extend(same);
        all.dedup();
        verdict.separate_by = separate_by(&all[0], &all[1]).to_string();
        verdict.reason.push_str(&format!(
            "; indistinguishable on held-out data from {} (would separate them: {})",
            all[1..].join(", "),
            verdict.separate_by
        ));
        verdict.indistinguishable = all;
    }
    (verdict, fl, names)
}
