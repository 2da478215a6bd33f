//! What a part program is compensated with at the machine: the control's offsets and tool
//! table, the machine's position at the start, and a tool point per tool.

use crate::error::{Context, Error, Result};
use std::collections::BTreeMap;
use std::path::Path;
use volver_core::gcode::offsets::{OffsetUnits, Offsets};
use volver_core::gcode::{Linearise, Program, Setup};
use volver_core::machine::Machine;

/// The offsets of `--offsets` (LinuxCNC's parameter file, or volver's TOML when the name ends
/// in `.toml`) and `--tool-table` (LinuxCNC's `.tbl`), the latter two in `units`.
///
/// ```
/// let o = volver::machining::offsets(None, None, "mm").unwrap();
/// assert!(!o.given);
/// ```
pub fn offsets(offsets: Option<&Path>, tools: Option<&Path>, units: &str) -> Result<Offsets> {
    let units = OffsetUnits::from_name(units)
        .ok_or_else(|| Error::Request(format!("--offset-units {units}: mm or inch")))?;
    let mut o = match offsets {
        None => Offsets::default(),
        Some(p) => {
            let label = p.display().to_string();
            let text = std::fs::read_to_string(p).with_context(|| format!("reading {label}"))?;
            if p.extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("toml"))
            {
                Offsets::from_toml_str(&text, &label)?
            } else {
                Offsets::from_linuxcnc_var(&text, &label, units)?
            }
        }
    };
    if let Some(p) = tools {
        if o.tool_table {
            return Err(Error::Request(format!(
                "--tool-table {}: the offsets file has [tool] tables already; give the tools in one of them",
                p.display()
            )));
        }
        let label = p.display().to_string();
        let text = std::fs::read_to_string(p).with_context(|| format!("reading {label}"))?;
        o.add_linuxcnc_tools(&text, &label, units)?;
    }
    Ok(o)
}

/// The machine's position at the start from `--start` (`X=0,Z=600,C=0`: mm and degrees,
/// machine coordinates), chain order.
///
/// ```
/// let m = volver::core::machine::Machine::default_xcfz();
/// let s = volver::machining::start(&m, Some("X=0,Z=600")).unwrap();
/// assert_eq!(s[..3], [Some(0.0), None, Some(600.0)]);
/// ```
pub fn start(machine: &Machine, text: Option<&str>) -> Result<[Option<f64>; 6]> {
    let mut out = [None; 6];
    let Some(text) = text else {
        return Ok(out);
    };
    let pairs = volver_core::machine::axis_value_pairs(text)
        .map_err(|m| Error::Request(format!("--start {text}: {m}")))?;
    for (letter, v) in pairs {
        let axis = volver_core::iso::Axis::from_letter(letter.chars().next().unwrap_or(' '))
            .filter(|_| letter.chars().count() == 1);
        let Some((k, a)) = axis.and_then(|a| machine.axis(a)) else {
            return Err(Error::Request(format!(
                "--start {text}: '{letter}' is not an axis of the machine ({})",
                machine.chain()
            )));
        };
        if !(v.is_finite() && v.abs() <= volver_core::gcode::MAX_AXIS_VALUE) {
            return Err(Error::Request(format!(
                "--start {text}: {} is not a position in {}",
                volver_core::error::number(v),
                a.file_unit()
            )));
        }
        if out[k].replace(v).is_some() {
            return Err(Error::Request(format!(
                "--start {text}: axis {letter} is given twice"
            )));
        }
    }
    Ok(out)
}

/// Reads `text` (from `label`) for `machine` with `setup`, and the tool point of every tool
/// it uses: with a tool table, `gauge` plus the tool's length (its Z entry) along `axis` (the
/// tool's direction from the holder to the tip, in the frame of the last tool-side axis) less
/// its X and Y offsets along that frame's x and y;
/// without one, `single` for every move — refused when the program changes between tools
/// unless `same_point`.
pub fn read_program(
    text: &str,
    label: &str,
    machine: &Machine,
    setup: &Setup,
    points: &ToolPoints,
) -> Result<(Program, BTreeMap<i64, [f64; 3]>)> {
    let prog = Program::read(text, label, machine, setup)?;
    let tools = prog.tools();
    let numbered: Vec<i64> = tools
        .iter()
        .flatten()
        .copied()
        .filter(|&t| t != 0)
        .collect();
    let mut out = BTreeMap::new();
    if setup.offsets.tool_table {
        for t in numbered {
            let o = setup.offsets.tools.get(&t).copied().unwrap_or([0.0; 6]);
            // The controlled point is the tip plus the tool's offset (machine = program +
            // offset): the tip is the gauge point less it, the length along the tool axis,
            // the X and Y offsets along the frame's x and y (the machine's at the reference).
            let side = [-o[0], -o[1], 0.0];
            out.insert(
                t,
                std::array::from_fn(|c| points.gauge[c] + o[2] * points.axis[c] + side[c]),
            );
        }
    } else if numbered.len() > 1 && !points.same_point {
        let list: Vec<String> = numbered.iter().map(|t| format!("T{t}")).collect();
        return Err(Error::Request(format!(
            "{label}: the program changes tools ({}) and no tool table gives their lengths: give \
             the tool table (--tool-table) so that each tool is compensated at its own tool point, \
             or --same-tool-point to compensate every tool at the one tool point",
            list.join(", ")
        )));
    }
    Ok((prog, out))
}

/// Where the tools' points are.
#[derive(Clone, Copy, Debug)]
pub struct ToolPoints {
    /// The point tool lengths are measured from (the spindle's gauge line), mm in the frame
    /// of the last tool-side axis.
    pub gauge: [f64; 3],
    /// The tool's direction from the holder to the tip (unit), same frame.
    pub axis: [f64; 3],
    /// Compensate every tool at one tool point when there is no tool table.
    pub same_point: bool,
}

/// The default linearisation with `chord` (mm) and `segment` (mm).
pub fn linearise(chord: f64, segment: Option<f64>) -> Linearise {
    Linearise {
        chord_tolerance_mm: chord,
        max_segment_mm: segment,
    }
}
