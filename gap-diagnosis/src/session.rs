//! arthrosim session recordings (MCAP) as gap-diagnosis input.
//!
//! A recording becomes an [`Experiment`]: the specimen, material and probe come from its
//! `scene.toml` attachment; one trial per probing (the device ticks' protocol annotations,
//! or contact onset/offset when the session has none); the measured force is the physics
//! step's contact force on the probe (`ContactStep.contact_force`, eq. (1)) and the pose the
//! probe pose of that step. The device ticks also give the rendering gap: what the device
//! rendered against the physics model's force on the same trajectory ([`rendering_gap`]).
use super::experiment::{
    Experiment, ExperimentSpec, MaterialSpec, ProbeSpec, Region, SpecimenSpec, TransformSpec,
    Trial, TrialSpec,
};
use super::signal::{interp, lag_by_xcorr, norm, sub};
use super::GapError;
use launch_config::{DeviceConfig, LaunchFile, SceneConfig};
use msgs::Pose;
use recordings::channels::*;
use recordings::read::{scan, Event};
use serde::{Deserialize, Serialize};
use session_metrics::Annotations;
use std::path::{Path, PathBuf};

/// Force magnitude above which a device tick counts in the rendering gap (model or device
/// side), N. Whether the probe touches the tissue is session-metrics' definition instead.
const CONTACT_FORCE_N: f64 = 1e-3;
/// Contact runs closer than this are one probing (a probe chattering at the surface), s.
const MERGE_GAP_S: f64 = 0.25;
/// Approach / release kept around a contact run when trials are split on contact, s.
const PAD_S: f64 = 0.5;

/// What the gap diagnosis needs from a recording.
#[derive(Debug, Clone)]
pub struct SessionRecording {
    pub path: PathBuf,
    pub scene: SceneConfig,
    /// Device limits and force scale the session ran with (`launch.toml` attachment).
    pub device: DeviceConfig,
    /// Where `device` came from (`launch.toml` or why defaults were used).
    pub device_source: String,
    /// The recorded launch file (`launch.toml` attachment), when readable: the base of a
    /// calibrated launch file.
    pub launch: Option<LaunchFile>,
    pub steps: Vec<ContactStep>,
    pub ticks: Vec<DeviceTick>,
}

fn input_err(path: &Path, msg: impl Into<String>) -> GapError {
    GapError::Input {
        file: path.to_path_buf(),
        msg: msg.into(),
    }
}

fn has_mcap_magic(path: &Path) -> bool {
    use std::io::Read;
    let mut buf = [0u8; 8];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut buf))
        .map(|_| buf == *mcap::MAGIC)
        .unwrap_or(false)
}

/// The recording an input path stands for: an `.mcap` file (or any file starting with the
/// MCAP magic), or a folder without `experiment.toml` holding exactly one `.mcap`.
/// `Ok(None)`: not a session input (an experiment folder or something else).
pub fn session_file(path: &Path) -> Result<Option<PathBuf>, GapError> {
    if path.is_file() {
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
        return Ok(
            (ext.eq_ignore_ascii_case("mcap") || has_mcap_magic(path)).then(|| path.to_path_buf())
        );
    }
    if !path.is_dir() || path.join("experiment.toml").exists() {
        return Ok(None);
    }
    let entries = std::fs::read_dir(path).map_err(|e| GapError::Io(path.to_path_buf(), e))?;
    let mut found: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.is_file()
                && p.extension()
                    .and_then(|e| e.to_str())
                    .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
        })
        .collect();
    found.sort();
    match found.len() {
        0 => Ok(None),
        1 => Ok(found.pop()),
        _ => Err(input_err(
            path,
            format!(
                "no experiment.toml and {} recordings ({}); name one .mcap file",
                found.len(),
                found
                    .iter()
                    .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )),
    }
}

/// Reads the lossless channels and the scene/launch attachments of a recording.
pub fn read_session(path: &Path) -> Result<SessionRecording, GapError> {
    let mut lossless = recordings::export::LosslessChannels::default();
    let mut scene_text: Option<String> = None;
    let mut launch_text: Option<String> = None;
    let outcome = scan(path, &mut |event| {
        match event {
            Event::Message {
                channel,
                header,
                data,
            } => lossless.push(path, channel, &header, data)?,
            Event::Attachment { name, data, .. } => {
                let text = String::from_utf8_lossy(data).into_owned();
                if name == ATTACHMENT_SCENE {
                    scene_text = Some(text);
                } else if name == ATTACHMENT_LAUNCH {
                    launch_text = Some(text);
                }
            }
            Event::Metadata(_) => {}
        }
        Ok(())
    })?;
    if outcome.profile != PROFILE {
        return Err(recordings::RecordingError::WrongProfile {
            path: path.to_path_buf(),
            found: outcome.profile,
        }
        .into());
    }
    let recordings::export::LosslessChannels { steps, ticks, .. } = lossless;
    if steps.is_empty() {
        return Err(input_err(
            path,
            format!(
                "recording has no {TOPIC_CONTACT_STEP} messages: the measured force and probe \
                 pose of a session come from its physics steps (was the physics node running?)"
            ),
        ));
    }
    let launch: Option<Result<LaunchFile, String>> = launch_text
        .as_deref()
        .filter(|t| !t.trim().is_empty())
        .map(|t| toml::from_str::<LaunchFile>(t).map_err(|e| e.message().to_string()));
    // The scene attachment is the scene after defaults; the launch file's [scene] is the
    // fallback for files written without it.
    let scene = match scene_text {
        Some(t) => toml::from_str::<SceneConfig>(&t).map_err(|e| {
            input_err(
                path,
                format!("attachment {ATTACHMENT_SCENE}: {}", e.message().trim()),
            )
        })?,
        None => match &launch {
            Some(Ok(l)) => l.scene.clone(),
            _ => {
                return Err(input_err(
                    path,
                    format!(
                        "recording has no {ATTACHMENT_SCENE} attachment: the specimen, material \
                         and probe the session ran with are unknown"
                    ),
                ))
            }
        },
    };
    let recorded_launch = launch.as_ref().and_then(|l| l.as_ref().ok()).cloned();
    let (device, device_source) = match launch {
        Some(Ok(l)) => (l.device, format!("{ATTACHMENT_LAUNCH} attachment")),
        Some(Err(e)) => (
            DeviceConfig::default(),
            format!("defaults ({ATTACHMENT_LAUNCH} attachment unreadable: {e})"),
        ),
        None => (
            DeviceConfig::default(),
            format!("defaults (no {ATTACHMENT_LAUNCH} attachment, or empty)"),
        ),
    };
    Ok(SessionRecording {
        path: path.to_path_buf(),
        scene,
        device,
        device_source,
        launch: recorded_launch,
        steps,
        ticks,
    })
}

/// The physics instance with the most steps (a restarted physics node starts its time and
/// sequence again; only one instance can be replayed as one specimen history).
fn main_instance(steps: &[ContactStep]) -> u64 {
    let mut counts: std::collections::BTreeMap<u64, usize> = Default::default();
    for s in steps {
        *counts.entry(s.instance_id).or_default() += 1;
    }
    counts
        .into_iter()
        .max_by_key(|(_, n)| *n)
        .map(|(i, _)| i)
        .unwrap_or(0)
}

/// Protocol annotations of the ticks, by tick sequence (`session_metrics::matching`).
fn annotations(ticks: &[DeviceTick]) -> Annotations {
    let mut a = Annotations::default();
    for t in ticks {
        a.push(t.sequence, t.region, t.probing_index, t.phase);
    }
    a
}

fn region_of(code: u32) -> Option<Region> {
    Region::from_code(code)
}

/// Touching the tissue, as `session_metrics::ContactSample::in_contact` defines it (some
/// constraint carries a normal impulse), not merely contacts within the alarm distance.
fn in_contact(s: &ContactStep) -> bool {
    s.sample().in_contact()
}

/// Index ranges of the steps forming each probing: runs of one annotated probing index, or,
/// without annotations, contact runs (merged across short breaks) padded for approach and
/// release.
fn probing_ranges(steps: &[&ContactStep], ann: &[(u32, u32, u32)]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    if ann.iter().any(|a| a.1 > 0) {
        let mut i = 0;
        while i < steps.len() {
            let p = ann[i].1;
            let mut j = i + 1;
            while j < steps.len() && ann[j].1 == p {
                j += 1;
            }
            if p > 0 {
                out.push((i, j));
            }
            i = j;
        }
        return out;
    }
    let t = |k: usize| steps[k].sim_time;
    let mut runs: Vec<(usize, usize)> = Vec::new();
    let mut i = 0;
    while i < steps.len() {
        if !in_contact(steps[i]) {
            i += 1;
            continue;
        }
        let mut j = i + 1;
        while j < steps.len() && in_contact(steps[j]) {
            j += 1;
        }
        match runs.last_mut() {
            Some(last) if t(i) - t(last.1 - 1) < MERGE_GAP_S => last.1 = j,
            _ => runs.push((i, j)),
        }
        i = j;
    }
    for (k, &(a, b)) in runs.iter().enumerate() {
        // pad into the free time around the run, never past the middle of the gap to a
        // neighbouring run (each step belongs to one trial)
        let lo_t = match k {
            0 => f64::NEG_INFINITY,
            _ => 0.5 * (t(runs[k - 1].1 - 1) + t(a)),
        }
        .max(t(a) - PAD_S);
        let hi_t = match runs.get(k + 1) {
            None => f64::INFINITY,
            Some(n) => 0.5 * (t(b - 1) + t(n.0)),
        }
        .min(t(b - 1) + PAD_S);
        let mut lo = a;
        while lo > 0 && t(lo - 1) >= lo_t {
            lo -= 1;
        }
        let mut hi = b;
        while hi < steps.len() && t(hi) <= hi_t {
            hi += 1;
        }
        out.push((lo, hi));
    }
    out
}

/// What a trial taken from a session holds of contact, in session-metrics' terms: the
/// numbers a researcher checks against the session summary and the study CSV.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TrialContact {
    pub name: String,
    pub region: Option<Region>,
    pub probing_index: u32,
    /// Physics steps of the trial in contact (`ContactSample::in_contact`).
    pub contact_steps: u64,
    /// Mean normal force F_n = −f·n over those steps, N (negative in compression).
    pub mean_normal_force_n: Option<f64>,
}

/// The experiment a recording stands for (see the module docs).
pub fn experiment_from_session(rec: &SessionRecording) -> Result<Experiment, GapError> {
    Ok(trials_from_session(rec)?.0)
}

/// The trials the diagnosis takes from a recording, with their contact in session terms.
pub fn trial_contacts(rec: &SessionRecording) -> Result<Vec<TrialContact>, GapError> {
    Ok(trials_from_session(rec)?.1)
}

fn trials_from_session(
    rec: &SessionRecording,
) -> Result<(Experiment, Vec<TrialContact>), GapError> {
    let path = &rec.path;
    let instance = main_instance(&rec.steps);
    let mut steps: Vec<&ContactStep> = rec
        .steps
        .iter()
        .filter(|s| s.instance_id == instance)
        .collect();
    // file order is step order for the recorder; a merged or repaired file may not be
    steps.sort_by_key(|s| s.sequence);
    let ann_by_seq = annotations(&rec.ticks);
    let ann: Vec<(u32, u32, u32)> = steps
        .iter()
        .map(|s| {
            let a = ann_by_seq
                .of_step(s.device_sequence_used)
                .unwrap_or_default();
            (a.region, a.probing_index, a.phase)
        })
        .collect();
    let ranges = probing_ranges(&steps, &ann);
    let annotated = ann.iter().any(|a| a.1 > 0);
    let mut trials = Vec::new();
    let mut contacts = Vec::new();
    let mut specs = Vec::new();
    let mut skipped_no_contact = 0;
    for (lo, hi) in ranges {
        let run = &steps[lo..hi];
        if !run.iter().any(|s| in_contact(s)) {
            // a probing that never touched the tissue says nothing about the tissue model
            skipped_no_contact += 1;
            continue;
        }
        // region: the most frequent annotated region of the run
        let mut votes = [0usize; 4];
        for a in &ann[lo..hi] {
            votes[(a.0 as usize).min(3)] += 1;
        }
        let region = (1..=3)
            .filter(|&c| votes[c] > 0)
            .max_by_key(|&c| votes[c])
            .and_then(|c| region_of(c as u32));
        let (mut t, mut force, mut pose) = (Vec::new(), Vec::new(), Vec::new());
        for s in run {
            let p: Pose = (&s.probe_pose).into();
            let f = [s.contact_force.x, s.contact_force.y, s.contact_force.z];
            let q = p.orientation;
            let qn = (q.iter().map(|v| v * v).sum::<f64>()).sqrt();
            let finite = s.sim_time.is_finite()
                && f.iter().chain(&p.position).all(|v| v.is_finite())
                && qn.is_finite()
                && qn > 1e-6;
            // time must increase strictly for the replay grid; a repeated step is dropped
            if !finite || t.last().is_some_and(|&l| s.sim_time <= l) {
                continue;
            }
            t.push(s.sim_time);
            force.push(f);
            pose.push(Pose {
                position: p.position,
                orientation: [q[0] / qn, q[1] / qn, q[2] / qn, q[3] / qn],
            });
        }
        if t.len() < 5 {
            continue;
        }
        let index = if annotated {
            ann[lo].1 as usize
        } else {
            trials.len() + 1
        };
        let mut name = format!(
            "probing_{index:03}_{}",
            region
                .map(|r| r.name())
                .unwrap_or(msgs::protocol::UNLABELLED)
        );
        // a protocol that runs again restarts its probing index: keep trial names unique
        let repeats = trials
            .iter()
            .filter(|t: &&Trial| t.name.starts_with(&name))
            .count();
        if repeats > 0 {
            name = format!("{name}_{}", repeats + 1);
        }
        let (mut contact_steps, mut normal_sum) = (0u64, 0.0);
        for sample in run.iter().map(|s| s.sample()).filter(|s| s.in_contact()) {
            contact_steps += 1;
            normal_sum += sample.normal_force();
        }
        contacts.push(TrialContact {
            name: name.clone(),
            region,
            probing_index: if annotated { ann[lo].1 } else { 0 },
            contact_steps,
            mean_normal_force_n: (contact_steps > 0).then(|| normal_sum / contact_steps as f64),
        });
        specs.push(TrialSpec {
            file: format!("{}#{name}", path.display()),
            region: region.map(|r| r.name().to_string()),
        });
        trials.push(Trial {
            name,
            file: path.clone(),
            region,
            t,
            force,
            pose,
            lead_in: 0.0,
        });
    }
    if trials.is_empty() {
        return Err(input_err(
            path,
            format!(
                "no probing with tissue contact in {} physics steps{}: nothing to compare",
                steps.len(),
                if skipped_no_contact > 0 {
                    format!(" ({skipped_no_contact} probing(s) without contact)")
                } else {
                    String::new()
                }
            ),
        ));
    }
    let sc = &rec.scene;
    let m = &sc.meniscus;
    let spec = ExperimentSpec {
        specimen: SpecimenSpec {
            mesh: m.mesh.clone(),
            fixed: m.fixed.clone(),
            transform: Some(TransformSpec {
                scale: m.transform.scale,
                rotation_deg: m.transform.rotation_deg,
                translation: m.transform.translation,
            }),
        },
        material: MaterialSpec {
            preset: sc.material.preset,
            youngs_modulus: sc.material.youngs_modulus,
            poisson_ratio: sc.material.poisson_ratio,
        },
        probe: ProbeSpec {
            model: sc.probe.model.clone(),
            tip_radius: sc.probe.tip_radius,
            mass: sc.probe.mass,
        },
        trials: specs,
    };
    Ok((
        Experiment {
            dir: path.clone(),
            spec,
            trials,
            quasi_static: false,
        },
        contacts,
    ))
}

/// Device limits the rendering gap is judged against.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RenderLimits {
    pub peak_force_n: f64,
    pub continuous_force_n: f64,
    pub force_scale: f64,
    pub source: String,
}

/// Rendering-gap statistics of one group of ticks in contact.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RenderGroup {
    pub group: String,
    pub ticks: usize,
    /// RMS of |rendered − model|, N.
    pub rmse_n: f64,
    /// Mean of |rendered| − |model|, N (negative: the device renders less).
    pub mean_error_n: f64,
    /// Least-squares gain k of rendered ≈ k · model.
    pub force_scale_fit: f64,
    /// Fraction of ticks at the peak force.
    pub saturated_fraction: f64,
    /// Fraction of ticks limited by the peak or continuous clamp (fault bit).
    pub clamped_fraction: f64,
}

/// Decimated magnitudes for the report's plot.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct RenderSeries {
    /// Seconds from the first tick.
    pub t: Vec<f64>,
    pub model: Vec<f64>,
    pub commanded: Vec<f64>,
    pub rendered: Vec<f64>,
}

/// Device-rendered force vs the physics model's force on the same trajectory.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RenderingGap {
    pub session: String,
    pub limits: RenderLimits,
    /// Ticks matched to the physics step whose frame they rendered.
    pub ticks: usize,
    pub unmatched_ticks: usize,
    /// Matched ticks in contact (the statistics below are over these).
    pub contact_ticks: usize,
    pub mean_model_force_n: f64,
    pub mean_rendered_force_n: f64,
    /// RMS of |rendered − model| (vector difference), N.
    pub rmse_n: f64,
    /// Mean of |rendered| − |model|, N.
    pub mean_error_n: f64,
    /// Least-squares gain rendered ≈ k · model, all contact ticks and unclamped ones only.
    pub force_scale_fit: f64,
    pub force_scale_fit_unclamped: Option<f64>,
    /// Coupling: the per-tick local contact update (commanded / force_scale) vs the step's
    /// force, RMS N.
    pub coupling_rmse_n: f64,
    /// Limits: rendered vs commanded (peak, continuous and rate limits), RMS N.
    pub limiter_rmse_n: f64,
    /// Scaling: the part explained by force_scale ≠ 1, RMS N.
    pub scaling_rmse_n: f64,
    /// Lag of the rendered force magnitude behind the model's (cross-correlation), s; None
    /// when the peak correlation is 0.5 or less.
    pub lag_s: Option<f64>,
    pub lag_correlation: Option<f64>,
    /// Mean age of the physics frame each tick rendered, s.
    pub mean_frame_age_s: f64,
    /// Fractions of contact ticks: at the peak force, clamped (peak or continuous), at the
    /// continuous limit (clamped below the peak), rate-limited, and where the model asked for
    /// more than the peak.
    pub saturated_peak_fraction: f64,
    pub clamped_fraction: f64,
    pub continuous_limited_fraction: f64,
    pub rate_limited_fraction: f64,
    pub model_above_peak_fraction: f64,
    pub by_region: Vec<RenderGroup>,
    /// Lag: RMS change of the model force over the lag, N.
    pub lag_rmse_n: f64,
    /// The largest contribution: `saturation`, `coupling`, `scaling`, `lag` or `none`.
    pub dominant: String,
    pub summary: String,
    pub series: RenderSeries,
}

#[derive(Default)]
struct GroupAcc {
    n: usize,
    se: f64,
    me: f64,
    rm: f64,
    mm: f64,
    sat: usize,
    clamped: usize,
}

impl GroupAcc {
    fn push(&mut self, m: [f64; 3], r: [f64; 3], sat: bool, clamped: bool) {
        let d = sub(r, m);
        self.n += 1;
        self.se += d.iter().map(|v| v * v).sum::<f64>();
        self.me += norm(r) - norm(m);
        self.rm += r.iter().zip(&m).map(|(a, b)| a * b).sum::<f64>();
        self.mm += m.iter().map(|v| v * v).sum::<f64>();
        self.sat += sat as usize;
        self.clamped += clamped as usize;
    }
    fn summary(&self, group: String) -> RenderGroup {
        let n = self.n.max(1) as f64;
        RenderGroup {
            group,
            ticks: self.n,
            rmse_n: (self.se / n).sqrt(),
            mean_error_n: self.me / n,
            force_scale_fit: if self.mm > 0.0 {
                self.rm / self.mm
            } else {
                f64::NAN
            },
            saturated_fraction: self.sat as f64 / n,
            clamped_fraction: self.clamped as f64 / n,
        }
    }
}

fn v3(v: &msgs::ros::Vector3) -> [f64; 3] {
    [v.x, v.y, v.z]
}

/// The rendering gap of a session: each device tick's rendered force against the contact
/// force of the physics step whose frame it rendered (same trajectory, same instant of the
/// model), split into coupling (local contact update between physics steps), limits
/// (saturation at the peak / continuous force, rate limit), scaling and lag.
pub fn rendering_gap(rec: &SessionRecording) -> Result<RenderingGap, GapError> {
    let path = &rec.path;
    if rec.ticks.is_empty() {
        return Err(input_err(
            path,
            format!(
                "recording has no {TOPIC_DEVICE_TICK} messages: the rendering gap compares the \
                 device's rendered force with the model's (was the haptic node running?)"
            ),
        ));
    }
    let d = &rec.device;
    let peak = d.peak_force_n;
    // The scale the session rendered with (`force_scale = 0` is the automatic choice).
    let scale = d.rendering().force_scale;
    let mut by_key: Vec<((u64, u64), usize)> = rec
        .steps
        .iter()
        .enumerate()
        .map(|(i, s)| ((s.instance_id, s.sequence), i))
        .collect();
    by_key.sort_unstable();
    let mut ticks: Vec<&DeviceTick> = rec.ticks.iter().collect();
    ticks.sort_by_key(|t| (t.header.stamp.to_nanos(), t.sequence));
    let t0 = ticks[0].header.stamp.to_nanos();
    let secs = |ns: u64| (ns as i128 - t0 as i128) as f64 * 1e-9;

    let mut all = GroupAcc::default();
    let mut regions: [GroupAcc; 4] = Default::default();
    let (mut matched, mut unmatched) = (0usize, 0usize);
    let (mut sum_m, mut sum_r, mut age) = (0.0, 0.0, 0.0);
    let (mut cont, mut rate, mut above) = (0usize, 0usize, 0usize);
    let (mut se_coupling, mut se_limiter, mut se_scaling) = (0.0, 0.0, 0.0);
    let (mut rm_u, mut mm_u) = (0.0, 0.0);
    let mut series: Vec<(f64, f64, f64, f64)> = Vec::new();
    let mut contact_times: Vec<f64> = Vec::new();
    for t in &ticks {
        let key = (t.frame_instance_used, t.frame_sequence_used);
        let Ok(k) = by_key.binary_search_by_key(&key, |e| e.0) else {
            unmatched += 1;
            continue;
        };
        matched += 1;
        let s = &rec.steps[by_key[k].1];
        let (m, c, r) = (
            v3(&s.contact_force),
            v3(&t.commanded_force),
            v3(&t.rendered_force),
        );
        let tick_t = secs(t.header.stamp.to_nanos());
        series.push((tick_t, norm(m), norm(c), norm(r)));
        // in contact when either side has a force: a device pushing while the model has no
        // contact is part of the gap
        if norm(m) <= CONTACT_FORCE_N && norm(r) <= CONTACT_FORCE_N {
            continue;
        }
        contact_times.push(tick_t);
        let sat = norm(r) >= peak * (1.0 - 1e-3);
        let clamped = t.faults & msgs::haptic_to_physics::fault::FORCE_CLAMPED != 0;
        all.push(m, r, sat, clamped);
        regions[(t.region as usize).min(3)].push(m, r, sat, clamped);
        sum_m += norm(m);
        sum_r += norm(r);
        age += t.frame_age_ns as f64 * 1e-9;
        cont += (clamped && !sat) as usize;
        rate += (t.faults & msgs::haptic_to_physics::fault::RATE_LIMITED != 0) as usize;
        above += (norm(m) > peak) as usize;
        let c_unscaled = c.map(|v| v / scale);
        se_coupling += norm(sub(c_unscaled, m)).powi(2);
        se_limiter += norm(sub(r, c)).powi(2);
        se_scaling += ((scale - 1.0) * norm(c_unscaled)).powi(2);
        if !clamped && !sat {
            rm_u += r.iter().zip(&m).map(|(a, b)| a * b).sum::<f64>();
            mm_u += m.iter().map(|v| v * v).sum::<f64>();
        }
    }
    if matched == 0 {
        return Err(input_err(
            path,
            format!(
                "none of the {} device ticks names a recorded physics step \
                 (frame_sequence_used / frame_instance_used): cannot pair rendered and model force",
                ticks.len()
            ),
        ));
    }
    let n = all.n;
    if n == 0 {
        return Err(input_err(
            path,
            "no device tick rendered a frame with tissue contact: no rendering gap to measure",
        ));
    }
    let nf = n as f64;
    let overall = all.summary("all".into());
    let by_region: Vec<RenderGroup> = (0..4)
        .filter(|&c| regions[c].n > 0)
        .map(|c| {
            let name = region_of(c as u32)
                .map(|r| r.name())
                .unwrap_or(msgs::protocol::UNLABELLED);
            regions[c].summary(name.into())
        })
        .collect();

    // lag of |rendered| behind |model| (steps at their own stamps, ticks at theirs)
    let mut steps: Vec<(f64, f64)> = rec
        .steps
        .iter()
        .map(|s| (secs(s.header.stamp.to_nanos()), norm(v3(&s.contact_force))))
        .collect();
    steps.sort_by(|a, b| a.0.total_cmp(&b.0));
    // strictly increasing times for interpolation (equal stamps keep the first)
    steps.dedup_by(|cur, prev| cur.0 <= prev.0);
    let mut tk: Vec<(f64, f64)> = series.iter().map(|s| (s.0, s.3)).collect();
    tk.dedup_by(|cur, prev| cur.0 <= prev.0);
    let (ts, ms): (Vec<f64>, Vec<f64>) = steps.into_iter().unzip();
    let (tt, rs): (Vec<f64>, Vec<f64>) = tk.into_iter().unzip();
    let xc = lag_by_xcorr(&ts, &ms, &tt, &rs, 0.25, 1e-3);
    // a lag is only meaningful when the shapes agree (heavy clamping flattens the rendered
    // force); same threshold as the per-trial lags
    let lag = xc.filter(|(_, c)| *c > 0.5);

    let coupling = (se_coupling / nf).sqrt();
    let limiter = (se_limiter / nf).sqrt();
    let scaling = (se_scaling / nf).sqrt();
    let mean_m = sum_m / nf;
    let lag_s = lag.map(|l| l.0);
    // the lag's share: how much the model force changes over the lag at the contact ticks
    let lag_part = match lag_s {
        Some(l) if ts.len() >= 2 => {
            let se: f64 = contact_times
                .iter()
                .map(|&t| (interp(&ts, &ms, t) - interp(&ts, &ms, t - l)).powi(2))
                .sum();
            (se / nf).sqrt()
        }
        _ => 0.0,
    };
    let parts = [
        ("saturation", limiter),
        ("coupling", coupling),
        ("scaling", scaling),
        ("lag", lag_part),
    ];
    let (dom, dom_v) = parts
        .iter()
        .copied()
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap();
    // below 5% of the contact force (or 10 mN) the device renders the model faithfully
    let dominant = if overall.rmse_n < (0.05 * mean_m).max(0.01) || dom_v <= 0.0 {
        "none"
    } else {
        dom
    };
    let sat_frac = overall.saturated_fraction;
    let summary = format!(
        "over {n} contact ticks the device rendered {:.3} N on average against the model's {:.3} N \
         (RMS difference {:.3} N, gain {:.3}); {:.1}% of ticks at the {:.2} N peak, {:.1}% at the \
         continuous limit; RMS parts: coupling {:.3} N, limits {:.3} N, scaling {:.3} N, lag {} \
         ({:.3} N); dominant: {dominant}",
        sum_r / nf,
        mean_m,
        overall.rmse_n,
        overall.force_scale_fit,
        100.0 * sat_frac,
        peak,
        100.0 * cont as f64 / nf,
        coupling,
        limiter,
        scaling,
        lag_s
            .map(|l| format!("{:.1} ms", 1e3 * l))
            .unwrap_or_else(|| "n/a".into()),
        lag_part,
    );
    // at most ~1500 points for the plot
    let step = series.len().div_ceil(1500).max(1);
    let mut rs_out = RenderSeries::default();
    for s in series.iter().step_by(step) {
        rs_out.t.push(s.0);
        rs_out.model.push(s.1);
        rs_out.commanded.push(s.2);
        rs_out.rendered.push(s.3);
    }
    Ok(RenderingGap {
        session: path.display().to_string(),
        limits: RenderLimits {
            peak_force_n: peak,
            continuous_force_n: d.continuous_force_n,
            force_scale: scale,
            source: rec.device_source.clone(),
        },
        ticks: matched,
        unmatched_ticks: unmatched,
        contact_ticks: n,
        mean_model_force_n: mean_m,
        mean_rendered_force_n: sum_r / nf,
        rmse_n: overall.rmse_n,
        mean_error_n: overall.mean_error_n,
        force_scale_fit: overall.force_scale_fit,
        force_scale_fit_unclamped: (mm_u > 0.0).then(|| rm_u / mm_u),
        coupling_rmse_n: coupling,
        limiter_rmse_n: limiter,
        scaling_rmse_n: scaling,
        lag_rmse_n: lag_part,
        lag_s,
        lag_correlation: xc.map(|l| l.1),
        mean_frame_age_s: age / nf,
        saturated_peak_fraction: sat_frac,
        clamped_fraction: overall.clamped_fraction,
        continuous_limited_fraction: cont as f64 / nf,
        rate_limited_fraction: rate as f64 / nf,
        model_above_peak_fraction: above as f64 / nf,
        by_region,
        dominant: dominant.into(),
        summary,
        series: rs_out,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step(seq: u64, t: f64, fz: f64, device_seq: u64) -> ContactStep {
        let mut s = ContactStep {
            instance_id: 1,
            sequence: seq,
            sim_time: t,
            device_sequence_used: device_seq,
            ..Default::default()
        };
        s.contact_force.z = fz;
        // Touching (session-metrics' definition) when the tissue pushes back along +z.
        if fz > 0.0 {
            s.contact_count = 1;
            s.touching = true;
            s.contact_normal.z = 1.0;
        }
        s.probe_pose.orientation.w = 1.0;
        s.probe_pose.position.z = -fz * 1e-4;
        s
    }

    fn recording(steps: Vec<ContactStep>, ticks: Vec<DeviceTick>) -> SessionRecording {
        SessionRecording {
            path: "s.mcap".into(),
            scene: SceneConfig::default(),
            device: DeviceConfig::default(),
            device_source: "defaults".into(),
            launch: None,
            steps,
            ticks,
        }
    }

    /// Probing p (1-based) of a protocol run twice: press from step 10 to 30 of 40.
    fn protocol(probings: &[(u32, u32)]) -> SessionRecording {
        let (mut steps, mut ticks) = (Vec::new(), Vec::new());
        for (j, &(probing, region)) in probings.iter().enumerate() {
            for k in 0..40u64 {
                let seq = j as u64 * 40 + k + 1;
                let fz = if (10..30).contains(&k) { 1.0 } else { 0.0 };
                steps.push(step(seq, seq as f64 * 0.01, fz, seq));
                ticks.push(DeviceTick {
                    sequence: seq,
                    probing_index: probing,
                    region,
                    phase: 2,
                    ..Default::default()
                });
            }
        }
        recording(steps, ticks)
    }

    #[test]
    fn repeated_protocols_give_unique_trial_names() {
        let rec = protocol(&[(1, 1), (2, 2), (1, 1), (2, 2), (1, 1)]);
        let exp = experiment_from_session(&rec).unwrap();
        let names: Vec<&str> = exp.trials.iter().map(|t| t.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "probing_001_posterior",
                "probing_002_mid",
                "probing_001_posterior_2",
                "probing_002_mid_2",
                "probing_001_posterior_3"
            ]
        );
        assert!(exp.trials.iter().all(|t| t.t.len() == 40));
    }

    #[test]
    fn without_annotations_contact_runs_are_padded_and_merged() {
        // two presses 0.1 s apart (one probing that lifted briefly) and one 2 s later
        let mut steps = Vec::new();
        for k in 0..500u64 {
            let t = k as f64 * 0.01;
            let fz =
                if (100..150).contains(&k) || (160..200).contains(&k) || (400..450).contains(&k) {
                    1.0
                } else {
                    0.0
                };
            steps.push(step(k + 1, t, fz, 0));
        }
        let exp = experiment_from_session(&recording(steps, vec![])).unwrap();
        assert_eq!(exp.trials.len(), 2);
        let span = |i: usize| (exp.trials[i].t[0], *exp.trials[i].t.last().unwrap());
        let (a0, a1) = span(0);
        let (b0, b1) = span(1);
        // 0.5 s before the first contact, 0.5 s after the last; split midway between runs
        assert!(
            (a0 - 0.5).abs() < 1e-9 && (a1 - 2.49).abs() < 1e-9,
            "{a0} {a1}"
        );
        assert!(
            (b0 - 3.5).abs() < 1e-9 && (b1 - 4.99).abs() < 1e-9,
            "{b0} {b1}"
        );
        assert!(exp.trials.iter().all(|t| t.region.is_none()));
    }

    #[test]
    fn rendering_gap_needs_ticks_that_name_recorded_steps() {
        let rec = protocol(&[(1, 1)]);
        // ticks exist but render no recorded frame
        let e = rendering_gap(&rec).unwrap_err().to_string();
        assert!(
            e.contains("s.mcap") && e.contains("frame_sequence_used"),
            "{e}"
        );
    }
}
