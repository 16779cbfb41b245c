//! The second stage: re-simulations at the support and the tilt the whole experiment fits,
//! and at the tilt with a support beside it. Their interpolation between knots is wrong in
//! ways a refit cannot undo; a replay at the fitted parameters makes the candidate exact
//! there, and the interpolation then carries only the step from it to a fold's own fit.
//!
//! A support is a spring in series with the tissue, so the force is convex in its compliance
//! and the chord between two knots lies above it: interpolated, a support is too stiff between
//! the knots, and the fit takes a softer one to make up for it. With the knots at 4000, 2000
//! and 1000 N/m per node, the study-mesh proxies' supports of 1818 and 1993 N/m were fitted
//! 19% and 18% soft; with a centre at the support's own fit, 10% and 3%.
//!
//! A tilt moves where the probe first touches. Between the baseline and the knots (then at
//! ±6°, now ±3°: [`crate::effects::TILT_STEP`]) the quadratic interpolation then puts part of
//! a knot's early touch into trials whose true tilt does not touch yet (1.7 N RMS in the free
//! approach at the true 4.1°, 2.3° of a study-mesh case, where the measurement carries only
//! its 0.02 N of noise). The phase-variance likelihood weighs that approach error heavily, so
//! a fold rejected the true tilt and the case read `none`.
//!
//! A tilt on a soft support is a third case of the same kind: the tilted knots are replayed
//! on the fixed base and the support's knots untilted, so their deltas, added, overstate the
//! tilt's force where the base gives (the true parameters of a study-mesh support+tilt case
//! left 31.7 N RMS where the baseline left 13.4 N). The pair gets its own centre, replayed
//! tilted on the fitted support. A centre alone fixes the pair's value there, not its slopes:
//! leaving the centre, each effect's delta still comes from knots replayed without the other
//! (a study-mesh pair whose centre stood at tilt_y −0.47° was 5.1 N RMS off at the true
//! −1.80°, where a replay is 0.44 N off), so the fit never left it. A pair's centre therefore
//! also carries the replay's slopes there, from a step along each parameter.
//!
//! While a pair's or the tilt's rounds search for the next centre, the candidate is the
//! replay's tangent at the last one ([`Centre::linear`]): the replay there plus its own slopes
//! times the step, a Gauss-Newton step limited to [`MAX_SEARCH_STEP`]. Fitted through the
//! interpolation with the centre's correction fading away from it, the search crept about
//! half a unit a round towards the pair's fit (the bench case's tilt 1.2° a round) and took
//! all six rounds; on the tangent the bench's search settles in five, at 216 centre replays
//! for 300 (README, "The pair's search on the replay's tangent").
//!
//! The tilt's pairs with an effect that is not re-simulated use the single tilt's centre, so
//! it carries the slopes too: a pair whose tilt the tilt alone had taken part of the other
//! effect for then reaches its own tilt (README, "Slopes at the tilt's centre"). The tilt
//! alone crept as the pair did, a degree or so a round short of a 6–8° tilt after its three
//! rounds (a study-mesh tilt+device proxy's centre at 4.0°, −3.3° for 6.4°, −4.6°), and the
//! pairs' fits leave the centre only so far; searched on the tangent as a pair is, its centre
//! stood at 6.2°, −4.2° (README, "The tilt's search on the replay's tangent").
use super::dataset::{replay_trials_at, Centre, TrialData};
use super::effects::{axpy_resimulated, Candidate, Effect, SUPPORT_KNOTS, SUPPORT_SPAN};
use super::fit::{default_free, fit, Nuisance};
use super::metrics::depth_series;
use super::model::{ForceModel, Replayed, Variant};
use super::GapError;

/// Below this fitted tilt (degrees, both axes together) the quadratic is close enough to its
/// baseline knot, and no re-simulation is made.
pub const MIN_CENTRE_DEG: f64 = 1.0;

/// Below this fitted support compliance (m/N per node) no support centre is made, and the
/// tilt+support pair uses the tilt's own centre: the support is negligible
/// ([`crate::strength::MIN_SUPPORT_COMPLIANCE`]).
pub const MIN_CENTRE_SUPPORT: f64 = crate::strength::MIN_SUPPORT_COMPLIANCE;

/// At most this many re-simulations per trial and centre for the support alone: the fit with
/// the first centre moves towards the true parameters (the interpolation's error shrinks near
/// the centre), and another centre at the refit is made when it moved by at least [`SETTLED`]
/// (in [`crate::effects::centre_unit`]s: 0.25° of tilt, 8.3·10⁻⁵ m/N of support compliance).
pub const ROUNDS: usize = 3;
/// At most this many for a pair or the tilt ([`searched`]): each of its centres moves the fit
/// only as far as the centre's weight reaches (its own distance from the neutral point), and a
/// pair's tilt beyond the knots (then at ±6°) took five (a coarse-mesh case's −2.6° → −6.1°
/// for a true −6.9°).
/// They are made on the pair's search trials ([`search_trials`]) until the fit there settles;
/// the other trials then get that centre, and rounds over every trial go on from it within
/// the same count.
pub const PAIR_ROUNDS: usize = 6;
pub const SETTLED: f64 = 0.5 / 6.0;

/// Fits the support alone to every trial (with the nuisances `nuisance`) and, when its
/// compliance is at least [`MIN_CENTRE_SUPPORT`], re-simulates every trial at it and stores
/// the correction as a [`Centre`]; then once more at the refit if it moved ([`ROUNDS`]). The
/// same for the tilt alone when it tilts by at least [`MIN_CENTRE_DEG`], searched as a pair's
/// are (below); with support knots,
/// for the tilt+support pair when its fitted support compliance is at least
/// [`MIN_CENTRE_SUPPORT`], from the tilt's centre whatever tilt the pair fits, or, where the
/// tilt alone never reached [`MIN_CENTRE_DEG`], from the pair's own fit when that tilts by
/// at least as much: up to [`PAIR_ROUNDS`] centres, each
/// with its slopes ([`Centre::slopes`]: one more replay per parameter), searched on a few
/// trials first ([`search_trials`]) on the replay's tangent ([`Centre::linear`]). What was
/// made is in
/// each trial's [`TrialData::centres`] ([`describe`]), in the order made: a pair with two
/// centres of one effect each ([`crate::effects::centre_for`]) takes the later, the tilt's,
/// whose interpolation errs most.
pub fn add_centres(
    data: &mut [TrialData],
    model: &dyn ForceModel,
    nuisance: Nuisance,
) -> Result<(), GapError> {
    let has = |data: &[TrialData], e: Effect| {
        !data.is_empty() && data.iter().all(|d| d.resims.contains_key(&e))
    };
    if has(data, Effect::Support) {
        let support = Candidate::single(Effect::Support);
        let significant = |th: &[f64]| th[0] >= MIN_CENTRE_SUPPORT;
        centre_rounds(data, model, nuisance, &support, &[], significant, None)?;
    }
    if !has(data, Effect::Tilt) {
        return Ok(());
    }
    let tilt = Candidate::single(Effect::Tilt);
    let significant = |th: &[f64]| th[0].hypot(th[1]) >= MIN_CENTRE_DEG;
    // Placed with a relaxation beside it: a relaxing hold lowers the force a tilt's earlier
    // touch adds, and fitted alone the tilt took the relaxation as less tilt. The refined
    // cycle's viscoelastic+tilt case (g1 0.47, τ 1.28 s, tilt 5.8°) had its centre 3.2° off
    // and read `tilt`, the tilt 59% short. Where nothing relaxes over the hold the centre is
    // the tilt's own fit.
    let placed = Some(Candidate::pair(Effect::Viscoelastic, Effect::Tilt));
    let angles = centre_rounds(data, model, nuisance, &tilt, &[], significant, placed)?;
    if !has(data, Effect::Support) {
        return Ok(());
    }
    let pair = Candidate::pair(Effect::Tilt, Effect::Support);
    match angles {
        Some(angles) => {
            let inits: Vec<Vec<f64>> = [SUPPORT_KNOTS[0], SUPPORT_SPAN]
                .iter()
                .map(|&c| vec![angles[0], angles[1], c])
                .collect();
            // the tilt alone was significant; on a soft support the pair's interpolation may
            // first fit less of it (its tilted knots stand on the fixed base)
            let significant = |th: &[f64]| th[2] >= MIN_CENTRE_SUPPORT;
            centre_rounds(data, model, nuisance, &pair, &inits, significant, None)?;
        }
        None => {
            // A tilt on a soft support may not reach significance alone: its knots stand on
            // the fixed base, so their force overstates the tilt's where the base gives, and
            // the fit takes less tilt for it. A coarse-mesh proxy case of 7.8° on 947 N/m per
            // node (seed 817) fitted under 1° alone and read `mesh`; the pair's own fit, over
            // the support's centre, still tilted 1.1° with the support beside it. Its centre
            // is then searched from there, each round tilted on the fitted support.
            let significant =
                |th: &[f64]| th[0].hypot(th[1]) >= MIN_CENTRE_DEG && th[2] >= MIN_CENTRE_SUPPORT;
            centre_rounds(data, model, nuisance, &pair, &[], significant, None)?;
        }
    }
    Ok(())
}

/// Up to [`ROUNDS`] ([`PAIR_ROUNDS`] for a pair) centres for candidate `c` (only re-simulated
/// effects), each at the candidate's fit over every trial with the centre before it in place
/// (a pair's over its [`search_trials`] until they settle, then
/// [`AFTER_SEARCH_ROUNDS`] more over every trial); returns the last
/// centre's parameters (None: the fit was never significant). With `placed`, `c`'s effects
/// with a relaxation beside them ([`relaxes_over_the_hold`]), a centre stands at `c`'s
/// parameters of that candidate's fit where its relaxation relaxes over the hold.
fn centre_rounds(
    data: &mut [TrialData],
    model: &dyn ForceModel,
    nuisance: Nuisance,
    c: &Candidate,
    inits: &[Vec<f64>],
    significant: impl Fn(&[f64]) -> bool,
    placed: Option<Candidate>,
) -> Result<Option<Vec<f64>>, GapError> {
    let every: Vec<usize> = (0..data.len()).collect();
    // a pair and the tilt search on a few trials first ([`search_trials`]): each of their
    // rounds replays a step along every parameter too; the support's rounds are cheap enough
    // on all of them
    let mut search = if searched(c) {
        search_trials(data)
    } else {
        every.clone()
    };
    // the first fit, before any of the pair's centres stands, sees every trial as before
    let mut mask = trial_mask(data, &every);
    let mut done: Option<Vec<f64>> = None;
    let rounds = if searched(c) { PAIR_ROUNDS } else { ROUNDS };
    let (mut made, mut budget) = (0, rounds);
    // the search settled on its trials
    let mut settled = false;
    loop {
        if settled || made == budget {
            // settled or out of rounds on the search's trials: the others get the last
            // centre, and a few rounds over every trial go on from it. Their centres reach
            // 1× as made, the searched ones' 3×: given the searched reach too, the study
            // proxies' pair came back with its support 11.0% off for 2.1% (bench and coarse
            // pair unchanged). Searched on the tangent, every trial's centre is on it in that
            // fit: the study pair's support comes back 11.2% off either way, the search having
            // settled at 6.7% (README, "The pair's search on the replay's tangent").
            settled = false;
            match &done {
                Some(last) if search.len() < data.len() => {
                    replay_rest(data, model, c, last, &search)?;
                    set_search(data, c, true);
                    search = every.clone();
                    mask = trial_mask(data, &search);
                    budget = made + AFTER_SEARCH_ROUNDS;
                }
                _ => break,
            }
        }
        let mut starts = inits.to_vec();
        starts.extend(done.clone());
        let mut theta = placed_fit(data, &mask, c, &starts, nuisance, placed.as_ref());
        if let Some(last) = done.as_ref().filter(|_| searched(c)) {
            limit_step(c, &mut theta, last);
        }
        if !significant(&theta) {
            break;
        }
        if let Some(last) = &done {
            if moved(c, &theta, last) < SETTLED {
                if search.len() == data.len() {
                    break;
                }
                settled = true;
                continue;
            }
        }
        replay_centre(data, model, c, &theta, &search)?;
        mask = trial_mask(data, &search);
        made += 1;
        if searched(c) {
            set_reach(data, c, SEARCH_REACH);
            set_search(data, c, true);
        }
        done = Some(theta);
    }
    // the fit fell below significance during the search: the other trials still get the last
    // centre, so every trial's candidate stands on it
    if let Some(last) = &done {
        if search.len() < data.len() {
            replay_rest(data, model, c, last, &search)?;
        }
    }
    // the candidate the diagnosis fits: the baseline at the neutral point again
    set_reach(data, c, 1.0);
    set_search(data, c, false);
    Ok(done)
}

/// `c`'s fit over the samples `mask` from `starts` (with the nuisance band `nuisance`, as
/// each candidate and the trials carry it); with `placed`, the wider candidate holding a
/// relaxation, `c`'s parameters of that candidate's fit where its relaxation relaxes over the
/// hold ([`relaxes_over_the_hold`]).
fn placed_fit(
    data: &[TrialData],
    mask: &[Vec<bool>],
    c: &Candidate,
    starts: &[Vec<f64>],
    nuisance: Nuisance,
    placed: Option<&Candidate>,
) -> Vec<f64> {
    let band = nuisance.for_candidate(c).for_data(data);
    let fitted = fit(c, data, mask, starts, &default_free(c), band).theta;
    let Some(w) = placed else {
        return fitted;
    };
    let nu = nuisance.for_candidate(w).for_data(data);
    let wide_starts: Vec<Vec<f64>> = starts
        .iter()
        .chain([&fitted])
        .map(|th| embed(w, c, th))
        .collect();
    let wide = fit(w, data, mask, &wide_starts, &default_free(w), nu);
    if relaxes_over_the_hold(w, &wide.theta) {
        extract(w, c, &wide.theta)
    } else {
        fitted
    }
}

/// How far `theta` stands from `last`, in [`crate::effects::centre_unit`]s.
fn moved(c: &Candidate, theta: &[f64], last: &[f64]) -> f64 {
    theta
        .iter()
        .zip(last)
        .zip(units(c))
        .map(|((a, b), u)| ((a - b) / u).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// How far a pair's or the tilt's latest centre reaches while its rounds look for the next one, in
/// multiples of the centre's distance from the neutral point ([`Centre::reach`]).
///
/// A centre's weight falls to 0 at that distance (once made: 1×, so the candidate stays the
/// baseline there), and a first pair centre stands near the neutral point, so its slopes
/// held the refit within a short step of it: the pair crept towards its fit by ~0.4 units a
/// round and the six rounds ran out short (the 1,435-node bench case's tilt 12–22% and the
/// coarse proxies' 11.5% short). Reaching 3× lets the refit follow the slopes as far as the
/// truth of those cases; the neutral point then keeps 0.79 of the correction, which only the
/// search sees. Where a centre has the replay's slopes the search now fits its tangent
/// instead, at every distance ([`Centre::linear`]); the reach holds for one whose step replay
/// diverged.
pub const SEARCH_REACH: f64 = 3.0;

/// Trials a pair's rounds search on before the rest get its centre: per region, the deepest
/// and the shallowest press. A pair's round replays each trial four times (the centre and a
/// step along each parameter), and the 15-trial bench case's rounds took 64 of its 115 s on
/// this session's machine. Its first fit sees every trial (no centre of the pair stands yet);
/// the rounds after it fit and replay only these, and every trial joins once the search
/// settles ([`AFTER_SEARCH_ROUNDS`]).
///
/// Why the two ends of the depth range: a support is a spring in series, so it softens a deep
/// press more than a shallow one, and the tilt moves every onset; the pair is told apart by
/// that contrast. Searched on the deepest press alone the coarse proxies' pair drifted to a
/// support 39% soft (the search's three trials could not separate the two); on the shallowest
/// alone the study proxies' support came back 12% off; on both ends 1.8% and 2.1%.
fn search_trials(data: &[TrialData]) -> Vec<usize> {
    let deepest = |i: usize| data[i].depth_grid.iter().copied().fold(0.0_f64, f64::max);
    let mut regions: Vec<Option<crate::experiment::Region>> = Vec::new();
    for d in data {
        if !regions.contains(&d.region) {
            regions.push(d.region);
        }
    }
    let mut out: Vec<usize> = Vec::new();
    for r in regions {
        let mut own: Vec<usize> = (0..data.len()).filter(|&i| data[i].region == r).collect();
        own.sort_by(|&a, &b| deepest(b).total_cmp(&deepest(a)).then(a.cmp(&b)));
        out.extend(own.first());
        if own.len() > 1 {
            out.extend(own.last());
        }
    }
    out.sort_unstable();
    out
}

/// Rounds over every trial after a pair's search ([`search_trials`]) settled or ran out of
/// [`PAIR_ROUNDS`]: a fit of three parameters on six trials may leave one off that all of
/// them move.
pub const AFTER_SEARCH_ROUNDS: usize = 2;

/// Every sample of the trials `which`, none of the others'.
fn trial_mask(data: &[TrialData], which: &[usize]) -> Vec<Vec<bool>> {
    data.iter()
        .enumerate()
        .map(|(i, d)| vec![which.contains(&i); d.t.len()])
        .collect()
}

/// The centre at `theta` for every trial outside `search`.
fn replay_rest(
    data: &mut [TrialData],
    model: &dyn ForceModel,
    c: &Candidate,
    theta: &[f64],
    search: &[usize],
) -> Result<(), GapError> {
    let rest: Vec<usize> = (0..data.len()).filter(|i| !search.contains(i)).collect();
    replay_centre(data, model, c, theta, &rest)
}

/// Whether `c`'s centres are searched from ([`Centre::linear`]): the replay's tangent there.
fn set_search(data: &mut [TrialData], c: &Candidate, linear: bool) {
    for k in data.iter_mut().flat_map(|d| d.centres.iter_mut()) {
        if k.effects == c.0 {
            k.linear = linear;
        }
    }
}

/// Longest step (in [`crate::effects::centre_unit`]s: 4.5° of tilt, 1.5·10⁻³ m/N of support
/// compliance) a pair's search takes from its last centre to the next: the replay's tangent
/// there ([`Centre::linear`]) is a Gauss-Newton step, exact for the support's spring but not
/// far past a tilt's onset.
pub const MAX_SEARCH_STEP: f64 = 1.5;

/// `theta` brought back along its step from `last` to at most [`MAX_SEARCH_STEP`].
fn limit_step(c: &Candidate, theta: &mut [f64], last: &[f64]) {
    let step = moved(c, theta, last);
    if step > MAX_SEARCH_STEP {
        let k = MAX_SEARCH_STEP / step;
        for (t, l) in theta.iter_mut().zip(last) {
            *t = l + k * (*t - l);
        }
    }
}

fn set_reach(data: &mut [TrialData], c: &Candidate, reach: f64) {
    for k in data.iter_mut().flat_map(|d| d.centres.iter_mut()) {
        if k.effects == c.0 {
            k.reach = reach;
        }
    }
}

/// A relaxation fitted beside a centre's effects ([`add_centres`]' tilt) places the centre
/// when it relaxes over the hold: a weight worth naming ([`crate::strength::MIN_PRONY_G1`])
/// and a time constant above [`MIN_PLACING_TAU`]. One at the fastest bound relaxes within two
/// samples of every load step, a shape of the loading ramp rather than a time course, and the
/// study-mesh tilt proxy fitted one (g1 0.11 at 0.05 s) that moved its centre 1.2° past the
/// truth and lost the case to `modulus+tilt`.
fn relaxes_over_the_hold(wide: &Candidate, theta: &[f64]) -> bool {
    // the relaxation's parameters in its own order: g1, tau1, then the optional second term
    let relaxation = extract(wide, &Candidate::single(Effect::Viscoelastic), theta);
    matches!(
        relaxation[..],
        [g1, tau1, ..] if g1 >= crate::strength::MIN_PRONY_G1 && tau1 > MIN_PLACING_TAU
    )
}

/// Shortest relaxation time (s) that places a centre ([`relaxes_over_the_hold`]): twice the
/// fit's lower bound, about four samples at the study's ~38 Hz.
pub const MIN_PLACING_TAU: f64 = 0.1;

/// `narrow`'s parameters `theta` within the wider candidate `wide`, whose other parameters
/// stay neutral.
fn embed(wide: &Candidate, narrow: &Candidate, theta: &[f64]) -> Vec<f64> {
    let mut out = wide.neutral();
    for (slot, v) in narrow_slots(wide, narrow).into_iter().zip(theta) {
        out[slot] = *v;
    }
    out
}

/// `narrow`'s parameters out of the wider candidate `wide`'s `theta`.
fn extract(wide: &Candidate, narrow: &Candidate, theta: &[f64]) -> Vec<f64> {
    narrow_slots(wide, narrow)
        .into_iter()
        .map(|slot| theta[slot])
        .collect()
}

/// Where each of `narrow`'s parameters stands among `wide`'s (both list them per effect, in
/// the effect's own order; `wide` holds `narrow`'s effects).
fn narrow_slots(wide: &Candidate, narrow: &Candidate) -> Vec<usize> {
    let params = wide.params();
    narrow
        .params()
        .iter()
        .filter_map(|(e, p)| {
            params
                .iter()
                .position(|(we, wp)| we == e && wp.name == p.name)
        })
        .collect()
}

fn units(c: &Candidate) -> Vec<f64> {
    c.params()
        .iter()
        .map(|(e, _)| super::effects::centre_unit(*e))
        .collect()
}

/// Whether `c`'s rounds search on the replay's tangent ([`Centre::linear`]): a pair's, and
/// the tilt's.
fn searched(c: &Candidate) -> bool {
    c.0.len() > 1 || c.0 == [Effect::Tilt]
}

/// The replay variant of candidate `c` (re-simulated effects only) at `theta`.
fn centre_variant(c: &Candidate, theta: &[f64]) -> Variant {
    let mut v = Variant::default();
    let mut k = 0;
    for &e in &c.0 {
        match e {
            Effect::Tilt => v.tilt = [theta[k].to_radians(), theta[k + 1].to_radians()],
            Effect::Support => v.support_stiffness = 1.0 / theta[k],
            Effect::Friction => v.friction = theta[k],
            _ => {}
        }
        k += e.params().len();
    }
    v
}

/// Re-simulates the trials `which` at `theta` and stores each one's correction (replacing an
/// earlier centre of the same effects); a pair's or the tilt's with its slopes
/// ([`slope_steps`]).
fn replay_centre(
    data: &mut [TrialData],
    model: &dyn ForceModel,
    c: &Candidate,
    theta: &[f64],
    which: &[usize],
) -> Result<(), GapError> {
    let steps = if searched(c) {
        slope_steps(c, theta)
    } else {
        Vec::new()
    };
    // the centre and its steps in one batch (per variant, per trial)
    let variants: Vec<Variant> = std::iter::once(centre_variant(c, theta))
        .chain(steps.iter().map(|(at, _)| centre_variant(c, at)))
        .collect();
    let trials: Vec<&TrialData> = which.iter().map(|&i| &data[i]).collect();
    let mut batch = replay_trials_at(&trials, model, &variants).into_iter();
    let replays = batch.next().unwrap_or_default();
    let stepped = per_trial(batch, which.len())?;
    for ((&i, r), steps_here) in which.iter().zip(replays).zip(stepped) {
        let d = &mut data[i];
        let r = r?;
        d.centres.retain(|k| k.effects != c.0);
        // a step the physics flagged as faulty is no solution: that trial keeps the plain
        // interpolation
        if r.diverged() {
            continue;
        }
        let mut interpolated = d.base.clone();
        axpy_resimulated(&mut interpolated, c, theta, d);
        let correction: Vec<[f64; 3]> = difference(&r.forces, &interpolated);
        let slopes = slopes_at(d, c, theta, &steps, &steps_here, &correction);
        let depth_grid = if c.0.contains(&Effect::Tilt) {
            depth_series(&d.path.positions(), &r.forces, d.normal)
        } else {
            Vec::new()
        };
        d.centres.push(Centre {
            effects: c.0.clone(),
            theta: theta.to_vec(),
            correction,
            slopes: slopes.relative,
            reach: 1.0,
            replay_slopes: slopes.replayed,
            linear: false,
            depth_grid,
        });
    }
    Ok(())
}

/// A step along each of `c`'s parameters from `theta` ([`SLOPE_STEP`] centre units): the
/// parameters there and the step's length.
fn slope_steps(c: &Candidate, theta: &[f64]) -> Vec<(Vec<f64>, f64)> {
    units(c)
        .iter()
        .enumerate()
        .map(|(i, u)| {
            let h = SLOPE_STEP * u;
            let mut at = theta.to_vec();
            at[i] += h;
            (at, h)
        })
        .collect()
}

/// Replays returned per variant, per trial (as [`replay_trials_at`] gives them), turned into
/// each of the `trials` trials' own replays in the variants' order.
fn per_trial(
    rows: impl IntoIterator<Item = Vec<Result<Replayed, GapError>>>,
    trials: usize,
) -> Result<Vec<Vec<Replayed>>, GapError> {
    let mut out: Vec<Vec<Replayed>> = (0..trials).map(|_| Vec::new()).collect();
    for row in rows {
        for (own, r) in out.iter_mut().zip(row) {
            own.push(r?);
        }
    }
    Ok(out)
}

/// A centre's slopes on trial `d` from its replays a step away (`steps_here`, at `steps`):
/// per parameter, the replay's change from the centre minus the interpolation's, per unit.
/// Only where every step replayed: one missing would leave the others' directions to carry
/// the error alone.
fn slopes_at(
    d: &TrialData,
    c: &Candidate,
    theta: &[f64],
    steps: &[(Vec<f64>, f64)],
    steps_here: &[Replayed],
    correction: &[[f64; 3]],
) -> Slopes {
    if steps_here.len() < steps.len() || steps_here.iter().any(|s| s.diverged()) {
        return Slopes::default();
    }
    // the replay at the centre: its interpolation there and the correction
    let mut replayed = d.base.clone();
    axpy_resimulated(&mut replayed, c, theta, d);
    for (r, k) in replayed.iter_mut().zip(correction) {
        *r = [0, 1, 2].map(|q| r[q] + k[q]);
    }
    let mut out = Slopes::default();
    for ((at, h), s) in steps.iter().zip(steps_here) {
        let mut interpolated = d.base.clone();
        axpy_resimulated(&mut interpolated, c, at, d);
        let per_unit = |a: &[[f64; 3]], b: &[[f64; 3]]| -> Vec<[f64; 3]> {
            a.iter()
                .zip(b)
                .map(|(a, b)| [0, 1, 2].map(|q| (a[q] - b[q]) / h))
                .collect()
        };
        out.relative
            .push(per_unit(&difference(&s.forces, &interpolated), correction));
        out.replayed.push(per_unit(&s.forces, &replayed));
    }
    out
}

/// A centre's slopes ([`slopes_at`]): the replay's minus the interpolation's
/// ([`Centre::slopes`]) and the replay's own ([`Centre::replay_slopes`]).
#[derive(Default)]
struct Slopes {
    relative: Vec<Vec<[f64; 3]>>,
    replayed: Vec<Vec<[f64; 3]>>,
}

/// A pair centre's slope step, in [`crate::effects::centre_unit`]s: 0.3° of tilt, 10⁻⁴ m/N
/// of support compliance; small against the distances a refit moves, large against the
/// replay's own tolerance.
pub const SLOPE_STEP: f64 = 0.1;

fn difference(a: &[[f64; 3]], b: &[[f64; 3]]) -> Vec<[f64; 3]> {
    a.iter()
        .zip(b)
        .map(|(f, q)| [f[0] - q[0], f[1] - q[1], f[2] - q[2]])
        .collect()
}

/// The centres in `data`, one line each, as the report lists them: the candidate, its
/// parameters with units and how many trials have a usable replay there.
pub fn describe(data: &[TrialData]) -> Vec<String> {
    let mut seen: Vec<&Centre> = Vec::new();
    for k in data.iter().flat_map(|d| &d.centres) {
        if !seen.iter().any(|s| s.effects == k.effects) {
            seen.push(k);
        }
    }
    seen.iter()
        .map(|k| {
            let c = Candidate(k.effects.clone());
            let params: Vec<String> = c
                .params()
                .iter()
                .zip(&k.theta)
                .map(|((_, p), v)| {
                    format!("{} {v:.4} {}", p.name, p.unit)
                        .trim_end()
                        .to_string()
                })
                .collect();
            let usable = data
                .iter()
                .filter(|d| d.centres.iter().any(|x| x.effects == k.effects))
                .count();
            format!(
                "{} at {} ({usable} of {} trials)",
                c.name(),
                params.join(", "),
                data.len()
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The study-mesh tilt proxy's relaxation (g1 0.11 at the 0.05 s bound) does not place the
    /// tilt's centre; the refined viscoelastic+tilt case's (g1 0.53 at 1.8 s) does, and a
    /// negligible weight does not.
    #[test]
    fn only_a_relaxation_over_the_hold_places_a_centre() {
        let w = Candidate::pair(Effect::Viscoelastic, Effect::Tilt);
        let relaxation = Candidate::single(Effect::Viscoelastic);
        let at = |g1: f64, tau1: f64| embed(&w, &relaxation, &[g1, tau1]);
        assert!(!relaxes_over_the_hold(&w, &at(0.11, 0.05)));
        assert!(relaxes_over_the_hold(&w, &at(0.53, 1.8)));
        assert!(!relaxes_over_the_hold(&w, &at(0.01, 1.8)));
        // the tilt's own parameters go in and come back out where they stand
        let tilt = Candidate::single(Effect::Tilt);
        let wide = embed(&w, &tilt, &[2.0, -3.0]);
        assert_eq!(extract(&w, &tilt, &wide), vec![2.0, -3.0]);
    }
}
