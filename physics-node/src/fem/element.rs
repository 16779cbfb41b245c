//! Tetrahedron kernels: rest shape, rotation extraction, the linear corotational element and
//! the stable neo-Hookean element. Each kernel returns the elastic nodal forces and the 4×4
//! grid of 3×3 stiffness blocks (K = −∂f/∂x), so both materials share one assembly.

#[cfg(test)]
use nalgebra::SMatrix;
use nalgebra::{Matrix3, Quaternion, SymmetricEigen, UnitQuaternion, Vector3};

/// The 9×9 tangent dP/dF in column-major vec(F) ordering (the tests' oracle; the element
/// contracts it term by term).
#[cfg(test)]
pub(crate) type Tangent9 = SMatrix<f64, 9, 9>;

/// Rest data of one tet: shape-function gradients g_a (F = Σ x_a g_aᵀ) and volume.
#[derive(Debug, Clone, Copy)]
pub(crate) struct TetRest {
    pub grad: [Vector3<f64>; 4],
    pub volume: f64,
}

impl TetRest {
    /// None when the rest tet is degenerate or inverted (volume ≤ 0 or not finite).
    pub fn new(x: [&nalgebra::Point3<f64>; 4]) -> Option<TetRest> {
        let dm = Matrix3::from_columns(&[x[1] - x[0], x[2] - x[0], x[3] - x[0]]);
        let det = dm.determinant();
        if !det.is_finite() || det <= 0.0 {
            return None;
        }
        let inv = dm.try_inverse()?;
        // Rows of Dm⁻¹ are the gradients of the shape functions of nodes 1..3.
        let g1 = inv.row(0).transpose();
        let g2 = inv.row(1).transpose();
        let g3 = inv.row(2).transpose();
        Some(TetRest {
            grad: [-(g1 + g2 + g3), g1, g2, g3],
            volume: det / 6.0,
        })
    }

    /// Deformation gradient F = Σ x_a g_aᵀ.
    #[inline]
    pub fn deformation_gradient(&self, x: [Vector3<f64>; 4]) -> Matrix3<f64> {
        // Differences keep translation out of the sum (better rounding far from the origin).
        let g = &self.grad;
        (x[1] - x[0]) * g[1].transpose()
            + (x[2] - x[0]) * g[2].transpose()
            + (x[3] - x[0]) * g[3].transpose()
    }
}

/// Rotation closest to `a` (Müller et al. 2016, "A robust method to extract the rotational
/// part of deformations"), warm-started from `q`. Always a proper rotation, also for
/// inverted elements (where polar decomposition would give a reflection); converges in one
/// or two iterations when `q` is last step's rotation. Returns the rotation matrix of the
/// final `q` (reusing the converged iteration's matrix instead of rebuilding it).
#[inline]
pub(crate) fn extract_rotation(
    a: &Matrix3<f64>,
    q: &mut UnitQuaternion<f64>,
    max_iter: usize,
    tolerance: f64,
) -> Matrix3<f64> {
    for _ in 0..max_iter {
        let r = q.to_rotation_matrix().into_inner();
        let num = r.column(0).cross(&a.column(0))
            + r.column(1).cross(&a.column(1))
            + r.column(2).cross(&a.column(2));
        let den = (r.column(0).dot(&a.column(0))
            + r.column(1).dot(&a.column(1))
            + r.column(2).dot(&a.column(2)))
        .abs()
            + 1.0e-9;
        let omega = num / den;
        let w = omega.norm();
        if !w.is_finite() || w <= tolerance {
            return r;
        }
        *q = if w < 0.05 {
            // Small step: first-order quaternion, no sin/cos (the iteration absorbs the
            // O(w³) error).
            UnitQuaternion::new_normalize(Quaternion::new(
                1.0,
                0.5 * omega.x,
                0.5 * omega.y,
                0.5 * omega.z,
            ))
        } else {
            UnitQuaternion::from_scaled_axis(omega)
        } * *q;
        q.renormalize_fast();
    }
    q.to_rotation_matrix().into_inner()
}

/// SOFA's "large" rotation: the Q of a QR (Gram–Schmidt) decomposition of `a`, i.e. the frame
/// whose first axis follows the first column and whose first two axes span the first two
/// columns. Exact for rigid motion, a proper rotation also for inverted elements, no
/// iteration (a few times cheaper than the polar rotation). `None` when the first two columns
/// are (nearly) parallel or not finite.
#[inline]
pub(crate) fn qr_rotation(a: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let c0 = a.column(0).into_owned();
    let c1 = a.column(1).into_owned();
    // u1 = c1 − c0 (c0·c1)/(c0·c0) needs no normalised c0, so the two square roots and
    // divisions below are independent instead of one chain (their latency was most of the
    // element pass once the stiffness blocks stopped being rebuilt every step).
    let n0_sq = c0.norm_squared();
    if !(n0_sq > 1e-24 && n0_sq.is_finite()) {
        return None;
    }
    let u1 = c1 - c0 * (c0.dot(&c1) / n0_sq);
    let n1_sq = u1.norm_squared();
    if !(n1_sq > 1e-24 * n0_sq.max(1.0) && n1_sq.is_finite()) {
        return None;
    }
    let q0 = c0 * (1.0 / n0_sq.sqrt());
    let q1 = u1 * (1.0 / n1_sq.sqrt());
    Some(Matrix3::from_columns(&[q0, q1, q0.cross(&q1)]))
}

/// Forces on the 4 nodes and stiffness blocks K[a][b] (only a ≤ b filled; K[b][a] = K[a][b]ᵀ).
pub(crate) struct ElementOutput {
    pub force: [Vector3<f64>; 4],
    pub k: [[Matrix3<f64>; 4]; 4],
    pub energy: f64,
}

impl ElementOutput {
    pub fn zero() -> Self {
        ElementOutput {
            force: [Vector3::zeros(); 4],
            k: [[Matrix3::zeros(); 4]; 4],
            energy: 0.0,
        }
    }
}

/// Linear corotational element: u = Rᵀx − X in the element frame R, f = −R K0 u,
/// K = R K0 Rᵀ (∂R/∂x neglected, as SOFA). `rot` is the rotation (already extracted).
#[inline]
pub(crate) fn corotational(
    rest: &TetRest,
    f: &Matrix3<f64>,
    rot: &Matrix3<f64>,
    mu: f64,
    lambda: f64,
    want_k: bool,
    out: &mut ElementOutput,
) {
    let v = rest.volume;
    let (eps, tr, sigma) = rotated_small_strain(f, rot, mu, lambda);
    out.energy = v * (mu * eps.norm_squared() + 0.5 * lambda * tr * tr);
    let p = rot * sigma * (-v);
    // Rotated gradients: R K0_ab Rᵀ = V[μ (g_a·g_b) I + μ ĝ_b ĝ_aᵀ + λ ĝ_a ĝ_bᵀ], ĝ = R g.
    let mut gh = [Vector3::zeros(); 4];
    for a in 0..4 {
        out.force[a] = p * rest.grad[a];
        gh[a] = rot * rest.grad[a];
    }
    if !want_k {
        return;
    }
    for a in 0..4 {
        for b in a..4 {
            out.k[a][b] = corotational_block(&gh, &rest.grad, a, b, v * mu, v * lambda);
        }
    }
}

/// Block K_ab of the linear corotational element from its rotated gradients ĝ = R g (`gh`)
/// and rest gradients g (`grad`): c_μ ĝ_b ĝ_aᵀ + c_λ ĝ_a ĝ_bᵀ + c_μ (g_a·g_b) I, with the
/// volume and any stiffness scale folded into c_μ = V μ and c_λ = V λ.
#[inline(always)]
fn corotational_block(
    gh: &[Vector3<f64>; 4],
    grad: &[Vector3<f64>; 4],
    a: usize,
    b: usize,
    c_mu: f64,
    c_lambda: f64,
) -> Matrix3<f64> {
    let d = c_mu * grad[a].dot(&grad[b]);
    let mut m = gh[b] * gh[a].transpose() * c_mu + gh[a] * gh[b].transpose() * c_lambda;
    m[(0, 0)] += d;
    m[(1, 1)] += d;
    m[(2, 2)] += d;
    m
}

/// The upper block pairs (a ≤ b) of a tet in the order of [`UpperScatter`].
pub(crate) const UPPER_PAIRS: [(usize, usize); 10] = [
    (0, 0),
    (0, 1),
    (0, 2),
    (0, 3),
    (1, 1),
    (1, 2),
    (1, 3),
    (2, 2),
    (2, 3),
    (3, 3),
];

/// Marks a scatter target that holds the pair's block transposed: the pair's first node has
/// the later free row, so its (a, b) block lands in the upper triangle as K_baᵀ.
pub(crate) const TRANSPOSED: u32 = 1 << 31;

/// Where each of a tet's [`UPPER_PAIRS`] goes in the packed upper triangle of the system:
/// block index (with [`TRANSPOSED`] set when stored as K_ba), or `NO_BLOCK` for a pair with a
/// held node. Built once with the pattern, so the step decides nothing per block.
pub(crate) type UpperScatter = [u32; 10];

/// Nodal forces of the linear corotational element (as [`corotational`], without energy
/// and stiffness): f = −R σ(sym(RᵀF) − I) V g_a.
#[inline(always)]
pub(crate) fn corotational_forces(
    rest: &TetRest,
    f: &Matrix3<f64>,
    rot: &Matrix3<f64>,
    mu: f64,
    lambda: f64,
    force: &mut [Vector3<f64>; 4],
) {
    let (_, _, sigma) = rotated_small_strain(f, rot, mu, lambda);
    let p = rot * sigma * (-rest.volume);
    for a in 0..4 {
        force[a] = p * rest.grad[a];
    }
}

/// Small strain in the element frame, eps = sym(RᵀF) − I, its trace, and the linear stress
/// σ = 2μ eps + λ tr(eps) I.
#[inline(always)]
fn rotated_small_strain(
    f: &Matrix3<f64>,
    rot: &Matrix3<f64>,
    mu: f64,
    lambda: f64,
) -> (Matrix3<f64>, f64, Matrix3<f64>) {
    let fr = rot.transpose() * f;
    let mut eps = (fr + fr.transpose()) * 0.5;
    eps[(0, 0)] -= 1.0;
    eps[(1, 1)] -= 1.0;
    eps[(2, 2)] -= 1.0;
    let tr = eps.trace();
    let mut sigma = eps * (2.0 * mu);
    sigma[(0, 0)] += lambda * tr;
    sigma[(1, 1)] += lambda * tr;
    sigma[(2, 2)] += lambda * tr;
    (eps, tr, sigma)
}

/// Adds `k_scale · R K0 Rᵀ` of a linear corotational element to the packed f32 upper
/// triangle the CG solver reads (`blocks`, 9 column-major entries a block) at `scatter`;
/// with `replaced` = Some(R_old), adds `k_scale · (R K0 Rᵀ − R_old K0 R_oldᵀ)` instead (the
/// element's blocks re-rotated in place; the rotation-free μV(g_a·g_b) I part cancels). The
/// stiffness scale is folded into the two material factors, so a block costs two scaled
/// outer products (K_ab = cμ ĝ_b ĝ_aᵀ + cλ ĝ_a ĝ_bᵀ + cμ (g_a·g_b) I).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(crate) fn corotational_stiffness_upper(
    rest: &TetRest,
    rot: &Matrix3<f64>,
    replaced: Option<&Matrix3<f64>>,
    mu: f64,
    lambda: f64,
    k_scale: f64,
    scatter: &UpperScatter,
    blocks: &mut [f32],
) {
    let v = rest.volume;
    let cm = v * mu * k_scale;
    let cl = v * lambda * k_scale;
    let rotated = |r: &Matrix3<f64>| {
        let mut gh = [[0.0f64; 3]; 4];
        let mut u = [[0.0f64; 3]; 4];
        let mut w = [[0.0f64; 3]; 4];
        for a in 0..4 {
            let g = r * rest.grad[a];
            gh[a] = [g.x, g.y, g.z];
            u[a] = [g.x * cm, g.y * cm, g.z * cm];
            w[a] = [g.x * cl, g.y * cl, g.z * cl];
        }
        (gh, u, w)
    };
    let (gh, u, w) = rotated(rot);
    let old = replaced.map(rotated);
    for (&(a0, b0), &target) in UPPER_PAIRS.iter().zip(scatter) {
        if target == super::sparse::NO_BLOCK {
            continue;
        }
        // A transposed target holds K_ba = the same formula with the roles swapped.
        let (a, b) = if target & TRANSPOSED != 0 {
            (b0, a0)
        } else {
            (a0, b0)
        };
        let k = 9 * (target & !TRANSPOSED) as usize;
        let m = &mut blocks[k..k + 9];
        match &old {
            None => {
                let d = cm * rest.grad[a].dot(&rest.grad[b]);
                for c in 0..3 {
                    for r in 0..3 {
                        let diag = if r == c { d } else { 0.0 };
                        m[3 * c + r] += (u[b][r] * gh[a][c] + w[a][r] * gh[b][c] + diag) as f32;
                    }
                }
            }
            Some((gh0, u0, w0)) => {
                for c in 0..3 {
                    for r in 0..3 {
                        let now = u[b][r] * gh[a][c] + w[a][r] * gh[b][c];
                        let before = u0[b][r] * gh0[a][c] + w0[a][r] * gh0[b][c];
                        m[3 * c + r] += (now - before) as f32;
                    }
                }
            }
        }
    }
}

/// Adds `k_scale · R K0 Rᵀ` of a linear corotational element to both triangles of the f64
/// system `a` at the tet's 4×4 block map `blocks` (`NO_BLOCK` where a node is held): the
/// blocks of [`corotational`] ([`corotational_block`]), with the stiffness scale folded into
/// the material factors, and K_ba = K_abᵀ.
#[inline(always)]
pub(crate) fn corotational_stiffness_full(
    rest: &TetRest,
    rot: &Matrix3<f64>,
    mu: f64,
    lambda: f64,
    k_scale: f64,
    blocks: &[u32; 16],
    a: &mut [Matrix3<f64>],
) {
    let v = rest.volume;
    let cm = v * mu * k_scale;
    let cl = v * lambda * k_scale;
    let gh = rest.grad.map(|g| rot * g);
    for &(ia, ib) in &UPPER_PAIRS {
        let idx = blocks[ia * 4 + ib];
        if idx == super::sparse::NO_BLOCK {
            continue;
        }
        let m = corotational_block(&gh, &rest.grad, ia, ib, cm, cl);
        a[idx as usize] += m;
        if ia != ib {
            a[blocks[ib * 4 + ia] as usize] += m.transpose();
        }
    }
}

/// Skew matrix [v]× (v × w = [v]× w).
#[inline]
fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Stable neo-Hookean element (Smith et al. 2018; energy in the form of Kim & Eberle 2022):
/// Ψ = μ/2 (I_C − 3) − μ (J − 1) + λ'/2 (J − 1)² with λ' = λ + μ so that it linearizes to
/// the same Lamé parameters as linear elasticity. Rest-stable and finite for J ≤ 0, so
/// inverted elements are pushed back. `project` clamps the 9×9 Hessian's negative
/// eigenvalues (PSD tangent, safe for CG); otherwise the consistent tangent is returned.
pub(crate) fn stable_neo_hookean(
    rest: &TetRest,
    f: &Matrix3<f64>,
    mu: f64,
    lambda: f64,
    project: bool,
    want_k: bool,
    out: &mut ElementOutput,
) {
    let v = rest.volume;
    let lam = lambda + mu;
    let j = f.determinant();
    let cof = cofactor(f);
    let ic = f.norm_squared();
    out.energy = v * (0.5 * mu * (ic - 3.0) - mu * (j - 1.0) + 0.5 * lam * (j - 1.0) * (j - 1.0));
    let s = lam * (j - 1.0) - mu;
    let p = f * mu + cof * s;
    for a in 0..4 {
        out.force[a] = -(p * rest.grad[a]) * v;
    }
    if !want_k {
        return;
    }
    // K_ab = V Σ_{j,m} g_a[j] H[(j,·),(m,·)] g_b[m] for the tangent H = μ I + λ' vec(C) vec(C)ᵀ
    // + s H_J (C = cof F), less its negative modes λ_n vec(Q_n) vec(Q_n)ᵀ when projected;
    // vec index 3j + k holds F_kj. Term by term the contraction is μ (g_a·g_b) I,
    // λ' (C g_a)(C g_b)ᵀ, −s [F (g_a × g_b)]× and λ_n (Q_n g_a)(Q_n g_b)ᵀ: a few 3-vectors per
    // node instead of the 9×9 tangent, which was most of a neo-Hookean replay's time.
    let modes = if project {
        negative_modes(f, mu, lam, s)
    } else {
        NegativeModes::default()
    };
    let g = &rest.grad;
    let cg = g.map(|ga| cof * ga);
    let mut qg = [[Vector3::zeros(); 4]; MAX_NEGATIVE_MODES];
    for (n, (_, q)) in modes.iter().enumerate() {
        for a in 0..4 {
            qg[n][a] = q * g[a];
        }
    }
    for a in 0..4 {
        for b in a..4 {
            let mut m = cg[a] * (cg[b] * lam).transpose() - skew(&(f * g[a].cross(&g[b]))) * s;
            let d = mu * g[a].dot(&g[b]);
            m[(0, 0)] += d;
            m[(1, 1)] += d;
            m[(2, 2)] += d;
            for (n, (eigenvalue, _)) in modes.iter().enumerate() {
                m -= qg[n][a] * (qg[n][b] * *eigenvalue).transpose();
            }
            out.k[a][b] = m * v;
        }
    }
}

/// cof F = J F⁻ᵀ, from cross products of F's columns so that it stays finite for a flat or
/// inverted element (∂J/∂F).
fn cofactor(f: &Matrix3<f64>) -> Matrix3<f64> {
    let (f0, f1, f2) = (f.column(0), f.column(1), f.column(2));
    Matrix3::from_columns(&[f1.cross(&f2), f2.cross(&f0), f0.cross(&f1)])
}

/// dP/dF of the stable neo-Hookean energy in column-major vec(F) ordering:
/// μ I + λ' g gᵀ + s H_J, with g = vec(cof F), s = λ'(J − 1) − μ and H_J the Hessian of det F
/// (the tests' oracle for [`stable_neo_hookean`]'s contraction).
#[cfg(test)]
fn stable_neo_hookean_tangent(
    f: &Matrix3<f64>,
    cof: &Matrix3<f64>,
    mu: f64,
    lam: f64,
    s: f64,
) -> Tangent9 {
    let (f0, f1, f2) = (
        f.column(0).into_owned(),
        f.column(1).into_owned(),
        f.column(2).into_owned(),
    );
    let mut h = Tangent9::identity() * mu;
    let g = SMatrix::<f64, 9, 1>::from_column_slice(cof.as_slice());
    h += g * g.transpose() * lam;
    let blocks = [
        (0, 1, -skew(&f2)),
        (0, 2, skew(&f1)),
        (1, 0, skew(&f2)),
        (1, 2, -skew(&f0)),
        (2, 0, -skew(&f1)),
        (2, 1, skew(&f0)),
    ];
    for (pi, qi, m) in blocks.iter() {
        let mut view = h.fixed_view_mut::<3, 3>(3 * pi, 3 * qi);
        view += m * s;
    }
    h
}

/// The negative modes of the stable neo-Hookean tangent, from its analytic eigensystem (Smith,
/// de Goes & Kim 2018, §4.4; Smith et al. 2019): each eigenvalue λ_n < 0 with its unit
/// eigenvector as a matrix Q_n (vec(Q_n), column-major). Clamping them to zero subtracts
/// λ_n vec(Q_n) vec(Q_n)ᵀ, the same projection as clamping a numeric 9×9 eigendecomposition at
/// a 3×3 SVD's cost. With the rotation-variant SVD F = U Σ Vᵀ (det U = det V = 1, σ₂ carries
/// the sign of J), the tangent μ I + λ' g gᵀ + s H_J is block-diagonal in the basis U D Vᵀ:
/// - for each axis i with (j, k) the other two, a twist (D = e_j e_kᵀ − e_k e_jᵀ) with
///   eigenvalue μ + s σ_i and a flip (D = e_j e_kᵀ + e_k e_jᵀ) with μ − s σ_i;
/// - on diagonal D a 3×3 block μ I + λ' c cᵀ + s [σ_k off the diagonal], c_i = σ_j σ_k.
fn negative_modes(f: &Matrix3<f64>, mu: f64, lam: f64, s: f64) -> NegativeModes {
    let mut modes = NegativeModes::default();
    let Some((u, sigma, v)) = rotation_variant_svd(f) else {
        // A failed SVD (non-finite F) leaves the tangent as it is; the step's own NaN
        // quarantine deals with the state.
        return modes;
    };
    let mut add = |eigenvalue: f64, d: &Matrix3<f64>| {
        if eigenvalue < 0.0 {
            modes.push(eigenvalue, u * d * v.transpose());
        }
    };
    let r = std::f64::consts::FRAC_1_SQRT_2;
    for i in 0..3 {
        let (j, k) = ((i + 1) % 3, (i + 2) % 3);
        let mut twist = Matrix3::zeros();
        twist[(j, k)] = r;
        twist[(k, j)] = -r;
        add(mu + s * sigma[i], &twist);
        let mut flip = Matrix3::zeros();
        flip[(j, k)] = r;
        flip[(k, j)] = r;
        add(mu - s * sigma[i], &flip);
    }
    let c = Vector3::new(
        sigma[1] * sigma[2],
        sigma[0] * sigma[2],
        sigma[0] * sigma[1],
    );
    let mut scaling = Matrix3::identity() * mu + c * c.transpose() * lam;
    for i in 0..3 {
        let (j, k) = ((i + 1) % 3, (i + 2) % 3);
        scaling[(j, k)] += s * sigma[i];
        scaling[(k, j)] += s * sigma[i];
    }
    // The scaling modes carry λ' and stay definite unless an element is crushed: a Cholesky
    // factor proves it at a fraction of the eigendecomposition's cost, which was a third of
    // what the projection still cost.
    if scaling.cholesky().is_some() {
        return modes;
    }
    let eig = SymmetricEigen::new(scaling);
    for n in 0..3 {
        let w = eig.eigenvectors.column(n);
        add(eig.eigenvalues[n], &Matrix3::from_diagonal(&w.into_owned()));
    }
    modes
}

/// The tangent has nine modes.
const MAX_NEGATIVE_MODES: usize = 9;

/// Up to [`MAX_NEGATIVE_MODES`] negative modes of a tangent: eigenvalue and eigenvector as a
/// 3×3 matrix ([`negative_modes`]); fixed capacity, so the element pass does not allocate.
#[derive(Default)]
struct NegativeModes {
    count: usize,
    modes: [(f64, Matrix3<f64>); MAX_NEGATIVE_MODES],
}

impl NegativeModes {
    fn push(&mut self, eigenvalue: f64, q: Matrix3<f64>) {
        if self.count < MAX_NEGATIVE_MODES {
            self.modes[self.count] = (eigenvalue, q);
            self.count += 1;
        }
    }

    fn iter(&self) -> impl Iterator<Item = &(f64, Matrix3<f64>)> {
        self.modes[..self.count].iter()
    }
}

/// F = U Σ Vᵀ with U and V proper rotations; the last singular value takes the sign of
/// det F. None when F is not finite.
///
/// As nalgebra's 3×3 SVD (McAdams et al. 2011): V from the eigenvectors of FᵀF, then a QR of
/// F V with its columns by decreasing norm. The eigenvectors come from cyclic Jacobi rotations
/// ([`jacobi_eigenvectors`]) and the QR from Gram–Schmidt with u₂ = u₀ × u₁, where nalgebra's
/// general tridiagonal eigensolver and Householder QR took a third of a neo-Hookean replay.
/// Both factors are proper rotations by construction (a product of rotations, a right-handed
/// frame), so σ₂ = u₂·(F v₂) carries the sign of det F.
fn rotation_variant_svd(f: &Matrix3<f64>) -> Option<(Matrix3<f64>, Vector3<f64>, Matrix3<f64>)> {
    if !f.iter().all(|x| x.is_finite()) {
        return None;
    }
    let mut v = jacobi_eigenvectors(f.transpose() * f);
    let mut b = f * v;
    // columns by decreasing norm; a swap negates one column so that det V stays 1
    let mut rho = [0, 1, 2].map(|k| b.column(k).norm_squared());
    for (i, j) in [(0, 1), (0, 2), (1, 2)] {
        if rho[i] < rho[j] {
            b.swap_columns(i, j);
            b.column_mut(j).neg_mut();
            v.swap_columns(i, j);
            v.column_mut(j).neg_mut();
            rho.swap(i, j);
        }
    }
    let (b0, b1, b2) = (
        b.column(0).into_owned(),
        b.column(1).into_owned(),
        b.column(2).into_owned(),
    );
    let n0 = b0.norm();
    if n0 == 0.0 {
        return Some((Matrix3::identity(), Vector3::zeros(), v));
    }
    let u0 = b0 / n0;
    let b1_perp = b1 - u0 * u0.dot(&b1);
    let n1 = b1_perp.norm();
    let u1 = if n1 > 1e-12 * n0 {
        b1_perp / n1
    } else {
        // rank one: any direction across u0 (the axis least along it)
        let k = u0.iamin();
        let mut e = Vector3::zeros();
        e[k] = 1.0;
        u0.cross(&e).normalize()
    };
    let u2 = u0.cross(&u1);
    let sigma = Vector3::new(n0, u1.dot(&b1), u2.dot(&b2));
    Some((Matrix3::from_columns(&[u0, u1, u2]), sigma, v))
}

/// Eigenvectors of the symmetric 3×3 matrix `a` as the columns of a proper rotation: cyclic
/// Jacobi rotations (each a plane rotation, so their product keeps det 1) until the
/// off-diagonal part is round-off against the whole, at most [`JACOBI_SWEEPS`] sweeps
/// (convergence is quadratic: three or four for a deformation gradient's FᵀF).
fn jacobi_eigenvectors(mut a: Matrix3<f64>) -> Matrix3<f64> {
    let mut v = Matrix3::identity();
    let scale = a.norm_squared();
    for _ in 0..JACOBI_SWEEPS {
        let off = a[(0, 1)].powi(2) + a[(0, 2)].powi(2) + a[(1, 2)].powi(2);
        if !(off > 1e-32 * scale) {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            let apq = a[(p, q)];
            if apq == 0.0 {
                continue;
            }
            // the rotation that zeroes a_pq (Numerical Recipes' `jacobi`): t = tan φ, the
            // smaller root, for the stable update
            let theta = (a[(q, q)] - a[(p, p)]) / (2.0 * apq);
            let t = if theta.abs() > 1e150 {
                0.5 / theta
            } else {
                theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt())
            };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            a[(p, p)] -= t * apq;
            a[(q, q)] += t * apq;
            a[(p, q)] = 0.0;
            a[(q, p)] = 0.0;
            let r = 3 - p - q;
            let (arp, arq) = (a[(r, p)], a[(r, q)]);
            a[(r, p)] = c * arp - s * arq;
            a[(p, r)] = a[(r, p)];
            a[(r, q)] = s * arp + c * arq;
            a[(q, r)] = a[(r, q)];
            for k in 0..3 {
                let (vkp, vkq) = (v[(k, p)], v[(k, q)]);
                v[(k, p)] = c * vkp - s * vkq;
                v[(k, q)] = s * vkp + c * vkq;
            }
        }
    }
    v
}

/// At most this many Jacobi sweeps ([`jacobi_eigenvectors`]).
const JACOBI_SWEEPS: usize = 8;

#[cfg(test)]
mod tests {
    use super::*;

    /// The oracle: clamp a numeric 9×9 eigendecomposition (what the element did before).
    fn numeric_projection(h: &Tangent9) -> Tangent9 {
        let eig = SymmetricEigen::new(*h);
        let d = eig.eigenvalues.map(|e| e.max(0.0));
        eig.eigenvectors * Tangent9::from_diagonal(&d) * eig.eigenvectors.transpose()
    }

    /// `h` less its negative modes λ_n vec(Q_n) vec(Q_n)ᵀ.
    fn projected(h: &Tangent9, modes: &NegativeModes) -> Tangent9 {
        let mut out = *h;
        for (eigenvalue, q) in modes.iter() {
            let q = SMatrix::<f64, 9, 1>::from_column_slice(q.as_slice());
            out -= q * q.transpose() * *eigenvalue;
        }
        out
    }

    /// The element's stiffness blocks equal the projected 9×9 tangent contracted with the
    /// shape gradients, K_ab = V Σ_{j,m} g_a[j] H[(j,·),(m,·)] g_b[m] (how the element built
    /// them before it contracted term by term), projected or not, for deformations from
    /// near rest to inverted.
    #[test]
    fn the_neo_hookean_blocks_are_the_contracted_tangent() {
        let (mu, lambda) = (1.3e6, 3.1e6);
        let lam = lambda + mu;
        let mut seed = 5u64;
        let rest_x = [
            nalgebra::Point3::new(0.0, 0.0, 0.0),
            nalgebra::Point3::new(1.1e-3, 0.1e-3, 0.0),
            nalgebra::Point3::new(0.2e-3, 0.9e-3, 0.1e-3),
            nalgebra::Point3::new(0.1e-3, 0.3e-3, 1.2e-3),
        ];
        let rest = TetRest::new([&rest_x[0], &rest_x[1], &rest_x[2], &rest_x[3]]).unwrap();
        let mut gradients = vec![
            Matrix3::identity(),
            Matrix3::from_diagonal(&Vector3::new(1.0, 0.9, -0.3)),
        ];
        for scale in [0.01, 0.3, 1.0] {
            for _ in 0..30 {
                let m = Matrix3::from_fn(|_, _| lcg(&mut seed) * scale);
                let rot = nalgebra::Rotation3::new(Vector3::from_fn(|_, _| lcg(&mut seed) * 3.0));
                gradients.push(rot.matrix() * (Matrix3::identity() + m));
            }
        }
        for f in &gradients {
            let x = rest_x.map(|p| f * p.coords);
            let f_tet = rest.deformation_gradient(x);
            let s = lam * (f_tet.determinant() - 1.0) - mu;
            for project in [false, true] {
                let mut out = ElementOutput::zero();
                stable_neo_hookean(&rest, &f_tet, mu, lambda, project, true, &mut out);
                let mut h = stable_neo_hookean_tangent(&f_tet, &cofactor(&f_tet), mu, lam, s);
                if project {
                    h = projected(&h, &negative_modes(&f_tet, mu, lam, s));
                }
                let scale = h.abs().max() * rest.volume * rest.grad[0].norm_squared();
                for a in 0..4 {
                    for b in a..4 {
                        let (ga, gb) = (rest.grad[a], rest.grad[b]);
                        let mut oracle = Matrix3::zeros();
                        for j in 0..3 {
                            for m in 0..3 {
                                oracle += h.fixed_view::<3, 3>(3 * j, 3 * m) * (ga[j] * gb[m]);
                            }
                        }
                        oracle *= rest.volume;
                        let err = (out.k[a][b] - oracle).amax();
                        assert!(
                            err <= 1e-12 * scale,
                            "F = {f_tet}, project {project}: K_{a}{b} off by {err:e}"
                        );
                    }
                }
            }
        }
    }

    fn lcg(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*seed >> 11) as f64) / ((1u64 << 53) as f64) * 2.0 - 1.0
    }

    /// The Jacobi SVD factors F into proper rotations around singular values that match
    /// nalgebra's (signed: the last takes det F's sign), on near-identity, inverted, flat,
    /// rank-one and strongly stretched gradients.
    #[test]
    fn the_rotation_variant_svd_factors_into_proper_rotations() {
        let mut seed = 11u64;
        let mut cases = vec![
            Matrix3::identity(),
            Matrix3::from_diagonal(&Vector3::new(1.0, 0.9, -0.3)),
            Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 0.0)),
            Matrix3::from_diagonal(&Vector3::new(2.0, 2.0, 2.0)),
            Vector3::new(1.0, 2.0, 3.0) * Vector3::new(0.5, -1.0, 0.25).transpose(),
        ];
        for scale in [1e-6, 0.05, 0.3, 1.0, 3.0] {
            for _ in 0..60 {
                let m = Matrix3::from_fn(|_, _| lcg(&mut seed) * scale);
                let rot = nalgebra::Rotation3::new(Vector3::from_fn(|_, _| lcg(&mut seed) * 3.0));
                cases.push(rot.matrix() * (Matrix3::identity() + m));
            }
        }
        for f in &cases {
            let (u, sigma, v) = rotation_variant_svd(f).expect("finite F");
            let tol = 1e-12 * f.norm().max(1.0);
            let back = u * Matrix3::from_diagonal(&sigma) * v.transpose();
            assert!(
                (back - f).amax() <= tol,
                "F = {f}: U Σ Vᵀ off by {:e}",
                (back - f).amax()
            );
            for q in [&u, &v] {
                assert!((q.transpose() * q - Matrix3::identity()).amax() <= 1e-12);
                assert!((q.determinant() - 1.0).abs() <= 1e-12);
            }
            let mut reference = f.svd(false, false).singular_values.as_slice().to_vec();
            reference.sort_by(|a, b| b.total_cmp(a));
            let ours = [sigma[0], sigma[1], sigma[2].abs()];
            for (a, b) in ours.iter().zip(&reference) {
                assert!(
                    (a - b).abs() <= tol,
                    "F = {f}: σ {ours:?} against {reference:?}"
                );
            }
            let det = f.determinant();
            if det.abs() > 1e-9 {
                assert_eq!(sigma[2].signum(), det.signum(), "F = {f}");
            }
        }
        assert!(rotation_variant_svd(&Matrix3::from_element(f64::NAN)).is_none());
    }

    #[test]
    fn the_analytic_projection_equals_the_numeric_one() {
        let (mu, lambda) = (1.3e6, 3.1e6);
        let lam = lambda + mu;
        let mut seed = 7u64;
        let mut cases = vec![
            Matrix3::identity(),
            Matrix3::from_diagonal(&Vector3::new(0.8, 0.8, 1.1)),
            Matrix3::from_diagonal(&Vector3::new(1.2, 1.2, 1.2)),
            // Inverted along one axis, and a flat element.
            Matrix3::from_diagonal(&Vector3::new(1.0, 0.9, -0.3)),
            Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 0.0)),
        ];
        for scale in [0.05, 0.3, 1.0] {
            for _ in 0..40 {
                let m = Matrix3::from_fn(|_, _| lcg(&mut seed) * scale);
                let rot = nalgebra::Rotation3::new(Vector3::from_fn(|_, _| lcg(&mut seed) * 3.0));
                cases.push(rot.matrix() * (Matrix3::identity() + m));
            }
        }
        let mut indefinite = 0;
        for f in &cases {
            let s = lam * (f.determinant() - 1.0) - mu;
            let h = stable_neo_hookean_tangent(f, &cofactor(f), mu, lam, s);
            let numeric = numeric_projection(&h);
            let analytic = projected(&h, &negative_modes(f, mu, lam, s));
            if SymmetricEigen::new(h).eigenvalues.min() < -1e-9 * mu {
                indefinite += 1;
            }
            let err = (analytic - numeric).abs().max();
            assert!(
                err <= 1e-9 * h.abs().max(),
                "F = {f}: analytic and numeric projections differ by {err:e}"
            );
            assert!(SymmetricEigen::new(analytic).eigenvalues.min() >= -1e-8 * mu);
        }
        // The cases must exercise the clamp, not only pass through definite tangents.
        assert!(
            indefinite > cases.len() / 4,
            "only {indefinite} indefinite tangents"
        );
    }
}
