//! What the uncertainty of a fit needs beyond the solvers crate: the grids of commands over
//! which a tool point's uncertainty is stated, the noise model named on a command line, and the
//! words for a combination of parameters the data cannot identify.

use crate::error::{Error, Result};
pub use crate::shared::{
    MIN_REPEAT_PAIRS, REPEAT_MARGIN, check_fit, combination_text, default_grid, held_text, noise_of,
};
use volver_core::machine::Machine;
use volver_core::model::Model;
use volver_core::plan::Plan;
use volver_core::units::UM_PER_MM;
use volver_solvers::uncertainty::NoiseModel;

/// The grid of `--grid` (a preset or a grid text), or the default.
pub fn grid_of(m: &Machine, text: Option<&str>) -> Result<Plan> {
    Ok(match text {
        Some(t) => crate::inputs::plan(m, None, Some(t))?,
        None => default_grid(m, 5)?,
    })
}

/// What an uncertainty assessment is asked (the options of `volver uncertainty`).
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct Request {
    /// The engine's name.
    pub engine: String,
    /// The tracker's noise (or the residuals').
    pub noise: NoiseModel,
    /// Prior magnitudes: the maximum a posteriori solution and its posterior U.
    pub priors: Option<volver_solvers::prior::Priors>,
    /// The commands whose tool points are judged.
    pub grid: Plan,
    /// The tool point (mm, in the frame of the last tool-side axis).
    pub tool: [f64; 3],
    /// Monte Carlo replicas besides the linearised uncertainty, and their seed.
    pub monte_carlo: Option<(usize, u64)>,
    /// The estimator: Φ (the paper's, default), ve, ml or whitened Φ.
    pub objective: volver_solvers::Objective,
}

impl Request {
    /// The default request on `model`: the native engine, σ from the residuals, no priors, 5
    /// positions over each axis, the tool point at the reflectors' centroid, no Monte Carlo.
    pub fn new(model: &Model) -> Result<Request> {
        Ok(Request {
            engine: "lm".into(),
            noise: NoiseModel::Residual,
            priors: None,
            grid: default_grid(model.machine(), 5)?,
            tool: crate::shared::reflector_centroid(model),
            monte_carlo: None,
            objective: volver_solvers::Objective::Phi,
        })
    }
}

/// A Monte Carlo run and its U95 per grid coordinate, after the set-up's rigid transform and
/// raw (mm).
pub type MonteCarloU95 = (volver_solvers::uncertainty::MonteCarlo, Vec<f64>, Vec<f64>);

/// The fit with its gauge stated and the expanded uncertainty of every parameter and of the
/// tool point over a grid, linearised and by Monte Carlo (see [`assess`]).
#[derive(Debug)]
#[non_exhaustive]
pub struct Assessment {
    /// The fit (the maximum a posteriori solution with priors).
    pub id: volver_solvers::strategy::Identification,
    /// Its covariance (the posterior's with priors).
    pub covariance: volver_solvers::uncertainty::Covariance,
    /// The tool point's U at each grid command, after the set-up's rigid transform and raw.
    pub aligned: Vec<volver_solvers::uncertainty::PointUncertainty>,
    /// Raw, in the workpiece frame.
    pub raw: Vec<volver_solvers::uncertainty::PointUncertainty>,
    /// The Monte Carlo run, and its U95 per grid coordinate (after the transform, raw; mm).
    pub monte_carlo: Option<MonteCarloU95>,
    /// The rule of the values the data do not determine; `None` without a gauge or priors.
    pub rule: Option<String>,
    /// Whether priors decided them.
    pub with_priors: bool,
    /// The fit against the noise: the intervals hold only for a complete model.
    pub model_check: volver_core::results::ModelCheck,
    /// Every estimator's expected tool-point error on the grid beside the Cramér–Rao limit
    /// (with a tracker noise model; `None` with the residuals' σ or when it cannot be formed).
    pub efficiency: Option<volver_solvers::efficiency::Efficiency>,
}

/// Fits `model` to `data` with the gauge stated, and assesses the uncertainty `request` asks
/// for; `progress` hears the Monte Carlo replicas done.
///
/// ```
/// let model = volver::core::model::Model::default_xcfz();
/// let data = volver::inputs::demo_test4(&model).unwrap().measurements;
/// let request = volver::uncertainty::Request::new(&model).unwrap();
/// let a = volver::uncertainty::assess(&model, &data, &request, &|_| {}).unwrap();
/// assert_eq!(a.aligned.len(), request.grid.positions.len());
/// assert!(a.aligned.iter().all(|u| u.u95_max_mm() > 0.0));
/// ```
pub fn assess(
    model: &Model,
    data: &volver_core::measure::MeasurementSet,
    request: &Request,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Assessment> {
    use volver_solvers::uncertainty::{ToolGrid, linear};
    let solver = volver_solvers::engine(&request.engine)?;
    let problem = volver_core::problem::Problem::new(model, data)?;
    let options = volver_solvers::Options {
        objective: request.objective,
        ..Default::default()
    };
    check_request(request, model)?;
    let fitted = crate::identification::fitted_problem(&problem, options.objective, request.noise)?;
    let mut id = volver_solvers::strategy::identify(
        solver.as_ref(),
        fitted,
        &model.initial_params(),
        &volver_solvers::strategy::Strategy::default(),
        &options,
        &mut volver_solvers::Silent,
    );
    if id.termination.failed() {
        return Err(Error::NotSolved(format!(
            "identification {}",
            id.termination
        )));
    }
    let cov = linear(
        &problem,
        id.gauge.as_ref(),
        &id.params,
        options.objective,
        request.noise,
    )
    .ok_or_else(|| {
        Error::Singular(
            "the Jacobian at the solution is not finite or a decomposition failed".into(),
        )
    })?;
    let covariance = match &request.priors {
        Some(p) => crate::identification::with_priors(&problem, &mut id, &cov, p)?,
        None => cov,
    };
    let grid = ToolGrid {
        commands: request.grid.positions.clone(),
        tool: request.tool,
    };
    let aligned = grid.uncertainty(model, &id.params, &covariance, true);
    let raw = grid.uncertainty(model, &id.params, &covariance, false);
    let mc = monte_carlo_run(model, data, request, &grid, &id, &covariance, progress)?;
    let rule = match &request.priors {
        Some(p) => Some(p.rule()),
        None => id
            .gauge
            .as_ref()
            .map(|_| volver_solvers::gauge::RULE.to_string()),
    };
    let model_check = check_fit(&problem, &id, request.noise);
    let efficiency = volver_solvers::efficiency::compare(
        &problem,
        id.gauge.as_ref(),
        &id.params,
        request.noise,
        &grid,
    );
    Ok(Assessment {
        efficiency,
        model_check,
        id,
        covariance,
        aligned,
        raw,
        monte_carlo: mc,
        rule,
        with_priors: request.priors.is_some(),
    })
}

/// The serde form of an [`Assessment`] (`volver uncertainty --json`).
#[derive(Clone, Debug, serde::Serialize)]
#[non_exhaustive]
pub struct Report {
    /// The rule of the values the data do not determine.
    pub gauge: Option<String>,
    /// The prior (mm RMS) on each held combination; `None` with priors.
    pub held_prior_mm: Option<f64>,
    /// The noise model, in words.
    pub noise: String,
    /// σ per coordinate (mm).
    pub sigma_mm: f64,
    /// The coverage factor k of every U.
    pub coverage_factor: f64,
    /// EMM of the fit (µm).
    pub emm_um: f64,
    /// The tool point (mm).
    pub tool_offset_mm: [f64; 3],
    /// Every parameter with its standard uncertainties.
    pub parameters: Vec<ParameterU>,
    /// The combinations the data do not determine.
    pub combinations: Vec<Combination>,
    /// The tool point at every grid command.
    pub points: Vec<PointU>,
    /// The Monte Carlo run.
    pub monte_carlo: Option<MonteCarloRun>,
    /// The fit against the noise, and what it means for these intervals.
    pub model_check: volver_core::results::ModelCheck,
    /// [`volver_core::results::ModelCheck::statement`].
    pub model_statement: String,
    /// The estimator fitted (`phi`, `ve`, `ml`, `phi-w`).
    pub objective: String,
    /// Every estimator's expected RMS tool-point error (3-D, after the set-up's transform,
    /// k = 1, µm) on the grid and the Cramér–Rao limit, with a tracker noise model.
    pub efficiency: Option<EfficiencyU>,
}

/// [`volver_solvers::efficiency::Efficiency`] in µm, for the JSON report.
#[derive(Clone, Debug, serde::Serialize)]
#[non_exhaustive]
pub struct EfficiencyU {
    /// The Cramér–Rao limit (µm).
    pub cramer_rao_um: f64,
    /// Each estimator's name and expected error (µm).
    pub estimators: Vec<(String, f64)>,
    /// Whether every station's noise is normal: the limit is the Cramér–Rao limit; else (a
    /// bounded noise) the Gauss–Markov limit of the estimators linear in the data.
    pub normal: bool,
}

impl From<&volver_solvers::efficiency::Efficiency> for EfficiencyU {
    fn from(e: &volver_solvers::efficiency::Efficiency) -> EfficiencyU {
        EfficiencyU {
            cramer_rao_um: e.limit_mm * UM_PER_MM,
            estimators: e
                .estimators
                .iter()
                .map(|(o, v)| (o.to_string(), v * UM_PER_MM))
                .collect(),
            normal: e.normal,
        }
    }
}

/// A parameter's value and standard uncertainties.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ParameterU {
    /// Its name.
    pub name: String,
    /// Its unit.
    pub unit: String,
    /// Its value.
    pub value: f64,
    /// Standard uncertainty: data and held parts together.
    pub u: f64,
    /// The data's part.
    pub u_data: f64,
    /// The Monte Carlo replicas' standard deviation.
    pub u_monte_carlo: Option<f64>,
}

/// A combination the data do not determine.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Combination {
    /// Held by the gauge (else decided by the priors).
    pub held: bool,
    /// Its relative curvature.
    pub relative_curvature: f64,
    /// The parameters it moves.
    pub parameters: Vec<crate::shared::Share>,
}

/// The tool point's expanded uncertainty (k = 2) at one grid command (µm).
#[derive(Clone, Debug, serde::Serialize)]
pub struct PointU {
    /// The commands, file units.
    pub commands: Vec<f64>,
    /// The identified tool point (mm).
    pub tool_point_mm: [f64; 3],
    /// U per coordinate after the set-up's rigid transform.
    pub u95_um: [f64; 3],
    /// Its data part.
    pub u95_data_um: [f64; 3],
    /// Its held part.
    pub u95_held_um: [f64; 3],
    /// U raw, in the workpiece frame.
    pub u95_raw_um: [f64; 3],
    /// U by Monte Carlo, after the transform.
    pub u95_monte_carlo_um: Option<[f64; 3]>,
}

/// What the Monte Carlo run was.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MonteCarloRun {
    /// Replicas solved.
    pub replicas: usize,
    /// Replicas that failed.
    pub failed: usize,
    /// Wall time (s).
    pub time_s: f64,
    /// Their seed.
    pub seed: u64,
}

impl Assessment {
    /// The commands of grid point `k` in file units.
    pub fn commands(model: &Model, grid: &Plan, k: usize) -> Vec<f64> {
        model
            .machine()
            .axes()
            .iter()
            .enumerate()
            .map(|(i, ax)| ax.to_file_units(grid.positions[k].0[i]))
            .collect()
    }

    /// Each parameter's standard uncertainty from the Monte Carlo replicas.
    pub fn parameters_monte_carlo(&self, model: &Model) -> Option<Vec<f64>> {
        self.monte_carlo
            .as_ref()
            .map(|(mc, _, _)| (0..model.n_params()).map(|j| mc.std_of(|p| p[j])).collect())
    }

    /// The serde form (`volver uncertainty --json`).
    pub fn report(&self, model: &Model, request: &Request) -> Report {
        use volver_solvers::uncertainty::{HELD_PRIOR_MM, K};
        let um3 = |v: [f64; 3]| v.map(|x| x * UM_PER_MM);
        let parts = self.covariance.parameter_parts();
        let u_mc = self.parameters_monte_carlo(model);
        let mc_aligned = self.monte_carlo.as_ref().map(|(_, a, _)| a);
        Report {
            gauge: self.rule.clone(),
            held_prior_mm: (!self.with_priors).then_some(HELD_PRIOR_MM),
            noise: request.noise.to_string(),
            sigma_mm: self.covariance.sigma_mm,
            coverage_factor: K,
            emm_um: self.id.reached.stats.emm_um,
            tool_offset_mm: request.tool,
            parameters: model
                .params()
                .iter()
                .enumerate()
                .map(|(j, info)| ParameterU {
                    name: info.name.clone(),
                    unit: info.unit.to_string(),
                    value: self.id.params[j],
                    u: parts[j].0.hypot(parts[j].1),
                    u_data: parts[j].0,
                    u_monte_carlo: u_mc.as_ref().map(|u| u[j]),
                })
                .collect(),
            combinations: self.id.gauge.as_ref().map_or_else(Vec::new, |g| {
                g.held
                    .iter()
                    .map(|h| Combination {
                        held: !self.with_priors,
                        relative_curvature: h.relative_curvature,
                        parameters: h
                            .parameters
                            .iter()
                            .map(|&(j, share)| crate::shared::Share {
                                name: model.params()[j].name.clone(),
                                share,
                            })
                            .collect(),
                    })
                    .collect()
            }),
            points: self
                .aligned
                .iter()
                .zip(&self.raw)
                .enumerate()
                .map(|(k, (u, r))| PointU {
                    commands: Self::commands(model, &request.grid, k),
                    tool_point_mm: u.tool_point_mm,
                    u95_um: um3(u.u95_mm()),
                    u95_data_um: um3(u.u95_data_mm),
                    u95_held_um: um3(u.u95_held_mm),
                    u95_raw_um: um3(r.u95_mm()),
                    u95_monte_carlo_um: mc_aligned.map(|m| {
                        [
                            m[3 * k] * UM_PER_MM,
                            m[3 * k + 1] * UM_PER_MM,
                            m[3 * k + 2] * UM_PER_MM,
                        ]
                    }),
                })
                .collect(),
            model_check: self.model_check.clone(),
            model_statement: self.model_check.statement(),
            objective: request.objective.to_string(),
            efficiency: self.efficiency.as_ref().map(EfficiencyU::from),
            monte_carlo: self.monte_carlo.as_ref().zip(request.monte_carlo).map(
                |((mc, _, _), (_, seed))| MonteCarloRun {
                    replicas: mc.samples.len(),
                    failed: mc.failed,
                    time_s: mc.time_s,
                    seed,
                },
            ),
        }
    }
}

/// The results file of the fit `id` of `model` to `data`, carrying its linearised uncertainty
/// (the gauge's rule, σ from the residuals or `noise`) and its check against the noise, as
/// `identify --out` writes it: what `compensate` and `tables` vouch for the errors with.
pub fn results_with_uncertainty(
    model: &Model,
    data: &volver_core::measure::MeasurementSet,
    id: &volver_solvers::strategy::Identification,
    noise: NoiseModel,
) -> Result<volver_core::results::ResultsFile> {
    let problem = volver_core::problem::Problem::new(model, data)?;
    let mut results = volver_core::results::ResultsFile::from_model(model, &id.params)?;
    let cov = volver_solvers::uncertainty::linear(
        &problem,
        id.gauge.as_ref(),
        &id.params,
        volver_solvers::Options::default().objective,
        noise,
    );
    if let Some(cov) = cov {
        let held = held_text(model, id.gauge.as_ref());
        let rule = crate::identification::gauge_rule(None, id);
        let mut record = cov.to_record(&rule, held);
        record.model_check = Some(check_fit(&problem, id, noise));
        results.uncertainty = Some(record);
    }
    Ok(results)
}

/// The mean ratio of Monte Carlo's U to the linearised data part of `us` over every coordinate
/// of every grid command (`mc`: three values per command, the same order) where the linearised U
/// exceeds 0.1 % of its largest: where it vanishes (the tool point at the reference of every
/// error, raw) the ratio would be Monte Carlo's rounding over zero. `NaN` when there is none.
///
/// ```
/// use volver_solvers::uncertainty::PointUncertainty;
/// let lin = |u: f64| PointUncertainty {
///     tool_point_mm: [0.0; 3],
///     u95_data_mm: [u; 3],
///     u95_held_mm: [0.0; 3],
///     worst_held: None,
/// };
/// // The first command's U vanishes: its Monte Carlo rounding does not count.
/// let us = [lin(0.0), lin(0.010)];
/// let mc = [1e-15, 1e-15, 1e-15, 0.011, 0.011, 0.011];
/// assert!((volver::uncertainty::monte_carlo_ratio(&us, &mc) - 1.1).abs() < 1e-12);
/// ```
pub fn monte_carlo_ratio(us: &[volver_solvers::uncertainty::PointUncertainty], mc: &[f64]) -> f64 {
    let largest = us.iter().flat_map(|u| u.u95_data_mm).fold(0.0, f64::max);
    let ratios: Vec<f64> = us
        .iter()
        .enumerate()
        .flat_map(|(i, u)| (0..3).map(move |c| (3 * i + c, u.u95_data_mm[c])))
        .filter(|&(_, l)| l > 1e-3 * largest)
        .map(|(i, l)| mc[i] / l)
        .collect();
    ratios.iter().sum::<f64>() / ratios.len() as f64
}

/// Refuses Monte Carlo with priors, and a number of replicas outside 2 … [`MAX_REPLICAS`], before the fit runs
/// (a count from the command line is bounded before anything is allocated for it).
///
/// [`MAX_REPLICAS`]: volver_solvers::uncertainty::MAX_REPLICAS
fn check_request(request: &Request, model: &Model) -> Result<()> {
    if let NoiseModel::Tracker(t) = request.noise {
        crate::shared::check_station_noises(model.machine(), &t)?;
    }
    use volver_solvers::uncertainty::MAX_REPLICAS;
    if request.priors.is_some() && request.monte_carlo.is_some() {
        return Err(Error::Request(
            "--monte-carlo with --prior: the Monte Carlo replicas re-fit the data's estimator; \
             the posterior of the priors is stated linearised only (run them apart)"
                .into(),
        ));
    }
    match request.monte_carlo {
        Some((n, _)) if !(2..=MAX_REPLICAS).contains(&n) => Err(Error::Request(format!(
            "--monte-carlo {n}: give 2 … {MAX_REPLICAS} replicas (a standard deviation needs \
             2; {MAX_REPLICAS} replicas of test 4 take about 15 min on two cores)"
        ))),
        _ => Ok(()),
    }
}

/// The Monte Carlo replicas an assessment asks for and their U95 per grid coordinate (after
/// the transform, raw; mm); `None` when it asks for none.
fn monte_carlo_run(
    model: &Model,
    data: &volver_core::measure::MeasurementSet,
    request: &Request,
    grid: &volver_solvers::uncertainty::ToolGrid,
    id: &volver_solvers::strategy::Identification,
    covariance: &volver_solvers::uncertainty::Covariance,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Option<MonteCarloU95>> {
    use volver_solvers::uncertainty::monte_carlo;
    let Some((n, seed)) = request.monte_carlo else {
        return Ok(None);
    };
    let options = volver_solvers::Options {
        objective: request.objective,
        ..Default::default()
    };
    let base = grid.points(model, &id.params);
    let mc = monte_carlo(
        &request.engine,
        model,
        data,
        &id.params,
        request.noise,
        covariance.sigma_mm,
        id.gauge.as_ref(),
        &options,
        n,
        seed,
        progress,
    )?;
    if mc.samples.len() < 2 {
        return Err(Error::NotSolved(format!(
            "Monte Carlo: {} of {n} replicas failed to solve, and a standard deviation needs \
             2 solved",
            mc.failed
        )));
    }
    let a = grid.monte_carlo_u95(model, &mc, &base, true);
    let r = grid.monte_carlo_u95(model, &mc, &base, false);
    Ok(Some((mc, a, r)))
}
