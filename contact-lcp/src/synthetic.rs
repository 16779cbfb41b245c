//! A synthetic contact patch for benchmarks: `n` contacts on a 0.5 mm grid under a probe tip,
//! normals tilted by up to ±0.05, a shallow indentation. Used by `haptic-bench` and the
//! `patch-timing` example, so both time the same problem.

use crate::MAX_ROWS;

/// The patch in constraint space (rows grouped by contact: normal, then two tangents).
pub struct SyntheticPatch {
    /// Contact points, m.
    pub points: Vec<[f64; 3]>,
    /// Rows of H: `[linear x, y, z, angular x, y, z]`, angular part about the origin.
    pub directions: Vec<[f64; 6]>,
    /// Free-motion violation per row, m.
    pub free_violation: Vec<f64>,
    /// W, row-major with stride [`MAX_ROWS`], m/N·s.
    pub compliance: Vec<f64>,
}

/// W = tissue + probe. Tissue: 1/(k dt) with k ≈ 2000 N/m per contact, coupling between
/// like rows decaying over 1 mm. Probe: the 35 g probe on its stiff coupling spring
/// (1e4 N/m) under implicit Euler, dt / (m + dt² k), through H (translation only).
pub fn synthetic_patch(n: usize, dt: f64) -> SyntheticPatch {
    let side = (n as f64).sqrt().ceil() as usize;
    let rows = 3 * n;
    let mut points = vec![[0.0f64; 3]; n];
    let mut directions = vec![[0.0f64; 6]; rows];
    let mut free_violation = vec![0.0; rows];
    for (k, p) in points.iter_mut().enumerate() {
        *p = [(k % side) as f64 * 5e-4, (k / side) as f64 * 5e-4, 0.0];
        let tilt = 0.05 * ((k % 3) as f64 - 1.0);
        let l = (1.0 + tilt * tilt).sqrt();
        let nz = [tilt / l, 0.0, 1.0 / l];
        let t1 = [nz[2], 0.0, -nz[0]];
        let t2 = [0.0, 1.0, 0.0];
        for (r, d) in [nz, t1, t2].iter().enumerate() {
            // Angular part: p × d.
            let a = [
                p[1] * d[2] - p[2] * d[1],
                p[2] * d[0] - p[0] * d[2],
                p[0] * d[1] - p[1] * d[0],
            ];
            directions[3 * k + r] = [d[0], d[1], d[2], a[0], a[1], a[2]];
        }
        free_violation[3 * k] = -2e-4 * (1.0 + 0.3 * ((k % 4) as f64));
    }
    let c0 = 1.0 / (2000.0 * dt);
    let probe = dt / (0.035 + dt * dt * 1e4);
    let mut compliance = vec![0.0; MAX_ROWS * MAX_ROWS];
    for i in 0..rows {
        for j in 0..rows {
            let (pi, pj) = (points[i / 3], points[j / 3]);
            let r = ((pi[0] - pj[0]).powi(2) + (pi[1] - pj[1]).powi(2)).sqrt();
            let (hi, hj) = (directions[i], directions[j]);
            let dir = hi[0] * hj[0] + hi[1] * hj[1] + hi[2] * hj[2];
            let tissue = if i % 3 == j % 3 {
                c0 * (-r / 1e-3).exp()
            } else {
                0.0
            };
            compliance[i * MAX_ROWS + j] = tissue + probe * dir;
        }
    }
    SyntheticPatch {
        points,
        directions,
        free_violation,
        compliance,
    }
}
