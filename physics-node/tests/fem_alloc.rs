//! The FEM step does not allocate: free motion (every solver), correction, commit, node
//! rotations and rest-compliance solves, counted by a global allocator on this thread.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use nalgebra::Vector3;
use physics_node::fem::test_meshes::{box_mesh, nodes_where};
use physics_node::fem::{
    FemModel, FemSettings, LinearSolver, Material, MaterialModel, Preconditioner,
};

struct Counting;

thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static COUNT: Cell<usize> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note();
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note();
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

fn note() {
    // try_with: the thread-locals may be gone during thread teardown.
    let _ = COUNTING.try_with(|c| {
        if c.get() {
            let _ = COUNT.try_with(|n| n.set(n.get() + 1));
        }
    });
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations_in(f: impl FnOnce()) -> usize {
    COUNT.with(|n| n.set(0));
    COUNTING.with(|c| c.set(true));
    f();
    COUNTING.with(|c| c.set(false));
    COUNT.with(|n| n.get())
}

#[test]
fn counting_allocator_sees_allocations() {
    let n = allocations_in(|| {
        let v = vec![1u8; 10];
        std::hint::black_box(v);
    });
    assert!(n >= 1);
}

#[test]
fn fem_step_does_not_allocate() {
    let mesh = box_mesh(0.03, 0.01, 0.008, 6, 3, 2);
    let fixed = nodes_where(&mesh, |p| p.z < 1e-9);
    let solvers = [
        LinearSolver::sofa_cg(),
        LinearSolver::Cg {
            max_iterations: 25,
            tolerance: 1e-9,
            preconditioner: Preconditioner::BlockJacobi,
        },
        LinearSolver::Cg {
            max_iterations: 25,
            tolerance: 1e-9,
            preconditioner: Preconditioner::RestCholesky,
        },
        LinearSolver::Cg {
            max_iterations: 25,
            tolerance: 1e-9,
            preconditioner: Preconditioner::WarpedRestCholesky,
        },
        LinearSolver::Direct,
    ];
    for model in [MaterialModel::Corotational, MaterialModel::StableNeoHookean] {
        for solver in solvers {
            let settings = FemSettings {
                solver,
                rayleigh_mass: 0.1,
                rayleigh_stiffness: 0.001,
                ..FemSettings::default()
            };
            let mut fem = FemModel::new(
                &mesh,
                Material::lateral().with_model(model),
                &fixed,
                settings,
            )
            .unwrap();
            let mut compliance = fem.rest_compliance(0.01, 8).unwrap();
            let n = fem.node_count();
            let mut forces = vec![Vector3::zeros(); n];
            let top = nodes_where(&mesh, |p| (p.z - 0.008).abs() < 1e-9);
            let correction: Vec<(usize, Vector3<f64>)> = top
                .iter()
                .map(|&i| (i, Vector3::new(0.0, 0.0, -1e-5)))
                .collect();
            let mut full = vec![0.0; 3 * n];
            let mut block = vec![0.0; 3 * n * 12];
            // Warm-up step outside the count (nothing is lazily allocated, but be fair).
            fem.free_motion(0.01, &forces).unwrap();
            fem.commit();
            let count = allocations_in(|| {
                for s in 0..20 {
                    forces[top[0]] = Vector3::new(0.0, 0.1 * s as f64, -0.5);
                    fem.update_node_rotations();
                    fem.free_motion(0.01, &forces).unwrap();
                    full[3 * top[1] + 2] = -1.0;
                    compliance.solve_in_place(&mut full);
                    block[5] = 1.0;
                    compliance.solve_block_in_place(&mut block, 12);
                    fem.apply_correction(&correction).unwrap();
                    fem.apply_correction_full(&full).unwrap();
                    fem.commit();
                    std::hint::black_box(fem.elastic_energy() + fem.kinetic_energy());
                }
            });
            assert_eq!(
                count, 0,
                "{model:?} / {solver:?}: {count} allocations in 20 steps"
            );
        }
    }
}
