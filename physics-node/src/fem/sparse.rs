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

/// Sparse Cholesky LLᵀ of a symmetric positive definite block matrix (faer, AMD ordering,
/// supernodal when worthwhile). Symbolic analysis once; `refactor` and the solves use
/// preallocated memory and do not allocate.
pub struct SparseCholesky {
    dim: usize,
    csc: LowerCsc,
    symbolic: SymbolicCholesky<usize>,
    l_values: Vec<f64>,
    mem: MemBuffer,
    max_cols: usize,
    factored: bool,
}

impl std::fmt::Debug for SparseCholesky {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SparseCholesky")
            .field("dim", &self.dim)
            .field("l_nnz", &self.l_values.len())
            .field("max_cols", &self.max_cols)
            .finish()
    }
}

impl SparseCholesky {
    /// Symbolic analysis of `pattern` and a first numeric factorization of `a`. Solves of up
    /// to `max_cols` right-hand sides at once run without allocating (wider blocks are
    /// solved in chunks).
    pub fn new(
        pattern: &BlockPattern,
        a: &[Matrix3<f64>],
        max_cols: usize,
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
        let req = StackReq::any_of(&[
            symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
            symbolic.solve_in_place_scratch::<f64>(max_cols, Par::Seq),
        ]);
        let mem = MemBuffer::try_new(req)
            .map_err(|_| FemError::Solver("out of memory for Cholesky workspace".into()))?;
        let l_values = vec![0.0; symbolic.len_val()];
        let mut chol = SparseCholesky {
            dim,
            csc,
            symbolic,
            l_values,
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
        self.l_values.len()
    }

    /// Numeric refactorization with new values on the same pattern. No allocation.
    pub fn refactor(&mut self, a: &[Matrix3<f64>]) -> Result<(), FemError> {
        self.csc.gather(a);
        self.factor_gathered()
    }

    fn factor_gathered(&mut self) -> Result<(), FemError> {
        self.factored = false;
        let mat = SparseColMatRef::new(
            SymbolicSparseColMatRef::new_checked(
                self.dim,
                self.dim,
                &self.csc.col_ptr,
                None,
                &self.csc.row_idx,
            ),
            &self.csc.values,
        );
        let stack = MemStack::new(&mut self.mem);
        self.symbolic
            .factorize_numeric_llt::<f64>(
                &mut self.l_values,
                mat,
                Side::Lower,
                LltRegularization::default(),
                Par::Seq,
                stack,
                Default::default(),
            )
            .map_err(|e| FemError::Solver(format!("matrix not positive definite: {e:?}")))?;
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
        let llt = LltRef::new(&self.symbolic, &self.l_values);
        for chunk in x.chunks_mut(self.dim * self.max_cols) {
            let k = chunk.len() / self.dim.max(1);
            if k == 0 {
                continue;
            }
            let rhs = MatMut::from_column_major_slice_mut(chunk, self.dim, k);
            llt.solve_in_place_with_conj(Conj::No, rhs, Par::Seq, MemStack::new(&mut self.mem));
        }
    }
}
