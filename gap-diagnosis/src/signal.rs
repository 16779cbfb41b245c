//! Signal helpers: interpolation onto other time bases, lag by cross-correlation, noise level,
//! the work a force does along a path.

/// Linear interpolation of `y(x)` at `xq`, clamped at the ends. `x` strictly increasing.
pub fn interp(x: &[f64], y: &[f64], xq: f64) -> f64 {
    let n = x.len();
    if n == 0 {
        return 0.0;
    }
    if xq <= x[0] {
        return y[0];
    }
    if xq >= x[n - 1] {
        return y[n - 1];
    }
    let i = x.partition_point(|&v| v <= xq).saturating_sub(1).min(n - 2);
    let w = (xq - x[i]) / (x[i + 1] - x[i]);
    y[i] + w * (y[i + 1] - y[i])
}

/// Value of a uniformly sampled signal (`t0 + k dt`) at time `t`, linear, clamped.
#[inline]
pub fn sample_uniform(t0: f64, dt: f64, y: &[[f64; 3]], t: f64) -> [f64; 3] {
    let n = y.len();
    let s = (t - t0) / dt;
    if s <= 0.0 {
        return y[0];
    }
    // s > 0 here, so truncation is the floor (and not a libm call on the fits' hottest path)
    let k = s as usize;
    if k + 1 >= n {
        return y[n - 1];
    }
    let w = s - k as f64;
    let (a, b) = (y[k], y[k + 1]);
    [
        a[0] + w * (b[0] - a[0]),
        a[1] + w * (b[1] - a[1]),
        a[2] + w * (b[2] - a[2]),
    ]
}

/// Lag (s) of `b` behind `a` (b(t) ≈ a(t − lag)), both sampled at their own (irregular) times,
/// estimated by the peak of the normalised cross-correlation on a uniform grid of step `h`,
/// refined by a parabola through the peak. Searches |lag| ≤ `max_lag`.
/// Returns (lag, peak correlation); None when either signal is flat.
pub fn lag_by_xcorr(
    ta: &[f64],
    a: &[f64],
    tb: &[f64],
    b: &[f64],
    max_lag: f64,
    h: f64,
) -> Option<(f64, f64)> {
    let t0 = ta.first()?.max(*tb.first()?);
    let t1 = ta.last()?.min(*tb.last()?);
    if t1 - t0 < 4.0 * h {
        return None;
    }
    let n = ((t1 - t0) / h) as usize + 1;
    let mut ga: Vec<f64> = (0..n).map(|k| interp(ta, a, t0 + k as f64 * h)).collect();
    let mut gb: Vec<f64> = (0..n).map(|k| interp(tb, b, t0 + k as f64 * h)).collect();
    for g in [&mut ga, &mut gb] {
        let m = g.iter().sum::<f64>() / n as f64;
        g.iter_mut().for_each(|v| *v -= m);
    }
    let ea = ga.iter().map(|v| v * v).sum::<f64>();
    let eb = gb.iter().map(|v| v * v).sum::<f64>();
    if ea < 1e-20 || eb < 1e-20 {
        return None;
    }
    let kmax = ((max_lag / h) as isize).min(n as isize / 2);
    let corr = |k: isize| -> f64 {
        // b[i] against a[i - k]
        let mut s = 0.0;
        for i in 0..n as isize {
            let j = i - k;
            if j >= 0 && j < n as isize {
                s += gb[i as usize] * ga[j as usize];
            }
        }
        s / (ea * eb).sqrt()
    };
    let cs: Vec<f64> = (-kmax..=kmax).map(corr).collect();
    let (imax, &cmax) = cs.iter().enumerate().max_by(|x, y| x.1.total_cmp(y.1))?;
    let mut shift = 0.0;
    if imax > 0 && imax + 1 < cs.len() {
        let (l, c, r) = (cs[imax - 1], cs[imax], cs[imax + 1]);
        let den = l - 2.0 * c + r;
        if den.abs() > 1e-15 {
            shift = (0.5 * (l - r) / den).clamp(-0.5, 0.5);
        }
    }
    Some(((imax as f64 - kmax as f64 + shift) * h, cmax))
}

/// Robust white-noise level of a sampled signal: MAD of second differences / √6
/// (a smooth signal contributes little to second differences; noise contributes 6σ²).
pub fn noise_sigma(y: &[f64]) -> f64 {
    if y.len() < 5 {
        return 0.0;
    }
    let mut d: Vec<f64> = y
        .windows(3)
        .map(|w| (w[0] - 2.0 * w[1] + w[2]).abs())
        .collect();
    let m = median(&mut d);
    1.4826 * m / 6f64.sqrt()
}

pub fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// First-order low-pass on a uniform grid, in place (time constant `tau`, s): exact for a
/// signal linear between grid points, as the relaxation's convolution is
/// ([`crate::effects::qlv_in_place`]). Over a step of `dt` with slope m from u₀, the output
/// goes to u₀ + m·dt − m·τ + (y₀ − u₀ + m·τ)·e^{−dt/τ}, so a ramp lags by exactly τ.
///
/// It used the step's end value for the whole step (y += (1 − e^{−dt/τ})(u − y)), half a
/// step ahead of the signal: a ramp lagged by τ − dt/2, so on the replay's 20 ms grid a
/// sensor's fitted τ came out 10 ms long. The project's truths applied the same filter and
/// could not show it; the independent code's sensor case (delay 30 ms, τ 20 ms, its
/// filter exact between its own samples) fitted a delay of 24.1 ms and a τ of 27.8 ms
/// (README, "Signal effects on the independent code").
pub fn lowpass_in_place(y: &mut [[f64; 3]], dt: f64, tau: f64) {
    if tau <= 0.0 || y.is_empty() {
        return;
    }
    let e = (-dt / tau).exp();
    // the share of the step's increment the output takes within the step
    let ramp = 1.0 - tau / dt * (1.0 - e);
    let mut out = y[0];
    let mut prev = y[0];
    for v in y.iter_mut() {
        let cur = *v;
        for k in 0..3 {
            out[k] = e * out[k] + (1.0 - e) * prev[k] + ramp * (cur[k] - prev[k]);
        }
        prev = cur;
        *v = out;
    }
}

#[inline]
/// The net work a probe moved through `positions` does on a tissue whose force on it was
/// `forces` at the same instants (trapezoidal), J, and Σ |F|·|dx|, the scale it is small
/// against. Over a probing that starts and ends out of contact, an elastic frictionless
/// contact gives it all back (0) and friction adds what it dissipates; a negative sum is
/// energy no passive specimen gives.
pub fn net_work(positions: &[[f64; 3]], forces: &[[f64; 3]]) -> (f64, f64) {
    let (mut w, mut scale_sum) = (0.0, 0.0);
    for k in 1..positions.len().min(forces.len()) {
        let f = scale(add(forces[k - 1], forces[k]), 0.5);
        let dx = sub(positions[k], positions[k - 1]);
        w -= dot(f, dx);
        scale_sum += norm(f) * norm(dx);
    }
    (w, scale_sum)
}

pub fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline]
pub fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}
#[inline]
pub fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
pub fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
#[inline]
pub fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// A unit direction across the unit `normal`: the world axis `axis` (0, 1, 2) with its
/// component along `normal` taken out, or the next axis where `normal` lies within ~25° of it
/// (a probing's slide over the surface).
pub fn tangent_across(normal: [f64; 3], axis: usize) -> [f64; 3] {
    let unit = |k: usize| {
        let mut e = [0.0; 3];
        e[k % 3] = 1.0;
        e
    };
    let a = if normal[axis].abs() < 0.9 {
        unit(axis)
    } else {
        unit(axis + 1)
    };
    let t = sub(a, scale(normal, dot(a, normal)));
    scale(t, 1.0 / norm(t))
}

/// Rotate a vector by a unit quaternion (x, y, z, w).
pub fn quat_rotate(q: [f64; 4], v: [f64; 3]) -> [f64; 3] {
    let (qx, qy, qz, qw) = (q[0], q[1], q[2], q[3]);
    let u = [qx, qy, qz];
    let t = scale(cross(u, v), 2.0);
    add(add(v, scale(t, qw)), cross(u, t))
}
pub fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
pub fn quat_mul(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    let (ax, ay, az, aw) = (a[0], a[1], a[2], a[3]);
    let (bx, by, bz, bw) = (b[0], b[1], b[2], b[3]);
    [
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ]
}
/// Quaternion of a rotation about x by `a` then about y by `b` (extrinsic), radians.
pub fn quat_tilt(a: f64, b: f64) -> [f64; 4] {
    let qx = [(a / 2.0).sin(), 0.0, 0.0, (a / 2.0).cos()];
    let qy = [0.0, (b / 2.0).sin(), 0.0, (b / 2.0).cos()];
    quat_mul(qy, qx)
}
pub fn quat_conj(q: [f64; 4]) -> [f64; 4] {
    [-q[0], -q[1], -q[2], q[3]]
}
/// Normalised linear interpolation of unit quaternions (short path).
pub fn nlerp(a: [f64; 4], b: [f64; 4], w: f64) -> [f64; 4] {
    let s = if a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] < 0.0 {
        -1.0
    } else {
        1.0
    };
    let mut q = [0.0; 4];
    for k in 0..4 {
        q[k] = a[k] * (1.0 - w) + s * b[k] * w;
    }
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    q.map(|v| v / n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tangent_across_a_normal_is_a_unit_tangent() {
        let n = [0.6, 0.0, 0.8];
        for (normal, axis) in [([0.0, 0.0, 1.0], 0), ([1.0, 0.0, 0.0], 0), (n, 0), (n, 2)] {
            let t = tangent_across(normal, axis);
            assert!(
                dot(t, normal).abs() < 1e-12 && (norm(t) - 1.0).abs() < 1e-12,
                "{normal:?} about axis {axis} → {t:?}"
            );
        }
        // along its axis the normal takes the next one: the x normal slides along y
        assert_eq!(tangent_across([1.0, 0.0, 0.0], 0), [0.0, 1.0, 0.0]);
        assert_eq!(tangent_across([0.0, 0.0, 1.0], 2), [1.0, 0.0, 0.0]);
    }

    #[test]
    fn lag_of_shifted_pulse() {
        let ta: Vec<f64> = (0..400)
            .map(|k| k as f64 * 0.026 + 0.003 * ((k * 7) % 5) as f64)
            .collect();
        let f = |t: f64| (-(t - 5.0f64).powi(2) / 0.5).exp();
        let a: Vec<f64> = ta.iter().map(|&t| f(t)).collect();
        let b: Vec<f64> = ta.iter().map(|&t| f(t - 0.12)).collect();
        let (lag, c) = lag_by_xcorr(&ta, &a, &ta, &b, 0.5, 0.005).unwrap();
        // within 10 ms at ~38 Hz irregular sampling (26 ms intervals)
        assert!((lag - 0.12).abs() < 0.01, "lag {lag}");
        assert!(c > 0.95);
        let (lag2, _) = lag_by_xcorr(&ta, &b, &ta, &a, 0.5, 0.005).unwrap();
        assert!((lag2 + 0.12).abs() < 0.01, "lag {lag2}");
    }

    #[test]
    fn noise_level_of_smooth_plus_white() {
        let mut s = 12345u64;
        let mut gauss = || {
            let mut u = || {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((s >> 11) as f64 + 0.5) / (1u64 << 53) as f64
            };
            let (u1, u2) = (u(), u());
            (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        };
        let y: Vec<f64> = (0..4000)
            .map(|k| (k as f64 * 0.01).sin() * 3.0 + 0.05 * gauss())
            .collect();
        let s = noise_sigma(&y);
        assert!((s - 0.05).abs() < 0.006, "sigma {s}");
    }

    /// A sensor's τ fitted 10 ms long on the replay's 20 ms grid: the filter took each step's
    /// end value for the whole step, so a ramp lagged by τ − dt/2 instead of τ.
    #[test]
    fn a_low_pass_on_a_coarse_grid_lags_a_ramp_by_its_time_constant() {
        let (dt, tau) = (0.02, 0.02);
        let mut y: Vec<[f64; 3]> = (0..200).map(|k| [k as f64 * dt, 0.0, 1.0]).collect();
        lowpass_in_place(&mut y, dt, tau);
        // settled on the ramp (slope 1): the output is the input τ earlier
        let lag = 199.0 * dt - y[199][0];
        assert!((lag - tau).abs() < 1e-9, "lag {lag} for tau {tau}");
        assert_eq!(y[199][2], 1.0);
        // and on a grid point, the closed form of a ramp from rest: t − τ(1 − e^{−t/τ})
        let t = 3.0 * dt;
        let exact = t - tau * (1.0 - (-t / tau).exp());
        assert!(
            (y[3][0] - exact).abs() < 1e-12,
            "{} against {exact}",
            y[3][0]
        );
    }

    #[test]
    fn interp_and_lowpass() {
        assert_eq!(interp(&[0.0, 1.0, 3.0], &[0.0, 2.0, 6.0], 2.0), 4.0);
        assert_eq!(interp(&[0.0, 1.0], &[1.0, 2.0], -1.0), 1.0);
        let mut y = vec![[0.0; 3]; 1];
        y.extend(std::iter::repeat_n([1.0; 3], 1000));
        lowpass_in_place(&mut y, 0.001, 0.05);
        // step response at t = tau reaches 1 - 1/e (the step is a ramp over the first 1 ms)
        assert!(
            (y[50][0] - (1.0 - (-1.0f64).exp())).abs() < 0.01,
            "{}",
            y[50][0]
        );
        let q = quat_tilt(0.3, 0.0);
        let v = quat_rotate(q, [0.0, 0.0, 1.0]);
        assert!((v[1] + 0.3f64.sin()).abs() < 1e-12 && (v[2] - 0.3f64.cos()).abs() < 1e-12);
    }
}
