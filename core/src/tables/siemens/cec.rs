//! The sag / cross-axis compensation file `%_N_NC_CEC_INI` (see the parent module for the
//! rules and their sources).

use super::{CecSign, SiemensOptions, Stored, at_reference, fmt, stored};
use crate::error::Result;
use crate::iso::Axis;
use crate::machine::Machine;
use crate::tables::controller::{check_table, label, machine_axis, refuse};
use crate::tables::per_axis::{AxisCorrection, PerAxisTables};

const CEC: &str = "Siemens sag/cross-axis compensation (%_N_NC_CEC_INI)";

/// One CEC table to write: its axes, direction and stored values.
struct CecTable {
    input: Axis,
    output: Axis,
    direction: i8,
    stored: Stored,
}

/// The `%_N_NC_CEC_INI` file of `t`, with the default [`SiemensOptions`]. See
/// [`siemens_cec_with`].
pub fn siemens_cec(t: &PerAxisTables, machine: &Machine) -> Result<String> {
    siemens_cec_with(t, machine, &SiemensOptions::default())
}

/// The `%_N_NC_CEC_INI` file of `t`: one table (`$AN_CEC[t,N]`, `_INPUT_AXIS`, `_OUTPUT_AXIS`,
/// `_STEP`, `_MIN`, `_MAX`, `_DIRECTION` 0, `_MULT_BY_TABLE` 0, `_IS_MODULO`) per cross-axis
/// table, then two per directional leadscrew table: the axis on itself, `_DIRECTION` 1 with
/// half the forward-minus-reverse difference and −1 with its negative (the LEC file holds the
/// mean). Values in the sign of [`SiemensOptions::cec_sign`].
///
/// Refused, naming the table: a cross-axis table whose forward and reverse values differ (CEC's
/// direction is the input axis', volver's the output axis'), more tables than
/// [`SiemensOptions::cec_max_tables`], more points than [`SiemensOptions::cec_max_points`],
/// unequal spacing, a non-zero value at the input axis' reference point (unless shifted), an
/// axis the machine lacks, positions not ascending, values not finite.
pub fn siemens_cec_with(
    t: &PerAxisTables,
    machine: &Machine,
    opts: &SiemensOptions,
) -> Result<String> {
    let sign = match opts.cec_sign {
        CecSign::AsLec => -1.0,
        CecSign::Correction => 1.0,
    };
    let mut tables = Vec::new();
    for table in t.tables.iter().filter(|x| !x.is_leadscrew()) {
        tables.push(cross_table(table, machine, opts, sign)?);
    }
    for table in t
        .tables
        .iter()
        .filter(|x| x.is_leadscrew() && x.is_directional())
    {
        tables.extend(direction_tables(table, machine, opts, sign)?);
    }
    if tables.len() > opts.cec_max_tables {
        return Err(refuse(
            CEC,
            format!(
                "{} tables ({} cross-axis, the rest two per directional leadscrew table); the \
                 control offers {} (SiemensOptions::cec_max_tables)",
                tables.len(),
                t.tables.iter().filter(|x| !x.is_leadscrew()).count(),
                opts.cec_max_tables
            ),
        ));
    }
    let mut s = String::from("%_N_NC_CEC_INI\nCHANDATA(1)\n");
    s.push_str(&header(opts.cec_sign));
    if tables.is_empty() {
        s.push_str("; no cross-axis or directional tables\n");
    }
    for (k, c) in tables.iter().enumerate() {
        write_table(&mut s, k, c, opts);
    }
    s.push_str("M17\n");
    Ok(s)
}

fn header(sign: CecSign) -> String {
    let rule = match sign {
        CecSign::AsLec => {
            "; sign: each value is MINUS the correction of the output axis' command, as in \
             $AA_ENC_COMP\n\
             ; (a positive value is taken to move the axis negative: NOT CITED, check it on the \
             machine)\n"
        }
        CecSign::Correction => {
            "; sign: each value is the correction of the output axis' command\n\
             ; (a positive value is taken to move the axis positive: NOT CITED, check it on the \
             machine)\n"
        }
    };
    format!(
        "; volver: sag / cross-axis compensation, SINUMERIK 840D sl\n{rule}\
         ; units: input positions in the input axis' mm or degrees, values in the output axis'\n\
         ; load with MD32710 $MA_CEC_ENABLE = 0 on the output axes, then set it to 1,\n\
         ; SD41300 $SN_CEC_TABLE_ENABLE[t] = 1 for each table t below, and reset the NCK\n"
    )
}

fn cross_table(
    table: &AxisCorrection,
    machine: &Machine,
    opts: &SiemensOptions,
    sign: f64,
) -> Result<CecTable> {
    check_table(table, CEC)?;
    let input = machine_axis(machine, table.input, CEC, table)?;
    machine_axis(machine, table.output, CEC, table)?;
    if table.is_directional() {
        return Err(refuse(
            CEC,
            format!(
                "table {} has different forward and reverse values: volver's directions are the \
                 output axis' ({}) and CEC's the input axis' ({}), so the file cannot carry them",
                label(table),
                table.output,
                table.input
            ),
        ));
    }
    let values: Vec<f64> = table.forward.iter().map(|v| sign * v).collect();
    let (values, shift) = at_reference(table, (&values, sign), input, opts, CEC)?;
    let md = (opts.cec_max_points, "MD18342 $MN_MM_CEC_MAX_POINTS");
    let mut st = stored(table, values, input, md, CEC)?;
    st.notes.extend(shift);
    Ok(CecTable {
        input: table.input,
        output: table.output,
        direction: 0,
        stored: st,
    })
}

fn direction_tables(
    table: &AxisCorrection,
    machine: &Machine,
    opts: &SiemensOptions,
    sign: f64,
) -> Result<Vec<CecTable>> {
    check_table(table, CEC)?;
    let a = machine_axis(machine, table.input, CEC, table)?;
    let md = (opts.cec_max_points, "MD18342 $MN_MM_CEC_MAX_POINTS");
    let mut out = Vec::new();
    for direction in [1i8, -1] {
        let values: Vec<f64> = (table.forward.iter().zip(&table.reverse))
            .map(|(f, r)| sign * f64::from(direction) * (f - r) / 2.0)
            .collect();
        let mut st = stored(table, values, a, md, CEC)?;
        st.notes.push(format!(
            "the {} half of axis {}'s direction difference (its mean is in %_N_AX_EEC_INI)",
            if direction > 0 { "forward" } else { "reverse" },
            table.input
        ));
        out.push(CecTable {
            input: table.input,
            output: table.output,
            direction,
            stored: st,
        });
    }
    Ok(out)
}

fn write_table(s: &mut String, k: usize, c: &CecTable, opts: &SiemensOptions) {
    let (i, o) = (opts.axis_name(c.input), opts.axis_name(c.output));
    let st = &c.stored;
    s.push_str(&format!(
        "; table {k}: axis {o} (volver {}) as a function of {i} (volver {}), {} points every {}\n",
        c.output,
        c.input,
        st.values.len(),
        fmt(st.step)
    ));
    for note in &st.notes {
        s.push_str(&format!("; table {k}: {note}\n"));
    }
    for (n, v) in st.values.iter().enumerate() {
        s.push_str(&format!("$AN_CEC[{k},{n}]={}\n", fmt(*v)));
    }
    s.push_str(&format!("$AN_CEC_INPUT_AXIS[{k}]=({i})\n"));
    s.push_str(&format!("$AN_CEC_OUTPUT_AXIS[{k}]=({o})\n"));
    s.push_str(&format!("$AN_CEC_STEP[{k}]={}\n", fmt(st.step)));
    s.push_str(&format!("$AN_CEC_MIN[{k}]={}\n", fmt(st.min)));
    s.push_str(&format!("$AN_CEC_MAX[{k}]={}\n", fmt(st.max)));
    s.push_str(&format!("$AN_CEC_DIRECTION[{k}]={}\n", c.direction));
    s.push_str(&format!("$AN_CEC_MULT_BY_TABLE[{k}]=0\n"));
    s.push_str(&format!("$AN_CEC_IS_MODULO[{k}]={}\n", u8::from(st.modulo)));
}
