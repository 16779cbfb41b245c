//! Assembly: elastic forces and the (upper or full) system matrix per step, and the
//! rest-state system.

use super::*;

impl FemModel {
    /// One pass over the elements at positions `self.x` (or at rest): elastic forces into
    /// `self.force`, and `k_scale · K`. `full`: both triangles into `self.a` (Cholesky
    /// gathers the lower one); otherwise the diagonal and upper blocks into `self.upper32`,
    /// which is all the CG product reads.
    pub(super) fn assemble(&mut self, at_rest: bool, k_scale: f64, want_k: bool, full: bool) {
        self.assemble_with(
            at_rest,
            k_scale,
            want_k,
            full,
            ROTATION_ITERATIONS,
            ROTATION_TOLERANCE,
        )
    }

    pub(super) fn assemble_with(
        &mut self,
        at_rest: bool,
        k_scale: f64,
        want_k: bool,
        full: bool,
        rot_iters: usize,
        rot_tol: f64,
    ) {
        let FemModel {
            tets,
            rest_elems,
            x,
            rest,
            elem_rot,
            elem_rot_m,
            a,
            force,
            elem_blocks,
            upper_scatter,
            upper32,
            elem_rot_k,
            upper32_k_scale,
            upper32_age,
            stiffness_updates,
            pattern,
            free_index,
            material,
            mu,
            lambda,
            settings,
            stiffening,
            ..
        } = self;
        // The rest system stays linear (it is the reference of the warped compliance).
        let stiff_active = !at_rest && stiffening.law.is_active();
        let (mu, lambda) = (*mu, *lambda);
        force.fill(Vector3::zeros());
        // The corotational material writes its blocks straight into the system its solver
        // reads: the packed upper triangle of the f32 CG matrix (the live step, from a scatter
        // map built once, re-rotating only the elements that turned) or both triangles of the
        // f64 system a factored solver reads (offline replays, static solves). Other
        // materials, and the rest system, assemble into `a` element by element and are packed
        // afterwards where the CG reads f32.
        let packed = !full && settings.cg_matrix == CgMatrix::F32;
        let corotational = want_k && material.model == MaterialModel::Corotational;
        let fused = corotational && packed;
        let fused_full = corotational && full && !at_rest;
        if want_k && !fused {
            if full {
                a.fill(Matrix3::zeros());
            } else {
                for (&d, &end) in pattern.diag.iter().zip(&pattern.row_ptr[1..]) {
                    a[d..end].fill(Matrix3::zeros());
                }
            }
        }
        let pos: &[Point3<f64>] = if at_rest { rest } else { x };
        let rotation = if at_rest {
            None
        } else {
            Some((settings.rotation, rot_iters, rot_tol))
        };
        let scale: &[f64] = if stiff_active { &stiffening.elem } else { &[] };
        if fused || fused_full {
            let target = if fused_full {
                StiffnessTarget::Full { elem_blocks, a }
            } else {
                // Rebuild from zero when the blocks are missing, for another dt, or old enough
                // that the f32 round-off of their in-place updates could add up; otherwise
                // re-rotate only the elements that turned.
                let rebuild = !(*upper32_k_scale == k_scale)
                    || *upper32_age >= STIFFNESS_REBUILD_STEPS
                    || settings.stiffness_rotation_tolerance <= 0.0;
                if rebuild {
                    upper32.clear();
                    *upper32_k_scale = k_scale;
                    *upper32_age = 0;
                } else {
                    *upper32_age += 1;
                }
                StiffnessTarget::PackedUpper {
                    scatter: upper_scatter,
                    blocks: upper32.blocks_mut(),
                    elem_rot_k,
                    scale_k: &mut stiffening.elem_k,
                    rebuild,
                    tolerance: settings.stiffness_rotation_tolerance,
                }
            };
            *stiffness_updates = CorotationalPass {
                tets,
                rest_elems,
                pos,
                rotation,
                elem_rot,
                elem_rot_m,
                mu,
                lambda,
                k_scale,
                target,
                force,
                scale,
            }
            .run();
            return;
        }
        let mut out = ElementOutput::zero();
        for (e, t) in tets.iter().enumerate() {
            let re = &rest_elems[e];
            let xe = [
                pos[t[0]].coords,
                pos[t[1]].coords,
                pos[t[2]].coords,
                pos[t[3]].coords,
            ];
            let f = re.deformation_gradient(xe);
            // Both materials keep the element rotation: the corotational element works in it,
            // and the warped compliance averages it per node.
            let rot = if at_rest {
                Matrix3::identity()
            } else {
                let r = element_rotation(
                    settings.rotation,
                    &f,
                    &mut elem_rot[e],
                    &elem_rot_m[e],
                    rot_iters,
                    rot_tol,
                );
                elem_rot_m[e] = r;
                r
            };
            let (mu, lambda) = if stiff_active {
                (mu * stiffening.elem[e], lambda * stiffening.elem[e])
            } else {
                (mu, lambda)
            };
            match material.model {
                MaterialModel::Corotational => {
                    element::corotational(re, &f, &rot, mu, lambda, want_k, &mut out);
                }
                MaterialModel::StableNeoHookean => {
                    element::stable_neo_hookean(
                        re,
                        &f,
                        mu,
                        lambda,
                        settings.project_tangent,
                        want_k,
                        &mut out,
                    );
                }
            }
            for k in 0..4 {
                force[t[k]] += out.force[k];
            }
            if !want_k {
                continue;
            }
            let eb = &elem_blocks[e];
            for ia in 0..4 {
                for ib in ia..4 {
                    let kab = &out.k[ia][ib];
                    let idx = eb[ia * 4 + ib];
                    if idx == NO_BLOCK {
                        continue;
                    }
                    if ia == ib {
                        a[idx as usize] += kab * k_scale;
                        continue;
                    }
                    let kba = kab.transpose();
                    if full {
                        a[idx as usize] += kab * k_scale;
                        a[eb[ib * 4 + ia] as usize] += kba * k_scale;
                    } else if free_index[t[ia]] < free_index[t[ib]] {
                        a[idx as usize] += kab * k_scale;
                    } else {
                        a[eb[ib * 4 + ia] as usize] += kba * k_scale;
                    }
                }
            }
        }
        if want_k && packed {
            upper32.pack(pattern, a);
            // Packed from a full assembly: not blocks the element pass may update in place.
            *upper32_k_scale = f64::NAN;
        }
    }

    /// A0 = M + h C0 + h² K0 at rest into `self.a`.
    pub(super) fn assemble_rest_system(&mut self, dt: f64) {
        let (alpha, beta) = (
            self.settings.rayleigh_mass,
            self.settings.rayleigh_stiffness,
        );
        let k_scale = dt * beta + dt * dt;
        self.assemble(true, k_scale, true, true);
        for (row, &node) in self.free_nodes.iter().enumerate() {
            // The rest system: the support at its rest stiffness, whatever the committed state.
            let d = (1.0 + dt * alpha) * self.mass[node] + k_scale * self.support_rest[node];
            let blk = &mut self.a[self.pattern.diag[row]];
            blk[(0, 0)] += d;
            blk[(1, 1)] += d;
            blk[(2, 2)] += d;
        }
    }
}
