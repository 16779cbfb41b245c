//! Transport probe: measures physics publish → frame receivable in this process.
//!
//! A thread with its own iceoryx2 node watches the contact-frame service and records
//! `now − publish_ns` for every frame. It only watches when a frame can come: the physics
//! node steps on absolute deadlines and each frame says when its next step starts
//! (`next_step_ns`), so no frame can be published before then. The probe sleeps until
//! shortly before that, then polls without yielding at SCHED_FIFO (below the servo thread),
//! so a time slice of another thread does not show up as transport latency.
//!
//! Spinning at real-time priority must not hold off the physics process it waits for:
//! - the probe keeps off the CPU the frame was published from (where physics wakes);
//! - it spins at most four physics steps (≥ 2 ms, ≤ one period) past the next step start,
//!   then polls at the idle rate;
//! - with one CPU it does not ask for SCHED_FIFO at all.
//!
//! That costs about one physics step of CPU per physics period.
//!
//! A frame the probe finds on its first poll after a sleep was already there before it
//! watched: its latency is an upper bound (counted as `unwatched`, still recorded, and the
//! window margin doubles).

use crate::stats::{LatencyHistogram, TRANSPORT_MAX_NS};
use msgs::ipc::{self, Queue};
use msgs::physics_to_haptic::ContactFrame;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// How far before the earliest possible publish the window opens at first, ns.
pub const INITIAL_MARGIN_NS: u64 = 200_000;
/// Polling period while no frame is expected (before the first frame, or after physics missed
/// a whole period: late, dead or restarting), ns.
pub const IDLE_POLL_NS: u64 = 1_000_000;

/// What a frame says about when the next one can come.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameTiming {
    pub publish_ns: u64,
    pub step_duration_ns: u64,
    pub next_step_ns: u64,
    pub dt_s: f64,
}

impl FrameTiming {
    pub fn of(frame: &ContactFrame) -> Self {
        Self {
            publish_ns: frame.publish_ns,
            step_duration_ns: frame.step_duration_ns,
            next_step_ns: frame.next_step_ns,
            dt_s: frame.dt_s,
        }
    }

    /// The publisher's period, ns (0 when the frame's dt is not a positive number).
    pub fn period_ns(&self) -> u64 {
        period_ns(self.dt_s)
    }

    /// When to start watching for the next frame: the publisher's next step start
    /// (`next_step_ns`) less `margin_ns`. A publisher that keeps no schedule
    /// (`next_step_ns` = 0) is assumed to step one period after this frame's step started.
    pub fn window_start_ns(&self, margin_ns: u64) -> u64 {
        let next_step = if self.next_step_ns != 0 {
            self.next_step_ns
        } else {
            self.publish_ns
                .saturating_sub(self.step_duration_ns)
                .saturating_add(self.period_ns())
        };
        next_step.saturating_sub(margin_ns)
    }
}

fn period_ns(dt_s: f64) -> u64 {
    if dt_s.is_finite() && dt_s > 0.0 {
        (dt_s * 1e9) as u64
    } else {
        0
    }
}

/// Counters the probe shares with the node.
#[derive(Debug, Default)]
pub struct ProbeCounters {
    /// Frames recorded.
    pub frames: AtomicU64,
    /// Frames that were already there when the window opened (latency is an upper bound).
    pub unwatched: AtomicU64,
    /// Whether the probe thread runs at SCHED_FIFO.
    pub fifo: AtomicBool,
}

/// Starts the probe thread; it runs until `stop` (or the process stop flag) is raised and
/// merges its histogram into `hist` every 50 ms.
pub fn spawn(
    session: String,
    fifo_priority: Option<i32>,
    stop: Arc<AtomicBool>,
    hist: Arc<Mutex<LatencyHistogram>>,
    counters: Arc<ProbeCounters>,
) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let cpus = KeepOff::new();
        if cpus.allowed_count() < 2 {
            // One CPU: a real-time spin would hold off the physics process it waits for.
            tracing::info!("transport probe: one CPU allowed, polling at normal priority");
        } else if let Some(p) = fifo_priority {
            match crate::servo::request_fifo(p) {
                Ok(()) => counters.fifo.store(true, Ordering::Relaxed),
                Err(e) => tracing::warn!(
                    "transport probe: SCHED_FIFO {p} not granted ({e}); its latencies include normal scheduling"
                ),
            }
        }
        if let Err(e) = watch(&session, &stop, &hist, &counters, cpus) {
            tracing::warn!("transport probe stopped: {e:#}");
        }
    })
}

/// How long the probe spins past the publisher's next step start before it gives up and
/// polls at the idle rate: four times the last step, at least 2 ms, at most one period.
/// Bounded so that a publisher that shares the probe's CPU after all is held off briefly.
pub fn spin_budget_ns(timing: &FrameTiming) -> u64 {
    let budget = timing.step_duration_ns.saturating_mul(4).max(2_000_000);
    match timing.period_ns() {
        0 => budget,
        p => budget.min(p),
    }
}

/// The CPUs this thread may run on, less the one a publisher wakes on.
pub struct KeepOff {
    allowed: libc::cpu_set_t,
    avoiding: Option<usize>,
}

impl KeepOff {
    /// The calling thread's current CPU set.
    pub fn new() -> Self {
        // SAFETY: cpu_set_t is plain data; sched_getaffinity fills it (on failure it stays
        // empty, which `allowed_count` reports as no CPU to move to).
        let mut allowed: libc::cpu_set_t = unsafe { std::mem::zeroed() };
        unsafe {
            libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut allowed);
        }
        Self {
            allowed,
            avoiding: None,
        }
    }

    pub fn allowed_count(&self) -> usize {
        // SAFETY: reads the set.
        unsafe { libc::CPU_COUNT(&self.allowed) as usize }
    }

    /// Restricts the calling thread to the allowed CPUs except `cpu` (no change when `cpu`
    /// is unknown, not allowed, or the only one).
    pub fn avoid(&mut self, cpu: Option<usize>) {
        let Some(cpu) = cpu else { return };
        if self.avoiding == Some(cpu)
            || cpu >= libc::CPU_SETSIZE as usize
            || self.allowed_count() < 2
            // SAFETY: reads the set; cpu < CPU_SETSIZE.
            || !unsafe { libc::CPU_ISSET(cpu, &self.allowed) }
        {
            return;
        }
        let mut set = self.allowed;
        // SAFETY: cpu < CPU_SETSIZE; the set stays non-empty (≥ 2 allowed).
        unsafe {
            libc::CPU_CLR(cpu, &mut set);
            if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0 {
                self.avoiding = Some(cpu);
            }
        }
    }
}

impl Default for KeepOff {
    fn default() -> Self {
        Self::new()
    }
}

fn stopped(stop: &AtomicBool) -> bool {
    stop.load(Ordering::Relaxed) || msgs::lifecycle::stop_flag().load(Ordering::Relaxed)
}

fn watch(
    session: &str,
    stop: &AtomicBool,
    hist: &Mutex<LatencyHistogram>,
    counters: &ProbeCounters,
    mut cpus: KeepOff,
) -> anyhow::Result<()> {
    let node = ipc::create_node("haptic-transport")?;
    let sub = ipc::subscriber::<ContactFrame>(&node, session, Queue::Newest)?;
    let fifo = counters.fifo.load(Ordering::Relaxed);
    let mut local = LatencyHistogram::new(TRANSPORT_MAX_NS);
    let mut last_merge = msgs::clock::monotonic_ns();
    let mut margin_ns = INITIAL_MARGIN_NS;
    // Watching until this time for the next frame; None: no frame expected (idle polling).
    let mut watch_until: Option<u64> = None;
    // The next poll is the first since a sleep: a frame it finds was there before we looked.
    let mut first_poll = true;
    while !stopped(stop) {
        let mut newest: Option<(FrameTiming, u32)> = None;
        while let Some(sample) = sub.receive().map_err(|e| anyhow::anyhow!("{e:?}"))? {
            let now = msgs::clock::monotonic_ns();
            let f = sample.payload();
            local.record(now.saturating_sub(f.publish_ns));
            counters.frames.fetch_add(1, Ordering::Relaxed);
            if first_poll {
                counters.unwatched.fetch_add(1, Ordering::Relaxed);
                tracing::debug!(
                    sequence = f.sequence,
                    latency_us = now.saturating_sub(f.publish_ns) / 1000,
                    watching = watch_until.is_some(),
                    "transport probe: frame was there before the window opened"
                );
            }
            newest = Some((FrameTiming::of(f), f.publisher_cpu_plus_one));
        }
        let now = msgs::clock::monotonic_ns();
        if now.saturating_sub(last_merge) > 50_000_000 {
            if let Ok(mut h) = hist.lock() {
                h.merge(&local);
            }
            local.clear();
            last_merge = now;
        }
        if let Some((timing, publisher_cpu_plus_one)) = newest {
            let period = timing.period_ns();
            if first_poll && watch_until.is_some() && margin_ns < period / 4 {
                // The frame came before the window opened: open the next ones earlier.
                margin_ns *= 2;
            }
            if fifo {
                // The publisher wakes where it slept; spinning there would hold it off.
                cpus.avoid(publisher_cpu_plus_one.checked_sub(1).map(|c| c as usize));
            }
            let start = timing.window_start_ns(margin_ns);
            watch_until = Some(start + margin_ns + spin_budget_ns(&timing));
            crate::servo::sleep_until(start);
            first_poll = true;
            continue;
        }
        match watch_until {
            Some(until) if now < until => {
                first_poll = false;
                if !fifo {
                    // Without SCHED_FIFO, spinning would take CPU time from physics.
                    // SAFETY: plain syscall.
                    unsafe { libc::sched_yield() };
                }
                std::hint::spin_loop();
            }
            _ => {
                watch_until = None;
                crate::servo::sleep_until(now + IDLE_POLL_NS);
                first_poll = true;
            }
        }
    }
    if let Ok(mut h) = hist.lock() {
        h.merge(&local);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn timing(next_step_ns: u64) -> FrameTiming {
        FrameTiming {
            publish_ns: 50_000_000,
            step_duration_ns: 2_000_000,
            next_step_ns,
            dt_s: 0.01,
        }
    }

    #[test]
    fn window_opens_margin_before_the_publishers_next_step() {
        assert_eq!(timing(58_000_000).window_start_ns(200_000), 57_800_000);
    }

    #[test]
    fn publisher_behind_real_time_opens_the_window_at_once() {
        // next_step_ns = publish_ns: the next step starts right after this frame.
        let t = timing(50_000_000);
        assert!(t.window_start_ns(200_000) <= t.publish_ns);
    }

    #[test]
    fn publisher_without_schedule_is_assumed_one_period_after_step_start() {
        // Step started at 48 ms; next start 58 ms.
        assert_eq!(timing(0).window_start_ns(200_000), 57_800_000);
    }

    #[test]
    fn spin_budget_is_four_steps_between_2_ms_and_one_period() {
        assert_eq!(spin_budget_ns(&timing(0)), 8_000_000);
        let mut t = timing(0);
        t.step_duration_ns = 100_000;
        assert_eq!(spin_budget_ns(&t), 2_000_000);
        t.step_duration_ns = 9_000_000;
        assert_eq!(spin_budget_ns(&t), 10_000_000);
    }

    #[test]
    fn keep_off_moves_the_thread_off_the_publishers_cpu() {
        std::thread::spawn(|| {
            let mut cpus = KeepOff::new();
            let n = cpus.allowed_count();
            assert!(n >= 1);
            let first = (0..libc::CPU_SETSIZE as usize)
                .find(|&c| unsafe { libc::CPU_ISSET(c, &cpus.allowed) })
                .unwrap();
            cpus.avoid(Some(first));
            let mut now: libc::cpu_set_t = unsafe { std::mem::zeroed() };
            unsafe {
                libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut now);
            }
            let still_on_it = unsafe { libc::CPU_ISSET(first, &now) };
            // With one CPU there is nowhere to go: the set is left alone.
            assert_eq!(still_on_it, n < 2, "{n} CPUs allowed");
            // Unknown and out-of-range CPUs change nothing.
            cpus.avoid(None);
            cpus.avoid(Some(usize::MAX));
        })
        .join()
        .unwrap();
    }

    #[test]
    fn nonsense_dt_gives_no_period_and_no_overflow() {
        let mut t = timing(0);
        t.dt_s = f64::NAN;
        assert_eq!(t.period_ns(), 0);
        assert_eq!(t.window_start_ns(u64::MAX), 0);
        t.publish_ns = u64::MAX;
        t.dt_s = 1e300;
        let _ = t.window_start_ns(0);
    }
}
