//! What each subcommand does. Returns the process exit code.

use crate::cli::{
    Cli, Command, GapArgs, GapCommand, NodeCommand, ProbeCurveArgs, RealityArgs, RecordingsCommand,
    ReplayArgs, RunArgs, TrainArgs, TraineesCommand, ValidateArgs,
};
use anyhow::{bail, Context, Result};
use gap_diagnosis as gap;
use launcher::{self, EndReason, LiveMode, RunOptions};
use std::path::{Path, PathBuf};

pub fn dispatch(cli: Cli) -> Result<i32> {
    match cli.command {
        Command::Run(args) => run(args),
        Command::Validate(args) => Ok(validate(&args)),
        Command::Replay(args) => replay(args),
        Command::Recordings(cmd) => recordings(cmd),
        Command::Gap(args) => gap_command(args),
        Command::Reality(args) => reality(args),
        Command::ProbeCurve(args) => probe_curve(args),
        Command::Train(args) => train(args),
        Command::Trainees(cmd) => trainees(cmd),
        Command::Node(node) => {
            match node {
                NodeCommand::Physics(a) => physics_node::node::run_node(a),
                NodeCommand::Haptic(a) => haptic_node::run_node(a),
                NodeCommand::Bridge(a) => viz_bridge::run_node(a),
                NodeCommand::Recorder(a) => recordings::recorder::run_node(a),
                NodeCommand::Viewer(a) => viewer::run_node(a),
            }?;
            Ok(0)
        }
    }
}

/// `arthrosim validate FILE...`: every file's problems, exit 1 when any file is invalid.
fn validate(args: &ValidateArgs) -> i32 {
    let mut failed = 0;
    for file in &args.files {
        match launch_config::load(file) {
            Ok(_) => println!("{}: ok", file.display()),
            Err(e) => {
                failed += 1;
                eprintln!("{e}");
            }
        }
    }
    if failed > 0 {
        eprintln!("{failed} of {} launch file(s) invalid", args.files.len());
        1
    } else {
        0
    }
}

/// The launch file of a session (the given file, or the embedded default), its origin for
/// messages, and the session name: the flag, then the environment, then the launch file.
fn session_launch(
    file: Option<&std::path::Path>,
    session_flag: &Option<String>,
) -> Result<(launch_config::LaunchFile, String, String)> {
    let (mut launch, origin) = match file {
        Some(path) => (launch_config::load(path)?, path.display().to_string()),
        None => (
            launch_config::load_str(
                launch_config::DEFAULT_LAUNCH,
                launch_config::DEFAULT_LAUNCH_ORIGIN,
            )?,
            launch_config::DEFAULT_LAUNCH_ORIGIN.to_string(),
        ),
    };
    let session = match (session_flag, std::env::var(msgs::ipc::SESSION_ENV)) {
        (Some(s), _) => s.clone(),
        (None, Ok(s)) => s,
        (None, Err(_)) => launch.session.name.clone(),
    };
    let session = msgs::ipc::session_name(Some(&session))?;
    launch.session.name = session.clone();
    Ok((launch, origin, session))
}

/// `arthrosim run [FILE]`.
fn run(args: RunArgs) -> Result<i32> {
    let (mut launch, origin, session) = session_launch(args.file.as_deref(), &args.session)?;
    let seconds = match args.seconds {
        Some(s)
            if !(s.is_finite() && (0.0..=launch_config::validate::MAX_SESSION_S).contains(&s)) =>
        {
            bail!(
                "--seconds {s}: must be a finite number from 0 to {} (30 days; 0 runs until Ctrl-C)",
                launch_config::validate::MAX_SESSION_S
            )
        }
        Some(s) => s,
        None => launch.session.seconds,
    };
    launch.session.seconds = seconds;
    let seconds = (seconds > 0.0).then_some(seconds);
    let out_dir = args.out.clone().unwrap_or_else(launcher::default_out_dir);
    replay_from_recording(&mut launch, &out_dir)?;

    let mut opts = RunOptions::for_current_exe(launch, origin, session, out_dir, seconds)?;
    opts.live = if args.quiet {
        LiveMode::Quiet
    } else if args.plain {
        LiveMode::Plain
    } else {
        LiveMode::Auto
    };
    let report = match launcher::run(&opts) {
        Ok(report) => report,
        Err(e) => {
            // A run refused before it started (e.g. its session name is live) leaves no empty
            // `sessions/<stamp>` folder behind; `remove_dir` only removes an empty one, so a
            // failed session's logs stay.
            if args.out.is_none() {
                let _ = std::fs::remove_dir(&opts.out_dir);
            }
            return Err(e.into());
        }
    };

    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!();
        println!(
            "session {:?}: {:.1} s, {}",
            report.session,
            report.wall_seconds,
            match &report.end {
                EndReason::Completed => "completed".to_string(),
                EndReason::Interrupted => "stopped by signal".to_string(),
                EndReason::NodeFinished { node } => format!("{} finished", node_name(node)),
                EndReason::NodeFailed { node, exit } =>
                    format!("{} failed ({exit})", node_name(node)),
            }
        );
        println!("{}", report.summary);
        for n in &report.nodes {
            let restarts = if n.restarts > 0 {
                format!(", {} restart(s)", n.restarts)
            } else {
                String::new()
            };
            let killed = if n.killed {
                ", killed after the grace period"
            } else {
                ""
            };
            println!("  {:<8} {}{restarts}{killed}", node_name(&n.node), n.exit);
        }
        if report.frames_missed > 0 {
            println!(
                "  launcher missed {} physics steps (summary is partial)",
                report.frames_missed
            );
        }
        println!("files: {}", report.out_dir);
    }
    if report.success() {
        Ok(0)
    } else {
        eprintln!("error: the session did not end cleanly (see the node lines above and the logs)");
        Ok(1)
    }
}

/// A replay device fed from a session recording: the recorded device trajectory (every
/// haptic tick's proxy pose) is written as the haptic node's replay CSV into the session
/// folder, and the launch file points at that copy (the haptic node itself reads CSV only).
fn replay_from_recording(launch: &mut launch_config::LaunchFile, out_dir: &Path) -> Result<()> {
    let path = Path::new(&launch.device.replay.path);
    let is_mcap = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"));
    if launch.device.backend != launch_config::device::DeviceBackend::Replay || !is_mcap {
        return Ok(());
    }
    std::fs::create_dir_all(out_dir)
        .with_context(|| format!("creating session folder {}", out_dir.display()))?;
    let csv = out_dir.join("replay_trajectory.csv");
    let rows = recordings::export_replay_csv(path, &csv).with_context(|| {
        format!(
            "device.replay.path {}: reading the recorded device trajectory",
            path.display()
        )
    })?;
    tracing::info!(
        recording = %path.display(),
        csv = %csv.display(),
        rows,
        "replaying the device trajectory of a recorded session"
    );
    launch.device.replay.path = csv.display().to_string();
    Ok(())
}

fn node_name(n: &launcher::NodeKind) -> &'static str {
    n.name()
}

/// `arthrosim replay FILE`.
fn replay(args: ReplayArgs) -> Result<i32> {
    let options = gap_diagnosis::replay::ReplayOptions {
        out: args.out.clone(),
        realtime: args.realtime,
        data_dir: None,
        scene: None,
        publish_session: args.publish_session.clone(),
        max_steps: args.max_steps,
        recording: launch_config::RecordingConfig::default(),
    };
    let report = gap_diagnosis::replay::replay(&args.file, &options)
        .with_context(|| format!("replaying {}", args.file.display()))?;
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        println!(
            "replayed {} of {} recorded steps in {:.2} s ({:.0} steps/s); {} bit-identical, max |Δf| {:.3e} N{}",
            report.steps,
            report.recorded_steps,
            report.wall_s,
            report.steps_per_s,
            report.identical_steps,
            report.max_force_difference_n,
            if report.bit_identical() { " — contact forces bit-identical" } else { "" }
        );
        if let Some(m) = &report.first_mismatch {
            println!(
                "first mismatch at step {}: recorded {:?}, replayed {:?}",
                m.sequence, m.recorded, m.replayed
            );
        }
        if let Some(out) = &report.output {
            println!(
                "written: {} ({} messages)",
                out.path.display(),
                out.messages
            );
        }
    }
    Ok(0)
}

/// `arthrosim recordings info|summary|export|repair`.
fn recordings(cmd: RecordingsCommand) -> Result<i32> {
    match cmd {
        RecordingsCommand::Info { file, json } => {
            let info = recordings::info(&file)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&info)?);
            } else {
                println!("{info}");
            }
        }
        RecordingsCommand::Summary { file, json } => {
            let summary = recordings::session_summary(&file)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&summary)?);
            } else {
                println!("{summary}");
            }
        }
        RecordingsCommand::Export { file, csv } => {
            let summary = recordings::export_csv(&file, &csv)?;
            for f in &summary.files {
                println!("{} ({} rows)", f.path.display(), f.rows);
            }
            if summary.unannotated_steps > 0 {
                println!(
                    "{} steps without region annotation",
                    summary.unannotated_steps
                );
            }
        }
        RecordingsCommand::Repair { file, out } => {
            let out = out.unwrap_or_else(|| repaired_name(&file));
            let report = recordings::repair(&file, &out)?;
            println!(
                "{} → {}: {} messages, {} channels{}",
                report.input.display(),
                report.output.display(),
                report.messages,
                report.channels,
                match &report.input_stopped_early {
                    Some(why) => format!(" (input ended early: {why})"),
                    None => String::new(),
                }
            );
        }
    }
    Ok(0)
}

fn repaired_name(file: &Path) -> PathBuf {
    let stem = file
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("recording");
    file.with_file_name(format!("{stem}.repaired.mcap"))
}

/// `arthrosim gap …`.
fn gap_command(args: GapArgs) -> Result<i32> {
    if let Some(GapCommand::Trials { file, json }) = &args.command {
        let recording = gap::session::read_session(file)?;
        let trials = gap::session::trial_contacts(&recording)?;
        if *json {
            println!("{}", serde_json::to_string_pretty(&trials)?);
        } else {
            println!(
                "{:<28} {:>10} {:>8} {:>14} {:>14}",
                "trial", "region", "probing", "contact steps", "mean F_n [N]"
            );
            for t in &trials {
                println!(
                    "{:<28} {:>10} {:>8} {:>14} {:>14}",
                    t.name,
                    t.region.map_or(msgs::protocol::UNLABELLED, |r| r.name()),
                    t.probing_index,
                    t.contact_steps,
                    t.mean_normal_force_n
                        .map_or("–".into(), |f| format!("{f:.3}"))
                );
            }
        }
        return Ok(0);
    }
    if let Some(GapCommand::Selftest {
        cases,
        seed,
        keep,
        verbose,
        json,
        exact,
    }) = args.command
    {
        if !(1..=gap::selftest::MAX_SELFTEST_CASES).contains(&cases) {
            bail!(
                "--cases {cases}: a self-test has 1 to {} cases",
                gap::selftest::MAX_SELFTEST_CASES
            );
        }
        let mut opts = gap::selftest::SelftestOptions {
            keep_dir: keep,
            verbose,
            diagnose: gap::Options {
                progress: !json,
                nuisance: !args.no_nuisance,
                contact_nuisance: !args.no_contact_nuisance,
                material_nuisance: !args.no_material_nuisance,
                centres: !args.no_centres,
                ..gap::Options::default()
            },
            ..gap::selftest::SelftestOptions::default()
        };
        if exact {
            opts = opts.exact();
        }
        let result = gap::selftest::selftest(cases, seed, &opts)?;
        print!("{}", result.table());
        if json {
            println!("{}", serde_json::to_string(&result.summary())?);
        }
        return Ok(0);
    }
    let out = args.out.context("--out REPORT_DIR is required")?;
    let opts = gap::Options {
        dt: args.dt,
        progress: !args.json,
        pairs: !args.no_pairs,
        nuisance: !args.no_nuisance,
        contact_nuisance: !args.no_contact_nuisance,
        material_nuisance: !args.no_material_nuisance,
        centres: !args.no_centres,
        level_band: match &args.level_band {
            Some(text) => gap::Options::parse_level_band(text).context("--level-band")?,
            None => gap::Options::default().level_band,
        },
        hertz_patch: args.hertz_patch,
        ..gap::Options::default()
    };
    // checked before anything is read: a bad flag fails before minutes of replays
    opts.check().context("--dt or --level-band")?;
    // (clap's `requires` did not hold against the positional EXPERIMENT_DIR)
    if let (Some(s), None) = (&args.site, &args.force_displacement) {
        bail!(
            "--site {s} chooses where a force–displacement table is pressed: it needs \
             --force-displacement FILE.csv (an experiment's trials carry their own sites)"
        );
    }
    // the session is read first: a bad recording fails before minutes of replays
    let rendering = match &args.session {
        Some(session) => Some(
            gap::session_rendering_gap(session)
                .with_context(|| format!("rendering gap of {}", session.display()))?,
        ),
        None => None,
    };
    // the calibration's output and base are checked first too
    let calibrate = match &args.calibrate {
        Some(out) => {
            gap::calibrate::check_out_path(out).context("--calibrate")?;
            let base = match &args.launch {
                Some(b) => Some(gap::calibrate::load_base(b).context("--launch")?),
                None => None,
            };
            Some((out, base))
        }
        None => None,
    };
    let site = match &args.site {
        Some(s) => {
            gap::Region::parse(s).ok_or_else(|| anyhow::anyhow!("--site {s}: not a region"))?
        }
        None => gap::Region::Mid,
    };
    let input = match (&args.experiment, &args.force_displacement) {
        (_, Some(table)) => gap::calibrate::Input::Table {
            file: table.clone(),
            site,
        },
        (Some(dir), None) => gap::calibrate::Input::Path(dir.clone()),
        (None, None) => bail!("give an EXPERIMENT_DIR or --force-displacement FILE.csv"),
    };
    let input_name = match &input {
        gap::calibrate::Input::Table { file: p, .. } | gap::calibrate::Input::Path(p) => {
            p.display().to_string()
        }
    };
    let (mut report, calibration) = match (calibrate, &input) {
        (Some((out, base)), _) => {
            let (report, cal) = gap::calibrate::calibrate_input(&input, base, &opts)
                .with_context(|| format!("diagnosing {input_name}"))?;
            (report, Some((out, cal)))
        }
        (None, gap::calibrate::Input::Table { file, site }) => (
            gap::diagnose_force_displacement_at(file, *site, &opts)
                .with_context(|| format!("diagnosing {input_name}"))?,
            None,
        ),
        (None, gap::calibrate::Input::Path(dir)) => (
            gap::diagnose_dir(dir, &opts).with_context(|| format!("diagnosing {input_name}"))?,
            None,
        ),
    };
    if let Some(g) = rendering {
        report.rendering_gap = Some(g);
    }
    gap::write_report(&report, &out)
        .with_context(|| format!("writing the report to {}", out.display()))?;
    if let Some((path, cal)) = &calibration {
        gap::calibrate::write_launch(cal, path).context("--calibrate")?;
    }
    if args.json {
        println!("{}", serde_json::to_string(&report.verdict)?);
    } else {
        println!(
            "verdict: {} (held-out shrink {:.1}%): {}",
            report.verdict.effect,
            100.0 * report.verdict.heldout_shrink,
            report.verdict.reason
        );
        for p in &report.verdict.params {
            println!(
                "  {} {} = {} ± {}{}{}{}",
                p.effect,
                p.name,
                gap::html::fmt_value(p.value),
                gap::html::fmt_value(p.std),
                if p.unit.is_empty() { "" } else { " " },
                p.unit,
                p.bound_note()
            );
        }
        match &report.rendering_gap {
            Some(r) => println!("rendering gap: {}", r.summary),
            None if args.session.is_none()
                && args
                    .experiment
                    .as_deref()
                    .is_some_and(|p| gap::session::session_file(p).ok().flatten().is_some()) =>
            {
                println!("rendering gap: not assessed (the recording has no device ticks)")
            }
            None => {}
        }
        println!("report: {}", out.join("report.html").display());
        if let Some((path, cal)) = &calibration {
            if cal.unchanged() {
                println!(
                    "calibrated launch file: {} (verdict none: its scene is the input scene, unchanged)",
                    path.display()
                );
            } else if let Some(t) = cal.table_fit {
                println!(
                    "calibrated launch file: {} (table fit: largest error {:.3} N = {:.1}% of the table's peak)",
                    path.display(),
                    t.max_error_n,
                    t.max_error_percent_of_peak
                );
            } else {
                println!(
                    "calibrated launch file: {} (promised held-out RMSE {:.4} N)",
                    path.display(),
                    cal.promised_heldout_rmse
                );
            }
            for c in &cal.changes {
                println!("  {}", c.line());
            }
            if cal.notes().next().is_some() {
                println!("  (effects marked `not written` are comments in the file, not physics)");
            }
        }
    }
    Ok(0)
}

/// `arthrosim reality --effect … --out DIR --truth FILE`.
fn reality(args: RealityArgs) -> Result<i32> {
    let out_abs = std::path::absolute(&args.out)?;
    let truth_abs = std::path::absolute(&args.truth)?;
    if truth_abs.starts_with(&out_abs) {
        bail!(
            "--truth {} lies inside the experiment folder {}; the truth must be kept apart",
            args.truth.display(),
            args.out.display()
        );
    }
    let effects: Vec<&str> = args.effects.iter().map(String::as_str).collect();
    let mut spec = gap::reality::RealitySpec::from_effects(&effects, args.seed)?;
    if args.exact {
        spec = spec.exact();
    }
    let truth = gap::reality::write_experiment(&spec, &args.out, &args.truth)
        .with_context(|| format!("writing the experiment to {}", args.out.display()))?;
    println!(
        "experiment {} written ({} trials); truth ({}, stiffness ×{:.3}; {}) in {}",
        args.out.display(),
        spec.probings_per_region * spec.regions.len(),
        truth.label,
        spec.stiffness_scale,
        truth.model,
        args.truth.display()
    );
    if !truth.redrawn.is_empty() {
        println!(
            "drawn again at another site, where the truth's physics flagged faulty steps: {}",
            truth.redrawn.join(", ")
        );
    }
    Ok(0)
}

/// A length with a unit (`8mm`, `0.8cm`, `0.008m`; a bare number is mm), in m.
fn parse_length(s: &str) -> Result<f64> {
    let t = s.trim();
    let (num, scale) = if let Some(v) = t.strip_suffix("mm") {
        (v, 1e-3)
    } else if let Some(v) = t.strip_suffix("cm") {
        (v, 1e-2)
    } else if let Some(v) = t.strip_suffix('m') {
        (v, 1.0)
    } else {
        (t, 1e-3)
    };
    let v: f64 = num
        .trim()
        .parse()
        .map_err(|_| anyhow::anyhow!("--depth {s:?}: expected a length such as 8mm"))?;
    if !(v.is_finite() && v > 0.0) {
        bail!("--depth {s:?}: must be > 0");
    }
    Ok(v * scale)
}

/// `arthrosim probe-curve [FILE]`.
fn probe_curve(args: ProbeCurveArgs) -> Result<i32> {
    use physics_node::probe_curve::{self as pc, ForceTable, ProbeCurveOptions, Region};
    let launch = match &args.file {
        Some(path) => launch_config::load(path)?,
        None => launch_config::load_str(
            launch_config::DEFAULT_LAUNCH,
            launch_config::DEFAULT_LAUNCH_ORIGIN,
        )?,
    };
    let origin = args.file.as_ref().map_or_else(
        || launch_config::DEFAULT_LAUNCH_ORIGIN.to_string(),
        |p| p.display().to_string(),
    );
    let region = Region::parse(&args.site).ok_or_else(|| {
        anyhow::anyhow!(
            "--site {:?}: expected posterior, mid or anterior",
            args.site
        )
    })?;
    let table = match &args.table {
        Some(p) => Some(ForceTable::load(p)?),
        None => None,
    };
    let mut depth = parse_length(&args.depth)?;
    if let Some(t) = &table {
        depth = depth.max(t.max_displacement_m());
    }
    let mut opts = ProbeCurveOptions::new(region, depth);
    opts.step_m = args.step_mm * 1e-3;
    opts.grade = args.grade;
    let data = launch_config::data_dir();
    let curve = pc::run(&launch.scene, &data, &opts)
        .with_context(|| format!("probe curve of the scene of {origin}"))?;
    let comparison = match &table {
        Some(t) => Some(pc::compare(&curve, t)?),
        None => None,
    };
    if args.json {
        let doc = serde_json::json!({
            "launch": origin,
            "mesh": launch.scene.meniscus.mesh,
            "curve": curve,
            "table": comparison,
        });
        println!("{}", serde_json::to_string_pretty(&doc)?);
        return Ok(0);
    }
    let s = &curve;
    println!(
        "probe curve: {origin}, mesh {}, {} site #{} at ({:.2}, {:.2}, {:.2}) mm, normal ({:.3}, {:.3}, {:.3}), grade {}",
        launch.scene.meniscus.mesh,
        s.region.name(),
        s.site_index,
        s.site_point_m[0] * 1e3,
        s.site_point_m[1] * 1e3,
        s.site_point_m[2] * 1e3,
        s.site_normal[0],
        s.site_normal[1],
        s.site_normal[2],
        s.degeneration_grade
    );
    println!("displacement_mm,force_N,active_contacts,active_reach_mm,physics_faults");
    // One line per 0.25 mm (and the last point).
    let mut next = 0.0;
    for (i, p) in s.points.iter().enumerate() {
        if p.displacement_m + 1e-12 >= next || i + 1 == s.points.len() {
            println!(
                "{:.3},{:.4},{},{:.2},{:#x}",
                p.displacement_m * 1e3,
                p.force_n,
                p.active_contacts,
                p.active_reach_m * 1e3,
                p.physics_faults
            );
            next = p.displacement_m + 0.25e-3;
        }
    }
    if let Some(first) = s.points.iter().find(|p| p.physics_faults != 0) {
        // A rolled-back step's force is not the tissue's response: say where they start.
        println!(
            "physics faults: {} steps rolled back, the first at {:.3} mm (bits {:#x})",
            s.faulty_steps(),
            first.displacement_m * 1e3,
            first.physics_faults
        );
    }
    if let Some(c) = &comparison {
        println!(
            "\ntable {} (offset {:.2} N subtracted, peak {:.2} N)",
            c.table.display(),
            c.offset_n,
            c.peak_n
        );
        println!("displacement_mm,table_N,simulated_N,error_N,error_%_of_peak");
        for p in &c.points {
            println!(
                "{:.2},{:.3},{:.3},{:+.3},{:+.1}",
                p.displacement_m * 1e3,
                p.table_n,
                p.simulated_n,
                p.error_n,
                p.error_percent_of_peak
            );
        }
        println!(
            "max error {:.3} N = {:.1}% of the table's peak",
            c.max_error_n, c.max_error_percent_of_peak
        );
    }
    Ok(0)
}

/// `arthrosim train`: the session runs under the launcher on a second thread while the
/// training driver runs the cases on this one; the driver's end (or Ctrl-C) stops the session.
fn train(args: TrainArgs) -> Result<i32> {
    training::check_trainee_name(&args.trainee)?;
    // Before the database or a session folder is touched.
    if !(1..=training::MAX_CASES).contains(&args.cases) {
        bail!(
            "--cases {}: a training session has 1 to {} specimens",
            args.cases,
            training::MAX_CASES
        );
    }
    let (mut launch, origin, session) = session_launch(args.file.as_deref(), &args.session)?;
    // A live session of that name is refused before the database gets a session row or a
    // session folder is made: the trainer finds the session's nodes by name, so it would
    // drive the live session's probe and store its cases as this trainee's. (The claim is
    // released at once; the launcher below takes its own, and refuses a run that started
    // in between.)
    drop(launcher::SessionLock::acquire(&session)?);
    let db_path = args.db.clone().unwrap_or_else(training::default_path);
    // Open (and refuse) the database before anything starts.
    let mut db = training::Db::open(&db_path)?;
    let operator = training::prepare_launch(&mut launch);
    let issues = launch_config::validate(&launch);
    if !issues.is_empty() {
        let text: Vec<String> = issues.iter().map(|i| i.to_string()).collect();
        bail!("{origin}: {}", text.join("; "));
    }
    let seed = args
        .seed
        .unwrap_or_else(|| msgs::clock::realtime_ns() ^ u64::from(std::process::id()));
    let out_dir = args.out.clone().unwrap_or_else(launcher::default_out_dir);
    let request = training::TrainRequest {
        trainee: args.trainee.clone(),
        cases: args.cases,
        seed,
        db: db_path.clone(),
        session: session.clone(),
        out_dir: out_dir.clone(),
        launch_origin: origin.clone(),
    };
    println!(
        "training {:?}: {} specimens, seed {seed}, operator {}, database {}",
        args.trainee,
        args.cases,
        operator.name(),
        db_path.display()
    );
    if launch.viewer.enabled {
        println!(
            "trainee page: http://{}:{}/",
            launch.viewer.bind, launch.viewer.http_port
        );
    }
    let mut opts = RunOptions::for_current_exe(launch.clone(), origin, session, out_dir, None)?;
    opts.live = LiveMode::Quiet;
    let stop = msgs::lifecycle::install_stop_flag();
    let session_thread = std::thread::spawn(move || {
        let report = launcher::run(&opts);
        if report.is_err() {
            // The session is gone (or never started): the cases must not wait for it.
            stop.store(true, std::sync::atomic::Ordering::SeqCst);
        }
        report
    });
    let mut progress = |line: &str| println!("{line}");
    let result = training::train(&request, &launch, operator, &mut db, stop, &mut progress);
    // The cases are done (or failed): end the session.
    stop.store(true, std::sync::atomic::Ordering::SeqCst);
    let report = session_thread
        .join()
        .map_err(|_| anyhow::anyhow!("the session thread panicked"))?;
    let text = result?;
    println!();
    print!("{text}");
    match report {
        Ok(r) => {
            println!("files: {}", r.out_dir);
            Ok(0)
        }
        Err(e) => {
            eprintln!("warning: the session did not end cleanly: {e}");
            Ok(1)
        }
    }
}

/// `arthrosim trainees report [NAME] --out DIR`.
fn trainees(cmd: TraineesCommand) -> Result<i32> {
    match cmd {
        TraineesCommand::Report { name, out, db } => {
            let db_path = db.unwrap_or_else(training::default_path);
            if !db_path.exists() {
                bail!("trainee database {} does not exist", db_path.display());
            }
            let db = training::Db::open(&db_path)?;
            let names = match name {
                Some(n) => {
                    training::check_trainee_name(&n)?;
                    vec![n]
                }
                None => db.trainee_names()?,
            };
            if names.is_empty() {
                bail!("no trainees in {}", db_path.display());
            }
            let single = names.len() == 1;
            let mut index = String::from(
                "<!doctype html><html><head><meta charset=\"utf-8\"><title>arthrosim trainees</title></head><body><h1>Trainees</h1><ul>",
            );
            for (i, n) in names.iter().enumerate() {
                let sessions = db.sessions_of(n)?;
                let dir = if single {
                    out.clone()
                } else {
                    out.join(format!("trainee-{}", i + 1))
                };
                let path = training::write_report(n, &sessions, &dir)?;
                println!("{n}: {} sessions → {}", sessions.len(), path.display());
                let html_name = n
                    .replace('&', "&amp;")
                    .replace('<', "&lt;")
                    .replace('>', "&gt;");
                index.push_str(&format!(
                    "<li><a href=\"trainee-{}/index.html\">{html_name}</a></li>",
                    i + 1
                ));
            }
            if !single {
                index.push_str("</ul></body></html>\n");
                std::fs::write(out.join("index.html"), index)
                    .with_context(|| format!("writing {}", out.join("index.html").display()))?;
            }
            Ok(0)
        }
    }
}
