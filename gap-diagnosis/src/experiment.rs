//! Experiment folders: `experiment.toml` + one CSV per probing trial.
//!
//! ```toml
//! [specimen]
//! mesh = "default:lateral:coarse"      # default:lateral|medial:coarse|fine|finest, study:lateral|medial, or a .msh path (relative to the folder)
//! fixed = "inferior"                   # inferior | none | path to 0-based node indices (relative to the folder)
//! transform = { scale = 1.0, rotation_deg = [0.0, 0.0, 0.0], translation = [0.0, 0.0, 0.0] }  # for a .msh path
//!
//! [material]                           # nominal material (what the simulation assumes)
//! preset = "lateral"                   # lateral | medial | custom
//! youngs_modulus = 3.5e6               # Pa, optional override
//! poisson_ratio = 0.29                 # optional override
//!
//! [probe]
//! model = "hook"                       # hook (the default) | sphere (a ball-tipped indenter) | an OBJ collision model (relative to the folder)
//! tip_radius = 1.5e-3                  # m
//! mass = 0.035                         # kg
//!
//! [[trial]]
//! file = "posterior_1.csv"
//! region = "posterior"                 # optional: posterior | mid | anterior
//! ```
//! CSV columns (any order, SI, world = specimen frame): `t_s,fx_N,fy_N,fz_N,px_m,py_m,pz_m,qx,qy,qz,qw`:
//! the force the tissue exerts on the probe as the sensor measured it and the pose of the probe
//! tip frame. Sampling may be irregular.
use super::GapError;
use launch_config::scene::MaterialPreset;
use msgs::csv_input::{self, Order, Spec};
use msgs::Pose;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub use msgs::protocol::Region;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransformSpec {
    #[serde(default = "one")]
    pub scale: f64,
    #[serde(default)]
    pub rotation_deg: [f64; 3],
    #[serde(default)]
    pub translation: [f64; 3],
}
fn one() -> f64 {
    1.0
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpecimenSpec {
    #[serde(default = "default_mesh")]
    pub mesh: String,
    #[serde(default = "default_fixed")]
    pub fixed: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transform: Option<TransformSpec>,
}
fn default_mesh() -> String {
    "default:lateral:coarse".into()
}
fn default_fixed() -> String {
    "inferior".into()
}
impl Default for SpecimenSpec {
    fn default() -> Self {
        SpecimenSpec {
            mesh: default_mesh(),
            fixed: default_fixed(),
            transform: None,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    /// The launch file's preset choice (an unknown value is a parse error naming the line).
    #[serde(default = "default_preset")]
    pub preset: MaterialPreset,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub youngs_modulus: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub poisson_ratio: Option<f64>,
}
fn default_preset() -> MaterialPreset {
    MaterialPreset::Lateral
}
impl Default for MaterialSpec {
    fn default() -> Self {
        MaterialSpec {
            preset: default_preset(),
            youngs_modulus: None,
            poisson_ratio: None,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProbeSpec {
    /// The indenter's collision geometry, so a replay presses with what the experiment
    /// pressed with: `hook` (the study's probe), `sphere` (a ball-tipped indenter of
    /// `tip_radius`) or the path of an OBJ collision model, relative to the folder.
    #[serde(default = "default_probe_model")]
    pub model: String,
    #[serde(default = "default_tip")]
    pub tip_radius: f64,
    #[serde(default = "default_probe_mass")]
    pub mass: f64,
}
fn default_probe_model() -> String {
    "hook".into()
}
fn default_tip() -> f64 {
    1.5e-3
}
fn default_probe_mass() -> f64 {
    0.035
}
impl Default for ProbeSpec {
    fn default() -> Self {
        ProbeSpec {
            model: default_probe_model(),
            tip_radius: default_tip(),
            mass: default_probe_mass(),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrialSpec {
    pub file: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub region: Option<String>,
}

/// The parsed `experiment.toml` (what the folder says; never which effect is present).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct ExperimentSpec {
    #[serde(default)]
    pub specimen: SpecimenSpec,
    #[serde(default)]
    pub material: MaterialSpec,
    #[serde(default)]
    pub probe: ProbeSpec,
    #[serde(default, rename = "trial")]
    pub trials: Vec<TrialSpec>,
}

// Span-carrying mirror used only for parsing, so errors can name the line.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSpec {
    #[serde(default)]
    specimen: Option<toml::Spanned<SpecimenSpec>>,
    #[serde(default)]
    material: MaterialSpec,
    #[serde(default)]
    probe: ProbeSpec,
    #[serde(default, rename = "trial")]
    trials: Vec<toml::Spanned<RawTrial>>,
}
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTrial {
    file: String,
    #[serde(default)]
    region: Option<toml::Spanned<String>>,
}

/// One probing trial as measured.
#[derive(Debug, Clone)]
pub struct Trial {
    pub name: String,
    pub file: PathBuf,
    pub region: Option<Region>,
    /// Sample times, s, strictly increasing.
    pub t: Vec<f64>,
    /// Force the tissue exerts on the probe, N, world frame.
    pub force: Vec<[f64; 3]>,
    /// Probe tip pose, world frame.
    pub pose: Vec<Pose>,
    /// Seconds of replay before the first sample, extrapolating the first motion backwards
    /// (0 for recorded trials; tables that start at contact use it for the approach).
    pub lead_in: f64,
}

/// An experiment: the folder's spec, its trials, and where the specimen mesh is.
#[derive(Debug, Clone)]
pub struct Experiment {
    pub dir: PathBuf,
    pub spec: ExperimentSpec,
    pub trials: Vec<Trial>,
    /// True for quasi-static tables (force–displacement): time-dependent effects do not apply.
    pub quasi_static: bool,
}

pub const CSV_COLUMNS: [&str; 11] = [
    "t_s", "fx_N", "fy_N", "fz_N", "px_m", "py_m", "pz_m", "qx", "qy", "qz", "qw",
];

pub(crate) fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())]
        .bytes()
        .filter(|&b| b == b'\n')
        .count()
        + 1
}

/// Read `dir/experiment.toml` and every trial CSV. `data_dir` resolves `study:` meshes.
pub fn load_experiment(dir: &Path, data_dir: &Path) -> Result<Experiment, GapError> {
    let toml_path = dir.join("experiment.toml");
    let text =
        std::fs::read_to_string(&toml_path).map_err(|e| GapError::Io(toml_path.clone(), e))?;
    let raw: RawSpec = toml::from_str(&text).map_err(|e| {
        let line = e.span().map(|s| line_of(&text, s.start)).unwrap_or(0);
        GapError::Line {
            file: toml_path.clone(),
            line,
            msg: e.message().to_string(),
        }
    })?;
    let (specimen, specimen_line) = match raw.specimen {
        Some(s) => {
            let line = line_of(&text, s.span().start);
            (s.into_inner(), line)
        }
        None => (SpecimenSpec::default(), 0),
    };
    check_mesh(&specimen, dir, data_dir).map_err(|msg| GapError::Line {
        file: toml_path.clone(),
        line: specimen_line,
        msg,
    })?;
    if raw.trials.is_empty() {
        return Err(GapError::Input {
            file: toml_path.clone(),
            msg: "no [[trial]] entries".into(),
        });
    }
    let mut trials = Vec::new();
    let mut specs = Vec::new();
    for rt in raw.trials {
        let tline = line_of(&text, rt.span().start);
        let rt = rt.into_inner();
        let region = match &rt.region {
            None => None,
            Some(r) => Some(Region::parse(r.get_ref()).ok_or_else(|| GapError::Line {
                file: toml_path.clone(),
                line: line_of(&text, r.span().start),
                msg: format!(
                    "unknown region {:?} (expected posterior, mid or anterior)",
                    r.get_ref()
                ),
            })?),
        };
        let path = dir.join(&rt.file);
        if !path.is_file() {
            return Err(GapError::Line {
                file: toml_path.clone(),
                line: tline,
                msg: format!("trial file {} not found", path.display()),
            });
        }
        let (t, force, pose) = read_trial_csv(&path)?;
        let name = Path::new(&rt.file)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| rt.file.clone());
        specs.push(TrialSpec {
            file: rt.file.clone(),
            region: region.map(|r| r.name().to_string()),
        });
        trials.push(Trial {
            name,
            file: path,
            region,
            t,
            force,
            pose,
            lead_in: 0.0,
        });
    }
    let spec = ExperimentSpec {
        specimen,
        material: raw.material,
        probe: raw.probe,
        trials: specs,
    };
    check_material(&spec)
        .and_then(|()| check_probe_model(&spec.probe, dir))
        .map_err(|msg| GapError::Input {
            file: toml_path.clone(),
            msg,
        })?;
    Ok(Experiment {
        dir: dir.to_path_buf(),
        spec,
        trials,
        quasi_static: false,
    })
}

fn check_material(spec: &ExperimentSpec) -> Result<(), String> {
    if let Some(e) = spec.material.youngs_modulus {
        if !(e.is_finite() && e > 0.0) {
            return Err(format!("youngs_modulus must be > 0, got {e}"));
        }
    }
    if let Some(nu) = spec.material.poisson_ratio {
        if !(nu.is_finite() && nu > -1.0 && nu < 0.5) {
            return Err(format!("poisson_ratio must be in (-1, 0.5), got {nu}"));
        }
    }
    if !(spec.probe.tip_radius > 0.0 && spec.probe.mass > 0.0) {
        return Err("probe tip_radius and mass must be > 0".into());
    }
    Ok(())
}

/// The probe model's collision geometry as the physics takes it: a built-in name, or the OBJ
/// path resolved against the experiment folder.
pub fn probe_model_path(probe: &ProbeSpec, dir: &Path) -> String {
    if launch_config::scene::BUILTIN_PROBE_MODELS.contains(&probe.model.as_str()) {
        probe.model.clone()
    } else {
        dir.join(&probe.model).display().to_string()
    }
}

fn check_probe_model(probe: &ProbeSpec, dir: &Path) -> Result<(), String> {
    if launch_config::scene::BUILTIN_PROBE_MODELS.contains(&probe.model.as_str()) {
        return Ok(());
    }
    let path = dir.join(&probe.model);
    let is_obj = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("obj"));
    if !is_obj {
        return Err(format!(
            "[probe] model {:?}: `hook`, `sphere` or the path of an OBJ collision model",
            probe.model
        ));
    }
    if !path.is_file() {
        return Err(format!(
            "[probe] model: OBJ collision model {} not found",
            path.display()
        ));
    }
    Ok(())
}

/// Resolve a specimen mesh spec; Err(message) when it does not exist.
pub fn check_mesh(s: &SpecimenSpec, dir: &Path, data_dir: &Path) -> Result<(), String> {
    let m = s.mesh.as_str();
    if let Some(rest) = m.strip_prefix("default:") {
        let ok = matches!(rest, "lateral" | "medial")
            || launch_config::scene::is_mesh_resolution(rest)
            || rest
                .split_once(':')
                .map(|(side, lvl)| {
                    matches!(side, "lateral" | "medial")
                        && launch_config::scene::is_mesh_resolution(lvl)
                })
                .unwrap_or(false);
        if !ok {
            return Err(format!("mesh not found: unknown built-in mesh {m:?}"));
        }
    } else if let Some(rest) = m.strip_prefix("study:") {
        let file = match rest {
            "lateral" => "meniscus/lateral_meniscus_computation.msh",
            "medial" => "meniscus/medial_meniscus_computation.msh",
            _ => return Err(format!("mesh not found: unknown study mesh {m:?}")),
        };
        let p = data_dir.join(file);
        if !p.is_file() {
            return Err(format!(
                "mesh not found: {} (set ARTHROSIM_DATA)",
                p.display()
            ));
        }
    } else {
        let p = dir.join(m);
        if !p.is_file() {
            return Err(format!("mesh not found: {}", p.display()));
        }
    }
    if !["inferior", "none"].contains(&s.fixed.as_str()) && !dir.join(&s.fixed).is_file() {
        return Err(format!(
            "fixed-node file not found: {}",
            dir.join(&s.fixed).display()
        ));
    }
    Ok(())
}

type TrialColumns = (Vec<f64>, Vec<[f64; 3]>, Vec<Pose>);

/// Longest trial, s: each trial is re-simulated step by step (and several times over for
/// the effect knots), so its span bounds the work and the memory of a diagnosis.
pub const MAX_TRIAL_SPAN_S: f64 = 600.0;
/// Largest |t| of a trial sample, s.
pub const MAX_TRIAL_TIME_S: f64 = 1.0e7;
/// Closest two samples may be, s (1 MHz; the study's sensor sampled at 38 Hz).
pub const MIN_TRIAL_INTERVAL_S: f64 = 1.0e-6;
/// Largest |coordinate| of a probe position, m (the specimen is centimetres across).
pub const MAX_TRIAL_POSITION_M: f64 = 10.0;

/// Reads a trial CSV under the workspace's CSV rules (`msgs::csv_input`: every required
/// column, finite numbers, strictly increasing time, unit quaternions; errors name file and
/// line).
pub fn read_trial_csv(path: &Path) -> Result<TrialColumns, GapError> {
    let text = std::fs::read_to_string(path).map_err(|e| GapError::Io(path.to_path_buf(), e))?;
    parse_trial_csv(&text, path)
}

pub fn parse_trial_csv(text: &str, path: &Path) -> Result<TrialColumns, GapError> {
    let spec = Spec {
        columns: &CSV_COLUMNS,
        order: Some((0, Order::Increasing, "time")),
        quaternion: Some([7, 8, 9, 10]),
        dropouts: &[],
        magnitude: &[
            (0, MAX_TRIAL_TIME_S),
            (4, MAX_TRIAL_POSITION_M),
            (5, MAX_TRIAL_POSITION_M),
            (6, MAX_TRIAL_POSITION_M),
        ],
    };
    let table = csv_input::parse(text, path, &spec)?;
    if table.len() < 5 {
        return Err(GapError::Line {
            file: path.to_path_buf(),
            line: table.header_line,
            msg: format!("only {} samples (need at least 5)", table.len()),
        });
    }
    let (mut t, mut f, mut p) = (Vec::new(), Vec::new(), Vec::new());
    let err = |line: usize, msg: String| GapError::Line {
        file: path.to_path_buf(),
        line,
        msg,
    };
    for (i, v) in table.rows().enumerate() {
        // Bounds beyond the CSV rules (time and position magnitudes are checked by the
        // reader): the trial is re-simulated step by step, so its time span and sample
        // spacing bound the work of a diagnosis.
        let lineno = table.line(i);
        if let Some(&last) = t.last() {
            if v[0] - last < MIN_TRIAL_INTERVAL_S {
                return Err(err(
                    lineno,
                    format!(
                        "column t_s: {} s after the previous sample; samples must be at least \
                         {MIN_TRIAL_INTERVAL_S} s apart",
                        v[0] - last
                    ),
                ));
            }
        }
        if let Some(&first) = t.first() {
            if v[0] - first > MAX_TRIAL_SPAN_S {
                return Err(err(
                    lineno,
                    format!(
                        "column t_s: the trial spans {} s up to here; at most {MAX_TRIAL_SPAN_S} s \
                         (each trial is re-simulated step by step)",
                        v[0] - first
                    ),
                ));
            }
        }
        t.push(v[0]);
        f.push([v[1], v[2], v[3]]);
        p.push(Pose {
            position: [v[4], v[5], v[6]],
            orientation: [v[7], v[8], v[9], v[10]],
        });
    }
    Ok((t, f, p))
}

/// Write a trial CSV in the experiment format.
pub fn write_trial_csv(
    path: &Path,
    t: &[f64],
    force: &[[f64; 3]],
    pose: &[Pose],
) -> Result<(), GapError> {
    use std::fmt::Write as _;
    let mut s = String::with_capacity(t.len() * 120);
    s.push_str(&CSV_COLUMNS.join(","));
    s.push('\n');
    for i in 0..t.len() {
        let (fo, po) = (force[i], pose[i]);
        let _ = writeln!(
            s,
            "{:.6},{:.6},{:.6},{:.6},{:.8},{:.8},{:.8},{:.8},{:.8},{:.8},{:.8}",
            t[i],
            fo[0],
            fo[1],
            fo[2],
            po.position[0],
            po.position[1],
            po.position[2],
            po.orientation[0],
            po.orientation[1],
            po.orientation[2],
            po.orientation[3]
        );
    }
    std::fs::write(path, s).map_err(|e| GapError::Io(path.to_path_buf(), e))
}

/// The cadaver-style force–displacement table (`displacement_mm,force_N`).
#[derive(Debug, Clone)]
pub struct ForceDisplacement {
    pub file: PathBuf,
    /// Probe displacement, mm (as in the file).
    pub displacement_mm: Vec<f64>,
    /// Force, N (as in the file).
    pub force_n: Vec<f64>,
}

/// Reads the table under the workspace's CSV rules (`msgs::csv_input`), displacement not
/// decreasing.
pub fn read_force_displacement(path: &Path) -> Result<ForceDisplacement, GapError> {
    let text = std::fs::read_to_string(path).map_err(|e| GapError::Io(path.to_path_buf(), e))?;
    let spec = Spec {
        order: Some((0, Order::NonDecreasing, "displacement")),
        ..Spec::columns(&["displacement_mm", "force_N"])
    };
    let table = csv_input::parse(&text, path, &spec)?;
    if table.len() < 4 {
        return Err(GapError::Line {
            file: path.to_path_buf(),
            line: table.header_line,
            msg: format!("only {} rows (need at least 4)", table.len()),
        });
    }
    let d = table.rows().map(|v| v[0]).collect();
    let f = table.rows().map(|v| v[1]).collect();
    Ok(ForceDisplacement {
        file: path.to_path_buf(),
        displacement_mm: d,
        force_n: f,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn specimen(mesh: &str) -> SpecimenSpec {
        SpecimenSpec {
            mesh: mesh.into(),
            fixed: default_fixed(),
            transform: None,
        }
    }

    /// The gap bench's ~1,400-node specimen (`default:lateral:40x6x4`) was refused as an
    /// unknown built-in mesh while launch files took it: one rule for both now.
    #[test]
    fn chosen_divisions_are_a_specimen_mesh_as_in_launch_files() {
        let here = Path::new(".");
        for ok in [
            "default:lateral:coarse",
            "default:medial:fine",
            "default:lateral:40x6x4",
            "default:44x3x2",
            "default:lateral",
        ] {
            assert!(check_mesh(&specimen(ok), here, here).is_ok(), "{ok}");
        }
        for bad in [
            "default:lateral:40x6",
            "default:lateral:0x6x4",
            "default:dorsal:coarse",
            "default:lateral:coarse:x",
        ] {
            let e = check_mesh(&specimen(bad), here, here).unwrap_err();
            assert!(e.contains(bad), "{bad}: {e}");
        }
    }
}
