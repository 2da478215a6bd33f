//! The compensated moves of a block: `G0`/`G1`, arcs `G2`/`G3`, and the drilling and boring
//! cycles expanded into `G0`/`G1` moves (LinuxCNC's `interp_cycles.cc` semantics).

use super::interp::{FeedMode, Parsed, Reader, refuse};
use super::path::arc_points;
use super::{Block, Step};
use crate::chain::MAX_AXES;
use crate::error::{Error, Place, Result};

/// Where a drill retracts between pecks in `G73`, and how far above the last depth `G83`
/// comes back down (LinuxCNC's `G83_RAPID_DELTA`: 0.010 inch, 0.254 mm).
pub const PECK_CLEARANCE_INCH: f64 = 0.010;

/// Whether a motion mode is a canned cycle (tenths of its G code).
fn is_cycle(mode: i64) -> bool {
    matches!(mode, 730 | 810 | 820 | 830 | 850 | 860 | 890)
}

/// The letters a motion mode takes besides the axes (tenths of its G code).
fn motion_letters(mode: i64) -> &'static [char] {
    match mode {
        20 | 30 => &['I', 'J', 'K', 'R', 'P'],
        730 | 830 => &['R', 'Q', 'L'],
        820 | 860 | 890 => &['R', 'P', 'L'],
        810 | 850 => &['R', 'L'],
        _ => &[],
    }
}

/// The pecks of `G73` (a small retract; `full` false) and `G83` (out to R and back down to
/// `delta` above the last depth; `full` true) from `r` down to `bottom` in steps of `q`, as
/// LinuxCNC's loop computes them (`depth -= q` while above the bottom).
fn pecks(
    full: bool,
    q: f64,
    [r, bottom, delta]: [f64; 3],
    at: &dyn Fn(f64) -> [f64; 3],
    moves: &mut Vec<(bool, [f64; 3])>,
    place: &Place,
) -> Result<()> {
    let mut depth = r - q;
    while depth > bottom {
        moves.push((false, at(depth)));
        if full {
            moves.push((true, at(r)));
        }
        moves.push((true, at(depth + delta)));
        depth -= q;
        if moves.len() > 100_000 {
            return Err(refuse(
                place,
                "Q",
                "the peck depth Q makes more than 100 000 moves",
            ));
        }
    }
    Ok(())
}

impl Reader<'_> {
    /// The block's motion in the motion mode (explicit or modal), if it has axis words; words
    /// no code of the block uses are refused.
    pub(crate) fn movement(&mut self, p: &Parsed, block: &mut Block, place: &Place) -> Result<()> {
        let before = self.motion;
        if let Some((g, _)) =
            p.g.iter()
                .find(|(g, _)| super::codes::g_group(*g) == Some(1))
        {
            self.motion = Some(*g);
            if *g == 800 {
                self.cycle = Default::default();
            }
            // A series of contiguous cycles starts: G98 retracts to where it started (LinuxCNC
            // keeps that height through changes of cycle code, as rs274 shows).
            match (is_cycle(*g), before.is_some_and(is_cycle)) {
                (true, false) => {
                    self.cycle_il = self.chain[2]
                        .and_then(|c| self.pos[c])
                        .map(|m| self.to_program(2, m));
                }
                (false, _) => self.cycle_il = None,
                (true, true) => {}
            }
        }
        self.orphans(p, place)?;
        if !p.any_axis() {
            if p.ijk.iter().any(Option::is_some) {
                return Err(refuse(place, "I", "arc words (I, J, K) without axis words"));
            }
            return Ok(());
        }
        let mode = match self.motion {
            None => {
                return Err(Error::input(
                    place.clone(),
                    "axis words before any motion code (G0, G1, G2, G3)",
                ));
            }
            Some(800) => {
                return Err(Error::input(
                    place.clone(),
                    "axis words with no motion mode in force (G80 cancels it): a control refuses \
                     them",
                ));
            }
            Some(m) => m,
        };
        match mode {
            0 | 10 => {
                let target = self.target(p, place)?;
                let mut m = self.straight(mode == 0, target, place)?;
                self.inverse_time(p, mode, &mut m, place)?;
                block.steps.push(Step::Move(m));
            }
            20 | 30 => {
                let mut m = self.arc(p, mode == 20, place)?;
                self.inverse_time(p, mode, &mut m, place)?;
                block.steps.push(Step::Move(m));
            }
            _ => self.cycle(p, mode, before != Some(mode), block, place)?,
        }
        Ok(())
    }

    /// Refuses a P, Q, R, L, E, H or I/J/K word that no code of the block (or its motion
    /// mode) uses: a control refuses it, or reads it as something volver did not.
    fn orphans(&self, p: &Parsed, place: &Place) -> Result<()> {
        let mut used: Vec<char> = Vec::new();
        if p.any_axis()
            && let Some(m) = self.motion
        {
            used.extend(motion_letters(m));
        }
        for (g, _) in &p.g {
            used.extend(match g {
                40 => &['P'][..],
                100 => &['L', 'P', 'R'][..],
                430 => &['H'][..],
                640 => &['P', 'Q'][..],
                _ => &[][..],
            });
        }
        for (m, _) in &p.m {
            used.extend(match m {
                190 => &['R', 'Q', 'P'][..],
                480..=530 => &['P'][..],
                610 => &['Q'][..],
                620..=680 => &['P', 'Q', 'E', 'L'][..],
                _ => &[][..],
            });
        }
        let ijk = ['I', 'J', 'K'];
        for (k, v) in p.ijk.iter().enumerate() {
            if v.is_some() && !used.contains(&ijk[k]) {
                return Err(refuse(
                    place,
                    &ijk[k].to_string(),
                    format!("{}: only arcs take I, J, K here", ijk[k]),
                ));
            }
        }
        for (letter, (_, w)) in &p.other {
            // D is taken only by cutter compensation (G41/G42), which volver refuses.
            let owned = matches!(letter, 'P' | 'Q' | 'R' | 'L' | 'E' | 'H' | 'D');
            if owned && !used.contains(letter) {
                return Err(refuse(
                    place,
                    w,
                    format!(
                        "{w}: no code of this block takes a {letter} word (a control refuses it or reads it as something else)"
                    ),
                ));
            }
            if *letter == 'O'
                && (p.any_axis() || !p.g.is_empty() || !p.m.is_empty() || p.other.len() > 1)
            {
                return Err(refuse(
                    place,
                    w,
                    "O words (subroutines, loops, conditions) are not read; a program number O… \
                     stands alone on its line",
                ));
            }
        }
        Ok(())
    }

    /// The end of a straight move: every axis word in the distance mode, in program units.
    fn target(&self, p: &Parsed, place: &Place) -> Result<[Option<f64>; MAX_AXES]> {
        let mut target = self.pos;
        for k in 0..6 {
            let (Some(v), Some(c)) = (p.axes[k], self.chain[k]) else {
                continue;
            };
            let prog = if self.absolute {
                v
            } else {
                self.program_at(k, place)? + v
            };
            target[c] = Some(self.to_machine(k, prog));
        }
        Ok(target)
    }

    /// In inverse time (`G93`), a feed move's F: required on every feed block (RS274NGC), kept
    /// with the move so that each of its points gets the F that keeps the move's time.
    fn inverse_time(
        &self,
        p: &Parsed,
        mode: i64,
        m: &mut super::Motion,
        place: &Place,
    ) -> Result<()> {
        if self.feed != FeedMode::InverseTime || mode == 0 {
            return Ok(());
        }
        match p.value('F') {
            Some(f) if f > 0.0 && f.is_finite() => {
                m.inverse_time_f = Some(f);
                Ok(())
            }
            _ => Err(refuse(
                place,
                "F",
                "in inverse time (G93) every feed move needs its F (1/minutes of the move)",
            )),
        }
    }

    /// An arc (or helix) in the plane in force, from the known position.
    fn arc(&mut self, p: &Parsed, clockwise: bool, place: &Place) -> Result<super::Motion> {
        if p.value('P').is_some_and(|t| t != 1.0) {
            return Err(refuse(
                place,
                "P",
                "arcs of several turns (G2/G3 with P) are not read",
            ));
        }
        let target = self.target(p, place)?;
        let from = self.known(&self.pos, place)?;
        let to = self.known(&target, place)?;
        // The centre's words relative to the start, in mm (incremental, or absolute G90.1).
        let mut centre = [None; 3];
        for (d, v) in p.ijk.iter().enumerate() {
            let Some(v) = *v else { continue };
            centre[d] = Some(if self.arc_absolute {
                let c = self.chain[d].ok_or_else(|| {
                    refuse(
                        place,
                        "I",
                        "the arc's centre is on an axis the machine lacks",
                    )
                })?;
                self.to_machine(d, v) - from[c]
            } else {
                v * self.scale()
            });
        }
        let radius = p.value('R').map(|r| r * self.scale());
        let pts = arc_points(
            self.machine,
            &from,
            &to,
            self.plane,
            centre,
            radius,
            clockwise,
            self.setup.lin.chord_tolerance_mm,
            place,
        )?;
        self.count(pts.len(), place)?;
        self.pos = target;
        self.compensated = true;
        Ok(self.motion(false, true, pts))
    }

    /// A drilling or boring cycle (`G73`, `G81`–`G83`, `G85`, `G86`, `G89`) expanded into moves
    /// at the positions LinuxCNC's interpreter makes (its `convert_cycle_xy`), each then
    /// compensated: in the XY plane, absolute mode.
    fn cycle(
        &mut self,
        p: &Parsed,
        mode: i64,
        first: bool,
        block: &mut Block,
        place: &Place,
    ) -> Result<()> {
        let code = super::codes::name('G', mode);
        self.cycle_allowed(p, &code, place)?;
        let words = self.cycle_words(p, mode, first, &code, place)?;
        let cur = [
            self.program_at(0, place)?,
            self.program_at(1, place)?,
            self.program_at(2, place)?,
        ];
        let (r, bottom) = (words.r.expect("checked"), words.z.expect("checked"));
        if r < bottom {
            return Err(refuse(
                place,
                "R",
                format!("{code}: the retract plane R {r} is below the bottom Z {bottom}"),
            ));
        }
        let x = p.axes[0].unwrap_or(cur[0]);
        let y = p.axes[1].unwrap_or(cur[1]);
        let repeats = match p.value('L') {
            None => 1,
            Some(l) if l >= 1.0 && l.fract() == 0.0 && l <= 1000.0 => l as usize,
            Some(l) => {
                return Err(refuse(
                    place,
                    "L",
                    format!("L{l}: a cycle repeats 1 … 1000 times"),
                ));
            }
        };
        let mut old_z = if self.retract_r {
            cur[2]
        } else {
            self.cycle_il.unwrap_or(cur[2])
        };
        let mut moves: Vec<(bool, [f64; 3])> = Vec::new();
        let mut extra: Vec<(usize, String)> = Vec::new();
        if old_z < r {
            moves.push((true, [cur[0], cur[1], r]));
            old_z = r;
        }
        let clear = if self.retract_r { r } else { old_z };
        for _ in 0..repeats {
            moves.push((true, [x, y, old_z]));
            if old_z != r {
                moves.push((true, [x, y, r]));
            }
            self.cycle_body(
                mode,
                &words,
                [x, y],
                r,
                bottom,
                clear,
                &mut moves,
                &mut extra,
                place,
            )?;
            old_z = clear;
        }
        self.cycle_steps(&moves, &extra, block, place)
    }

    /// Refuses a cycle outside `G17`, `G90` and feed per minute, or moving a rotary axis.
    fn cycle_allowed(&self, p: &Parsed, code: &str, place: &Place) -> Result<()> {
        if self.setup.dialect == crate::dialect::Dialect::Fanuc {
            return Err(refuse(
                place,
                code,
                format!(
                    "{code}: a Fanuc-style control's cycles retract and peck by amounts its \
                     parameters hold, which volver cannot see: expand the cycle into G0/G1 moves \
                     (CAM output) first"
                ),
            ));
        }
        if self.plane != 0 || !self.absolute || self.feed == FeedMode::InverseTime {
            return Err(refuse(
                place,
                code,
                format!(
                    "{code} is expanded in the XY plane (G17), absolute mode (G90) and feed per \
                     minute only: controls read cycles in other planes, incremental mode and \
                     inverse time differently"
                ),
            ));
        }
        if p.axes[3..].iter().any(Option::is_some) {
            return Err(refuse(
                place,
                code,
                format!("{code}: rotary axes do not move in a cycle"),
            ));
        }
        Ok(())
    }

    /// The cycle's R, Z, P and Q: from the block, else as last given (sticky); refused when a
    /// cycle starts without them.
    fn cycle_words(
        &mut self,
        p: &Parsed,
        mode: i64,
        first: bool,
        code: &str,
        place: &Place,
    ) -> Result<super::interp::CycleWords> {
        let w = &mut self.cycle;
        if let Some(z) = p.axes[2] {
            w.z = Some(z);
        }
        if let Some(r) = p.value('R') {
            w.r = Some(r);
        }
        if let Some(q) = p.value('Q') {
            w.q = Some(q);
        }
        if let Some(t) = p.value('P') {
            w.p = Some(t);
        }
        let need = |ok: bool, what: &str| {
            if ok {
                Ok(())
            } else {
                Err(refuse(place, code, format!("{code} needs {what}")))
            }
        };
        need(!first || p.axes[2].is_some(), "its bottom Z when it starts")?;
        need(
            !first || p.value('R').is_some(),
            "its retract plane R when it starts",
        )?;
        need(
            w.z.is_some() && w.r.is_some(),
            "its retract plane R and bottom Z",
        )?;
        if matches!(mode, 730 | 830) {
            need(w.q.is_some_and(|q| q > 0.0), "a peck depth Q > 0")?;
        }
        if matches!(mode, 820 | 860 | 890) {
            need(w.p.is_some_and(|t| t >= 0.0), "its dwell P (s)")?;
        }
        Ok(*w)
    }

    /// The moves of one repeat of a cycle at the hole (x, y), from the retract plane `r`.
    #[allow(clippy::too_many_arguments)]
    fn cycle_body(
        &self,
        mode: i64,
        w: &super::interp::CycleWords,
        [x, y]: [f64; 2],
        r: f64,
        bottom: f64,
        clear: f64,
        moves: &mut Vec<(bool, [f64; 3])>,
        extra: &mut Vec<(usize, String)>,
        place: &Place,
    ) -> Result<()> {
        let at = |z: f64| [x, y, z];
        let delta = PECK_CLEARANCE_INCH * if self.inch { 1.0 } else { 25.4 };
        let dwell = |extra: &mut Vec<(usize, String)>, n: usize| {
            extra.push((
                n,
                format!("G4 P{}", super::modes::number(w.p.unwrap_or(0.0))),
            ));
        };
        match mode {
            730 | 830 => {
                let q = w.q.expect("checked");
                pecks(mode == 830, q, [r, bottom, delta], &at, moves, place)?;
                moves.push((false, at(bottom)));
                moves.push((true, at(clear)));
            }
            810 | 820 | 860 => {
                moves.push((false, at(bottom)));
                if mode != 810 {
                    dwell(extra, moves.len());
                }
                if mode == 860 {
                    if !matches!(self.spindle, 30 | 40) {
                        return Err(refuse(
                            place,
                            "G86",
                            "G86 stops and restarts the spindle, which is not turning (M3/M4)",
                        ));
                    }
                    extra.push((moves.len(), "M5".into()));
                    moves.push((true, at(clear)));
                    extra.push((
                        moves.len(),
                        if self.spindle == 30 { "M3" } else { "M4" }.into(),
                    ));
                } else {
                    moves.push((true, at(clear)));
                }
            }
            // As LinuxCNC 2.9's interpreter moves (seen in rs274): G85 feeds out to R and
            // rapids to the clearance; G89 dwells and feeds out to the clearance.
            850 => {
                moves.push((false, at(bottom)));
                moves.push((false, at(r)));
                moves.push((true, at(clear)));
            }
            890 => {
                moves.push((false, at(bottom)));
                dwell(extra, moves.len());
                moves.push((false, at(clear)));
            }
            _ => unreachable!("cycle codes are checked"),
        }
        Ok(())
    }

    /// The cycle's moves (program X, Y, Z) as compensated steps, with the words between them
    /// (`extra`: (number of moves before it, words)).
    fn cycle_steps(
        &mut self,
        moves: &[(bool, [f64; 3])],
        extra: &[(usize, String)],
        block: &mut Block,
        place: &Place,
    ) -> Result<()> {
        let mut e = extra.iter().peekable();
        for (i, (rapid, xyz)) in moves.iter().enumerate() {
            while let Some((_, w)) = e.next_if(|(n, _)| *n == i) {
                block.steps.push(Step::Words(w.clone()));
            }
            let mut target = self.pos;
            for (k, v) in xyz.iter().enumerate() {
                let c = self.chain[k].expect("checked by program_at");
                target[c] = Some(self.to_machine(k, *v));
            }
            let m = self.straight(*rapid, target, place)?;
            block.steps.push(Step::Move(m));
        }
        for (_, w) in e {
            block.steps.push(Step::Words(w.clone()));
        }
        Ok(())
    }
}
