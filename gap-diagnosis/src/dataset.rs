//! Trials prepared for fitting: measured samples, the replay grid, baseline and re-simulated
//! forces, and the per-sample geometry (normal, depth, phase).
use super::effects::Effect;
use super::experiment::{Experiment, Region, Trial};
use super::metrics::{depth_series, phases, trial_normal, Phase};
use super::model::{replay_checked, ForceModel, ProbePath, Replayed, Variant};
use super::signal::{interp, nlerp, norm, sample_uniform};
use super::GapError;
use msgs::Pose;
use rayon::prelude::*;
use std::collections::HashMap;

/// A re-simulation at a fitted parameter value: (parameter value, force on the grid).
pub type ExtraKnot = (f64, Vec<[f64; 3]>);

/// A re-simulation at the parameters the whole experiment fits for a candidate's
/// re-simulated effects ([`crate::centres`]), kept as what it corrects in their
/// interpolation there ([`crate::effects::centre_for`]).
#[derive(Debug, Clone)]
pub struct Centre {
    /// The re-simulated effects, in application order, and their parameters there (the
    /// candidate's units: tilt in degrees, support compliance in m/N, μ).
    pub effects: Vec<Effect>,
    pub theta: Vec<f64>,
    /// Re-simulated force minus the effects' interpolation at `theta`, on the grid.
    pub correction: Vec<[f64; 3]>,
    /// For a centre of two effects, per parameter (in `theta`'s order), the re-simulated
    /// force's slope there minus the interpolation's, on the grid (N per parameter unit),
    /// from one more replay a step away ([`crate::centres`]): the interpolation of a pair
    /// adds each effect's delta as replayed without the other, so its slopes at the centre
    /// are the wrong ones. The single tilt's centre has them too: its rounds search on them,
    /// and the pairs of a tilt with an effect that is not re-simulated leave it along them.
    /// Empty for the support's centre (given slopes, it moved the device+support case's
    /// support from 3% to 19% off), or where a step's replay diverged.
    pub slopes: Vec<Vec<[f64; 3]>>,
    /// The distance from the centre at which its weight falls to 0, in multiples of its own
    /// distance from the neutral point ([`crate::effects::centre_weight`]): 1 once made, so
    /// the candidate is the baseline there; wider while a pair's or the tilt's rounds look for the next
    /// centre ([`crate::centres::SEARCH_REACH`]).
    pub reach: f64,
    /// The replay's own slopes at the centre, per parameter as [`Centre::slopes`] (the
    /// re-simulated force's change a step away, per unit, without the interpolation's taken
    /// off); given with the slopes, empty where they are.
    pub replay_slopes: Vec<Vec<[f64; 3]>>,
    /// While a pair's rounds search for their next centre ([`crate::centres`]): the candidate
    /// is the replay's tangent at the centre, with the re-simulated effects' interpolation
    /// held there, at every distance ([`crate::effects::predict`]); false once made.
    pub linear: bool,
    /// For a tilted centre, the probe's depth (mm) from the touch of the replay there, as
    /// [`TrialData::depth_grid`] is from the baseline's: a tilt moves where the probe first
    /// touches, and a hardening beside it stiffens with the depth pressed at the tilt
    /// ([`crate::effects::predict`]). Empty for an untilted centre.
    pub depth_grid: Vec<f64>,
}

#[derive(Debug, Clone)]
pub struct TrialData {
    pub name: String,
    pub region: Option<Region>,
    /// Measurement times and measured force.
    pub t: Vec<f64>,
    pub f: Vec<[f64; 3]>,
    /// Replay grid and the probe path on it.
    pub path: ProbePath,
    pub acc_grid: Vec<[f64; 3]>,
    pub depth_grid: Vec<f64>,
    /// Baseline replay on the grid.
    pub base: Vec<[f64; 3]>,
    /// The baseline replay diverged (the physics flagged a step, [`Replayed::diverged`]). It
    /// is reported in `diverged_replays`; the trial is still fitted on it, as every other
    /// prediction is relative to it and nothing replaces it.
    pub base_diverged: bool,
    /// Re-simulations per effect, in the order of `Effect::resims`. A diverged one (the
    /// physics flagged a faulty step: [`Replayed::diverged`]) is replaced by the baseline and
    /// flagged in `resim_ok`.
    pub resims: HashMap<Effect, Vec<Vec<[f64; 3]>>>,
    /// Per effect and knot: the re-simulation is usable (absent: all usable).
    pub resim_ok: HashMap<Effect, Vec<bool>>,
    /// Re-simulations added at fitted parameter values (calibration's refinement, see
    /// `calibrate::refine`): (parameter value, force on the grid) per piecewise-linear effect.
    /// Empty for a plain diagnosis.
    pub extra_knots: HashMap<Effect, Vec<ExtraKnot>>,
    /// The replay with a penalty layer of [`crate::fit::CONTACT_KNOT`] between probe and
    /// tissue: the contact nuisance's knot ([`crate::fit::Nuisance`]). None when it was not
    /// replayed (the nuisance off) or its replay diverged (`contact_knot_diverged`).
    pub contact_knot: Option<Vec<[f64; 3]>>,
    pub contact_knot_diverged: bool,
    /// The replay with the stable neo-Hookean law instead of the corotational one: the
    /// material nuisance's knot ([`crate::fit::MATERIAL_WEIGHT_MAX`]). None when it was not
    /// replayed (the nuisance off) or its replay diverged (`material_knot_diverged`).
    pub material_knot: Option<Vec<[f64; 3]>>,
    pub material_knot_diverged: bool,
    /// Re-simulations at fitted parameters ([`Centre`]; empty: none made, or diverged).
    pub centres: Vec<Centre>,
    /// Contact normal (outward), depth (mm) and phase at the measurement times.
    pub normal: [f64; 3],
    pub depth: Vec<f64>,
    pub phase: Vec<Phase>,
    /// Residual-variance group of each measurement ([`VarGroup`]).
    pub var_group: Vec<VarGroup>,
    /// Baseline at measurement times.
    pub base_at_t: Vec<[f64; 3]>,
}

impl TrialData {
    pub fn resim(&self, e: Effect) -> &Vec<Vec<[f64; 3]>> {
        &self.resims[&e]
    }
    pub fn has_resims(&self, e: Effect) -> bool {
        e.resims().is_empty() || self.resims.contains_key(&e)
    }
    /// Whether knot `k` of effect `e`'s re-simulations is usable.
    pub fn resim_valid(&self, e: Effect, k: usize) -> bool {
        self.resim_ok
            .get(&e)
            .and_then(|v| v.get(k).copied())
            .unwrap_or(true)
    }
    /// Labels (`trial: variant`) of the re-simulations found diverged.
    pub fn diverged_labels(&self) -> Vec<String> {
        let mut out = Vec::new();
        if self.base_diverged {
            out.push(format!("{}: {}", self.name, Variant::default().label()));
        }
        let mut effects: Vec<&Effect> = self.resim_ok.keys().collect();
        effects.sort();
        for e in effects {
            let vs = e.resims();
            for (k, ok) in self.resim_ok[e].iter().enumerate() {
                if !ok {
                    let label = vs.get(k).map(|v| v.label()).unwrap_or_default();
                    out.push(format!("{}: {label}", self.name));
                }
            }
        }
        if self.contact_knot_diverged {
            out.push(format!("{}: {}", self.name, contact_knot_variant().label()));
        }
        if self.material_knot_diverged {
            out.push(format!(
                "{}: {}",
                self.name,
                material_knot_variant().label()
            ));
        }
        out
    }
}

/// The probe path of a trial on a uniform grid starting at its first sample.
pub fn grid_path(trial: &Trial, dt: f64) -> ProbePath {
    let t0 = trial.t[0] - trial.lead_in.max(0.0);
    let t1 = *trial.t.last().unwrap();
    let n = ((t1 - t0) / dt).ceil() as usize + 1;
    let poses = (0..n)
        .map(|k| {
            let t = t0 + k as f64 * dt;
            let i = trial
                .t
                .partition_point(|&v| v <= t)
                .saturating_sub(1)
                .min(trial.t.len() - 2);
            // before the first sample (lead-in) the first motion is extended backwards
            let w = ((t - trial.t[i]) / (trial.t[i + 1] - trial.t[i]))
                .clamp(if i == 0 { f64::NEG_INFINITY } else { 0.0 }, 1.0);
            let (a, b) = (&trial.pose[i], &trial.pose[i + 1]);
            let mut p = [0.0; 3];
            for q in 0..3 {
                p[q] = a.position[q] + w * (b.position[q] - a.position[q]);
            }
            Pose {
                position: p,
                orientation: nlerp(a.orientation, b.orientation, w.max(0.0)),
            }
        })
        .collect();
    ProbePath { t0, dt, poses }
}

/// Samples out of contact this close (s) to a simulated contact count as near contact: the
/// contact's timing error and a sensor's delay and low-pass show there.
pub const CONTACT_MARGIN_S: f64 = 0.15;

/// Groups of measurements that get one residual variance each in the fits and scores: out of
/// contact, the residual is the sensor noise alone (plus a bias); near a contact, the contact's
/// timing; in contact, the model's error, which differs by phase.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VarGroup {
    Free = 0,
    NearContact = 1,
    Loading = 2,
    Hold = 3,
    Unloading = 4,
    Sliding = 5,
}

impl VarGroup {
    pub const COUNT: usize = 6;
    fn of(phase: Phase, near_contact: bool) -> VarGroup {
        match phase {
            Phase::Approach if near_contact => VarGroup::NearContact,
            Phase::Approach => VarGroup::Free,
            Phase::Loading => VarGroup::Loading,
            Phase::Hold => VarGroup::Hold,
            Phase::Unloading => VarGroup::Unloading,
            Phase::Sliding => VarGroup::Sliding,
        }
    }
}

/// Options for building the dataset.
#[derive(Debug, Clone)]
pub struct BuildOptions {
    /// Replay step, s (quasi-static stepping: larger than the node's 0.01 s is allowed
    /// because the probe is prescribed and inertia is negligible at probing speeds).
    pub dt: f64,
    pub progress: bool,
    /// Replay the contact nuisance's knot ([`contact_knot_variant`]) for every trial.
    pub contact_knot: bool,
    /// Replay the material nuisance's knot ([`material_knot_variant`]) for every trial.
    pub material_knot: bool,
}

/// The re-simulation the contact nuisance interpolates towards: the baseline with a penalty
/// layer of [`crate::fit::CONTACT_KNOT`] in series with the tissue under each probe ball.
pub fn contact_knot_variant() -> Variant {
    Variant {
        interface_compliance: crate::fit::CONTACT_KNOT,
        ..Variant::default()
    }
}

/// The re-simulation the material nuisance interpolates towards: the baseline with the stable
/// neo-Hookean law instead of the linear corotational one.
pub fn material_knot_variant() -> Variant {
    Variant {
        neo_hookean: true,
        ..Variant::default()
    }
}

/// A replay's cost per step relative to the corotational baseline's on the same mesh; only
/// its order matters. The stable neo-Hookean law: ×2.1, timed on three protocol probings of
/// the 1,435-node specimen since its element contracts the tangent term by term
/// (`examples/replay_timing.rs`: 2.52–2.57 s against 1.19–1.20 s; the other knots 0.9–1.3×,
/// left at 1). It was ×2.9 before that and ×6.5
/// before its tangent's projection became analytic; each puts the neo-Hookean replays first,
/// so the order, and so the output, is the same.
fn relative_replay_cost(v: &Variant) -> f64 {
    let mut c = 1.0;
    if v.neo_hookean {
        c *= 2.1;
    }
    if v.fine_mesh {
        // four times the facets, about eight times the nodes, a direct solve
        c *= 8.0;
    }
    c
}

/// What a replay in [`build`] is for.
#[derive(Debug, Clone, Copy, PartialEq)]
enum ReplayRole {
    Baseline,
    Resim(Effect),
    ContactKnot,
    MaterialKnot,
}

/// Replay every trial at baseline and at each re-simulation the `effects` need, in parallel.
pub fn build(
    exp: &Experiment,
    model: &dyn ForceModel,
    effects: &[Effect],
    opts: &BuildOptions,
) -> Result<Vec<TrialData>, GapError> {
    let paths: Vec<ProbePath> = exp.trials.iter().map(|t| grid_path(t, opts.dt)).collect();
    let mut variants: Vec<(ReplayRole, Variant)> = vec![(ReplayRole::Baseline, Variant::default())];
    for &e in effects {
        for v in e.resims() {
            variants.push((ReplayRole::Resim(e), v));
        }
    }
    if opts.contact_knot {
        variants.push((ReplayRole::ContactKnot, contact_knot_variant()));
    }
    if opts.material_knot {
        variants.push((ReplayRole::MaterialKnot, material_knot_variant()));
    }
    let only: Vec<Variant> = variants.iter().map(|(_, v)| v.clone()).collect();
    let path_refs: Vec<&ProbePath> = paths.iter().collect();
    let bar = progress_bar(
        opts.progress,
        (only.len() * paths.len()) as u64,
        "replaying",
    );
    let results = replay_grid(model, &only, &path_refs, || {
        if let Some(b) = &bar {
            b.inc(1);
        }
    });
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    let mut forces: Vec<Vec<Option<Replayed>>> = Vec::with_capacity(results.len());
    for (v, row) in results.into_iter().enumerate() {
        let mut own = Vec::with_capacity(row.len());
        for (t, r) in row.into_iter().enumerate() {
            own.push(Some(r.map_err(|e| {
                GapError::Sim(format!(
                    "trial {} ({}), {}: {e}",
                    exp.trials[t].name,
                    exp.trials[t].file.display(),
                    only[v].label()
                ))
            })?));
        }
        forces.push(own);
    }
    let mut out = Vec::with_capacity(paths.len());
    for (ti, (trial, path)) in exp.trials.iter().zip(paths).enumerate() {
        let base = forces[0][ti].take().unwrap();
        let base_diverged = base.diverged();
        let base = base.forces;
        let mut resims: HashMap<Effect, Vec<Vec<[f64; 3]>>> = HashMap::new();
        let mut usable: HashMap<Effect, Vec<bool>> = HashMap::new();
        let (mut contact_knot, mut material_knot) = (None, None);
        for (vi, (role, _)) in variants.iter().enumerate().skip(1) {
            let r = forces[vi][ti].take().unwrap();
            match role {
                ReplayRole::Resim(e) => {
                    usable.entry(*e).or_default().push(!r.diverged());
                    resims.entry(*e).or_default().push(r.forces);
                }
                ReplayRole::ContactKnot => contact_knot = Some(r),
                ReplayRole::MaterialKnot => material_knot = Some(r),
                ReplayRole::Baseline => {}
            }
        }
        let mut td = prepare(trial, path, base, resims);
        td.base_diverged = base_diverged;
        flag_diverged(&mut td, &usable);
        if let Some(r) = contact_knot {
            td.contact_knot_diverged = r.diverged();
            td.contact_knot = (!r.diverged()).then_some(r.forces);
        }
        if let Some(r) = material_knot {
            td.material_knot_diverged = r.diverged();
            td.material_knot = (!r.diverged()).then_some(r.forces);
        }
        out.push(td);
    }
    Ok(out)
}

/// Replays every prepared trial at `variant`, in parallel (the re-simulations made after the
/// dataset: calibration's extra knots, the tilt's centres). An error names the trial.
pub fn replay_trials(
    data: &[TrialData],
    model: &dyn ForceModel,
    variant: &Variant,
) -> Vec<Result<Replayed, GapError>> {
    let trials: Vec<&TrialData> = data.iter().collect();
    replay_trials_at(&trials, model, std::slice::from_ref(variant))
        .pop()
        .unwrap_or_default()
}

/// Replays each of `trials` at each of `variants` as one parallel batch, longest first
/// ([`replay_grid`], as the first build does); returned per variant, per trial. A pair's
/// centre needs four variants: the centre and a step along each parameter. An error names
/// the trial.
pub fn replay_trials_at(
    trials: &[&TrialData],
    model: &dyn ForceModel,
    variants: &[Variant],
) -> Vec<Vec<Result<Replayed, GapError>>> {
    let paths: Vec<&ProbePath> = trials.iter().map(|d| &d.path).collect();
    replay_grid(model, variants, &paths, || {})
        .into_iter()
        .zip(variants)
        .map(|(row, v)| {
            row.into_iter()
                .zip(trials)
                .map(|(r, d)| {
                    r.map_err(|err| {
                        GapError::Sim(format!("trial {}, {}: {err}", d.name, v.label()))
                    })
                })
                .collect()
        })
        .collect()
}

/// Every path replayed at every variant in parallel, returned per variant, per path; `done`
/// is called after each replay. The longest first, so the two threads finish together: a
/// neo-Hookean replay costs ~3 corotational ones (its element tangent is projected per
/// element and step), and when they came last one thread ran them alone (80 s of replays
/// where the work was 66 s, when it cost ~6).
fn replay_grid(
    model: &dyn ForceModel,
    variants: &[Variant],
    paths: &[&ProbePath],
    done: impl Fn() + Sync,
) -> Vec<Vec<Result<Replayed, GapError>>> {
    let mut jobs: Vec<(usize, usize)> = (0..variants.len())
        .flat_map(|v| (0..paths.len()).map(move |t| (v, t)))
        .collect();
    let cost =
        |&(v, t): &(usize, usize)| relative_replay_cost(&variants[v]) * paths[t].poses.len() as f64;
    jobs.sort_by(|a, b| cost(b).total_cmp(&cost(a)));
    let results: Vec<Result<Replayed, GapError>> = jobs
        .par_iter()
        .with_max_len(1)
        .map(|&(v, t)| {
            let r = replay_checked(model, &variants[v], paths[t]);
            done();
            r
        })
        .collect();
    let mut grid: Vec<Vec<Option<Result<Replayed, GapError>>>> = variants
        .iter()
        .map(|_| (0..paths.len()).map(|_| None).collect())
        .collect();
    for ((v, t), r) in jobs.into_iter().zip(results) {
        grid[v][t] = Some(r);
    }
    grid.into_iter()
        .map(|row| row.into_iter().flatten().collect())
        .collect()
}

/// Replace diverged re-simulations (`usable[e][k]` false: the physics flagged a faulty step)
/// by the baseline and flag them in `resim_ok` (the effects' interpolation then uses the
/// remaining knots).
pub fn flag_diverged(td: &mut TrialData, usable: &HashMap<Effect, Vec<bool>>) {
    let mut flags: HashMap<Effect, Vec<bool>> = HashMap::new();
    for (e, rs) in td.resims.iter_mut() {
        let ok: Vec<bool> = (0..rs.len())
            .map(|k| {
                usable
                    .get(e)
                    .and_then(|u| u.get(k).copied())
                    .unwrap_or(true)
            })
            .collect();
        if ok.iter().all(|&b| b) {
            continue;
        }
        for (r, &good) in rs.iter_mut().zip(&ok) {
            if !good {
                r.clone_from(&td.base);
            }
        }
        flags.insert(*e, ok);
    }
    td.resim_ok = flags;
}

pub fn progress_bar(show: bool, len: u64, msg: &'static str) -> Option<indicatif::ProgressBar> {
    if !show {
        return None;
    }
    let b = indicatif::ProgressBar::new(len);
    b.set_style(
        indicatif::ProgressStyle::with_template("{msg:>10} [{bar:40}] {pos}/{len} {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    b.set_message(msg);
    Some(b)
}

/// Geometry and phases of a trial once its baseline replay is known.
pub fn prepare(
    trial: &Trial,
    path: ProbePath,
    base: Vec<[f64; 3]>,
    resims: HashMap<Effect, Vec<Vec<[f64; 3]>>>,
) -> TrialData {
    let pos = path.positions();
    let normal = trial_normal(&base, &trial.force);
    let depth_grid = depth_series(&pos, &base, normal);
    let peak = base.iter().map(|f| norm(*f)).fold(0.0, f64::max);
    let contact: Vec<bool> = base
        .iter()
        .zip(&depth_grid)
        .map(|(f, d)| norm(*f) > (0.03 * peak).max(0.01) || *d > 0.0)
        .collect();
    let ph_grid = phases(&pos, &depth_grid, normal, path.dt, &contact);
    let dt = path.dt;
    let n = pos.len();
    let acc_grid: Vec<[f64; 3]> = (0..n)
        .map(|i| {
            if i == 0 || i + 1 >= n {
                return [0.0; 3];
            }
            let mut a = [0.0; 3];
            for q in 0..3 {
                a[q] = (pos[i + 1][q] - 2.0 * pos[i][q] + pos[i - 1][q]) / (dt * dt);
            }
            a
        })
        .collect();
    let tg: Vec<f64> = (0..n).map(|k| path.t0 + k as f64 * dt).collect();
    let depth: Vec<f64> = trial
        .t
        .iter()
        .map(|&t| interp(&tg, &depth_grid, t))
        .collect();
    let phase: Vec<Phase> = trial
        .t
        .iter()
        .map(|&t| ph_grid[(((t - path.t0) / dt).round() as usize).min(n - 1)])
        .collect();
    // grid steps to the nearest simulated contact (forward and backward passes)
    let mut dist = vec![usize::MAX; n];
    let mut last = None;
    for i in 0..n {
        if contact[i] {
            last = Some(i);
        }
        if let Some(l) = last {
            dist[i] = i - l;
        }
    }
    last = None;
    for i in (0..n).rev() {
        if contact[i] {
            last = Some(i);
        }
        if let Some(l) = last {
            dist[i] = dist[i].min(l - i);
        }
    }
    let margin = (CONTACT_MARGIN_S / dt).ceil() as usize;
    let var_group: Vec<VarGroup> = trial
        .t
        .iter()
        .zip(&phase)
        .map(|(&t, &ph)| {
            let k = (((t - path.t0) / dt).round().max(0.0) as usize).min(n - 1);
            VarGroup::of(ph, dist[k] <= margin)
        })
        .collect();
    let base_at_t = trial
        .t
        .iter()
        .map(|&t| sample_uniform(path.t0, dt, &base, t))
        .collect();
    TrialData {
        name: trial.name.clone(),
        region: trial.region,
        t: trial.t.clone(),
        f: trial.force.clone(),
        path,
        acc_grid,
        depth_grid,
        base,
        resims,
        resim_ok: HashMap::new(),
        extra_knots: HashMap::new(),
        contact_knot: None,
        contact_knot_diverged: false,
        material_knot: None,
        material_knot_diverged: false,
        base_diverged: false,
        centres: Vec::new(),
        normal,
        depth,
        phase,
        var_group,
        base_at_t,
    }
}

/// For unit tests: a trial of `n` samples `dt` apart, at rest at the origin, pressed along z
/// from its third sample to its third-last (the first and last two free). The replay gives
/// `replayed` N while it presses and nothing elsewhere; the measurement `measured` N there
/// and `bias` N where it does not. Its grid is the measurement's own times.
#[cfg(test)]
pub(crate) fn pressed_at_rest(
    region: Option<Region>,
    n: usize,
    dt: f64,
    [replayed, measured, bias]: [f64; 3],
) -> TrialData {
    let poses: Vec<Pose> = (0..n)
        .map(|_| Pose {
            position: [0.0; 3],
            orientation: [0.0, 0.0, 0.0, 1.0],
        })
        .collect();
    let pressing = |i: usize| (2..n - 2).contains(&i);
    let along_z = |inside: f64, outside: f64| -> Vec<[f64; 3]> {
        (0..n)
            .map(|i| [0.0, 0.0, if pressing(i) { inside } else { outside }])
            .collect()
    };
    let trial = Trial {
        name: "press".into(),
        file: Default::default(),
        region,
        t: (0..n).map(|i| i as f64 * dt).collect(),
        force: along_z(measured, bias),
        pose: poses.clone(),
        lead_in: 0.0,
    };
    let base = along_z(replayed, 0.0);
    let path = ProbePath { t0: 0.0, dt, poses };
    let mut td = prepare(&trial, path, base.clone(), Default::default());
    td.base_at_t = base;
    td
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::experiment::load_experiment;
    use crate::model::Replayed;
    use crate::reality::{flat_sites, write_experiment_with, RealitySpec};

    /// A model whose replays at `faulty` are flagged by "the physics"; no contact otherwise.
    struct FlagsOne {
        faulty: Variant,
    }
    impl ForceModel for FlagsOne {
        fn replay_untilted(&self, _: &Variant, p: &ProbePath) -> Result<Vec<[f64; 3]>, GapError> {
            Ok(vec![[0.0; 3]; p.poses.len()])
        }
        fn replay_untilted_checked(
            &self,
            v: &Variant,
            p: &ProbePath,
        ) -> Result<Replayed, GapError> {
            Ok(Replayed {
                forces: self.replay_untilted(v, p)?,
                faulty_steps: u64::from(*v == self.faulty),
            })
        }
        fn describe(&self) -> String {
            "flags one variant".into()
        }
    }

    /// Regression: a baseline replay the physics flagged was used without a word (only the
    /// re-simulations and the nuisances' knots were checked); it is now named in
    /// `diverged_replays` like they are.
    #[test]
    fn a_diverged_baseline_is_reported() {
        let sites = flat_sites();
        let dir = std::env::temp_dir().join(format!("dataset_baseline_{}", std::process::id()));
        let mut spec = RealitySpec::from_effects(&["none"], 4).unwrap();
        spec.probings_per_region = 1;
        let truth = FlagsOne {
            faulty: Variant::default(),
        };
        write_experiment_with(&spec, &truth, &sites, &dir.join("exp"), &dir.join("t.json"))
            .unwrap();
        let exp = load_experiment(&dir.join("exp"), &crate::data_dir()).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        let opts = BuildOptions {
            dt: 0.02,
            progress: false,
            contact_knot: true,
            material_knot: false,
        };
        let data = build(&exp, &truth, &[], &opts).unwrap();
        assert_eq!(data.len(), 3);
        for d in &data {
            assert!(d.base_diverged);
            assert_eq!(d.diverged_labels(), vec![format!("{}: baseline", d.name)]);
        }
        // the knot flagged instead: the baseline is clean
        let knot = FlagsOne {
            faulty: contact_knot_variant(),
        };
        let data = build(&exp, &knot, &[], &opts).unwrap();
        for d in &data {
            assert!(!d.base_diverged && d.contact_knot_diverged);
            assert_eq!(d.diverged_labels().len(), 1);
        }
    }
}
