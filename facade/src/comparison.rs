//! The whole of `volver compare` as one library call: every engine asked for on one problem,
//! side by side, judged on Φ and the residuals. [`Comparison`] is what `volver compare --json`
//! prints.
//!
//! ```
//! let model = volver::core::model::Model::default_xcfz();
//! let data = volver::inputs::demo_test4(&model).unwrap().measurements;
//! let lm = volver::solvers::engine("lm").unwrap();
//! let c = volver::comparison::compare(&model, &data, "demo", &[lm], &Default::default(), true).unwrap();
//! assert_eq!(c.engines.len(), 1);
//! assert!(c.engines[0].reason.converged());
//! ```

use crate::error::{Context, Error, Result};
use serde::Serialize;
use volver_core::measure::MeasurementSet;
use volver_core::model::Model;
use volver_core::problem::{Problem, Residuals};
use volver_solvers::identifiability::hold_weak;
use volver_solvers::init::init_tracker;
use volver_solvers::lm::LevenbergMarquardt;
use volver_solvers::{Objective, Options, Silent, Solver, Task, Termination};

/// Every engine's result on one problem.
#[derive(Clone, Debug, Serialize)]
#[non_exhaustive]
pub struct Comparison {
    /// Where the data come from.
    pub data: String,
    /// Measured points.
    pub points: usize,
    /// The model's parameters.
    pub parameters: usize,
    /// What was minimised.
    pub objective: Objective,
    /// Directions held first as not identifiable (with the gauge option).
    pub gauge_directions_held: usize,
    /// One row per engine, in the order asked.
    pub engines: Vec<Row>,
}

/// One engine's result.
#[derive(Clone, Debug, Serialize)]
#[non_exhaustive]
pub struct Row {
    /// The engine.
    pub engine: String,
    /// Φ at its end (mm).
    pub phi_mm: f64,
    /// ve at its end (mm²).
    pub ve_mm2: f64,
    /// EMM at its end (µm).
    pub emm_um: f64,
    /// EMax at its end (µm).
    pub emax_um: f64,
    /// Steps tried.
    pub iterations: usize,
    /// Objective evaluations.
    pub evaluations: usize,
    /// Jacobian passes.
    pub jacobian_evaluations: usize,
    /// Wall time (s).
    pub time_s: f64,
    /// How it ended, in words.
    pub termination: String,
    /// How it ended.
    pub reason: Termination,
}

/// Runs every engine of `engines` on `model` and `data` (labelled `source`) from the model's
/// start with the tracker fitted rigidly, under `options`; with `gauge`, the directions the data
/// cannot identify (at the native LM's solution) are held first, so that the engines are
/// compared on a well-posed problem.
pub fn compare(
    model: &Model,
    data: &MeasurementSet,
    source: &str,
    engines: &[Box<dyn Solver>],
    options: &Options,
    gauge: bool,
) -> Result<Comparison> {
    let problem = Problem::new(model, data)?;
    let start =
        init_tracker(&problem, &model.initial_params()).context("fitting the tracker pose")?;
    let task = Task::new(problem.clone());
    let (task, held) = if gauge {
        let lm = LevenbergMarquardt::default().solve(&task, &start, options, &mut Silent);
        let t = hold_weak(
            &task,
            &lm.params,
            100.0 * volver_solvers::identifiability::RANK_TOLERANCE,
        )
        .ok_or_else(|| Error::Singular("the identifiability analysis failed".into()))?;
        let held = t.constraints.rows.len() - task.constraints.rows.len();
        (t, held)
    } else {
        (task, 0)
    };
    let rows = engines
        .iter()
        .map(|e| {
            let s = e.solve(&task, &start, options, &mut Silent).summary;
            Row {
                engine: e.name().to_string(),
                phi_mm: s.reached.phi_mm,
                ve_mm2: s.reached.ve_mm2,
                emm_um: s.reached.stats.emm_um,
                emax_um: s.reached.stats.emax_um,
                iterations: s.iterations,
                evaluations: s.evaluations,
                jacobian_evaluations: s.jacobian_evaluations,
                time_s: s.time_s,
                termination: s.termination.to_string(),
                reason: s.termination,
            }
        })
        .collect();
    Ok(Comparison {
        data: source.to_string(),
        points: problem.n_points(),
        parameters: model.n_params(),
        objective: options.objective,
        gauge_directions_held: held,
        engines: rows,
    })
}
