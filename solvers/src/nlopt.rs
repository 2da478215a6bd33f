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

use crate::loss::{cost_and_gradient, cost_of, norms};
use crate::options::{Objective, Options};
use crate::run::{Started, begin};
use crate::summary::Termination;
use crate::{Iteration, Observer, Solution, Solver, Task};
use ::nlopt as nl;
use std::cell::RefCell;
use std::panic::{AssertUnwindSafe, catch_unwind};

/// NLopt algorithms volver offers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
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

/// The NLopt engine with one algorithm.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct Nlopt {
    /// The algorithm.
    pub algorithm: Algorithm,
}

impl Nlopt {
    /// The engine running `algorithm`.
    pub fn new(algorithm: Algorithm) -> Nlopt {
        Nlopt { algorithm }
    }
}

/// What the objective callback tracks between calls.
struct State<'o> {
    eps: f64,
    /// NLopt sees cost / scale (the cost at the start of the run), so that its absolute
    /// internal tests (L-BFGS' gradient norm) stay meaningful as the cost falls by decades.
    scale: f64,
    calls: usize,
    gradients: usize,
    best: f64,
    nonfinite: Option<String>,
    /// Non-finite objective calls, by call number, for [`crate::run::FiniteEdge`].
    edge: crate::run::FiniteEdge,
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
        let problem = &*task.problem;
        let n = start.len();
        let np = problem.n_points();
        let nf = free.n_free();
        let phi0 = norms0.iter().sum::<f64>() / np as f64;
        let objective = options.objective;
        let eps_final = |phi: f64| (options.irls_final_epsilon * phi).max(1e-300);
        let d = &free.d;
        let slsqp = self.algorithm == Algorithm::Slsqp;
        // SLSQP's variables: s = p / D (every parameter); the others': z.
        let tangent = free.tangent();
        let params_of = |x: &[f64]| -> Vec<f64> {
            if slsqp {
                let mut p: Vec<f64> = x.iter().zip(d).map(|(s, d)| s * d).collect();
                for &(j, v) in &free.fixed {
                    p[j] = v;
                }
                p
            } else {
                free.params(x)
            }
        };
        let state = RefCell::new(State {
            eps: (options.irls_initial_epsilon * phi0).max(1e-300),
            scale: 1.0,
            calls: 0,
            gradients: 0,
            best: f64::INFINITY,
            nonfinite: None,
            edge: Default::default(),
            observer,
        });
        let f = |x: &[f64], grad: Option<&mut [f64]>, _: &mut ()| -> f64 {
            let result = catch_unwind(AssertUnwindSafe(|| {
                let mut st = state.borrow_mut();
                st.calls += 1;
                let p = params_of(x);
                let eps = st.eps;
                let value = match grad {
                    Some(g) => {
                        st.gradients += 1;
                        match cost_and_gradient(problem, objective, eps, &p) {
                            Some((c, gp)) => {
                                let sc = st.scale;
                                if slsqp {
                                    for (j, gj) in g.iter_mut().enumerate() {
                                        *gj = gp[j] * d[j] / sc;
                                    }
                                } else {
                                    for (k, gk) in g.iter_mut().enumerate() {
                                        *gk = (0..n).map(|j| tangent[(j, k)] * gp[j]).sum::<f64>()
                                            / sc;
                                    }
                                }
                                c
                            }
                            None => f64::NAN,
                        }
                    }
                    None => match norms(problem, &p) {
                        Some(v) => cost_of(objective, &v, eps),
                        None => f64::NAN,
                    },
                };
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
                let emm_um = if st.observer.wants_metrics() {
                    norms(problem, &p)
                        .map(|v| v.iter().sum::<f64>() / np as f64 * 1e3)
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
                value / st.scale
            }));
            result.unwrap_or(f64::NAN)
        };
        let (dim, mut x) = if slsqp {
            (
                n,
                p0.iter().zip(d).map(|(p, d)| p / d).collect::<Vec<f64>>(),
            )
        } else {
            (nf, vec![0.0; nf])
        };
        // SLSQP's equality constraints, in s: (A D) s = b, duplicate rows dropped.
        let (a, b) = task.constraints.dense(n);
        let mut rows: Vec<(Vec<f64>, f64)> = Vec::new();
        for (i, &bi) in b.iter().enumerate() {
            let row: Vec<f64> = (0..n).map(|j| a[i * n + j] * d[j]).collect();
            if !rows.iter().any(|(r, c)| *r == row && *c == bi) {
                rows.push((row, bi));
            }
        }
        let base_evaluations = run.summary.evaluations;
        let cost_at = |x: &[f64], eps: f64| {
            norms(problem, &params_of(x)).map(|v| cost_of(objective, &v, eps))
        };
        let mut restarts = 0;
        let termination = loop {
            let eps = state.borrow().eps;
            let stage_cost = cost_at(&x, eps).unwrap_or(f64::NAN);
            state.borrow_mut().scale = if stage_cost.is_finite() && stage_cost > 0.0 {
                stage_cost
            } else {
                1.0
            };
            let final_stage = objective == Objective::Ve || eps <= eps_final(phi0) * 1.0001;
            let used = state.borrow().calls;
            let remaining = options
                .max_evaluations
                .saturating_sub(base_evaluations + used);
            if remaining == 0 {
                break Termination::EvaluationLimit;
            }
            let algorithm = match self.algorithm {
                Algorithm::Lbfgs => nl::Algorithm::Lbfgs,
                Algorithm::Slsqp => nl::Algorithm::Slsqp,
                Algorithm::Mma => nl::Algorithm::Mma,
                Algorithm::Bobyqa => nl::Algorithm::Bobyqa,
            };
            let mut opt = nl::Nlopt::new(algorithm, dim, &f, nl::Target::Minimize, ());
            let mut setup = || -> nl::OptResult {
                opt.set_ftol_rel(if final_stage {
                    options.objective_tolerance
                } else {
                    1e-3
                })?;
                opt.set_xtol_rel(options.parameter_tolerance)?;
                opt.set_maxeval(remaining.min(u32::MAX as usize) as u32)?;
                if slsqp && !rows.is_empty() {
                    let m = rows.len();
                    let tol: Vec<f64> = rows.iter().map(|(_, c)| 1e-12 * (1.0 + c.abs())).collect();
                    opt.add_equality_mconstraint(
                        m,
                        |out: &mut [f64], s: &[f64], grad: Option<&mut [f64]>, _: &mut ()| {
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
                    opt.set_initial_step1(1e-3)?;
                }
                Ok(nl::SuccessState::Success)
            };
            if let Err(e) = setup() {
                break Termination::InvalidInput(crate::Invalid::Reported(format!(
                    "NLopt refused its settings: {e:?}"
                )));
            }
            let result = opt.optimize(&mut x);
            drop(opt);
            let t = termination_of(&result);
            // A non-finite trial point is a rejected evaluation, not the end: the run fails
            // only if NLopt itself gives up on it (its result is then kept only if finite).
            let nonfinite = state.borrow_mut().nonfinite.take();
            let t = match (t, nonfinite) {
                (Termination::Stalled(s), Some(why)) => {
                    Termination::Stalled(crate::Stall::Reported(format!("{s}; {why}")))
                }
                (t, _) => t,
            };
            let settled = t.converged() || matches!(t, Termination::Stalled(_));
            if final_stage && settled && restarts < 10 {
                // A run that still lowered the cost by half restarts, rescaled: L-BFGS's
                // internal tests are absolute and stop early on exact fits.
                let now = cost_at(&x, eps).unwrap_or(f64::NAN);
                if now < 0.5 * stage_cost {
                    restarts += 1;
                    state.borrow_mut().best = f64::INFINITY;
                    continue;
                }
            }
            if final_stage || !settled {
                break t;
            }
            let p = params_of(&x);
            let phi = norms(problem, &p)
                .map(|v| v.iter().sum::<f64>() / np as f64)
                .unwrap_or(phi0);
            let mut st = state.borrow_mut();
            st.eps = (st.eps / 10.0).max(eps_final(phi));
            st.best = f64::INFINITY;
        };
        let st = state.into_inner();
        run.summary.iterations = st.calls;
        run.summary.evaluations = base_evaluations + st.calls;
        run.summary.jacobian_evaluations += st.gradients;
        run.edge = st.edge.shifted(base_evaluations);
        let p = params_of(&x);
        run.finish(p, termination)
    }
}
