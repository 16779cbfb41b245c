//! Stepping: linearized backward Euler free motion, constraint correction, commit, and
//! the static Newton solve used for set-up.

use super::*;

impl FemModel {
    /// Free motion over `dt` with per-node external forces (N; held nodes ignore theirs):
    /// one linearized backward-Euler step from the committed state into the free state.
    /// Does not allocate.
    pub fn free_motion(
        &mut self,
        dt: f64,
        external_forces: &[Vector3<f64>],
    ) -> Result<SolveStats, FemError> {
        let n = self.x.len();
        if external_forces.len() != n {
            return Err(FemError::Input(format!(
                "{} external forces for {n} nodes",
                external_forces.len()
            )));
        }
        if !(dt.is_finite() && dt > 0.0) {
            return Err(FemError::Input(format!("dt must be > 0 s, got {dt}")));
        }
        self.last_dt = dt;
        // Secant modulus factors of the committed state (no-op for the linear law).
        self.stiffening
            .update(&self.tets, &self.rest_elems, &self.x, &self.elem_rot_m);
        self.stiffening.update_support(
            &self.support_rest,
            &mut self.support,
            &self.x,
            &self.rest,
            self.support_length,
        );
        let (alpha, beta) = (
            self.settings.rayleigh_mass,
            self.settings.rayleigh_stiffness,
        );
        let k_scale = dt * beta + dt * dt;
        // CG reads only the upper triangle; the direct solver factors the lower one.
        let full = self.settings.solver.factors_current_system();
        self.assemble(false, k_scale, true, full);
        // K·v for the implicit damping and stiffness terms, from the assembled k_scale·K
        // (before the mass goes on the diagonal): one sparse product instead of two 3×3
        // products per element block during assembly.
        for (row, &node) in self.free_nodes.iter().enumerate() {
            let vi = self.v[node];
            self.z[3 * row] = vi.x;
            self.z[3 * row + 1] = vi.y;
            self.z[3 * row + 2] = vi.z;
        }
        let packed = self.packed_cg_matrix();
        if packed {
            self.upper32.mul_dot(&self.z, &mut self.q, false);
        } else {
            self.pattern.mul_dot_upper(&self.a, &self.z, &mut self.q);
        }
        let inv_k_scale = 1.0 / k_scale;
        let g = self.settings.gravity;
        for (row, &node) in self.free_nodes.iter().enumerate() {
            let m = self.mass[node];
            let ks = self.support[node];
            let d = (1.0 + dt * alpha) * m + k_scale * ks;
            if packed {
                self.upper32.set_shift(row, d);
            } else {
                let blk = &mut self.a[self.pattern.diag[row]];
                blk[(0, 0)] += d;
                blk[(1, 1)] += d;
                blk[(2, 2)] += d;
            }
            let vi = self.v[node];
            let disp = self.x[node] - self.rest[node];
            let f = external_forces[node] + self.force[node] + g * m
                - vi * (alpha * m)
                - (Vector3::new(self.q[3 * row], self.q[3 * row + 1], self.q[3 * row + 2])
                    * inv_k_scale
                    + vi * ks)
                    * (beta + dt)
                - disp * ks;
            let b = f * dt;
            self.rhs[3 * row] = b.x;
            self.rhs[3 * row + 1] = b.y;
            self.rhs[3 * row + 2] = b.z;
        }
        let stats = self.solve_system(dt)?;
        self.last_stats = stats;
        // Free state: held nodes stay where they are.
        self.x_free.copy_from_slice(&self.x);
        self.v_free.fill(Vector3::zeros());
        for (row, &node) in self.free_nodes.iter().enumerate() {
            let dv = Vector3::new(self.dv[3 * row], self.dv[3 * row + 1], self.dv[3 * row + 2]);
            let v = self.v[node] + dv;
            if !v.iter().all(|c| c.is_finite()) {
                return Err(FemError::Diverged(format!(
                    "non-finite velocity at node {node} after the implicit solve"
                )));
            }
            self.v_free[node] = v;
            self.x_free[node] = self.x[node] + v * dt;
        }
        Ok(stats)
    }

    /// Constraint correction: moves the given nodes of the free state by dx (m) and changes
    /// their velocity by dx/dt (dt of the last free motion), consistent with x = x₀ + dt·v.
    /// Held nodes are left in place.
    pub fn apply_correction(&mut self, node_dx: &[(usize, Vector3<f64>)]) -> Result<(), FemError> {
        let inv_dt = 1.0 / self.last_dt;
        for &(node, dx) in node_dx {
            if node >= self.x.len() {
                return Err(FemError::Input(format!(
                    "correction for node {node} out of range"
                )));
            }
            if self.free_index[node] == NO_BLOCK {
                continue;
            }
            self.x_free[node] += dx;
            self.v_free[node] += dx * inv_dt;
        }
        Ok(())
    }

    /// Constraint correction from a full vector (3 per node, m).
    pub fn apply_correction_full(&mut self, dx: &[f64]) -> Result<(), FemError> {
        if dx.len() != 3 * self.x.len() {
            return Err(FemError::Input(format!(
                "correction vector has {} entries, expected {}",
                dx.len(),
                3 * self.x.len()
            )));
        }
        let inv_dt = 1.0 / self.last_dt;
        for &node in &self.free_nodes {
            let d = Vector3::new(dx[3 * node], dx[3 * node + 1], dx[3 * node + 2]);
            self.x_free[node] += d;
            self.v_free[node] += d * inv_dt;
        }
        Ok(())
    }

    /// The free (and corrected) state becomes the committed state.
    pub fn commit(&mut self) {
        let mut motion: f64 = 0.0;
        for (to, from) in self.x_free.iter().zip(&self.x) {
            motion = motion.max((to - from).norm_squared());
        }
        self.last_motion = motion.sqrt();
        self.x.copy_from_slice(&self.x_free);
        self.v.copy_from_slice(&self.v_free);
    }

    /// Free motion of a settled tissue (the offline replay's shortcut, see
    /// `Simulation::offline`): at rest where it is. Its last step moved it less than a
    /// few nanometres with no contact force on it, so the linearized step from an
    /// equilibrium is that decaying remainder; assembling and solving it changes nothing a
    /// force can show.
    pub fn free_motion_at_rest(&mut self, dt: f64) {
        self.last_dt = dt;
        self.x_free.copy_from_slice(&self.x);
        self.v_free.fill(Vector3::zeros());
    }

    /// `free_motion` then `commit` (no contact).
    pub fn step(
        &mut self,
        dt: f64,
        external_forces: &[Vector3<f64>],
    ) -> Result<SolveStats, FemError> {
        let s = self.free_motion(dt, external_forces)?;
        self.commit();
        Ok(s)
    }

    pub(super) fn solve_system(&mut self, dt: f64) -> Result<SolveStats, FemError> {
        if self.free_nodes.is_empty() {
            return Ok(SolveStats::default());
        }
        match self.settings.solver {
            LinearSolver::Direct => {
                let chol = self
                    .direct
                    .as_mut()
                    .ok_or_else(|| FemError::Solver("direct solver not prepared".into()))?;
                chol.refactor(&self.a)?;
                self.dv.copy_from_slice(&self.rhs);
                chol.solve_in_place(&mut self.dv);
                Ok(SolveStats {
                    iterations: 0,
                    relative_residual: 0.0,
                })
            }
            LinearSolver::Cg {
                max_iterations,
                tolerance,
                preconditioner,
            } => {
                match preconditioner {
                    Preconditioner::BlockJacobi => {
                        let packed = self.packed_cg_matrix();
                        for (row, inv) in self.jacobi.iter_mut().enumerate() {
                            let d = if packed {
                                self.upper32.diagonal_block(row, true)
                            } else {
                                self.a[self.pattern.diag[row]]
                            };
                            *inv = d.try_inverse().unwrap_or_else(Matrix3::identity);
                        }
                    }
                    Preconditioner::RestCholesky | Preconditioner::WarpedRestCholesky => {
                        let stale = match &self.rest_factor {
                            Some((fdt, _)) => *fdt != dt,
                            None => true,
                        };
                        if stale {
                            self.refactor_rest_preconditioner(dt)?;
                        }
                        if preconditioner == Preconditioner::WarpedRestCholesky {
                            self.update_node_rotations();
                        }
                    }
                    Preconditioner::LaggedFactor => {
                        if self.refactor_lagged {
                            self.direct
                                .as_mut()
                                .ok_or_else(|| {
                                    FemError::Solver("lagged factor not prepared".into())
                                })?
                                .refactor(&self.a)?;
                            self.refactor_lagged = false;
                        }
                    }
                    Preconditioner::None => {}
                }
                let stats = self.cg(max_iterations, tolerance, preconditioner);
                if preconditioner == Preconditioner::LaggedFactor
                    && stats.iterations > LAGGED_FACTOR_ITERATIONS
                {
                    self.refactor_lagged = true;
                }
                Ok(stats)
            }
        }
    }

    /// Quasi-static equilibrium under `external_forces` (+ gravity if `with_gravity`) by
    /// Newton iterations on K Δx = f with a direct solve (allocates; for set-up and tests).
    /// Converged when the largest update is below `tolerance` × the mesh's size. Returns
    /// the number of Newton iterations.
    pub fn solve_static(
        &mut self,
        external_forces: &[Vector3<f64>],
        with_gravity: bool,
        max_iterations: usize,
        tolerance: f64,
    ) -> Result<usize, FemError> {
        let n = self.x.len();
        if external_forces.len() != n {
            return Err(FemError::Input(format!(
                "{} external forces for {n} nodes",
                external_forces.len()
            )));
        }
        if self.free_nodes.is_empty() {
            return Ok(0);
        }
        let (mut lo, mut hi) = (self.rest[0].coords, self.rest[0].coords);
        for p in &self.rest {
            lo = lo.inf(&p.coords);
            hi = hi.sup(&p.coords);
        }
        let size = (hi - lo).norm();
        let saved_v = self.v.clone();
        self.v.fill(Vector3::zeros());
        let mut chol: Option<SparseCholesky> = None;
        let mut rhs = vec![0.0; 3 * self.free_nodes.len()];
        let g = if with_gravity {
            self.settings.gravity
        } else {
            Vector3::zeros()
        };
        let mut result = Err(FemError::Solver(format!(
            "static solve did not converge in {max_iterations} Newton iterations"
        )));
        for it in 1..=max_iterations {
            self.assemble_with(
                false,
                1.0,
                true,
                true,
                ROTATION_ITERATIONS_COLD,
                ROTATION_TOLERANCE_COLD,
            );
            for (row, &node) in self.free_nodes.iter().enumerate() {
                let ks = self.support[node];
                let blk = &mut self.a[self.pattern.diag[row]];
                blk[(0, 0)] += ks;
                blk[(1, 1)] += ks;
                blk[(2, 2)] += ks;
                let r = external_forces[node] + g * self.mass[node] + self.force[node]
                    - (self.x[node] - self.rest[node]) * ks;
                rhs[3 * row] = r.x;
                rhs[3 * row + 1] = r.y;
                rhs[3 * row + 2] = r.z;
            }
            match &mut chol {
                Some(c) => c.refactor(&self.a)?,
                None => chol = Some(SparseCholesky::new(&self.pattern, &self.a, 1)?),
            }
            let c = chol.as_mut().expect("factor built above");
            c.solve_in_place(&mut rhs);
            let mut step = 0.0f64;
            for (row, &node) in self.free_nodes.iter().enumerate() {
                let d = Vector3::new(rhs[3 * row], rhs[3 * row + 1], rhs[3 * row + 2]);
                step = step.max(d.amax());
                self.x[node] += d;
            }
            if !step.is_finite() {
                result = Err(FemError::Diverged(
                    "static solve produced non-finite positions".into(),
                ));
                break;
            }
            if step <= tolerance * size {
                result = Ok(it);
                break;
            }
        }
        self.v = saved_v;
        self.x_free.copy_from_slice(&self.x);
        self.v_free.copy_from_slice(&self.v);
        self.last_motion = f64::INFINITY;
        result
    }
}
