//! The library of candidates: one family per kind of extension (the module table of
//! [`crate::analysis::candidates`]), each a small builder that lists its members for a model, in the
//! order [`FAMILIES`] gives.
//!
//! The switches of the error model that a candidate turns on (a drift, the range's scale …) are
//! data ([`SWITCHES`]); the families over axes, reflectors, periods and variables are builders.

use super::Candidate;
use volver_core::basis::BasisKind;
use volver_core::iso::ErrorId;
use volver_core::machine::{Machine, MachineAxis};
use volver_core::measure::MeasurementSet;
use volver_core::model::{
    BallScrewSpec, ErrorModelSpec, ErrorTermSpec, Model, OneOrMany, ReversalSpec,
};
use volver_core::units::UM_PER_MM;

/// Periodic positioning errors are tried with periods travel/2 … travel/SCREW_PERIODS.
pub const SCREW_PERIODS: usize = 8;

/// A candidate that turns on one switch of the error model: offered when the model does not
/// have it yet and the machine allows it.
struct Switch {
    /// The candidate's id.
    id: &'static str,
    /// What it means, in words.
    description: &'static str,
    /// Whether the model already has it (or the machine cannot have it): then not offered.
    present: fn(&Model) -> bool,
    /// Turns it on in a spec.
    enable: fn(&mut ErrorModelSpec),
}

/// The candidates that turn on one switch of the error model, by id.
const SWITCHES: [Switch; 5] = [
    Switch {
        id: "thermal-drift",
        description: "thermal drift of the tool point with time (needs t_s)",
        present: |m| m.spec().effects.thermal_drift,
        enable: |s| s.effects.thermal_drift = true,
    },
    Switch {
        id: "range-scale",
        description: "a scale error of the tracker's range",
        present: |m| m.spec().effects.range_scale,
        enable: |s| s.effects.range_scale = true,
    },
    Switch {
        id: "range-offset",
        description: "each station's range offset (the dead path: every range too long or \
                      too short by a constant)",
        present: |m| m.spec().tracker.range_offset,
        enable: |s| s.tracker.range_offset = true,
    },
    Switch {
        id: "station-drift",
        description: "each station's position drifting with time (its stand growing as it \
                      warms; needs t_s)",
        present: |m| !m.machine().has_stations() || m.spec().effects.station_drift,
        enable: |s| s.effects.station_drift = true,
    },
    Switch {
        id: "tracker-drift",
        description: "the tracker's orientation drifting with time (its stand turning as it \
                      warms; needs t_s)",
        present: |m| m.spec().effects.tracker_drift,
        enable: |s| s.effects.tracker_drift = true,
    },
];

/// The switch of [`SWITCHES`] with id `id`.
fn switch(id: &str) -> Option<&'static Switch> {
    SWITCHES.iter().find(|s| s.id == id)
}

/// One family of candidates.
enum Family {
    /// One switch of the error model ([`SWITCHES`], by id).
    Switch(&'static str),
    /// A builder that appends the family's members for a model.
    Each(fn(&Model, &mut Vec<Candidate>)),
}

/// The families, in the order the library lists them (the ranking breaks ties by it).
const FAMILIES: [Family; 13] = [
    Family::Each(missing_errors),
    Family::Each(raised_errors),
    Family::Switch("thermal-drift"),
    Family::Each(reflector_offsets),
    Family::Switch("range-scale"),
    Family::Each(ball_screws),
    Family::Each(reversals),
    Family::Each(axis_drifts),
    Family::Switch("range-offset"),
    Family::Switch("station-drift"),
    Family::Switch("tracker-drift"),
    Family::Each(fields),
    Family::Each(tracker_tilt),
];

/// The library of candidates for a model.
pub fn library(model: &Model) -> Vec<Candidate> {
    let mut out = Vec::new();
    for family in &FAMILIES {
        match family {
            Family::Switch(id) => {
                if let Some(s) = switch(id).filter(|s| !(s.present)(model)) {
                    out.push(extension(
                        model,
                        s.id.into(),
                        s.description.into(),
                        s.enable,
                    ));
                }
            }
            Family::Each(build) => build(model, &mut out),
        }
    }
    out
}

/// The candidates of the library that `data` can identify at all: the library less the
/// reversal of an axis no point arrived at from each side (`reversal:X` when every point of X
/// arrived forward, or in reverse, or before X moved: a reversal is then a constant offset of
/// X's positioning error, which the model's constants and the tracker's pose absorb; see
/// [`volver_core::diagnose::coverage`]). `volver identify --add` takes any candidate of
/// [`library`].
pub fn offered(model: &Model, data: &MeasurementSet) -> Vec<Candidate> {
    let machine = model.machine();
    library(model)
        .into_iter()
        .filter(|c| {
            let Some(letter) = c.id.strip_prefix("reversal:") else {
                return true;
            };
            machine.axis_named(letter).is_some_and(|(k, _)| {
                volver_core::diagnose::coverage(machine, &data.points, k).both_sides()
            })
        })
        .collect()
}

/// A candidate `id` whose spec is the model's with `edit` applied.
fn extension(
    model: &Model,
    id: String,
    description: String,
    edit: impl FnOnce(&mut ErrorModelSpec),
) -> Candidate {
    let mut spec = model.spec().clone();
    edit(&mut spec);
    Candidate {
        id,
        description,
        spec,
    }
}

/// `add:EAC`: every ISO 230 error of every axis (component errors, then location and
/// squareness errors) the model leaves out — linear axes' as a Legendre polynomial of the
/// model's polynomial degree, rotary axes' as a first-harmonic Fourier series, location and
/// squareness errors as a constant.
fn missing_errors(model: &Model, out: &mut Vec<Candidate>) {
    let degree = polynomial_degree(model.spec());
    for ax in model.machine().axes() {
        let mut ids: Vec<ErrorId> = ErrorId::components_of(ax.axis).to_vec();
        ids.extend(
            ErrorId::location_names(ax.axis)
                .iter()
                .filter_map(|n| n.parse::<ErrorId>().ok()),
        );
        for id in ids {
            if model.term(id).is_some() {
                continue;
            }
            let (basis, degree, order, what) = match id {
                ErrorId::Location { .. } => (None, None, None, "a constant".to_string()),
                _ if ax.axis.is_rotary() => (
                    Some(BasisKind::Fourier),
                    None,
                    Some(1),
                    "a first-harmonic Fourier series".to_string(),
                ),
                _ => (
                    Some(BasisKind::Legendre),
                    Some(degree),
                    None,
                    format!("a Legendre polynomial of degree {degree}"),
                ),
            };
            let term = ErrorTermSpec {
                name: OneOrMany::One(id.to_string()),
                basis,
                degree,
                nodes: None,
                order,
            };
            out.push(extension(
                model,
                format!("add:{id}"),
                format!("add the missing error {id} as {what}"),
                |s| s.errors.push(term),
            ));
        }
    }
}

/// `raise:EXX` and `raise-axis:X`: the next degree or harmonic of each modelled error, then of
/// every modelled error of its axis at once, axis by axis.
fn raised_errors(model: &Model, out: &mut Vec<Candidate>) {
    let spec = model.spec();
    for ax in model.machine().axes() {
        let mut axis_spec = spec.clone();
        let mut any = false;
        for t in model.terms().iter().filter(|t| t.id.axis() == ax.axis) {
            if let Some(s) = raised(spec, t.id) {
                let what = if t.basis.kind().is_periodic() {
                    format!("harmonic {}", t.basis.degree() + 1)
                } else {
                    format!("degree {}", t.basis.degree() + 1)
                };
                out.push(Candidate {
                    id: format!("raise:{}", t.id),
                    description: format!("give {} its {what}", t.id),
                    spec: s,
                });
                if let Some(s) = raised(&axis_spec, t.id) {
                    axis_spec = s;
                    any = true;
                }
            }
        }
        if any {
            out.push(Candidate {
                id: format!("raise-axis:{}", ax.axis),
                description: format!("raise the degree or harmonic of every error of {}", ax.axis),
                spec: axis_spec,
            });
        }
    }
}

/// `reflector-offset:R1`: each reflector the model does not yet give an offset of its own.
fn reflector_offsets(model: &Model, out: &mut Vec<Candidate>) {
    for r in model.machine().reflectors() {
        if !model.spec().effects.reflector_offset.contains(&r.id) {
            out.push(extension(
                model,
                format!("reflector-offset:{}", r.id),
                format!("reflector {} off its nominal offset", r.id),
                |s| s.effects.reflector_offset.push(r.id.clone()),
            ));
        }
    }
}

/// The periods (mm) of the periodic positioning errors tried on a linear axis: travel/2 …
/// travel/[`SCREW_PERIODS`], each rounded to the µm.
fn screw_periods_mm(ax: &MachineAxis) -> impl Iterator<Item = f64> {
    let travel = ax.max - ax.min;
    (2..=SCREW_PERIODS).map(move |k| {
        let period = travel / k as f64;
        (period * UM_PER_MM).round() / UM_PER_MM
    })
}

/// `ball-screw:X:700`: a periodic positioning error of each linear axis for each period of
/// [`screw_periods_mm`] the model does not have yet.
fn ball_screws(model: &Model, out: &mut Vec<Candidate>) {
    let screws = &model.spec().effects.ball_screw;
    for ax in model
        .machine()
        .axes()
        .iter()
        .filter(|a| !a.axis.is_rotary())
    {
        let letter = ax.axis.to_string();
        for period in screw_periods_mm(ax) {
            if screws
                .iter()
                .any(|b| b.axis == letter && (b.period_mm - period).abs() < 1e-9)
            {
                continue;
            }
            let screw = BallScrewSpec {
                axis: letter.clone(),
                period_mm: period,
            };
            out.push(extension(
                model,
                format!("ball-screw:{letter}:{period}"),
                format!("a periodic positioning error of {letter} with a period of {period} mm"),
                |s| s.effects.ball_screw.push(screw),
            ));
        }
    }
}

/// `reversal:X`: a reversal value of each axis the model gives none (ISO 230-2's B: backlash,
/// lost motion; `[effects] reversal`), linear and rotary alike.
fn reversals(model: &Model, out: &mut Vec<Candidate>) {
    let have = &model.spec().effects.reversal;
    for ax in model.machine().axes() {
        let letter = ax.axis.to_string();
        if have.iter().any(|r| r.axis() == letter) {
            continue;
        }
        out.push(extension(
            model,
            format!("reversal:{letter}"),
            format!(
                "a reversal of {letter} (backlash, lost motion: ISO 230-2's B, the tool ±B/2 \
                 along the axis relative to the workpiece by the direction of approach)"
            ),
            |s| s.effects.reversal.push(ReversalSpec::Axis(letter.clone())),
        ));
    }
}

/// `thermal-scale:X` and `location-drift:C`: the thermal growth of each linear axis' scale and
/// the drift of each rotary axis' line, axis by axis in chain order.
fn axis_drifts(model: &Model, out: &mut Vec<Candidate>) {
    let fx = &model.spec().effects;
    for ax in model.machine().axes() {
        let letter = ax.axis.to_string();
        let candidate = if ax.axis.is_rotary() {
            if fx.location_drift.contains(&letter) {
                continue;
            }
            extension(
                model,
                format!("location-drift:{letter}"),
                format!("the line of {letter} drifting with time (its location errors × t)"),
                |s| s.effects.location_drift.push(letter.clone()),
            )
        } else {
            if fx.thermal_scale.contains(&letter) {
                continue;
            }
            extension(
                model,
                format!("thermal-scale:{letter}"),
                format!(
                    "the scale of {letter} growing with time (E{letter}{letter} += α·{}·t)",
                    letter.to_lowercase()
                ),
                |s| s.effects.thermal_scale.push(letter.clone()),
            )
        };
        out.push(candidate);
    }
}

/// `field:X`, `field:X*Z`: a generic field over every variable and every pair
/// ([`field_variables`]) the model does not have yet.
fn fields(model: &Model, out: &mut Vec<Candidate>) {
    for vars in field_variables(model.machine()) {
        let name = vars.join("*");
        if model.spec().effects.field.contains(&name) {
            continue;
        }
        let description = if vars.len() == 1 {
            format!(
                "a smooth displacement of the tool point that depends on {name} (a generic field)"
            )
        } else {
            format!(
                "a displacement of the tool point that depends jointly on {} and {} (a generic \
                 field: a non-rigid effect)",
                vars[0], vars[1]
            )
        };
        out.push(extension(
            model,
            format!("field:{name}"),
            description,
            |s| s.effects.field.push(name.clone()),
        ));
    }
}

/// `tracker-tilt`: the tracker's rotations about its x and y axes, when the model identifies
/// neither.
fn tracker_tilt(model: &Model, out: &mut Vec<Candidate>) {
    let identify = &model.spec().tracker.identify;
    if !identify.iter().any(|n| n == "rx") && !identify.iter().any(|n| n == "ry") {
        out.push(extension(
            model,
            "tracker-tilt".into(),
            "identify the tracker's tilt (rx, ry)".into(),
            |s| {
                s.tracker
                    .identify
                    .extend(["rx".to_string(), "ry".to_string()])
            },
        ));
    }
}

/// The highest polynomial degree among the model's polynomial error functions (a Chebyshev
/// function of m nodes has degree m − 1; 3 when none has one).
fn polynomial_degree(spec: &ErrorModelSpec) -> usize {
    spec.errors
        .iter()
        .filter(|e| {
            matches!(
                e.basis,
                Some(BasisKind::Legendre | BasisKind::Monomial | BasisKind::Chebyshev)
            )
        })
        .map(|e| {
            e.degree
                .or(e.nodes.map(|n| n.saturating_sub(1)))
                .unwrap_or(3)
        })
        .max()
        .unwrap_or(3)
}

/// The spec with `id` moved to an entry of its own whose degree, nodes or order is raised by 1.
fn raised(spec: &ErrorModelSpec, id: ErrorId) -> Option<ErrorModelSpec> {
    let mut spec = spec.clone();
    let name = id.to_string();
    let pos = spec.errors.iter().position(|e| {
        e.name
            .names()
            .iter()
            .any(|n| n.parse::<ErrorId>().ok() == Some(id))
    })?;
    let mut entry = spec.errors[pos].clone();
    match entry.basis {
        None | Some(BasisKind::Constant) => return None,
        Some(BasisKind::Fourier | BasisKind::Sine) => {
            entry.order = Some(entry.order.unwrap_or(1) + 1);
        }
        Some(BasisKind::Chebyshev) if entry.nodes.is_some() => {
            entry.nodes = entry.nodes.map(|n| n + 1);
        }
        Some(_) => entry.degree = Some(entry.degree.unwrap_or(3) + 1),
    }
    let rest: Vec<String> = spec.errors[pos]
        .name
        .names()
        .iter()
        .filter(|n| n.parse::<ErrorId>().ok() != Some(id))
        .map(|s| s.to_string())
        .collect();
    if rest.is_empty() {
        spec.errors.remove(pos);
    } else {
        spec.errors[pos].name = OneOrMany::Many(rest);
    }
    entry.name = OneOrMany::One(name);
    spec.errors.push(entry);
    Some(spec)
}

/// The variables of the generic fields, alone and in pairs: every axis in chain order, then the
/// time `t`.
fn field_variables(machine: &Machine) -> Vec<Vec<String>> {
    let mut vars: Vec<String> = machine.axes().iter().map(|a| a.axis.to_string()).collect();
    vars.push("t".into());
    let mut out: Vec<Vec<String>> = vars.iter().map(|v| vec![v.clone()]).collect();
    for (i, a) in vars.iter().enumerate() {
        for b in &vars[i + 1..] {
            out.push(vec![a.clone(), b.clone()]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ids(model: &Model) -> Vec<String> {
        library(model).into_iter().map(|c| c.id).collect()
    }

    /// X travels 1400 mm and Z 600 mm: periods travel/2 … travel/8, rounded to the µm.
    #[test]
    fn ball_screw_periods_are_the_travel_over_two_to_eight_rounded_to_the_micrometre() {
        let screws: Vec<String> = ids(&Model::default_xcfz())
            .into_iter()
            .filter(|id| id.starts_with("ball-screw:"))
            .collect();
        let expected = [
            "X:700",
            "X:466.667",
            "X:350",
            "X:280",
            "X:233.333",
            "X:200",
            "X:175",
            "Z:300",
            "Z:200",
            "Z:150",
            "Z:120",
            "Z:100",
            "Z:85.714",
            "Z:75",
        ];
        let expected: Vec<String> = expected.iter().map(|p| format!("ball-screw:{p}")).collect();
        assert_eq!(screws, expected);
    }

    /// A switch the model already has is not offered again; one the machine cannot have (a
    /// station's drift without stations) never is.
    #[test]
    fn a_switch_already_on_is_not_offered() {
        let model = Model::default_xcfz();
        let before = ids(&model);
        assert!(before.contains(&"thermal-drift".to_string()));
        assert!(before.contains(&"tracker-tilt".to_string()));
        assert!(!before.contains(&"station-drift".to_string()));
        let mut spec = model.spec().clone();
        spec.effects.thermal_drift = true;
        spec.effects.range_scale = true;
        let on = Model::new(model.machine().clone(), spec).expect("a valid model");
        let after = ids(&on);
        assert!(!after.contains(&"thermal-drift".to_string()));
        assert!(!after.contains(&"range-scale".to_string()));
        assert_eq!(after.len() + 2, before.len());
    }

    /// Every candidate changes the model, builds, and has an id of its own; the families come in
    /// the order of the module table's builders.
    #[test]
    fn every_candidate_extends_the_model_once() {
        let model = Model::default_xcfz();
        let all = library(&model);
        let mut seen = std::collections::HashSet::new();
        for c in &all {
            assert!(seen.insert(c.id.clone()), "{} twice", c.id);
            assert_ne!(&c.spec, model.spec(), "{} changes nothing", c.id);
            let extended = Model::new(model.machine().clone(), c.spec.clone());
            // A new parameter, or one the model held now free (the tracker's tilt).
            let frees = |e: Model| {
                e.n_params() > model.n_params()
                    || e.constraints().rows.len() < model.constraints().rows.len()
            };
            assert!(extended.is_ok_and(frees), "{} frees no parameter", c.id);
        }
        let first = |prefix: &str| all.iter().position(|c| c.id.starts_with(prefix));
        let order = [
            "add:",
            "raise:",
            "thermal-drift",
            "reflector-offset:",
            "range-scale",
            "ball-screw:",
            "reversal:",
            "thermal-scale:",
            "range-offset",
            "tracker-drift",
            "field:",
            "tracker-tilt",
        ];
        let positions: Vec<Option<usize>> = order.iter().map(|p| first(p)).collect();
        assert!(positions.iter().all(Option::is_some), "{positions:?}");
        assert!(positions.windows(2).all(|w| w[0] < w[1]), "{positions:?}");
    }

    /// A reversal is offered for the axes some points reached from each side: in test 4's own
    /// order X only moves forward (no `reversal:X`), C and Z turn back; shuffled, all three.
    /// The library itself (what `identify --add` takes) has all three either way.
    #[test]
    fn a_reversal_is_offered_only_for_an_axis_reached_from_both_sides() {
        use crate::analysis::observability::nominal_data;
        let model = Model::default_xcfz();
        let plan = volver_core::plan::Plan::preset(model.machine(), "test4").expect("a preset");
        let reversals = |data: &MeasurementSet| -> Vec<String> {
            offered(&model, data)
                .into_iter()
                .filter(|c| c.id.starts_with("reversal:"))
                .map(|c| c.id)
                .collect()
        };
        let own = nominal_data(&model, &plan);
        assert_eq!(reversals(&own), ["reversal:C", "reversal:Z"]);
        let shuffled = nominal_data(&model, &plan.shuffled(7));
        assert_eq!(
            reversals(&shuffled),
            ["reversal:X", "reversal:C", "reversal:Z"]
        );
        let all = ids(&model);
        assert!(
            ["reversal:X", "reversal:C", "reversal:Z"]
                .iter()
                .all(|id| all.contains(&id.to_string()))
        );
    }

    /// Four variables (X, C, Z and t): four fields alone and six pairs, in chain order.
    #[test]
    fn the_fields_are_every_variable_and_every_pair() {
        let fields: Vec<String> = ids(&Model::default_xcfz())
            .into_iter()
            .filter_map(|id| id.strip_prefix("field:").map(str::to_string))
            .collect();
        assert_eq!(
            fields,
            ["X", "C", "Z", "t", "X*C", "X*Z", "X*t", "C*Z", "C*t", "Z*t"]
        );
    }

    /// Raising EXX of the paper's model (twelve errors share one cubic entry) moves EXX to an
    /// entry of degree 4 and leaves the other eleven as they were; a constant cannot be raised.
    #[test]
    fn raising_an_error_moves_it_to_an_entry_of_its_own() {
        let spec = Model::default_xcfz().spec().clone();
        assert_eq!(polynomial_degree(&spec), 3);
        let exx: ErrorId = "EXX".parse().expect("an ISO name");
        let raised = raised(&spec, exx).expect("a cubic can be raised");
        assert_eq!(raised.errors.len(), spec.errors.len() + 1);
        let last = raised.errors.last().expect("the new entry");
        assert_eq!(last.name.names(), ["EXX"]);
        assert_eq!(last.degree, Some(4));
        assert_eq!(raised.errors[0].name.names().len(), 11);
        assert_eq!(raised.errors[0].degree, Some(3));
        let a0z: ErrorId = "A0Z".parse().expect("an ISO name");
        assert!(super::raised(&spec, a0z).is_none());
    }
}
