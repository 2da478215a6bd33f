//! The compensated program: every point of a compensated move replaced by its compensated
//! command, written in the program's coordinates, offsets and units, and verified through the
//! forward model as written.

use super::{Block, MAX_DECIMALS, Motion, Program, Report, START_STATE, Step};
use crate::chain::MAX_AXES;
use crate::compensate::{
    Compensated, Compensator, PathPoint, REVERSAL_TOLERANCE_UM, Travel, reversal_axes,
};
use crate::error::{Error, Place, Result};
use crate::iso::Axis;
use crate::machine::{Commands, Machine};
use crate::model::PointState;
use std::collections::BTreeMap;

/// The compensators of a program's tools: each tool's own tool point (its length along the
/// spindle), and one for moves with no tool of the table (or a program read without one).
#[derive(Clone, Debug)]
pub struct Tooling<'a> {
    /// For moves whose tool has no compensator of its own.
    pub default: Compensator<'a>,
    /// By tool number.
    pub tools: BTreeMap<i64, Compensator<'a>>,
}

impl<'a> Tooling<'a> {
    /// One tool point for every move.
    pub fn single(comp: Compensator<'a>) -> Tooling<'a> {
        Tooling {
            default: comp,
            tools: BTreeMap::new(),
        }
    }

    /// The compensator of `tool`.
    pub fn of(&self, tool: Option<i64>) -> &Compensator<'a> {
        tool.and_then(|t| self.tools.get(&t))
            .unwrap_or(&self.default)
    }
}

/// How the compensated program is written.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WriteOptions {
    /// Decimals of the positions in mm and degrees (one more in inch programs), 0–12.
    pub decimals: usize,
    /// Write compensated points beyond an axis' travel (each marked by a comment on its line)
    /// instead of refusing them.
    pub allow_outside_travel: bool,
    /// The dialect written: Fanuc-style gets a decimal point on every axis value.
    pub dialect: crate::dialect::Dialect,
    /// The reversal tolerance (µm on a linear axis, µrad on a rotary one, ≥ 0): a written
    /// command going back by less does not reverse its axis ([`Travel`] states the rule).
    pub reversal_tolerance_um: f64,
}

impl Default for WriteOptions {
    fn default() -> Self {
        WriteOptions {
            decimals: 4,
            allow_outside_travel: false,
            dialect: crate::dialect::Dialect::LinuxCnc,
            reversal_tolerance_um: REVERSAL_TOLERANCE_UM,
        }
    }
}

/// The axes in the conventional order X Y Z A B C (chain positions).
fn conventional_order(machine: &Machine) -> Vec<usize> {
    let axes = machine.axes();
    let mut order: Vec<usize> = (0..axes.len()).collect();
    order.sort_by_key(|&k| Axis::ALL.iter().position(|&a| a == axes[k].axis));
    order
}

/// The writer's running state.
struct Writer<'p, 'c> {
    program: &'p Program,
    machine: &'p Machine,
    tooling: &'c Tooling<'c>,
    options: WriteOptions,
    order: Vec<usize>,
    out: String,
    report: Report,
    /// Each axis' direction along the path the control executes.
    travel: Travel,
    /// With a reversal in the model, the paths on which the control skipped an optional move
    /// (block delete) and the line of that move: the next move must be written the same on
    /// each ([`Writer::merge`]).
    alternatives: Vec<(Travel, usize)>,
}

impl Program {
    /// [`Program::compensate_with`] with one tool point and `decimals`, refusing points beyond
    /// the travel.
    pub fn compensate(
        &self,
        comp: &Compensator,
        machine: &Machine,
        decimals: usize,
        header: &str,
    ) -> Result<(String, Report)> {
        let options = WriteOptions {
            decimals,
            ..WriteOptions::default()
        };
        self.compensate_with(&Tooling::single(comp.clone()), machine, &options, header)
    }

    /// The program with every point of its compensated moves replaced by the compensated
    /// command of its tool's compensator, written for a control: any leading `%` and program
    /// number (`O…`) first, then the header as comments and one explicit modal state
    /// ([`START_STATE`]); moves as absolute `G0`/`G1` with every axis in the order X Y Z A B C,
    /// in the program's coordinates (the same offsets) and units, each verified through the
    /// forward model as written; the other words of each block in place (the stops after its
    /// moves), without the distance-mode and motion words that volver's absolute moves replace;
    /// the reference and machine-coordinate moves as written with a comment. A compensated
    /// point beyond an axis' travel is refused unless [`WriteOptions::allow_outside_travel`].
    pub fn compensate_with(
        &self,
        tooling: &Tooling,
        machine: &Machine,
        options: &WriteOptions,
        header: &str,
    ) -> Result<(String, Report)> {
        if options.decimals > MAX_DECIMALS {
            return Err(Error::InvalidOption {
                name: "decimals",
                message: format!(
                    "{} decimals: at most {MAX_DECIMALS} (1e-{MAX_DECIMALS} mm is far below any \
                     machine's resolution)",
                    options.decimals
                ),
            });
        }
        let tol = options.reversal_tolerance_um;
        if !(tol.is_finite() && tol >= 0.0) {
            return Err(Error::InvalidOption {
                name: "reversal_tolerance_um",
                message: format!(
                    "{tol}: the reversal tolerance must be a length of zero or more (µm; µrad on \
                     a rotary axis)"
                ),
            });
        }
        let mut travel = Travel::new(tooling.default.model(), tol);
        travel.moved_to(&internal(machine, &self.start));
        let mut w = Writer {
            program: self,
            machine,
            tooling,
            options: *options,
            order: conventional_order(machine),
            out: String::new(),
            report: Report::default(),
            travel,
            alternatives: Vec::new(),
        };
        let lead = self.lead();
        for b in &self.blocks[..lead] {
            w.line(&b.rewritten(""));
        }
        for l in header.lines() {
            w.line(&format!("({})", l.replace(['(', ')'], "")));
        }
        w.line(START_STATE);
        for b in &self.blocks[lead..] {
            w.block(b)?;
        }
        w.report.tools = self.tools();
        Ok((w.out, w.report))
    }

    /// The number of leading tape marks (`%`) and program-number lines (`O…`).
    fn lead(&self) -> usize {
        self.blocks
            .iter()
            .take_while(|b| {
                b.source.trim_start().starts_with('%')
                    || (b.steps.is_empty()
                        && b.number.is_none()
                        && !b.optional
                        && b.kept.len() == 1
                        && b.kept[0].starts_with('O'))
            })
            .count()
    }
}

impl Writer<'_, '_> {
    fn line(&mut self, text: &str) {
        self.out.push_str(text);
        self.out.push('\n');
    }

    /// One block: its moves' points, the words between them, its kept words on the first line
    /// and its stops on the last.
    fn block(&mut self, b: &Block) -> Result<()> {
        let moves = !b.held_moves.is_empty() || b.motions().next().is_some();
        // The paths that skip an optional move: from here as it stands.
        let skipped = (moves && b.optional && self.travel.directed()).then(|| {
            let mut v = vec![(self.travel.clone(), b.line)];
            v.extend(self.alternatives.iter().cloned());
            v
        });
        self.block_lines(b)?;
        if moves {
            let mut alternatives = skipped.unwrap_or_default();
            alternatives.dedup_by(|a, b| a.0 == b.0);
            self.alternatives = alternatives;
        }
        Ok(())
    }

    /// [`Writer::block`]'s lines.
    fn block_lines(&mut self, b: &Block) -> Result<()> {
        for h in &b.held_moves {
            let to = internal(self.machine, h);
            self.travel.moved_to(&to);
            for (t, _) in &mut self.alternatives {
                t.moved_to(&to);
            }
        }
        if b.steps.is_empty() {
            let mut line = b.rewritten("");
            let mut tail = b.after.clone();
            if let Some(n) = &b.note {
                tail.push(format!("(volver: {})", n.replace(['(', ')'], "")));
                self.report.uncompensated.push(b.line);
            }
            if !tail.is_empty() {
                line = [line, tail.join(" ")].join(" ").trim().to_string();
            }
            if !line.is_empty() || b.source.trim().is_empty() {
                self.line(&line);
            }
            return Ok(());
        }
        let mut lines: Vec<String> = Vec::new();
        for step in &b.steps {
            match step {
                Step::Words(words) => lines.push(words.clone()),
                Step::Move(m) => self.motion(b, m, &mut lines)?,
            }
        }
        let prefix = if b.optional { "/" } else { "" };
        let last = lines.len() - 1;
        for (i, text) in lines.iter().enumerate() {
            let mut line = if i == 0 {
                b.rewritten(text)
            } else {
                format!("{prefix}{text}")
            };
            if i == last {
                for a in &b.after {
                    line.push(' ');
                    line.push_str(a);
                }
                line.push_str(&format!(" (line {})", b.line));
            }
            self.line(&line);
        }
        Ok(())
    }

    /// The compensated points of one move, as lines: each point compensated in the directions
    /// its axes arrive with ([`Travel`]).
    fn motion(&mut self, b: &Block, m: &Motion, lines: &mut Vec<String>) -> Result<()> {
        self.report.moves += 1;
        self.report.arcs += usize::from(m.arc);
        let comp = self.tooling.of(m.tool);
        let place = Place::file(&self.program.file).at_line(b.line);
        let n = m.points.len();
        let (machine, options) = (self.machine, self.options);
        let write = |q: &Commands| written(machine, &options, m, q).1;
        for p in &m.points {
            let mut programmed = Commands::default();
            for (k, a) in self.machine.axes().iter().enumerate() {
                programmed.0[k] = a.from_file_units(p[k]);
            }
            let pt = self
                .travel
                .next(comp, &programmed, &write)
                .map_err(|e| Error::input(place.clone(), e.to_string()))?;
            self.merge(comp, &programmed, &write, &pt, &place)?;
            let c = &pt.compensated;
            let (texts, written) = written(machine, &options, m, &c.commands);
            let mut text = String::from(if m.rapid { "G0" } else { "G1" });
            for &k in &self.order {
                text.push_str(&format!(
                    " {}{}",
                    self.machine.axes()[k].axis.letter(),
                    texts[k]
                ));
            }
            if let Some(f) = m.inverse_time_f {
                // Equal chords: each takes 1/n of the move's time.
                text.push_str(&format!(" F{}", super::modes::number(f * n as f64)));
            }
            if let Some(beyond) = self.travel_limits(c, &place)? {
                text.push_str(&format!(" (volver: {beyond})"));
            }
            let state = PointState {
                t_s: 0.0,
                approach: pt.approach,
            };
            self.report.reversals += pt.reversed.len();
            if pt.unsettled.is_empty() {
                self.verify(&comp.in_state(state), c, &written, b.line);
            } else {
                // Held short of its target by the rule (Travel): reported on its own.
                let rep = &mut self.report;
                rep.points += 1;
                rep.unsettled_points += 1;
                rep.max_error_mm = rep.max_error_mm.max(c.error_mm);
                rep.max_unsettled_deviation_mm = rep.max_unsettled_deviation_mm.max(c.deviation_mm);
                if rep.unsettled_reversals.last() != Some(&b.line) {
                    rep.unsettled_reversals.push(b.line);
                }
            }
            lines.push(text);
        }
        Ok(())
    }

    /// Refuses a point whose compensated command depends on whether the control skipped an
    /// optional move before it: on each path that skipped one, the point is compensated in that
    /// path's directions and must be written as `pt` is.
    fn merge(
        &mut self,
        comp: &Compensator,
        programmed: &Commands,
        write: &dyn Fn(&Commands) -> Commands,
        pt: &PathPoint,
        place: &Place,
    ) -> Result<()> {
        let letters: Vec<char> = self
            .machine
            .axes()
            .iter()
            .map(|a| a.axis.letter())
            .collect();
        let reversal = reversal_axes(comp.model());
        for (t, line) in &mut self.alternatives {
            let other = t
                .next(comp, programmed, write)
                .map_err(|e| Error::input(place.clone(), e.to_string()))?;
            if other.written == pt.written {
                continue;
            }
            let side = |s: i8| match s {
                1 => "forward",
                -1 => "in reverse",
                _ => "from an unknown side",
            };
            let sides: Vec<String> = reversal
                .iter()
                .filter(|&&k| other.approach.0[k] != pt.approach.0[k])
                .map(|&k| {
                    format!(
                        "{} arrives {} if the control runs line {line}, {} if it skips it",
                        letters[k],
                        side(pt.approach.0[k]),
                        side(other.approach.0[k])
                    )
                })
                .collect();
            return Err(Error::input(
                place.clone(),
                format!(
                    "the compensated command here depends on whether the control skips optional \
                     line {line} (block delete '/'): {}, and its reversal puts the tool elsewhere; \
                     approach this point from the same side either way (a move before it that \
                     does not depend on line {line}), or remove the '/'",
                    if sides.is_empty() {
                        "the axes arrive from different sides".to_string()
                    } else {
                        sides.join("; ")
                    }
                ),
            ));
        }
        Ok(())
    }

    /// Refuses a compensated command beyond an axis' travel, or (when allowed) says by how
    /// much, for a comment on its line.
    fn travel_limits(&mut self, c: &Compensated, place: &Place) -> Result<Option<String>> {
        if c.outside_travel.is_empty() {
            return Ok(None);
        }
        let axes = self.machine.axes();
        let text: Vec<String> = c
            .outside_travel
            .iter()
            .map(|&k| {
                let a = &axes[k];
                let v = a.to_file_units(c.commands.0[k]);
                let (lo, hi) = (a.to_file_units(a.min), a.to_file_units(a.max));
                let by = if v < lo { lo - v } else { v - hi };
                format!(
                    "{} at {v:.4} {} is beyond its travel {lo}…{hi} by {by:.4}",
                    a.axis,
                    a.file_unit()
                )
            })
            .collect();
        let line = place.line.unwrap_or(0);
        if !self.options.allow_outside_travel {
            return Err(Error::input(
                place.clone(),
                format!(
                    "the compensated command puts {}: a control stops there (soft limit); \
                     allow it (--allow-outside-travel) to write it marked on its line",
                    text.join("; ")
                ),
            ));
        }
        if self.report.outside_travel.last() != Some(&line) {
            self.report.outside_travel.push(line);
        }
        Ok(Some(text.join("; ")))
    }

    /// The verification of one compensated command, as solved and as written.
    fn verify(&mut self, comp: &Compensator, c: &Compensated, written: &Commands, line: usize) {
        let rep = &mut self.report;
        rep.points += 1;
        rep.max_error_mm = rep.max_error_mm.max(c.error_mm);
        rep.max_deviation_mm = rep.max_deviation_mm.max(c.deviation_mm);
        rep.max_written_deviation_mm = rep
            .max_written_deviation_mm
            .max(comp.deviation_mm(written, c.target));
        if let Some(o) = &c.orientation {
            rep.max_direction_error_rad = rep.max_direction_error_rad.max(o.error_rad);
            if o.near_singularity {
                rep.max_singular_direction_deviation_rad = rep
                    .max_singular_direction_deviation_rad
                    .max(o.deviation_rad);
                if rep.near_singularity.last() != Some(&line) {
                    rep.near_singularity.push(line);
                }
            } else {
                let wd = comp.direction_deviation_rad(written, o.target);
                rep.max_direction_deviation_rad =
                    rep.max_direction_deviation_rad.max(o.deviation_rad);
                rep.max_written_direction_deviation_rad =
                    rep.max_written_direction_deviation_rad.max(wd);
            }
        }
    }
}

/// The compensated command `commands` as written in move `m`'s program coordinates and units
/// with `options`' decimals and dialect, and the machine command those texts stand for
/// (internal units).
fn written(
    machine: &Machine,
    options: &WriteOptions,
    m: &Motion,
    commands: &Commands,
) -> (Vec<String>, Commands) {
    let mut out = *commands;
    let texts = machine
        .axes()
        .iter()
        .enumerate()
        .map(|(k, a)| {
            let unit = if m.inch && !a.axis.is_rotary() {
                25.4
            } else {
                1.0
            };
            let decimals = options.decimals + usize::from(unit != 1.0);
            let prog = (a.to_file_units(commands.0[k]) - m.offset[k]) / unit;
            let t = (options.dialect).decimal_point(format!("{:.decimals$}", prog + 0.0));
            let back: f64 = t.parse().expect("a formatted number parses");
            out.0[k] = a.from_file_units(back * unit + m.offset[k]);
            t
        })
        .collect();
    (texts, out)
}

/// Machine positions in file units (mm, degrees; `None` where unknown) in internal units.
fn internal(machine: &Machine, p: &[Option<f64>; MAX_AXES]) -> [Option<f64>; MAX_AXES] {
    let mut out = [None; MAX_AXES];
    for (k, a) in machine.axes().iter().enumerate() {
        out[k] = p[k].map(|v| a.from_file_units(v));
    }
    out
}

impl Block {
    /// The block as volver writes it: block delete, block number, `moves` (when not empty), the
    /// kept words and the comments. A tape-mark line (`%`) is copied.
    pub(crate) fn rewritten(&self, moves: &str) -> String {
        if self.source.trim_start().starts_with('%') {
            return self.source.trim().to_string();
        }
        let mut parts: Vec<&str> = Vec::new();
        if let Some(n) = &self.number {
            parts.push(n);
        }
        if !moves.is_empty() {
            parts.push(moves);
        }
        parts.extend(self.kept.iter().map(String::as_str));
        parts.extend(self.comments.iter().map(String::as_str));
        let body = parts.join(" ");
        if self.optional && !body.is_empty() {
            format!("/{body}")
        } else {
            body
        }
    }
}
