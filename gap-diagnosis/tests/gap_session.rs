//! Session recordings as gap-diagnosis input: a session is simulated with the real physics
//! (`physics_node::sim::Simulation`, probe driven along the study protocol at six sites),
//! written with the recorder's `SessionWriter` together with 1 kHz device ticks from a
//! renderer with known scale, saturation and frame delay, read back, turned into an
//! experiment, diagnosed, and its rendering gap measured against what was written.

// The recordings crate's test helpers (synthetic ticks and steps, the recorder process).
#[path = "../../recordings/tests/common/mod.rs"]
mod common;

use common::*;
use gap_diagnosis::{self as gap, session, Effect, Region};
use launch_config::{RecordingConfig, SceneConfig};
use msgs::haptic_to_physics::{fault, DeviceState};
use msgs::Pose;
use physics_node::sim::Simulation;
use recordings::{SessionInfo, SessionWriter};
use std::path::{Path, PathBuf};

const DT: f64 = 0.01;
/// Press depth of each probing, m.
const DEPTH: f64 = 0.5e-3;
const TICKS_PER_STEP: u64 = 10;
const T0_NS: u64 = 1_700_000_000_000_000_000;

/// How the synthetic device renders.
#[derive(Clone, Copy)]
struct Render {
    /// Protocol annotations (probing index, region, phase) on the ticks.
    annotate: bool,
    /// Write device ticks at all.
    ticks: bool,
    force_scale: f64,
    /// The device's peak force as a fraction of the scaled model peak of the session: the
    /// synthetic renderer saturates on the top of every press whatever the scene's stiffness
    /// (a fixed 30 N stopped saturating when the hook began to press tip first).
    peak_fraction: f64,
    /// Ticks render the frame this many physics steps old.
    delay_steps: usize,
}

/// One written physics step.
struct Step {
    t: f64,
    force: [f64; 3],
    pose: Pose,
    contact: bool,
    probing: u32,
    region: u32,
}

/// One written device tick.
struct Tick {
    model: Option<[f64; 3]>,
    model_contact: bool,
    rendered: [f64; 3],
}

struct Written {
    file: PathBuf,
    steps: Vec<Step>,
    ticks: Vec<Tick>,
    probings: usize,
    /// The device's peak force written to the launch file, N.
    peak: f64,
}

fn norm(a: [f64; 3]) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}

fn pose_at(p: [f64; 3]) -> Pose {
    Pose {
        position: p,
        orientation: [0.0, 0.0, 0.0, 1.0],
    }
}

/// Simulates two probings per region and writes the session.
fn write_session(dir: &Path, render: Render) -> Written {
    let scene = SceneConfig {
        dt: DT,
        ..SceneConfig::default()
    };
    let data = gap::data_dir();
    let mut sim = Simulation::new(&scene, &data).expect("default scene builds");
    sim.set_instance_id(7);
    let sites: Vec<_> = (1..=3u32)
        .flat_map(|r| {
            sim.probing_sites()
                .iter()
                .filter(move |s| s.region == r)
                .take(2)
                .cloned()
                .collect::<Vec<_>>()
        })
        .collect();
    assert_eq!(sites.len(), 6, "two probing sites per region");
    // (pose, probing index, region, phase) per physics step: 20 mm above each site, the
    // study protocol (approach, press 2 mm, hold, release), back up 20 mm
    let mut plan: Vec<(Pose, u32, u32, u32)> = Vec::new();
    for (j, s) in sites.iter().enumerate() {
        let n = [s.normal.x, s.normal.y, s.normal.z];
        // the probe pose is the tip sphere's centre: touching at the site is one tip radius
        // above it
        let r = scene.probe.tip_radius;
        let p = [
            s.point.x + r * n[0],
            s.point.y + r * n[1],
            s.point.z + r * n[2],
        ];
        let high = [p[0] + 0.02 * n[0], p[1] + 0.02 * n[1], p[2] + 0.02 * n[2]];
        for _ in 0..20 {
            plan.push((pose_at(high), 0, 0, 0));
        }
        let path = gap::reality::protocol_path(p, n, DEPTH, 0.0, None, DT);
        for (k, pose) in path.poses.iter().enumerate() {
            let t = k as f64 * DT;
            let phase = match t {
                t if t < 1.0 => 1,
                t if t < 2.0 => 2,
                t if t < 3.0 => 3,
                _ => 4,
            };
            plan.push((*pose, j as u32 + 1, s.region, phase));
        }
        for _ in 0..20 {
            plan.push((pose_at(high), 0, 0, 0));
        }
    }
    // The model's peak contact force over the plan (a first pass in a fresh simulation),
    // for the device's peak.
    let model_peak = {
        let mut pre = Simulation::new(&scene, &data).expect("default scene builds");
        pre.teleport_probe(&plan[0].0);
        let mut peak: f64 = 0.0;
        for (pose, ..) in &plan {
            pre.set_probe_kinematic(pose);
            pre.step().unwrap();
            peak = peak.max(norm(pre.contact_frame().contact_force));
        }
        peak
    };
    let device_peak = render.peak_fraction * render.force_scale * model_peak;
    let launch_text = format!(
        "[device]\nforce_scale = {}\npeak_force_n = {}\n",
        render.force_scale, device_peak
    );
    let info = SessionInfo {
        session: "gap-session".into(),
        launch_path: Some("lab.toml".into()),
        launch_text,
        scene_toml: toml::to_string(&scene).unwrap(),
        source: "test".into(),
    };
    let file = dir.join("session.mcap");
    let mut w = SessionWriter::create(&file, &RecordingConfig::default(), &info).unwrap();
    let mut steps: Vec<Step> = Vec::new();
    let mut ticks = Vec::new();
    let mut frames: Vec<(u64, u64)> = Vec::new(); // (instance, sequence) per written step
    let mut tick_seq = 0u64;
    sim.teleport_probe(&plan[0].0);
    for (k, (pose, probing, region, phase)) in plan.iter().enumerate() {
        // the ticks of the interval before step k, rendering the frame `delay_steps` old
        if render.ticks {
            for j in 1..=TICKS_PER_STEP {
                tick_seq += 1;
                let mut d = boxed_zeroed::<DeviceState>();
                d.instance_id = 3;
                d.sequence = tick_seq;
                d.proxy_pose = *pose;
                d.proxy_pose.orientation = [0.0, 0.0, 0.0, 1.0];
                let used = k.checked_sub(1 + render.delay_steps);
                let mut tick = Tick {
                    model: None,
                    model_contact: false,
                    rendered: [0.0; 3],
                };
                if let Some(u) = used {
                    let f = steps[u].force;
                    let c = f.map(|v| v * render.force_scale);
                    let n = norm(c);
                    let r = if n > device_peak {
                        d.faults |= fault::FORCE_CLAMPED;
                        c.map(|v| v * device_peak / n)
                    } else {
                        c
                    };
                    d.frame_instance_used = frames[u].0;
                    d.frame_sequence_used = frames[u].1;
                    d.commanded_force = c;
                    d.rendered_force = r;
                    tick.model = Some(f);
                    tick.model_contact = steps[u].contact;
                    tick.rendered = r;
                }
                if render.annotate {
                    d.probing_index = *probing;
                    d.region = *region;
                    d.phase = *phase;
                }
                let log = T0_NS + (k as u64 * TICKS_PER_STEP + j) * 1_000_000;
                w.write_device_state(&d, log).unwrap();
                ticks.push(tick);
            }
        }
        sim.set_device_sequence(tick_seq);
        sim.set_probe_kinematic(pose);
        sim.step().unwrap();
        let frame = sim.contact_frame();
        let log = T0_NS + (k as u64 + 1) * TICKS_PER_STEP * 1_000_000;
        w.write_contact_frame(frame, log).unwrap();
        frames.push((frame.instance_id, frame.sequence));
        let f = frame.contact_force;
        steps.push(Step {
            t: frame.sim_time_s,
            force: f,
            pose: frame.probe_pose,
            contact: norm(f) > 1e-3,
            probing: *probing,
            region: *region,
        });
    }
    w.finish(Default::default()).unwrap();
    Written {
        file,
        steps,
        ticks,
        probings: sites.len(),
        peak: device_peak,
    }
}

const RENDER: Render = Render {
    annotate: true,
    ticks: true,
    force_scale: 0.8,
    peak_fraction: 0.9,
    delay_steps: 2,
};

#[test]
fn session_probings_become_trials_with_the_recorded_force_and_pose() {
    let dir = test_dir("gap-session-trials");
    let w = write_session(&dir, RENDER);
    let peak = w.steps.iter().map(|s| norm(s.force)).fold(0.0, f64::max);
    eprintln!(
        "peak contact force {peak:.3} N over {} steps",
        w.steps.len()
    );
    assert!(peak > 0.1, "the protocol presses the tissue ({peak} N)");

    let rec = session::read_session(&w.file).unwrap();
    assert_eq!(rec.steps.len(), w.steps.len());
    assert_eq!(rec.device.peak_force_n, w.peak, "limits from launch.toml");
    let exp = session::experiment_from_session(&rec).unwrap();
    assert_eq!(exp.trials.len(), w.probings);
    let regions: Vec<Option<Region>> = exp.trials.iter().map(|t| t.region).collect();
    use Region::*;
    assert_eq!(
        regions,
        [Posterior, Posterior, Mid, Mid, Anterior, Anterior].map(Some)
    );
    for (i, trial) in exp.trials.iter().enumerate() {
        let written: Vec<&Step> = w
            .steps
            .iter()
            .filter(|s| s.probing == i as u32 + 1)
            .collect();
        assert_eq!(trial.t.len(), written.len(), "{}", trial.name);
        assert_eq!(written[0].region, trial.region.unwrap().code());
        for (k, s) in written.iter().enumerate() {
            // bit-exact: the lossless channel carries float64
            assert_eq!(trial.t[k].to_bits(), s.t.to_bits());
            assert_eq!(trial.force[k], s.force, "{} sample {k}", trial.name);
            assert_eq!(trial.pose[k].position, s.pose.position);
        }
    }
    assert_eq!(exp.spec.specimen.mesh, SceneConfig::default().meniscus.mesh);

    // without annotations, trials are split on contact onset/offset: same six probings,
    // each covering its contact run
    let dir2 = test_dir("gap-session-contact-split");
    let w2 = write_session(
        &dir2,
        Render {
            annotate: false,
            ..RENDER
        },
    );
    let exp2 = session::experiment_from_session(&session::read_session(&w2.file).unwrap()).unwrap();
    assert_eq!(exp2.trials.len(), w2.probings);
    for (i, trial) in exp2.trials.iter().enumerate() {
        assert_eq!(trial.region, None);
        let contact_t: Vec<f64> = w2
            .steps
            .iter()
            .filter(|s| s.probing == i as u32 + 1 && s.contact)
            .map(|s| s.t)
            .collect();
        assert!(
            trial.t[0] < contact_t[0] && trial.t.last() > contact_t.last(),
            "{} covers its contact run with approach and release",
            trial.name
        );
    }
}

#[test]
fn rendering_gap_measures_scale_saturation_and_lag() {
    let dir = test_dir("gap-session-rendering");
    let w = write_session(&dir, RENDER);
    let rec = session::read_session(&w.file).unwrap();
    let g = session::rendering_gap(&rec).unwrap();
    eprintln!("{}", g.summary);
    let contact: Vec<&Tick> = w
        .ticks
        .iter()
        .filter(|t| t.model.is_some() && (t.model_contact || norm(t.rendered) > 1e-3))
        .collect();
    assert_eq!(
        g.ticks,
        w.ticks.iter().filter(|t| t.model.is_some()).count()
    );
    assert_eq!(g.unmatched_ticks, w.ticks.len() - g.ticks);
    assert_eq!(g.contact_ticks, contact.len());
    let saturated = contact
        .iter()
        .filter(|t| norm(t.model.unwrap()) * RENDER.force_scale >= w.peak * (1.0 - 1e-3))
        .count();
    assert!(
        saturated > 0 && saturated < contact.len() / 2,
        "the test renderer saturates at the peaks ({saturated} of {})",
        contact.len()
    );
    let frac = saturated as f64 / contact.len() as f64;
    assert!(
        (g.saturated_peak_fraction - frac).abs() < 1e-12,
        "{} vs {frac}",
        g.saturated_peak_fraction
    );
    let rmse = (contact
        .iter()
        .map(|t| {
            let m = t.model.unwrap();
            let r = t.rendered;
            (0..3).map(|k| (r[k] - m[k]).powi(2)).sum::<f64>()
        })
        .sum::<f64>()
        / contact.len() as f64)
        .sqrt();
    assert!((g.rmse_n - rmse).abs() < 1e-9, "{} vs {rmse}", g.rmse_n);
    // below the peak the device is the model times the scale; saturation pulls the overall
    // gain lower
    let k = g.force_scale_fit_unclamped.unwrap();
    assert!((k - RENDER.force_scale).abs() < 1e-9, "{k}");
    assert!(g.force_scale_fit < RENDER.force_scale - 0.01);
    assert!(g.mean_error_n < 0.0);
    assert!(
        g.coupling_rmse_n < 1e-9,
        "commanded/scale is the model force"
    );
    // rendered force stamps trail the frame they render by 2-3 steps (20-30 ms)
    let lag = g.lag_s.unwrap();
    assert!((0.015..0.035).contains(&lag), "lag {lag}");
    assert_eq!(g.by_region.len(), 3);
    assert_eq!(
        g.by_region.iter().map(|r| r.ticks).sum::<usize>(),
        contact.len()
    );
    assert!(
        ["saturation", "scaling"].contains(&g.dominant.as_str()),
        "{}",
        g.dominant
    );
}

#[test]
fn session_diagnosis_reports_the_rendering_gap_in_json_and_html() {
    let dir = test_dir("gap-session-diagnose");
    let w = write_session(&dir, RENDER);
    let opts = gap::Options {
        effects: vec![Effect::Modulus],
        pairs: false,
        ..Default::default()
    };
    // a folder holding one recording is accepted like the file itself
    let report = gap::diagnose_dir(&dir, &opts).unwrap();
    assert_eq!(report.trials, w.probings);
    assert_eq!(report.input, w.file.display().to_string());
    // the measurement is this physics model's own force: the replay reproduces it
    let base = report.heldout.baseline_rmse;
    let peak = w.steps.iter().map(|s| norm(s.force)).fold(0.0, f64::max);
    eprintln!(
        "baseline RMSE {base:.4} N (peak {peak:.3} N), verdict {}",
        report.verdict.effect
    );
    assert!(base < 0.1 * peak, "baseline {base} vs peak {peak}");
    let g = report.rendering_gap.as_ref().expect("rendering gap");
    assert!(g.saturated_peak_fraction > 0.0);

    let out = dir.join("report");
    gap::write_report(&report, &out).unwrap();
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let rg = &json["rendering_gap"];
    assert_eq!(rg["contact_ticks"].as_u64(), Some(g.contact_ticks as u64));
    assert!(rg["force_scale_fit"].as_f64().is_some());
    assert_eq!(rg["limits"]["peak_force_n"].as_f64(), Some(w.peak));
    for field in [
        "verdict",
        "heldout",
        "localisation",
        "ranking",
        "trial_reports",
    ] {
        assert!(json.get(field).is_some(), "{field} kept");
    }
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.contains("Rendering gap") && html.contains("rendered |f|"));

    // an experiment folder's report has no rendering gap until a session is attached
    let mut plain = report.clone();
    plain.rendering_gap = None;
    let s = serde_json::to_string(&plain).unwrap();
    assert!(!s.contains("rendering_gap"));
    gap::attach_session(&mut plain, &w.file).unwrap();
    assert_eq!(plain.rendering_gap.unwrap().contact_ticks, g.contact_ticks);
}

#[test]
fn recordings_without_the_needed_channels_get_clear_errors() {
    let dir = test_dir("gap-session-bad");
    // physics steps but no device ticks: trials split on contact, no rendering gap; asking
    // for the rendering gap names the missing topic
    let w = write_session(
        &dir,
        Render {
            ticks: false,
            ..RENDER
        },
    );
    let rec = session::read_session(&w.file).unwrap();
    assert!(rec.ticks.is_empty());
    assert_eq!(
        session::experiment_from_session(&rec).unwrap().trials.len(),
        w.probings
    );
    let e = session::rendering_gap(&rec).unwrap_err().to_string();
    assert!(
        e.contains("session.mcap") && e.contains("/arthrosim/recording/device_tick"),
        "{e}"
    );

    // device ticks only: no physics steps
    let only_ticks = dir.join("ticks_only.mcap");
    let info = SessionInfo {
        scene_toml: toml::to_string(&SceneConfig::default()).unwrap(),
        ..Default::default()
    };
    let mut wr = SessionWriter::create(&only_ticks, &RecordingConfig::default(), &info).unwrap();
    for seq in 1..=50 {
        let mut d = boxed_zeroed::<DeviceState>();
        fill_device(&mut d, seq, 1);
        wr.write_device_state(&d, T0_NS + seq * 1_000_000).unwrap();
    }
    wr.finish(Default::default()).unwrap();
    let e = gap::diagnose_dir(&only_ticks, &gap::Options::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("ticks_only.mcap") && e.contains("/arthrosim/recording/contact_step"),
        "{e}"
    );

    // physics steps that never touch the tissue
    let no_contact = dir.join("no_contact.mcap");
    let mut wr = SessionWriter::create(&no_contact, &RecordingConfig::default(), &info).unwrap();
    for seq in 1..=50u64 {
        let mut f = boxed_zeroed::<msgs::physics_to_haptic::ContactFrame>();
        f.instance_id = 1;
        f.sequence = seq;
        f.sim_time_s = seq as f64 * DT;
        f.probe_pose.orientation = [0.0, 0.0, 0.0, 1.0];
        wr.write_contact_frame(&f, T0_NS + seq * 10_000_000)
            .unwrap();
    }
    wr.finish(Default::default()).unwrap();
    let e = session::experiment_from_session(&session::read_session(&no_contact).unwrap())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("no_contact.mcap") && e.contains("no probing with tissue contact"),
        "{e}"
    );

    // not an MCAP at all, though named like one
    let fake = dir.join("fake.mcap");
    std::fs::write(&fake, "t_s,fx_N\n").unwrap();
    let e = gap::diagnose_dir(&fake, &gap::Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("fake.mcap") && e.contains("not an MCAP"), "{e}");

    // a folder with two recordings and no experiment.toml: which one is ambiguous
    let two = dir.join("two");
    std::fs::create_dir_all(&two).unwrap();
    std::fs::copy(&w.file, two.join("a.mcap")).unwrap();
    std::fs::copy(&w.file, two.join("b.mcap")).unwrap();
    let e = gap::diagnose_dir(&two, &gap::Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("a.mcap, b.mcap"), "{e}");

    // a missing path is not taken for a recording
    assert!(session::session_file(&dir.join("missing.mcap"))
        .unwrap()
        .is_none());
}
