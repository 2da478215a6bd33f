//! # volver-solvers
//!
//! The optimisation side of volver. Every engine implements [`Solver`]: it minimises an
//! objective ([`Objective`]: Φ or ve) of a [`Problem`] under linear equality constraints
//! `A p = b` (the model's, plus the parameters a phase holds), from a start, with shared
//! [`Options`], and returns a [`Solution`] whose [`Summary`] says what happened. A failed run is a
//! status in the summary, never a panic.
//!
//! - [`lm`]: the native Levenberg–Marquardt engine on faer (always available);
//! - [`strategy`]: phases (table 1 of the paper), sub-loops, and the joint, independent,
//!   combined and cross-validation methods, for any engine;
//! - [`candidates`]: what the model misses, ranked by a score test;
//! - [`identifiability`]: rank, condition, uncertainties, correlations, inseparable parameters;
//! - [`init`]: the tracker pose's starting value by a rigid best fit (Kabsch);
//! - [`nullspace`]: constraint elimination, `p = p₀ + N z`;
//! - [`strd`]: NIST's StRD nonlinear-regression suite, scored by the log relative error.
#![deny(missing_docs)]

pub mod candidates;
#[cfg(feature = "ceres")]
pub mod ceres;
#[cfg(feature = "clarabel")]
pub mod clarabel;
mod coordinates;
pub mod gauge;
pub mod identifiability;
pub mod init;
pub mod kernels;
pub mod lm;
mod loss;
#[cfg(feature = "nlopt")]
pub mod nlopt;
pub mod nullspace;
pub mod observability;
pub mod options;
pub mod polish;
pub mod prior;
mod run;
pub mod strategy;
pub mod strd;
pub mod summary;
pub mod uncertainty;

pub use options::{Objective, Options};
pub use summary::{Evaluation, Summary, Termination};

use volver_core::model::{Constraint, ConstraintKind, Constraints, ParamInfo};
use volver_core::problem::Problem;

/// What to solve: a problem, the constraints to honour and a label.
#[derive(Clone, Debug)]
pub struct Task<'a> {
    /// Model and measurements.
    pub problem: Problem<'a>,
    /// Every constraint: the model's, plus held parameters.
    pub constraints: Constraints,
    /// Label of the phase, for reports.
    pub phase: String,
    /// The unweighted normal equations at a point, when the caller already formed them there
    /// (the gauge, at its reference): an engine starting at that very point takes them instead
    /// of a pass of its own.
    pub(crate) plain: Option<std::sync::Arc<PlainNormal>>,
}

/// `JᵀJ` and `Jᵀr` at the point `at` (see [`Task`]).
#[derive(Debug)]
pub(crate) struct PlainNormal {
    pub(crate) at: Vec<f64>,
    pub(crate) h: faer::Mat<f64>,
    pub(crate) g: Vec<f64>,
}

impl<'a> Task<'a> {
    /// The problem under the model's own constraints.
    pub fn new(problem: Problem<'a>) -> Task<'a> {
        Task {
            constraints: problem.constraints().into_owned(),
            problem,
            phase: "all".to_string(),
            plain: None,
        }
    }

    /// The problem with every parameter for which `hold` is true held at its value in `at`.
    pub fn holding(
        problem: Problem<'a>,
        hold: impl Fn(usize, &ParamInfo) -> bool,
        at: &[f64],
        phase: &str,
    ) -> Task<'a> {
        let model = problem.model();
        let mut task = Task::new(problem);
        for (j, info) in model.params().iter().enumerate() {
            if hold(j, info) {
                task.constraints.rows.push(Constraint {
                    kind: ConstraintKind::Fixed,
                    label: format!("{} held by the phase", info.name),
                    coeffs: vec![(j, 1.0)],
                    rhs: at[j],
                });
            }
        }
        task.phase = phase.to_string();
        task
    }
}

/// The result of a solve.
#[derive(Clone, Debug)]
pub struct Solution {
    /// The parameters reached (every constraint satisfied).
    pub params: Vec<f64>,
    /// What happened.
    pub summary: Summary,
}

/// Progress of one iteration, for [`Observer`]s.
#[derive(Clone, Copy, Debug)]
pub struct Iteration {
    /// Steps tried so far.
    pub iteration: usize,
    /// Evaluations so far.
    pub evaluations: usize,
    /// Current objective (smoothed Φ_ε or ve).
    pub cost: f64,
    /// Current EMM (µm).
    pub emm_um: f64,
    /// Damping λ used for the step.
    pub damping: f64,
    /// Length of the step in the scaled free coordinates.
    pub step: f64,
    /// Whether the step was accepted.
    pub accepted: bool,
}

/// Watches a solve (progress display, logging).
pub trait Observer {
    /// Called after every step tried.
    fn iteration(&mut self, _it: &Iteration) {}

    /// Whether [`Iteration::emm_um`] is read: engines whose own iteration reports lack the
    /// residual modules (Ceres) then spend a residual pass per iteration to compute it.
    fn wants_metrics(&self) -> bool {
        true
    }
}

/// An observer that does nothing.
#[derive(Clone, Copy, Debug, Default)]
pub struct Silent;

impl Observer for Silent {
    fn wants_metrics(&self) -> bool {
        false
    }
}

/// A minimisation engine.
pub trait Solver {
    /// Its name (`lm`, `nlopt`, `ceres`, `clarabel`).
    fn name(&self) -> &'static str;

    /// Minimises `options.objective` over the parameters that satisfy `task.constraints`,
    /// starting from `start` (projected onto the constraints if it misses them).
    fn solve(
        &self,
        task: &Task,
        start: &[f64],
        options: &Options,
        observer: &mut dyn Observer,
    ) -> Solution;
}

/// Names of the engines this build has, in the order [`engine`] knows them: `lm` always;
/// `lm+clarabel` and `clarabel` with the `clarabel` feature; `ceres` with `ceres`;
/// `nlopt-lbfgs`, `nlopt-slsqp`, `nlopt-mma` and `nlopt-bobyqa` with `nlopt`.
///
/// ```
/// let names = volver_solvers::engine_names();
/// assert_eq!(names[0], "lm");
/// for name in &names {
///     assert_eq!(volver_solvers::engine(name).unwrap().name(), *name);
/// }
/// assert!(volver_solvers::engine("simplex").is_err());
/// ```
pub fn engine_names() -> Vec<&'static str> {
    #[allow(unused_mut)]
    let mut names = vec!["lm"];
    #[cfg(feature = "clarabel")]
    names.extend(["lm+clarabel", "clarabel"]);
    #[cfg(feature = "ceres")]
    names.push("ceres");
    #[cfg(feature = "nlopt")]
    names.extend(["nlopt-lbfgs", "nlopt-slsqp", "nlopt-mma", "nlopt-bobyqa"]);
    names
}

/// The engine called `name`, or an error listing the engines of this build (and the Cargo
/// feature that brings a known engine this build lacks).
pub fn engine(name: &str) -> Result<Box<dyn Solver>, String> {
    let engine: Box<dyn Solver> = match name {
        "lm" => Box::new(lm::LevenbergMarquardt),
        #[cfg(feature = "clarabel")]
        "clarabel" => Box::new(crate::clarabel::ProxLinear),
        #[cfg(feature = "clarabel")]
        "lm+clarabel" => Box::new(crate::clarabel::Polished),
        #[cfg(feature = "ceres")]
        "ceres" => Box::new(ceres::Ceres::default()),
        #[cfg(feature = "nlopt")]
        "nlopt-lbfgs" => Box::new(crate::nlopt::Nlopt::new(crate::nlopt::Algorithm::Lbfgs)),
        #[cfg(feature = "nlopt")]
        "nlopt-slsqp" => Box::new(crate::nlopt::Nlopt::new(crate::nlopt::Algorithm::Slsqp)),
        #[cfg(feature = "nlopt")]
        "nlopt-mma" => Box::new(crate::nlopt::Nlopt::new(crate::nlopt::Algorithm::Mma)),
        #[cfg(feature = "nlopt")]
        "nlopt-bobyqa" => Box::new(crate::nlopt::Nlopt::new(crate::nlopt::Algorithm::Bobyqa)),
        other => {
            let feature = match other {
                "ceres" => Some("ceres"),
                "clarabel" | "lm+clarabel" => Some("clarabel"),
                o if o.starts_with("nlopt") => Some("nlopt"),
                _ => None,
            };
            let hint = feature
                .map(|f| format!(" ('{other}' needs the Cargo feature `{f}`)"))
                .unwrap_or_default();
            return Err(format!(
                "unknown solver '{other}'{hint}: this build has {}",
                engine_names().join(", ")
            ));
        }
    };
    Ok(engine)
}

/// Φ, ve, EMM and EMax of a problem at `params`.
pub fn evaluate(problem: &Problem, params: &[f64]) -> Evaluation {
    // The modules on every core, summed in point order: the same bits as one thread.
    let norms = crate::loss::norms_of(problem, params);
    let n = norms.len() as f64;
    Evaluation {
        phi_mm: norms.iter().sum::<f64>() / n,
        ve_mm2: norms.iter().map(|r| r * r).sum::<f64>() / n,
        stats: volver_core::metrics::ErrorStats::of_modules(norms.iter().copied()),
    }
}
