//! Siemens SINUMERIK 840D sl compensation tables: leadscrew / measuring-system error
//! compensation (`%_N_AX_EEC_INI`, `$AA_ENC_COMP…`) and sag / cross-axis compensation
//! (`%_N_NC_CEC_INI`, `$AN_CEC…`).
//!
//! The rules, from SINUMERIK 840D sl / 828D "Extended Functions" function manual, chapter K3
//! "Compensations", 03/2013 (6FC5397-1BP40-3BA1), section 4.4 (each cited in
//! `vendor-notes.md`, "Controller table formats"):
//! - both files are INI programs: the first line names the file (`%_N_AX_EEC_INI`,
//!   `%_N_NC_CEC_INI`), then `CHANDATA(1)`, one assignment per line, `;` comments, `M17` at the
//!   end (examples of 4.4.2.3 and 4.4.3);
//! - values in mm (degrees on a rotary axis), linear interpolation between interpolation points
//!   `MIN + N·STEP`, `N = 0 … k`, `MAX = MIN + k·STEP`; the first value held below MIN, the last
//!   above MAX, except with `…_IS_MODULO = 1`, which repeats the table cyclically (the value at
//!   MAX immediately followed by the one at MIN);
//! - point counts: `N ≤ MD38000 $MA_MM_ENC_COMP_MAX_POINTS − 1` (LEC, per axis),
//!   `N ≤ MD18342 $MN_MM_CEC_MAX_POINTS[t] − 1` (CEC, per table);
//! - the compensation value at the reference point should be zero (no jump when the
//!   compensation comes on after referencing);
//! - **LEC sign**: the value modifies the axis' actual value; "a positive compensation value
//!   causes the corresponding machine axis to move in the negative direction" (4.4.2.1). So
//!   the LEC value is the **negative** of volver's correction (what volver adds to the command);
//! - CEC: input (basic) axis, output (compensation) axis by machine axis name,
//!   `$AN_CEC_DIRECTION` 0 / 1 / −1 (both directions / only while the basic axis moves
//!   positive / negative), `$AN_CEC_MULT_BY_TABLE` 0 (no product), `$AN_CEC_IS_MODULO`.
//!
//! **Not cited: the sign of a CEC value.** The public pages found do not say whether a
//! positive `$AN_CEC` value moves the compensation axis positive or negative. volver writes it
//! like the LEC value (the negative of the correction), says so in the file, and
//! [`SiemensOptions::cec_sign`] turns it; check it on the machine (README, "Controller files").
//!
//! `$AA_ENC_COMP` has no direction: a directional leadscrew table goes in the LEC file as the
//! mean of both directions, and its half-differences go in the CEC file as two tables of the
//! axis on itself with `$AN_CEC_DIRECTION` 1 and −1 (the manual's "position-dependent backlash
//! compensation … using two tables", 4.4.3, `$AN_CEC_DIRECTION`). Load both files.
//!
//! ```
//! use volver_core::iso::Axis;
//! use volver_core::machine::Machine;
//! use volver_core::tables::per_axis::{AxisCorrection, Family, PerAxisTables};
//! use volver_core::tables::siemens::siemens_lec;
//! let t = PerAxisTables {
//!     family: Family::Leadscrew,
//!     tools: vec![[0.0; 3]],
//!     tables: vec![AxisCorrection {
//!         input: Axis::X,
//!         output: Axis::X,
//!         positions: vec![0.0, 700.0, 1400.0],
//!         forward: vec![0.0, -0.004, -0.008],
//!         reverse: vec![0.0, -0.004, -0.008],
//!     }],
//! };
//! let lec = siemens_lec(&t, &Machine::default_xcfz()).unwrap();
//! // A correction of −4 µm is written +0.004: the control subtracts the value.
//! assert!(lec.contains("$AA_ENC_COMP[0,1,X1]=0.004\n"));
//! assert!(lec.contains("$AA_ENC_COMP_STEP[0,X1]=700.0\n"));
//! ```

use super::controller::{check_table, constant_step, interpolate, label, machine_axis, refuse};
use super::per_axis::{AxisCorrection, PerAxisTables};
use crate::error::{Result, number};
use crate::iso::Axis;
use crate::machine::{Machine, MachineAxis};

mod cec;
#[cfg(test)]
mod tests;

pub use cec::{siemens_cec, siemens_cec_with};

const LEC: &str = "Siemens leadscrew error compensation (%_N_AX_EEC_INI)";

/// How far from zero (file units: mm or degrees) a table's value at the reference point may
/// be before it is refused: 1 nm, or 1 µ° on a rotary axis.
pub const REFERENCE_TOLERANCE: f64 = 1e-6;

/// The sign of the values of the CEC file (not cited: see the module documentation).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum CecSign {
    /// Like `$AA_ENC_COMP`: the value is the negative of volver's correction (a positive value
    /// moves the compensation axis negative).
    #[default]
    AsLec,
    /// The value is volver's correction (a positive value moves the compensation axis
    /// positive).
    Correction,
}

/// Options of the Siemens writers: the machine's axis names and limits.
#[derive(Clone, Debug, PartialEq)]
pub struct SiemensOptions {
    /// The machine axis name of each axis (`X1`, `AX1` …); an axis not listed is named by its
    /// letter and `1` (`X1`, `Y1`, `Z1`, `A1`, `B1`, `C1`: the names of the manual's examples,
    /// Siemens' default machine axis names). Default: none listed.
    pub axis_names: Vec<(Axis, String)>,
    /// MD38000 `$MA_MM_ENC_COMP_MAX_POINTS`: the most LEC points per axis. Default 200 (the
    /// fixed size of the 808D and 828D; set the machine's value).
    pub enc_comp_max_points: usize,
    /// MD18342 `$MN_MM_CEC_MAX_POINTS`: the most points of one CEC table. Default 200 (the
    /// 828D's fixed size).
    pub cec_max_points: usize,
    /// How many CEC tables the control offers. Default 8 (the 828D's).
    pub cec_max_tables: usize,
    /// The measuring system `e` of `$AA_ENC_COMP[e, N, axis]`: 0 the first, 1 the second.
    /// Default 0.
    pub measuring_system: usize,
    /// A table whose value at the reference point is not zero is refused (false, the default)
    /// or shifted by that value (true: the axis' zero moves by it; said in the file).
    pub shift_to_reference: bool,
    /// The sign of the CEC values. Default [`CecSign::AsLec`].
    pub cec_sign: CecSign,
}

impl Default for SiemensOptions {
    fn default() -> Self {
        SiemensOptions {
            axis_names: Vec::new(),
            enc_comp_max_points: 200,
            cec_max_points: 200,
            cec_max_tables: 8,
            measuring_system: 0,
            shift_to_reference: false,
            cec_sign: CecSign::AsLec,
        }
    }
}

impl SiemensOptions {
    /// The machine axis name of `axis`.
    pub fn axis_name(&self, axis: Axis) -> String {
        self.axis_names
            .iter()
            .find(|(a, _)| *a == axis)
            .map(|(_, n)| n.clone())
            .unwrap_or_else(|| format!("{axis}1"))
    }
}

/// A number as the files write it: up to nine decimals, trailing zeros dropped, at least one
/// decimal (`10.0`, `0.003`), never `-0.0`.
pub(crate) fn fmt(v: f64) -> String {
    let mut s = format!("{v:.9}");
    while s.ends_with('0') && !s.ends_with(".0") {
        s.pop();
    }
    if s == "-0.0" { "0.0".into() } else { s }
}

/// One table as a control stores it: MIN, STEP, the values (already in the format's sign),
/// whether it repeats cyclically, and what the file says about it.
pub(crate) struct Stored {
    pub min: f64,
    pub max: f64,
    pub step: f64,
    pub values: Vec<f64>,
    pub modulo: bool,
    pub notes: Vec<String>,
}

/// Checks `values` (one per position of `t`, `sign` × the correction) against the reference
/// point of `reference_axis` (Siemens: zero there) and shifts them when `opts` allow; returns
/// the shifted values and the note saying so.
pub(crate) fn at_reference(
    t: &AxisCorrection,
    (values, sign): (&[f64], f64),
    reference_axis: &MachineAxis,
    opts: &SiemensOptions,
    format: &str,
) -> Result<(Vec<f64>, Option<String>)> {
    let r = reference_axis.to_file_units(reference_axis.reference);
    let v0 = interpolate(&t.positions, values, r);
    let c0 = v0 * sign;
    if v0.abs() <= REFERENCE_TOLERANCE {
        return Ok((values.to_vec(), None));
    }
    if !opts.shift_to_reference {
        return Err(refuse(
            format,
            format!(
                "table {}: the correction at the reference point {} {} of axis {} is {} {}, not \
                 zero; Siemens asks for zero there (no jump when the compensation comes on after \
                 referencing): fit with the table held at zero there, or shift it \
                 (SiemensOptions::shift_to_reference, which moves the axis' zero)",
                label(t),
                number(r),
                reference_axis.file_unit(),
                reference_axis.axis,
                number(c0),
                if t.output.is_rotary() { "deg" } else { "mm" },
            ),
        ));
    }
    let note = format!(
        "the correction is shifted by {} so that it is zero at the reference point {} (this \
         moves the axis' zero)",
        fmt(-c0),
        fmt(r)
    );
    Ok((values.iter().map(|v| v - v0).collect(), Some(note)))
}

/// MIN, MAX, STEP and modulo of table `t` over the axis `a` it is a function of; `values` the
/// values to store. Modulo: a rotary input whose table spans one full turn with equal values
/// at both ends.
pub(crate) fn stored(
    t: &AxisCorrection,
    values: Vec<f64>,
    a: &MachineAxis,
    max_points: (usize, &str),
    format: &str,
) -> Result<Stored> {
    let step = constant_step(t, format)?;
    let n = t.positions.len();
    if n > max_points.0 {
        let span = t.positions[n - 1] - t.positions[0];
        return Err(refuse(
            format,
            format!(
                "table {} has {n} points; {} allows {}: raise it on the control, or use a step \
                 of at least {} {} over the table's {} {}",
                label(t),
                max_points.1,
                max_points.0,
                number((span / (max_points.0.max(2) - 1) as f64 * 1e3).ceil() / 1e3),
                a.file_unit(),
                number(span),
                a.file_unit()
            ),
        ));
    }
    let (min, max) = (t.positions[0], t.positions[n - 1]);
    let full_turn = a.axis.is_rotary() && ((max - min) - 360.0).abs() <= 1e-9;
    let modulo = full_turn && (values[0] - values[n - 1]).abs() <= 1e-9;
    let mut notes = Vec::new();
    // A modulo table of a rotary axis runs from 0° to 360° (808D p. 109): a table over another
    // turn (−180° … 180°) is turned to start at 0° when 0° is one of its positions.
    let k = (-min / step).round();
    if modulo && min.abs() > 1e-9 && (min + k * step).abs() <= 1e-9 * step.max(1.0) {
        let m = n - 1;
        let k = (k as i64).rem_euclid(m as i64) as usize;
        let mut turned: Vec<f64> = (0..m).map(|i| values[(i + k) % m]).collect();
        turned.push(turned[0]);
        notes.push(format!(
            "a full turn from {} to {} deg, written from 0 to 360 deg as modulo tables run",
            fmt(min),
            fmt(max)
        ));
        return Ok(Stored {
            min: 0.0,
            max: 360.0,
            step,
            values: turned,
            modulo,
            notes,
        });
    }
    if full_turn && !modulo {
        notes.push(format!(
            "not modulo: its values at {} and {} deg differ by {}, so the table holds its end \
             values instead of repeating",
            fmt(min),
            fmt(max),
            fmt(values[n - 1] - values[0])
        ));
    }
    Ok(Stored {
        min,
        max,
        step,
        values,
        modulo,
        notes,
    })
}

/// The `%_N_AX_EEC_INI` file of every leadscrew table of `t`, with the default
/// [`SiemensOptions`]. See [`siemens_lec_with`].
pub fn siemens_lec(t: &PerAxisTables, machine: &Machine) -> Result<String> {
    siemens_lec_with(t, machine, &SiemensOptions::default())
}

/// The `%_N_AX_EEC_INI` file of every leadscrew table of `t`: `$AA_ENC_COMP[e,N,AXIS]` =
/// minus the correction (mean of both directions for a directional table, whose difference
/// [`siemens_cec_with`] writes), `_STEP`, `_MIN`, `_MAX`, `_IS_MODULO`. Cross-axis tables are
/// [`siemens_cec_with`]'s and are left out.
///
/// Refused, naming the table: unequal spacing, more points than
/// [`SiemensOptions::enc_comp_max_points`], a non-zero value at the axis' reference point
/// (unless shifted), two tables of one axis, an axis the machine lacks, positions not
/// ascending, values not finite.
pub fn siemens_lec_with(
    t: &PerAxisTables,
    machine: &Machine,
    opts: &SiemensOptions,
) -> Result<String> {
    let e = opts.measuring_system;
    let mut s = String::from("%_N_AX_EEC_INI\nCHANDATA(1)\n");
    s.push_str(
        "; volver: leadscrew (measuring system) error compensation, SINUMERIK 840D sl\n\
         ; sign: each value is MINUS the correction of the axis' command: the control adds it to \
         the axis' actual value,\n\
         ; so a positive value moves the axis negative (K3 4.4.2.1)\n\
         ; units: positions and values in mm, degrees on a rotary axis\n\
         ; load with MD32700 $MA_ENC_COMP_ENABLE = 0, then set it to 1 and reset the NCK\n",
    );
    let mut done: Vec<Axis> = Vec::new();
    for table in t.tables.iter().filter(|x| x.is_leadscrew()) {
        if done.contains(&table.input) {
            return Err(refuse(
                LEC,
                format!("two tables for axis {}: an axis has one", table.input),
            ));
        }
        done.push(table.input);
        let a = machine_axis(machine, table.input, LEC, table)?;
        check_table(table, LEC)?;
        let mean: Vec<f64> = (table.forward.iter().zip(&table.reverse))
            .map(|(f, r)| -(f + r) / 2.0)
            .collect();
        let (values, shift) = at_reference(table, (&mean, -1.0), a, opts, LEC)?;
        let md = (
            opts.enc_comp_max_points,
            "MD38000 $MA_MM_ENC_COMP_MAX_POINTS",
        );
        let mut st = stored(table, values, a, md, LEC)?;
        st.notes.extend(shift);
        if table.is_directional() {
            st.notes.push(
                "directional: this is the mean of both directions; the half-differences are \
                 in %_N_NC_CEC_INI (two tables with $AN_CEC_DIRECTION 1 and -1)"
                    .into(),
            );
        }
        write_lec(&mut s, &st, &opts.axis_name(table.input), e, table.input);
    }
    s.push_str("M17\n");
    Ok(s)
}

fn write_lec(s: &mut String, st: &Stored, name: &str, e: usize, axis: Axis) {
    s.push_str(&format!(
        "; axis {name} (volver {axis}): {} points every {}\n",
        st.values.len(),
        fmt(st.step)
    ));
    for note in &st.notes {
        s.push_str(&format!("; axis {name}: {note}\n"));
    }
    for (i, v) in st.values.iter().enumerate() {
        s.push_str(&format!("$AA_ENC_COMP[{e},{i},{name}]={}\n", fmt(*v)));
    }
    s.push_str(&format!("$AA_ENC_COMP_STEP[{e},{name}]={}\n", fmt(st.step)));
    s.push_str(&format!("$AA_ENC_COMP_MIN[{e},{name}]={}\n", fmt(st.min)));
    s.push_str(&format!("$AA_ENC_COMP_MAX[{e},{name}]={}\n", fmt(st.max)));
    s.push_str(&format!(
        "$AA_ENC_COMP_IS_MODULO[{e},{name}]={}\n",
        u8::from(st.modulo)
    ));
}
