//! Precomputed constraint correction (SOFA's PrecomputedConstraintCorrection with rotations):
//! the tissue's response to a contact impulse comes from columns of A0⁻¹, the inverse of the
//! implicit-Euler system matrix in the rest state (factorized once), rotated by the nodal
//! rotations of the current configuration: A⁻¹ ≈ R A0⁻¹ Rᵀ.
//!
//! Units: an impulse λ (N·s) on the tissue changes velocities by A⁻¹ Hᵀ λ and positions by
//! dt A⁻¹ Hᵀ λ, so W = dt H A⁻¹ Hᵀ (m/(N·s)); the probe adds dt H M_eff⁻¹ Hᵀ.
//!
//! Columns are cached per surface node (3 columns of length 3·n_free each): all of them when
//! they fit in the memory budget (computed once, in blocks), otherwise a bounded cache
//! filled on demand with least-recently-used eviction (a miss costs one 3-column solve, no
//! allocation).

use crate::contact::Contact;
use crate::probe::Probe;
use nalgebra::{Matrix3, Vector3};

/// Marks a node without free degrees of freedom (held) or a node without a cache slot.
pub const NONE: u32 = u32::MAX;

/// Solves A0 X = B for the rest-state system matrix (velocity form: X is the velocity change
/// of the free nodes for the impulses B). `x` holds `ncols` columns of length `dim()` one
/// after another (column-major) and is overwritten with the solution. Must not allocate.
pub trait RestSolver {
    fn dim(&self) -> usize;
    fn solve_block(&mut self, x: &mut [f64], ncols: usize);
}

/// Nodes solved together when the whole cache is filled at start.
const PRECOMPUTE_BLOCK_NODES: usize = 16;

pub struct ComplianceCache {
    /// Node → first free dof / 3 (free row), NONE for held nodes.
    free_index: Vec<u32>,
    dim: usize,
    /// Slot storage: slot s holds columns 3 of length dim at [s·3·dim ..].
    columns: Vec<f64>,
    node_slot: Vec<u32>,
    slot_node: Vec<u32>,
    slot_stamp: Vec<u64>,
    stamp: u64,
    /// Cache misses since start (each one solve).
    pub misses: u64,
    /// True when every surface node has a slot (no miss can happen).
    pub complete: bool,
}

impl ComplianceCache {
    /// `surface_nodes`: nodes that can be touched (boundary). `budget_bytes` bounds the column
    /// storage; when all surface nodes fit, they are computed now.
    pub fn new(
        free_index: Vec<u32>,
        surface_nodes: &[usize],
        solver: &mut dyn RestSolver,
        budget_bytes: usize,
    ) -> ComplianceCache {
        let dim = solver.dim();
        let touchable: Vec<usize> = surface_nodes
            .iter()
            .copied()
            .filter(|&n| free_index[n] != NONE)
            .collect();
        let per_slot = 3 * dim * std::mem::size_of::<f64>();
        let max_slots = (budget_bytes / per_slot.max(1)).max(96);
        let complete = touchable.len() <= max_slots;
        let slots = if complete { touchable.len() } else { max_slots };
        let mut cache = ComplianceCache {
            node_slot: vec![NONE; free_index.len()],
            free_index,
            dim,
            columns: vec![0.0; slots * 3 * dim],
            slot_node: vec![NONE; slots],
            slot_stamp: vec![0; slots],
            stamp: 0,
            misses: 0,
            complete,
        };
        if complete {
            for (chunk_i, chunk) in touchable.chunks(PRECOMPUTE_BLOCK_NODES).enumerate() {
                let first = chunk_i * PRECOMPUTE_BLOCK_NODES;
                let block = &mut cache.columns[first * 3 * dim..(first + chunk.len()) * 3 * dim];
                block.iter_mut().for_each(|v| *v = 0.0);
                for (j, &node) in chunk.iter().enumerate() {
                    let f = cache.free_index[node] as usize;
                    for k in 0..3 {
                        block[(3 * j + k) * dim + 3 * f + k] = 1.0;
                    }
                }
                solver.solve_block(block, 3 * chunk.len());
                for (j, &node) in chunk.iter().enumerate() {
                    cache.node_slot[node] = (first + j) as u32;
                    cache.slot_node[first + j] = node as u32;
                }
            }
        }
        cache
    }

    pub fn slots(&self) -> usize {
        self.slot_node.len()
    }

    pub fn free_index(&self, node: usize) -> u32 {
        self.free_index[node]
    }

    /// Makes sure `node`'s columns are cached; returns its slot (NONE for held nodes).
    /// `pinned` slots (used by the current step) are not evicted.
    pub fn ensure(&mut self, node: usize, solver: &mut dyn RestSolver, pinned: &[u32]) -> u32 {
        if self.free_index[node] == NONE {
            return NONE;
        }
        self.stamp += 1;
        let s = self.node_slot[node];
        if s != NONE {
            self.slot_stamp[s as usize] = self.stamp;
            return s;
        }
        // Least recently used, not pinned; ties by slot index (deterministic).
        let mut victim = NONE;
        let mut oldest = u64::MAX;
        for (i, &st) in self.slot_stamp.iter().enumerate() {
            if st < oldest && !pinned.contains(&(i as u32)) {
                oldest = st;
                victim = i as u32;
            }
        }
        if victim == NONE {
            return NONE;
        }
        let v = victim as usize;
        if self.slot_node[v] != NONE {
            self.node_slot[self.slot_node[v] as usize] = NONE;
        }
        let dim = self.dim;
        let block = &mut self.columns[v * 3 * dim..(v + 1) * 3 * dim];
        block.iter_mut().for_each(|x| *x = 0.0);
        let f = self.free_index[node] as usize;
        for k in 0..3 {
            block[k * dim + 3 * f + k] = 1.0;
        }
        solver.solve_block(block, 3);
        self.misses += 1;
        self.slot_node[v] = node as u32;
        self.node_slot[node] = victim;
        self.slot_stamp[v] = self.stamp;
        victim
    }

    /// Block (a, b) of A0⁻¹: rows of free row `fa`, columns of slot `sb`.
    #[inline]
    fn block(&self, fa: usize, sb: u32) -> Matrix3<f64> {
        let base = sb as usize * 3 * self.dim + 3 * fa;
        let d = self.dim;
        let c = &self.columns;
        Matrix3::new(
            c[base],
            c[base + d],
            c[base + 2 * d],
            c[base + 1],
            c[base + d + 1],
            c[base + 2 * d + 1],
            c[base + 2],
            c[base + d + 2],
            c[base + 2 * d + 2],
        )
    }
}

/// Per-step assembly of W and application of the corrections. Holds the scratch buffers.
pub struct ConstraintCorrection {
    /// Per contact and local node: cache slot (NONE: held node / no slot).
    slots: Vec<[u32; 3]>,
    pinned: Vec<u32>,
    /// Tissue velocity correction in the rest frame, per free dof.
    dv_local: Vec<f64>,
}

impl ConstraintCorrection {
    pub fn new(dim: usize, max_contacts: usize) -> ConstraintCorrection {
        ConstraintCorrection {
            slots: Vec::with_capacity(max_contacts),
            pinned: Vec::with_capacity(3 * max_contacts),
            dv_local: vec![0.0; dim],
        }
    }

    /// Fills W (row-major, stride `stride`) for `contacts`: tissue part with nodal rotations
    /// `rotations` (per mesh node) plus the probe's compliance about its free position.
    #[allow(clippy::too_many_arguments)]
    pub fn assemble(
        &mut self,
        contacts: &[Contact],
        cache: &mut ComplianceCache,
        solver: &mut dyn RestSolver,
        rotations: &[Matrix3<f64>],
        probe: &Probe,
        dt: f64,
        w: &mut [f64],
        stride: usize,
    ) {
        let m = contacts.len();
        self.slots.clear();
        self.pinned.clear();
        for c in contacts {
            let mut s = [NONE; 3];
            for a in 0..3 {
                s[a] = cache.ensure(c.nodes[a], solver, &self.pinned);
                if s[a] != NONE {
                    self.pinned.push(s[a]);
                }
            }
            self.slots.push(s);
        }
        // Per contact pair: the world-frame tissue compliance between the two contact points,
        // M = Σ_a Σ_b w_a w_b R_a A0⁻¹_ab R_bᵀ (each 3×3 block of A0⁻¹ read once), then
        // W_block = Dᵀ_kr M D_ks with D = [n t1 t2], plus the probe's part.
        for kr in 0..m {
            let cr = &contacts[kr];
            let dr_mat = Matrix3::from_columns(&[cr.normal, cr.t1, cr.t2]);
            let arm_r = probe.arm_free(cr.sphere);
            for ks in kr..m {
                let cs = &contacts[ks];
                let mut tissue = Matrix3::zeros();
                for b in 0..3 {
                    let sb = self.slots[ks][b];
                    if sb == NONE || cs.weights[b] == 0.0 {
                        continue;
                    }
                    let rb = &rotations[cs.nodes[b]];
                    for a in 0..3 {
                        let fa = cache.free_index(cr.nodes[a]);
                        if fa == NONE || cr.weights[a] == 0.0 {
                            continue;
                        }
                        let block = cache.block(fa as usize, sb);
                        tissue += rotations[cr.nodes[a]]
                            * block
                            * rb.transpose()
                            * (cr.weights[a] * cs.weights[b]);
                    }
                }
                let ds_mat = Matrix3::from_columns(&[cs.normal, cs.t1, cs.t2]);
                let wt = dr_mat.transpose() * tissue * ds_mat;
                let arm_s = probe.arm_free(cs.sphere);
                for i in 0..3 {
                    let dr = dr_mat.column(i).into_owned();
                    let hr_ang = arm_r.cross(&dr);
                    let r = 3 * kr + i;
                    let j0 = if ks == kr { i } else { 0 };
                    for j in j0..3 {
                        let ds = ds_mat.column(j).into_owned();
                        let hs_ang = arm_s.cross(&ds);
                        let (lin, ang) = probe.mobility(&ds, &hs_ang);
                        let probe_part = dr.dot(&lin) + hr_ang.dot(&ang);
                        let v = dt * (wt[(i, j)] + probe_part);
                        let c = 3 * ks + j;
                        w[r * stride + c] = v;
                        w[c * stride + r] = v;
                    }
                }
            }
        }
    }

    /// Tissue correction for impulses `lambda`: Δx = dt R A0⁻¹ Rᵀ Hᵀ λ written into `dx`
    /// (3 per mesh node, zero for untouched/held nodes). Uses the slots of the last
    /// [`Self::assemble`]. Returns false when nothing moves.
    pub fn tissue_displacement(
        &mut self,
        contacts: &[Contact],
        cache: &ComplianceCache,
        rotations: &[Matrix3<f64>],
        lambda: &[f64],
        dt: f64,
        dx: &mut [f64],
    ) -> bool {
        let dim = cache.dim;
        self.dv_local.iter_mut().for_each(|v| *v = 0.0);
        let mut any = false;
        for (k, c) in contacts.iter().enumerate() {
            // Impulse on the tissue: H_tissueᵀ λ with H_tissue = −w d.
            let f_world =
                -(c.normal * lambda[3 * k] + c.t1 * lambda[3 * k + 1] + c.t2 * lambda[3 * k + 2]);
            if f_world == Vector3::zeros() {
                continue;
            }
            for a in 0..3 {
                let slot = self.slots[k][a];
                if slot == NONE {
                    continue;
                }
                let g = rotations[c.nodes[a]].transpose() * f_world * c.weights[a];
                let col = &cache.columns[slot as usize * 3 * dim..(slot as usize + 1) * 3 * dim];
                let (c0, rest) = col.split_at(dim);
                let (c1, c2) = rest.split_at(dim);
                for ((dv, (&x0, &x1)), &x2) in
                    self.dv_local.iter_mut().zip(c0.iter().zip(c1)).zip(c2)
                {
                    *dv += x0 * g.x + x1 * g.y + x2 * g.z;
                }
                any = true;
            }
        }
        dx.iter_mut().for_each(|v| *v = 0.0);
        if !any {
            return false;
        }
        for (node, &f) in cache.free_index.iter().enumerate() {
            if f == NONE {
                continue;
            }
            let f = f as usize;
            let local = Vector3::new(
                self.dv_local[3 * f],
                self.dv_local[3 * f + 1],
                self.dv_local[3 * f + 2],
            );
            let d = rotations[node] * local * dt;
            dx[3 * node] = d.x;
            dx[3 * node + 1] = d.y;
            dx[3 * node + 2] = d.z;
        }
        true
    }
}

/// Direction of row `k` (0 normal, 1 t1, 2 t2) of a contact.
#[inline]
pub fn direction(c: &Contact, k: usize) -> Vector3<f64> {
    match k {
        0 => c.normal,
        1 => c.t1,
        _ => c.t2,
    }
}
