//! One simulation of meniscus and probe, stepped in SOFA's FreeMotionAnimationLoop order:
//!
//! 1. free motion: FEM implicit step without contact, probe coupled to its proxy (implicit);
//! 2. proximity queries: probe spheres against the refitted boundary surface (side tracked);
//! 3. one constraint per close pair (normal + two tangents), W = W_tissue + W_probe from the
//!    precomputed, rotation-warped compliance;
//! 4. LCP with Coulomb friction (projected block Gauss–Seidel, warm start, `contact-lcp`);
//! 5. corrected motion: δx_tissue = dt R A0⁻¹ Rᵀ Hᵀ λ, probe Δv = M_eff⁻¹ Hᵀ λ.
//!
//! Everything the haptic node needs is left in a [`ContactFrame`] (boxed, filled in place).
//! A step allocates nothing and iterates nothing unordered, so the same inputs give
//! bit-identical outputs.

use crate::compliance::{direction, ComplianceCache, ConstraintCorrection, Filling, RestSolver};
use crate::contact::{ContactDetector, ContactParams, TissueSurface};
use crate::error::PhysicsError;
use crate::fem::{FemModel, FemSettings, Material, RestCompliance, StrainStiffening};
use crate::geometry::ProbingSite;
use crate::probe::{pose_to_nalgebra, Probe};
use launch_config::SceneConfig;
use msgs::physics_to_haptic::ContactFrame;
use msgs::{MAX_CONTACTS, MAX_ROWS};
use nalgebra::{Point3, Vector3};
use std::io::Write;
use std::path::Path;

/// Memory for cached compliance columns before the cache turns lazy, bytes.
const COMPLIANCE_BUDGET_BYTES: usize = 768 << 20;
/// Widest block of columns solved at once when filling the cache.
const BLOCK_COLUMNS: usize = 48;
/// A tissue whose last step moved no node further than this, m, has settled (offline
/// replays only, see [`Simulation::offline`]). At the implicit step's decay of ~0.7 per
/// step, what is left to move is ~3× the last step: 30 nm, under which a tissue of even
/// 10 N/mm changes its force by 0.3 mN, two orders below a probing sensor's noise (the
/// study's: ~0.02 N).
pub const SETTLED_MOTION_M: f64 = 1.0e-8;

/// Adapter: the FEM's rest factorization on reduced (free-dof) vectors of length `dim`
/// (the solver a [`ComplianceCache`] owns).
pub struct RestFactor {
    rest: RestCompliance,
    dim: usize,
}

impl RestFactor {
    pub fn new(rest: RestCompliance) -> RestFactor {
        let dim = cache_dim(&rest);
        RestFactor { rest, dim }
    }
}

impl RestSolver for RestFactor {
    fn dim(&self) -> usize {
        self.dim
    }
    fn solve_block(&mut self, x: &mut [f64], ncols: usize) {
        self.rest.cholesky_mut().solve_block_in_place(x, ncols);
    }
}

/// Wall time spent per phase of the step, accumulated since start (ns): the built-in profile
/// the bench reports.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PhaseTimes {
    /// Collision surface refit and nodal rotations.
    pub prepare_ns: u64,
    /// FEM free motion (assembly + linear solve) and probe free motion.
    pub free_motion_ns: u64,
    /// Proximity queries.
    pub detection_ns: u64,
    /// W assembly (including compliance cache misses).
    pub compliance_ns: u64,
    /// LCP solve.
    pub lcp_ns: u64,
    /// Corrected motion and commit.
    pub correction_ns: u64,
}

/// The material-dependent parts of a simulation, prepared off the real-time loop
/// ([`Simulation::prepare_material`]) and swapped in at a step boundary.
pub struct MaterialParts {
    grade: f64,
    /// Time step the rest factorization (inside the cache's solver) was built for.
    dt: f64,
    fem: FemModel,
    cache: ComplianceCache,
}

impl MaterialParts {
    pub fn grade(&self) -> f64 {
        self.grade
    }
}

/// A meniscus–probe simulation.
pub struct Simulation {
    scene: SceneConfig,
    dt: f64,
    gravity: Vector3<f64>,
    time: f64,
    sequence: u64,
    instance_id: u64,
    device_sequence: u64,
    fem: FemModel,
    cache: ComplianceCache,
    /// Rest positions of every mesh node (the prefetcher's map).
    rest_positions: Vec<Point3<f64>>,
    correction: ConstraintCorrection,
    surface: TissueSurface,
    /// Rigid support under the held inferior surface (bone), if anything is held.
    support: Option<TissueSurface>,
    detector: ContactDetector,
    probe: Probe,
    friction: f64,
    lcp_settings: contact_lcp::Settings,
    frame: Box<ContactFrame>,
    /// Warm start per probe sphere (λ of its last contact).
    warm: Vec<[f64; 3]>,
    lambda: Vec<f64>,
    dx: Vec<f64>,
    external: Vec<Vector3<f64>>,
    prev_rows: usize,
    contact_force: [f64; 3],
    contact_torque: [f64; 3],
    /// Visual model: boundary vertices of the tet mesh (node indices) and compact triangles.
    visual_nodes: Vec<usize>,
    visual_positions: Vec<Point3<f64>>,
    visual_triangles: Vec<[usize; 3]>,
    /// Configured visual surface (replaces the boundary as the visual model).
    visual: Option<crate::visual::VisualModel>,
    sites: Vec<ProbingSite>,
    degeneration_grade: f64,
    /// Haptic instance whose device state drives the probe (0: none / external target).
    device_instance: u64,
    /// `msgs::physics_to_haptic::drive` bits written into the frame.
    drive: u32,
    /// Per-step checks and the last good state.
    monitor: crate::faults::FaultMonitor,
    report: crate::faults::StepReport,
    times: PhaseTimes,
    /// Node rotations divided by √(patch modulus factor): the stiffness-warped compliance
    /// R A0⁻¹ Rᵀ / s of a strain-stiffened tissue (only used when it stiffens).
    warp: Vec<nalgebra::Matrix3<f64>>,
    /// Secant modulus factor of the loaded patch in the last step (1: linear or no contact).
    patch_stiffening: f64,
    /// `[scene.contact] interface_compliance`, m/N (0: hard contact).
    interface_compliance: f64,
    /// Offline replays skip the work of a settled tissue ([`Self::offline`]).
    settled_shortcuts: bool,
    /// The kinematic probe target of the last stepped step (None: no step since a
    /// teleport or a roll-back), and what that step reported to the checks.
    last_target: Option<(Vector3<f64>, nalgebra::UnitQuaternion<f64>)>,
    last_report: crate::faults::StepReport,
    /// Steps the settled shortcuts took: [whole step repeated, free motion at rest].
    settled_steps: [u64; 2],
}

impl Simulation {
    /// Builds the scene: meniscus mesh and fixed set, FE model, rest factorization and
    /// compliance cache, collision surface, probe. A compliance cache that cannot hold the
    /// whole surface is filled inline (deterministic; see [`Self::with_filling`]).
    pub fn new(scene: &SceneConfig, data_dir: &Path) -> Result<Simulation, PhysicsError> {
        Self::with_filling(scene, data_dir, Filling::Inline)
    }

    /// A simulation for offline replays (the gap diagnosis, its self-test and calibration):
    /// compliance columns are solved inline when a surface node is first touched, in a cache
    /// of the smallest size ([`crate::compliance::MIN_SLOTS`] nodes, least recently used
    /// replaced), instead of for every surface node up front. A replay touches a few dozen
    /// nodes; the up-front solve of all of them was 0.2 s of a 1.1 s replay on a 1,435-node
    /// specimen (and ~90 MB), and a diagnosis builds ~135.
    ///
    /// It also skips the work of a settled tissue (its last step moved no node further than
    /// [`SETTLED_MOTION_M`]), 40–60% of a probing's steps. While the probe is held still at
    /// a kinematic target, a step repeats the last one and is not taken. While no contact
    /// force acts on the tissue (the approach, and after release once it has recovered), its
    /// free motion is no motion and is neither assembled nor solved. Forces stay within a
    /// few tenths of a millinewton of the full step's. The live node keeps every step, since
    /// `arthrosim replay` must reproduce its recording bit for bit.
    pub fn offline(scene: &SceneConfig, data_dir: &Path) -> Result<Simulation, PhysicsError> {
        let mut sim = Self::with_compliance(scene, data_dir, Filling::Inline, 0)?;
        sim.settled_shortcuts = true;
        Ok(sim)
    }

    /// Turns the settled shortcuts of [`Self::offline`] on or off (off: every step is
    /// taken in full, as the live node takes it).
    pub fn set_settled_shortcuts(&mut self, on: bool) {
        self.settled_shortcuts = on;
    }

    /// Steps the settled shortcuts of [`Self::offline`] took: (repeated, free motion at rest).
    pub fn settled_steps(&self) -> (u64, u64) {
        (self.settled_steps[0], self.settled_steps[1])
    }

    /// [`Self::new`] with a choice of how a partial compliance cache is filled: the real-time
    /// physics node uses [`Filling::Prefetch`] (no solve inside a step).
    pub fn with_filling(
        scene: &SceneConfig,
        data_dir: &Path,
        filling: Filling,
    ) -> Result<Simulation, PhysicsError> {
        Self::with_compliance(scene, data_dir, filling, COMPLIANCE_BUDGET_BYTES)
    }

    /// [`Self::with_filling`] with the compliance cache's memory budget, bytes (tests use a
    /// small one to exercise a partial cache on a small mesh).
    pub fn with_compliance(
        scene: &SceneConfig,
        data_dir: &Path,
        filling: Filling,
        budget_bytes: usize,
    ) -> Result<Simulation, PhysicsError> {
        if !(scene.dt.is_finite() && scene.dt > 0.0) {
            return Err(PhysicsError::Config(format!(
                "dt must be > 0 s, got {}",
                scene.dt
            )));
        }
        if !scene.gravity.iter().all(|g| g.is_finite()) {
            return Err(PhysicsError::Config("gravity is not finite".into()));
        }
        let c = &scene.contact;
        if !(c.alarm_distance.is_finite()
            && c.contact_distance.is_finite()
            && c.contact_distance >= 0.0)
            || c.alarm_distance < c.contact_distance
        {
            return Err(PhysicsError::Config(format!(
                "contact: need 0 ≤ contact_distance ({}) ≤ alarm_distance ({})",
                c.contact_distance, c.alarm_distance
            )));
        }
        if !(c.interface_compliance.is_finite() && c.interface_compliance >= 0.0) {
            return Err(PhysicsError::Config(format!(
                "contact: interface_compliance must be ≥ 0 m/N, got {}",
                c.interface_compliance
            )));
        }
        if !(c.friction.is_finite() && c.friction >= 0.0) {
            return Err(PhysicsError::Config(format!(
                "contact: friction must be ≥ 0, got {}",
                c.friction
            )));
        }
        if c.max_contacts == 0 || c.max_contacts as usize > MAX_CONTACTS {
            return Err(PhysicsError::Config(format!(
                "contact: max_contacts must be 1..={MAX_CONTACTS}, got {}",
                c.max_contacts
            )));
        }
        if !(c.lcp_tolerance.is_finite() && c.lcp_tolerance >= 0.0) || c.lcp_max_iterations == 0 {
            return Err(PhysicsError::Config(
                "contact: lcp_tolerance ≥ 0 and lcp_max_iterations ≥ 1 needed".into(),
            ));
        }

        let loaded = crate::mesh::load_scene_mesh(&scene.meniscus, data_dir)
            .map_err(|e| PhysicsError::Mesh(e.to_string()))?;
        let mesh = loaded.mesh;
        let fixed = loaded.fixed_nodes;
        let sites = loaded.probing_sites;
        // High-resolution visual surface carried barycentrically by the tets, if configured.
        let visual = match loaded.visual {
            Some(surface) => Some(
                crate::visual::VisualModel::new(&mesh, surface)
                    .map_err(|e| PhysicsError::Mesh(e.to_string()))?,
            ),
            None => None,
        };

        let material =
            Material::from_config(&scene.material).map_err(|e| PhysicsError::Fem(e.to_string()))?;
        let settings =
            FemSettings::from_scene(scene).map_err(|e| PhysicsError::Fem(e.to_string()))?;
        let mut fem = FemModel::new(&mesh, material, &fixed, settings)
            .map_err(|e| PhysicsError::Fem(e.to_string()))?;
        fem.set_stiffening(
            StrainStiffening::new(scene.material.strain_stiffening)
                .map_err(|e| PhysicsError::Fem(e.to_string()))?,
        );
        let rest = fem
            .rest_compliance(scene.dt, BLOCK_COLUMNS)
            .map_err(|e| PhysicsError::Fem(e.to_string()))?;

        let triangles = mesh.boundary_faces();
        fem.set_support_length(support_length(&mesh, &triangles, &fixed));
        let mut surface = TissueSurface::new(triangles.clone(), &mesh.nodes)
            .ok_or_else(|| PhysicsError::Mesh("tet mesh has no boundary surface".into()))?;
        // Support sheet: boundary triangles whose nodes are all held, turned to face the tissue.
        let support_tris: Vec<[usize; 3]> = triangles
            .iter()
            .filter(|t| t.iter().all(|&n| rest.free_index(n).is_none()))
            .map(|t| [t[0], t[2], t[1]])
            .collect();
        let support = TissueSurface::new(support_tris, &mesh.nodes);
        for (flag, t) in surface.rigid.iter_mut().zip(&triangles) {
            *flag = t.iter().all(|&n| rest.free_index(n).is_none());
        }
        let free_index: Vec<u32> = (0..mesh.nodes.len())
            .map(|n| {
                rest.free_index(n)
                    .map_or(crate::compliance::NONE, |i| i as u32)
            })
            .collect();
        let dim = cache_dim(&rest);
        let cache = ComplianceCache::new(
            free_index,
            &surface.nodes,
            &surface.triangles,
            &mesh.nodes,
            Box::new(RestFactor { rest, dim }),
            budget_bytes,
            filling,
        );

        let probe = Probe::new(&scene.probe, c.contact_distance, data_dir)?;
        let params = ContactParams {
            alarm_distance: c.alarm_distance,
            contact_distance: c.contact_distance,
            max_contacts: c.max_contacts as usize,
            hertz_patch: c.hertz_patch,
        };
        let detector = ContactDetector::new(params, probe.spheres.len());

        let mut slot = Box::new(core::mem::MaybeUninit::<ContactFrame>::uninit());
        msgs::Topic::zeroed_in(&mut *slot);
        // SAFETY: zeroed_in initialised the frame (plain old data).
        let mut frame: Box<ContactFrame> =
            unsafe { Box::from_raw(Box::into_raw(slot) as *mut ContactFrame) };
        frame.dt_s = scene.dt;
        frame.friction_mu = c.friction;
        frame.probe_pose = probe.pose();
        frame.probe_free_pose = probe.pose();
        frame.proxy_pose = probe.target_pose();

        let visual_nodes = surface.nodes.clone();
        let mut node_to_visual = vec![usize::MAX; mesh.nodes.len()];
        for (i, &n) in visual_nodes.iter().enumerate() {
            node_to_visual[n] = i;
        }
        let visual_triangles = triangles
            .iter()
            .map(|t| {
                [
                    node_to_visual[t[0]],
                    node_to_visual[t[1]],
                    node_to_visual[t[2]],
                ]
            })
            .collect();
        let visual_positions = visual_nodes.iter().map(|&n| mesh.nodes[n]).collect();

        let n_nodes = mesh.nodes.len();
        let spheres = probe.spheres.len();
        let monitor = crate::faults::FaultMonitor::new(&scene.faults, &fem);
        Ok(Simulation {
            scene: scene.clone(),
            dt: scene.dt,
            gravity: Vector3::from(scene.gravity),
            time: 0.0,
            sequence: 0,
            instance_id: 0,
            device_sequence: 0,
            fem,
            cache,
            rest_positions: mesh.nodes.clone(),
            correction: ConstraintCorrection::new(dim, MAX_CONTACTS),
            surface,
            support,
            detector,
            probe,
            friction: c.friction,
            lcp_settings: contact_lcp::Settings {
                max_iterations: c.lcp_max_iterations,
                tolerance: c.lcp_tolerance,
                deadline: None,
                deadline_check_every: 2,
            },
            frame,
            warm: vec![[0.0; 3]; spheres],
            lambda: vec![0.0; MAX_ROWS],
            dx: vec![0.0; 3 * n_nodes],
            external: vec![Vector3::zeros(); n_nodes],
            prev_rows: 0,
            contact_force: [0.0; 3],
            contact_torque: [0.0; 3],
            visual_nodes,
            visual_positions,
            visual_triangles,
            visual,
            sites,
            degeneration_grade: scene.material.degeneration_grade,
            device_instance: 0,
            drive: 0,
            monitor,
            report: crate::faults::StepReport::default(),
            times: PhaseTimes::default(),
            warp: vec![nalgebra::Matrix3::identity(); n_nodes],
            patch_stiffening: 1.0,
            interface_compliance: c.interface_compliance,
            settled_shortcuts: false,
            last_target: None,
            last_report: crate::faults::StepReport::default(),
            settled_steps: [0; 2],
        })
    }

    /// Device proxy: the probe follows it through the coupling spring.
    pub fn set_proxy_pose(&mut self, pose: &msgs::Pose) {
        if let Some((p, q)) = pose_to_nalgebra(pose) {
            self.probe.set_proxy(p, q);
        }
    }

    /// Prescribed probe pose for the next step (replay of experiments); coupling off.
    pub fn set_probe_kinematic(&mut self, pose: &msgs::Pose) {
        if let Some((p, q)) = pose_to_nalgebra(pose) {
            self.probe.set_kinematic(p, q);
        }
    }

    /// Puts the probe at `pose` at rest (no step), e.g. above a probing site before a run.
    pub fn teleport_probe(&mut self, pose: &msgs::Pose) {
        if let Some((p, q)) = pose_to_nalgebra(pose) {
            self.probe.position = p;
            self.probe.orientation = q;
            self.probe.velocity = Vector3::zeros();
            self.probe.angular_velocity = Vector3::zeros();
            self.probe.free_position = p;
            self.probe.free_orientation = q;
            self.probe.target_position = p;
            self.probe.target_orientation = q;
            self.detector.reset_tracking();
            self.warm.iter_mut().for_each(|w| *w = [0.0; 3]);
            self.last_target = None;
        }
    }

    /// Builds the material-dependent parts of `scene` at degeneration grade `grade` (FE
    /// model, rest factorization, compliance cache): seconds of work and up to the cache
    /// budget of memory, meant for a worker thread. [`Self::swap_material`] puts them in.
    pub fn prepare_material(
        scene: &SceneConfig,
        data_dir: &Path,
        grade: f64,
    ) -> Result<MaterialParts, PhysicsError> {
        if !(grade.is_finite() && (0.0..=2.0).contains(&grade)) {
            return Err(PhysicsError::Config(format!(
                "degeneration grade must be in 0..=2, got {grade}"
            )));
        }
        let mut scene = scene.clone();
        scene.material.degeneration_grade = grade;
        let sim = Simulation::new(&scene, data_dir)?;
        Ok(MaterialParts {
            grade,
            dt: sim.dt,
            fem: sim.fem,
            cache: sim.cache,
        })
    }

    /// Swaps prepared material parts in at a step boundary: the current positions and
    /// velocities move to the new FE model (O(nodes), no allocation), and the old parts come
    /// back, to be dropped off the real-time loop. Parts built for another mesh are refused
    /// and returned as they are.
    // The refused parts are handed back by value so the caller drops them off the loop;
    // boxing them would allocate at every swap.
    #[allow(clippy::result_large_err)]
    pub fn swap_material(
        &mut self,
        mut parts: MaterialParts,
    ) -> Result<MaterialParts, MaterialParts> {
        if parts.fem.node_count() != self.fem.node_count() || parts.dt != self.dt {
            return Err(parts);
        }
        for n in 0..self.fem.node_count() {
            // Only fail for an out-of-range node or a non-finite value: the committed state
            // of a good step is finite.
            let _ = parts.fem.set_position(n, self.fem.positions()[n]);
            let _ = parts.fem.set_velocity(n, self.fem.velocities()[n]);
        }
        std::mem::swap(&mut self.fem, &mut parts.fem);
        std::mem::swap(&mut self.cache, &mut parts.cache);
        std::mem::swap(&mut self.degeneration_grade, &mut parts.grade);
        self.scene.material.degeneration_grade = self.degeneration_grade;
        Ok(parts)
    }

    /// The degeneration grade in use.
    pub fn degeneration_grade(&self) -> f64 {
        self.degeneration_grade
    }

    /// Records which device state drove this step (published in the frame).
    pub fn set_device_sequence(&mut self, sequence: u64) {
        self.device_sequence = sequence;
    }

    /// Records which device sample (haptic instance and tick) drives the next step; the
    /// haptic node renders only frames computed for its own samples.
    pub fn set_device_sample(&mut self, instance: u64, sequence: u64) {
        self.device_instance = instance;
        self.device_sequence = sequence;
        self.drive &= !msgs::physics_to_haptic::drive::EXTERNAL_TARGET;
    }

    /// The probe follows an external target (not a device) from the next step on: frames
    /// say so and name no device sample, so no haptic node renders them.
    pub fn set_external_drive(&mut self) {
        self.device_instance = 0;
        self.device_sequence = 0;
        self.drive |= msgs::physics_to_haptic::drive::EXTERNAL_TARGET;
    }

    /// Faulty steps since start (each one flagged, rolled back and not rendered).
    pub fn physics_faults(&self) -> u64 {
        self.monitor.faulty_steps
    }

    /// Instance id written into every frame.
    pub fn set_instance_id(&mut self, id: u64) {
        self.instance_id = id;
        self.frame.instance_id = id;
    }

    /// One FreeMotionAnimationLoop step, checked. Allocation-free. A step that fails a check
    /// (see [`crate::faults`]) or errors numerically is still published, with its
    /// `physics_faults` bits set, and the state is rolled back; it returns `Ok` (survived).
    pub fn step(&mut self) -> Result<(), PhysicsError> {
        use msgs::physics_to_haptic::{drive, physics_fault};
        self.report = crate::faults::StepReport {
            lcp_converged: true,
            ..Default::default()
        };
        let (faults, errored) = match self.advance() {
            Ok(()) => (self.monitor.check(&self.report, &mut self.fem), false),
            Err(PhysicsError::Numerical { detail, .. }) => {
                self.monitor.note_numerical(&detail);
                (physics_fault::NUMERICAL, true)
            }
            Err(e) => return Err(e),
        };
        let frame = &mut *self.frame;
        frame.physics_faults = faults;
        frame.drive = self.drive;
        if faults == 0 {
            self.monitor.commit_good(&self.fem, &self.probe);
            return Ok(());
        }
        if errored {
            // The step stopped midway: close it so time and sequence still advance, with no
            // contact problem a consumer could use.
            frame.contact_count = 0;
            frame.row_count = 0;
            self.close_step_header();
        }
        self.monitor
            .roll_back(faults, self.time, &mut self.fem, &mut self.probe);
        self.warm.iter_mut().for_each(|w| *w = [0.0; 3]);
        self.last_target = None;
        self.frame.drive |= drive::ROLLED_BACK;
        Ok(())
    }

    /// The unchecked step.
    fn advance(&mut self) -> Result<(), PhysicsError> {
        let dt = self.dt;
        let settled = self.settled_shortcuts && self.fem.last_step_motion() < SETTLED_MOTION_M;
        if settled
            && self.probe.drive == crate::probe::ProbeDrive::Kinematic
            && self.last_target == Some((self.probe.target_position, self.probe.target_orientation))
        {
            // Probe held where it was and the tissue settled around it: the step is its
            // own fixed point (same contacts, same λ, same force).
            self.repeat_settled_step();
            return Ok(());
        }
        let clock = std::time::Instant::now();
        let lap = |acc: &mut u64, last: &mut std::time::Instant| {
            let now = std::time::Instant::now();
            *acc += (now - *last).as_nanos() as u64;
            *last = now;
        };
        let mut last = clock;
        // Start-of-step geometry: collision surface and nodal rotations of the committed state.
        self.surface.refit(self.fem.positions());
        self.fem.update_node_rotations();
        self.cache.prefetch(&self.probe);
        lap(&mut self.times.prepare_ns, &mut last);

        // 1. Free motion (none for a settled tissue that no contact force acts on: the
        // external forces of an offline replay are zero).
        if settled && self.contact_force == [0.0; 3] {
            self.fem.free_motion_at_rest(dt);
            self.settled_steps[1] += 1;
        } else {
            let cg =
                self.fem
                    .free_motion(dt, &self.external)
                    .map_err(|e| PhysicsError::Numerical {
                        time: self.time,
                        detail: e.to_string(),
                    })?;
            self.report.cg_residual = cg.relative_residual;
        }
        self.probe.free_motion(dt, &self.gravity);
        lap(&mut self.times.free_motion_ns, &mut last);

        // 2. Proximity queries.
        let x0 = self.fem.positions();
        let xf = self.fem.free_positions();
        let mut motion: f64 = 0.0;
        for &n in &self.surface.nodes {
            motion = motion.max((xf[n] - x0[n]).norm());
        }
        self.detector.detect(
            &self.probe,
            &self.surface,
            self.support.as_ref(),
            x0,
            xf,
            &self.rest_positions,
            motion,
        );
        // A kinematic probe against held nodes only is a rigid–rigid contact: nothing can
        // move to resolve it (W = 0), so it carries no constraint.
        if self.probe.drive == crate::probe::ProbeDrive::Kinematic {
            let cache = &self.cache;
            let ContactDetector {
                contacts, patches, ..
            } = &mut self.detector;
            contacts.retain(|c| {
                c.spread(patches)
                    .any(|(n, w)| w > 1e-9 && cache.free_index(n) != crate::compliance::NONE)
            });
        }
        lap(&mut self.times.detection_ns, &mut last);
        let contacts = &self.detector.contacts;
        let m = contacts.len();
        let rows = 3 * m;

        // 3. Constraint rows and compliance.
        let frame = &mut *self.frame;
        for r in 0..self.prev_rows {
            frame.compliance[r * MAX_ROWS..r * MAX_ROWS + self.prev_rows].fill(0.0);
        }
        self.prev_rows = rows;
        // The contact compliance is the rest compliance warped by the node rotations and, for
        // a strain-stiffening tissue, divided by the secant modulus factor of the loaded
        // patch: with the probe moving quasi-statically the free motion relaxes the tissue
        // almost completely (mg nodal masses against kN/m), so the contact force is W⁻¹ times
        // the violation and the stiffening has to be in W. One factor for the patch (the
        // mean node factor under the contacts, weighted by their free penetration) scales
        // W and the tissue correction alike, so the deformed shape stays the rest response.
        //
        // A stiffening elastic support (see `fem::stiffening`) is in series with the tissue:
        // W = W_support / f_support + W_tissue / f_tissue. The share of the support in the
        // patch's compliance is the share of the patch's displacement that is the support's
        // (largest support displacement over the patch's mean displacement), so the factor
        // is 1 / (α / f_support + (1 − α) / f_tissue).
        let rotations = if self.fem.stiffening().is_active() {
            let factors = self.fem.node_stiffening();
            let x = self.fem.positions();
            let (mut sum, mut weight, mut moved) = (0.0, 0.0, 0.0);
            for c in contacts.iter() {
                let w = (-c.free_violation[0]).max(0.0);
                for (n, wn) in c.spread(&self.detector.patches) {
                    sum += w * wn * factors[n];
                    moved += w * wn * (x[n] - self.rest_positions[n]).norm();
                    weight += w * wn;
                }
            }
            let tissue = if weight > 0.0 { sum / weight } else { 1.0 };
            let (support_u, support_factor) = self.fem.support_hardening();
            let share = if weight > 0.0 && moved > 0.0 {
                (support_u / (moved / weight)).min(1.0)
            } else {
                0.0
            };
            let patch = 1.0 / (share / support_factor + (1.0 - share) / tissue);
            self.patch_stiffening = patch;
            let inv_sqrt = 1.0 / patch.sqrt();
            for (w, r) in self.warp.iter_mut().zip(self.fem.node_rotations()) {
                *w = r * inv_sqrt;
            }
            &self.warp[..]
        } else {
            self.fem.node_rotations()
        };
        if m > 0 {
            self.correction.assemble(
                contacts,
                &self.detector.patches,
                &mut self.cache,
                rotations,
                &self.probe,
                dt,
                &mut frame.compliance,
                MAX_ROWS,
            );
            // A penalty interface in series with the tissue: each probe ball yields along a
            // contact normal by the interface compliance times its contacts' total normal
            // force along it (one layer per ball, however many points its touch was
            // discretised into), so the LCP leaves that much penetration. λ is an impulse
            // (force × dt), so the compliance enters W over dt.
            let c = self.interface_compliance / dt;
            if c > 0.0 {
                for (k, a) in contacts.iter().enumerate() {
                    for (l, b) in contacts.iter().enumerate() {
                        if a.sphere == b.sphere {
                            frame.compliance[3 * k * MAX_ROWS + 3 * l] +=
                                c * a.normal.dot(&b.normal);
                        }
                    }
                }
            }
        }
        for (k, c) in contacts.iter().enumerate() {
            let arm = self.probe.arm_free(c.sphere);
            for j in 0..3 {
                let d = direction(c, j);
                let ang = arm.cross(&d);
                frame.constraint_directions[3 * k + j] = [d.x, d.y, d.z, ang.x, ang.y, ang.z];
                frame.free_violation[3 * k + j] = c.free_violation[j];
                self.lambda[3 * k + j] = self.warm[c.sphere][j];
            }
            frame.contact_points[k] = [c.point.x, c.point.y, c.point.z];
        }

        lap(&mut self.times.compliance_ns, &mut last);
        // 4. LCP.
        let mut iterations = 0;
        let mut residual = 0.0;
        if m > 0 {
            let problem = contact_lcp::Problem {
                compliance: &frame.compliance,
                free_violation: &frame.free_violation,
                friction_mu: self.friction,
                row_count: rows,
            };
            match contact_lcp::solve(&problem, &mut self.lambda[..rows], &self.lcp_settings) {
                Ok(sol) => {
                    iterations = sol.iterations;
                    residual = sol.residual;
                    self.report.lcp_converged = sol.converged;
                    self.report.penetration = crate::faults::corrected_penetration(
                        &frame.compliance,
                        &frame.free_violation,
                        &self.lambda,
                        rows,
                    );
                }
                Err(e) => {
                    return Err(PhysicsError::Numerical {
                        time: self.time,
                        detail: format!("contact LCP: {e}"),
                    })
                }
            }
        }
        for w in self.warm.iter_mut() {
            *w = [0.0; 3];
        }
        for (k, c) in contacts.iter().enumerate() {
            self.warm[c.sphere] = [
                self.lambda[3 * k],
                self.lambda[3 * k + 1],
                self.lambda[3 * k + 2],
            ];
        }

        lap(&mut self.times.lcp_ns, &mut last);
        // 5. Corrected motion.
        let mut impulse = Vector3::zeros();
        let mut angular = Vector3::zeros();
        for r in 0..rows {
            let h = &frame.constraint_directions[r];
            impulse += Vector3::new(h[0], h[1], h[2]) * self.lambda[r];
            angular += Vector3::new(h[3], h[4], h[5]) * self.lambda[r];
        }
        let probe_free_pose = self.probe.free_pose();
        let proxy_pose = self.probe.target_pose();
        let target = (self.probe.target_position, self.probe.target_orientation);
        self.probe.commit(dt, &impulse, &angular);
        if m > 0
            && self.correction.tissue_displacement(
                contacts,
                &self.cache,
                rotations,
                &self.lambda[..rows],
                dt,
                &mut self.dx,
            )
        {
            self.fem
                .apply_correction_full(&self.dx)
                .map_err(|e| PhysicsError::Numerical {
                    time: self.time,
                    detail: e.to_string(),
                })?;
        }
        self.fem.commit();
        lap(&mut self.times.correction_ns, &mut last);

        let force = impulse / dt;
        let torque = angular / dt;
        if !(force.iter().all(|v| v.is_finite())
            && self.probe.position.iter().all(|v| v.is_finite()))
        {
            // Before time and sequence advance: the errored step is closed by `step`, once.
            return Err(PhysicsError::Numerical {
                time: (self.sequence + 1) as f64 * dt,
                detail: "non-finite contact force or probe position".into(),
            });
        }
        self.time = (self.sequence + 1) as f64 * dt;
        self.sequence += 1;
        self.contact_force = [force.x, force.y, force.z];
        self.contact_torque = [torque.x, torque.y, torque.z];
        self.report.contacts = m;
        self.report.force = self.contact_force;
        self.last_report = self.report;
        self.last_target = Some(target);

        // Frame header and results.
        frame.instance_id = self.instance_id;
        frame.sequence = self.sequence;
        frame.sim_time_s = self.time;
        frame.dt_s = dt;
        frame.contact_count = m as u32;
        frame.row_count = rows as u32;
        frame.friction_mu = self.friction;
        frame.lcp_iterations = iterations;
        frame.lcp_residual = residual;
        frame.device_sequence_used = self.device_sequence;
        frame.device_instance_used = self.device_instance;
        frame.proxy_pose = proxy_pose;
        frame.probe_free_pose = probe_free_pose;
        frame.probe_pose = self.probe.pose();
        frame.lambda[..rows].copy_from_slice(&self.lambda[..rows]);
        frame.lambda[rows..].fill(0.0);
        frame.contact_force = self.contact_force;
        frame.contact_torque = self.contact_torque;

        // Visual model follows the nodes.
        let x = self.fem.positions();
        match &mut self.visual {
            Some(v) => v.update(x),
            None => {
                for (dst, &n) in self.visual_positions.iter_mut().zip(&self.visual_nodes) {
                    *dst = x[n];
                }
            }
        }
        Ok(())
    }

    /// A step of a settled tissue under a probe held at the last step's target: time and
    /// the frame's header advance, everything else is the last step's.
    fn repeat_settled_step(&mut self) {
        self.report = self.last_report;
        self.close_step_header();
        self.settled_steps[0] += 1;
    }

    /// Time and sequence advance by one step and the frame's header says so, for a step that
    /// left the rest of the frame as it was (repeated) or emptied it (errored midway).
    fn close_step_header(&mut self) {
        self.time = (self.sequence + 1) as f64 * self.dt;
        self.sequence += 1;
        let frame = &mut *self.frame;
        frame.instance_id = self.instance_id;
        frame.sequence = self.sequence;
        frame.sim_time_s = self.time;
        frame.dt_s = self.dt;
        frame.device_sequence_used = self.device_sequence;
        frame.device_instance_used = self.device_instance;
    }

    /// Secant modulus factor the contact compliance of the last step was divided by (1 for
    /// a linear tissue or without contact).
    pub fn patch_stiffening(&self) -> f64 {
        self.patch_stiffening
    }

    pub fn contact_frame(&self) -> &ContactFrame {
        &self.frame
    }

    /// Eq. (1): Hᵀλ/dt on the probe, world frame, N.
    pub fn contact_force(&self) -> [f64; 3] {
        self.contact_force
    }

    /// The contacts of the last step (probe sphere, triangle, normal, gaps).
    pub fn contacts(&self) -> &[crate::contact::Contact] {
        &self.detector.contacts
    }

    pub fn contact_count(&self) -> usize {
        self.detector.contacts.len()
    }

    pub fn probe_pose(&self) -> msgs::Pose {
        self.probe.pose()
    }

    pub fn time(&self) -> f64 {
        self.time
    }

    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// Visual model vertices, world m.
    pub fn surface_positions(&self) -> &[Point3<f64>] {
        match &self.visual {
            Some(v) => &v.positions,
            None => &self.visual_positions,
        }
    }

    /// Visual model triangles, counter-clockwise seen from outside.
    pub fn surface_triangles(&self) -> &[[usize; 3]] {
        match &self.visual {
            Some(v) => &v.surface.triangles,
            None => &self.visual_triangles,
        }
    }

    pub fn probing_sites(&self) -> &[ProbingSite] {
        &self.sites
    }

    pub fn node_count(&self) -> usize {
        self.fem.node_count()
    }

    pub fn tet_count(&self) -> usize {
        self.fem.tet_count()
    }

    /// The FE model (read access for diagnostics and tests).
    pub fn fem(&self) -> &FemModel {
        &self.fem
    }

    /// The probe (read access).
    pub fn probe(&self) -> &Probe {
        &self.probe
    }

    /// Compliance cache misses so far: nodes a step needed that were not cached (inline
    /// filling: each one 3-column solve inside the step; prefetch: each one approximated).
    pub fn compliance_misses(&self) -> u64 {
        self.cache.misses
    }

    /// Contacts whose tissue compliance was approximated so far (prefetch filling: a node
    /// of the contact was not cached yet).
    pub fn compliance_approximations(&self) -> u64 {
        self.cache.approximated
    }

    /// Surface nodes whose compliance is cached now.
    pub fn compliance_cached_nodes(&self) -> usize {
        self.cache.cached_nodes()
    }

    /// Waits (set-up, not the real-time loop) until the prefetcher has cached the surface
    /// around the probe's current pose and target; true when it did within `timeout`.
    pub fn wait_compliance_prefetched(&mut self, timeout: std::time::Duration) -> bool {
        self.cache.wait_prefetched(&self.probe, timeout)
    }

    /// The inputs a new [`ComplianceCache`] for this scene needs besides its solver and
    /// free rows: surface nodes, surface triangles and rest positions (to build one off the
    /// real-time loop).
    pub fn compliance_layout(&self) -> (&[usize], &[[usize; 3]], &[Point3<f64>]) {
        (
            &self.surface.nodes,
            &self.surface.triangles,
            &self.rest_positions,
        )
    }

    /// Swaps in a compliance cache built elsewhere (e.g. on a worker thread after a material
    /// change) and returns the old one. Cheap: the caller drops the old one off the loop.
    pub fn swap_compliance(&mut self, cache: ComplianceCache) -> ComplianceCache {
        std::mem::replace(&mut self.cache, cache)
    }

    /// Total mechanical energy, J: tissue (elastic, kinetic, gravity) + probe (kinetic,
    /// gravity, coupling spring). Without input it must not grow.
    pub fn energy(&mut self) -> f64 {
        let g = self.gravity;
        let tissue =
            self.fem.elastic_energy() + self.fem.kinetic_energy() + self.fem.gravity_energy();
        let probe_gravity = -self.probe.mass() * g.dot(&self.probe.position);
        let coupling = match self.probe.drive {
            crate::probe::ProbeDrive::Coupled => self.probe.coupling_energy(),
            crate::probe::ProbeDrive::Kinematic => 0.0,
        };
        tissue + self.probe.kinetic_energy() + probe_gravity + coupling
    }

    /// Accumulated wall time per phase of the step.
    pub fn phase_times(&self) -> PhaseTimes {
        self.times
    }

    /// Number of cache slots and whether the whole surface is cached.
    pub fn compliance_cache_info(&self) -> (usize, bool) {
        (self.cache.slots(), self.cache.complete)
    }
}

fn cache_dim(rest: &RestCompliance) -> usize {
    3 * (0..rest.node_count())
        .filter(|&n| rest.free_index(n).is_some())
        .count()
}

/// Contact-force CSV export: `time_s,fx_n,fy_n,fz_n,contacts,px_m,py_m,pz_m,qx,qy,qz,qw`.
pub struct ContactForceCsv {
    out: std::io::BufWriter<std::fs::File>,
}

impl ContactForceCsv {
    pub const HEADER: &'static str = "time_s,fx_n,fy_n,fz_n,contacts,px_m,py_m,pz_m,qx,qy,qz,qw";

    pub fn create(path: &Path) -> std::io::Result<ContactForceCsv> {
        let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
        writeln!(out, "{}", Self::HEADER)?;
        Ok(ContactForceCsv { out })
    }

    /// Appends the current step of `sim`.
    pub fn write(&mut self, sim: &Simulation) -> std::io::Result<()> {
        let f = sim.contact_force();
        let p = sim.probe_pose();
        writeln!(
            self.out,
            "{:.6},{:.9},{:.9},{:.9},{},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9}",
            sim.time(),
            f[0],
            f[1],
            f[2],
            sim.contact_count(),
            p.position[0],
            p.position[1],
            p.position[2],
            p.orientation[0],
            p.orientation[1],
            p.orientation[2],
            p.orientation[3]
        )
    }

    pub fn flush(&mut self) -> std::io::Result<()> {
        self.out.flush()
    }
}

/// Mean thickness of the body above its support: tet volume over the area of the boundary
/// triangles whose three nodes are all in `fixed`, m (0 without such a triangle). The
/// stiffening law reads a support displacement over this length as a strain.
fn support_length(mesh: &crate::mesh::TetMesh, triangles: &[[usize; 3]], fixed: &[usize]) -> f64 {
    let mut is_fixed = vec![false; mesh.nodes.len()];
    for &i in fixed {
        if let Some(f) = is_fixed.get_mut(i) {
            *f = true;
        }
    }
    let area: f64 = triangles
        .iter()
        .filter(|t| t.iter().all(|&n| is_fixed[n]))
        .map(|t| {
            let [a, b, c] = t.map(|n| mesh.nodes[n]);
            0.5 * (b - a).cross(&(c - a)).norm()
        })
        .sum();
    let volume: f64 = mesh
        .tets
        .iter()
        .map(|t| {
            let [a, b, c, d] = t.map(|n| mesh.nodes[n]);
            ((b - a).cross(&(c - a)).dot(&(d - a)) / 6.0).abs()
        })
        .sum();
    if area > 0.0 {
        volume / area
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use msgs::physics_to_haptic::physics_fault;

    /// A step whose contact force or probe position came out non-finite used to advance the
    /// sequence twice (once in `advance`, before its last check, and once more when the
    /// errored step was closed): the haptic node saw a frame missing that was never sent.
    #[test]
    fn a_non_finite_step_does_not_skip_a_sequence_number() {
        let scene = launch_config::SceneConfig::default();
        let mut sim = Simulation::new(&scene, &launch_config::data_dir()).unwrap();
        sim.step().unwrap();
        let before = sim.frame.sequence;
        sim.probe.velocity = Vector3::new(f64::NAN, 0.0, 0.0);
        sim.step().unwrap();
        assert_ne!(sim.frame.physics_faults & physics_fault::NUMERICAL, 0);
        assert_eq!(sim.frame.sequence, before + 1);
        assert!((sim.frame.sim_time_s - (before + 1) as f64 * sim.dt).abs() < 1e-12);
        sim.step().unwrap();
        assert_eq!(sim.frame.sequence, before + 2);
    }
}
