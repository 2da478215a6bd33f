//! Ceres Solver as a volver engine (feature `ceres`), through our own FFI crate
//! `volver-ceres-sys` (a C++ shim over Ceres 2.1 read by bindgen).
//!
//! * **One parameter block**, the model's parameters scaled by the column norms of the
//!   Jacobian at the start (`s = p / D`, as in the native engine), with Ceres' Jacobi scaling on
//!   top. Each measured point is a residual block of 3 residuals whose Jacobian block is our
//!   exact dual-number Jacobian row times D (no automatic or numeric differentiation in Ceres).
//! * **Constraints**: the start is projected onto `A p = b`; held parameters become a
//!   `SubsetManifold` (exact); general linear constraints (squareness from straightness) a
//!   linear manifold `s₀ + N t` over the null space of `A D` (the native engine's). No free
//!   parameter: nothing to solve.
//! * **Objectives**: ve is plain least squares (Ceres minimises `½ Σ ‖r_i‖²`). Φ uses the loss
//!   `ρ(s) = 2(√(s + ε²) − ε)` on every block, so Ceres minimises `Σ (√(‖r_i‖² + ε²) − ε)`,
//!   the smoothed sum of modules, with Ceres' own Triggs correction. ε shrinks tenfold between
//!   solves (from [`Options::irls_initial_epsilon`] to [`Options::irls_final_epsilon`] × Φ),
//!   the same continuation as the native engine.
//! * **Criteria**: Ceres' function, parameter and gradient tolerances take the paper's criteria;
//!   the iteration limit is Ceres' own; the evaluation limit is enforced by the iteration
//!   callback. The termination names the criterion Ceres reports.
//!
//! ```
//! # #[cfg(feature = "ceres")] {
//! use volver_core::machine::Machine;
//! use volver_core::model::{ErrorModelSpec, Model};
//! use volver_core::noise::TrackerNoise;
//! use volver_core::plan::Plan;
//! use volver_core::problem::Problem;
//! use volver_core::simulate::{Magnitudes, Simulation, Truth};
//! use volver_solvers::{ceres::Ceres, Options, Silent, Solver, Task};
//! let m = Machine::default_xcfz();
//! let truth = Truth::random(&m, &ErrorModelSpec::complete(&m), &Magnitudes::default(), 1).unwrap();
//! let mut sim = Simulation::new(Plan::preset(&m, "test3").unwrap(), truth, 1);
//! sim.noise = TrackerNoise::NONE;
//! let data = sim.run().unwrap().measurements;
//! let model = Model::default_xcfz();
//! let problem = Problem::new(&model, &data).unwrap();
//! let sol = Ceres::default().solve(&Task::new(problem), &model.initial_params(),
//!                                  &Options::default(), &mut Silent);
//! assert!(!sol.summary.termination.failed(), "{}", sol.summary.termination);
//! assert!(sol.summary.reached.stats.emm_um < 1e-5 * sol.summary.initial.stats.emm_um);
//! # }
//! ```

use crate::engines::coordinates::held_values;
use crate::engines::lm::irls::Continuation;
use crate::engines::run::{Started, begin};
use crate::options::{Objective, Options};
use crate::summary::Termination;
use crate::{Iteration, Observer, Solution, Solver, Task};
use std::sync::atomic::{AtomicUsize, Ordering};
use volver_ceres_sys as cs;
use volver_core::problem::{Residuals, norm};
use volver_core::units::{TINY, UM_PER_MM};

pub use crate::engines::sections::{CeresSettings, LinearSolver};

/// The Ceres engine with its settings ([`CeresSettings`]: the linear solver and the threads).
///
/// ```
/// # #[cfg(feature = "ceres")] {
/// use volver_solvers::ceres::{Ceres, CeresSettings, LinearSolver};
/// use volver_solvers::Solver;
/// let s = CeresSettings::default().with_threads(2).with_linear_solver(LinearSolver::DenseQr);
/// assert_eq!(Ceres::new(s).settings().threads, 2);
/// assert_eq!(Ceres::new(s).name(), "ceres");
/// # }
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Ceres {
    settings: CeresSettings,
}

impl Ceres {
    /// The engine with `settings` (checked when it solves: a run with settings out of range
    /// ends as invalid input naming the field; [`crate::engine_with`] refuses them before).
    pub fn new(settings: CeresSettings) -> Ceres {
        Ceres { settings }
    }

    /// Its settings.
    pub fn settings(&self) -> &CeresSettings {
        &self.settings
    }
}

/// Ceres' linear solver for volver's.
fn linear_solver(l: LinearSolver) -> cs::LinearSolver {
    match l {
        LinearSolver::DenseQr => cs::LinearSolver::DenseQr,
        LinearSolver::DenseNormalCholesky => cs::LinearSolver::DenseNormalCholesky,
        LinearSolver::SparseNormalCholesky => cs::LinearSolver::SparseNormalCholesky,
        LinearSolver::Cgnr => cs::LinearSolver::Cgnr,
    }
}

/// The residual blocks: point i's residual and its dual-number Jacobian row.
struct Cost<'t, 'a> {
    problem: &'t (dyn Residuals + 'a),
    /// Column scaling: p = s ∘ d.
    d: &'t [f64],
    /// Residual passes (block 0 is evaluated once per pass).
    passes: AtomicUsize,
    /// The passes the evaluation limit leaves Ceres: a pass past them is refused (every block
    /// fails, nothing is evaluated, nothing counted), and the run ends on the limit.
    limit: usize,
    /// Whether a pass was refused at the limit.
    over: std::sync::atomic::AtomicBool,
    /// Residual blocks whose residual or Jacobian was not finite.
    nonfinite: AtomicUsize,
    /// The last pass with such a block (0: none).
    nonfinite_pass: AtomicUsize,
}

impl cs::CostFunction for Cost<'_, '_> {
    fn evaluate(
        &self,
        block: usize,
        params: &[f64],
        residuals: &mut [f64],
        jacobian: Option<&mut [f64]>,
    ) -> bool {
        if block == 0 && !self.over.load(Ordering::Relaxed) {
            if self.passes.load(Ordering::Relaxed) >= self.limit {
                self.over.store(true, Ordering::Relaxed);
            } else {
                self.passes.fetch_add(1, Ordering::Relaxed);
            }
        }
        if self.over.load(Ordering::Relaxed) {
            return false;
        }
        // p = s ∘ d in a per-thread buffer: no allocation per residual block.
        thread_local!(static P: std::cell::RefCell<Vec<f64>> = const { std::cell::RefCell::new(Vec::new()) });
        let (r, jac_ok) = P.with_borrow_mut(|p| {
            p.clear();
            p.extend(params.iter().zip(self.d).map(|(s, d)| s * d));
            match jacobian {
                Some(j) => {
                    let r = self.problem.residual_and_jacobian(block, p, j);
                    let n = p.len();
                    for (k, v) in j.iter_mut().enumerate() {
                        *v *= self.d[k % n];
                    }
                    (r, j.iter().all(|v| v.is_finite()))
                }
                None => (self.problem.residual(block, p), true),
            }
        });
        residuals.copy_from_slice(&r);
        let ok = jac_ok && r.iter().all(|v| v.is_finite());
        if !ok {
            self.nonfinite.fetch_add(1, Ordering::Relaxed);
            self.nonfinite_pass
                .fetch_max(self.passes.load(Ordering::Relaxed), Ordering::Relaxed);
        }
        ok
    }
}

/// The termination of one Ceres solve in volver's terms.
fn termination_of(s: &cs::Summary, evaluation_limit: bool) -> Termination {
    match s.termination {
        cs::Termination::Convergence => {
            if s.message.starts_with("Parameter tolerance") {
                Termination::ParameterChange
            } else if s.message.starts_with("Gradient tolerance") {
                Termination::Gradient
            } else {
                Termination::ObjectiveChange
            }
        }
        cs::Termination::NoConvergence => Termination::IterationLimit,
        cs::Termination::UserSuccess if evaluation_limit => Termination::EvaluationLimit,
        cs::Termination::UserSuccess | cs::Termination::UserFailure => {
            Termination::NumericalFailure(crate::Failure::Reported(format!(
                "Ceres stopped by its callback: {}",
                s.message
            )))
        }
        cs::Termination::Failure => {
            Termination::NumericalFailure(crate::Failure::Reported(format!("Ceres: {}", s.message)))
        }
    }
}

/// The parameter block's manifold: free, a subset held (every constraint holds one parameter),
/// or the linear manifold `s₀ + N t` over the null space of `A D`.
fn space_of(task: &Task, free: &crate::engines::coordinates::Free) -> cs::Space {
    let (n, nf) = (free.d.len(), free.n_free());
    if task.constraints.rows.is_empty() {
        cs::Space::Free
    } else if held_values(&task.constraints).len() == task.constraints.rows.len() {
        let mut idx: Vec<usize> = free.fixed.iter().map(|&(j, _)| j).collect();
        idx.sort_unstable();
        idx.dedup();
        cs::Space::Subset(idx)
    } else {
        let b = free.ns.basis();
        cs::Space::Linear {
            basis: (0..n * nf).map(|k| b[(k / nf, k % nf)]).collect(),
            columns: nf,
        }
    }
}

/// What the iteration callback of the solves follows: the run's options and observer, the
/// passes counted before the first solve, the last pass that improved the cost, and whether
/// the current solve was stopped at the evaluation limit.
struct Progress<'t, 'a, 'o> {
    problem: &'t (dyn Residuals + 'a),
    /// Column scaling: p = s ∘ d.
    d: &'t [f64],
    cost: &'t Cost<'t, 'a>,
    options: &'o Options,
    observer: &'o mut dyn Observer,
    wants: bool,
    base_evaluations: usize,
    /// Iterations of the earlier solves, and the smoothing of this one (mm).
    done_before: usize,
    eps: f64,
    improved_pass: usize,
    evaluation_limit: bool,
}

impl Progress<'_, '_, '_> {
    /// One Ceres iteration: the report (Ceres' cost as Φ_ε or ve; EMM from a residual pass
    /// when the observer reads it) and the evaluation limit.
    fn on_iteration(&mut self, it: &cs::Iteration, params: &[f64]) -> cs::Control {
        let np = self.problem.n_points();
        let passes = self.cost.passes.load(Ordering::Relaxed);
        let evaluations = self.base_evaluations + passes;
        // A stage's start counts as an improvement, as in the other engines.
        if it.iteration == 0 || it.successful {
            self.improved_pass = passes;
        }
        if it.iteration > 0 {
            let objective_now = if self.options.objective.loss() == Objective::Ve {
                2.0 * it.cost / np as f64
            } else {
                it.cost / np as f64 + self.eps
            };
            let emm_um = if self.wants {
                let p: Vec<f64> = params.iter().zip(self.d).map(|(s, d)| s * d).collect();
                (0..np)
                    .map(|i| norm(self.problem.residual(i, &p)))
                    .sum::<f64>()
                    / np as f64
                    * UM_PER_MM
            } else {
                f64::NAN
            };
            self.observer.iteration(&Iteration {
                iteration: self.done_before + it.iteration,
                evaluations,
                cost: objective_now,
                emm_um,
                damping: 1.0 / it.trust_region_radius,
                step: it.step_norm,
                accepted: it.successful,
            });
        }
        if evaluations >= self.options.max_evaluations {
            self.evaluation_limit = true;
            cs::Control::Stop
        } else {
            cs::Control::Continue
        }
    }
}

impl Ceres {
    /// Ceres' options for the next solve of the continuation (`iterations` already done, Φ₀ =
    /// `phi0_mm` over `np` points).
    fn options_for(
        &self,
        options: &Options,
        continuation: &Continuation,
        iterations: usize,
        (np, phi0_mm): (usize, f64),
    ) -> cs::Options {
        cs::Options {
            trust_region: cs::TrustRegion::LevenbergMarquardt,
            linear_solver: linear_solver(self.settings.linear_solver),
            max_iterations: options.max_iterations.saturating_sub(iterations),
            function_tolerance: continuation.tolerance(options.objective_tolerance),
            // Ceres' gradient test is absolute, in its cost (≈ n Φ or ½ n ve).
            gradient_tolerance: options.gradient_tolerance * np as f64 * phi0_mm.max(TINY),
            parameter_tolerance: options.parameter_tolerance,
            // Ceres' radius is the inverse of the LM damping.
            initial_trust_region_radius: 1.0 / options.initial_damping.max(TINY),
            threads: self.settings.threads,
            jacobi_scaling: true,
        }
    }

    /// The solves of the ε-continuation until the last one ends or one fails; the run's
    /// iterations and Jacobian evaluations counted.
    fn stages(
        &self,
        cp: &mut cs::Problem<'_>,
        run: &mut crate::engines::run::Run,
        progress: &mut Progress,
        phi0_mm: f64,
    ) -> Termination {
        let options = progress.options;
        let np = progress.problem.n_points();
        let mut continuation = Continuation::new(options, phi0_mm);
        loop {
            let final_stage = continuation.is_final();
            let iterations = run.summary.iterations;
            let ceres_options = self.options_for(options, &continuation, iterations, (np, phi0_mm));
            if ceres_options.max_iterations == 0 {
                return Termination::IterationLimit;
            }
            progress.evaluation_limit = false;
            progress.done_before = iterations;
            progress.eps = continuation.eps();
            let summary = match cp
                .solve(&ceres_options, &mut |it: &cs::Iteration, params: &[f64]| {
                    progress.on_iteration(it, params)
                }) {
                Ok(s) => s,
                Err(_) if progress.cost.over.load(Ordering::Relaxed) => {
                    return Termination::EvaluationLimit;
                }
                Err(e) => {
                    return Termination::NumericalFailure(crate::Failure::Reported(e.to_string()));
                }
            };
            // Ceres counts its iteration 0 (the start's evaluation) as a successful step.
            run.summary.iterations +=
                (summary.successful_steps + summary.unsuccessful_steps).saturating_sub(1);
            run.summary.jacobian_evaluations += summary.jacobian_evaluations;
            let limit = progress.evaluation_limit || progress.cost.over.load(Ordering::Relaxed);
            let t = if progress.cost.over.load(Ordering::Relaxed) {
                Termination::EvaluationLimit
            } else {
                termination_of(&summary, limit)
            };
            if final_stage || !t.converged() {
                return t;
            }
            // Φ: sharpen the smoothing (Ceres' cost is Σ (√(‖r‖² + ε²) − ε) ≈ n Φ).
            continuation.shrink(summary.final_cost / np as f64);
            if let Err(e) = cp.set_loss_epsilon(continuation.eps()) {
                return Termination::NumericalFailure(crate::Failure::Reported(e.to_string()));
            }
        }
    }
}

/// The run's evaluations and its finite edge from the blocks Ceres evaluated (`base`: the
/// evaluations before the first solve, `improved_pass` the last pass that improved), and the
/// termination naming non-finite blocks when it failed.
fn account(
    run: &mut crate::engines::run::Run,
    cost: &Cost,
    (base, improved_pass): (usize, usize),
    termination: Termination,
) -> Termination {
    run.summary.evaluations = base + cost.passes.load(Ordering::Relaxed);
    let nonfinite_pass = cost.nonfinite_pass.load(Ordering::Relaxed);
    let nonfinite = cost.nonfinite.load(Ordering::Relaxed);
    // Ceres evaluates blocks, not trial points: the edge sees the last pass with a
    // non-finite block, and counts blocks.
    if nonfinite > 0 {
        run.edge.nonfinite_at(base + nonfinite_pass);
        run.edge.count = nonfinite;
    }
    run.edge.improved = base + improved_pass;
    if nonfinite > 0 && !termination.converged() {
        match termination {
            Termination::NumericalFailure(s) => {
                Termination::NumericalFailure(crate::Failure::Reported(format!(
                    "{s} (a residual or Jacobian entry was not finite)"
                )))
            }
            t => t,
        }
    } else {
        termination
    }
}

impl Solver for Ceres {
    fn name(&self) -> &'static str {
        "ceres"
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
        if let Err(e) = self.settings.validate() {
            return run.finish(p0, Termination::InvalidInput(crate::Invalid::Refused(e)));
        }
        let problem = &*task.problem;
        let np = problem.n_points();
        let phi0 = norms0.iter().sum::<f64>() / np as f64;
        let d = &free.d;
        let s0: Vec<f64> = p0.iter().zip(d).map(|(p, d)| p / d).collect();
        let loss = if options.objective.loss() == Objective::Ve {
            cs::Loss::None
        } else {
            cs::Loss::Module {
                epsilon: Continuation::new(options, phi0).eps(),
            }
        };
        let cost = Cost {
            problem,
            d,
            passes: AtomicUsize::new(0),
            limit: options
                .max_evaluations
                .saturating_sub(run.summary.evaluations),
            over: std::sync::atomic::AtomicBool::new(false),
            nonfinite: AtomicUsize::new(0),
            nonfinite_pass: AtomicUsize::new(0),
        };
        let mut cp = match cs::Problem::new(&s0, np, 3, &cost, loss)
            .and_then(|mut cp| cp.set_space(&space_of(task, &free)).map(|_| cp))
        {
            Ok(cp) => cp,
            Err(e) => {
                return run.finish(
                    p0,
                    Termination::InvalidInput(crate::Invalid::Reported(e.to_string())),
                );
            }
        };
        let base_evaluations = run.summary.evaluations;
        let mut progress = Progress {
            problem,
            d,
            cost: &cost,
            options,
            wants: observer.wants_metrics(),
            observer,
            base_evaluations,
            done_before: 0,
            eps: 0.0,
            improved_pass: 0,
            evaluation_limit: false,
        };
        let termination = self.stages(&mut cp, &mut run, &mut progress, phi0);
        let improved = (base_evaluations, progress.improved_pass);
        let termination = account(&mut run, &cost, improved, termination);
        let mut p: Vec<f64> = cp.params().iter().zip(d).map(|(s, d)| s * d).collect();
        for &(j, v) in &free.fixed {
            p[j] = v;
        }
        run.finish(p, termination)
    }
}
