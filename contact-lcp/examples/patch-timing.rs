//! Timing of the haptic re-solve on the synthetic contact patch of `haptic-bench`
//! (a dense 0.5 mm grid under a probe tip, μ = 0.2, a cold start every 10 solves from the
//! frame's λ = 0, ±50 µm hand jitter per solve), without the renderer around it.
//!
//! `cargo run --release -p contact-lcp --example patch-timing -- [contacts] [solves] [every]`
//!
//! With `every` > 0, every `every`-th solve is also compared (outside the timing) with a
//! reference solution of the same problem converged to 1e-14: the relative error of λ
//! (max-norm) and of the rendered force Σ h λ.
use contact_lcp::synthetic::synthetic_patch;
use contact_lcp::{solve, Problem, Settings, MAX_ROWS};
use std::time::Instant;

fn main() {
    let mut args = std::env::args().skip(1);
    let n: usize = args.next().map_or(32, |s| s.parse().unwrap());
    let solves: u64 = args.next().map_or(200_000, |s| s.parse().unwrap());
    let every: u64 = args.next().map_or(0, |s| s.parse().unwrap());
    let mut errors_lambda = Vec::new();
    let mut errors_force = Vec::new();
    let p = synthetic_patch(n, 0.01);
    let rows = 3 * n;
    let settings = Settings {
        max_iterations: 50,
        tolerance: 1e-3,
        deadline: None,
        deadline_check_every: 2,
    };
    let mut lambda = [0.0f64; MAX_ROWS];
    let mut delta = [0.0f64; MAX_ROWS];
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    // Solve times up to 1 s, in the workspace's one latency histogram.
    let mut times = msgs::timing::LatencyHistogram::new(1_000_000_000);
    let mut cold = msgs::timing::LatencyHistogram::new(1_000_000_000);
    let mut iterations = 0u64;
    let mut cold_iterations = 0u64;
    let mut checksum = 0.0;
    for i in 0..solves {
        if i % 10 == 0 {
            lambda[..rows].fill(0.0);
        }
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        let jitter = (seed % 1000) as f64 / 1000.0 - 0.5;
        let dx = [jitter * 1e-4, -jitter * 5e-5, jitter * 1e-4];
        for ((d, h), f) in delta[..rows]
            .iter_mut()
            .zip(&p.directions)
            .zip(&p.free_violation)
        {
            *d = f + h[0] * dx[0] + h[1] * dx[1] + h[2] * dx[2];
        }
        let problem = Problem {
            compliance: &p.compliance,
            free_violation: &delta[..rows],
            friction_mu: 0.2,
            row_count: rows,
        };
        let t = Instant::now();
        let s = solve(&problem, &mut lambda[..rows], &settings).unwrap();
        let ns = t.elapsed().as_nanos() as u64;
        times.record(ns);
        iterations += s.iterations as u64;
        if i % 10 == 0 {
            cold.record(ns);
            cold_iterations += s.iterations as u64;
        }
        checksum += lambda[..rows].iter().sum::<f64>();
        if every > 0 && i % every == 0 {
            let mut reference = [0.0f64; MAX_ROWS];
            let exact = Settings {
                max_iterations: 1_000_000,
                tolerance: 1e-14,
                ..settings
            };
            let s = solve(&problem, &mut reference[..rows], &exact).unwrap();
            assert!(s.converged, "reference: {s:?}");
            let max_ref = reference[..rows].iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let max_err = (0..rows).fold(0.0f64, |m, r| m.max((lambda[r] - reference[r]).abs()));
            errors_lambda.push(max_err / max_ref);
            let force = |l: &[f64]| {
                let mut f = [0.0; 3];
                for (h, l) in p.directions.iter().zip(l) {
                    for c in 0..3 {
                        f[c] += h[c] * l;
                    }
                }
                f
            };
            let (f, g) = (force(&lambda[..rows]), force(&reference[..rows]));
            let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            errors_force.push(norm([f[0] - g[0], f[1] - g[1], f[2] - g[2]]) / norm(g));
        }
    }
    let mean = times.mean_ns() / 1e3;
    println!(
        "contacts {n}: p50 {:.2} µs p99 {:.2} µs mean {:.2} µs, iterations mean {:.2}; cold starts p50 {:.2} µs, iterations {:.2}; checksum {checksum:.15e}",
        times.quantile_us(0.5),
        times.quantile_us(0.99),
        mean,
        iterations as f64 / solves as f64,
        cold.quantile_us(0.5),
        cold_iterations as f64 / cold.count() as f64,
    );
    if every > 0 {
        for (what, e) in [("λ", &mut errors_lambda), ("force", &mut errors_force)] {
            let mean = e.iter().sum::<f64>() / e.len() as f64;
            e.sort_by(f64::total_cmp);
            println!(
                "  relative error of {what} vs converged ({} samples): mean {mean:.3e} p99 {:.3e} max {:.3e}",
                e.len(),
                e[(e.len() - 1) * 99 / 100],
                e[e.len() - 1]
            );
        }
    }
}
