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
//! - [`nullspace`]: constraint elimination, `p = p₀ + N z`.
#![deny(missing_docs)]

pub mod candidates;
pub mod identifiability;
pub mod init;
pub mod lm;
pub mod nullspace;
pub mod options;
pub mod strategy;
pub mod summary;

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
}

impl<'a> Task<'a> {
    /// The problem under the model's own constraints.
    pub fn new(problem: Problem<'a>) -> Task<'a> {
        Task {
            problem,
            constraints: problem.model().constraints().clone(),
            phase: "all".to_string(),
        }
    }

    /// The problem with every parameter for which `hold` is true held at its value in `at`.
    pub fn holding(
        problem: Problem<'a>,
        hold: impl Fn(usize, &ParamInfo) -> bool,
        at: &[f64],
        phase: &str,
    ) -> Task<'a> {
        let mut task = Task::new(problem);
        for (j, info) in problem.model().params().iter().enumerate() {
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
}

/// An observer that does nothing.
#[derive(Clone, Copy, Debug, Default)]
pub struct Silent;

impl Observer for Silent {}

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

/// Φ, ve, EMM and EMax of a problem at `params`.
pub fn evaluate(problem: &Problem, params: &[f64]) -> Evaluation {
    let norms: Vec<f64> = (0..problem.n_points())
        .map(|i| volver_core::problem::norm(problem.residual(i, params)))
        .collect();
    let n = norms.len() as f64;
    Evaluation {
        phi_mm: norms.iter().sum::<f64>() / n,
        ve_mm2: norms.iter().map(|r| r * r).sum::<f64>() / n,
        stats: volver_core::metrics::ErrorStats::of_modules(norms.iter().copied()),
    }
}
