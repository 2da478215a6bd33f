//! The compensated program: every point of a compensated move replaced by its compensated
//! command, written in the program's coordinates, offsets and units, and verified through the
//! forward model as written.

use super::{Block, MAX_DECIMALS, Motion, Program, Report, START_STATE, Step};
use crate::compensate::{Compensated, Compensator};
use crate::error::{Error, Place, Result};
use crate::iso::Axis;
use crate::machine::{Commands, Machine};
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
}

impl Default for WriteOptions {
    fn default() -> Self {
        WriteOptions {
            decimals: 4,
            allow_outside_travel: false,
            dialect: crate::dialect::Dialect::LinuxCnc,
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
        let mut w = Writer {
            program: self,
            machine,
            tooling,
            options: *options,
            order: conventional_order(machine),
            out: String::new(),
            report: Report::default(),
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

    /// The compensated points of one move, as lines.
    fn motion(&mut self, b: &Block, m: &Motion, lines: &mut Vec<String>) -> Result<()> {
        self.report.moves += 1;
        self.report.arcs += usize::from(m.arc);
        let comp = self.tooling.of(m.tool);
        let place = Place::file(&self.program.file).at_line(b.line);
        let n = m.points.len();
        for p in &m.points {
            let mut programmed = Commands::default();
            for (k, a) in self.machine.axes().iter().enumerate() {
                programmed.0[k] = a.from_file_units(p[k]);
            }
            let c = comp
                .compensate(&programmed)
                .map_err(|e| Error::input(place.clone(), e.to_string()))?;
            let (texts, written) = self.written(m, &c.commands);
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
            if let Some(beyond) = self.travel(&c, &place)? {
                text.push_str(&format!(" (volver: {beyond})"));
            }
            self.verify(comp, &c, &written, b.line);
            lines.push(text);
        }
        Ok(())
    }

    /// The compensated command as written in the move's program coordinates and units, and the
    /// machine command those texts stand for (internal units).
    fn written(&self, m: &Motion, commands: &Commands) -> (Vec<String>, Commands) {
        let mut out = *commands;
        let texts = self
            .machine
            .axes()
            .iter()
            .enumerate()
            .map(|(k, a)| {
                let unit = if m.inch && !a.axis.is_rotary() {
                    25.4
                } else {
                    1.0
                };
                let decimals = self.options.decimals + usize::from(unit != 1.0);
                let prog = (a.to_file_units(commands.0[k]) - m.offset[k]) / unit;
                let t = (self.options.dialect).decimal_point(format!("{:.decimals$}", prog + 0.0));
                let back: f64 = t.parse().expect("a formatted number parses");
                out.0[k] = a.from_file_units(back * unit + m.offset[k]);
                t
            })
            .collect();
        (texts, out)
    }

    /// Refuses a compensated command beyond an axis' travel, or (when allowed) says by how
    /// much, for a comment on its line.
    fn travel(&mut self, c: &Compensated, place: &Place) -> Result<Option<String>> {
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
