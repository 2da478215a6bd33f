//! The directions of approach of measurements taken by a plan: the plan file's (stated by a
//! bidirectional plan's `approach_<AXIS>` columns, else its order's), matched row by row.

use super::Plan;
use crate::error::{Error, Place, Result};
use crate::machine::Machine;
use crate::measure::{MeasurementSet, measuring_order};

/// How far a measured command may lie from the plan's (internal units: mm or rad) and still be
/// the plan's row: the plan file's 1e-9 of its unit rounded, a measurement file's 6 decimals.
const SAME_COMMAND: f64 = 1e-5;

impl MeasurementSet {
    /// Takes each measurement's directions of approach from `plan`, the plan the measurements
    /// were taken by: the data in their measuring order ([`measuring_order`]) are the plan's
    /// measurements in its order, once per station (the plan measured from each station in
    /// turn), each row checked to be the plan's (its commands within 1e-5 mm or rad, its
    /// reflector). The directions volver's measuring program of the plan gives
    /// ([`Plan::program_or_order_approaches`]: a bidirectional plan's stated ones; the
    /// clearance axes from the clearance's side; the others by the plan's order) replace those
    /// derived from the data's order; an axis whose
    /// direction the measurement file states (`approach_<AXIS>` columns) keeps the file's, and
    /// a file's direction the plan states otherwise is refused as a contradiction. `plan_file`
    /// and `data_file` name the files in messages.
    ///
    /// ```
    /// use volver_core::machine::Machine;
    /// use volver_core::measure::MeasurementSet;
    /// use volver_core::plan::{Plan, sides::Overrun};
    /// let m = Machine::default_xcfz();
    /// let grid = Plan::parse_grid(&m, "X=100:300:100,C=0,Z=0").unwrap();
    /// let plan = grid.bidirectional(&m, &Overrun::default()).unwrap();
    /// // The tracker's export: the plan's rows in its order, no direction recorded.
    /// let mut csv = String::from("X,C,Z,reflector,meas_x,meas_y,meas_z\n");
    /// for (i, s) in plan.steps().iter().enumerate() {
    ///     let x = m.axes()[0].to_file_units(plan.positions[s.position].0[0]);
    ///     csv += &format!("{x},0,0,{},{i},0,0\n", m.reflectors()[s.reflector].id);
    /// }
    /// let mut data = MeasurementSet::from_csv_str(&m, &csv, "d.csv").unwrap();
    /// data.take_approach_from_plan(&m, &plan, "plan.csv", "d.csv").unwrap();
    /// let x: Vec<i8> = data.points.iter().map(|p| p.approach.0[0]).collect();
    /// assert_eq!(&x[..4], &[1, 1, -1, -1]); // each pose from below, then from above
    /// ```
    pub fn take_approach_from_plan(
        &mut self,
        machine: &Machine,
        plan: &Plan,
        plan_file: &str,
        data_file: &str,
    ) -> Result<()> {
        let (n, m) = (self.points.len(), plan.n_points());
        if m == 0 || n % m != 0 {
            return Err(Error::input(
                Place::file(plan_file),
                format!(
                    "the measurements ({data_file}) have {n} rows and the plan {m} measurements: \
                     data taken by a plan are its measurements in its order, once per station"
                ),
            ));
        }
        let steps = plan.steps();
        let planned = plan.program_or_order_approaches(machine, n / m);
        let order = measuring_order(&self.points);
        for (at, &i) in order.iter().enumerate() {
            let step = steps[at % m];
            let p = &mut self.points[i];
            let want = &plan.positions[step.position];
            let n_axes = machine.axes().len();
            let same = (0..n_axes).all(|k| (p.commands.0[k] - want.0[k]).abs() <= SAME_COMMAND);
            if !same || p.reflector != step.reflector {
                return Err(Error::input(
                    Place::file(data_file).at_line(p.line),
                    format!(
                        "this row is measurement {} in measuring order, but the plan's \
                         measurement {} ({plan_file}, row {}) is {} with reflector {}: the data \
                         were not taken by this plan in its order",
                        at + 1,
                        at % m + 1,
                        at % m + 1,
                        describe(machine, want),
                        machine.reflectors()[step.reflector].id
                    ),
                ));
            }
            for k in 0..n_axes {
                let from_plan = planned[at].0[k];
                if !self.approach_stated[k] || p.approach.0[k] == 0 {
                    // Not stated by the file, or stated unknown: the plan's.
                    p.approach.0[k] = from_plan;
                } else if plan.approach.is_some() && from_plan != 0 && p.approach.0[k] != from_plan
                {
                    return Err(Error::input(
                        Place::file(data_file).at_line(p.line).at_field(
                            crate::approach::column_name(machine.axes()[k].axis.letter()),
                        ),
                        format!(
                            "the file says {} arrived {}, the plan ({plan_file}, row {}) {}: \
                             contradicting directions of approach",
                            machine.axes()[k].axis,
                            side(p.approach.0[k]),
                            at % m + 1,
                            side(from_plan)
                        ),
                    ));
                }
            }
        }
        Ok(())
    }
}

/// A command in file units (`X=100 C=0 Z=0`).
fn describe(machine: &Machine, c: &crate::machine::Commands) -> String {
    machine
        .axes()
        .iter()
        .enumerate()
        .map(|(k, ax)| {
            format!(
                "{}={}",
                ax.axis,
                crate::error::number(ax.to_file_units(c.0[k]))
            )
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// A direction in words.
fn side(s: i8) -> &'static str {
    match s {
        1 => "moving forward (+)",
        -1 => "moving in reverse (−)",
        _ => "from an unknown side",
    }
}
