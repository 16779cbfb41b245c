//! The blind self-test on truth that differs from the replay model as reality does (issue 15,
//! point 4): the truth runs on the refined mesh with a ball tip where the replay presses the
//! hook on the coarse one, every case carries a random ±15% stiffness offset, the presses are
//! the study's 0.5–1.2 mm, sampling is irregular at ~38 Hz with noise, and there are pairs.
//! The assertions are what the diagnosis reaches on these cases, not what the self-consistent
//! mode (truth = replay model) reaches; that one stays a fast unit check in `gap_physics`.
use gap_diagnosis::reality::Fidelity;
use gap_diagnosis::selftest::{selftest, SelftestOptions};
use gap_diagnosis::{self as gap};

fn data_present() -> bool {
    let d = gap::data_dir();
    let ok = d
        .join("meniscus/lateral_meniscus_computation.msh")
        .is_file();
    if !ok && std::env::var("CI").map(|v| v == "true").unwrap_or(false) {
        panic!("CI=true but the study data is missing at {}", d.display());
    }
    ok
}

/// The cases: no effect (the stiffness offset alone), the two effects the hidden sets
/// missed or mistook behind a stiffness offset (friction, support), and a modulus beyond the
/// model's own error. Four cases of fifteen trials keep it within CI's time.
const CASES: [&str; 4] = ["none", "friction", "support", "modulus"];

#[test]
fn reality_like_selftest_reaches_its_accuracy() {
    if !data_present() {
        return;
    }
    let opts = SelftestOptions {
        fidelity: Fidelity::Reality,
        verbose: true,
        cases: Some(CASES.iter().map(|s| s.to_string()).collect()),
        ..Default::default()
    };
    let r = selftest(CASES.len(), 15, &opts).unwrap();
    eprintln!("{}", r.table());
    let s = r.summary();
    // every case carried an offset, and a different one
    let offsets: Vec<f64> = r.cases.iter().map(|c| c.stiffness_offset).collect();
    assert!(
        offsets.iter().all(|o| (o - 1.0).abs() <= 0.15 && *o != 1.0),
        "{offsets:?}"
    );
    // a persistent stiffness offset is not `support`, and `none` stays `none`
    for c in r.cases.iter().filter(|c| c.truth == "none") {
        assert_eq!(
            c.found, "none",
            "case {}: offset {}",
            c.case, c.stiffness_offset
        );
    }
    // reached (seed 15): none → none (offset 0.84 within the floor), friction → none and
    // support → modulus: the site-to-site stiffness error of the coarse replay against the
    // refined truth (between-trial spread ~60%) sets a floor that hides them (issue 15)
    assert!(s.correct >= REACHED, "{}/{} correct", s.correct, s.cases);
}

/// Cases of [`CASES`] the diagnosis names exactly (seed 15; `modulus` was not yet measured).
const REACHED: usize = 1;
