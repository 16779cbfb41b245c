//! The frictional contact LCP in constraint space, solved by projected block Gauss–Seidel.
//! Below both the physics node (which solves each step's contacts) and the haptic node
//! (which re-solves the newest step's problem for the stylus's position every tick): the
//! problem comes in as W, δ_free and μ, the impulses λ go out.
//!
//! Problem (one block of 3 rows per contact: normal n, tangents t1, t2):
//!
//! ```text
//!   δ = δ_free + W λ                       (λ: impulses, N·s; δ: violation, m)
//!   0 ≤ λn  ⟂  δn ≥ 0                      (normal complementarity)
//!   |λt| ≤ μ λn; stick (δt = 0) inside the cone, slide on its boundary opposing δt
//! ```
//!
//! W is row-major with stride [`MAX_ROWS`] (the layout of `msgs::physics_to_haptic::ContactFrame`),
//! only the leading `row_count × row_count` block is read. The solver is used both by the
//! physics node (every step) and by the haptic node (every 1 ms tick), so it has fixed capacity,
//! allocates nothing, warm-starts from the λ it is given, and stops at an iteration cap, a
//! tolerance, or a deadline.
//!
//! Convergence measure: after each sweep, `residual = max_i |Δλ_i| / max(max_i |λ_i|, λ_floor)`,
//! the largest change of an impulse relative to the largest impulse (dimensionless, so the
//! same tolerance works in SI for soft and stiff tissue). An all-zero solution that does not
//! change has residual 0.
//!
//! Sliding friction projects the tangential trial impulse radially onto the disc of radius
//! μ λn and re-solves the normal with that tangential impulse (a few inner passes). This is
//! exact for isotropic tangential compliance (W_tt = w·I), the usual case for a point contact,
//! and the common approximation otherwise (SOFA's nlcp_gaussseidel does the same).

use std::time::Instant;

/// Maximum number of contacts (mirrors `msgs::MAX_CONTACTS`).
pub const MAX_CONTACTS: usize = 32;
/// Rows per contact: normal, tangent 1, tangent 2 (mirrors `msgs::ROWS_PER_CONTACT`).
pub const ROWS_PER_CONTACT: usize = 3;
/// Row stride of W (mirrors `msgs::MAX_ROWS`; haptic-node and physics-node assert at compile
/// time that the copies agree, since this crate has no dependencies).
pub const MAX_ROWS: usize = MAX_CONTACTS * ROWS_PER_CONTACT;

pub mod synthetic;

/// Smallest |λ| used to normalise the residual, N·s (avoids dividing by zero near separation).
const LAMBDA_FLOOR: f64 = 1e-12;
/// Inner passes of the sliding projection within one block.
const SLIDING_PASSES: usize = 12;

/// Why a problem was rejected. On any error the λ given to [`solve`] is set to zero.
#[derive(Debug, Clone, PartialEq)]
pub enum LcpError {
    /// Row count not a multiple of 3 or above [`MAX_ROWS`].
    RowCount { rows: usize },
    /// A slice is shorter than the layout requires.
    SliceTooShort {
        what: &'static str,
        len: usize,
        needed: usize,
    },
    /// μ negative or not finite.
    Friction { mu: f64 },
    /// A NaN or infinity in W or δ_free, found while evaluating this row.
    NonFinite { row: usize },
    /// The contact's 3×3 diagonal block of W is not positive definite enough to solve.
    DegenerateBlock { contact: usize },
    /// Settings out of range (tolerance not finite / negative).
    Settings { detail: &'static str },
}

impl core::fmt::Display for LcpError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            LcpError::RowCount { rows } => write!(
                f,
                "row count {rows} is not a multiple of {ROWS_PER_CONTACT} in 0..={MAX_ROWS}"
            ),
            LcpError::SliceTooShort { what, len, needed } => {
                write!(f, "{what} has {len} entries, {needed} needed")
            }
            LcpError::Friction { mu } => {
                write!(f, "friction coefficient {mu} is not a finite value ≥ 0")
            }
            LcpError::NonFinite { row } => {
                write!(
                    f,
                    "non-finite compliance or free violation in constraint row {row}"
                )
            }
            LcpError::DegenerateBlock { contact } => write!(
                f,
                "diagonal compliance block of contact {contact} is not positive definite"
            ),
            LcpError::Settings { detail } => write!(f, "solver settings: {detail}"),
        }
    }
}

impl std::error::Error for LcpError {}

/// One contact problem, borrowed from wherever it lives (a contact frame, a scratch buffer).
#[derive(Debug, Clone, Copy)]
pub struct Problem<'a> {
    /// W, row-major with stride [`MAX_ROWS`], m/(N·s); at least `(rows-1)·MAX_ROWS + rows` long.
    pub compliance: &'a [f64],
    /// δ_free per row, m (negative = interpenetration).
    pub free_violation: &'a [f64],
    /// Coulomb friction coefficient (0 = frictionless).
    pub friction_mu: f64,
    /// Active rows, 3 per contact.
    pub row_count: usize,
}

/// When to stop iterating.
#[derive(Debug, Clone, Copy)]
pub struct Settings {
    /// Maximum Gauss–Seidel sweeps over all contacts.
    pub max_iterations: u32,
    /// Stop when the relative impulse change of a sweep is at most this.
    pub tolerance: f64,
    /// Give up (keeping the best-so-far λ, which is always feasible) after this instant.
    pub deadline: Option<Instant>,
    /// Check the deadline every this many sweeps (reading the clock costs ~20 ns).
    pub deadline_check_every: u32,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            max_iterations: 100,
            tolerance: 1e-3,
            deadline: None,
            deadline_check_every: 2,
        }
    }
}

/// How a solve ended.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Solution {
    /// Sweeps performed.
    pub iterations: u32,
    /// Relative impulse change of the last sweep (see module docs).
    pub residual: f64,
    /// `residual ≤ tolerance`.
    pub converged: bool,
    /// The deadline stopped the solve before convergence.
    pub deadline_hit: bool,
    /// Contacts left out because their 3×3 diagonal block of W is not positive definite
    /// (normal compliance ≤ 0, or an indefinite block): their impulse is zero, the other
    /// contacts are solved as if they were absent.
    pub dropped_contacts: u32,
}

/// Dot product of two equal-length slices with four independent accumulators, so the
/// compiler can vectorise it (a single accumulator chain cannot be reordered).
#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f64; 4];
    let mut ca = a.chunks_exact(4);
    let mut cb = b.chunks_exact(4);
    for (x, y) in (&mut ca).zip(&mut cb) {
        acc[0] += x[0] * y[0];
        acc[1] += x[1] * y[1];
        acc[2] += x[2] * y[2];
        acc[3] += x[3] * y[3];
    }
    let mut tail = 0.0;
    for (x, y) in ca.remainder().iter().zip(cb.remainder()) {
        tail += x * y;
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

/// Solves the contact LCP in place: `lambda` holds the warm start on entry (non-finite
/// entries are reset to 0, the rest projected onto the friction cone) and the solution on
/// exit. Only the first `row_count` entries of `lambda` are touched.
pub fn solve(
    problem: &Problem<'_>,
    lambda: &mut [f64],
    settings: &Settings,
) -> Result<Solution, LcpError> {
    let rows = problem.row_count;
    if rows > MAX_ROWS || !rows.is_multiple_of(ROWS_PER_CONTACT) {
        return Err(LcpError::RowCount { rows });
    }
    if !(settings.tolerance.is_finite() && settings.tolerance >= 0.0) {
        return Err(LcpError::Settings {
            detail: "tolerance must be finite and ≥ 0",
        });
    }
    if rows == 0 {
        return Ok(Solution {
            converged: true,
            ..Solution::default()
        });
    }
    let w_needed = (rows - 1) * MAX_ROWS + rows;
    for (what, len, needed) in [
        ("compliance", problem.compliance.len(), w_needed),
        ("free violation", problem.free_violation.len(), rows),
        ("lambda", lambda.len(), rows),
    ] {
        if len < needed {
            zero(lambda, rows);
            return Err(LcpError::SliceTooShort { what, len, needed });
        }
    }
    let mu = problem.friction_mu;
    if !(mu.is_finite() && mu >= 0.0) {
        zero(lambda, rows);
        return Err(LcpError::Friction { mu });
    }
    let w = problem.compliance;
    let dfree = problem.free_violation;
    let contacts = rows / ROWS_PER_CONTACT;

    // A contact whose own block cannot be solved (not positive definite) is dropped, not
    // the whole problem: one bad contact (often a separated one) must not cost every other
    // contact its force.
    let mut dropped = [false; MAX_CONTACTS];
    let mut dropped_contacts = 0u32;
    for (k, d) in dropped[..contacts].iter_mut().enumerate() {
        let block = block_at(w, 3 * k);
        if block.iter().flatten().all(|v| v.is_finite()) && !block_usable(&block, mu) {
            *d = true;
            dropped_contacts += 1;
        }
    }

    // Warm start: must be finite and feasible, otherwise the first sweep's "others'
    // contribution" would carry garbage.
    for k in 0..contacts {
        let l = &mut lambda[3 * k..3 * k + 3];
        if dropped[k] || !l.iter().all(|v| v.is_finite()) || l[0] <= 0.0 {
            l.fill(0.0);
            continue;
        }
        project_cone(l, mu);
    }

    // Current violation δ = δ_free + W λ, kept up to date as impulses change: a block whose
    // impulse does not change (a contact that stays separated) costs nothing, and a change
    // of one impulse is one row update. W is symmetric (H A⁻¹ Hᵀ), so the column of an
    // impulse is read as its (contiguous) row.
    let mut delta = [0.0f64; MAX_ROWS];
    let delta = &mut delta[..rows];
    delta.copy_from_slice(&dfree[..rows]);
    for (j, &l) in lambda[..rows].iter().enumerate() {
        if l != 0.0 {
            axpy(l, &w[j * MAX_ROWS..j * MAX_ROWS + rows], delta);
        }
    }

    // Every sweep reads each contact's own 3×3 block of W and, for the sticking trial, its
    // inverse. Both are constant during the solve: gather them once into contiguous memory
    // (W's rows are MAX_ROWS apart, three cache lines per block, and larger than L1 at 32
    // contacts), invert once and test finiteness once. Frictionless contacts need only W_nn.
    let mut locals = [Local::EMPTY; MAX_CONTACTS];
    for (k, local) in locals[..contacts].iter_mut().enumerate() {
        let block = block_at(w, 3 * k);
        let finite = block.iter().flatten().all(|v| v.is_finite());
        let (inv, invertible) = if mu != 0.0 {
            inverse3(&block)
        } else {
            ([[0.0; 3]; 3], false)
        };
        let lift = if !(finite && block[0][0] > 0.0) {
            [f64::NAN; 3]
        } else if mu == 0.0 {
            [1.0 / block[0][0], 0.0, 0.0]
        } else if invertible {
            inv[0]
        } else {
            [f64::NAN; 3]
        };
        *local = Local {
            block,
            inv,
            invertible,
            finite,
            lift,
        };
    }

    let check_every = settings.deadline_check_every.max(1);
    let mut solution = Solution {
        dropped_contacts,
        ..Solution::default()
    };
    for iteration in 1..=settings.max_iterations {
        let mut max_change = 0.0f64;
        let mut max_lambda = 0.0f64;
        for (k, local) in locals[..contacts].iter().enumerate() {
            if dropped[k] {
                continue;
            }
            let r = 3 * k;
            let block = &local.block;
            let old = [lambda[r], lambda[r + 1], lambda[r + 2]];
            if old == [0.0; 3] {
                // A contact without impulse that stays separated changes nothing: most of a
                // sweep over a patch whose probe lifts most points off. Decided by the same
                // normal trial as the block solve below (there `others` is δ); anything else
                // (an impulse, a non-finite trial, which the full path rejects) goes there.
                let l = &local.lift;
                let trial = -(l[0] * delta[r] + l[1] * delta[r + 1] + l[2] * delta[r + 2]);
                if (f64::MIN..=0.0).contains(&trial) {
                    continue;
                }
            }
            // Violation this contact would have with its own impulse removed.
            let mut others = [0.0; 3];
            for c in 0..3 {
                others[c] = delta[r + c]
                    - (block[c][0] * old[0] + block[c][1] * old[1] + block[c][2] * old[2]);
            }
            // Non-finite input reaches the solver through the violation or this block (a
            // non-finite W entry of an impulse that changes poisons δ on the next block).
            let finite = others.iter().all(|v| v.is_finite()) && local.finite;
            if !finite {
                zero(lambda, rows);
                return Err(LcpError::NonFinite {
                    row: r + others.iter().position(|v| !v.is_finite()).unwrap_or(0),
                });
            }
            let inv = local.invertible.then_some(&local.inv);
            let new = solve_block(block, inv, &others, mu)
                .ok_or(LcpError::DegenerateBlock { contact: k });
            let new = match new {
                Ok(v) => v,
                Err(e) => {
                    zero(lambda, rows);
                    return Err(e);
                }
            };
            let change = [new[0] - old[0], new[1] - old[1], new[2] - old[2]];
            if change[1] == 0.0 && change[2] == 0.0 {
                // Frictionless or tangentially unchanged: one row.
                if change[0] != 0.0 {
                    axpy(change[0], &w[r * MAX_ROWS..r * MAX_ROWS + rows], delta);
                }
            } else {
                axpy3(
                    change,
                    &w[r * MAX_ROWS..r * MAX_ROWS + rows],
                    &w[(r + 1) * MAX_ROWS..(r + 1) * MAX_ROWS + rows],
                    &w[(r + 2) * MAX_ROWS..(r + 2) * MAX_ROWS + rows],
                    delta,
                );
            }
            for c in 0..3 {
                max_change = max_change.max(change[c].abs());
                max_lambda = max_lambda.max(new[c].abs());
                lambda[r + c] = new[c];
            }
        }
        solution.iterations = iteration;
        solution.residual = if max_change == 0.0 {
            0.0
        } else {
            max_change / max_lambda.max(LAMBDA_FLOOR)
        };
        if solution.residual <= settings.tolerance {
            solution.converged = true;
            return Ok(solution);
        }
        if let Some(deadline) = settings.deadline {
            if iteration % check_every == 0 && Instant::now() >= deadline {
                solution.deadline_hit = true;
                return Ok(solution);
            }
        }
    }
    Ok(solution)
}

/// The CPU has AVX2 and FMA (std caches the detection).
#[cfg(target_arch = "x86_64")]
#[inline]
fn avx2_fma() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

/// y += a·x. The hot kernel of the sweep (≤ 96 entries): with AVX2 and FMA when the CPU has
/// them (checked once, cached by std), portable otherwise.
#[inline]
fn axpy(a: f64, x: &[f64], y: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    {
        if avx2_fma() {
            // SAFETY: the features this function is compiled for were just detected.
            unsafe { axpy_avx2_fma(a, x, y) };
            return;
        }
    }
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi += a * xi;
    }
}

/// y += a[0]·x0 + a[1]·x1 + a[2]·x2 in one pass over y (a contact's three rows).
#[inline]
fn axpy3(a: [f64; 3], x0: &[f64], x1: &[f64], x2: &[f64], y: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    {
        if avx2_fma() {
            // SAFETY: the features this function is compiled for were just detected.
            unsafe { axpy3_avx2_fma(a, x0, x1, x2, y) };
            return;
        }
    }
    for (((yi, u), v), w) in y.iter_mut().zip(x0).zip(x1).zip(x2) {
        *yi += a[0] * u + a[1] * v + a[2] * w;
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn axpy3_avx2_fma(a: [f64; 3], x0: &[f64], x1: &[f64], x2: &[f64], y: &mut [f64]) {
    for (((yi, u), v), w) in y.iter_mut().zip(x0).zip(x1).zip(x2) {
        *yi = a[2].mul_add(*w, a[1].mul_add(*v, a[0].mul_add(*u, *yi)));
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn axpy_avx2_fma(a: f64, x: &[f64], y: &mut [f64]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi = a.mul_add(*xi, *yi);
    }
}

fn zero(lambda: &mut [f64], rows: usize) {
    let n = rows.min(lambda.len());
    lambda[..n].fill(0.0);
}

/// Scales the tangential impulse into the cone |λt| ≤ μ λn (λn ≥ 0 assumed).
#[inline]
fn project_cone(l: &mut [f64], mu: f64) {
    let limit = mu * l[0];
    let t = (l[1] * l[1] + l[2] * l[2]).sqrt();
    if t > limit && t > 0.0 {
        let s = limit / t;
        l[1] *= s;
        l[2] *= s;
    }
}

/// What a sweep needs of one contact besides δ and λ, constant during a solve.
#[derive(Clone, Copy)]
struct Local {
    /// The contact's 3×3 diagonal block of W.
    block: [[f64; 3]; 3],
    /// Its inverse, valid when `invertible` (only computed with friction).
    inv: [[f64; 3]; 3],
    invertible: bool,
    /// Every entry of `block` is finite.
    finite: bool,
    /// The normal impulse this contact takes when it has none is −lift·δ (`inv[0]`, or
    /// 1/W_nn without friction); NaN where the block solve does not decide it that way.
    lift: [f64; 3],
}

impl Local {
    /// All zero (a plain memset): a placeholder for the contacts beyond the problem's.
    const EMPTY: Local = Local {
        block: [[0.0; 3]; 3],
        inv: [[0.0; 3]; 3],
        invertible: false,
        finite: false,
        lift: [0.0; 3],
    };
}

/// A finite contact block the solver can use: positive normal compliance and, with friction,
/// positive semi-definite (every principal minor ≥ 0 up to rounding; a singular tangential
/// part is solved row-wise). An indefinite block would let Gauss–Seidel grow the impulse
/// without bound.
fn block_usable(b: &[[f64; 3]; 3], mu: f64) -> bool {
    if !(b[0][0] > 0.0) {
        return false;
    }
    if mu == 0.0 {
        return true;
    }
    let scale = b[0][0].abs().max(b[1][1].abs()).max(b[2][2].abs());
    let tol = 1e-9;
    let minor = |i: usize, j: usize| b[i][i] * b[j][j] - b[i][j] * b[j][i];
    let det = b[0][0] * (b[1][1] * b[2][2] - b[1][2] * b[2][1])
        - b[0][1] * (b[1][0] * b[2][2] - b[1][2] * b[2][0])
        + b[0][2] * (b[1][0] * b[2][1] - b[1][1] * b[2][0]);
    b[1][1] >= -tol * scale
        && b[2][2] >= -tol * scale
        && minor(0, 1) >= -tol * scale * scale
        && minor(0, 2) >= -tol * scale * scale
        && minor(1, 2) >= -tol * scale * scale
        && det >= -tol * scale * scale * scale
}

/// The 3×3 diagonal block of contact rows r..r+3.
#[inline]
fn block_at(w: &[f64], r: usize) -> [[f64; 3]; 3] {
    [
        [
            w[r * MAX_ROWS + r],
            w[r * MAX_ROWS + r + 1],
            w[r * MAX_ROWS + r + 2],
        ],
        [
            w[(r + 1) * MAX_ROWS + r],
            w[(r + 1) * MAX_ROWS + r + 1],
            w[(r + 1) * MAX_ROWS + r + 2],
        ],
        [
            w[(r + 2) * MAX_ROWS + r],
            w[(r + 2) * MAX_ROWS + r + 1],
            w[(r + 2) * MAX_ROWS + r + 2],
        ],
    ]
}

/// One contact: the impulse that makes `others + B λ` satisfy the contact law.
/// `None` when the block cannot be solved (non-positive normal compliance, singular block).
/// `inv`: the block's inverse when it has one (None: singular, solved row-wise).
#[inline]
fn solve_block(
    b: &[[f64; 3]; 3],
    inv: Option<&[[f64; 3]; 3]>,
    others: &[f64; 3],
    mu: f64,
) -> Option<[f64; 3]> {
    let wnn = b[0][0];
    if !(wnn > 0.0) {
        return None;
    }
    if mu == 0.0 {
        // Frictionless: tangential impulses are zero, the normal is a scalar projection.
        return Some([(-others[0] / wnn).max(0.0), 0.0, 0.0]);
    }
    // Sticking trial: all three rows satisfied, δ = 0. A block whose tangential part is
    // singular (a contact on a triangle with held nodes, or a kinematic probe) falls back to
    // row-wise projection instead of failing the whole step.
    let Some(inv) = inv else {
        return Some(solve_rows(b, others, mu));
    };
    let mut stick = [0.0; 3];
    for (s, row) in stick.iter_mut().zip(inv) {
        *s = -(row[0] * others[0] + row[1] * others[1] + row[2] * others[2]);
    }
    if stick[0] <= 0.0 {
        // Would pull: separation. (δn = others_n ≥ 0 then, since B is positive definite.)
        return Some([0.0; 3]);
    }
    if (stick[1] * stick[1] + stick[2] * stick[2]).sqrt() <= mu * stick[0] {
        return Some(stick);
    }
    // Sliding: alternate normal row (with tangential fixed) and tangential 2×2 trial
    // (with normal fixed) projected onto the disc of radius μ λn.
    let det_t = b[1][1] * b[2][2] - b[1][2] * b[2][1];
    if !(det_t > 0.0) {
        return Some(solve_rows(b, others, mu));
    }
    let mut l = stick;
    project_cone(&mut l, mu);
    for _ in 0..SLIDING_PASSES {
        let prev = l;
        l[0] = (-(others[0] + b[0][1] * l[1] + b[0][2] * l[2]) / wnn).max(0.0);
        if l[0] == 0.0 {
            return Some([0.0; 3]);
        }
        let r1 = -(others[1] + b[1][0] * l[0]);
        let r2 = -(others[2] + b[2][0] * l[0]);
        l[1] = (b[2][2] * r1 - b[1][2] * r2) / det_t;
        l[2] = (b[1][1] * r2 - b[2][1] * r1) / det_t;
        project_cone(&mut l, mu);
        // The normal–tangent coupling is weak (|W_nt| μ / W_nn ≪ 1): a few passes suffice.
        let change = (l[0] - prev[0])
            .abs()
            .max((l[1] - prev[1]).abs())
            .max((l[2] - prev[2]).abs());
        if change <= 1e-14 * l[0] {
            break;
        }
    }
    Some(l)
}

/// Row-wise projected Gauss–Seidel on one contact block (normal row, then each tangent row
/// with a positive diagonal), projected onto the friction cone after each pass. Used when
/// the block cannot be solved as a whole; rows without compliance keep a zero impulse.
/// Requires `b[0][0] > 0` (checked by the caller).
fn solve_rows(b: &[[f64; 3]; 3], others: &[f64; 3], mu: f64) -> [f64; 3] {
    let mut l = [0.0; 3];
    for _ in 0..SLIDING_PASSES {
        let prev = l;
        l[0] = (-(others[0] + b[0][1] * l[1] + b[0][2] * l[2]) / b[0][0]).max(0.0);
        for t in 1..3 {
            let u = 3 - t;
            l[t] = if b[t][t] > 0.0 {
                -(others[t] + b[t][0] * l[0] + b[t][u] * l[u]) / b[t][t]
            } else {
                0.0
            };
        }
        project_cone(&mut l, mu);
        let change = (l[0] - prev[0])
            .abs()
            .max((l[1] - prev[1]).abs())
            .max((l[2] - prev[2]).abs());
        if change <= 1e-14 * l[0].max(f64::MIN_POSITIVE) {
            break;
        }
    }
    l
}

/// Inverse of a 3×3 matrix (adjugate over determinant); `None` when singular or not finite.
#[cfg(test)]
fn invert3(a: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let (inv, ok) = inverse3(a);
    ok.then_some(inv)
}

/// [`invert3`] without branches: the adjugate over the determinant and whether it is the
/// inverse (the determinant nonzero and every entry finite).
#[inline(always)]
fn inverse3(a: &[[f64; 3]; 3]) -> ([[f64; 3]; 3], bool) {
    let c00 = a[1][1] * a[2][2] - a[1][2] * a[2][1];
    let c01 = a[1][2] * a[2][0] - a[1][0] * a[2][2];
    let c02 = a[1][0] * a[2][1] - a[1][1] * a[2][0];
    let det = a[0][0] * c00 + a[0][1] * c01 + a[0][2] * c02;
    let d = 1.0 / det;
    let inv = [
        [
            c00 * d,
            (a[0][2] * a[2][1] - a[0][1] * a[2][2]) * d,
            (a[0][1] * a[1][2] - a[0][2] * a[1][1]) * d,
        ],
        [
            c01 * d,
            (a[0][0] * a[2][2] - a[0][2] * a[2][0]) * d,
            (a[0][2] * a[1][0] - a[0][0] * a[1][2]) * d,
        ],
        [
            c02 * d,
            (a[0][1] * a[2][0] - a[0][0] * a[2][1]) * d,
            (a[0][0] * a[1][1] - a[0][1] * a[1][0]) * d,
        ],
    ];
    let ok = det.abs() > 0.0 && det.is_finite() && inv.iter().flatten().all(|v| v.is_finite());
    (inv, ok)
}

/// Violation δ = δ_free + W λ for the first `rows` rows, written to `out` (for checks and
/// diagnostics; not used by the solver).
pub fn violation(problem: &Problem<'_>, lambda: &[f64], out: &mut [f64]) {
    let rows = problem.row_count.min(out.len());
    for (i, o) in out.iter_mut().enumerate().take(rows) {
        *o = problem.free_violation[i]
            + dot(
                &problem.compliance[i * MAX_ROWS..i * MAX_ROWS + problem.row_count],
                &lambda[..problem.row_count],
            );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn empty_w() -> Vec<f64> {
        vec![0.0; MAX_ROWS * MAX_ROWS]
    }

    fn set(w: &mut [f64], i: usize, j: usize, v: f64) {
        w[i * MAX_ROWS + j] = v;
    }

    fn tight() -> Settings {
        Settings {
            max_iterations: 500,
            tolerance: 1e-12,
            ..Settings::default()
        }
    }

    /// A diagonal single-contact block.
    fn single(wn: f64, wt: f64) -> Vec<f64> {
        let mut w = empty_w();
        set(&mut w, 0, 0, wn);
        set(&mut w, 1, 1, wt);
        set(&mut w, 2, 2, wt);
        w
    }

    #[test]
    fn one_frictionless_contact_matches_closed_form() {
        let wn = 2.5e-3;
        let w = single(wn, 1e-3);
        for dn in [-1e-3, -4e-4, 0.0, 3e-4] {
            let dfree = [dn, 1e-4, -2e-4];
            let mut lambda = [0.0; 3];
            let p = Problem {
                compliance: &w,
                free_violation: &dfree,
                friction_mu: 0.0,
                row_count: 3,
            };
            let s = solve(&p, &mut lambda, &tight()).unwrap();
            assert!(s.converged);
            let expected = (-dn / wn).max(0.0);
            assert!(
                (lambda[0] - expected).abs() < 1e-12,
                "dn {dn}: {} vs {expected}",
                lambda[0]
            );
            assert_eq!(lambda[1], 0.0);
            assert_eq!(lambda[2], 0.0);
        }
    }

    #[test]
    fn separation_gives_zero_impulse_even_from_a_bad_warm_start() {
        let w = single(1e-3, 1e-3);
        let dfree = [2e-4, 0.0, 0.0];
        let mut lambda = [0.7, 0.3, 0.1];
        let p = Problem {
            compliance: &w,
            free_violation: &dfree,
            friction_mu: 0.5,
            row_count: 3,
        };
        let s = solve(&p, &mut lambda, &tight()).unwrap();
        assert!(s.converged);
        assert_eq!(lambda, [0.0; 3]);
    }

    /// Two frictionless contacts coupled through W: normals rows 0 and 3,
    /// W_n = [[a, c], [c, b]], solved by hand.
    fn two_contacts(a: f64, b: f64, c: f64) -> Vec<f64> {
        let mut w = empty_w();
        for k in 0..2 {
            for t in 1..3 {
                set(&mut w, 3 * k + t, 3 * k + t, 1.0);
            }
        }
        set(&mut w, 0, 0, a);
        set(&mut w, 3, 3, b);
        set(&mut w, 0, 3, c);
        set(&mut w, 3, 0, c);
        w
    }

    /// One contact with W_nn ≤ 0 (or an indefinite friction block) drops that contact; the
    /// other is solved as if it were alone (closed form λ = −δ/W_nn).
    #[test]
    fn a_degenerate_contact_block_drops_that_contact_only() {
        for (bad_wnn, bad_t_coupling, mu) in [(0.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (1.0, 3.0, 0.4)] {
            let mut w = two_contacts(2.0, bad_wnn, 0.0);
            // Contact 1: indefinite with friction when its normal couples strongly to a tangent.
            set(&mut w, 3, 4, bad_t_coupling);
            set(&mut w, 4, 3, bad_t_coupling);
            let dfree = [-1.0, 0.0, 0.0, -2.0, 0.0, 0.0];
            let mut lambda = [0.0, 0.0, 0.0, 5.0, 0.0, 0.0];
            let p = Problem {
                compliance: &w,
                free_violation: &dfree,
                friction_mu: mu,
                row_count: 6,
            };
            let s = solve(&p, &mut lambda, &tight()).unwrap();
            assert_eq!(
                s.dropped_contacts, 1,
                "W_nn {bad_wnn}, W_nt {bad_t_coupling}"
            );
            assert!((lambda[0] - 0.5).abs() < 1e-12, "{lambda:?}");
            assert_eq!(&lambda[3..], &[0.0; 3]);
        }
    }

    #[test]
    fn two_coupled_contacts_both_active() {
        // [2 1; 1 3] λ = -[-1, -2]  →  det 5, λ1 = (3·1 − 1·2)/5 = 0.2, λ2 = (2·2 − 1·1)/5 = 0.6.
        let w = two_contacts(2.0, 3.0, 1.0);
        let dfree = [-1.0, 0.0, 0.0, -2.0, 0.0, 0.0];
        let mut lambda = [0.0; 6];
        let p = Problem {
            compliance: &w,
            free_violation: &dfree,
            friction_mu: 0.0,
            row_count: 6,
        };
        let s = solve(&p, &mut lambda, &tight()).unwrap();
        assert!(s.converged, "{s:?}");
        assert!((lambda[0] - 0.2).abs() < 1e-9, "{lambda:?}");
        assert!((lambda[3] - 0.6).abs() < 1e-9, "{lambda:?}");
        let mut d = [0.0; 6];
        violation(&p, &lambda, &mut d);
        assert!(d[0].abs() < 1e-9 && d[3].abs() < 1e-9);
    }

    #[test]
    fn two_coupled_contacts_one_lifts_off() {
        // dfree = [-1, -5]: the unconstrained solution gives λ1 = (3·1 − 1·5)/5 < 0, so contact 1
        // separates: λ1 = 0, λ2 = 5/3, δ1 = −1 + 5/3 = 2/3 ≥ 0.
        let w = two_contacts(2.0, 3.0, 1.0);
        let dfree = [-1.0, 0.0, 0.0, -5.0, 0.0, 0.0];
        let mut lambda = [0.0; 6];
        let p = Problem {
            compliance: &w,
            free_violation: &dfree,
            friction_mu: 0.0,
            row_count: 6,
        };
        let s = solve(&p, &mut lambda, &tight()).unwrap();
        assert!(s.converged);
        assert_eq!(lambda[0], 0.0);
        assert!((lambda[3] - 5.0 / 3.0).abs() < 1e-9);
        let mut d = [0.0; 6];
        violation(&p, &lambda, &mut d);
        assert!((d[0] - 2.0 / 3.0).abs() < 1e-9);
    }

    #[test]
    fn friction_sticks_inside_the_cone() {
        // λn = 1e-3/1e-3 = 1; stick λt = −2e-4/2e-3 = −0.1; |λt| = 0.1 ≤ μ λn = 0.3 → stick.
        let w = single(1e-3, 2e-3);
        let dfree = [-1e-3, 2e-4, 0.0];
        let mut lambda = [0.0; 3];
        let p = Problem {
            compliance: &w,
            free_violation: &dfree,
            friction_mu: 0.3,
            row_count: 3,
        };
        let s = solve(&p, &mut lambda, &tight()).unwrap();
        assert!(s.converged);
        assert!((lambda[0] - 1.0).abs() < 1e-12);
        assert!((lambda[1] + 0.1).abs() < 1e-12);
        assert!(lambda[2].abs() < 1e-15);
        let mut d = [0.0; 3];
        violation(&p, &lambda, &mut d);
        assert!(
            d.iter().all(|v| v.abs() < 1e-15),
            "sticking means no slip: {d:?}"
        );
    }

    #[test]
    fn friction_slides_on_the_cone_boundary_opposing_slip() {
        // λn = 1; stick would need λt = −(0.3, 0.4), |λt| = 0.5 > μ λn = 0.2 → slide.
        let w = single(1e-3, 2e-3);
        let dfree = [-1e-3, 6e-4, 8e-4]; // slip direction (0.6, 0.8)
        let mut lambda = [0.0; 3];
        let p = Problem {
            compliance: &w,
            free_violation: &dfree,
            friction_mu: 0.2,
            row_count: 3,
        };
        let s = solve(&p, &mut lambda, &tight()).unwrap();
        assert!(s.converged);
        assert!((lambda[0] - 1.0).abs() < 1e-12);
        assert!((lambda[1] + 0.2 * 0.6).abs() < 1e-12, "{lambda:?}");
        assert!((lambda[2] + 0.2 * 0.8).abs() < 1e-12, "{lambda:?}");
        let mut d = [0.0; 3];
        violation(&p, &lambda, &mut d);
        // Still slipping in the same direction, friction opposes it.
        assert!(d[1] > 0.0 && d[2] > 0.0);
        assert!(
            (d[1] * lambda[2] - d[2] * lambda[1]).abs() < 1e-15,
            "anti-parallel"
        );
    }

    #[test]
    fn coupled_block_sliding_keeps_normal_satisfied_and_tangent_on_cone() {
        // Normal–tangent coupling (an inclined compliance), isotropic tangential block.
        let mut w = single(1e-3, 2e-3);
        set(&mut w, 0, 1, 3e-4);
        set(&mut w, 1, 0, 3e-4);
        let dfree = [-1e-3, 1e-3, 0.0];
        let mut lambda = [0.0; 3];
        let mu = 0.25;
        let p = Problem {
            compliance: &w,
            free_violation: &dfree,
            friction_mu: mu,
            row_count: 3,
        };
        let s = solve(&p, &mut lambda, &tight()).unwrap();
        assert!(s.converged);
        // Hand solution: λt = −μ λn, 1e-3 λn + 3e-4 λt = 1e-3 → λn = 1e-3 / (1e-3 − 0.25·3e-4).
        let ln = 1e-3 / (1e-3 - mu * 3e-4);
        assert!((lambda[0] - ln).abs() < 1e-9, "{lambda:?} vs {ln}");
        assert!((lambda[1] + mu * ln).abs() < 1e-9);
        let mut d = [0.0; 3];
        violation(&p, &lambda, &mut d);
        assert!(d[0].abs() < 1e-12 && d[1] > 0.0);
    }

    #[test]
    fn warm_start_converges_in_one_sweep() {
        let w = two_contacts(2.0, 3.0, 1.0);
        let dfree = [-1.0, 0.0, 0.0, -2.0, 0.0, 0.0];
        let mut lambda = [0.0; 6];
        let p = Problem {
            compliance: &w,
            free_violation: &dfree,
            friction_mu: 0.0,
            row_count: 6,
        };
        solve(&p, &mut lambda, &tight()).unwrap();
        let s = solve(&p, &mut lambda, &tight()).unwrap();
        assert_eq!(s.iterations, 1);
        assert!(s.converged);
    }

    #[test]
    fn many_contacts_converge_and_respect_the_cone() {
        // 32 contacts on a strongly coupled, symmetric positive definite W (a shared
        // compliance plus a local one), with friction.
        let mut w = empty_w();
        let rows = MAX_ROWS;
        for i in 0..rows {
            for j in 0..rows {
                let shared = if i % 3 == 0 && j % 3 == 0 { 2e-4 } else { 0.0 };
                w[i * MAX_ROWS + j] = shared + if i == j { 1e-3 } else { 0.0 };
            }
        }
        let mut dfree = [0.0; MAX_ROWS];
        for k in 0..MAX_CONTACTS {
            dfree[3 * k] = -1e-4 * (1.0 + (k % 5) as f64);
            dfree[3 * k + 1] = 2e-5 * ((k % 3) as f64 - 1.0);
            dfree[3 * k + 2] = 1e-5 * ((k % 4) as f64 - 1.5);
        }
        let mut lambda = [0.0; MAX_ROWS];
        let p = Problem {
            compliance: &w,
            free_violation: &dfree,
            friction_mu: 0.3,
            row_count: rows,
        };
        let s = solve(
            &p,
            &mut lambda,
            &Settings {
                max_iterations: 2000,
                tolerance: 1e-9,
                ..Settings::default()
            },
        )
        .unwrap();
        assert!(s.converged, "{s:?}");
        let mut d = [0.0; MAX_ROWS];
        violation(&p, &lambda, &mut d);
        for k in 0..MAX_CONTACTS {
            let (ln, t1, t2) = (lambda[3 * k], lambda[3 * k + 1], lambda[3 * k + 2]);
            assert!(ln >= 0.0);
            assert!((t1 * t1 + t2 * t2).sqrt() <= 0.3 * ln + 1e-12);
            assert!(d[3 * k] > -1e-9, "no interpenetration left");
            // Complementarity: either separated with no force or in contact.
            assert!(
                ln == 0.0 || d[3 * k].abs() < 1e-8,
                "contact {k}: λn {ln} δn {}",
                d[3 * k]
            );
        }
    }

    /// Regression: with friction, a contact whose tangential compliance is singular (a
    /// kinematic probe on a triangle with held nodes) failed the whole step with
    /// "diagonal compliance block … is not positive definite".
    #[test]
    fn friction_with_singular_tangent_block_solves_the_normal_row() {
        let wn = 2.0e-3;
        let w = single(wn, 0.0);
        let dfree = [-1e-3, 2e-4, 0.0];
        let mut lambda = [0.0; 3];
        let p = Problem {
            compliance: &w,
            free_violation: &dfree,
            friction_mu: 0.3,
            row_count: 3,
        };
        let out = solve(&p, &mut lambda, &tight()).expect("solvable normal row");
        assert!(out.converged);
        assert!(
            (lambda[0] - 1e-3 / wn).abs() < 1e-12,
            "λn = −δn/Wnn, got {}",
            lambda[0]
        );
        assert_eq!(
            lambda[1], 0.0,
            "a row without compliance carries no impulse"
        );
        assert_eq!(lambda[2], 0.0);
    }

    #[test]
    fn non_finite_and_degenerate_input_is_rejected() {
        let p_ok = single(1e-3, 1e-3);
        let dfree = [f64::NAN, 0.0, 0.0];
        let mut lambda = [1.0, 0.0, 0.0];
        let p = Problem {
            compliance: &p_ok,
            free_violation: &dfree,
            friction_mu: 0.0,
            row_count: 3,
        };
        assert_eq!(
            solve(&p, &mut lambda, &tight()),
            Err(LcpError::NonFinite { row: 0 })
        );
        assert_eq!(lambda, [0.0; 3], "λ is zeroed on error");

        let mut w = single(1e-3, 1e-3);
        set(&mut w, 2, 1, f64::INFINITY);
        let dfree = [-1e-3, 0.0, 0.0];
        let p = Problem {
            compliance: &w,
            free_violation: &dfree,
            friction_mu: 0.2,
            row_count: 3,
        };
        assert!(matches!(
            solve(&p, &mut lambda, &tight()),
            Err(LcpError::NonFinite { .. })
        ));

        let zero_w = empty_w();
        let p = Problem {
            compliance: &zero_w,
            free_violation: &dfree,
            friction_mu: 0.0,
            row_count: 3,
        };
        // A zero block is dropped (no impulse), not an error.
        lambda = [1.0, 0.0, 0.0];
        let s = solve(&p, &mut lambda, &tight()).unwrap();
        assert_eq!(s.dropped_contacts, 1);
        assert_eq!(lambda, [0.0; 3]);

        let p = Problem {
            compliance: &p_ok,
            free_violation: &dfree,
            friction_mu: f64::NAN,
            row_count: 3,
        };
        assert!(matches!(
            solve(&p, &mut lambda, &tight()),
            Err(LcpError::Friction { .. })
        ));

        let p = Problem {
            compliance: &p_ok,
            free_violation: &dfree,
            friction_mu: 0.0,
            row_count: 4,
        };
        assert_eq!(
            solve(&p, &mut lambda, &tight()),
            Err(LcpError::RowCount { rows: 4 })
        );

        let p = Problem {
            compliance: &p_ok[..10],
            free_violation: &dfree,
            friction_mu: 0.0,
            row_count: 3,
        };
        assert!(matches!(
            solve(&p, &mut lambda, &tight()),
            Err(LcpError::SliceTooShort {
                what: "compliance",
                ..
            })
        ));
    }

    #[test]
    fn nan_warm_start_is_discarded() {
        let w = single(2e-3, 1e-3);
        let dfree = [-1e-3, 0.0, 0.0];
        let mut lambda = [f64::NAN, 0.0, 0.0];
        let p = Problem {
            compliance: &w,
            free_violation: &dfree,
            friction_mu: 0.0,
            row_count: 3,
        };
        solve(&p, &mut lambda, &tight()).unwrap();
        assert!((lambda[0] - 0.5).abs() < 1e-12);
    }

    #[test]
    fn iteration_cap_and_deadline_stop_early_with_a_feasible_answer() {
        let w = two_contacts(2.0, 3.0, 1.95);
        let dfree = [-1.0, 0.0, 0.0, -2.0, 0.0, 0.0];
        let mut lambda = [0.0; 6];
        let p = Problem {
            compliance: &w,
            free_violation: &dfree,
            friction_mu: 0.0,
            row_count: 6,
        };
        let s = solve(
            &p,
            &mut lambda,
            &Settings {
                max_iterations: 2,
                tolerance: 1e-12,
                ..Settings::default()
            },
        )
        .unwrap();
        assert_eq!(s.iterations, 2);
        assert!(!s.converged);
        assert!(lambda[0] >= 0.0 && lambda[3] >= 0.0);

        let mut lambda = [0.0; 6];
        let s = solve(
            &p,
            &mut lambda,
            &Settings {
                max_iterations: 1_000_000,
                tolerance: 0.0,
                deadline: Some(Instant::now()),
                deadline_check_every: 1,
            },
        )
        .unwrap();
        assert!(s.deadline_hit);
        assert_eq!(s.iterations, 1);
    }

    #[test]
    fn block_inverse_inverts_and_refuses_singular_blocks() {
        let a = [[2.0, 0.3, -0.1], [0.3, 1.5, 0.2], [-0.1, 0.2, 1.1]];
        let inv = invert3(&a).unwrap();
        for i in 0..3 {
            for j in 0..3 {
                let v: f64 = (0..3).map(|k| a[i][k] * inv[k][j]).sum();
                assert!((v - (i == j) as u8 as f64).abs() < 1e-14, "{i}{j}: {v}");
            }
        }
        assert!(invert3(&[[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).is_none());
        assert!(invert3(&[[f64::NAN, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).is_none());
    }

    /// The sweep as it was before the per-solve gathering and the separation shortcut (one
    /// block read from W, one full block solve per contact and sweep): optimisations of
    /// [`solve`] must reproduce it.
    #[allow(clippy::manual_is_multiple_of, clippy::neg_cmp_op_on_partial_ord)]
    mod reference {
        use super::super::*;

        pub fn reference_solve(
            problem: &Problem<'_>,
            lambda: &mut [f64],
            settings: &Settings,
        ) -> Result<Solution, LcpError> {
            let rows = problem.row_count;
            if rows > MAX_ROWS || rows % ROWS_PER_CONTACT != 0 {
                return Err(LcpError::RowCount { rows });
            }
            if !(settings.tolerance.is_finite() && settings.tolerance >= 0.0) {
                return Err(LcpError::Settings {
                    detail: "tolerance must be finite and ≥ 0",
                });
            }
            if rows == 0 {
                return Ok(Solution {
                    converged: true,
                    ..Solution::default()
                });
            }
            let w_needed = (rows - 1) * MAX_ROWS + rows;
            for (what, len, needed) in [
                ("compliance", problem.compliance.len(), w_needed),
                ("free violation", problem.free_violation.len(), rows),
                ("lambda", lambda.len(), rows),
            ] {
                if len < needed {
                    zero(lambda, rows);
                    return Err(LcpError::SliceTooShort { what, len, needed });
                }
            }
            let mu = problem.friction_mu;
            if !(mu.is_finite() && mu >= 0.0) {
                zero(lambda, rows);
                return Err(LcpError::Friction { mu });
            }
            let w = problem.compliance;
            let dfree = problem.free_violation;
            let contacts = rows / ROWS_PER_CONTACT;

            // Warm start: must be finite and feasible, otherwise the first sweep's "others'
            // contribution" would carry garbage.
            for k in 0..contacts {
                let l = &mut lambda[3 * k..3 * k + 3];
                if !l.iter().all(|v| v.is_finite()) || l[0] <= 0.0 {
                    l.fill(0.0);
                    continue;
                }
                project_cone(l, mu);
            }

            // Current violation δ = δ_free + W λ, kept up to date as impulses change: a block whose
            // impulse does not change (a contact that stays separated) costs nothing, and a change
            // of one impulse is one row update. W is symmetric (H A⁻¹ Hᵀ), so the column of an
            // impulse is read as its (contiguous) row.
            let mut delta = [0.0f64; MAX_ROWS];
            let delta = &mut delta[..rows];
            delta.copy_from_slice(&dfree[..rows]);
            for (j, &l) in lambda[..rows].iter().enumerate() {
                if l != 0.0 {
                    axpy(l, &w[j * MAX_ROWS..j * MAX_ROWS + rows], delta);
                }
            }

            // The sticking trial of every sweep solves with the contact's own 3×3 block: invert each
            // block once per solve instead of once per sweep (the block solve, not the row updates,
            // dominated a 32-contact sweep). Frictionless contacts need only W_nn.
            let mut inverses = [[[0.0f64; 3]; 3]; MAX_CONTACTS];
            let mut invertible = [false; MAX_CONTACTS];
            if mu != 0.0 {
                for k in 0..contacts {
                    let r = 3 * k;
                    let block = block_at(w, r);
                    if let Some(inv) = invert3(&block) {
                        inverses[k] = inv;
                        invertible[k] = true;
                    }
                }
            }

            let check_every = settings.deadline_check_every.max(1);
            let mut solution = Solution::default();
            for iteration in 1..=settings.max_iterations {
                let mut max_change = 0.0f64;
                let mut max_lambda = 0.0f64;
                for k in 0..contacts {
                    let r = 3 * k;
                    let block = block_at(w, r);
                    let old = [lambda[r], lambda[r + 1], lambda[r + 2]];
                    // Violation this contact would have with its own impulse removed.
                    let mut others = [0.0; 3];
                    for c in 0..3 {
                        others[c] = delta[r + c]
                            - (block[c][0] * old[0] + block[c][1] * old[1] + block[c][2] * old[2]);
                    }
                    // Non-finite input reaches the solver through the violation or this block (a
                    // non-finite W entry of an impulse that changes poisons δ on the next block).
                    let finite = others.iter().all(|v| v.is_finite())
                        && block.iter().flatten().all(|v| v.is_finite());
                    if !finite {
                        zero(lambda, rows);
                        return Err(LcpError::NonFinite {
                            row: r + others.iter().position(|v| !v.is_finite()).unwrap_or(0),
                        });
                    }
                    let inv = invertible[k].then_some(&inverses[k]);
                    let new = reference_block(&block, inv, &others, mu)
                        .ok_or(LcpError::DegenerateBlock { contact: k });
                    let new = match new {
                        Ok(v) => v,
                        Err(e) => {
                            zero(lambda, rows);
                            return Err(e);
                        }
                    };
                    let change = [new[0] - old[0], new[1] - old[1], new[2] - old[2]];
                    if change[1] == 0.0 && change[2] == 0.0 {
                        // Frictionless or tangentially unchanged: one row.
                        if change[0] != 0.0 {
                            axpy(change[0], &w[r * MAX_ROWS..r * MAX_ROWS + rows], delta);
                        }
                    } else {
                        axpy3(
                            change,
                            &w[r * MAX_ROWS..r * MAX_ROWS + rows],
                            &w[(r + 1) * MAX_ROWS..(r + 1) * MAX_ROWS + rows],
                            &w[(r + 2) * MAX_ROWS..(r + 2) * MAX_ROWS + rows],
                            delta,
                        );
                    }
                    for c in 0..3 {
                        max_change = max_change.max(change[c].abs());
                        max_lambda = max_lambda.max(new[c].abs());
                        lambda[r + c] = new[c];
                    }
                }
                solution.iterations = iteration;
                solution.residual = if max_change == 0.0 {
                    0.0
                } else {
                    max_change / max_lambda.max(LAMBDA_FLOOR)
                };
                if solution.residual <= settings.tolerance {
                    solution.converged = true;
                    return Ok(solution);
                }
                if let Some(deadline) = settings.deadline {
                    if iteration % check_every == 0 && Instant::now() >= deadline {
                        solution.deadline_hit = true;
                        return Ok(solution);
                    }
                }
            }
            Ok(solution)
        }

        fn reference_block(
            b: &[[f64; 3]; 3],
            inv: Option<&[[f64; 3]; 3]>,
            others: &[f64; 3],
            mu: f64,
        ) -> Option<[f64; 3]> {
            let wnn = b[0][0];
            if !(wnn > 0.0) {
                return None;
            }
            if mu == 0.0 {
                // Frictionless: tangential impulses are zero, the normal is a scalar projection.
                return Some([(-others[0] / wnn).max(0.0), 0.0, 0.0]);
            }
            // Sticking trial: all three rows satisfied, δ = 0. A block whose tangential part is
            // singular (a contact on a triangle with held nodes, or a kinematic probe) falls back to
            // row-wise projection instead of failing the whole step.
            let Some(inv) = inv else {
                return Some(solve_rows(b, others, mu));
            };
            let mut stick = [0.0; 3];
            for (s, row) in stick.iter_mut().zip(inv) {
                *s = -(row[0] * others[0] + row[1] * others[1] + row[2] * others[2]);
            }
            if stick[0] <= 0.0 {
                // Would pull: separation. (δn = others_n ≥ 0 then, since B is positive definite.)
                return Some([0.0; 3]);
            }
            if (stick[1] * stick[1] + stick[2] * stick[2]).sqrt() <= mu * stick[0] {
                return Some(stick);
            }
            // Sliding: alternate normal row (with tangential fixed) and tangential 2×2 trial
            // (with normal fixed) projected onto the disc of radius μ λn.
            let det_t = b[1][1] * b[2][2] - b[1][2] * b[2][1];
            if !(det_t > 0.0) {
                return Some(solve_rows(b, others, mu));
            }
            let mut l = stick;
            project_cone(&mut l, mu);
            for _ in 0..SLIDING_PASSES {
                let prev = l;
                l[0] = (-(others[0] + b[0][1] * l[1] + b[0][2] * l[2]) / wnn).max(0.0);
                if l[0] == 0.0 {
                    return Some([0.0; 3]);
                }
                let r1 = -(others[1] + b[1][0] * l[0]);
                let r2 = -(others[2] + b[2][0] * l[0]);
                l[1] = (b[2][2] * r1 - b[1][2] * r2) / det_t;
                l[2] = (b[1][1] * r2 - b[2][1] * r1) / det_t;
                project_cone(&mut l, mu);
                // The normal–tangent coupling is weak (|W_nt| μ / W_nn ≪ 1): a few passes suffice.
                let change = (l[0] - prev[0])
                    .abs()
                    .max((l[1] - prev[1]).abs())
                    .max((l[2] - prev[2]).abs());
                if change <= 1e-14 * l[0] {
                    break;
                }
            }
            Some(l)
        }
    }

    /// A small deterministic generator (xorshift64*), uniform in [0, 1).
    struct Rng(u64);

    impl Rng {
        fn next(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
        }

        fn range(&mut self, lo: f64, hi: f64) -> f64 {
            lo + (hi - lo) * self.next()
        }
    }

    /// A random contact patch like the haptic node sees: `n` points under a probe, tissue
    /// compliance coupled over a random length, the probe's rigid compliance through the
    /// contact directions, optionally a local anisotropic / normal–tangent coupled term per
    /// contact, and now and then a contact with no tangential compliance (a held node).
    fn random_patch(rng: &mut Rng, n: usize) -> (Vec<f64>, Vec<f64>) {
        let rows = 3 * n;
        let side = rng.range(2e-4, 3e-3);
        let mut dirs = vec![[0.0f64; 3]; rows];
        let mut points = vec![[0.0f64; 2]; n];
        for k in 0..n {
            points[k] = [rng.range(0.0, side), rng.range(0.0, side)];
            let tilt = [rng.range(-0.3, 0.3), rng.range(-0.3, 0.3)];
            let l = (1.0 + tilt[0] * tilt[0] + tilt[1] * tilt[1]).sqrt();
            let nz = [tilt[0] / l, tilt[1] / l, 1.0 / l];
            // t1 ⟂ n in the x–z plane direction, t2 = n × t1.
            let a = [nz[2], 0.0, -nz[0]];
            let la = (a[0] * a[0] + a[2] * a[2]).sqrt();
            let t1 = [a[0] / la, 0.0, a[2] / la];
            let t2 = [
                nz[1] * t1[2] - nz[2] * t1[1],
                nz[2] * t1[0] - nz[0] * t1[2],
                nz[0] * t1[1] - nz[1] * t1[0],
            ];
            dirs[3 * k] = nz;
            dirs[3 * k + 1] = t1;
            dirs[3 * k + 2] = t2;
        }
        let c0 = rng.range(5e-3, 0.2);
        let length = rng.range(2e-4, 2e-3);
        let probe = rng.range(0.0, 0.05);
        let mut w = empty_w();
        for i in 0..rows {
            for j in 0..rows {
                let (pi, pj) = (points[i / 3], points[j / 3]);
                let r = ((pi[0] - pj[0]).powi(2) + (pi[1] - pj[1]).powi(2)).sqrt();
                let (di, dj) = (dirs[i], dirs[j]);
                let dot = di[0] * dj[0] + di[1] * dj[1] + di[2] * dj[2];
                let tissue = if i % 3 == j % 3 {
                    c0 * (-r / length).exp()
                } else {
                    0.0
                };
                w[i * MAX_ROWS + j] = tissue + probe * dot;
            }
        }
        for k in 0..n {
            if rng.next() < 0.4 {
                // + L Lᵀ with a random lower-triangular L: anisotropic, coupled, still PSD.
                let s = c0 * rng.range(0.0, 0.5);
                let l = [
                    [rng.range(0.0, 1.0), 0.0, 0.0],
                    [rng.range(-0.5, 0.5), rng.range(0.0, 1.0), 0.0],
                    [
                        rng.range(-0.5, 0.5),
                        rng.range(-0.5, 0.5),
                        rng.range(0.0, 1.0),
                    ],
                ];
                for a in 0..3 {
                    for b in 0..3 {
                        let v: f64 = (0..3).map(|c| l[a][c] * l[b][c]).sum();
                        w[(3 * k + a) * MAX_ROWS + 3 * k + b] += s * v;
                    }
                }
            }
            if rng.next() < 0.1 {
                for t in 1..3 {
                    let row = 3 * k + t;
                    for j in 0..rows {
                        w[row * MAX_ROWS + j] = 0.0;
                        w[j * MAX_ROWS + row] = 0.0;
                    }
                }
            }
        }
        let depth = rng.range(0.0, 4e-4);
        let mut dfree = vec![0.0; rows];
        for k in 0..n {
            dfree[3 * k] = rng.range(-depth, 2e-4);
            dfree[3 * k + 1] = rng.range(-1e-4, 1e-4);
            dfree[3 * k + 2] = rng.range(-1e-4, 1e-4);
        }
        (w, dfree)
    }

    #[test]
    fn sweeps_reproduce_the_reference_sweep_on_random_patches() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        let mut separated = 0;
        let mut sliding = 0;
        for case in 0..3000 {
            let n = 1 + (rng.next() * MAX_CONTACTS as f64) as usize;
            let rows = 3 * n;
            let (w, dfree) = random_patch(&mut rng, n);
            let mu = [0.0, 0.05, 0.2, 0.2, 0.5, 1.0][(rng.next() * 6.0) as usize];
            let p = Problem {
                compliance: &w,
                free_violation: &dfree,
                friction_mu: mu,
                row_count: rows,
            };
            let settings = Settings {
                max_iterations: [3, 50, 500][(rng.next() * 3.0) as usize],
                tolerance: [1e-3, 1e-3, 1e-6][(rng.next() * 3.0) as usize],
                ..Settings::default()
            };
            // Cold, warm from a random guess, or warm from a nearby solution.
            let mut warm = [0.0; MAX_ROWS];
            match case % 3 {
                0 => {}
                1 => {
                    for v in warm[..rows].iter_mut() {
                        *v = rng.range(-0.2, 1.0) * 1e-2 / w[0].max(1e-3);
                    }
                }
                _ => {
                    reference::reference_solve(&p, &mut warm[..rows], &settings).unwrap();
                    for v in warm[..rows].iter_mut() {
                        *v *= rng.range(0.9, 1.1);
                    }
                }
            }
            let mut expected = warm;
            let mut got = warm;
            let a = reference::reference_solve(&p, &mut expected[..rows], &settings).unwrap();
            let b = solve(&p, &mut got[..rows], &settings).unwrap();
            assert_eq!(a, b, "case {case}: n {n} μ {mu}");
            assert_eq!(expected[..rows], got[..rows], "case {case}: n {n} μ {mu}");
            for k in 0..n {
                let l = &got[3 * k..3 * k + 3];
                if l[0] == 0.0 {
                    separated += 1;
                } else if mu > 0.0 && (l[1] * l[1] + l[2] * l[2]).sqrt() >= mu * l[0] * 0.999 {
                    sliding += 1;
                }
            }
        }
        // The cases exercise all three outcomes.
        assert!(separated > 1000 && sliding > 1000, "{separated} {sliding}");
    }

    #[test]
    fn empty_problem_is_trivially_solved() {
        let w = empty_w();
        let p = Problem {
            compliance: &w,
            free_violation: &[],
            friction_mu: 0.0,
            row_count: 0,
        };
        let s = solve(&p, &mut [], &Settings::default()).unwrap();
        assert!(s.converged && s.iterations == 0);
    }
}
