//! Plans compared on simulated truths (`volver plan --compare`): the realised tool-point error
//! of each plan's fit against the truth, the coverage of its predicted U, and whether a hidden
//! drift is found.

use super::Nominal;
use crate::error::{Error, Result};
use serde::Serialize;
use volver_core::model::Model;
use volver_core::noise::TrackerNoise;
use volver_core::plan::Plan;
use volver_core::problem::Problem;
use volver_core::simulate::{Effect, Magnitudes, Simulation, Truth};
use volver_core::units::UM_PER_MM;
use volver_solvers::uncertainty::{NoiseModel, ToolGrid};

/// One simulated test of a compared plan: its fit's tool-point error and how many coordinates
/// its U (k = 2) covers.
struct Replica {
    /// EMM of the identified tool point over the grid, after the set-up's transform (µm).
    emm_um: f64,
    /// Coordinates within their U.
    inside: usize,
    /// Coordinates checked.
    total: usize,
}

/// Simulates `plan` on `truth` with `noise` (seed `seed`), fits `model` and checks the tool
/// point over `tg` against the truth.
fn replica(
    model: &Model,
    plan: &Plan,
    truth: &Truth,
    seed: u64,
    noise: &TrackerNoise,
    tg: &ToolGrid,
    label: &str,
) -> Result<Replica> {
    let mut sim = Simulation::new(plan.clone(), truth.clone(), seed);
    sim.noise = *noise;
    let data = sim.run()?.measurements;
    let problem = Problem::new(model, &data)?;
    let id = volver_solvers::strategy::fit(problem.clone());
    if id.termination.failed() {
        return Err(Error::NotSolved(format!(
            "{label}, seed {seed}: {}",
            id.termination
        )));
    }
    let base = tg.points(&truth.model, &truth.params);
    let d = tg.deviations(model, &id.params, &base, true);
    let emm = (0..base.len())
        .map(|k| (d[3 * k].powi(2) + d[3 * k + 1].powi(2) + d[3 * k + 2].powi(2)).sqrt())
        .sum::<f64>()
        / base.len() as f64;
    let cov = volver_solvers::uncertainty::linear(
        &problem,
        id.gauge.as_ref(),
        &id.params,
        volver_solvers::Objective::Phi,
        NoiseModel::Tracker(*noise),
    )
    .ok_or_else(|| Error::Singular(format!("{label}, seed {seed}: the fit's covariance")))?;
    let (mut inside, mut total) = (0usize, 0usize);
    for (k, u) in tg
        .uncertainty(model, &id.params, &cov, true)
        .iter()
        .enumerate()
    {
        let u = u.u95_mm();
        for c in 0..3 {
            total += 1;
            inside += usize::from(d[3 * k + c].abs() <= u[c]);
        }
    }
    Ok(Replica {
        emm_um: emm * UM_PER_MM,
        inside,
        total,
    })
}

/// Whether the diagnosis of `plan` simulated on `truth` with `effect` (seed `seed`) finds the
/// effect first.
fn drift_found(
    model: &Model,
    plan: &Plan,
    truth: Truth,
    seed: u64,
    noise: &TrackerNoise,
    effect: &Effect,
) -> Result<bool> {
    let mut sim = Simulation::new(plan.clone(), truth, seed);
    sim.noise = *noise;
    sim.effects = vec![effect.clone()];
    let data = sim.run()?.measurements;
    let diagnosis = crate::diagnosis::diagnose_with(model, &data, Some(noise))?;
    let name = effect.id();
    Ok(diagnosis.finding().is_some_and(|c| c.id.starts_with(name)))
}

/// One plan of a comparison.
#[derive(Clone, Debug, Serialize)]
pub struct Compared {
    /// The plan's label (as given).
    pub label: String,
    /// Its measurements.
    pub points: usize,
    /// Predicted U (k = 2) of the tool point after the set-up's transform, mean over the grid
    /// (µm).
    pub u95_mean_um: f64,
    /// The realised error of the identified tool point against the truth after the set-up's
    /// transform: EMM over the grid, mean over the seeds (µm).
    pub realised_emm_um: f64,
    /// The same per seed (µm).
    pub realised_per_seed_um: Vec<f64>,
    /// The share of grid coordinates whose realised deviation is within the U predicted for
    /// the fit of that seed, over every seed.
    pub coverage: f64,
    /// Seeds where a hidden drift (`drift`) was the diagnosis' finding, of those run.
    pub drift_found: usize,
    /// Seeds run with the drift.
    pub drift_runs: usize,
}

/// Compares `plans` on `seeds` simulated truths (random errors of `model`'s structure at the
/// default magnitudes, seeds 1…`seeds`, the tracker's `noise`): see [`Compared`]. With `drift`
/// (an effect such as `thermal-drift=10,-5,60`), each seed is also simulated with it hidden
/// and diagnosed with `model`.
pub fn compare(
    model: &Model,
    plans: &[(String, Plan)],
    seeds: u64,
    noise: &TrackerNoise,
    tool: [f64; 3],
    drift: Option<&str>,
) -> Result<Vec<Compared>> {
    let machine = model.machine();
    let grid = crate::shared::default_grid(machine, 5)?;
    let tg = ToolGrid {
        commands: grid.positions.clone(),
        tool,
    };
    let drift = drift.map(Effect::parse).transpose()?;
    let mut rows = Vec::new();
    for (label, plan) in plans {
        let (u95_mean_um, _) =
            Nominal::of(model, plan)?.predicted_u(model, noise, tool, &grid.positions)?;
        let mut realised = Vec::new();
        let (mut inside, mut total) = (0usize, 0usize);
        let (mut found, mut runs) = (0usize, 0usize);
        for seed in 1..=seeds {
            let truth = Truth::random(machine, model.spec(), &Magnitudes::default(), seed)?;
            let r = replica(model, plan, &truth, seed, noise, &tg, label)?;
            realised.push(r.emm_um);
            inside += r.inside;
            total += r.total;
            if let Some(effect) = &drift {
                runs += 1;
                found += usize::from(drift_found(model, plan, truth, seed, noise, effect)?);
            }
        }
        rows.push(Compared {
            label: label.clone(),
            points: plan.n_points(),
            u95_mean_um,
            realised_emm_um: realised.iter().sum::<f64>() / realised.len().max(1) as f64,
            realised_per_seed_um: realised,
            coverage: inside as f64 / total.max(1) as f64,
            drift_found: found,
            drift_runs: runs,
        });
    }
    Ok(rows)
}
