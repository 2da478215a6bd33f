//! The direction of approach: from which side each axis reached a measured point (ISO 230-2's
//! forward ↑ and reverse ↓ approach), derived from the measuring order or stated per point.
//!
//! An axis that stops short of its command on the side it came from (backlash, a drive's lost
//! motion) puts the tool where it does not only by its position but by the direction of its
//! last move: the **reversal value** B of ISO 230-2, the mean deviation (of the tool relative
//! to the workpiece, along the command) approaching in the positive direction minus the one
//! approaching in the negative. volver's reversal effect (`[effects] reversal = ["X"]`,
//! parameter `reversal.X.b`) moves the tool relative to the workpiece by `s · B / 2` along the
//! axis (the axis' positioning error by `σ · s · B / 2`, σ = −1 on the workpiece side), where
//! `s` is the point's [`Approach`] on that axis: +1 when the axis
//! arrived moving in its positive direction, −1 moving in its negative, 0 when unknown (an
//! axis that never moves in the test: the mean of both directions is predicted).
//!
//! **Where the direction comes from** (the same rule for every reader):
//! 1. an `approach_<AXIS>` column of the measurement file (`+1`, `-1`, `0`, or `+`, `-`), when the
//!    measuring software records it, wins for that axis: a plan that overruns each position
//!    and comes back (ISO 230-2) approaches from a side the order of the points does not show;
//! 2. otherwise the **measuring order**: the order of the time stamps when every row has one
//!    (a file sorted by something else is put back in time order), else the rows' order. The
//!    direction of an axis at a point is the sign of its last move before the point, a move
//!    being a change of its command larger than [`MOVE_TOLERANCE`] (commands as written: a
//!    rotary axis from 350° to 10° moves −340°). Before an axis' first move, the direction of
//!    that first move: the test is taken to have reached its first position moving the way it
//!    then goes on (as a measuring program that starts with an approach move does). This is an
//!    assumption, stated so: were those points predicted at the mean of both sides, their
//!    contrast with the rest would seem to measure a reversal that a test approaching the axis
//!    from one side cannot measure. An axis that never moves keeps 0 (unknown) throughout.
//!    State the direction in `approach_<AXIS>` columns where the assumption is wrong.
//!
//! An `approach_<AXIS>` column must give every row a value (a partial column is refused: the
//! rows without one would silently take the order's direction).
//!
//! ```
//! use volver_core::approach::{Approach, from_order};
//! use volver_core::machine::Commands;
//! let c = |x: f64| Commands([x, 0.0, 0.0, 0.0, 0.0, 0.0]);
//! let a = from_order(&[c(0.0), c(100.0), c(100.0), c(50.0)], 3);
//! // The first point: X's first move is +, so it is taken to have arrived moving +.
//! assert_eq!(a.iter().map(|a| a.0[0]).collect::<Vec<_>>(), [1, 1, 1, -1]);
//! assert_eq!(a[3].sign(1), 0.0);
//! ```

use crate::chain::MAX_AXES;
use crate::machine::Commands;

/// The smallest change of a command counted as a move (internal units: mm or rad): below the
/// resolution of any file volver reads or writes.
pub const MOVE_TOLERANCE: f64 = 1e-9;

/// The direction of approach of each axis at a point, chain order: +1 (arrived moving in the
/// axis' positive direction), −1 (negative), 0 (unknown: the mean of both directions).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Approach(pub [i8; MAX_AXES]);

impl Approach {
    /// No axis' direction known: every reversal predicted at its mean (zero).
    pub const UNKNOWN: Approach = Approach([0; MAX_AXES]);

    /// Every one of the first `n_axes` axes arriving from `sign` (+1 or −1).
    pub fn all(n_axes: usize, sign: i8) -> Approach {
        let mut a = [0; MAX_AXES];
        a[..n_axes.min(MAX_AXES)].fill(sign.signum());
        Approach(a)
    }

    /// The direction of chain axis `k` as a number: +1.0, −1.0 or 0.0.
    #[inline]
    pub fn sign(&self, k: usize) -> f64 {
        f64::from(self.0[k])
    }

    /// Whether no axis' direction is known.
    pub fn is_unknown(&self) -> bool {
        self.0 == [0; MAX_AXES]
    }

    /// The directions after a move from `from` to `to`: each axis that moves takes the sign of
    /// its move, the others keep theirs.
    pub fn after_move(self, from: &Commands, to: &Commands, n_axes: usize) -> Approach {
        let mut a = self.0;
        for (k, s) in a.iter_mut().enumerate().take(n_axes.min(MAX_AXES)) {
            let d = to.0[k] - from.0[k];
            if d.abs() > MOVE_TOLERANCE {
                *s = if d > 0.0 { 1 } else { -1 };
            }
        }
        Approach(a)
    }

    /// The directions as text, one sign per axis of `letters` (`X+ C- Z?`).
    pub fn describe(&self, letters: &[char]) -> String {
        letters
            .iter()
            .enumerate()
            .map(|(k, l)| {
                let s = match self.0[k] {
                    1 => "+",
                    -1 => "-",
                    _ => "?",
                };
                format!("{l}{s}")
            })
            .collect::<Vec<_>>()
            .join(" ")
    }
}

/// The directions of approach of points visited in `order` (their commands, in measuring order)
/// on a machine of `n_axes` axes: each the sign of every axis' last move before it.
///
/// Before an axis' first move its direction is that of the first move (see the module
/// documentation); an axis that never moves has 0.
pub fn from_order(order: &[Commands], n_axes: usize) -> Vec<Approach> {
    let mut out = Vec::with_capacity(order.len());
    let mut state = Approach::UNKNOWN;
    for (i, c) in order.iter().enumerate() {
        if i > 0 {
            state = state.after_move(&order[i - 1], c, n_axes);
        }
        out.push(state);
    }
    assume_first_moves(&mut out);
    out
}

/// The directions of the points before each axis' first known direction in `approaches`
/// (measuring order) set to that direction: the assumption of [`from_order`] (see the module
/// documentation); an axis with no known direction keeps 0.
pub fn assume_first_moves(approaches: &mut [Approach]) {
    for k in 0..MAX_AXES {
        if let Some(first) = approaches.iter().position(|a| a.0[k] != 0) {
            let s = approaches[first].0[k];
            approaches[..first].iter_mut().for_each(|a| a.0[k] = s);
        }
    }
}

/// A direction of approach read from a file's cell: `+1`, `1`, `+` (forward), `-1`, `-`
/// (reverse), `0` (unknown); `None` for anything else.
///
/// ```
/// use volver_core::approach::parse_sign;
/// assert_eq!(parse_sign(" +1 "), Some(1));
/// assert_eq!(parse_sign("-"), Some(-1));
/// assert_eq!(parse_sign("0"), Some(0));
/// assert_eq!(parse_sign("+0"), Some(0));
/// assert_eq!(parse_sign("up"), None);
/// ```
pub fn parse_sign(text: &str) -> Option<i8> {
    match text.trim() {
        "+1" | "1" | "+" | "1.0" | "+1.0" => Some(1),
        "-1" | "-" | "-1.0" => Some(-1),
        // `+0` as measurement files write an unknown direction (`{:+}`).
        "0" | "+0" | "-0" | "0.0" => Some(0),
        _ => None,
    }
}

/// The column of axis `letter`'s direction of approach in measurement and plan files.
pub fn column_name(letter: char) -> String {
    format!("approach_{letter}")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(x: f64, y: f64) -> Commands {
        Commands([x, y, 0.0, 0.0, 0.0, 0.0])
    }

    #[test]
    fn an_axis_keeps_its_direction_until_it_moves_again() {
        let order = [
            c(0.0, 5.0),
            c(10.0, 5.0),
            c(10.0, 1.0),
            c(10.0, 1.0),
            c(3.0, 2.0),
        ];
        let a = from_order(&order, 2);
        let x: Vec<i8> = a.iter().map(|a| a.0[0]).collect();
        let y: Vec<i8> = a.iter().map(|a| a.0[1]).collect();
        assert_eq!(x, [1, 1, 1, 1, -1]);
        assert_eq!(y, [-1, -1, -1, -1, 1]);
    }

    #[test]
    fn moves_below_the_tolerance_are_no_moves() {
        let a = from_order(&[c(1.0, 0.0), c(1.0 + 1e-12, 0.0)], 2);
        assert_eq!(a, [Approach::UNKNOWN; 2]);
        assert_eq!(Approach::all(2, -3).0, [-1, -1, 0, 0, 0, 0]);
        assert_eq!(Approach::all(2, 1).describe(&['X', 'Z']), "X+ Z+");
    }
}
