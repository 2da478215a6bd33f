//! The truth of a synthetic test expressed in the fitted model's parametrisation, so that its
//! error functions can be drawn against the fit's: the same squareness rule, the same
//! reference, the same gauge.

use crate::error::{Error, Result};
use volver_core::measure::MeasurementSet;
use volver_core::model::Model;
use volver_core::problem::Problem;

/// A truth written in another model's parameters ([`truth_in_model`]).
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct TruthInModel {
    /// The parameters of the fitted model that reproduce the truth's points.
    pub params: Vec<f64>,
    /// What the model cannot express of the truth: the EMM (µm) left at those parameters
    /// (zero to the solver's precision when the truth lies in the model's span).
    pub misfit_um: f64,
}

/// The truth `truth` (its own model and parameters) in the parameters of `model`: `model`
/// fitted as an identification fits it ([`volver_solvers::strategy::fit`]: the same
/// constraints, squareness rule and gauge) to the truth's noise-free observations at the
/// commands, reflectors, stations and times of `data`. A squareness the truth carries
/// separately (its rule `separate`) thereby lands in the straightness slope the model's rule
/// puts it in, a constant or slope the tracker's pose takes up goes to the tracker, and what
/// the data cannot identify is held where the fit holds it. When the truth lies in the model's
/// span (the same errors, bases that hold its functions) the result is exact and the misfit
/// zero to the solver's precision; otherwise it is the least-squares image of the truth's
/// points in the model, what a fit of noise-free data would find, and the misfit says how far.
///
/// `Err` when the truth's machine is not the measurements' (another chain, other reflectors or
/// stations) or the fit fails.
pub fn truth_in_model(
    model: &Model,
    data: &MeasurementSet,
    truth: (&Model, &[f64]),
) -> Result<TruthInModel> {
    let (tm, tp) = truth;
    let (a, b) = (tm.machine(), model.machine());
    if a.chain() != b.chain() {
        return Err(Error::Mismatch(format!(
            "the truth's machine has chain {}, the measurements' {}",
            a.chain(),
            b.chain()
        )));
    }
    if a.reflectors().len() != b.reflectors().len() || a.stations().len() != b.stations().len() {
        return Err(Error::Mismatch(format!(
            "the truth's machine has {} reflectors and {} stations, the measurements' {} and {}",
            a.reflectors().len(),
            a.stations().len(),
            b.reflectors().len(),
            b.stations().len()
        )));
    }
    let mut clean = data.clone();
    for p in &mut clean.points {
        p.measured = tm.observe(p, tp);
    }
    let id = volver_solvers::strategy::fit(Problem::new(model, &clean)?);
    if id.termination.failed() {
        return Err(Error::NotSolved(format!(
            "expressing the truth in the model's parameters failed: {}",
            id.termination
        )));
    }
    Ok(TruthInModel {
        misfit_um: id.reached.stats.emm_um,
        params: id.params,
    })
}
