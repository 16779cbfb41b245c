//! Fuzz tests of the experiment readers (issue 14 point 6): mutated experiment TOML files
//! and trial CSVs never panic, never allocate beyond a bound proportional to the file size,
//! and every error names the file and the line; huge time spans are refused at their row.

include!("../../tests/support/fuzz_common.rs");

use gap_diagnosis::experiment::{load_experiment, parse_trial_csv};
use gap_diagnosis::GapError;
use proptest::prelude::*;
use std::path::{Path, PathBuf};
use std::time::Instant;

fn test_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("arthrosim-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

const HEADER: &str = "t_s,fx_N,fy_N,fz_N,px_m,py_m,pz_m,qx,qy,qz,qw";

fn trial_csv(n: usize) -> String {
    let mut s = String::from(HEADER);
    s.push('\n');
    for i in 0..n {
        s.push_str(&format!(
            "{},0,0,{},0,0,{},0,0,0,1\n",
            i as f64 * 0.026,
            i as f64 * 0.1,
            0.01 - i as f64 * 1e-4
        ));
    }
    s
}

const EXPERIMENT: &str = "[specimen]\nmesh = \"default:lateral:coarse\"\nfixed = \"inferior\"\n\n\
[material]\npreset = \"lateral\"\n\n[probe]\ntip_radius = 0.0005\n\n\
[[trial]]\nfile = \"a.csv\"\nregion = \"mid\"\n\n[[trial]]\nfile = \"b.csv\"\n";

#[test]
fn mutated_experiment_inputs_fail_typed_within_bounded_memory() {
    let data = gap_diagnosis::data_dir();
    let dir = test_dir("fuzz-experiment");
    std::fs::write(dir.join("experiment.toml"), EXPERIMENT).unwrap();
    std::fs::write(dir.join("a.csv"), trial_csv(12)).unwrap();
    std::fs::write(dir.join("b.csv"), trial_csv(8)).unwrap();
    load_experiment(&dir, &data).expect("the seed experiment is valid");
    let csv_seed = trial_csv(12);

    let cases = fuzz_cases(800);
    let started = Instant::now();
    let (runs, errors) = (
        std::cell::RefCell::new([0u32; 2]),
        std::cell::Cell::new(0u32),
    );
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig {
        cases,
        failure_persistence: None,
        ..ProptestConfig::default()
    });
    let strategy = (any::<bool>(), proptest::collection::vec(mutation(), 1..6));
    let result = runner.run(&strategy, |(toml, mutations)| {
        let (err, peak, len, file) = if toml {
            let bytes = mutate(EXPERIMENT.as_bytes(), &mutations);
            std::fs::write(dir.join("experiment.toml"), &bytes).unwrap();
            let (r, peak) = counting::measure(|| load_experiment(&dir, &data));
            // The trial files (20 rows) are read too.
            (r.err(), peak, bytes.len() + 2048, "experiment.toml")
        } else {
            let bytes = mutate(csv_seed.as_bytes(), &mutations);
            let text = String::from_utf8_lossy(&bytes).into_owned();
            let (r, peak) = counting::measure(|| parse_trial_csv(&text, &dir.join("a.csv")));
            (r.err(), peak, text.len(), "a.csv")
        };
        runs.borrow_mut()[toml as usize] += 1;
        prop_assert!(
            peak <= alloc_limit(len, 256),
            "{file}: {peak} bytes allocated for {len} bytes of input"
        );
        if let Some(e) = err {
            errors.set(errors.get() + 1);
            let msg = e.to_string();
            prop_assert!(
                msg.contains(file) || msg.contains(".csv"),
                "error does not name the file: {msg}"
            );
            if let GapError::Line { line, .. } = e {
                prop_assert!(line >= 1, "{msg}");
            }
        }
        Ok(())
    });
    let secs = started.elapsed().as_secs_f64();
    let (runs, errors) = (runs.into_inner(), errors.get());
    println!(
        "{{\"fuzz\":\"experiment\",\"cases\":{},\"toml\":{},\"csv\":{},\"errors\":{errors},\"seconds\":{secs:.2}}}",
        runs[0] + runs[1],
        runs[1],
        runs[0]
    );
    result.unwrap();
}

proptest! {
    #![proptest_config(ProptestConfig { cases: fuzz_cases(200), failure_persistence: None, ..ProptestConfig::default() })]

    /// A trial whose time column jumps by a huge span (or to a huge time) is refused at the
    /// row that does it, naming the file, the line and the column.
    #[test]
    fn huge_csv_time_spans_are_refused_with_file_line_and_column(
        rows in 5usize..20,
        at in 1usize..5,
        exponent in 3i32..300,
    ) {
        let mut lines: Vec<String> = trial_csv(rows).lines().map(String::from).collect();
        let jump = 10f64.powi(exponent);
        // Shift every row from `at` on by the jump (time stays increasing).
        for (i, line) in lines.iter_mut().enumerate().skip(1) {
            if i > at {
                let (t, rest) = line.split_once(',').unwrap();
                *line = format!("{},{rest}", t.parse::<f64>().unwrap() + jump);
            }
        }
        let text = lines.join("\n") + "\n";
        let e = parse_trial_csv(&text, Path::new("/fuzz/span.csv")).unwrap_err();
        let msg = e.to_string();
        let expected = format!("/fuzz/span.csv:{}:", at + 2);
        prop_assert!(msg.starts_with(&expected) && msg.contains("t_s"), "{}", msg);
    }
}
