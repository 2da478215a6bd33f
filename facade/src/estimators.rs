//! The estimators side by side on one data set: Φ (the paper's), ml (maximum likelihood:
//! least squares on the residuals whitened by each station's noise) and whitened Φ, each fitted
//! by the native engine, with its expected tool-point error and U from its own linearised
//! covariance, the realised error against the truth when it is known, and the Cramér–Rao limit
//! of the plan and noise (see [`volver_solvers::efficiency`]). What `volver demo` and
//! `volver study paper` print.
//!
//! Every error is the RMS over the grid of the tool point's 3-D error after the set-up's rigid
//! transform (µm); U is the largest expanded uncertainty (k = 2) of a coordinate over the grid.

use crate::error::{Error, Result};
use serde::Serialize;
use volver_core::measure::MeasurementSet;
use volver_core::model::Model;
use volver_core::noise::TrackerNoise;
use volver_core::problem::Problem;
use volver_core::simulate::Truth;
use volver_core::units::UM_PER_MM;
use volver_solvers::efficiency::{cramer_rao, expected_rms_mm, realised_rms_mm};
use volver_solvers::uncertainty::{NoiseModel, ToolGrid, linear};
use volver_solvers::{Objective, Options, Silent};

/// The estimators the demo and the study compare.
pub const COMPARED: [Objective; 3] = [Objective::Phi, Objective::Ml, Objective::PhiW];

/// One estimator on the data.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[non_exhaustive]
pub struct Row {
    /// The estimator.
    pub objective: Objective,
    /// The realised RMS tool-point error against the truth (µm), when it is known.
    pub realised_um: Option<f64>,
    /// The expected RMS tool-point error from its covariance (µm, k = 1).
    pub expected_um: f64,
    /// The largest U (k = 2) of a tool-point coordinate over the grid (µm).
    pub u95_max_um: f64,
    /// The fit's EMM (µm).
    pub emm_um: f64,
    /// Wall time of the fit (s).
    pub time_s: f64,
}

/// The estimators side by side and the limit.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[non_exhaustive]
pub struct SideBySide {
    /// One row per estimator of [`COMPARED`].
    pub rows: Vec<Row>,
    /// The Cramér–Rao limit (µm, the same measure as `expected_um`), at the ml fit; for a
    /// bounded noise (`normal` false) the Gauss–Markov limit of the estimators linear in the
    /// data.
    pub cramer_rao_um: f64,
    /// Whether the noise is normal (see `cramer_rao_um`).
    pub normal: bool,
}

impl SideBySide {
    /// The limit's name: "Cramér–Rao limit" for normal noise, "Gauss–Markov limit" for a
    /// bounded one.
    pub fn limit_name(&self) -> &'static str {
        if self.normal {
            "Cramér–Rao limit"
        } else {
            "Gauss–Markov limit"
        }
    }
}

/// Fits `data` with `model` by each estimator of [`COMPARED`] under the tracker noise `noise`
/// and judges the tool points of `grid` (against `truth` when given).
///
/// ```
/// use volver::core::{model::Model, noise::TrackerNoise, plan::Plan};
/// use volver::core::simulate::{Magnitudes, Simulation, Truth};
/// use volver::solvers::uncertainty::ToolGrid;
/// let model = Model::default_xcfz();
/// let m = model.machine();
/// let truth = Truth::random(m, model.spec(), &Magnitudes::default(), 3).unwrap();
/// let mut sim = Simulation::new(Plan::preset(m, "test3").unwrap(), truth.clone(), 3);
/// sim.noise = TrackerNoise::PAPER;
/// let data = sim.run().unwrap().measurements;
/// let grid = ToolGrid {
///     commands: Plan::parse_grid(m, "X=0:1400:700,C=0:270:90,Z=0:600:300").unwrap().positions,
///     tool: volver::shared::reflector_centroid(&model),
/// };
/// let s = volver::estimators::side_by_side(&model, &data, TrackerNoise::PAPER, &grid, Some(&truth))
///     .unwrap();
/// assert_eq!(s.rows.len(), 3);
/// assert!(s.rows.iter().all(|r| r.expected_um >= s.cramer_rao_um * (1.0 - 1e-6)));
/// ```
pub fn side_by_side(
    model: &Model,
    data: &MeasurementSet,
    noise: TrackerNoise,
    grid: &ToolGrid,
    truth: Option<&Truth>,
) -> Result<SideBySide> {
    let problem = Problem::new(model, data)?;
    let noise = NoiseModel::Tracker(noise);
    let mut rows = Vec::new();
    let mut limit = None;
    for objective in COMPARED {
        let fitted = crate::identification::fitted_problem(&problem, objective, noise)?;
        let options = Options {
            objective,
            max_iterations: 1000,
            max_evaluations: 10_000,
            ..Options::default()
        };
        let id = volver_solvers::strategy::identify(
            &volver_solvers::lm::LevenbergMarquardt::default(),
            fitted,
            &model.initial_params(),
            &volver_solvers::strategy::Strategy::default(),
            &options,
            &mut Silent,
        );
        if id.termination.failed() {
            return Err(Error::NotSolved(format!(
                "the {objective} fit {}",
                id.termination
            )));
        }
        let singular = || Error::Singular(format!("the {objective} fit's covariance"));
        let cov = linear(&problem, id.gauge.as_ref(), &id.params, objective, noise)
            .ok_or_else(singular)?;
        if objective == Objective::Ml {
            let c =
                cramer_rao(&problem, id.gauge.as_ref(), &id.params, noise).ok_or_else(singular)?;
            limit = Some(expected_rms_mm(grid, model, &id.params, &c) * UM_PER_MM);
        }
        let base = grid.points(model, &id.params);
        let realised = truth.map(|t| {
            realised_rms_mm(&grid.deviations(&t.model, &t.params, &base, true)) * UM_PER_MM
        });
        let u95_max_um = grid
            .uncertainty(model, &id.params, &cov, true)
            .iter()
            .map(|u| u.u95_max_mm())
            .fold(0.0, f64::max)
            * UM_PER_MM;
        rows.push(Row {
            objective,
            realised_um: realised,
            expected_um: expected_rms_mm(grid, model, &id.params, &cov) * UM_PER_MM,
            u95_max_um,
            emm_um: id.reached.stats.emm_um,
            time_s: id.time_s,
        });
    }
    Ok(SideBySide {
        rows,
        cramer_rao_um: limit.unwrap_or(f64::NAN),
        normal: match noise {
            NoiseModel::Tracker(t) => t.distribution == volver_core::noise::Distribution::Normal,
            _ => false,
        },
    })
}

/// [`side_by_side`] over random truths (default magnitudes, the seeds `seeds`) of `model`
/// measured by `plan` under `noise`: each figure the RMS over the truths (U95 the mean of the
/// largest), the limit likewise. `Err` when no seed is given or a fit fails.
pub fn over_truths(
    model: &Model,
    plan: &volver_core::plan::Plan,
    noise: TrackerNoise,
    grid: &ToolGrid,
    seeds: std::ops::Range<u64>,
) -> Result<SideBySide> {
    use volver_core::simulate::{Magnitudes, Simulation};
    let n = seeds.end.saturating_sub(seeds.start) as f64;
    if n == 0.0 {
        return Err(Error::Request(
            "no truth to compare the estimators on".into(),
        ));
    }
    let mut sum: Option<SideBySide> = None;
    for seed in seeds {
        let truth = Truth::random(model.machine(), model.spec(), &Magnitudes::default(), seed)?;
        let mut sim = Simulation::new(plan.clone(), truth.clone(), seed);
        sim.noise = noise;
        let data = sim.run()?.measurements;
        let s = side_by_side(model, &data, noise, grid, Some(&truth))?;
        let sq = |v: f64| v * v / n;
        sum = Some(match sum {
            None => SideBySide {
                cramer_rao_um: sq(s.cramer_rao_um),
                normal: s.normal,
                rows: s
                    .rows
                    .into_iter()
                    .map(|r| Row {
                        realised_um: r.realised_um.map(sq),
                        expected_um: sq(r.expected_um),
                        u95_max_um: r.u95_max_um / n,
                        emm_um: r.emm_um / n,
                        ..r
                    })
                    .collect(),
            },
            Some(mut acc) => {
                acc.cramer_rao_um += sq(s.cramer_rao_um);
                for (a, r) in acc.rows.iter_mut().zip(s.rows) {
                    a.realised_um = a.realised_um.zip(r.realised_um).map(|(a, b)| a + sq(b));
                    a.expected_um += sq(r.expected_um);
                    a.u95_max_um += r.u95_max_um / n;
                    a.emm_um += r.emm_um / n;
                    a.time_s += r.time_s;
                }
                acc
            }
        });
    }
    let mut s = sum.expect("at least one seed");
    s.cramer_rao_um = s.cramer_rao_um.sqrt();
    for r in &mut s.rows {
        r.realised_um = r.realised_um.map(f64::sqrt);
        r.expected_um = r.expected_um.sqrt();
    }
    Ok(s)
}
