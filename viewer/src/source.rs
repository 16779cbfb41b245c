//! The shared-memory side of the viewer (the thread that owns the iceoryx2 ports, which are
//! not `Send`). It only reads the newest sample of each stream (never the 1 kHz queue in
//! full), converts at the viewer's rates, and hands the results to the output thread through
//! a bounded queue: when the outputs fall behind, updates are dropped and counted, never
//! waited for. The physics and haptic loops publish into iceoryx2 without knowing the
//! viewer exists.

use std::mem::MaybeUninit;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::time::{Duration, Instant};

use msgs::haptic_to_monitor::HapticStats;
use msgs::haptic_to_physics::DeviceState;
use msgs::ipc::{self, LinkError, Queue};
use msgs::physics_to_haptic::ContactFrame;
use msgs::physics_to_viz::SurfaceFrame;
use msgs::ros_mapping::{Mapping, StampClock};
use msgs::training::{TrainingAnswer, TrainingPrompt};
use msgs::Topic;

use crate::mapping::{self, PageEvent, RosOut, Status};

/// What the shared-memory thread hands to the output thread.
#[derive(Debug)]
pub enum Update {
    Ros { stamp_ns: u64, msg: RosOut },
    Page(PageEvent),
}

/// Counters shared with the output thread and the status.
#[derive(Debug, Default)]
pub struct Counters {
    pub contact_frames: AtomicU64,
    pub device_states: AtomicU64,
    pub surfaces: AtomicU64,
    pub enqueued: AtomicU64,
    /// Updates dropped because the output thread was behind.
    pub dropped: AtomicU64,
    /// Page events dropped because a browser was behind.
    pub dropped_page: AtomicU64,
    pub answers_forwarded: AtomicU64,
    pub ipc_errors: AtomicU64,
}

impl Counters {
    /// The run's totals as one JSON object (printed as `VIEWED {json}` when the viewer stops,
    /// so a session's log shows what the viewer read and what it dropped).
    pub fn totals_json(&self) -> serde_json::Value {
        let get = |c: &AtomicU64| c.load(Ordering::Relaxed);
        serde_json::json!({
            "contact_frames": get(&self.contact_frames),
            "device_states": get(&self.device_states),
            "surfaces": get(&self.surfaces),
            "enqueued": get(&self.enqueued),
            "dropped": get(&self.dropped),
            "dropped_page": get(&self.dropped_page),
            "answers_forwarded": get(&self.answers_forwarded),
            "ipc_errors": get(&self.ipc_errors),
        })
    }
}

/// Rates of the outputs.
#[derive(Debug, Clone, Copy)]
pub struct Rates {
    pub state_period: Duration,
    pub mesh_period: Duration,
}

fn boxed_zeroed<T: Topic>() -> Box<MaybeUninit<T>> {
    let mut b = Box::new(MaybeUninit::<T>::uninit());
    T::zeroed_in(&mut b);
    b
}

fn push(tx: &SyncSender<Update>, counters: &Counters, update: Update) {
    match tx.try_send(update) {
        Ok(()) => {
            counters.enqueued.fetch_add(1, Ordering::Relaxed);
        }
        Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
            counters.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// Runs the shared-memory side until `stop`; `ready` is called once the ports are open.
#[allow(clippy::too_many_arguments)]
pub fn run(
    session: &str,
    frames: Mapping,
    rates: Rates,
    clock: StampClock,
    tx: SyncSender<Update>,
    answers: Receiver<(u32, u32)>,
    counters: Arc<Counters>,
    stop: &AtomicBool,
    ready: impl FnOnce(),
) -> Result<(), LinkError> {
    let node = ipc::create_node("viewer")?;
    let contact_sub = ipc::subscriber::<ContactFrame>(&node, session, Queue::Newest)?;
    let device_sub = ipc::subscriber::<DeviceState>(&node, session, Queue::Newest)?;
    let surface_sub = ipc::subscriber::<SurfaceFrame>(&node, session, Queue::Newest)?;
    let haptic_sub = ipc::subscriber::<HapticStats>(&node, session, Queue::Newest)?;
    let prompt_sub = ipc::subscriber::<TrainingPrompt>(&node, session, Queue::Newest)?;
    let answer_pub = ipc::publisher::<TrainingAnswer>(&node, session)?;
    ready();

    let mut frame = boxed_zeroed::<ContactFrame>();
    let mut device = boxed_zeroed::<DeviceState>();
    let mut surface = boxed_zeroed::<SurfaceFrame>();
    let mut haptic = boxed_zeroed::<HapticStats>();
    let mut prompt = boxed_zeroed::<TrainingPrompt>();
    let (mut have_frame, mut have_device, mut have_haptic) = (false, false, false);
    let mut topology = None;
    let mut last_state = Instant::now() - rates.state_period;
    let mut last_mesh = Instant::now() - rates.mesh_period;
    let mut last_diag = Instant::now();
    let mut rate_window = (Instant::now(), 0u64, 0u64); // (start, first sequence, instance)
    let mut status = Status {
        region: "none",
        ..Default::default()
    };
    let mut answer_sequence = 0u64;
    let mut out = Vec::with_capacity(8);

    while !stop.load(Ordering::Relaxed) {
        let mut busy = false;
        let now_ns = msgs::clock::monotonic_ns();
        let step = (|| -> Result<(), LinkError> {
            // SAFETY (all assume_init below): zeroed at creation, only overwritten with whole
            // samples by take_newest.
            let f = unsafe { frame.assume_init_mut() };
            let n = ipc::take_newest(&contact_sub, f)?;
            if n > 0 {
                have_frame = true;
                busy = true;
                counters
                    .contact_frames
                    .fetch_add(n as u64, Ordering::Relaxed);
                status.ipc_latency_ms = now_ns.saturating_sub(f.publish_ns) as f64 / 1e6;
                status.contacts = f.contact_count;
                // Physics rate from sequence numbers: exact even though only the newest
                // frame is read.
                let (start, first, instance) = rate_window;
                if instance != f.instance_id {
                    rate_window = (Instant::now(), f.sequence, f.instance_id);
                } else if start.elapsed() >= Duration::from_secs(1) {
                    status.physics_hz =
                        f.sequence.saturating_sub(first) as f64 / start.elapsed().as_secs_f64();
                    rate_window = (Instant::now(), f.sequence, f.instance_id);
                }
            }
            let d = unsafe { device.assume_init_mut() };
            if ipc::take_newest(&device_sub, d)? > 0 {
                have_device = true;
                counters.device_states.fetch_add(1, Ordering::Relaxed);
                status.region = mapping::region_name(d.region);
                status.probing = d.probing_index;
                status.faults = mapping::fault_names(d.faults);
            }
            let h = unsafe { haptic.assume_init_mut() };
            if ipc::take_newest(&haptic_sub, h)? > 0 {
                have_haptic = true;
                status.haptic_hz = h.tick_hz;
            }
            let p = unsafe { prompt.assume_init_mut() };
            if ipc::take_newest(&prompt_sub, p)? > 0 {
                busy = true;
                push(
                    &tx,
                    &counters,
                    Update::Page(PageEvent::new("training", mapping::page_prompt(p))),
                );
            }
            status.dropped = counters.dropped.load(Ordering::Relaxed)
                + counters.dropped_page.load(Ordering::Relaxed);

            if have_frame && last_state.elapsed() >= rates.state_period {
                last_state = Instant::now();
                let dev = if have_device { Some(&*d) } else { None };
                mapping::contact_messages(f, &frames, &clock, &mut out);
                if let Some(dev) = dev {
                    mapping::device_messages(dev, &frames, &clock, &mut out);
                }
                for msg in out.drain(..) {
                    push(
                        &tx,
                        &counters,
                        Update::Ros {
                            stamp_ns: f.publish_ns,
                            msg,
                        },
                    );
                }
                let json = mapping::page_state(f, dev, &status, &clock);
                push(&tx, &counters, Update::Page(PageEvent::new("state", json)));
            }
            if last_diag.elapsed() >= Duration::from_secs(1) {
                last_diag = Instant::now();
                let hs = if have_haptic { Some(&*h) } else { None };
                let stamp = clock.stamp(msgs::clock::monotonic_ns());
                push(
                    &tx,
                    &counters,
                    Update::Ros {
                        stamp_ns: msgs::clock::monotonic_ns(),
                        msg: mapping::diagnostics(&status, hs, stamp),
                    },
                );
            }

            let s = unsafe { surface.assume_init_mut() };
            let n = ipc::take_newest(&surface_sub, s)?;
            if n > 0 {
                counters.surfaces.fetch_add(n as u64, Ordering::Relaxed);
            }
            if s.vertex_count > 0 && last_mesh.elapsed() >= rates.mesh_period && n > 0 {
                last_mesh = Instant::now();
                busy = true;
                let key = mapping::topology_key(s);
                if topology != Some(key) {
                    topology = Some(key);
                    push(
                        &tx,
                        &counters,
                        Update::Page(PageEvent::new("topology", mapping::page_topology(s))),
                    );
                }
                push(
                    &tx,
                    &counters,
                    Update::Page(PageEvent::new("mesh", mapping::page_mesh(s, &clock))),
                );
                push(
                    &tx,
                    &counters,
                    Update::Ros {
                        stamp_ns: s.publish_ns,
                        msg: mapping::mesh_message(s, &frames, &clock),
                    },
                );
            }

            while let Ok((case_index, grade)) = answers.try_recv() {
                answer_sequence += 1;
                let answer = TrainingAnswer {
                    sequence: answer_sequence,
                    publish_ns: msgs::clock::monotonic_ns(),
                    case_index,
                    grade,
                    source: msgs::training::source::PAGE,
                    _pad: 0,
                };
                ipc::send_copy(&answer_pub, &answer)?;
                counters.answers_forwarded.fetch_add(1, Ordering::Relaxed);
            }
            Ok(())
        })();
        if let Err(e) = step {
            // A publisher that died mid-sample must not end the viewer: count, go on.
            counters.ipc_errors.fetch_add(1, Ordering::Relaxed);
            tracing::warn!("shared-memory link: {e}");
        }
        if !busy {
            std::thread::sleep(Duration::from_millis(2));
        }
    }
    Ok(())
}
