//! Building the FE model, its state and accessors, material changes and reset.

use super::*;

impl FemModel {
    /// Builds the model. `fixed` are held in place, or supported by springs when
    /// `settings.support_stiffness > 0`.
    pub fn new(
        mesh: &TetMesh,
        material: Material,
        fixed: &[usize],
        settings: FemSettings,
    ) -> Result<Self, FemError> {
        material.validate()?;
        settings.validate()?;
        let n = mesh.nodes.len();
        if n == 0 || mesh.tets.is_empty() {
            return Err(FemError::Mesh(format!(
                "mesh has {n} nodes and {} tets; need at least one tet",
                mesh.tets.len()
            )));
        }
        for (i, p) in mesh.nodes.iter().enumerate() {
            if !p.iter().all(|c| c.is_finite()) {
                return Err(FemError::Mesh(format!(
                    "node {i} has a non-finite coordinate"
                )));
            }
        }
        let mut rest_elems = Vec::with_capacity(mesh.tets.len());
        let mut mass = vec![0.0; n];
        for (e, t) in mesh.tets.iter().enumerate() {
            if let Some(&bad) = t.iter().find(|&&i| i >= n) {
                return Err(FemError::Mesh(format!(
                    "tet {e} refers to node {bad}, but the mesh has {n} nodes"
                )));
            }
            let r = TetRest::new([
                &mesh.nodes[t[0]],
                &mesh.nodes[t[1]],
                &mesh.nodes[t[2]],
                &mesh.nodes[t[3]],
            ])
            .ok_or_else(|| {
                FemError::Mesh(format!(
                    "tet {e} {t:?} has zero or negative volume (orient tets positively)"
                ))
            })?;
            for &i in t {
                mass[i] += material.density * r.volume / 4.0;
            }
            rest_elems.push(r);
        }
        let mut held = vec![false; n];
        let mut support = vec![0.0; n];
        for &i in fixed {
            if i >= n {
                return Err(FemError::Input(format!(
                    "fixed node {i} out of range (mesh has {n} nodes)"
                )));
            }
            if settings.support_stiffness > 0.0 {
                support[i] = settings.support_stiffness;
            } else {
                held[i] = true;
            }
        }
        let mut free_index = vec![NO_BLOCK; n];
        let mut free_nodes = Vec::new();
        for i in 0..n {
            // A node in no tet has no mass: hold it so the system stays definite.
            if !held[i] && mass[i] > 0.0 {
                free_index[i] = free_nodes.len() as u32;
                free_nodes.push(i);
            }
        }
        let nf = free_nodes.len();
        let (pattern, elem_blocks) = BlockPattern::from_tets(&free_index, nf, &mesh.tets);
        let nnz = pattern.nnz_blocks();
        let upper32 = UpperF32::new(&pattern);
        let upper_scatter = upper32.scatter(&pattern, &free_index, &mesh.tets, &elem_blocks);
        let (mu, lambda) = material.lame();
        let stiffening = StiffeningState::new(StrainStiffening::NONE, &mesh.tets, &rest_elems, n);
        let mut model = FemModel {
            material,
            mu,
            lambda,
            settings,
            tets: mesh.tets.clone(),
            rest_elems,
            rest: mesh.nodes.clone(),
            x: mesh.nodes.clone(),
            v: vec![Vector3::zeros(); n],
            x_free: mesh.nodes.clone(),
            v_free: vec![Vector3::zeros(); n],
            mass,
            support_rest: support.clone(),
            support,
            support_length: 0.0,
            free_index,
            free_nodes,
            elem_rot: vec![UnitQuaternion::identity(); mesh.tets.len()],
            elem_rot_m: vec![Matrix3::identity(); mesh.tets.len()],
            node_rot_q: vec![UnitQuaternion::identity(); n],
            node_rot: vec![Matrix3::identity(); n],
            node_rot_sum: vec![Matrix3::zeros(); n],
            pattern,
            elem_blocks,
            upper_scatter,
            a: vec![Matrix3::zeros(); nnz],
            upper32,
            elem_rot_k: vec![Matrix3::identity(); mesh.tets.len()],
            upper32_k_scale: f64::NAN,
            upper32_age: 0,
            stiffness_updates: 0,
            jacobi: vec![Matrix3::zeros(); nf],
            force: vec![Vector3::zeros(); n],
            rhs: vec![0.0; 3 * nf],
            dv: vec![0.0; 3 * nf],
            r: vec![0.0; 3 * nf],
            p: vec![0.0; 3 * nf],
            q: vec![0.0; 3 * nf],
            z: vec![0.0; 3 * nf],
            rest_factor: None,
            direct: None,
            refactor_lagged: true,
            last_dt: settings.dt,
            last_stats: SolveStats::default(),
            last_motion: f64::INFINITY,
            stiffening,
        };
        model.prepare_solver()?;
        Ok(model)
    }

    /// Builds whatever factorization the chosen solver needs (allocates; not in the step).
    pub(super) fn prepare_solver(&mut self) -> Result<(), FemError> {
        if self.free_nodes.is_empty() {
            return Ok(());
        }
        match self.settings.solver {
            LinearSolver::Cg {
                preconditioner: Preconditioner::RestCholesky | Preconditioner::WarpedRestCholesky,
                ..
            } => {
                let dt = self.settings.dt;
                self.assemble_rest_system(dt);
                self.rest_factor = Some((dt, SparseCholesky::new(&self.pattern, &self.a, 1)?));
            }
            solver if solver.factors_current_system() => {
                let dt = self.settings.dt;
                self.assemble_rest_system(dt);
                // The lagged factor only preconditions a CG run to its tolerance in f64, so f32
                // is enough there; the direct solver's factor is the solve itself.
                let precision = match solver {
                    LinearSolver::Direct => FactorPrecision::F64,
                    _ => FactorPrecision::F32,
                };
                self.direct = Some(SparseCholesky::with_precision(
                    &self.pattern,
                    &self.a,
                    1,
                    precision,
                )?);
                self.refactor_lagged = true;
            }
            _ => {}
        }
        Ok(())
    }

    // ---- accessors -------------------------------------------------------------------

    pub fn material(&self) -> &Material {
        &self.material
    }
    pub fn settings(&self) -> &FemSettings {
        &self.settings
    }
    pub fn node_count(&self) -> usize {
        self.x.len()
    }
    pub fn tet_count(&self) -> usize {
        self.tets.len()
    }
    pub fn tets(&self) -> &[[usize; 4]] {
        &self.tets
    }
    /// Committed positions, m.
    pub fn positions(&self) -> &[Point3<f64>] {
        &self.x
    }
    /// Committed velocities, m/s.
    pub fn velocities(&self) -> &[Vector3<f64>] {
        &self.v
    }
    /// Rest positions, m.
    pub fn rest_positions(&self) -> &[Point3<f64>] {
        &self.rest
    }
    /// Free-motion (plus applied corrections) positions of the step in progress.
    pub fn free_positions(&self) -> &[Point3<f64>] {
        &self.x_free
    }
    pub fn free_velocities(&self) -> &[Vector3<f64>] {
        &self.v_free
    }
    /// Lumped nodal masses, kg.
    pub fn masses(&self) -> &[f64] {
        &self.mass
    }
    /// Free (simulated) row of a node in the reduced system, None when held.
    pub fn free_index(&self, node: usize) -> Option<usize> {
        match self.free_index.get(node) {
            Some(&i) if i != NO_BLOCK => Some(i as usize),
            _ => None,
        }
    }
    /// Nodes in the reduced system, in row order.
    pub fn free_nodes(&self) -> &[usize] {
        &self.free_nodes
    }
    pub fn is_held(&self, node: usize) -> bool {
        self.free_index(node).is_none()
    }
    /// Elements whose stiffness blocks the last step wrote: in the packed CG matrix those
    /// that turned (all on a rebuild; see [`FemSettings::stiffness_rotation_tolerance`]),
    /// in a factored solver's f64 system every one; 0 where the material is not corotational.
    pub fn stiffness_updates(&self) -> usize {
        self.stiffness_updates
    }

    /// Statistics of the last linear solve.
    pub fn last_solve(&self) -> SolveStats {
        self.last_stats
    }
    /// Block pattern of the reduced system.
    pub fn pattern(&self) -> &BlockPattern {
        &self.pattern
    }

    /// Replaces the material (e.g. a new degeneration grade between probings). Same model
    /// kind keeps all factorizations' patterns; rest factors are rebuilt (allocates).
    pub fn set_material(&mut self, material: Material) -> Result<(), FemError> {
        material.validate()?;
        // Lumped mass follows density.
        let scale = material.density / self.material.density;
        for m in &mut self.mass {
            *m *= scale;
        }
        self.material = material;
        let (mu, lambda) = material.lame();
        self.mu = mu;
        self.lambda = lambda;
        self.upper32_k_scale = f64::NAN;
        self.last_motion = f64::INFINITY;
        self.prepare_solver()
    }

    /// Support spring stiffness of every supported node at rest, N/m (a degeneration grade
    /// scales it with the modulus). Refactors like [`Self::set_material`].
    pub fn set_support_stiffness(&mut self, stiffness: f64) -> Result<(), FemError> {
        if !(stiffness.is_finite() && stiffness > 0.0) {
            return Err(FemError::Input(format!(
                "support stiffness must be finite and > 0 N/m, got {stiffness}"
            )));
        }
        for (k, s) in self.support_rest.iter_mut().zip(self.support.iter_mut()) {
            if *k > 0.0 {
                *k = stiffness;
                *s = stiffness;
            }
        }
        self.stiffening.support_factor = 1.0;
        self.stiffening.support_displacement = 0.0;
        self.upper32_k_scale = f64::NAN;
        self.last_motion = f64::INFINITY;
        self.prepare_solver()
    }

    /// Sets the length over which a support displacement is a strain for the stiffening law
    /// (the body's mean thickness above its support), m.
    pub fn set_support_length(&mut self, length: f64) {
        self.support_length = if length.is_finite() && length > 0.0 {
            length
        } else {
            0.0
        };
        self.last_motion = f64::INFINITY;
    }

    /// Length over which a support displacement is a strain, m (0: not set).
    pub fn support_length(&self) -> f64 {
        self.support_length
    }

    /// Largest support displacement of the committed state at the last `free_motion`, m,
    /// and the support's stiffening factor at it (1 with the linear law or no support).
    pub fn support_hardening(&self) -> (f64, f64) {
        (
            self.stiffening.support_displacement,
            self.stiffening.support_factor,
        )
    }

    /// Sets the strain-stiffening law (see [`StrainStiffening`]); the factors follow from the
    /// next step's committed state.
    pub fn set_stiffening(&mut self, law: StrainStiffening) {
        self.stiffening.law = law;
        self.stiffening.reset();
        self.support.copy_from_slice(&self.support_rest);
        self.upper32_k_scale = f64::NAN;
        self.last_motion = f64::INFINITY;
    }

    pub fn stiffening(&self) -> StrainStiffening {
        self.stiffening.law
    }

    /// Modulus factor per node (volume-weighted mean of its elements') of the committed state
    /// at the last `free_motion`; all 1 with the linear law.
    pub fn node_stiffening(&self) -> &[f64] {
        &self.stiffening.node
    }

    /// Modulus factor per element at the last `free_motion`.
    pub fn element_stiffening(&self) -> &[f64] {
        &self.stiffening.elem
    }

    /// Sets a node's committed position (kinematic held nodes, test set-ups) and free position.
    pub fn set_position(&mut self, node: usize, p: Point3<f64>) -> Result<(), FemError> {
        if node >= self.x.len() || !p.iter().all(|c| c.is_finite()) {
            return Err(FemError::Input(format!(
                "set_position: bad node {node} or position"
            )));
        }
        self.x[node] = p;
        self.x_free[node] = p;
        self.last_motion = f64::INFINITY;
        Ok(())
    }

    /// Sets a free node's committed velocity.
    pub fn set_velocity(&mut self, node: usize, v: Vector3<f64>) -> Result<(), FemError> {
        if node >= self.x.len() || !v.iter().all(|c| c.is_finite()) {
            return Err(FemError::Input(format!(
                "set_velocity: bad node {node} or velocity"
            )));
        }
        if self.free_index(node).is_some() {
            self.v[node] = v;
            self.v_free[node] = v;
        }
        self.last_motion = f64::INFINITY;
        Ok(())
    }

    /// Back to rest: positions, velocities, rotations and warm start reset.
    pub fn reset(&mut self) {
        self.x.copy_from_slice(&self.rest);
        self.x_free.copy_from_slice(&self.rest);
        self.v.fill(Vector3::zeros());
        self.v_free.fill(Vector3::zeros());
        self.elem_rot.fill(UnitQuaternion::identity());
        self.elem_rot_m.fill(Matrix3::identity());
        self.node_rot_q.fill(UnitQuaternion::identity());
        self.node_rot.fill(Matrix3::identity());
        self.dv.fill(0.0);
        self.upper32_k_scale = f64::NAN;
        self.stiffening.reset();
        self.support.copy_from_slice(&self.support_rest);
        self.last_motion = f64::INFINITY;
    }

    /// Largest node displacement of the last committed step, m (infinite before the first
    /// one and after the state or the material was set from outside). A tissue that moved
    /// less than a few nanometres in its last step has settled: its next free motion is
    /// nothing but that step's decaying remainder.
    pub fn last_step_motion(&self) -> f64 {
        self.last_motion
    }

    // ---- assembly --------------------------------------------------------------------

    /// The CG system lives in `upper32` (f32), not in the upper triangle of `a`.
    pub(super) fn packed_cg_matrix(&self) -> bool {
        // a factored solver's CG reads the full f64 system its factor is built from
        matches!(self.settings.solver, LinearSolver::Cg { .. })
            && !self.settings.solver.factors_current_system()
            && self.settings.cg_matrix == CgMatrix::F32
    }
}
