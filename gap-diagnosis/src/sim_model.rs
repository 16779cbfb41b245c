//! The shipped replay model: the physics node's `Simulation`, probe driven kinematically.
use super::experiment::Experiment;
use super::model::{ForceModel, ProbePath, Replayed, Variant};
use super::GapError;
use launch_config::SceneConfig;
use physics_node::sim::Simulation;
use std::path::{Path, PathBuf};

#[derive(Debug, Clone)]
pub struct SimForceModel {
    pub scene: SceneConfig,
    pub data_dir: PathBuf,
    /// Mesh spec of the refined discretisation of the same specimen (None: not available).
    pub fine_mesh: Option<String>,
}

/// The refined spec of a built-in mesh (`default:lateral:coarse` → `default:lateral:fine`).
pub fn refined_spec(spec: &str) -> Option<String> {
    let rest = spec.strip_prefix("default:")?;
    let (side, level) = match rest.split_once(':') {
        Some((s, l)) => (s, l),
        None if matches!(rest, "coarse" | "fine" | "finest") => ("lateral", rest),
        None => (rest, "coarse"),
    };
    let next = match level {
        "coarse" => "fine",
        "fine" => "finest",
        _ => return None,
    };
    Some(format!("default:{side}:{next}"))
}

impl SimForceModel {
    pub fn from_scene(scene: SceneConfig, data_dir: &Path) -> SimForceModel {
        let fine_mesh = refined_spec(&scene.meniscus.mesh);
        SimForceModel {
            scene,
            data_dir: data_dir.to_path_buf(),
            fine_mesh,
        }
    }

    /// Scene of an experiment: its specimen, nominal material and probe; quasi-static replay.
    pub fn for_experiment(exp: &Experiment, data_dir: &Path) -> Result<SimForceModel, GapError> {
        let s = &exp.spec;
        let mut scene = SceneConfig::default();
        let mesh = &s.specimen.mesh;
        scene.meniscus.mesh = if mesh.starts_with("default:") || mesh.starts_with("study:") {
            mesh.clone()
        } else {
            exp.dir.join(mesh).display().to_string()
        };
        scene.meniscus.fixed = if ["inferior", "none"].contains(&s.specimen.fixed.as_str()) {
            s.specimen.fixed.clone()
        } else {
            exp.dir.join(&s.specimen.fixed).display().to_string()
        };
        if let Some(t) = &s.specimen.transform {
            scene.meniscus.transform.scale = t.scale;
            scene.meniscus.transform.rotation_deg = t.rotation_deg;
            scene.meniscus.transform.translation = t.translation;
        }
        scene.material.preset = s.material.preset;
        scene.material.youngs_modulus = s.material.youngs_modulus;
        scene.material.poisson_ratio = s.material.poisson_ratio;
        scene.probe.model = super::experiment::probe_model_path(&s.probe, &exp.dir);
        scene.probe.tip_radius = s.probe.tip_radius;
        scene.probe.mass = s.probe.mass;
        // check the scene builds now, so a bad mesh is reported before any replay
        Simulation::new(&scene, data_dir).map_err(|e| GapError::Input {
            file: exp.dir.join("experiment.toml"),
            msg: format!("specimen: {e}"),
        })?;
        Ok(SimForceModel::from_scene(scene, data_dir))
    }

    /// Scene of a session recording (its `scene.toml`), checked to build.
    pub fn for_session(
        rec: &super::session::SessionRecording,
        data_dir: &Path,
    ) -> Result<SimForceModel, GapError> {
        Simulation::new(&rec.scene, data_dir).map_err(|e| GapError::Input {
            file: rec.path.clone(),
            msg: format!(
                "specimen of the {} attachment: {e}",
                recordings::channels::ATTACHMENT_SCENE
            ),
        })?;
        Ok(SimForceModel::from_scene(rec.scene.clone(), data_dir))
    }

    /// The scene a replay of variant `v` steps: the model's scene with the effect applied,
    /// step `dt`, and the offline solver of `[scene.solver] offline` (converged by default,
    /// not the live node's 25-iteration CG).
    pub fn scene_for(&self, v: &Variant, dt: f64) -> Result<SceneConfig, GapError> {
        let mut sc = self.scene.clone();
        sc.dt = dt;
        sc.solver = sc.solver.offline()?;
        sc.material.modulus_scale *= v.modulus_scale;
        if v.neo_hookean {
            sc.material.model = launch_config::scene::MaterialModel::StableNeoHookean;
        }
        // effects add to the nominal scene (a recorded session may already have friction or
        // an elastic support; experiment folders start from zero for both)
        sc.contact.friction += v.friction;
        if v.support_stiffness > 0.0 {
            sc.meniscus.support_stiffness = v.support_stiffness;
        }
        if v.fine_mesh {
            sc.meniscus.mesh = self.fine_mesh.clone().ok_or_else(|| {
                GapError::Sim(format!("no refined mesh for {}", self.scene.meniscus.mesh))
            })?;
        }
        Ok(sc)
    }

    /// The protocol's probing sites (five per region) of this specimen.
    pub fn sites(&self) -> Result<Vec<super::reality::Site>, GapError> {
        let sim = self.simulation(&Variant::default(), self.scene.dt)?;
        Ok(sim
            .probing_sites()
            .iter()
            .filter_map(|s| {
                let region = super::experiment::Region::ALL
                    .into_iter()
                    .find(|r| r.code() == s.region)?;
                Some(super::reality::Site {
                    region,
                    point: [s.point.x, s.point.y, s.point.z],
                    normal: [s.normal.x, s.normal.y, s.normal.z],
                })
            })
            .collect())
    }

    /// A simulation of this scene (for reality generation: probing sites, surface).
    pub fn simulation(&self, v: &Variant, dt: f64) -> Result<Simulation, GapError> {
        Simulation::new(&self.scene_for(v, dt)?, &self.data_dir)
            .map_err(|e| GapError::Sim(e.to_string()))
    }
}

impl ForceModel for SimForceModel {
    fn replay_untilted(&self, v: &Variant, path: &ProbePath) -> Result<Vec<[f64; 3]>, GapError> {
        self.replay_untilted_checked(v, path).map(|r| r.forces)
    }
    fn replay_untilted_checked(&self, v: &Variant, path: &ProbePath) -> Result<Replayed, GapError> {
        let mut sim = self.simulation(v, path.dt)?;
        let mut out = Vec::with_capacity(path.poses.len());
        if let Some(p0) = path.poses.first() {
            sim.teleport_probe(p0);
        }
        for pose in &path.poses {
            sim.set_probe_kinematic(pose);
            sim.step().map_err(|e| GapError::Sim(e.to_string()))?;
            out.push(sim.contact_force());
        }
        // The physics' own per-step checks (force bound, penetration, LCP/CG convergence,
        // energy) decide whether the replay diverged.
        Ok(Replayed {
            forces: out,
            faulty_steps: sim.physics_faults(),
        })
    }
    fn describe(&self) -> String {
        format!(
            "physics_node::sim::Simulation, kinematic probe, mesh {}, {} E scale {}",
            self.scene.meniscus.mesh, self.scene.material.model, self.scene.material.modulus_scale
        )
    }
    fn has_refinement(&self) -> bool {
        self.fine_mesh.is_some()
    }
}
