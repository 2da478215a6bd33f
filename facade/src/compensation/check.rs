//! A compensation checked on a machine whose errors are known (a simulated truth, or a machine
//! measured again after compensation): where the tool is before and after, over a grid of
//! programmed commands.

use crate::error::{Error, Result};
use serde::Serialize;
use volver_core::compensate::{Compensator, angle_between};
use volver_core::machine::{Commands, Machine};
use volver_core::metrics::{ErrorStats, rigid_fit};
use volver_core::plan::Plan;
use volver_core::units::URAD_PER_RAD;

/// What a compensation does on a known machine.
#[derive(Clone, Debug, Serialize)]
#[non_exhaustive]
pub struct TruthCheck {
    /// The programmed commands checked (internal units: mm, rad).
    #[serde(skip)]
    pub grid: Vec<Commands>,
    /// The true tool point's error at the programmed commands (workpiece frame).
    pub before: ErrorStats,
    /// The true tool point's error at the compensated commands (workpiece frame).
    pub after: ErrorStats,
    /// `after` once the workpiece set-up's best rigid transform is taken up.
    pub rigid: ErrorStats,
    /// The tool's direction, when its orientation is compensated (five-axis machines).
    pub direction: Option<DirectionCheck>,
    /// The largest deviation of a compensated command's model tool point from its target (mm):
    /// how well the inverse model was solved.
    pub worst_deviation_mm: f64,
    /// The largest direction deviation of a compensated command away from the singularity, in
    /// the model (rad).
    pub worst_direction_rad: f64,
    /// The largest direction deviation left near the singularity, in the model (rad).
    pub worst_singular_rad: f64,
    /// Compensated commands that leave an axis' travel.
    pub outside_travel: usize,
    /// Commands that pass near the singularity (the tilt axis at zero).
    pub near_singularity: usize,
}

/// The true direction error of the tool (µrad) before and after compensation.
#[derive(Clone, Copy, Debug, Serialize)]
#[non_exhaustive]
pub struct DirectionCheck {
    /// Mean and largest at the programmed commands (µrad).
    pub before_urad: (f64, f64),
    /// Mean and largest at the compensated commands (µrad).
    pub after_urad: (f64, f64),
    /// Mean and largest after the set-up's rigid turn (µrad).
    pub rigid_urad: (f64, f64),
}

/// The pairs (true, target) and direction errors gathered over the grid.
#[derive(Default)]
struct Gathered {
    before: Vec<([f64; 3], [f64; 3])>,
    after: Vec<([f64; 3], [f64; 3])>,
    dir_before: Vec<f64>,
    dir_after: Vec<f64>,
    dirs: Vec<([f64; 3], [f64; 3])>,
    worst: f64,
    worst_rad: f64,
    worst_singular_rad: f64,
    outside: usize,
    singular: usize,
}

impl Gathered {
    /// Compensates `programmed` with `comp` and records where `truth` puts the tool.
    fn add(
        &mut self,
        comp: &Compensator,
        truth: &Compensator,
        programmed: &Commands,
    ) -> Result<()> {
        let c = comp.compensate(programmed)?;
        self.worst = self.worst.max(c.deviation_mm);
        self.outside += usize::from(!c.outside_travel.is_empty());
        self.before.push((truth.actual_point(programmed), c.target));
        self.after.push((truth.actual_point(&c.commands), c.target));
        let Some(o) = c.orientation.as_ref() else {
            return Ok(());
        };
        if o.near_singularity {
            self.worst_singular_rad = self.worst_singular_rad.max(o.deviation_rad);
        } else {
            self.worst_rad = self.worst_rad.max(o.deviation_rad);
        }
        self.singular += usize::from(o.near_singularity);
        self.dir_before
            .push(truth.direction_deviation_rad(programmed, o.target));
        self.dir_after
            .push(truth.direction_deviation_rad(&c.commands, o.target));
        let actual = truth.actual_direction(&c.commands).ok_or_else(|| {
            Error::Mismatch("the truth's compensator has no tool axis to check".into())
        })?;
        self.dirs.push((actual, o.target));
        Ok(())
    }

    /// The direction check after the set-up's turn (the rigid fit of the compensated tool
    /// points onto their targets); none without directions.
    fn direction(&self) -> Option<DirectionCheck> {
        if self.dirs.is_empty() {
            return None;
        }
        let (a, b): (Vec<_>, Vec<_>) = self.after.iter().copied().unzip();
        let (r, _) = rigid_fit(&a, &b);
        let dir_rigid: Vec<f64> = self
            .dirs
            .iter()
            .map(|(d, t)| {
                let rd: [f64; 3] = std::array::from_fn(|i| (0..3).map(|j| r[i][j] * d[j]).sum());
                angle_between(rd, *t)
            })
            .collect();
        Some(DirectionCheck {
            before_urad: mean_max_urad(&self.dir_before),
            after_urad: mean_max_urad(&self.dir_after),
            rigid_urad: mean_max_urad(&dir_rigid),
        })
    }
}

/// Mean and largest of `v` (rad) in µrad.
fn mean_max_urad(v: &[f64]) -> (f64, f64) {
    (
        URAD_PER_RAD * v.iter().sum::<f64>() / v.len().max(1) as f64,
        URAD_PER_RAD * v.iter().copied().fold(0.0, f64::max),
    )
}

/// The error statistics of (actual, target) pairs.
fn stats(v: &[([f64; 3], [f64; 3])]) -> ErrorStats {
    let (a, b): (Vec<_>, Vec<_>) = v.iter().copied().unzip();
    ErrorStats::between(&a, &b)
}

/// Checks the compensation `comp` on the known machine `truth` (a compensator of the true model
/// and parameters with the same tool point, and the same tool axis when the orientation is
/// compensated) over the programmed commands `grid`: the true tool point's error before and after
/// (and after the set-up's rigid transform), the tool direction's likewise, and how well each
/// command was solved.
///
/// ```
/// use volver::compensation::check_on_truth;
/// use volver::core::compensate::Compensator;
/// use volver::core::model::Model;
/// let model = Model::default_xcfz();
/// let params = model.initial_params();
/// let tool = [0.0, 0.0, 0.0];
/// let comp = Compensator::new(&model, &params, tool)?;
/// let grid = [model.machine().commands_from_file_units(&[700.0, 90.0, 300.0])];
/// // Compensating the nominal machine with its own (zero) errors changes nothing.
/// let check = check_on_truth(&comp, &comp, &grid)?;
/// assert!(check.before.emm_um < 1e-6 && check.after.emm_um < 1e-6);
/// # Ok::<(), volver::Error>(())
/// ```
pub fn check_on_truth(
    comp: &Compensator,
    truth: &Compensator,
    grid: &[Commands],
) -> Result<TruthCheck> {
    check_pair(comp, truth, grid)?;
    let mut g = Gathered::default();
    for programmed in grid {
        g.add(comp, truth, programmed)?;
    }
    let (a, b): (Vec<_>, Vec<_>) = g.after.iter().copied().unzip();
    // What a workpiece set-up leaves: the compensated tool points after the best rigid
    // transform onto their targets (a constant shift and turn of the tool relative to the table
    // is taken up when the workpiece is set up and probed); the turn applies to the directions.
    let rigid = ErrorStats::after_rigid(&a, &b);
    Ok(TruthCheck {
        grid: grid.to_vec(),
        before: stats(&g.before),
        after: stats(&g.after),
        rigid,
        direction: g.direction(),
        worst_deviation_mm: g.worst,
        worst_direction_rad: g.worst_rad,
        worst_singular_rad: g.worst_singular_rad,
        outside_travel: g.outside,
        near_singularity: g.singular,
    })
}

/// Refuses a check that could only give meaningless numbers: an empty grid, a truth of another
/// machine (another chain or other axes), another tool point or tool axis, or a grid command
/// outside the machine's axes (non-zero beyond its last axis).
fn check_pair(comp: &Compensator, truth: &Compensator, grid: &[Commands]) -> Result<()> {
    if grid.is_empty() {
        return Err(Error::Request(
            "an empty grid: a compensation is checked at one command at least".into(),
        ));
    }
    let (m, t) = (comp.model().machine(), truth.model().machine());
    if m.chain() != t.chain() || m.axes().len() != t.axes().len() {
        return Err(Error::Mismatch(format!(
            "the truth's machine has chain {}, the compensated one {}",
            t.chain(),
            m.chain()
        )));
    }
    if comp.tool() != truth.tool() || comp.tool_axis() != truth.tool_axis() {
        return Err(Error::Mismatch(format!(
            "the truth is checked at tool point {:?} mm (axis {:?}), the compensation is for \
             {:?} mm (axis {:?}): give both the same",
            truth.tool(),
            truth.tool_axis(),
            comp.tool(),
            comp.tool_axis()
        )));
    }
    let n = m.axes().len();
    if let Some(q) = grid.iter().find(|q| q.0[n..].iter().any(|v| *v != 0.0)) {
        return Err(Error::Mismatch(format!(
            "grid command {:?} has values beyond the machine's {n} axes: a grid of another machine",
            q.0
        )));
    }
    Ok(())
}

/// A grid over the travel for checking a compensation: `per_axis` positions per linear axis
/// from 10 % inside one end of its travel to 10 % inside the other (compensation moves a command
/// at an end outside the travel), a rotary axis of a full turn at `per_axis` equal steps of the
/// turn, starting at its lower limit.
pub fn travel_grid(machine: &Machine, per_axis: usize) -> Result<Vec<Commands>> {
    if per_axis < 2 {
        return Err(Error::Request(format!(
            "{per_axis} positions per axis: a grid over the travel needs at least 2"
        )));
    }
    let n = per_axis as f64;
    let ranges: Vec<String> = machine
        .axes()
        .iter()
        .map(|ax| {
            let (a, b) = (ax.to_file_units(ax.min), ax.to_file_units(ax.max));
            if ax.axis.is_rotary() && b - a >= 360.0 - 1e-9 {
                let step = 360.0 / n;
                format!("{}={a}:{}:{step}", ax.axis, a + step * (n - 1.0))
            } else {
                let (lo, hi) = (a + 0.1 * (b - a), b - 0.1 * (b - a));
                format!("{}={lo}:{hi}:{}", ax.axis, (hi - lo) / (n - 1.0))
            }
        })
        .collect();
    Ok(Plan::parse_grid(machine, &ranges.join(","))?.positions)
}
