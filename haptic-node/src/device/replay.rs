//! Replay of a recorded proxy trajectory from CSV (`t_s,px_m,py_m,pz_m,qx,qy,qz,qw`, scene
//! frame), read with the workspace's one CSV reader (`msgs::csv_input`). Poses are
//! interpolated linearly (normalised-lerp for the orientation). Time must be finite and
//! increasing and a finite quaternion must be a unit one, as in every CSV input; non-finite
//! pose values are the one exception and are kept as recorded, so a recording with a
//! dropped-out sensor (and the quarantine tests' NaN trajectories) exercises the node's
//! quarantine exactly like a live device would.

use super::{Device, DeviceError, DeviceSample};
use launch_config::device::ReplayConfig;
use msgs::csv_input::{self, Order, Spec};
use msgs::haptic_to_physics::DeviceKind;
use msgs::Pose;
use std::path::Path;

const HEADER: [&str; 8] = ["t_s", "px_m", "py_m", "pz_m", "qx", "qy", "qz", "qw"];

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimedPose {
    pub t_s: f64,
    pub pose: Pose,
}

/// Parses the CSV text under the workspace's CSV rules (`msgs::csv_input`: every column
/// present, finite time increasing, unit quaternions; errors name file and line); `path`
/// names the file in errors. The pose columns are dropout columns: a non-finite pose is kept
/// as recorded (see the module documentation).
pub fn parse_trajectory(text: &str, path: &str) -> Result<Vec<TimedPose>, DeviceError> {
    let spec = Spec {
        columns: &HEADER,
        order: Some((0, Order::Increasing, "time")),
        quaternion: Some([4, 5, 6, 7]),
        dropouts: &[1, 2, 3, 4, 5, 6, 7],
        magnitude: &[],
    };
    let table =
        csv_input::parse(text, Path::new(path), &spec).map_err(|e| DeviceError::ReplayLine {
            path: path.into(),
            line: e.line,
            problem: e.problem,
        })?;
    if table.is_empty() {
        return Err(DeviceError::Replay {
            path: path.into(),
            problem: "no poses after the header".into(),
        });
    }
    Ok(table
        .rows()
        .map(|v| TimedPose {
            t_s: v[0],
            pose: Pose {
                position: [v[1], v[2], v[3]],
                orientation: [v[4], v[5], v[6], v[7]],
            },
        })
        .collect())
}

pub struct Replay {
    poses: Vec<TimedPose>,
    looped: bool,
    time_scale: f64,
    start_ns: u64,
    cursor: usize,
    finished: bool,
}

impl Replay {
    pub fn open(c: &ReplayConfig, start_ns: u64) -> Result<Replay, DeviceError> {
        if c.path.is_empty() {
            return Err(DeviceError::Replay {
                path: "<none>".into(),
                problem: "[device.replay] path is not set".into(),
            });
        }
        if Path::new(&c.path)
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
        {
            // The node reads CSV only; the launcher converts recordings before starting it.
            return Err(DeviceError::Replay {
                path: c.path.clone(),
                problem: "a session recording: start the replay with `arthrosim run` (which \
                          extracts its device trajectory) or export it as the replay CSV first"
                    .into(),
            });
        }
        let text =
            std::fs::read_to_string(Path::new(&c.path)).map_err(|e| DeviceError::Replay {
                path: c.path.clone(),
                problem: e.to_string(),
            })?;
        let poses = parse_trajectory(&text, &c.path)?;
        Replay::new(poses, c, start_ns)
    }

    pub fn new(
        poses: Vec<TimedPose>,
        c: &ReplayConfig,
        start_ns: u64,
    ) -> Result<Replay, DeviceError> {
        if !(c.time_scale.is_finite() && c.time_scale > 0.0) {
            return Err(DeviceError::Replay {
                path: c.path.clone(),
                problem: format!("[device.replay] time_scale = {} must be > 0", c.time_scale),
            });
        }
        if poses.iter().any(|p| !p.pose.is_finite()) {
            tracing::warn!(path = %c.path, "replay trajectory has non-finite poses: they will be quarantined");
        }
        Ok(Replay {
            poses,
            looped: c.looped,
            time_scale: c.time_scale,
            start_ns,
            cursor: 0,
            finished: false,
        })
    }
}

fn lerp(a: f64, b: f64, u: f64) -> f64 {
    a + (b - a) * u
}

impl Device for Replay {
    fn kind(&self) -> DeviceKind {
        DeviceKind::Replay
    }

    fn sample(&mut self, now_ns: u64, out: &mut DeviceSample) -> Result<(), DeviceError> {
        let first = self.poses[0].t_s;
        let last = self.poses[self.poses.len() - 1].t_s;
        let mut t = first + now_ns.saturating_sub(self.start_ns) as f64 * 1e-9 * self.time_scale;
        if t > last {
            if self.looped && last > first {
                t = first + (t - first) % (last - first);
            } else {
                self.finished = true;
                t = last;
            }
        }
        if t < self.poses[self.cursor].t_s {
            self.cursor = 0;
        }
        while self.cursor + 1 < self.poses.len() && self.poses[self.cursor + 1].t_s <= t {
            self.cursor += 1;
        }
        let a = self.poses[self.cursor];
        let b = self.poses[(self.cursor + 1).min(self.poses.len() - 1)];
        let span = b.t_s - a.t_s;
        let u = if span > 0.0 {
            ((t - a.t_s) / span).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let mut q = [0.0; 4];
        // Shortest-arc nlerp.
        let dot: f64 = (0..4)
            .map(|k| a.pose.orientation[k] * b.pose.orientation[k])
            .sum();
        let sign = if dot < 0.0 { -1.0 } else { 1.0 };
        for k in 0..4 {
            q[k] = lerp(a.pose.orientation[k], sign * b.pose.orientation[k], u);
        }
        let n = (q.iter().map(|v| v * v).sum::<f64>()).sqrt();
        if n > 0.0 {
            q.iter_mut().for_each(|v| *v /= n);
        }
        out.pose = Pose {
            position: [
                lerp(a.pose.position[0], b.pose.position[0], u),
                lerp(a.pose.position[1], b.pose.position[1], u),
                lerp(a.pose.position[2], b.pose.position[2], u),
            ],
            orientation: q,
        };
        let inv = if span > 0.0 && !self.finished {
            self.time_scale / span
        } else {
            0.0
        };
        for k in 0..3 {
            out.velocity[k] = (b.pose.position[k] - a.pose.position[k]) * inv;
        }
        out.velocity[3..].fill(0.0);
        Ok(())
    }

    fn command_force(&mut self, _now_ns: u64, _force: [f64; 3]) -> Result<(), DeviceError> {
        // A replayed trajectory is prescribed: the force is published, not applied.
        Ok(())
    }

    fn zero_force(&mut self) {}

    fn finished(&self) -> bool {
        self.finished
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CSV: &str =
        "t_s,px_m,py_m,pz_m,qx,qy,qz,qw\n0,0,0,0.01,0,0,0,1\n1,0,0,0,0,0,0,1\n2,0.01,0,0,0,0,0,1\n";

    #[test]
    fn interpolates_and_finishes() {
        let poses = parse_trajectory(CSV, "t.csv").unwrap();
        let mut r = Replay::new(poses, &ReplayConfig::default(), 0).unwrap();
        let mut s = DeviceSample::default();
        r.sample(500_000_000, &mut s).unwrap();
        assert!((s.pose.position[2] - 0.005).abs() < 1e-12);
        assert!((s.velocity[2] + 0.01).abs() < 1e-12);
        r.sample(1_500_000_000, &mut s).unwrap();
        assert!((s.pose.position[0] - 0.005).abs() < 1e-12);
        assert!(!r.finished());
        r.sample(3_000_000_000, &mut s).unwrap();
        assert!(r.finished());
        assert_eq!(s.pose.position, [0.01, 0.0, 0.0]);
    }

    #[test]
    fn errors_name_file_and_line() {
        let e = parse_trajectory(
            "t_s,px_m,py_m,pz_m,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n1,0,x,0,0,0,0,1\n",
            "a.csv",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("a.csv") && e.contains("line 3") && e.contains("py_m"),
            "{e}"
        );
        let e = parse_trajectory("t,x\n", "b.csv").unwrap_err().to_string();
        assert!(e.contains("b.csv") && e.contains("line 1"), "{e}");
        let e = parse_trajectory(
            "t_s,px_m,py_m,pz_m,qx,qy,qz,qw\n1,0,0,0,0,0,0,1\n1,0,0,0,0,0,0,1\n",
            "c.csv",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("line 3") && e.contains("time not increasing"),
            "{e}"
        );
        let e = parse_trajectory("t_s,px_m,py_m,pz_m,qx,qy,qz,qw\n0,0,0\n", "d.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2") && e.contains("3 columns"), "{e}");
        // NaN positions parse (they are quarantined at the tick).
        let p = parse_trajectory(
            "t_s,px_m,py_m,pz_m,qx,qy,qz,qw\n0,NaN,0,0,0,0,0,1\n",
            "e.csv",
        )
        .unwrap();
        assert!(p[0].pose.position[0].is_nan());
        // A zero quaternion is rejected like in every CSV input.
        let e = parse_trajectory("t_s,px_m,py_m,pz_m,qx,qy,qz,qw\n0,0,0,0,0,0,0,0\n", "f.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2") && e.contains("zero quaternion"), "{e}");
    }
}
