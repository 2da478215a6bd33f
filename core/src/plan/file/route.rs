//! The moves of a measuring program between its visits: through the clearance position, and,
//! for an axis whose direction of approach the plan states, over the overrun to its position in
//! that direction ([`super::gcode`] documents the rules).

use crate::approach::Approach;
use crate::chain::MAX_AXES;
use crate::dialect::Dialect;
use crate::machine::{Commands, Machine};
use std::fmt::Write as _;

/// The program's moves as they are written, and where they leave the machine.
pub(super) struct Route<'a> {
    /// The program written so far.
    pub(super) out: String,
    machine: &'a Machine,
    d: Dialect,
    /// The clearance position: (chain index, position in mm or rad).
    clearance: &'a [(usize, f64)],
    /// Each axis' overrun (mm or rad).
    overrun: [f64; MAX_AXES],
    /// The approach moves' feed (mm/min; degrees/min for a rotary axis alone).
    feed: f64,
    /// Where the machine is, as far as the program knows (NaN before an axis' first move).
    now: Commands,
    /// Each axis' direction of approach at `now`: the direction of its last approach move when
    /// it has not moved since, else 0.
    approached: [i8; MAX_AXES],
    /// The visit's block number, taken by its first block.
    number: Option<usize>,
    /// Each axis' direction of its last move as written (0 before its first known move): the
    /// direction of approach the program gives a measurement.
    pub(super) arrived: Approach,
}

impl<'a> Route<'a> {
    /// A route on `machine` continuing the program `out`, in dialect `d`, retracting to
    /// `clearance`, approaching over `overrun` (per axis, mm or rad) at `feed` (mm/min).
    pub(super) fn new(
        out: String,
        machine: &'a Machine,
        d: Dialect,
        clearance: &'a [(usize, f64)],
        (overrun, feed): ([f64; MAX_AXES], f64),
    ) -> Route<'a> {
        Route {
            out,
            machine,
            d,
            clearance,
            overrun,
            feed,
            now: Commands([f64::NAN; MAX_AXES]),
            approached: [0; MAX_AXES],
            number: None,
            arrived: Approach::UNKNOWN,
        }
    }

    fn is_clearance(&self, j: usize) -> bool {
        self.clearance.iter().any(|c| c.0 == j)
    }

    /// The axis word's value of axis `j` at `c` as the dialect writes it (file units), `None`
    /// when unknown.
    fn written(&self, c: &Commands, j: usize) -> Option<String> {
        let v = c.0[j];
        (!v.is_nan()).then(|| self.d.value(self.machine.axes()[j].to_file_units(v)))
    }

    /// Whether axis `j` is where `to` puts it, as written.
    fn at(&self, to: &Commands, j: usize) -> bool {
        let w = self.written(to, j);
        w.is_some() && self.written(&self.now, j) == w
    }

    /// Whether axis `j` must be approached to reach `to` arriving in direction `sign` (0: no
    /// direction stated): it is elsewhere, or did not arrive there by an approach in `sign`.
    fn needs(&self, to: &Commands, j: usize, sign: i8) -> bool {
        sign != 0 && !(self.at(to, j) && self.approached[j] == sign)
    }

    /// The moves to `to` for visit `number`, each axis that `approach` states a direction for
    /// arriving in it over its overrun (see [`super::gcode`]).
    pub(super) fn visit(
        &mut self,
        to: &Commands,
        approach: Option<&Approach>,
        number: Option<usize>,
    ) {
        self.number = number;
        let n = self.machine.axes().len();
        let sign = |j: usize| approach.map_or(0, |a| a.0[j]);
        let others: Vec<usize> = (0..n).filter(|&j| !self.is_clearance(j)).collect();
        let lateral = self.now.0[..n].iter().any(|v| v.is_nan())
            || others
                .iter()
                .any(|&j| !self.at(to, j) || self.needs(to, j, sign(j)));
        if lateral {
            // Retract: linear clearance axes first, then rotary ones.
            for rotary in [false, true] {
                let mut next = self.now;
                for &(j, v) in self.clearance {
                    if self.machine.axes()[j].axis.is_rotary() == rotary {
                        next.0[j] = v;
                    }
                }
                self.rapid(&next, "clearance");
            }
            // The other axes to their positions, or to where their approach starts, then the
            // approaches at feed: every move of theirs with the clearance axes held.
            let approaching: Vec<usize> = others
                .iter()
                .copied()
                .filter(|&j| self.needs(to, j, sign(j)))
                .collect();
            let mut next = self.now;
            for &j in &others {
                next.0[j] = to.0[j];
            }
            for &j in &approaching {
                next.0[j] = to.0[j] - f64::from(sign(j)) * self.overrun[j];
            }
            self.rapid(&next, "");
            if !approaching.is_empty() {
                let note = self.directions(&approaching, sign);
                let mut there = self.now;
                for &j in &approaching {
                    there.0[j] = to.0[j];
                }
                self.feed_to(&there, &note);
                for &j in &approaching {
                    self.approached[j] = sign(j);
                }
            }
        }
        // Approach: rotary clearance axes first, then linear ones; those with a stated
        // direction one at a time.
        for rotary in [true, false] {
            let group: Vec<usize> = self
                .clearance
                .iter()
                .map(|c| c.0)
                .filter(|&j| self.machine.axes()[j].axis.is_rotary() == rotary)
                .collect();
            let mut next = self.now;
            for &j in group.iter().filter(|&&j| sign(j) == 0) {
                next.0[j] = to.0[j];
            }
            self.rapid(&next, "");
            for &j in &group {
                if self.needs(to, j, sign(j)) {
                    self.approach_alone(j, to.0[j], sign(j));
                }
            }
        }
    }

    /// The approach of clearance axis `j` alone to `target` arriving in direction `sign`: a
    /// rapid to the overrun's distance on the side it comes from (when farther), then at feed
    /// to where the approach starts (through the position when it starts beyond it: an
    /// overshoot away from the clearance is never a rapid), then to the position.
    fn approach_alone(&mut self, j: usize, target: f64, sign: i8) {
        let o = self.overrun[j];
        let toward = target - self.now.0[j];
        if toward.abs() > o {
            let near = self.moved(j, target - toward.signum() * o);
            self.rapid(&near, "");
        }
        let begin = self.moved(j, target - f64::from(sign) * o);
        if !self.at(&begin, j) {
            self.feed_to(&begin, "");
        }
        let note = self.directions(&[j], |_| sign);
        let end = self.moved(j, target);
        self.feed_to(&end, &note);
        self.approached[j] = sign;
    }

    /// Where the machine is with axis `j` at `v`.
    fn moved(&self, j: usize, v: f64) -> Commands {
        let mut c = self.now;
        c.0[j] = v;
        c
    }

    /// The comment of an approach: `approach X+ C-`.
    fn directions(&self, axes: &[usize], sign: impl Fn(usize) -> i8) -> String {
        let words: Vec<String> = axes
            .iter()
            .map(|&j| {
                let s = if sign(j) > 0 { '+' } else { '-' };
                format!("{}{s}", self.machine.axes()[j].axis)
            })
            .collect();
        format!("approach {}", words.join(" "))
    }

    /// The block's number, when it is the visit's first block.
    fn number(&mut self) {
        if let Some(n) = self.number.take() {
            let _ = write!(self.out, "N{n} ");
        }
    }

    /// The axis words of the axes whose written value changes from `now` to `to` (or was
    /// unknown).
    fn changed(&self, to: &Commands) -> Vec<usize> {
        (0..self.machine.axes().len())
            .filter(|&j| {
                let w = self.written(to, j);
                w.is_some() && self.written(&self.now, j) != w
            })
            .collect()
    }

    /// A rapid in machine coordinates to `to` (NaN: unknown) naming the axes whose written value
    /// changes or was unknown, nothing when none does; `note` as a comment.
    pub(super) fn rapid(&mut self, to: &Commands, note: &str) {
        let moved = self.changed(to);
        if moved.is_empty() {
            return;
        }
        let words: Vec<String> = moved
            .iter()
            .map(|&j| {
                let w = self.written(to, j).unwrap_or_default();
                format!("{}{w}", self.machine.axes()[j].axis)
            })
            .collect();
        self.number();
        let _ = write!(self.out, "G53 {} {}", self.d.rapid(), words.join(" "));
        self.end_block(note);
        self.arrive(to, &moved);
    }

    /// A feed move to `to` from a known position: an incremental move (`G91 G1`, the written
    /// positions' differences, so that it ends where a `G53` move to `to` would, whatever work
    /// offset is in force; Fanuc's `G53` moves at rapid only), then back to absolute (`G90`).
    fn feed_to(&mut self, to: &Commands, note: &str) {
        let moved = self.changed(to);
        if moved.is_empty() {
            return;
        }
        // The positions as written (rounded to 1e-6 of the unit, as [`Dialect::value`]).
        let value = |c: &Commands, j: usize| {
            (self.machine.axes()[j].to_file_units(c.0[j]) * 1e6).round() / 1e6
        };
        let words: Vec<String> = moved
            .iter()
            .map(|&j| {
                let delta = value(to, j) - value(&self.now, j);
                format!("{}{}", self.machine.axes()[j].axis, self.d.value(delta))
            })
            .collect();
        self.number();
        let _ = write!(
            self.out,
            "G91 {} {} F{}",
            self.d.feed(),
            words.join(" "),
            self.d.value(self.feed)
        );
        self.end_block(note);
        self.out.push_str("G90\n");
        self.arrive(to, &moved);
    }

    /// The machine at `to` after a move of the axes `moved`: each moved axis' direction is the
    /// move's, and none arrived by an approach.
    fn arrive(&mut self, to: &Commands, moved: &[usize]) {
        self.arrived = self
            .arrived
            .after_move(&self.now, to, self.machine.axes().len());
        for &j in moved {
            self.now.0[j] = to.0[j];
            self.approached[j] = 0;
        }
    }

    /// Ends a block with `note` as a comment (none when empty).
    fn end_block(&mut self, note: &str) {
        if !note.is_empty() {
            let _ = write!(self.out, " {}", self.d.comment(note));
        }
        self.out.push('\n');
    }

    /// The final retract to the clearance position (nothing before the first visit).
    pub(super) fn retract(&mut self) {
        let n = self.machine.axes().len();
        if self.now.0[..n].iter().any(|v| v.is_nan()) {
            return;
        }
        let mut clear = self.now;
        for &(j, value) in self.clearance {
            clear.0[j] = value;
        }
        self.rapid(&clear, "clearance");
    }
}
