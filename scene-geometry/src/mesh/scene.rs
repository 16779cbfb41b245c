//! Mesh specs of the `[scene.meniscus]` section → a loaded meniscus in the world frame.

use std::path::{Path, PathBuf};

use launch_config::scene::MeniscusConfig;

use super::{
    read_fixed_nodes, read_msh, read_surface, MeshError, Sliver, SurfaceMesh, TetMesh, Transform,
};
use crate::geometry::{self, ParametricMeniscus, ProbingSite, Resolution, Side};

/// Raw study units → m: the study scene scales ×26 to mm.
pub const STUDY_SCALE: f64 = 0.026;

/// Share of the mesh height, from the bottom, in which `fixed = "inferior"` looks for
/// downward-facing boundary faces on meshes without a known inferior set.
const INFERIOR_BAND: f64 = 0.35;

/// A meniscus ready for the simulation, in the world frame (m, z up, inferior plane z ≈ 0,
/// footprint centred at the origin for `default:` and `study:` specs).
#[derive(Debug, Clone)]
pub struct LoadedMeniscus {
    /// Human-readable name of what was loaded.
    pub name: String,
    /// Lateral or medial, when the spec says so.
    pub side: Option<Side>,
    pub mesh: TetMesh,
    /// Held nodes (sorted, unique, mesh-node indices).
    pub fixed_nodes: Vec<usize>,
    /// Boundary of `mesh`, outward counter-clockwise.
    pub surface: SurfaceMesh,
    /// Mesh node of each `surface` vertex.
    pub surface_to_node: Vec<usize>,
    /// Five probing sites per region (posterior, mid, anterior) on the superior surface.
    pub probing_sites: Vec<ProbingSite>,
    /// World-from-file transform that was applied (identity for the parametric mesh).
    pub transform: Transform,
    /// Thin but valid tets (warned about at load).
    pub slivers: Vec<Sliver>,
    /// The visual surface (`cfg.visual` with `cfg.visual_transform`), world m, if any.
    pub visual: Option<SurfaceMesh>,
}

impl LoadedMeniscus {
    /// For each mesh node, its `surface` vertex (`None` for interior nodes).
    pub fn node_to_surface(&self) -> Vec<Option<usize>> {
        let mut map = vec![None; self.mesh.nodes.len()];
        for (v, &n) in self.surface_to_node.iter().enumerate() {
            map[n] = Some(v);
        }
        map
    }
}

/// Where study data lives: `$ARTHROSIM_DATA`, else the repository's sibling `shared/data`.
pub fn resolve_data_dir() -> PathBuf {
    match std::env::var_os("ARTHROSIM_DATA") {
        Some(d) if !d.is_empty() => PathBuf::from(d),
        _ => PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data")),
    }
}

fn spec_err(spec: &str, problem: impl Into<String>) -> MeshError {
    MeshError::Spec {
        spec: spec.into(),
        problem: problem.into(),
    }
}

fn parse_side(spec: &str, s: &str) -> Result<Side, MeshError> {
    match s {
        "lateral" => Ok(Side::Lateral),
        "medial" => Ok(Side::Medial),
        _ => Err(spec_err(
            spec,
            format!("unknown meniscus `{s}` (lateral | medial)"),
        )),
    }
}

fn parse_resolution(spec: &str, s: &str) -> Result<Resolution, MeshError> {
    match s {
        "coarse" => Ok(Resolution::Coarse),
        "fine" => Ok(Resolution::Fine),
        "finest" => Ok(Resolution::Finest),
        _ => launch_config::scene::parse_mesh_divisions(s)
            .map(Resolution::Divisions)
            .ok_or_else(|| {
                spec_err(
                    spec,
                    format!(
                        "unknown resolution `{s}` ({})",
                        launch_config::scene::RESOLUTIONS
                    ),
                )
            }),
    }
}

/// Resolves a relative path against the working directory, then against `data_dir`.
fn locate(path: &str, data_dir: &Path) -> PathBuf {
    let p = PathBuf::from(path);
    if p.is_absolute() || p.exists() {
        p
    } else {
        let q = data_dir.join(&p);
        if q.exists() {
            q
        } else {
            p
        }
    }
}

/// Loads the meniscus a scene asks for.
///
/// Specs: `default:lateral:coarse|fine|finest`, `default:medial:…` (the parametric
/// meniscus; `default:coarse` etc. mean the lateral one), `study:lateral`, `study:medial`
/// (the study's meshes under `<data_dir>/meniscus/`, scaled ×0.026 to m and put in the
/// canonical frame), or a path to a `.msh` file, transformed by `cfg.transform`.
/// `cfg.fixed`: `inferior` (the inferior surface; for `study:lateral` the study's own list),
/// `none`, or a node-list file (0-based indices in the mesh file's node order).
pub fn load_scene_mesh(cfg: &MeniscusConfig, data_dir: &Path) -> Result<LoadedMeniscus, MeshError> {
    let spec = cfg.mesh.trim();
    let parts: Vec<&str> = spec.split(':').collect();
    let mut loaded = match parts.as_slice() {
        ["default"] => parametric(spec, Side::Lateral, Resolution::Coarse, cfg, data_dir)?,
        ["default", x] => match *x {
            "lateral" | "medial" => parametric(
                spec,
                parse_side(spec, x)?,
                Resolution::Coarse,
                cfg,
                data_dir,
            )?,
            r => parametric(
                spec,
                Side::Lateral,
                parse_resolution(spec, r)?,
                cfg,
                data_dir,
            )?,
        },
        ["default", side, res] => parametric(
            spec,
            parse_side(spec, side)?,
            parse_resolution(spec, res)?,
            cfg,
            data_dir,
        )?,
        ["study", side] => study(spec, parse_side(spec, side)?, cfg, data_dir)?,
        _ if spec.starts_with("default:") || spec.starts_with("study:") => {
            return Err(spec_err(
                spec,
                "expected default:SIDE:RESOLUTION or study:SIDE",
            ))
        }
        _ => msh_file(spec, cfg, data_dir)?,
    };
    if let Some(v) = &cfg.visual {
        let path = locate(v, data_dir);
        let mut surface = read_surface(&path)?;
        Transform::from_config(&cfg.visual_transform)?.apply_surface(&mut surface);
        loaded.visual = Some(surface);
    }
    Ok(loaded)
}

fn finish(
    name: String,
    side: Option<Side>,
    mesh: TetMesh,
    fixed_nodes: Vec<usize>,
    transform: Transform,
    slivers: Vec<Sliver>,
    sites: impl FnOnce(&SurfaceMesh) -> Vec<ProbingSite>,
) -> LoadedMeniscus {
    let (surface, surface_to_node) = mesh.boundary_surface();
    let probing_sites = sites(&surface);
    LoadedMeniscus {
        name,
        side,
        mesh,
        fixed_nodes,
        surface,
        surface_to_node,
        probing_sites,
        transform,
        slivers,
        visual: None,
    }
}

/// A node list from a file, in file node order, mapped through `map` (file position → mesh
/// node; `None` for nodes the mesh dropped).
fn fixed_from_file(
    path: &Path,
    file_nodes: usize,
    map: impl Fn(usize) -> Option<usize>,
) -> Result<Vec<usize>, MeshError> {
    let list = read_fixed_nodes(path, file_nodes)?;
    let mut out = Vec::with_capacity(list.len());
    for i in list {
        match map(i) {
            Some(m) => out.push(m),
            None => {
                return Err(MeshError::invalid(
                    path,
                    format!("fixed node {i} belongs to no tetrahedron"),
                ))
            }
        }
    }
    out.sort_unstable();
    out.dedup();
    Ok(out)
}

fn parametric(
    spec: &str,
    side: Side,
    res: Resolution,
    cfg: &MeniscusConfig,
    data_dir: &Path,
) -> Result<LoadedMeniscus, MeshError> {
    let p = ParametricMeniscus::new(side, res);
    let fixed = match cfg.fixed.as_str() {
        "inferior" => p.inferior.clone(),
        "none" => Vec::new(),
        f => {
            let n = p.mesh.nodes.len();
            fixed_from_file(&locate(f, data_dir), n, Some)?
        }
    };
    let name = format!("parametric {side:?} meniscus ({res:?}), `{spec}`").to_lowercase();
    let mesh = p.mesh.clone();
    Ok(finish(
        name,
        Some(side),
        mesh,
        fixed,
        Transform::identity(),
        Vec::new(),
        |s| geometry::parametric_probing_sites(&p, s),
    ))
}

fn study(
    spec: &str,
    side: Side,
    cfg: &MeniscusConfig,
    data_dir: &Path,
) -> Result<LoadedMeniscus, MeshError> {
    let dir = data_dir.join("meniscus");
    let (file, list) = match side {
        Side::Lateral => (
            "lateral_meniscus_computation.msh",
            Some(dir.join("lateral_meniscus_fixed_nodes.txt")),
        ),
        Side::Medial => ("medial_meniscus_computation.msh", None),
    };
    let msh = read_msh(&dir.join(file))?;
    let file_nodes = msh.file_index.last().map_or(0, |&l| l + 1);
    let map = |i: usize| msh.mesh_index_of_file(i);
    let study_fixed = match &list {
        Some(l) => Some(fixed_from_file(l, file_nodes, map)?),
        None => None,
    };
    let mut mesh = msh.mesh.clone();
    let scale = Transform {
        scale: STUDY_SCALE,
        ..Transform::identity()
    };
    scale.apply_tets(&mut mesh);
    let frame = geometry::canonical_frame(&mesh, study_fixed.as_deref());
    let iso = frame.isometry;
    for p in &mut mesh.nodes {
        *p = iso * *p;
    }
    let fixed = match cfg.fixed.as_str() {
        "inferior" => match study_fixed {
            Some(f) => f,
            None => mesh.inferior_nodes(INFERIOR_BAND),
        },
        "none" => Vec::new(),
        f => fixed_from_file(&locate(f, data_dir), file_nodes, map)?,
    };
    let transform = Transform {
        scale: STUDY_SCALE,
        rotation: iso.rotation.to_rotation_matrix(),
        translation: iso.translation.vector,
    };
    let name = format!(
        "study {} meniscus, `{spec}`",
        if side == Side::Lateral {
            "lateral"
        } else {
            "medial"
        }
    );
    Ok(finish(
        name,
        Some(side),
        mesh,
        fixed,
        transform,
        msh.slivers,
        geometry::probing_sites,
    ))
}

fn msh_file(
    spec: &str,
    cfg: &MeniscusConfig,
    data_dir: &Path,
) -> Result<LoadedMeniscus, MeshError> {
    let path = locate(spec, data_dir);
    if path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .as_deref()
        != Some("msh")
    {
        return Err(spec_err(
            spec,
            "not default:…, study:… or a path to a .msh file",
        ));
    }
    let msh = read_msh(&path)?;
    let file_nodes = msh.file_index.last().map_or(0, |&l| l + 1);
    let transform = Transform::from_config(&cfg.transform)?;
    let mut mesh = msh.mesh.clone();
    transform.apply_tets(&mut mesh);
    let fixed = match cfg.fixed.as_str() {
        "inferior" => mesh.inferior_nodes(INFERIOR_BAND),
        "none" => Vec::new(),
        f => fixed_from_file(&locate(f, data_dir), file_nodes, |i| {
            msh.mesh_index_of_file(i)
        })?,
    };
    Ok(finish(
        format!("mesh file {}", path.display()),
        None,
        mesh,
        fixed,
        transform,
        msh.slivers,
        geometry::probing_sites,
    ))
}
