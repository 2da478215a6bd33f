//! The whole of `volver identify` as one library call: the fit under the stated gauge, the
//! uncertainty the results carry (or the maximum a posteriori solution with priors), the
//! plausibility of what the data determine, the verdict on keeping the fit, and the results
//! file. [`Outcome::report`] is the serde form the CLI prints with `--json`.
//!
//! ```
//! use volver::identification::{Settings, identify};
//! let model = volver::core::model::Model::default_xcfz();
//! let data = volver::inputs::demo_test4(&model).unwrap().measurements;
//! let outcome = identify(&model, &data, &Settings::default(), &mut volver::solvers::Silent).unwrap();
//! assert!(outcome.refusal.is_none());
//! assert!(outcome.id.reached.stats.emm_um < outcome.id.initial.stats.emm_um);
//! assert_eq!(outcome.results.parameters.len(), model.n_params());
//! ```

use crate::error::{Context, Error, Result};
pub use crate::shared::Share;
use serde::Serialize;
use std::path::Path;
use volver_core::machine::Machine;
use volver_core::measure::MeasurementSet;
use volver_core::metrics::ErrorStats;
use volver_core::model::Model;
use volver_core::plausibility::{self, Implausible};
use volver_core::problem::{Problem, Residuals};
use volver_core::results::ResultsFile;
use volver_core::simulate::{SimulationRecord, Truth};
use volver_core::units::S_PER_H;
use volver_solvers::observability::Finding;
use volver_solvers::prior::Priors;
use volver_solvers::strategy::{Identification, Phasing, Strategy};
use volver_solvers::summary::Summary;
use volver_solvers::uncertainty::{Covariance, NoiseModel};
use volver_solvers::{Objective, Observer, Options};

/// What an identification is asked (the options of `volver identify`).
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct Settings {
    /// The engine's name ([`volver_solvers::engine_names`]).
    pub engine: String,
    /// The engines' options (objective, limits).
    pub options: Options,
    /// Every engine's own settings (threads, linear solver, sub-problem tolerances …); the
    /// engine reads its sections ([`volver_solvers::engine_with`]).
    pub engines: volver_solvers::Settings,
    /// The phases and sub-loops.
    pub phasing: Phasing,
    /// How many times the phase sequence may run (fig. 14 of the paper).
    pub subloops: usize,
    /// The tracker's noise for the uncertainty the results record.
    pub noise: NoiseModel,
    /// Prior magnitudes: the maximum a posteriori solution instead of the gauge's minimum norm.
    pub priors: Option<Priors>,
    /// Keep a fit stopped on a limit or with implausible sizes (else it is refused).
    pub accept: bool,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            engine: "lm".into(),
            options: Options::default(),
            engines: volver_solvers::Settings::default(),
            phasing: Phasing::One,
            subloops: 1,
            noise: NoiseModel::Residual,
            priors: None,
            accept: false,
        }
    }
}

/// A combination of parameters the data cannot identify: its curvature relative to the
/// largest, and the parameters it moves most (at most four) with their shares.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Unidentified {
    /// Relative curvature in the function metric.
    pub relative_curvature: f64,
    /// The parameters it moves, with their shares.
    pub parameters: Vec<Share>,
}

/// Everything an identification produced.
#[derive(Debug)]
#[non_exhaustive]
pub struct Outcome {
    /// The fit.
    pub id: Identification,
    /// The engine's name.
    pub engine: String,
    /// Objective, phases and sub-loops as asked.
    pub objective: Objective,
    /// The phases.
    pub phasing: Phasing,
    /// The sub-loops.
    pub subloops: usize,
    /// Measured points.
    pub points: usize,
    /// What the positions can and cannot measure with this layout (before any fit).
    pub observability: Vec<Finding>,
    /// The covariance the results carry (the posterior's with priors); `None` when the fit
    /// failed.
    pub covariance: Option<Covariance>,
    /// How the values the data do not determine were chosen (`"none"` without a gauge, `"none
    /// (the gauge failed: …)"` when it was asked for and could not be formed).
    pub rule: String,
    /// The combinations the data cannot identify.
    pub unidentified: Vec<Unidentified>,
    /// Sizes out of the plausible range.
    pub implausible: Vec<Implausible>,
    /// Why the fit must not be used (failed, implausible or not converged without
    /// [`Settings::accept`]); `None`: it may be written and used.
    pub refusal: Option<String>,
    /// The results file of the fit, with its uncertainty.
    pub results: ResultsFile,
    /// The noise error of the measurements when the truth is known ([`noise_error`]).
    pub noise_error: Option<ErrorStats>,
    /// Whether priors decided what the data do not determine.
    pub with_priors: bool,
}

/// The serde form of an [`Outcome`] (`volver identify --json`).
#[derive(Clone, Debug, Serialize)]
#[non_exhaustive]
pub struct Report {
    /// The engine.
    pub solver: String,
    /// `phi` or `ve`.
    pub objective: String,
    /// The phases' name.
    pub strategy: String,
    /// Sub-loops allowed.
    pub subloops: usize,
    /// Measured points.
    pub points: usize,
    /// EMM (µm) at the start (errors zero, the tracker fitted rigidly) and at the end.
    pub emm_initial_um: f64,
    /// EMM (µm) at the end.
    pub emm_final_um: f64,
    /// EMax (µm) at the start.
    pub emax_initial_um: f64,
    /// EMax (µm) at the end.
    pub emax_final_um: f64,
    /// Φ (mm) at the end.
    pub phi_final_mm: f64,
    /// ve (mm²) at the end.
    pub ve_final_mm2: f64,
    /// The final value of the objective minimised: Φ (mm), ve (mm²), or for ml and phi-w the
    /// whitened residuals' ve and Φ (dimensionless, in units of the noise).
    pub objective_final: f64,
    /// Final EMM as a percentage of the initial.
    pub residual_percent: f64,
    /// The measurements' noise error (µm) when the truth is known.
    pub noise_error_um: Option<f64>,
    /// Their noise EMax (µm).
    pub noise_emax_um: Option<f64>,
    /// Steps tried over every phase.
    pub iterations: usize,
    /// Evaluations over every phase.
    pub evaluations: usize,
    /// Wall time (s).
    pub time_s: f64,
    /// How the fit ended, in words.
    pub termination: String,
    /// Whether it converged.
    pub converged: bool,
    /// One summary per phase.
    pub phases: Vec<Summary>,
    /// The identified values by name (the results file's layout).
    pub parameters: serde_json::Value,
    /// The gauge's or the priors' rule; absent without either.
    pub gauge: Option<String>,
    /// The combinations the data cannot identify.
    pub unidentifiable: Vec<Unidentified>,
    /// Implausible sizes, in words.
    pub implausible: Vec<String>,
    /// Why the fit was refused.
    pub refused: Option<String>,
    /// What the positions can and cannot measure.
    pub observability: Vec<Observed>,
}

/// A statement about the layout, in the JSON form.
#[derive(Clone, Debug, Serialize)]
pub struct Observed {
    /// Its kind, in lower case.
    pub kind: String,
    /// What cannot be measured.
    pub what: String,
    /// What would fix it.
    pub fix: String,
}

/// Where the machine `a` (of a truth file) differs from `b` (of the measurements), one
/// `field: a against b` per differing value (`axes.X.range: [0.0, 3000.0] against …`); the
/// tracker's noise is not part of the machine's geometry and is left out. Empty when they agree.
pub fn machine_differences(
    a: &volver_core::machine::MachineSpec,
    b: &volver_core::machine::MachineSpec,
) -> Vec<String> {
    let value = |spec: &volver_core::machine::MachineSpec| {
        let mut spec = spec.clone();
        spec.tracker.noise = None;
        serde_json::to_value(&spec).unwrap_or(serde_json::Value::Null)
    };
    let mut out = Vec::new();
    json_differences("", &value(a), &value(b), &mut out);
    out
}

/// The leaves where `a` and `b` differ, as `path: a against b`, into `out`.
fn json_differences(
    path: &str,
    a: &serde_json::Value,
    b: &serde_json::Value,
    out: &mut Vec<String>,
) {
    use serde_json::Value;
    let at = |key: &str| {
        if path.is_empty() {
            key.to_string()
        } else {
            format!("{path}.{key}")
        }
    };
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            for k in keys {
                let (u, v) = (
                    x.get(k).unwrap_or(&Value::Null),
                    y.get(k).unwrap_or(&Value::Null),
                );
                json_differences(&at(k), u, v, out);
            }
        }
        (Value::Array(x), Value::Array(y))
            if x.len() == y.len() && x.iter().any(|e| e.is_object()) =>
        {
            for (i, (u, v)) in x.iter().zip(y).enumerate() {
                json_differences(&at(&i.to_string()), u, v, out);
            }
        }
        _ if a != b => out.push(format!("{path}: {a} against {b}")),
        _ => {}
    }
}

/// The noise error of the measurements `data` (read from `data_path`) given the true errors
/// in `truth_path` (a results file): the generator's own figure from the `simulation.json`
/// beside the truth when it belongs to these data (the `measurements.csv` written beside it,
/// with this number of points: it knows effects the results format cannot hold), else the EMM
/// of the measurements against the truth's prediction.
pub fn noise_error(
    truth_path: &Path,
    machine: &Machine,
    data_path: &Path,
    data: &MeasurementSet,
) -> Result<ErrorStats> {
    let label = truth_path.display().to_string();
    let truth = Truth::from_results(
        &ResultsFile::load(truth_path).context("reading the truth file")?,
        &label,
    )?;
    let differences = machine_differences(truth.model.machine().spec(), machine.spec());
    if !differences.is_empty() {
        return Err(Error::Mismatch(format!(
            "the machine of {label} is not the machine of the measurements: {}",
            differences.join("; ")
        )));
    }
    let dir = truth_path.parent().unwrap_or(Path::new("."));
    let belongs = volver_core::fsio::same_file(&dir.join("measurements.csv"), data_path);
    let record_path = dir.join("simulation.json");
    // A record beside these data that cannot be read is an error, not a silent fallback to
    // the prediction (which misses what the results format cannot hold).
    let record = match belongs.then(|| std::fs::read_to_string(&record_path).ok()).flatten() {
        None => None,
        Some(text) => Some(
            serde_json::from_str::<SimulationRecord>(volver_core::error::without_bom(&text))
                .with_context(|| {
                    format!(
                        "{}: not a simulation record (written by `volver simulate` beside {label}); \
                         restore it or remove it to judge the noise from the truth's prediction",
                        record_path.display()
                    )
                })?,
        ),
    }
    .filter(|r| r.points == data.points.len());
    Ok(match record {
        Some(r) => r.noise_error,
        None => Problem::new(&truth.model, data)?.stats(&truth.params),
    })
}

/// Identifies `model` from `data` as `settings` ask (see the module documentation); progress
/// goes to `observer`. `Err` for what cannot start (an unknown engine, invalid options, a
/// decomposition of the priors that fails); a fit that fails or must not be used is an
/// `Ok` with [`Outcome::refusal`].
pub fn identify(
    model: &Model,
    data: &MeasurementSet,
    settings: &Settings,
    observer: &mut dyn Observer,
) -> Result<Outcome> {
    if settings.subloops == 0 {
        return Err(Error::Request("--subloops must be at least 1".into()));
    }
    let solver = volver_solvers::engine_with(&settings.engine, &settings.engines)?;
    let options = &settings.options;
    options.validate()?;
    let problem = Problem::new(model, data)?;
    let strategy = Strategy {
        phasing: settings.phasing,
        subloops: settings.subloops,
        ..Strategy::default()
    };
    let observability =
        volver_solvers::observability::observe(model, data, &model.initial_params());
    let fitted = fitted_problem(&problem, options.objective, settings.noise)?;
    let mut id = volver_solvers::strategy::identify(
        solver.as_ref(),
        fitted.clone(),
        &model.initial_params(),
        &strategy,
        options,
        observer,
    );
    let (covariance, rule) = uncertainty_of(&problem, &mut id, settings)?;
    if settings.priors.is_some() && fitted.is_whitened() {
        // The posterior's evaluation with the whitened objective's value too.
        id.reached = volver_solvers::evaluate(&fitted, &id.params);
    }
    let mut results = ResultsFile::from_model(model, &id.params)?;
    results.time_origin_s = model.needs_time().then_some(data.time_origin_s);
    if let Some(cov) = &covariance {
        // One name per column of the held factor: none when the priors decided them.
        let held = crate::shared::held_text(
            model,
            id.gauge.as_ref().filter(|_| settings.priors.is_none()),
        );
        let mut record = cov.to_record(&rule, held);
        record.model_check = Some(crate::shared::check_fit(&problem, &id, settings.noise));
        results.uncertainty = Some(record);
    }
    let implausible = implausible_sizes(&problem, &id, covariance.as_ref());
    let refusal = refusal(&id, &implausible, settings.accept).map(|r| {
        match id
            .termination
            .failed()
            .then(|| problem.first_non_finite(&id.params))
            .flatten()
        {
            Some(place) => format!("{r}; first at {place}"),
            None => r,
        }
    });
    let unidentified = unidentified(model, &id);
    Ok(Outcome {
        engine: solver.name().to_string(),
        objective: options.objective,
        phasing: settings.phasing,
        subloops: settings.subloops,
        points: data.points.len(),
        observability,
        covariance,
        rule,
        unidentified,
        implausible,
        refusal,
        results,
        noise_error: None,
        with_priors: settings.priors.is_some(),
        id,
    })
}

/// The residuals the estimator of `objective` weighs: `problem`'s own (mm) for Φ and ve,
/// whitened by each station's noise for ml and phi-w — its own noise where the machine file
/// states one, else `noise` (`--noise` or the `[tracker]` table's); `Err` names a station
/// without any.
///
/// ```
/// # use volver::core::{measure::MeasurementSet, model::Model, noise::TrackerNoise, problem::Problem};
/// # use volver::solvers::{Objective, uncertainty::NoiseModel};
/// let model = Model::default_xcfz();
/// let csv = "reflector,X,C,Z,meas_x,meas_y,meas_z\nR1,0,0,0,950.003,75.004,1450\n";
/// let data = MeasurementSet::from_csv_str(model.machine(), csv, "inline.csv").unwrap();
/// let problem = Problem::new(&model, &data).unwrap();
/// let tracker = NoiseModel::Tracker(TrackerNoise::PAPER);
/// let ml = volver::identification::fitted_problem(&problem, Objective::Ml, tracker).unwrap();
/// assert!(ml.is_whitened());
/// assert!(!volver::identification::fitted_problem(&problem, Objective::Phi, tracker).unwrap().is_whitened());
/// // No noise stated anywhere: ml cannot weigh the points.
/// let err = volver::identification::fitted_problem(&problem, Objective::Ml, NoiseModel::Residual);
/// assert!(err.unwrap_err().to_string().contains("--noise"));
/// ```
pub fn fitted_problem<'a>(
    problem: &Problem<'a>,
    objective: Objective,
    noise: NoiseModel,
) -> Result<Problem<'a>> {
    volver_solvers::uncertainty::weighed(&problem.plain(), objective, noise)
        .map_err(|e| Error::Request(format!("--objective {objective}: {e}")))
}

/// The rule of the values the data do not determine, as outputs state it: the priors' rule
/// (`priors`), the gauge's, `none`, or — when a gauge was asked for and could not be formed —
/// `none (the gauge failed: …)`, never the same word as no gauge asked.
///
/// ```
/// # use volver::identification::gauge_rule;
/// # use volver::core::model::Model;
/// # use volver::solvers::strategy::{fit, GAUGE_FAILED};
/// # let model = Model::default_xcfz();
/// # let m = model.machine();
/// # let data = volver::core::simulate::Simulation::new(
/// #     volver::core::plan::Plan::parse_grid(m, "X=0:1400:350,C=0:330:30,Z=0:600:150").unwrap(),
/// #     volver::core::simulate::Truth::random(m, model.spec(), &Default::default(), 1).unwrap(),
/// #     1).run().unwrap().measurements;
/// let mut id = fit(volver::core::problem::Problem::new(&model, &data).unwrap());
/// assert_eq!(gauge_rule(None, &id), volver::solvers::gauge::RULE);
/// (id.gauge, id.gauge_failed) = (None, Some(GAUGE_FAILED.to_string()));
/// assert!(gauge_rule(None, &id).starts_with("none (the gauge failed: "));
/// ```
pub fn gauge_rule(priors: Option<String>, id: &Identification) -> String {
    match (priors, &id.gauge) {
        (Some(p), _) => p,
        (None, Some(_)) => volver_solvers::gauge::RULE.to_string(),
        (None, None) => match &id.gauge_failed {
            Some(why) => format!("none (the gauge failed: {why})"),
            None => "none".to_string(),
        },
    }
}

/// The covariance the results carry and the rule of the values the data do not determine;
/// with priors, moves the fit to the maximum a posteriori solution.
fn uncertainty_of(
    problem: &Problem,
    id: &mut Identification,
    settings: &Settings,
) -> Result<(Option<Covariance>, String)> {
    let covariance = if id.termination.failed() {
        None
    } else {
        volver_solvers::uncertainty::linear(
            problem,
            id.gauge.as_ref(),
            &id.params,
            settings.options.objective,
            settings.noise,
        )
    };
    let rule = gauge_rule(settings.priors.as_ref().map(|p| p.rule()), id);
    match (&settings.priors, covariance) {
        (Some(p), Some(cov)) => Ok((Some(with_priors(problem, id, &cov, p)?), rule)),
        (Some(_), None) => Err(Error::Singular(format!(
            "--prior: the fit has no covariance ({}), so the priors cannot be combined with it",
            id.termination
        ))),
        (None, cov) => Ok((cov, rule)),
    }
}

/// Moves the fit `id` on `problem` with covariance `cov` to the maximum a posteriori solution
/// under `priors`; returns the posterior covariance.
pub(crate) fn with_priors(
    problem: &Problem,
    id: &mut Identification,
    cov: &Covariance,
    priors: &Priors,
) -> Result<Covariance> {
    let post = volver_solvers::prior::maximum_a_posteriori(
        problem.model(),
        id.gauge.as_ref(),
        &id.params,
        cov,
        priors,
    )
    .ok_or_else(|| {
        Error::Singular("the maximum a posteriori solution (a decomposition failed)".into())
    })?;
    id.params = post.params;
    id.reached = volver_solvers::evaluate(problem, &id.params);
    Ok(post.covariance)
}

/// Plausibility of what the data determine: the fit on the gauge (values along the
/// unidentified combinations at the reference; else the minimum-norm point of the analysis),
/// each value allowed its expanded uncertainty from the data.
fn implausible_sizes(
    problem: &Problem,
    id: &Identification,
    covariance: Option<&Covariance>,
) -> Vec<Implausible> {
    let model = problem.model();
    let tracker_start = volver_solvers::init::init_tracker(problem, &model.initial_params()).ok();
    let determined = volver_solvers::identifiability::analyse(
        &volver_solvers::Task::new(problem.clone()),
        &id.params,
        volver_solvers::identifiability::RANK_TOLERANCE,
        1.0,
    );
    // Each value is allowed its uncertainty from the data: the fit's covariance (the gauge's,
    // its held combinations at the reference need no allowance), else the analysis'.
    let data_columns: Option<Vec<Vec<f64>>> = covariance.map(|c| {
        (0..c.data.ncols())
            .map(|k| (0..c.data.nrows()).map(|j| c.data[(j, k)]).collect())
            .collect()
    });
    let representative = match (&id.gauge, &determined, &tracker_start) {
        (Some(_), _, _) => id.params.clone(),
        (None, Some(a), Some(start)) => a.minimum_norm(&id.params, start),
        _ => id.params.clone(),
    };
    plausibility::check(
        model,
        &representative,
        &plausibility::Context {
            tracker_start: tracker_start.as_deref(),
            covariance_factor: data_columns
                .as_deref()
                .or(determined.as_ref().map(|a| a.covariance_factor.as_slice())),
            emm_um: Some(id.reached.stats.emm_um),
            relaxed: false,
            time_span_h: problem
                .data()
                .time_span_s()
                .filter(|&t| t > 0.0)
                .map(|t| t / S_PER_H),
        },
    )
}

/// Honest exits: a failed run, a run stopped by a limit and a run with implausible sizes must
/// not be used (a later `compensate` or `tables` must not see them), unless `accept` keeps the
/// last two.
fn refusal(id: &Identification, implausible: &[Implausible], accept: bool) -> Option<String> {
    if id.termination.failed() {
        Some(format!("identification {}", id.termination))
    } else if !accept && !implausible.is_empty() {
        let list: Vec<String> = implausible
            .iter()
            .take(4)
            .map(ToString::to_string)
            .collect();
        Some(format!(
            "implausible sizes ({}): {}; {} (--accept keeps the fit anyway)",
            id.termination,
            list.join("; "),
            plausibility::WHERE_TO_LOOK
        ))
    } else if !accept && !id.termination.converged() {
        Some(format!(
            "{}, not converged: raise --max-iterations or --max-evaluations, or pass --accept \
             to keep this fit",
            id.termination
        ))
    } else {
        None
    }
}

/// The combinations the gauge held, by the parameters they move (a metrologist needs to know
/// which errors are not determined, and by which rule their values were chosen).
fn unidentified(model: &Model, id: &Identification) -> Vec<Unidentified> {
    let Some(g) = &id.gauge else {
        return Vec::new();
    };
    g.held
        .iter()
        .map(|h| Unidentified {
            relative_curvature: h.relative_curvature,
            parameters: h
                .parameters
                .iter()
                .take(4)
                .map(|&(j, share)| Share {
                    name: model.params()[j].name.clone(),
                    share,
                })
                .collect(),
        })
        .collect()
}

impl Outcome {
    /// The serde form (`volver identify --json`).
    pub fn report(&self) -> Result<Report> {
        let id = &self.id;
        Ok(Report {
            solver: self.engine.clone(),
            objective: self.objective.to_string(),
            strategy: self.phasing.name().to_string(),
            subloops: self.subloops,
            points: self.points,
            emm_initial_um: id.initial.stats.emm_um,
            emm_final_um: id.reached.stats.emm_um,
            emax_initial_um: id.initial.stats.emax_um,
            emax_final_um: id.reached.stats.emax_um,
            phi_final_mm: id.reached.phi_mm,
            ve_final_mm2: id.reached.ve_mm2,
            objective_final: id.reached.cost(self.objective),
            residual_percent: id.residual_percent(),
            noise_error_um: self.noise_error.map(|s| s.emm_um),
            noise_emax_um: self.noise_error.map(|s| s.emax_um),
            iterations: id.iterations(),
            evaluations: id.evaluations(),
            time_s: id.time_s,
            termination: id.termination.to_string(),
            converged: id.termination.converged(),
            phases: id.phases.clone(),
            parameters: serde_json::to_value(&self.results.parameters)?,
            gauge: (self.rule != "none").then(|| self.rule.clone()),
            unidentifiable: self.unidentified.clone(),
            implausible: self.implausible.iter().map(ToString::to_string).collect(),
            refused: self.refusal.clone(),
            observability: self
                .observability
                .iter()
                .map(|f| Observed {
                    kind: format!("{:?}", f.kind).to_lowercase(),
                    what: f.what.clone(),
                    fix: f.fix.clone(),
                })
                .collect(),
        })
    }
}
