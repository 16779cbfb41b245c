//! Fuzz tests of the recording reader (issue 14 point 6), in the style of `bad_files.rs`
//! but property-based: mutated MCAP recordings never panic, never allocate beyond a bound
//! proportional to the file size, and every error names the file.

include!("../../tests/support/fuzz_common.rs");

mod common;

use common::*;
use launch_config::RecordingConfig;
use msgs::haptic_to_physics::DeviceState;
use msgs::physics_to_haptic::ContactFrame;
use proptest::prelude::*;
use recordings::{SessionInfo, SessionWriter};
use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

fn small_session(path: &Path) -> Vec<u8> {
    let config = RecordingConfig {
        flush_interval_s: 0.05,
        ..Default::default()
    };
    let mut w = SessionWriter::create(path, &config, &SessionInfo::default()).unwrap();
    let mut d = boxed_zeroed::<DeviceState>();
    let mut f = boxed_zeroed::<ContactFrame>();
    for seq in 1..=120u64 {
        fill_device(&mut d, seq, 1);
        let log = 1_000_000_000 + seq * 1_000_000;
        w.write_device_state(&d, log).unwrap();
        if seq % 10 == 0 {
            fill_frame(&mut f, seq / 10, 2, seq);
            w.write_contact_frame(&f, log).unwrap();
        }
        w.maybe_flush(log).unwrap();
    }
    w.finish(BTreeMap::new()).unwrap();
    std::fs::read(path).unwrap()
}

/// The MCAP reader accepts chunks up to 1000:1 (zstd of real recordings stays far below),
/// so what it may allocate is bounded by ~1000 × the file.
const MCAP_BYTES_PER_BYTE: usize = 1100;

#[test]
fn mutated_recordings_fail_typed_within_bounded_memory() {
    let dir = test_dir("fuzz-mcap");
    let seed = small_session(&dir.join("seed.mcap"));
    let path = dir.join("case.mcap");
    let cases = fuzz_cases(400);
    let started = Instant::now();
    let (runs, errors) = (std::cell::Cell::new(0u32), std::cell::Cell::new(0u32));
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig {
        cases,
        failure_persistence: None,
        ..ProptestConfig::default()
    });
    let strategy = proptest::collection::vec(mutation(), 1..8);
    let result = runner.run(&strategy, |mutations| {
        let bytes = mutate(&seed, &mutations);
        std::fs::write(&path, &bytes).unwrap();
        let ((info, lossless), peak) = counting::measure(|| {
            (
                recordings::info(&path),
                recordings::export::read_lossless(&path),
            )
        });
        runs.set(runs.get() + 1);
        prop_assert!(
            peak <= alloc_limit(bytes.len(), MCAP_BYTES_PER_BYTE),
            "{peak} bytes allocated for a {}-byte recording",
            bytes.len()
        );
        for e in [info.err(), lossless.err()].into_iter().flatten() {
            errors.set(errors.get() + 1);
            let msg = e.to_string();
            prop_assert!(
                msg.contains("case.mcap"),
                "error does not name the file: {msg}"
            );
        }
        Ok(())
    });
    let secs = started.elapsed().as_secs_f64();
    let (runs, errors) = (runs.get(), errors.get());
    println!("{{\"fuzz\":\"mcap\",\"cases\":{runs},\"errors\":{errors},\"seconds\":{secs:.2}}}");
    result.unwrap();
}
