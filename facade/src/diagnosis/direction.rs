//! The residuals split by each axis' direction of approach, as the diagnosis shows them
//! ([`volver_core::diagnose::by_direction`]): the evidence of a reversal the model lacks.

use serde::Serialize;
use volver_core::diagnose::{self, DirectionSplit};
use volver_core::problem::Problem;

/// How many standard errors a forward–reverse difference must reach to be shown as a reversal
/// the residuals show: as for a bin of a breakdown ([`super::BIN_ABOVE_NOISE_Z`]).
pub const DIRECTION_Z: f64 = super::BIN_ABOVE_NOISE_Z;

/// The points of one side ([`volver_core::diagnose::SideMean`]).
#[derive(Clone, Debug, Serialize)]
pub struct Side {
    /// Points that arrived from this side.
    pub count: usize,
    /// The common positioning error their measurements show beyond the model (measured −
    /// predicted; µm for a linear axis, µrad for a rotary one).
    pub mean: f64,
    /// Its expanded uncertainty (k = 2), from the points' scatter.
    pub u95: f64,
}

/// One axis' residuals split by direction of approach: the common positioning error the
/// points arriving forward (+) and in reverse (−) show beyond the model, and their difference
/// at the same position, the reversal value the residuals show.
#[derive(Clone, Debug, Serialize)]
pub struct Direction {
    /// The axis.
    pub axis: String,
    /// The unit of every figure: `µm` (a linear axis, along its own direction) or `µrad` (a
    /// rotary one, about its line).
    pub unit: &'static str,
    /// All the points that arrived moving in the axis' positive direction.
    pub forward: Side,
    /// All the points that arrived moving in its negative direction.
    pub reverse: Side,
    /// Forward less reverse at the same position, over the positions reached from both sides:
    /// the reversal value the residuals show, in the sign of the model's `reversal.X.b`
    /// ([`volver_core::diagnose::DirectionSplit::difference`]); without such a position, over
    /// all the points (it then mixes a reversal with the positioning error).
    pub difference: f64,
    /// Its expanded uncertainty (k = 2).
    pub u95: f64,
    /// The difference in standard errors.
    pub z: f64,
    /// `true` when it exceeds [`DIRECTION_Z`] standard errors at positions reached from both
    /// sides: the residuals depend on the direction of approach of this axis.
    pub significant: bool,
    /// The axis' distinct positions in the data.
    pub positions: usize,
    /// Those reached from both sides (only they separate a reversal from the positioning error
    /// by the data alone).
    pub positions_both: usize,
}

impl Direction {
    fn of(problem: &Problem, s: &DirectionSplit) -> Direction {
        let side = |m: &diagnose::SideMean| Side {
            count: m.count,
            mean: m.mean,
            u95: 2.0 * m.standard_error,
        };
        Direction {
            axis: problem.model().machine().axes()[s.axis].axis.to_string(),
            unit: s.unit,
            forward: side(&s.forward),
            reverse: side(&s.reverse),
            difference: s.difference(),
            u95: 2.0 * s.standard_error(),
            z: s.z(),
            significant: s.within.is_some() && s.z().abs() > DIRECTION_Z,
            positions: s.coverage.positions,
            positions_both: s.coverage.positions_both,
        }
    }

    /// The split in words: `X: forward vs reverse differ by 15.81 ± 0.80 µm at the same
    /// position (k = 2; 6 of 8 positions reached from both sides; over all points, forward
    /// +4.16 µm over 522 points, reverse -4.19 µm over 517)`.
    pub fn text(&self) -> String {
        let sides = format!(
            "forward {:+.2} {u} over {} points, reverse {:+.2} {u} over {}",
            self.forward.mean,
            self.forward.count,
            self.reverse.mean,
            self.reverse.count,
            u = self.unit
        );
        if self.positions_both == 0 {
            return format!(
                "{}: {sides}; no position reached from both sides, so their difference ({:.2} ± \
                 {:.2} {}, k = 2) mixes a reversal with the positioning error",
                self.axis, self.difference, self.u95, self.unit
            );
        }
        format!(
            "{}: forward vs reverse differ by {:.2} ± {:.2} {} at the same position (k = 2; {} \
             of {} positions reached from both sides; over all points, {sides})",
            self.axis, self.difference, self.u95, self.unit, self.positions_both, self.positions
        )
    }
}

/// The splits of the fit at `params` with residuals `r`, for every axis reached from both
/// sides (chain order).
pub(super) fn directions(problem: &Problem, params: &[f64], r: &[[f64; 3]]) -> Vec<Direction> {
    diagnose::by_direction(problem, params, r)
        .iter()
        .map(|s| Direction::of(problem, s))
        .collect()
}
