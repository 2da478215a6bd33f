//! Compensation: the inverse of the forward model.
//!
//! A machine with identified errors puts its tool somewhere else than commanded. Compensation
//! asks the opposite question: which command puts the tool point where the *nominal* machine
//! would put it for the programmed command? With `T(q, p)` the tool point relative to the
//! workpiece ([`Model::tool_point`]) at commands `q` and errors `p`, the compensated command
//! `q*` solves
//!
//! ```text
//! T(q*, p) = T(q_programmed, 0)
//! ```
//!
//! by Newton's method from `q = q_programmed`, with the exact 3 × m Jacobian `∂T/∂q` from dual
//! numbers over the commands (the error functions are differentiated along their axes too).
//! Three equations fix three axes: by default the linear axes when the machine has three of
//! them (rotary axes keep their programmed angle: the tool *position* is compensated, not its
//! orientation), otherwise every axis. [`Compensator::holding`] picks other axes. With fewer
//! than three free axes the command is a least-squares fit and the deviation says what is left.
//!
//! **Five axes: the tool's direction too.** [`Compensator::with_orientation`] steers the tool
//! point and the direction of the tool's axis with every axis of a five-axis machine (three
//! equations for the point, two for the direction: `d(q*, p) = d(q_programmed, 0)`), from the
//! programmed command (so the nearest of the two solution branches). Each step meets the
//! point's linearised equations and minimises the direction's residual over what they leave
//! free. Near the singularity — the direction hardly turning with one rotary axis (the tilt
//! axis at zero) — that axis keeps its programmed angle instead of swinging up to half a turn
//! for microradians; the point is still met, and what is left of the direction is reported
//! ([`OrientationResult`]).
//!
//! **Directions of approach.** An axis with a reversal (ISO 230-2's B, `[effects] reversal`)
//! puts the tool on one side or the other by the direction it arrives from: a compensator
//! [`in_state`](Compensator::in_state) solves `T(q*, p, s) = T(q_programmed, 0)` with each
//! axis' direction `s` ([`crate::model::PointState`]); by default every direction is unknown
//! and the reversal is at its mean. Along a path (a program, a point list in its order),
//! [`Travel`] settles each axis' direction from the commands the control executes, point by
//! point, and compensates each point in it (its module states the rule).
//!
//! Every compensated command is verified: the tool point it gives through the forward model
//! (an independent `f64` evaluation) is compared with the target, and the deviation is
//! reported (and the direction's angle from its target). Units: mm and rad.
//!
//! ```
//! use volver_core::compensate::Compensator;
//! use volver_core::model::Model;
//! let model = Model::default_xcfz();
//! let mut p = model.initial_params();
//! p[model.param_index("EXX.c1").unwrap()] = 0.05; // 50 µm of positioning error at the end of X
//! let comp = Compensator::new(&model, &p, [0.0; 3]).unwrap();
//! let programmed = model.machine().commands_from_file_units(&[1400.0, 30.0, 300.0]);
//! let c = comp.compensate(&programmed).unwrap();
//! assert!(c.deviation_mm < 1e-9);
//! assert!((c.commands.0[0] - 1400.0).abs() > 0.01); // X moved to cancel EXX
//! ```

use crate::chain::MAX_AXES;
use crate::error::{Error, Result};
use crate::iso::Axis;
use crate::kinematics::{PointErrors, tool_in_workpiece};
use crate::machine::Commands;
use crate::model::{Model, PointState};
use num_dual::{DualNum, DualSVec64};

mod direction;
mod points;
mod step;
pub use direction::{PathPoint, REVERSAL_TOLERANCE_UM, Travel, reversal_axes};
pub use points::{ListedPoint, MAX_AXIS_VALUE, read_points, written};
pub use step::solve_dense;
use step::{ConstrainedStep, solve_step};

/// Deviation below which Newton's iteration stops (mm).
pub const NEWTON_TOLERANCE_MM: f64 = 1e-11;

/// Most Newton steps per point.
pub const MAX_NEWTON_STEPS: usize = 50;

/// The inverse model of one machine with one set of identified errors.
#[derive(Clone, Debug)]
pub struct Compensator<'a> {
    model: &'a Model,
    params: &'a [f64],
    tool: [f64; 3],
    /// Chain positions of the axes Newton moves.
    free: Vec<usize>,
    /// The tool's axis (unit, frame of the last tool-side axis) when its direction is
    /// compensated too ([`Compensator::with_orientation`]).
    axis: Option<[f64; 3]>,
    /// The state the machine is in ([`Compensator::in_state`]): each axis' direction of
    /// approach (the reversal's side) and the time (the test's start by default).
    state: PointState,
}

/// One compensated command.
#[derive(Clone, Debug, PartialEq)]
pub struct Compensated {
    /// The compensated command (internal units: mm, rad; chain order).
    pub commands: Commands,
    /// The target: the nominal machine's tool point at the programmed command (mm, workpiece
    /// frame).
    pub target: [f64; 3],
    /// How far the tool point of the compensated command is from the target, through the
    /// forward model (mm).
    pub deviation_mm: f64,
    /// How far the uncompensated machine's tool point is from the target (mm): what
    /// compensation removes.
    pub error_mm: f64,
    /// Newton steps taken.
    pub steps: usize,
    /// Axes (chain positions) whose compensated command leaves the travel range: a linear axis
    /// or a rotary axis of limited range beyond its range, a full-turn rotary axis more than a
    /// turn beyond it.
    pub outside_travel: Vec<usize>,
    /// With the tool's orientation compensated ([`Compensator::with_orientation`]), its
    /// direction: the target (the nominal machine's tool direction at the programmed command,
    /// unit, workpiece frame), the angle between the compensated command's direction and it
    /// through the forward model (rad), and the uncompensated machine's angle.
    pub orientation: Option<OrientationResult>,
}

/// What compensation did to the tool's direction (see [`Compensated::orientation`]).
#[derive(Clone, Debug, PartialEq)]
pub struct OrientationResult {
    /// The nominal machine's tool direction at the programmed command (unit, workpiece frame).
    pub target: [f64; 3],
    /// The angle between the compensated command's tool direction and the target, through the
    /// forward model (rad).
    pub deviation_rad: f64,
    /// The angle of the uncompensated machine's tool direction from the target (rad).
    pub error_rad: f64,
    /// How much the tool's direction turns per radian of the rotary axis that turns it least
    /// (the smallest singular value of the direction's Jacobian over the free rotary axes, at
    /// the compensated command): `sin` of the tilt on a machine whose two rotary axes are
    /// perpendicular. Near zero the rotary axes are nearly parallel (the tilt axis near zero):
    /// meeting the direction exactly would need a large turn of the other rotary axis, which
    /// then keeps its programmed angle while the tilt axis corrects what it can.
    pub sensitivity: f64,
    /// `sensitivity` below `sin` [`SINGULAR_TILT_DEG`]: the command passes near the singularity.
    pub near_singularity: bool,
}

/// A compensated command whose direction turns by less than `sin` of this (degrees) per radian of
/// a rotary axis is reported near the singularity ([`OrientationResult::near_singularity`]).
pub const SINGULAR_TILT_DEG: f64 = 1.0;

/// The scale of the direction's residuals against the point's (mm per rad: 1 µrad as 1 µm), so
/// that their rows of the Jacobian are of a size. The solution does not depend on it: the
/// point's equations are met exactly and the direction's residual is minimised over what they
/// leave free.
pub const DIRECTION_LEVER_MM: f64 = 1000.0;

/// Newton's iteration stops once the direction is within this angle (rad) of its target (and
/// the point within [`NEWTON_TOLERANCE_MM`]).
pub const NEWTON_TOLERANCE_RAD: f64 = 1e-12;

impl<'a> Compensator<'a> {
    /// The inverse model of `model` with errors `params`, steering the tool point `tool` (mm, in
    /// the frame of the last tool-side axis, like a reflector offset). The free axes are the
    /// linear ones when the machine has exactly three, otherwise every axis (at most three).
    pub fn new(model: &'a Model, params: &'a [f64], tool: [f64; 3]) -> Result<Compensator<'a>> {
        let axes = model.machine().axes();
        let linear = axes.iter().filter(|a| !a.axis.is_rotary()).count();
        let held: Vec<Axis> = if linear == 3 {
            axes.iter()
                .filter(|a| a.axis.is_rotary())
                .map(|a| a.axis)
                .collect()
        } else {
            Vec::new()
        };
        Compensator::holding(model, params, tool, &held)
    }

    /// [`Compensator::new`] with the axes `held` at their programmed values and every other
    /// axis free. More than three free axes leave the inverse undetermined and are refused.
    pub fn holding(
        model: &'a Model,
        params: &'a [f64],
        tool: [f64; 3],
        held: &[Axis],
    ) -> Result<Compensator<'a>> {
        check_params(model, params)?;
        let m = model.machine();
        for h in held {
            if m.axis(*h).is_none() {
                return Err(Error::MachineMismatch {
                    message: format!(
                        "axis {h} is held but the machine ({}) has no such axis",
                        m.chain()
                    ),
                });
            }
        }
        let free: Vec<usize> = (0..m.axes().len())
            .filter(|&k| !held.contains(&m.axes()[k].axis))
            .collect();
        if free.len() > 3 {
            return Err(Error::InvalidOption {
                name: "hold",
                message: format!(
                    "{} free axes for the three coordinates of the tool point: hold {} of them",
                    free.len(),
                    free.len() - 3
                ),
            });
        }
        if free.is_empty() {
            return Err(Error::InvalidOption {
                name: "hold",
                message: "every axis is held: nothing left to compensate with".into(),
            });
        }
        Ok(Compensator {
            model,
            params,
            tool,
            free,
            axis: None,
            state: PointState::default(),
        })
    }

    /// The inverse model steering the tool point `tool` *and* the tool's direction `axis` (both
    /// in the frame of the last tool-side axis, like a reflector offset; `axis` is normalised):
    /// every axis of a five-axis machine is solved so that the point and the direction match
    /// the nominal machine's (three equations for the point, two for the direction). Refused
    /// unless the machine has five axes, two of them rotary, or when `axis` is not a direction.
    ///
    /// ```
    /// use volver_core::compensate::Compensator;
    /// let model = volver_core::presets::named("table-table").unwrap().model().unwrap();
    /// let mut p = model.initial_params();
    /// p[model.param_index("B0A").unwrap()] = 20e-6; // A's line turned 20 µrad about y
    /// p[model.param_index("X0C").unwrap()] = 0.015; // C's line 15 µm off in x
    /// let comp = Compensator::with_orientation(&model, &p, [0.0, 0.0, -150.0], [0.0, 0.0, -1.0]).unwrap();
    /// // Chain order A, C, X, Y, Z (degrees, mm).
    /// let programmed = model.machine().commands_from_file_units(&[30.0, 45.0, 100.0, -50.0, 200.0]);
    /// let c = comp.compensate(&programmed).unwrap();
    /// let o = c.orientation.unwrap();
    /// assert!(c.deviation_mm < 1e-9 && o.deviation_rad < 1e-9);
    /// assert!(c.error_mm > 0.01 && o.error_rad > 1e-6 && !o.near_singularity);
    /// assert!((o.sensitivity - 0.5).abs() < 1e-6); // sin 30°: A tilts C's line by 30°
    /// ```
    pub fn with_orientation(
        model: &'a Model,
        params: &'a [f64],
        tool: [f64; 3],
        axis: [f64; 3],
    ) -> Result<Compensator<'a>> {
        check_params(model, params)?;
        let m = model.machine();
        if !is_five_axis(m) {
            let rotary = m.axes().iter().filter(|a| a.axis.is_rotary()).count();
            return Err(Error::MachineMismatch {
                message: format!(
                    "compensating the tool's orientation needs a five-axis machine (three linear \
                     and two rotary axes); {} has {} axes, {rotary} rotary: compensate the tool \
                     point alone",
                    m.chain(),
                    m.axes().len()
                ),
            });
        }
        let len = crate::problem::norm(axis);
        if !(len.is_finite() && len > 1e-9) {
            return Err(Error::InvalidOption {
                name: "tool_axis",
                message: format!(
                    "the tool's axis {axis:?} is not a direction (a non-zero vector, in the frame \
                     of the last tool-side axis)"
                ),
            });
        }
        Ok(Compensator {
            model,
            params,
            tool,
            free: (0..5).collect(),
            axis: Some(axis.map(|v| v / len)),
            state: PointState::default(),
        })
    }

    /// The same inverse model with the machine in `state`: each axis arriving from the side
    /// `state.approach` gives, so that its reversal is on that side (the mean of both sides
    /// for an axis whose direction is unknown, as [`Model::tool_point_in`]). Every command it
    /// solves and every point it gives ([`Compensator::actual_point`], the deviations) is in
    /// that state; the nominal machine's point is the same in every state.
    ///
    /// ```
    /// use volver_core::approach::Approach;
    /// use volver_core::compensate::Compensator;
    /// use volver_core::model::{Model, PointState};
    /// let text = "[effects]\nreversal = [\"X\"]";
    /// let model = Model::from_toml_str(volver_core::machine::Machine::default_xcfz(), text, "m.toml").unwrap();
    /// let mut p = model.initial_params();
    /// p[model.param_index("reversal.X.b").unwrap()] = -0.015; // B = −15 µm: lost motion
    /// let comp = Compensator::new(&model, &p, [0.0; 3]).unwrap();
    /// let q = model.machine().commands_from_file_units(&[700.0, 0.0, 300.0]);
    /// let at = |s: i8| PointState { t_s: 0.0, approach: Approach::all(3, s) };
    /// let up = comp.in_state(at(1)).compensate(&q).unwrap().commands.0[0];
    /// let down = comp.in_state(at(-1)).compensate(&q).unwrap().commands.0[0];
    /// // Arriving forward the tool stops |B|/2 short of its target (relative to the workpiece
    /// // X carries): the command is |B|/2 long (and |B|/2 short in reverse).
    /// assert!((up - (700.0 + 0.0075)).abs() < 1e-12 && (down - (700.0 - 0.0075)).abs() < 1e-12);
    /// ```
    pub fn in_state(&self, state: PointState) -> Compensator<'a> {
        Compensator {
            state,
            ..self.clone()
        }
    }

    /// The state it compensates in ([`Compensator::in_state`]).
    pub fn state(&self) -> PointState {
        self.state
    }

    /// The axes Newton moves (chain positions).
    pub fn free_axes(&self) -> &[usize] {
        &self.free
    }

    /// The nominal machine's tool point at `commands` (mm, workpiece frame).
    pub fn nominal_point(&self, commands: &Commands) -> [f64; 3] {
        tool_in_workpiece(
            self.model.machine(),
            &commands.0,
            &self.tool,
            &PointErrors::<f64>::zero(),
        )
    }

    /// The real machine's tool point at `commands`, with the identified errors, in its state
    /// ([`Compensator::in_state`]) (mm).
    pub fn actual_point(&self, commands: &Commands) -> [f64; 3] {
        self.model
            .tool_point_in(&commands.0, &self.tool, self.state, self.params)
    }

    /// The model whose errors it compensates.
    pub fn model(&self) -> &Model {
        self.model
    }

    /// The tool point it compensates (mm, frame of the last tool-side axis).
    pub fn tool(&self) -> [f64; 3] {
        self.tool
    }

    /// The tool's axis when its direction is compensated (unit, frame of the last tool-side
    /// axis).
    pub fn tool_axis(&self) -> Option<[f64; 3]> {
        self.axis
    }

    /// The nominal machine's tool direction at `commands` (unit, workpiece frame); `None` when
    /// the direction is not compensated.
    pub fn nominal_direction(&self, commands: &Commands) -> Option<[f64; 3]> {
        let zero = PointErrors::<f64>::zero();
        let m = self.model.machine();
        self.axis.map(|a| {
            let tip = tool_in_workpiece(m, &commands.0, &self.tool, &zero);
            let back = tool_in_workpiece(m, &commands.0, &self.behind(a), &zero);
            unit([tip[0] - back[0], tip[1] - back[1], tip[2] - back[2]])
        })
    }

    /// The real machine's tool direction at `commands`, with the identified errors (unit,
    /// workpiece frame); `None` when the direction is not compensated.
    pub fn actual_direction(&self, commands: &Commands) -> Option<[f64; 3]> {
        self.axis.map(|a| {
            let tip = self.actual_point(commands);
            let back =
                self.model
                    .tool_point_in(&commands.0, &self.behind(a), self.state, self.params);
            unit([tip[0] - back[0], tip[1] - back[1], tip[2] - back[2]])
        })
    }

    /// The angle (rad) between the real machine's tool direction at `commands` and `target`,
    /// through an independent `f64` evaluation of the forward model: the verification of a
    /// command's orientation. Zero when the direction is not compensated.
    pub fn direction_deviation_rad(&self, commands: &Commands, target: [f64; 3]) -> f64 {
        self.actual_direction(commands)
            .map_or(0.0, |d| angle_between(d, target))
    }

    /// The point one unit behind the tool point along the tool's axis `a`.
    fn behind(&self, a: [f64; 3]) -> [f64; 3] {
        [
            self.tool[0] - a[0],
            self.tool[1] - a[1],
            self.tool[2] - a[2],
        ]
    }

    /// The command that puts the tool where the nominal machine puts it for `programmed` (and
    /// turns it the way the nominal machine turns it, with [`Compensator::with_orientation`]).
    ///
    /// Newton's iteration starts at the programmed command, so it finds the solution nearest it
    /// (the branch the program chose; a five-axis direction has a second one, the tilt
    /// mirrored and the other rotary axis half a turn away). It fails (naming the command) only
    /// when it meets a non-finite value or a singular Jacobian (for the tool point alone; where
    /// the direction cannot be met, at the singularity, the nearest command is kept and
    /// [`OrientationResult::deviation_rad`] says what is left); a deviation that stays above the
    /// tolerance is reported for the caller to judge.
    pub fn compensate(&self, programmed: &Commands) -> Result<Compensated> {
        let target = self.nominal_point(programmed);
        let target_dir = self.nominal_direction(programmed);
        let (q, steps, error_mm, sensitivity) = match target_dir {
            Some(t) => self.solve_oriented(programmed, target, t)?,
            None => {
                let (q, steps, error_mm) = self.solve_point(programmed, target)?;
                (q, steps, error_mm, f64::NAN)
            }
        };
        let deviation_mm = self.deviation_mm(&q, target);
        let orientation = target_dir.map(|t| OrientationResult {
            target: t,
            deviation_rad: self.direction_deviation_rad(&q, t),
            error_rad: self.direction_deviation_rad(programmed, t),
            sensitivity,
            near_singularity: sensitivity < SINGULAR_TILT_DEG.to_radians().sin(),
        });
        let axes = self.model.machine().axes();
        // Rotary axes too: a trunnion beyond its range, or a turntable commanded more than a
        // turn beyond its (a full-turn axis at −0.001° is at 359.999°).
        let outside_travel = (0..axes.len())
            .filter(|&k| {
                let a = &axes[k];
                let full_turn =
                    a.axis.is_rotary() && a.max - a.min >= std::f64::consts::TAU * (1.0 - 1e-9);
                let slack = if full_turn {
                    std::f64::consts::TAU
                } else {
                    1e-9 * (a.max - a.min).abs().max(1.0)
                };
                q.0[k] < a.min - slack || q.0[k] > a.max + slack
            })
            .collect();
        Ok(Compensated {
            commands: q,
            target,
            deviation_mm,
            error_mm,
            steps,
            outside_travel,
            orientation,
        })
    }

    /// How far the real machine's tool point at `commands` is from `target` (mm), through an
    /// independent `f64` evaluation of the forward model: the verification of a command.
    pub fn deviation_mm(&self, commands: &Commands, target: [f64; 3]) -> f64 {
        let x = self.actual_point(commands);
        crate::problem::norm([x[0] - target[0], x[1] - target[1], x[2] - target[2]])
    }

    /// Newton's iteration for the tool point alone from `programmed`: the command, the steps
    /// taken and the uncompensated error (mm).
    fn solve_point(
        &self,
        programmed: &Commands,
        target: [f64; 3],
    ) -> Result<(Commands, usize, f64)> {
        let mut q = *programmed;
        // The first iterate's point is the uncompensated machine's (the duals' real parts are
        // the f64 evaluation).
        let mut error_mm = None;
        let mut steps = 0;
        let mut best = (f64::INFINITY, q);
        while steps < MAX_NEWTON_STEPS {
            let (r, jac) = self.residual_and_jacobian(&q, target, None);
            let d = crate::problem::norm([r[0], r[1], r[2]]);
            if !d.is_finite() {
                return Err(Error::NonFinite {
                    message: format!(
                        "compensation met a non-finite tool point at command {:?}",
                        q.0
                    ),
                });
            }
            error_mm.get_or_insert(d);
            if d < best.0 {
                best = (d, q);
            }
            if d <= NEWTON_TOLERANCE_MM {
                break;
            }
            let step =
                solve_step(&jac, &r[..3], self.free.len()).ok_or_else(|| Error::Singular {
                    message: format!(
                        "compensation: the Jacobian of the tool point is singular at command {:?}",
                        q.0
                    ),
                })?;
            for (i, &k) in self.free.iter().enumerate() {
                q.0[k] -= step[i];
            }
            steps += 1;
            // A least-squares fit (fewer than three free axes) stops when the step vanishes.
            let size: f64 = step.iter().map(|s| s * s).sum::<f64>().sqrt();
            if size <= 1e-15 * (1.0 + q.0.iter().map(|v| v.abs()).fold(0.0, f64::max)) {
                break;
            }
        }
        Ok((best.1, steps, error_mm.unwrap_or(f64::NAN)))
    }

    /// The tool point and direction from `programmed` by Gauss–Newton steps that meet the
    /// point's linearised equations and minimise the direction's residual over what they leave
    /// free, each accepted only when it brings the point closer (once it is there: the
    /// direction), else with the direction's part damped in Marquardt's manner until it does
    /// ([`Compensator::damped_step`]). Near the singularity (the direction's sensitivity to a
    /// rotary axis below `sin` [`SINGULAR_TILT_DEG`] at the programmed command) the exact
    /// solution needs a large turn of that rotary axis (up to half a turn of a table to tilt
    /// the tool by microradians): that axis keeps its programmed value, the other four meet
    /// the point exactly and the direction as closely as the tilt axis alone can. The command,
    /// the steps taken, the uncompensated error (mm) and the direction's sensitivity at the
    /// command ([`OrientationResult::sensitivity`]).
    fn solve_oriented(
        &self,
        programmed: &Commands,
        target: [f64; 3],
        t: [f64; 3],
    ) -> Result<(Commands, usize, f64, f64)> {
        let m = self.free.len();
        let (r, jac) = self.residual_and_jacobian(programmed, target, Some(t));
        let mut at = Oriented {
            q: *programmed,
            cost: oriented_cost(&r),
            r,
            jac,
        };
        if !(at.cost.0.is_finite() && at.cost.1.is_finite()) {
            return Err(Error::NonFinite {
                message: format!(
                    "compensation met a non-finite tool point at command {:?}",
                    at.q.0
                ),
            });
        }
        let error_mm = crate::problem::norm([r[0], r[1], r[2]]);
        let held = self.held_rotary(&at.jac);
        let active: Vec<usize> = (0..m).filter(|&i| Some(i) != held).collect();
        let mut lambda = 0.0_f64;
        let mut steps = 0;
        while steps < MAX_NEWTON_STEPS {
            let r = &at.r;
            let d = crate::problem::norm([r[0], r[1], r[2]]);
            let d_dir = crate::problem::norm([r[3], r[4], r[5]]) / DIRECTION_LEVER_MM;
            if d <= NEWTON_TOLERANCE_MM && d_dir <= NEWTON_TOLERANCE_RAD {
                break;
            }
            let Some(split) = ConstrainedStep::new(&at.jac, r, m, &active) else {
                break;
            };
            let Some(next) = self.damped_step(&mut at, &split, lambda, (target, t)) else {
                break;
            };
            lambda = next;
            steps += 1;
        }
        Ok((at.q, steps, error_mm, self.rotary_sensitivity(&at.jac)))
    }

    /// Near the singularity (the direction's sensitivity to the rotary axes below `sin`
    /// [`SINGULAR_TILT_DEG`]), the free rotary axis (its index among the free axes) the
    /// direction depends on least, which the oriented iteration holds; `None` elsewhere.
    fn held_rotary(&self, jac: &[f64]) -> Option<usize> {
        let m = self.free.len();
        (self.rotary_sensitivity(jac) < SINGULAR_TILT_DEG.to_radians().sin())
            .then(|| {
                let axes = self.model.machine().axes();
                (0..m)
                    .filter(|&i| axes[self.free[i]].axis.is_rotary())
                    .min_by(|&i, &j| {
                        let col = |i: usize| (3..6).map(|c| jac[c * m + i].powi(2)).sum::<f64>();
                        col(i).total_cmp(&col(j))
                    })
            })
            .flatten()
    }

    /// One step of the oriented iteration from `at` (replaced by the new command when the step
    /// is accepted) with `split`'s direction part damped from `lambda` up, ten times more per
    /// try, until the step is better ([`oriented_better`]); the damping to start the next step
    /// from, or `None` when even a damping of 1e12 does not improve (only the cost's rounding is
    /// left). `(target, t)`: the tool point (mm) and direction to meet.
    fn damped_step(
        &self,
        at: &mut Oriented,
        split: &ConstrainedStep,
        lambda: f64,
        (target, t): ([f64; 3], [f64; 3]),
    ) -> Option<f64> {
        let mut trial = lambda;
        loop {
            if let Some(step) = split.step(trial) {
                let mut q = at.q;
                for (i, &k) in self.free.iter().enumerate() {
                    q.0[k] -= step[i];
                }
                let (r, jac) = self.residual_and_jacobian(&q, target, Some(t));
                let cost = oriented_cost(&r);
                if oriented_better(cost, at.cost) {
                    *at = Oriented { q, r, jac, cost };
                    return Some(if trial < 1e-9 { 0.0 } else { trial / 10.0 });
                }
            }
            // No decrease (or a singular system): more damping of the direction's part,
            // down to where the cost's rounding is all that is left.
            trial = if trial == 0.0 { 1e-12 } else { trial * 10.0 };
            if trial > 1e12 {
                return None;
            }
        }
    }

    /// The residuals at `q` — the tool point's offset from `target` (mm) and, with a target
    /// direction, the direction's offset from it times [`DIRECTION_LEVER_MM`] — and their exact
    /// Jacobian with respect to the free axes (rows × m, row-major; 3 or 6 rows), from dual
    /// numbers over the commands.
    fn residual_and_jacobian(
        &self,
        q: &Commands,
        target: [f64; 3],
        target_dir: Option<[f64; 3]>,
    ) -> ([f64; 6], Vec<f64>) {
        type D = DualSVec64<MAX_AXES>;
        let m = self.free.len();
        let mut u = q.0.map(D::from_re);
        for (i, &k) in self.free.iter().enumerate() {
            u[k] = D::from_re(q.0[k]).derivative(i);
        }
        let tip = self
            .model
            .tool_point_in(&u, &self.tool, self.state, self.params);
        let mut rows: Vec<D> = (0..3).map(|c| tip[c] - target[c]).collect();
        if let (Some(a), Some(t)) = (self.axis, target_dir) {
            let back = self
                .model
                .tool_point_in(&u, &self.behind(a), self.state, self.params);
            let d = [tip[0] - back[0], tip[1] - back[1], tip[2] - back[2]];
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            rows.extend((0..3).map(|c| (d[c] / len - t[c]) * DIRECTION_LEVER_MM));
        }
        let mut r = [0.0; 6];
        let mut jac = vec![0.0; rows.len() * m];
        for (c, v) in rows.iter().enumerate() {
            r[c] = v.re;
            if let Some(eps) = &v.eps.0 {
                jac[c * m..(c + 1) * m].copy_from_slice(&eps.as_slice()[..m]);
            }
        }
        (r, jac)
    }

    /// The smallest singular value of the direction's Jacobian (rows 3–5 of `jac`, unweighted)
    /// over the free rotary axes: how much the tool turns per radian of the rotary axis that
    /// turns it least.
    fn rotary_sensitivity(&self, jac: &[f64]) -> f64 {
        let m = self.free.len();
        let axes = self.model.machine().axes();
        let rot: Vec<usize> = (0..m)
            .filter(|&i| axes[self.free[i]].axis.is_rotary())
            .collect();
        if rot.len() != 2 || jac.len() < 6 * m {
            return f64::NAN;
        }
        let col = |i: usize, c: usize| jac[(3 + c) * m + rot[i]] / DIRECTION_LEVER_MM;
        let g = |i: usize, j: usize| (0..3).map(|c| col(i, c) * col(j, c)).sum::<f64>();
        let (a, b, d) = (g(0, 0), g(0, 1), g(1, 1));
        let mean = 0.5 * (a + d);
        let disc = (0.25 * (a - d) * (a - d) + b * b).sqrt();
        (mean - disc).max(0.0).sqrt()
    }
}

/// Whether `machine` has five axes, two of them rotary: a machine whose compensation can steer
/// the tool's direction ([`Compensator::with_orientation`]).
///
/// ```
/// let five = volver_core::presets::named("head-head").unwrap().machine().unwrap();
/// assert!(volver_core::compensate::is_five_axis(&five));
/// assert!(!volver_core::compensate::is_five_axis(&volver_core::machine::Machine::default_xcfz()));
/// ```
pub fn is_five_axis(machine: &crate::machine::Machine) -> bool {
    let axes = machine.axes();
    axes.len() == 5 && axes.iter().filter(|a| a.axis.is_rotary()).count() == 2
}

/// Where the oriented iteration stands: the command, its residuals (point in mm, direction
/// times [`DIRECTION_LEVER_MM`]), their Jacobian over the free axes and the cost
/// ([`oriented_cost`]).
struct Oriented {
    q: Commands,
    r: [f64; 6],
    jac: Vec<f64>,
    cost: (f64, f64),
}

/// The oriented iteration's cost of residuals `r`: the point's distance (mm) and the
/// direction's residual (mm at [`DIRECTION_LEVER_MM`]), judged in that order
/// ([`oriented_better`]).
fn oriented_cost(r: &[f64; 6]) -> (f64, f64) {
    (
        crate::problem::norm([r[0], r[1], r[2]]),
        crate::problem::norm([r[3], r[4], r[5]]),
    )
}

/// Whether cost `new` is better than `old`: first by the point, then (once the point is met to
/// [`NEWTON_TOLERANCE_MM`]) by the direction. Each step meets the point's linearised equations,
/// and at the singularity the direction's residual stays and must not outweigh the point's last
/// digits.
fn oriented_better(new: (f64, f64), old: (f64, f64)) -> bool {
    new.0.is_finite()
        && new.1.is_finite()
        && if old.0 > NEWTON_TOLERANCE_MM {
            new.0 < old.0
        } else {
            new.0 <= NEWTON_TOLERANCE_MM && new.1 < old.1
        }
}

/// Refuses a parameter vector that is not `model`'s.
fn check_params(model: &Model, params: &[f64]) -> Result<()> {
    if params.len() != model.n_params() {
        return Err(Error::ParameterCount {
            expected: model.n_params(),
            got: params.len(),
            message: format!(
                "compensation needs {} parameters, got {}",
                model.n_params(),
                params.len()
            ),
        });
    }
    Ok(())
}

/// The cross product `a × b`.
pub fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// `v` scaled to unit length.
fn unit(v: [f64; 3]) -> [f64; 3] {
    let n = crate::problem::norm(v);
    v.map(|x| x / n)
}

/// The angle between two unit vectors (rad), accurate at small angles (from the cross
/// product's length, not the dot product's).
///
/// ```
/// let a = volver_core::compensate::angle_between([0.0, 0.0, 1.0], [1e-9, 0.0, 1.0]);
/// assert!((a - 1e-9).abs() < 1e-20);
/// ```
pub fn angle_between(a: [f64; 3], b: [f64; 3]) -> f64 {
    let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    crate::problem::norm(cross(a, b)).atan2(dot)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The dual Jacobian of the point and direction residuals against central differences, on
    /// a five-axis machine with errors set.
    #[test]
    fn the_orientation_jacobian_matches_finite_differences() {
        let model = crate::presets::named("head-table")
            .unwrap()
            .model()
            .unwrap();
        let mut p = model.initial_params();
        for (name, v) in [
            ("X0B", 0.02),
            ("C0B", 3e-5),
            ("EAC.b1", 4e-5),
            ("EYX.c2", 0.01),
        ] {
            p[model.param_index(name).unwrap()] = v;
        }
        let comp = Compensator::with_orientation(&model, &p, [5.0, -3.0, -220.0], [0.1, 0.0, -1.0])
            .unwrap();
        // Chain order C, X, Y, Z, B.
        let q = model
            .machine()
            .commands_from_file_units(&[75.0, 120.0, -80.0, 200.0, -40.0]);
        let target = comp.nominal_point(&q);
        let dir = comp.nominal_direction(&q);
        let (_, jac) = comp.residual_and_jacobian(&q, target, dir);
        // The direction is the difference of two points 1 mm apart some 500 mm from the origin:
        // its rounding (~1e-13) over the step bounds the differences' accuracy, so they are
        // judged against the Jacobian's largest entry.
        let scale = jac.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        for k in 0..5 {
            let h = 1e-5;
            let (mut a, mut b) = (q, q);
            a.0[k] += h;
            b.0[k] -= h;
            let (ra, _) = comp.residual_and_jacobian(&a, target, dir);
            let (rb, _) = comp.residual_and_jacobian(&b, target, dir);
            for c in 0..6 {
                let fd = (ra[c] - rb[c]) / (2.0 * h);
                let exact = jac[c * 5 + k];
                assert!(
                    (fd - exact).abs() <= 1e-7 * scale,
                    "row {c}, axis {k}: {exact} against {fd} (largest entry {scale})"
                );
            }
        }
    }
}
