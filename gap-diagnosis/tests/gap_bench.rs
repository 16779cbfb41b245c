//! Benchmark (ignored in normal runs; timing is printed, never asserted):
//! `cargo test --release -p recordings --test gap_bench -- --ignored --nocapture`
//! prints one JSON line: a generated 15-trial experiment (five probings × three regions)
//! diagnosed end to end with the physics model.
#[test]
#[ignore]
fn gap_diagnose_15_trials() {
    let effect = std::env::var("GAP_BENCH_EFFECT").unwrap_or_else(|_| "hardening".into());
    let v = gap_diagnosis::selftest::bench(&effect, 5, &gap_diagnosis::Options::default()).unwrap();
    println!("{v}");
}

/// The full case cycle through the physics model (release; slow):
/// `GAP_CASES=14 cargo test --release -p recordings --test gap_bench -- --ignored --nocapture selftest_cycle`
#[test]
#[ignore]
fn selftest_cycle() {
    let n: usize = std::env::var("GAP_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(14);
    let opts = gap_diagnosis::selftest::SelftestOptions {
        verbose: true,
        ..Default::default()
    };
    let r = gap_diagnosis::selftest::selftest(n, 21, &opts).unwrap();
    print!("{}", r.table());
    println!("{}", serde_json::to_string(&r.summary()).unwrap());
}
