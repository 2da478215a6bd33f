//! NLopt as a volver engine (feature `nlopt`; the `nlopt` crate builds NLopt 2.9.1 from
//! source, which needs cmake).
//!
//! Gradient-based algorithms get the exact gradient of the objective from the dual-number
//! Jacobian (one Jacobian pass per gradient, no normal matrix):
//!
//! * [`Algorithm::Lbfgs`] (`LD_LBFGS`) and [`Algorithm::Mma`] (`LD_MMA`) work in the scaled
//!   constraint-free coordinates `p = D (s₀ + N z)` (neither takes equality constraints);
//! * [`Algorithm::Slsqp`] (`LD_SLSQP`) works on all the (column-scaled) parameters and gets the
//!   equality constraints `A p = b` natively, with their gradients;
//! * [`Algorithm::Bobyqa`] (`LN_BOBYQA`, derivative-free, in the free coordinates) is there for
//!   comparison: expect it to stop at the evaluation limit on models of many parameters.
//!
//! Φ is not differentiable where a residual vanishes, so it is minimised through the smoothed
//! `Φ_ε = (1/n) Σ √(‖r_i‖² + ε²)`, with ε shrinking tenfold between runs from
//! [`Options::irls_initial_epsilon`] to [`Options::irls_final_epsilon`] × Φ (the continuation of
//! the other engines). NLopt does not count iterations: the summary's iterations are the
//! objective calls.
//!
//! ```
//! # #[cfg(feature = "nlopt")] {
//! use volver_core::machine::Machine;
//! use volver_core::model::{ErrorModelSpec, Model};
//! use volver_core::plan::Plan;
//! use volver_core::problem::Problem;
//! use volver_core::simulate::{Magnitudes, Simulation, Truth};
//! use volver_solvers::nlopt::{Algorithm, Nlopt};
//! use volver_solvers::{lm::LevenbergMarquardt, Objective, Options, Silent, Solver, Task};
//! let m = Machine::default_xcfz();
//! let truth = Truth::random(&m, &ErrorModelSpec::complete(&m), &Magnitudes::default(), 1).unwrap();
//! let data = Simulation::new(Plan::preset(&m, "test3").unwrap(), truth, 1).run().unwrap().measurements;
//! let model = Model::default_xcfz();
//! let problem = Problem::new(&model, &data).unwrap();
//! let options = Options { objective: Objective::Ve, ..Options::default() };
//! let task = Task::new(problem);
//! let lm = LevenbergMarquardt::default().solve(&task, &model.initial_params(), &options, &mut Silent);
//! let sq = Nlopt::new(Algorithm::Slsqp).solve(&task, &model.initial_params(), &options, &mut Silent);
//! assert!(!sq.summary.termination.failed(), "{}", sq.summary.termination);
//! assert!(sq.summary.reached.ve_mm2 < lm.summary.reached.ve_mm2 * (1.0 + 1e-6));
//! # }
//! ```

use crate::engines::coordinates::Free;
use crate::engines::lm::irls::Continuation;
use crate::engines::loss::{cost_and_gradient, cost_of, norms};
use crate::engines::run::{Started, begin};
use crate::options::{Objective, Options};
use crate::summary::Termination;
use crate::{Iteration, Observer, Solution, Solver, Task};
use ::nlopt as nl;
use faer::Mat;
use std::cell::RefCell;
use std::panic::{AssertUnwindSafe, catch_unwind};
use volver_core::problem::Residuals;
use volver_core::units::UM_PER_MM;

/// NLopt algorithms volver offers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Algorithm {
    /// `LD_LBFGS`: limited-memory BFGS, in the free coordinates.
    Lbfgs,
    /// `LD_SLSQP`: sequential quadratic programming, equality constraints passed natively.
    Slsqp,
    /// `LD_MMA`: method of moving asymptotes, in the free coordinates.
    Mma,
    /// `LN_BOBYQA`: derivative-free quadratic models, in the free coordinates.
    Bobyqa,
}

pub use crate::engines::sections::NloptSettings;

/// The NLopt engine with one algorithm and its settings ([`NloptSettings`]).
///
/// ```
/// # #[cfg(feature = "nlopt")] {
/// use volver_solvers::nlopt::{Algorithm, Nlopt, NloptSettings};
/// use volver_solvers::Solver;
/// let e = Nlopt::with_settings(Algorithm::Bobyqa, NloptSettings::default().with_max_restarts(2));
/// assert_eq!((e.name(), e.settings().max_restarts), ("nlopt-bobyqa", 2));
/// # }
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct Nlopt {
    /// The algorithm.
    pub algorithm: Algorithm,
    settings: NloptSettings,
}

impl Nlopt {
    /// The engine running `algorithm` with the default settings.
    pub fn new(algorithm: Algorithm) -> Nlopt {
        Nlopt::with_settings(algorithm, NloptSettings::default())
    }

    /// The engine running `algorithm` with `settings` (checked when it solves: a run with
    /// settings out of range ends as invalid input naming the field; [`crate::engine_with`]
    /// refuses them before).
    pub fn with_settings(algorithm: Algorithm, settings: NloptSettings) -> Nlopt {
        Nlopt {
            algorithm,
            settings,
        }
    }

    /// Its settings.
    pub fn settings(&self) -> &NloptSettings {
        &self.settings
    }
}

/// The [`Options`] fields NLopt does not read: it counts no iterations (the summary's are its
/// objective calls), has no damping, and its gradient tests are its own.
const UNREAD: [&str; 3] = ["max_iterations", "gradient_tolerance", "initial_damping"];

/// What the objective callback tracks between calls.
struct State<'o> {
    /// The current smoothing (mm).
    eps: f64,
    /// NLopt sees cost / scale (the cost at the start of the run), so that its absolute
    /// internal tests (L-BFGS' gradient norm) stay meaningful as the cost falls by decades.
    scale: f64,
    calls: usize,
    /// The calls allowed (the evaluation limit's share), and whether one past it was refused.
    limit: usize,
    refused: bool,
    /// Residual passes of volver's own between NLopt's solves (a stage's cost and Φ).
    passes: usize,
    gradients: usize,
    best: f64,
    nonfinite: Option<String>,
    /// Non-finite objective calls, by call number, for [`crate::engines::run::FiniteEdge`].
    edge: crate::engines::run::FiniteEdge,
    observer: &'o mut dyn Observer,
}

fn termination_of(result: &Result<(nl::SuccessState, f64), (nl::FailState, f64)>) -> Termination {
    use nl::{FailState as F, SuccessState as S};
    match result {
        Ok((S::FtolReached, _)) => Termination::ObjectiveChange,
        Ok((S::XtolReached, _)) => Termination::ParameterChange,
        Ok((S::MaxEvalReached, _)) => Termination::EvaluationLimit,
        Ok((S::MaxTimeReached, _)) => Termination::IterationLimit,
        Ok((S::Success, _)) | Ok((S::StopValReached, _)) => Termination::Gradient,
        Err((F::RoundoffLimited, _)) => Termination::Stalled(crate::Stall::Reported(
            "NLopt: rounding errors limited progress".into(),
        )),
        Err((F::InvalidArgs, _)) => {
            Termination::InvalidInput(crate::Invalid::Reported("NLopt: invalid arguments".into()))
        }
        Err((F::ForcedStop, _)) => {
            Termination::NumericalFailure(crate::Failure::Reported("NLopt: forced stop".into()))
        }
        Err((F::OutOfMemory, _)) => {
            Termination::NumericalFailure(crate::Failure::Reported("NLopt: out of memory".into()))
        }
        Err((F::Failure, _)) => Termination::Stalled(crate::Stall::Reported(
            "NLopt: generic failure, usually its line search".into(),
        )),
    }
}

impl Solver for Nlopt {
    fn name(&self) -> &'static str {
        match self.algorithm {
            Algorithm::Lbfgs => "nlopt-lbfgs",
            Algorithm::Slsqp => "nlopt-slsqp",
            Algorithm::Mma => "nlopt-mma",
            Algorithm::Bobyqa => "nlopt-bobyqa",
        }
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

impl Nlopt {
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
        let problem = &*task.problem;
        let np = problem.n_points();
        let phi0 = norms0.iter().sum::<f64>() / np as f64;
        let vars = Variables {
            free: &free,
            slsqp: self.algorithm == Algorithm::Slsqp,
            tangent: free.tangent(),
        };
        let callback = Callback {
            problem,
            objective: options.objective.loss(),
            vars: &vars,
            state: RefCell::new(State {
                eps: Continuation::new(options, phi0).eps(),
                scale: 1.0,
                calls: 0,
                limit: 0,
                refused: false,
                passes: 0,
                gradients: 0,
                best: f64::INFINITY,
                nonfinite: None,
                edge: Default::default(),
                observer,
            }),
        };
        let mut x = vars.start(&p0);
        let rows = equality_rows(task, &free.d);
        let base = run.summary.evaluations;
        let termination = self.stages(&callback, &mut x, options, (&rows, base, phi0));
        let st = callback.state.into_inner();
        run.summary.iterations = st.calls;
        run.summary.evaluations = base + st.calls + st.passes;
        run.summary.jacobian_evaluations += st.gradients;
        run.edge = st.edge.shifted(base);
        let p = vars.params(&x);
        run.finish(p, termination)
    }
}

/// The variables NLopt sees and how they map to the parameters: SLSQP's `s = p / D` (every
/// parameter, the equality constraints passed natively), the others' free coordinates z.
struct Variables<'f> {
    free: &'f Free,
    slsqp: bool,
    /// `D N`: the parameters' change per unit of z.
    tangent: Mat<f64>,
}

impl Variables<'_> {
    /// The parameters at the variables `x`.
    fn params(&self, x: &[f64]) -> Vec<f64> {
        if self.slsqp {
            let mut p: Vec<f64> = x.iter().zip(&self.free.d).map(|(s, d)| s * d).collect();
            for &(j, v) in &self.free.fixed {
                p[j] = v;
            }
            p
        } else {
            self.free.params(x)
        }
    }

    /// The variables at the start `p0`.
    fn start(&self, p0: &[f64]) -> Vec<f64> {
        if self.slsqp {
            p0.iter().zip(&self.free.d).map(|(p, d)| p / d).collect()
        } else {
            vec![0.0; self.free.n_free()]
        }
    }

    /// The gradient `g` in the variables of the cost whose gradient in the parameters is `gp`,
    /// divided by the run's `scale`.
    fn gradient(&self, gp: &[f64], g: &mut [f64], scale: f64) {
        if self.slsqp {
            for (j, gj) in g.iter_mut().enumerate() {
                *gj = gp[j] * self.free.d[j] / scale;
            }
        } else {
            let n = gp.len();
            for (k, gk) in g.iter_mut().enumerate() {
                *gk = (0..n).map(|j| self.tangent[(j, k)] * gp[j]).sum::<f64>() / scale;
            }
        }
    }
}

/// The objective NLopt calls: the smoothed cost at the variables (and its gradient when asked),
/// scaled, each call reported to the observer and the non-finite ones recorded.
struct Callback<'f, 'a, 'o> {
    problem: &'f (dyn Residuals + 'a),
    objective: Objective,
    vars: &'f Variables<'f>,
    state: RefCell<State<'o>>,
}

impl Callback<'_, '_, '_> {
    /// NLopt sees the cost divided by `cost` (a stage's first), 1 when it is not positive.
    fn rescale(&self, cost: f64) {
        self.state.borrow_mut().scale = if cost.is_finite() && cost > 0.0 {
            cost
        } else {
            1.0
        };
    }

    /// The next solve may make `remaining` calls.
    fn allow(&self, remaining: usize) {
        let mut st = self.state.borrow_mut();
        st.limit = st.calls + remaining;
    }

    /// The next stage of the continuation, with smoothing `eps` (mm).
    fn next_stage(&self, eps: f64) {
        let mut st = self.state.borrow_mut();
        st.eps = eps;
        st.best = f64::INFINITY;
    }

    /// One call from NLopt; NaN (a refused point) when the model is not finite there or a
    /// panic unwinds from it (it must not cross the C library).
    fn call(&self, x: &[f64], grad: Option<&mut [f64]>) -> f64 {
        let result = catch_unwind(AssertUnwindSafe(|| {
            let mut st = self.state.borrow_mut();
            if st.calls >= st.limit {
                // Past the evaluation limit (NLopt's own test comes late in some algorithms):
                // refused, nothing evaluated, and the solve ends on the limit.
                st.refused = true;
                return f64::NAN;
            }
            st.calls += 1;
            let p = self.vars.params(x);
            let value = self.value(&mut st, &p, grad);
            self.record(&mut st, &p, value);
            value / st.scale
        }));
        result.unwrap_or(f64::NAN)
    }

    /// The cost at `p` (and its gradient into `grad` when asked); NaN when not finite.
    fn value(&self, st: &mut State, p: &[f64], grad: Option<&mut [f64]>) -> f64 {
        let eps = st.eps;
        match grad {
            Some(g) => {
                st.gradients += 1;
                match cost_and_gradient(self.problem, self.objective, eps, p) {
                    Some((c, gp)) => {
                        self.vars.gradient(&gp, g, st.scale);
                        c
                    }
                    None => f64::NAN,
                }
            }
            None => match norms(self.problem, p) {
                Some(v) => cost_of(self.objective, &v, eps),
                None => f64::NAN,
            },
        }
    }

    /// The call's bookkeeping: a non-finite value recorded, the best cost so far, the report.
    fn record(&self, st: &mut State, p: &[f64], value: f64) {
        if !value.is_finite() {
            if st.nonfinite.is_none() {
                st.nonfinite = Some(format!(
                    "a residual or Jacobian entry is not finite at objective call {}",
                    st.calls
                ));
            }
            let call = st.calls;
            st.edge.nonfinite_at(call);
        }
        let accepted = value < st.best;
        if accepted {
            st.best = value;
            st.edge.improved = st.calls;
        }
        let (calls, best) = (st.calls, st.best);
        let np = self.problem.n_points();
        let emm_um = if st.observer.wants_metrics() {
            norms(self.problem, p)
                .map(|v| v.iter().sum::<f64>() / np as f64 * UM_PER_MM)
                .unwrap_or(f64::NAN)
        } else {
            f64::NAN
        };
        st.observer.iteration(&Iteration {
            iteration: calls,
            evaluations: calls,
            cost: best,
            emm_um,
            damping: 0.0,
            step: 0.0,
            accepted,
        });
    }
}

/// SLSQP's equality constraints in s, `(A D) s = b`, duplicate rows dropped.
fn equality_rows(task: &Task, d: &[f64]) -> Vec<(Vec<f64>, f64)> {
    let n = d.len();
    let (a, b) = task.constraints.dense(n);
    let mut rows: Vec<(Vec<f64>, f64)> = Vec::new();
    for (i, &bi) in b.iter().enumerate() {
        let row: Vec<f64> = (0..n).map(|j| a[i * n + j] * d[j]).collect();
        if !rows.iter().any(|(r, c)| *r == row && *c == bi) {
            rows.push((row, bi));
        }
    }
    rows
}

/// A run's settings for one solve: the relative objective-change `tolerance`, the evaluations
/// `remaining`, SLSQP's equality `rows`.
struct Setup<'r> {
    tolerance: f64,
    remaining: usize,
    rows: &'r [(Vec<f64>, f64)],
}

impl Nlopt {
    /// NLopt's algorithm.
    fn nl_algorithm(&self) -> nl::Algorithm {
        match self.algorithm {
            Algorithm::Lbfgs => nl::Algorithm::Lbfgs,
            Algorithm::Slsqp => nl::Algorithm::Slsqp,
            Algorithm::Mma => nl::Algorithm::Mma,
            Algorithm::Bobyqa => nl::Algorithm::Bobyqa,
        }
    }

    /// Sets the tolerances, the evaluation limit, SLSQP's equality constraints and BOBYQA's
    /// first step on `opt`.
    fn configure<F: nl::ObjFn<()>>(
        &self,
        opt: &mut nl::Nlopt<F, ()>,
        options: &Options,
        setup: &Setup,
    ) -> nl::OptResult {
        opt.set_ftol_rel(setup.tolerance)?;
        opt.set_xtol_rel(options.parameter_tolerance)?;
        opt.set_maxeval(setup.remaining.min(u32::MAX as usize) as u32)?;
        let rows = setup.rows;
        if self.algorithm == Algorithm::Slsqp && !rows.is_empty() {
            let m = rows.len();
            let n = rows[0].0.len();
            let tol: Vec<f64> = rows
                .iter()
                .map(|(_, c)| self.settings.equality_tolerance * (1.0 + c.abs()))
                .collect();
            opt.add_equality_mconstraint(
                m,
                // `move`: NLopt keeps the closure until `opt` is dropped, after this function
                // returns (`rows` borrows the caller's buffer, which outlives `opt`).
                move |out: &mut [f64], s: &[f64], grad: Option<&mut [f64]>, _: &mut ()| {
                    for (i, (row, c)) in rows.iter().enumerate() {
                        out[i] = row.iter().zip(s).map(|(a, s)| a * s).sum::<f64>() - c;
                    }
                    if let Some(g) = grad {
                        for (i, (row, _)) in rows.iter().enumerate() {
                            g[i * n..(i + 1) * n].copy_from_slice(row);
                        }
                    }
                },
                (),
                &tol,
            )?;
        }
        if self.algorithm == Algorithm::Bobyqa {
            // Free coordinates are scaled: a unit moves the residuals by ~1 mm.
            opt.set_initial_step1(self.settings.initial_step)?;
        }
        if self.algorithm == Algorithm::Lbfgs && self.settings.vector_storage.is_some() {
            opt.set_vector_storage(self.settings.vector_storage)?;
        }
        Ok(nl::SuccessState::Success)
    }

    /// One solve from `x` (moved to its end): NLopt's termination, a stall naming the first
    /// non-finite call.
    fn solve_once(
        &self,
        callback: &Callback,
        x: &mut [f64],
        options: &Options,
        setup: &Setup,
    ) -> Termination {
        let f = |x: &[f64], grad: Option<&mut [f64]>, _: &mut ()| -> f64 { callback.call(x, grad) };
        let mut opt = nl::Nlopt::new(self.nl_algorithm(), x.len(), &f, nl::Target::Minimize, ());
        if let Err(e) = self.configure(&mut opt, options, setup) {
            return Termination::InvalidInput(crate::Invalid::Reported(format!(
                "NLopt refused its settings: {e:?}"
            )));
        }
        let result = opt.optimize(x);
        drop(opt);
        let refused = std::mem::take(&mut callback.state.borrow_mut().refused);
        let t = if refused {
            Termination::EvaluationLimit
        } else {
            termination_of(&result)
        };
        // A non-finite trial point is a rejected evaluation, not the end: the run fails
        // only if NLopt itself gives up on it (its result is then kept only if finite).
        let nonfinite = callback.state.borrow_mut().nonfinite.take();
        match (t, nonfinite) {
            (Termination::Stalled(s), Some(why)) => {
                Termination::Stalled(crate::Stall::Reported(format!("{s}; {why}")))
            }
            (t, _) => t,
        }
    }

    /// The solves of the ε-continuation from `x` (moved to the end) until the last converges
    /// (restarted, rescaled, while a solve still halves the cost, at most
    /// [`NloptSettings::max_restarts`] times) or one fails; `base`: the run's evaluations before
    /// the first. The residual passes between the solves (a stage's cost, Φ) count as
    /// evaluations, within the limit.
    fn stages(
        &self,
        callback: &Callback,
        x: &mut [f64],
        options: &Options,
        (rows, base, phi0_mm): (&[(Vec<f64>, f64)], usize, f64),
    ) -> Termination {
        let (problem, objective) = (callback.problem, callback.objective);
        let np = problem.n_points();
        let spent = || {
            let st = callback.state.borrow();
            base + st.calls + st.passes
        };
        // The residual modules at x, a pass counted; `None` past the limit.
        let norms_at = |x: &[f64]| -> Option<Option<Vec<f64>>> {
            if spent() >= options.max_evaluations {
                return None;
            }
            callback.state.borrow_mut().passes += 1;
            Some(norms(problem, &callback.vars.params(x)))
        };
        let mut continuation = Continuation::new(options, phi0_mm);
        let mut restarts = 0;
        // The modules at x when known (the start's, or the last pass's).
        let mut known: Option<Option<Vec<f64>>> = None;
        loop {
            let eps = continuation.eps();
            let Some(at_x) = known.take().or_else(|| norms_at(x)) else {
                return Termination::EvaluationLimit;
            };
            let stage_cost = at_x
                .as_ref()
                .map(|v| cost_of(objective, v, eps))
                .unwrap_or(f64::NAN);
            callback.rescale(stage_cost);
            let final_stage = continuation.is_final();
            let remaining = options.max_evaluations.saturating_sub(spent());
            if remaining == 0 {
                return Termination::EvaluationLimit;
            }
            let setup = Setup {
                tolerance: continuation.tolerance(options.objective_tolerance),
                remaining,
                rows,
            };
            callback.allow(remaining);
            let t = self.solve_once(callback, x, options, &setup);
            let settled = t.converged() || matches!(t, Termination::Stalled(_));
            if final_stage || !settled {
                if !(final_stage && settled && restarts < self.settings.max_restarts) {
                    return t;
                }
                // A run that still lowered the cost by half restarts, rescaled: L-BFGS's
                // internal tests are absolute and stop early on exact fits.
                let Some(now) = norms_at(x) else {
                    return t;
                };
                let now_cost = now.as_ref().map(|v| cost_of(objective, v, eps));
                if !now_cost.is_some_and(|c| c < 0.5 * stage_cost) {
                    return t;
                }
                restarts += 1;
                known = Some(now);
                callback.state.borrow_mut().best = f64::INFINITY;
                continue;
            }
            let Some(now) = norms_at(x) else {
                return Termination::EvaluationLimit;
            };
            let phi = now
                .as_ref()
                .map(|v| v.iter().sum::<f64>() / np as f64)
                .unwrap_or(phi0_mm);
            known = Some(now);
            continuation.shrink(phi);
            callback.next_stage(continuation.eps());
        }
    }
}
