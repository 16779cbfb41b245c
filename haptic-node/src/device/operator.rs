//! The operator model of the emulator: where the trainee's hand is over time, following the
//! study's protocol — five probings in each of the posterior, mid and anterior regions,
//! each with approach, press, hold and release.

use super::DeviceError;
use launch_config::device::EmulatedConfig;

pub use msgs::protocol::Phase;

/// A probing site: a point on the superior surface with its outward normal (scene frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Site {
    pub point: [f64; 3],
    pub normal: [f64; 3],
    /// 1 posterior, 2 mid, 3 anterior.
    pub region: u32,
}

/// Sites on the plane z = `height`, normal +z: one row per region (posterior at −x,
/// anterior at +x), `per_region` sites 4 mm apart in y. For runs against an analytic
/// half-space.
pub fn plane_sites(height: f64, per_region: u32) -> Vec<Site> {
    let mut sites = Vec::new();
    for region in 1..=3u32 {
        for j in 0..per_region {
            sites.push(Site {
                point: [
                    (region as f64 - 2.0) * 0.010,
                    (j as f64 - (per_region as f64 - 1.0) / 2.0) * 0.004,
                    height,
                ],
                normal: [0.0, 0.0, 1.0],
                region,
            });
        }
    }
    sites
}

/// Picks `per_region` sites of each region, in protocol order (posterior, mid, anterior).
pub fn protocol_sites(all: &[Site], per_region: u32) -> Vec<Site> {
    let mut out = Vec::new();
    for region in 1..=3u32 {
        out.extend(
            all.iter()
                .filter(|s| s.region == region)
                .take(per_region as usize)
                .copied(),
        );
    }
    out
}

#[derive(Debug, Clone, Copy)]
struct Segment {
    from: [f64; 3],
    to: [f64; 3],
    t0: f64,
    duration: f64,
    phase: Phase,
    probing: u32,
    region: u32,
    /// The site's outward unit normal (the direction the felt force pushes the hand).
    normal: [f64; 3],
}

/// The hand trajectory, precomputed as straight segments (no allocation when sampled).
///
/// Pressing to a force (the study's examiner, [`Protocol::with_felt_target`]): the press
/// segment runs toward the deepest allowed point, and ends where the hand first feels the
/// target force along the site normal; the hold is there, and the rest of the pass moves
/// earlier by the time saved. Each pass starts again from the nominal segments.
#[derive(Debug, Clone)]
pub struct Protocol {
    segments: Vec<Segment>,
    /// The segments as planned, restored at the start of every pass.
    nominal: Vec<Segment>,
    total_s: f64,
    nominal_total_s: f64,
    repeat: bool,
    cursor: usize,
    /// Start time of the current pass, s.
    pass_start: f64,
    /// Force the hand presses to, felt along the site normal, N (0: press to the depth).
    felt_target_n: f64,
    /// Approach speed, for re-timing the release after a press ended early.
    fast: f64,
}

/// Where the hand is and what it is doing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandState {
    pub position: [f64; 3],
    pub velocity: [f64; 3],
    pub phase: Phase,
    pub probing: u32,
    pub region: u32,
    pub finished: bool,
}

fn add(a: [f64; 3], b: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] + b[0] * s, a[1] + b[1] * s, a[2] + b[2] * s]
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

impl Protocol {
    pub fn new(c: &EmulatedConfig, sites: &[Site]) -> Result<Protocol, DeviceError> {
        let bad = |what: &str| DeviceError::Emulated(format!("[device.emulated] {what}"));
        for (v, name) in [
            (c.approach_speed_m_per_s, "approach_speed_m_per_s"),
            (c.press_speed_m_per_s, "press_speed_m_per_s"),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(&format!("{name} = {v} must be > 0")));
            }
        }
        for (v, name) in [
            (c.hover_m, "hover_m"),
            (c.press_depth_m, "press_depth_m"),
            (c.hold_s, "hold_s"),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(bad(&format!("{name} = {v} must be ≥ 0")));
            }
        }
        let sites = protocol_sites(sites, c.probings_per_region);
        if sites.is_empty() {
            return Err(bad(
                "no probing sites: the scene gave none and none were configured",
            ));
        }
        let mut segments = Vec::new();
        let mut t = 0.0;
        let mut push = |from: [f64; 3],
                        to: [f64; 3],
                        duration: f64,
                        phase,
                        probing,
                        region,
                        normal: [f64; 3]| {
            segments.push(Segment {
                from,
                to,
                t0: t,
                duration,
                phase,
                probing,
                region,
                normal,
            });
            t += duration;
        };
        let mut at = add(sites[0].point, sites[0].normal, c.hover_m);
        for (i, s) in sites.iter().enumerate() {
            let (k, r) = (i as u32 + 1, s.region);
            let n = s.normal;
            let norm = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if !(norm.is_finite() && norm > 0.0 && s.point.iter().all(|v| v.is_finite())) {
                return Err(bad(&format!(
                    "probing site {k} has a non-finite point or zero normal"
                )));
            }
            let n = [n[0] / norm, n[1] / norm, n[2] / norm];
            let hover = add(s.point, n, c.hover_m);
            let pressed = add(s.point, n, -c.press_depth_m);
            let fast = c.approach_speed_m_per_s;
            push(at, hover, dist(at, hover) / fast, Phase::Approach, k, r, n);
            push(hover, s.point, c.hover_m / fast, Phase::Approach, k, r, n);
            push(
                s.point,
                pressed,
                c.press_depth_m / c.press_speed_m_per_s,
                Phase::Press,
                k,
                r,
                n,
            );
            push(pressed, pressed, c.hold_s, Phase::Hold, k, r, n);
            push(
                pressed,
                hover,
                dist(pressed, hover) / fast,
                Phase::Release,
                k,
                r,
                n,
            );
            at = hover;
        }
        Ok(Protocol {
            nominal: segments.clone(),
            segments,
            total_s: t,
            nominal_total_s: t,
            repeat: c.repeat,
            cursor: 0,
            pass_start: 0.0,
            felt_target_n: 0.0,
            fast: c.approach_speed_m_per_s,
        })
    }

    /// Presses to a felt force instead of to the depth: each press ends where the force the
    /// hand feels along the site normal first reaches `felt_n` (N), or at `press_depth_m`
    /// (then the deepest the hand may go) if it never does. 0 keeps pressing to the depth.
    pub fn with_felt_target(mut self, felt_n: f64) -> Protocol {
        self.felt_target_n = if felt_n.is_finite() {
            felt_n.max(0.0)
        } else {
            0.0
        };
        self
    }

    /// The force target, felt along the site normal, N (0: presses to the depth).
    pub fn felt_target_n(&self) -> f64 {
        self.felt_target_n
    }

    /// The hand at protocol time `t` when it feels `felt_n` along the current site's
    /// normal (N, positive pushing the hand out of the tissue). Times are expected to grow.
    pub fn hand_feeling(&mut self, t: f64, felt_n: f64) -> HandState {
        let h = self.hand(t);
        if self.felt_target_n > 0.0
            && h.phase == Phase::Press
            && !h.finished
            && felt_n >= self.felt_target_n
        {
            self.end_press_at(t - self.pass_start, h.position);
            return HandState {
                velocity: [0.0; 3],
                phase: Phase::Hold,
                ..h
            };
        }
        h
    }

    /// Ends the current press segment at pass time `t`, hand position `p`: the hold is at `p`
    /// and the release leaves from there; everything after moves earlier by the time saved.
    fn end_press_at(&mut self, t: f64, p: [f64; 3]) {
        let i = self.cursor;
        if i + 2 >= self.segments.len() {
            return;
        }
        let press = &mut self.segments[i];
        let saved_press = (press.t0 + press.duration - t).max(0.0);
        press.duration -= saved_press;
        press.to = p;
        let hold = &mut self.segments[i + 1];
        hold.t0 -= saved_press;
        hold.from = p;
        hold.to = p;
        let release = &mut self.segments[i + 2];
        let old_release = release.duration;
        release.t0 -= saved_press;
        release.from = p;
        release.duration = dist(p, release.to) / self.fast;
        let saved = saved_press + (old_release - release.duration);
        for s in &mut self.segments[i + 3..] {
            s.t0 -= saved;
        }
        self.total_s -= saved;
        // Past the shortened press: the hold is current.
        self.cursor = i + 1;
    }

    fn restart_pass(&mut self, start: f64) {
        self.segments.copy_from_slice(&self.nominal);
        self.total_s = self.nominal_total_s;
        self.cursor = 0;
        self.pass_start = start;
    }

    /// The current site's outward normal (last segment's when finished).
    pub fn normal(&self) -> [f64; 3] {
        self.segments[self.cursor].normal
    }

    /// Duration of one pass through the protocol, s (as planned; a press to force may end
    /// earlier).
    pub fn duration_s(&self) -> f64 {
        self.nominal_total_s
    }

    /// Start position of the hand.
    pub fn start(&self) -> [f64; 3] {
        self.segments[0].from
    }

    /// The hand at protocol time `t` (s since start). Times are expected to grow; a repeat
    /// wraps around.
    pub fn hand(&mut self, t: f64) -> HandState {
        let last = *self.segments.last().expect("protocol has segments");
        let t = t.max(0.0);
        if t < self.pass_start {
            // Time went back: start over from the plan.
            self.restart_pass(0.0);
        }
        if t - self.pass_start >= self.total_s {
            if !self.repeat {
                return HandState {
                    position: last.to,
                    velocity: [0.0; 3],
                    phase: Phase::Idle,
                    probing: 0,
                    region: 0,
                    finished: true,
                };
            }
            // Next pass (or passes, after a long stall), from the plan.
            let mut start = self.pass_start + self.total_s;
            if self.nominal_total_s > 0.0 && t - start >= self.nominal_total_s {
                start += ((t - start) / self.nominal_total_s).floor() * self.nominal_total_s;
            }
            self.restart_pass(start);
        }
        let t = if self.total_s > 0.0 {
            t - self.pass_start
        } else {
            0.0
        };
        if t < self.segments[self.cursor].t0 {
            self.cursor = 0;
        }
        while self.cursor + 1 < self.segments.len()
            && t >= self.segments[self.cursor].t0 + self.segments[self.cursor].duration
        {
            self.cursor += 1;
        }
        let s = self.segments[self.cursor];
        let (u, rate) = if s.duration > 0.0 {
            (((t - s.t0) / s.duration).clamp(0.0, 1.0), 1.0 / s.duration)
        } else {
            (1.0, 0.0)
        };
        let d = [
            s.to[0] - s.from[0],
            s.to[1] - s.from[1],
            s.to[2] - s.from[2],
        ];
        HandState {
            position: add(s.from, d, u),
            velocity: [d[0] * rate, d[1] * rate, d[2] * rate],
            phase: s.phase,
            probing: s.probing,
            region: s.region,
            finished: false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn protocol_visits_five_sites_per_region_with_all_phases() {
        let c = EmulatedConfig {
            repeat: false,
            ..EmulatedConfig::default()
        };
        let mut p = Protocol::new(&c, &plane_sites(0.0, 5)).unwrap();
        let mut seen = Vec::new();
        let mut deepest: f64 = 1.0;
        let mut t = 0.0;
        while t < p.duration_s() + 1.0 {
            let h = p.hand(t);
            if !h.finished && seen.last() != Some(&(h.probing, h.region, h.phase)) {
                seen.push((h.probing, h.region, h.phase));
            }
            deepest = deepest.min(h.position[2]);
            t += 0.001;
        }
        assert!(p.hand(t).finished);
        let probings: std::collections::BTreeSet<_> = seen.iter().map(|s| (s.0, s.1)).collect();
        assert_eq!(probings.len(), 15);
        for region in 1..=3 {
            assert_eq!(probings.iter().filter(|s| s.1 == region).count(), 5);
        }
        for phase in [Phase::Approach, Phase::Press, Phase::Hold, Phase::Release] {
            assert_eq!(
                seen.iter().filter(|s| s.2 == phase).count(),
                15,
                "{phase:?}"
            );
        }
        assert!((deepest + c.press_depth_m).abs() < 1e-9);
    }

    #[test]
    fn bad_protocol_settings_are_rejected() {
        let c = EmulatedConfig {
            press_speed_m_per_s: 0.0,
            ..EmulatedConfig::default()
        };
        assert!(Protocol::new(&c, &plane_sites(0.0, 5)).is_err());
        assert!(Protocol::new(&EmulatedConfig::default(), &[]).is_err());
    }
}
