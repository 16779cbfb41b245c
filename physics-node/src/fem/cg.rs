//! Conjugate gradients (SOFA's CGLinearSolver, optionally preconditioned) on the step's
//! system.

use super::*;

impl FemModel {
    /// Refactors the rest preconditioner for another dt (numeric only; keeps `self.a`).
    pub(super) fn refactor_rest_preconditioner(&mut self, dt: f64) -> Result<(), FemError> {
        // The rest system needs its own value array: build it in a copy of `a` swapped in
        // and out (allocates, but only when dt differs from the nominal one).
        let current = std::mem::take(&mut self.a);
        self.a = current.clone();
        self.assemble_rest_system(dt);
        let res = match &mut self.rest_factor {
            Some((fdt, chol)) => {
                *fdt = dt;
                chol.refactor(&self.a)
            }
            None => SparseCholesky::new(&self.pattern, &self.a, 1).map(|c| {
                self.rest_factor = Some((dt, c));
            }),
        };
        self.a = current;
        // assemble() overwrote `force`, but the right-hand side is already built.
        res
    }

    /// z = P⁻¹ r.
    pub(super) fn precondition(&mut self, pc: Preconditioner) {
        match pc {
            Preconditioner::None => self.z.copy_from_slice(&self.r),
            Preconditioner::LaggedFactor => {
                self.z.copy_from_slice(&self.r);
                if let Some(chol) = &mut self.direct {
                    chol.solve_in_place(&mut self.z);
                }
            }
            Preconditioner::BlockJacobi => {
                for (row, inv) in self.jacobi.iter().enumerate() {
                    let r = Vector3::new(self.r[3 * row], self.r[3 * row + 1], self.r[3 * row + 2]);
                    let z = inv * r;
                    self.z[3 * row] = z.x;
                    self.z[3 * row + 1] = z.y;
                    self.z[3 * row + 2] = z.z;
                }
            }
            Preconditioner::RestCholesky | Preconditioner::WarpedRestCholesky => {
                let warped = pc == Preconditioner::WarpedRestCholesky;
                for (row, &node) in self.free_nodes.iter().enumerate() {
                    let r = Vector3::new(self.r[3 * row], self.r[3 * row + 1], self.r[3 * row + 2]);
                    let z = if warped {
                        self.node_rot[node].transpose() * r
                    } else {
                        r
                    };
                    self.z[3 * row] = z.x;
                    self.z[3 * row + 1] = z.y;
                    self.z[3 * row + 2] = z.z;
                }
                if let Some((_, chol)) = &mut self.rest_factor {
                    chol.solve_in_place(&mut self.z);
                }
                if warped {
                    for (row, &node) in self.free_nodes.iter().enumerate() {
                        let z = self.node_rot[node]
                            * Vector3::new(
                                self.z[3 * row],
                                self.z[3 * row + 1],
                                self.z[3 * row + 2],
                            );
                        self.z[3 * row] = z.x;
                        self.z[3 * row + 1] = z.y;
                        self.z[3 * row + 2] = z.z;
                    }
                }
            }
        }
    }

    /// Preconditioned CG on A Δv = rhs from Δv = 0 (SOFA's default, `warmStart` off). A warm
    /// start from the previous Δv extrapolates the last step's acceleration: with the
    /// iteration cap binding (always, at tolerance 1e-9) that made plain 25-iteration CG
    /// unstable under contact on the study's medial mesh and 10-iteration CG on the
    /// 2,560-node default; from zero, a truncated solve only under-resolves (dissipates).
    /// The offline lagged-factor CG does start warm: it runs to its tolerance under a cap
    /// that does not bind (and from zero after a solve that stopped at it), so the start only
    /// changes how many iterations it takes (19% fewer, and 14% fewer refactors, over 15
    /// replays on a 1,435-node specimen; forces within 3 mN of a cold start, the solve's own
    /// tolerance).
    /// Products read the upper triangle: packed in f32 (`self.upper32`) or in `self.a`.
    pub(super) fn cg(&mut self, max_iter: usize, tol: f64, pc: Preconditioner) -> SolveStats {
        let packed = self.packed_cg_matrix();
        let b_norm = dot(&self.rhs, &self.rhs).sqrt();
        if b_norm == 0.0 {
            self.dv.fill(0.0);
            return SolveStats::default();
        }
        // Warm only from a converged last solve: a capped one is what went unstable.
        let warm = pc == Preconditioner::LaggedFactor && self.last_stats.relative_residual <= tol;
        let mut r_norm = if warm {
            // r = b − A·Δv_prev; a factored solver's system is the f64 one in `a`, never packed
            self.pattern.mul_dot_upper(&self.a, &self.dv, &mut self.q);
            for ((r, b), q) in self.r.iter_mut().zip(&self.rhs).zip(&self.q) {
                *r = b - q;
            }
            dot(&self.r, &self.r).sqrt()
        } else {
            self.dv.fill(0.0);
            // r = b − A·0
            self.r.copy_from_slice(&self.rhs);
            b_norm
        };
        let mut iterations = 0;
        if r_norm / b_norm <= tol {
            return SolveStats {
                iterations,
                relative_residual: r_norm / b_norm,
            };
        }
        // Unpreconditioned: z = r, so skip the copy and reuse r·r for r·z.
        let plain = pc == Preconditioner::None;
        let mut rz = if plain {
            self.p.copy_from_slice(&self.r);
            dot(&self.r, &self.r)
        } else {
            self.precondition(pc);
            self.p.copy_from_slice(&self.z);
            dot(&self.r, &self.z)
        };
        while iterations < max_iter {
            iterations += 1;
            let pq = if packed {
                self.upper32.mul_dot(&self.p, &mut self.q, true)
            } else {
                self.pattern.mul_dot_upper(&self.a, &self.p, &mut self.q)
            };
            if !(pq > 0.0) {
                break;
            }
            let alpha = rz / pq;
            let mut rr = 0.0;
            for (((dv, r), p), q) in self
                .dv
                .iter_mut()
                .zip(self.r.iter_mut())
                .zip(&self.p)
                .zip(&self.q)
            {
                *dv += alpha * p;
                *r -= alpha * q;
                rr += *r * *r;
            }
            r_norm = rr.sqrt();
            if r_norm / b_norm <= tol {
                break;
            }
            let rz_new = if plain {
                rr
            } else {
                self.precondition(pc);
                dot(&self.r, &self.z)
            };
            let beta = rz_new / rz;
            rz = rz_new;
            let z: &[f64] = if plain { &self.r } else { &self.z };
            for (p, z) in self.p.iter_mut().zip(z) {
                *p = z + beta * *p;
            }
        }
        SolveStats {
            iterations,
            relative_residual: r_norm / b_norm,
        }
    }
}

pub(super) fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}
