//! Fuzz and property tests of the launch-file reader (issue 14 point 6): mutated launch
//! files never panic, never allocate beyond a bound proportional to their size, and every
//! error names the file; every duration, rate and step has an upper bound whose error names
//! the file, the line and the key.

include!("../../tests/support/fuzz_common.rs");

use proptest::prelude::*;
use std::time::Instant;

const ORIGIN: &str = "/fuzz/launch.toml";

fn seeds() -> Vec<&'static str> {
    vec![
        launch_config::DEFAULT_LAUNCH,
        include_str!("../launch/study_lateral.toml"),
        include_str!("../launch/study_lateral_calibrated.toml"),
        include_str!("../launch/replay.toml"),
        include_str!("../launch/remote_viewer.toml"),
    ]
}

#[test]
fn mutated_launch_files_fail_typed_within_bounded_memory() {
    let cases = fuzz_cases(5_000);
    let seeds = seeds();
    let started = Instant::now();
    let errors = std::cell::Cell::new(0u32);
    let runs = std::cell::Cell::new(0u32);
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig {
        cases,
        failure_persistence: None,
        ..ProptestConfig::default()
    });
    let strategy = (0..seeds.len(), proptest::collection::vec(mutation(), 1..6));
    let result = runner.run(&strategy, |(seed, mutations)| {
        let bytes = mutate(seeds[seed].as_bytes(), &mutations);
        let text = String::from_utf8_lossy(&bytes).into_owned();
        let (result, peak) = counting::measure(|| launch_config::load_str(&text, ORIGIN));
        runs.set(runs.get() + 1);
        prop_assert!(
            peak <= alloc_limit(text.len(), 256),
            "{peak} bytes allocated for {} bytes of launch file",
            text.len()
        );
        if let Err(e) = result {
            errors.set(errors.get() + 1);
            let msg = e.to_string();
            prop_assert!(msg.contains(ORIGIN), "error does not name the file: {msg}");
            for issue in e.issues() {
                // Keys written in the file are located; defaults have no line.
                if let Some(line) = issue.line {
                    prop_assert!(line >= 1 && line <= text.lines().count().max(1));
                }
            }
        }
        Ok(())
    });
    let secs = started.elapsed().as_secs_f64();
    let (runs, errors) = (runs.get(), errors.get());
    println!(
        "{{\"fuzz\":\"launch_toml\",\"cases\":{runs},\"errors\":{errors},\"seconds\":{secs:.2}}}"
    );
    result.unwrap();
}

/// Every duration, rate and step key with its section, a value beyond its bound, and the
/// bound's unit word the message must show.
const BOUNDED: &[(&str, &str, &str)] = &[
    ("session", "seconds", "s"),
    ("launcher", "restart_backoff_s", "s"),
    ("launcher", "ready_timeout_s", "s"),
    ("launcher", "stop_grace_s", "s"),
    ("launcher", "status_period_s", "s"),
    ("scene", "dt", "s"),
    ("device", "rate_hz", "Hz"),
    ("device", "continuous_window_s", "s"),
    ("device", "stale_frame_s", "s"),
    ("device", "stale_ramp_s", "s"),
    ("device", "lcp_budget_s", "s"),
    ("device", "stats_rate_hz", "Hz"),
    ("device.emulated", "hold_s", "s"),
    ("device.replay", "time_scale", ""),
    ("recording", "mesh_rate_hz", "Hz"),
];

proptest! {
    #![proptest_config(ProptestConfig { cases: fuzz_cases(200), failure_persistence: None, ..ProptestConfig::default() })]

    /// A huge (but finite) value of any bounded key is refused, naming file, line and key.
    #[test]
    fn huge_durations_rates_and_steps_are_refused_with_file_line_and_key(
        which in 0..BOUNDED.len(),
        exponent in 7i32..308,
        mantissa in 1.0f64..9.99,
        blank_lines in 0usize..5,
    ) {
        let (section, key, _) = BOUNDED[which];
        // `recording.mesh_rate_hz` is allowed up to 1e9 Hz (every step's surface); the other
        // bounded keys stop below 1e7.
        let exponent = if key == "mesh_rate_hz" { exponent.max(10) } else { exponent };
        let value = mantissa * 10f64.powi(exponent);
        let text = format!("{}[{section}]\n{key} = {value:e}\n", "\n".repeat(blank_lines));
        let expected_line = blank_lines + 2;
        let err = launch_config::load_str(&text, ORIGIN).expect_err("a huge value must be refused");
        let dotted = format!("{section}.{key}");
        let issue = err
            .issues()
            .iter()
            .find(|i| i.key == dotted)
            .unwrap_or_else(|| panic!("no issue for {dotted}: {err}"));
        prop_assert_eq!(issue.line, Some(expected_line), "{}", err);
        let msg = err.to_string();
        let located = format!("{ORIGIN}:{expected_line}:");
        prop_assert!(msg.contains(&located) && msg.contains(&dotted), "{}", msg);
    }
}

#[test]
fn session_length_and_bridge_depths_have_upper_bounds() {
    for (text, key) in [
        (
            "[bridge]\nqueue_depth = 100000000000\n",
            "bridge.queue_depth",
        ),
        (
            "[recording]\nchunk_size_bytes = 100000000000\n",
            "recording.chunk_size_bytes",
        ),
        ("[scene]\ndt = 1e-9\n", "scene.dt"),
    ] {
        let err = launch_config::load_str(text, ORIGIN).expect_err(text);
        let issue = err.issues().iter().find(|i| i.key == key);
        assert!(issue.is_some_and(|i| i.line == Some(2)), "{key}: {err}");
    }
    // At the bound is fine.
    let text = format!(
        "[session]\nseconds = {}\n",
        launch_config::validate::MAX_SESSION_S
    );
    launch_config::load_str(&text, ORIGIN).unwrap();
}
