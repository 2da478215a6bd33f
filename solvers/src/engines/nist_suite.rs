//! NIST's StRD nonlinear-regression suite run by the engines: each problem from both certified
//! starts, scored by the log relative error (LRE, [`volver_core::nist::lre`]) of the parameters
//! (the worst one) and of the residual sum of squares, as Ceres and MINPACK are scored.
//!
//! ```
//! use volver_core::nist;
//! use volver_solvers::nist_suite;
//! let ds = nist::dataset("Misra1a").unwrap();
//! let run = nist_suite::run(&ds, 0, &nist_suite::lm(), &nist_suite::options());
//! assert!(run.lre_rss >= 4.0, "{run:?}");
//! ```

use crate::{Objective, Options, Silent, Solver, Task, Termination};
use serde::Serialize;
use volver_core::nist::{Dataset, Difficulty, lre};
use volver_core::problem::{CurveFit, Residuals};

/// The native LM as the suite runs it: no direction held as unidentifiable (the suite's
/// problems are ill-conditioned on purpose: that is what it tests), and geodesic acceleration.
pub fn lm() -> crate::engines::lm::LevenbergMarquardt {
    crate::engines::lm::LevenbergMarquardt {
        rank_tolerance: 0.0,
        geodesic_acceleration: true,
        ..Default::default()
    }
}

/// The engine `name` as the suite runs it: the native LM of [`lm`] (also the first stage of
/// `lm+clarabel`), the others with their default settings.
pub fn engine(name: &str) -> Result<Box<dyn Solver>, crate::Error> {
    let settings = super::sections::Settings {
        lm: lm(),
        ..Default::default()
    };
    crate::engine_with(name, &settings)
}

/// The options of the suite: least squares (ve), tolerances at the limit of double precision,
/// generous limits (MGH10 from start 1 takes the native LM about 1800 steps along its valley).
pub fn options() -> Options {
    Options {
        objective: Objective::Ve,
        parameter_tolerance: 1e-15,
        objective_tolerance: 1e-15,
        gradient_tolerance: 0.0,
        max_iterations: 10_000,
        max_evaluations: 50_000,
        ..Options::default()
    }
}

/// One engine on one problem from one start.
#[derive(Clone, Debug, Serialize)]
pub struct StrdRun {
    /// Problem name.
    pub problem: String,
    /// NIST's difficulty.
    pub difficulty: Difficulty,
    /// Start 1 or 2.
    pub start: usize,
    /// Engine name.
    pub engine: String,
    /// LRE of the worst parameter (0 to 11).
    pub lre_params: f64,
    /// LRE of the residual sum of squares (0 to 11).
    pub lre_rss: f64,
    /// Residual sum of squares reached.
    pub rss: f64,
    /// Iterations.
    pub iterations: usize,
    /// Evaluations.
    pub evaluations: usize,
    /// Wall time (s).
    pub time_s: f64,
    /// Why it stopped.
    pub termination: Termination,
    /// What the shared first-order check measured at the end ([`crate::stationarity`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stationarity: Option<crate::summary::Stationarity>,
    /// Directions the design cannot identify at the end ([`crate::Summary::unidentifiable`]).
    pub unidentifiable: usize,
}

/// Runs `engine` on `dataset` from start `start` (0 or 1).
pub fn run(dataset: &Dataset, start: usize, engine: &dyn Solver, options: &Options) -> StrdRun {
    let problem = CurveFit::new(dataset);
    let task = Task::new(problem);
    let s = engine.solve(&task, &dataset.starts[start], options, &mut Silent);
    let rss = problem.ve(&s.params) * problem.n_points() as f64;
    let finite = s.params.iter().all(|v| v.is_finite()) && rss.is_finite();
    let lre_params = if finite {
        s.params
            .iter()
            .zip(&dataset.certified)
            .map(|(&q, &c)| lre(q, c))
            .fold(11.0, f64::min)
    } else {
        0.0
    };
    StrdRun {
        problem: dataset.name.clone(),
        difficulty: dataset.difficulty,
        start: start + 1,
        engine: engine.name().to_string(),
        lre_params,
        lre_rss: if finite {
            lre(rss, dataset.certified_rss)
        } else {
            0.0
        },
        rss,
        iterations: s.summary.iterations,
        evaluations: s.summary.evaluations,
        time_s: s.summary.time_s,
        termination: s.summary.termination,
        stationarity: s.summary.stationarity,
        unidentifiable: s.summary.unidentifiable,
    }
}
