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
//! were not sorted since they were written). Lines starting with `#` are comments, blank lines
//! are skipped and cells may be quoted (the file is read through [`crate::csvio`]). Rows with the
//! same axis values are the same pose: the plan's positions are its distinct poses in order of
//! first appearance. Every error names the file, line and column.
//!
//! **Directions of approach.** A plan that states from which side each axis arrives at a
//! measured position (a bidirectional plan, [`super::sides`]) has an `approach_<AXIS>` column
//! for each axis whose stated directions its row order does not give: `+1` (the axis arrives
//! moving in its positive direction), `-1` (negative), `0` (not stated: no approach move); the
//! cells are read as in measurement files ([`crate::approach::parse_sign`]). A stated column wins
//! for its axis; the other axes' directions are those of the rows' order. A plan file without
//! such columns keeps its meaning: every direction is the order's. A column must give every row
//! a direction (an empty cell, or a value that is no direction, is refused naming the line and
//! column).
//!
//! [`gcode`] writes a plan's measuring program: G-code that visits the poses in the file's order
//! through a clearance position and waits the plan's measuring time at each (see
//! [`ProgramOptions`] and [`crate::dialect`]).

use super::{Plan, Step};
use crate::approach::{self, Approach};
use crate::chain::MAX_AXES;
use crate::csvio::{self, Format, Header, Row};
use crate::error::{Error, Place, Result};
use crate::machine::{Commands, Machine};
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

mod program;
mod route;
pub use program::{
    DEFAULT_APPROACH_FEED, MAX_APPROACH_FEED, MAX_SECONDS_PER_POINT, MAX_SETTLE_S,
    MIN_SECONDS_PER_POINT, ProgramOptions, Wait, gcode, program_approaches,
};

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
    out.push_str(",reflector");
    let stated = stated_axes(plan, machine);
    for (k, ax) in machine.axes().iter().enumerate() {
        if stated[k] {
            let _ = write!(out, ",{}", approach::column_name(ax.axis.letter()));
        }
    }
    out.push('\n');
    let directions = plan.approaches(1);
    for (i, s) in plan.steps().iter().enumerate() {
        let _ = write!(out, "{}", i + 1);
        let c = &plan.positions[s.position];
        for (k, ax) in machine.axes().iter().enumerate() {
            // Rounded to 1e-9 of the unit: the written value reads back as the same pose.
            let v = (ax.to_file_units(c.0[k]) * 1e9).round() / 1e9;
            let _ = write!(out, ",{}", v + 0.0);
        }
        let _ = write!(
            out,
            ",{}",
            csvio::cell(&machine.reflectors()[s.reflector].id)
        );
        for k in (0..machine.axes().len()).filter(|&k| stated[k]) {
            out.push_str(match directions[i].0[k] {
                1 => ",+1",
                -1 => ",-1",
                _ => ",0",
            });
        }
        out.push('\n');
    }
    out
}

/// The axes whose directions `plan` states and its order does not give: the `approach_<AXIS>`
/// columns its file needs to be read back the same.
fn stated_axes(plan: &Plan, machine: &Machine) -> [bool; MAX_AXES] {
    let mut out = [false; MAX_AXES];
    let Some(stated) = &plan.approach else {
        return out;
    };
    let order = Plan {
        approach: None,
        ..plan.clone()
    };
    for (s, d) in stated.iter().zip(order.approaches(1)) {
        for (k, o) in out.iter_mut().enumerate().take(machine.axes().len()) {
            *o |= s.0[k] != d.0[k];
        }
    }
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
    let format = Format {
        comments: true,
        ..Format::default()
    };
    let Some(mut table) = csvio::read(text, file, format)? else {
        return Err(Error::input(
            Place::file(file),
            "empty plan file: expected a header with the axis columns and reflector",
        ));
    };
    let mut reader = PlanReader::new(machine, table.header())?;
    for row in table.rows() {
        reader.add(&row?)?;
    }
    reader.finish(file)
}

/// A plan file's columns and the plan read from its rows so far.
struct PlanReader<'m> {
    machine: &'m Machine,
    /// The axes' columns, in chain order.
    axes: Vec<usize>,
    reflector: usize,
    order: Option<usize>,
    /// The distinct poses, in order of first appearance.
    positions: Vec<Commands>,
    /// Each distinct pose's index, by its bits (a hash lookup: a million rows read in linear
    /// time; `-0.0` is `0.0`).
    index: HashMap<[u64; MAX_AXES], usize>,
    sequence: Vec<Step>,
    /// The reflectors measured.
    used: Vec<usize>,
    /// `approach_<AXIS>` columns: (chain axis, column).
    approach_columns: Vec<(usize, usize)>,
    /// The directions the columns state, one per row.
    approach: Vec<Approach>,
}

impl<'m> PlanReader<'m> {
    /// The columns of `header`: the machine's axes, `reflector` and optionally `order`, nothing
    /// else.
    fn new(machine: &'m Machine, header: &Header) -> Result<PlanReader<'m>> {
        let axes = crate::measure::axis_columns(machine, header)?;
        let reflector = header.require("reflector", || {
            "missing column 'reflector'; a plan file has the axis letters, reflector and \
             optionally order"
                .to_string()
        })?;
        let order = header.find("order")?;
        let approach_columns = crate::measure::approach_columns(machine, header)?;
        let is_axis = |n: &str| {
            machine
                .axes()
                .iter()
                .any(|ax| ax.axis.letter().to_string() == n)
        };
        if let Some(unknown) = header.names().iter().find(|n| {
            n.as_str() != "reflector"
                && n.as_str() != "order"
                && !n.starts_with("approach_")
                && !is_axis(n)
        }) {
            return Err(Error::input(
                header.place(unknown),
                format!(
                    "unknown column '{unknown}': a plan file has the axes of {}, reflector, \
                     order and approach_<AXIS>",
                    machine.chain()
                ),
            ));
        }
        Ok(PlanReader {
            machine,
            axes,
            reflector,
            order,
            positions: Vec::new(),
            index: HashMap::new(),
            sequence: Vec::new(),
            used: Vec::new(),
            approach_columns,
            approach: Vec::new(),
        })
    }

    /// Adds the measurement of `row`: its order checked, its pose found or added.
    fn add(&mut self, row: &Row) -> Result<()> {
        if let Some(c) = self.order {
            let want = self.sequence.len() + 1;
            if row.number(c, "count")? != want as f64 {
                return Err(row.error(
                    c,
                    format!(
                        "order {} where row {want} of the plan stands: the rows are measured in \
                         the file's order",
                        row.text(c)
                    ),
                ));
            }
        }
        let commands = crate::measure::read_commands(self.machine, row, &self.axes)?;
        let reflector = self
            .machine
            .reflector_named(row.text(self.reflector))
            .map_err(|m| row.error(self.reflector, m))?;
        let positions = &mut self.positions;
        let position = *self
            .index
            .entry(commands.0.map(|v| (v + 0.0).to_bits()))
            .or_insert_with(|| {
                positions.push(commands);
                positions.len() - 1
            });
        if !self.used.contains(&reflector) {
            self.used.push(reflector);
        }
        if !self.approach_columns.is_empty() {
            self.approach
                .push(read_approach(row, &self.approach_columns)?);
        }
        self.sequence.push(Step {
            position,
            reflector,
        });
        if self.sequence.len() > super::MAX_PLAN_POSITIONS {
            return Err(Error::input(
                row.place_of_row(),
                format!(
                    "more than {} measurements: a plan has at most that many",
                    super::MAX_PLAN_POSITIONS
                ),
            ));
        }
        Ok(())
    }

    /// The plan read, named after `file`; a file without rows is refused.
    fn finish(mut self, file: &str) -> Result<Plan> {
        if self.sequence.is_empty() {
            return Err(Error::input(
                Place::file(file),
                "the plan file has a header but no measurement rows",
            ));
        }
        self.used.sort_unstable();
        let name = Path::new(file)
            .file_name()
            .map_or(file.to_string(), |n| n.to_string_lossy().into_owned());
        let mut plan = Plan {
            name,
            positions: self.positions,
            reflectors: self.used,
            sequence: Some(self.sequence),
            approach: None,
        };
        if !self.approach_columns.is_empty() {
            // The stated axes' directions as the columns give them, the others the order's.
            let mut stated = self.approach;
            for (a, d) in stated.iter_mut().zip(plan.approaches(1)) {
                for k in 0..MAX_AXES {
                    if !self.approach_columns.iter().any(|c| c.0 == k) {
                        a.0[k] = d.0[k];
                    }
                }
            }
            plan.approach = Some(stated);
        }
        Ok(plan)
    }
}

/// The directions of approach `row` states in its `approach_<AXIS>` columns (`columns`: chain
/// axis, column); an empty cell or a value that is no direction is refused.
fn read_approach(row: &Row, columns: &[(usize, usize)]) -> Result<Approach> {
    let mut a = Approach::UNKNOWN;
    for &(k, col) in columns {
        a.0[k] = approach::parse_sign(row.text(col)).ok_or_else(|| {
            row.error(
                col,
                format!(
                    "'{}' is no direction of approach: a plan's approach column gives every row \
                     +1 (the axis arrives moving in its positive direction), -1 (negative) or 0 \
                     (not stated)",
                    row.text(col)
                ),
            )
        })?;
    }
    Ok(a)
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

    /// A bidirectional plan's stated directions are written in `approach_<AXIS>` columns and
    /// read back the same; a file without them keeps the order's directions; a column gives
    /// the axis' directions and the order the others; a partial column, a value that is no
    /// direction and a column for no axis are refused naming the line and column.
    #[test]
    fn stated_directions_round_trip_and_contradictions_are_refused() {
        use crate::plan::sides::Overrun;
        let m = Machine::default_xcfz();
        let plain = Plan::preset(&m, "test3").unwrap().shuffled(2);
        let plan = plain.bidirectional(&m, &Overrun::default()).unwrap();
        let text = to_csv(&plan, &m, "both sides");
        let header = text.lines().find(|l| l.starts_with("order")).unwrap();
        assert_eq!(
            header,
            "order,X,C,Z,reflector,approach_X,approach_C,approach_Z"
        );
        assert!(text.contains(",R1,+1,+1,+1\n") && text.contains(",R2,-1,-1,-1\n"));
        let back = from_csv_str(&m, &text, "b.csv").unwrap();
        assert_eq!(back.approaches(1), plan.approaches(1));
        assert_eq!(back.approaches(2), plan.approaches(2));
        assert_eq!(to_csv(&back, &m, "both sides"), text);
        // Without the columns: the order's directions, as before.
        let back = from_csv_str(&m, &to_csv(&plain, &m, ""), "p.csv").unwrap();
        assert!(back.approach.is_none());
        assert_eq!(back.approaches(2), plain.approaches(2));
        // One column: X as stated, C and Z from the rows' order (as the file without it).
        let rows = "0,0,0,R1\n700,0,0,R1\n700,90,0,R1\n";
        let order = from_csv_str(&m, &format!("X,C,Z,reflector\n{rows}"), "o.csv")
            .unwrap()
            .approaches(1);
        let text = "X,C,Z,reflector,approach_X\n0,0,0,R1,-1\n700,0,0,R1,+\n700,90,0,R1,-1\n";
        let a = from_csv_str(&m, text, "s.csv").unwrap().approaches(1);
        assert_eq!(a.iter().map(|a| a.0[0]).collect::<Vec<_>>(), [-1, 1, -1]);
        assert_ne!(order[0].0[0], -1);
        for k in [1, 2] {
            let axis =
                |v: &[crate::approach::Approach]| v.iter().map(|a| a.0[k]).collect::<Vec<_>>();
            assert_eq!(axis(&a), axis(&order));
        }
        assert_eq!(order[2].0[1], 1);
        let e = |t: &str| from_csv_str(&m, t, "s.csv").unwrap_err().to_string();
        let msg = e("X,C,Z,reflector,approach_X\n0,0,0,R1,-1\n700,0,0,R1,\n");
        assert!(
            msg.contains("s.csv:3") && msg.contains("approach_X") && msg.contains("every row"),
            "{msg}"
        );
        let msg = e("X,C,Z,reflector,approach_X\n0,0,0,R1,up\n");
        assert!(
            msg.contains("s.csv:2") && msg.contains("'up' is no direction"),
            "{msg}"
        );
        let msg = e("X,C,Z,reflector,approach_Y\n0,0,0,R1,1\n");
        assert!(
            msg.contains("s.csv:1") && msg.contains("'approach_Y' names no axis"),
            "{msg}"
        );
        let msg = e("X,C,Z,reflector,approach_X,approach_X\n0,0,0,R1,1,1\n");
        assert!(
            msg.contains("s.csv:1") && msg.contains("approach_X"),
            "{msg}"
        );
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
