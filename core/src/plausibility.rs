//! Plausibility of identified errors: sizes no machine tool has point at a wrong input (a
//! mirrored tracker frame, swapped measurement columns, a typo in an axis offset, another unit),
//! not at the machine. Each kind has a stated limit, far above any machine that is worth
//! verifying and far below what such input faults produce (metres):
//!
//! | what | limit |
//! |---|---|
//! | a translation error over its axis' travel (EXX, EYC …), a location error (X0C …), a reflector offset, a periodic positioning error's amplitude | [`MAX_TRANSLATION_MM`] = 1 mm |
//! | a rotation error over its axis' travel (EAX, ECC …), a squareness or location tilt (B0Z, A0C …) | [`MAX_ANGLE_RAD`] = 1 mrad (1 mm per metre) |
//! | a reversal value B (`reversal.X.b`, ISO 230-2: a few µm to tens of µm on a linear axis, a few to tens of µrad on a rotary table; the norm of a reversal function's coefficients) | [`MAX_TRANSLATION_MM`] = 1 mm on a linear axis, [`MAX_ANGLE_RAD`] = 1 mrad on a rotary one |
//! | a thermal drift | 1 mm/h |
//! | a range scale | 1 000 ppm |
//! | a scale growing with time | [`MAX_SCALE_GROWTH_PPM_PER_H`] = 100 ppm/h (steel at 9 K/h) |
//! | a location drifting with time | 1 mm/h |
//! | the tracker's orientation drifting with time | 1 mrad/h |
//! | a generic field's coefficients (in the diagnosis: the largest displacement it adds beyond what the rest of the model expresses, `volver_solvers::candidates`) | [`MAX_TRANSLATION_MM`] = 1 mm |
//! | the tracker's pose against its rigid fit to the measurements (errors zero) | [`MAX_TRACKER_SHIFT_MM`] = 25 mm, 5 mrad |
//! | the EMM the fit leaves | [`MAX_TRANSLATION_MM`] = 1 mm |
//!
//! The diagnosis applies these limits to what a candidate adds beyond the current model, not to
//! its raw coefficients (which may trade metres against the model's own parameters along
//! directions the model already expresses). Parameters read from a results file are checked against ten times these limits
//! ([`Context::relaxed`]). A value is implausible only when it exceeds its limit by more than its expanded uncertainty
//! (k = 2) when the covariance is given: a value the data barely determine is not evidence of
//! a wrong input. Values along directions the data do not determine at all mean nothing and
//! must be removed first (the minimum-norm representative of the fit,
//! `volver_solvers::identifiability::Identifiability::minimum_norm`).
//!
//! ```
//! use volver_core::model::Model;
//! use volver_core::plausibility::{Context, check};
//! let model = Model::default_xcfz();
//! let mut p = model.initial_params();
//! assert!(check(&model, &p, &Context::default()).is_empty());
//! p[model.param_index("EYC.d").unwrap()] = 1.8; // 1.8 mm of radial error: an offset typo
//! let found = check(&model, &p, &Context::default());
//! assert_eq!(found[0].name, "EYC");
//! assert!(found[0].to_string().contains("1800 µm"));
//! ```

use crate::iso::Unit;
use crate::model::Model;
use crate::units::{UM_PER_MM, URAD_PER_RAD};
use std::fmt;

/// Largest plausible translation error (mm).
pub const MAX_TRANSLATION_MM: f64 = 1.0;
/// Largest plausible growth of an axis' scale with time (ppm/h): steel (11.5 ppm/K) warming
/// by 9 K an hour.
pub const MAX_SCALE_GROWTH_PPM_PER_H: f64 = 100.0;
/// The time over which a rate's per-hour limit is the plausible change (h): a day. A drift is
/// judged by what it moves over the test, at most its limit × 24 h (1 mm/h: 24 mm), which the
/// time stamps' unit does not change; tests up to a day are judged no stricter than by the rate
/// itself (only gross faults, a unit off by orders, are caught).
pub const RATE_SPAN_H: f64 = 24.0;
/// Largest plausible rotation error (rad).
pub const MAX_ANGLE_RAD: f64 = 1e-3;
/// Largest plausible shift of the tracker from its rigid fit (mm); its angles: 5 mrad.
pub const MAX_TRACKER_SHIFT_MM: f64 = 25.0;
const MAX_TRACKER_TURN_RAD: f64 = 5e-3;

/// The largest plausible size of a value in `unit` (in that unit): a translation
/// [`MAX_TRANSLATION_MM`], an angle [`MAX_ANGLE_RAD`] (and per hour), a drift 1 mm/h, a scale 1 000 ppm, a scale
/// growth [`MAX_SCALE_GROWTH_PPM_PER_H`].
///
/// ```
/// use volver_core::iso::Unit;
/// use volver_core::plausibility::limit;
/// assert_eq!(limit(Unit::Mm), 1.0);
/// assert_eq!(limit(Unit::Rad), 1e-3);
/// ```
pub fn limit(unit: Unit) -> f64 {
    match unit {
        Unit::Mm => MAX_TRANSLATION_MM,
        Unit::MmPerHour => 1.0,
        Unit::RadPerHour => MAX_ANGLE_RAD,
        Unit::Ppm => 1e3,
        Unit::PpmPerHour => MAX_SCALE_GROWTH_PPM_PER_H,
        Unit::Rad => MAX_ANGLE_RAD,
    }
}

/// An identified size beyond its limit.
#[derive(Clone, Debug, PartialEq)]
pub struct Implausible {
    /// The error (`EYC`), effect parameter group (`screw.X.200`) or `tracker`.
    pub name: String,
    /// Its largest magnitude, in `unit`.
    pub value: f64,
    /// The limit, in `unit`.
    pub limit: f64,
    /// `µm`, `µrad`, `µm/h` or `ppm`.
    pub unit: &'static str,
}

impl fmt::Display for Implausible {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Whole units, or two or three significant digits below one (a rate per hour of stamps in
        // µs read as seconds is tiny).
        let shown = |v: f64| {
            if v.abs() >= 1.0 || v == 0.0 {
                format!("{v:.0}")
            } else if v.abs() >= 0.01 {
                format!("{v:.3}")
            } else {
                format!("{v:.2e}")
            }
        };
        write!(
            f,
            "{} reaches {} {} (plausible: up to {} {})",
            self.name,
            shown(self.value),
            self.unit,
            shown(self.limit),
            self.unit
        )
    }
}

/// What to check when identified sizes are implausible, for messages.
pub const WHERE_TO_LOOK: &str = "sizes like these come from the input, not the machine: check \
     the machine file (the chain's order, axis offsets, reflector offsets, the tracker's mount \
     and orientation) and the measurement file (the meas_x, meas_y, meas_z columns' order and \
     signs, a mirrored tracker frame, the units)";

/// `true` when `v` exceeds `limit` or is not a number.
fn beyond(v: f64, limit: f64) -> bool {
    v.is_nan() || v > limit
}

/// What [`check`] may use besides the parameters.
#[derive(Clone, Copy, Debug, Default)]
pub struct Context<'a> {
    /// The tracker pose of the rigid fit the identification started from.
    pub tracker_start: Option<&'a [f64]>,
    /// A factor `F` of the parameters' covariance (`Cov = F Fᵀ`, one column per identified
    /// direction, in the parameters' units).
    pub covariance_factor: Option<&'a [Vec<f64>]>,
    /// The EMM the fit leaves (µm).
    pub emm_um: Option<f64>,
    /// Ten times every limit: for parameters read from a results file, which carries no
    /// covariance and whose values along unidentified directions are wherever the fit left
    /// them (only gross input faults are caught then).
    pub relaxed: bool,
    /// The span of the measurements' time stamps (h, [`crate::measure::MeasurementSet::time_span_s`]):
    /// a rate over time (mm/h, rad/h, ppm/h) is then judged by what it moves over the test,
    /// against its per-hour limit over [`RATE_SPAN_H`] (its limit × 24 h / span as a rate), so
    /// that the verdict does not depend on the unit of the stamps. `None` (a results file, which
    /// keeps no span): the rate itself against its limit.
    pub time_span_h: Option<f64>,
}

/// The implausible sizes of `params` (most implausible first).
pub fn check(model: &Model, params: &[f64], context: &Context) -> Vec<Implausible> {
    let mut out = Vec::new();
    let k = if context.relaxed { 10.0 } else { 1.0 };
    if let Some(emm) = context.emm_um
        && beyond(emm, MAX_TRANSLATION_MM * UM_PER_MM)
    {
        out.push(Implausible {
            name: "the fit's EMM".into(),
            value: emm,
            limit: MAX_TRANSLATION_MM * UM_PER_MM,
            unit: "µm",
        });
    }
    let judged = Judged {
        model,
        params,
        context,
        k,
    };
    out.extend(judged.implausible_errors());
    out.extend(judged.implausible_effects());
    if let Some(start) = context.tracker_start {
        out.extend(implausible_tracker_moves(model, params, start));
    }
    out.sort_by(|a, b| (b.value / b.limit).total_cmp(&(a.value / a.limit)));
    out
}

/// The parameters judged, in their model and context, against `k` times the limits.
struct Judged<'a> {
    /// The model.
    model: &'a Model,
    /// Its parameter values.
    params: &'a [f64],
    /// What is known besides them.
    context: &'a Context<'a>,
    /// The factor on every limit (10 when relaxed).
    k: f64,
}

impl Judged<'_> {
    /// The error functions whose peak over the travel (less its expanded uncertainty) is beyond
    /// `k` times its limit (µm, µrad).
    fn implausible_errors(&self) -> Vec<Implausible> {
        let Judged {
            model,
            params,
            context,
            k,
        } = *self;
        let mut out = Vec::new();
        // Expanded uncertainty (k = 2) of a linear function with gradient g.
        let expanded = |g: &[(usize, f64)]| -> f64 {
            context.covariance_factor.map_or(0.0, |f| {
                2.0 * f
                    .iter()
                    .map(|c| g.iter().map(|&(j, gj)| c[j] * gj).sum::<f64>().powi(2))
                    .sum::<f64>()
                    .sqrt()
            })
        };
        for t in model.terms() {
            let ax = &model.machine().axes()[t.axis];
            let value = |u: f64, p: &[f64]| model.error_value(t.id, u, p).unwrap_or(0.0);
            let (peak, at) = (0..=64)
                .map(|i| {
                    let u = ax.min + (ax.max - ax.min) * i as f64 / 64.0;
                    (value(u, params).abs(), u)
                })
                .fold(
                    (0.0, ax.min),
                    |m, x| if x.0 > m.0 || x.0.is_nan() { x } else { m },
                );
            let (scale, limit, unit) = if t.id.unit() == Unit::Mm {
                (UM_PER_MM, k * MAX_TRANSLATION_MM * UM_PER_MM, "µm")
            } else {
                (URAD_PER_RAD, k * MAX_ANGLE_RAD * URAD_PER_RAD, "µrad")
            };
            // The gradient of the value at its peak (exact for the linear bases).
            let mut q = params.to_vec();
            let base = value(at, params);
            let g: Vec<(usize, f64)> = t
                .params
                .clone()
                .map(|j| {
                    q[j] += 1.0;
                    let d = value(at, &q) - base;
                    q[j] -= 1.0;
                    (j, d)
                })
                .collect();
            let margin = expanded(&g);
            if beyond((peak - margin) * scale, limit) {
                out.push(Implausible {
                    name: t.id.to_string(),
                    value: peak * scale,
                    limit,
                    unit,
                });
            }
        }
        out
    }

    /// The effect parameters beyond `k` times their limit, by group (screw.X.200.a/b,
    /// drift.x/y/z, reflector.R1.x/y/z, …); a rate judged by what it moves over the test's span.
    fn implausible_effects(&self) -> Vec<Implausible> {
        let mut out = Vec::new();
        for (name, value, unit, own) in self.model.effect_sizes(self.params, |_| true) {
            let per_hour = matches!(own, Unit::MmPerHour | Unit::RadPerHour | Unit::PpmPerHour);
            let over_span = match self.context.time_span_h {
                Some(t) if per_hour && t > 0.0 => RATE_SPAN_H / t,
                _ => 1.0,
            };
            let limit = self.k * limit(own) * own.micro().0 * over_span;
            if beyond(value, limit) {
                out.push(Implausible {
                    name,
                    value,
                    limit,
                    unit,
                });
            }
        }
        out
    }
}

/// The tracker's moves from `start` (its rigid fit) beyond [`MAX_TRACKER_SHIFT_MM`] or
/// [`MAX_TRACKER_TURN_RAD`] (reported in µm, µrad).
fn implausible_tracker_moves(model: &Model, params: &[f64], start: &[f64]) -> Vec<Implausible> {
    let mut out = Vec::new();
    let t = model.tracker_start();
    let shift = (0..3)
        .map(|k| (params[t + k] - start[t + k]).powi(2))
        .sum::<f64>()
        .sqrt();
    let turn = (3..6)
        .map(|k| (params[t + k] - start[t + k]).powi(2))
        .sum::<f64>()
        .sqrt();
    if beyond(shift, MAX_TRACKER_SHIFT_MM) {
        out.push(Implausible {
            name: "tracker position (from its rigid fit)".into(),
            value: shift * UM_PER_MM,
            limit: MAX_TRACKER_SHIFT_MM * UM_PER_MM,
            unit: "µm",
        });
    }
    if beyond(turn, MAX_TRACKER_TURN_RAD) {
        out.push(Implausible {
            name: "tracker orientation (from its rigid fit)".into(),
            value: turn * URAD_PER_RAD,
            limit: MAX_TRACKER_TURN_RAD * URAD_PER_RAD,
            unit: "µrad",
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::ErrorModelSpec;

    /// A reversal is judged as a translation on a linear axis and as an angle on a rotary one:
    /// 40 µm of backlash on X and 60 µrad on C pass; 1.5 mm on X (a value in the wrong unit)
    /// and 2 mrad on C do not.
    #[test]
    fn a_reversal_is_judged_by_its_axis_kind() {
        let spec = ErrorModelSpec::from_toml_str("[effects]\nreversal = [\"X\", \"C\"]", "m.toml")
            .expect("a spec");
        let model = Model::new(crate::machine::Machine::default_xcfz(), spec).expect("a model");
        let (x, c) = (
            model.param_index("reversal.X.b").expect("X's"),
            model.param_index("reversal.C.b").expect("C's"),
        );
        let mut p = model.initial_params();
        (p[x], p[c]) = (0.040, 60e-6);
        assert!(check(&model, &p, &Context::default()).is_empty());
        (p[x], p[c]) = (1.5, 2e-3);
        let found = check(&model, &p, &Context::default());
        let names: Vec<String> = found.iter().map(|f| f.to_string()).collect();
        assert_eq!(
            names,
            [
                "reversal.C reaches 2000 µrad (plausible: up to 1000 µrad)",
                "reversal.X reaches 1500 µm (plausible: up to 1000 µm)"
            ]
        );
    }
}
