//! The renderer renders force only from frames computed for its own device's samples: a frame
//! from another haptic instance, from a probe driven by an external target, claiming a device
//! tick this node has not published, or flagged with a physics fault ramps the force to zero
//! (like a stale frame: within the stale ramp, never faster than the rate limit), and force
//! comes back under the rate limit once an own, good frame arrives.

use haptic_node::config::Limits;
use haptic_node::render::{boxed_frame, norm, Renderer};
use msgs::haptic_to_physics::fault;
use msgs::physics_to_haptic::{drive, physics_fault, ContactFrame};
use msgs::Pose;

const OWN: u64 = 0xA11CE;

/// One contact below the proxy, pressed 1 mm: a firm push up.
fn pressing(frame: &mut ContactFrame, sequence: u64, now_ns: u64, device_sequence: u64) {
    frame.instance_id = 7;
    frame.sequence = sequence;
    frame.publish_ns = now_ns;
    frame.dt_s = 0.01;
    frame.contact_count = 1;
    frame.row_count = 3;
    frame.friction_mu = 0.0;
    frame.proxy_pose = Pose::IDENTITY;
    frame.probe_free_pose = Pose::IDENTITY;
    frame.probe_pose = Pose::IDENTITY;
    frame.constraint_directions[0] = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
    frame.constraint_directions[1] = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    frame.constraint_directions[2] = [0.0, 1.0, 0.0, 0.0, 0.0, 0.0];
    frame.free_violation[0] = -1e-3;
    for r in 0..3 {
        frame.compliance[r * msgs::MAX_ROWS + r] = 1e-4;
    }
    frame.device_instance_used = OWN;
    frame.device_sequence_used = device_sequence;
    frame.physics_faults = 0;
    frame.drive = 0;
}

struct Bench {
    renderer: Renderer,
    limits: Limits,
    now: u64,
    tick: u64,
}

impl Bench {
    fn new() -> Bench {
        let limits = Limits::from_config(&launch_config::DeviceConfig::default()).unwrap();
        let mut renderer = Renderer::new(limits.clone());
        renderer.set_device_instance(OWN);
        Bench {
            renderer,
            limits,
            now: 1_000_000_000,
            tick: 0,
        }
    }

    /// One tick; `offer` edits a fresh pressing frame (None: no new frame this tick).
    fn tick(&mut self, offer: Option<&dyn Fn(&mut ContactFrame)>) -> (f64, u32) {
        self.now += self.limits.period_ns;
        self.tick += 1;
        self.renderer.set_device_sequence(self.tick - 1);
        if let Some(edit) = offer {
            let mut f = boxed_frame();
            pressing(
                &mut f,
                self.tick,
                self.now,
                self.tick.saturating_sub(2).max(1),
            );
            edit(&mut f);
            self.renderer.accept_frame(&mut f, self.now);
        }
        let out = self.renderer.tick(self.now, &Pose::IDENTITY, true);
        (norm(out.rendered), out.faults)
    }

    /// Presses with own frames until the force is steady; returns it.
    fn settle(&mut self) -> f64 {
        let mut f = 0.0;
        for _ in 0..3000 {
            f = self.tick(Some(&|_| {})).0;
        }
        assert!(f > 0.5, "own frames render a force ({f} N)");
        f
    }

    /// Feeds frames edited by `edit` for one stale-ramp time plus margin; checks the force
    /// ramps to zero (the stale-frame ramp), monotonically, with `bit` reported.
    fn ramps_to_zero(&mut self, edit: &dyn Fn(&mut ContactFrame), bit: u32) {
        let mut last = norm(self.renderer.last_force());
        let ticks = (self.limits.stale_ramp_s * self.limits.rate_hz).ceil() as usize + 5;
        for i in 0..ticks {
            let (f, faults) = self.tick(Some(edit));
            assert!(
                faults & bit != 0,
                "tick {i}: fault bit {bit:#x} not reported ({faults:#x})"
            );
            assert!(f <= last + 1e-12, "tick {i}: force rose {last} → {f}");
            last = f;
        }
        assert_eq!(last, 0.0, "force did not reach zero within the stale ramp");
        // Past the staleness limit of the last frame rendered, the refusal is still named
        // (regression: from 20 ms on, refused frames were reported as stale only, so the
        // diagnostics undercounted foreign ones: 1,251 of 12,379 in a flood).
        let past_stale = (self.limits.stale_frame_ns / self.limits.period_ns) as usize + 10;
        // Frames arrive at the physics rate (one tick in ten), as in a session.
        for i in 0..past_stale {
            let (f, faults) = self.tick((i % 10 == 0).then_some(edit));
            assert!(
                faults & bit != 0,
                "tick {} after the ramp: fault bit {bit:#x} not reported ({faults:#x})",
                i
            );
            assert_eq!(f, 0.0);
        }
    }
}

#[test]
fn frames_for_another_device_or_an_external_target_or_faulty_are_not_rendered() {
    type Edit = Box<dyn Fn(&mut ContactFrame)>;
    let cases: Vec<(&str, Edit, u32)> = vec![
        (
            "another haptic instance",
            Box::new(|f| f.device_instance_used = OWN + 1),
            fault::FOREIGN_FRAME,
        ),
        (
            "external target",
            Box::new(|f| {
                f.device_instance_used = 0;
                f.device_sequence_used = 0;
                f.drive = drive::EXTERNAL_TARGET;
            }),
            fault::FOREIGN_FRAME,
        ),
        (
            "a device tick from the future",
            Box::new(|f| f.device_sequence_used += 1_000_000),
            fault::FOREIGN_FRAME,
        ),
        (
            "physics fault",
            Box::new(|f| {
                f.physics_faults = physics_fault::FORCE_BOUND;
                f.drive = drive::ROLLED_BACK;
                // A diverged solve: a huge push the clamp would otherwise pass at peak.
                f.free_violation[0] = -10.0;
            }),
            fault::PHYSICS_FAULT,
        ),
    ];
    for (name, edit, bit) in cases {
        let mut b = Bench::new();
        let steady = b.settle();
        eprintln!("{name}: steady {steady:.3} N");
        b.ramps_to_zero(edit.as_ref(), bit);
        // Own good frames again: the force comes back, under the rate limit.
        let max_step = b.limits.max_force_rate_n_per_s * b.limits.period_ns as f64 * 1e-9;
        let mut last = 0.0;
        for _ in 0..3000 {
            let (f, _) = b.tick(Some(&|_| {}));
            assert!(f - last <= max_step + 1e-9, "{name}: resumed too fast");
            last = f;
        }
        assert!(
            last > 0.5,
            "{name}: force back to {last} N only (steady {steady} N)"
        );
    }
}

#[test]
fn a_frame_using_an_old_device_sample_is_stale() {
    let mut b = Bench::new();
    b.settle();
    let lag = (b.limits.stale_frame_ns as f64 * 1e-9 * b.limits.rate_hz) as u64 + 10;
    b.ramps_to_zero(
        &move |f: &mut ContactFrame| f.device_sequence_used = f.sequence.saturating_sub(lag).max(1),
        fault::STALE_FRAME,
    );
}
