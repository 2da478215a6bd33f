//! The whole of `volver compare` as one library call: every engine asked for on one problem,
//! side by side, judged on the objective minimised (Φ, ve, or for `ml` and `phi-w` the value of
//! the residuals whitened by the noise) and the residuals. [`Comparison`] is what `volver compare
//! --json` prints.
//!
//! ```
//! use volver::solvers::{Objective, Options, uncertainty::NoiseModel};
//! let model = volver::core::model::Model::default_xcfz();
//! let data = volver::inputs::demo_test4(&model).unwrap().measurements;
//! let lm = volver::solvers::engine("lm").unwrap();
//! let c = volver::comparison::compare(
//!     &model, &data, "demo", &[lm], &Default::default(), true, NoiseModel::Residual,
//! ).unwrap();
//! assert_eq!(c.engines.len(), 1);
//! assert!(c.engines[0].reason.converged());
//! assert_eq!(c.engines[0].value, c.engines[0].phi_mm); // Φ is the objective's value
//! // Maximum likelihood weighs the residuals by the tracker's noise; without one it cannot.
//! let ml = Options { objective: Objective::Ml, max_iterations: 5, ..Options::default() };
//! let lm = || vec![volver::solvers::engine("lm").unwrap()];
//! let noise = NoiseModel::Tracker(volver::core::noise::TrackerNoise::PAPER);
//! let c = volver::comparison::compare(&model, &data, "demo", &lm(), &ml, false, noise).unwrap();
//! assert!(c.engines[0].value > 0.0 && c.noise.is_some());
//! let mut spec = model.machine().spec().clone();
//! spec.tracker.noise = None; // a machine file without [tracker] noise
//! let machine = volver::core::machine::Machine::from_spec(spec, "inline").unwrap();
//! let bare = volver::core::model::Model::from_toml_str(
//!     machine, volver::core::model::DEFAULT_MODEL_TOML, "inline",
//! ).unwrap();
//! let err = volver::comparison::compare(&bare, &data, "demo", &lm(), &ml, false, NoiseModel::Residual);
//! assert!(err.unwrap_err().to_string().contains("--noise"));
//! ```

use crate::error::{Context, Error, Result};
use serde::Serialize;
use volver_core::measure::MeasurementSet;
use volver_core::model::Model;
use volver_core::problem::{Problem, Residuals};
use volver_solvers::identifiability::hold_weak;
use volver_solvers::init::init_tracker;
use volver_solvers::lm::LevenbergMarquardt;
use volver_solvers::uncertainty::NoiseModel;
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
    /// The noise the residuals were whitened by, for the noise-weighted objectives (`ml`,
    /// `phi-w`; a station whose machine-file table states its own noise is weighed by that);
    /// `None` for Φ and ve.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub noise: Option<String>,
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
    /// The value of the objective minimised at its end ([`volver_solvers::Evaluation::cost`]:
    /// Φ in mm, ve in mm², `ml`'s and `phi-w`'s dimensionless, of the whitened residuals).
    pub value: f64,
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
    /// What the shared first-order check measured at its end
    /// ([`volver_solvers::stationarity`]); absent when it did not run.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stationarity: Option<volver_solvers::summary::Stationarity>,
    /// Free directions the design cannot identify at its end, counted alike for every engine.
    pub unidentifiable: usize,
}

/// Runs every engine of `engines` on `model` and `data` (labelled `source`) from the model's
/// start with the tracker fitted rigidly, under `options`; with `gauge`, the directions the data
/// cannot identify (at the native LM's solution) are held first, so that the engines are
/// compared on a well-posed problem. For `ml` and `phi-w` the engines get the residuals
/// whitened by each station's noise, its own where the machine file states one, else `noise`
/// ([`crate::identification::fitted_problem`]); `Err` names a station without any.
pub fn compare(
    model: &Model,
    data: &MeasurementSet,
    source: &str,
    engines: &[Box<dyn Solver>],
    options: &Options,
    gauge: bool,
    noise: NoiseModel,
) -> Result<Comparison> {
    let problem = Problem::new(model, data)?;
    let fitted = crate::identification::fitted_problem(&problem, options.objective, noise)?;
    let start =
        init_tracker(&problem, &model.initial_params()).context("fitting the tracker pose")?;
    let task = Task::new(fitted.clone());
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
                value: s.reached.cost(options.objective),
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
                stationarity: s.stationarity,
                unidentifiable: s.unidentifiable,
            }
        })
        .collect();
    Ok(Comparison {
        data: source.to_string(),
        points: problem.n_points(),
        parameters: model.n_params(),
        objective: options.objective,
        noise: fitted.is_whitened().then(|| match noise {
            NoiseModel::Tracker(t) => format!("tracker {t}"),
            _ => "each station's own".to_string(),
        }),
        gauge_directions_held: held,
        engines: rows,
    })
}
