//! The servo tick allocates nothing: renderer (local LCP re-solve, limits) and the device
//! backends' sample/command, counted by a global allocator.

use haptic_node::config::Limits;
use haptic_node::device::emulated::EmulatedTouch;
use haptic_node::device::operator::{plane_sites, Protocol};
use haptic_node::device::replay::{parse_trajectory, Replay};
use haptic_node::device::{Device, DeviceSample};
use haptic_node::render::{boxed_frame, Renderer};
use msgs::MAX_ROWS;
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

struct Counting;
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    // Only the servo thread under test is counted (the test harness has threads of its own).
    static ARMED: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

fn count() {
    if ARMED.with(|a| a.get()) {
        ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn servo_tick_does_not_allocate() {
    let config = launch_config::DeviceConfig::default();
    let limits = Limits::from_config(&config).unwrap();
    let mut renderer = Renderer::new(limits);
    // 32 frictional contacts on a plane under the probe.
    let mut frame = boxed_frame();
    frame.dt_s = 0.01;
    frame.contact_count = 32;
    frame.row_count = 96;
    frame.friction_mu = 0.3;
    for k in 0..32 {
        frame.constraint_directions[3 * k] = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        frame.constraint_directions[3 * k + 1] = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        frame.constraint_directions[3 * k + 2] = [0.0, 1.0, 0.0, 0.0, 0.0, 0.0];
        frame.free_violation[3 * k] = -1e-4;
    }
    for i in 0..96 {
        for j in 0..96 {
            frame.compliance[i * MAX_ROWS + j] = if i == j {
                2.0
            } else if i % 3 == j % 3 {
                0.5
            } else {
                0.0
            };
        }
    }
    let mut spare = boxed_frame();
    let mut emulated = EmulatedTouch::new(
        &config.emulated,
        // Pressing to a felt force: the press ends (segments re-timed) inside the loop.
        Protocol::new(&config.emulated, &plane_sites(0.0, 5))
            .unwrap()
            .with_felt_target(0.05),
        0,
    )
    .unwrap();
    let poses = parse_trajectory(
        "t_s,px_m,py_m,pz_m,qx,qy,qz,qw\n0,0,0,0.001,0,0,0,1\n5,0,0,-0.001,0,0,0,1\n",
        "inline.csv",
    )
    .unwrap();
    let mut replay = Replay::new(poses, &config.replay, 0).unwrap();
    let mut sample = DeviceSample::default();

    ARMED.with(|a| a.set(true));
    let before = ALLOCATIONS.load(Ordering::SeqCst);
    let mut t = 0u64;
    for i in 0..3000u64 {
        t += 1_000_000;
        if i % 10 == 0 {
            *spare = *frame;
            spare.sequence = i + 1;
            spare.publish_ns = t;
            renderer.accept_frame(&mut spare, t);
        }
        emulated.sample(t, &mut sample).unwrap();
        replay.sample(t, &mut sample).unwrap();
        let out = renderer.tick(t, &sample.pose, true);
        assert!(out.lcp_ns > 0 && out.faults & msgs::haptic_to_physics::fault::STALE_FRAME == 0);
        emulated.command_force(t, out.rendered).unwrap();
    }
    let after = ALLOCATIONS.load(Ordering::SeqCst);
    ARMED.with(|a| a.set(false));
    assert_eq!(after - before, 0, "allocations in 3000 ticks");
}
