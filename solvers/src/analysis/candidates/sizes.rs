//! The sizes of what a candidate adds beyond the current model, and whether they are
//! plausible ([`crate::analysis::candidates::Score::size`], [`crate::analysis::candidates::Score::flag`]).

use super::novelty::Expressible;
use faer::Mat;
use volver_core::iso::Unit;
use volver_core::measure::MeasurementSet;
use volver_core::model::Model;
use volver_core::plausibility::{RATE_SPAN_H, limit};
use volver_core::units::{S_PER_H, UM_PER_MM, URAD_PER_RAD};

/// What a candidate's sizes are measured against: the current `model` fitted at `params`, the
/// candidate's `extended` model stepping from `start` (the fit carried over), its Jacobian `jac`
/// at `start` over the data points, and what the current model can express there.
pub(super) struct Sizing<'a> {
    /// The candidate's id.
    pub(super) id: &'a str,
    /// The current model.
    pub(super) model: &'a Model,
    /// The candidate's extended model.
    pub(super) extended: &'a Model,
    /// The current fit (the current model's parameters).
    pub(super) params: &'a [f64],
    /// What the current model can express at the data points.
    pub(super) expressible: &'a Expressible,
    /// The extended model's Jacobian at `start` over the data points (mm per parameter unit).
    pub(super) jac: &'a Mat<f64>,
    /// The extended model's start: the current fit carried over, new parameters zero.
    pub(super) start: &'a [f64],
    /// The rank tolerance (relative curvature).
    pub(super) tolerance: f64,
}

impl Sizing<'_> {
    /// The size of what the candidate adds beyond the current model when its extended model
    /// steps from `start` to `q` ([`crate::analysis::candidates::Score::size`]), in the unit returned;
    /// `None` when not finite.
    pub(super) fn size(&self, q: &[f64]) -> Option<(f64, Unit)> {
        let (model, extended, jac, start) = (self.model, self.extended, self.jac, self.start);
        let new = self
            .expressible
            .novelty((model, extended), jac, (start, q), self.tolerance)?;
        if self.id.starts_with("field:") {
            return Some((new.peak_um, Unit::Mm));
        }
        // Each added or raised function's lower coefficients take what they express of its new
        // ones (one function at a time: no swap between functions).
        let mut own = new.representative.clone();
        for t in extended.terms() {
            if model.term(t.id).is_none_or(|old| old.basis != t.basis) {
                let coefficients: Vec<usize> = t.params.clone().collect();
                let q = new.own_functions(extended, jac, start, (&coefficients, &new.fresh))?;
                for k in coefficients {
                    own[k] = q[k];
                }
            }
        }
        Some(implied_size(self.id, model, self.params, extended, &own))
    }

    /// The plausible bound of a size in `unit`, in its reporting unit (µm, µrad, µm/h, ppm):
    /// a size in a rate's unit is judged as a rate over the data's span ([`plausible`] of the
    /// candidate's first new parameter); a size in a length or an angle (a field's
    /// displacement, over t too) as that length or angle ([`limit`]).
    pub(super) fn bound(&self, data: &MeasurementSet, unit: Unit) -> f64 {
        let (model, extended) = (self.model, self.extended);
        let (scale, _) = unit.micro();
        let first_new = (0..extended.n_params())
            .find(|&j| model.param_index(&extended.params()[j].name).is_none())
            .unwrap_or(usize::MAX);
        let rate = matches!(unit, Unit::MmPerHour | Unit::RadPerHour | Unit::PpmPerHour);
        let bound = if rate {
            plausible(extended, data, first_new, unit)
        } else {
            limit(unit)
        };
        bound * scale
    }

    /// Why the candidate is not plausible, when it is not: its size (held to plausible sizes,
    /// `size` in `size_unit`) beyond `bound`, or evidence (`delta_bic`) that needs, without the
    /// bound, a size beyond it — the free step `qf` scoring `bic_free` below −10 and more than
    /// 10 better. `None` when the free step's size is not finite.
    pub(super) fn flag(
        &self,
        (size, size_unit, bound): (f64, &str, f64),
        (qf, bic_free): (&[f64], f64),
        delta_bic: f64,
    ) -> Option<Option<String>> {
        if size > bound {
            return Some(Some(format!(
                "its size, {size:.0} {size_unit}, exceeds the plausible {bound:.0} {size_unit}"
            )));
        }
        let (size_free, _) = self.size(qf)?;
        Some(
            (size_free > bound && bic_free < -10.0 && delta_bic - bic_free > 10.0).then(|| {
                format!(
                    "nearly unidentifiable: the data support it only with a size of \
                     {size_free:.0} {size_unit} (ΔBIC {bic_free:.0}), beyond the plausible \
                     {bound:.0} {size_unit}"
                )
            }),
        )
    }
}

/// The size of what the candidate adds, by its kind: for a new effect (drift, periodic
/// positioning error, reflector offset, range scale) the norm of its new parameters (µm/h, the
/// amplitude in µm, µm, ppm); for `tracker-tilt` the tilt it frees (µrad); for an added or raised
/// error function the largest change of that function over the travel (µm or µrad). Changes the
/// Gauss–Newton step makes to parameters the model already had (say the tracker's tilt, when the
/// model identifies it) are not the candidate's size.
fn implied_size(
    id: &str,
    model: &Model,
    params: &[f64],
    extended: &Model,
    q: &[f64],
) -> (f64, Unit) {
    // New effect parameters: the norm of each group (drift.x/y/z, screw.X.a/b …).
    let groups = extended.effect_sizes(q, |j| {
        model.param_index(&extended.params()[j].name).is_none()
    });
    if let Some(g) = groups.iter().max_by(|a, b| a.1.total_cmp(&b.1)) {
        return (g.1, g.3);
    }
    if id == "range-offset" {
        // The largest station offset, in µm.
        let largest = extended
            .stations()
            .iter()
            .filter_map(|b| b.offset)
            .map(|j| q[j].abs() * UM_PER_MM)
            .fold(0.0, f64::max);
        return (largest, Unit::Mm);
    }
    if id == "tracker-tilt" {
        let (ts, te) = (model.tracker_start(), extended.tracker_start());
        let tilt = ((q[te + 3] - params[ts + 3]).powi(2) + (q[te + 4] - params[ts + 4]).powi(2))
            .sqrt()
            * URAD_PER_RAD;
        return (tilt, Unit::Rad);
    }
    let mut best: (f64, Unit) = (0.0, Unit::Mm);
    for t in extended.terms() {
        if model.term(t.id).is_some_and(|old| old.basis == t.basis) {
            continue;
        }
        let ax = &extended.machine().axes()[t.axis];
        let scale = t.id.unit().micro();
        let peak = (0..=64)
            .map(|i| {
                let u = ax.min + (ax.max - ax.min) * i as f64 / 64.0;
                let new = extended.error_value(t.id, u, q).unwrap_or(0.0);
                let old = model.error_value(t.id, u, params).unwrap_or(0.0);
                (new - old).abs() * scale.0
            })
            .fold(0.0, f64::max);
        if peak > best.0 {
            best = (peak, t.id.unit());
        }
    }
    best
}

/// The plausible size of parameter `j` of `model` (in `unit`, [`limit`]); for a rate over time
/// (a drift, a field's `tᵖ`, [`Model::time_power`]) the rate that moves it by [`limit`] ×
/// ([`RATE_SPAN_H`] h)ᵖ over the data's span `T` (h), `limit × (24 / T)ᵖ`, so that the diagnosis
/// does not depend on the unit of the time stamps (the rule of
/// [`volver_core::plausibility::Context::time_span_h`]).
pub(super) fn plausible(
    model: &Model,
    data: &volver_core::measure::MeasurementSet,
    j: usize,
    unit: Unit,
) -> f64 {
    let span_h = data.time_span_s().filter(|&t| t > 0.0).map(|t| t / S_PER_H);
    match (span_h, j < model.n_params()) {
        (Some(t), true) if model.time_power(j) > 0 => {
            limit(unit) * (RATE_SPAN_H / t).powi(model.time_power(j) as i32)
        }
        _ => limit(unit),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::observability::nominal_data;
    use volver_core::plan::Plan;
    use volver_core::simulate::DEFAULT_SECONDS_PER_POINT;

    /// A drift (mm/h) is plausible up to the rate that moves the tool point by the length
    /// bound over 24 h, scaled to the data's span: `limit × 24 h / T`; a length is judged by the
    /// bound alone.
    #[test]
    fn a_rate_is_plausible_over_the_data_span() {
        let base = Model::default_xcfz();
        let mut spec = base.spec().clone();
        spec.effects.thermal_drift = true;
        let model = Model::new(base.machine().clone(), spec).expect("a model");
        let plan = Plan::preset(model.machine(), "test3").expect("a preset");
        let data = nominal_data(&model, &plan);
        let span_h = (data.points.len() - 1) as f64 * DEFAULT_SECONDS_PER_POINT / S_PER_H;
        let j = model.param_index("drift.x").expect("the drift");
        let rate = plausible(&model, &data, j, Unit::MmPerHour);
        let want = limit(Unit::MmPerHour) * RATE_SPAN_H / span_h;
        assert!((rate - want).abs() < 1e-12 * want, "{rate} against {want}");
        let length = model.param_index("EXX.c1").expect("EXX");
        assert_eq!(plausible(&model, &data, length, Unit::Mm), limit(Unit::Mm));
    }
}
