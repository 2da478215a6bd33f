//! The IRLS schedule of a Φ fit: the smoothing ε of `Φ_ε = (1/n) Σ √(‖r_i‖² + ε²)` (mm) and
//! the stage whose model a step uses.
//!
//! * [`Irls`], the native LM's: a *majorising* stage with ε = [`Options::irls_initial_epsilon`]
//!   × the current Φ, handed over to a *Newton* stage at ε = [`Options::irls_final_epsilon`] ×
//!   Φ once its steps gain little ([`FIRST_GAIN`], then down to [`MAJORISING_GAIN`]), handed
//!   back when the Newton model fails there ([`NEWTON_REFUSALS`]); a fit with scalar residuals
//!   continues in ε from [`CONTINUATION`] × the initial fraction down to
//!   [`SCALAR_FINAL_EPSILON`] (see [`crate::engines::lm`]: a fit of scalar residuals alone
//!   ends at its L1 vertex instead, and continues in ε only where that finish fails).
//! * [`Continuation`], the Ceres and NLopt wrappers': a solve per ε, ε shrinking tenfold from
//!   `irls_initial_epsilon × Φ₀` to `irls_final_epsilon × Φ`, the last solve with the run's
//!   objective-change tolerance, the earlier ones with [`STAGE_TOLERANCE`].
//!
//! Every ε is floored at [`TINY`] (an exact fit's Φ = 0 would make the weights `1/ε`
//! infinite). Each change of ε changes the cost: the caller recomputes it (the LM's
//! `Lm::recost`).

use crate::options::{Objective, Options};
use volver_core::units::TINY;

/// The majorising stage of a Φ fit first hands over to Newton once a step gains less than this
/// fraction of the cost.
pub(crate) const FIRST_GAIN: f64 = 1e-3;

/// A Newton stage that refuses this many trial steps in a row has been handed a point where its
/// model fails (a residual near the kink of its norm that the optimum does not interpolate): the
/// majorising stage resumes, to hand over at a gain a hundred times smaller.
pub(crate) const NEWTON_REFUSALS: usize = 2;

/// A refused Newton step counts towards [`NEWTON_REFUSALS`] when the decrease it predicted was
/// above this share of the cost.
pub(crate) const NEWTON_FAILURE_SHARE: f64 = 1e-9;

/// The smallest hand-over gain: from there on the Newton stage runs to the end.
pub(crate) const MAJORISING_GAIN: f64 = 1e-6;

/// Each resumed majorising stage hands over at this share of the previous hand-over gain.
const GAIN_SHRINK: f64 = 1e-2;

/// A Φ fit with scalar residuals (ranges alone, whose module is the absolute value: an L1
/// fit) starts its Newton stage at ε = this × [`Options::irls_initial_epsilon`] × Φ and, each
/// time it converges there, goes on from that optimum with ε this much smaller, down to
/// [`SCALAR_FINAL_EPSILON`] × Φ (or [`Options::irls_final_epsilon`] × Φ when that is larger):
/// a scalar residual's exact curvature is ε²/(r² + ε²)^³ᐟ²,
/// so a Newton model at the final ε straight away sees only the points already within ε of
/// zero, and the damped steps crawl.
pub(crate) const CONTINUATION: f64 = 0.1;

/// A Φ fit with scalar residuals ends its continuation at ε = this × Φ when
/// [`Options::irls_final_epsilon`] is smaller: Φ_ε − Φ ≤ ε, so Φ is then exact to 1e-6 relative
/// (every finer stage costs some thirty damped steps on test 4's ranges and moves Φ by less).
pub(crate) const SCALAR_FINAL_EPSILON: f64 = 1e-6;

/// A Φ fit with scalar residuals converges in a stage once a step gains less than this share
/// of the stage's ε fraction (the smoothing moves Φ by up to ε).
const SCALAR_STAGE_GAIN: f64 = 1e-3;

/// ε (mm) at `fraction` of Φ = `phi_mm`, floored at [`TINY`].
pub(crate) fn epsilon(fraction: f64, phi_mm: f64) -> f64 {
    (fraction * phi_mm).max(TINY)
}

/// The model of the cost a step uses (see [`crate::engines::lm`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Stage {
    /// Φ's majorising stage: every point with its full curvature, ε following Φ.
    Majorising,
    /// The exact Gauss–Newton model (Triggs-corrected for Φ); least squares' only stage.
    Newton,
}

/// The native LM's IRLS schedule (see the module documentation): the stage, ε, the Newton
/// stage's ε fraction, the hand-over gain and the Newton stage's refused trials in a row.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Irls {
    objective: Objective,
    /// [`Options::irls_initial_epsilon`] and [`Options::irls_final_epsilon`].
    initial_fraction: f64,
    final_fraction: f64,
    /// Whether some residuals are scalar ([`volver_core::problem::Residuals::scalar`]).
    scalar: bool,
    stage: Stage,
    /// The smoothing (mm).
    eps: f64,
    /// The Newton stage's ε as a fraction of Φ (see [`CONTINUATION`]).
    fraction: f64,
    /// The majorising stage's hand-over gain.
    gain: f64,
    /// The Newton stage's refused trials in a row.
    refused: usize,
}

impl Irls {
    /// The schedule at the start, Φ = `phi0_mm`: least squares in its only (Newton) stage, Φ in
    /// the majorising stage at ε = `irls_initial_epsilon × Φ₀`.
    pub(crate) fn new(options: &Options, scalar: bool, phi0_mm: f64) -> Irls {
        let objective = options.objective.loss();
        Irls {
            objective,
            initial_fraction: options.irls_initial_epsilon,
            final_fraction: options.irls_final_epsilon,
            scalar,
            stage: if objective == Objective::Ve {
                Stage::Newton
            } else {
                Stage::Majorising
            },
            eps: epsilon(options.irls_initial_epsilon, phi0_mm),
            fraction: options.irls_final_epsilon,
            gain: FIRST_GAIN,
            refused: 0,
        }
    }

    /// The current stage.
    pub(crate) fn stage(&self) -> Stage {
        self.stage
    }

    /// The current smoothing ε (mm).
    pub(crate) fn eps(&self) -> f64 {
        self.eps
    }

    /// A point's weight and radial reduction in the current stage's model, for a residual of
    /// module `r` (mm) among `np` points (the radial reduction only in the Newton stage).
    pub(crate) fn weight(&self, r: f64, np: usize) -> (f64, f64) {
        let (w, c) = crate::engines::loss::weight_of(self.objective, r, self.eps, np);
        (w, if self.stage == Stage::Newton { c } else { 0.0 })
    }

    /// The majorising stage's ε follows Φ = `phi_mm` at each Jacobian pass; `true` when ε was
    /// set (the cost must be recomputed).
    pub(crate) fn follow(&mut self, phi_mm: f64) -> bool {
        if self.stage != Stage::Majorising {
            return false;
        }
        self.eps = epsilon(self.initial_fraction, phi_mm);
        true
    }

    /// The objective-change test's tolerance from the run's `objective_tolerance`: for a Φ fit
    /// with scalar residuals no finer than a thousandth of the current ε's share of Φ.
    pub(crate) fn objective_tolerance(&self, objective_tolerance: f64) -> f64 {
        if self.scalar && self.objective == Objective::Phi {
            objective_tolerance.max(SCALAR_STAGE_GAIN * self.fraction)
        } else {
            objective_tolerance
        }
    }

    /// Whether the majorising stage has slowed down: an accepted step from the cost `old` to
    /// `new` gained less than the hand-over gain of `old`.
    pub(crate) fn majorising_slowed(&self, old: f64, new: f64) -> bool {
        old - new <= self.gain * old
    }

    /// A trial was accepted: the Newton stage's refusals in a row start again.
    pub(crate) fn accepted(&mut self) {
        self.refused = 0;
    }

    /// A trial predicting the decrease `pred` from the cost `cost` was refused: it counts
    /// towards [`NEWTON_REFUSALS`] when `pred` is above [`NEWTON_FAILURE_SHARE`] of the cost
    /// (near the optimum refusals are how the damping finds the rounding).
    pub(crate) fn refused(&mut self, pred: f64, cost: f64) {
        if pred > NEWTON_FAILURE_SHARE * cost {
            self.refused += 1;
        }
    }

    /// Whether the Newton stage has failed where it was handed the point and the majorising
    /// stage may resume ([`NEWTON_REFUSALS`] refused trials in a row, a hand-over gain left).
    pub(crate) fn newton_failed(&self) -> bool {
        self.stage == Stage::Newton
            && self.objective == Objective::Phi
            && self.refused >= NEWTON_REFUSALS
            && self.gain > MAJORISING_GAIN
    }

    /// Φ's Newton stage begins at Φ = `phi_mm`: ε = `irls_final_epsilon × Φ` (for scalar
    /// residuals [`CONTINUATION`] × `irls_initial_epsilon × Φ`, the continuation's start).
    pub(crate) fn hand_over(&mut self, phi_mm: f64) {
        self.stage = Stage::Newton;
        self.refused = 0;
        let last = self.final_fraction;
        self.fraction = if self.scalar {
            (self.initial_fraction * CONTINUATION).max(last)
        } else {
            last
        };
        self.eps = epsilon(self.fraction, phi_mm);
    }

    /// A Φ fit with scalar residuals whose Newton stage converged above the final ε goes on at
    /// Φ = `phi_mm` with ε [`CONTINUATION`] times smaller; `false` (nothing changed) when ε is
    /// already the final one, or for any other fit.
    pub(crate) fn shrink(&mut self, phi_mm: f64) -> bool {
        let last = self.final_fraction.max(SCALAR_FINAL_EPSILON);
        if self.stage != Stage::Newton || self.objective != Objective::Phi || self.fraction <= last
        {
            return false;
        }
        self.fraction = (self.fraction * CONTINUATION).max(last);
        self.eps = epsilon(self.fraction, phi_mm);
        self.refused = 0;
        true
    }

    /// Φ's majorising stage resumes at Φ = `phi_mm` (the Newton stage failed where it was
    /// handed the point), to hand over at a gain a hundred times smaller (not below
    /// [`MAJORISING_GAIN`]): ε back to `irls_initial_epsilon × Φ`.
    pub(crate) fn back_to_majorising(&mut self, phi_mm: f64) {
        self.stage = Stage::Majorising;
        self.gain = (self.gain * GAIN_SHRINK).max(MAJORISING_GAIN);
        self.refused = 0;
        self.eps = epsilon(self.initial_fraction, phi_mm);
    }
}

/// A solve of the smoothed problem converged before the last ε stops at this relative
/// objective change (the continuation of Ceres and NLopt: an intermediate ε needs no more).
#[cfg(any(feature = "ceres", feature = "nlopt", test))]
pub(crate) const STAGE_TOLERANCE: f64 = 1e-3;

/// ε shrinks by this factor between the solves of [`Continuation`].
#[cfg(any(feature = "ceres", feature = "nlopt", test))]
const SHRINK: f64 = 10.0;

/// [`Continuation`]'s last solve is the one whose ε is within this factor of
/// `irls_final_epsilon × Φ₀`. The margin is not a tuning: ε reaches the final fraction by
/// tenfold divisions of `irls_initial_epsilon × Φ₀`, which round (at the defaults, 0.1 → 1e-9,
/// eight divisions end 1 ulp above `1e-9 × Φ₀` for about a quarter of the Φ₀), and once the
/// floor `irls_final_epsilon × Φ` takes over at a Φ a hair above Φ₀ (a start at the optimum,
/// where the smoothing moves Φ either way) ε would stay there without ever counting as the last:
/// solve after solve at the same ε until a limit. A relative 1e-4 covers both and is far below
/// the tenfold step between two ε.
#[cfg(any(feature = "ceres", feature = "nlopt", test))]
const FINAL_MARGIN: f64 = 1.0001;

/// The ε-continuation of the Ceres and NLopt wrappers (see the module documentation).
#[cfg(any(feature = "ceres", feature = "nlopt", test))]
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Continuation {
    objective: Objective,
    /// [`Options::irls_final_epsilon`].
    final_fraction: f64,
    /// The current smoothing (mm).
    eps: f64,
    /// `irls_final_epsilon × Φ₀` (mm): the last solve's ε.
    last: f64,
}

#[cfg(any(feature = "ceres", feature = "nlopt", test))]
impl Continuation {
    /// The first solve's ε: `irls_initial_epsilon × Φ₀` (Φ₀ = `phi0_mm`).
    pub(crate) fn new(options: &Options, phi0_mm: f64) -> Continuation {
        Continuation {
            objective: options.objective.loss(),
            final_fraction: options.irls_final_epsilon,
            eps: epsilon(options.irls_initial_epsilon, phi0_mm),
            last: epsilon(options.irls_final_epsilon, phi0_mm),
        }
    }

    /// The current smoothing ε (mm).
    pub(crate) fn eps(&self) -> f64 {
        self.eps
    }

    /// Whether this solve is the last: least squares' only one, or Φ's at the final ε (within
    /// [`FINAL_MARGIN`]).
    pub(crate) fn is_final(&self) -> bool {
        self.objective == Objective::Ve || self.eps <= self.last * FINAL_MARGIN
    }

    /// The relative objective-change tolerance of this solve: `objective_tolerance` for the
    /// last, [`STAGE_TOLERANCE`] before.
    pub(crate) fn tolerance(&self, objective_tolerance: f64) -> f64 {
        if self.is_final() {
            objective_tolerance
        } else {
            STAGE_TOLERANCE
        }
    }

    /// The next solve's ε after one converged at Φ = `phi_mm`: tenfold smaller, not below
    /// `irls_final_epsilon × Φ`.
    pub(crate) fn shrink(&mut self, phi_mm: f64) {
        self.eps = (self.eps / SHRINK).max(epsilon(self.final_fraction, phi_mm));
    }
}

#[cfg(test)]
mod tests;
