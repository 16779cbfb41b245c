//! Benchmark (ignored in normal runs; timing is printed, never asserted):
//! `cargo test --release -p recordings --test gap_bench -- --ignored --nocapture`
//! prints one JSON line: a generated 15-trial experiment (five probings × three regions)
//! diagnosed end to end with the physics model.
#[test]
#[ignore]
fn gap_diagnose_15_trials() {
    let effect = std::env::var("GAP_BENCH_EFFECT").unwrap_or_else(|_| "hardening".into());
    let v = recordings::gap::selftest::bench(&effect, 5, &recordings::gap::Options::default()).unwrap();
    println!("{v}");
}
