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
//! [`gcode`] writes a plan's measuring program: G-code that visits the poses in the file's order
//! through a clearance position and waits the plan's measuring time at each (see
//! [`ProgramOptions`] and [`crate::dialect`]).

use super::{Plan, Step};
use crate::chain::MAX_AXES;
use crate::csvio::{self, Format, Header, Row};
use crate::dialect::{Dialect, MAX_DWELL_S};
use crate::error::{Error, Place, Result};
use crate::machine::{Commands, Machine};
use crate::units::S_PER_H;
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
        let _ = writeln!(
            out,
            ",{}",
            csvio::cell(&machine.reflectors()[s.reflector].id)
        );
    }
    out
}

/// How the measuring program waits at each pose for the tracker to measure.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Wait {
    /// A dwell of the plan's measuring time for the reflectors measured there (`G4`/`G04`):
    /// the tracker measures on its own (a triggered or continuous measurement).
    #[default]
    Time,
    /// A program stop (`M0`) per pose: the operator measures, then presses cycle start.
    Stop,
    /// An optional stop (`M1`) per pose: as `Stop` with the control's optional-stop switch on.
    OptionalStop,
}

impl std::str::FromStr for Wait {
    type Err = String;

    /// `time`, `m0` or `m1`.
    fn from_str(s: &str) -> std::result::Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "time" => Ok(Wait::Time),
            "m0" => Ok(Wait::Stop),
            "m1" => Ok(Wait::OptionalStop),
            _ => Err(format!(
                "unknown wait '{s}': expected time (a dwell of the plan's measuring time per \
                 pose), m0 (a program stop per pose) or m1 (an optional stop per pose)"
            )),
        }
    }
}

/// The longest extra settling wait per pose of a measuring program (s): an hour.
pub const MAX_SETTLE_S: f64 = 3600.0;

/// The longest measuring time per reflector measurement a measuring program takes (s): an hour.
pub const MAX_SECONDS_PER_POINT: f64 = 3600.0;

/// The shortest measuring time per reflector measurement a measuring program takes (s): a
/// tenth of a second, so that the waits (written to the millisecond) add up to the plan's
/// duration within 0.5 %.
pub const MIN_SECONDS_PER_POINT: f64 = 0.1;

/// How [`gcode`] writes a measuring program.
#[derive(Clone, Debug, PartialEq)]
pub struct ProgramOptions {
    /// The G-code dialect.
    pub dialect: Dialect,
    /// How the program waits at each pose.
    pub wait: Wait,
    /// The clearance position: (chain index, position in mm or rad) as
    /// [`Machine::clearance`] gives it; at least one axis.
    pub clearance: Vec<(usize, f64)>,
    /// The measuring time of one reflector measurement (s, [`MIN_SECONDS_PER_POINT`] to
    /// [`MAX_SECONDS_PER_POINT`]): the plan's time per point, from which its duration is
    /// computed.
    pub seconds_per_point: f64,
    /// An extra wait per pose for the machine and the tracker to settle (s, 0 to
    /// [`MAX_SETTLE_S`]), before the measuring time (or the stop); not part of the plan's
    /// duration.
    pub settle_s: f64,
}

impl ProgramOptions {
    /// The defaults for `machine`: LinuxCNC, timed waits of
    /// [`super::DEFAULT_SECONDS_PER_POINT`] per reflector, no extra settling wait, the
    /// machine file's clearance (empty when it has none: [`gcode`] then refuses).
    pub fn new(machine: &Machine) -> ProgramOptions {
        ProgramOptions {
            dialect: Dialect::LinuxCnc,
            wait: Wait::Time,
            clearance: machine.clearance().to_vec(),
            seconds_per_point: super::DEFAULT_SECONDS_PER_POINT,
            settle_s: 0.0,
        }
    }

    /// The options' values checked: the message names the field at fault.
    fn check(&self, machine: &Machine) -> Result<()> {
        let at = |field: &str, m: String| {
            Err(Error::input(
                Place::file("the measuring program").at_field(field),
                m,
            ))
        };
        let spp = self.seconds_per_point;
        if !(spp.is_finite() && (MIN_SECONDS_PER_POINT..=MAX_SECONDS_PER_POINT).contains(&spp)) {
            return at(
                "seconds_per_point",
                format!(
                    "{spp:?} s: a measuring time per point of {MIN_SECONDS_PER_POINT} to \
                     {MAX_SECONDS_PER_POINT} s (waits are written to the millisecond)"
                ),
            );
        }
        let settle = self.settle_s;
        if !(settle.is_finite() && (0.0..=MAX_SETTLE_S).contains(&settle)) {
            return at(
                "settle_s",
                format!("{settle:?} s: a settling wait of 0 to {MAX_SETTLE_S} s per pose"),
            );
        }
        if self.clearance.is_empty() {
            return at(
                "clearance",
                "no clearance position: the program retracts there between poses; give the \
                 machine file a [clearance] table (e.g. `Z = 600.0`, the axis and end that take \
                 the reflectors away from the workpiece) or `volver plan --clearance Z=600`"
                    .to_string(),
            );
        }
        for (i, &(j, v)) in self.clearance.iter().enumerate() {
            let Some(ax) = machine.axes().get(j) else {
                return at(
                    "clearance",
                    format!("axis index {j}: the machine has no such axis"),
                );
            };
            let text = format!("{}={}", ax.axis, ax.to_file_units(v));
            if self.clearance[..i].iter().any(|c| c.0 == j) || v.is_nan() {
                return at("clearance", format!("{text}: given twice or not a number"));
            }
            // The machine's own check of a clearance (travel, finite).
            if let Err(m) = machine.clearance_from_text(&text) {
                return at("clearance", m);
            }
        }
        Ok(())
    }
}

/// One visit of a pose: the plan's position, the reflectors measured there in order and the
/// plan row (0-based) of the first.
struct Visit {
    position: usize,
    reflectors: Vec<usize>,
    first_row: usize,
}

/// The visits of `plan`: runs of steps at one pose, each reflector once per run.
fn visits(plan: &Plan) -> Vec<Visit> {
    let mut out: Vec<Visit> = Vec::new();
    for (i, s) in plan.steps().iter().enumerate() {
        match out.last_mut() {
            Some(v) if v.position == s.position && !v.reflectors.contains(&s.reflector) => {
                v.reflectors.push(s.reflector)
            }
            _ => out.push(Visit {
                position: s.position,
                reflectors: vec![s.reflector],
                first_row: i,
            }),
        }
    }
    out
}

/// The measuring program of `plan` on `machine` (G-code in the options' dialect, the machine's
/// axis words in mm and degrees as machine coordinates, `G53` on every move, whatever work
/// offset is in force).
///
/// - It starts with `%` (and `O0001` for Fanuc), a header naming the plan (`title`), its size,
///   the clearance and the waits, and a start block: `G40 G49 G80` (cutter compensation, tool
///   length offset, canned cycles off), `G21 G90 G17 G94`, `M5 M9` (spindle, coolant off).
/// - Before the first pose it rapids to the clearance position moving only the clearance axes.
///   Between poses it rapids to the clearance (only the clearance axes move; linear ones first,
///   then rotary ones), then moves every other axis (rotary ones too) with the clearance axes
///   held, then approaches (only the clearance axes move: rotary ones first, then linear ones).
///   When no other axis changes between two poses it moves the clearance axes directly. No
///   rapid ever moves a clearance axis and another axis at once.
/// - At each visit of a pose it waits ([`Wait::Time`]) the options' settling time plus
///   `seconds_per_point` for each reflector measured there, so that without settling the waits
///   add up to the plan's duration at that time per point (per station: a plan measured from
///   several stations is run once from each); or stops (`M0`/`M1`). The wait's comment names
///   the reflectors to measure, in order, and the plan file's rows they are.
/// - It ends at the clearance position with `M30` and `%`.
///
/// Refused when the options have no clearance or a time out of bounds (the message names the
/// field).
///
/// ```
/// use volver_core::machine::Machine;
/// use volver_core::plan::{Plan, file};
/// let m = Machine::default_xcfz(); // its machine file: [clearance] Z = 600.0
/// let plan = Plan::parse_grid(&m, "X=0:1400:1400,C=90,Z=0").unwrap();
/// let nc = file::gcode(&plan, &m, &file::ProgramOptions::new(&m), "a test").unwrap();
/// let blocks: Vec<&str> = nc.lines().filter(|l| !l.starts_with('(')).collect();
/// assert_eq!(
///     blocks,
///     [
///         "%", "G40 G49 G80", "G21 G90 G17 G94", "M5 M9",
///         "N1 G53 G0 Z600 (clearance)", "G53 G0 X0 C90", "G53 G0 Z0",
///         "G4 P20 (visit 1, pose 1: measure R1 R2, plan rows 1-2)",
///         "N2 G53 G0 Z600 (clearance)", "G53 G0 X1400", "G53 G0 Z0",
///         "G4 P20 (visit 2, pose 2: measure R1 R2, plan rows 3-4)",
///         "G53 G0 Z600 (clearance)", "M30", "%",
///     ]
/// );
/// let mut no_clearance = file::ProgramOptions::new(&m);
/// no_clearance.clearance.clear();
/// let e = file::gcode(&plan, &m, &no_clearance, "a test").unwrap_err().to_string();
/// assert!(e.contains("--clearance Z=600"), "{e}");
/// ```
pub fn gcode(
    plan: &Plan,
    machine: &Machine,
    options: &ProgramOptions,
    title: &str,
) -> Result<String> {
    options.check(machine)?;
    let visits = visits(plan);
    let most = visits.iter().map(|v| v.reflectors.len()).max().unwrap_or(0);
    let longest = options.settle_s + options.seconds_per_point * most as f64;
    if longest > MAX_DWELL_S {
        return Err(Error::input(
            Place::file("the measuring program").at_field("seconds_per_point"),
            format!(
                "a pose measuring {most} reflectors would wait {longest} s, more than the \
                 {MAX_DWELL_S} s a dwell can hold"
            ),
        ));
    }
    let d = options.dialect;
    let mut out = d.program_start();
    header(&mut out, plan, machine, options, &visits, title);
    out.push_str(d.start_blocks());
    let mut at: Option<Commands> = None;
    for (k, v) in visits.iter().enumerate() {
        let pose = plan.positions[v.position];
        let number = (k < 99_999).then_some(k + 1);
        moves_to(&mut out, machine, options, at.as_ref(), &pose, number);
        at = Some(pose);
        wait(&mut out, machine, options, k, v);
    }
    if let Some(last) = at {
        let mut clear = last;
        for &(j, value) in &options.clearance {
            clear.0[j] = value;
        }
        rapid(
            &mut out,
            machine,
            d,
            (&last, &clear),
            "clearance",
            &mut None,
        );
    }
    out.push_str(d.program_end());
    Ok(out)
}

/// The program's header comments: the plan, its size, the clearance, the waits.
fn header(
    out: &mut String,
    plan: &Plan,
    machine: &Machine,
    options: &ProgramOptions,
    visits: &[Visit],
    title: &str,
) {
    let d = options.dialect;
    let steps = plan.steps();
    let counts: Vec<String> = plan
        .reflectors
        .iter()
        .map(|&r| {
            let n = steps.iter().filter(|s| s.reflector == r).count();
            format!("{} x {n}", machine.reflectors()[r].id)
        })
        .collect();
    let clearance: Vec<String> = options
        .clearance
        .iter()
        .map(|&(j, v)| {
            let ax = &machine.axes()[j];
            format!("{}{}", ax.axis, d.value(ax.to_file_units(v)))
        })
        .collect();
    let mut lines = vec![
        format!("volver measuring program: {title}"),
        format!(
            "{} measurements in {} visits of {} poses; reflectors {}; machine {}",
            steps.len(),
            visits.len(),
            plan.positions.len(),
            counts.join(", "),
            machine.chain()
        ),
        format!(
            "positions: machine coordinates G53, mm and degrees; dialect {d}; clearance {}: \
             between poses only the clearance axes retract, then the others move, then only \
             the clearance axes approach",
            clearance.join(" ")
        ),
    ];
    lines.push(wait_note(options, steps.len(), machine.stations().len()));
    for l in lines {
        out.push_str(&d.comment(&l));
        out.push('\n');
    }
}

/// The header's line on the waits of a program of `measurements` measured from `stations`.
fn wait_note(options: &ProgramOptions, measurements: usize, stations: usize) -> String {
    let settle = if options.settle_s > 0.0 {
        format!("{} s to settle, then ", options.settle_s)
    } else {
        String::new()
    };
    let spp = options.seconds_per_point;
    match options.wait {
        Wait::Time => format!(
            "at each pose: {settle}{spp} s per reflector measured there; the waits of the \
             measurements add up to {:.4} h, the plan's duration at {spp} s per point{}; moves \
             and settling come on top",
            measurements as f64 * spp / S_PER_H,
            if stations > 1 {
                format!(" for one of its {stations} stations: run the program from each")
            } else {
                String::new()
            }
        ),
        Wait::Stop => format!(
            "at each pose: {settle}a program stop M0: measure the reflectors named, in order, \
             then cycle start"
        ),
        Wait::OptionalStop => format!(
            "at each pose: {settle}an optional stop M1, the optional stop switch on: measure the \
             reflectors named, in order, then cycle start"
        ),
    }
}

/// The moves from `from` (unknown before the first pose) to `to`, through the clearance
/// position unless only clearance axes change; `number` is the visit's block number.
fn moves_to(
    out: &mut String,
    machine: &Machine,
    options: &ProgramOptions,
    from: Option<&Commands>,
    to: &Commands,
    number: Option<usize>,
) {
    let d = options.dialect;
    let is_clearance = |j: usize| options.clearance.iter().any(|c| c.0 == j);
    let n = machine.axes().len();
    let same = |a: &Commands, j: usize| written(machine, d, a, j) == written(machine, d, to, j);
    let lateral = from.is_none_or(|f| (0..n).any(|j| !is_clearance(j) && !same(f, j)));
    // Where the machine is, as far as the program knows: the first move states its axes.
    let mut now = match from {
        Some(f) => *f,
        None => Commands([f64::NAN; crate::chain::MAX_AXES]),
    };
    let mut number = number;
    if lateral {
        // Retract: linear clearance axes first, then rotary ones.
        for rotary in [false, true] {
            let mut next = now;
            for &(j, v) in &options.clearance {
                if machine.axes()[j].axis.is_rotary() == rotary {
                    next.0[j] = v;
                }
            }
            rapid(out, machine, d, (&now, &next), "clearance", &mut number);
            now = next;
        }
        let mut next = *to;
        for &(j, v) in &options.clearance {
            next.0[j] = v;
        }
        rapid(out, machine, d, (&now, &next), "", &mut number);
        now = next;
    }
    // Approach: rotary clearance axes first, then linear ones.
    for rotary in [true, false] {
        let mut next = now;
        for &(j, _) in &options.clearance {
            if machine.axes()[j].axis.is_rotary() == rotary {
                next.0[j] = to.0[j];
            }
        }
        rapid(out, machine, d, (&now, &next), "", &mut number);
        now = next;
    }
}

/// The axis word's value of axis `j` at `c` as `d` writes it (file units), `None` when unknown.
fn written(machine: &Machine, d: Dialect, c: &Commands, j: usize) -> Option<String> {
    let v = c.0[j];
    (!v.is_nan()).then(|| d.value(machine.axes()[j].to_file_units(v)))
}

/// A rapid in machine coordinates from `from` to `to` (NaN: unknown) naming the axes whose
/// written value changes or was unknown, nothing when none does; `note` as a comment, and
/// `number` (taken) as the block's `N` when the block is written.
fn rapid(
    out: &mut String,
    machine: &Machine,
    d: Dialect,
    (from, to): (&Commands, &Commands),
    note: &str,
    number: &mut Option<usize>,
) {
    let words: Vec<String> = machine
        .axes()
        .iter()
        .enumerate()
        .filter_map(|(j, ax)| {
            let w = written(machine, d, to, j)?;
            (written(machine, d, from, j).as_ref() != Some(&w)).then(|| format!("{}{w}", ax.axis))
        })
        .collect();
    if words.is_empty() {
        return;
    }
    if let Some(n) = number.take() {
        let _ = write!(out, "N{n} ");
    }
    let _ = write!(out, "G53 {} {}", d.rapid(), words.join(" "));
    if !note.is_empty() {
        let _ = write!(out, " {}", d.comment(note));
    }
    out.push('\n');
}

/// The wait of visit `k` (0-based): a dwell or a stop, with the comment naming what to measure.
fn wait(out: &mut String, machine: &Machine, options: &ProgramOptions, k: usize, v: &Visit) {
    let d = options.dialect;
    let ids: Vec<&str> = v
        .reflectors
        .iter()
        .map(|&r| machine.reflectors()[r].id.as_str())
        .collect();
    let rows = match v.reflectors.len() {
        1 => format!("plan row {}", v.first_row + 1),
        n => format!("plan rows {}-{}", v.first_row + 1, v.first_row + n),
    };
    let comment = d.comment(&format!(
        "visit {}, pose {}: measure {}, {rows}",
        k + 1,
        v.position + 1,
        ids.join(" ")
    ));
    match options.wait {
        Wait::Time => {
            let seconds = options.settle_s + options.seconds_per_point * v.reflectors.len() as f64;
            let _ = writeln!(out, "{} {comment}", d.dwell_words(seconds));
        }
        stop => {
            if options.settle_s > 0.0 {
                let settle = d.dwell_words(options.settle_s);
                let _ = writeln!(out, "{settle} {}", d.comment("settle"));
            }
            let word = d.stop(stop == Wait::OptionalStop);
            let _ = writeln!(out, "{word} {comment}");
        }
    }
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
        let is_axis = |n: &str| {
            machine
                .axes()
                .iter()
                .any(|ax| ax.axis.letter().to_string() == n)
        };
        if let Some(unknown) = header
            .names()
            .iter()
            .find(|n| n.as_str() != "reflector" && n.as_str() != "order" && !is_axis(n))
        {
            return Err(Error::input(
                header.place(unknown),
                format!(
                    "unknown column '{unknown}': a plan file has the axes of {}, reflector and \
                     order",
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
        Ok(Plan {
            name,
            positions: self.positions,
            reflectors: self.used,
            sequence: Some(self.sequence),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_measuring_program_retracts_moves_approaches_and_waits_in_each_dialect() {
        let m = Machine::default_xcfz();
        let csv = "X,C,Z,reflector\n700,90,300,R1\n700,90,300,R2\n700,90,300,R2\n\
                   700,90,100,R1\n0,180,0,R1\n";
        let plan = from_csv_str(&m, csv, "p.csv").unwrap();
        let body = |o: &ProgramOptions| -> Vec<String> {
            let nc = gcode(&plan, &m, o, "t").unwrap();
            nc.lines()
                .filter(|l| !l.starts_with('(') && !l.starts_with('%') && !l.starts_with('O'))
                .skip_while(|l| !l.contains("G53"))
                .map(str::to_string)
                .collect()
        };
        let mut o = ProgramOptions::new(&m);
        o.seconds_per_point = 7.5;
        assert_eq!(
            body(&o),
            [
                "N1 G53 G0 Z600 (clearance)",
                "G53 G0 X700 C90",
                "G53 G0 Z300",
                "G4 P15 (visit 1, pose 1: measure R1 R2, plan rows 1-2)",
                // The same pose again (R2 twice): no move; then Z alone: a direct move.
                "G4 P7.5 (visit 2, pose 1: measure R2, plan row 3)",
                "N3 G53 G0 Z100",
                "G4 P7.5 (visit 3, pose 2: measure R1, plan row 4)",
                "N4 G53 G0 Z600 (clearance)",
                "G53 G0 X0 C180",
                "G53 G0 Z0",
                "G4 P7.5 (visit 4, pose 3: measure R1, plan row 5)",
                "G53 G0 Z600 (clearance)",
                "M30",
            ]
        );
        o.dialect = Dialect::Fanuc;
        o.wait = Wait::OptionalStop;
        o.settle_s = 2.25;
        o.clearance = m.clearance_from_text("Z=550").unwrap();
        let f = body(&o);
        assert_eq!(
            &f[..5],
            [
                "N1 G53 G00 Z550. (clearance)",
                "G53 G00 X700. C90.",
                "G53 G00 Z300.",
                "G04 P2250 (settle)",
                "M01 (visit 1, pose 1: measure R1 R2, plan rows 1-2)",
            ]
        );
        let nc = gcode(&plan, &m, &o, "t").unwrap();
        assert!(
            nc.starts_with("%\nO0001\n(volver measuring program: t)\n"),
            "{nc}"
        );
        assert!(
            nc.contains("\nG40 G49 G80\nG21 G90 G17 G94\nM05\nM09\n"),
            "{nc}"
        );
        assert!(nc.ends_with("M30\n%\n"), "{nc}");
    }

    #[test]
    fn measuring_program_times_out_of_bounds_name_the_field() {
        let m = Machine::default_xcfz();
        let plan = Plan::parse_grid(&m, "X=0:1400:700,C=0,Z=0").unwrap();
        let e = |o: &ProgramOptions| gcode(&plan, &m, o, "t").unwrap_err().to_string();
        let mut bad = ProgramOptions::new(&m);
        bad.settle_s = 1e300;
        assert!(e(&bad).contains("field 'settle_s': 1e300 s"), "{}", e(&bad));
        bad.settle_s = 0.0;
        bad.seconds_per_point = f64::NAN;
        assert!(e(&bad).contains("field 'seconds_per_point'"), "{}", e(&bad));
        bad.seconds_per_point = 3600.0;
        bad.settle_s = 3600.0;
        assert!(gcode(&plan, &m, &bad, "t").is_ok());
        for (clearance, needle) in [
            (vec![(7, 0.0)], "axis index 7"),
            (vec![(2, 700.0)], "outside the travel range [0, 600]"),
            (vec![(2, f64::INFINITY)], "finite"),
            (vec![(2, 600.0), (2, 500.0)], "given twice"),
        ] {
            let o = ProgramOptions {
                clearance,
                ..ProgramOptions::new(&m)
            };
            let msg = e(&o);
            assert!(
                msg.contains("field 'clearance'") && msg.contains(needle),
                "{msg}"
            );
        }
        // 28 reflectors at one pose, an hour each: past the longest dwell a control takes.
        let mut spec = m.spec().clone();
        spec.reflectors = (0..28)
            .map(|i| crate::machine::ReflectorSpec {
                id: format!("R{}", i + 1),
                offset: [i as f64, 0.0, 0.0],
            })
            .collect();
        let many = Machine::from_spec(spec, "many").unwrap();
        let one = Plan::parse_grid(&many, "X=0,C=0,Z=0").unwrap();
        let mut long = ProgramOptions::new(&many);
        (long.seconds_per_point, long.settle_s) = (3600.0, 3600.0);
        let msg = gcode(&one, &many, &long, "t").unwrap_err().to_string();
        assert!(
            msg.contains("measuring 28 reflectors would wait 104400 s"),
            "{msg}"
        );
    }

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
