//! The check every engine's claim of convergence must pass: first-order optimality under the
//! constraints, measured the same way whichever engine stopped.
//!
//! An engine's own criteria (a small step, a small change of the objective, a small gradient in
//! its own scaling) say that it stopped moving, not that it stopped at a minimum: a quasi-Newton
//! method whose line search fails near a kink of Φ, or that runs into a valley where the
//! objective is nearly flat (a sphere of 10⁴ mm radius through points that a 50 mm sphere fits),
//! stops moving too. After every run that claims convergence, `Run::finish` (the end every
//! engine shares) measures at the point reached, in the free coordinates of the constraints:
//!
//! * the **gain**: how much of the objective one more step of its majorising model could still
//!   remove, relative to the objective — for ve the Gauss–Newton step's `gᵀH⁺g / ‖r‖²` (the
//!   squared cosine between the residual vector and the span of the Jacobian's free columns,
//!   the relative-offset idea of Bates & Watts 1981 and of MINPACK's `gtol` test), for Φ the
//!   IRLS step's `½ gᵀH⁺g / Σ √(‖rᵢ‖² + ε²)` with `H = Σ Jᵢᵀ Jᵢ / √(‖rᵢ‖² + ε²)` (the weights
//!   majorise the smoothed Φ the engines minimise, ε = [`Options::irls_final_epsilon`] × Φ, so
//!   a residual at a kink weighs ~1/ε and its unit vector, whose direction is rounding, gains
//!   nothing). The gain is taken over the directions the design identifies (curvature above
//!   [`RANK_TOLERANCE`] of the largest, Marquardt-scaled, as the native LM holds them): along the
//!   others the objective may fall by parts in 10⁴ while the parameters run away, which no
//!   engine is asked to follow; they are counted instead. The gain is dimensionless, invariant to the parameters' units and
//!   between 0 and 1 (½ for Φ);
//! * the **objective against the start**: a run that ends above the objective of its start
//!   (the start projected onto the constraints) by more than [`TOLERANCE`] of it did not
//!   converge, whatever its criteria said (an engine restarted at an optimum may end a few
//!   parts in 10¹¹ above it: its smoothing of Φ, not a step uphill).
//!
//! A claim passes when the gain is at most [`TOLERANCE`], or when the gain is below the
//! objective's rounding (residuals at the rounding of what they measure:
//! `(16 ε · observation_scale)²` per point, which no step can resolve); otherwise the run is
//! reported as [`Stall::NotStationary`], stopped, not converged, with what was measured. The
//! same pass counts the directions the design cannot identify ([`Summary::unidentifiable`]) for
//! every engine. The pass is one Jacobian pass at the end; it is not counted in
//! [`Summary::evaluations`] (it is the check's, not the engine's).
//!
//! [`Options::irls_final_epsilon`]: crate::Options::irls_final_epsilon
//! [`RANK_TOLERANCE`]: crate::nullspace::RANK_TOLERANCE
//! [`Stall::NotStationary`]: crate::Stall::NotStationary
//! [`Summary::unidentifiable`]: crate::Summary::unidentifiable
//! [`Summary::evaluations`]: crate::Summary::evaluations

use crate::engines::coordinates::{reduce, scaled_null_space};
use crate::engines::kernels::accumulate_weighted;
use crate::nullspace::RANK_TOLERANCE;
use crate::options::Objective;
use faer::{Mat, Side};
use volver_core::model::Constraints;
use volver_core::problem::Residuals;

/// The largest gain (see the module) at which a claimed convergence is accepted: one more step
/// of the objective's own majorising model could remove at most this fraction of it. A run
/// that converged by its engine's criteria at their defaults ends far below it (measured on
/// NIST's StRD and the agreement suite: see the tests); a run stopped at a point that is not
/// stationary ends far above it.
pub const TOLERANCE: f64 = 1e-8;

pub use crate::summary::Stationarity;

/// What the end-of-run pass gives: the check, and the directions the design cannot identify.
pub(crate) struct Measured {
    pub(crate) stationarity: Stationarity,
    pub(crate) unidentifiable: usize,
}

/// The check at `p`, whose residual modules are `modules`, for the loss `objective` (Φ or ve on
/// the residuals given), the smoothing
/// `epsilon` (a fraction of Φ), the objective of the start `start_cost` (the loss's own value:
/// Φ or ve of the given residuals). `None` when the Jacobian there is not finite or the
/// constraints cannot be eliminated (the engine's own termination then stands).
pub(crate) fn measure(
    problem: &dyn Residuals,
    constraints: &Constraints,
    p: &[f64],
    modules: &[f64],
    objective: Objective,
    epsilon: f64,
    start_cost: f64,
) -> Option<Measured> {
    let n = problem.n_points();
    if n == 0 || modules.len() != n || modules.iter().any(|m| !m.is_finite()) {
        return None;
    }
    let phi = modules.iter().sum::<f64>() / n as f64;
    let eps = epsilon * phi;
    let phi_loss = objective.loss() == Objective::Phi;
    // Σ of the loss per point (Σ √(m² + ε²) for Φ, Σ m² for ve) and the rounding's gain bound.
    let (total, rounding_abs) = (0..n).fold((0.0, 0.0), |(t, r), i| {
        let m = modules[i];
        let delta = 16.0 * f64::EPSILON * problem.observation_scale(i).abs();
        if phi_loss {
            let s = m.hypot(eps);
            (t + s, r + 0.5 * delta * delta / s.max(f64::MIN_POSITIVE))
        } else {
            (t + m * m, r + delta * delta)
        }
    });
    let weight = move |m: f64| {
        if phi_loss {
            (1.0 / m.hypot(eps).max(f64::MIN_POSITIVE), 0.0)
        } else {
            (1.0, 0.0)
        }
    };
    let mut passes = accumulate_weighted(problem, p, &weight, phi_loss, false)?;
    let mut weighted = passes.pop()?;
    let design = passes.pop().unwrap_or_else(|| weighted.clone());
    // A parameter whose column is at rounding level (see below) is not moved by the check; a
    // free one is counted as unidentifiable (one a constraint holds is not free).
    let held = crate::engines::coordinates::held_values(constraints);
    let mut flat = rounding_columns(&design.h);
    for &j in &flat {
        weighted.g[j] = 0.0;
        for k in 0..p.len() {
            weighted.h[(j, k)] = 0.0;
            weighted.h[(k, j)] = 0.0;
        }
    }
    flat.retain(|j| !held.iter().any(|(k, _)| k == j));
    let (d, ns) = scaled_null_space(&design.h, constraints, p);
    let ns = ns.ok()?;
    let (hd, _) = reduce(&d, ns.basis(), &design.h, None);
    let (hw, gw) = reduce(&d, ns.basis(), &weighted.h, Some(&weighted.g));
    // Only the directions the design identifies are judged (the others are counted).
    let (mu, dirs) = crate::engines::coordinates::design_from_reduced(&hd)?;
    let mu_max = mu.iter().copied().fold(0.0_f64, f64::max);
    let keep: Vec<usize> = (0..mu.len())
        .filter(|&i| mu[i] > RANK_TOLERANCE * mu_max)
        .collect();
    let q = Mat::from_fn(dirs.nrows(), keep.len(), |k, c| dirs[(k, keep[c])]);
    let hq = crate::engines::kernels::sandwich(hw.as_ref(), q.as_ref());
    let gq: Vec<f64> = (0..keep.len())
        .map(|c| (0..gw.len()).map(|k| q[(k, c)] * gw[k]).sum())
        .collect();
    let quadratic = pseudo_quadratic(&hq, &gq)?;
    let gain_abs = if phi_loss { 0.5 * quadratic } else { quadratic };
    let relative = |v: f64| if total > 0.0 { v / total } else { 0.0 };
    let cost = if phi_loss { phi } else { total / n as f64 };
    Some(Measured {
        stationarity: Stationarity {
            gain: relative(gain_abs),
            tolerance: TOLERANCE,
            rounding: relative(rounding_abs),
            above_start: cost > start_cost * (1.0 + TOLERANCE),
        },
        unidentifiable: (mu.len() - keep.len()).max(flat.len()),
    })
}

/// The parameters whose design column is at rounding level: squared norm at most 1e-24 of the
/// typical one (the median of the columns the data see), the floor of the engines' column
/// scaling ([`scaled_null_space`]). A rate constant run off to where `exp(−b·x)` underflows
/// (NIST's BoxBOD from its first start, b₂ ≈ 40 … 400) has such a column: the data no longer
/// see it, and the linear model's "gain" along it would be an extrapolation by 10¹⁶.
fn rounding_columns(h: &Mat<f64>) -> Vec<usize> {
    let typical = crate::engines::coordinates::typical_column(h);
    (0..h.nrows())
        .filter(|&j| h[(j, j)] <= 1e-24 * typical)
        .collect()
}

/// `gᵀ H⁺ g` over the directions whose Marquardt-scaled curvature is above [`RANK_TOLERANCE`]
/// of the largest; `None` when the eigen-decomposition fails.
fn pseudo_quadratic(h: &Mat<f64>, g: &[f64]) -> Option<f64> {
    let k = h.nrows();
    if k == 0 {
        return Some(0.0);
    }
    let dmax = (0..k).map(|i| h[(i, i)]).fold(0.0_f64, f64::max);
    let s: Vec<f64> = (0..k)
        .map(|i| 1.0 / h[(i, i)].max(1e-12 * dmax).max(f64::MIN_POSITIVE).sqrt())
        .collect();
    let hp = Mat::from_fn(k, k, |i, j| s[i] * h[(i, j)] * s[j]);
    let evd = hp.self_adjoint_eigen(Side::Lower).ok()?;
    let mu = evd.S().column_vector();
    let u = evd.U();
    let mu_max = (0..k).map(|i| mu[i]).fold(0.0_f64, f64::max);
    Some(
        (0..k)
            .filter(|&c| mu[c] > RANK_TOLERANCE * mu_max)
            .map(|c| {
                let proj: f64 = (0..k).map(|i| u[(i, c)] * s[i] * g[i]).sum();
                proj * proj / mu[c]
            })
            .sum(),
    )
}
