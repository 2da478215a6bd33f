//! Identification strategies, for any engine.
//!
//! **Phases** (paper, table 1): which parameter groups each phase identifies; the others are
//! held at their current values. The tracker pose and extra effects (group `other`) are
//! identified in every phase.
//!
//! | name | phases |
//! |---|---|
//! | `one` | squareness + translation + rotation |
//! | `two` | squareness · translation + rotation (table 1, "2 phases") |
//! | `tr` | squareness + translation · rotation (tables 6, 8, "2 phases TR") |
//! | `rt` | squareness + rotation · translation (tables 6, 8, "2 phases RT") |
//! | `three-tr` | squareness · translation · rotation |
//! | `three-rt` | squareness · rotation · translation |
//!
//! **Sub-loops** (fig. 14): the phase sequence is repeated, each pass with its own solves,
//! until a pass no longer lowers the EMM (relative 1e-9) or the count is reached.
//!
//! **Methods** (section 5.3, tables 11–12): [`identify`] on one data set (joint);
//! [`independent`] (tests 1 + 2: the linear-axis errors from one set, the rotary-axis errors
//! from another, each alone); [`combined`] (test 5: the linear-axis errors from one set held
//! while the rotary-axis errors are identified on another); [`cross_validate`] (the
//! compensated error of a reference set, with only its tracker pose fitted, table 12).

use crate::engines::gauge::Gauge;
use crate::engines::init::init_tracker;
use crate::options::Options;
use crate::summary::{Evaluation, Summary, Termination};
use crate::{Observer, Solution, Solver, Task, evaluate, same_bits};
use serde::Serialize;
use std::time::Instant;
use volver_core::iso::Group;
use volver_core::model::{Model, Owner, ParamInfo};
use volver_core::problem::{Problem, Residuals};

/// The phase sequences of table 1 and tables 6 and 8.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum Phasing {
    /// Everything at once.
    #[default]
    One,
    /// Squareness, then translation and rotation.
    Two,
    /// Squareness and translation, then rotation.
    Tr,
    /// Squareness and rotation, then translation.
    Rt,
    /// Squareness, translation, rotation.
    ThreeTr,
    /// Squareness, rotation, translation.
    ThreeRt,
}

/// Names accepted by [`Phasing::parse`].
pub const PHASINGS: [&str; 6] = ["one", "two", "tr", "rt", "three-tr", "three-rt"];

impl Phasing {
    /// From its name (see the module table).
    pub fn parse(s: &str) -> Result<Phasing, crate::Error> {
        Ok(match s {
            "one" | "1" => Phasing::One,
            "two" | "2" => Phasing::Two,
            "tr" => Phasing::Tr,
            "rt" => Phasing::Rt,
            "three-tr" => Phasing::ThreeTr,
            "three-rt" => Phasing::ThreeRt,
            _ => {
                return Err(crate::Error::UnknownPhasing {
                    name: s.to_string(),
                    known: &PHASINGS,
                });
            }
        })
    }

    /// Its name.
    pub fn name(self) -> &'static str {
        PHASINGS[self as usize]
    }

    /// The groups identified in each phase (besides the tracker and `other`, always free).
    pub fn phases(self) -> Vec<Vec<Group>> {
        use Group::{Rotation as R, Squareness as S, Translation as T};
        match self {
            Phasing::One => vec![vec![S, T, R]],
            Phasing::Two => vec![vec![S], vec![T, R]],
            Phasing::Tr => vec![vec![S, T], vec![R]],
            Phasing::Rt => vec![vec![S, R], vec![T]],
            Phasing::ThreeTr => vec![vec![S], vec![T], vec![R]],
            Phasing::ThreeRt => vec![vec![S], vec![R], vec![T]],
        }
    }
}

/// A strategy: phases, sub-loops and whether the tracker pose is first fitted rigidly.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Strategy {
    /// The phase sequence.
    pub phasing: Phasing,
    /// How many times the sequence may run (≥ 1).
    pub subloops: usize,
    /// Start the tracker pose from a rigid best fit ([`init_tracker`]).
    pub init_tracker: bool,
    /// Hold the combinations the design cannot identify by the stated rule of
    /// [`crate::engines::gauge`] (machine problems only). Without it, their values are wherever the
    /// engine stopped.
    pub gauge: bool,
}

impl Default for Strategy {
    fn default() -> Self {
        Strategy {
            phasing: Phasing::One,
            subloops: 1,
            init_tracker: true,
            gauge: true,
        }
    }
}

/// The outcome of a strategy: parameters and one summary per solve.
#[derive(Clone, Debug)]
pub struct Identification {
    /// The identified parameters.
    pub params: Vec<f64>,
    /// One summary per phase solved, in order.
    pub phases: Vec<Summary>,
    /// At the start, after the tracker's rigid fit: the uncompensated machine.
    pub initial: Evaluation,
    /// What the identification reached, at its end.
    pub reached: Evaluation,
    /// How the last solve ended (or why the strategy could not start).
    pub termination: Termination,
    /// Wall time (s).
    pub time_s: f64,
    /// The gauge the fit honoured ([`Strategy::gauge`]; `None` without it or when the design
    /// could not be analysed).
    pub gauge: Option<Gauge>,
    /// Why the gauge [`Strategy::gauge`] asked for could not be formed (the fit then went on
    /// without it, and says so): `None` when it was formed or not asked for.
    pub gauge_failed: Option<String>,
}

/// Why [`crate::engines::gauge::gauge`] gave nothing: its pass or its decomposition failed.
pub const GAUGE_FAILED: &str = "the design's information at the reference could not be formed \
    (a Jacobian that is not finite there) or decomposed";

impl Identification {
    /// Final EMM as a percentage of the initial EMM.
    /// 0 when the initial EMM is already 0 (nothing to reduce), never NaN.
    pub fn residual_percent(&self) -> f64 {
        let (a, b) = (self.reached.stats.emm_um, self.initial.stats.emm_um);
        if b > 0.0 { 100.0 * a / b } else { 0.0 }
    }

    /// Steps tried over every phase.
    pub fn iterations(&self) -> usize {
        self.phases.iter().map(|s| s.iterations).sum()
    }

    /// Evaluations over every phase.
    pub fn evaluations(&self) -> usize {
        self.phases.iter().map(|s| s.evaluations).sum()
    }
}

/// Which axes' errors a method may identify.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorScope {
    /// Every modelled error.
    All,
    /// Errors of linear axes (squareness included).
    Linear,
    /// Errors of rotary axes.
    Rotary,
    /// None: only the measurement's parameters ([`Model::is_measurement_param`]: the tracker's
    /// and stations' poses, reflector offsets, range scale, the test's drift terms), never the
    /// machine's geometry.
    None,
}

/// Whether parameter `j` (`info`) of `model` is an error of the given kind of axis; the tracker
/// and `other` parameters are always eligible, but for [`ErrorScope::None`], which takes the
/// measurement's parameters alone ([`Model::is_measurement_param`]).
fn eligible(model: &Model, j: usize, info: &ParamInfo, errors: ErrorScope) -> bool {
    if errors == ErrorScope::None {
        return model.is_measurement_param(j);
    }
    if matches!(info.group, Group::Tracker | Group::Other) {
        return true;
    }
    let rotary = match info.owner {
        Owner::Term { term, .. } => model.terms()[term].id.axis().is_rotary(),
        Owner::Tracker(_) | Owner::Station { .. } | Owner::Effect(_) => return true,
        // An owner to come is not an error of an axis: kept, as the tracker and effects are.
        _ => return true,
    };
    match errors {
        ErrorScope::All => true,
        ErrorScope::Linear => !rotary,
        ErrorScope::Rotary => rotary,
        ErrorScope::None => false,
    }
}

/// Runs a strategy on one data set, identifying the errors `errors` allows (the others stay at
/// their `start` values).
pub fn identify_errors(
    solver: &dyn Solver,
    problem: Problem,
    start: &[f64],
    errors: ErrorScope,
    strategy: &Strategy,
    options: &Options,
    observer: &mut dyn Observer,
) -> Identification {
    let mut run = Run::new(problem, start, errors, strategy);
    if let Err(refused) = run.prepare() {
        return run.finish(refused);
    }
    run.loops(solver, options, observer);
    run.onto_common_gauge();
    let termination = run.termination.clone();
    run.finish(termination)
}

/// A strategy's run on one data set ([`identify_errors`]): what it has reached so far.
struct Run<'a, 'p> {
    /// When the run started.
    t0: Instant,
    /// The problem.
    problem: Problem<'p>,
    /// Its model.
    model: &'p Model,
    /// The errors the run may identify.
    errors: ErrorScope,
    /// The strategy.
    strategy: &'a Strategy,
    /// The parameters reached.
    p: Vec<f64>,
    /// Whether the tracker (and stations) in `p` are the rigid fit to p's errors: the gauge's
    /// reference then needs no fit of its own while p's errors are at theirs.
    fitted: bool,
    /// The first phase's start, after the tracker's rigid fit.
    first_start: Vec<f64>,
    /// The evaluation at `first_start`: the first phase's own when it starts there (the usual
    /// case: one evaluation of the start, not two), else evaluated when first needed.
    initial: std::cell::OnceCell<Evaluation>,
    /// One summary per phase solved.
    phases: Vec<Summary>,
    /// How the last solve ended.
    termination: Termination,
    /// The evaluation at `p` when it is known (a phase's result).
    at_p: Option<Evaluation>,
    /// The gauge the fit honours.
    gauge: Option<Gauge>,
    /// Why a gauge asked for could not be formed.
    gauge_failed: Option<String>,
}

impl<'a, 'p> Run<'a, 'p> {
    /// A run of `strategy` on `problem` from `start`, identifying the errors `errors` allows.
    fn new(
        problem: Problem<'p>,
        start: &[f64],
        errors: ErrorScope,
        strategy: &'a Strategy,
    ) -> Run<'a, 'p> {
        Run {
            t0: Instant::now(),
            model: problem.model(),
            problem,
            errors,
            strategy,
            p: start.to_vec(),
            fitted: false,
            first_start: start.to_vec(),
            initial: std::cell::OnceCell::new(),
            phases: Vec::new(),
            termination: Termination::NoFreeParameters,
            at_p: None,
            gauge: None,
            gauge_failed: None,
        }
    }

    /// Checks the strategy and the data and fits the tracker rigidly when the strategy asks
    /// for it; the termination that refuses the run when it cannot start (no sub-loop, a rigid
    /// fit refused, a mesh too small for the model).
    fn prepare(&mut self) -> Result<(), Termination> {
        if self.strategy.subloops == 0 {
            return Err(Termination::InvalidInput(crate::Invalid::NoSubloop));
        }
        if self.strategy.init_tracker {
            let q = init_tracker(&self.problem, &self.p)
                .map_err(|e| Termination::InvalidInput(crate::Invalid::Refused(e)))?;
            self.p = q;
            self.fitted = true;
        }
        self.first_start.clone_from(&self.p);
        // A mesh too small for the model: fewer equations (3 per point) than free parameters (at
        // least the eligible ones less one per constraint) can identify nothing reliably.
        let (model, errors) = (self.model, self.errors);
        let eligible_count = model
            .params()
            .iter()
            .enumerate()
            .filter(|(j, info)| eligible(model, *j, info, errors))
            .count();
        let free = eligible_count.saturating_sub(model.constraints().rows.len());
        // Distinct poses only: a point measured twice adds no equation about the machine.
        let needed = (MIN_EQUATIONS_PER_PARAMETER * free).div_ceil(3);
        distinct_poses(&self.problem, needed).map_err(|distinct| {
            Termination::InvalidInput(crate::Invalid::MeshTooSmall {
                distinct,
                points: self.problem.n_points(),
                free,
                per_parameter: MIN_EQUATIONS_PER_PARAMETER,
            })
        })
    }

    /// The evaluation at the first phase's start.
    fn initial(&self) -> Evaluation {
        *self
            .initial
            .get_or_init(|| evaluate(&self.problem, &self.first_start))
    }

    /// The sub-loops: the phase sequence, again while a pass lowers the EMM (relative 1e-9)
    /// and the count allows, until a solve fails.
    fn loops(&mut self, solver: &dyn Solver, options: &Options, observer: &mut dyn Observer) {
        // EMM at the end of the previous loop (the initial one before the first).
        let mut emm: Option<f64> = None;
        'loops: for pass in 0..self.strategy.subloops {
            for groups in self.strategy.phasing.phases() {
                if !self.solve_phase(&groups, pass, (solver, options), observer) {
                    break 'loops;
                }
            }
            let before = emm.unwrap_or_else(|| self.initial().stats.emm_um);
            let now = self
                .at_p
                .unwrap_or_else(|| evaluate(&self.problem, &self.p))
                .stats
                .emm_um;
            if before - now <= 1e-9 * before {
                break;
            }
            emm = Some(now);
        }
    }

    /// One phase of sub-loop `pass`: the parameters of `groups` (and the tracker's and
    /// `other`, always) solved from `p` with the others held, under the phase's own gauge
    /// when the strategy asks for one. `false` when the solve failed.
    fn solve_phase(
        &mut self,
        groups: &[Group],
        pass: usize,
        (solver, options): (&dyn Solver, &Options),
        observer: &mut dyn Observer,
    ) -> bool {
        let (model, errors) = (self.model, self.errors);
        let free = |j: usize, info: &ParamInfo| {
            eligible(model, j, info, errors)
                && (matches!(info.group, Group::Tracker | Group::Other)
                    || groups.contains(&info.group))
        };
        let names: Vec<String> = groups.iter().map(ToString::to_string).collect();
        let label = if self.strategy.subloops > 1 {
            format!("{} (loop {})", names.join("+"), pass + 1)
        } else {
            names.join("+")
        };
        let task = Task::holding(
            self.problem.clone(),
            |j, info| !free(j, info),
            &self.p,
            &label,
        );
        let phase_gauge = if self.strategy.gauge {
            self.phase_gauge(&task, free)
        } else {
            None
        };
        // Solved under the gauge's constraints, from the start moved onto it: the engine
        // never wanders along what the data cannot see.
        let (phase_task, phase_start) = match &phase_gauge {
            Some(g) => (g.apply(&task), g.project(&self.p)),
            None => (task.clone(), self.p.clone()),
        };
        let mut sol = solver.solve(&phase_task, &phase_start, options, observer);
        if same_bits(&phase_start, &self.first_start) {
            let _ = self.initial.set(sol.summary.initial);
        }
        if let Some(g) = phase_gauge
            && !sol.summary.termination.failed()
        {
            sol = onto_gauge(&task, &g, sol, options);
            self.gauge = Some(g);
        }
        self.termination = sol.summary.termination.clone();
        let failed = self.termination.failed();
        self.phases.push(sol.summary);
        if failed {
            return false;
        }
        self.p = sol.params;
        self.at_p = self.phases.last().map(|s: &Summary| s.reached);
        self.fitted = false;
        true
    }

    /// The phase's own gauge for `task` (the parameters `free` accepts solved): its free
    /// errors' reference is zero (the held ones stay where the phase holds them), the tracker's
    /// the rigid fit to that; the directions are those the design cannot identify there. A
    /// start that is the reference but for the tracker's last bits (every free error at its
    /// initial value: the usual start) is moved to the reference itself, the same rigid fit,
    /// so that the engine takes the gauge's pass there as its first.
    fn phase_gauge(
        &mut self,
        task: &Task,
        free: impl Fn(usize, &ParamInfo) -> bool,
    ) -> Option<Gauge> {
        let reference = gauge_reference(&self.problem, &self.p, free, self.fitted);
        let t = self.model.tracker_start();
        let off_tracker = |j: usize| !(t..t + 6).contains(&j);
        if (0..self.p.len())
            .filter(|&j| off_tracker(j))
            .all(|j| self.p[j].to_bits() == reference[j].to_bits())
        {
            self.p.clone_from(&reference);
        }
        let g = crate::engines::gauge::gauge(
            task,
            &reference,
            &reference,
            crate::engines::gauge::TOLERANCE,
        );
        if g.is_none() {
            self.gauge_failed = Some(GAUGE_FAILED.to_string());
        }
        g
    }

    /// Several phases: each held its own flat combinations, and a later phase moves the tracker
    /// along an earlier one's. The result goes onto the gauge of every parameter the call
    /// identifies (moving along flat combinations: the fit stays, to first order).
    fn onto_common_gauge(&mut self) {
        if self.phases.len() <= 1 || self.termination.failed() || self.gauge.is_none() {
            return;
        }
        let (model, errors) = (self.model, self.errors);
        let base = Task::holding(
            self.problem.clone(),
            |j, info| !eligible(model, j, info, errors),
            &self.p,
            "gauge",
        );
        let reference = gauge_reference(
            &self.problem,
            &self.p,
            |j, info| eligible(model, j, info, errors),
            false,
        );
        self.gauge = crate::engines::gauge::gauge(
            &base,
            &reference,
            &reference,
            crate::engines::gauge::TOLERANCE,
        );
        match &self.gauge {
            Some(g) => {
                self.p = g.project(&self.p);
                self.at_p = None;
            }
            None => self.gauge_failed = Some(GAUGE_FAILED.to_string()),
        }
    }

    /// The identification the run reached, ended by `termination`.
    fn finish(self, termination: Termination) -> Identification {
        let initial = self.initial();
        Identification {
            reached: self
                .at_p
                .unwrap_or_else(|| evaluate(&self.problem, &self.p)),
            params: self.p,
            phases: self.phases,
            initial,
            termination,
            time_s: self.t0.elapsed().as_secs_f64(),
            gauge: self.gauge,
            gauge_failed: self.gauge_failed,
        }
    }
}

/// The gauge's reference for a solve that identifies the parameters `free` accepts: those errors
/// at their initial value (zero), the others as in `p`, and the tracker's rigid fit to that —
/// `p` itself when its tracker is that fit already (`fitted`: the rigid fit to p's errors) and
/// its free errors are at their initial values to the bit.
fn gauge_reference(
    problem: &Problem,
    p: &[f64],
    free: impl Fn(usize, &ParamInfo) -> bool,
    fitted: bool,
) -> Vec<f64> {
    let model = problem.model();
    let initial_params = model.initial_params();
    let mut reference = p.to_vec();
    let mut moved = false;
    for (j, info) in model.params().iter().enumerate() {
        if free(j, info) && info.group != Group::Tracker {
            moved |= reference[j].to_bits() != initial_params[j].to_bits();
            reference[j] = initial_params[j];
        }
    }
    if fitted && !moved {
        return reference;
    }
    init_tracker(problem, &reference).unwrap_or(reference)
}

/// `sol` (of `task` under the gauge `g`'s constraints) settled on the gauge: moved along the
/// held combinations onto it (a no-op when the engine kept the constraints) and polished to the
/// optimum under its constraints ([`crate::engines::polish::settle`]: Newton steps until the gradient, not
/// the cost's rounding, says it is there), so that the result does not depend on where the engine
/// stopped along the weakly identified directions (not again when the engine polished it under
/// them itself, [`Summary::polished`]). Its Newton steps and passes are added to the summary.
fn onto_gauge(task: &Task, g: &Gauge, sol: Solution, options: &Options) -> Solution {
    let problem = &*task.problem;
    let t0 = Instant::now();
    let mut out = sol;
    let projected = g.project(&out.params);
    if out.summary.polished {
        // The engine polished it under these very constraints (and evaluated it there, unless
        // the projection moved it).
        if !same_bits(&projected, &out.params) {
            out.params = projected;
            out.summary.reached = evaluate(problem, &out.params);
        }
        return out;
    }
    out.params = match crate::engines::polish::settle(
        &g.apply(task),
        &projected,
        options.objective,
        options.irls_final_epsilon,
    ) {
        Ok((q, report)) => {
            out.summary.iterations += report.steps;
            out.summary.jacobian_evaluations += report.jacobian_evaluations;
            out.summary.evaluations += report.evaluations + report.jacobian_evaluations;
            q
        }
        Err(_) => projected,
    };
    out.summary.reached = evaluate(problem, &out.params);
    out.summary.time_s += t0.elapsed().as_secs_f64();
    out
}

/// Fewest equations (3 per distinct pose and reflector) per free parameter a mesh must give.
pub const MIN_EQUATIONS_PER_PARAMETER: usize = 3;

/// Whether a problem's data hold at least `needed` distinct (commands, reflector, station)
/// keys (rotary positions a turn apart are one pose), read until they do; `Err` with how many
/// they hold when they do not.
fn distinct_poses(problem: &Problem, needed: usize) -> Result<(), usize> {
    let (model, data) = (problem.model(), problem.data());
    let mut keys = std::collections::HashSet::new();
    for p in &data.points {
        keys.insert(volver_core::measure::pose_key(model.machine(), p));
        if keys.len() >= needed {
            return Ok(());
        }
    }
    if keys.len() >= needed {
        Ok(())
    } else {
        Err(keys.len())
    }
}

/// [`identify_errors`] with every error free: the joint method.
pub fn identify(
    solver: &dyn Solver,
    problem: Problem,
    start: &[f64],
    strategy: &Strategy,
    options: &Options,
    observer: &mut dyn Observer,
) -> Identification {
    identify_errors(
        solver,
        problem,
        start,
        ErrorScope::All,
        strategy,
        options,
        observer,
    )
}

/// The joint method with the native engine, the default strategy (one phase, tracker fitted
/// rigidly first) and default options, from the model's initial parameters: the common case.
///
/// ```
/// # use volver_core::{machine::Machine, model::Model, plan::Plan, problem::Problem};
/// # use volver_core::simulate::{Magnitudes, Simulation, Truth};
/// let m = Machine::default_xcfz();
/// let truth = Truth::random_complete(&m, &Magnitudes::default(), 2).unwrap();
/// let data = Simulation::new(Plan::preset(&m, "test3").unwrap(), truth, 2).run().unwrap().measurements;
/// let model = Model::default_xcfz();
/// let id = volver_solvers::strategy::fit(Problem::new(&model, &data).unwrap());
/// assert!(id.termination.converged() && id.reached.stats.emm_um < id.initial.stats.emm_um);
/// ```
pub fn fit(problem: Problem) -> Identification {
    let start = problem.model().initial_params();
    identify(
        &crate::engines::lm::LevenbergMarquardt::default(),
        problem,
        &start,
        &Strategy::default(),
        &Options::default(),
        &mut crate::Silent,
    )
}

/// Tests 1 + 2: the linear-axis errors identified on `linear` alone (rotary errors held at
/// `start`), the rotary-axis errors on `rotary` alone (linear errors held at `start`); the result
/// takes each group from its own identification and the tracker pose from the rotary one.
pub fn independent(
    solver: &dyn Solver,
    linear: Problem,
    rotary: Problem,
    start: &[f64],
    strategy: &Strategy,
    options: &Options,
    observer: &mut dyn Observer,
) -> (Vec<f64>, Identification, Identification) {
    let model = linear.model();
    let a = identify_errors(
        solver,
        linear,
        start,
        ErrorScope::Linear,
        strategy,
        options,
        observer,
    );
    let b = identify_errors(
        solver,
        rotary,
        start,
        ErrorScope::Rotary,
        strategy,
        options,
        observer,
    );
    let p = model
        .params()
        .iter()
        .enumerate()
        .map(|(j, info)| {
            if eligible(model, j, info, ErrorScope::Linear)
                && !eligible(model, j, info, ErrorScope::Rotary)
            {
                a.params[j]
            } else {
                b.params[j]
            }
        })
        .collect();
    (p, a, b)
}

/// Test 5: the linear-axis errors identified on `linear`, then held while the rotary-axis
/// errors are identified on `rotary`.
pub fn combined(
    solver: &dyn Solver,
    linear: Problem,
    rotary: Problem,
    start: &[f64],
    strategy: &Strategy,
    options: &Options,
    observer: &mut dyn Observer,
) -> (Identification, Identification) {
    let a = identify_errors(
        solver,
        linear,
        start,
        ErrorScope::Linear,
        strategy,
        options,
        observer,
    );
    let b = identify_errors(
        solver,
        rotary,
        &a.params,
        ErrorScope::Rotary,
        strategy,
        options,
        observer,
    );
    (a, b)
}

/// Table 12: the error left in a reference set when the machine is compensated with `params`.
/// Only the measurement's parameters ([`Model::is_measurement_param`]: the tracker's and
/// stations' poses, reflector offsets, range scale, the reference test's own drift terms) are
/// fitted on the reference set, from the model's initial values; the machine's geometry keeps
/// `params`' values to the bit. The result's `initial` is the uncompensated machine as
/// [`identify`] first sees the reference set (every error zero, the tracker's rigid fit), so
/// that the baseline is the initial EMM an identification of the reference would print.
pub fn cross_validate(
    solver: &dyn Solver,
    reference: Problem,
    params: &[f64],
    options: &Options,
    observer: &mut dyn Observer,
) -> Identification {
    let model = reference.model();
    let initial = model.initial_params();
    let uncompensated = init_tracker(&reference, &initial).unwrap_or_else(|_| initial.clone());
    let before = evaluate(&reference, &uncompensated);
    let start: Vec<f64> = (0..params.len())
        .map(|j| {
            if model.is_measurement_param(j) {
                initial[j]
            } else {
                params[j]
            }
        })
        .collect();
    let mut after = identify_errors(
        solver,
        reference,
        &start,
        ErrorScope::None,
        &Strategy::default(),
        options,
        observer,
    );
    after.initial = before;
    after
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engines::lm::LevenbergMarquardt;
    use volver_core::plan::Plan;
    use volver_core::simulate::{Magnitudes, Simulation, Truth};

    fn run(problem: Problem, start: &[f64], strategy: &Strategy) -> Identification {
        identify_errors(
            &LevenbergMarquardt::default(),
            problem,
            start,
            ErrorScope::All,
            strategy,
            &Options::default(),
            &mut crate::Silent,
        )
    }

    /// Each phasing by its name, and the groups of its phases as table 1 of the paper gives them.
    #[test]
    fn phasings_are_read_by_name_and_list_the_papers_phases() {
        for name in PHASINGS {
            let p = Phasing::parse(name).expect("a phasing");
            assert_eq!(p.name(), name);
        }
        assert!(Phasing::parse("four").is_err());
        let words = |p: Phasing| -> Vec<String> {
            p.phases()
                .iter()
                .map(|g| {
                    g.iter()
                        .map(ToString::to_string)
                        .collect::<Vec<_>>()
                        .join("+")
                })
                .collect()
        };
        assert_eq!(words(Phasing::One), ["squareness+translation+rotation"]);
        assert_eq!(
            words(Phasing::ThreeRt),
            ["squareness", "rotation", "translation"]
        );
        assert_eq!(words(Phasing::Tr), ["squareness+translation", "rotation"]);
    }

    /// A strategy without a sub-loop, and a mesh of 2 × 2 × 2 positions and 2 reflectors (16
    /// distinct poses, 48 equations) for the paper's model, are refused before any solve, the
    /// parameters left at the start.
    #[test]
    fn a_strategy_that_cannot_start_is_refused_with_its_reason() {
        let model = Model::default_xcfz();
        let plan = Plan::parse_grid(model.machine(), "X=0:1400:1400,C=0:180:180,Z=0:600:600")
            .expect("a grid");
        let data = crate::analysis::observability::nominal_data(&model, &plan);
        let start = model.initial_params();
        let none = Strategy {
            subloops: 0,
            ..Strategy::default()
        };
        let id = run(
            Problem::new(&model, &data).expect("a problem"),
            &start,
            &none,
        );
        assert_eq!(
            id.termination,
            Termination::InvalidInput(crate::Invalid::NoSubloop)
        );
        assert!(id.phases.is_empty() && same_bits(&id.params, &start));
        let id = run(
            Problem::new(&model, &data).expect("a problem"),
            &start,
            &Strategy::default(),
        );
        let free = model.n_params() - model.constraints().rows.len();
        assert_eq!(
            id.termination,
            Termination::InvalidInput(crate::Invalid::MeshTooSmall {
                distinct: 16,
                points: 16,
                free,
                per_parameter: MIN_EQUATIONS_PER_PARAMETER,
            })
        );
        assert!(id.phases.is_empty() && id.gauge.is_none());
    }

    /// Two phases on noise-free data of the paper's test 3 that the model can explain (its
    /// own error functions, the tracker untilted): the squareness first, then the translation
    /// and rotation errors, each a solve of its own; together they explain the data (the EMM
    /// falls to under 1 % of the uncompensated machine's), and the result lies on the gauge of
    /// every identified parameter.
    #[test]
    fn two_phases_solve_in_the_papers_order_and_end_on_the_gauge() {
        let model = Model::default_xcfz();
        let machine = model.machine();
        let mut truth =
            Truth::random(machine, model.spec(), &Magnitudes::default(), 5).expect("a truth");
        let t = truth.model.tracker_start();
        truth.params[t + 3..t + 6].fill(0.0);
        let plan = Plan::preset(machine, "test3").expect("a preset");
        let mut simulation = Simulation::new(plan, truth, 5);
        simulation.noise = volver_core::noise::TrackerNoise::NONE;
        let data = simulation.run().expect("a simulation").measurements;
        let two = Strategy {
            phasing: Phasing::Two,
            ..Strategy::default()
        };
        let problem = Problem::new(&model, &data).expect("a problem");
        let id = run(problem, &model.initial_params(), &two);
        assert!(id.termination.converged(), "{:?}", id.termination);
        let labels: Vec<&str> = id.phases.iter().map(|s| s.phase.as_str()).collect();
        assert_eq!(labels, ["squareness", "translation+rotation"]);
        assert!(
            id.reached.stats.emm_um < 0.01 * id.initial.stats.emm_um,
            "{} of {} µm",
            id.reached.stats.emm_um,
            id.initial.stats.emm_um
        );
        let g = id.gauge.as_ref().expect("a gauge");
        assert!(g.offsets(&id.params).iter().all(|o| o.abs() < 1e-9));
    }

    /// Cross-validation fits the measurement's parameters alone: every parameter of the
    /// machine's geometry keeps the given value to the bit.
    #[test]
    fn cross_validation_keeps_the_machine_to_the_bit() {
        let model = Model::default_xcfz();
        let plan = Plan::preset(model.machine(), "test3").expect("a preset");
        let data = crate::analysis::observability::nominal_data(&model, &plan);
        let mut params = model.initial_params();
        let j = model.param_index("EXX.c1").expect("EXX is modelled");
        params[j] = 0.004;
        let id = cross_validate(
            &LevenbergMarquardt::default(),
            Problem::new(&model, &data).expect("a problem"),
            &params,
            &Options::default(),
            &mut crate::Silent,
        );
        for (k, (a, b)) in id.params.iter().zip(&params).enumerate() {
            if !model.is_measurement_param(k) {
                assert_eq!(a.to_bits(), b.to_bits(), "{}", model.params()[k].name);
            }
        }
        assert!(id.reached.stats.emm_um > 0.0);
    }
}
