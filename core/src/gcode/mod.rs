//! G-code programs read as a control reads them, and written back compensated.
//!
//! **Specification.** RS274NGC as LinuxCNC documents it (its G-code reference: "Modal Groups",
//! "Order of Execution", "Numbered Parameters", "Tool Table Format"; NIST's RS274NGC
//! interpreter version 3, Kramer, Proctor and Messina 2000, which it descends from). LinuxCNC's
//! own interpreter `rs274` judges volver's output in the tests (`tests/gcode_rs274.rs`).
//!
//! **Reading by modal group.** Every G and M code is compared by value (`G043.4` is `G43.4`,
//! `M0128` is `M128`) against the codes volver knows ([`codes::KNOWN_G`], [`codes::KNOWN_M`]);
//! anything else is refused with the file, line and word, because volver cannot tell whether it
//! moves the machine. Two codes of one modal group in a block are refused. Modal words apply to
//! the whole block wherever they stand, and a block executes in RS274NGC's order (feed mode, F,
//! S, T, M6, spindle, coolant, dwell, plane, units, cutter compensation, tool length, coordinate
//! system, path control, distance mode, retract mode, `G10`/`G28`/`G30`/`G52`/`G92`, the motion,
//! the stops). The non-modal codes (`G4`, `G10`, `G28`, `G30`, `G52`, `G53`, `G92`…) and their
//! words never become moves: their axis words are offsets, reference points or machine
//! coordinates; a block where a motion code and such a code both claim the axis words is
//! refused (as RS274NGC refuses it).
//!
//! **Machine positions.** A program position becomes a machine position (what the machine's
//! kinematic model and compensation work in) through the offsets the control keeps
//! ([`offsets::Offsets`]: the work offsets `G54`…`G59.3`, `G52`/`G92`, the tool length of
//! `G43 Hn` from the tool table, read from LinuxCNC's `.var` and `.tbl` files or a TOML file):
//! machine = program × unit + work offset + G92 offset + tool offset. `G20` programs are read
//! in inches. Every axis' position must be known before a compensated move (compensation moves
//! every axis): the first move states them all, a reference move (`G28`) or machine move
//! (`G53`) sets them, or [`Setup::start`] gives them. The tool in the spindle (`T`, `M6`, `M61`)
//! goes with every move, so that each tool is compensated at its own tool point.
//!
//! **Moves.** `G0`/`G1`; arcs `G2`/`G3` (centre by `I J K`, incremental or `G90.1` absolute,
//! or radius `R`; helices) linearised into chords within the chord tolerance, because
//! compensation bends them; long moves optionally split (`max_segment_mm`); the drilling and
//! boring cycles `G73`, `G81`, `G82`, `G83`, `G85`, `G86`, `G89` expanded into `G0`/`G1` moves
//! (with their dwells and spindle words) exactly where LinuxCNC's interpreter moves, in `G17`,
//! `G90`: a cycle kept as a cycle at a compensated hole position would still move Z straight
//! down in the control, while compensation bends that line, so no kept cycle is exact. `G28`
//! and `G30` are kept as reference moves (machine coordinates, not compensated; their
//! intermediate point written absolute) and `G53` moves as written. In inverse time (`G93`)
//! every chord gets the F that keeps its move's time.
//!
//! **Refused**, with the file, line, word and why: tool-centre-point modes (see
//! [`codes::TOOL_CENTRE_POINT`]), probing (`G38.x`, `G31`), threading and tapping (`G33`,
//! `G76`, `G84`, `G74`), cutter radius compensation (`G41`, `G42`), scaling and rotation,
//! subprograms (`M98`, `M99`, O words), parameters and expressions, `G4` without `P` (Fanuc's
//! `G04 X2.5`), `G92`/`G10 L20` after a compensated move (the offset would take up the
//! compensation), `G43` without a tool table, tools missing from it, unknown positions, and
//! any word no code of its block uses.
//!
//! [`Program::compensate_with`] writes the program back with every point compensated, in the
//! program's own coordinate system, offsets and units (only the positions change, so the
//! control applies the same offsets), and verifies every written command through the forward
//! model.
//!
//! **Directions.** Each point is compensated in the direction each axis arrives there with,
//! taken from the written commands the control executes, reference and machine-coordinate
//! moves included ([`crate::compensate::Travel`] states the rule): an axis with a reversal has
//! its reversal on the side it comes from. Arcs are cut at the points where an axis of their
//! plane turns, so that a reversal inside an arc happens at a point of the path. With a
//! reversal in the model, a point whose compensation depends on whether the control skips an
//! optional move before it (block delete) is refused.

pub mod codes;
mod interp;
mod lex;
mod modes;
mod movement;
pub mod offsets;
mod path;
mod write;

use crate::chain::MAX_AXES;
use crate::error::{Error, Result};
use crate::machine::Machine;
pub use codes::{TOOL_CENTRE_POINT, TOOL_CENTRE_POINT_NAMES};
pub use offsets::Offsets;
pub use write::{Tooling, WriteOptions};

/// How arcs and long moves are cut into points.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Linearise {
    /// Largest distance between an arc and its chords (mm).
    pub chord_tolerance_mm: f64,
    /// Longest linear segment (mm, over the linear axes); `None` keeps linear moves whole.
    pub max_segment_mm: Option<f64>,
}

impl Default for Linearise {
    fn default() -> Self {
        Linearise {
            chord_tolerance_mm: 0.001,
            max_segment_mm: None,
        }
    }
}

/// What a program is read with besides its text: how moves are cut, the control's offsets, the
/// machine's position at the start and the tool in the spindle.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Setup {
    /// How arcs and long moves are cut into points.
    pub lin: Linearise,
    /// The control's offsets and tool table.
    pub offsets: Offsets,
    /// The machine position at the start (mm, degrees; chain order), `None` where unknown.
    pub start: [Option<f64>; MAX_AXES],
    /// The tool in the spindle at the start.
    pub tool: Option<i64>,
    /// The dialect the program is written in: Fanuc-style programs dwell with `G04 X` (seconds)
    /// or `P` (ms), need a decimal point on every axis value (without one a Fanuc control
    /// reads the least input increment) and get no cycle expanded (their peck and retract
    /// amounts are control parameters).
    pub dialect: crate::dialect::Dialect,
}

/// A compensated move's points.
#[derive(Clone, Debug, PartialEq)]
pub struct Motion {
    /// `G0` (rapid) rather than a feed move.
    pub rapid: bool,
    /// Whether the block was an arc (linearised).
    pub arc: bool,
    /// The machine positions to pass through, the last being the move's end (mm, degrees;
    /// chain order).
    pub points: Vec<[f64; MAX_AXES]>,
    /// The offsets in force (mm, degrees; chain order): machine = program × unit + offset.
    pub offset: [f64; MAX_AXES],
    /// Whether the program is in inches (`G20`) there.
    pub inch: bool,
    /// In inverse time (`G93`), the move's F (1/minutes).
    pub inverse_time_f: Option<f64>,
    /// The tool in the spindle.
    pub tool: Option<i64>,
}

/// What a block does, in order: compensated moves, and words written between them (the dwells
/// and spindle words of an expanded cycle).
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum Step {
    /// A compensated move.
    Move(Motion),
    /// Words written on a line of their own (`G4 P0.5`, `M5`).
    Words(String),
}

/// One line of a program.
#[derive(Clone, Debug, PartialEq)]
pub struct Block {
    /// 1-based line number.
    pub line: usize,
    /// The line as written.
    pub source: String,
    /// Block delete: the block starts with `/` (a control skips it when its switch is on).
    pub optional: bool,
    /// Its block number as written (`N20`).
    pub number: Option<String>,
    /// The words written on its first line besides the moves (`F500`, `M3`, `G54`, `G4 P2`,
    /// `G28 Z0` …), as written.
    pub kept: Vec<String>,
    /// The words written on its last line: the stops (`M0`, `M1`, `M2`, `M30`, `M60`), which a
    /// control executes after the block's moves.
    pub after: Vec<String>,
    /// Its comments as written, with their delimiters (`(roughing)`, `; end`).
    pub comments: Vec<String>,
    /// Its compensated moves and the words between them.
    pub steps: Vec<Step>,
    /// Why a move of this block is kept uncompensated (`G28`, `G53`).
    pub note: Option<String>,
    /// The machine positions such an uncompensated move passes through, in order (mm,
    /// degrees; chain order; `None` for an axis it does not move): `G28`'s intermediate point
    /// and reference position, `G53`'s end. The directions of approach follow them.
    pub held_moves: Vec<[Option<f64>; MAX_AXES]>,
}

impl Block {
    /// The block's compensated moves.
    pub fn motions(&self) -> impl Iterator<Item = &Motion> {
        self.steps.iter().filter_map(|s| match s {
            Step::Move(m) => Some(m),
            Step::Words(_) => None,
        })
    }
}

/// A program read for one machine.
#[derive(Clone, Debug, PartialEq)]
pub struct Program {
    /// The file it came from (for messages).
    pub file: String,
    /// Its lines.
    pub blocks: Vec<Block>,
    /// The machine position at the start, where known (mm, degrees; chain order):
    /// [`Setup::start`].
    pub start: [Option<f64>; MAX_AXES],
}

/// What [`Program::compensate_with`] measured.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Report {
    /// Motion blocks read.
    pub moves: usize,
    /// Arcs among them.
    pub arcs: usize,
    /// Points written (each a compensated command).
    pub points: usize,
    /// Largest distance between the uncompensated tool point and its target (mm).
    pub max_error_mm: f64,
    /// Largest deviation of the compensated commands as solved (mm).
    pub max_deviation_mm: f64,
    /// Largest deviation of the commands as written, rounded to the output's decimals (mm).
    pub max_written_deviation_mm: f64,
    /// Lines (1-based) of points whose compensated command leaves an axis' travel.
    pub outside_travel: Vec<usize>,
    /// With the tool's orientation compensated: the largest angle of the uncompensated tool
    /// direction from its target (rad).
    pub max_direction_error_rad: f64,
    /// … of the compensated commands' directions away from the singularity, as solved (rad).
    pub max_direction_deviation_rad: f64,
    /// … of those commands as written (rad).
    pub max_written_direction_deviation_rad: f64,
    /// Lines (1-based) of points whose compensated command passes near the singularity
    /// ([`crate::compensate::OrientationResult::near_singularity`]: the direction is met there
    /// only as far as the tilt axis can).
    pub near_singularity: Vec<usize>,
    /// The largest angle left there (rad).
    pub max_singular_direction_deviation_rad: f64,
    /// Reference moves and machine-coordinate moves kept as written, not compensated
    /// (`G28`, `G30`, `G53`): their lines.
    pub uncompensated: Vec<usize>,
    /// The tools whose tool points compensated the moves (`None`: the one tool point).
    pub tools: Vec<Option<i64>>,
    /// How many times an axis with a reversal changed direction (from one side to the other):
    /// each change compensated at its turning point ([`crate::compensate::Travel`]).
    pub reversals: usize,
    /// Lines (1-based) of points where an axis with a reversal went back but could not be
    /// compensated as reversed (an overshooting axis, ISO 230-2's B > 0, less than |B| behind
    /// the point it turned at: it holds its command; [`crate::compensate::PathPoint::unsettled`]).
    /// Their deviations are not in the largest deviations above.
    pub unsettled_reversals: Vec<usize>,
    /// How many points those lines hold.
    pub unsettled_points: usize,
    /// The largest deviation of those points from their targets (mm): less than the axis' |B|.
    pub max_unsettled_deviation_mm: f64,
}

/// The modal state the writer states at the top of its output: absolute, mm, XY plane (the
/// reader starts in it too).
pub const START_STATE: &str = "G90 G21 G17";

impl Program {
    /// Reads a program for `machine` with no offsets, no known start position and the default
    /// linearisation `lin`; `file` names it in messages. See [`Program::read`].
    pub fn parse(text: &str, file: &str, machine: &Machine, lin: &Linearise) -> Result<Program> {
        Program::read(
            text,
            file,
            machine,
            &Setup {
                lin: *lin,
                ..Setup::default()
            },
        )
    }

    /// Reads a program for `machine` with `setup`; `file` names it in messages.
    ///
    /// ```
    /// use volver_core::gcode::{Program, Setup, Offsets};
    /// use volver_core::machine::Machine;
    /// let m = Machine::default_xcfz();
    /// let mut setup = Setup::default();
    /// setup.offsets = Offsets::from_toml_str("[work.G54]\nX = 100.0\n", "o.toml").unwrap();
    /// let p = Program::read("G54 G0 X10 C0 Z5\nG4 P2\nG0 X20\n", "p.nc", &m, &setup).unwrap();
    /// let pts = p.points();
    /// assert_eq!(pts.len(), 2);
    /// assert_eq!(pts[1].0[0], 120.0); // X20 in G54 is machine X 120
    /// ```
    pub fn read(text: &str, file: &str, machine: &Machine, setup: &Setup) -> Result<Program> {
        let lin = &setup.lin;
        if !(lin.chord_tolerance_mm > 0.0 && lin.chord_tolerance_mm.is_finite()) {
            return Err(Error::InvalidOption {
                name: "chord_tol_mm",
                message: "the chord tolerance must be a positive length (mm)".into(),
            });
        }
        let blocks = interp::Reader::new(machine, setup, file).read(text)?;
        Ok(Program {
            file: file.to_string(),
            blocks,
            start: setup.start,
        })
    }

    /// Every point the program's compensated moves pass through, in order (machine positions,
    /// mm and degrees, chain order), with whether it is a rapid move and whether its block is
    /// optional (block delete).
    pub fn points(&self) -> Vec<([f64; MAX_AXES], bool, bool)> {
        self.blocks
            .iter()
            .flat_map(|b| b.motions().map(move |m| (b, m)))
            .flat_map(|(b, m)| m.points.iter().map(move |p| (*p, m.rapid, b.optional)))
            .collect()
    }

    /// The tools in the spindle during compensated moves, in order of first use (`None`: no
    /// tool known).
    pub fn tools(&self) -> Vec<Option<i64>> {
        let mut out: Vec<Option<i64>> = Vec::new();
        for b in &self.blocks {
            for m in b.motions() {
                if !out.contains(&m.tool) {
                    out.push(m.tool);
                }
            }
        }
        out
    }
}

/// The most decimals the writer writes.
pub const MAX_DECIMALS: usize = 12;

/// The largest axis position read (mm or degrees): 1 km, beyond any machine's travel (the point
/// lists' bound, [`crate::compensate::MAX_AXIS_VALUE`]).
pub use crate::compensate::MAX_AXIS_VALUE;

/// The most points one move may be cut into.
pub const MAX_MOVE_POINTS: usize = 100_000;

/// The most points a program may be cut into (48 bytes each per axis set).
pub const MAX_PROGRAM_POINTS: usize = 5_000_000;
