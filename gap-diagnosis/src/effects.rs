//! The candidate effects: each a small parametrised addition to the baseline model.
//!
//! Post-processing effects act exactly on the replayed baseline force (displacement-driven
//! replay: elastic force ∝ E, so `modulus` is a scale; `hardening` a depth-dependent
//! stiffening factor; `viscoelastic` the QLV hereditary integral on the elastic force;
//! `device` bias + tool inertia; `sensor` delay + first-order low-pass). Re-simulated effects
//! (`friction`, `tilt`, `support`, `mesh`) are replayed at a few parameter values and
//! interpolated (piecewise linear in μ and in support compliance, quadratic per tilt angle).
use super::dataset::{Centre, TrialData};
use super::fit::NuisanceFit;
use super::model::Variant;
use super::signal::{lowpass_in_place, sample_uniform};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Effect {
    // order = order of application (tissue geometry/contact, material, device, sensor)
    Friction,
    Tilt,
    Support,
    Mesh,
    Modulus,
    Hardening,
    Viscoelastic,
    Device,
    Sensor,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ParamSpec {
    pub name: &'static str,
    pub unit: &'static str,
    pub lo: f64,
    pub hi: f64,
    /// Value at which the effect vanishes (the baseline).
    pub neutral: f64,
    /// Optimise in log space.
    pub log: bool,
    /// Held at `neutral` unless freeing it lowers the BIC clearly (the second Prony term:
    /// one term is the default model, two only when the data ask for it).
    pub optional: bool,
}

const fn p(
    name: &'static str,
    unit: &'static str,
    lo: f64,
    hi: f64,
    neutral: f64,
    log: bool,
) -> ParamSpec {
    ParamSpec {
        name,
        unit,
        lo,
        hi,
        neutral,
        log,
        optional: false,
    }
}

/// An optional parameter (see [`ParamSpec::optional`]).
const fn opt(p: ParamSpec) -> ParamSpec {
    ParamSpec {
        optional: true,
        ..p
    }
}

/// Tilt re-simulation step (rad) for the quadratic interpolation. The tilt turns the specimen
/// about the frame's origin, and the probe sites stand 15–20 mm from it, so a step of θ moves a
/// press by about 18 mm · θ along its normal: 0.94 mm at 3°, the size of the study's presses
/// (0.5–1.2 mm). At 6° a knot's press moved 1.9 mm, and missed the tissue or pressed it two to
/// three times as deep; the quadratic through such knots put a 2–2.5° tilt at a fitted 0.3°,
/// below [`crate::centres::MIN_CENTRE_DEG`], so no replay ever came near it. Knots at ±3° and
/// ±6° together fitted large tilts better but lost a small one on the independent code's
/// truth, at four replays a trial more (README, "Tilt knots at ±3°").
pub const TILT_STEP: f64 = 0.05236; // 3°
pub const FRICTION_KNOTS: [f64; 2] = [0.15, 0.4];
/// Support compliance knots, m/N per node (k = 4000, 2000 and 1000 N/m). A support is a
/// spring in series with the tissue, so the force is convex in its compliance and a chord
/// between two knots lies above it: between 4000 and 1000 N/m alone, a support of 1818 N/m was
/// interpolated stiff and fitted 0.66× (README, "Fitted strengths against the truth"). The
/// middle knot costs one replay per trial.
pub const SUPPORT_KNOTS: [f64; 3] = [2.5e-4, 5.0e-4, 1.0e-3];
/// The largest support knot: one unit of support in a centre's distance.
pub const SUPPORT_SPAN: f64 = SUPPORT_KNOTS[SUPPORT_KNOTS.len() - 1];

impl Effect {
    pub const ALL: [Effect; 9] = [
        Effect::Modulus,
        Effect::Hardening,
        Effect::Viscoelastic,
        Effect::Friction,
        Effect::Tilt,
        Effect::Device,
        Effect::Support,
        Effect::Mesh,
        Effect::Sensor,
    ];
    pub fn name(self) -> &'static str {
        match self {
            Effect::Modulus => "modulus",
            Effect::Hardening => "hardening",
            Effect::Viscoelastic => "viscoelastic",
            Effect::Friction => "friction",
            Effect::Tilt => "tilt",
            Effect::Device => "device",
            Effect::Support => "support",
            Effect::Mesh => "mesh",
            Effect::Sensor => "sensor",
        }
    }
    pub fn parse(s: &str) -> Option<Effect> {
        Effect::ALL.into_iter().find(|e| e.name() == s)
    }
    /// The effects a `+`-joined candidate name ([`Candidate::name`], e.g. `tilt+support`)
    /// names; unknown parts are skipped.
    pub fn of_candidate(name: &str) -> impl Iterator<Item = Effect> + '_ {
        name.split('+').filter_map(Effect::parse)
    }
    pub fn params(self) -> Vec<ParamSpec> {
        match self {
            Effect::Modulus => vec![p("modulus_scale", "", 0.02, 5.0, 1.0, true)],
            Effect::Hardening => vec![
                p("small_strain_scale", "", 0.01, 5.0, 1.0, true),
                p("stiffening_rate", "1/mm", 0.0, 2.0, 0.0, false),
            ],
            Effect::Viscoelastic => vec![
                p("prony_g1", "", 0.0, 0.9, 0.0, false),
                p("prony_tau1", "s", 0.05, 10.0, 1.0, true),
                opt(p("prony_g2", "", 0.0, 0.9, 0.0, false)),
                opt(p("prony_tau2", "s", 0.5, 50.0, 5.0, true)),
            ],
            Effect::Friction => vec![p("mu", "", 0.0, 0.8, 0.0, false)],
            Effect::Tilt => vec![
                p("tilt_x", "deg", -15.0, 15.0, 0.0, false),
                p("tilt_y", "deg", -15.0, 15.0, 0.0, false),
            ],
            Effect::Device => vec![
                p("bias_x", "N", -3.0, 3.0, 0.0, false),
                p("bias_y", "N", -3.0, 3.0, 0.0, false),
                p("bias_z", "N", -3.0, 3.0, 0.0, false),
                p("tool_mass", "kg", -0.2, 0.2, 0.0, false),
            ],
            Effect::Support => vec![p(
                "support_compliance",
                "m/N per node",
                0.0,
                2.0e-3,
                0.0,
                false,
            )],
            Effect::Mesh => vec![],
            Effect::Sensor => vec![
                p("delay", "s", 0.0, 0.3, 0.0, false),
                p("lowpass_tau", "s", 0.0, 0.3, 0.0, false),
            ],
        }
    }
    /// Effects that only make sense with a time history.
    pub fn time_dependent(self) -> bool {
        matches!(self, Effect::Viscoelastic | Effect::Sensor)
    }
    /// Effects that need sliding or tangential information.
    pub fn needs_tangential(self) -> bool {
        matches!(self, Effect::Friction)
    }
    /// Effects that change every probing of the protocol: a stiffness, a stiffening, a
    /// support or a relaxation changes every press, a tilt every path, a device's bias or a
    /// sensor's lag every sample or onset. Friction acts only where the probe slides and a
    /// mesh effect only near some sites. The held-out gain of an effect that acts on every
    /// probing must hold trial by trial to be significant (`decide`, rule (d)); one that acts
    /// on a few trials has only those to show it on.
    pub fn acts_on_every_probing(self) -> bool {
        !matches!(self, Effect::Friction | Effect::Mesh)
    }
    /// The re-simulation at parameter value `x` of an effect interpolated piecewise-linearly
    /// between knots (`friction`: μ; `support`: compliance, m/N per node); None for the others.
    pub fn knot_variant(self, x: f64) -> Option<Variant> {
        match self {
            Effect::Friction => Some(Variant {
                friction: x,
                ..Variant::default()
            }),
            Effect::Support if x > 0.0 => Some(Variant {
                support_stiffness: 1.0 / x,
                ..Variant::default()
            }),
            _ => None,
        }
    }
    /// The default knots of a piecewise-linear effect (see [`Effect::knot_variant`]).
    pub fn default_knots(self) -> &'static [f64] {
        match self {
            Effect::Friction => &FRICTION_KNOTS,
            Effect::Support => &SUPPORT_KNOTS,
            _ => &[],
        }
    }
    /// Re-simulations this effect interpolates between (in order).
    pub fn resims(self) -> Vec<Variant> {
        let v = Variant::default();
        match self {
            Effect::Friction => FRICTION_KNOTS
                .iter()
                .map(|&mu| Variant {
                    friction: mu,
                    ..v.clone()
                })
                .collect(),
            Effect::Support => SUPPORT_KNOTS
                .iter()
                .map(|&c| Variant {
                    support_stiffness: 1.0 / c,
                    ..v.clone()
                })
                .collect(),
            Effect::Tilt => vec![
                Variant {
                    tilt: [TILT_STEP, 0.0],
                    ..v.clone()
                },
                Variant {
                    tilt: [-TILT_STEP, 0.0],
                    ..v.clone()
                },
                Variant {
                    tilt: [0.0, TILT_STEP],
                    ..v.clone()
                },
                Variant {
                    tilt: [0.0, -TILT_STEP],
                    ..v.clone()
                },
            ],
            Effect::Mesh => vec![Variant {
                fine_mesh: true,
                ..v
            }],
            _ => vec![],
        }
    }
}

/// A candidate explanation: one effect or a pair, in application order.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Candidate(pub Vec<Effect>);

impl Candidate {
    pub fn single(e: Effect) -> Candidate {
        Candidate(vec![e])
    }
    pub fn pair(a: Effect, b: Effect) -> Candidate {
        let mut v = vec![a, b];
        v.sort();
        Candidate(v)
    }
    pub fn name(&self) -> String {
        // names listed in the issue's order joined by '+'
        let mut v = self.0.clone();
        v.sort_by_key(|e| Effect::ALL.iter().position(|x| x == e));
        v.iter().map(|e| e.name()).collect::<Vec<_>>().join("+")
    }
    pub fn params(&self) -> Vec<(Effect, ParamSpec)> {
        self.0
            .iter()
            .flat_map(|&e| e.params().into_iter().map(move |p| (e, p)))
            .collect()
    }
    pub fn neutral(&self) -> Vec<f64> {
        self.params().iter().map(|(_, p)| p.neutral).collect()
    }
    /// The candidate carries a global stiffness scale of its own (`modulus`, `hardening`'s
    /// small-strain scale): the stiffness nuisance would be the same parameter twice, so it is
    /// not fitted beside it and the candidate's scale is the total ([`crate::fit::Nuisance`]).
    pub fn absorbs_stiffness(&self) -> bool {
        self.0
            .iter()
            .any(|e| matches!(e, Effect::Modulus | Effect::Hardening))
    }
}

fn axpy(dst: &mut [[f64; 3]], a: f64, x: &[[f64; 3]], y: Option<&[[f64; 3]]>) {
    // dst += a (x − y)
    for (i, d) in dst.iter_mut().enumerate() {
        for k in 0..3 {
            d[k] += a * (x[i][k] - y.map(|y| y[i][k]).unwrap_or(0.0));
        }
    }
}

/// Piecewise-linear interpolation in a parameter between re-simulated knots: the baseline at
/// 0, the effect's default knots, and any knots calibration added at fitted values
/// ([`TrialData::extra_knots`]); beyond the last knot, the last segment extended. A diverged
/// knot is left out (the segment then spans its neighbours).
fn piecewise_knots(grid: &mut [[f64; 3]], td: &TrialData, e: Effect, x: f64, defaults: &[f64]) {
    let r = td.resim(e);
    let mut knots: Vec<(f64, &[[f64; 3]])> = Vec::with_capacity(4);
    for (k, &xk) in defaults.iter().enumerate() {
        // a trial replayed with fewer knots than the effect has now has none beyond them
        if k < r.len() && td.resim_valid(e, k) {
            knots.push((xk, &r[k]));
        }
    }
    if let Some(extra) = td.extra_knots.get(&e) {
        knots.extend(extra.iter().map(|(xk, f)| (*xk, f.as_slice())));
    }
    knots.sort_by(|a, b| a.0.total_cmp(&b.0));
    knots.dedup_by(|a, b| a.0 == b.0);
    if knots.is_empty() {
        return;
    }
    // the segment holding x: (0, baseline) to the first knot, or between two knots, or the
    // last one extended
    let i = knots
        .iter()
        .position(|k| x <= k.0)
        .unwrap_or(knots.len() - 1);
    if i == 0 {
        let (x1, r1) = knots[0];
        axpy(grid, x / x1, r1, Some(&td.base));
    } else {
        let ((xa, ra), (xb, rb)) = (knots[i - 1], knots[i]);
        axpy(grid, 1.0, ra, Some(&td.base));
        axpy(grid, (x - xa) / (xb - xa), rb, Some(ra));
    }
}

/// Model force on the trial's grid and at its measurement times for candidate `c` at `theta`,
/// with the nuisances `nuisance` ([`crate::fit::Nuisance`]; [`NuisanceFit::NEUTRAL`]: none).
/// `grid` and `out` are scratch buffers (resized here).
///
/// The contact and material nuisances move the baseline towards the trial's contact knot and
/// material knot by their weights w and m (like re-simulated effects), and scale friction's
/// delta by 1 + w·ρ_c + m·ρ_m (+ ρ_s beside a support, from its interpolation at `theta`), ρ
/// each knot's relative change of the baseline's normal force ([`layer_change`]). The
/// stiffness scale acts on the tissue's force after the re-simulated effects (a stiffer
/// specimen at the same friction, tilt or support scales the whole replayed force: the replay
/// is displacement-driven and linear in the modulus and support together) and before a
/// device's bias and tool inertia, which are not tissue. Everything after it is affine in the
/// force, so the prediction is affine in the stiffness s and in s × each weight: what lets the
/// fits profile all three out ([`crate::fit::PhaseQuad`]).
pub fn predict(
    c: &Candidate,
    theta: &[f64],
    td: &TrialData,
    nuisance: NuisanceFit,
    grid: &mut Vec<[f64; 3]>,
    out: &mut Vec<[f64; 3]>,
) {
    // the re-simulated effects' deltas all add to the tissue's force before anything scales
    // it, so they and the centre's correction come first. Friction's first: by Coulomb's law
    // it is μ times the normal force, so the contact nuisance's layer, which lowers the
    // normal force, lowers it in proportion. Its knots were replayed without the layer, and
    // its delta added to the layer's lower normal force read μ 15–25% low (0.31 for 0.41
    // beside a fitted 8.3 µm/N).
    grid.clear();
    let layer = td.contact_knot.as_ref().filter(|_| nuisance.contact != 0.0);
    let law = td
        .material_knot
        .as_ref()
        .filter(|_| nuisance.material != 0.0);
    let (w, m) = (nuisance.contact, nuisance.material);
    let friction = c.0.contains(&Effect::Friction);
    // A soft support lowers the normal force as the layer does, and friction with it; its
    // knots stand on the fixed base. Added unscaled, friction's delta on a coarse-mesh
    // friction+support proxy (μ 0.48 on 1,316 N/m per node) left 5.7 N RMS at the truth
    // (0.84 N scaled), and the case read `modulus+friction` with a modulus ×0.21.
    let supported = friction && c.0.contains(&Effect::Support);
    if friction && (layer.is_some() || law.is_some() || supported) {
        // linear in both weights, as the nuisances' profile needs (fit::PhaseQuad): the
        // normal force's relative change under the layer, under the other law and under the
        // support add (the support's from its interpolation, in `out` until the end)
        out.clear();
        if supported {
            out.resize(td.base.len(), [0.0; 3]);
            axpy_resimulated_where(out, c, theta, td, |e| e == Effect::Support);
        }
        grid.resize(td.base.len(), [0.0; 3]);
        axpy_resimulated_where(grid, c, theta, td, |e| e == Effect::Friction);
        for (j, (g, b)) in grid.iter_mut().zip(&td.base).enumerate() {
            let mut through = 1.0;
            if let Some(d) = out.get(j) {
                through += layer_change(*b, [b[0] + d[0], b[1] + d[1], b[2] + d[2]], td.normal);
            }
            let mut moved = *b;
            for (weight, knot) in [(w, layer), (m, law)] {
                if let Some(k) = knot {
                    through += weight * layer_change(*b, k[j], td.normal);
                    for q in 0..3 {
                        moved[q] += weight * (k[j][q] - b[q]);
                    }
                }
            }
            for q in 0..3 {
                g[q] = through * g[q] + moved[q];
            }
        }
    } else {
        grid.extend_from_slice(&td.base);
        for (weight, knot) in [(w, layer), (m, law)] {
            if let Some(k) = knot {
                axpy(grid, weight, k, Some(&td.base));
            }
        }
        axpy_resimulated_where(grid, c, theta, td, |e| e == Effect::Friction);
    }
    // the depth a hardening stiffens with: the tilted centre's own where the candidate uses
    // one, by its weight (the baseline's beyond it)
    let mut tilted_depth: Option<(&[f64], f64)> = None;
    // the geometric ones (tilt, support, mesh) as replayed: scaling them by the layer's
    // change too fitted the layer at twice its weight beside a tilt, and a held-out region
    // then missed by twice as much (README, "Friction through the contact layer")
    match centre_for(c, theta, td) {
        Some((centre, _, offset)) if searching(centre) => {
            tilted_depth = own_depth(centre, 1.0);
            // the replay's tangent at the centre: the interpolation held there, so the
            // correction makes it the replay, and the replay's own slopes carry the step
            let mut at = [0.0; MAX_CANDIDATE_PARAMS];
            let at = &mut at[..theta.len()];
            at.copy_from_slice(theta);
            for (slot, v) in centre_slots(c, centre).zip(&centre.theta) {
                at[slot] = *v;
            }
            axpy_resimulated_where(grid, c, at, td, |e| e != Effect::Friction);
            axpy(grid, 1.0, &centre.correction, None);
            for (slope, d) in centre.replay_slopes.iter().zip(offset) {
                axpy(grid, d, slope, None);
            }
        }
        Some((centre, w, offset)) => {
            tilted_depth = own_depth(centre, w);
            axpy_resimulated_where(grid, c, theta, td, |e| e != Effect::Friction);
            axpy(grid, w, &centre.correction, None);
            for (slope, d) in centre.slopes.iter().zip(offset) {
                axpy(grid, w * d, slope, None);
            }
        }
        None => axpy_resimulated_where(grid, c, theta, td, |e| e != Effect::Friction),
    }
    let stiffness = nuisance.stiffness;
    let mut k = 0;
    let mut delay = 0.0;
    let mut scaled = false;
    for &e in &c.0 {
        let np = e.params().len();
        let th = &theta[k..k + np];
        k += np;
        if e == Effect::Device && !scaled {
            scale_grid(grid, stiffness);
            scaled = true;
        }
        match e {
            // added above
            Effect::Friction | Effect::Support | Effect::Tilt | Effect::Mesh => {}
            Effect::Modulus => grid.iter_mut().for_each(|g| *g = g.map(|v| v * th[0])),
            Effect::Hardening => {
                for (i, (g, d)) in grid.iter_mut().zip(&td.depth_grid).enumerate() {
                    let d = match tilted_depth {
                        Some((own, w)) => w * own[i] + (1.0 - w) * d,
                        None => *d,
                    };
                    let f = th[0] * (th[1] * d.max(0.0)).exp();
                    *g = g.map(|v| v * f);
                }
            }
            Effect::Viscoelastic => {
                qlv_in_place(grid, td.path.dt, &[(th[0], th[1]), (th[2], th[3])])
            }
            Effect::Device => {
                for (g, a) in grid.iter_mut().zip(&td.acc_grid) {
                    for q in 0..3 {
                        g[q] += th[q] - th[3] * a[q];
                    }
                }
            }
            Effect::Sensor => {
                lowpass_in_place(grid, td.path.dt, th[1]);
                delay = th[0];
            }
        }
    }
    if !scaled {
        scale_grid(grid, stiffness);
    }
    out.clear();
    out.extend(
        td.t.iter()
            .map(|&t| sample_uniform(td.path.t0, td.path.dt, grid, t - delay)),
    );
}

/// Below this normal force (N) of the baseline the contact layer's relative change of it is
/// not taken (0: before the touch, where a ratio is noise over noise).
pub const LAYER_CHANGE_MIN_FORCE: f64 = 0.05;

/// The contact nuisance's knot's relative change of the normal force from the baseline's,
/// ρ = (k·n − b·n)/(b·n), within −1…1; 0 where the baseline carries less than
/// [`LAYER_CHANGE_MIN_FORCE`].
pub fn layer_change(base: [f64; 3], knot: [f64; 3], normal: [f64; 3]) -> f64 {
    let dot = |a: [f64; 3]| a[0] * normal[0] + a[1] * normal[1] + a[2] * normal[2];
    let (b, k) = (dot(base), dot(knot));
    if b.abs() < LAYER_CHANGE_MIN_FORCE {
        return 0.0;
    }
    ((k - b) / b).clamp(-1.0, 1.0)
}

/// The tilt's interpolation between re-simulations: per axis, the quadratic through the
/// baseline and the knots at ±[`TILT_STEP`] (one side diverged: the secant through the
/// other), added to `grid`. Angles in degrees.
pub fn tilt_quadratic(grid: &mut [[f64; 3]], td: &TrialData, th_deg: [f64; 2]) {
    let r = td.resim(Effect::Tilt);
    let h = TILT_STEP;
    for (axis, ang) in [
        (0usize, th_deg[0].to_radians()),
        (1, th_deg[1].to_radians()),
    ] {
        let (rp, rm) = (&r[2 * axis], &r[2 * axis + 1]);
        let ok_p = td.resim_valid(Effect::Tilt, 2 * axis);
        let ok_m = td.resim_valid(Effect::Tilt, 2 * axis + 1);
        match (ok_p, ok_m) {
            (true, true) => {
                let a1 = ang / (2.0 * h);
                let a2 = ang * ang / (2.0 * h * h);
                for (i, g) in grid.iter_mut().enumerate() {
                    for q in 0..3 {
                        g[q] += a1 * (rp[i][q] - rm[i][q])
                            + a2 * (rp[i][q] + rm[i][q] - 2.0 * td.base[i][q]);
                    }
                }
            }
            // one side diverged: the secant through the other
            (true, false) => axpy(grid, ang / h, rp, Some(&td.base)),
            (false, true) => axpy(grid, -ang / h, rm, Some(&td.base)),
            (false, false) => {}
        }
    }
}

/// Adds the interpolated deltas of candidate `c`'s re-simulated effects at `theta` to `grid`
/// (no centre: [`centre_for`]).
pub fn axpy_resimulated(grid: &mut [[f64; 3]], c: &Candidate, theta: &[f64], td: &TrialData) {
    axpy_resimulated_where(grid, c, theta, td, |_| true);
}

/// [`axpy_resimulated`] for the effects `keep` accepts.
fn axpy_resimulated_where(
    grid: &mut [[f64; 3]],
    c: &Candidate,
    theta: &[f64],
    td: &TrialData,
    keep: impl Fn(Effect) -> bool,
) {
    let mut k = 0;
    for &e in &c.0 {
        let np = e.params().len();
        let th = &theta[k..k + np];
        k += np;
        if !keep(e) {
            continue;
        }
        match e {
            Effect::Friction => piecewise_knots(grid, td, Effect::Friction, th[0], &FRICTION_KNOTS),
            Effect::Support => piecewise_knots(grid, td, Effect::Support, th[0], &SUPPORT_KNOTS),
            Effect::Tilt => tilt_quadratic(grid, td, [th[0], th[1]]),
            Effect::Mesh if td.resim_valid(Effect::Mesh, 0) => {
                axpy(grid, 1.0, &td.resim(Effect::Mesh)[0], Some(&td.base));
            }
            _ => {}
        }
    }
}

/// One unit of each re-simulated parameter in [`centre_weight`]'s distance: the span its
/// default knots cover (tilt: the ±3° step; support and friction: the larger knot).
pub fn centre_unit(e: Effect) -> f64 {
    match e {
        Effect::Tilt => TILT_STEP.to_degrees(),
        Effect::Support => SUPPORT_SPAN,
        Effect::Friction => FRICTION_KNOTS[1],
        _ => 1.0,
    }
}

/// The centre ([`TrialData::centres`]) candidate `c` uses at `theta`, its weight there and
/// the candidate's step from it (its values of the centre's parameters minus the centre's,
/// what [`Centre::slopes`] multiply): the centre made for exactly `c`'s re-simulated effects,
/// else the one made for the most of them (a pair's tilt uses the tilt's own centre).
pub fn centre_for<'a>(
    c: &Candidate,
    theta: &[f64],
    td: &'a TrialData,
) -> Option<(&'a Centre, f64, [f64; MAX_CENTRE_PARAMS])> {
    if td.centres.is_empty() {
        return None;
    }
    // a centre's effects are re-simulated ones: those of the candidate, or some of them
    let centre = td
        .centres
        .iter()
        .filter(|k| k.effects.iter().all(|e| c.0.contains(e)))
        .max_by_key(|k| k.effects.len())?;
    // the candidate's values of the centre's parameters; both list effects in application
    // order, so they come in the centre's order
    let mut at = Vec::with_capacity(centre.theta.len());
    let mut units = Vec::with_capacity(centre.theta.len());
    for ((e, _), &v) in c.params().iter().zip(theta) {
        if centre.effects.contains(e) {
            at.push(v);
            units.push(centre_unit(*e));
        }
    }
    // a searching centre is the replay's tangent everywhere: how far that holds is the
    // search's step limit ([`crate::centres::MAX_SEARCH_STEP`])
    let w = if searching(centre) {
        1.0
    } else {
        centre_weight(&at, &centre.theta, &units, centre.reach)
    };
    let mut offset = [0.0; MAX_CENTRE_PARAMS];
    for ((o, a), k) in offset.iter_mut().zip(&at).zip(&centre.theta) {
        *o = a - k;
    }
    (w > 0.0).then_some((centre, w, offset))
}

/// The most parameters a centre has: the tilt's two and the support's one.
pub const MAX_CENTRE_PARAMS: usize = 3;

/// The most parameters a candidate has: a pair of the four-parameter effects (viscoelastic,
/// device).
pub const MAX_CANDIDATE_PARAMS: usize = 8;

/// A tilted centre's own depth ([`Centre::depth_grid`]) and its weight `w`, where it has one.
fn own_depth(centre: &Centre, w: f64) -> Option<(&[f64], f64)> {
    (!centre.depth_grid.is_empty()).then_some((centre.depth_grid.as_slice(), w))
}

/// Whether `centre` is searched from ([`Centre::linear`]) and has the replay's slopes for it.
fn searching(centre: &Centre) -> bool {
    centre.linear && centre.replay_slopes.len() == centre.theta.len()
}

/// Where each of `centre`'s parameters stands in candidate `c`'s (which holds its effects).
fn centre_slots<'a>(c: &'a Candidate, centre: &'a Centre) -> impl Iterator<Item = usize> + 'a {
    c.params()
        .into_iter()
        .enumerate()
        .filter(|(_, (e, _))| centre.effects.contains(e))
        .map(|(i, _)| i)
}

/// Weight of a centre's correction at `at` (the centre at `centre`, each coordinate divided by
/// its `units`): 1 at the centre, falling smoothly (C¹) to 0 at the centre's own distance from
/// the neutral point (every re-simulated effect vanishes at 0) and held there beyond. So the
/// candidate is exact at the re-simulated parameters, and at the neutral point it is still
/// exactly the baseline, which the other candidates and the floor share. `reach` multiplies
/// that distance: 1 for every centre the diagnosis uses; a pair's search for its next centre
/// reaches further ([`crate::centres::SEARCH_REACH`]).
pub fn centre_weight(at: &[f64], centre: &[f64], units: &[f64], reach: f64) -> f64 {
    let (mut r2, mut d2) = (0.0, 0.0);
    for ((a, c), u) in at.iter().zip(centre).zip(units) {
        r2 += (c / u).powi(2);
        d2 += ((a - c) / u).powi(2);
    }
    r2 *= reach * reach;
    if r2 == 0.0 {
        return 0.0;
    }
    let v = 1.0 - d2 / r2;
    if v > 0.0 {
        v * v
    } else {
        0.0
    }
}

fn scale_grid(grid: &mut [[f64; 3]], s: f64) {
    if s != 1.0 {
        grid.iter_mut().for_each(|g| *g = g.map(|v| v * s));
    }
}

/// Largest total Prony weight: the long-term modulus stays ≥ 5% of the instantaneous one.
pub const MAX_PRONY_SUM: f64 = 0.95;

/// Quasi-linear viscoelasticity with Prony terms (g_i, τ_i),
/// G(t) = 1 − Σ g_i + Σ g_i e^{−t/τ_i} (G(0) = 1): F(t) = ∫ G(t − s) dF_e(s), by the exact
/// recursion for piecewise-linear F_e. Weights summing above [`MAX_PRONY_SUM`] are scaled
/// down to it.
pub fn qlv_in_place<const N: usize>(f: &mut [[f64; 3]], dt: f64, terms: &[(f64, f64); N]) {
    let sum: f64 = terms.iter().map(|t| t.0.max(0.0)).sum();
    if f.is_empty() || sum == 0.0 {
        return;
    }
    let s = if sum > MAX_PRONY_SUM {
        MAX_PRONY_SUM / sum
    } else {
        1.0
    };
    // per term: weight, decay per step and, for a ramp over one step, the share of the
    // increment the convolution with e^{-t/τ} gives, (τ/dt)(1 − e); a term without weight
    // adds nothing. Fixed-size, so the fits' inner loop unrolls (it was 15% of a fit).
    let coef: [(f64, f64, f64); N] = terms.map(|(g, tau)| {
        if g > 0.0 {
            let e = (-dt / tau).exp();
            (g * s, e, tau / dt * (1.0 - e))
        } else {
            (0.0, 0.0, 0.0)
        }
    });
    let g_total = sum * s;
    let mut h = [f[0]; N];
    let mut prev = f[0];
    for v in f.iter_mut() {
        let cur = *v;
        for k in 0..3 {
            let mut out = (1.0 - g_total) * cur[k];
            for (hj, &(g, e, w)) in h.iter_mut().zip(&coef) {
                hj[k] = e * hj[k] + w * (cur[k] - prev[k]);
                out += g * hj[k];
            }
            v[k] = out;
        }
        prev = cur;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: friction's knots are replayed without the contact nuisance's layer, and its
    /// delta added to the layer's lower normal force read μ 15–25% low. Through the layer it
    /// is μ times the lowered normal force, and likewise through the material nuisance's other
    /// law; a geometric effect's delta (support) is added as replayed.
    #[test]
    fn friction_passes_through_the_contact_layer() {
        use crate::dataset::prepare;
        use crate::experiment::Trial;
        use crate::model::ProbePath;
        let (n, dt) = (40, 0.02);
        let t: Vec<f64> = (0..n).map(|i| i as f64 * dt).collect();
        let poses: Vec<msgs::Pose> = (0..n)
            .map(|i| msgs::Pose {
                position: [1e-5 * i as f64, 0.0, 0.0],
                orientation: [0.0, 0.0, 0.0, 1.0],
            })
            .collect();
        let constant = |f: [f64; 3]| vec![f; n];
        let trial = Trial {
            name: "slide".into(),
            file: Default::default(),
            region: None,
            t: t.clone(),
            force: constant([0.0, 0.0, 10.0]),
            pose: poses.clone(),
            lead_in: 0.0,
        };
        let path = ProbePath { t0: 0.0, dt, poses };
        let resims = std::collections::HashMap::from([
            (
                Effect::Friction,
                vec![constant([1.5, 0.0, 10.0]), constant([4.0, 0.0, 10.0])],
            ),
            (
                Effect::Support,
                vec![
                    constant([0.0, 0.0, 8.0]),
                    constant([0.0, 0.0, 6.5]),
                    constant([0.0, 0.0, 5.0]),
                ],
            ),
        ]);
        let mut td = prepare(&trial, path, constant([0.0, 0.0, 10.0]), resims);
        // the layer takes 30% off the normal force
        td.contact_knot = Some(constant([0.0, 0.0, 7.0]));
        // the other law 20%
        td.material_knot = Some(constant([0.0, 0.0, 8.0]));
        let at_both = |c: Candidate, theta: &[f64], contact: f64, material: f64| {
            let (mut g, mut out) = (Vec::new(), Vec::new());
            let nu = NuisanceFit {
                contact,
                material,
                ..NuisanceFit::NEUTRAL
            };
            predict(&c, theta, &td, nu, &mut g, &mut out);
            out[n / 2]
        };
        let at = |c: Candidate, theta: &[f64], contact: f64| at_both(c, theta, contact, 0.0);
        let close = |a: [f64; 3], b: [f64; 3]| (0..3).all(|q| (a[q] - b[q]).abs() < 1e-9);
        let friction = Candidate::single(Effect::Friction);
        // without the layer: μ 0.4 of 10 N
        assert!(close(at(friction.clone(), &[0.4], 0.0), [4.0, 0.0, 10.0]));
        // through the whole layer: μ 0.4 of 7 N
        let f = at(friction.clone(), &[0.4], 1.0);
        assert!(close(f, [2.8, 0.0, 7.0]), "{f:?}");
        // half of it: 8.5 N, and linear in the weight
        let f = at(friction.clone(), &[0.4], 0.5);
        assert!(close(f, [3.4, 0.0, 8.5]), "{f:?}");
        // through the other law alone: μ 0.4 of 8 N; through the layer and half the other
        // law: of 10 − 3 − 1 = 6 N (the two changes add, linear in both weights)
        let f = at_both(friction.clone(), &[0.4], 0.0, 1.0);
        assert!(close(f, [3.2, 0.0, 8.0]), "{f:?}");
        let f = at_both(friction, &[0.4], 1.0, 0.5);
        assert!(close(f, [2.4, 0.0, 6.0]), "{f:?}");
        // without friction the law's change is added like the layer's
        let f = at_both(
            Candidate::single(Effect::Support),
            &[SUPPORT_KNOTS[0]],
            0.0,
            1.0,
        );
        assert!(close(f, [0.0, 0.0, 6.0]), "{f:?}");
        // the support's delta (−2 N at its first knot) is added as replayed
        let f = at(Candidate::single(Effect::Support), &[SUPPORT_KNOTS[0]], 1.0);
        assert!(close(f, [0.0, 0.0, 5.0]), "{f:?}");
        // before the touch no ratio is taken
        assert_eq!(
            layer_change([0.0, 0.0, 0.01], [0.0; 3], [0.0, 0.0, 1.0]),
            0.0
        );
        assert_eq!(
            layer_change([0.0, 0.0, 2.0], [0.0, 0.0, 9.0], [0.0, 0.0, 1.0]),
            1.0
        );
    }

    #[test]
    fn qlv_relaxes_in_hold_to_long_term_modulus() {
        // ramp to 1 N in 0.1 s then hold 10 s: relaxes from ~1 to (1 − g)
        let dt = 0.01;
        let mut f: Vec<[f64; 3]> = (0..1010)
            .map(|i| [0.0, 0.0, (i as f64 / 10.0).min(1.0)])
            .collect();
        qlv_in_place(&mut f, dt, &[(0.4, 0.5)]);
        assert!(f[10][2] > 0.95 && f[10][2] <= 1.0, "peak {}", f[10][2]);
        let at = |t: f64| f[(t / dt) as usize + 10][2];
        let expect = |t: f64| 0.6 + 0.4 * (-t / 0.5f64).exp();
        for t in [0.5, 1.0, 2.0] {
            assert!(
                (at(t) - expect(t)).abs() < 0.02,
                "t={t}: {} vs {}",
                at(t),
                expect(t)
            );
        }
        assert!((f[1009][2] - 0.6).abs() < 1e-3);
    }

    #[test]
    fn qlv_with_two_terms_relaxes_on_both_time_scales() {
        // step-like ramp to 1 N in 0.1 s, hold 40 s: G(t) = 0.4 + 0.3 e^{-t/0.3} + 0.3 e^{-t/8}
        let dt = 0.01;
        let mut f: Vec<[f64; 3]> = (0..4010)
            .map(|i| [0.0, (i as f64 / 10.0).min(1.0), 0.0])
            .collect();
        qlv_in_place(&mut f, dt, &[(0.3, 0.3), (0.3, 8.0)]);
        let at = |t: f64| f[(t / dt) as usize + 10][1];
        // the ramp's own relaxation shifts the curve by ~half the ramp time
        let expect = |t: f64| {
            let t = t + 0.05;
            0.4 + 0.3 * (-t / 0.3f64).exp() + 0.3 * (-t / 8.0f64).exp()
        };
        for t in [0.2, 0.6, 1.5, 5.0, 20.0] {
            assert!(
                (at(t) - expect(t)).abs() < 0.01,
                "t={t}: {} vs {}",
                at(t),
                expect(t)
            );
        }
        // the second term alone equals the one-term model; weights above the cap are scaled
        let ramp: Vec<[f64; 3]> = (0..500).map(|i| [(i as f64 * 0.01).min(1.0); 3]).collect();
        let (mut a, mut b) = (ramp.clone(), ramp.clone());
        qlv_in_place(&mut a, dt, &[(0.0, 1.0), (0.4, 0.5)]);
        qlv_in_place(&mut b, dt, &[(0.4, 0.5)]);
        assert_eq!(a, b);
        let mut c = ramp.clone();
        qlv_in_place(&mut c, dt, &[(0.9, 0.2), (0.9, 0.2)]);
        let mut d = ramp;
        qlv_in_place(&mut d, dt, &[(MAX_PRONY_SUM, 0.2)]);
        for (x, y) in c.iter().zip(&d) {
            assert!((x[0] - y[0]).abs() < 1e-12);
        }
    }

    #[test]
    fn candidate_names_follow_issue_order() {
        assert_eq!(
            Candidate::pair(Effect::Sensor, Effect::Modulus).name(),
            "modulus+sensor"
        );
        assert_eq!(
            Candidate::pair(Effect::Tilt, Effect::Hardening).name(),
            "hardening+tilt"
        );
        for e in Effect::ALL {
            assert_eq!(Effect::parse(e.name()), Some(e));
            for p in e.params() {
                assert!(p.lo <= p.neutral && p.neutral <= p.hi, "{}", p.name);
            }
        }
    }

    /// A centre's weight is 1 there, 0 at the neutral point and at or beyond the centre's own
    /// distance from it, between them in [0, 1] and continuous: the candidate stays exactly the
    /// baseline at the neutral point and nothing jumps as a fit moves.
    #[test]
    fn a_centre_weighs_one_at_itself_and_nothing_at_the_neutral_point() {
        let (c, u) = ([4.0, -2.0, 3e-4], [6.0, 6.0, SUPPORT_SPAN]);
        assert_eq!(centre_weight(&c, &c, &u, 1.0), 1.0);
        assert_eq!(centre_weight(&[0.0; 3], &c, &u, 1.0), 0.0);
        assert_eq!(centre_weight(&[8.0, -4.0, 6e-4], &c, &u, 1.0), 0.0);
        let mut last = centre_weight(&[0.0; 3], &c, &u, 1.0);
        for k in 1..=1000 {
            let f = k as f64 / 1000.0;
            let at = [c[0] * f, c[1] * f, c[2] * f];
            let w = centre_weight(&at, &c, &u, 1.0);
            assert!(
                (0.0..=1.0).contains(&w) && w >= last,
                "{f}: {w} after {last}"
            );
            assert!(w - last < 0.01, "{f}: a jump {last} -> {w}");
            last = w;
        }
        assert_eq!(
            centre_weight(&c, &[0.0; 3], &u, 1.0),
            0.0,
            "a centre at neutral is none"
        );
    }

    /// Reaching 3× (a pair's search), the weight is still 1 at the centre, falls to 0 only at
    /// three times the centre's distance from the neutral point, and leaves (8/9)² at the
    /// neutral point itself.
    #[test]
    fn a_searching_centre_reaches_three_times_as_far() {
        let (c, u) = ([4.0, -2.0, 3e-4], [6.0, 6.0, SUPPORT_SPAN]);
        assert_eq!(centre_weight(&c, &c, &u, 3.0), 1.0);
        let neutral = centre_weight(&[0.0; 3], &c, &u, 3.0);
        assert!(
            (neutral - (8.0f64 / 9.0).powi(2)).abs() < 1e-12,
            "{neutral}"
        );
        // twice as far from the neutral point as the centre: 0 at reach 1, kept at reach 3
        let beyond = [8.0, -4.0, 6e-4];
        assert_eq!(centre_weight(&beyond, &c, &u, 1.0), 0.0);
        assert!((centre_weight(&beyond, &c, &u, 3.0) - neutral).abs() < 1e-12);
        // four times: beyond the reach
        assert_eq!(centre_weight(&[16.0, -8.0, 1.2e-3], &c, &u, 3.0), 0.0);
    }

    /// A hardening beside a tilt stiffens with the depth pressed at the tilt, from where the
    /// tilted replay first touches. With the baseline's depth, a study-mesh hardening+tilt
    /// proxy (rate 0.34 /mm, tilt 6.5°; seed 1203) put the rate on presses the tilt made
    /// deeper or missed: the pair left 20.1 N held out where the tilt alone left 15.4 N
    /// (15.8 N with the centre's own depth).
    #[test]
    fn a_hardening_beside_a_tilt_stiffens_with_the_depth_at_the_tilt() {
        let n = 12;
        let mut td = crate::dataset::pressed_at_rest(None, n, 0.02, [10.0, 10.0, 0.0]);
        // the tilt's knots as the baseline: its interpolation adds nothing anywhere
        td.resims = [(Effect::Tilt, vec![td.base.clone(); 4])]
            .into_iter()
            .collect();
        assert!(td.depth_grid.iter().all(|d| *d == 0.0));
        let own: Vec<f64> = (0..n).map(|i| 0.5 * i as f64).collect();
        let zero = vec![[0.0; 3]; n];
        td.centres.push(Centre {
            effects: vec![Effect::Tilt],
            theta: vec![4.0, -2.0],
            correction: zero.clone(),
            slopes: vec![zero.clone(); 2],
            reach: 1.0,
            replay_slopes: vec![zero; 2],
            linear: false,
            depth_grid: own.clone(),
        });
        let pair = Candidate::pair(Effect::Hardening, Effect::Tilt);
        // in application order: the tilt's angles, then the hardening's scale and rate
        let rate = 0.3;
        // at the centre: its own depth
        let at_centre = pressing_force(&pair, &[4.0, -2.0, 1.0, rate], &td);
        let want = 10.0 * (rate * own[5]).exp();
        assert!((at_centre - want).abs() < 1e-9, "{at_centre} for {want}");
        // halfway to it from the neutral point: the centre's weight (1 - 1/4)² blends the two
        let w = 0.75_f64.powi(2);
        let halfway = pressing_force(&pair, &[2.0, -1.0, 1.0, rate], &td);
        let want = 10.0 * (rate * w * own[5]).exp();
        assert!((halfway - want).abs() < 1e-9, "{halfway} for {want}");
        // untilted, or without a centre: the baseline's depth (no stiffening at 0 mm)
        let untilted = pressing_force(&pair, &[0.0, 0.0, 1.0, rate], &td);
        assert!((untilted - 10.0).abs() < 1e-9, "{untilted}");
    }

    /// A pressing trial with the support's knots replayed (each knot's force a fraction of
    /// the baseline's) and a centre of the support at `theta` (correction `k` N along z
    /// wherever it presses, the replay's slope `slope` N per m/N there).
    fn supported(theta: f64, k: f64, slope: f64, linear: bool) -> TrialData {
        let n = 12;
        let mut td = crate::dataset::pressed_at_rest(None, n, 0.02, [10.0, 10.0, 0.0]);
        let along_z = |v: f64| -> Vec<[f64; 3]> {
            (0..n)
                .map(|i| [0.0, 0.0, if (2..n - 2).contains(&i) { v } else { 0.0 }])
                .collect()
        };
        let knots = SUPPORT_KNOTS
            .iter()
            .map(|c| along_z(10.0 / (1.0 + 500.0 * c)));
        td.resims = [(Effect::Support, knots.collect())].into_iter().collect();
        td.centres.push(Centre {
            effects: vec![Effect::Support],
            theta: vec![theta],
            correction: along_z(k),
            slopes: vec![along_z(0.0)],
            reach: 1.0,
            replay_slopes: vec![along_z(slope)],
            linear,
            depth_grid: Vec::new(),
        });
        td
    }

    /// The normal force `c` predicts at `theta` on trial `td`, where it presses.
    fn pressing_force(c: &Candidate, theta: &[f64], td: &TrialData) -> f64 {
        let (mut grid, mut out) = (Vec::new(), Vec::new());
        predict(c, theta, td, NuisanceFit::NEUTRAL, &mut grid, &mut out);
        out[5][2]
    }

    /// A pair's search fits the replay's tangent at its last centre: what the replay gave
    /// there plus its own slope times the step, however far the fit goes (it crept ~0.5
    /// units a round while the interpolation's curvature and the centre's fading weight held
    /// it). Once made, the same centre fades again and the interpolation is back beyond it.
    #[test]
    fn a_searching_centre_is_the_replays_tangent_at_any_distance() {
        let support = Candidate::single(Effect::Support);
        let (theta, k, slope) = (5.0e-4, -0.3, -4000.0);
        let at_centre = 10.0 / (1.0 + 500.0 * theta) + k;
        let searching = supported(theta, k, slope, true);
        for step in [0.0, 1.0e-4, 1.0e-3, 1.4e-3] {
            let f = pressing_force(&support, &[theta + step], &searching);
            let tangent = at_centre + slope * step;
            assert!((f - tangent).abs() < 1e-9, "{step}: {f} for {tangent}");
        }
        // made: beyond the centre's own distance from the neutral point, the interpolation
        let made = supported(theta, k, slope, false);
        let far = pressing_force(&support, &[1.0e-3 + 1.0e-4], &made);
        let interpolated = pressing_force(&support, &[1.0e-3 + 1.0e-4], &{
            let mut plain = made.clone();
            plain.centres.clear();
            plain
        });
        assert!(
            (far - interpolated).abs() < 1e-12,
            "{far} for {interpolated}"
        );
        assert!((far - (at_centre + slope * 6.0e-4)).abs() > 0.5);
    }
}
