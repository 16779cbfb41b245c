//! Blinded degeneration-grade training (`arthrosim train`) and trainee records
//! (`arthrosim trainees report`).
//!
//! - [`db`]: the trainee database (SQLite, bundled; WAL; explicit migrations; refuses newer
//!   schemas, corrupt and foreign files without touching them).
//! - [`driver`]: runs the cases beside a session: hidden grade per specimen, probing
//!   measures, answers from the page, the Touch's buttons or the emulated operator's policy.
//! - [`report`]: end-of-session text and the self-contained HTML report.
//!
//! The session itself (physics, haptic, viewer, recorder) is started by the launcher; the
//! CLI runs it beside [`train`].

pub mod db;
pub mod driver;
pub mod report;

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use anyhow::Context as _;
use launch_config::LaunchFile;

pub use db::{check_trainee_name, default_path, Db, DbError};
pub use driver::{hidden_grades, Operator};

/// What `arthrosim train` was asked for.
#[derive(Debug, Clone)]
pub struct TrainRequest {
    pub trainee: String,
    pub cases: u32,
    pub seed: u64,
    pub db: PathBuf,
    /// The session's iceoryx2 name.
    pub session: String,
    /// The session folder (recording, logs, the training report).
    pub out_dir: PathBuf,
    pub launch_origin: String,
}

/// How deep the emulated operator presses each specimen in training, m.
pub const TRAINING_PRESS_DEPTH_M: f64 = 0.002;

/// Most specimens one training session may have. A trainee answers a case in seconds to a
/// minute, so 1,000 is days of probing in one session, far beyond a lab's 6–12. The bound
/// keeps the hidden grade sequence (built whole before the first case) small: an unbounded
/// `--cases 4000000000` allocated and shuffled 16 GB before the session could stop.
pub const MAX_CASES: u32 = 1000;

/// Adjusts a launch file for training: the viewer on (the trainee page), the recorder on
/// (every case is in the session's MCAP), no time bound (the cases end the session), and
/// with the emulated device, a protocol that visits every region within a few seconds.
pub fn prepare_launch(launch: &mut LaunchFile) -> Operator {
    launch.session.seconds = 0.0;
    launch.viewer.enabled = true;
    launch.recording.enabled = true;
    launch.nodes.physics = true;
    launch.nodes.haptic = true;
    // The hidden grade is loaded by command; start healthy whatever the file says.
    launch.scene.material.degeneration_grade = 0.0;
    if launch.device.backend == launch_config::device::DeviceBackend::Emulated {
        launch.device.emulated.probings_per_region = launch.training.emulated_probings_per_region;
        launch.device.emulated.repeat = true;
        // The policy compares stiffness (force over depth) between specimens, as a trainee
        // pressing each to the same 2 mm does. Pressing to a felt force instead ends each
        // press on the rate-limited rendered force, which lags more on stiffer tissue: the
        // peak-force/depth ratio then mixes the lag into the grade (train_e2e: 3 of 6).
        launch.device.emulated.press_force_n = 0.0;
        launch.device.emulated.press_depth_m = TRAINING_PRESS_DEPTH_M;
        Operator::Emulated
    } else {
        Operator::Trainee
    }
}

/// Runs the cases against the running session and stores them; returns the end-of-session
/// text (confusion, accuracy, comparison with the trainee's earlier sessions).
pub fn train(
    request: &TrainRequest,
    launch: &LaunchFile,
    operator: Operator,
    db: &mut Db,
    stop: &AtomicBool,
    progress: &mut dyn driver::Progress,
) -> anyhow::Result<String> {
    check_trainee_name(&request.trainee)?;
    anyhow::ensure!(
        (1..=MAX_CASES).contains(&request.cases),
        "{} cases: a training session has 1 to {MAX_CASES}",
        request.cases
    );
    let config = &launch.training;
    config.validate()?;
    let scales = config.scales();
    let now = || utc_now();
    let trainee_id = db.trainee(&request.trainee, &now())?;
    let out_dir = std::path::absolute(&request.out_dir).unwrap_or(request.out_dir.clone());
    let recording = out_dir.join(&launch.recording.file_name);
    let gap_report = out_dir.join("gap").join("report.html");
    let session_id = db.start_session(&db::NewSession {
        trainee_id,
        started_utc: &now(),
        seed: request.seed,
        case_count: request.cases,
        grade_scales: &scales,
        operator: operator.name(),
        launch_origin: &request.launch_origin,
        session_dir: &out_dir.display().to_string(),
        recording_path: Some(&recording.display().to_string()),
        gap_report_path: Some(&gap_report.display().to_string()),
    })?;
    let truths = hidden_grades(request.cases, scales.len() as u32, request.seed);
    let driver = driver::Driver {
        config,
        session: &request.session,
        operator,
        stop,
        utc_now: &now,
    };
    let mut store = |row: &db::CaseRow| -> anyhow::Result<()> {
        db.add_case(session_id, row)?;
        Ok(())
    };
    let result = driver.run(&truths, progress, &mut store);
    db.finish_session(session_id, &now())?;
    result?;

    let sessions = db.sessions_of(&request.trainee)?;
    let (this, earlier) = match sessions.iter().position(|s| s.id == session_id) {
        Some(i) => (&sessions[i], &sessions[..i]),
        None => anyhow::bail!("session {session_id} not found after writing it"),
    };
    let text = report::session_text(this, earlier);
    write_report(&request.trainee, &sessions, &out_dir.join("training"))
        .context("writing the trainee report into the session folder")?;
    Ok(text)
}

/// Writes `index.html` of a trainee's report into `dir`.
pub fn write_report(
    trainee: &str,
    sessions: &[db::SessionRow],
    dir: &Path,
) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let path = dir.join("index.html");
    std::fs::write(&path, report::html(trainee, sessions, &utc_now()))
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(path)
}

/// `YYYY-MM-DDTHH:MM:SSZ` now.
pub fn utc_now() -> String {
    let ns = msgs::clock::realtime_ns();
    let secs = ns / 1_000_000_000;
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}
