//! What each estimator can get out of a plan and a noise, against the physical limit: the
//! expected error of the tool point (after the set-up's rigid transform) of Φ, ve, ml and
//! whitened Φ, each from its linearised covariance ([`crate::uncertainty::linear`]: the sandwich
//! for Φ, ve and whitened Φ, the inverse whitened information for ml), beside the
//! **Cramér–Rao limit** — the smallest covariance any unbiased estimator can reach.
//!
//! For normal noise the limit is the inverse Fisher information `(Σ J_iᵀ Σ_i⁻¹ J_i)⁻¹`, each
//! point weighed by the inverse covariance of its station's noise at the point (the tracker's
//! spherical model; a range by its range σ): exactly the covariance of the ml estimate, which is
//! efficient there. For a bounded (uniform) noise the Fisher information is not defined; the
//! figure stated is then the same matrix for the noise's covariance, the Gauss–Markov limit of
//! the estimators linear in the data (and the Cramér–Rao limit of a normal noise of that
//! covariance).
//!
//! The expected error is the RMS over the grid of the tool point's 3-D error,
//! `√(tr(G C Gᵀ)/K)` for the grid's K tool points, G their Jacobian after the transform and C
//! the covariance from the data (the combinations the gauge holds are a rule, not information,
//! and are left out).
//!
//! ```
//! use volver_core::{machine::Machine, model::Model, plan::Plan, problem::Problem};
//! use volver_core::noise::TrackerNoise;
//! use volver_core::simulate::{Magnitudes, Simulation, Truth};
//! use volver_solvers::efficiency::compare;
//! use volver_solvers::uncertainty::{NoiseModel, ToolGrid};
//! use volver_solvers::Objective;
//! let m = Machine::default_xcfz();
//! let truth = Truth::random_complete(&m, &Magnitudes::default(), 2).unwrap();
//! let noise = TrackerNoise::from_text("normal:30,30,4,0.8").unwrap();
//! let mut sim = Simulation::new(Plan::preset(&m, "test3").unwrap(), truth, 2);
//! sim.noise = noise;
//! let data = sim.run().unwrap().measurements;
//! let model = Model::default_xcfz();
//! let problem = Problem::new(&model, &data).unwrap();
//! let id = volver_solvers::strategy::fit(problem.clone());
//! let grid = ToolGrid {
//!     commands: Plan::parse_grid(&m, "X=0:1400:700,C=0:270:90,Z=0:600:300").unwrap().positions,
//!     tool: [0.0, 0.0, 0.0],
//! };
//! let e = compare(&problem, id.gauge.as_ref(), &id.params, NoiseModel::Tracker(noise), &grid)
//!     .unwrap();
//! // No estimator beats the limit; ml is at it (it is the limit's own covariance).
//! let ml = e.expected_mm(Objective::Ml).unwrap();
//! assert!((ml / e.limit_mm - 1.0).abs() < 1e-6);
//! for (_, v) in &e.estimators {
//!     assert!(*v >= e.limit_mm * (1.0 - 1e-6));
//! }
//! ```

use crate::Objective;
use crate::engines::gauge::Gauge;
use crate::uncertainty::{Covariance, NoiseModel, ToolGrid, linear};
use volver_core::problem::Problem;

/// Each estimator's expected tool-point error and the Cramér–Rao limit, on one plan and noise.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Efficiency {
    /// The limit: the RMS tool-point error (mm, 3-D, after the set-up's transform, k = 1) of
    /// the inverse Fisher information (see the module).
    pub limit_mm: f64,
    /// Each estimator (Φ, ve, ml, whitened Φ) and its expected RMS tool-point error (mm, the
    /// same measure); an estimator whose covariance cannot be formed is left out.
    pub estimators: Vec<(Objective, f64)>,
    /// Whether every station's noise is normal: the limit is then the Cramér–Rao limit and ml
    /// the maximum-likelihood estimate; else (a bounded noise) the Gauss–Markov limit of the
    /// estimators linear in the data, and ml is noise-weighted least squares.
    pub normal: bool,
}

impl Efficiency {
    /// The expected error of `objective` (mm), if it was formed.
    pub fn expected_mm(&self, objective: Objective) -> Option<f64> {
        self.estimators
            .iter()
            .find(|(o, _)| *o == objective)
            .map(|e| e.1)
    }
}

/// The expected RMS 3-D tool-point error over `grid` (mm, k = 1) under the data's part of
/// `cov`, after the set-up's rigid transform: `√(tr(G C Gᵀ)/K)`.
pub fn expected_rms_mm(
    grid: &ToolGrid,
    model: &volver_core::model::Model,
    params: &[f64],
    cov: &Covariance,
) -> f64 {
    rms_through(&grid.jacobian(model, params, true), cov)
}

/// [`expected_rms_mm`] through the grid's Jacobian after the transform `g` (3K × n).
fn rms_through(g: &faer::Mat<f64>, cov: &Covariance) -> f64 {
    let y = g * &cov.data;
    let k = (g.nrows() / 3).max(1) as f64;
    let mut sum = 0.0;
    for r in 0..y.nrows() {
        for c in 0..y.ncols() {
            sum += y[(r, c)] * y[(r, c)];
        }
    }
    (sum / k).sqrt()
}

/// The realised RMS 3-D tool-point error (mm) of deviations `dev` (3K values, point-major, as
/// [`ToolGrid::deviations`] gives them).
pub fn realised_rms_mm(dev: &[f64]) -> f64 {
    let k = (dev.len() / 3).max(1) as f64;
    (dev.iter().map(|v| v * v).sum::<f64>() / k).sqrt()
}

/// The Cramér–Rao limit of the plan of `problem` under the tracker noise `noise` (each station
/// its own where the machine file states one) at `params`, with `gauge`'s combinations held:
/// the inverse whitened information (see the module). `None` without a tracker noise model, or
/// when a decomposition fails.
pub fn cramer_rao(
    problem: &Problem,
    gauge: Option<&Gauge>,
    params: &[f64],
    noise: NoiseModel,
) -> Option<Covariance> {
    match noise {
        NoiseModel::Tracker(_) => linear(problem, gauge, params, Objective::Ml, noise),
        _ => None,
    }
}

/// Every estimator's expected tool-point error on `grid` beside the Cramér–Rao limit, for the
/// plan of `problem` at `params` under `noise` (a tracker model: `None` for the residuals'
/// isotropic σ, which weighs every direction alike and has no limit of its own to state).
pub fn compare(
    problem: &Problem,
    gauge: Option<&Gauge>,
    params: &[f64],
    noise: NoiseModel,
    grid: &ToolGrid,
) -> Option<Efficiency> {
    let model = problem.model();
    let limit = cramer_rao(problem, gauge, params, noise)?;
    // The tool points' Jacobian after the transform, once for every covariance.
    let g = grid.jacobian(model, params, true);
    let limit_mm = rms_through(&g, &limit);
    let estimators = Objective::ALL
        .iter()
        .filter_map(|&o| {
            let cov = if o == Objective::Ml {
                limit.clone()
            } else {
                linear(problem, gauge, params, o, noise)?
            };
            Some((o, rms_through(&g, &cov)))
        })
        .collect();
    let machine = model.machine();
    let normal = match noise {
        NoiseModel::Tracker(t) => (0..machine.stations().len()).all(|k| {
            machine.station_noise_or(k, t).distribution == volver_core::noise::Distribution::Normal
        }),
        _ => false,
    };
    Some(Efficiency {
        limit_mm,
        estimators,
        normal,
    })
}
