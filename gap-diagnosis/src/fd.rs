//! A force–displacement table (like the study's cadaver curve) as a quasi-static indentation
//! experiment on the study's lateral mesh.
//!
//! As in the study's scene (`getEmpiricalForces.py`): displacement × 2/3 is the indentation
//! depth and the first row's force is an offset subtracted from all rows. The probe is
//! pressed along the inward normal of the mid-region probing site, depth 0 being where the
//! simulated contact begins (found by a first approach sweep); the measured force acts along
//! the simulated force direction at the same depth (the table has no direction).
use super::experiment::{
    read_force_displacement, Experiment, ExperimentSpec, Region, SpecimenSpec, Trial, TrialSpec,
};
use super::model::{replay, ForceModel, ProbePath, Variant};
use super::signal::{add, interp, norm, scale};
use super::sim_model::SimForceModel;
use super::{GapError, Options, Report};
use msgs::Pose;
use std::path::Path;

/// Scene conventions for a table.
#[derive(Debug, Clone)]
pub struct TableConvention {
    /// Depth = displacement × this (the study: 2/3).
    pub displacement_scale: f64,
    /// Subtract the first row's force (the study: 0.31 N offset).
    pub subtract_first_row: bool,
    /// Mesh spec (the study: `study:lateral`).
    pub mesh: String,
    pub region: Region,
    /// Indentation speed of the quasi-static replay, m/s.
    pub speed: f64,
}

impl Default for TableConvention {
    fn default() -> Self {
        TableConvention {
            displacement_scale: 2.0 / 3.0,
            subtract_first_row: true,
            mesh: "study:lateral".into(),
            region: Region::Mid,
            speed: 1.0e-3,
        }
    }
}

/// Diagnose a force–displacement table with the physics model (the study's convention, at
/// the mid-body site).
pub fn diagnose_force_displacement(file: &Path, opts: &Options) -> Result<Report, GapError> {
    diagnose_force_displacement_at(file, Region::Mid, opts)
}

/// Same at the middle protocol site of another region.
pub fn diagnose_force_displacement_at(
    file: &Path,
    region: Region,
    opts: &Options,
) -> Result<Report, GapError> {
    let data = super::data_dir();
    let conv = TableConvention {
        region,
        ..TableConvention::default()
    };
    let mut scene = launch_config::SceneConfig::default();
    scene.meniscus.mesh = conv.mesh.clone();
    let model = SimForceModel::from_scene(scene, &data);
    diagnose_table_at_mid_site(file, &conv, &model, opts)
}

impl TableConvention {
    /// Issue 13's convention for calibrating a scene to a table: displacement as measured
    /// (no ×2/3), the first row's force as the offset, a press at the mid-body site of the
    /// scene's own mesh.
    pub fn as_measured(mesh: &str) -> TableConvention {
        TableConvention {
            displacement_scale: 1.0,
            mesh: mesh.to_string(),
            ..TableConvention::default()
        }
    }
}

/// Diagnose a table against `scene` (its mesh, material, probe and support) with
/// [`TableConvention::as_measured`]: what `gap --force-displacement --calibrate` fits.
pub fn diagnose_table_in_scene(
    file: &Path,
    scene: &launch_config::SceneConfig,
    opts: &Options,
) -> Result<Report, GapError> {
    let conv = TableConvention::as_measured(&scene.meniscus.mesh);
    let model = SimForceModel::from_scene(scene.clone(), &super::data_dir());
    diagnose_table_at_mid_site(file, &conv, &model, opts)
}

fn diagnose_table_at_mid_site(
    file: &Path,
    conv: &TableConvention,
    model: &SimForceModel,
    opts: &Options,
) -> Result<Report, GapError> {
    opts.check()?;
    let site = mid_site(file, conv, model)?;
    diagnose_table_with(file, conv, model, site.point, site.normal, opts)
}

/// The middle probing site of the convention's region on the model's specimen.
pub fn mid_site(
    file: &Path,
    conv: &TableConvention,
    model: &SimForceModel,
) -> Result<super::reality::Site, GapError> {
    // the table is read first: a bad file fails before the specimen is built
    read_force_displacement(file)?;
    let sites = model.sites().map_err(|e| GapError::Input {
        file: file.to_path_buf(),
        msg: format!("{} ({e})", conv.mesh),
    })?;
    let mid: Vec<_> = sites.iter().filter(|s| s.region == conv.region).collect();
    let site = mid.get(mid.len() / 2).ok_or_else(|| {
        GapError::Sim(format!(
            "no {} probing site on {}",
            conv.region.name(),
            conv.mesh
        ))
    })?;
    Ok(**site)
}

/// Same with any model and probing site (point on the surface, outward normal).
pub fn diagnose_table_with(
    file: &Path,
    conv: &TableConvention,
    model: &dyn ForceModel,
    point: [f64; 3],
    normal: [f64; 3],
    opts: &Options,
) -> Result<Report, GapError> {
    let start = std::time::Instant::now();
    opts.check()?;
    let (exp, input) = table_experiment(file, conv, model, point, normal, opts.dt)?;
    let mut r = super::diagnose(&exp, model, opts)?;
    r.input = input;
    r.elapsed_s = start.elapsed().as_secs_f64();
    Ok(r)
}

/// The table as a one-trial quasi-static experiment pressed at `point` along −`normal`
/// (replay step `dt`), and the label a report gives it.
pub fn table_experiment(
    file: &Path,
    conv: &TableConvention,
    model: &dyn ForceModel,
    point: [f64; 3],
    normal: [f64; 3],
    dt: f64,
) -> Result<(Experiment, String), GapError> {
    let table = read_force_displacement(file)?;
    let offset = if conv.subtract_first_row {
        table.force_n[0]
    } else {
        0.0
    };
    let depth_m: Vec<f64> = table
        .displacement_mm
        .iter()
        .map(|d| d * conv.displacement_scale * 1e-3)
        .collect();
    let dmax = *depth_m.last().unwrap();
    // approach sweep: from 4 mm above to dmax + 1 mm below the site point
    let above = 4.0e-3;
    let n_steps = ((above + dmax + 1.0e-3) / conv.speed / dt).ceil() as usize + 1;
    let sweep = ProbePath {
        t0: 0.0,
        dt,
        poses: (0..n_steps)
            .map(|k| Pose {
                position: add(point, scale(normal, above - conv.speed * dt * k as f64)),
                orientation: [0.0, 0.0, 0.0, 1.0],
            })
            .collect(),
    };
    let f = replay(model, &Variant::default(), &sweep)?;
    let peak = f.iter().map(|v| norm(*v)).fold(0.0, f64::max);
    let onset = f
        .iter()
        .position(|v| norm(*v) > (0.01f64).max(1e-3 * peak))
        .ok_or_else(|| {
            GapError::Sim(format!(
                "the probe never touched the specimen along the normal at {point:?}"
            ))
        })?;
    let offset_along_n = above - conv.speed * dt * onset as f64; // contact begins here
                                                                 // simulated force direction as a function of depth
    let depth_grid: Vec<f64> = (0..n_steps)
        .map(|k| offset_along_n - (above - conv.speed * dt * k as f64))
        .collect();
    let dir_at = |d: f64| -> [f64; 3] {
        let v =
            [0, 1, 2].map(|q| interp(&depth_grid, &f.iter().map(|x| x[q]).collect::<Vec<_>>(), d));
        let m = norm(v);
        if m > 1e-9 {
            scale(v, 1.0 / m)
        } else {
            normal
        }
    };
    let lead_in = 3.0e-3 / conv.speed;
    let mut t = Vec::new();
    let mut force = Vec::new();
    let mut pose = Vec::new();
    for (&d, &fv) in depth_m.iter().zip(&table.force_n) {
        // quasi-static: time only orders the samples; equal displacements get a tiny step
        let mut ti = d / conv.speed;
        if let Some(&last) = t.last() {
            if ti <= last {
                ti = last + 0.05;
            }
        }
        t.push(ti);
        let u = dir_at(d);
        force.push(scale(u, fv - offset));
        pose.push(Pose {
            position: add(point, scale(normal, offset_along_n - d)),
            orientation: [0.0, 0.0, 0.0, 1.0],
        });
    }
    let trial = Trial {
        name: file
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "table".into()),
        file: file.to_path_buf(),
        region: Some(conv.region),
        t,
        force,
        pose,
        lead_in,
    };
    let exp = Experiment {
        dir: file.to_path_buf(),
        spec: ExperimentSpec {
            specimen: SpecimenSpec {
                mesh: conv.mesh.clone(),
                ..Default::default()
            },
            trials: vec![TrialSpec {
                file: file.display().to_string(),
                region: Some(conv.region.name().into()),
            }],
            ..Default::default()
        },
        trials: vec![trial],
        quasi_static: true,
    };
    let input = format!(
        "{} (force–displacement table: depth = displacement × {:.3}, offset {:.3} N removed, {} site, {})",
        file.display(),
        conv.displacement_scale,
        offset,
        conv.region.name(),
        conv.mesh
    );
    Ok((exp, input))
}
