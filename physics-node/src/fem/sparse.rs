//! Sparse storage of the FEM system: a 3×3-block CSR pattern over the free nodes, built once
//! from the tets, whose values are overwritten in place every step; and a faer sparse
//! Cholesky that keeps its symbolic analysis and reuses preallocated memory, so numeric
//! refactorization and solves do not allocate.

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky,
    SymmetricOrdering,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};
use nalgebra::Matrix3;

use super::element::{UpperScatter, TRANSPOSED, UPPER_PAIRS};
use super::FemError;

/// Marks "no block" (a pair with a held node) in per-element block maps.
pub(crate) const NO_BLOCK: u32 = u32::MAX;

/// Symmetric 3×3-block CSR pattern (both triangles stored, so products are one pass).
#[derive(Debug, Clone)]
/// Fields are crate-private so the invariants (sorted rows, column indices < n) that the
/// unchecked product relies on cannot be broken from outside.
pub struct BlockPattern {
    /// Number of block rows (free nodes).
    pub(crate) n: usize,
    pub(crate) row_ptr: Vec<usize>,
    pub(crate) cols: Vec<u32>,
    /// Position of the diagonal block of each row in `cols`.
    pub(crate) diag: Vec<usize>,
}

impl BlockPattern {
    /// Pattern of the tets' node couplings restricted to free nodes (`free_index[node]` is the
    /// free row or `NO_BLOCK`); returns the pattern and, per tet, the block index of each
    /// local pair (a, b) at `a * 4 + b`.
    pub(crate) fn from_tets(
        free_index: &[u32],
        n_free: usize,
        tets: &[[usize; 4]],
    ) -> (BlockPattern, Vec<[u32; 16]>) {
        let mut neighbours: Vec<Vec<u32>> = (0..n_free).map(|i| vec![i as u32]).collect();
        for t in tets {
            for &a in t {
                let fa = free_index[a];
                if fa == NO_BLOCK {
                    continue;
                }
                for &b in t {
                    let fb = free_index[b];
                    if fb != NO_BLOCK {
                        neighbours[fa as usize].push(fb);
                    }
                }
            }
        }
        let mut row_ptr = Vec::with_capacity(n_free + 1);
        let mut cols = Vec::new();
        let mut diag = Vec::with_capacity(n_free);
        row_ptr.push(0);
        for (i, nb) in neighbours.iter_mut().enumerate() {
            nb.sort_unstable();
            nb.dedup();
            let start = cols.len();
            let d = nb.binary_search(&(i as u32)).expect("diagonal present");
            diag.push(start + d);
            cols.extend_from_slice(nb);
            row_ptr.push(cols.len());
        }
        let pattern = BlockPattern {
            n: n_free,
            row_ptr,
            cols,
            diag,
        };
        let elem_blocks = tets
            .iter()
            .map(|t| {
                let mut m = [NO_BLOCK; 16];
                for a in 0..4 {
                    for b in 0..4 {
                        let (fa, fb) = (free_index[t[a]], free_index[t[b]]);
                        if fa != NO_BLOCK && fb != NO_BLOCK {
                            m[a * 4 + b] = pattern.find(fa as usize, fb as usize) as u32;
                        }
                    }
                }
                m
            })
            .collect();
        (pattern, elem_blocks)
    }

    /// Block index of (row, col); panics if absent (pattern construction only).
    pub(crate) fn find(&self, row: usize, col: usize) -> usize {
        let s = &self.cols[self.row_ptr[row]..self.row_ptr[row + 1]];
        self.row_ptr[row] + s.binary_search(&(col as u32)).expect("block in pattern")
    }

    /// Number of block rows (free nodes).
    pub fn block_rows(&self) -> usize {
        self.n
    }
    /// Row pointers into [`Self::block_cols`].
    pub fn row_ptr(&self) -> &[usize] {
        &self.row_ptr
    }
    /// Block column of each stored block.
    pub fn block_cols(&self) -> &[u32] {
        &self.cols
    }
    /// Index of each row's diagonal block.
    pub fn diagonal(&self) -> &[usize] {
        &self.diag
    }

    pub fn nnz_blocks(&self) -> usize {
        self.cols.len()
    }

    /// y = A x for block values `a` on this pattern (flat vectors, 3 per row).
    pub fn mul(&self, a: &[Matrix3<f64>], x: &[f64], y: &mut [f64]) {
        self.mul_dot(a, x, y);
    }

    /// y = A x, returning x·y (CG needs both; one pass over memory).
    pub fn mul_dot(&self, a: &[Matrix3<f64>], x: &[f64], y: &mut [f64]) -> f64 {
        let n = self.n;
        assert!(a.len() >= self.cols.len() && x.len() >= 3 * n && y.len() >= 3 * n);
        assert!(self.row_ptr.len() == n + 1 && self.row_ptr[n] <= self.cols.len());
        let mut dot = 0.0;
        for i in 0..n {
            let (mut s0, mut s1, mut s2) = (0.0, 0.0, 0.0);
            // SAFETY: row_ptr is non-decreasing and ends within `cols`/`a` (asserted above and
            // by construction), every column index is < n, and x has 3n entries.
            unsafe {
                let (k0, k1) = (
                    *self.row_ptr.get_unchecked(i),
                    *self.row_ptr.get_unchecked(i + 1),
                );
                for k in k0..k1 {
                    let j = *self.cols.get_unchecked(k) as usize * 3;
                    let m = a.get_unchecked(k).as_slice();
                    let (x0, x1, x2) = (
                        *x.get_unchecked(j),
                        *x.get_unchecked(j + 1),
                        *x.get_unchecked(j + 2),
                    );
                    // Column-major 3×3.
                    s0 += m[0] * x0 + m[3] * x1 + m[6] * x2;
                    s1 += m[1] * x0 + m[4] * x1 + m[7] * x2;
                    s2 += m[2] * x0 + m[5] * x1 + m[8] * x2;
                }
            }
            y[3 * i] = s0;
            y[3 * i + 1] = s1;
            y[3 * i + 2] = s2;
            dot += s0 * x[3 * i] + s1 * x[3 * i + 1] + s2 * x[3 * i + 2];
        }
        dot
    }
}

impl BlockPattern {
    /// y = A x reading only the diagonal and upper blocks (A symmetric: the lower block
    /// (j, i) is the transpose of the upper (i, j)), returning x·y. Half the memory traffic
    /// of [`Self::mul_dot`]; lower blocks of `a` may be stale. Same result up to the order
    /// of the sums.
    pub(crate) fn mul_dot_upper(&self, a: &[Matrix3<f64>], x: &[f64], y: &mut [f64]) -> f64 {
        let n = self.n;
        assert!(a.len() >= self.cols.len() && x.len() >= 3 * n && y.len() >= 3 * n);
        assert!(self.row_ptr.len() == n + 1 && self.row_ptr[n] <= self.cols.len());
        assert!(self.diag.len() == n);
        y[..3 * n].fill(0.0);
        let mut dot = 0.0;
        for i in 0..n {
            // SAFETY: as in `mul_dot`; in addition diag[i] lies in row i's range and the
            // columns after it are sorted and > i (hence < n), so every y index is < 3n.
            unsafe {
                let (d, k1) = (
                    *self.diag.get_unchecked(i),
                    *self.row_ptr.get_unchecked(i + 1),
                );
                let (xi0, xi1, xi2) = (
                    *x.get_unchecked(3 * i),
                    *x.get_unchecked(3 * i + 1),
                    *x.get_unchecked(3 * i + 2),
                );
                let m = a.get_unchecked(d).as_slice();
                // Column-major 3×3. y[i] already holds the transposed contributions of the
                // rows above.
                let mut s0 = *y.get_unchecked(3 * i) + m[0] * xi0 + m[3] * xi1 + m[6] * xi2;
                let mut s1 = *y.get_unchecked(3 * i + 1) + m[1] * xi0 + m[4] * xi1 + m[7] * xi2;
                let mut s2 = *y.get_unchecked(3 * i + 2) + m[2] * xi0 + m[5] * xi1 + m[8] * xi2;
                for k in d + 1..k1 {
                    let j = *self.cols.get_unchecked(k) as usize * 3;
                    let m = a.get_unchecked(k).as_slice();
                    let (x0, x1, x2) = (
                        *x.get_unchecked(j),
                        *x.get_unchecked(j + 1),
                        *x.get_unchecked(j + 2),
                    );
                    s0 += m[0] * x0 + m[3] * x1 + m[6] * x2;
                    s1 += m[1] * x0 + m[4] * x1 + m[7] * x2;
                    s2 += m[2] * x0 + m[5] * x1 + m[8] * x2;
                    // Lower block (j, i) = mᵀ.
                    *y.get_unchecked_mut(j) += m[0] * xi0 + m[1] * xi1 + m[2] * xi2;
                    *y.get_unchecked_mut(j + 1) += m[3] * xi0 + m[4] * xi1 + m[5] * xi2;
                    *y.get_unchecked_mut(j + 2) += m[6] * xi0 + m[7] * xi1 + m[8] * xi2;
                }
                *y.get_unchecked_mut(3 * i) = s0;
                *y.get_unchecked_mut(3 * i + 1) = s1;
                *y.get_unchecked_mut(3 * i + 2) = s2;
                dot += s0 * xi0 + s1 * xi1 + s2 * xi2;
            }
        }
        dot
    }
}

/// The diagonal and upper blocks of a matrix on a [`BlockPattern`], packed row after row
/// (diagonal first) in single precision: what the CG products read. The packed upper
/// triangle of the 2,560-node default mesh is 0.7 MB in f32 against 1.4 MB in f64 (plus the
/// unused lower blocks interleaved), which lets the 26 products of a step run from the 1 MB
/// L2 cache instead of L3; they were memory-bound, not arithmetic-bound. Entries keep 7
/// significant digits, far below what a 25-iteration CG resolves; products accumulate in f64.
#[derive(Debug, Clone)]
pub(crate) struct UpperF32 {
    n: usize,
    /// Block row starts into `cols` (n + 1 entries).
    row_ptr: Vec<usize>,
    cols: Vec<u32>,
    /// 9 column-major entries per block, then 4 zeros so a 4-lane read of the last block's
    /// third column stays inside.
    vals: Vec<f32>,
    /// The mirrored contributions, 4 lanes per row: 4-lane updates of a 3-strided vector
    /// would overlap the next node's entries and stall store-to-load forwarding.
    mirrored: Vec<f64>,
    /// A diagonal shift per row (the step's mass and support terms), f64, added by shifted
    /// products: kept apart so the stiffness blocks can persist across steps.
    shift: Vec<f64>,
}

impl UpperF32 {
    pub(crate) fn new(p: &BlockPattern) -> Self {
        let mut row_ptr = Vec::with_capacity(p.n + 1);
        let mut cols = Vec::new();
        row_ptr.push(0);
        for i in 0..p.n {
            cols.extend_from_slice(&p.cols[p.diag[i]..p.row_ptr[i + 1]]);
            row_ptr.push(cols.len());
        }
        let vals = vec![0.0; 9 * cols.len() + 4];
        UpperF32 {
            n: p.n,
            row_ptr,
            cols,
            vals,
            mirrored: vec![0.0; 4 * p.n],
            shift: vec![0.0; p.n],
        }
    }

    /// Per tet, where each of its [`UPPER_PAIRS`] goes in the packed blocks (see
    /// [`UpperScatter`]), from the per-pair block map of [`BlockPattern::from_tets`].
    pub(crate) fn scatter(
        &self,
        p: &BlockPattern,
        free_index: &[u32],
        tets: &[[usize; 4]],
        elem_blocks: &[[u32; 16]],
    ) -> Vec<UpperScatter> {
        tets.iter()
            .zip(elem_blocks)
            .map(|(t, eb)| {
                let mut s = [NO_BLOCK; 10];
                for (target, &(a, b)) in s.iter_mut().zip(UPPER_PAIRS.iter()) {
                    let (fa, fb) = (free_index[t[a]], free_index[t[b]]);
                    if fa == NO_BLOCK || fb == NO_BLOCK {
                        continue;
                    }
                    // The block lies in the row of the earlier free node; packed rows start
                    // at their diagonal.
                    let (row, full, flag) = if fa <= fb {
                        (fa as usize, eb[a * 4 + b] as usize, 0)
                    } else {
                        (fb as usize, eb[b * 4 + a] as usize, TRANSPOSED)
                    };
                    *target = (full - p.diag[row] + self.row_ptr[row]) as u32 | flag;
                }
                s
            })
            .collect()
    }

    /// All packed entries to zero (before an element pass adds into them).
    pub(crate) fn clear(&mut self) {
        self.vals.fill(0.0);
    }

    /// The packed blocks, 9 column-major entries each (an element pass adds into them).
    pub(crate) fn blocks_mut(&mut self) -> &mut [f32] {
        let n = self.vals.len() - 4;
        &mut self.vals[..n]
    }

    /// Sets row `row`'s diagonal shift (see `shift`).
    pub(crate) fn set_shift(&mut self, row: usize, d: f64) {
        self.shift[row] = d;
    }

    /// Row `row`'s diagonal block, with its shift when `shifted`.
    pub(crate) fn diagonal_block(&self, row: usize, shifted: bool) -> Matrix3<f64> {
        let k = 9 * self.row_ptr[row];
        let m = Matrix3::from_iterator(self.vals[k..k + 9].iter().map(|&v| v as f64));
        if shifted {
            m + Matrix3::identity() * self.shift[row]
        } else {
            m
        }
    }

    /// Packs the diagonal and upper blocks of `a` (on the pattern this was built from).
    pub(crate) fn pack(&mut self, p: &BlockPattern, a: &[Matrix3<f64>]) {
        let mut out = self.vals.chunks_exact_mut(9);
        for i in 0..self.n {
            for blk in &a[p.diag[i]..p.row_ptr[i + 1]] {
                let dst = out.next().expect("packed size matches the pattern");
                for (d, &v) in dst.iter_mut().zip(blk.as_slice()) {
                    *d = v as f32;
                }
            }
        }
    }

    /// y = A x with A symmetric (the lower triangle read as the transposed upper), plus the
    /// diagonal shift when `shifted`; returns x·y, as [`BlockPattern::mul_dot_upper`].
    pub(crate) fn mul_dot(&mut self, x: &[f64], y: &mut [f64], shifted: bool) -> f64 {
        let n = self.n;
        assert!(x.len() >= 3 * n && y.len() >= 3 * n);
        assert!(self.vals.len() == 9 * self.cols.len() + 4 && self.row_ptr.len() == n + 1);
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                // SAFETY: the features were just detected; the shape was asserted above.
                return unsafe { self.mul_dot_avx2(x, y, shifted) };
            }
        }
        self.mul_dot_portable(x, y, shifted)
    }

    /// [`Self::mul_dot`] without SIMD (CPUs without AVX2/FMA).
    pub(crate) fn mul_dot_portable(&self, x: &[f64], y: &mut [f64], shifted: bool) -> f64 {
        let n = self.n;
        y[..3 * n].fill(0.0);
        let mut dot = 0.0;
        for i in 0..n {
            let xi = [x[3 * i], x[3 * i + 1], x[3 * i + 2]];
            let d = if shifted { self.shift[i] } else { 0.0 };
            let mut s = [
                y[3 * i] + d * xi[0],
                y[3 * i + 1] + d * xi[1],
                y[3 * i + 2] + d * xi[2],
            ];
            for k in self.row_ptr[i]..self.row_ptr[i + 1] {
                let j = self.cols[k] as usize * 3;
                let m = &self.vals[9 * k..9 * k + 9];
                let xj = [x[j], x[j + 1], x[j + 2]];
                for r in 0..3 {
                    s[r] += m[r] as f64 * xj[0] + m[3 + r] as f64 * xj[1] + m[6 + r] as f64 * xj[2];
                }
                if k == self.row_ptr[i] {
                    continue; // the diagonal block has no mirror
                }
                for c in 0..3 {
                    y[j + c] += m[3 * c] as f64 * xi[0]
                        + m[3 * c + 1] as f64 * xi[1]
                        + m[3 * c + 2] as f64 * xi[2];
                }
            }
            y[3 * i..3 * i + 3].copy_from_slice(&s);
            dot += s[0] * xi[0] + s[1] * xi[1] + s[2] * xi[2];
        }
        dot
    }

    /// [`Self::mul_dot`] with 4-lane AVX2/FMA arithmetic: each block's columns are read as
    /// 4 floats (the fourth belongs to the next column and is ignored), widened to f64; the
    /// upper product `M x_j` is three FMAs and the mirrored `Mᵀ x_i` three products and a
    /// horizontal reduction. Sums in another order than the portable path.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn mul_dot_avx2(&mut self, x: &[f64], y: &mut [f64], shifted: bool) -> f64 {
        use std::arch::x86_64::*;
        let n = self.n;
        self.mirrored.fill(0.0);
        let vp = self.vals.as_ptr();
        let mp = self.mirrored.as_mut_ptr();
        let yp = y.as_mut_ptr();
        let xp = x.as_ptr();
        let mut dot = 0.0;
        for i in 0..n {
            let (k0, k1) = (
                *self.row_ptr.get_unchecked(i),
                *self.row_ptr.get_unchecked(i + 1),
            );
            let (xi0, xi1, xi2) = (*xp.add(3 * i), *xp.add(3 * i + 1), *xp.add(3 * i + 2));
            let xi = _mm256_set_pd(0.0, xi2, xi1, xi0);
            // The transposed contributions of the rows above, and the shift.
            let mut s = _mm256_loadu_pd(mp.add(4 * i));
            if shifted {
                s = _mm256_fmadd_pd(_mm256_set1_pd(*self.shift.get_unchecked(i)), xi, s);
            }
            let m = vp.add(9 * k0);
            s = _mm256_fmadd_pd(_mm256_cvtps_pd(_mm_loadu_ps(m)), _mm256_set1_pd(xi0), s);
            s = _mm256_fmadd_pd(
                _mm256_cvtps_pd(_mm_loadu_ps(m.add(3))),
                _mm256_set1_pd(xi1),
                s,
            );
            s = _mm256_fmadd_pd(
                _mm256_cvtps_pd(_mm_loadu_ps(m.add(6))),
                _mm256_set1_pd(xi2),
                s,
            );
            for k in k0 + 1..k1 {
                let col = *self.cols.get_unchecked(k) as usize;
                let j = 3 * col;
                let m = vp.add(9 * k);
                let c0 = _mm256_cvtps_pd(_mm_loadu_ps(m));
                let c1 = _mm256_cvtps_pd(_mm_loadu_ps(m.add(3)));
                let c2 = _mm256_cvtps_pd(_mm_loadu_ps(m.add(6)));
                // The block's product first, then one add: three FMAs chained on `s` made
                // every block wait for the previous one's latency.
                let mut mx = _mm256_mul_pd(c0, _mm256_broadcast_sd(&*xp.add(j)));
                mx = _mm256_fmadd_pd(c1, _mm256_broadcast_sd(&*xp.add(j + 1)), mx);
                mx = _mm256_fmadd_pd(c2, _mm256_broadcast_sd(&*xp.add(j + 2)), mx);
                s = _mm256_add_pd(s, mx);
                // Lower block (j, i) = Mᵀ: y_j[c] += column c · x_i (x_i's lane 3 is 0, which
                // clears the foreign fourth lane of every column).
                let t0 = _mm256_mul_pd(c0, xi);
                let t1 = _mm256_mul_pd(c1, xi);
                let t2 = _mm256_mul_pd(c2, xi);
                let h01 = _mm256_hadd_pd(t0, t1); // [t0₀₁, t1₀₁, t0₂₃, t1₂₃]
                let h22 = _mm256_hadd_pd(t2, t2); // [t2₀₁, t2₀₁, t2₂₃, t2₂₃]
                let lo = _mm256_blend_pd::<0b1100>(h01, h22); // [t0₀₁, t1₀₁, t2₂₃, ·]
                let hi = _mm256_permute2f128_pd::<0x21>(h01, h22); // [t0₂₃, t1₂₃, t2₀₁, ·]
                let mj = mp.add(4 * col);
                _mm256_storeu_pd(
                    mj,
                    _mm256_add_pd(_mm256_loadu_pd(mj), _mm256_add_pd(lo, hi)),
                );
            }
            let mut t = [0.0f64; 4];
            _mm256_storeu_pd(t.as_mut_ptr(), s);
            *yp.add(3 * i) = t[0];
            *yp.add(3 * i + 1) = t[1];
            *yp.add(3 * i + 2) = t[2];
            dot += t[0] * xi0 + t[1] * xi1 + t[2] * xi2;
        }
        dot
    }
}

/// Map from a block pattern to the scalar lower-triangular CSC that faer factors.
#[derive(Debug, Clone)]
struct LowerCsc {
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    values: Vec<f64>,
    /// Per scalar entry: block index and offset inside the (column-major) 3×3 block.
    source: Vec<(u32, u8)>,
}

impl LowerCsc {
    fn new(p: &BlockPattern) -> Self {
        let n = 3 * p.n;
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        let mut source = Vec::new();
        col_ptr.push(0);
        // Symmetric pattern: block column J's rows are block row J's columns.
        for bj in 0..p.n {
            for cj in 0..3 {
                let c = 3 * bj + cj;
                for k in p.row_ptr[bj]..p.row_ptr[bj + 1] {
                    let bi = p.cols[k] as usize;
                    if bi < bj {
                        continue;
                    }
                    // Block (bi, bj) is the transpose of block (bj, bi) = a[k]; read (bi, bj)
                    // directly instead.
                    let kij = p.find(bi, bj);
                    for ri in 0..3 {
                        let r = 3 * bi + ri;
                        if r >= c {
                            row_idx.push(r);
                            // nalgebra Matrix3 is column-major: (ri, cj) at cj * 3 + ri.
                            source.push((kij as u32, (cj * 3 + ri) as u8));
                        }
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        let values = vec![0.0; row_idx.len()];
        LowerCsc {
            col_ptr,
            row_idx,
            values,
            source,
        }
    }

    fn gather(&mut self, a: &[Matrix3<f64>]) {
        for (v, &(k, o)) in self.values.iter_mut().zip(&self.source) {
            *v = a[k as usize].as_slice()[o as usize];
        }
    }
}

/// Precision a [`SparseCholesky`] stores its factor in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FactorPrecision {
    /// f64: the direct solver's, the rest compliance's and every exact solve's.
    F64,
    /// f32 factor and solves (the right-hand side rounded on the way in, the result widened
    /// on the way out): only where the factor preconditions an iteration that is itself run
    /// to a tolerance in f64, the offline lagged-factor CG. The solves stream half the bytes
    /// of L (1,435 nodes: they were a third of an offline replay's time).
    F32,
}

/// The numeric factor in the chosen precision.
enum Factor {
    F64 {
        l: Vec<f64>,
    },
    F32 {
        values: Vec<f32>,
        l: Vec<f32>,
        rhs: Vec<f32>,
    },
}

/// Sparse Cholesky LLᵀ of a symmetric positive definite block matrix (faer, AMD ordering,
/// supernodal when worthwhile). Symbolic analysis once; `refactor` and the solves use
/// preallocated memory and do not allocate.
pub struct SparseCholesky {
    dim: usize,
    csc: LowerCsc,
    symbolic: SymbolicCholesky<usize>,
    factor: Factor,
    mem: MemBuffer,
    max_cols: usize,
    factored: bool,
}

impl std::fmt::Debug for SparseCholesky {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SparseCholesky")
            .field("dim", &self.dim)
            .field("l_nnz", &self.factor_nnz())
            .field("precision", &self.precision())
            .field("max_cols", &self.max_cols)
            .finish()
    }
}

impl SparseCholesky {
    /// Symbolic analysis of `pattern` and a first numeric factorization of `a`, in f64. Solves
    /// of up to `max_cols` right-hand sides at once run without allocating (wider blocks are
    /// solved in chunks).
    pub fn new(
        pattern: &BlockPattern,
        a: &[Matrix3<f64>],
        max_cols: usize,
    ) -> Result<Self, FemError> {
        Self::with_precision(pattern, a, max_cols, FactorPrecision::F64)
    }

    /// [`Self::new`] with the factor stored in `precision`.
    pub fn with_precision(
        pattern: &BlockPattern,
        a: &[Matrix3<f64>],
        max_cols: usize,
        precision: FactorPrecision,
    ) -> Result<Self, FemError> {
        let max_cols = max_cols.max(1);
        let dim = 3 * pattern.n;
        let mut csc = LowerCsc::new(pattern);
        csc.gather(a);
        let sym = SymbolicSparseColMatRef::new_checked(dim, dim, &csc.col_ptr, None, &csc.row_idx);
        let symbolic = factorize_symbolic_cholesky(
            sym,
            Side::Lower,
            SymmetricOrdering::Amd,
            CholeskySymbolicParams::default(),
        )
        .map_err(|e| FemError::Solver(format!("symbolic Cholesky failed: {e:?}")))?;
        // the workspace and the factor's storage in its precision
        let (req, factor) = match precision {
            FactorPrecision::F64 => (
                StackReq::any_of(&[
                    symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
                    symbolic.solve_in_place_scratch::<f64>(max_cols, Par::Seq),
                ]),
                Factor::F64 {
                    l: vec![0.0; symbolic.len_val()],
                },
            ),
            FactorPrecision::F32 => (
                StackReq::any_of(&[
                    symbolic.factorize_numeric_llt_scratch::<f32>(Par::Seq, Default::default()),
                    symbolic.solve_in_place_scratch::<f32>(max_cols, Par::Seq),
                ]),
                Factor::F32 {
                    values: vec![0.0; csc.values.len()],
                    l: vec![0.0; symbolic.len_val()],
                    rhs: vec![0.0; dim * max_cols],
                },
            ),
        };
        let mem = MemBuffer::try_new(req)
            .map_err(|_| FemError::Solver("out of memory for Cholesky workspace".into()))?;
        let mut chol = SparseCholesky {
            dim,
            csc,
            symbolic,
            factor,
            mem,
            max_cols,
            factored: false,
        };
        chol.factor_gathered()?;
        Ok(chol)
    }

    /// Scalar dimension (3 × free nodes).
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Number of stored values of L.
    pub fn factor_nnz(&self) -> usize {
        self.symbolic.len_val()
    }

    /// The precision the factor is stored and applied in.
    pub fn precision(&self) -> FactorPrecision {
        match self.factor {
            Factor::F64 { .. } => FactorPrecision::F64,
            Factor::F32 { .. } => FactorPrecision::F32,
        }
    }

    /// Numeric refactorization with new values on the same pattern. No allocation.
    pub fn refactor(&mut self, a: &[Matrix3<f64>]) -> Result<(), FemError> {
        self.csc.gather(a);
        self.factor_gathered()
    }

    fn factor_gathered(&mut self) -> Result<(), FemError> {
        self.factored = false;
        let structure = SymbolicSparseColMatRef::new_checked(
            self.dim,
            self.dim,
            &self.csc.col_ptr,
            None,
            &self.csc.row_idx,
        );
        let stack = MemStack::new(&mut self.mem);
        match &mut self.factor {
            Factor::F64 { l } => {
                let mat = SparseColMatRef::new(structure, &self.csc.values[..]);
                factorize(&self.symbolic, l, mat, stack)?;
            }
            Factor::F32 { values, l, .. } => {
                for (v, &w) in values.iter_mut().zip(&self.csc.values) {
                    *v = w as f32;
                }
                let mat = SparseColMatRef::new(structure, &values[..]);
                factorize(&self.symbolic, l, mat, stack)?;
            }
        }
        self.factored = true;
        Ok(())
    }

    /// x ← A⁻¹ x for one right-hand side of length `dim()`. No allocation.
    pub fn solve_in_place(&mut self, x: &mut [f64]) {
        self.solve_block_in_place(x, 1);
    }

    /// X ← A⁻¹ X for `ncols` right-hand sides stored column-major (`x.len() == dim * ncols`).
    /// Solving columns as one block is several times faster than one by one.
    pub fn solve_block_in_place(&mut self, x: &mut [f64], ncols: usize) {
        assert!(
            self.factored,
            "SparseCholesky used after a failed factorization"
        );
        assert_eq!(x.len(), self.dim * ncols, "right-hand side size");
        for chunk in x.chunks_mut(self.dim * self.max_cols) {
            let k = chunk.len() / self.dim.max(1);
            if k == 0 {
                continue;
            }
            let stack = MemStack::new(&mut self.mem);
            match &mut self.factor {
                Factor::F64 { l } => {
                    let llt = LltRef::new(&self.symbolic, l);
                    let rhs = MatMut::from_column_major_slice_mut(chunk, self.dim, k);
                    llt.solve_in_place_with_conj(Conj::No, rhs, Par::Seq, stack);
                }
                Factor::F32 { l, rhs, .. } => {
                    let narrow = &mut rhs[..chunk.len()];
                    for (n, &w) in narrow.iter_mut().zip(chunk.iter()) {
                        *n = w as f32;
                    }
                    let llt = LltRef::new(&self.symbolic, l);
                    let m = MatMut::from_column_major_slice_mut(narrow, self.dim, k);
                    llt.solve_in_place_with_conj(Conj::No, m, Par::Seq, stack);
                    for (w, &n) in chunk.iter_mut().zip(narrow.iter()) {
                        *w = n as f64;
                    }
                }
            }
        }
    }
}

/// The numeric LLᵀ of `a` into `l`, in `a`'s precision.
fn factorize<T: faer::traits::ComplexField>(
    symbolic: &SymbolicCholesky<usize>,
    l: &mut [T],
    a: SparseColMatRef<'_, usize, T>,
    stack: &mut MemStack,
) -> Result<(), FemError> {
    symbolic
        .factorize_numeric_llt::<T>(
            l,
            a,
            Side::Lower,
            LltRegularization::default(),
            Par::Seq,
            stack,
            Default::default(),
        )
        .map(|_| ())
        .map_err(|e| FemError::Solver(format!("matrix not positive definite: {e:?}")))
}
