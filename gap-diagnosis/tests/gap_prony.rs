//! The `viscoelastic` effect with one or two Prony terms: trials whose measured force is a
//! known QLV response of the replayed force are fitted; the second term is used when, and
//! only when, the data need it.
use gap_diagnosis::dataset::{prepare, TrialData};
use gap_diagnosis::effects::qlv_in_place;
use gap_diagnosis::fit::{make_folds, score_candidate, Baseline, CandidateScore, Nuisance};
use gap_diagnosis::model::ProbePath;
use gap_diagnosis::{Candidate, Effect, Region, Trial};
use msgs::Pose;

const DT: f64 = 0.02;

/// Press 1.2 mm along −z in 1 s, hold `hold` s, release in 1 s; elastic force ∝ depth^1.5.
/// Measured: the QLV response with `terms`, at irregular ~38 Hz, with noise.
fn trial<const N: usize>(
    i: usize,
    region: Region,
    hold: f64,
    terms: &[(f64, f64); N],
    seed: &mut u64,
) -> TrialData {
    let mut rnd = || {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let depth_max = 1.2e-3 * (0.8 + 0.1 * i as f64);
    let t_end = 1.0 + 1.0 + hold + 1.0 + 0.5;
    let n = (t_end / DT).round() as usize + 1;
    let z = |t: f64| -> f64 {
        // +0.5 mm above the surface at t = 0, contact at 0.5 s
        let d = if t < 2.0 {
            -0.5e-3 + (depth_max + 0.5e-3) * t / 2.0
        } else if t < 2.0 + hold {
            depth_max
        } else {
            depth_max - (depth_max + 0.5e-3) * (t - 2.0 - hold) / 2.0
        };
        -d
    };
    let poses: Vec<Pose> = (0..n)
        .map(|k| Pose {
            position: [0.0, 0.0, z(k as f64 * DT)],
            orientation: [0.0, 0.0, 0.0, 1.0],
        })
        .collect();
    let base: Vec<[f64; 3]> = poses
        .iter()
        .map(|p| [0.0, 0.0, 4.0e4 * (-p.position[2]).max(0.0).powf(1.5)])
        .collect();
    let mut truth = base.clone();
    qlv_in_place(&mut truth, DT, terms);
    let mut t = vec![0.01];
    while *t.last().unwrap() < t_end - 0.05 {
        let next = t.last().unwrap() + (1.0 + 0.25 * (2.0 * rnd() - 1.0)) / 38.0;
        t.push(next);
    }
    t.pop();
    let at = |y: &[[f64; 3]], tq: f64| {
        let s = tq / DT;
        let k = (s.floor() as usize).min(n - 2);
        let w = s - k as f64;
        let mut v = [0.0; 3];
        for q in 0..3 {
            v[q] = y[k][q] + w * (y[k + 1][q] - y[k][q]);
        }
        v
    };
    let force: Vec<[f64; 3]> = t
        .iter()
        .map(|&tq| {
            let mut v = at(&truth, tq);
            for x in v.iter_mut() {
                *x += 0.004 * (rnd() + rnd() + rnd() - 1.5);
            }
            v
        })
        .collect();
    let pose: Vec<Pose> = t
        .iter()
        .map(|&tq| Pose {
            position: [0.0, 0.0, z(tq)],
            orientation: [0.0, 0.0, 0.0, 1.0],
        })
        .collect();
    let tr = Trial {
        name: format!("{}_{i}", region.name()),
        file: Default::default(),
        region: Some(region),
        t,
        force,
        pose,
        lead_in: 0.0,
    };
    let path = ProbePath {
        t0: 0.0,
        dt: DT,
        poses,
    };
    prepare(&tr, path, base, Default::default())
}

/// Two probings per region from the QLV truth with these Prony terms (same seed every call).
fn dataset<const N: usize>(terms: &[(f64, f64); N]) -> Vec<TrialData> {
    let mut seed = 11u64;
    Region::ALL
        .into_iter()
        .flat_map(|r| (0..2).map(move |i| (r, i)))
        .map(|(r, i)| trial(i, r, 4.0, terms, &mut seed))
        .collect()
}

fn score<const N: usize>(terms: &[(f64, f64); N]) -> CandidateScore {
    let data = dataset(terms);
    let (_, folds) = make_folds(&data);
    score_candidate(
        &Candidate::single(Effect::Viscoelastic),
        &data,
        &folds,
        &Baseline::of(&data),
        &[],
        Nuisance::STIFFNESS,
    )
}

fn param(c: &CandidateScore, name: &str) -> Option<f64> {
    c.params.iter().find(|p| p.name == name).map(|p| p.value)
}

#[test]
fn one_prony_term_when_one_suffices() {
    let c = score(&[(0.4, 0.5)]);
    eprintln!("{:?}", c.params);
    assert_eq!(c.n_params, 2, "{:?}", c.params);
    assert!(
        param(&c, "prony_g2").is_none(),
        "held terms are not reported"
    );
    let g1 = param(&c, "prony_g1").unwrap();
    let tau1 = param(&c, "prony_tau1").unwrap();
    assert!((g1 - 0.4).abs() < 0.03, "g1 {g1}");
    assert!((tau1 - 0.5).abs() < 0.1, "tau1 {tau1}");
    assert!(c.heldout_shrink > 0.8, "shrink {}", c.heldout_shrink);
}

#[test]
fn two_prony_terms_when_relaxation_has_two_time_scales() {
    let c = score(&[(0.25, 0.3), (0.3, 6.0)]);
    eprintln!("{:?}", c.params);
    assert_eq!(c.n_params, 4, "{:?}", c.params);
    let g = |n| param(&c, n).unwrap();
    assert!((g("prony_g1") - 0.25).abs() < 0.05, "{:?}", c.params);
    assert!((g("prony_tau1") - 0.3).abs() < 0.1, "{:?}", c.params);
    assert!((g("prony_g2") - 0.3).abs() < 0.08, "{:?}", c.params);
    assert!((2.5..15.0).contains(&g("prony_tau2")), "{:?}", c.params);
    assert!(c.heldout_shrink > 0.8, "shrink {}", c.heldout_shrink);
    // one term alone cannot follow both time scales
    let one = score_one_term(&[(0.25, 0.3), (0.3, 6.0)]);
    assert!(
        c.heldout_rmse < 0.7 * one,
        "two terms {} vs one term {one}",
        c.heldout_rmse
    );
}

/// RMSE of the best one-term QLV (second term held at 0) fitted on all of the two-term
/// data: in-sample, so it flatters the one-term model.
fn score_one_term<const N: usize>(terms: &[(f64, f64); N]) -> f64 {
    use gap_diagnosis::fit::{default_free, fit, Nuisance};
    let data = dataset(terms);
    let c = Candidate::single(Effect::Viscoelastic);
    let all: Vec<Vec<bool>> = data.iter().map(|d| vec![true; d.t.len()]).collect();
    let sse = fit(&c, &data, &all, &[], &default_free(&c), Nuisance::STIFFNESS).sse;
    let n: usize = data.iter().map(|d| 3 * d.t.len()).sum();
    (sse / n as f64).sqrt()
}
