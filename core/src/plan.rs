//! Test plans: the commanded positions of a verification and the reflectors measured at each.
//!
//! Named presets reproduce the paper's meshes for the XCFZ machine (section 6.2, tables 4 and 7);
//! plain grids are given per axis as `start:end:step` in file units (mm, degrees).
//!
//! | preset | mesh |
//! |---|---|
//! | `table4` / `test2` | X = 0, Z = 0, C 0–360° step 5° |
//! | `table7` | X 0–1400 step 100 mm, Z 0–600 step 50 mm, C = 0 |
//! | `test1` | X 0–1400 step 100 mm, Z 0–600 step 75 mm, C = 0 |
//! | `test3` | X 0–1400 step 300 mm, Z 0–600 step 225 mm, C 0–360° step 45° |
//! | `test4` | X 0–1400 step 200 mm, Z 0–600 step 150 mm, C 0–360° step 30° (the reference test) |
//! | `test5` | the mesh of `test3` (test 5 differs by its strategy: linear-axis errors from test 1) |
//!
//! Where a step does not divide the range (300 mm over 1400 mm), the end of the range is added as
//! a last, shorter step: the paper's meshes start *and finish* at the ends of table 7. C = 360° is
//! kept: it is the pose of C = 0 measured again, a repeated point. Every reflector of the machine
//! is measured at every position. Points are ordered as a machine would run them: the first axis
//! of the chain slowest, the last fastest.
//!
//! ```
//! use volver_core::machine::Machine;
//! use volver_core::plan::Plan;
//! let m = Machine::default_xcfz();
//! let p = Plan::preset(&m, "test4").unwrap();
//! assert_eq!(p.positions.len(), 8 * 5 * 13); // X 0..1400/200, Z 0..600/150, C 0..360/30
//! assert_eq!(p.n_points(), 2 * 520);         // two reflectors
//! ```

use crate::error::{Error, Place, Result};
use crate::iso::Axis;
use crate::machine::{Commands, Machine, MachineAxis};

pub mod file;
pub mod order;
pub mod sides;
mod taken;

/// The named presets, in the order `volver simulate --help` lists them.
pub const PRESETS: [&str; 7] = [
    "table4", "table7", "test1", "test2", "test3", "test4", "test5",
];

/// The most positions a plan may have (each measured at every reflector): far beyond any
/// laser-tracker test, which measures hundreds to a few thousand.
pub const MAX_PLAN_POSITIONS: usize = 1_000_000;

/// Test duration used when none is given: this many seconds per measured point.
pub const DEFAULT_SECONDS_PER_POINT: f64 = 10.0;

/// Values of one axis in a grid, file units.
#[derive(Clone, Debug, PartialEq)]
pub struct AxisRange {
    /// The axis.
    pub axis: Axis,
    /// First value.
    pub start: f64,
    /// Last value (included).
    pub end: f64,
    /// Step (> 0; ignored when start == end).
    pub step: f64,
}

impl AxisRange {
    /// The values: start, start + step, … up to end, with end always included.
    pub fn values(&self) -> Vec<f64> {
        if self.start == self.end {
            return vec![self.start];
        }
        let n = ((self.end - self.start) / self.step + 1e-9).floor() as usize;
        let mut v: Vec<f64> = (0..=n).map(|i| self.start + i as f64 * self.step).collect();
        if (self.end - v[n]).abs() > 1e-9 * self.step {
            v.push(self.end);
        }
        v
    }
}

/// A test plan: commanded positions (chain order, internal units) and the reflectors measured
/// at each.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    /// Name (preset name or the grid text).
    pub name: String,
    /// Commanded positions, in measuring order.
    pub positions: Vec<Commands>,
    /// Reflector indices measured at every position (when `sequence` is `None`), or every
    /// reflector the sequence uses.
    pub reflectors: Vec<usize>,
    /// The measuring sequence, when it is not every reflector of `reflectors` at every position
    /// in order (a designed plan: `volver plan`, [`crate::plan::file`]).
    pub sequence: Option<Vec<Step>>,
    /// The direction of approach each measurement states, one per measurement in
    /// [`Plan::steps`] order: a plan whose program overruns each position and comes back from a
    /// chosen side ([`Plan::bidirectional`], a plan file's `approach_<AXIS>` columns), 0 where
    /// an axis' direction is not stated (no approach move: unknown). `None`: the directions
    /// are the measuring order's ([`Plan::approaches`]).
    pub approach: Option<Vec<crate::approach::Approach>>,
}

/// One measurement of a plan: the reflector `reflector` (machine index) at `positions[position]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Step {
    /// Index into [`Plan::positions`].
    pub position: usize,
    /// Reflector index (into the machine's reflectors).
    pub reflector: usize,
}

impl Plan {
    /// Number of measured points.
    pub fn n_points(&self) -> usize {
        match &self.sequence {
            Some(s) => s.len(),
            None => self.positions.len() * self.reflectors.len(),
        }
    }

    /// The measurements in measuring order: the sequence, or every reflector in turn at every
    /// position.
    ///
    /// ```
    /// use volver_core::machine::Machine;
    /// use volver_core::plan::{Plan, Step};
    /// let p = Plan::preset(&Machine::default_xcfz(), "test4").unwrap();
    /// let steps = p.steps();
    /// assert_eq!(steps.len(), 1040);
    /// assert_eq!(steps[1], Step { position: 0, reflector: 1 });
    /// ```
    pub fn steps(&self) -> Vec<Step> {
        match &self.sequence {
            Some(s) => s.clone(),
            None => self
                .positions
                .iter()
                .enumerate()
                .flat_map(|(position, _)| {
                    self.reflectors.iter().map(move |&reflector| Step {
                        position,
                        reflector,
                    })
                })
                .collect(),
        }
    }

    /// The plan measured in a random order (a Fisher–Yates shuffle of its measurements, seeded):
    /// the order an optimised route or a shop's own program may take, which approaches each
    /// axis' positions from either side at random.
    ///
    /// ```
    /// use volver_core::machine::Machine;
    /// use volver_core::plan::Plan;
    /// let m = Machine::default_xcfz();
    /// let plan = Plan::preset(&m, "test4").unwrap();
    /// let s = plan.shuffled(3);
    /// let (mut a, mut b) = (plan.steps(), s.steps());
    /// assert_ne!(a, b);
    /// a.sort();
    /// b.sort();
    /// assert_eq!(a, b);
    /// ```
    ///
    /// Directions the plan states go with their measurements (each is made by its own approach
    /// move, whatever comes before it).
    pub fn shuffled(&self, seed: u64) -> Plan {
        let mut steps = self.steps();
        let mut approach = self.approach.clone();
        let mut rng = crate::random::Rng::new(seed ^ 0x5EED_0F0D_E125_u64);
        for i in (1..steps.len()).rev() {
            let j = (rng.next_u64() % (i as u64 + 1)) as usize;
            steps.swap(i, j);
            if let Some(a) = approach.as_mut().filter(|a| a.len() == steps.len()) {
                a.swap(i, j);
            }
        }
        Plan {
            name: format!("{} (shuffled, seed {seed})", self.name),
            sequence: Some(steps),
            approach,
            ..self.clone()
        }
    }

    /// The direction of approach of every measurement when the plan is run `passes` times in
    /// a row (once from each station), in that order: the directions the plan states
    /// ([`Plan::approach`], the same in every pass), else each axis' last move before the point
    /// ([`crate::approach::from_order`]; a pass continues from where the previous one ended).
    ///
    /// ```
    /// use volver_core::machine::Machine;
    /// use volver_core::plan::Plan;
    /// let m = Machine::default_xcfz();
    /// let plan = Plan::parse_grid(&m, "X=0:1400:700,C=0,Z=0").unwrap();
    /// let a = plan.approaches(2);
    /// assert_eq!(a.len(), 2 * plan.n_points());
    /// // X at 1400 arrived moving +; the second pass starts with a move back to 0 (−).
    /// assert_eq!((a[4].0[0], a[6].0[0]), (1, -1));
    /// ```
    ///
    /// A bidirectional plan states both directions at every pose:
    ///
    /// ```
    /// use volver_core::machine::Machine;
    /// use volver_core::plan::{Plan, sides::Overrun};
    /// let m = Machine::default_xcfz();
    /// let plan = Plan::parse_grid(&m, "X=0:1400:700,C=90,Z=300").unwrap();
    /// let both = plan.bidirectional(&m, &Overrun::default()).unwrap();
    /// let x: Vec<i8> = both.approaches(1).iter().map(|a| a.0[0]).collect();
    /// // X = 0 is the end of its travel: approached from above (−) both times.
    /// assert_eq!(x, [-1, -1, -1, -1, 1, 1, -1, -1, 1, 1, 1, 1]);
    /// ```
    pub fn approaches(&self, passes: usize) -> Vec<crate::approach::Approach> {
        if let Some(stated) = &self.approach {
            let n = self.n_points();
            return (0..passes)
                .flat_map(|_| (0..n).map(|i| stated.get(i).copied().unwrap_or_default()))
                .collect();
        }
        let steps = self.steps();
        let order: Vec<Commands> = (0..passes)
            .flat_map(|_| steps.iter().map(|s| self.positions[s.position]))
            .collect();
        crate::approach::from_order(&order, crate::chain::MAX_AXES)
    }

    /// The directions of approach [`Plan::approaches`] gives, but as volver's measuring program
    /// makes them on `machine` when it has a clearance position ([`file::program_approaches`]
    /// with [`file::ProgramOptions::new`]: its clearance axes, retracted between poses, arrive
    /// from the clearance's side), repeated for each of `passes` runs (the program run once per
    /// station). Without a clearance, or when the program cannot be written (an approach
    /// outside the travel), the order's.
    pub fn program_or_order_approaches(
        &self,
        machine: &Machine,
        passes: usize,
    ) -> Vec<crate::approach::Approach> {
        let options = file::ProgramOptions::new(machine);
        if options.clearance.is_empty() {
            return self.approaches(passes);
        }
        match file::program_approaches(self, machine, &options) {
            Ok(one) => (0..passes).flat_map(|_| one.iter().copied()).collect(),
            Err(_) => self.approaches(passes),
        }
    }

    /// A named preset of the paper (see the module documentation). The presets are defined for
    /// machines with the axes X, C and Z; each axis must reach the preset's range.
    pub fn preset(machine: &Machine, name: &str) -> Result<Plan> {
        let r = |axis, start, end, step| AxisRange {
            axis,
            start,
            end,
            step,
        };
        let ranges = match name {
            "table4" | "test2" => vec![
                r(Axis::X, 0.0, 0.0, 0.0),
                r(Axis::C, 0.0, 360.0, 5.0),
                r(Axis::Z, 0.0, 0.0, 0.0),
            ],
            "table7" => vec![
                r(Axis::X, 0.0, 1400.0, 100.0),
                r(Axis::C, 0.0, 0.0, 0.0),
                r(Axis::Z, 0.0, 600.0, 50.0),
            ],
            "test1" => vec![
                r(Axis::X, 0.0, 1400.0, 100.0),
                r(Axis::C, 0.0, 0.0, 0.0),
                r(Axis::Z, 0.0, 600.0, 75.0),
            ],
            "test3" | "test5" => {
                vec![
                    r(Axis::X, 0.0, 1400.0, 300.0),
                    r(Axis::C, 0.0, 360.0, 45.0),
                    r(Axis::Z, 0.0, 600.0, 225.0),
                ]
            }
            "test4" => vec![
                r(Axis::X, 0.0, 1400.0, 200.0),
                r(Axis::C, 0.0, 360.0, 30.0),
                r(Axis::Z, 0.0, 600.0, 150.0),
            ],
            _ => {
                return Err(Error::input(
                    Place::file("plan").at_field("name"),
                    format!(
                        "unknown plan '{name}'; presets are {}, or a grid such as X=0:1400:100,Z=0:600:50,C=0",
                        PRESETS.join(", ")
                    ),
                ));
            }
        };
        Plan::grid_named(machine, &ranges, name)
    }

    /// A plain grid from text: one `AXIS=start:end:step` or `AXIS=value` per axis of the
    /// machine, comma-separated, in file units, e.g. `X=0:1400:100,Z=0:600:50,C=0`.
    ///
    /// Several grids joined by `;` are measured one after the other (a union: a grid of the
    /// linear axes, then the rotary axes swept at a few positions, say; a position an earlier
    /// grid has is measured once), e.g.
    /// `X=0:1400:200,Z=0:600:150,C=0; X=700,Z=300,C=0:330:30`.
    ///
    /// ```
    /// use volver_core::machine::Machine;
    /// use volver_core::plan::Plan;
    /// let m = Machine::default_xcfz();
    /// let p = Plan::parse_grid(&m, "X=0:1400:700,Z=0,C=0; X=700,Z=300,C=0:330:30").unwrap();
    /// assert_eq!(p.positions.len(), 3 + 12);
    /// ```
    pub fn parse_grid(machine: &Machine, text: &str) -> Result<Plan> {
        let grids: Vec<&str> = text.split(';').map(str::trim).collect();
        if grids.len() > 1 {
            return Plan::union_of_grids(machine, &grids, text);
        }
        let ranges = text
            .split(',')
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .map(AxisRange::parse)
            .collect::<Result<Vec<_>>>()?;
        Plan::grid_named(machine, &ranges, text)
    }

    /// The grids of `grids` (the `;`-separated parts of `text`) one after the other, each
    /// position measured once, where it first comes.
    fn union_of_grids(machine: &Machine, grids: &[&str], text: &str) -> Result<Plan> {
        let place = || Place::file("plan").at_field("grid");
        let mut plan = Plan::parse_grid(machine, grids[0])?;
        let key = |q: &Commands| q.0.map(f64::to_bits);
        let mut seen: std::collections::HashSet<_> = plan.positions.iter().map(key).collect();
        for g in &grids[1..] {
            if g.is_empty() {
                return Err(Error::input(
                    place(),
                    "an empty grid between ';' separators",
                ));
            }
            let next = Plan::parse_grid(machine, g)?;
            // A position an earlier grid has is measured once (where it first comes).
            for q in next.positions {
                if seen.insert(key(&q)) {
                    plan.positions.push(q);
                }
            }
            if plan.positions.len() > MAX_PLAN_POSITIONS {
                return Err(Error::input(
                    place(),
                    format!("more than {MAX_PLAN_POSITIONS} positions"),
                ));
            }
        }
        plan.name = text.to_string();
        Ok(plan)
    }

    /// A grid over the given ranges (one per axis of the machine, any order).
    pub fn grid(machine: &Machine, ranges: &[AxisRange]) -> Result<Plan> {
        Plan::grid_named(machine, ranges, "grid")
    }

    /// A grid named `name` (its errors' field): every axis' values, then their Cartesian
    /// product, first chain axis slowest.
    fn grid_named(machine: &Machine, ranges: &[AxisRange], name: &str) -> Result<Plan> {
        let place = || Place::file("plan").at_field(name.to_string());
        let mut per_axis: Vec<Vec<f64>> = Vec::new();
        for ax in machine.axes() {
            let found: Vec<&AxisRange> = ranges.iter().filter(|r| r.axis == ax.axis).collect();
            let r = match found.as_slice() {
                [r] => *r,
                [] => {
                    return Err(Error::input(
                        place(),
                        format!("no values for axis {} of {}", ax.axis, machine.chain()),
                    ));
                }
                _ => {
                    return Err(Error::input(
                        place(),
                        format!("axis {} is given twice", ax.axis),
                    ));
                }
            };
            per_axis.push(r.checked_values(ax).map_err(|m| Error::input(place(), m))?);
        }
        let total = per_axis.iter().map(|v| v.len() as f64).product::<f64>();
        if total > MAX_PLAN_POSITIONS as f64 {
            return Err(Error::input(
                place(),
                format!(
                    "the grid has {total:.3e} positions; a plan has at most {MAX_PLAN_POSITIONS}: \
                     use larger steps"
                ),
            ));
        }
        if let Some(extra) = ranges.iter().find(|r| machine.axis(r.axis).is_none()) {
            return Err(Error::input(
                place(),
                format!(
                    "axis {} is not in the machine's chain {}",
                    extra.axis,
                    machine.chain()
                ),
            ));
        }
        Ok(Plan {
            name: name.to_string(),
            positions: cartesian(&per_axis),
            reflectors: (0..machine.reflectors().len()).collect(),
            sequence: None,
            approach: None,
        })
    }
}

/// Every combination of one value per axis (internal units), first axis slowest.
pub(crate) fn cartesian(per_axis: &[Vec<f64>]) -> Vec<Commands> {
    let mut positions = vec![Commands::default()];
    for (k, values) in per_axis.iter().enumerate() {
        positions = positions
            .iter()
            .flat_map(|c| {
                values.iter().map(move |&v| {
                    let mut c = *c;
                    c.0[k] = v;
                    c
                })
            })
            .collect();
    }
    positions
}

impl AxisRange {
    /// One `AXIS=start:end:step` or `AXIS=value` of a grid (file units: mm or degrees).
    fn parse(part: &str) -> Result<AxisRange> {
        let place = || Place::file("plan").at_field("grid");
        let (name, spec) = part.split_once('=').ok_or_else(|| {
            Error::input(
                place(),
                format!("'{part}' is not AXIS=start:end:step or AXIS=value"),
            )
        })?;
        let mut letters = name.trim().chars();
        let axis = match (letters.next().and_then(Axis::from_letter), letters.next()) {
            (Some(a), None) => a,
            _ => {
                return Err(Error::input(
                    place(),
                    format!("'{name}' is not an axis letter"),
                ));
            }
        };
        let not_a_range = || {
            Error::input(
                place(),
                format!("'{spec}' (axis {axis}) is not start:end:step or a number"),
            )
        };
        let nums: Vec<f64> = spec
            .split(':')
            .map(|s| s.trim().parse::<f64>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| not_a_range())?;
        match nums.as_slice() {
            [v] => Ok(AxisRange {
                axis,
                start: *v,
                end: *v,
                step: 0.0,
            }),
            [s, e, st] => Ok(AxisRange {
                axis,
                start: *s,
                end: *e,
                step: *st,
            }),
            _ => Err(not_a_range()),
        }
    }

    /// The range's values on `ax` in internal units (mm, rad), or the message saying why they
    /// cannot be: not start ≤ end with a positive step, outside the travel, or more values
    /// than a plan may have (counted before anything is allocated: a step of 1e-9 mm would ask
    /// for 10¹² values).
    fn checked_values(&self, ax: &MachineAxis) -> std::result::Result<Vec<f64>, String> {
        let r = self;
        let text = || {
            format!(
                "{}:{}:{}",
                crate::error::number(r.start),
                crate::error::number(r.end),
                crate::error::number(r.step)
            )
        };
        let finite = r.start.is_finite() && r.end.is_finite() && r.step.is_finite();
        if !finite || (r.start != r.end && (r.step <= 0.0 || r.end < r.start)) {
            return Err(format!(
                "axis {}: {} is not start ≤ end with a positive step",
                ax.axis,
                text()
            ));
        }
        let (lo, hi) = (ax.to_file_units(ax.min), ax.to_file_units(ax.max));
        let tol = 1e-9 * (hi - lo).abs().max(1.0);
        if r.start < lo - tol || r.end > hi + tol {
            return Err(format!(
                "axis {}: {}..{} {} leaves the travel range [{lo}, {hi}]",
                ax.axis,
                crate::error::number(r.start),
                crate::error::number(r.end),
                ax.file_unit()
            ));
        }
        let count = if r.start == r.end {
            1.0
        } else {
            ((r.end - r.start) / r.step).floor() + 2.0
        };
        if count > MAX_PLAN_POSITIONS as f64 {
            return Err(format!(
                "axis {}: {} has {count:.3e} values; a plan has at most {MAX_PLAN_POSITIONS} \
                 positions: use a larger step",
                ax.axis,
                text()
            ));
        }
        Ok(r.values()
            .into_iter()
            .map(|v| ax.from_file_units(v))
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_ranges_parse_and_check_their_values() {
        let r = AxisRange::parse("X=0:10:5").unwrap();
        assert_eq!((r.axis, r.start, r.end, r.step), (Axis::X, 0.0, 10.0, 5.0));
        let single = AxisRange::parse(" C = 90 ").unwrap();
        assert_eq!((single.start, single.end, single.step), (90.0, 90.0, 0.0));
        assert!(AxisRange::parse("X=1:2").is_err());
        assert!(AxisRange::parse("Q=1").is_err());
        let m = Machine::default_xcfz();
        let c = &m.axes()[1];
        // Degrees in, radians out.
        let v = single.checked_values(c).unwrap();
        assert_eq!(v, vec![90f64.to_radians()]);
        let beyond = AxisRange::parse("X=0:2000:100").unwrap();
        let e = beyond.checked_values(&m.axes()[0]).unwrap_err();
        assert_eq!(e, "axis X: 0..2000 mm leaves the travel range [0, 1400]");
    }

    #[test]
    fn paper_meshes_have_the_paper_sizes() {
        let m = Machine::default_xcfz();
        let count = |n: &str| Plan::preset(&m, n).unwrap().positions.len();
        assert_eq!(count("table4"), 73); // 0..360 step 5, 360 included
        assert_eq!(count("table7"), 15 * 13);
        assert_eq!(count("test1"), 15 * 9);
        assert_eq!(count("test3"), 6 * 9 * 4); // X 0,300,…,1200,1400; C 0..360/45; Z 0,225,450,600
        assert_eq!(count("test4"), 8 * 13 * 5);
        assert_eq!(
            Plan::preset(&m, "test5").unwrap().positions,
            Plan::preset(&m, "test3").unwrap().positions
        );
    }

    #[test]
    fn ranges_include_their_end() {
        let r = AxisRange {
            axis: Axis::X,
            start: 0.0,
            end: 1400.0,
            step: 300.0,
        };
        assert_eq!(r.values(), [0.0, 300.0, 600.0, 900.0, 1200.0, 1400.0]);
        let r = AxisRange {
            axis: Axis::Z,
            start: 0.0,
            end: 600.0,
            step: 150.0,
        };
        assert_eq!(r.values(), [0.0, 150.0, 300.0, 450.0, 600.0]);
    }

    #[test]
    fn grids_from_text_and_their_errors() {
        let m = Machine::default_xcfz();
        let p = Plan::parse_grid(&m, "X=0:1400:700, Z=0:600:600, C=90").unwrap();
        assert_eq!(p.positions.len(), 3 * 2);
        assert!((p.positions[0].0[1] - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
        // First chain axis (X) slowest, last (Z) fastest.
        assert_eq!((p.positions[1].0[0], p.positions[1].0[2]), (0.0, 600.0));
        let e = |t: &str| Plan::parse_grid(&m, t).unwrap_err().to_string();
        assert!(e("X=0:1400:100,Z=0:600:50").contains("no values for axis C"));
        assert!(e("X=0:1500:100,Z=0,C=0").contains("leaves the travel range [0, 1400]"));
        assert!(e("X=0:1400:0,Z=0,C=0").contains("positive step"));
        assert!(e("X=0,Y=0,Z=0,C=0").contains("not in the machine's chain"));
        assert!(e("X=a,Z=0,C=0").contains("not start:end:step"));
        assert!(
            Plan::preset(&m, "test9")
                .unwrap_err()
                .to_string()
                .contains("table4, table7")
        );
    }
}
