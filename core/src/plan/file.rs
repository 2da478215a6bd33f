//! Plan files: a test plan as the machine runs it, one measurement per row in measuring order.
//!
//! ```text
//! # volver plan "designed": 4 points at 3 poses; reflectors R1, R2
//! order,X,C,Z,reflector
//! 1,0,0,0,R1
//! 2,0,0,0,R2
//! 3,1400,90,600,R1
//! 4,700,180,300,R2
//! ```
//!
//! Columns (comma-separated, any order, names as in measurement files): one per axis of the
//! machine in file units (mm, degrees; a unit annotation such as `X [mm]` is accepted), the
//! `reflector` id, and optionally `order` (1, 2, 3 … in the file's row order: a check that rows
//! were not sorted since they were written). Lines starting with `#` are comments. Rows with the
//! same axis values are the same pose: the plan's positions are its distinct poses in order of
//! first appearance. Every error names the file, line and column.

use super::{Plan, Step};
use crate::chain::MAX_AXES;
use crate::error::{Error, Place, Result};
use crate::machine::{Commands, Machine};
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

/// The plan file of `plan` on `machine`, `comment` (one line or several) first as `#` lines.
///
/// ```
/// use volver_core::machine::Machine;
/// use volver_core::plan::{Plan, file};
/// let m = Machine::default_xcfz();
/// let plan = Plan::parse_grid(&m, "X=0:1400:1400,C=90,Z=0").unwrap();
/// let text = file::to_csv(&plan, &m, "two poses");
/// assert!(text.starts_with("# two poses\norder,X,C,Z,reflector\n1,0,90,0,R1\n2,0,90,0,R2\n"));
/// let back = file::from_csv_str(&m, &text, "plan.csv").unwrap();
/// assert_eq!(back.steps(), plan.steps());
/// ```
pub fn to_csv(plan: &Plan, machine: &Machine, comment: &str) -> String {
    let mut out = String::new();
    for line in comment.lines() {
        let _ = writeln!(out, "# {line}");
    }
    out.push_str("order");
    for ax in machine.axes() {
        let _ = write!(out, ",{}", ax.axis);
    }
    out.push_str(",reflector\n");
    for (i, s) in plan.steps().iter().enumerate() {
        let _ = write!(out, "{}", i + 1);
        let c = &plan.positions[s.position];
        for (k, ax) in machine.axes().iter().enumerate() {
            // Rounded to 1e-9 of the unit: the written value reads back as the same pose.
            let v = (ax.to_file_units(c.0[k]) * 1e9).round() / 1e9;
            let _ = write!(out, ",{}", v + 0.0);
        }
        let _ = writeln!(out, ",{}", machine.reflectors()[s.reflector].id);
    }
    out
}

/// The measuring program of `plan` on `machine` (RS-274/NGC G-code, the machine's axis words in
/// mm and degrees): each visit of a pose is a rapid absolute move followed by a dwell of
/// `dwell_s` seconds (`G4 P`, seconds as RS-274/NGC reads it) for the machine and the tracker
/// to settle, with a comment naming the reflectors to measure there and the plan file's rows
/// they are. The header states the plan (`title`), its size, the reflectors and the order.
///
/// ```
/// use volver_core::gcode::{Linearise, Program};
/// use volver_core::machine::Machine;
/// use volver_core::plan::{Plan, file};
/// let m = Machine::default_xcfz();
/// let plan = Plan::parse_grid(&m, "X=0:1400:700,C=90,Z=0:600:600").unwrap();
/// let nc = file::gcode(&plan, &m, 2.0, "a test");
/// assert!(nc.contains("G4 P2 (pose 1: measure R1 R2, plan rows 1-2)"));
/// let moves = Program::parse(&nc, "plan.nc", &m, &Linearise::default()).unwrap().points();
/// assert_eq!(moves.len(), plan.positions.len());
/// assert_eq!(&moves[1].0[..3], &[0.0, 90.0, 600.0]);
/// ```
pub fn gcode(plan: &Plan, machine: &Machine, dwell_s: f64, title: &str) -> String {
    let clean = |t: &str| t.replace(['(', ')'], "");
    let steps = plan.steps();
    // Visits: runs of steps at one pose.
    let mut visits: Vec<(usize, Vec<usize>, usize)> = Vec::new(); // (position, reflectors, first row)
    for (i, s) in steps.iter().enumerate() {
        match visits.last_mut() {
            Some(v) if v.0 == s.position && !v.1.contains(&s.reflector) => v.1.push(s.reflector),
            _ => visits.push((s.position, vec![s.reflector], i)),
        }
    }
    let ids = |rs: &[usize]| {
        rs.iter()
            .map(|&r| machine.reflectors()[r].id.as_str())
            .collect::<Vec<_>>()
            .join(" ")
    };
    let counts: Vec<String> = plan
        .reflectors
        .iter()
        .map(|&r| {
            format!(
                "{} x {}",
                machine.reflectors()[r].id,
                steps.iter().filter(|s| s.reflector == r).count()
            )
        })
        .collect();
    let mut out = String::from("%\n");
    let _ = writeln!(out, "(volver plan: {})", clean(title));
    let _ = writeln!(
        out,
        "({} measurements in {} visits of {} poses; reflectors {}; machine {})",
        steps.len(),
        visits.len(),
        plan.positions.len(),
        counts.join(", "),
        clean(&machine.chain().to_string())
    );
    let _ = writeln!(
        out,
        "(at each pose: dwell {dwell_s} s for the machine and tracker to settle, then measure \
         the reflectors named, in order; the rows are those of the plan file)"
    );
    let _ = writeln!(
        out,
        "(G4 P is in seconds as RS-274/NGC reads it: controls that read P in ms need it scaled)"
    );
    let _ = writeln!(out, "{}", crate::gcode::START_STATE);
    for (k, (position, reflectors, first)) in visits.iter().enumerate() {
        let c = &plan.positions[*position];
        let words: Vec<String> = machine
            .axes()
            .iter()
            .enumerate()
            .map(|(j, ax)| {
                let v = (ax.to_file_units(c.0[j]) * 1e6).round() / 1e6;
                format!("{}{}", ax.axis, v + 0.0)
            })
            .collect();
        let _ = writeln!(out, "N{} G0 {}", k + 1, words.join(" "));
        let rows = if reflectors.len() == 1 {
            format!("plan row {}", first + 1)
        } else {
            format!("plan rows {}-{}", first + 1, first + reflectors.len())
        };
        let _ = writeln!(
            out,
            "G4 P{} (pose {}: measure {}, {rows})",
            dwell_s + 0.0,
            k + 1,
            clean(&ids(reflectors))
        );
    }
    out.push_str("M30\n%\n");
    out
}

/// Reads a plan file for `machine`.
pub fn load(machine: &Machine, path: &Path) -> Result<Plan> {
    let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    from_csv_str(machine, &text, &path.display().to_string())
}

/// Parses a plan file for `machine`; `file` names the source in messages. The plan's name is
/// the file's.
pub fn from_csv_str(machine: &Machine, text: &str, file: &str) -> Result<Plan> {
    // A byte-order mark (spreadsheets write one) is not part of the first column's name.
    let text = crate::error::without_bom(text);
    // Comment lines are blanked (not removed) so that line numbers stay the file's.
    let body: String = text
        .lines()
        .map(|l| {
            if l.trim_start().starts_with('#') {
                ""
            } else {
                l
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    let mut lines = body
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty());
    let Some((header_line, header)) = lines.next() else {
        return Err(Error::input(
            Place::file(file),
            "empty plan file: expected a header with the axis columns and reflector",
        ));
    };
    // Names without their unit annotations (`X [mm]`, `C (deg)`), checked below.
    let (names, units): (Vec<String>, Vec<Option<String>>) = header
        .split(',')
        .map(|h| {
            let (name, unit) = crate::measure::split_unit(h);
            (name.to_string(), unit.map(str::to_string))
        })
        .unzip();
    let at_header = |field: &str| Place::file(file).at_line(header_line).at_field(field);
    let column = |name: &str| -> Result<Option<usize>> {
        let found: Vec<usize> = (0..names.len()).filter(|&i| names[i] == name).collect();
        match found.as_slice() {
            [] => Ok(None),
            [i] => Ok(Some(*i)),
            _ => Err(Error::input(
                at_header(name),
                format!("column '{name}' appears twice in the header"),
            )),
        }
    };
    let mut axis_cols = Vec::new();
    for ax in machine.axes() {
        let name = ax.axis.letter().to_string();
        let col = column(&name)?.ok_or_else(|| {
            Error::input(
                at_header(&name),
                format!(
                    "missing column '{name}' (axis {name} of {}, in {})",
                    machine.chain(),
                    ax.file_unit()
                ),
            )
        })?;
        axis_cols.push(col);
    }
    for (&col, ax) in axis_cols.iter().zip(machine.axes()) {
        if let Some(u) = &units[col] {
            crate::measure::check_unit(u, ax.file_unit())
                .map_err(|m| Error::input(at_header(&names[col]), m))?;
        }
    }
    let refl_col = column("reflector")?.ok_or_else(|| {
        Error::input(
            at_header("reflector"),
            "missing column 'reflector'; a plan file has the axis letters, reflector and optionally order",
        )
    })?;
    let order_col = column("order")?;
    if let Some(unknown) = names.iter().find(|n| {
        n.as_str() != "reflector"
            && n.as_str() != "order"
            && !machine
                .axes()
                .iter()
                .any(|ax| ax.axis.letter().to_string() == **n)
    }) {
        return Err(Error::input(
            at_header(unknown),
            format!(
                "unknown column '{unknown}': a plan file has the axes of {}, reflector and order",
                machine.chain()
            ),
        ));
    }
    let mut positions: Vec<Commands> = Vec::new();
    // Each distinct pose's index, by its bits (a hash lookup: a million rows read in linear
    // time; `-0.0` is `0.0`).
    let mut index: HashMap<[u64; MAX_AXES], usize> = HashMap::new();
    let mut sequence = Vec::new();
    let mut used = Vec::new();
    for (line, row) in lines {
        let fields: Vec<&str> = row.split(',').map(str::trim).collect();
        let at = |col: usize| Place::file(file).at_line(line).at_field(names[col].clone());
        if fields.len() != names.len() {
            return Err(Error::input(
                Place::file(file).at_line(line),
                format!(
                    "{} fields where the header has {}",
                    fields.len(),
                    names.len()
                ),
            ));
        }
        let number = |col: usize, unit: &str| -> Result<f64> {
            let s = fields[col];
            match s.parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(v),
                _ => Err(Error::input(
                    at(col),
                    format!("expected a finite number ({unit}), found \"{s}\""),
                )),
            }
        };
        if let Some(c) = order_col {
            let want = sequence.len() + 1;
            if number(c, "count")? != want as f64 {
                return Err(Error::input(
                    at(c),
                    format!(
                        "order {} where row {want} of the plan stands: the rows are measured in \
                         the file's order",
                        fields[c]
                    ),
                ));
            }
        }
        let mut commands = Commands::default();
        for (k, (&col, ax)) in axis_cols.iter().zip(machine.axes()).enumerate() {
            let v = number(col, ax.file_unit())?;
            commands.0[k] = ax
                .position_from_file(v)
                .map_err(|m| Error::input(at(col), m))?;
        }
        let id = fields[refl_col];
        let reflector = machine
            .reflector_named(id)
            .map_err(|m| Error::input(at(refl_col), m))?;
        let position = *index
            .entry(commands.0.map(|v| (v + 0.0).to_bits()))
            .or_insert_with(|| {
                positions.push(commands);
                positions.len() - 1
            });
        if !used.contains(&reflector) {
            used.push(reflector);
        }
        sequence.push(Step {
            position,
            reflector,
        });
        if sequence.len() > super::MAX_PLAN_POSITIONS {
            return Err(Error::input(
                Place::file(file).at_line(line),
                format!(
                    "more than {} measurements: a plan has at most that many",
                    super::MAX_PLAN_POSITIONS
                ),
            ));
        }
    }
    if sequence.is_empty() {
        return Err(Error::input(
            Place::file(file),
            "the plan file has a header but no measurement rows",
        ));
    }
    used.sort_unstable();
    let name = Path::new(file)
        .file_name()
        .map_or(file.to_string(), |n| n.to_string_lossy().into_owned());
    Ok(Plan {
        name,
        positions,
        reflectors: used,
        sequence: Some(sequence),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_shuffled_plan_round_trips_and_bad_files_name_line_and_column() {
        let m = Machine::default_xcfz();
        let mut plan = Plan::preset(&m, "test3").unwrap();
        let mut steps = plan.steps();
        steps.reverse();
        steps.truncate(100);
        plan.sequence = Some(steps);
        let text = to_csv(&plan, &m, "a test\nof two lines");
        let back = from_csv_str(&m, &text, "p.csv").unwrap();
        let poses = |p: &Plan| -> Vec<(Commands, usize)> {
            p.steps()
                .iter()
                .map(|s| (p.positions[s.position], s.reflector))
                .collect()
        };
        assert_eq!(poses(&back), poses(&plan));
        assert_eq!(back.name, "p.csv");
        let e = |t: &str| from_csv_str(&m, t, "p.csv").unwrap_err().to_string();
        assert!(e("").contains("empty plan file"));
        let msg = e("X,C,Z\n0,0,0\n");
        assert!(
            msg.contains("p.csv:1") && msg.contains("reflector"),
            "{msg}"
        );
        let msg = e("X,C,Z,reflector\n0,0,0,R1\n0,400,0,R1\n");
        assert!(
            msg.contains("p.csv:3") && msg.contains("C") && msg.contains("travel"),
            "{msg}"
        );
        let msg = e("X,C,Z,reflector\n0,0,0,R9\n");
        assert!(msg.contains("p.csv:2") && msg.contains("R9"), "{msg}");
        let msg = e("order,X,C,Z,reflector\n2,0,0,0,R1\n");
        assert!(msg.contains("p.csv:2") && msg.contains("order"), "{msg}");
        let msg = e("X,C,Z,reflector,Y\n0,0,0,R1,0\n");
        assert!(msg.contains("unknown column 'Y'"), "{msg}");
        let msg = e("# comment\nX,C,Z,reflector\n0,x,0,R1\n");
        assert!(
            msg.contains("p.csv:3") && msg.contains("found \"x\""),
            "{msg}"
        );
        let msg = e("X [m],C,Z,reflector\n0,0,0,R1\n");
        assert!(
            msg.contains("p.csv:1") && msg.contains("unit 'm', expected mm"),
            "{msg}"
        );
        assert!(from_csv_str(&m, "X [mm],C (deg),Z,reflector\n0,0,0,R1\n", "p.csv").is_ok());
        let msg = e("X,C,Z,reflector\n0,0,R1\n");
        assert!(msg.contains("p.csv:2") && msg.contains("3 fields"), "{msg}");
    }

    /// A byte-order mark is not part of the first column's name; `-0` is the pose `0`.
    #[test]
    fn a_byte_order_mark_and_negative_zero_are_read() {
        let m = Machine::default_xcfz();
        let text = "\u{feff}order,X,C,Z,reflector\n1,0,0,0,R1\n2,-0,0,-0.0,R2\n";
        let plan = from_csv_str(&m, text, "p.csv").unwrap();
        assert_eq!(plan.positions.len(), 1);
        assert_eq!(plan.steps().len(), 2);
    }

    /// A million rows of distinct poses (the documented largest plan) are read: the poses are
    /// indexed by a hash, not searched row by row (which took ~20 min here), and every row
    /// finds its own pose.
    #[test]
    fn a_million_distinct_poses_are_indexed() {
        let m = Machine::default_xcfz();
        let n = super::super::MAX_PLAN_POSITIONS;
        let mut text = String::from("X,C,Z,reflector\n");
        for i in 0..n {
            let (x, c, z) = (i % 1000, (i / 1000) % 100, i / 100_000);
            let _ = writeln!(text, "{}.{x:03},{c}.5,{z},R{}", x / 2, 1 + i % 2);
        }
        let plan = from_csv_str(&m, &text, "big.csv").unwrap();
        assert_eq!(plan.steps().len(), n);
        assert_eq!(plan.positions.len(), n);
        let last = plan.steps()[n - 1];
        assert_eq!(last.position, n - 1);
        assert_eq!(plan.positions[last.position].0[2], 9.0);
        // One pose more: refused with the bound named.
        text.push_str("1,1,1,R1\n");
        let msg = from_csv_str(&m, &text, "big.csv").unwrap_err().to_string();
        assert!(msg.contains("1000000"), "{msg}");
    }
}
