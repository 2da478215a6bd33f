//! What a solve reports, in the spirit of Ceres' `Solver::Summary`: the objective before and
//! after, the error metrics, counts, time, and the criterion that stopped it. A failed run is a
//! status here, never a panic.

use crate::options::Objective;
use serde::{Deserialize, Serialize};
use std::fmt;
use volver_core::metrics::ErrorStats;

/// Why a solve stopped.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
#[serde(tag = "reason", content = "detail", rename_all = "kebab-case")]
pub enum Termination {
    /// Criterion 1: the parameter change fell below its tolerance.
    ParameterChange,
    /// Criterion 2: the objective change fell below its tolerance.
    ObjectiveChange,
    /// Criterion 3: the iteration limit.
    IterationLimit,
    /// Criterion 4: the evaluation limit.
    EvaluationLimit,
    /// The gradient vanished (a stationary point).
    Gradient,
    /// The engine stopped without meeting a tolerance or a limit, at a finite point it did not
    /// reject: pressed against the edge of the region where the model is finite, or NLopt's
    /// `ROUNDOFF_LIMITED` or generic `FAILURE` (typically its line search near the optimum,
    /// where rounding dominates). The result is usually near the optimum but not certified.
    Stalled(Stall),
    /// Nothing to identify: no free parameter.
    NoFreeParameters,
    /// The objective or a step became non-finite, or a factorisation failed (which, and
    /// where, in [`Failure`]). The last finite parameters are kept.
    NumericalFailure(Failure),
    /// The input cannot be solved (inconsistent constraints, bad options, a start of the wrong
    /// length, a mesh too small); [`Invalid`] says which.
    InvalidInput(Invalid),
}

impl Termination {
    /// `true` for a convergence criterion (1, 2, gradient, or nothing to do); `false` for a
    /// limit or a failure.
    pub fn converged(&self) -> bool {
        matches!(
            self,
            Termination::ParameterChange
                | Termination::ObjectiveChange
                | Termination::Gradient
                | Termination::NoFreeParameters
        )
    }

    /// `true` for a failure (the result should not be used).
    pub fn failed(&self) -> bool {
        matches!(
            self,
            Termination::NumericalFailure(_) | Termination::InvalidInput(_)
        )
    }
}

impl fmt::Display for Termination {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Termination::ParameterChange => f.write_str("converged: minimum parameter change"),
            Termination::ObjectiveChange => f.write_str("converged: minimum objective change"),
            Termination::IterationLimit => f.write_str("stopped: iteration limit"),
            Termination::EvaluationLimit => f.write_str("stopped: evaluation limit"),
            Termination::Gradient => f.write_str("converged: gradient vanished"),
            Termination::Stalled(s) => write!(f, "stopped: no further progress ({s})"),
            Termination::NoFreeParameters => f.write_str("nothing to identify: no free parameter"),
            Termination::NumericalFailure(s) => write!(f, "failed: numerical failure ({s})"),
            Termination::InvalidInput(s) => write!(f, "failed: invalid input ({s})"),
        }
    }
}

/// Where in a run something happened.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum At {
    /// At the start.
    Start,
    /// At this iteration.
    Iteration(usize),
    /// At the end.
    End,
}

impl fmt::Display for At {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            At::Start => f.write_str("at the start"),
            At::Iteration(i) => write!(f, "at iteration {i}"),
            At::End => f.write_str("at the end"),
        }
    }
}

/// A numerical failure, by kind: what became non-finite or which decomposition failed, and
/// where. Serialized as its text (the `detail` of [`Termination`]); read back as
/// [`Failure::Reported`].
///
/// ```
/// use volver_solvers::summary::{At, Failure};
/// let f = Failure::JacobianNotFinite(At::Iteration(3));
/// assert_eq!(f.to_string(), "the Jacobian is not finite at iteration 3");
/// ```
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum Failure {
    /// The Jacobian is not finite.
    JacobianNotFinite(At),
    /// The residuals are not finite.
    ResidualsNotFinite(At),
    /// The objective is not finite.
    ObjectiveNotFinite(At),
    /// The step is not finite.
    StepNotFinite(At),
    /// The second derivative along the step (geodesic acceleration) is not finite.
    SecondDerivativeNotFinite(At),
    /// Geodesic acceleration refused every step up to a damping of 1e30.
    AccelerationRefusedEveryStep(At),
    /// The eigen-decomposition of a matrix failed.
    Decomposition {
        /// Which matrix ("the design's normal matrix" …).
        matrix: &'static str,
        /// Where.
        at: At,
    },
    /// What an external engine (Ceres, Clarabel) or an earlier run reported, in its words.
    Reported(String),
}

impl fmt::Display for Failure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Failure::JacobianNotFinite(at) => write!(f, "the Jacobian is not finite {at}"),
            Failure::ResidualsNotFinite(at) => write!(f, "the residuals are not finite {at}"),
            Failure::ObjectiveNotFinite(at) => write!(f, "the objective is not finite {at}"),
            Failure::StepNotFinite(at) => write!(f, "the step is not finite {at}"),
            Failure::SecondDerivativeNotFinite(at) => {
                write!(f, "the second derivative along the step is not finite {at}")
            }
            Failure::AccelerationRefusedEveryStep(at) => write!(
                f,
                "geodesic acceleration refused every step up to damping 1e30 {at}"
            ),
            Failure::Decomposition { matrix, at } => {
                write!(f, "the eigen-decomposition of {matrix} failed {at}")
            }
            Failure::Reported(s) => f.write_str(s),
        }
    }
}

/// Why a run stalled.
///
/// ```
/// use volver_solvers::{Stall, Termination};
/// let t = Termination::Stalled(Stall::AtFiniteEdge { last: 7, count: 3, window: 2, of: 20 });
/// // Serialized as before the reasons were typed: the text as `detail`, read back as its words.
/// let json = serde_json::to_string(&t).unwrap();
/// assert!(json.starts_with(r#"{"reason":"stalled","detail":"stopped at the edge"#), "{json}");
/// let back: Termination = serde_json::from_str(&json).unwrap();
/// assert_eq!(back.to_string(), t.to_string());
/// ```
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum Stall {
    /// It claimed convergence at the edge of the region where the model is finite: `last`
    /// was the last non-finite trial evaluation, `count` of them in all, `window` among the
    /// last `of` evaluations.
    AtFiniteEdge {
        /// The last non-finite trial evaluation.
        last: usize,
        /// Non-finite trials in all.
        count: usize,
        /// Non-finite trials among the last `of` evaluations.
        window: usize,
        /// The window's length.
        of: usize,
    },
    /// The engine claimed convergence (`claimed`, its criterion) at a point that fails the
    /// shared first-order check ([`crate::stationarity`]): one more step of the objective's
    /// majorising model could still remove `gain` of it, or it ended above its start.
    NotStationary {
        /// The criterion the engine claimed, in its words.
        claimed: String,
        /// What the check measured.
        measured: Stationarity,
    },
    /// What an external engine reported, in its words.
    Reported(String),
}

impl fmt::Display for Stall {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Stall::AtFiniteEdge {
                last,
                count,
                window,
                of,
            } => write!(
                f,
                "stopped at the edge of the region where the model is finite, not at a \
                 minimum: trial evaluation {last} was not finite ({count} such, {window} of the \
                 last {of})"
            ),
            Stall::NotStationary { claimed, measured } => {
                write!(f, "the engine claimed \"{claimed}\" at a point that ")?;
                if measured.gain > measured.tolerance.max(measured.rounding) {
                    write!(
                        f,
                        "is not stationary: one more step could still remove {:.1e} of the \
                         objective (tolerance {:.0e})",
                        measured.gain, measured.tolerance
                    )?;
                    if measured.above_start {
                        f.write_str(", and it ended above its start")?;
                    }
                    Ok(())
                } else {
                    write!(
                        f,
                        "is above its start by more than {:.0e} of the objective",
                        measured.tolerance
                    )
                }
            }
            Stall::Reported(s) => f.write_str(s),
        }
    }
}

/// Why a run could not start.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum Invalid {
    /// An option or setting out of its range, or a rigid fit of the tracker that cannot be made.
    Refused(crate::Error),
    /// The start has the wrong length or values that are not finite.
    Start {
        /// Its length.
        values: usize,
        /// Whether every value is finite.
        finite: bool,
        /// The model's parameters.
        params: usize,
    },
    /// The constraints cannot be eliminated.
    Constraints(crate::nullspace::ConstraintError),
    /// A strategy with no sub-loop.
    NoSubloop,
    /// Too few distinct poses for the model: fewer than `per_parameter` equations per free
    /// parameter.
    MeshTooSmall {
        /// Distinct poses.
        distinct: usize,
        /// Measured points.
        points: usize,
        /// At least this many free parameters.
        free: usize,
        /// The equations per free parameter required.
        per_parameter: usize,
    },
    /// What an external engine refused, in its words.
    Reported(String),
}

impl fmt::Display for Invalid {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Invalid::Refused(e) => write!(f, "{e}"),
            Invalid::Start {
                values,
                finite,
                params,
            } => write!(
                f,
                "the start has {values} values (finite: {finite}), the model {params} parameters"
            ),
            Invalid::Constraints(e) => write!(f, "{e}"),
            Invalid::NoSubloop => f.write_str("the strategy needs at least one sub-loop"),
            Invalid::MeshTooSmall {
                distinct,
                points,
                free,
                per_parameter,
            } => write!(
                f,
                "{distinct} distinct poses ({points} points) give {} equations for at least \
                 {free} free parameters: the mesh is too small for this model (at least \
                 {per_parameter} equations per free parameter, {} distinct poses; many more in \
                 practice)",
                3 * distinct,
                (per_parameter * free).div_ceil(3)
            ),
            Invalid::Reported(s) => f.write_str(s),
        }
    }
}

/// The three reasons that carry a detail serialize it as its text and read it back as their
/// `Reported` variant.
macro_rules! as_text {
    ($t:ty) => {
        impl Serialize for $t {
            fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.collect_str(self)
            }
        }
        impl<'de> Deserialize<'de> for $t {
            fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                String::deserialize(d).map(<$t>::Reported)
            }
        }
    };
}
as_text!(Failure);
as_text!(Stall);
as_text!(Invalid);

/// Objective values and error metrics at one parameter vector.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Evaluation {
    /// Φ, mean error module (mm).
    pub phi_mm: f64,
    /// ve, mean squared error module (mm²).
    pub ve_mm2: f64,
    /// EMM and EMax (µm).
    pub stats: ErrorStats,
    /// Φ of the residuals whitened by their noise (dimensionless) when the solve weighed them
    /// by it (objectives `ml`, `phi-w`); Φ, ve and the statistics above stay those of the
    /// residuals in mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub phi_w: Option<f64>,
    /// ve of the whitened residuals (dimensionless), as [`Evaluation::phi_w`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ve_w: Option<f64>,
}

impl Evaluation {
    /// The value of `objective` (Φ in mm, ve in mm², ml's and whitened Φ's dimensionless; NaN
    /// for a noise-weighted objective not evaluated on whitened residuals).
    pub fn cost(&self, objective: Objective) -> f64 {
        match objective {
            Objective::Phi => self.phi_mm,
            Objective::Ve => self.ve_mm2,
            Objective::Ml => self.ve_w.unwrap_or(f64::NAN),
            Objective::PhiW => self.phi_w.unwrap_or(f64::NAN),
        }
    }
}

/// One solve (one phase of a strategy).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Engine name (`lm`, `nlopt`, …).
    pub solver: String,
    /// What was minimised.
    pub objective: Objective,
    /// Label of the phase (`all`, `squareness`, `translation+rotation` …).
    pub phase: String,
    /// Parameters free in this solve (after constraints and held groups).
    pub free_parameters: usize,
    /// Free directions the data cannot identify at the point reached: the design's curvatures
    /// at most [`crate::nullspace::RANK_TOLERANCE`] of the largest, counted the same way for
    /// every engine by the check at the end of the run ([`crate::stationarity`]; 0 when the
    /// run failed before it).
    pub unidentifiable: usize,
    /// Observations: the scalar equations the points give (3 per point, 1 per range alone).
    #[serde(default)]
    pub observations: usize,
    /// Measured points.
    pub points: usize,
    /// At the start.
    pub initial: Evaluation,
    /// What the solve reached, at its end (serialized as `final_`, the key results files
    /// have always used).
    #[serde(rename = "final_")]
    pub reached: Evaluation,
    /// Iterations (steps tried).
    pub iterations: usize,
    /// Objective evaluations (residual passes), Jacobian passes included: the engine's, from the
    /// start's evaluation on, never more than [`crate::Options::max_evaluations`] (the
    /// evaluation of the end point for this summary's [`Summary::reached`] is not counted).
    pub evaluations: usize,
    /// Jacobian passes.
    pub jacobian_evaluations: usize,
    /// Wall time (s).
    pub time_s: f64,
    /// The criterion that stopped it.
    pub termination: Termination,
    /// Whether the engine ended with a Newton polish of the optimum under the task's
    /// constraints ([`crate::engines::polish::settle`]; the native LM on a converged Φ fit with nothing
    /// held, or at the vertex of a Φ fit of ranges alone), so that the identification need not
    /// polish it again.
    #[serde(default)]
    pub polished: bool,
    /// What the shared first-order check measured at the end ([`crate::stationarity`]);
    /// `None` when it did not run (a failed run, nothing free).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stationarity: Option<Stationarity>,
    /// The [`crate::Options`] fields set away from their defaults that this engine does not
    /// read (by field name; `Options`' documentation says which engine reads which), so that a
    /// setting with no effect is stated rather than silently dropped. Empty for an engine that
    /// reads them all.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub ignored_options: Vec<String>,
}

impl Summary {
    /// The final objective value (Φ in mm, ve in mm², ml's and whitened Φ's dimensionless).
    pub fn final_cost(&self) -> f64 {
        self.reached.cost(self.objective)
    }

    /// Final EMM as a percentage of the initial EMM (the paper's residual error).
    /// 0 when the initial EMM is already 0 (nothing to reduce), never NaN.
    pub fn residual_percent(&self) -> f64 {
        let (a, b) = (self.reached.stats.emm_um, self.initial.stats.emm_um);
        if b > 0.0 { 100.0 * a / b } else { 0.0 }
    }

    /// Whether the data give fewer observations than the solve had free parameters: then at
    /// least `free − observations` directions are not identified by any data, whatever the
    /// engine reports (a warning in [`Summary::full_report`] and [`Summary::warning`]).
    pub fn underdetermined(&self) -> bool {
        self.observations < self.free_parameters
    }

    /// The warning a reader needs before trusting the result, if any: fewer observations than
    /// free parameters.
    pub fn warning(&self) -> Option<String> {
        self.underdetermined().then(|| {
            format!(
                "fewer observations ({}) than free parameters ({}): at least {} directions are \
                 fixed by the start and the engine, not by the data",
                self.observations,
                self.free_parameters,
                self.free_parameters - self.observations
            )
        })
    }

    /// One line.
    pub fn brief_report(&self) -> String {
        format!(
            "{} ({}, {}): EMM {:.4} → {:.4} µm ({:.4} %), {} iterations, {} evaluations, {:.2} s, {}",
            self.solver,
            self.objective,
            self.phase,
            self.initial.stats.emm_um,
            self.reached.stats.emm_um,
            self.residual_percent(),
            self.iterations,
            self.evaluations,
            self.time_s,
            self.termination
        ) + &self.ignored_note()
            + &self
                .warning()
                .map(|w| format!("; WARNING: {w}"))
                .unwrap_or_default()
    }

    /// `; options not read by this engine: …` when some are (see
    /// [`Summary::ignored_options`]), else nothing.
    fn ignored_note(&self) -> String {
        if self.ignored_options.is_empty() {
            String::new()
        } else {
            format!(
                "; options not read by this engine: {}",
                self.ignored_options.join(", ")
            )
        }
    }

    /// Several lines with every figure.
    pub fn full_report(&self) -> String {
        let mut s = String::new();
        let line = |s: &mut String, k: &str, v: String| {
            s.push_str(&format!("  {k:<26}{v}\n"));
        };
        s.push_str(&format!(
            "Solver summary ({}, phase {})\n",
            self.solver, self.phase
        ));
        line(&mut s, "objective", self.objective.to_string());
        line(
            &mut s,
            "points (observations)",
            format!("{} ({})", self.points, self.observations),
        );
        line(
            &mut s,
            "free parameters",
            format!(
                "{} ({} not identifiable from the data)",
                self.free_parameters, self.unidentifiable
            ),
        );
        line(
            &mut s,
            "Φ initial / final (mm)",
            format!("{:.6e} / {:.6e}", self.initial.phi_mm, self.reached.phi_mm),
        );
        line(
            &mut s,
            "ve initial / final (mm²)",
            format!("{:.6e} / {:.6e}", self.initial.ve_mm2, self.reached.ve_mm2),
        );
        line(
            &mut s,
            "EMM initial / final (µm)",
            format!(
                "{:.4} / {:.4}",
                self.initial.stats.emm_um, self.reached.stats.emm_um
            ),
        );
        line(
            &mut s,
            "EMax initial / final (µm)",
            format!(
                "{:.4} / {:.4}",
                self.initial.stats.emax_um, self.reached.stats.emax_um
            ),
        );
        line(
            &mut s,
            "residual error",
            format!("{:.4} %", self.residual_percent()),
        );
        line(&mut s, "iterations", self.iterations.to_string());
        line(
            &mut s,
            "evaluations (Jacobians)",
            format!("{} ({})", self.evaluations, self.jacobian_evaluations),
        );
        line(&mut s, "time", format!("{:.3} s", self.time_s));
        line(&mut s, "termination", self.termination.to_string());
        if !self.ignored_options.is_empty() {
            line(&mut s, "options not read", self.ignored_options.join(", "));
        }
        self.checks_report(&mut s, &line);
        s
    }

    /// The lines of [`Summary::full_report`] on the shared check and the warning.
    fn checks_report(&self, s: &mut String, line: &dyn Fn(&mut String, &str, String)) {
        if let Some(st) = &self.stationarity {
            line(
                s,
                "first-order check",
                format!(
                    "{} (gain {:.1e}, tolerance {:.0e})",
                    if st.stationary() {
                        "stationary"
                    } else {
                        "NOT stationary"
                    },
                    st.gain,
                    st.tolerance
                ),
            );
        }
        if let Some(w) = self.warning() {
            line(s, "WARNING", w);
        }
    }
}

/// What the check measured at the end of a run ([`crate::stationarity`]).
///
/// ```
/// use volver_solvers::summary::Stationarity;
/// let s = Stationarity { gain: 3e-12, tolerance: 1e-8, rounding: 1e-20, above_start: false };
/// assert!(s.stationary());
/// assert!(!Stationarity { above_start: true, ..s }.stationary());
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Stationarity {
    /// The fraction of the objective one more step of its majorising model could remove
    /// (dimensionless, 0 at a stationary point).
    pub gain: f64,
    /// The tolerance the gain was judged against ([`crate::stationarity::TOLERANCE`]).
    pub tolerance: f64,
    /// The gain the residuals' rounding alone could give, relative to the objective: a gain
    /// below it is not judged.
    pub rounding: f64,
    /// Whether the objective ended above its start's by more than `tolerance` of it.
    pub above_start: bool,
}

impl Stationarity {
    /// Whether the point passes: not above the start, and a gain within the tolerance or the
    /// rounding.
    pub fn stationary(&self) -> bool {
        !self.above_start && self.gain <= self.tolerance.max(self.rounding)
    }
}
