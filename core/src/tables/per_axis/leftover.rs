//! What per-axis tables leave of the tool point's error, evaluated exactly over a grid of the
//! travel ([`leftover`]), beside the error before compensation and what full volumetric
//! compensation leaves; and the tables applied as a control applies them
//! ([`PerAxisTables::corrections`]).

use super::{AxisCorrection, ErrorSize, Family, PerAxisTables};
use crate::approach::Approach;
use crate::compensate::Compensator;
use crate::error::{Error, Result};
use crate::kinematics::{PointErrors, tool_in_workpiece};
use crate::machine::{Commands, Machine};
use crate::model::{Model, PointState};

/// The most commands of [`evaluation_grid`] (each evaluated at every tool point).
pub const EVALUATION_BUDGET: usize = 20_000;

/// The most positions per axis of [`evaluation_grid`] (a full turn takes one fewer).
pub const EVALUATION_POSITIONS: usize = 12;

impl AxisCorrection {
    /// The correction at input position `position` (file units) for the output axis arriving
    /// in `direction` (+1 forward, −1 reverse, 0 unknown: the mean of both), interpolated
    /// linearly between the positions and held at the end values beyond them (output axis'
    /// file units).
    ///
    /// ```
    /// use volver_core::iso::Axis;
    /// use volver_core::tables::per_axis::AxisCorrection;
    /// let t = AxisCorrection { input: Axis::X, output: Axis::X, positions: vec![0.0, 10.0],
    ///                          forward: vec![0.0, 0.002], reverse: vec![0.0, 0.004] };
    /// assert!((t.value_at(5.0, 1) - 0.001).abs() < 1e-15);
    /// assert!((t.value_at(5.0, -1) - 0.002).abs() < 1e-15);
    /// assert!((t.value_at(50.0, 0) - 0.003).abs() < 1e-15);
    /// ```
    pub fn value_at(&self, position: f64, direction: i8) -> f64 {
        let p = &self.positions;
        let (Some(&first), Some(&last)) = (p.first(), p.last()) else {
            return 0.0;
        };
        let at = |v: &[f64]| -> f64 {
            if position <= first {
                return v[0];
            }
            if position >= last {
                return v[p.len() - 1];
            }
            let i = p.partition_point(|&x| x <= position).clamp(1, p.len() - 1);
            let t = (position - p[i - 1]) / (p[i] - p[i - 1]);
            v[i - 1] + t * (v[i] - v[i - 1])
        };
        match direction.signum() {
            1 => at(&self.forward),
            -1 => at(&self.reverse),
            _ => 0.5 * (at(&self.forward) + at(&self.reverse)),
        }
    }
}

impl PerAxisTables {
    /// What a control applying these tables adds to each axis' command at the programmed
    /// `commands` (internal units: mm, rad; chain order), each output axis arriving from the
    /// side `approach` gives (the mean of both where it is unknown). A table over a rotary axis
    /// whose travel and table are a full turn takes the input position turned into it.
    ///
    /// # Errors
    /// A table naming an axis `machine` does not have.
    pub fn corrections(
        &self,
        machine: &Machine,
        commands: &Commands,
        approach: Approach,
    ) -> Result<Commands> {
        let axes = machine.axes();
        let index = |axis| {
            axes.iter()
                .position(|a| a.axis == axis)
                .ok_or_else(|| Error::MachineMismatch {
                    message: format!(
                        "a per-axis table names axis {axis}, which the machine ({}) lacks",
                        machine.chain()
                    ),
                })
        };
        let mut c = Commands::default();
        for t in &self.tables {
            let (k, j) = (index(t.input)?, index(t.output)?);
            let a = &axes[k];
            let mut x = a.to_file_units(commands.0[k]);
            let span = t.positions.last().unwrap_or(&0.0) - t.positions.first().unwrap_or(&0.0);
            if a.axis.is_rotary() && (span - 360.0).abs() < 1e-9 {
                x = t.positions[0] + (x - t.positions[0]).rem_euclid(360.0);
            }
            c.0[j] += axes[j].from_file_units(t.value_at(x, approach.0[j]));
        }
        Ok(c)
    }
}

/// The tool point's error at one command of the evaluation grid for one tool point (mm,
/// workpiece frame: the real machine's point less the nominal machine's at the programmed
/// command).
#[derive(Clone, Debug, PartialEq)]
pub struct LeftoverPoint {
    /// Index of the programmed command in [`Leftover::grid`].
    pub command: usize,
    /// Index of the tool point in [`Leftover::tools`].
    pub tool: usize,
    /// Before compensation, at the programmed command.
    pub before: [f64; 3],
    /// With the tables as a control applies them, every direction unknown (the mean values).
    pub tables: [f64; 3],
    /// With a reversal in the model: every axis arriving forward, the tables' forward values
    /// applied, and then every axis arriving in reverse with the reverse values.
    pub directions: Option<([f64; 3], [f64; 3])>,
    /// With full volumetric compensation ([`Compensator::new`] at this tool point).
    pub volumetric: [f64; 3],
}

/// What per-axis tables leave of the tool point's error over the evaluation grid (every
/// command with every tool point), beside the error before compensation and what full
/// volumetric compensation leaves.
#[derive(Clone, Debug, PartialEq)]
pub struct Leftover {
    /// Which tables.
    pub family: Family,
    /// The programmed commands evaluated (internal units: mm, rad), [`evaluation_grid`]'s
    /// unless given otherwise.
    pub grid: Vec<Commands>,
    /// The tool points (mm, frame of the last tool-side axis).
    pub tools: Vec<[f64; 3]>,
    /// The error before compensation.
    pub before: ErrorSize,
    /// The error with the tables, every direction unknown (the mean values): evaluated
    /// exactly, `T(q + c(q), p) − T(q, 0)`.
    pub tables: ErrorSize,
    /// With a reversal in the model, the error with every axis arriving forward (the tables'
    /// forward values) and in reverse (the reverse values); `None` without one.
    pub directions: Option<(ErrorSize, ErrorSize)>,
    /// The error full volumetric compensation leaves (tool point compensated, every direction
    /// unknown): what `volver compensate` leaves, rounding of its solution.
    pub volumetric: ErrorSize,
    /// Every command with every tool point: the vectors, for a map.
    pub points: Vec<LeftoverPoint>,
}

/// The evaluation grid over `machine`'s travel: the tensor grid of `n` positions per axis
/// from one end of its travel to the other (equal steps; a full turn in `n − 1` equal steps
/// from its start, its end being its start), `n` the largest up to [`EVALUATION_POSITIONS`]
/// with at most [`EVALUATION_BUDGET`] commands: 12 on a machine of three axes (every 1/11 of a
/// linear travel, every 32.7° of a full turn), 7 on one of five. Steps of odd fractions of the
/// travel put most positions between the tables' positions, so that what their linear
/// interpolation leaves is in the leftover.
///
/// ```
/// let m = volver_core::machine::Machine::default_xcfz();
/// let g = volver_core::tables::per_axis::evaluation_grid(&m);
/// assert_eq!(g.len(), 12 * 11 * 12);
/// ```
pub fn evaluation_grid(machine: &Machine) -> Vec<Commands> {
    let axes = machine.axes();
    // A full turn's last position is its first: left out.
    let count =
        |a: &crate::machine::MachineAxis, n: usize| if a.is_full_turn() { n - 1 } else { n };
    let n = (3..=EVALUATION_POSITIONS)
        .rev()
        .find(|&n| axes.iter().map(|a| count(a, n)).product::<usize>() <= EVALUATION_BUDGET)
        .unwrap_or(3);
    let lists: Vec<Vec<f64>> = axes
        .iter()
        .map(|a| {
            (0..count(a, n))
                .map(|i| a.min + (a.max - a.min) * i as f64 / (n - 1) as f64)
                .collect()
        })
        .collect();
    crate::plan::cartesian(&lists)
}

/// What `tables` leave of `model`'s tool point error with errors `params` at every command of
/// `grid` and every tool point of the tables, evaluated exactly (the tables applied as a control
/// applies them, [`PerAxisTables::corrections`], and the tool point through the forward model),
/// with the error before compensation and what full volumetric compensation leaves
/// ([`Compensator::new`]).
///
/// # Errors
/// An empty grid, parameters of another model, tables naming an axis the machine lacks, a
/// compensation that fails ([`Compensator::compensate`]).
pub fn leftover(
    model: &Model,
    params: &[f64],
    tables: &PerAxisTables,
    grid: &[Commands],
) -> Result<Leftover> {
    if grid.is_empty() || tables.tools.is_empty() {
        return Err(Error::InvalidOption {
            name: "grid",
            message: "the leftover of per-axis tables needs one command and one tool point at \
                      least"
                .into(),
        });
    }
    let m = model.machine();
    let n = m.axes().len();
    let directional = !crate::compensate::reversal_axes(model).is_empty();
    let mut points = Vec::with_capacity(grid.len() * tables.tools.len());
    for (t, tool) in tables.tools.iter().enumerate() {
        let comp = Compensator::new(model, params, *tool)?;
        for (i, q) in grid.iter().enumerate() {
            let nominal = tool_in_workpiece(m, &q.0, tool, &PointErrors::<f64>::zero());
            let at = |approach: Approach| -> Result<[f64; 3]> {
                let c = tables.corrections(m, q, approach)?;
                let mut moved = *q;
                moved.0.iter_mut().zip(&c.0).for_each(|(v, d)| *v += d);
                let state = PointState { t_s: 0.0, approach };
                Ok(minus(
                    model.tool_point_in(&moved.0, tool, state, params),
                    nominal,
                ))
            };
            let compensated = comp.compensate(q)?;
            points.push(LeftoverPoint {
                command: i,
                tool: t,
                before: minus(model.tool_point(&q.0, tool, params), nominal),
                tables: at(Approach::UNKNOWN)?,
                directions: if directional {
                    Some((at(Approach::all(n, 1))?, at(Approach::all(n, -1))?))
                } else {
                    None
                },
                volumetric: minus(comp.actual_point(&compensated.commands), compensated.target),
            });
        }
    }
    let size = |f: &dyn Fn(&LeftoverPoint) -> [f64; 3]| error_size(grid, &points, f);
    Ok(Leftover {
        family: tables.family,
        grid: grid.to_vec(),
        tools: tables.tools.clone(),
        before: size(&|p| p.before),
        tables: size(&|p| p.tables),
        directions: directional.then(|| {
            (
                size(&|p| p.directions.map_or([0.0; 3], |d| d.0)),
                size(&|p| p.directions.map_or([0.0; 3], |d| d.1)),
            )
        }),
        volumetric: size(&|p| p.volumetric),
        points,
    })
}

/// `a − b`.
fn minus(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// The EMM and EMax of the vectors `f` picks from `points` (mm) and where the largest is.
fn error_size(
    grid: &[Commands],
    points: &[LeftoverPoint],
    f: &dyn Fn(&LeftoverPoint) -> [f64; 3],
) -> ErrorSize {
    ErrorSize::of(grid, points.iter().map(|p| (p.command, f(p))))
}
