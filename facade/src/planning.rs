//! Measurement planning (`volver plan`): the test that identifies what compensation needs, in the
//! points there is time for, in an order that keeps drift separable; and the study that compares
//! plans on simulated truths.
//!
//! [`plan`] chooses the poses and reflectors by an optimal-design criterion
//! ([`volver_solvers::design`]: I-optimal for the tool point over the work volume, or
//! D-optimal) among every reflector at every pose of a fine candidate grid, orders them
//! ([`volver_core::plan::order`]) with a reference pose repeated over the test, and predicts what
//! the plan will give: the U (k = 2) of the identified tool point over the volume after the
//! set-up's transform (volver's Φ estimate, [`volver_solvers::uncertainty::linear`] on the
//! plan's nominal points under the tracker's noise) and the combinations it leaves unidentified.
//! [`compare`] runs plans on simulated truths: the realised tool-point error, the coverage of
//! the predicted U, and whether a hidden drift is found.

use crate::error::{Error, Result};
use serde::Serialize;
use volver_core::machine::{Commands, Machine, ReflectorSpec};
use volver_core::measure::MeasurementSet;
use volver_core::model::Model;
use volver_core::noise::TrackerNoise;
use volver_core::plan::order::{self, Visit};
use volver_core::plan::sides::{self, Overrun};
use volver_core::plan::{AxisRange, MAX_PLAN_POSITIONS, Plan, Step};
use volver_core::problem::Problem;
use volver_core::units::{S_PER_H, UM_PER_MM};
use volver_solvers::design::{Criterion, Design, Space};
use volver_solvers::gauge::Gauge;
use volver_solvers::uncertainty::{NoiseModel, ToolGrid};

mod compare;
pub use compare::{Compared, compare};

/// The most candidate points a design weighs (their whitened rows are held in memory: 50 000
/// points of a 200-parameter model take 240 MB).
pub const MAX_CANDIDATES: usize = 50_000;

/// What to plan.
#[derive(Clone, Debug)]
pub struct Request {
    /// Measurements in the plan (the reference pose's repeats included); a bidirectional plan
    /// measures each of them twice.
    pub points: usize,
    /// The design criterion.
    pub criterion: Criterion,
    /// The tool offset compensation is for (mm, from the last tool-side axis).
    pub tool: [f64; 3],
    /// The tracker's noise.
    pub noise: TrackerNoise,
    /// Candidate values per axis: linear axes get this many evenly over their travel, full-turn
    /// rotary axes this many over the turn (the end left out: it is the start).
    pub per_axis: usize,
    /// Seed of the measuring order.
    pub seed: u64,
    /// Visits of the reference pose between the first and the last (which are visits too).
    pub repeats: usize,
    /// Measuring time per point, for the duration (s).
    pub seconds_per_point: f64,
    /// Iterations of the design algorithm at most.
    pub iterations: usize,
    /// Candidate reflector positions beside the machine's (on the last tool-side axis), which
    /// the design may choose.
    pub extra_reflectors: Vec<ReflectorSpec>,
    /// Each measurement made twice, from below then from above on every moving axis, over
    /// this overrun ([`volver_core::plan::sides`]): the design weighs each pair's information,
    /// a reversal's included; `None`: one measurement each, its directions the order's.
    pub bidirectional: Option<Overrun>,
}

impl Default for Request {
    fn default() -> Self {
        Request {
            points: 1040,
            criterion: Criterion::I,
            tool: [0.0; 3],
            noise: TrackerNoise::PAPER,
            per_axis: 13,
            seed: 1,
            repeats: 8,
            seconds_per_point: volver_core::simulate::DEFAULT_SECONDS_PER_POINT,
            iterations: 300,
            extra_reflectors: Vec::new(),
            bidirectional: None,
        }
    }
}

/// A planned test and what it promises.
#[derive(Clone, Debug)]
pub struct Planned {
    /// The plan, in measuring order.
    pub plan: Plan,
    /// The model the plan is for: the request's, on a machine with the extra reflectors the
    /// plan uses (write its machine file beside the plan: the plan names them).
    pub model: Model,
    /// What was chosen and predicted.
    pub report: Report,
}

/// What `volver plan` prints (its `--json`).
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// The criterion.
    pub criterion: Criterion,
    /// Measurements, distinct poses, reflectors used (ids).
    pub points: usize,
    /// Distinct poses.
    pub poses: usize,
    /// Reflector ids the plan uses, and the measurements of each.
    pub reflectors: Vec<(String, usize)>,
    /// Candidate points (every reflector at every candidate pose).
    pub candidates: usize,
    /// Duration at the given time per point (h).
    pub duration_h: f64,
    /// The design's equivalence ratio (1 at the optimum) and iterations.
    pub equivalence: f64,
    /// Iterations of the design algorithm.
    pub iterations: usize,
    /// The tool offset (mm).
    pub tool_mm: [f64; 3],
    /// Predicted U (k = 2) of the identified tool point over the volume after the set-up's
    /// transform, identified by the Φ estimate (the paper's, `identify`'s default): mean and
    /// largest over the grid (µm, largest coordinate at each point).
    pub u95_mean_um: f64,
    /// See `u95_mean_um`.
    pub u95_max_um: f64,
    /// The combinations the plan leaves unidentified (the gauge holds them), each as its
    /// leading parameters.
    pub unidentified: Vec<String>,
    /// The combinations no candidate identifies: a reflector elsewhere or another tool offset
    /// is needed for these.
    pub unidentifiable_by_candidates: Vec<String>,
    /// Reflector positions that would identify some of them: each with the combinations the
    /// candidates would still leave with it added (fewer than without), best first.
    pub reflector_advice: Vec<Advice>,
    /// The reference pose (file units) and its visits.
    pub reference: Vec<f64>,
    /// Visits of the reference pose (first, last and between).
    pub reference_visits: usize,
    /// The largest correlation of time with an axis function, and which.
    pub aliasing: (f64, String),
    /// Every estimator's expected RMS tool-point error over the grid (3-D, after the
    /// set-up's transform, k = 1, µm) beside the Cramér–Rao limit of the plan and noise; `None`
    /// when it cannot be formed.
    pub efficiency: Option<crate::uncertainty::EfficiencyU>,
    /// Wall time of the planning (s).
    pub time_s: f64,
    /// How a bidirectional plan approaches its poses; `None` for a plan measured once each.
    pub bidirectional: Option<BothSides>,
    /// The axes the model gives a reversal value (`[effects] reversal`).
    pub reversal_axes: Vec<String>,
}

/// How a bidirectional plan approaches its poses.
#[derive(Clone, Debug, Serialize)]
pub struct BothSides {
    /// The measurements designed, each made twice (`points` is twice this).
    pub designed: usize,
    /// Each moving axis' overrun: its letter, the overrun (mm or degrees) and whether it was
    /// clipped to half the axis' travel.
    pub overrun: Vec<(String, f64, bool)>,
    /// Each moving axis' poses approached from one side only (within the overrun of an end
    /// of its travel): its letter and the count.
    pub one_sided_poses: Vec<(String, usize)>,
}

/// A reflector position and what the candidates leave unidentified with it.
#[derive(Clone, Debug, Serialize)]
pub struct Advice {
    /// Its id (`auto+x` … for an offset from the reflectors' centroid).
    pub id: String,
    /// Its offset on the last tool-side axis (mm).
    pub offset_mm: [f64; 3],
    /// Combinations the candidate poses would leave unidentified with it.
    pub unidentified: usize,
}

/// `model` on its machine with `extra` reflectors added.
fn with_reflectors(model: &Model, extra: &[ReflectorSpec]) -> Result<Model> {
    if extra.is_empty() {
        return Ok(model.clone());
    }
    let mut spec = model.machine().spec().clone();
    let machines = spec.reflectors.len();
    for r in extra {
        if let Some(k) = spec.reflectors.iter().position(|x| x.id == r.id) {
            let whose = if k < machines {
                "one of the machine's reflectors"
            } else {
                "another candidate reflector"
            };
            return Err(Error::Mismatch(format!(
                "candidate reflector '{}' has the id of {whose}",
                r.id
            )));
        }
        spec.reflectors.push(r.clone());
    }
    let machine = Machine::from_spec(spec, "the machine with the candidate reflectors")?;
    Ok(Model::new(machine, model.spec().clone())?)
}

/// What the candidate poses leave unidentified with a reflector added at each of six positions
/// 100 mm from the reflectors' centroid along the axes of the tool-side frame, keeping those
/// that leave fewer than `base` combinations (none when `base` is 0: nothing to advise).
fn advice(model: &Model, per_axis: usize, base: usize) -> Result<Vec<Advice>> {
    if base == 0 {
        return Ok(Vec::new());
    }
    let r = model.machine().reflectors();
    let c: [f64; 3] =
        std::array::from_fn(|k| r.iter().map(|x| x.offset[k]).sum::<f64>() / r.len() as f64);
    let mut out = Vec::new();
    for i in 0..6 {
        let mut offset = c;
        offset[i / 2] += if i % 2 == 0 { 100.0 } else { -100.0 };
        let trial = ReflectorSpec {
            id: format!(
                "auto{}{}",
                if i % 2 == 0 { '+' } else { '-' },
                ['x', 'y', 'z'][i / 2]
            ),
            offset,
        };
        let m = with_reflectors(model, std::slice::from_ref(&trial))?;
        let candidates = candidate_grid(m.machine(), per_axis)?;
        let held = Nominal::of(&m, &candidates)?
            .gauge
            .map_or(0, |g| g.held.len());
        if held < base {
            out.push(Advice {
                id: trial.id,
                offset_mm: trial.offset,
                unidentified: held,
            });
        }
    }
    out.sort_by_key(|a| a.unidentified);
    Ok(out)
}

/// The candidate values per axis a plan of `machine` weighs by default: 13 (about), or fewer
/// where 13 per axis would give more than [`MAX_CANDIDATES`] candidate points with `reflectors`
/// reflectors (a five-axis machine gets 6 with three reflectors).
///
/// ```
/// let five = volver_core::presets::named("head-head").unwrap().machine().unwrap();
/// assert_eq!(volver::planning::default_per_axis(&five, 3).unwrap(), 6);
/// let xcfz = volver_core::machine::Machine::default_xcfz();
/// assert_eq!(volver::planning::default_per_axis(&xcfz, 2).unwrap(), 13);
/// ```
pub fn default_per_axis(machine: &Machine, reflectors: usize) -> Result<usize> {
    for n in (2..=13).rev() {
        if candidate_grid(machine, n)?.positions.len() * reflectors.max(1) <= MAX_CANDIDATES {
            return Ok(n);
        }
    }
    Ok(2)
}

/// The candidate grid: about `per_axis` values over each axis' travel, at a round step (1, 2,
/// 2.5 or 5 times a power of ten in file units, the nearest to an even division; the end of the
/// travel is always a candidate), a full turn at a divisor of 360° without its end.
///
/// ```
/// let m = volver_core::machine::Machine::default_xcfz();
/// let g = volver::planning::candidate_grid(&m, 13).unwrap();
/// // X 0…1400 step 100, C 0…330 step 30, Z 0…600 step 50.
/// assert_eq!(g.positions.len(), 15 * 12 * 13);
/// ```
pub fn candidate_grid(machine: &Machine, per_axis: usize) -> Result<Plan> {
    let per_axis = per_axis.max(2);
    let round_step = |raw: f64| {
        let p = 10f64.powf(raw.log10().floor());
        [1.0, 2.0, 2.5, 5.0, 10.0]
            .iter()
            .map(|m| m * p)
            .min_by(|a, b| (a - raw).abs().total_cmp(&(b - raw).abs()))
            .unwrap_or(raw)
    };
    let ranges: Vec<AxisRange> = machine
        .axes()
        .iter()
        .map(|ax| {
            let (a, b) = (ax.to_file_units(ax.min), ax.to_file_units(ax.max));
            let full_turn = ax.axis.is_rotary() && (b - a) >= 360.0 - 1e-9;
            let span = b - a;
            let step = if span <= 0.0 {
                0.0
            } else if full_turn {
                // A divisor of the turn, so that the values repeat turn after turn.
                let raw = span / per_axis as f64;
                [5.0, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 90.0]
                    .into_iter()
                    .min_by(|a, b| (a - raw).abs().total_cmp(&(b - raw).abs()))
                    .unwrap_or(raw)
            } else {
                round_step(span / (per_axis - 1) as f64)
            };
            let end = if full_turn { b - step } else { b };
            AxisRange {
                axis: ax.axis,
                start: a,
                end: if step > 0.0 { end } else { a },
                step,
            }
        })
        .collect();
    Ok(Plan::grid(machine, &ranges)?)
}

/// A plan's nominal points and its gauge there (what the plan leaves unidentified).
struct Nominal {
    data: MeasurementSet,
    gauge: Option<Gauge>,
}

impl Nominal {
    fn of(model: &Model, plan: &Plan) -> Result<Nominal> {
        let data = volver_solvers::observability::nominal_data(model, plan);
        let p0 = model.initial_params();
        let gauge = {
            let task = volver_solvers::Task::new(Problem::new(model, &data)?);
            volver_solvers::gauge::gauge(&task, &p0, &p0, volver_solvers::gauge::TOLERANCE)
        };
        Ok(Nominal { data, gauge })
    }

    /// Every estimator's expected error on the tool point `tool` over `grid` beside the
    /// Cramér–Rao limit of the plan under `noise` (see [`volver_solvers::efficiency`]).
    fn efficiency(
        &self,
        model: &Model,
        noise: &TrackerNoise,
        tool: [f64; 3],
        grid: &[Commands],
    ) -> Result<Option<crate::uncertainty::EfficiencyU>> {
        let problem = Problem::new(model, &self.data)?;
        let tg = ToolGrid {
            commands: grid.to_vec(),
            tool,
        };
        Ok(volver_solvers::efficiency::compare(
            &problem,
            self.gauge.as_ref(),
            &model.initial_params(),
            NoiseModel::Tracker(*noise),
            &tg,
        )
        .as_ref()
        .map(crate::uncertainty::EfficiencyU::from))
    }

    /// The predicted U (k = 2, µm) of the tool point `tool` over `grid` after the set-up's
    /// transform for the plan identified by volver's Φ estimate under `noise`: mean and
    /// largest of each point's largest coordinate.
    fn predicted_u(
        &self,
        model: &Model,
        noise: &TrackerNoise,
        tool: [f64; 3],
        grid: &[Commands],
    ) -> Result<(f64, f64)> {
        let problem = Problem::new(model, &self.data)?;
        let p0 = model.initial_params();
        let cov = volver_solvers::uncertainty::linear(
            &problem,
            self.gauge.as_ref(),
            &p0,
            volver_solvers::Objective::Phi,
            NoiseModel::Tracker(*noise),
        )
        .ok_or_else(|| Error::Singular("the plan's covariance could not be computed".into()))?;
        let tg = ToolGrid {
            commands: grid.to_vec(),
            tool,
        };
        let us: Vec<f64> = tg
            .uncertainty(model, &p0, &cov, true)
            .iter()
            .map(|u| u.u95_max_mm() * UM_PER_MM)
            .collect();
        let mean = us.iter().sum::<f64>() / us.len().max(1) as f64;
        Ok((mean, us.iter().copied().fold(0.0, f64::max)))
    }
}

/// The duration (h) of `n` measurements at `seconds_per_point` from every station of `model`
/// (each measures the plan).
fn duration_h(model: &Model, n: usize, seconds_per_point: f64) -> f64 {
    (n * model.machine().stations().len()) as f64 * seconds_per_point / S_PER_H
}

/// Refuses a reflector list that names a reflector twice (`test4/R1+R1`): a plan measures each
/// of its reflectors at every pose once.
pub fn check_distinct_reflectors(machine: &Machine, reflectors: &[usize]) -> Result<()> {
    for (i, r) in reflectors.iter().enumerate() {
        if reflectors[..i].contains(r) {
            return Err(Error::Mismatch(format!(
                "reflector {} is named twice: each reflector of a plan is measured once per pose",
                machine.reflectors()[*r].id
            )));
        }
    }
    Ok(())
}

impl Request {
    /// Refuses requests a plan cannot serve, before anything is allocated for them: 1 …
    /// 1 000 000 measurements ([`MAX_PLAN_POSITIONS`], as a plan file), at least 2 candidate
    /// positions per axis (one measures no error of an axis: the design's ratio went to 3e9),
    /// visits of the reference pose that leave room for the design, a positive measuring time
    /// per point, a finite tool offset and a tracker noise (without it every design is equally
    /// good), at least one iteration of the design. [`plan`] calls it first.
    ///
    /// ```
    /// use volver::planning::Request;
    /// assert!(Request::default().validate().is_ok());
    /// let too_few = Request { per_axis: 1, ..Request::default() };
    /// assert!(too_few.validate().unwrap_err().to_string().starts_with("--per-axis 1"));
    /// ```
    ///
    /// [`MAX_PLAN_POSITIONS`]: volver_core::plan::MAX_PLAN_POSITIONS
    pub fn validate(&self) -> Result<()> {
        check_seconds_per_point(self.seconds_per_point)?;
        if !(1..=MAX_PLAN_POSITIONS).contains(&self.points) {
            return Err(Error::Request(format!(
                "{} measurements: a plan has 1 … {MAX_PLAN_POSITIONS} (--points, or --hours × \
                 3600 / --seconds-per-point per station)",
                self.points
            )));
        }
        if self.per_axis < 2 {
            return Err(Error::Request(format!(
                "--per-axis {}: at least 2 candidate positions per axis (a single one measures \
                 no error of the axis)",
                self.per_axis
            )));
        }
        if self.repeats >= self.points {
            return Err(Error::Request(format!(
                "--repeats {}: the reference pose's visits must leave room in a plan of {} \
                 measurements",
                self.repeats, self.points
            )));
        }
        if !self.tool.iter().all(|c| c.is_finite()) {
            return Err(Error::Request(format!(
                "tool offset {:?} mm: three finite numbers",
                self.tool
            )));
        }
        if self.iterations == 0 {
            return Err(Error::Request(
                "0 iterations of the design algorithm: at least 1".into(),
            ));
        }
        if self.noise.is_none() {
            return Err(Error::Request(
                "planning needs the tracker's noise (--noise or the machine file's [tracker] \
                 noise): without it every design is equally good"
                    .into(),
            ));
        }
        Ok(())
    }

    /// The measurements that `hours` of measuring give at `seconds_per_point` when each of
    /// `stations` stations measures the plan (`--hours`).
    ///
    /// ```
    /// use volver::planning::Request;
    /// assert_eq!(Request::points_for_hours(2.0, 6.0, 1).unwrap(), 1200);
    /// assert!(Request::points_for_hours(-1.0, 6.0, 1).is_err());
    /// ```
    pub fn points_for_hours(hours: f64, seconds_per_point: f64, stations: usize) -> Result<usize> {
        check_seconds_per_point(seconds_per_point)?;
        if stations == 0 {
            return Err(Error::Request(
                "0 stations: a plan is measured by one station at least".into(),
            ));
        }
        if !(hours.is_finite() && hours > 0.0) {
            return Err(Error::Request(format!(
                "--hours {hours}: a positive number of hours"
            )));
        }
        Ok((hours * S_PER_H / seconds_per_point / stations as f64) as usize)
    }
}

/// `--seconds-per-point` must be a positive number of seconds.
fn check_seconds_per_point(seconds: f64) -> Result<()> {
    if !(seconds.is_finite() && seconds > 0.0) {
        return Err(Error::Request(format!(
            "--seconds-per-point {seconds}: a positive number of seconds"
        )));
    }
    Ok(())
}

/// Plans a test of `request.points` measurements for `model` (see the module documentation).
pub fn plan(model: &Model, request: &Request) -> Result<Planned> {
    request.validate()?;
    let t0 = std::time::Instant::now();
    let (given, full) = (model, with_reflectors(model, &request.extra_reflectors)?);
    let model = &full;
    let machine = model.machine();
    let candidates = checked_candidates(machine, request)?;
    let grid = crate::shared::default_grid(machine, 5)?;
    let (weighed, space) = design_space(model, &candidates, request, &grid.positions)?;
    let (reference, design) = reference_and_design(&space, request, &candidates)?;
    let visits_of_reference = request.repeats + 2;
    let (sequence, _) = order::sequence(
        machine,
        &candidates.positions,
        visits_of(
            &candidates.steps(),
            &design.counts,
            candidates.positions.len(),
        ),
        Some((reference.clone(), request.repeats)),
        request.seed,
        50,
    );
    let planned = compact(
        &candidates.positions,
        &sequence,
        format!(
            "{}-optimal, {} points",
            request.criterion.letter(),
            request.points
        ),
    );
    let designed = planned.n_points();
    let (planned, bidirectional) = both_sides(machine, planned, request.bidirectional.as_ref())?;
    let nominal = Nominal::of(model, &planned)?;
    let ((u95_mean_um, u95_max_um), efficiency) = (
        nominal.predicted_u(model, &request.noise, request.tool, &grid.positions)?,
        nominal.efficiency(model, &request.noise, request.tool, &grid.positions)?,
    );
    let unidentified = crate::shared::held_text(model, nominal.gauge.as_ref());
    let unidentifiable_by_candidates =
        crate::shared::held_text(model, Nominal::of(model, &weighed)?.gauge.as_ref());
    // Advice for what the candidates cannot identify (the request's extra reflectors are
    // candidates already).
    let reflector_advice = advice(model, request.per_axis, unidentifiable_by_candidates.len())?;
    let plan_model = plan_model(given, machine, &request.extra_reflectors, &planned)?;
    let n = planned.n_points();
    Ok(Planned {
        report: Report {
            criterion: request.criterion,
            points: n,
            poses: planned.positions.len(),
            reflectors: reflector_counts(machine, &planned),
            candidates: space.len(),
            duration_h: duration_h(model, n, request.seconds_per_point),
            equivalence: design.equivalence,
            iterations: design.iterations,
            tool_mm: request.tool,
            u95_mean_um,
            u95_max_um,
            unidentified,
            unidentifiable_by_candidates,
            reflector_advice,
            reference: file_units_rounded(machine, &candidates.positions[reference.position]),
            reference_visits: visits_of_reference,
            aliasing: order::aliasing(machine, &planned.positions, &planned.steps()),
            efficiency,
            time_s: t0.elapsed().as_secs_f64(),
            bidirectional: bidirectional.map(|b| BothSides { designed, ..b }),
            reversal_axes: reversal_axes(model),
        },
        plan: reindex(planned, machine, plan_model.machine()),
        model: plan_model,
    })
}

/// The axes `model` gives a reversal value (`[effects] reversal`).
fn reversal_axes(model: &Model) -> Vec<String> {
    let reversal = &model.spec().effects.reversal;
    reversal.iter().map(|r| r.axis().to_string()).collect()
}

/// The candidates the design weighs (a bidirectional plan's in pairs: each point approached
/// from each side, [`pairs`]) and their information.
fn design_space(
    model: &Model,
    candidates: &Plan,
    request: &Request,
    grid: &[Commands],
) -> Result<(Plan, Space)> {
    let weighed = match &request.bidirectional {
        Some(overrun) => pairs(model.machine(), candidates, overrun)?,
        None => candidates.clone(),
    };
    let group = weighed.n_points() / candidates.n_points().max(1);
    let space = Space::grouped(model, (&weighed, group), &request.noise, request.tool, grid)
        .ok_or_else(|| {
            Error::Singular(
                "the candidates' Jacobians are not finite at the nominal machine".into(),
            )
        })?;
    Ok((weighed, space))
}

/// Every step of `candidates` twice, from below then from above on every axis that moves
/// among them ([`sides::sides`]): the candidates of a bidirectional design, in pairs.
fn pairs(machine: &Machine, candidates: &Plan, overrun: &Overrun) -> Result<Plan> {
    overrun.check()?;
    let moving = sides::moving_axes(machine, &candidates.positions);
    let per_axis = overrun.per_axis(machine);
    let steps = candidates.steps();
    let mut sequence = Vec::with_capacity(2 * steps.len());
    let mut approach = Vec::with_capacity(2 * steps.len());
    for s in &steps {
        for a in sides::sides(
            machine,
            &candidates.positions[s.position],
            &moving,
            &per_axis,
        ) {
            sequence.push(*s);
            approach.push(a);
        }
    }
    Ok(Plan {
        name: format!("{} in pairs", candidates.name),
        sequence: Some(sequence),
        approach: Some(approach),
        ..candidates.clone()
    })
}

/// `planned` measured from both sides when `overrun` is given ([`Plan::bidirectional`]), with
/// how (its `designed` left to the caller); else as it is.
fn both_sides(
    machine: &Machine,
    planned: Plan,
    overrun: Option<&Overrun>,
) -> Result<(Plan, Option<BothSides>)> {
    let Some(overrun) = overrun else {
        return Ok((planned, None));
    };
    let both = planned.bidirectional(machine, overrun)?;
    let moving = sides::moving_axes(machine, &both.positions);
    let ends = sides::one_sided(&both, machine, overrun);
    let mut report = BothSides {
        designed: 0,
        overrun: Vec::new(),
        one_sided_poses: Vec::new(),
    };
    for (k, ax) in machine
        .axes()
        .iter()
        .enumerate()
        .filter(|&(k, _)| moving[k])
    {
        let (o, clipped) = overrun.on(ax);
        let letter = ax.axis.to_string();
        report
            .overrun
            .push((letter.clone(), ax.to_file_units(o), clipped));
        report.one_sided_poses.push((letter, ends[k]));
    }
    Ok((both, Some(report)))
}

/// The reference pose and the design of what is left: the reference pose's visits come out of
/// the budget, so a first design tells which pose it is (the one the design measures most) and
/// the second is made for the measurements left.
fn reference_and_design(
    space: &Space,
    request: &Request,
    candidates: &Plan,
) -> Result<(Visit, Design)> {
    let steps = candidates.steps();
    let first = space
        .design(request.points, request.criterion, request.iterations)
        .ok_or_else(|| Error::Singular("the design's information matrix is singular".into()))?;
    let reference = reference_of(&steps, &first.counts, candidates.positions.len());
    let reserved = (request.repeats + 2) * reference.reflectors.len();
    if reserved >= request.points {
        return Err(Error::Request(format!(
            "{} points leave nothing beside the reference pose's {reserved} measurements",
            request.points
        )));
    }
    let design = space
        .design(
            request.points - reserved,
            request.criterion,
            request.iterations,
        )
        .ok_or_else(|| Error::Singular("the design's information matrix is singular".into()))?;
    Ok((reference, design))
}

/// The candidate grid of the request's `per_axis` positions per axis, refused beyond
/// [`MAX_CANDIDATES`] points, or when a station's noise has σ = 0 for what it measures.
fn checked_candidates(machine: &Machine, request: &Request) -> Result<Plan> {
    crate::shared::check_station_noises(machine, &request.noise)?;
    let per_axis = request.per_axis;
    let candidates = candidate_grid(machine, per_axis)?;
    let sides = if request.bidirectional.is_some() {
        2
    } else {
        1
    };
    if sides * candidates.n_points() > MAX_CANDIDATES {
        return Err(Error::Request(format!(
            "{} candidate points ({} poses × {} reflectors{}): at most {MAX_CANDIDATES}; use a \
             smaller --per-axis",
            sides * candidates.n_points(),
            candidates.positions.len(),
            candidates.reflectors.len(),
            if sides == 2 { " × 2 sides" } else { "" }
        )));
    }
    Ok(candidates)
}

/// The reference pose of a design (`counts` per candidate step): the pose it measures most
/// (the first on a tie), visited with the reflectors the design measures there.
fn reference_of(steps: &[Step], counts: &[usize], n_positions: usize) -> Visit {
    let mut per_pose = vec![0usize; n_positions];
    for (s, &c) in steps.iter().zip(counts) {
        per_pose[s.position] += c;
    }
    let position = (0..per_pose.len())
        .max_by_key(|&p| (per_pose[p], std::cmp::Reverse(p)))
        .unwrap_or(0);
    let reflectors = steps
        .iter()
        .zip(counts)
        .filter(|(s, c)| s.position == position && **c > 0)
        .map(|(s, _)| s.reflector)
        .collect();
    Visit {
        position,
        reflectors,
    }
}

/// The visits of a design (`counts` per candidate step): a pose measured k times at a reflector
/// is visited k times, each visit measuring the reflectors with visits left.
fn visits_of(steps: &[Step], counts: &[usize], n_positions: usize) -> Vec<Visit> {
    let mut visits = Vec::new();
    for pose in 0..n_positions {
        let mine: Vec<(usize, usize)> = steps
            .iter()
            .zip(counts)
            .filter(|(s, c)| s.position == pose && **c > 0)
            .map(|(s, c)| (s.reflector, *c))
            .collect();
        let most = mine.iter().map(|m| m.1).max().unwrap_or(0);
        for k in 0..most {
            visits.push(Visit {
                position: pose,
                reflectors: mine.iter().filter(|m| m.1 > k).map(|m| m.0).collect(),
            });
        }
    }
    visits
}

/// The plan's model: the `given` machine with those of the `extra` reflectors that the plan
/// (reflector indices of `machine`) measures.
fn plan_model(
    given: &Model,
    machine: &Machine,
    extra: &[ReflectorSpec],
    planned: &Plan,
) -> Result<Model> {
    let used_extra: Vec<ReflectorSpec> = extra
        .iter()
        .filter(|r| {
            machine
                .reflector_index(&r.id)
                .is_some_and(|i| planned.reflectors.contains(&i))
        })
        .cloned()
        .collect();
    with_reflectors(given, &used_extra)
}

/// Each reflector the plan measures, with its number of measurements.
fn reflector_counts(machine: &Machine, planned: &Plan) -> Vec<(String, usize)> {
    let steps = planned.steps();
    planned
        .reflectors
        .iter()
        .map(|&r| {
            (
                machine.reflectors()[r].id.clone(),
                steps.iter().filter(|s| s.reflector == r).count(),
            )
        })
        .collect()
}

/// A pose in file units (mm, degrees) rounded to 1e-9, without the radians' round trip
/// (29.999999999999996°).
fn file_units_rounded(machine: &Machine, pose: &Commands) -> Vec<f64> {
    machine
        .axes()
        .iter()
        .enumerate()
        .map(|(k, ax)| (ax.to_file_units(pose.0[k]) * 1e9).round() / 1e9)
        .collect()
}

/// `plan` (reflector indices of `from`) with the indices of the same reflector ids in `to`.
fn reindex(mut plan: Plan, from: &Machine, to: &Machine) -> Plan {
    let map = |r: usize| to.reflector_index(&from.reflectors()[r].id).unwrap_or(r);
    plan.reflectors = plan.reflectors.iter().map(|&r| map(r)).collect();
    if let Some(seq) = &mut plan.sequence {
        for s in seq.iter_mut() {
            s.reflector = map(s.reflector);
        }
    }
    plan
}

/// A plan of `sequence` over `positions` keeping only the positions it visits, in order of first
/// visit.
fn compact(positions: &[Commands], sequence: &[Step], name: String) -> Plan {
    let mut index = vec![usize::MAX; positions.len()];
    let mut kept = Vec::new();
    let mut reflectors = Vec::new();
    let steps = sequence
        .iter()
        .map(|s| {
            if index[s.position] == usize::MAX {
                index[s.position] = kept.len();
                kept.push(positions[s.position]);
            }
            if !reflectors.contains(&s.reflector) {
                reflectors.push(s.reflector);
            }
            Step {
                position: index[s.position],
                reflector: s.reflector,
            }
        })
        .collect();
    reflectors.sort_unstable();
    Plan {
        name,
        positions: kept,
        reflectors,
        sequence: Some(steps),
        approach: None,
    }
}
