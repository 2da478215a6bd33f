//! Compensation along a path: each axis' direction of motion, so that every compensated command
//! puts the axis' reversal (ISO 230-2's B, [`crate::approach`]) on the side the axis arrives
//! from.
//!
//! **The rule.** The direction of an axis at a point is that of the last move of its *written*
//! command — what the control executes, rounded to the output's decimals — since that is what
//! its drive sees; an axis that does not move keeps the direction of its last move, and before
//! its first move it is unknown (the mean of both sides). Because the compensation itself
//! moves the commands, the direction and the command are settled together, point by point, in
//! a fixed order:
//!
//! 1. the point is compensated with every axis keeping its direction;
//! 2. an axis whose written command then goes back — more than the *reversal tolerance*
//!    (default [`REVERSAL_TOLERANCE_UM`] µm, µrad on a rotary axis) behind the furthest point
//!    it reached since its direction was set, or that far from where it stood while its
//!    direction is unknown — reverses, and the point is compensated again with its new
//!    direction;
//! 3. the reversal holds when the command written in the new direction reverses the axis by
//!    step 2's measure (the drive does reverse: the direction is that of the command written).
//!    Otherwise the point is **unsettled**: an axis that overshoots (lands beyond its target in
//!    the direction it moves: ISO 230-2's B > 0, the tool relative to the workpiece along the
//!    axis) cannot reach a point less than |B| behind the one it turned at, in either state
//!    (reversed, its command would not go back; not reversed, it would go back, and so
//!    reverse). Such an axis holds its command there — it does not move, so it keeps its
//!    direction — and the tool is off its target by as much as the program has gone back (less
//!    than |B| and the tolerance; [`Compensated::deviation_mm`] says how far); it reverses at
//!    the first point the program has gone back more than that from the turn;
//! 4. steps 2–3 repeat while an axis' direction changes (the axes' compensations interact a
//!    little); each axis reverses or holds at most once per point.
//!
//! A move back by less than the tolerance leaves the axis' direction (and its lost motion)
//! alone: a compensation that moves a near-stationary axis back and forth by fractions of a
//! micrometre does not take up its backlash each time; on an axis with lost motion (ISO 230-2's
//! B < 0: it stops short of its target on the side it comes from) the slide stays in the play,
//! within the tolerance of its target. With a tolerance of zero every move back of the written
//! command reverses. (The model's `reversal.X.b` is ISO 230-2's B, the tool's deviation
//! relative to the workpiece; the reversal of the axis' own error — the slide's, in the machine
//! frame, as the tables hold it — is B on an axis that moves the tool and −B on one that moves
//! the workpiece; see [`crate::tables::Directional`].)
//!
//! The written program is a line between consecutive points, so each of its moves has one
//! direction per axis: a reversal inside a programmed move (an arc turning an axis at its
//! extreme, whose point the reader puts on the chords; a compensated command that turns back
//! between the points of a split move) happens at a point, which is compensated in the
//! direction the axis arrives there with, the next point in the new one.

use super::{Compensated, Compensator};
use crate::approach::{Approach, MOVE_TOLERANCE};
use crate::chain::MAX_AXES;
use crate::error::Result;
use crate::machine::Commands;
use crate::model::{Model, PointState};
use crate::units::{UM_PER_MM, URAD_PER_RAD};

/// The default reversal tolerance (µm on a linear axis, µrad on a rotary one): a written command
/// going back by less does not reverse its axis (see the module's documentation).
pub const REVERSAL_TOLERANCE_UM: f64 = 1.0;

/// The chain positions of the axes `model` gives a reversal (`[effects] reversal`): those whose
/// direction of approach moves the tool point.
pub fn reversal_axes(model: &Model) -> Vec<usize> {
    let mut out: Vec<usize> = model.reversal_axes().into_iter().map(|(k, _)| k).collect();
    out.sort_unstable();
    out
}

/// Each axis' direction of motion along a path of written commands (see the module's
/// documentation): the state the next point is compensated in.
#[derive(Clone, Debug, PartialEq)]
pub struct Travel {
    /// Each axis' direction of approach: the sign of its last move.
    approach: Approach,
    /// Each axis' last written command (internal units), `None` while unknown.
    last: [Option<f64>; MAX_AXES],
    /// The furthest each axis' command reached in its direction since it was set (where it
    /// stood while its direction is unknown); meaningful where `last` is known.
    extreme: [f64; MAX_AXES],
    /// Each axis' reversal tolerance (internal units: mm, rad).
    tolerance: [f64; MAX_AXES],
    /// The axes whose direction moves the tool point (a reversal in the model).
    reversal: [bool; MAX_AXES],
    n_axes: usize,
}

/// One point of a path, compensated in its axes' directions.
#[derive(Clone, Debug, PartialEq)]
pub struct PathPoint {
    /// The compensated command, solved in the state [`PathPoint::approach`] gives.
    pub compensated: Compensated,
    /// The command as written (what the control executes; internal units).
    pub written: Commands,
    /// Each axis' direction of approach to the point: the state it was compensated in.
    pub approach: Approach,
    /// The axes (chain positions) with a reversal whose direction changed at this point from
    /// one side to the other (not the first move of an axis whose direction was unknown).
    pub reversed: Vec<usize>,
    /// The axes (chain positions) with a reversal that could not reverse here although the
    /// program goes back (step 3 of the rule): each holds its last command, and the point is
    /// off its target by [`Compensated::deviation_mm`].
    pub unsettled: Vec<usize>,
}

/// What the rule makes of one axis' written command `w`.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Judged {
    /// It keeps its direction; the furthest point reached becomes this.
    Keep(f64),
    /// It reverses to this direction.
    Reverse(i8),
}

impl Travel {
    /// A path on `model`'s machine starting with every axis' position and direction unknown;
    /// `tolerance_um`: the reversal tolerance (µm on a linear axis, µrad on a rotary one, ≥ 0).
    pub fn new(model: &Model, tolerance_um: f64) -> Travel {
        let axes = model.machine().axes();
        let mut tolerance = [0.0; MAX_AXES];
        for (k, a) in axes.iter().enumerate() {
            let t = if a.axis.is_rotary() {
                tolerance_um / URAD_PER_RAD
            } else {
                tolerance_um / UM_PER_MM
            };
            tolerance[k] = t.max(MOVE_TOLERANCE);
        }
        let mut reversal = [false; MAX_AXES];
        for k in reversal_axes(model) {
            reversal[k] = true;
        }
        Travel {
            approach: Approach::UNKNOWN,
            last: [None; MAX_AXES],
            extreme: [0.0; MAX_AXES],
            tolerance,
            reversal,
            n_axes: axes.len(),
        }
    }

    /// Each axis' direction of approach now.
    pub fn approach(&self) -> Approach {
        self.approach
    }

    /// Whether any axis' direction moves the tool point (the model has a reversal).
    pub fn directed(&self) -> bool {
        self.reversal.iter().any(|&r| r)
    }

    /// The machine moved to `to` (internal units; `None`: the axis does not move) without
    /// compensation: a known start position, a reference move (`G28`), a move in machine
    /// coordinates (`G53`). Each axis that moves takes the direction of its move by the rule.
    pub fn moved_to(&mut self, to: &[Option<f64>; MAX_AXES]) {
        let mut w = Commands::default();
        for (k, t) in to.iter().enumerate().take(self.n_axes) {
            w.0[k] = t.or(self.last[k]).unwrap_or(0.0);
        }
        let moved: Vec<bool> = (0..self.n_axes).map(|k| to[k].is_some()).collect();
        let mut next = self.approach;
        for k in (0..self.n_axes).filter(|&k| moved[k]) {
            if let Judged::Reverse(d) = self.judge(k, w.0[k]) {
                next.0[k] = d;
            }
        }
        self.settle(next, &w, &moved);
    }

    /// The next point of the path: `programmed` compensated by `comp` with each axis' direction
    /// settled by the rule, `write` giving the command a solved one is written as (internal
    /// units). The path's state moves to the point.
    pub fn next(
        &mut self,
        comp: &Compensator,
        programmed: &Commands,
        write: &dyn Fn(&Commands) -> Commands,
    ) -> Result<PathPoint> {
        let before = self.approach;
        let mut s = before;
        let mut held = [false; MAX_AXES];
        let mut unsettled = Vec::new();
        let mut round = 0;
        let (mut c, mut w) = loop {
            let c = comp.in_state(self.state(s)).compensate(programmed)?;
            let w = write(&c.commands);
            let again = self.round(&mut s, before, &w, &mut held, &mut unsettled);
            round += 1;
            if !again || round > self.n_axes + 1 {
                break (c, w);
            }
        };
        unsettled.sort_unstable();
        if !unsettled.is_empty() {
            // Step 3: each unsettled axis holds its last command; the deviation is what it
            // leaves.
            for &k in &unsettled {
                c.commands.0[k] = self.last[k].unwrap_or(c.commands.0[k]);
            }
            w = write(&c.commands);
            let comp = comp.in_state(self.state(s));
            c.deviation_mm = comp.deviation_mm(&w, c.target);
            if let Some(o) = &mut c.orientation {
                o.deviation_rad = comp.direction_deviation_rad(&w, o.target);
            }
        }
        // The other axes take the rule's direction at the command written.
        let judged = self.judged(&w);
        for k in (0..self.n_axes).filter(|&k| !self.reversal[k]) {
            s.0[k] = judged.0[k];
        }
        let all = vec![true; self.n_axes];
        self.settle(s, &w, &all);
        Ok(PathPoint {
            compensated: c,
            written: w,
            approach: s,
            reversed: (0..self.n_axes)
                .filter(|&k| self.reversal[k] && before.0[k] != 0 && s.0[k] != before.0[k])
                .collect(),
            unsettled,
        })
    }

    /// One round of steps 2–3 at written command `w`, solved with directions `s` (changed in
    /// place) from the directions `before` the point: a reversed axis whose command does not
    /// reverse it holds (`held`, `unsettled`), an axis the command reverses takes the new
    /// direction. Whether a direction changed (the point is solved again).
    fn round(
        &self,
        s: &mut Approach,
        before: Approach,
        w: &Commands,
        held: &mut [bool; MAX_AXES],
        unsettled: &mut Vec<usize>,
    ) -> bool {
        let judged = self.judged(w);
        let mut again = false;
        for (k, h) in held.iter_mut().enumerate().take(self.n_axes) {
            if !self.reversal[k] || *h {
                continue;
            }
            if s.0[k] != before.0[k] {
                // Step 3: a reversal holds when the command written in the new direction
                // reverses the axis by step 2's measure, else the axis holds its command.
                if self.judge(k, w.0[k]) != Judged::Reverse(s.0[k]) {
                    s.0[k] = before.0[k];
                    *h = true;
                    unsettled.push(k);
                    again = true;
                }
            } else if judged.0[k] != s.0[k] {
                s.0[k] = judged.0[k];
                again = true;
            }
        }
        again
    }

    /// The state of a point reached with directions `approach` (at the test's start).
    fn state(&self, approach: Approach) -> PointState {
        PointState { t_s: 0.0, approach }
    }

    /// Every axis' direction by the rule if the written command were `w`.
    fn judged(&self, w: &Commands) -> Approach {
        let mut a = self.approach;
        for k in 0..self.n_axes {
            if let Judged::Reverse(d) = self.judge(k, w.0[k]) {
                a.0[k] = d;
            }
        }
        a
    }

    /// The rule for axis `k` at written command `w`: it reverses when `w` is more than the
    /// tolerance behind the furthest point it reached in its direction (from where it stood, in
    /// either direction, while its direction is unknown).
    fn judge(&self, k: usize, w: f64) -> Judged {
        let (s, e, tol) = (self.approach.0[k], self.extreme[k], self.tolerance[k]);
        if self.last[k].is_none() {
            return Judged::Keep(w);
        }
        match s {
            1 if w < e - tol => Judged::Reverse(-1),
            1 => Judged::Keep(e.max(w)),
            -1 if w > e + tol => Judged::Reverse(1),
            -1 => Judged::Keep(e.min(w)),
            _ if (w - e).abs() > tol => Judged::Reverse(if w > e { 1 } else { -1 }),
            _ => Judged::Keep(e),
        }
    }

    /// Moves the state to written command `w` with directions `next` on the axes `moved`: a
    /// changed direction starts its furthest point at `w`, a kept one extends it.
    fn settle(&mut self, next: Approach, w: &Commands, moved: &[bool]) {
        for k in (0..self.n_axes).filter(|&k| moved[k]) {
            self.extreme[k] = if self.last[k].is_none() || next.0[k] != self.approach.0[k] {
                w.0[k]
            } else {
                match self.judge(k, w.0[k]) {
                    Judged::Keep(e) => e,
                    // A held (unsettled) axis whose command goes back: its furthest point stays.
                    Judged::Reverse(_) => self.extreme[k],
                }
            };
            self.approach.0[k] = next.0[k];
            self.last[k] = Some(w.0[k]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine::Machine;

    /// The XCFZ machine with a reversal of X whose slide B (the reversal of EXX itself) is
    /// `b_mm`: X carries the workpiece, so ISO 230-2's B (`reversal.X.b`) is −`b_mm`.
    fn model_with(b_mm: f64) -> (Model, Vec<f64>) {
        let model = Model::from_toml_str(
            Machine::default_xcfz(),
            "[effects]\nreversal = [\"X\"]",
            "m.toml",
        )
        .unwrap();
        let mut p = model.initial_params();
        p[model.param_index("reversal.X.b").unwrap()] = -b_mm;
        (model, p)
    }

    /// X back and forth: each point compensated in the direction it is reached with, the first
    /// in the mean; the reversal settles at the turning point.
    #[test]
    fn back_and_forth_reverses_at_the_turning_points() {
        for b in [0.015, -0.015] {
            let (model, p) = model_with(b);
            let comp = Compensator::new(&model, &p, [0.0; 3]).unwrap();
            let mut t = Travel::new(&model, REVERSAL_TOLERANCE_UM);
            let at = |x: f64| model.machine().commands_from_file_units(&[x, 0.0, 300.0]);
            let round = |c: &Commands| {
                let mut w = *c;
                w.0.iter_mut().for_each(|v| *v = (*v * 1e4).round() / 1e4);
                w
            };
            let mut got = Vec::new();
            for x in [100.0, 300.0, 500.0, 200.0, 100.0, 400.0] {
                let pt = t.next(&comp, &at(x), &round).unwrap();
                assert!(pt.unsettled.is_empty(), "B {b}: {pt:?}");
                got.push(pt.approach.0[0]);
            }
            assert_eq!(got, [0, 1, 1, -1, -1, 1], "B {b}");
        }
    }

    /// A move back by less than the tolerance keeps the direction; by more, it reverses.
    #[test]
    fn the_tolerance_and_the_unsettled_points_of_an_overshooting_axis() {
        // X carries the workpiece: a slide B of −15 µm is ISO 230-2's +15 µm, an overshoot.
        let (model, p) = model_with(-0.015);
        let comp = Compensator::new(&model, &p, [0.0; 3]).unwrap();
        let at = |x: f64| model.machine().commands_from_file_units(&[x, 0.0, 300.0]);
        let exact = |c: &Commands| *c;
        let mut t = Travel::new(&model, 1.0);
        for x in [100.0, 200.0, 199.9995] {
            t.next(&comp, &at(x), &exact).unwrap();
        }
        assert_eq!(t.approach().0[0], 1, "0.5 µm back is within 1 µm");
        // 5 µm back, overshooting by 15 µm: in reverse the command would go 10 µm forward. X
        // holds its command, 4.5 µm off (it was 0.5 µm back already).
        let held = t.last[0].unwrap();
        let pt = t.next(&comp, &at(199.995), &exact).unwrap();
        assert_eq!((pt.approach.0[0], pt.unsettled.clone()), (1, vec![0]));
        assert_eq!(pt.written.0[0], held);
        assert!(
            (pt.compensated.deviation_mm - 0.0045).abs() < 1e-9,
            "{pt:?}"
        );
        // 10 µm back from the turn: still held.
        let pt = t.next(&comp, &at(199.99), &exact).unwrap();
        assert_eq!((pt.approach.0[0], pt.written.0[0]), (1, held));
        // 17 µm back: the reverse command goes back from the held one by more than 1 µm.
        let pt = t.next(&comp, &at(199.983), &exact).unwrap();
        assert_eq!((pt.approach.0[0], pt.reversed.clone()), (-1, vec![0]));
        assert!(pt.unsettled.is_empty() && pt.compensated.deviation_mm < 1e-9);
    }
}
