//! Checks shared by the controller-table writers (LinuxCNC, Siemens): a per-axis table is
//! well formed (as many values as positions, finite, strictly ascending positions) and its axes
//! are the machine's.

use super::per_axis::AxisCorrection;
use crate::error::{Error, Result, number};
use crate::iso::Axis;
use crate::machine::{Machine, MachineAxis};

/// An error of a controller-table writer: `format` names the file format, `message` the table
/// and what is wrong.
pub(crate) fn refuse(format: &str, message: String) -> Error {
    Error::InvalidOption {
        name: "tables",
        message: format!("{format}: {message}"),
    }
}

/// The name of a table in messages: `X` for X's leadscrew table, `Y(X)` for the correction
/// of Y as a function of X.
pub(crate) fn label(t: &AxisCorrection) -> String {
    if t.is_leadscrew() {
        format!("{}", t.input)
    } else {
        format!("{}({})", t.output, t.input)
    }
}

/// The machine's axis `axis`, or the error saying the tables name an axis the machine lacks.
pub(crate) fn machine_axis<'m>(
    machine: &'m Machine,
    axis: Axis,
    format: &str,
    t: &AxisCorrection,
) -> Result<&'m MachineAxis> {
    machine.axis(axis).map(|(_, a)| a).ok_or_else(|| {
        refuse(
            format,
            format!(
                "table {} names axis {axis}, which the machine does not have",
                label(t)
            ),
        )
    })
}

/// Refuses a table whose value lists differ in length from its positions, that holds a value
/// that is not finite, or whose positions are not strictly ascending.
pub(crate) fn check_table(t: &AxisCorrection, format: &str) -> Result<()> {
    let name = label(t);
    let n = t.positions.len();
    if n == 0 {
        return Err(refuse(format, format!("table {name} has no positions")));
    }
    if t.forward.len() != n || t.reverse.len() != n {
        return Err(refuse(
            format,
            format!(
                "table {name} has {n} positions but {} forward and {} reverse values",
                t.forward.len(),
                t.reverse.len()
            ),
        ));
    }
    for (i, ((p, f), r)) in t
        .positions
        .iter()
        .zip(&t.forward)
        .zip(&t.reverse)
        .enumerate()
    {
        if !(p.is_finite() && f.is_finite() && r.is_finite()) {
            return Err(refuse(
                format,
                format!(
                    "table {name}, point {i}: position {}, values {} / {}: every number must be \
                     finite",
                    number(*p),
                    number(*f),
                    number(*r)
                ),
            ));
        }
        if i > 0 && *p <= t.positions[i - 1] {
            return Err(refuse(
                format,
                format!(
                    "table {name}, point {i}: position {} does not follow {}: positions must be \
                     strictly ascending",
                    number(*p),
                    number(t.positions[i - 1])
                ),
            ));
        }
    }
    Ok(())
}

/// The table's constant spacing (file units), or the error naming the first interval that
/// differs from the first by more than 1e-9 of it (formats that store only MIN, MAX and STEP).
pub(crate) fn constant_step(t: &AxisCorrection, format: &str) -> Result<f64> {
    let name = label(t);
    if t.positions.len() < 2 {
        return Err(refuse(
            format,
            format!("table {name} has a single position: the format needs a step between two"),
        ));
    }
    let step = t.positions[1] - t.positions[0];
    for (i, w) in t.positions.windows(2).enumerate() {
        let d = w[1] - w[0];
        if (d - step).abs() > 1e-9 * step {
            return Err(refuse(
                format,
                format!(
                    "table {name}: the interval {} … {} is {} but the first is {}: the format \
                     stores one step, so positions must be equally spaced (interval {i})",
                    number(w[0]),
                    number(w[1]),
                    number(d),
                    number(step)
                ),
            ));
        }
    }
    Ok(step)
}

/// The value of `values` at `x` (file units) by linear interpolation over ascending
/// `positions`, the end values held beyond them.
pub(crate) fn interpolate(positions: &[f64], values: &[f64], x: f64) -> f64 {
    let n = positions.len();
    if x <= positions[0] {
        return values[0];
    }
    if x >= positions[n - 1] {
        return values[n - 1];
    }
    let k = positions.partition_point(|&p| p <= x) - 1;
    let s = (x - positions[k]) / (positions[k + 1] - positions[k]);
    values[k] + s * (values[k + 1] - values[k])
}
