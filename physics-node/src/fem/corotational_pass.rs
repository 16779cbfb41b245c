//! The element pass of the corotational material: QR rotations and forces four elements at a
//! time (lane arrays the compiler vectorises), with the stiffness blocks written straight into
//! the system a solver reads: the packed upper-triangle CG matrix (the live step), or both
//! triangles of the f64 system a factored solver reads (offline replays, static solves).

use super::*;

/// Where the pass writes `k_scale · K`.
pub(super) enum StiffnessTarget<'a> {
    /// The packed f32 upper triangle the CG solver reads ([`UpperF32`]), at each tet's
    /// [`UpperScatter`]; updated in place where an element turned, or rebuilt.
    PackedUpper {
        scatter: &'a [UpperScatter],
        blocks: &'a mut [f32],
        /// Rotation each element's blocks were built with.
        elem_rot_k: &'a mut [Matrix3<f64>],
        /// Modulus factor each element's blocks were built with (updated when rebuilt).
        scale_k: &'a mut [f64],
        /// Add every element's blocks (into cleared `blocks`) instead of updating.
        rebuild: bool,
        /// Re-rotate an element's blocks once its rotation (or its modulus factor,
        /// relatively) moved by more than this.
        tolerance: f64,
    },
    /// Both triangles of the f64 system (`FemModel::a`, cleared by the caller) at each tet's
    /// 4×4 block map: every element's blocks, every pass. A factored solver reads this
    /// system, and the offline replays want their K exact at the step's rotations.
    Full {
        elem_blocks: &'a [[u32; 16]],
        a: &'a mut [Matrix3<f64>],
    },
}

/// The element pass of the corotational material: forces, and `k_scale · K` written straight
/// to its blocks ([`StiffnessTarget`]).
pub(super) struct CorotationalPass<'a> {
    pub(super) tets: &'a [[usize; 4]],
    pub(super) rest_elems: &'a [TetRest],
    pub(super) pos: &'a [Point3<f64>],
    /// Rotation method, iterations and tolerance; None at rest (identity).
    pub(super) rotation: Option<(RotationMethod, usize, f64)>,
    pub(super) elem_rot: &'a mut [UnitQuaternion<f64>],
    pub(super) elem_rot_m: &'a mut [Matrix3<f64>],
    pub(super) mu: f64,
    pub(super) lambda: f64,
    pub(super) k_scale: f64,
    pub(super) target: StiffnessTarget<'a>,
    pub(super) force: &'a mut [Vector3<f64>],
    /// Modulus factor per element (strain stiffening); empty: 1 everywhere.
    pub(super) scale: &'a [f64],
}

impl CorotationalPass<'_> {
    /// Returns the number of elements whose blocks were written.
    pub(super) fn run(self) -> usize {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                // SAFETY: the features were just detected.
                return unsafe { self.run_avx2() };
            }
        }
        self.run_portable()
    }

    /// The same loop compiled for AVX2/FMA (the kernels inline into it): the element
    /// arithmetic is ~600 flops a tet, a third of a step on the 2,560-node mesh.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn run_avx2(self) -> usize {
        self.run_portable()
    }

    #[inline(always)]
    pub(super) fn run_portable(mut self) -> usize {
        let mut written = 0;
        let mut start = 0;
        if matches!(self.rotation, Some((RotationMethod::Qr, _, _))) {
            // Four elements side by side: rotation and forces lane by lane, which the
            // compiler turns into 4-wide arithmetic (the scalar chain of square roots and
            // divisions per element was the pass's cost).
            let chunks = self.tets.len() / 4;
            for c in 0..chunks {
                let e0 = 4 * c;
                let (rots, forces) = self.qr_forces_x4(e0);
                for l in 0..4 {
                    written += self.finish(e0 + l, &rots[l], &forces[l]) as usize;
                }
            }
            start = 4 * chunks;
        }
        let mut nodal = [Vector3::zeros(); 4];
        for e in start..self.tets.len() {
            let t = self.tets[e];
            let re = &self.rest_elems[e];
            let f = re.deformation_gradient([
                self.pos[t[0]].coords,
                self.pos[t[1]].coords,
                self.pos[t[2]].coords,
                self.pos[t[3]].coords,
            ]);
            let rot = match self.rotation {
                None => Matrix3::identity(),
                Some((method, iterations, tolerance)) => {
                    let r = element_rotation(
                        method,
                        &f,
                        &mut self.elem_rot[e],
                        &self.elem_rot_m[e],
                        iterations,
                        tolerance,
                    );
                    self.elem_rot_m[e] = r;
                    r
                }
            };
            element::corotational_forces(re, &f, &rot, self.mu, self.lambda, &mut nodal);
            written += self.finish(e, &rot, &nodal) as usize;
        }
        written
    }

    /// Element `e`'s forces onto its nodes, and its stiffness blocks: always into the full
    /// system; into the packed one when the pass rebuilds or the element's rotation moved past
    /// the tolerance. True when the blocks were written.
    #[inline(always)]
    pub(super) fn finish(
        &mut self,
        e: usize,
        rot: &Matrix3<f64>,
        nodal: &[Vector3<f64>; 4],
    ) -> bool {
        let t = self.tets[e];
        let s = self.scale.get(e).copied().unwrap_or(1.0);
        for k in 0..4 {
            self.force[t[k]] += nodal[k] * s;
        }
        let (scatter, blocks, built, s_built, rebuild, tolerance) = match &mut self.target {
            StiffnessTarget::Full { elem_blocks, a } => {
                element::corotational_stiffness_full(
                    &self.rest_elems[e],
                    rot,
                    self.mu * s,
                    self.lambda * s,
                    self.k_scale,
                    &elem_blocks[e],
                    a,
                );
                return true;
            }
            StiffnessTarget::PackedUpper {
                scatter,
                blocks,
                elem_rot_k,
                scale_k,
                rebuild,
                tolerance,
            } => (
                &scatter[e],
                &mut **blocks,
                &mut elem_rot_k[e],
                &mut scale_k[e],
                *rebuild,
                *tolerance,
            ),
        };
        let rescaled = s != *s_built;
        if !rebuild {
            let turned = (rot - *built).amax() > tolerance;
            let stiffened = (s - *s_built).abs() > tolerance * *s_built;
            if !(turned || stiffened) {
                return false;
            }
            if rescaled {
                // The modulus changed: take the old blocks out whole, then add the new ones.
                element::corotational_stiffness_upper(
                    &self.rest_elems[e],
                    built,
                    None,
                    -self.mu * *s_built,
                    -self.lambda * *s_built,
                    self.k_scale,
                    scatter,
                    blocks,
                );
            }
        }
        let replaced = if rebuild || rescaled {
            None
        } else {
            Some(*built)
        };
        element::corotational_stiffness_upper(
            &self.rest_elems[e],
            rot,
            replaced.as_ref(),
            self.mu * s,
            self.lambda * s,
            self.k_scale,
            scatter,
            blocks,
        );
        *built = *rot;
        *s_built = s;
        true
    }

    /// QR rotations (into `elem_rot_m`) and corotational nodal forces of elements
    /// `e0..e0 + 4`, computed lane by lane: the same arithmetic as [`element::qr_rotation`]
    /// and [`element::corotational_forces`] (node 0's force as minus the others').
    #[inline(always)]
    pub(super) fn qr_forces_x4(
        &mut self,
        e0: usize,
    ) -> ([Matrix3<f64>; 4], [[Vector3<f64>; 4]; 4]) {
        type L = [f64; 4];
        // Edge vectors d_b = x_b − x_0 and rest gradients g_b (b = 1..3), per lane.
        let mut d = [[[0.0; 4]; 3]; 3];
        let mut g = [[[0.0; 4]; 3]; 3];
        let mut vol: L = [0.0; 4];
        for l in 0..4 {
            let t = self.tets[e0 + l];
            let re = &self.rest_elems[e0 + l];
            let x0 = self.pos[t[0]].coords;
            for b in 0..3 {
                let db = self.pos[t[b + 1]].coords - x0;
                for k in 0..3 {
                    d[b][k][l] = db[k];
                    g[b][k][l] = re.grad[b + 1][k];
                }
            }
            vol[l] = re.volume;
        }
        // F[i][j] = Σ_b d_b[i] g_b[j].
        let mut f = [[[0.0; 4]; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                f[i][j] = lanes(|l| {
                    d[0][i][l] * g[0][j][l] + d[1][i][l] * g[1][j][l] + d[2][i][l] * g[2][j][l]
                });
            }
        }
        // QR: q0 = c0/|c0|, u1 = c1 − c0 (c0·c1)/(c0·c0), q1 = u1/|u1|, q2 = q0 × q1.
        let n0_sq =
            lanes(|l| f[0][0][l] * f[0][0][l] + f[1][0][l] * f[1][0][l] + f[2][0][l] * f[2][0][l]);
        let c01 =
            lanes(|l| f[0][0][l] * f[0][1][l] + f[1][0][l] * f[1][1][l] + f[2][0][l] * f[2][1][l]);
        let s = lanes(|l| c01[l] / n0_sq[l]);
        let mut u1 = [[0.0; 4]; 3];
        for i in 0..3 {
            u1[i] = lanes(|l| f[i][1][l] - f[i][0][l] * s[l]);
        }
        let n1_sq = lanes(|l| u1[0][l] * u1[0][l] + u1[1][l] * u1[1][l] + u1[2][l] * u1[2][l]);
        let inv0 = lanes(|l| 1.0 / n0_sq[l].sqrt());
        let inv1 = lanes(|l| 1.0 / n1_sq[l].sqrt());
        let mut r = [[[0.0; 4]; 3]; 3]; // r[i][j]: row i, column j
        for i in 0..3 {
            r[i][0] = lanes(|l| f[i][0][l] * inv0[l]);
            r[i][1] = lanes(|l| u1[i][l] * inv1[l]);
        }
        for i in 0..3 {
            let (j, k) = ((i + 1) % 3, (i + 2) % 3);
            r[i][2] = lanes(|l| r[j][0][l] * r[k][1][l] - r[k][0][l] * r[j][1][l]);
        }
        let mut rots = [Matrix3::zeros(); 4];
        for l in 0..4 {
            let valid = n0_sq[l] > 1e-24
                && n0_sq[l].is_finite()
                && n1_sq[l] > 1e-24 * n0_sq[l].max(1.0)
                && n1_sq[l].is_finite();
            if valid {
                rots[l] = Matrix3::from_fn(|i, j| r[i][j][l]);
                self.elem_rot_m[e0 + l] = rots[l];
            } else {
                // Degenerate element: keep its previous rotation, as the scalar path.
                rots[l] = self.elem_rot_m[e0 + l];
                for i in 0..3 {
                    for j in 0..3 {
                        r[i][j][l] = rots[l][(i, j)];
                    }
                }
            }
        }
        // Small strain in the rotated frame: eps = sym(RᵀF) − I, σ = 2μ eps + λ tr(eps) I.
        let mut fr = [[[0.0; 4]; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                fr[i][j] = lanes(|l| {
                    r[0][i][l] * f[0][j][l] + r[1][i][l] * f[1][j][l] + r[2][i][l] * f[2][j][l]
                });
            }
        }
        let (mu, lambda) = (self.mu, self.lambda);
        let tr = lanes(|l| fr[0][0][l] + fr[1][1][l] + fr[2][2][l] - 3.0);
        let mut sigma = [[[0.0; 4]; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                sigma[i][j] = lanes(|l| {
                    let eps = 0.5 * (fr[i][j][l] + fr[j][i][l]) - if i == j { 1.0 } else { 0.0 };
                    2.0 * mu * eps + if i == j { lambda * tr[l] } else { 0.0 }
                });
            }
        }
        // P = −V R σ; f_b = P g_b (b = 1..3), f_0 = −(f_1 + f_2 + f_3).
        let mut p = [[[0.0; 4]; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                p[i][j] = lanes(|l| {
                    -vol[l]
                        * (r[i][0][l] * sigma[0][j][l]
                            + r[i][1][l] * sigma[1][j][l]
                            + r[i][2][l] * sigma[2][j][l])
                });
            }
        }
        let mut forces = [[Vector3::zeros(); 4]; 4];
        for b in 0..3 {
            for i in 0..3 {
                let fb = lanes(|l| {
                    p[i][0][l] * g[b][0][l] + p[i][1][l] * g[b][1][l] + p[i][2][l] * g[b][2][l]
                });
                for l in 0..4 {
                    forces[l][b + 1][i] = fb[l];
                }
            }
        }
        for nodal in forces.iter_mut() {
            nodal[0] = -(nodal[1] + nodal[2] + nodal[3]);
        }
        (rots, forces)
    }
}

/// One value per lane of a 4-element group.
#[inline(always)]
pub(super) fn lanes(f: impl Fn(usize) -> f64) -> [f64; 4] {
    [f(0), f(1), f(2), f(3)]
}

/// Rotation of `a` (a deformation gradient or a sum of rotations) by `method`; QR falls back
/// to `previous` for a degenerate `a`, polar warm-starts from (and updates) `q`.
#[inline]
pub(super) fn element_rotation(
    method: RotationMethod,
    a: &Matrix3<f64>,
    q: &mut UnitQuaternion<f64>,
    previous: &Matrix3<f64>,
    iterations: usize,
    tolerance: f64,
) -> Matrix3<f64> {
    match method {
        RotationMethod::Qr => element::qr_rotation(a).unwrap_or(*previous),
        RotationMethod::Polar => element::extract_rotation(a, q, iterations, tolerance),
    }
}
