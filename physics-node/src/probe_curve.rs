//! Quasi-static probe curve of a scene: the probe, held in the emulated operator's probing
//! pose (identity orientation: body z along the world z, the hook's tip lowest), is pressed
//! kinematically along a probing site's outward normal, and the tissue contact force of
//! eq. (1) along the normal is recorded against the probe displacement along the normal from
//! first touch. This is how labs characterise a scene (`arthrosim probe-curve`) and how the
//! tests check it against the cadaver force–displacement table.
//!
//! The press is slow enough to be quasi-static: at 0.02 mm per 10 ms step the tissue's
//! nodal masses (mg) against its stiffness (kN/m) relax within a step, so the curve does not
//! depend on the rate (see the `probe_curve` tests).

use crate::error::PhysicsError;
use crate::geometry::ProbingSite;
use crate::sim::Simulation;
use launch_config::SceneConfig;
use nalgebra::{Point3, UnitQuaternion, Vector3};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Normal force above which the probe counts as touching, N.
pub const TOUCH_FORCE_N: f64 = 1e-3;
/// Default probe travel per 10 ms step, m.
pub const DEFAULT_STEP_M: f64 = 0.02e-3;
/// Clearance between the tip sphere and the surface at the start, m.
const START_CLEARANCE_M: f64 = 0.2e-3;

/// Errors of a probe curve.
#[derive(Debug, thiserror::Error)]
pub enum ProbeCurveError {
    #[error(transparent)]
    Physics(#[from] PhysicsError),
    #[error("the scene has no probing site in the {0} region")]
    NoSite(&'static str),
    #[error("{0}")]
    Options(String),
    #[error("the probe travelled {travel_mm:.2} mm along the {site} site's normal without touching the tissue")]
    NoTouch { site: &'static str, travel_mm: f64 },
    #[error("{path}: cannot read: {detail}")]
    Io { path: PathBuf, detail: String },
    #[error("{path}:{line}: {detail}")]
    Table {
        path: PathBuf,
        line: usize,
        detail: String,
    },
}

/// The protocol's regions, as probing sites are tagged (one definition, the wire's).
pub use msgs::protocol::Region;

// Probing sites carry the mesh crate's region codes; they are the wire's.
const _: () = assert!(
    crate::geometry::REGION_POSTERIOR == Region::Posterior as u32
        && crate::geometry::REGION_MID == Region::Mid as u32
        && crate::geometry::REGION_ANTERIOR == Region::Anterior as u32
);

/// What to press and how far.
#[derive(Debug, Clone, PartialEq)]
pub struct ProbeCurveOptions {
    pub region: Region,
    /// Probe displacement from first touch to reach, m.
    pub depth_m: f64,
    /// Probe travel per step, m.
    pub step_m: f64,
    /// Degeneration grade (0..=2) instead of the scene's.
    pub grade: Option<f64>,
}

impl ProbeCurveOptions {
    pub fn new(region: Region, depth_m: f64) -> Self {
        ProbeCurveOptions {
            region,
            depth_m,
            step_m: DEFAULT_STEP_M,
            grade: None,
        }
    }
}

/// One step of the press.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CurvePoint {
    /// Probe displacement along the inward normal from first touch, m.
    pub displacement_m: f64,
    /// Tissue contact force on the probe along the outward normal (eq. (1)), N.
    pub force_n: f64,
    /// Contacts in the step, and of those the ones carrying force.
    pub contacts: usize,
    pub active_contacts: usize,
    /// Largest distance of a force-carrying contact point from the tip sphere's centre, m.
    pub active_reach_m: f64,
    /// `msgs::physics_to_haptic::physics_fault` bits of the step (0: a good step). A faulty
    /// step was rolled back, so its force is not the tissue's response to this displacement.
    pub physics_faults: u32,
}

/// A probe curve.
#[derive(Debug, Clone, Serialize)]
pub struct ProbeCurve {
    pub region: Region,
    /// Index of the site among the scene's probing sites.
    pub site_index: usize,
    pub site_point_m: [f64; 3],
    pub site_normal: [f64; 3],
    pub degeneration_grade: f64,
    pub step_m: f64,
    /// Probe travel from the start pose to first touch, m.
    pub touch_travel_m: f64,
    /// From first touch on (the first point is the last step without force).
    pub points: Vec<CurvePoint>,
}

impl ProbeCurve {
    /// Force at displacement `d` (m), linear between steps; None beyond the curve.
    pub fn force_at(&self, d: f64) -> Option<f64> {
        let p = &self.points;
        if p.is_empty() || d < p[0].displacement_m || d > p[p.len() - 1].displacement_m + 1e-12 {
            return None;
        }
        let k = p.partition_point(|q| q.displacement_m < d);
        if k == 0 {
            return Some(p[0].force_n);
        }
        if k >= p.len() {
            return Some(p[p.len() - 1].force_n);
        }
        let (a, b) = (&p[k - 1], &p[k]);
        let u = (d - a.displacement_m) / (b.displacement_m - a.displacement_m);
        Some(a.force_n + u * (b.force_n - a.force_n))
    }

    /// Steps of the curve the physics flagged as faulty (and rolled back).
    pub fn faulty_steps(&self) -> usize {
        self.points.iter().filter(|p| p.physics_faults != 0).count()
    }

    /// Largest distance of a force-carrying contact from the tip centre over the curve, m.
    pub fn max_active_reach_m(&self) -> f64 {
        self.points
            .iter()
            .map(|p| p.active_reach_m)
            .fold(0.0, f64::max)
    }
}

/// The probing site of a region the curve presses at: the middle one of the region's sites
/// (the protocol's region centre).
pub fn region_site(sites: &[ProbingSite], region: Region) -> Option<(usize, ProbingSite)> {
    let idx: Vec<usize> = (0..sites.len())
        .filter(|&i| sites[i].region == region.code())
        .collect();
    let i = *idx.get(idx.len() / 2)?;
    Some((i, sites[i]))
}

/// Builds the scene's simulation and presses the probe at the region's site.
pub fn run(
    scene: &SceneConfig,
    data_dir: &Path,
    opts: &ProbeCurveOptions,
) -> Result<ProbeCurve, ProbeCurveError> {
    if !(opts.depth_m.is_finite() && opts.depth_m > 0.0 && opts.depth_m <= 0.03) {
        return Err(ProbeCurveError::Options(format!(
            "depth {} m out of range (0, 30 mm]",
            opts.depth_m
        )));
    }
    if !(opts.step_m.is_finite() && opts.step_m >= 1e-6 && opts.step_m <= 0.5e-3) {
        return Err(ProbeCurveError::Options(format!(
            "step {} m out of range [0.001, 0.5] mm",
            opts.step_m
        )));
    }
    let mut scene = scene.clone();
    if let Some(g) = opts.grade {
        if !(g.is_finite() && (0.0..=2.0).contains(&g)) {
            return Err(ProbeCurveError::Options(format!(
                "degeneration grade {g} out of range 0..=2"
            )));
        }
        scene.material.degeneration_grade = g;
    }
    let mut sim = Simulation::offline(&scene, data_dir)?;
    press(&mut sim, &scene, opts)
}

/// Presses the probe of a freshly built `sim` (see [`run`]).
pub fn press(
    sim: &mut Simulation,
    scene: &SceneConfig,
    opts: &ProbeCurveOptions,
) -> Result<ProbeCurve, ProbeCurveError> {
    let (site_index, site) = region_site(sim.probing_sites(), opts.region)
        .ok_or(ProbeCurveError::NoSite(opts.region.name()))?;
    let n = site.normal.normalize();
    // The emulated operator's pose: the device's identity orientation.
    let q = UnitQuaternion::identity();
    // Start with the tip sphere just clear of the surface along the normal.
    let r = sim
        .probe()
        .spheres
        .first()
        .map_or(scene.probe.tip_radius, |s| s.radius);
    let start: Point3<f64> = site.point + n * (r + START_CLEARANCE_M);
    sim.teleport_probe(&crate::probe::pose(start, q));

    let max_travel = START_CLEARANCE_M + r + opts.depth_m + 2.0e-3;
    let mut travel = 0.0;
    let mut touch: Option<f64> = None;
    let mut prev = (0.0, 0.0);
    let mut points = Vec::new();
    loop {
        travel += opts.step_m;
        let pos = start - n * travel;
        sim.set_probe_kinematic(&crate::probe::pose(pos, q));
        sim.step()?;
        let force = Vector3::from(sim.contact_force()).dot(&n);
        let (contacts, active, reach) = active_contacts(sim);
        match touch {
            None if force > TOUCH_FORCE_N => {
                // The last step without force is the first touch.
                let t = prev.0;
                touch = Some(t);
                points.push(CurvePoint {
                    displacement_m: 0.0,
                    force_n: prev.1,
                    contacts: 0,
                    active_contacts: 0,
                    active_reach_m: 0.0,
                    physics_faults: 0,
                });
            }
            None => {
                prev = (travel, force);
                if travel > max_travel {
                    return Err(ProbeCurveError::NoTouch {
                        site: opts.region.name(),
                        travel_mm: travel * 1e3,
                    });
                }
                continue;
            }
            Some(_) => {}
        }
        let t0 = touch.unwrap_or(0.0);
        points.push(CurvePoint {
            displacement_m: travel - t0,
            force_n: force,
            contacts,
            active_contacts: active,
            active_reach_m: reach,
            physics_faults: sim.contact_frame().physics_faults,
        });
        if travel - t0 >= opts.depth_m - 1e-12 {
            break;
        }
    }
    Ok(ProbeCurve {
        region: opts.region,
        site_index,
        site_point_m: [site.point.x, site.point.y, site.point.z],
        site_normal: [n.x, n.y, n.z],
        degeneration_grade: scene.material.degeneration_grade,
        step_m: opts.step_m,
        touch_travel_m: touch.unwrap_or(0.0),
        points,
    })
}

/// (contacts, contacts with a positive normal impulse, largest distance of those from the
/// tip sphere's centre).
fn active_contacts(sim: &Simulation) -> (usize, usize, f64) {
    let frame = sim.contact_frame();
    let tip = sim.probe().sphere_world(0);
    let mut active = 0;
    let mut reach: f64 = 0.0;
    for (k, c) in sim.contacts().iter().enumerate() {
        if frame.lambda[3 * k] > 0.0 {
            active += 1;
            reach = reach.max((c.point - tip).norm());
        }
    }
    (sim.contacts().len(), active, reach)
}

/// A force–displacement table (the cadaver CSV format: `displacement_mm,force_N`, the first
/// data row the offset to subtract).
#[derive(Debug, Clone, Serialize)]
pub struct ForceTable {
    pub path: PathBuf,
    /// First row (offset), mm and N.
    pub offset_mm: f64,
    pub offset_n: f64,
    /// Rows after subtracting the offset: displacement m, force N.
    pub rows: Vec<(f64, f64)>,
}

impl ForceTable {
    pub fn load(path: &Path) -> Result<ForceTable, ProbeCurveError> {
        let text = std::fs::read_to_string(path).map_err(|e| ProbeCurveError::Io {
            path: path.to_path_buf(),
            detail: e.to_string(),
        })?;
        Self::parse(&text, path)
    }

    pub fn parse(text: &str, path: &Path) -> Result<ForceTable, ProbeCurveError> {
        let bad = |line: usize, detail: String| ProbeCurveError::Table {
            path: path.to_path_buf(),
            line,
            detail,
        };
        let mut raw: Vec<(f64, f64)> = Vec::new();
        let mut header_seen = false;
        for (i, line) in text.lines().enumerate() {
            let ln = i + 1;
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let cells: Vec<&str> = line.split(',').map(str::trim).collect();
            if !header_seen && raw.is_empty() && cells.iter().any(|c| c.parse::<f64>().is_err()) {
                let want = ["displacement_mm", "force_n"];
                let got: Vec<String> = cells.iter().map(|c| c.to_ascii_lowercase()).collect();
                if got != want {
                    return Err(bad(
                        ln,
                        format!("header {line:?}: expected `displacement_mm,force_N`"),
                    ));
                }
                header_seen = true;
                continue;
            }
            if cells.len() != 2 {
                return Err(bad(
                    ln,
                    format!(
                        "{} columns, expected 2 (displacement_mm,force_N)",
                        cells.len()
                    ),
                ));
            }
            let num = |s: &str, what: &str| -> Result<f64, ProbeCurveError> {
                let v: f64 = s
                    .parse()
                    .map_err(|_| bad(ln, format!("{what} {s:?} is not a number")))?;
                if !v.is_finite() {
                    return Err(bad(ln, format!("{what} {s:?} is not finite")));
                }
                Ok(v)
            };
            let d = num(cells[0], "displacement")?;
            let f = num(cells[1], "force")?;
            if let Some(&(d_prev, _)) = raw.last() {
                if d <= d_prev {
                    return Err(bad(
                        ln,
                        format!("displacement {d} mm does not increase (previous {d_prev} mm)"),
                    ));
                }
            }
            raw.push((d, f));
        }
        if raw.len() < 2 {
            return Err(bad(
                text.lines().count(),
                format!(
                    "{} data rows; need the offset row and at least one more",
                    raw.len()
                ),
            ));
        }
        let (d0, f0) = raw[0];
        Ok(ForceTable {
            path: path.to_path_buf(),
            offset_mm: d0,
            offset_n: f0,
            rows: raw
                .iter()
                .map(|&(d, f)| ((d - d0) * 1e-3, f - f0))
                .collect(),
        })
    }

    /// Largest force after the offset, N.
    pub fn peak_n(&self) -> f64 {
        self.rows.iter().map(|r| r.1).fold(0.0, f64::max)
    }

    /// Largest displacement, m.
    pub fn max_displacement_m(&self) -> f64 {
        self.rows.last().map_or(0.0, |r| r.0)
    }
}

/// The curve against a table, point by point.
#[derive(Debug, Clone, Serialize)]
pub struct TableComparison {
    pub table: PathBuf,
    pub offset_n: f64,
    pub peak_n: f64,
    pub points: Vec<TablePoint>,
    /// Largest |error|, N, and as % of the table's peak.
    pub max_error_n: f64,
    pub max_error_percent_of_peak: f64,
}

#[derive(Debug, Clone, Copy, Serialize)]
pub struct TablePoint {
    pub displacement_m: f64,
    pub table_n: f64,
    pub simulated_n: f64,
    /// simulated − table, N.
    pub error_n: f64,
    pub error_percent_of_peak: f64,
}

/// Compares a curve with a table (the curve must reach the table's last displacement).
pub fn compare(curve: &ProbeCurve, table: &ForceTable) -> Result<TableComparison, ProbeCurveError> {
    let peak = table.peak_n();
    if !(peak > 0.0) {
        return Err(ProbeCurveError::Table {
            path: table.path.clone(),
            line: 0,
            detail: "no positive force after the offset".into(),
        });
    }
    let mut points = Vec::with_capacity(table.rows.len());
    let mut max_err: f64 = 0.0;
    for &(d, f) in &table.rows {
        let sim = curve.force_at(d).ok_or_else(|| {
            ProbeCurveError::Options(format!(
                "the curve ends at {:.2} mm, short of the table's {:.2} mm",
                curve.points.last().map_or(0.0, |p| p.displacement_m) * 1e3,
                d * 1e3
            ))
        })?;
        let e = sim - f;
        max_err = max_err.max(e.abs());
        points.push(TablePoint {
            displacement_m: d,
            table_n: f,
            simulated_n: sim,
            error_n: e,
            error_percent_of_peak: 100.0 * e / peak,
        });
    }
    Ok(TableComparison {
        table: table.path.clone(),
        offset_n: table.offset_n,
        peak_n: peak,
        points,
        max_error_n: max_err,
        max_error_percent_of_peak: 100.0 * max_err / peak,
    })
}
