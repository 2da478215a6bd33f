//! Options shared by every engine: the objective and the paper's four convergence criteria
//! (section 6.1) — minimum parameter change, minimum objective change, iteration limit,
//! evaluation limit — plus a gradient test and the IRLS schedule for Φ.

use serde::{Deserialize, Serialize};
use std::fmt;

/// What is minimised.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[non_exhaustive]
pub enum Objective {
    /// Φ, the mean error module (eq. 12), the paper's choice: robust to outliers, not a sum of
    /// squares. The native engine minimises it by iteratively reweighted least squares.
    #[default]
    Phi,
    /// ve, the mean squared error module (eq. 1): ordinary least squares.
    Ve,
    /// The maximum-likelihood estimate under the stated noise: ve of the residuals whitened
    /// by each point's noise (the tracker's spherical model at the point, each station's own; a
    /// range by its range σ) — least squares weighted by the inverse noise covariance, the
    /// efficient estimator under normal noise. The engines minimise ve of the residuals they
    /// are given and refuse this objective on residuals that are not whitened
    /// (`Problem::whitened`); the identification whitens them.
    Ml,
    /// Φ of the whitened residuals (the mean Mahalanobis distance): Φ's robustness to outliers
    /// with the noise's weighting. Whitened residuals as for [`Objective::Ml`].
    #[serde(rename = "phi-w")]
    PhiW,
}

impl Objective {
    /// Every objective, in the order the CLI lists them.
    pub const ALL: [Objective; 4] = [
        Objective::Phi,
        Objective::Ve,
        Objective::Ml,
        Objective::PhiW,
    ];

    /// The loss the engines apply to the residuals they are given: [`Objective::Phi`] (the mean
    /// module) for Φ and whitened Φ, [`Objective::Ve`] (the mean squared module) for ve and ml.
    ///
    /// ```
    /// use volver_solvers::Objective;
    /// assert_eq!(Objective::Ml.loss(), Objective::Ve);
    /// assert_eq!(Objective::PhiW.loss(), Objective::Phi);
    /// assert!(Objective::Ml.whitened() && !Objective::Phi.whitened());
    /// ```
    pub fn loss(self) -> Objective {
        match self {
            Objective::Phi | Objective::PhiW => Objective::Phi,
            Objective::Ve | Objective::Ml => Objective::Ve,
        }
    }

    /// Whether it weighs the residuals by their noise (needs whitened residuals).
    pub fn whitened(self) -> bool {
        matches!(self, Objective::Ml | Objective::PhiW)
    }
}

impl fmt::Display for Objective {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Objective::Phi => "phi",
            Objective::Ve => "ve",
            Objective::Ml => "ml",
            Objective::PhiW => "phi-w",
        })
    }
}

impl std::str::FromStr for Objective {
    type Err = crate::Error;
    fn from_str(s: &str) -> Result<Self, crate::Error> {
        match s {
            "phi" | "Φ" => Ok(Objective::Phi),
            "ve" => Ok(Objective::Ve),
            "ml" => Ok(Objective::Ml),
            "phi-w" | "phiw" | "Φw" => Ok(Objective::PhiW),
            _ => Err(crate::Error::UnknownObjective(s.to_string())),
        }
    }
}

/// Convergence criteria and tuning, with documented defaults ([`Options::default`]), shared by
/// every engine; each engine's own settings are in [`crate::Settings`].
///
/// Which engine reads which field (an engine's summary lists the fields set away from their
/// defaults that it does not read, [`crate::Summary::ignored_options`]):
///
/// | field | lm, lm+clarabel | clarabel | ceres | nlopt-* |
/// |---|---|---|---|---|
/// | `objective` | ✓ | ✓ | ✓ | ✓ |
/// | `parameter_tolerance` | ✓ | ✓ | ✓ | ✓ (`xtol_rel`) |
/// | `objective_tolerance` | ✓ | ✓ | ✓ | ✓ (`ftol_rel`) |
/// | `max_iterations` | ✓ | ✓ (sub-problems) | ✓ | — (counts no iterations) |
/// | `max_evaluations` | ✓ | ✓ | ✓ | ✓ (`maxeval`) |
/// | `gradient_tolerance` | ✓ | — | ✓ | — |
/// | `initial_damping` | ✓ | ✓ (proximal weight) | ✓ (1 / trust radius) | — |
/// | `irls_initial_epsilon`, `irls_final_epsilon` | ✓ | — (Φ kept exact) | ✓ | ✓ |
///
/// The limits are counted exactly: a run never counts more iterations than `max_iterations`
/// nor more evaluations than `max_evaluations`, and one stopped by a limit says which.
///
/// ```
/// use volver_solvers::Options;
/// let o = Options { max_iterations: 50, ..Options::default() };
/// assert!(o.validate().is_ok());
/// assert!(Options { parameter_tolerance: -1.0, ..o }.validate().is_err());
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Options {
    /// The objective.
    pub objective: Objective,
    /// Criterion 1, minimum parameter change: stop when the step in the scaled free
    /// coordinates is below `parameter_tolerance · (‖z‖ + parameter_tolerance)`. Default 1e-10.
    pub parameter_tolerance: f64,
    /// Criterion 2, minimum objective change: stop when an accepted step lowers the objective by
    /// less than `objective_tolerance` times its value. Default 1e-12.
    pub objective_tolerance: f64,
    /// Criterion 3, iteration limit (accepted or rejected steps; Clarabel's sub-problems solved;
    /// not read by NLopt, which counts objective calls instead). Default 200.
    pub max_iterations: usize,
    /// Criterion 4, evaluation limit: objective evaluations, Jacobians included, the start's
    /// among them (at least [`MIN_EVALUATIONS`]). Default 2000.
    pub max_evaluations: usize,
    /// Stop when the largest scaled gradient component is below this times the objective
    /// (the native LM; Ceres' gradient tolerance; not read by Clarabel and NLopt). Default 1e-13.
    pub gradient_tolerance: f64,
    /// Starting Levenberg–Marquardt damping λ, relative to the damping scale (the diagonal of
    /// the normal matrix); Clarabel's first proximal weight, Ceres' first trust radius its
    /// inverse; not read by NLopt. Default 1e-4.
    pub initial_damping: f64,
    /// Φ only: the smoothing ε of the IRLS weights `1/√(‖r‖² + ε²)` starts at this fraction of
    /// Φ: in the native LM's majorising stage it stays at this fraction of the current Φ; NLopt
    /// and Ceres shrink it tenfold each time the smoothed problem converges. Default 0.1.
    pub irls_initial_epsilon: f64,
    /// Φ only: the final IRLS ε as a fraction of Φ (the native LM's Newton stage, the others'
    /// last solve). Default 1e-9.
    pub irls_final_epsilon: f64,
}

/// The smallest [`Options::max_evaluations`]: what a solve may take at its start (the start's
/// residuals and Jacobian, the residuals of the start projected onto the constraints).
pub const MIN_EVALUATIONS: usize = 3;

/// The largest ratio `2‖a‖ / ‖v‖` of geodesic acceleration to step, in the damping norm, that
/// the native LM accepts (Transtrum & Sethna's α = 0.75).
pub const ACCELERATION_RATIO: f64 = 0.75;

impl Default for Options {
    fn default() -> Self {
        Options {
            objective: Objective::Phi,
            parameter_tolerance: 1e-10,
            objective_tolerance: 1e-12,
            max_iterations: 200,
            max_evaluations: 2000,
            gradient_tolerance: 1e-13,
            initial_damping: 1e-4,
            irls_initial_epsilon: 0.1,
            irls_final_epsilon: 1e-9,
        }
    }
}

impl Options {
    /// Checks every value; the message names the field.
    pub fn validate(&self) -> Result<(), crate::Error> {
        let nonneg = [
            ("parameter_tolerance", self.parameter_tolerance),
            ("objective_tolerance", self.objective_tolerance),
            ("gradient_tolerance", self.gradient_tolerance),
        ];
        for (name, v) in nonneg {
            if !(v.is_finite() && v >= 0.0) {
                return Err(crate::Error::OutOfRange {
                    field: name,
                    value: v,
                    expected: "≥ 0",
                });
            }
        }
        let positive = [
            ("initial_damping", self.initial_damping),
            ("irls_initial_epsilon", self.irls_initial_epsilon),
            ("irls_final_epsilon", self.irls_final_epsilon),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(crate::Error::OutOfRange {
                    field: name,
                    value: v,
                    expected: "> 0",
                });
            }
        }
        if self.irls_final_epsilon > self.irls_initial_epsilon {
            return Err(crate::Error::EpsilonOrder {
                initial_epsilon: self.irls_initial_epsilon,
                final_epsilon: self.irls_final_epsilon,
            });
        }
        if self.max_iterations == 0 || self.max_evaluations == 0 {
            return Err(crate::Error::NoLimit);
        }
        if self.max_evaluations < MIN_EVALUATIONS {
            return Err(crate::Error::TooFewEvaluations {
                value: self.max_evaluations,
                min: MIN_EVALUATIONS,
            });
        }
        Ok(())
    }
}
