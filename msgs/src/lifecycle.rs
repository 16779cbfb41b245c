//! Process lifecycle shared by every node binary: a stop flag raised by SIGINT / SIGTERM /
//! SIGHUP, and the readiness line the launcher waits for.

use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_stop_signal(_: libc::c_int) {
    // Only an atomic store: async-signal-safe.
    STOP.store(true, Ordering::SeqCst);
}

/// Installs SIGINT, SIGTERM and SIGHUP handlers that raise the stop flag, and returns it. A
/// node's loop checks the flag each iteration and stops cleanly (force to zero, files
/// closed). SIGHUP (the terminal closed, the SSH session dropped) stops in order like
/// SIGTERM instead of killing the process mid-write.
pub fn install_stop_flag() -> &'static AtomicBool {
    // SAFETY: installing a handler that only performs an atomic store.
    unsafe {
        let handler = on_stop_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
        libc::signal(libc::SIGINT, handler);
        libc::signal(libc::SIGTERM, handler);
        libc::signal(libc::SIGHUP, handler);
    }
    &STOP
}

/// The process-wide stop flag (also raised by signals once installed).
pub fn stop_flag() -> &'static AtomicBool {
    &STOP
}

/// Prints `READY <node>` on stdout and flushes: the launcher's readiness signal, sent once
/// the node's shared-memory ports are open and it is stepping.
pub fn announce_ready(node: &str) {
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "READY {node}");
    let _ = out.flush();
}
