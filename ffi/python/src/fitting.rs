//! Fitting: `identify`, `diagnose` and `uncertainty`, as the CLI's subcommands of those names
//! call the library (their `--json` is what Python gets, as plain objects).

use crate::convert::{Names, count, count_opt, plain};
use crate::errors::{detached, to_py};
use pyo3::prelude::*;
use std::path::PathBuf;
use volver::core::machine::Machine;
use volver::core::measure::MeasurementSet;
use volver::core::model::Model;
use volver::identification::{Outcome, Settings};
use volver::solvers::Options;
use volver::solvers::prior::Priors;
use volver::solvers::strategy::Phasing;

/// Adds this file's functions to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(identify, m)?)?;
    m.add_function(wrap_pyfunction!(diagnose, m)?)?;
    m.add_function(wrap_pyfunction!(uncertainty, m)?)?;
    Ok(())
}

/// The files a fit reads: data, machine (file or embedded name), model, import profile, plan.
#[derive(Clone, Debug)]
pub struct Files {
    data: PathBuf,
    machine: Option<PathBuf>,
    model: Option<PathBuf>,
    import_profile: Option<PathBuf>,
    plan_file: Option<PathBuf>,
}

impl Files {
    /// Reads them as the CLI's `Inputs::load` does.
    fn load(&self) -> volver::Result<(Machine, Model, MeasurementSet)> {
        volver::inputs::load_taken_by(
            self.machine.as_deref(),
            self.model.as_deref(),
            &self.data,
            self.import_profile.as_deref(),
            self.plan_file.as_deref(),
        )
    }
}

/// What `identify` is asked beside its files.
#[derive(Clone, Debug)]
pub struct IdentifyRequest {
    engine: String,
    objective: String,
    noise: Option<String>,
    priors: Vec<String>,
    strategy: String,
    subloops: usize,
    max_iterations: Option<usize>,
    max_evaluations: Option<usize>,
    geodesic_acceleration: bool,
    add: Vec<String>,
    accept: bool,
    out: Option<PathBuf>,
}

/// The library's settings from the request, checked as `volver identify` checks them.
fn settings(r: &IdentifyRequest) -> volver::Result<Settings> {
    let mut options = Options {
        objective: r.objective.parse()?,
        ..Options::default()
    };
    if let Some(v) = r.max_iterations {
        options.max_iterations = v;
    }
    if let Some(v) = r.max_evaluations {
        options.max_evaluations = v;
    }
    let mut settings = Settings::default();
    settings.engine.clone_from(&r.engine);
    settings.options = options;
    if r.geodesic_acceleration {
        if !r.engine.starts_with("lm") {
            return Err(volver::Error::Request(format!(
                "geodesic_acceleration is a setting of the native LM (lm, lm+clarabel), not of {}",
                r.engine
            )));
        }
        settings.engines.lm.geodesic_acceleration = true;
    }
    settings.priors = (!r.priors.is_empty())
        .then(|| Priors::parse(&r.priors))
        .transpose()?;
    settings.phasing = Phasing::parse(&r.strategy)?;
    if r.subloops == 0 {
        return Err(volver::Error::Request("subloops must be at least 1".into()));
    }
    settings.subloops = r.subloops;
    settings.accept = r.accept;
    volver::solvers::engine(&settings.engine)?;
    settings.options.validate()?;
    Ok(settings)
}

/// The identification `volver identify` runs (no history file is appended), its `--json`
/// value (with `noise_used`), the fitted model's parameter names and the parameter vector.
fn run_identify(
    files: &Files,
    r: &IdentifyRequest,
) -> volver::Result<(serde_json::Value, Vec<String>, Vec<f64>, Outcome)> {
    let (machine, model, data) = files.load()?;
    let model = volver::inputs::with_candidates(&machine, model, &r.add)?;
    let mut settings = settings(r)?;
    let (noise_model, noise_used) = volver::inputs::noise_rule(r.noise.as_deref(), &machine)?;
    settings.noise = noise_model;
    let outcome =
        volver::identification::identify(&model, &data, &settings, &mut volver::solvers::Silent)?;
    if let Some(out) = &r.out
        && outcome.refusal.is_none()
    {
        outcome.results.save(out)?;
    }
    let noise_used = if outcome.id.termination.failed() {
        noise_used
    } else {
        noise_used.judged(
            noise_model,
            &model,
            &data,
            &outcome.id.params,
            outcome.id.reached.stats.emm_um,
        )
    };
    let mut value = serde_json::to_value(outcome.report()?)?;
    value["noise_used"] = serde_json::to_value(&noise_used)?;
    let names = model.params().iter().map(|p| p.name.clone()).collect();
    let params = outcome.id.params.clone();
    Ok((value, names, params, outcome))
}

/// `volver identify --json`: the report as a dict, with `parameter_names` and `params` (numpy,
/// mm and rad). A fit that must not be used (stopped on a limit, implausible sizes) raises
/// NotSolvedError or ImplausibleError (`accept=True` keeps it, as `--accept`), the report in
/// the exception's `result`; `out` writes the results file (JSON) of a fit that may be used.
#[pyfunction]
#[pyo3(signature = (data, machine=None, model=None, *, engine="lm".to_string(), objective="phi".to_string(), noise=None, priors=Names::default(), strategy="one".to_string(), subloops=1, max_iterations=None, max_evaluations=None, geodesic_acceleration=false, add=Names::default(), accept=false, out=None, import_profile=None, plan_file=None), text_signature = "(data, machine=None, model=None, *, engine='lm', objective='phi', noise=None, priors=(), strategy='one', subloops=1, max_iterations=None, max_evaluations=None, geodesic_acceleration=False, add=(), accept=False, out=None, import_profile=None, plan_file=None)")]
#[allow(clippy::too_many_arguments)]
fn identify<'py>(
    py: Python<'py>,
    data: PathBuf,
    machine: Option<PathBuf>,
    model: Option<PathBuf>,
    engine: String,
    objective: String,
    noise: Option<String>,
    priors: Names,
    strategy: String,
    subloops: i64,
    max_iterations: Option<i64>,
    max_evaluations: Option<i64>,
    geodesic_acceleration: bool,
    add: Names,
    accept: bool,
    out: Option<PathBuf>,
    import_profile: Option<PathBuf>,
    plan_file: Option<PathBuf>,
) -> PyResult<Bound<'py, PyAny>> {
    let files = Files {
        data,
        machine,
        model,
        import_profile,
        plan_file,
    };
    let request = IdentifyRequest {
        engine,
        objective,
        noise,
        priors: priors.0,
        strategy,
        subloops: count(py, "subloops", subloops)?,
        max_iterations: count_opt(py, "max_iterations", max_iterations)?,
        max_evaluations: count_opt(py, "max_evaluations", max_evaluations)?,
        geodesic_acceleration,
        add: add.0,
        accept,
        out,
    };
    let (value, names, params, outcome) = detached(py, || run_identify(&files, &request))?;
    let result = plain(py, &value)?;
    result.set_item("parameter_names", names)?;
    result.set_item("params", numpy::PyArray1::from_vec(py, params))?;
    if let Some(refusal) = outcome.refusal {
        let e = if outcome.implausible.is_empty() {
            volver::Error::NotSolved(format!("{refusal}; no results written"))
        } else {
            volver::Error::Implausible(format!("{refusal}; no results written"))
        };
        let err = to_py(py, e);
        err.value(py).setattr("result", &result)?;
        return Err(err);
    }
    Ok(result)
}

/// `volver diagnose --json`: where the fit fails and what it most likely misses; the
/// candidates (`candidates`: a list of dicts with `id`, `description`, `delta_bic`, `emm_um`,
/// `size` and `size_unit` …) best first, at most `top`.
#[pyfunction]
#[pyo3(signature = (data, machine=None, model=None, *, top=10, noise=None, import_profile=None, plan_file=None), text_signature = "(data, machine=None, model=None, *, top=10, noise=None, import_profile=None, plan_file=None)")]
#[allow(clippy::too_many_arguments)]
fn diagnose<'py>(
    py: Python<'py>,
    data: PathBuf,
    machine: Option<PathBuf>,
    model: Option<PathBuf>,
    top: i64,
    noise: Option<String>,
    import_profile: Option<PathBuf>,
    plan_file: Option<PathBuf>,
) -> PyResult<Bound<'py, PyAny>> {
    let top: usize = count(py, "top", top)?;
    let files = Files {
        data,
        machine,
        model,
        import_profile,
        plan_file,
    };
    let d = detached(py, || {
        let (_, model, set) = files.load()?;
        let noise = match &noise {
            Some(text) => Some(volver::core::noise::TrackerNoise::from_text(text)?),
            None => model.machine().default_noise(),
        };
        let mut d = volver::diagnosis::diagnose_with(&model, &set, noise.as_ref())?;
        d.candidates.truncate(top);
        Ok(d)
    })?;
    plain(py, &d)
}

/// What `uncertainty` is asked beside its files.
#[derive(Clone, Debug)]
struct UncertaintyRequest {
    noise: Option<String>,
    monte_carlo: Option<usize>,
    seed: u64,
    tool: Option<String>,
    grid: Option<String>,
    priors: Vec<String>,
    engine: String,
    objective: String,
}

/// The assessment `volver uncertainty` makes and its `--json` value.
fn run_uncertainty(files: &Files, r: &UncertaintyRequest) -> volver::Result<serde_json::Value> {
    let (machine, model, data) = files.load()?;
    let mut request = volver::uncertainty::Request::new(&model)?;
    let (noise_model, noise_used) = volver::inputs::noise_rule(r.noise.as_deref(), &machine)?;
    request.noise = noise_model;
    request.engine.clone_from(&r.engine);
    volver::solvers::engine(&r.engine)?;
    request.priors = (!r.priors.is_empty())
        .then(|| Priors::parse(&r.priors))
        .transpose()?;
    request.monte_carlo = r.monte_carlo.map(|n| (n, r.seed));
    request.objective = r.objective.parse()?;
    request.grid = volver::uncertainty::grid_of(&machine, r.grid.as_deref())?;
    request.tool = volver::compensation::tool_point_of(r.tool.as_deref(), None, &model)?;
    let assessment = volver::uncertainty::assess(&model, &data, &request, &|_| {})?;
    let noise_used = noise_used.judged(
        noise_model,
        &model,
        &data,
        &assessment.id.params,
        assessment.id.reached.stats.emm_um,
    );
    let mut value = serde_json::to_value(assessment.report(&model, &request))?;
    value["noise_used"] = serde_json::to_value(&noise_used)?;
    Ok(value)
}

/// `volver uncertainty --json`: the fit with its gauge stated and the expanded uncertainty
/// (k = 2) of every parameter and of the tool point over a grid, linearised and, with
/// `monte_carlo=N`, by N Monte Carlo replicas (seed `seed`).
#[pyfunction]
#[pyo3(signature = (data, machine=None, model=None, *, noise=None, monte_carlo=None, seed=1, tool_offset_mm=None, grid=None, priors=Names::default(), engine="lm".to_string(), objective="phi".to_string(), import_profile=None, plan_file=None), text_signature = "(data, machine=None, model=None, *, noise=None, monte_carlo=None, seed=1, tool_offset_mm=None, grid=None, priors=(), engine='lm', objective='phi', import_profile=None, plan_file=None)")]
#[allow(clippy::too_many_arguments)]
fn uncertainty<'py>(
    py: Python<'py>,
    data: PathBuf,
    machine: Option<PathBuf>,
    model: Option<PathBuf>,
    noise: Option<String>,
    monte_carlo: Option<i64>,
    seed: i64,
    tool_offset_mm: Option<[f64; 3]>,
    grid: Option<String>,
    priors: Names,
    engine: String,
    objective: String,
    import_profile: Option<PathBuf>,
    plan_file: Option<PathBuf>,
) -> PyResult<Bound<'py, PyAny>> {
    let files = Files {
        data,
        machine,
        model,
        import_profile,
        plan_file,
    };
    let request = UncertaintyRequest {
        noise,
        monte_carlo: count_opt(py, "monte_carlo", monte_carlo)?,
        seed: count(py, "seed", seed)?,
        tool: crate::convert::tool_text(tool_offset_mm),
        grid,
        priors: priors.0,
        engine,
        objective,
    };
    let value = detached(py, || run_uncertainty(&files, &request))?;
    plain(py, &value)
}
