//! The reader: each block's words by modal group, executed in RS274NGC's order (LinuxCNC's
//! G-code reference, "Order of Execution"), with the offsets and the tool in force, into the
//! machine positions the block moves through.

use super::codes::{self, KNOWN_G, KNOWN_M};
use super::lex::{Word, program_lines, split_comments, words};
use super::offsets::{LETTERS, Offsets};
use super::path::linear_points;
use super::{Block, MAX_AXIS_VALUE, MAX_PROGRAM_POINTS, Motion, Setup};
use crate::chain::MAX_AXES;
use crate::error::{Error, Place, Result};
use crate::iso::Axis;
use crate::machine::Machine;
use std::collections::BTreeMap;

/// What a block's axis words belong to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Owner {
    /// The motion mode: a compensated move.
    Motion,
    /// A non-modal code that takes them for itself (G10, G28, G30, G43.1, G52, G92).
    Taken,
    /// `G53`: a move in machine coordinates, not compensated.
    Machine,
}

/// The feed-rate mode in force.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum FeedMode {
    PerMinute,
    InverseTime,
    PerRevolution,
}

/// The sticky words of canned cycles (program units).
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct CycleWords {
    pub r: Option<f64>,
    pub z: Option<f64>,
    pub p: Option<f64>,
    pub q: Option<f64>,
}

/// One block's words, sorted.
#[derive(Default)]
pub(crate) struct Parsed {
    pub number: Option<String>,
    pub g: Vec<(i64, String)>,
    pub m: Vec<(i64, String)>,
    /// Axis words by letter (X Y Z A B C), program units.
    pub axes: [Option<f64>; 6],
    /// The axis words as written.
    pub axis_text: Vec<String>,
    pub ijk: [Option<f64>; 3],
    /// Every other letter's word (F S T H D P Q R L E O and inert words): value and text.
    pub other: BTreeMap<char, (f64, String)>,
}

impl Parsed {
    pub fn has(&self, letter: char, g: i64) -> bool {
        match letter {
            'G' => self.g.iter().any(|(c, _)| *c == g),
            _ => self.m.iter().any(|(c, _)| *c == g),
        }
    }

    pub fn value(&self, letter: char) -> Option<f64> {
        self.other.get(&letter).map(|(v, _)| *v)
    }

    pub fn any_axis(&self) -> bool {
        self.axes.iter().any(Option::is_some)
    }
}

/// The reader's state between blocks.
pub(crate) struct Reader<'a> {
    pub machine: &'a Machine,
    pub setup: &'a Setup,
    pub file: &'a str,
    /// The chain position of each letter of [`LETTERS`].
    pub chain: [Option<usize>; 6],
    /// The machine position (mm, degrees; chain order); `None` while unknown.
    pub pos: [Option<f64>; MAX_AXES],
    /// Whether the position was reached by a compensated move (the compensated program is then
    /// elsewhere by the compensation).
    pub compensated: bool,
    pub inch: bool,
    pub absolute: bool,
    pub arc_absolute: bool,
    pub plane: usize,
    /// The motion mode (tenths of its G code), `None` before any.
    pub motion: Option<i64>,
    pub feed: FeedMode,
    pub offsets: Offsets,
    pub system: usize,
    pub saved_g92: [f64; 6],
    pub tool_offset: [f64; 6],
    pub selected: Option<i64>,
    pub tool: Option<i64>,
    /// M3, M4 or M5 (in tenths).
    pub spindle: i64,
    pub cycle: CycleWords,
    /// `G99`: cycles retract to R (RS274NGC's default, as LinuxCNC starts).
    pub retract_r: bool,
    /// The Z (program units) where the current series of contiguous canned cycles started:
    /// `G98` retracts there.
    pub cycle_il: Option<f64>,
    /// An optional (block delete) move was read and no move since makes the path the same
    /// whether the control skipped it or not: its line.
    pub ambiguous: Option<usize>,
    /// The axes (chain positions) optional moves changed since then.
    pub delete_changed: [bool; MAX_AXES],
    pub total_points: usize,
}

/// An input error at `place` (shorthand).
pub(crate) fn refuse(place: &Place, field: &str, message: impl Into<String>) -> Error {
    Error::input(place.clone().at_field(field), message)
}

impl<'a> Reader<'a> {
    pub fn new(machine: &'a Machine, setup: &'a Setup, file: &'a str) -> Reader<'a> {
        let chain = std::array::from_fn(|i| {
            let axis = Axis::from_letter(LETTERS[i]).expect("axis letter");
            machine.axis(axis).map(|(k, _)| k)
        });
        Reader {
            machine,
            setup,
            file,
            chain,
            pos: setup.start,
            compensated: false,
            inch: false,
            absolute: true,
            arc_absolute: false,
            plane: 0,
            motion: None,
            feed: FeedMode::PerMinute,
            offsets: setup.offsets.clone(),
            system: setup.offsets.active,
            saved_g92: setup.offsets.g92,
            tool_offset: [0.0; 6],
            selected: None,
            tool: setup.tool,
            spindle: 50,
            cycle: CycleWords::default(),
            retract_r: true,
            cycle_il: None,
            ambiguous: None,
            delete_changed: [false; MAX_AXES],
            total_points: 0,
        }
    }

    /// mm per program unit.
    pub fn scale(&self) -> f64 {
        if self.inch { 25.4 } else { 1.0 }
    }

    /// The offset in force per letter: machine = program × scale + origin (mm, degrees).
    pub fn origin(&self) -> [f64; 6] {
        let o = self.offsets.origin(self.system);
        std::array::from_fn(|k| o[k] + self.tool_offset[k])
    }

    /// The machine position of program value `v` on letter `k`.
    pub fn to_machine(&self, k: usize, v: f64) -> f64 {
        let s = if k < 3 { self.scale() } else { 1.0 };
        v * s + self.origin()[k]
    }

    /// The program value of machine position `m` on letter `k`.
    pub fn to_program(&self, k: usize, m: f64) -> f64 {
        let s = if k < 3 { self.scale() } else { 1.0 };
        (m - self.origin()[k]) / s
    }

    /// The current program position on letter `k`, or an error naming it when unknown.
    pub fn program_at(&self, k: usize, place: &Place) -> Result<f64> {
        let c = self.chain[k].ok_or_else(|| {
            refuse(
                place,
                &LETTERS[k].to_string(),
                format!(
                    "the machine ({}) has no axis {}",
                    self.machine.chain(),
                    LETTERS[k]
                ),
            )
        })?;
        let m = self.pos[c].ok_or_else(|| self.unknown(c, place))?;
        Ok(self.to_program(k, m))
    }

    /// The error for an axis whose position is not known.
    pub fn unknown(&self, c: usize, place: &Place) -> Error {
        let letter = self.machine.axes()[c].axis.letter();
        refuse(
            place,
            &letter.to_string(),
            format!(
                "the position of axis {letter} is not known here (no earlier move states it): \
                 compensation moves every axis, so state {letter} in the first move, or give \
                 the machine's start position (--start)"
            ),
        )
    }

    /// The machine's offsets per chain position, for the writer.
    pub fn chain_offsets(&self) -> [f64; MAX_AXES] {
        let o = self.origin();
        let mut out = [0.0; MAX_AXES];
        for (k, c) in self.chain.iter().enumerate() {
            if let Some(c) = c {
                out[*c] = o[k];
            }
        }
        out
    }

    /// A motion through `points` (machine positions) from the state.
    pub fn motion(&self, rapid: bool, arc: bool, points: Vec<[f64; MAX_AXES]>) -> Motion {
        Motion {
            rapid,
            arc,
            points,
            offset: self.chain_offsets(),
            inch: self.inch,
            inverse_time_f: None,
            tool: self.tool,
        }
    }

    /// Counts `n` points against the program's bound.
    pub fn count(&mut self, n: usize, place: &Place) -> Result<()> {
        self.total_points += n;
        if self.total_points > MAX_PROGRAM_POINTS {
            return Err(Error::input(
                place.clone(),
                format!(
                    "the program needs more than {MAX_PROGRAM_POINTS} points at this chord \
                     tolerance and segment length: raise them, or split the program"
                ),
            ));
        }
        Ok(())
    }

    /// A straight move (rapid or feed) to `target` (machine, chain order), every axis known.
    pub fn straight(
        &mut self,
        rapid: bool,
        target: [Option<f64>; MAX_AXES],
        place: &Place,
    ) -> Result<Motion> {
        let to = self.known(&target, place)?;
        // From an unknown start (the program's first move) the move goes straight to its end.
        let pts = match self.known(&self.pos, place) {
            Ok(from) => linear_points(self.machine, &from, &to, &self.setup.lin, place)?,
            Err(_) => vec![to],
        };
        self.count(pts.len(), place)?;
        self.pos = target;
        self.compensated = true;
        Ok(self.motion(rapid, false, pts))
    }

    /// Every axis of `p` known, or the error naming the first that is not.
    pub fn known(&self, p: &[Option<f64>; MAX_AXES], place: &Place) -> Result<[f64; MAX_AXES]> {
        let mut out = [0.0; MAX_AXES];
        for c in 0..self.machine.axes().len() {
            out[c] = p[c].ok_or_else(|| self.unknown(c, place))?;
        }
        Ok(out)
    }

    /// Reads the whole program.
    pub fn read(mut self, text: &str) -> Result<Vec<Block>> {
        let mut blocks = Vec::new();
        for (i, raw) in program_lines(text).into_iter().enumerate() {
            let place = Place::file(self.file).at_line(i + 1);
            blocks.push(self.block(i + 1, raw, &place)?);
        }
        Ok(blocks)
    }

    /// One line.
    fn block(&mut self, line: usize, raw: &str, place: &Place) -> Result<Block> {
        let trimmed = raw.trim();
        let mut block = Block {
            line,
            source: raw.to_string(),
            optional: false,
            number: None,
            kept: Vec::new(),
            after: Vec::new(),
            comments: Vec::new(),
            steps: Vec::new(),
            note: None,
            held_moves: Vec::new(),
        };
        if trimmed.starts_with('%') {
            return Ok(block);
        }
        block.optional = trimmed.starts_with('/');
        let (code, comments) = split_comments(trimmed.trim_start_matches('/'), place)?;
        block.comments = comments;
        codes::refuse_tool_centre_point_names(&code, place)?;
        let ws = words(&code, place)?;
        let parsed = self.sort(&ws, place)?;
        block.number = parsed.number.clone();
        self.execute(&parsed, &mut block, place)?;
        Ok(block)
    }

    /// The words of a block sorted by kind; unknown codes, two words of one modal group, two
    /// words of one letter are refused.
    fn sort(&self, ws: &[Word], place: &Place) -> Result<Parsed> {
        let mut p = Parsed::default();
        let mut groups: Vec<(char, u8, String)> = Vec::new();
        for w in ws {
            match w.letter {
                'N' => {
                    if p.number.replace(w.text.clone()).is_some() {
                        return Err(refuse(place, &w.text, "two block numbers (N) in one block"));
                    }
                    // RS274NGC reads a block number only first in its block.
                    if !std::ptr::eq(w, &ws[0]) {
                        return Err(refuse(
                            place,
                            &w.text,
                            format!("{}: a block number N stands first in its block", w.text),
                        ));
                    }
                }
                'G' | 'M' => self.g_or_m_word(&mut p, &mut groups, w, place)?,
                'X' | 'Y' | 'Z' | 'A' | 'B' | 'C' => self.axis_word(&mut p, w, place)?,
                'U' | 'V' | 'W' => {
                    return Err(refuse(
                        place,
                        &w.letter.to_string(),
                        format!("axis word {}: secondary axes U, V, W are not read", w.text),
                    ));
                }
                'I' | 'J' | 'K' => {
                    let k = (w.letter as u8 - b'I') as usize;
                    if p.ijk[k].replace(w.value).is_some() {
                        return Err(refuse(
                            place,
                            &w.text,
                            format!("two {} words in one block", w.letter),
                        ));
                    }
                }
                _ => {
                    if p.other
                        .insert(w.letter, (w.value, w.text.clone()))
                        .is_some()
                    {
                        return Err(refuse(
                            place,
                            &w.text,
                            format!("two {} words in one block", w.letter),
                        ));
                    }
                }
            }
        }
        Ok(p)
    }

    /// A G or M word: its code into the block's list, refused when a word of its modal group
    /// is already there (`groups`: letter, group and word of those seen).
    fn g_or_m_word(
        &self,
        p: &mut Parsed,
        groups: &mut Vec<(char, u8, String)>,
        w: &Word,
        place: &Place,
    ) -> Result<()> {
        let code = self.code(w, place)?;
        let group = if w.letter == 'G' {
            codes::g_group(code)
        } else {
            codes::m_group(code)
        }
        .ok_or_else(|| {
            refuse(
                place,
                &w.text,
                format!("{} is not a code any control knows", w.text),
            )
        })?;
        // Non-modal G codes (group 0) may share a block, as may M7 and M8.
        let shared = (w.letter == 'G' && group == 0) || (w.letter == 'M' && group == 8);
        if !shared
            && let Some((_, _, first)) = groups
                .iter()
                .find(|(l, g, _)| *l == w.letter && *g == group)
        {
            return Err(refuse(
                place,
                &w.text,
                format!(
                    "{first} and {} are both in the {} modal group: a block may hold \
                     one of them",
                    w.text,
                    codes::group_name(w.letter, group)
                ),
            ));
        }
        groups.push((w.letter, group, w.text.clone()));
        let list = if w.letter == 'G' { &mut p.g } else { &mut p.m };
        list.push((code, w.text.clone()));
        Ok(())
    }

    /// A G or M code's value, refused (naming the word and what is known) when volver does not
    /// read it.
    fn code(&self, w: &Word, place: &Place) -> Result<i64> {
        let Some(code) = codes::tenths(w) else {
            return Err(refuse(
                place,
                &w.text,
                format!("{} is not a code any control knows", w.text),
            ));
        };
        codes::refuse_tool_centre_point(w, code, place)?;
        let name = codes::name(w.letter, code);
        let (known, refusal) = if w.letter == 'G' {
            (codes::g_group(code).is_some(), codes::g_refusal(code))
        } else {
            let whole = code % 10 == 0;
            (
                whole && codes::m_group(code).is_some(),
                codes::m_refusal(code),
            )
        };
        if known {
            return Ok(code);
        }
        if let Some(why) = refusal {
            return Err(refuse(
                place,
                &w.text,
                format!("{} ({name}): {why}", w.text),
            ));
        }
        let list = if w.letter == 'G' { KNOWN_G } else { KNOWN_M };
        Err(refuse(
            place,
            &w.text,
            format!(
                "{} ({name}) is not a code volver reads, so it cannot tell whether it moves the \
                 machine; it reads {list}",
                w.text
            ),
        ))
    }

    /// An axis word, refused for an axis the machine lacks, a second word for one axis, or a
    /// value beyond any machine.
    fn axis_word(&self, p: &mut Parsed, w: &Word, place: &Place) -> Result<()> {
        if self.setup.dialect == crate::dialect::Dialect::Fanuc && !w.text.contains('.') {
            return Err(refuse(
                place,
                &w.text,
                format!(
                    "{}: a Fanuc-style control reads a value without a decimal point in its least \
                     input increment ({}0.001 mm on most), unless its DPI parameter is set: write \
                     {}.",
                    w.text, w.letter, w.text
                ),
            ));
        }
        let k = LETTERS
            .iter()
            .position(|&l| l == w.letter)
            .expect("axis letter");
        if self.chain[k].is_none() {
            return Err(refuse(
                place,
                &w.letter.to_string(),
                format!(
                    "axis word {} for an axis the machine ({}) does not have",
                    w.text,
                    self.machine.chain()
                ),
            ));
        }
        if p.axes[k].replace(w.value).is_some() {
            return Err(refuse(
                place,
                &w.text,
                format!("two words for axis {} in one block", w.letter),
            ));
        }
        if w.value.abs() > MAX_AXIS_VALUE {
            return Err(refuse(
                place,
                &w.letter.to_string(),
                format!(
                    "{} is beyond any machine's travel (|value| ≤ {MAX_AXIS_VALUE:e} mm or degrees)",
                    w.text
                ),
            ));
        }
        p.axis_text.push(w.text.clone());
        Ok(())
    }

    /// Executes a block in RS274NGC's order: modes, tools and spindle, dwell, units and
    /// offsets, the non-modal codes, the motion, and the stops last.
    fn execute(&mut self, p: &Parsed, block: &mut Block, place: &Place) -> Result<()> {
        let start = self.pos;
        self.modes(p, block, place)?;
        self.tools(p, block, place)?;
        let owner = self.non_modal(p, block, place)?;
        if owner == Owner::Motion {
            self.movement(p, block, place)?;
            self.block_delete(p, block, &start, place)?;
        } else if owner == Owner::Taken
            && let Some((_, w)) = p.g.iter().find(|(g, _)| codes::g_group(*g) == Some(1))
        {
            return Err(refuse(
                place,
                w,
                format!(
                    "{w} and a code that takes axis words for itself (G10, G28, G30, G43.1, G52, \
                     G92) share the block: RS274NGC refuses it (\"two g codes that both use axis \
                     values\")"
                ),
            ));
        }
        for (m, w) in &p.m {
            if codes::m_group(*m) == Some(4) {
                block.after.push(w.clone());
            }
        }
        Ok(())
    }

    /// Block delete: a control skips an optional block (`/`) when its switch is on, so the
    /// moves after an optional move must mean the same from either start. Refused until a
    /// straight move in absolute mode states every axis the optional move changed (its end is
    /// then the same either way); arcs, split moves, cycles and incremental moves in between are
    /// refused with the optional block's line.
    fn block_delete(
        &mut self,
        p: &Parsed,
        block: &Block,
        start: &[Option<f64>; MAX_AXES],
        place: &Place,
    ) -> Result<()> {
        if block.steps.is_empty() {
            return Ok(());
        }
        if let Some(line) = self.ambiguous {
            let single = matches!(
                &block.steps[..],
                [super::Step::Move(m)] if !m.arc && m.points.len() == 1
            );
            let stated = (0..6).all(|k| {
                let changed = self.chain[k].is_some_and(|c| self.delete_changed[c]);
                !changed || p.axes[k].is_some()
            });
            if !(single && self.absolute && stated) {
                return Err(Error::input(
                    place.clone(),
                    format!(
                        "this move starts where optional line {line} (block delete '/') leaves \
                         the machine, and it would not mean the same if the control skipped that \
                         line: follow an optional move with a straight absolute move that states \
                         every axis it changed, or remove the '/'"
                    ),
                ));
            }
            self.ambiguous = None;
            self.delete_changed = [false; MAX_AXES];
        }
        if block.optional {
            self.ambiguous = Some(block.line);
            for (c, changed) in self.delete_changed.iter_mut().enumerate() {
                *changed |= start[c] != self.pos[c];
            }
        }
        Ok(())
    }
}
