//! What the measuring order lets the data say of each axis' reversal (ISO 230-2's B): a
//! reversal moves a point by `s·B/2` along the axis' positioning error, `s` its direction of
//! approach, which at one position is a constant and so is the positioning error there. Only
//! the positions reached from both sides tell the two apart
//! ([`volver_core::diagnose::coverage`]).

use super::{Finding, Kind};
use volver_core::diagnose::{Coverage, coverage};
use volver_core::machine::{Machine, MachineAxis};
use volver_core::measure::MeasurementSet;
use volver_core::model::Model;

/// The positioning error of an axis (EXX, EZZ, ECC …).
fn positioning_error(ax: &MachineAxis) -> String {
    const COMPONENTS: [&str; 6] = ["X", "Y", "Z", "A", "B", "C"];
    let dir = ax.axis.direction() + if ax.axis.is_rotary() { 3 } else { 0 };
    format!("E{}{}", COMPONENTS[dir], ax.axis)
}

/// How the points arrived at an axis, in words: `1030 points forward, 0 in reverse, 10 before
/// X first moved; 0 of 8 positions reached from both sides`.
fn counts(letter: &str, c: &Coverage) -> String {
    let before = if c.unknown > 0 {
        format!(", {} before {letter} first moved", c.unknown)
    } else {
        String::new()
    };
    format!(
        "{} points forward, {} in reverse{before}; {} of {} positions reached from both sides",
        c.forward, c.reverse, c.positions_both, c.positions
    )
}

/// What the data can say of the reversal of axis `ax` whose points arrived as `c`, in words,
/// and whether it is separable from the positioning error by the data alone.
fn verdict(ax: &MachineAxis, c: &Coverage) -> (String, bool) {
    let (letter, error) = (ax.axis.to_string(), positioning_error(ax));
    let counts = counts(&letter, c);
    let words = if !c.both_sides() {
        format!(
            "the data approach {letter} from one side only ({counts}): its reversal cannot be \
             separated from its positioning error {error} — it is then a constant offset of \
             {error}, which the model's constants absorb (the tracker's pose, the axes' \
             locations)"
        )
    } else if !c.separable() {
        format!(
            "no position of {letter} is approached from both sides ({counts}): its reversal is \
             told from its positioning error {error} only by the shape the model gives {error} \
             (a step between the positions reached forward and those reached in reverse), not \
             by the data"
        )
    } else {
        format!(
            "{letter} is approached from both sides ({counts}): its reversal is measured at \
             the positions reached from both sides"
        )
    };
    (words, c.separable())
}

/// The findings for the reversals `model` has on `data`: one for each axis with a reversal
/// that no position reached from both sides separates from its positioning error.
pub(super) fn findings(model: &Model, data: &MeasurementSet) -> Vec<Finding> {
    let machine = model.machine();
    model
        .spec()
        .effects
        .reversal
        .iter()
        .filter_map(|r| {
            let (k, ax) = machine.axis_named(r.axis())?;
            let c = coverage(machine, &data.points, k);
            let (what, separable) = verdict(ax, &c);
            let rests = if c.both_sides() {
                "the shape the model gives the positioning error"
            } else {
                "the points measured before the axis first moved (their direction unknown), if \
                 any"
            };
            (!separable).then(|| Finding {
                kind: Kind::OneSided,
                axis: Some(ax.axis),
                what: format!(
                    "{what}; what a fit gives reversal.{} rests on {rests}",
                    ax.axis
                ),
                fix: format!(
                    "approach positions of {l} from both sides (a shuffled or bidirectional \
                     measuring order: each reached once moving + and once moving −), or leave \
                     {l}'s reversal out of the model",
                    l = ax.axis
                ),
            })
        })
        .collect()
}

/// For every axis that moves in `data` (at least two positions), what the measuring order lets
/// a fit say of its reversal, in words (`X: the data approach X from one side only (…)`), and
/// whether the data separate it from the positioning error: `volver layout --plan` prints them
/// whatever the model, for a plan that should measure reversals.
///
/// ```
/// use volver_core::model::Model;
/// use volver_core::plan::Plan;
/// use volver_solvers::observability::{nominal_data, reversal_lines};
/// let model = Model::default_xcfz();
/// let plan = Plan::preset(model.machine(), "test4").unwrap();
/// // In its own order X only moves forward; shuffled, every axis comes from both sides.
/// let own = reversal_lines(model.machine(), &nominal_data(&model, &plan));
/// assert!(own[0].0.starts_with("X: the data approach X from one side only") && !own[0].1);
/// let shuffled = reversal_lines(model.machine(), &nominal_data(&model, &plan.shuffled(1)));
/// assert!(shuffled.iter().all(|(_, separable)| *separable));
/// ```
pub fn reversal_lines(machine: &Machine, data: &MeasurementSet) -> Vec<(String, bool)> {
    machine
        .axes()
        .iter()
        .enumerate()
        .filter_map(|(k, ax)| {
            let c = coverage(machine, &data.points, k);
            (c.positions > 1).then(|| {
                let (words, separable) = verdict(ax, &c);
                (format!("{}: {words}", ax.axis), separable)
            })
        })
        .collect()
}
