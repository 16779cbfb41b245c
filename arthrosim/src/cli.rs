//! The command line (clap derive).

use clap::{Args, Parser, Subcommand};
use std::path::PathBuf;

#[derive(Debug, Parser)]
#[command(
    name = "arthrosim",
    version,
    about = "Reality-based haptic simulation of arthroscopic meniscus examination"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run a session: start every enabled node as its own process, show live status, stop
    /// them cleanly, print the summary in the study's terms.
    Run(RunArgs),
    /// Check launch files without starting anything (exit 1 if any is invalid).
    Validate(ValidateArgs),
    /// Re-drive a new session from a recording (the proxy follows the recorded device).
    Replay(ReplayArgs),
    /// Inspect, export and repair MCAP recordings.
    #[command(subcommand)]
    Recordings(RecordingsCommand),
    /// Sim-to-real gap diagnosis of an experiment folder (or a force–displacement table):
    /// where the forces differ, which unmodelled effect explains it, how far the gap shrinks.
    Gap(GapArgs),
    /// Write a generated experiment folder from a higher-fidelity truth with injected
    /// effects (the truth goes to a separate file outside the folder).
    Reality(RealityArgs),
    /// Press the probe quasi-statically along a probing site's normal and print the tissue
    /// force against probe displacement (and the error against a force–displacement table).
    ProbeCurve(ProbeCurveArgs),
    /// Blinded degeneration-grade training: a session of N specimens with hidden grades;
    /// probe each, answer its grade (page or Touch buttons; the emulated operator answers by
    /// a stiffness policy), see the confusion matrix and accuracy; results go to SQLite.
    Train(TrainArgs),
    /// Trainee records: the learning-curve report.
    #[command(subcommand)]
    Trainees(TraineesCommand),
    /// Run one node in this process (used by `run`).
    #[command(subcommand, hide = true)]
    Node(NodeCommand),
}

#[derive(Debug, Args)]
pub struct RunArgs {
    /// Launch file (TOML). Without one, the embedded default session.
    pub file: Option<PathBuf>,
    /// Stop after this many seconds (default: `[session] seconds`, 0 = until Ctrl-C).
    #[arg(long, value_name = "N")]
    pub seconds: Option<f64>,
    /// Session folder for the resolved launch file, summary.json, node logs and the
    /// recording (default: sessions/<UTC timestamp>).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// iceoryx2 session name (default: $ARTHROSIM_SESSION, else `[session] name`).
    #[arg(long, value_name = "NAME")]
    pub session: Option<String>,
    /// Plain status lines even on a terminal.
    #[arg(long, conflicts_with = "quiet")]
    pub plain: bool,
    /// No live status and no node output (logs are still written).
    #[arg(long)]
    pub quiet: bool,
    /// Print the summary as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct ValidateArgs {
    /// Launch files to check.
    #[arg(required = true, value_name = "FILE")]
    pub files: Vec<PathBuf>,
}

#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// The recording (MCAP) to replay.
    pub file: PathBuf,
    /// Pace the replay at the recorded simulation time (default: as fast as possible).
    #[arg(long)]
    pub realtime: bool,
    /// Write the replayed session to this MCAP file.
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
    /// Re-publish on this iceoryx2 session so a running bridge puts the replay on ROS 2.
    #[arg(long, value_name = "NAME")]
    pub publish_session: Option<String>,
    /// Stop after this many physics steps.
    #[arg(long, value_name = "N")]
    pub max_steps: Option<u64>,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Subcommand)]
pub enum RecordingsCommand {
    /// Topics, counts, rates, duration and gaps of a recording (FILE.mcap with its parts
    /// FILE.1.mcap, … written by a restarted recorder, or a session folder).
    Info {
        file: PathBuf,
        #[arg(long)]
        json: bool,
    },
    /// The study's per-region summary of a recording (mean normal force in contact, probe
    /// displacement, probings): the same numbers the live session summary computes.
    Summary {
        file: PathBuf,
        #[arg(long)]
        json: bool,
    },
    /// Export the study's CSV (time, contact force, contact flag, normal force, probe pose;
    /// per region and per probing).
    Export {
        file: PathBuf,
        /// Folder for the CSV files.
        #[arg(long, value_name = "DIR")]
        csv: PathBuf,
    },
    /// Rewrite a truncated recording (e.g. after `kill -9`) with a summary and index.
    Repair {
        file: PathBuf,
        /// Output file (default: FILE with `.repaired.mcap`).
        #[arg(long, value_name = "FILE")]
        out: Option<PathBuf>,
    },
}

#[derive(Debug, Subcommand)]
pub enum NodeCommand {
    /// The physics node (FEM, contact, compliance).
    Physics(physics_node::node::NodeArgs),
    /// The 1 kHz haptic node (Touch, emulator, replay).
    Haptic(haptic_node::NodeArgs),
    /// The ROS 2 bridge.
    Bridge(viz_bridge::NodeArgs),
    /// The MCAP recorder.
    Recorder(recordings::recorder::NodeArgs),
    /// The live viewer (Foxglove WebSocket and the trainee page).
    Viewer(viewer::NodeArgs),
}

#[derive(Debug, Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct GapArgs {
    #[command(subcommand)]
    pub command: Option<GapCommand>,
    /// Experiment folder (experiment.toml and one CSV per trial), an arthrosim session
    /// recording (FILE.mcap), or a folder holding one recording.
    #[arg(
        value_name = "EXPERIMENT_DIR",
        required_unless_present = "force_displacement"
    )]
    pub experiment: Option<PathBuf>,
    /// A force–displacement table (like the cadaver one) instead of an experiment folder.
    #[arg(long, value_name = "FILE.csv", conflicts_with = "experiment")]
    pub force_displacement: Option<PathBuf>,
    /// Region whose middle protocol site presses the table (`--force-displacement` only).
    /// The mid body by default, where the cadaver table was measured; another region where
    /// the scene's mid body cannot hold the press (the study mesh slopes 45–52° there).
    #[arg(long, value_parser = ["posterior", "mid", "anterior"])]
    pub site: Option<String>,
    /// A haptic session recording (MCAP) of the same trajectories: adds the rendering gap
    /// (device-rendered vs model force) to the report. Implied when EXPERIMENT_DIR is a
    /// recording.
    #[arg(long, value_name = "FILE.mcap", conflicts_with = "force_displacement")]
    pub session: Option<PathBuf>,
    /// Folder for report.json and report.html.
    #[arg(long, value_name = "REPORT_DIR", required = true)]
    pub out: Option<PathBuf>,
    /// Replay step, s (1e-5 to 0.1, like `[scene] dt`).
    #[arg(long, default_value_t = 0.02)]
    pub dt: f64,
    /// Only single effects (no pairs).
    #[arg(long)]
    pub no_pairs: bool,
    /// Print the verdict as one JSON line.
    #[arg(long)]
    pub json: bool,
    /// Do not fit the global stiffness nuisance (judge effects against the replay as it is,
    /// as before issue 15; for comparison).
    #[arg(long)]
    pub no_nuisance: bool,
    /// Fit the stiffness nuisance without the contact nuisance (a compliance in series with
    /// the tissue under the probe, up to 10 µm/N; saves one replay per trial; for comparison).
    #[arg(long)]
    pub no_contact_nuisance: bool,
    /// Fit the stiffness and contact nuisances without the material nuisance (a mixture of the
    /// replay's corotational law and the stable neo-Hookean one; saves one replay per trial;
    /// for comparison).
    #[arg(long)]
    pub no_material_nuisance: bool,
    /// Do not re-simulate the trials at the tilt and the support the whole experiment fits,
    /// alone and together (the second stage; saves up to three replays per trial for
    /// each of the tilt and the support when a tilt of 1° or more, or a support, is fitted, and
    /// up to 24 for the pair; for comparison). `--no-tilt-centre` is its older name.
    #[arg(long, alias = "no-tilt-centre")]
    pub no_centres: bool,
    /// The band the nuisances may move the response's level in, as a fraction of the
    /// replay's mean normal force (default 0.696,1.15): how far the specimen may differ from
    /// the replay in level without an effect. A lab that knows its reference (e.g. only ever
    /// softer than the replay) narrows it; a modulus beyond it is named from the measured
    /// level (README, "A level beyond the nuisances' reach").
    #[arg(long, value_name = "LO,HI")]
    pub level_band: Option<String>,
    /// Replay the probe's balls spread over their Hertz contact patch instead of holding the
    /// closest points, the tissue scaled to the closest points' level on the specimen's
    /// protocol probings: the shape of an outside code's distributed contact (README, "The
    /// Hertz patch in the replay").
    #[arg(long)]
    pub hertz_patch: bool,
    /// Also write a launch file whose scene carries the verdict as physics (modulus →
    /// modulus_scale, support → support_stiffness, friction → friction, …; see the README).
    /// A force–displacement table is then fitted in the base scene (press at `--site`,
    /// displacement as measured, first row as offset, tissue keys reset), not the study's.
    #[arg(long, value_name = "OUT.toml")]
    pub calibrate: Option<PathBuf>,
    /// Launch file the calibration starts from (default: the embedded default; for a
    /// session recording, the launch file it recorded).
    #[arg(long, value_name = "BASE.toml", requires = "calibrate")]
    pub launch: Option<PathBuf>,
}

#[derive(Debug, Subcommand)]
pub enum GapCommand {
    /// The trials the diagnosis takes from a session recording (one per probing with
    /// contact), with their region, contact steps and mean normal force; no re-simulation.
    Trials {
        file: PathBuf,
        #[arg(long)]
        json: bool,
    },
    /// Diagnose N generated cases blind (each effect alone, some pairs, none) and print the
    /// confusion matrix and the mean held-out shrink.
    Selftest {
        /// Generated cases (1 to 1000).
        #[arg(long, default_value_t = 12)]
        cases: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Keep the generated experiment folders here.
        #[arg(long, value_name = "DIR")]
        keep: Option<PathBuf>,
        /// One line per case while running.
        #[arg(long)]
        verbose: bool,
        /// Last line: one JSON object (cases, correct, accuracy, heldout_shrink_mean).
        #[arg(long)]
        json: bool,
        /// The old self-consistent mode: the truth is the replay model itself (by default it
        /// is the specimen mesh refined once onto its smooth surface, solved directly, with a
        /// systematic stiffness offset uniform within ±15% in every case). A fast check of the
        /// statistics.
        #[arg(long)]
        exact: bool,
    },
}

#[derive(Debug, Args)]
pub struct RealityArgs {
    /// Injected effects: NAME or NAME=STRENGTH, repeated or comma-separated (modulus,
    /// hardening, viscoelastic, friction, tilt, device, support, mesh, sensor; `none`).
    #[arg(long = "effect", value_name = "NAME[=STRENGTH]", value_delimiter = ',')]
    pub effects: Vec<String>,
    /// Seed of the generated strengths, noise and sampling.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Experiment folder to write.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Truth file (must be outside the experiment folder).
    #[arg(long, value_name = "FILE")]
    pub truth: PathBuf,
    /// The truth is the replay model itself (by default it is the specimen mesh refined once
    /// onto its smooth surface, solved directly, its modulus and support scaled by a factor
    /// drawn from the seed within ±15%; the truth file records both).
    #[arg(long)]
    pub exact: bool,
}

#[derive(Debug, Args)]
pub struct ProbeCurveArgs {
    /// Launch file (TOML) whose scene is pressed. Without one, the embedded default session.
    pub file: Option<PathBuf>,
    /// Probing region: the middle one of its protocol sites.
    #[arg(long, default_value = "mid", value_parser = ["posterior", "mid", "anterior"])]
    pub site: String,
    /// Probe displacement from first touch to reach, with a unit (`8mm`, `0.008m`; a bare
    /// number is mm). With --table, at least the table's last displacement is reached.
    #[arg(long, default_value = "8mm")]
    pub depth: String,
    /// Degeneration grade 0..=2 instead of the scene's (grade 2: −41% modulus).
    #[arg(long)]
    pub grade: Option<f64>,
    /// Probe travel per 10 ms step, mm (quasi-static).
    #[arg(long, default_value_t = 0.02)]
    pub step_mm: f64,
    /// A force–displacement table (`displacement_mm,force_N`, first row the offset to
    /// subtract, as the cadaver table): print the error at each of its points.
    #[arg(long, value_name = "FILE.csv")]
    pub table: Option<PathBuf>,
    /// Print one JSON document instead of text.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Trainee name (created on first use; no path separators or control characters).
    #[arg(long, value_name = "NAME")]
    pub trainee: String,
    /// Number of scored specimens (1 to 1000).
    #[arg(long, default_value_t = 6, value_name = "N")]
    pub cases: u32,
    /// Seed of the hidden grade sequence (default: from the clock; stored with the session).
    #[arg(long, value_name = "S")]
    pub seed: Option<u64>,
    /// Trainee database (SQLite). Default: $XDG_DATA_HOME/arthrosim/trainees.sqlite, else
    /// ~/.local/share/arthrosim/trainees.sqlite.
    #[arg(long, value_name = "PATH")]
    pub db: Option<PathBuf>,
    /// Launch file (TOML). Without one, the embedded default session.
    pub file: Option<PathBuf>,
    /// Session folder (default: sessions/<UTC timestamp>).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// iceoryx2 session name (default: $ARTHROSIM_SESSION, else `[session] name`).
    #[arg(long, value_name = "NAME")]
    pub session: Option<String>,
}

#[derive(Debug, Subcommand)]
pub enum TraineesCommand {
    /// Write a self-contained HTML report (learning curve, confusion, response time and
    /// force per grade, links to each session's recording and gap report).
    Report {
        /// The trainee (default: every trainee, one page each plus an index).
        name: Option<String>,
        /// Folder for the report.
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// Trainee database (default as for `train`).
        #[arg(long, value_name = "PATH")]
        db: Option<PathBuf>,
    },
}
