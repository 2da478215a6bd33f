//! Bidirectional plans: every pose measured from both sides of each moving axis, as ISO 230-2
//! measures positioning (its forward ↑ and reverse ↓ approach), so that an axis' reversal value
//! B (`[effects] reversal`) is measured rather than guessed from whatever order the poses take.
//!
//! [`Plan::bidirectional`] measures each visit of a pose twice, back to back: first with every
//! moving axis (one that takes more than one value in the plan) arriving from below (moving in
//! its positive direction, +1), then with every moving axis arriving from above (−1). Each
//! approach starts at the position minus (plus) the [`Overrun`] and ends at the position, so the
//! axis arrives moving in the stated direction whatever it did before (the measuring program
//! writes these moves, [`super::file::gcode`]). Measured back to back, the two measurements of a
//! pair are minutes apart: a drift does not enter their difference, which is B (ISO 230-2's
//! linear cycle, a forward pass through every position then a reverse pass, would separate them
//! by half the test). A pose where an axis is within the overrun of an end of its travel is
//! approached on that axis from the only side the travel allows, both times. The measurements,
//! and the measuring time, double.
//!
//! ```
//! use volver_core::machine::Machine;
//! use volver_core::plan::{Plan, sides::Overrun};
//! let m = Machine::default_xcfz();
//! let plan = Plan::parse_grid(&m, "X=700,C=0:90:90,Z=300").unwrap();
//! let both = plan.bidirectional(&m, &Overrun::default()).unwrap();
//! assert_eq!(both.n_points(), 2 * plan.n_points());
//! let c: Vec<i8> = both.approach.as_ref().unwrap().iter().map(|a| a.0[1]).collect();
//! // C = 0° is the end of its travel [0°, 360°]: from above (−1) both times; X and Z never move.
//! assert_eq!(c, [-1, -1, -1, -1, 1, 1, -1, -1]);
//! assert_eq!(both.approach.as_ref().unwrap()[4].describe(&['X', 'C', 'Z']), "X? C+ Z?");
//! ```

use super::{Plan, Step};
use crate::approach::Approach;
use crate::chain::MAX_AXES;
use crate::error::{Error, Place, Result};
use crate::machine::{Commands, Machine, MachineAxis};

/// The default overrun of a linear axis (mm): a few millimetres, more than any backlash or lost
/// motion of a machine tool's drive, so that the drive is fully turned before the position.
pub const DEFAULT_OVERRUN_MM: f64 = 5.0;

/// The default overrun of a rotary axis (degrees).
pub const DEFAULT_OVERRUN_DEG: f64 = 1.0;

/// The distance an axis travels in the stated direction before it arrives at a measured position
/// (file units: mm for a linear axis, degrees for a rotary one).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Overrun {
    /// A linear axis' overrun (mm, > 0).
    pub linear_mm: f64,
    /// A rotary axis' overrun (degrees, > 0).
    pub rotary_deg: f64,
}

impl Default for Overrun {
    /// [`DEFAULT_OVERRUN_MM`] and [`DEFAULT_OVERRUN_DEG`].
    fn default() -> Self {
        Overrun {
            linear_mm: DEFAULT_OVERRUN_MM,
            rotary_deg: DEFAULT_OVERRUN_DEG,
        }
    }
}

impl Overrun {
    /// Refuses an overrun that is not a positive finite number (the message names the field:
    /// `overrun_mm` or `overrun_deg`).
    pub fn check(&self) -> Result<()> {
        for (field, v, unit) in [
            ("overrun_mm", self.linear_mm, "mm"),
            ("overrun_deg", self.rotary_deg, "deg"),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::input(
                    Place::file("the overrun").at_field(field),
                    format!(
                        "{v:?} {unit}: the distance an axis travels in the stated direction \
                         before a measured position is a positive number"
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The overrun on `ax` in internal units (mm or rad): the overrun of its kind, at most half
    /// its travel (so that every position of the travel has a side to be approached from);
    /// with whether it was clipped.
    ///
    /// ```
    /// use volver_core::machine::Machine;
    /// use volver_core::plan::sides::Overrun;
    /// let m = Machine::default_xcfz();
    /// let (c, clipped) = Overrun::default().on(&m.axes()[1]);
    /// assert_eq!((c, clipped), (1f64.to_radians(), false));
    /// let wide = Overrun { linear_mm: 1000.0, rotary_deg: 1.0 };
    /// assert_eq!(wide.on(&m.axes()[0]), (700.0, true)); // X travels 1400 mm
    /// ```
    pub fn on(&self, ax: &MachineAxis) -> (f64, bool) {
        let o = if ax.axis.is_rotary() {
            self.rotary_deg.to_radians()
        } else {
            self.linear_mm
        };
        let half = 0.5 * (ax.max - ax.min).abs();
        if o > half { (half, true) } else { (o, false) }
    }

    /// The overrun of every axis of `machine` in chain order (internal units, [`Overrun::on`]).
    pub fn per_axis(&self, machine: &Machine) -> [f64; MAX_AXES] {
        let mut out = [0.0; MAX_AXES];
        for (o, ax) in out.iter_mut().zip(machine.axes()) {
            *o = self.on(ax).0;
        }
        out
    }
}

/// Whether `ax` can arrive at `value` moving in direction `sign` (±1) over `overrun` (internal
/// units) without leaving its travel: the approach starts at `value − sign · overrun`.
pub fn fits(ax: &MachineAxis, value: f64, sign: i8, overrun: f64) -> bool {
    let start = value - f64::from(sign) * overrun;
    let tol = 1e-9 * (ax.max - ax.min).abs().max(1.0);
    start >= ax.min - tol && start <= ax.max + tol
}

/// The axes (chain order) that take more than one value over `positions`: the moving axes
/// a bidirectional plan approaches from both sides.
pub fn moving_axes(machine: &Machine, positions: &[Commands]) -> [bool; MAX_AXES] {
    let mut out = [false; MAX_AXES];
    if let Some(first) = positions.first() {
        for (k, o) in out.iter_mut().enumerate().take(machine.axes().len()) {
            *o = positions
                .iter()
                .any(|p| (p.0[k] - first.0[k]).abs() > crate::approach::MOVE_TOLERANCE);
        }
    }
    out
}

/// The two directions `pose` is measured with on the `moving` axes: first from below (+1) where
/// the travel leaves room for the overrun below the position, else from above; then from above
/// (−1) where it leaves room above, else from below. Other axes 0 (no approach stated).
pub fn sides(
    machine: &Machine,
    pose: &Commands,
    moving: &[bool; MAX_AXES],
    overrun: &[f64; MAX_AXES],
) -> [Approach; 2] {
    let mut out = [Approach::UNKNOWN; 2];
    for (k, ax) in machine.axes().iter().enumerate() {
        if !moving[k] {
            continue;
        }
        let v = pose.0[k];
        out[0].0[k] = if fits(ax, v, 1, overrun[k]) { 1 } else { -1 };
        out[1].0[k] = if fits(ax, v, -1, overrun[k]) { -1 } else { 1 };
    }
    out
}

/// The runs of `steps` at one pose, each reflector once per run: (first step, end).
fn runs(steps: &[Step]) -> Vec<(usize, usize)> {
    let mut out: Vec<(usize, usize)> = Vec::new();
    for (i, s) in steps.iter().enumerate() {
        match out.last_mut() {
            Some((a, b))
                if steps[*a].position == s.position
                    && !steps[*a..*b].iter().any(|t| t.reflector == s.reflector) =>
            {
                *b = i + 1
            }
            _ => out.push((i, i + 1)),
        }
    }
    out
}

impl Plan {
    /// The plan measured from both sides (see the module's documentation): each visit of a pose
    /// (its run of reflectors) measured first from below on every moving axis, then from
    /// above, the directions stated ([`Plan::approach`]). Refused when the plan states its
    /// directions already, when no axis moves, or when the overrun is not a positive number.
    pub fn bidirectional(&self, machine: &Machine, overrun: &Overrun) -> Result<Plan> {
        overrun.check()?;
        let place = || Place::file("plan").at_field("approach");
        if self.approach.is_some() {
            return Err(Error::input(
                place(),
                format!(
                    "plan {} states its directions of approach already: it is measured as it \
                     says",
                    self.name
                ),
            ));
        }
        let moving = moving_axes(machine, &self.positions);
        if !moving.iter().any(|&m| m) {
            return Err(Error::input(
                place(),
                format!(
                    "no axis moves in plan {}: there is no side to approach a position from",
                    self.name
                ),
            ));
        }
        let per_axis = overrun.per_axis(machine);
        let steps = self.steps();
        let mut sequence = Vec::with_capacity(2 * steps.len());
        let mut approach = Vec::with_capacity(2 * steps.len());
        for (a, b) in runs(&steps) {
            let both = sides(
                machine,
                &self.positions[steps[a].position],
                &moving,
                &per_axis,
            );
            for side in both {
                sequence.extend_from_slice(&steps[a..b]);
                approach.extend(std::iter::repeat_n(side, b - a));
            }
        }
        Ok(Plan {
            name: format!("{} (bidirectional)", self.name),
            positions: self.positions.clone(),
            reflectors: self.reflectors.clone(),
            sequence: Some(sequence),
            approach: Some(approach),
        })
    }
}

/// For each axis of `machine` (chain order), the poses of `plan` approached from one side only
/// on it: a bidirectional plan's poses within the overrun of an end of the axis' travel (0 for
/// an axis that never moves).
pub fn one_sided(plan: &Plan, machine: &Machine, overrun: &Overrun) -> Vec<usize> {
    let moving = moving_axes(machine, &plan.positions);
    let per_axis = overrun.per_axis(machine);
    machine
        .axes()
        .iter()
        .enumerate()
        .map(|(k, ax)| {
            plan.positions
                .iter()
                .filter(|p| {
                    moving[k]
                        && !(fits(ax, p.0[k], 1, per_axis[k]) && fits(ax, p.0[k], -1, per_axis[k]))
                })
                .count()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_pose_is_measured_from_both_sides_of_every_moving_axis() {
        let m = Machine::default_xcfz();
        let plan = Plan::preset(&m, "test3").unwrap().shuffled(4);
        let both = plan.bidirectional(&m, &Overrun::default()).unwrap();
        assert_eq!(both.n_points(), 2 * plan.n_points());
        let steps = both.steps();
        let a = both.approaches(1);
        // Every step of the plan, twice: from each side where the travel allows.
        let o = Overrun::default().per_axis(&m);
        for (s, dir) in steps.iter().zip(&a) {
            let p = plan.positions[s.position];
            for (k, ax) in m.axes().iter().enumerate() {
                assert!(dir.0[k] != 0, "axis {k} moves in test 3");
                assert!(fits(ax, p.0[k], dir.0[k], o[k]));
            }
        }
        for (k, ax) in m.axes().iter().enumerate() {
            let mut seen = std::collections::HashMap::new();
            for (s, dir) in steps.iter().zip(&a) {
                seen.entry((s.position, s.reflector))
                    .or_insert_with(Vec::new)
                    .push(dir.0[k]);
            }
            for ((pos, _), signs) in seen {
                let v = plan.positions[pos].0[k];
                let both_fit = fits(ax, v, 1, o[k]) && fits(ax, v, -1, o[k]);
                let has = |s: i8| signs.contains(&s);
                assert_eq!(has(1) && has(-1), both_fit, "axis {k} at {v}: {signs:?}");
            }
        }
        // X = 0 and 1400, C = 0 and 360, Z = 0 and 600 are travel ends: a sixth of X's poses
        // and so on.
        let ends = one_sided(&both, &m, &Overrun::default());
        let n = plan.positions.len();
        assert_eq!(ends, [2 * n / 6, 2 * n / 9, 2 * n / 4]);
        assert!(both.bidirectional(&m, &Overrun::default()).is_err());
    }

    #[test]
    fn bad_overruns_and_plans_without_motion_are_refused() {
        let m = Machine::default_xcfz();
        let plan = Plan::parse_grid(&m, "X=0:1400:700,C=0,Z=0").unwrap();
        let bad = Overrun {
            linear_mm: -1.0,
            rotary_deg: 1.0,
        };
        let e = plan.bidirectional(&m, &bad).unwrap_err().to_string();
        assert!(e.contains("overrun_mm") && e.contains("-1.0 mm"), "{e}");
        let still = Plan::parse_grid(&m, "X=700,C=0,Z=0").unwrap();
        let e = still
            .bidirectional(&m, &Overrun::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("no axis moves"), "{e}");
        // Runs of reflectors at one pose are kept: R1 R2 from below, then R1 R2 from above.
        let both = plan.bidirectional(&m, &Overrun::default()).unwrap();
        let s = both.steps();
        assert_eq!(
            s[..4].iter().map(|s| s.reflector).collect::<Vec<_>>(),
            [0, 1, 0, 1]
        );
    }
}
