//! Clarabel (pure Rust, feature `clarabel`, on by default) as a volver engine: the exact
//! convex sub-problem of Φ solved as a second-order cone program, iterated (a prox-linear
//! method).
//!
//! At the current point, with residuals `r_i` and Jacobian blocks `J_i` (our dual-number
//! Jacobian, in the scaled constraint-free coordinates `p = D (s₀ + N z)`, so that `A δp = 0`
//! holds for every step), a step δ solves
//!
//! ```text
//! Φ:   min (1/n) Σ t_i + (μ/2) ‖δ‖²   s.t.  ‖r_i + J_i δ‖ ≤ t_i (cones of dimension 4),
//!                                          ‖δ‖ ≤ Δ (the trust region, a cone of dim k + 1);
//! ve:  min (1/n) ‖r + J δ‖² + (μ/2) ‖δ‖²  s.t.  ‖δ‖ ≤ Δ.
//! ```
//!
//! Φ's sub-problem is exact: Φ's only non-smoothness, the norm, is kept, not smoothed, so a
//! noise-free fit converges to Φ = 0 without a smoothing schedule. The step is accepted when
//! the actual decrease is at least 1e-4 of the model's; μ and Δ adapt to the ratio like a
//! trust region. The data are scaled by the current Φ (or ve) so that Clarabel's tolerances are
//! relative.
//!
//! [`Polished`] (`lm+clarabel`) runs the native LM first and polishes its result this way: the
//! LM's IRLS reaches Φ to its final smoothing ε, the SOCP to Clarabel's tolerances.
//!
//! ```
//! use volver_core::machine::Machine;
//! use volver_core::model::{ErrorModelSpec, Model};
//! use volver_core::plan::Plan;
//! use volver_core::problem::Problem;
//! use volver_core::simulate::{Magnitudes, Simulation, Truth};
//! use volver_solvers::clarabel::ProxLinear;
//! use volver_solvers::{lm::LevenbergMarquardt, Options, Silent, Solver, Task};
//! let m = Machine::default_xcfz();
//! let truth = Truth::random(&m, &ErrorModelSpec::complete(&m), &Magnitudes::default(), 1).unwrap();
//! let data = Simulation::new(Plan::preset(&m, "test3").unwrap(), truth, 1).run().unwrap().measurements;
//! let model = Model::default_xcfz();
//! let problem = Problem::new(&model, &data).unwrap();
//! let task = Task::new(problem);
//! let lm = LevenbergMarquardt::default().solve(&task, &model.initial_params(), &Options::default(), &mut Silent);
//! let socp = ProxLinear::default().solve(&task, &model.initial_params(), &Options::default(), &mut Silent);
//! assert!(!socp.summary.termination.failed(), "{}", socp.summary.termination);
//! // The SOCP reaches Φ's optimum exactly; the LM's IRLS stops at or above it.
//! let (a, b) = (lm.summary.reached.phi_mm, socp.summary.reached.phi_mm);
//! assert!(b <= a * (1.0 + 1e-9) && b > 0.99 * a, "Φ: LM {a}, SOCP {b}");
//! ```

use crate::engines::lm::LevenbergMarquardt;
use crate::engines::run::{Started, begin};
use crate::options::{Objective, Options};
use crate::summary::Termination;
use crate::{Iteration, Observer, Solution, Solver, Task};
use ::clarabel::algebra::CscMatrix;
use ::clarabel::solver::{
    DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
};
use faer::Mat;
use volver_core::problem::norm;
use volver_core::units::{TINY, UM_PER_MM};

pub use crate::engines::sections::ClarabelSettings;

/// The prox-linear engine (`clarabel`) with its settings ([`ClarabelSettings`]).
///
/// ```
/// use volver_solvers::clarabel::{ClarabelSettings, ProxLinear};
/// let e = ProxLinear::new(ClarabelSettings::default().with_socp_max_iterations(50));
/// assert_eq!(e.settings().socp_max_iterations, 50);
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ProxLinear {
    settings: ClarabelSettings,
}

impl ProxLinear {
    /// The engine with `settings` (checked when it solves: a run with settings out of range
    /// ends as invalid input naming the field; [`crate::engine_with`] refuses them before).
    pub fn new(settings: ClarabelSettings) -> ProxLinear {
        ProxLinear { settings }
    }

    /// Its settings.
    pub fn settings(&self) -> &ClarabelSettings {
        &self.settings
    }
}

/// The native LM followed by a prox-linear polish (`lm+clarabel`), each with its settings.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Polished {
    lm: LevenbergMarquardt,
    polish: ProxLinear,
}

impl Polished {
    /// The LM with `lm`, its polish with `clarabel`.
    pub fn new(lm: LevenbergMarquardt, clarabel: ClarabelSettings) -> Polished {
        Polished {
            lm,
            polish: ProxLinear::new(clarabel),
        }
    }
}

/// The [`Options`] fields the prox-linear engine does not read: its sub-problem keeps Φ's
/// norm exact (no smoothing ε) and it has no gradient test.
const UNREAD: [&str; 3] = [
    "gradient_tolerance",
    "irls_initial_epsilon",
    "irls_final_epsilon",
];

/// Residuals and the Jacobian in the free coordinates at one point.
struct Linearisation {
    /// 3 per point.
    r: Vec<f64>,
    /// Row-major (3 n) × k.
    jz: Vec<f64>,
}

fn linearise(task: &Task, p: &[f64], tangent: &Mat<f64>) -> Option<Linearisation> {
    let problem = &*task.problem;
    let (n, k) = (tangent.nrows(), tangent.ncols());
    let np = problem.n_points();
    let mut row = vec![0.0; 3 * n];
    let mut r = Vec::with_capacity(3 * np);
    let mut jz = vec![0.0; 3 * np * k];
    for i in 0..np {
        let ri = problem.residual_and_jacobian(i, p, &mut row);
        if ri.iter().chain(&row).any(|v| !v.is_finite()) {
            return None;
        }
        r.extend_from_slice(&ri);
        for c in 0..3 {
            let out = &mut jz[(3 * i + c) * k..(3 * i + c + 1) * k];
            for j in 0..n {
                let v = row[c * n + j];
                if v != 0.0 {
                    for (o, kk) in out.iter_mut().zip(0..k) {
                        *o += v * tangent[(j, kk)];
                    }
                }
            }
        }
    }
    Some(Linearisation { r, jz })
}

/// The cone program of a sub-problem: `min ½ xᵀPx + qᵀx` subject to `A x + s = b`, s in the
/// cones.
struct ConeProgram {
    p: CscMatrix<f64>,
    q: Vec<f64>,
    a: CscMatrix<f64>,
    b: Vec<f64>,
    cones: Vec<SupportedConeT<f64>>,
}

/// The sub-problem's settings and where the step's values are (the first `k` variables).
struct Subproblem {
    /// The proximal weight μ and the trust radius Δ (scaled coordinates).
    mu: f64,
    radius: f64,
    /// The data are divided by this (the current objective), so that Clarabel's tolerances are
    /// relative.
    scale: f64,
}

/// Clarabel's settings for the sub-problems.
fn settings(s: &ClarabelSettings) -> Result<::clarabel::solver::DefaultSettings<f64>, String> {
    DefaultSettingsBuilder::default()
        .verbose(false)
        .max_iter(s.socp_max_iterations)
        .tol_gap_abs(s.tol_gap_abs)
        .tol_gap_rel(s.tol_gap_rel)
        .tol_feas(s.tol_feas)
        .build()
        .map_err(|e| format!("Clarabel settings: {e:?}"))
}

/// Solves the sub-problem (data scaled by `sub.scale`); the step, or Clarabel's status.
fn step(
    objective: Objective,
    lin: &Linearisation,
    k: usize,
    sub: &Subproblem,
    clarabel: &ClarabelSettings,
) -> Result<Vec<f64>, String> {
    let settings = settings(clarabel)?;
    let program = if objective.loss() == Objective::Ve {
        ve_program(lin, k, sub)
    } else {
        phi_program(lin, k, sub)
    };
    solve_cone(program, settings, k)
}

/// Φ's sub-problem: variables (δ, t), `min (1/n) Σ t_i + (μ/2)‖δ‖²` with the cones
/// `‖r_i + J_i δ‖ ≤ t_i` (rows 4i … 4i + 3) and `‖δ‖ ≤ Δ` (the last k + 1 rows). The CSC of
/// A is built column by column.
fn phi_program(lin: &Linearisation, k: usize, sub: &Subproblem) -> ConeProgram {
    let np = lin.r.len() / 3;
    let nvar = k + np;
    let m = 4 * np + k + 1;
    let mut colptr = vec![0usize];
    let mut rowval = Vec::new();
    let mut nzval = Vec::new();
    for c in 0..k {
        for i in 0..np {
            for d in 0..3 {
                let v = lin.jz[(3 * i + d) * k + c];
                if v != 0.0 {
                    rowval.push(4 * i + 1 + d);
                    nzval.push(-v / sub.scale);
                }
            }
        }
        rowval.push(4 * np + 1 + c);
        nzval.push(-1.0);
        colptr.push(rowval.len());
    }
    for i in 0..np {
        rowval.push(4 * i);
        nzval.push(-1.0);
        colptr.push(rowval.len());
    }
    let a = CscMatrix::new(m, nvar, colptr, rowval, nzval);
    let mut b = vec![0.0; m];
    for i in 0..np {
        for d in 0..3 {
            b[4 * i + 1 + d] = lin.r[3 * i + d] / sub.scale;
        }
    }
    b[4 * np] = sub.radius;
    let mut cones: Vec<SupportedConeT<f64>> = vec![SupportedConeT::SecondOrderConeT(4); np];
    cones.push(SupportedConeT::SecondOrderConeT(k + 1));
    let mut q = vec![0.0; nvar];
    for qi in q.iter_mut().skip(k) {
        *qi = 1.0 / np as f64;
    }
    let pdiag: Vec<f64> = (0..k).map(|_| sub.mu).collect();
    let p = CscMatrix::new(
        nvar,
        nvar,
        (0..=nvar).map(|c| c.min(k)).collect(),
        (0..k).collect(),
        pdiag,
    );
    ConeProgram { p, q, a, b, cones }
}

/// ve's sub-problem: `P = (2/n) JᵀJ / scale + μ I` (upper triangle), `q = (2/n) Jᵀr / scale`,
/// and the cone `‖δ‖ ≤ Δ`.
fn ve_program(lin: &Linearisation, k: usize, sub: &Subproblem) -> ConeProgram {
    let np = lin.r.len() / 3;
    let nn = np as f64;
    let jm = Mat::from_fn(3 * np, k, |i, c| lin.jz[i * k + c]);
    let jtj = jm.transpose() * &jm;
    let mut pc = vec![0usize];
    let mut pr = Vec::new();
    let mut pv = Vec::new();
    for c in 0..k {
        for rr in 0..=c {
            let v = 2.0 / nn * jtj[(rr, c)] / sub.scale + if rr == c { sub.mu } else { 0.0 };
            if v != 0.0 {
                pr.push(rr);
                pv.push(v);
            }
        }
        pc.push(pr.len());
    }
    let p = CscMatrix::new(k, k, pc, pr, pv);
    let q = (0..k)
        .map(|c| {
            2.0 / nn
                * (0..3 * np)
                    .map(|i| lin.jz[i * k + c] * lin.r[i])
                    .sum::<f64>()
                / sub.scale
        })
        .collect();
    let mut colptr = vec![0usize];
    let mut rowval = Vec::new();
    let mut nzval = Vec::new();
    for c in 0..k {
        rowval.push(1 + c);
        nzval.push(-1.0);
        colptr.push(rowval.len());
    }
    let a = CscMatrix::new(k + 1, k, colptr, rowval, nzval);
    let mut b = vec![0.0; k + 1];
    b[0] = sub.radius;
    let cones = vec![SupportedConeT::SecondOrderConeT(k + 1)];
    ConeProgram { p, q, a, b, cones }
}

/// Clarabel's solution of `program`: its first `k` variables (the step).
fn solve_cone(
    program: ConeProgram,
    settings: ::clarabel::solver::DefaultSettings<f64>,
    k: usize,
) -> Result<Vec<f64>, String> {
    let ConeProgram { p, q, a, b, cones } = program;
    let mut solver = DefaultSolver::new(&p, &q, &a, &b, &cones, settings)
        .map_err(|e| format!("Clarabel refused the sub-problem: {e:?}"))?;
    solver.solve();
    match solver.solution.status {
        SolverStatus::Solved | SolverStatus::AlmostSolved => {
            let x = solver.solution.x[..k].to_vec();
            if x.iter().all(|v| v.is_finite()) {
                Ok(x)
            } else {
                Err("Clarabel returned a non-finite step".into())
            }
        }
        s => Err(format!("Clarabel: {s:?}")),
    }
}

/// The model's prediction of the objective after step δ (without the proximal term).
fn model_value(objective: Objective, lin: &Linearisation, k: usize, delta: &[f64]) -> f64 {
    let np = lin.r.len() / 3;
    let mut sum = 0.0;
    for i in 0..np {
        let mut v = [0.0; 3];
        for (d, vd) in v.iter_mut().enumerate() {
            let row = &lin.jz[(3 * i + d) * k..(3 * i + d + 1) * k];
            *vd = lin.r[3 * i + d] + row.iter().zip(delta).map(|(a, b)| a * b).sum::<f64>();
        }
        let m = norm(v);
        sum += if objective.loss() == Objective::Ve {
            m * m
        } else {
            m
        };
    }
    sum / np as f64
}

fn objective_value(objective: Objective, norms: &[f64]) -> f64 {
    crate::engines::loss::cost_of(objective, norms, 0.0)
}

/// The smallest proximal weight μ (relative to the scaled sub-problem).
const MU_FLOOR: f64 = 1e-12;

/// μ past which a sub-problem Clarabel cannot solve ends the run.
const MU_MAX: f64 = 1e20;

/// What follows a trial.
enum Next {
    /// Accepted: linearise at the new point.
    Relinearise,
    /// Refused (the region shrunk) or the sub-problem failed: another trial.
    Retry,
    /// The run ends.
    Stop(Termination),
}

/// The prox-linear iteration's state: the point (p, its distance z from the start in the free
/// coordinates, its residual modules in mm and its objective), the proximal weight μ and the
/// trust radius Δ.
struct Prox<'c, 'a, 'o> {
    task: &'c Task<'a>,
    options: &'o Options,
    settings: &'o ClarabelSettings,
    free: crate::engines::coordinates::Free,
    p: Vec<f64>,
    z: Vec<f64>,
    norms: Vec<f64>,
    cost: f64,
    mu: f64,
    radius: f64,
}

impl Prox<'_, '_, '_> {
    /// A sub-problem Clarabel cannot solve: the region shrinks for another trial; `false` when
    /// μ or Δ are past use.
    fn after_failure(&mut self) -> bool {
        if self.mu > MU_MAX || self.radius < TINY {
            return false;
        }
        self.mu = (self.mu * 10.0).max(1e-6);
        self.radius /= 4.0;
        true
    }

    /// Φ at the current point (µm).
    fn emm_um(&self) -> f64 {
        self.norms.iter().sum::<f64>() / self.norms.len() as f64 * UM_PER_MM
    }

    /// The trial of the sub-problem's step `delta` from the linearisation `lin`: the stopping
    /// tests on its prediction, its evaluation, the report, then acceptance (μ and Δ adapted
    /// to the gain ratio) or refusal (the region shrunk).
    fn trial(
        &mut self,
        lin: &Linearisation,
        delta: &[f64],
        run: &mut crate::engines::run::Run,
        observer: &mut dyn Observer,
    ) -> Next {
        let (options, objective) = (self.options, self.options.objective);
        let k = self.free.n_free();
        let step_norm = delta.iter().map(|v| v * v).sum::<f64>().sqrt();
        let znorm = self.z.iter().map(|v| v * v).sum::<f64>().sqrt();
        let small_step =
            step_norm <= options.parameter_tolerance * (znorm + options.parameter_tolerance);
        let pred = self.cost - model_value(objective, lin, k, delta);
        if pred <= options.objective_tolerance * self.cost {
            return Next::Stop(if small_step {
                Termination::ParameterChange
            } else {
                Termination::ObjectiveChange
            });
        }
        let p_new = self.free.step(&self.p, delta);
        run.summary.evaluations += 1;
        let new = crate::engines::loss::norms(&*self.task.problem, &p_new);
        let cost_new = new
            .as_ref()
            .map(|v| objective_value(objective, v))
            .unwrap_or(f64::INFINITY);
        if new.is_none() {
            run.nonfinite_trial();
        }
        let rho = (self.cost - cost_new) / pred;
        let accepted = rho > self.settings.acceptance;
        if accepted {
            run.improved();
        }
        let np = self.norms.len();
        observer.iteration(&Iteration {
            iteration: run.summary.iterations,
            evaluations: run.summary.evaluations,
            cost: if accepted { cost_new } else { self.cost },
            emm_um: match (&new, accepted) {
                (Some(v), true) => v.iter().sum::<f64>() / np as f64 * UM_PER_MM,
                (None, true) => f64::NAN,
                (_, false) => self.emm_um(),
            },
            damping: self.mu,
            step: step_norm,
            accepted,
        });
        if !accepted {
            self.mu = (self.mu * 4.0).max(MU_FLOOR);
            self.radius = step_norm / 4.0;
            return if small_step {
                Next::Stop(Termination::ParameterChange)
            } else {
                Next::Retry
            };
        }
        let old = self.cost;
        self.z = self.z.iter().zip(delta).map(|(a, b)| a + b).collect();
        self.p = p_new;
        self.norms = new.unwrap_or_default();
        self.cost = cost_new;
        self.adapt(rho, step_norm);
        if small_step {
            Next::Stop(Termination::ParameterChange)
        } else if old - self.cost <= options.objective_tolerance * old {
            Next::Stop(Termination::ObjectiveChange)
        } else {
            Next::Relinearise
        }
    }

    /// μ and Δ after an accepted step of length `step_norm` with gain ratio `rho`: a good model
    /// (ρ > ¾) loosens both, a poor one (ρ < ¼) tightens both.
    fn adapt(&mut self, rho: f64, step_norm: f64) {
        if rho > 0.75 {
            self.mu = (self.mu / 3.0).max(MU_FLOOR);
            self.radius = self.radius.max(3.0 * step_norm);
        } else if rho < 0.25 {
            self.mu *= 2.0;
            self.radius = self.radius.min(step_norm.max(TINY));
        }
    }

    /// The trials from one linearisation until one is accepted or the run ends.
    fn trials(
        &mut self,
        lin: &Linearisation,
        run: &mut crate::engines::run::Run,
        observer: &mut dyn Observer,
    ) -> Option<Termination> {
        let (options, k) = (self.options, self.free.n_free());
        loop {
            if run.summary.iterations >= options.max_iterations {
                return Some(Termination::IterationLimit);
            }
            if run.summary.evaluations >= options.max_evaluations {
                return Some(Termination::EvaluationLimit);
            }
            run.summary.iterations += 1;
            // μ is relative to the scaled sub-problem (objective ≈ 1 at δ = 0).
            let sub = Subproblem {
                mu: self.mu,
                radius: self.radius,
                scale: self.cost,
            };
            let next = match step(options.objective, lin, k, &sub, self.settings) {
                Ok(delta) => self.trial(lin, &delta, run, observer),
                Err(_) if self.after_failure() => Next::Retry,
                Err(e) => Next::Stop(Termination::NumericalFailure(crate::Failure::Reported(e))),
            };
            match next {
                Next::Relinearise => return None,
                Next::Retry => {}
                Next::Stop(t) => return Some(t),
            }
        }
    }
}

impl Solver for ProxLinear {
    fn name(&self) -> &'static str {
        "clarabel"
    }

    fn solve(
        &self,
        task: &Task,
        start: &[f64],
        options: &Options,
        observer: &mut dyn Observer,
    ) -> Solution {
        let mut solution = self.solve_here(task, start, options, observer);
        solution.summary.ignored_options = crate::engines::sections::ignored(options, &UNREAD);
        solution
    }
}

impl ProxLinear {
    /// [`Solver::solve`], but for the options it does not read.
    fn solve_here(
        &self,
        task: &Task,
        start: &[f64],
        options: &Options,
        observer: &mut dyn Observer,
    ) -> Solution {
        let Started {
            mut run,
            free,
            p0,
            norms0,
            ..
        } = match begin(self.name(), task, start, options) {
            Ok(b) => b,
            Err(solution) => return *solution,
        };
        if let Err(e) = self.settings.validate() {
            return run.finish(p0, Termination::InvalidInput(crate::Invalid::Refused(e)));
        }
        let np = task.problem.n_points();
        let cost = objective_value(options.objective, &norms0);
        let ve0 = norms0.iter().map(|r| r * r).sum::<f64>() / np as f64;
        // Scaled coordinates: a unit of z moves the residual vector by ~1 mm. A first step may
        // change the residuals by up to ten times their norm.
        let radius = (10.0 * (np as f64 * ve0).sqrt()).max(1e-6);
        let tangent = free.tangent();
        let mut prox = Prox {
            task,
            options,
            settings: &self.settings,
            z: vec![0.0; free.n_free()],
            free,
            p: p0,
            norms: norms0,
            cost,
            mu: options.initial_damping,
            radius,
        };
        let termination = loop {
            if prox.cost == 0.0 {
                break Termination::Gradient;
            }
            if run.summary.evaluations >= options.max_evaluations {
                break Termination::EvaluationLimit;
            }
            let Some(lin) = linearise(task, &prox.p, &tangent) else {
                break Termination::NumericalFailure(crate::Failure::JacobianNotFinite(
                    crate::At::Iteration(run.summary.iterations),
                ));
            };
            run.summary.evaluations += 1;
            run.summary.jacobian_evaluations += 1;
            if let Some(t) = prox.trials(&lin, &mut run, observer) {
                break t;
            }
        };
        run.finish(prox.p, termination)
    }
}

/// The fewest evaluations a polish of `lm+clarabel` is started with: the start's residuals
/// and Jacobian, a linearisation and a trial.
const POLISH_EVALUATIONS: usize = 4;

impl Solver for Polished {
    fn name(&self) -> &'static str {
        "lm+clarabel"
    }

    fn solve(
        &self,
        task: &Task,
        start: &[f64],
        options: &Options,
        observer: &mut dyn Observer,
    ) -> Solution {
        let first = self.lm.solve(task, start, options, observer);
        // The polish gets what the LM left of the limits; none when the LM failed, or left too
        // little for a sub-problem (the start's residuals and Jacobian, a
        // linearisation and a trial).
        let left = Options {
            max_iterations: options
                .max_iterations
                .saturating_sub(first.summary.iterations),
            max_evaluations: options
                .max_evaluations
                .saturating_sub(first.summary.evaluations),
            ..options.clone()
        };
        if first.summary.termination.failed()
            || left.max_iterations == 0
            || left.max_evaluations < POLISH_EVALUATIONS
        {
            let mut s = first;
            s.summary.solver = self.name().to_string();
            return s;
        }
        let mut second = self.polish.solve(task, &first.params, &left, observer);
        second.summary.ignored_options.clear();
        let s = &mut second.summary;
        s.solver = self.name().to_string();
        s.initial = first.summary.initial;
        s.iterations += first.summary.iterations;
        s.evaluations += first.summary.evaluations;
        s.jacobian_evaluations += first.summary.jacobian_evaluations;
        s.time_s += first.summary.time_s;
        s.unidentifiable = first.summary.unidentifiable;
        // A polish that cannot improve keeps the LM's result.
        if second.summary.termination.failed()
            || second.summary.final_cost() > first.summary.final_cost()
        {
            let mut kept = first.clone();
            kept.summary.solver = self.name().to_string();
            kept.summary.iterations = second.summary.iterations;
            kept.summary.evaluations = second.summary.evaluations;
            kept.summary.time_s = second.summary.time_s;
            return kept;
        }
        second
    }
}
