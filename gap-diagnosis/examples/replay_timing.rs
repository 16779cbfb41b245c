//! Development tool: where an offline replay's time goes. Replays one protocol probing per
//! region (the region's first site, pressed to the middle of the study's depths and slid) on
//! a specimen, as the gap diagnosis replays a trial, and prints per probing the construction
//! time, the whole replay's, the steps the settled shortcuts skipped, the CG iterations of
//! the steps taken (as a histogram) and the step's phases.
//!
//! `cargo run --release -p gap-diagnosis --example replay_timing` (environment:
//! `REPLAY_TIMING_MESH`, default `default:lateral:40x6x4`, the 1,435-node bench specimen;
//! `REPLAY_TIMING_NEO_HOOKEAN=1` replays the material knot's neo-Hookean law;
//! `REPLAY_TIMING_REPEATS`, default 1, replays each probing that many times).
//! The README's "Element kernels for the offline replays" was measured with it.
use anyhow::Context;
use gap_diagnosis::experiment::Region;
use gap_diagnosis::reality::{protocol_path, STUDY_PRESS_DEPTHS};
use gap_diagnosis::{SimForceModel, Variant};
use launch_config::SceneConfig;
use std::time::Instant;

/// CG iteration counts at or above this share the histogram's last bin.
const HISTOGRAM_BINS: usize = 12;

fn main() -> anyhow::Result<()> {
    let data = gap_diagnosis::data_dir();
    let mut scene = SceneConfig::default();
    scene.meniscus.mesh =
        std::env::var("REPLAY_TIMING_MESH").unwrap_or_else(|_| "default:lateral:40x6x4".into());
    let repeats: usize = match std::env::var("REPLAY_TIMING_REPEATS") {
        Ok(s) => s
            .parse()
            .with_context(|| format!("REPLAY_TIMING_REPEATS {s:?} is not a count"))?,
        Err(_) => 1,
    };
    let variant = Variant {
        neo_hookean: std::env::var_os("REPLAY_TIMING_NEO_HOOKEAN").is_some(),
        ..Variant::default()
    };
    let model = SimForceModel::from_scene(scene, &data);
    let sites = model.sites()?;
    let [lo, hi] = STUDY_PRESS_DEPTHS;
    let mut total = 0.0;
    for region in Region::ALL {
        let Some(site) = sites.iter().find(|s| s.region == region) else {
            continue;
        };
        let path = protocol_path(
            site.point,
            site.normal,
            0.5 * (lo + hi),
            model.scene.probe.tip_radius,
            // along world x, across the normal: any tangent slides the probe
            Some([1.0, 0.0, 0.0]),
            0.02,
        );
        for _ in 0..repeats {
            let start = Instant::now();
            let mut sim = model.simulation(&variant, path.dt)?;
            let built = start.elapsed().as_secs_f64();
            if let Some(p0) = path.poses.first() {
                sim.teleport_probe(p0);
            }
            let (mut taken, mut iterations) = (0usize, 0usize);
            let mut histogram = [0usize; HISTOGRAM_BINS];
            for pose in &path.poses {
                let skipped = sim.settled_steps();
                sim.set_probe_kinematic(pose);
                sim.step()?;
                if sim.settled_steps() == skipped {
                    let it = sim.fem().last_solve().iterations;
                    taken += 1;
                    iterations += it;
                    histogram[it.min(HISTOGRAM_BINS - 1)] += 1;
                }
            }
            let elapsed = start.elapsed().as_secs_f64();
            total += elapsed;
            let ph = sim.phase_times();
            let ms = |ns: u64| ns as f64 * 1e-6;
            let (repeated, at_rest) = sim.settled_steps();
            println!(
                "{region:?}: {} steps, built in {built:.3} s, replayed in {elapsed:.3} s; \
                 skipped {repeated} repeated and {at_rest} at rest; {taken} taken with \
                 {iterations} CG iterations {histogram:?}; phases (ms): prepare {:.0}, free \
                 motion {:.0}, detection {:.0}, compliance {:.0}, LCP {:.0}, correction {:.0}",
                path.poses.len(),
                ms(ph.prepare_ns),
                ms(ph.free_motion_ns),
                ms(ph.detection_ns),
                ms(ph.compliance_ns),
                ms(ph.lcp_ns),
                ms(ph.correction_ns),
            );
        }
    }
    println!("total {total:.3} s");
    Ok(())
}
