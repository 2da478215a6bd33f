//! Controller tables: the identified errors as tables over each axis' positions, in formats that
//! compensation software reads, and read back.
//!
//! **Sign convention: errors, not corrections.** Every value is the ISO 230-1 error (the
//! deviation of the real axis from the nominal one, as the forward model uses it); the controller
//! applies its negative. Positions are in file units (mm, degrees), errors in mm and rad (µm and
//! µrad in the plain CSV). Names are ISO 230-1's: EXX … ECC for component errors, X0C, B0Z …
//! for location and squareness errors (digit zero).
//!
//! The tables hold every error the model describes as a function of one axis: its component
//! errors, with ball-screw errors added to the positioning error they belong to. Location and
//! squareness errors are constants. Thermal drift, the tracker pose and reflector offsets belong
//! to the measurement, not to the machine, and are not exported. The squareness rule of the model
//! is kept: with the paper's rule the squareness sits in the straightness' slope and the
//! squareness constants are zero, so a controller that applies both gets it once. Squareness
//! constants are written in **ISO 230-1's sign** (the right-hand turn of the axis' line of
//! motion about the named axis, [`ErrorId::iso_sign`]), which is the opposite of the model's
//! parameter for C0X, A0Y and B0Z; the ISG and Etalon files say so in a comment.
//!
//! What the tables carry is computed, not assumed: [`ErrorTables::tool_point`] is the tool point
//! as a control applies them, and [`uncarried`] lists every machine part the tables cannot
//! express (a field over the axes, a part that grows with time) with the error it leaves.
//!
//! **Directions of approach.** An axis with a reversal (`[effects] reversal`, parameter
//! `reversal.X.b` = ISO 230-2's B) has two positioning errors at each position: arriving
//! **forward** (its command increasing) `E↑ = E + σB/2`, arriving in **reverse**
//! `E↓ = E − σB/2` (σ = +1 on an axis that moves the tool, −1 on one that moves the
//! workpiece), so that `σB = E↑ − E↓` and `E`, the value the tables hold for every error, is
//! the mean of both directions. The tables keep B per position ([`AxisTable::reversal`]) for the axis'
//! positioning error (EXX for X, ECC for C); the other errors do not depend on the direction.
//! In ISO 230-2's terms — mean positional deviations `x̄↑`, `x̄↓` of the tool relative to the
//! workpiece along the axis' command, reversal value `B = x̄↑ − x̄↓` — these are the same
//! numbers on an axis that moves the tool, and their negatives on one that moves the workpiece
//! (its slide's error moves the workpiece, so the tool the other way: [`Directional::deviations`]
//! turns them). [`ErrorTables::directional`] gives the forward and reverse values at any
//! position and [`Directional::corrections`] what a control adds to the axis' command in each
//! direction (LinuxCNC's `nominal forward reverse` compensation files, Siemens'
//! direction-dependent tables); [`ErrorTables::tool_point_in`] is the tool point as a control
//! applying them moves it. The plain CSV carries both directions; the ISG and Etalon formats
//! have no direction: they hold the mean and say in their comments that the reversal is not
//! carried ([`uncarried_in`] sizes what that leaves).
//!
//! Formats:
//! - **ISG CSV** ([`ErrorTables::to_isg_csv`]), the tabular format of ISG-kernel volumetric
//!   compensation: `//` comments; blocks separated by `#`; each block a header of argument and
//!   parameter names and whitespace-separated rows. The first block holds the constants, one
//!   row; then one block per axis with its position as argument (`X EXX EYX …`).
//! - **Etalon exchange style** ([`ErrorTables::to_etalon`]), INI-like as in Etalon's "Vendor"
//!   exchange format: `[C0B]` / `VALUE = …` for constants, and `[EXY]` / `Gridpoints = { … }`
//!   with one `position value` row per line for functions.
//! - **Plain CSV** ([`ErrorTables::to_plain_csv`]): one row per value,
//!   `error,axis,position,position_unit,value,value_unit` (an empty position for constants);
//!   lengths in µm (`um`, the mm value × 1 000), angles in µrad (`urad`, the rad value × 10⁶).
//!   With a reversal, two more columns `forward,reverse`: the value on forward and on reverse
//!   approach, filled on the rows of an error that depends on the direction (the positioning
//!   error of an axis with a reversal; `value` their mean) and empty on the others (the value
//!   holds both ways). Files without them are read as before.
//!
//! Per-axis **correction** tables for controls without volumetric compensation
//! ([`per_axis::PerAxisTables`]) are written by [`linuxcnc`] (LinuxCNC's `COMP_FILE`) and
//! [`siemens`] (SINUMERIK `%_N_AX_EEC_INI`, `%_N_NC_CEC_INI`), each in its control's sign.
//!
//! ```
//! use volver_core::model::Model;
//! use volver_core::tables::ErrorTables;
//! let model = Model::default_xcfz();
//! let mut p = model.initial_params();
//! p[model.param_index("EXX.c1").unwrap()] = 0.01;
//! let t = ErrorTables::from_model(&model, &p, 100.0, 10.0).unwrap();
//! let back = ErrorTables::from_isg_csv(&t.to_isg_csv(), "x.csv").unwrap();
//! assert!(t.max_difference(&back).unwrap() < 1e-9);
//! ```

use crate::error::{Error, Result};
use crate::iso::{Axis, ErrorId};
use crate::machine::Commands;
use crate::model::Model;
use crate::units::{UM_PER_MM, URAD_PER_RAD};

mod carry;
mod controller;
mod direction;
pub mod linuxcnc;
pub mod per_axis;
mod read;
pub mod siemens;
pub use carry::{THERMAL_SIZE_AFTER_S, Uncarried, uncarried};
pub use direction::{Directional, TableFormat, uncarried_in};

/// The most rows of one axis' table (compensation tables have tens to thousands).
pub const MAX_TABLE_ROWS: usize = 100_000;

/// The errors of one axis over its positions.
#[derive(Clone, Debug, PartialEq)]
pub struct AxisTable {
    /// The axis.
    pub axis: Axis,
    /// Positions (file units: mm, or degrees for a rotary axis), increasing.
    pub positions: Vec<f64>,
    /// Each component error's name and values (mm or rad), one per position: for an error that
    /// depends on the direction of approach, the mean of both directions.
    pub errors: Vec<(String, Vec<f64>)>,
    /// With a reversal of the axis, ISO 230-2's reversal value B at each position (mm, or rad
    /// for a rotary axis) of its positioning error (EXX for X, ECC for C): forward approach
    /// `value + B/2`, reverse `value − B/2` ([`ErrorTables::directional`]). `None`: no error of
    /// the axis depends on the direction.
    pub reversal: Option<Vec<f64>>,
}

impl AxisTable {
    /// The name of the axis' positioning error (EXX for X, ECC for C): the one a reversal
    /// enters.
    pub fn positioning(&self) -> String {
        ErrorId::Component {
            component: self.axis,
            axis: self.axis,
        }
        .to_string()
    }
}

/// Every exported error of a machine.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ErrorTables {
    /// The constants (location and squareness errors): name and value (mm or rad) in ISO
    /// 230-1's sign ([`ErrorId::iso_sign`]: the squareness errors C0X, A0Y and B0Z are the
    /// negatives of the model's parameters of those names).
    pub constants: Vec<(String, f64)>,
    /// The tables, in chain order.
    pub axes: Vec<AxisTable>,
}

fn is_angle(name: &str) -> bool {
    name.parse::<ErrorId>()
        .map(|e| e.component().is_rotary())
        .unwrap_or(false)
}

/// Refuses a table step larger than the axis' travel `lo … hi` (file units): the table would
/// hold the end of the travel alone.
fn check_step(step: f64, lo: f64, hi: f64, a: &crate::machine::MachineAxis) -> Result<()> {
    if step > hi - lo && hi > lo {
        return Err(Error::InvalidOption {
            name: "step",
            message: format!(
                "a step of {} {unit} exceeds axis {}'s travel of {} {unit}: a table needs both ends of \
             the travel and the positions between; use a step of at most the travel",
                crate::error::number(step),
                a.axis,
                hi - lo,
                unit = a.file_unit(),
            ),
        });
    }
    Ok(())
}

/// Refuses parameters that are not `model`'s and table steps that are not positive and finite.
fn check_arguments(
    model: &Model,
    params: &[f64],
    linear_step: f64,
    rotary_step: f64,
) -> Result<()> {
    if params.len() != model.n_params() {
        return Err(Error::ParameterCount {
            expected: model.n_params(),
            got: params.len(),
            message: format!(
                "tables need {} parameters, got {}",
                model.n_params(),
                params.len()
            ),
        });
    }
    let usable = |s: f64| s > 0.0 && s.is_finite();
    if !(usable(linear_step) && usable(rotary_step)) {
        return Err(Error::InvalidOption {
            name: "step",
            message: "table steps must be positive and finite".into(),
        });
    }
    Ok(())
}

/// The table's positions over axis `a`'s travel (file units), every `step` from its start and
/// its end last; at most [`MAX_TABLE_ROWS`], and a step no larger than the travel.
fn table_positions(a: &crate::machine::MachineAxis, step: f64) -> Result<Vec<f64>> {
    let (lo, hi) = (a.to_file_units(a.min), a.to_file_units(a.max));
    let rows = ((hi - lo) / step).ceil() + 1.0;
    // `rows` is finite here (a positive finite step over a finite travel).
    if rows > MAX_TABLE_ROWS as f64 {
        return Err(Error::InvalidOption {
            name: "step",
            message: format!(
                "a step of {} {} over axis {}'s travel gives {rows:.3e} rows; a table has at \
                 most {MAX_TABLE_ROWS}: use a larger step",
                crate::error::number(step),
                a.file_unit(),
                a.axis
            ),
        });
    }
    check_step(step, lo, hi, a)?;
    let mut positions = Vec::new();
    let mut x = lo;
    while x < hi - 1e-9 * step {
        positions.push(x);
        x = lo + step * positions.len() as f64;
    }
    positions.push(hi);
    Ok(positions)
}

impl ErrorTables {
    /// Tables of `model` with errors `params`, every `linear_step` mm over a linear axis' travel
    /// and every `rotary_step` degrees over a rotary axis' (the last position is the end of the
    /// travel).
    pub fn from_model(
        model: &Model,
        params: &[f64],
        linear_step: f64,
        rotary_step: f64,
    ) -> Result<ErrorTables> {
        check_arguments(model, params, linear_step, rotary_step)?;
        let m = model.machine();
        let mut reference = Commands::default();
        for (k, a) in m.axes().iter().enumerate() {
            reference.0[k] = a.reference;
        }
        let at_reference = model.errors_at(&reference, params);
        let constants = model
            .terms()
            .iter()
            .filter(|t| matches!(t.id, ErrorId::Location { .. }))
            .map(|t| {
                let v = at_reference.location[t.axis][t.id.component().index()];
                // ISO 230-1's reading: C0X, A0Y and B0Z are the negatives of the model's.
                // (+ 0.0: a zero stays +0, not −0, in the files.)
                (t.id.to_string(), v * t.id.iso_sign() + 0.0)
            })
            .collect();
        let mut axes = Vec::new();
        let reversal = crate::compensate::reversal_axes(model);
        for (k, a) in m.axes().iter().enumerate() {
            let mut comps = model.modelled_components(k);
            let reverses = reversal.contains(&k);
            if reverses {
                comps[a.axis.index()] = true;
            }
            if !comps.iter().any(|&c| c) {
                continue;
            }
            let step = if a.axis.is_rotary() {
                rotary_step
            } else {
                linear_step
            };
            let positions = table_positions(a, step)?;
            let ids = ErrorId::components_of(a.axis);
            let mut errors: Vec<(String, Vec<f64>)> = (0..6)
                .filter(|&c| comps[c])
                .map(|c| (ids[c].to_string(), Vec::with_capacity(positions.len())))
                .collect();
            let mut b = Vec::new();
            for &pos in &positions {
                let mut cmd = reference;
                cmd.0[k] = a.from_file_units(pos);
                let e = model.errors_at(&cmd, params);
                for (slot, c) in (0..6).filter(|&c| comps[c]).enumerate() {
                    errors[slot].1.push(e.component[k][c]);
                }
                if reverses {
                    b.push(direction::reversal_at(model, params, &cmd, k));
                }
            }
            axes.push(AxisTable {
                axis: a.axis,
                positions,
                errors,
                reversal: reverses.then_some(b),
            });
        }
        Ok(ErrorTables { constants, axes })
    }

    /// The largest difference between two sets of tables with the same layout (mm or rad), or
    /// `None` when the layouts differ (names, axes, positions).
    pub fn max_difference(&self, other: &ErrorTables) -> Option<f64> {
        if self.constants.len() != other.constants.len() || self.axes.len() != other.axes.len() {
            return None;
        }
        let mut d: f64 = 0.0;
        for (a, b) in self.constants.iter().zip(&other.constants) {
            if a.0 != b.0 {
                return None;
            }
            d = d.max((a.1 - b.1).abs());
        }
        for (a, b) in self.axes.iter().zip(&other.axes) {
            if a.axis != b.axis
                || a.errors.len() != b.errors.len()
                || a.positions.len() != b.positions.len()
            {
                return None;
            }
            for (x, y) in a.positions.iter().zip(&b.positions) {
                if (x - y).abs() > 1e-9 {
                    return None;
                }
            }
            match (&a.reversal, &b.reversal) {
                (None, None) => {}
                (Some(ra), Some(rb)) if ra.len() == rb.len() => {
                    for (x, y) in ra.iter().zip(rb) {
                        d = d.max((x - y).abs());
                    }
                }
                _ => return None,
            }
            for (ea, eb) in a.errors.iter().zip(&b.errors) {
                if ea.0 != eb.0 || ea.1.len() != eb.1.len() {
                    return None;
                }
                for (x, y) in ea.1.iter().zip(&eb.1) {
                    d = d.max((x - y).abs());
                }
            }
        }
        Some(d)
    }

    /// The `//` comment lines that state the sign of the squareness constants, when the tables
    /// hold one (empty otherwise).
    fn squareness_note(&self) -> String {
        let names: Vec<&str> = self
            .constants
            .iter()
            .filter(|(n, _)| n.parse::<ErrorId>().is_ok_and(|id| id.is_squareness()))
            .map(|(n, _)| n.as_str())
            .collect();
        if names.is_empty() {
            return String::new();
        }
        format!(
            "// squareness ({}): ISO 230-1 sign, the angle (rad) by which the axis' line of \
             motion is turned right-handed about the named axis (C0X, A0Y and B0Z are the \
             negatives of volver's model parameters of those names)\n",
            names.join(", ")
        )
    }

    /// The ISG CSV text (see the module documentation).
    pub fn to_isg_csv(&self) -> String {
        let mut s = String::from(
            "// volver: identified geometric errors, ISG CSV table format\n\
             // sign convention: ERRORS (ISO 230-1 deviations), not corrections\n\
             // units: positions mm (linear axes) or degrees (rotary axes); errors mm or rad\n",
        );
        s.push_str(&self.no_direction_note());
        s.push_str(&self.squareness_note());
        if !self.constants.is_empty() {
            s.push_str("// location and squareness errors (constant)\n");
            let names: Vec<&str> = self.constants.iter().map(|c| c.0.as_str()).collect();
            s.push_str(&names.join(" "));
            s.push('\n');
            let vals: Vec<String> = self.constants.iter().map(|c| fmt_value(c.1)).collect();
            s.push_str(&vals.join(" "));
            s.push('\n');
        }
        for (i, t) in self.axes.iter().enumerate() {
            if i > 0 || !self.constants.is_empty() {
                s.push_str("#\n");
            }
            s.push_str(&format!("// component errors of axis {}\n", t.axis));
            s.push_str(&t.axis.to_string());
            for (name, _) in &t.errors {
                s.push(' ');
                s.push_str(name);
            }
            s.push('\n');
            for (i, p) in t.positions.iter().enumerate() {
                s.push_str(&format!("{p:.6}"));
                for (_, v) in &t.errors {
                    s.push(' ');
                    s.push_str(&fmt_value(v[i]));
                }
                s.push('\n');
            }
        }
        s
    }

    /// The Etalon-exchange-style text (see the module documentation).
    pub fn to_etalon(&self) -> String {
        let mut s = String::from(
            "// volver: identified geometric errors, Etalon exchange style (\"Vendor\" variant)\n\
             // sign convention: ERRORS (ISO 230-1 deviations), not corrections\n\
             // units: positions mm (linear axes) or degrees (rotary axes); errors mm or rad\n\
             // Gridpoints rows: position value\n",
        );
        s.push_str(&self.no_direction_note());
        s.push_str(&self.squareness_note());
        for (name, v) in &self.constants {
            s.push_str(&format!("[{name}]\nVALUE = {}\n", fmt_value(*v)));
        }
        for t in &self.axes {
            for (name, vals) in &t.errors {
                s.push_str(&format!("[{name}]\nGridpoints = {{\n"));
                for (p, v) in t.positions.iter().zip(vals) {
                    s.push_str(&format!("  {p:.6} {}\n", fmt_value(*v)));
                }
                s.push_str(&format!("}}  // end of {name}\n"));
            }
        }
        s
    }

    /// The plain CSV text (see the module documentation): µm and µrad; with a reversal, the
    /// `forward` and `reverse` columns.
    pub fn to_plain_csv(&self) -> String {
        let directed = self.axes.iter().any(|t| t.reversal.is_some());
        let mut s = String::from("error,axis,position,position_unit,value,value_unit");
        s.push_str(if directed { ",forward,reverse\n" } else { "\n" });
        let empty = if directed { ",," } else { "" };
        for (n, v) in &self.constants {
            // The axis of the error (empty for a name that is not one, which no reader gives).
            let axis = n
                .parse::<ErrorId>()
                .map_or(String::new(), |id| id.axis().to_string());
            let (scale, unit, dec) = plain_unit(n);
            s.push_str(&format!("{n},{axis},,,{:.dec$},{unit}{empty}\n", v * scale));
        }
        for t in &self.axes {
            let pu = if t.axis.is_rotary() { "deg" } else { "mm" };
            let positioning = t.positioning();
            for (n, vals) in &t.errors {
                let (scale, unit, dec) = plain_unit(n);
                let b = t.reversal.as_ref().filter(|_| *n == positioning);
                for (i, (p, v)) in t.positions.iter().zip(vals).enumerate() {
                    let both = match b {
                        Some(b) => format!(
                            ",{:.dec$},{:.dec$}",
                            (v + 0.5 * b[i]) * scale,
                            (v - 0.5 * b[i]) * scale
                        ),
                        None => empty.to_string(),
                    };
                    s.push_str(&format!(
                        "{n},{},{p:.6},{pu},{:.dec$},{unit}{both}\n",
                        t.axis,
                        v * scale
                    ));
                }
            }
        }
        s
    }
}

/// The plain CSV's factor from volver's units (mm, rad), its unit and its decimals for error
/// `name`: lengths in µm (× 1e3, 9 decimals), angles in µrad (× 1e6, 6 decimals), both to
/// 1e-12 of mm or rad as the other formats.
fn plain_unit(name: &str) -> (f64, &'static str, usize) {
    if is_angle(name) {
        (URAD_PER_RAD, "urad", 6)
    } else {
        (UM_PER_MM, "um", 9)
    }
}

fn fmt_value(v: f64) -> String {
    let s = format!("{v:.12}");
    // A value that rounds to zero is written 0, not −0.
    match s.strip_prefix('-') {
        Some(rest) if rest.chars().all(|c| c == '0' || c == '.') => rest.to_string(),
        _ => s,
    }
}
