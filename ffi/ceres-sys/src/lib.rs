//! # volver-ceres-sys
//!
//! Ceres Solver for volver, through a small C++ shim (`shim/volver_ceres.cpp`) whose C header
//! `bindgen` reads at build time. Ceres' own C API is too thin (fixed options, progress printed to
//! stdout, no summary, no constant blocks or manifolds); the shim exposes what an identification
//! needs:
//!
//! - one parameter block, residual blocks evaluated by a Rust callback that returns residuals
//!   and exact Jacobian blocks;
//! - a loss on every residual block: none (least squares), the smoothed error module
//!   `ρ(s) = 2(√(s + ε²) − ε)`, or Ceres' `SoftLOneLoss(ε)`, with ε changeable between solves;
//! - a constant block, a subset of constant parameters (`SubsetManifold`) or an affine subspace
//!   (a linear manifold, for linear equality constraints);
//! - the solver options (trust region, linear solver, tolerances, iteration limit, threads), an
//!   iteration callback that may stop the solve, and the summary. Nothing is printed.
//!
//! [`raw`] holds the generated bindings; [`Problem`] is the thin safe wrapper, the only other
//! place with `unsafe`. Panics in a callback are caught before they reach C++ and count as a
//! failed evaluation.
//!
//! ```
//! use volver_ceres_sys::{CostFunction, Loss, Options, Problem, Termination};
//! /// r(x) = (x0 − 1, 10 (x1 − x0²)): Rosenbrock as least squares.
//! struct Rosenbrock;
//! impl CostFunction for Rosenbrock {
//!     fn evaluate(&self, _b: usize, x: &[f64], r: &mut [f64], j: Option<&mut [f64]>) -> bool {
//!         r[0] = x[0] - 1.0;
//!         r[1] = 10.0 * (x[1] - x[0] * x[0]);
//!         if let Some(j) = j {
//!             j.copy_from_slice(&[1.0, 0.0, -20.0 * x[0], 10.0]);
//!         }
//!         true
//!     }
//! }
//! let cost = Rosenbrock;
//! let mut problem = Problem::new(&[-1.2, 1.0], 1, 2, &cost, Loss::None).unwrap();
//! let summary = problem.solve(&Options::default(), &mut |_, _| Default::default()).unwrap();
//! assert_eq!(summary.termination, Termination::Convergence);
//! let x = problem.params();
//! assert!((x[0] - 1.0).abs() < 1e-8 && (x[1] - 1.0).abs() < 1e-8);
//! ```
#![deny(missing_docs)]

use std::ffi::{CStr, c_int, c_void};
use std::panic::{AssertUnwindSafe, catch_unwind};

/// The bindings bindgen generated from `shim/volver_ceres.h`.
#[allow(
    non_camel_case_types,
    non_upper_case_globals,
    non_snake_case,
    missing_docs,
    clippy::all
)]
pub mod raw {
    include!(concat!(env!("OUT_DIR"), "/bindings.rs"));
}

/// Residual blocks of a problem, evaluated on demand.
pub trait CostFunction: Sync {
    /// Writes the residuals of block `block` at `params` into `residuals` and, when asked, its
    /// Jacobian (row-major, residuals × parameters) into `jacobian`. Returns `false` when the
    /// block cannot be evaluated there (Ceres rejects the step).
    fn evaluate(
        &self,
        block: usize,
        params: &[f64],
        residuals: &mut [f64],
        jacobian: Option<&mut [f64]>,
    ) -> bool;
}

/// The loss on each residual block's squared norm `s`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Loss {
    /// `ρ(s) = s`: least squares; Ceres minimises `½ Σ ‖r_i‖²`.
    None,
    /// `ρ(s) = 2(√(s + ε²) − ε)`: Ceres minimises `Σ (√(‖r_i‖² + ε²) − ε)`, the smoothed sum
    /// of error modules (→ `Σ ‖r_i‖` as ε → 0).
    Module {
        /// Smoothing ε (> 0, the residuals' unit).
        epsilon: f64,
    },
    /// Ceres' `SoftLOneLoss(a = ε)`: ε times [`Loss::Module`].
    SoftLOne {
        /// Scale ε (> 0).
        epsilon: f64,
    },
}

/// Which parameters move.
#[derive(Clone, Debug, PartialEq)]
pub enum Space {
    /// All of them.
    Free,
    /// None (the block is constant).
    Constant,
    /// All but these indices (distinct, fewer than all): Ceres' `SubsetManifold`.
    Subset(Vec<usize>),
    /// The affine subspace `x₀ + B t` through the current value: `basis` is row-major
    /// n × `columns` with orthonormal columns (a linear manifold).
    Linear {
        /// Row-major n × `columns`.
        basis: Vec<f64>,
        /// Dimension of the subspace (0 < columns ≤ n).
        columns: usize,
    },
}

/// Trust-region strategy.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TrustRegion {
    /// Levenberg–Marquardt (Ceres' default).
    #[default]
    LevenbergMarquardt,
    /// Powell's dogleg.
    Dogleg,
}

/// Linear solver of the trust-region step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LinearSolver {
    /// Dense QR of the Jacobian (Ceres' default for small problems).
    #[default]
    DenseQr,
    /// Cholesky of the dense normal equations.
    DenseNormalCholesky,
    /// Sparse Cholesky of the normal equations (SuiteSparse).
    SparseNormalCholesky,
    /// Conjugate gradients on the normal equations.
    Cgnr,
}

/// Solver options (the subset of `ceres::Solver::Options` volver sets).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Options {
    /// Trust-region strategy.
    pub trust_region: TrustRegion,
    /// Linear solver.
    pub linear_solver: LinearSolver,
    /// Iteration limit.
    pub max_iterations: usize,
    /// Stop when `|Δcost| / cost` falls below this.
    pub function_tolerance: f64,
    /// Stop when the projected gradient's max norm falls below this.
    pub gradient_tolerance: f64,
    /// Stop when `‖Δx‖ ≤ tol (‖x‖ + tol)`.
    pub parameter_tolerance: f64,
    /// Initial trust-region radius (Ceres' default 1e4 when ≤ 0).
    pub initial_trust_region_radius: f64,
    /// Threads evaluating residual blocks (the cost function must be `Sync`).
    pub threads: usize,
    /// Scale the Jacobian's columns by their norms.
    pub jacobi_scaling: bool,
}

impl Default for Options {
    /// Ceres' defaults: LM, dense QR, 50 iterations, tolerances 1e-6, 1e-10, 1e-8, one thread.
    fn default() -> Self {
        Options {
            trust_region: TrustRegion::LevenbergMarquardt,
            linear_solver: LinearSolver::DenseQr,
            max_iterations: 50,
            function_tolerance: 1e-6,
            gradient_tolerance: 1e-10,
            parameter_tolerance: 1e-8,
            initial_trust_region_radius: 1e4,
            threads: 1,
            jacobi_scaling: true,
        }
    }
}

/// One iteration, as Ceres' iteration callback sees it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Iteration {
    /// Iteration number (0: the start).
    pub iteration: usize,
    /// Whether the step was accepted.
    pub successful: bool,
    /// Ceres' cost `½ Σ ρ(‖r_i‖²)`.
    pub cost: f64,
    /// Change of the cost.
    pub cost_change: f64,
    /// Max norm of the gradient.
    pub gradient_max_norm: f64,
    /// Norm of the step.
    pub step_norm: f64,
    /// Trust-region radius.
    pub trust_region_radius: f64,
    /// Time since the solve started (s).
    pub time_s: f64,
}

/// What the iteration callback asks for.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Control {
    /// Go on.
    #[default]
    Continue,
    /// Stop; Ceres reports `UserFailure`.
    Abort,
    /// Stop; Ceres reports `UserSuccess`.
    Stop,
}

/// Ceres' termination type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Termination {
    /// A tolerance was met (the message says which).
    Convergence,
    /// The iteration limit (or time limit).
    NoConvergence,
    /// Ceres failed (the message says why).
    Failure,
    /// The iteration callback stopped it.
    UserSuccess,
    /// The iteration callback aborted it.
    UserFailure,
}

/// What a solve reports (from `ceres::Solver::Summary`).
#[derive(Clone, Debug, PartialEq)]
pub struct Summary {
    /// Termination type.
    pub termination: Termination,
    /// Ceres' message ("Function tolerance reached. …").
    pub message: String,
    /// Accepted steps.
    pub successful_steps: usize,
    /// Rejected steps.
    pub unsuccessful_steps: usize,
    /// Residual evaluations.
    pub residual_evaluations: usize,
    /// Jacobian evaluations.
    pub jacobian_evaluations: usize,
    /// Cost at the start.
    pub initial_cost: f64,
    /// Cost at the end.
    pub final_cost: f64,
    /// Wall time inside Ceres (s).
    pub time_s: f64,
}

/// A failure of the shim (bad arguments, a C++ exception), with its message.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Error(pub String);

impl std::fmt::Display for Error {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Ceres shim: {}", self.0)
    }
}

impl std::error::Error for Error {}

fn last_error() -> Error {
    // SAFETY: the shim returns a pointer to a NUL-terminated thread-local string that lives
    // until the next shim call on this thread; it is copied at once.
    let msg = unsafe { CStr::from_ptr(raw::volver_ceres_last_error()) };
    Error(msg.to_string_lossy().into_owned())
}

fn check(code: c_int) -> Result<(), Error> {
    if code == 0 { Ok(()) } else { Err(last_error()) }
}

struct CostContext<'c> {
    cost: &'c dyn CostFunction,
    n_params: usize,
    n_residuals: usize,
}

extern "C" fn cost_trampoline(
    user: *mut c_void,
    block: usize,
    params: *const f64,
    residuals: *mut f64,
    jacobian: *mut f64,
) -> c_int {
    // SAFETY: `user` is the `CostContext` the owning `Problem` boxed; it outlives the Ceres
    // problem. Ceres passes the parameter block (n values), room for the block's residuals and,
    // when not null, for its row-major Jacobian (residuals × n).
    let result = catch_unwind(AssertUnwindSafe(|| unsafe {
        let ctx = &*(user as *const CostContext);
        let p = std::slice::from_raw_parts(params, ctx.n_params);
        let r = std::slice::from_raw_parts_mut(residuals, ctx.n_residuals);
        let j = (!jacobian.is_null())
            .then(|| std::slice::from_raw_parts_mut(jacobian, ctx.n_residuals * ctx.n_params));
        ctx.cost.evaluate(block, p, r, j)
    }));
    matches!(result, Ok(true)) as c_int
}

type IterationFn<'f> = dyn FnMut(&Iteration, &[f64]) -> Control + 'f;

extern "C" fn iteration_trampoline(
    user: *mut c_void,
    it: *const raw::volver_ceres_iteration,
) -> raw::volver_ceres_control {
    // SAFETY: `user` points at the `&mut dyn FnMut` and parameter count that `Problem::solve`
    // holds for the duration of the solve; `it` and its parameter block are valid for the
    // duration of the call.
    let result = catch_unwind(AssertUnwindSafe(|| unsafe {
        let (f, n) = &mut *(user as *mut (&mut IterationFn, usize));
        let it = &*it;
        let params = std::slice::from_raw_parts(it.params, *n);
        f(
            &Iteration {
                iteration: it.iteration.max(0) as usize,
                successful: it.step_is_successful != 0,
                cost: it.cost,
                cost_change: it.cost_change,
                gradient_max_norm: it.gradient_max_norm,
                step_norm: it.step_norm,
                trust_region_radius: it.trust_region_radius,
                time_s: it.cumulative_time_s,
            },
            params,
        )
    }));
    match result {
        Ok(Control::Continue) => raw::volver_ceres_control::VOLVER_CERES_CONTINUE,
        Ok(Control::Stop) => raw::volver_ceres_control::VOLVER_CERES_STOP,
        Ok(Control::Abort) | Err(_) => raw::volver_ceres_control::VOLVER_CERES_ABORT,
    }
}

/// A Ceres problem over one parameter block, with residual blocks of equal size evaluated by a
/// [`CostFunction`] that outlives it.
pub struct Problem<'c> {
    raw: *mut raw::volver_ceres_problem,
    // Boxed so that its address, handed to C++, stays put.
    _ctx: Box<CostContext<'c>>,
    n_params: usize,
    loss: Loss,
}

// SAFETY: the shim's problem is only touched through `&mut self` (or `&self` for a read of the
// parameter block); the cost function is `Sync`.
unsafe impl Send for Problem<'_> {}

impl<'c> Problem<'c> {
    /// A problem starting at `params`, with `blocks` residual blocks of `residuals_per_block`
    /// residuals each.
    pub fn new(
        params: &[f64],
        blocks: usize,
        residuals_per_block: usize,
        cost: &'c dyn CostFunction,
        loss: Loss,
    ) -> Result<Problem<'c>, Error> {
        if params.is_empty()
            || residuals_per_block == 0
            || residuals_per_block > c_int::MAX as usize
        {
            return Err(Error(
                "empty parameter block or residual blocks of no residuals".into(),
            ));
        }
        if let Some(j) = params.iter().position(|v| !v.is_finite()) {
            return Err(Error(format!("start value {j} is not finite")));
        }
        let (kind, eps) = loss_kind(loss);
        let ctx = Box::new(CostContext {
            cost,
            n_params: params.len(),
            n_residuals: residuals_per_block,
        });
        // SAFETY: `params` holds `params.len()` values (copied by the shim); `ctx` lives in a Box
        // owned by the returned problem, which frees the shim's problem before the box.
        let raw = unsafe {
            raw::volver_ceres_problem_new(
                params.len(),
                params.as_ptr(),
                blocks,
                residuals_per_block as c_int,
                Some(cost_trampoline),
                &*ctx as *const CostContext as *mut c_void,
                kind,
                eps,
            )
        };
        if raw.is_null() {
            return Err(last_error());
        }
        Ok(Problem {
            raw,
            _ctx: ctx,
            n_params: params.len(),
            loss,
        })
    }

    /// Number of parameters.
    pub fn n_params(&self) -> usize {
        self.n_params
    }

    /// Changes the loss's ε (the loss kind given at creation stays).
    pub fn set_loss_epsilon(&mut self, epsilon: f64) -> Result<(), Error> {
        self.loss = match self.loss {
            Loss::None => return Err(Error("the problem has no loss".into())),
            Loss::Module { .. } => Loss::Module { epsilon },
            Loss::SoftLOne { .. } => Loss::SoftLOne { epsilon },
        };
        // SAFETY: `self.raw` is a live problem.
        check(unsafe { raw::volver_ceres_set_loss_epsilon(self.raw, epsilon) })
    }

    /// Restricts the parameters that move. Call once, before solving.
    pub fn set_space(&mut self, space: &Space) -> Result<(), Error> {
        let n = self.n_params;
        match space {
            Space::Free => Ok(()),
            // SAFETY: `self.raw` is a live problem.
            Space::Constant => check(unsafe { raw::volver_ceres_set_constant(self.raw) }),
            Space::Subset(held) => {
                let mut seen = vec![false; n];
                for &j in held {
                    if j >= n || std::mem::replace(&mut seen[j], true) {
                        return Err(Error(format!("held index {j} repeated or not below {n}")));
                    }
                }
                if held.len() >= n {
                    return Err(Error("every parameter held: use Space::Constant".into()));
                }
                let idx: Vec<c_int> = held.iter().map(|&j| j as c_int).collect();
                // SAFETY: `idx` holds `idx.len()` distinct indices below n (checked above).
                check(unsafe { raw::volver_ceres_set_subset(self.raw, idx.as_ptr(), idx.len()) })
            }
            Space::Linear { basis, columns } => {
                if *columns == 0 || *columns > n || basis.len() != n * columns {
                    return Err(Error(format!(
                        "a linear space needs 0 < columns ≤ {n} and {n} × columns basis values; got {columns} columns and {} values",
                        basis.len()
                    )));
                }
                // SAFETY: `basis` holds n × columns values (checked above).
                check(unsafe { raw::volver_ceres_set_linear(self.raw, basis.as_ptr(), *columns) })
            }
        }
    }

    /// The parameter block's current value.
    pub fn params(&self) -> Vec<f64> {
        let mut out = vec![0.0; self.n_params];
        // SAFETY: `out` has room for the block's n values.
        unsafe { raw::volver_ceres_get_params(self.raw, out.as_mut_ptr()) };
        out
    }

    /// Sets the parameter block (n values).
    pub fn set_params(&mut self, params: &[f64]) -> Result<(), Error> {
        if params.len() != self.n_params {
            return Err(Error(format!(
                "{} values for a block of {}",
                params.len(),
                self.n_params
            )));
        }
        // SAFETY: `params` holds the block's n values.
        check(unsafe { raw::volver_ceres_set_params(self.raw, params.as_ptr()) })
    }

    /// Solves from the current parameters; `on_iteration` sees every iteration and the
    /// parameter block after it, and may stop the solve.
    pub fn solve(
        &mut self,
        options: &Options,
        on_iteration: &mut dyn FnMut(&Iteration, &[f64]) -> Control,
    ) -> Result<Summary, Error> {
        let o = raw::volver_ceres_options {
            trust_region: match options.trust_region {
                TrustRegion::LevenbergMarquardt => {
                    raw::volver_ceres_trust_region::VOLVER_CERES_LEVENBERG_MARQUARDT
                }
                TrustRegion::Dogleg => raw::volver_ceres_trust_region::VOLVER_CERES_DOGLEG,
            },
            linear_solver: match options.linear_solver {
                LinearSolver::DenseQr => raw::volver_ceres_linear_solver::VOLVER_CERES_DENSE_QR,
                LinearSolver::DenseNormalCholesky => {
                    raw::volver_ceres_linear_solver::VOLVER_CERES_DENSE_NORMAL_CHOLESKY
                }
                LinearSolver::SparseNormalCholesky => {
                    raw::volver_ceres_linear_solver::VOLVER_CERES_SPARSE_NORMAL_CHOLESKY
                }
                LinearSolver::Cgnr => raw::volver_ceres_linear_solver::VOLVER_CERES_CGNR,
            },
            max_iterations: options.max_iterations.min(c_int::MAX as usize) as c_int,
            function_tolerance: options.function_tolerance,
            gradient_tolerance: options.gradient_tolerance,
            parameter_tolerance: options.parameter_tolerance,
            initial_trust_region_radius: options.initial_trust_region_radius,
            num_threads: options.threads.clamp(1, 1024) as c_int,
            jacobi_scaling: options.jacobi_scaling as c_int,
        };
        let mut s = raw::volver_ceres_summary::default();
        let mut f: (&mut IterationFn, usize) = (on_iteration, self.n_params);
        // SAFETY: `self.raw` is live; `o` and `s` are valid for the call; the callback's user
        // pointer is `&mut f`, which lives until the call returns.
        let code = unsafe {
            raw::volver_ceres_solve(
                self.raw,
                &o,
                Some(iteration_trampoline),
                &mut f as *mut (&mut IterationFn, usize) as *mut c_void,
                &mut s,
            )
        };
        check(code)?;
        use raw::volver_ceres_termination as T;
        // SAFETY: the shim NUL-terminates the message inside its buffer.
        let message = unsafe { CStr::from_ptr(s.message.as_ptr()) }
            .to_string_lossy()
            .into_owned();
        Ok(Summary {
            termination: match s.termination {
                T::VOLVER_CERES_CONVERGENCE => Termination::Convergence,
                T::VOLVER_CERES_NO_CONVERGENCE => Termination::NoConvergence,
                T::VOLVER_CERES_USER_SUCCESS => Termination::UserSuccess,
                T::VOLVER_CERES_USER_FAILURE => Termination::UserFailure,
                T::VOLVER_CERES_FAILURE => Termination::Failure,
            },
            message,
            successful_steps: s.successful_steps.max(0) as usize,
            unsuccessful_steps: s.unsuccessful_steps.max(0) as usize,
            residual_evaluations: s.residual_evaluations.max(0) as usize,
            jacobian_evaluations: s.jacobian_evaluations.max(0) as usize,
            initial_cost: s.initial_cost,
            final_cost: s.final_cost,
            time_s: s.total_time_s,
        })
    }
}

fn loss_kind(loss: Loss) -> (raw::volver_ceres_loss, f64) {
    use raw::volver_ceres_loss as L;
    match loss {
        Loss::None => (L::VOLVER_CERES_LOSS_NONE, 0.0),
        Loss::Module { epsilon } => (L::VOLVER_CERES_LOSS_MODULE, epsilon),
        Loss::SoftLOne { epsilon } => (L::VOLVER_CERES_LOSS_SOFT_L_ONE, epsilon),
    }
}

impl Drop for Problem<'_> {
    fn drop(&mut self) {
        // SAFETY: `self.raw` was created by `volver_ceres_problem_new` and is freed once.
        unsafe { raw::volver_ceres_problem_free(self.raw) };
    }
}
