//! Precomputed constraint correction (SOFA's PrecomputedConstraintCorrection with rotations):
//! the tissue's response to a contact impulse comes from columns of A0⁻¹, the inverse of the
//! implicit-Euler system matrix in the rest state (factorized once), rotated by the nodal
//! rotations of the current configuration: A⁻¹ ≈ R A0⁻¹ Rᵀ.
//!
//! Units: an impulse λ (N·s) on the tissue changes velocities by A⁻¹ Hᵀ λ and positions by
//! dt A⁻¹ Hᵀ λ, so W = dt H A⁻¹ Hᵀ (m/(N·s)); the probe adds dt H M_eff⁻¹ Hᵀ.
//!
//! Columns are cached per surface node (3 columns of length 3·n_free each). When all of them
//! fit in the memory budget they are computed once at start (in blocks). Otherwise the cache
//! is bounded (least-recently-used eviction) and filled one of two ways ([`Filling`]):
//! - `Inline`: a miss is solved inside the step (one 3-column solve; deterministic, for
//!   offline replays);
//! - `Prefetch`: a worker thread owns the factorization and solves the nodes near the probe
//!   and its target ahead of need, handing finished columns over through bounded channels
//!   (buffers are recycled, so the step neither allocates nor solves). A node still missing
//!   when a step needs it is left out of that contact and the contact's weight is carried by
//!   its cached nodes (counted in [`ComplianceCache::approximated`]).
//!
//! A cache is `Send` and built without the simulation, so a new one (another material) can be
//! built on a worker thread and swapped in with [`crate::sim::Simulation::swap_compliance`].

use crate::contact::{Contact, Patch, PATCH_NODES};
use crate::probe::Probe;
use nalgebra::{Matrix3, Point3, Vector3};
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

/// Marks a node without free degrees of freedom (held) or a node without a cache slot.
pub const NONE: u32 = u32::MAX;

/// Solves A0 X = B for the rest-state system matrix (velocity form: X is the velocity change
/// of the free nodes for the impulses B). `x` holds `ncols` columns of length `dim()` one
/// after another (column-major) and is overwritten with the solution. Must not allocate.
pub trait RestSolver: Send {
    fn dim(&self) -> usize;
    fn solve_block(&mut self, x: &mut [f64], ncols: usize);
}

/// Nodes solved together when the whole cache is filled at start, and by the prefetcher.
const PRECOMPUTE_BLOCK_NODES: usize = 16;
/// Buffers in flight between the prefetcher and the step beyond the cache's slots.
const PREFETCH_SPARE_BUFFERS: usize = 2 * PRECOMPUTE_BLOCK_NODES;
/// Most probe points a prefetch hint carries (sphere centres now and at the target).
const HINT_POINTS: usize = 128;
/// Prefetch radius beyond a probe sphere's surface, m: what the probe can reach (plus the
/// tissue's deformation) before the worker sees the next hint.
const PREFETCH_MARGIN_M: f64 = 4.0e-3;
// A contact point lies on a surface triangle: its nodes can be up to the longest surface
// edge away from it, which the worker adds to the margin.

/// How a cache that does not hold the whole surface gets its columns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Filling {
    /// Misses are solved inside the step (deterministic; for offline use).
    Inline,
    /// A worker thread solves the nodes near the probe ahead of need (real time).
    Prefetch,
}

/// The smallest cache, nodes: more than a probe's contacts touch at once (32 slots), with
/// room for the nodes it passes on a slide.
pub const MIN_SLOTS: usize = 96;

/// Columns of one node: 3 columns of length `dim`, column-major.
type Columns = Box<[f64]>;

/// Where the probe is and is going: the prefetcher's input.
#[derive(Clone)]
struct Hint {
    generation: u64,
    count: usize,
    points: [Point3<f64>; HINT_POINTS],
    radii: [f64; HINT_POINTS],
}

struct Shared {
    hint: Mutex<Hint>,
    stop: std::sync::atomic::AtomicBool,
    /// Latest hint generation for which every candidate node has been handed over.
    done_generation: std::sync::atomic::AtomicU64,
    /// Blocks being solved right now.
    in_flight: std::sync::atomic::AtomicUsize,
}

/// Step side of the prefetch worker.
struct Prefetcher {
    shared: Arc<Shared>,
    /// Finished columns: (node, columns).
    ready: Receiver<(u32, Columns)>,
    /// Buffers handed back: (node evicted from it or NONE, buffer).
    spare: SyncSender<(u32, Columns)>,
    thread: Option<JoinHandle<()>>,
    generation: u64,
}

impl Drop for Prefetcher {
    fn drop(&mut self) {
        self.shared
            .stop
            .store(true, std::sync::atomic::Ordering::Relaxed);
        // Not joined: the worker may be inside a block solve, and a cache swapped out of the
        // real-time loop must not wait for it. It stops at its next check (or when its
        // channels are gone).
        if let Some(t) = self.thread.take() {
            t.thread().unpark();
        }
    }
}

enum Filler {
    /// Every surface node is cached: nothing to fill.
    Complete,
    Inline(Box<dyn RestSolver>),
    Prefetch(Prefetcher),
}

pub struct ComplianceCache {
    /// Node → first free dof / 3 (free row), NONE for held nodes.
    free_index: Vec<u32>,
    dim: usize,
    /// Slot s holds its node's 3 columns (an empty box until the prefetcher fills it).
    columns: Vec<Columns>,
    node_slot: Vec<u32>,
    slot_node: Vec<u32>,
    slot_stamp: Vec<u64>,
    stamp: u64,
    /// Nodes a step needed that were not cached (inline: each one solve inside the step;
    /// prefetch: each one left out of its contact).
    pub misses: u64,
    /// Contacts whose tissue compliance was approximated because a node was not cached
    /// (prefetch only): the contact's weight was carried by its cached nodes.
    pub approximated: u64,
    /// True when every surface node has a slot (no miss can happen).
    pub complete: bool,
    filler: Filler,
}

impl ComplianceCache {
    /// `surface_nodes`: nodes that can be touched (boundary), `surface_triangles` their
    /// triangles (mesh node indices); `rest_positions`: every mesh node's rest position (the
    /// prefetcher's map of where nodes are). `budget_bytes` bounds
    /// the column storage; when all surface nodes fit, they are computed now (on the calling
    /// thread) and `filling` does not matter.
    pub fn new(
        free_index: Vec<u32>,
        surface_nodes: &[usize],
        surface_triangles: &[[usize; 3]],
        rest_positions: &[Point3<f64>],
        mut solver: Box<dyn RestSolver>,
        budget_bytes: usize,
        filling: Filling,
    ) -> ComplianceCache {
        let dim = solver.dim();
        let touchable: Vec<usize> = surface_nodes
            .iter()
            .copied()
            .filter(|&n| free_index[n] != NONE)
            .collect();
        let per_slot = 3 * dim * std::mem::size_of::<f64>();
        let max_slots = (budget_bytes / per_slot.max(1)).max(MIN_SLOTS);
        let complete = touchable.len() <= max_slots;
        let slots = if complete { touchable.len() } else { max_slots };
        let n_nodes = free_index.len();
        let mut cache = ComplianceCache {
            node_slot: vec![NONE; n_nodes],
            free_index,
            dim,
            columns: Vec::with_capacity(slots),
            slot_node: vec![NONE; slots],
            slot_stamp: vec![0; slots],
            stamp: 0,
            misses: 0,
            approximated: 0,
            complete,
            filler: Filler::Complete,
        };
        if complete {
            let mut block = vec![0.0; PRECOMPUTE_BLOCK_NODES * 3 * dim];
            for chunk in touchable.chunks(PRECOMPUTE_BLOCK_NODES) {
                let block = &mut block[..chunk.len() * 3 * dim];
                fill_unit_columns(block, chunk, &cache.free_index, dim);
                solver.solve_block(block, 3 * chunk.len());
                for (j, &node) in chunk.iter().enumerate() {
                    let s = cache.columns.len();
                    cache
                        .columns
                        .push(block[j * 3 * dim..(j + 1) * 3 * dim].into());
                    cache.node_slot[node] = s as u32;
                    cache.slot_node[s] = node as u32;
                }
            }
            return cache;
        }
        match filling {
            Filling::Inline => {
                cache.columns = (0..slots).map(|_| vec![0.0; 3 * dim].into()).collect();
                cache.filler = Filler::Inline(solver);
            }
            Filling::Prefetch => {
                cache.columns = (0..slots).map(|_| Box::default()).collect();
                let positions: Vec<Point3<f64>> =
                    touchable.iter().map(|&n| rest_positions[n]).collect();
                let reach = PREFETCH_MARGIN_M + longest_edge(surface_triangles, rest_positions);
                cache.filler = Filler::Prefetch(Prefetcher::start(
                    solver,
                    cache.free_index.clone(),
                    touchable,
                    positions,
                    slots,
                    reach,
                ));
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

    /// Surface nodes cached now.
    pub fn cached_nodes(&self) -> usize {
        self.slot_node.iter().filter(|&&n| n != NONE).count()
    }

    /// Prefetch: tells the worker where the probe is and where it is driven to, and takes
    /// over the columns it has finished. Call once per step before [`ConstraintCorrection::
    /// assemble`]. Never blocks, never allocates, never solves.
    pub fn prefetch(&mut self, probe: &Probe) {
        let Filler::Prefetch(p) = &mut self.filler else {
            return;
        };
        if let Ok(mut h) = p.shared.hint.try_lock() {
            p.generation += 1;
            let n = probe.spheres.len();
            let stride = n.div_ceil(HINT_POINTS / 2).max(1);
            let mut k = 0;
            for i in (0..n).step_by(stride) {
                let s = &probe.spheres[i];
                let target = probe.target_position + probe.target_orientation * s.local;
                h.points[k] = Point3::from(probe.sphere_world(i));
                h.radii[k] = s.radius;
                h.points[k + 1] = Point3::from(target);
                h.radii[k + 1] = s.radius;
                k += 2;
            }
            h.count = k;
            h.generation = p.generation;
        }
        if let Some(t) = &p.thread {
            t.thread().unpark();
        }
        while let Ok((node, buf)) = p.ready.try_recv() {
            let node = node as usize;
            if self.node_slot[node] != NONE {
                let _ = p.spare.try_send((node as u32, buf));
                continue;
            }
            // Least recently used slot (empty slots have stamp 0); ties by index.
            let mut victim = 0;
            let mut oldest = u64::MAX;
            for (i, &st) in self.slot_stamp.iter().enumerate() {
                if st < oldest {
                    oldest = st;
                    victim = i;
                }
            }
            self.stamp += 1;
            let old = std::mem::replace(&mut self.columns[victim], buf);
            let evicted = self.slot_node[victim];
            if evicted != NONE {
                self.node_slot[evicted as usize] = NONE;
            }
            self.slot_node[victim] = node as u32;
            self.node_slot[node] = victim as u32;
            self.slot_stamp[victim] = self.stamp;
            if evicted != NONE || !old.is_empty() {
                // The channel holds every buffer there is: it cannot be full.
                let _ = p.spare.try_send((evicted, old));
            }
        }
    }

    /// Blocks until the prefetcher has cached every surface node within its margin of the
    /// probe's last hint, or `timeout` passes (set-up and tests; not for the step). Returns
    /// whether it got there.
    pub fn wait_prefetched(&mut self, probe: &Probe, timeout: std::time::Duration) -> bool {
        let start = std::time::Instant::now();
        loop {
            self.prefetch(probe);
            let Filler::Prefetch(p) = &self.filler else {
                return true;
            };
            let done = p
                .shared
                .done_generation
                .load(std::sync::atomic::Ordering::Acquire);
            let busy = p
                .shared
                .in_flight
                .load(std::sync::atomic::Ordering::Acquire);
            if done >= p.generation && busy == 0 {
                self.prefetch(probe);
                return true;
            }
            if start.elapsed() > timeout {
                return false;
            }
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
    }

    /// Makes sure `node`'s columns are cached; returns its slot (NONE for held nodes, and for
    /// a node not cached yet when a worker fills the cache). `pinned` slots (used by the
    /// current step) are not evicted.
    pub fn ensure(&mut self, node: usize, pinned: &[u32]) -> u32 {
        if self.free_index[node] == NONE {
            return NONE;
        }
        self.stamp += 1;
        let s = self.node_slot[node];
        if s != NONE {
            self.slot_stamp[s as usize] = self.stamp;
            return s;
        }
        self.misses += 1;
        let Filler::Inline(solver) = &mut self.filler else {
            return NONE;
        };
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
        let block = &mut self.columns[v];
        fill_unit_columns(block, &[node], &self.free_index, self.dim);
        solver.solve_block(block, 3);
        self.slot_node[v] = node as u32;
        self.node_slot[node] = victim;
        self.slot_stamp[v] = self.stamp;
        victim
    }

    /// Block (a, b) of A0⁻¹: rows of free row `fa`, columns of slot `sb`.
    #[inline]
    fn block(&self, fa: usize, sb: u32) -> Matrix3<f64> {
        let base = 3 * fa;
        let d = self.dim;
        let c = &self.columns[sb as usize];
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

/// Longest edge of the surface triangles, m.
fn longest_edge(triangles: &[[usize; 3]], positions: &[Point3<f64>]) -> f64 {
    let mut longest: f64 = 0.0;
    for t in triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if let (Some(pa), Some(pb)) = (positions.get(a), positions.get(b)) {
                longest = longest.max((pa - pb).norm());
            }
        }
    }
    longest
}

/// Right-hand sides for `nodes`: 3 unit columns each (column-major, length `dim`).
fn fill_unit_columns(block: &mut [f64], nodes: &[usize], free_index: &[u32], dim: usize) {
    block.fill(0.0);
    for (j, &node) in nodes.iter().enumerate() {
        let f = free_index[node] as usize;
        for k in 0..3 {
            block[(3 * j + k) * dim + 3 * f + k] = 1.0;
        }
    }
}

impl Prefetcher {
    fn start(
        solver: Box<dyn RestSolver>,
        free_index: Vec<u32>,
        touchable: Vec<usize>,
        positions: Vec<Point3<f64>>,
        slots: usize,
        reach: f64,
    ) -> Prefetcher {
        let buffers = slots + PREFETCH_SPARE_BUFFERS;
        let (ready_tx, ready) = std::sync::mpsc::sync_channel(buffers);
        let (spare, spare_rx) = std::sync::mpsc::sync_channel(buffers);
        let shared = Arc::new(Shared {
            hint: Mutex::new(Hint {
                generation: 0,
                count: 0,
                points: [Point3::origin(); HINT_POINTS],
                radii: [0.0; HINT_POINTS],
            }),
            stop: std::sync::atomic::AtomicBool::new(false),
            done_generation: std::sync::atomic::AtomicU64::new(0),
            in_flight: std::sync::atomic::AtomicUsize::new(0),
        });
        let worker = Worker {
            shared: shared.clone(),
            solver,
            free_index,
            touchable,
            positions,
            reach,
            // Keep a quarter of the slots for what the step touches outside the margin.
            target: (slots * 3 / 4).max(1),
            buffers,
            ready: ready_tx,
            spare: spare_rx,
        };
        let thread = std::thread::Builder::new()
            .name("compliance-prefetch".into())
            .spawn(move || worker.run())
            .ok();
        Prefetcher {
            shared,
            ready,
            spare,
            thread,
            generation: 0,
        }
    }
}

struct Worker {
    shared: Arc<Shared>,
    solver: Box<dyn RestSolver>,
    free_index: Vec<u32>,
    touchable: Vec<usize>,
    positions: Vec<Point3<f64>>,
    /// Distance from a probe sphere's surface within which nodes are prefetched, m.
    reach: f64,
    /// Most nodes kept around the probe.
    target: usize,
    /// Buffers that may exist (slots + spare).
    buffers: usize,
    ready: SyncSender<(u32, Columns)>,
    spare: Receiver<(u32, Columns)>,
}

impl Worker {
    fn run(mut self) {
        use std::sync::atomic::Ordering;
        let dim = self.solver.dim();
        let mut sent = vec![false; self.free_index.len()];
        let mut pool: Vec<Columns> = Vec::new();
        let mut allocated = 0usize;
        let mut candidates: Vec<(f64, usize)> = Vec::new();
        let mut todo: Vec<usize> = Vec::with_capacity(PRECOMPUTE_BLOCK_NODES);
        let mut block = vec![0.0; PRECOMPUTE_BLOCK_NODES * 3 * dim];
        let mut seen_generation = u64::MAX;
        let mut hint_generation = 0;
        loop {
            if self.shared.stop.load(Ordering::Relaxed) {
                return;
            }
            loop {
                match self.spare.try_recv() {
                    Ok((evicted, buf)) => {
                        if evicted != NONE {
                            sent[evicted as usize] = false;
                        }
                        pool.push(buf);
                    }
                    Err(TryRecvError::Empty) => break,
                    Err(TryRecvError::Disconnected) => return,
                }
            }
            let hint = match self.shared.hint.lock() {
                Ok(h) => h.clone(),
                Err(_) => return,
            };
            if hint.generation != seen_generation {
                seen_generation = hint.generation;
                hint_generation = hint.generation;
                candidates.clear();
                for (i, x) in self.positions.iter().enumerate() {
                    let mut d = f64::INFINITY;
                    for k in 0..hint.count {
                        d = d.min((x - hint.points[k]).norm() - hint.radii[k]);
                    }
                    if d < self.reach {
                        candidates.push((d, self.touchable[i]));
                    }
                }
                candidates.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                candidates.truncate(self.target);
            }
            todo.clear();
            todo.extend(
                candidates
                    .iter()
                    .map(|&(_, n)| n)
                    .filter(|&n| !sent[n])
                    .take(PRECOMPUTE_BLOCK_NODES),
            );
            if todo.is_empty() {
                self.shared
                    .done_generation
                    .store(hint_generation, Ordering::Release);
                std::thread::park_timeout(std::time::Duration::from_millis(5));
                continue;
            }
            // A buffer per node: recycled, new while under the limit, else wait for one.
            while pool.len() < todo.len() && allocated < self.buffers {
                pool.push(vec![0.0; 3 * dim].into());
                allocated += 1;
            }
            if pool.len() < todo.len() {
                match self.spare.recv_timeout(std::time::Duration::from_millis(5)) {
                    Ok((evicted, buf)) => {
                        if evicted != NONE {
                            sent[evicted as usize] = false;
                        }
                        pool.push(buf);
                    }
                    Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
                    Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => return,
                }
                if pool.is_empty() {
                    continue;
                }
                todo.truncate(pool.len());
            }
            self.shared.in_flight.fetch_add(1, Ordering::AcqRel);
            let block = &mut block[..todo.len() * 3 * dim];
            fill_unit_columns(block, &todo, &self.free_index, dim);
            self.solver.solve_block(block, 3 * todo.len());
            for (j, &node) in todo.iter().enumerate() {
                let mut buf = pool.pop().expect("a buffer per node");
                buf.copy_from_slice(&block[j * 3 * dim..(j + 1) * 3 * dim]);
                sent[node] = true;
                if self.ready.send((node as u32, buf)).is_err() {
                    return;
                }
            }
            self.shared.in_flight.fetch_sub(1, Ordering::AcqRel);
        }
    }
}

/// Per-step assembly of W and application of the corrections. Holds the scratch buffers.
pub struct ConstraintCorrection {
    /// Per contact: its range in the per-node lists below (a triangle's three nodes, or a
    /// Hertz patch's).
    spans: Vec<(usize, usize)>,
    /// Per contact and node: the mesh node,
    nodes: Vec<usize>,
    /// its cache slot (NONE: held node / no slot),
    slots: Vec<u32>,
    /// and the weight used (the contact's; when a node is not cached, its share is carried
    /// by the cached nodes of the contact).
    weights: Vec<f64>,
    pinned: Vec<u32>,
    /// Tissue velocity correction in the rest frame, per free dof.
    dv_local: Vec<f64>,
}

impl ConstraintCorrection {
    pub fn new(dim: usize, max_contacts: usize) -> ConstraintCorrection {
        ConstraintCorrection {
            spans: Vec::with_capacity(max_contacts),
            // every contact a patch at most (one per probe ball, fewer than max_contacts)
            nodes: Vec::with_capacity(PATCH_NODES * max_contacts),
            slots: Vec::with_capacity(PATCH_NODES * max_contacts),
            weights: Vec::with_capacity(PATCH_NODES * max_contacts),
            pinned: Vec::with_capacity(PATCH_NODES * max_contacts),
            dv_local: vec![0.0; dim],
        }
    }

    /// Fills W (row-major, stride `stride`) for `contacts`: tissue part with nodal rotations
    /// `rotations` (per mesh node) plus the probe's compliance about its free position.
    #[allow(clippy::too_many_arguments)]
    pub fn assemble(
        &mut self,
        contacts: &[Contact],
        patches: &[Patch],
        cache: &mut ComplianceCache,
        rotations: &[Matrix3<f64>],
        probe: &Probe,
        dt: f64,
        w: &mut [f64],
        stride: usize,
    ) {
        let m = contacts.len();
        self.spans.clear();
        self.nodes.clear();
        self.slots.clear();
        self.weights.clear();
        self.pinned.clear();
        for c in contacts {
            let start = self.slots.len();
            let mut free_weight = 0.0;
            let mut cached_weight = 0.0;
            for (node, w) in c.spread(patches) {
                let mut s = NONE;
                if cache.free_index(node) != NONE {
                    free_weight += w;
                    s = cache.ensure(node, &self.pinned);
                    if s != NONE {
                        self.pinned.push(s);
                        cached_weight += w;
                    }
                }
                self.nodes.push(node);
                self.slots.push(s);
                self.weights.push(if s != NONE { w } else { 0.0 });
            }
            if cached_weight != free_weight {
                // Approximation: the missing node's share goes to the cached nodes of the
                // same contact (all missing: the tissue is rigid there for this step).
                cache.approximated += 1;
                let scale = if cached_weight > 0.0 {
                    free_weight / cached_weight
                } else {
                    0.0
                };
                self.weights[start..].iter_mut().for_each(|w| *w *= scale);
            }
            self.spans.push((start, self.slots.len()));
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
                let (rs, re) = self.spans[kr];
                let (ss, se) = self.spans[ks];
                for b in ss..se {
                    let sb = self.slots[b];
                    let wb = self.weights[b];
                    if sb == NONE || wb == 0.0 {
                        continue;
                    }
                    let rb = &rotations[self.nodes[b]];
                    for a in rs..re {
                        let fa = cache.free_index(self.nodes[a]);
                        let wa = self.weights[a];
                        if fa == NONE || wa == 0.0 {
                            continue;
                        }
                        let block = cache.block(fa as usize, sb);
                        tissue += rotations[self.nodes[a]] * block * rb.transpose() * (wa * wb);
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
            let (start, end) = self.spans[k];
            for a in start..end {
                let slot = self.slots[a];
                if slot == NONE {
                    continue;
                }
                let g = rotations[self.nodes[a]].transpose() * f_world * self.weights[a];
                let col = &cache.columns[slot as usize];
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
