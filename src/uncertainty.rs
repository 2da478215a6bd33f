//! What the uncertainty of a fit needs beyond the solvers crate: the grids of commands over
//! which a tool point's uncertainty is stated, the noise model named on a command line, and the
//! words for a combination of parameters the data cannot identify.

use anyhow::{Result, bail};
use volver_core::machine::Machine;
use volver_core::model::Model;
use volver_core::noise::TrackerNoise;
use volver_core::plan::Plan;
use volver_solvers::gauge::Gauge;
use volver_solvers::uncertainty::NoiseModel;

/// A grid of `per_axis` evenly spaced positions over every axis' travel (a full-turn rotary
/// axis stops one step short of its end, which is its start).
pub fn default_grid(m: &Machine, per_axis: usize) -> Result<Plan> {
    let parts: Vec<String> = m
        .axes()
        .iter()
        .map(|ax| {
            let (a, b) = (ax.to_file_units(ax.min), ax.to_file_units(ax.max));
            let full_turn = ax.axis.is_rotary() && (b - a) >= 360.0 - 1e-9;
            let steps = if full_turn { per_axis } else { per_axis - 1 };
            let step = (b - a) / steps.max(1) as f64;
            let end = if full_turn { b - step } else { b };
            if step > 0.0 {
                format!("{}={a}:{end}:{step}", ax.axis)
            } else {
                format!("{}={a}", ax.axis)
            }
        })
        .collect();
    Ok(Plan::parse_grid(m, &parts.join(","))?)
}

/// The grid of `--grid` (a preset or a grid text), or the default.
pub fn grid_of(m: &Machine, text: Option<&str>) -> Result<Plan> {
    Ok(match text {
        Some(t) if t.contains('=') => Plan::parse_grid(m, t)?,
        Some(t) => Plan::preset(m, t)?,
        None => default_grid(m, 5)?,
    })
}

/// The noise model of `--noise`.
pub fn noise_of(text: Option<&str>) -> Result<NoiseModel> {
    Ok(match text {
        Some(t) => {
            let n = TrackerNoise::from_text(t)?;
            if n.is_none() {
                bail!("--noise {t}: a noise-free tracker gives no uncertainty; give its noise")
            }
            NoiseModel::Tracker(n)
        }
        None => NoiseModel::Residual,
    })
}

/// The names of the parameters a held combination moves, with their shares.
pub fn combination_text(model: &Model, gauge: &Gauge, c: usize) -> String {
    let parts: Vec<String> = gauge.held[c]
        .parameters
        .iter()
        .take(4)
        .map(|&(j, s)| format!("{} {s:+.2}", model.params()[j].name))
        .collect();
    parts.join(", ")
}
