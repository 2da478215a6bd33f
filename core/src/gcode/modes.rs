//! The modal and non-modal codes of a block that do not move the tool along a compensated
//! path: feed mode, plane, units, offsets, tools, dwells, reference moves.

use super::Block;
use super::codes;
use super::interp::{FeedMode, Owner, Parsed, Reader, refuse};
use super::offsets::LETTERS;
use crate::chain::MAX_AXES;
use crate::error::{Place, Result};

impl Reader<'_> {
    /// Feed mode, plane, units, cutter compensation off, coordinate system, path control,
    /// distance modes, retract mode, and the dwell.
    pub(crate) fn modes(&mut self, p: &Parsed, block: &mut Block, place: &Place) -> Result<()> {
        self.modal_codes(p, block);
        if p.has('G', 40) && self.dwell(p, block, place)? {
            return Ok(());
        }
        if let Some((v, w)) = p.other.get(&'S')
            && *v < 0.0
        {
            return Err(refuse(place, w, format!("{w}: a spindle speed is ≥ 0")));
        }
        for letter in ['O', 'F', 'S'] {
            if let Some((_, w)) = p.other.get(&letter) {
                // An inverse-time F belongs to its compensated move's points (see movement);
                // a block whose axis words a non-modal code takes (G53, G28 …) keeps it.
                let inverse = letter == 'F' && self.feed == FeedMode::InverseTime;
                let taken =
                    p.g.iter()
                        .any(|(g, _)| matches!(g, 100 | 280 | 300 | 431 | 520 | 530 | 920));
                if !inverse || !p.any_axis() || taken {
                    block.kept.push(w.clone());
                }
            }
        }
        Ok(())
    }

    /// The block's G codes: the modes they set (feed mode, plane, units, coordinate system,
    /// retract mode, distance modes), and the codes the output keeps as written.
    fn modal_codes(&mut self, p: &Parsed, block: &mut Block) {
        for (g, w) in &p.g {
            match g {
                930 => self.feed = FeedMode::InverseTime,
                940 => self.feed = FeedMode::PerMinute,
                950 => self.feed = FeedMode::PerRevolution,
                170 | 180 | 190 => self.plane = ((g - 170) / 10) as usize,
                200 => self.inch = true,
                210 => self.inch = false,
                540..=593 => {
                    let systems = [540, 550, 560, 570, 580, 590, 591, 592, 593];
                    if let Some(system) = systems.iter().position(|c| c == g) {
                        self.system = system;
                    }
                }
                980 => self.retract_r = false,
                990 => self.retract_r = true,
                900 | 910 => self.absolute = *g == 900,
                901 | 911 => self.arc_absolute = *g == 901,
                _ => {}
            }
            // Distance modes are not copied (the output's moves are absolute), nor motion codes
            // (the output states its own); the codes with words of their own are written with
            // them where they are read.
            let written_elsewhere = matches!(
                g,
                900 | 910 | 901 | 911 | 40 | 100 | 280 | 300 | 430 | 431 | 520 | 530 | 920 | 640
            );
            if *g == 640 {
                let mut w = w.clone();
                for l in ['P', 'Q'] {
                    if let Some((_, t)) = p.other.get(&l) {
                        w = format!("{w} {t}");
                    }
                }
                block.kept.push(w);
            }
            if !written_elsewhere && codes::g_group(*g) != Some(1) {
                block.kept.push(w.clone());
            }
        }
    }

    /// The block's dwell `G4 P…` kept as written (a Fanuc `G04 X…` with its words); whether
    /// the block is a Fanuc dwell, which nothing else of it follows.
    fn dwell(&self, p: &Parsed, block: &mut Block, place: &Place) -> Result<bool> {
        if self.fanuc_dwell(p) {
            if let Some((_, g)) = p.g.iter().find(|(g, _)| *g == 40) {
                block.kept.push(format!("{g} {}", self.words_text(p)));
            }
            return Ok(true);
        }
        let Some((_, pw)) = p.other.get(&'P') else {
            let hint = if p.axes[0].is_some() {
                " (G4 X… is Fanuc's dwell in seconds, which RS274NGC controls refuse: write \
                 G4 P…)"
            } else {
                ""
            };
            return Err(refuse(
                place,
                "G4",
                format!("G4 without its dwell time P{hint}"),
            ));
        };
        block.kept.push(format!("G4 {pw}"));
        Ok(false)
    }

    /// A Fanuc-style dwell `G04 X<seconds>` (no P): its X is the time, not a position.
    pub(crate) fn fanuc_dwell(&self, p: &Parsed) -> bool {
        self.setup.dialect == crate::dialect::Dialect::Fanuc
            && p.has('G', 40)
            && p.value('P').is_none()
            && p.axes[0].is_some()
            && p.axes[1..].iter().all(Option::is_none)
    }

    /// Tool selection and change, spindle, the tool length offset (`G43 Hn`, `G43.1`, `G49`)
    /// and the other M codes.
    pub(crate) fn tools(&mut self, p: &Parsed, block: &mut Block, place: &Place) -> Result<()> {
        if let Some((t, w)) = p.other.get(&'T') {
            let t = self.tool_number(*t, w, place)?;
            self.selected = Some(t);
            block.kept.push(w.clone());
        }
        for (m, w) in &p.m {
            match m {
                60 => {
                    let Some(t) = self.selected else {
                        return Err(refuse(
                            place,
                            w,
                            "M6 changes to the selected tool, and no T word selected one",
                        ));
                    };
                    self.tool = Some(t);
                }
                610 => {
                    let Some((q, qw)) = p.other.get(&'Q') else {
                        return Err(refuse(
                            place,
                            w,
                            "M61 sets the tool in the spindle: it needs Q",
                        ));
                    };
                    self.tool = Some(self.tool_number(*q, qw, place)?);
                    block.kept.push(format!("{w} {qw}"));
                    continue;
                }
                30 | 40 | 50 => self.spindle = *m,
                _ => {}
            }
            if codes::m_group(*m) != Some(4) {
                block.kept.push(w.clone());
                block.kept.extend(m_words(*m, p));
            }
        }
        if p.has('G', 490) {
            self.tool_offset = [0.0; 6];
        }
        if p.has('G', 430) {
            self.g43(p, block, place)?;
        }
        if p.has('G', 431) {
            let w = self.words_text(p);
            self.tool_offset = [0.0; 6];
            for k in 0..6 {
                if let Some(v) = p.axes[k] {
                    self.tool_offset[k] = v * if k < 3 { self.scale() } else { 1.0 };
                }
            }
            block.kept.push(format!("G43.1 {w}"));
        }
        Ok(())
    }

    /// `G43 [Hn]`: the tool length offset of tool n (default: the tool in the spindle); with no
    /// tool known in the spindle yet (no `M6`, no start tool), tool n is taken to be there.
    fn g43(&mut self, p: &Parsed, block: &mut Block, place: &Place) -> Result<()> {
        if !self.offsets.tool_table {
            return Err(refuse(
                place,
                "G43",
                "G43 applies a tool length from the control's tool table, which volver was not \
                 given: pass it (--tool-table FILE.tbl, or [tool.N] tables in --offsets)",
            ));
        }
        let h = match p.other.get(&'H') {
            Some((h, w)) => {
                block.kept.push(format!("G43 {w}"));
                self.tool_number(*h, w, place)?
            }
            None => {
                block.kept.push("G43".into());
                self.tool.ok_or_else(|| {
                    refuse(
                        place,
                        "G43",
                        "G43 without H uses the tool in the spindle, and no M6 loaded one",
                    )
                })?
            }
        };
        self.tool_offset = self.offsets.tools.get(&h).copied().unwrap_or([0.0; 6]);
        // A program that applies tool n's length with no tool change before it runs with the
        // tool the control has loaded: tool n, whose point compensates its moves.
        if self.tool.is_none() && h != 0 {
            self.tool = Some(h);
        }
        Ok(())
    }

    /// A tool number from a T, H or Q word: whole, ≥ 0, and in the tool table when one is
    /// given (0 is the empty spindle).
    fn tool_number(&self, v: f64, w: &str, place: &Place) -> Result<i64> {
        if v.fract() != 0.0 || !(0.0..=1e9).contains(&v) {
            return Err(refuse(
                place,
                w,
                format!("{w}: a tool number is a whole number ≥ 0"),
            ));
        }
        let t = v as i64;
        if self.offsets.tool_table && t != 0 && !self.offsets.tools.contains_key(&t) {
            return Err(refuse(
                place,
                w,
                format!("tool {t} is not in the tool table: its length is not known"),
            ));
        }
        Ok(t)
    }

    /// The axis words of a block as written, joined.
    pub(crate) fn words_text(&self, p: &Parsed) -> String {
        p.axis_text.join(" ")
    }

    /// The non-modal codes that take axis words or set offsets: `G10`, `G28`/`G30` (and `.1`),
    /// `G52`, `G53`, `G92` (and `.1`–`.3`). Returns who owns the block's axis words.
    pub(crate) fn non_modal(
        &mut self,
        p: &Parsed,
        block: &mut Block,
        place: &Place,
    ) -> Result<Owner> {
        if self.fanuc_dwell(p) {
            return Ok(Owner::Taken);
        }
        if p.has('G', 431) {
            return Ok(Owner::Taken);
        }
        for (g, w) in &p.g {
            match g {
                100 => {
                    self.g10(p, block, place)?;
                    return Ok(Owner::Taken);
                }
                280 | 300 => {
                    self.reference(p, usize::from(*g == 300), w, block, place)?;
                    return Ok(Owner::Taken);
                }
                281 | 301 => {
                    let pos = self.known(&self.pos, place)?;
                    let h = usize::from(*g == 301);
                    for k in 0..6 {
                        if let Some(c) = self.chain[k] {
                            self.offsets.home[h][k] = pos[c];
                        }
                    }
                }
                520 | 920 => {
                    self.g92(p, *g == 520, w, block, place)?;
                    return Ok(Owner::Taken);
                }
                921 => (self.offsets.g92, self.saved_g92) = ([0.0; 6], [0.0; 6]),
                922 => self.saved_g92 = std::mem::replace(&mut self.offsets.g92, [0.0; 6]),
                923 => self.offsets.g92 = self.saved_g92,
                530 => {
                    self.g53(p, w, block, place)?;
                    return Ok(Owner::Machine);
                }
                _ => {}
            }
        }
        Ok(Owner::Motion)
    }

    /// `G10 L1 Pn` (tool n's offsets), `G10 L2 Pn` (coordinate system n's offsets), `G10 L20
    /// Pn` (coordinate system n such that the current position reads the given values).
    fn g10(&mut self, p: &Parsed, block: &mut Block, place: &Place) -> Result<()> {
        let (Some(l), Some(pn)) = (p.value('L'), p.value('P')) else {
            return Err(refuse(place, "G10", "G10 needs its L and P words"));
        };
        if !self.absolute {
            return Err(refuse(
                place,
                "G10",
                "G10 in incremental mode (G91) is not read: set offsets in G90",
            ));
        }
        if p.value('R').is_some_and(|r| r != 0.0) {
            return Err(refuse(
                place,
                "R",
                "a rotated coordinate system (G10 … R) is not read",
            ));
        }
        let text = format!(
            "G10 {} {}{}{}",
            p.other[&'L'].1,
            p.other[&'P'].1,
            if p.axis_text.is_empty() { "" } else { " " },
            self.words_text(p)
        );
        block.kept.push(text);
        let unit = self.scale();
        let scale = |k: usize| if k < 3 { unit } else { 1.0 };
        match l as i64 {
            1 => {
                let t = self.tool_number(pn, "P", place)?;
                let entry = self.offsets.tools.entry(t).or_insert([0.0; 6]);
                for (k, e) in entry.iter_mut().enumerate() {
                    if let Some(v) = p.axes[k] {
                        *e = v * scale(k);
                    }
                }
                self.offsets.tool_table = true;
            }
            2 | 20 => {
                let s = match pn as i64 {
                    0 => self.system,
                    n @ 1..=9 => n as usize - 1,
                    _ => {
                        return Err(refuse(
                            place,
                            "P",
                            "G10 P: 0 (the system in force) or 1 (G54) … 9 (G59.3)",
                        ));
                    }
                };
                for k in 0..6 {
                    let Some(v) = p.axes[k] else { continue };
                    self.offsets.work[s][k] = if l as i64 == 2 {
                        v * scale(k)
                    } else {
                        let m = self.uncompensated_at(k, "G10 L20", place)?;
                        m - v * scale(k) - self.offsets.g92[k] - self.tool_offset[k]
                    };
                }
            }
            _ => {
                return Err(refuse(
                    place,
                    "L",
                    "G10 L1, L2 and L20 are read (L10 and L11 set tool offsets from the current \
                     position, which compensation moves: give the tool table instead)",
                ));
            }
        }
        Ok(())
    }

    /// The machine position on letter `k` for a code that sets an offset from it (`G92`, `G10
    /// L20`): refused when unknown, or when a compensated move reached it (the compensated
    /// program stands elsewhere by the compensation, and the offset would shift every later
    /// point by it).
    fn uncompensated_at(&self, k: usize, code: &str, place: &Place) -> Result<f64> {
        let c = self.chain[k].expect("checked axis");
        let m = self.pos[c].ok_or_else(|| self.unknown(c, place))?;
        if self.compensated {
            return Err(refuse(
                place,
                code,
                format!(
                    "{code} sets an offset from the current position, which compensation has \
                     moved: the offset would shift every later point by the compensation; set it \
                     with G10 L2 or G52 (explicit values) instead"
                ),
            ));
        }
        Ok(m)
    }

    /// `G52` (a local offset of the given axes) and `G92` (an offset such that the current
    /// position reads the given values). LinuxCNC keeps both in one offset.
    fn g92(
        &mut self,
        p: &Parsed,
        local: bool,
        w: &str,
        block: &mut Block,
        place: &Place,
    ) -> Result<()> {
        if !p.any_axis() {
            return Err(refuse(place, w, format!("{w} needs axis words")));
        }
        for k in 0..6 {
            let Some(v) = p.axes[k] else { continue };
            let s = if k < 3 { self.scale() } else { 1.0 };
            self.offsets.g92[k] = if local {
                v * s
            } else {
                let m = self.uncompensated_at(k, "G92", place)?;
                m - v * s - self.offsets.work[self.system][k] - self.tool_offset[k]
            };
        }
        block.kept.push(format!("{w} {}", self.words_text(p)));
        Ok(())
    }

    /// `G28`/`G30`: a rapid to the intermediate point the axis words give (program
    /// coordinates), then to the stored reference position (machine coordinates) of those axes
    /// (every axis without words). Kept as reference moves, not compensated; axis words are
    /// written absolute.
    fn reference(
        &mut self,
        p: &Parsed,
        h: usize,
        w: &str,
        block: &mut Block,
        place: &Place,
    ) -> Result<()> {
        let mut words = Vec::new();
        let mut via = [None; MAX_AXES];
        let mut home = [None; MAX_AXES];
        for (k, l) in LETTERS.iter().enumerate() {
            let (Some(v), Some(c)) = (p.axes[k], self.chain[k]) else {
                continue;
            };
            let prog = if self.absolute {
                v
            } else {
                self.program_at(k, place)? + v
            };
            words.push(format!(
                "{l}{}",
                self.setup.dialect.decimal_point(number(prog))
            ));
            via[c] = Some(self.to_machine(k, prog));
            home[c] = Some(self.offsets.home[h][k]);
        }
        if words.is_empty() {
            for k in 0..6 {
                if let Some(c) = self.chain[k] {
                    home[c] = Some(self.offsets.home[h][k]);
                }
            }
        } else {
            block.held_moves.push(via);
        }
        block.held_moves.push(home);
        for (c, v) in home.iter().enumerate() {
            if v.is_some() {
                self.pos[c] = *v;
            }
        }
        self.compensated = false;
        block.kept.push(if words.is_empty() {
            w.to_string()
        } else {
            format!("{w} {}", words.join(" "))
        });
        block.note = Some(format!(
            "{w}: a reference move in machine coordinates, not compensated"
        ));
        Ok(())
    }

    /// `G53 G0|G1 …`: a move in machine coordinates, copied as written, not compensated.
    fn g53(&mut self, p: &Parsed, w: &str, block: &mut Block, place: &Place) -> Result<()> {
        let motion =
            p.g.iter()
                .find(|(g, _)| matches!(g, 0 | 10))
                .ok_or_else(|| {
                    refuse(
                        place,
                        w,
                        "G53 moves in machine coordinates with G0 or G1 in its block",
                    )
                })?;
        if !self.absolute {
            return Err(refuse(
                place,
                w,
                "G53 in incremental mode (G91): RS274NGC refuses it",
            ));
        }
        self.motion = Some(motion.0);
        let mut to = [None; MAX_AXES];
        for k in 0..6 {
            if let (Some(v), Some(c)) = (p.axes[k], self.chain[k]) {
                self.pos[c] = Some(v * if k < 3 { self.scale() } else { 1.0 });
                to[c] = self.pos[c];
            }
        }
        block.held_moves.push(to);
        self.compensated = false;
        block
            .kept
            .push(format!("{w} {} {}", motion.1, self.words_text(p)));
        block.note = Some(format!(
            "{w}: a move in machine coordinates, not compensated"
        ));
        Ok(())
    }
}

/// The words an M code takes (`M19 R Q P`, `M62 P`, `M66 P E L Q`, `M67 E`, `M48–M53 P`), as
/// written.
fn m_words(m: i64, p: &Parsed) -> Vec<String> {
    let letters: &[char] = match m {
        190 => &['R', 'Q', 'P'],
        480..=530 => &['P'],
        620..=680 => &['P', 'Q', 'E', 'L'],
        _ => &[],
    };
    letters
        .iter()
        .filter_map(|l| p.other.get(l).map(|(_, w)| w.clone()))
        .collect()
}

/// A number as a control reads it: no exponent, at most 9 decimals, no trailing zeros.
pub(crate) fn number(v: f64) -> String {
    let s = format!("{:.9}", v + 0.0);
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" { "0".into() } else { s.to_string() }
}
