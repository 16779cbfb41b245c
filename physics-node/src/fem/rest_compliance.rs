//! Precomputed constraint correction: the rest-state system factored once, solved per
//! column or block of columns without allocating.

use super::*;

impl FemModel {
    /// Factors the rest-state system A0 = M + dt C0 + dt² K0 once, for precomputed
    /// constraint correction. `max_block_columns`: widest block solved without allocating.
    pub fn rest_compliance(
        &mut self,
        dt: f64,
        max_block_columns: usize,
    ) -> Result<RestCompliance, FemError> {
        if !(dt.is_finite() && dt > 0.0) {
            return Err(FemError::Input(format!("dt must be > 0 s, got {dt}")));
        }
        if self.free_nodes.is_empty() {
            return Err(FemError::Input("every node is held: no compliance".into()));
        }
        let saved = self.a.clone();
        self.assemble_rest_system(dt);
        let chol = SparseCholesky::new(&self.pattern, &self.a, max_block_columns);
        self.a = saved;
        let cols = max_block_columns.max(1);
        Ok(RestCompliance {
            chol: chol?,
            free_index: self.free_index.clone(),
            free_nodes: self.free_nodes.clone(),
            n_nodes: self.x.len(),
            max_cols: cols,
            scratch: vec![0.0; 3 * self.free_nodes.len() * cols],
            dt,
        })
    }
}

/// The rest-state system A0 = M + dt C0 + dt² K0 factored once (precomputed constraint
/// correction). Solves act on full vectors of 3 entries per mesh node; held nodes' entries
/// are ignored on input and zero on output. No allocation after construction.
pub struct RestCompliance {
    chol: SparseCholesky,
    free_index: Vec<u32>,
    free_nodes: Vec<usize>,
    n_nodes: usize,
    max_cols: usize,
    scratch: Vec<f64>,
    dt: f64,
}

impl std::fmt::Debug for RestCompliance {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RestCompliance")
            .field("nodes", &self.n_nodes)
            .field("free_nodes", &self.free_nodes.len())
            .field("dt", &self.dt)
            .field("cholesky", &self.chol)
            .finish()
    }
}

impl RestCompliance {
    /// The time step A0 was built for, s.
    pub fn dt(&self) -> f64 {
        self.dt
    }
    pub fn node_count(&self) -> usize {
        self.n_nodes
    }
    /// Row of a node in the reduced (free-dof) system, None when held.
    pub fn free_index(&self, node: usize) -> Option<usize> {
        match self.free_index.get(node) {
            Some(&i) if i != NO_BLOCK => Some(i as usize),
            _ => None,
        }
    }
    /// The factor itself, on reduced vectors (3 per free node, in `free_index` order).
    pub fn cholesky_mut(&mut self) -> &mut SparseCholesky {
        &mut self.chol
    }

    /// x ← A0⁻¹ x, `x.len() == 3 * nodes` (velocity response, m/s per N·s of impulse;
    /// multiply by dt for displacement).
    pub fn solve_in_place(&mut self, x: &mut [f64]) {
        self.solve_block_in_place(x, 1);
    }

    /// X ← A0⁻¹ X for `ncols` full-length columns stored column-major
    /// (`x.len() == 3 * nodes * ncols`); solved as blocks of up to `max_block_columns`.
    pub fn solve_block_in_place(&mut self, x: &mut [f64], ncols: usize) {
        let full = 3 * self.n_nodes;
        assert_eq!(
            x.len(),
            full * ncols,
            "RestCompliance: right-hand side size"
        );
        let red = 3 * self.free_nodes.len();
        let mut c0 = 0;
        while c0 < ncols {
            let k = (ncols - c0).min(self.max_cols);
            let s = &mut self.scratch[..red * k];
            for c in 0..k {
                let col = &x[(c0 + c) * full..(c0 + c + 1) * full];
                for (row, &node) in self.free_nodes.iter().enumerate() {
                    s[c * red + 3 * row..c * red + 3 * row + 3]
                        .copy_from_slice(&col[3 * node..3 * node + 3]);
                }
            }
            self.chol.solve_block_in_place(s, k);
            for c in 0..k {
                let col = &mut x[(c0 + c) * full..(c0 + c + 1) * full];
                col.fill(0.0);
                for (row, &node) in self.free_nodes.iter().enumerate() {
                    col[3 * node..3 * node + 3]
                        .copy_from_slice(&s[c * red + 3 * row..c * red + 3 * row + 3]);
                }
            }
            c0 += k;
        }
    }
}
