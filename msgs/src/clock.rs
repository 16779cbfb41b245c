//! One clock for every process: CLOCK_MONOTONIC in nanoseconds, comparable across processes
//! on the same machine (frame age and transport latency are differences of these).

/// Nanoseconds of CLOCK_MONOTONIC.
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: valid pointer to a timespec; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Nanoseconds since the Unix epoch (CLOCK_REALTIME), for ROS 2 header stamps and MCAP
/// log times.
pub fn realtime_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: as above.
    unsafe { libc::clock_gettime(libc::CLOCK_REALTIME, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// A random-enough 64-bit instance id (clock, pid and address entropy mixed by splitmix64).
pub fn new_instance_id() -> u64 {
    let local = 0u8;
    let mut z = monotonic_ns()
        ^ realtime_ns().rotate_left(17)
        ^ ((std::process::id() as u64) << 32)
        ^ (&local as *const u8 as u64);
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    (z ^ (z >> 31)).max(1)
}

/// The CPU the calling thread runs on, plus one (0: not known). For
/// [`ContactFrame::publisher_cpu_plus_one`](crate::physics_to_haptic::ContactFrame).
pub fn current_cpu_plus_one() -> u32 {
    // SAFETY: plain call (vDSO on Linux).
    let cpu = unsafe { libc::sched_getcpu() };
    if cpu >= 0 {
        cpu as u32 + 1
    } else {
        0
    }
}
