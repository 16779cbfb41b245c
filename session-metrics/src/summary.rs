//! The end-of-session summary in the study's terms, as a pure function over the samples the
//! launcher collected ([`SessionRecord`] → [`SessionSummary`]).
//!
//! Conventions (documented in the summary itself):
//! - Contact force `f`: the physics node's eq. (1) force on the probe, Hᵀλ/dt, world frame.
//! - Contact normal `n`: the outward tissue normal (rows 3k of H), weighted by each
//!   contact's normal impulse when several contacts are active.
//! - **Normal force** `F_n = −f·n`: the force the probe presses into the tissue along the
//!   outward normal, negative in compression, the sign the study reports (−4.0 N measured,
//!   −4.16 N simulated). Its mean is taken over the physics steps in contact: at least one
//!   constraint carries a normal impulse (λn > 0). Constraints inside the alarm distance that
//!   carry nothing (the probe near, not touching) do not count.
//! - **Probe displacement** of a probing: `(x₀ − x)·n₀`, how far the probe has moved into the
//!   tissue along the normal `n₀` of the probing's first touching step, from its position `x₀`
//!   then; the maximum over the probing's contact steps.
//! - Regions and probings come from the haptic node's `DeviceState.region` /
//!   `probing_index` annotations (the emulated or replayed protocol) of the device tick each
//!   physics step used ([`crate::matching`]). Without a probing index, each contact episode
//!   counts as one probing.

use crate::contact::{dot, ContactSample};
use crate::matching::Annotations;
use msgs::physics_to_haptic::ContactFrame;
use msgs::protocol::{Region, UNLABELLED};
use serde::Serialize;
use std::fmt;

/// Everything a session summary is computed from: collected live by the launcher, or read
/// back from a recording.
#[derive(Debug, Clone, Default)]
pub struct SessionRecord {
    /// Every physics step seen, in arrival order.
    pub contacts: Vec<ContactSample>,
    /// The device stream's protocol annotations by tick sequence.
    pub annotations: Annotations,
    /// Device states seen and the span of their timestamps (per haptic instance summed).
    pub device_ticks: u64,
    pub device_span_ns: u64,
    /// Newest rate the haptic node reported about itself (HapticStats.tick_hz).
    pub haptic_reported_hz: Option<f64>,
    device_instance: u64,
    device_first_ns: u64,
    device_last_ns: u64,
}

impl SessionRecord {
    pub fn push_contact(&mut self, frame: &ContactFrame) {
        self.contacts.push(ContactSample::from_frame(frame));
    }

    /// Counts one device state and keeps its protocol annotation.
    pub fn push_device(
        &mut self,
        instance_id: u64,
        sequence: u64,
        publish_ns: u64,
        region: u32,
        probing_index: u32,
        phase: u32,
    ) {
        if instance_id != self.device_instance || self.device_ticks == 0 {
            self.device_span_ns += self.device_last_ns.saturating_sub(self.device_first_ns);
            self.device_instance = instance_id;
            self.device_first_ns = publish_ns;
        }
        self.device_last_ns = publish_ns;
        self.device_ticks += 1;
        self.annotations
            .push(sequence, region, probing_index, phase);
    }

    /// Device-time span including the current haptic instance.
    fn total_device_span_ns(&self) -> u64 {
        self.device_span_ns + self.device_last_ns.saturating_sub(self.device_first_ns)
    }
}

/// Per-region results in the study's terms.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct RegionSummary {
    pub region: String,
    /// Physics steps with at least one contact.
    pub contact_steps: u64,
    /// Simulated time in contact, s.
    pub contact_time_s: f64,
    /// Probings with contact.
    pub probings: u32,
    /// Mean normal force during contact, N (negative = compression, the study's sign).
    pub mean_normal_force_n: Option<f64>,
    /// Most compressive normal force, N.
    pub peak_normal_force_n: Option<f64>,
    /// Mean magnitude of the contact force during contact, N.
    pub mean_force_magnitude_n: Option<f64>,
    /// Largest probe displacement along the first touching step's normal over the probings, m.
    pub max_probe_displacement_m: Option<f64>,
    /// Mean over probings of each probing's largest displacement, m.
    pub mean_probe_displacement_m: Option<f64>,
}

/// How the session rendered the tissue force (from the launch file's `[device]`: see
/// `launch_config::device::Rendering`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct RenderingSummary {
    pub force_scale: f64,
    /// The scale was chosen automatically from the tissue reference and the device limits.
    pub automatic: bool,
    /// Virtual coupling in series with the contact compliance, tissue side, N/m.
    pub coupling_stiffness_n_per_m: f64,
    /// Largest felt stiffness, N/m (= force_scale × coupling).
    pub felt_stiffness_limit_n_per_m: f64,
}

/// The end-of-session summary.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct SessionSummary {
    /// posterior, mid, anterior (always present), then `unlabelled` when contacts had no
    /// region annotation.
    pub regions: Vec<RegionSummary>,
    pub physics_steps: u64,
    /// Physics steps per wall-clock second.
    pub physics_hz: Option<f64>,
    /// Simulated seconds per wall-clock second.
    pub physics_realtime_factor: Option<f64>,
    /// Mean wall time of a physics step, ms.
    pub physics_step_ms_mean: Option<f64>,
    pub physics_instances: u32,
    /// Physics steps that failed a fault check (flagged, rolled back, not rendered).
    pub physics_faults: u64,
    /// What tripped, over the session (names of the `physics_fault` bits seen).
    pub physics_fault_kinds: Vec<&'static str>,
    pub haptic_ticks: u64,
    /// Device states per wall-clock second as received by the launcher.
    pub haptic_hz: Option<f64>,
    /// The haptic node's own newest rate estimate.
    pub haptic_reported_hz: Option<f64>,
    /// How the tissue force was rendered: force scale and virtual coupling (None: no
    /// haptic node in the session).
    pub rendering: Option<RenderingSummary>,
    pub conventions: &'static str,
}

/// One sentence per convention, stored with every summary.
pub const CONVENTIONS: &str =
    "normal force F_n = -f.n with f the eq. (1) contact force on the probe \
(world frame) and n the outward tissue normal: negative in compression, as the study reports \
(-4.0 N measured, -4.16 N simulated); mean over physics steps in contact (some normal impulse \
> 0; constraints inside the alarm distance that carry nothing do not count). Probe \
displacement: (x0 - x).n0 from the probe position x0 and normal n0 at the probing's first \
touching step, maximum over the probing. Regions/probings from DeviceState annotations.";

impl SessionSummary {
    /// The region's entry by name.
    pub fn region(&self, name: &str) -> Option<&RegionSummary> {
        self.regions.iter().find(|r| r.region == name)
    }

    /// Regions among posterior/mid/anterior with at least one contact step.
    pub fn regions_with_contact(&self) -> Vec<&str> {
        self.regions
            .iter()
            .filter(|r| r.region != UNLABELLED && r.contact_steps > 0)
            .map(|r| r.region.as_str())
            .collect()
    }
}

#[derive(Default)]
struct RegionAccumulator {
    contact_steps: u64,
    contact_time_s: f64,
    normal_sum: f64,
    normal_min: Option<f64>,
    magnitude_sum: f64,
    /// Per probing: largest displacement.
    probing_max: Vec<f64>,
}

/// The open probing: (region, probing index or episode marker, first-touch probe position x0,
/// its contact normal n0, the probing's slot in the region's list).
type OpenProbing = (u32, u32, [f64; 3], [f64; 3], usize);

/// Aggregates a session's samples into the study's summary. Pure: same record, same summary.
pub fn summarize(record: &SessionRecord) -> SessionSummary {
    let mut regions: [RegionAccumulator; 4] = Default::default();

    // Walk contacts in time order; each takes the annotation of the device tick it used.
    let mut order: Vec<usize> = (0..record.contacts.len()).collect();
    order.sort_by_key(|&i| record.contacts[i].publish_ns);
    let mut open: Option<OpenProbing> = None;
    let mut previous_in_contact = false;

    for &i in &order {
        let s = &record.contacts[i];
        let current = record
            .annotations
            .of_step(s.device_sequence_used)
            .unwrap_or_default();
        let region = Region::from_code(current.region).map_or(0, Region::code);
        if !s.in_contact() {
            previous_in_contact = false;
            if current.probing_index == 0 {
                open = None; // an episode ends with the contact
            }
            continue;
        }
        let acc = &mut regions[region as usize];
        let f_n = s.normal_force();
        acc.contact_steps += 1;
        acc.contact_time_s += if s.dt_s.is_finite() { s.dt_s } else { 0.0 };
        acc.normal_sum += f_n;
        acc.normal_min = Some(acc.normal_min.map_or(f_n, |m: f64| m.min(f_n)));
        acc.magnitude_sum += dot(s.contact_force, s.contact_force).sqrt();

        let same_probing = match open {
            Some((r, p, ..)) => {
                r == region
                    && if current.probing_index == 0 {
                        p == 0 && previous_in_contact
                    } else {
                        p == current.probing_index
                    }
            }
            None => false,
        };
        if !same_probing {
            acc.probing_max.push(0.0);
            open = Some((
                region,
                current.probing_index,
                s.probe_position,
                s.normal,
                acc.probing_max.len() - 1,
            ));
        }
        if let Some((_, _, x0, n0, slot)) = open {
            let d = dot(
                [
                    x0[0] - s.probe_position[0],
                    x0[1] - s.probe_position[1],
                    x0[2] - s.probe_position[2],
                ],
                n0,
            );
            let m = &mut acc.probing_max[slot];
            if d > *m {
                *m = d;
            }
        }
        previous_in_contact = true;
    }

    let mut out = Vec::new();
    for (code, acc) in regions.iter().enumerate() {
        if code == 0 && acc.contact_steps == 0 {
            continue;
        }
        let steps = acc.contact_steps as f64;
        let probings = acc.probing_max.len();
        let mut r = RegionSummary {
            region: Region::name_of_code(code as u32).to_string(),
            contact_steps: acc.contact_steps,
            contact_time_s: acc.contact_time_s,
            probings: probings as u32,
            ..Default::default()
        };
        if acc.contact_steps > 0 {
            r.mean_normal_force_n = Some(acc.normal_sum / steps);
            r.peak_normal_force_n = acc.normal_min;
            r.mean_force_magnitude_n = Some(acc.magnitude_sum / steps);
            r.max_probe_displacement_m = acc.probing_max.iter().copied().reduce(f64::max);
            r.mean_probe_displacement_m =
                Some(acc.probing_max.iter().sum::<f64>() / probings as f64);
        }
        out.push(r);
    }
    // Study order: posterior, mid, anterior, then unlabelled.
    out.sort_by_key(|r| Region::parse(&r.region).map_or(9, Region::code));

    // Rates per physics instance (a restart starts a new one), summed.
    let mut instances: Vec<(u64, u64, u64, f64, f64, u64)> = Vec::new(); // id, first, last, t0, t1, n
    let mut step_ns_sum = 0u128;
    for s in &record.contacts {
        step_ns_sum += s.step_duration_ns as u128;
        match instances.iter_mut().find(|e| e.0 == s.instance_id) {
            Some(e) => {
                e.1 = e.1.min(s.publish_ns);
                e.2 = e.2.max(s.publish_ns);
                e.3 = e.3.min(s.sim_time_s);
                e.4 = e.4.max(s.sim_time_s);
                e.5 += 1;
            }
            None => instances.push((
                s.instance_id,
                s.publish_ns,
                s.publish_ns,
                s.sim_time_s,
                s.sim_time_s,
                1,
            )),
        }
    }
    let wall_ns: u64 = instances.iter().map(|e| e.2 - e.1).sum();
    let intervals: u64 = instances.iter().map(|e| e.5 - 1).sum();
    let sim_s: f64 = instances.iter().map(|e| e.4 - e.3).sum();
    let physics_steps = record.contacts.len() as u64;
    let device_span = record.total_device_span_ns();
    let physics_faults = record
        .contacts
        .iter()
        .filter(|s| s.physics_faults != 0)
        .count() as u64;
    let fault_bits = record
        .contacts
        .iter()
        .fold(0u32, |acc, s| acc | s.physics_faults);

    SessionSummary {
        regions: out,
        physics_steps,
        physics_hz: (wall_ns > 0).then(|| intervals as f64 / (wall_ns as f64 * 1e-9)),
        physics_realtime_factor: (wall_ns > 0).then(|| sim_s / (wall_ns as f64 * 1e-9)),
        physics_step_ms_mean: (physics_steps > 0)
            .then(|| step_ns_sum as f64 / physics_steps as f64 * 1e-6),
        physics_instances: instances.len() as u32,
        physics_faults,
        physics_fault_kinds: msgs::physics_to_haptic::physics_fault::names(fault_bits).collect(),
        haptic_ticks: record.device_ticks,
        haptic_hz: (device_span > 0 && record.device_ticks > 1)
            .then(|| (record.device_ticks - 1) as f64 / (device_span as f64 * 1e-9)),
        haptic_reported_hz: record.haptic_reported_hz,
        rendering: None,
        conventions: CONVENTIONS,
    }
}

fn opt(v: Option<f64>, scale: f64, decimals: usize) -> String {
    match v {
        Some(x) => format!("{:.*}", decimals, x * scale),
        None => "–".into(),
    }
}

impl fmt::Display for SessionSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{:<11} {:>8} {:>10} {:>14} {:>12} {:>16} {:>16}",
            "region",
            "probings",
            "contact s",
            "mean F_n [N]",
            "peak F_n [N]",
            "max displ. [mm]",
            "mean displ. [mm]"
        )?;
        for r in &self.regions {
            writeln!(
                f,
                "{:<11} {:>8} {:>10.2} {:>14} {:>12} {:>16} {:>16}",
                r.region,
                r.probings,
                r.contact_time_s,
                opt(r.mean_normal_force_n, 1.0, 3),
                opt(r.peak_normal_force_n, 1.0, 3),
                opt(r.max_probe_displacement_m, 1e3, 2),
                opt(r.mean_probe_displacement_m, 1e3, 2),
            )?;
        }
        writeln!(
            f,
            "physics: {} steps, {} Hz, real-time factor {}, step {} ms{}",
            self.physics_steps,
            opt(self.physics_hz, 1.0, 1),
            opt(self.physics_realtime_factor, 1.0, 2),
            opt(self.physics_step_ms_mean, 1.0, 2),
            if self.physics_instances > 1 {
                format!(" ({} instances: restarted)", self.physics_instances)
            } else {
                String::new()
            }
        )?;
        if self.physics_faults > 0 {
            writeln!(
                f,
                "physics faults: {} steps flagged and rolled back ({})",
                self.physics_faults,
                self.physics_fault_kinds.join(", ")
            )?;
        }
        writeln!(
            f,
            "haptic:  {} ticks, {} Hz received, {} Hz reported",
            self.haptic_ticks,
            opt(self.haptic_hz, 1.0, 1),
            opt(self.haptic_reported_hz, 1.0, 1)
        )?;
        if let Some(r) = &self.rendering {
            writeln!(
                f,
                "rendering: force scale {:.4}{}, virtual coupling {:.2} N/mm at the tissue, felt stiffness ≤ {:.2} N/mm",
                r.force_scale,
                if r.automatic { " (automatic)" } else { "" },
                r.coupling_stiffness_n_per_m * 1e-3,
                r.felt_stiffness_limit_n_per_m * 1e-3
            )?;
        }
        write!(
            f,
            "F_n = -f·n: negative in compression (study: -4.0 N measured, -4.16 N simulated); \
             displacement along the normal of the first touching step"
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use msgs::Topic;

    const MS: u64 = 1_000_000;

    fn sample(t_ms: u64, contact: bool, fz: f64, z: f64) -> ContactSample {
        ContactSample {
            instance_id: 7,
            sequence: t_ms,
            publish_ns: t_ms * MS,
            sim_time_s: t_ms as f64 * 1e-3,
            dt_s: 0.01,
            step_duration_ns: 2 * MS,
            contact_count: contact as u32,
            physics_faults: 0,
            // The device ticks at 1 kHz with sequence = its time in ms.
            device_sequence_used: t_ms,
            normal: if contact { [0.0, 0.0, 1.0] } else { [0.0; 3] },
            touching: contact,
            contact_force: [0.0, 0.0, fz],
            probe_position: [0.0, 0.0, z],
        }
    }

    fn region_record() -> SessionRecord {
        let mut rec = SessionRecord::default();
        // Device: region 1 probing 1 from 0 ms, region 2 probing 2 from 100 ms,
        // region 3 probing 3 from 200 ms; 1 kHz ticks.
        for t in 1..300u64 {
            let (region, probing) = (1 + (t / 100) as u32, 1 + (t / 100) as u32);
            rec.push_device(42, t, t * MS, region, probing, 2);
        }
        // Physics every 10 ms; contact in the middle of each 100 ms window, pressing down
        // (the probe moves −z into the tissue whose outward normal is +z).
        for step in 0..30u64 {
            let t = step * 10 + 5;
            let phase = t % 100;
            let contact = (20..80).contains(&phase);
            let depth = if contact {
                (phase - 20) as f64 * 1e-4
            } else {
                0.0
            };
            let force = if contact { 1.0 + (t / 100) as f64 } else { 0.0 };
            rec.contacts.push(sample(t, contact, force, 0.01 - depth));
        }
        rec
    }

    #[test]
    fn regions_get_their_own_forces_displacements_and_probings() {
        let s = summarize(&region_record());
        assert_eq!(
            s.regions_with_contact(),
            vec!["posterior", "mid", "anterior"]
        );
        for (name, force) in [("posterior", 1.0), ("mid", 2.0), ("anterior", 3.0)] {
            let r = s.region(name).unwrap();
            assert_eq!(r.probings, 1, "{name}");
            assert_eq!(r.contact_steps, 6, "{name}");
            // Tissue pushes the probe along +n: compression is negative in the study's sign.
            assert!(
                (r.mean_normal_force_n.unwrap() + force).abs() < 1e-12,
                "{name}"
            );
            // Contact steps at phases 25..75: displacement from phase 25 to 75 = 50 × 1e-4.
            assert!(
                (r.max_probe_displacement_m.unwrap() - 5e-3).abs() < 1e-12,
                "{name}"
            );
            assert!((r.contact_time_s - 0.06).abs() < 1e-12);
        }
        assert!(s.region("unlabelled").is_none());
        assert_eq!(s.physics_steps, 30);
        // 30 frames 10 ms apart: 29 intervals over 290 ms = 100 Hz.
        assert!((s.physics_hz.unwrap() - 100.0).abs() < 1e-9);
        assert!((s.haptic_hz.unwrap() - 1000.0).abs() < 1e-9);
        assert_eq!(s.haptic_ticks, 299);
        assert_eq!(s.physics_instances, 1);
    }

    #[test]
    fn unannotated_episodes_count_as_probings() {
        let mut rec = SessionRecord::default();
        let mut t = 0;
        for episode in 0..3 {
            for k in 0..5 {
                rec.contacts.push(sample(
                    t,
                    true,
                    2.0,
                    -(k as f64) * 1e-3 * (episode + 1) as f64,
                ));
                t += 10;
            }
            rec.contacts.push(sample(t, false, 0.0, 0.0));
            t += 10;
        }
        let s = summarize(&rec);
        let r = s.region("unlabelled").unwrap();
        assert_eq!(r.probings, 3);
        assert!((r.max_probe_displacement_m.unwrap() - 12e-3).abs() < 1e-12);
        assert!((r.mean_probe_displacement_m.unwrap() - 8e-3).abs() < 1e-12);
        assert_eq!(s.regions_with_contact(), Vec::<&str>::new());
        for name in ["posterior", "mid", "anterior"] {
            assert_eq!(s.region(name).unwrap().contact_steps, 0);
        }
    }

    #[test]
    fn faulty_steps_are_counted_not_summarised() {
        let mut record = region_record();
        let clean = summarize(&record);
        let mut bad = sample(10_000, true, -1e5, 0.0);
        bad.physics_faults = msgs::physics_to_haptic::physics_fault::FORCE_BOUND;
        record.contacts.push(bad);
        let s = summarize(&record);
        assert_eq!(clean.physics_faults, 0);
        assert_eq!(s.physics_faults, 1);
        assert_eq!(
            s.physics_fault_kinds,
            vec!["contact force beyond the scene bound"]
        );
        for (a, b) in clean.regions.iter().zip(&s.regions) {
            assert_eq!(a.peak_normal_force_n, b.peak_normal_force_n);
            assert_eq!(a.contact_steps, b.contact_steps);
        }
    }

    #[test]
    fn empty_session_has_no_rates_and_no_panics() {
        let s = summarize(&SessionRecord::default());
        assert_eq!(s.physics_hz, None);
        assert_eq!(s.haptic_hz, None);
        assert_eq!(s.regions.len(), 3);
        assert!(s.regions.iter().all(|r| r.mean_normal_force_n.is_none()));
        let text = s.to_string();
        assert!(text.contains("posterior") && text.contains("anterior"));
    }

    #[test]
    fn a_physics_restart_does_not_count_the_gap_as_steps() {
        let mut rec = SessionRecord::default();
        for k in 0..11u64 {
            let mut a = sample(k * 10, false, 0.0, 0.0);
            a.instance_id = 1;
            rec.contacts.push(a);
            // Second instance 10 s later, also at 100 Hz.
            let mut b = sample(10_000 + k * 10, false, 0.0, 0.0);
            b.instance_id = 2;
            rec.contacts.push(b);
        }
        let s = summarize(&rec);
        assert_eq!(s.physics_instances, 2);
        assert!((s.physics_hz.unwrap() - 100.0).abs() < 1e-9);
    }

    #[test]
    fn frame_normal_is_impulse_weighted() {
        let mut slot = Box::new(core::mem::MaybeUninit::<ContactFrame>::uninit());
        let frame = ContactFrame::zeroed_in(&mut slot);
        frame.contact_count = 2;
        frame.row_count = 6;
        frame.constraint_directions[0] = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        frame.constraint_directions[3] = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        frame.lambda[0] = 3.0;
        frame.lambda[3] = 0.0;
        frame.contact_force = [0.0, 0.0, 4.0];
        let s = ContactSample::from_frame(frame);
        assert_eq!(s.normal, [0.0, 0.0, 1.0]);
        assert_eq!(s.contact_count, 2);
        assert!(s.touching);
    }

    /// Regression: constraints inside the alarm distance with no impulse counted as contact,
    /// diluting the mean normal force and starting the displacement millimetres early.
    #[test]
    fn near_but_not_touching_is_not_contact() {
        let mut slot = Box::new(core::mem::MaybeUninit::<ContactFrame>::uninit());
        let frame = ContactFrame::zeroed_in(&mut slot);
        frame.contact_count = 1;
        frame.row_count = 3;
        frame.constraint_directions[0] = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        frame.publish_ns = 5 * MS;
        let near = ContactSample::from_frame(frame);
        assert!(!near.touching);
        assert_eq!(near.normal, [0.0, 0.0, 1.0], "viewers still get a normal");
        let mut rec = SessionRecord::default();
        rec.contacts.push(near);
        let s = summarize(&rec);
        assert!(
            s.regions.iter().all(|r| r.contact_steps == 0),
            "{:?}",
            s.regions
        );
    }
}
