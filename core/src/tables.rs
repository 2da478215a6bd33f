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
//! squareness constants are zero, so a controller that applies both gets it once.
//!
//! What the tables carry is computed, not assumed: [`ErrorTables::tool_point`] is the tool point
//! as a control applies them, and [`uncarried`] lists every machine part the tables cannot
//! express (a field over the axes, a part that grows with time) with the error it leaves.
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

use crate::error::{Error, Place, Result};
use crate::iso::{Axis, ErrorId};
use crate::machine::Commands;
use crate::model::Model;

mod carry;
pub use carry::{THERMAL_SIZE_AFTER_S, Uncarried, uncarried};

/// The most rows of one axis' table (compensation tables have tens to thousands).
pub const MAX_TABLE_ROWS: usize = 100_000;

/// The errors of one axis over its positions.
#[derive(Clone, Debug, PartialEq)]
pub struct AxisTable {
    /// The axis.
    pub axis: Axis,
    /// Positions (file units: mm, or degrees for a rotary axis), increasing.
    pub positions: Vec<f64>,
    /// Each component error's name and values (mm or rad), one per position.
    pub errors: Vec<(String, Vec<f64>)>,
}

/// Every exported error of a machine.
#[derive(Clone, Debug, PartialEq)]
pub struct ErrorTables {
    /// The constants (location and squareness errors): name and value (mm or rad).
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
                (t.id.to_string(), v)
            })
            .collect();
        let mut axes = Vec::new();
        for (k, a) in m.axes().iter().enumerate() {
            let comps = model.modelled_components(k);
            if !comps.iter().any(|&c| c) {
                continue;
            }
            let step = if a.axis.is_rotary() {
                rotary_step
            } else {
                linear_step
            };
            let (lo, hi) = (a.to_file_units(a.min), a.to_file_units(a.max));
            let rows = ((hi - lo) / step).ceil() + 1.0;
            // `rows` is finite here (a positive finite step over a finite travel).
            if rows > MAX_TABLE_ROWS as f64 {
                return Err(Error::InvalidOption {
                    name: "step",
                    message: format!(
                        "a step of {} {} over axis {}'s travel gives {rows:.3e} rows; a table \
                         has at most {MAX_TABLE_ROWS}: use a larger step",
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
            let ids = ErrorId::components_of(a.axis);
            let mut errors: Vec<(String, Vec<f64>)> = (0..6)
                .filter(|&c| comps[c])
                .map(|c| (ids[c].to_string(), Vec::with_capacity(positions.len())))
                .collect();
            for &pos in &positions {
                let mut cmd = reference;
                cmd.0[k] = a.from_file_units(pos);
                let e = model.errors_at(&cmd, params);
                for (slot, c) in (0..6).filter(|&c| comps[c]).enumerate() {
                    errors[slot].1.push(e.component[k][c]);
                }
            }
            axes.push(AxisTable {
                axis: a.axis,
                positions,
                errors,
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

    /// The ISG CSV text (see the module documentation).
    pub fn to_isg_csv(&self) -> String {
        let mut s = String::from(
            "// volver: identified geometric errors, ISG CSV table format\n\
             // sign convention: ERRORS (ISO 230-1 deviations), not corrections\n\
             // units: positions mm (linear axes) or degrees (rotary axes); errors mm or rad\n",
        );
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

    /// Reads [`ErrorTables::to_isg_csv`]'s format back; `file` names it in messages.
    pub fn from_isg_csv(text: &str, file: &str) -> Result<ErrorTables> {
        let mut out = ErrorTables {
            constants: Vec::new(),
            axes: Vec::new(),
        };
        let mut header: Option<(usize, Vec<String>)> = None;
        for (i, raw) in text.lines().enumerate() {
            let place = Place::file(file).at_line(i + 1);
            let line = raw.split("//").next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            if line == "#" {
                header = None;
                continue;
            }
            let cells: Vec<&str> = line.split_whitespace().collect();
            let Some((_, names)) = &header else {
                let names: Vec<String> = cells.iter().map(|c| c.to_string()).collect();
                for n in &names[1.min(names.len())..] {
                    n.parse::<ErrorId>().map_err(|e| {
                        Error::input(
                            place.clone().at_field(n.clone()),
                            format!("not an ISO 230-1 error name: {e}"),
                        )
                    })?;
                }
                if let Some(axis) = single_axis(&names[0]) {
                    out.axes.push(AxisTable {
                        axis,
                        positions: Vec::new(),
                        errors: names[1..].iter().map(|n| (n.clone(), Vec::new())).collect(),
                    });
                } else {
                    names[0].parse::<ErrorId>().map_err(|e| {
                        Error::input(
                            place.clone().at_field(names[0].clone()),
                            format!("expected an axis letter or an ISO 230-1 error name: {e}"),
                        )
                    })?;
                }
                header = Some((i + 1, names));
                continue;
            };
            if cells.len() != names.len() {
                return Err(Error::input(
                    place,
                    format!(
                        "{} values for the header's {} names",
                        cells.len(),
                        names.len()
                    ),
                ));
            }
            let vals = cells
                .iter()
                .zip(names)
                .map(|(c, n)| parse_number(c, &place, n))
                .collect::<Result<Vec<f64>>>()?;
            if single_axis(&names[0]).is_some() {
                let t = out.axes.last_mut().expect("table opened at its header");
                t.positions.push(vals[0]);
                for (e, v) in t.errors.iter_mut().zip(&vals[1..]) {
                    e.1.push(*v);
                }
            } else {
                out.constants.extend(names.iter().cloned().zip(vals));
            }
        }
        Ok(out)
    }

    /// The Etalon-exchange-style text (see the module documentation).
    pub fn to_etalon(&self) -> String {
        let mut s = String::from(
            "// volver: identified geometric errors, Etalon exchange style (\"Vendor\" variant)\n\
             // sign convention: ERRORS (ISO 230-1 deviations), not corrections\n\
             // units: positions mm (linear axes) or degrees (rotary axes); errors mm or rad\n\
             // Gridpoints rows: position value\n",
        );
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

    /// Reads [`ErrorTables::to_etalon`]'s format back; `file` names it in messages.
    pub fn from_etalon(text: &str, file: &str) -> Result<ErrorTables> {
        let mut out = ErrorTables {
            constants: Vec::new(),
            axes: Vec::new(),
        };
        let mut section: Option<ErrorId> = None;
        let mut grid: Option<(Vec<f64>, Vec<f64>)> = None;
        for (i, raw) in text.lines().enumerate() {
            let place = Place::file(file).at_line(i + 1);
            let line = raw.split("//").next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            if let Some((pos, vals)) = grid.as_mut() {
                if line.starts_with('}') {
                    let id = section.expect("a grid is inside a section");
                    let (pos, vals) = grid.take().expect("open grid");
                    let axis = id.axis();
                    if out.axes.last().is_none_or(|t| t.axis != axis) {
                        out.axes.push(AxisTable {
                            axis,
                            positions: pos.clone(),
                            errors: Vec::new(),
                        });
                    }
                    let t = out.axes.last_mut().expect("just pushed");
                    if t.positions.len() != pos.len()
                        || t.positions
                            .iter()
                            .zip(&pos)
                            .any(|(a, b)| (a - b).abs() > 1e-9)
                    {
                        return Err(Error::input(
                            place,
                            format!("{id}'s positions differ from the other errors of axis {axis}"),
                        ));
                    }
                    t.errors.push((id.to_string(), vals));
                    continue;
                }
                let cells: Vec<&str> = line.split_whitespace().collect();
                if cells.len() != 2 {
                    return Err(Error::input(
                        place,
                        "expected 'position value' in Gridpoints",
                    ));
                }
                pos.push(parse_number(cells[0], &place, "position")?);
                vals.push(parse_number(cells[1], &place, "value")?);
                continue;
            }
            if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
                section = Some(name.parse::<ErrorId>().map_err(|e| {
                    Error::input(
                        place.clone().at_field(name),
                        format!("not an ISO 230-1 error name: {e}"),
                    )
                })?);
                continue;
            }
            let Some(id) = section else {
                return Err(Error::input(place, "a value before any [NAME] section"));
            };
            let (key, value) = line
                .split_once('=')
                .map(|(k, v)| (k.trim(), v.trim()))
                .ok_or_else(|| {
                    Error::input(place.clone(), "expected 'VALUE = …' or 'Gridpoints = {'")
                })?;
            match key {
                "VALUE" => out
                    .constants
                    .push((id.to_string(), parse_number(value, &place, "VALUE")?)),
                "Gridpoints" if value == "{" => grid = Some((Vec::new(), Vec::new())),
                _ => {
                    return Err(Error::input(
                        place.at_field(key),
                        "expected 'VALUE = …' or 'Gridpoints = {'",
                    ));
                }
            }
        }
        if grid.is_some() {
            return Err(Error::input(
                Place::file(file),
                "the file ends inside a Gridpoints block (no closing '}')",
            ));
        }
        Ok(out)
    }

    /// The plain CSV text (see the module documentation): µm and µrad.
    pub fn to_plain_csv(&self) -> String {
        let mut s = String::from("error,axis,position,position_unit,value,value_unit\n");
        for (n, v) in &self.constants {
            let id: ErrorId = n.parse().expect("ISO name");
            let (scale, unit, dec) = plain_unit(n);
            s.push_str(&format!("{n},{},,,{:.dec$},{unit}\n", id.axis(), v * scale));
        }
        for t in &self.axes {
            let pu = if t.axis.is_rotary() { "deg" } else { "mm" };
            for (n, vals) in &t.errors {
                let (scale, unit, dec) = plain_unit(n);
                for (p, v) in t.positions.iter().zip(vals) {
                    s.push_str(&format!(
                        "{n},{},{p:.6},{pu},{:.dec$},{unit}\n",
                        t.axis,
                        v * scale
                    ));
                }
            }
        }
        s
    }

    /// Reads [`ErrorTables::to_plain_csv`]'s format back; `file` names it in messages.
    pub fn from_plain_csv(text: &str, file: &str) -> Result<ErrorTables> {
        let mut out = ErrorTables {
            constants: Vec::new(),
            axes: Vec::new(),
        };
        let mut lines = text.lines().enumerate();
        match lines.next() {
            Some((_, h)) if h.trim() == "error,axis,position,position_unit,value,value_unit" => {}
            _ => {
                return Err(Error::input(
                    Place::file(file).at_line(1),
                    "expected the header error,axis,position,position_unit,value,value_unit",
                ));
            }
        }
        for (i, raw) in lines {
            let place = Place::file(file).at_line(i + 1);
            if raw.trim().is_empty() {
                continue;
            }
            let c: Vec<&str> = raw.split(',').map(str::trim).collect();
            if c.len() != 6 {
                return Err(Error::input(
                    place,
                    format!("{} fields, expected 6", c.len()),
                ));
            }
            let id: ErrorId = c[0].parse().map_err(|e| {
                Error::input(
                    place.clone().at_field("error"),
                    format!("not an ISO 230-1 error name: {e}"),
                )
            })?;
            let scale = match c[5] {
                // µm → mm, µrad → rad.
                "um" => 1e-3,
                "urad" => 1e-6,
                other => {
                    return Err(Error::input(
                        place.at_field("value_unit"),
                        format!("expected um or urad, found \"{other}\""),
                    ));
                }
            };
            if (c[5] == "urad") != id.component().is_rotary() {
                return Err(Error::input(
                    place.at_field("value_unit"),
                    format!(
                        "{id} is {}",
                        if id.component().is_rotary() {
                            "an angle (urad)"
                        } else {
                            "a length (um)"
                        }
                    ),
                ));
            }
            let v = parse_number(c[4], &place, "value")? * scale;
            if c[2].is_empty() {
                out.constants.push((id.to_string(), v));
                continue;
            }
            let p = parse_number(c[2], &place, "position")?;
            let axis = id.axis();
            if out.axes.last().is_none_or(|t| t.axis != axis) {
                out.axes.push(AxisTable {
                    axis,
                    positions: Vec::new(),
                    errors: Vec::new(),
                });
            }
            let t = out.axes.last_mut().expect("just pushed");
            if t.errors.last().is_none_or(|e| e.0 != c[0]) {
                t.errors.push((id.to_string(), Vec::new()));
            }
            let n = t.errors.len();
            if n == 1 {
                t.positions.push(p);
            } else if t
                .positions
                .get(t.errors[n - 1].1.len())
                .is_none_or(|q| (q - p).abs() > 1e-9)
            {
                return Err(Error::input(
                    place.at_field("position"),
                    format!("{id}'s positions differ from the other errors of axis {axis}"),
                ));
            }
            t.errors[n - 1].1.push(v);
        }
        Ok(out)
    }
}

/// The plain CSV's factor from volver's units (mm, rad), its unit and its decimals for error
/// `name`: lengths in µm (× 1e3, 9 decimals), angles in µrad (× 1e6, 6 decimals), both to
/// 1e-12 of mm or rad as the other formats.
fn plain_unit(name: &str) -> (f64, &'static str, usize) {
    if is_angle(name) {
        (1e6, "urad", 6)
    } else {
        (1e3, "um", 9)
    }
}

fn single_axis(s: &str) -> Option<Axis> {
    let mut it = s.chars();
    match (it.next(), it.next()) {
        (Some(c), None) => Axis::from_letter(c),
        _ => None,
    }
}

fn fmt_value(v: f64) -> String {
    format!("{v:.12}")
}

fn parse_number(s: &str, place: &Place, field: &str) -> Result<f64> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(Error::input(
            place.clone().at_field(field),
            format!("expected a finite number, found \"{s}\""),
        )),
    }
}
