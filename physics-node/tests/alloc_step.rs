//! Zero heap allocations inside `Simulation::step` after warm-up, with contact active
//! (counting global allocator, armed only on the test's thread around the steps).

use nalgebra::{UnitQuaternion, Vector3};
use physics_node::sim::Simulation;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

struct Counting;
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);
thread_local! {
    static ARMED: Cell<bool> = const { Cell::new(false) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if ARMED.with(|a| a.get()) {
            ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if ARMED.with(|a| a.get()) {
            ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn check(mesh: &str, friction: f64, hertz_patch: bool) {
    let mut scene = launch_config::SceneConfig::default();
    scene.meniscus.mesh = mesh.into();
    scene.contact.friction = friction;
    scene.contact.hertz_patch = hertz_patch;
    let mut sim = Simulation::new(&scene, &launch_config::data_dir()).unwrap();
    let site = *sim.probing_sites().iter().find(|s| s.region == 2).unwrap();
    let n = site.normal.normalize();
    let q = UnitQuaternion::rotation_between(&Vector3::z(), &n).unwrap();
    let (t1, _) = physics_node::contact::tangents(&n);
    let r = scene.probe.tip_radius;
    sim.teleport_probe(&physics_node::probe::pose(site.point + n * (r + 0.2e-3), q));
    let target = |k: usize| {
        let t = k as f64 * 0.01;
        physics_node::probe::pose(
            site.point + n * (r - 1.5e-3 * (t / 0.3).min(1.0)) + t1 * (2e-3 * (2.0 * t).sin()),
            q,
        )
    };
    for k in 0..60 {
        sim.set_proxy_pose(&target(k));
        sim.step().unwrap();
    }
    let mut contact_steps = 0;
    ALLOCATIONS.store(0, Ordering::SeqCst);
    for k in 60..260 {
        let pose = target(k);
        ARMED.with(|a| a.set(true));
        sim.set_proxy_pose(&pose);
        let res = sim.step();
        ARMED.with(|a| a.set(false));
        res.unwrap();
        contact_steps += (sim.contact_count() > 0) as usize;
    }
    let n_alloc = ALLOCATIONS.load(Ordering::SeqCst);
    println!("{mesh}, patch {hertz_patch}: {n_alloc} allocations in 200 steps, {contact_steps} with contact");
    assert_eq!(
        contact_steps, 200,
        "contact must be active in every measured step"
    );
    assert_eq!(n_alloc, 0, "Simulation::step allocated {n_alloc} times");
}

#[test]
fn step_does_not_allocate_with_contact() {
    check("default:lateral:coarse", 0.0, false);
    check("default:lateral:coarse", 0.4, false);
}

/// The contact spread over each ball's Hertz patch integrates it in scratch reserved once.
#[test]
fn step_does_not_allocate_with_contacts_spread_over_their_patches() {
    check("default:lateral:coarse", 0.0, true);
    check("default:lateral:coarse", 0.4, true);
}
