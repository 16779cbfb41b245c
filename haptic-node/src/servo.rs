//! Timing of the servo loop: absolute deadlines on CLOCK_MONOTONIC, and real-time
//! scheduling with locked memory when the OS grants it.

/// Sleeps until the absolute CLOCK_MONOTONIC time `deadline_ns` (immune to drift: the next
/// deadline is computed from the previous one, not from the wake-up time).
pub fn sleep_until(deadline_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long,
    };
    loop {
        // SAFETY: valid timespec, null remainder (absolute sleeps need none).
        let r = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        if r != libc::EINTR {
            return;
        }
        // A signal (SIGTERM raising the stop flag) interrupted the sleep: the caller checks.
        if msgs::lifecycle::stop_flag().load(std::sync::atomic::Ordering::SeqCst) {
            return;
        }
    }
}

/// Sleeps until `spin_ns` before `deadline_ns`, then waits out the rest reading the clock
/// (at most `spin_ns` of spinning per call, plus whatever the sleep overshoots into it).
/// Wake-up latency below `spin_ns` then no longer shows in the tick period.
pub fn wait_until(deadline_ns: u64, spin_ns: u64) {
    if spin_ns > 0 {
        sleep_until(deadline_ns.saturating_sub(spin_ns));
        while msgs::clock::monotonic_ns() < deadline_ns {
            if msgs::lifecycle::stop_flag().load(std::sync::atomic::Ordering::Relaxed) {
                return;
            }
            std::hint::spin_loop();
        }
    } else {
        sleep_until(deadline_ns);
    }
}

/// What the OS granted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Realtime {
    pub fifo: bool,
    pub locked: bool,
}

/// Asks for SCHED_FIFO at `priority` (clamped to 1–99) for the calling thread, with a 1 ns
/// timer slack (50 µs by default for normal threads would delay every wake-up).
pub fn request_fifo(priority: i32) -> Result<(), std::io::Error> {
    // SAFETY: plain prctl on the calling thread.
    unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong, 0, 0, 0) };
    let param = libc::sched_param {
        sched_priority: priority.clamp(1, 99),
    };
    // SAFETY: plain call on the calling thread; it returns the error (errno is not set).
    match unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) } {
        0 => Ok(()),
        rc => Err(std::io::Error::from_raw_os_error(rc)),
    }
}

/// Asks for SCHED_FIFO at `priority` for the calling thread and locks current and future
/// memory (no page faults in the loop). Logs what was not granted.
pub fn request_realtime(priority: i32) -> Realtime {
    let priority = priority.clamp(1, 99);
    let fifo = request_fifo(priority);
    // SAFETY: plain syscall on the calling process.
    let locked = match unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) } {
        0 => Ok(()),
        _ => Err(std::io::Error::last_os_error()),
    };
    if let Err(e) = &fifo {
        tracing::warn!(
            "SCHED_FIFO priority {priority} not granted ({e}): the servo loop runs with normal scheduling"
        );
    }
    if let Err(e) = &locked {
        tracing::warn!("mlockall not granted ({e}): page faults may delay ticks");
    }
    let (fifo, locked) = (fifo.is_ok(), locked.is_ok());
    if fifo && locked {
        tracing::info!(priority, "real-time scheduling and locked memory granted");
    }
    Realtime { fifo, locked }
}
