//! The measuring program of a plan: G-code that visits its poses in the plan file's order
//! through a clearance position and waits the plan's measuring time at each ([`gcode`]).

use super::super::Plan;
use super::super::sides::{Overrun, fits};
use super::route::Route;
use crate::approach::Approach;
use crate::dialect::{Dialect, MAX_DWELL_S};
use crate::error::{Error, Place, Result};
use crate::machine::Machine;
use crate::units::S_PER_H;
use std::fmt::Write as _;

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

/// The default feed of the approach moves (mm/min; degrees/min for a rotary axis moving
/// alone): the last overrun of an approach (5 mm by default) takes 0.3 s.
pub const DEFAULT_APPROACH_FEED: f64 = 1000.0;

/// The fastest feed of the approach moves a measuring program takes (mm/min).
pub const MAX_APPROACH_FEED: f64 = 100_000.0;

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
    /// How far an axis whose direction of approach the plan states travels in that direction
    /// before its position ([`Overrun::on`]: at most half the axis' travel).
    pub overrun: Overrun,
    /// The feed of the approach moves (mm/min, 0 < feed ≤ [`MAX_APPROACH_FEED`]; degrees/min
    /// for a rotary axis moving alone).
    pub approach_feed: f64,
}

impl ProgramOptions {
    /// The defaults for `machine`: LinuxCNC, timed waits of
    /// [`crate::plan::DEFAULT_SECONDS_PER_POINT`] per reflector, no extra settling wait, the
    /// machine file's clearance (empty when it has none: [`gcode`] then refuses), the default
    /// [`Overrun`] and [`DEFAULT_APPROACH_FEED`].
    pub fn new(machine: &Machine) -> ProgramOptions {
        ProgramOptions {
            dialect: Dialect::LinuxCnc,
            wait: Wait::Time,
            clearance: machine.clearance().to_vec(),
            seconds_per_point: crate::plan::DEFAULT_SECONDS_PER_POINT,
            settle_s: 0.0,
            overrun: Overrun::default(),
            approach_feed: DEFAULT_APPROACH_FEED,
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
        self.overrun.check()?;
        let feed = self.approach_feed;
        if !(feed.is_finite() && feed > 0.0 && feed <= MAX_APPROACH_FEED) {
            return at(
                "approach_feed",
                format!(
                    "{feed:?} mm/min: the approach moves' feed is more than 0 and at most \
                     {MAX_APPROACH_FEED} mm/min"
                ),
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
    /// The directions of approach the plan states for its measurements.
    approach: Option<Approach>,
}

/// The visits of `plan`: runs of steps at one pose with one stated direction of approach, each
/// reflector once per run.
fn visits(plan: &Plan) -> Vec<Visit> {
    let mut out: Vec<Visit> = Vec::new();
    let stated = plan.approach.as_ref();
    for (i, s) in plan.steps().iter().enumerate() {
        let approach = stated.map(|a| a.get(i).copied().unwrap_or_default());
        match out.last_mut() {
            Some(v)
                if v.position == s.position
                    && !v.reflectors.contains(&s.reflector)
                    && v.approach == approach =>
            {
                v.reflectors.push(s.reflector)
            }
            _ => out.push(Visit {
                position: s.position,
                reflectors: vec![s.reflector],
                first_row: i,
                approach,
            }),
        }
    }
    out
}

/// Refuses a stated direction of approach whose overrun would leave the axis' travel (the
/// message names the plan row and the axis).
fn check_approaches(plan: &Plan, machine: &Machine, overrun: &Overrun) -> Result<()> {
    let Some(stated) = &plan.approach else {
        return Ok(());
    };
    for (i, (s, a)) in plan.steps().iter().zip(stated).enumerate() {
        let pose = plan.positions[s.position];
        for (k, ax) in machine.axes().iter().enumerate() {
            let (o, _) = overrun.on(ax);
            if a.0[k] == 0 || fits(ax, pose.0[k], a.0[k], o) {
                continue;
            }
            let (v, o) = (ax.to_file_units(pose.0[k]), ax.to_file_units(o));
            let unit = ax.file_unit();
            return Err(Error::input(
                Place::file("the measuring program").at_field("approach"),
                format!(
                    "plan row {}: axis {} at {} {unit} is to arrive moving {} over the overrun \
                     of {} {unit}, which starts at {} {unit}, outside its travel [{}, {}] {unit}: \
                     approach it from the other side, or give a smaller overrun",
                    i + 1,
                    ax.axis,
                    crate::error::number(v),
                    if a.0[k] > 0 { "up (+1)" } else { "down (-1)" },
                    crate::error::number(o),
                    crate::error::number(v - f64::from(a.0[k]) * o),
                    crate::error::number(ax.to_file_units(ax.min)),
                    crate::error::number(ax.to_file_units(ax.max)),
                ),
            ));
        }
    }
    Ok(())
}

/// The measuring program of `plan` on `machine` (G-code in the options' dialect, the machine's
/// axis words in mm and degrees as machine coordinates, `G53` on every rapid, whatever work
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
/// - **Approach moves**, for a plan that states directions of approach ([`Plan::approach`]:
///   a bidirectional plan, a plan file's `approach_<AXIS>` columns, the order's directions for
///   the axes without a column): each axis with a direction (+1 or −1) at a visit arrives at its
///   position moving in that direction over at least the overrun ([`ProgramOptions::overrun`]).
///   The other axes do so at the clearance: a rapid to the position minus (plus) the overrun,
///   then a feed move to it, those axes together. Each clearance axis does so alone, after the
///   others: a rapid to the overrun's distance on the side it comes from, then at feed to where
///   its approach starts (through the position, when that is beyond it: an overshoot away from
///   the clearance is never a rapid), then to the position. Feed moves are incremental
///   (`G91 G1 … F`, then `G90`), the differences of the written positions: they end where a
///   `G53` move would, whatever the work offset (Fanuc's `G53` moves at rapid only). An axis
///   that arrived at the pose in the stated direction at the visit before is not moved again;
///   an axis with no direction (0) moves as without approach moves. Refused when an approach
///   would start outside the axis' travel (the message names the plan row and the axis).
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
    Ok(run(plan, machine, options, title)?.0)
}

/// The direction of approach of each of `plan`'s measurements as its measuring program
/// ([`gcode`] with `options`) makes them: each axis' last move as written before the
/// measurement — the clearance axes, retracted between poses, arrive from the clearance's side
/// whatever the order of the poses says; an axis with a stated direction arrives in it. Before
/// an axis' first move, the direction of that move ([`crate::approach`]); 0 for an axis that
/// never moves. What real data taken by the program have ([`MeasurementSet::take_approach_from_plan`]).
///
/// ```
/// use volver_core::machine::Machine;
/// use volver_core::plan::{Plan, file};
/// let m = Machine::default_xcfz(); // [clearance] Z = 600.0
/// // Z steps up, X back and forth: between poses the program retracts Z to 600 and brings it
/// // down, so Z arrives at 0 and 300 moving − whatever the plan's order says (+ from 0 to
/// // 300); at 600, the clearance itself, it arrived by the retract, moving +.
/// let plan = Plan::parse_grid(&m, "X=0,C=0,Z=0;X=700,C=0,Z=300;X=0,C=0,Z=600").unwrap();
/// let a = file::program_approaches(&plan, &m, &file::ProgramOptions::new(&m)).unwrap();
/// let z: Vec<i8> = a.iter().map(|a| a.0[2]).collect();
/// assert_eq!(z, [-1, -1, -1, -1, 1, 1]);
/// assert_eq!(plan.approaches(1)[2].0[2], 1);
/// ```
///
/// [`MeasurementSet::take_approach_from_plan`]: crate::measure::MeasurementSet::take_approach_from_plan
pub fn program_approaches(
    plan: &Plan,
    machine: &Machine,
    options: &ProgramOptions,
) -> Result<Vec<Approach>> {
    let (_, arrived) = run(plan, machine, options, "")?;
    let mut out = Vec::with_capacity(plan.n_points());
    for (v, a) in visits(plan).iter().zip(arrived) {
        out.extend(std::iter::repeat_n(a, v.reflectors.len()));
    }
    crate::approach::assume_first_moves(&mut out);
    Ok(out)
}

/// [`gcode`] and the directions each visit's axes arrive with.
fn run(
    plan: &Plan,
    machine: &Machine,
    options: &ProgramOptions,
    title: &str,
) -> Result<(String, Vec<Approach>)> {
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
    check_approaches(plan, machine, &options.overrun)?;
    let d = options.dialect;
    let mut out = d.program_start();
    header(&mut out, plan, machine, options, &visits, title);
    out.push_str(d.start_blocks());
    let overrun = options.overrun.per_axis(machine);
    let mut route = Route::new(
        out,
        machine,
        d,
        &options.clearance,
        (overrun, options.approach_feed),
    );
    let mut arrived = Vec::with_capacity(visits.len());
    for (k, v) in visits.iter().enumerate() {
        let pose = plan.positions[v.position];
        let number = (k < 99_999).then_some(k + 1);
        route.visit(&pose, v.approach.as_ref(), number);
        arrived.push(route.arrived);
        wait(&mut route.out, machine, options, k, v);
    }
    route.retract();
    let mut out = route.out;
    out.push_str(d.program_end());
    Ok((out, arrived))
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
    if let Some(note) = approach_note(plan, machine, options) {
        lines.push(note);
        lines.push(APPROACH_RULES.to_string());
    }
    lines.push(wait_note(options, steps.len(), machine.stations().len()));
    for l in lines {
        out.push_str(&d.comment(&l));
        out.push('\n');
    }
}

/// The header's line on the approach moves of a plan that states directions of approach.
fn approach_note(plan: &Plan, machine: &Machine, options: &ProgramOptions) -> Option<String> {
    let stated = plan.approach.as_ref()?;
    let axes: Vec<String> = machine
        .axes()
        .iter()
        .enumerate()
        .filter(|&(k, _)| stated.iter().any(|a| a.0[k] != 0))
        .map(|(_, ax)| {
            let (o, clipped) = options.overrun.on(ax);
            let half = if clipped { ", half its travel" } else { "" };
            format!(
                "{} {} {}{half}",
                ax.axis,
                crate::error::number(ax.to_file_units(o)),
                ax.file_unit()
            )
        })
        .collect();
    Some(format!(
        "approach: the plan states from which side each axis arrives; before each measurement \
         such an axis goes to its position minus or plus the overrun ({}), then arrives moving \
         in the stated direction at feed F{}",
        axes.join(", "),
        options.dialect.value(options.approach_feed)
    ))
}

/// The header's line on how the approach moves are written and kept safe.
const APPROACH_RULES: &str = "approach moves: G91 G1 incremental, then G90; the other axes at \
     the clearance, each clearance axis alone; no rapid takes a clearance axis beyond a position \
     away from the clearance";

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
    let letters: Vec<char> = machine.axes().iter().map(|a| a.axis.letter()).collect();
    let from = v
        .approach
        .map(|a| {
            let words: Vec<String> = a
                .describe(&letters)
                .split(' ')
                .filter(|w| !w.ends_with('?'))
                .map(str::to_string)
                .collect();
            format!(", approached {}", words.join(" "))
        })
        .filter(|t| !t.ends_with("approached "))
        .unwrap_or_default();
    let comment = d.comment(&format!(
        "visit {}, pose {}: measure {}, {rows}{from}",
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::file::from_csv_str;

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

    /// A plan that states directions of approach: each stated axis goes to its position minus
    /// (plus) the overrun and arrives at feed in the stated direction: the other axes at the
    /// clearance, Z alone (its overshoot below the pose at feed); an approach that would leave
    /// the travel is refused naming the plan row and the axis.
    #[test]
    fn stated_directions_get_approach_moves_over_the_overrun() {
        let m = Machine::default_xcfz();
        let csv = "X,C,Z,reflector,approach_X,approach_C,approach_Z\n\
                   700,90,300,R1,+1,+1,+1\n700,90,300,R1,-1,-1,-1\n1400,90,600,R1,+1,0,+1\n";
        let plan = from_csv_str(&m, csv, "p.csv").unwrap();
        let o = ProgramOptions::new(&m);
        let nc = gcode(&plan, &m, &o, "t").unwrap();
        let body: Vec<&str> = nc
            .lines()
            .filter(|l| !l.starts_with('(') && !l.starts_with('%'))
            .skip_while(|l| !l.contains("G53"))
            .collect();
        assert_eq!(
            body,
            [
                "N1 G53 G0 Z600 (clearance)",
                "G53 G0 X695 C89",
                "G91 G1 X5 C1 F1000 (approach X+ C+)",
                "G90",
                "G53 G0 Z305",
                "G91 G1 Z-10 F1000",
                "G90",
                "G91 G1 Z5 F1000 (approach Z+)",
                "G90",
                "G4 P10 (visit 1, pose 1: measure R1, plan row 1, approached X+ C+ Z+)",
                "N2 G53 G0 Z600 (clearance)",
                "G53 G0 X705 C91",
                "G91 G1 X-5 C-1 F1000 (approach X- C-)",
                "G90",
                "G53 G0 Z305",
                "G91 G1 Z-5 F1000 (approach Z-)",
                "G90",
                "G4 P10 (visit 2, pose 1: measure R1, plan row 2, approached X- C- Z-)",
                "N3 G53 G0 Z600 (clearance)",
                "G53 G0 X1395",
                "G91 G1 X5 F1000 (approach X+)",
                "G90",
                "G91 G1 Z-5 F1000",
                "G90",
                "G91 G1 Z5 F1000 (approach Z+)",
                "G90",
                "G4 P10 (visit 3, pose 2: measure R1, plan row 3, approached X+ Z+)",
                "M30",
            ]
        );
        assert!(nc.contains("(approach: the plan states"), "{nc}");
        let fanuc = ProgramOptions {
            dialect: Dialect::Fanuc,
            approach_feed: 500.0,
            ..ProgramOptions::new(&m)
        };
        let nc = gcode(&plan, &m, &fanuc, "t").unwrap();
        assert!(
            nc.contains("\nG91 G01 X5. C1. F500. (approach X+ C+)\nG90\n"),
            "{nc}"
        );
        // Z = 600 is the top of its travel: it cannot arrive there moving down.
        let csv = "X,C,Z,reflector,approach_Z\n700,90,300,R1,+1\n1400,90,600,R1,-1\n";
        let plan = from_csv_str(&m, csv, "p.csv").unwrap();
        let e = gcode(&plan, &m, &o, "t").unwrap_err().to_string();
        assert!(
            e.contains("plan row 2: axis Z at 600 mm")
                && e.contains("starts at 605 mm, outside its travel [0, 600] mm"),
            "{e}"
        );
        let bad = ProgramOptions {
            approach_feed: 0.0,
            ..ProgramOptions::new(&m)
        };
        let e = gcode(&plan, &m, &bad, "t").unwrap_err().to_string();
        assert!(e.contains("field 'approach_feed'"), "{e}");
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
}
