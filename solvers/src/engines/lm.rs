//! The native Levenberg–Marquardt engine on `faer`.
//!
//! A solve is a state (the point, the IRLS stage, λ, the design, the damping scale) moved by
//! named steps, in the manner of Ceres' `TrustRegionMinimizer`: a *Jacobian pass* forms the
//! weighted normal equations; the *restriction* reduces them to the free coordinates, applies the
//! gradient test and keeps the identifiable design directions; *trial steps* at growing λ are
//! each *judged* (gain ratio, then the parameter- and objective-change tests) until one is
//! accepted; a Φ fit's *next stage* swaps the majorising model for Newton's; a converged
//! fit is *refined* (least squares) or *polished* (Φ). Each stopping test is a predicate of its
//! own.
//!
//! * **Passes** ([`crate::engines::kernels`]): each pass runs over the points in blocks of
//!   [`crate::engines::kernels::BLOCK`] on every thread, reduced in a tree of fixed shape (the same bits
//!   whatever the threads); no dense Jacobian of the whole problem is kept. For Φ each block's weighted
//!   Jacobian rows (3 per point) are multiplied into its `JᵀWJ`; for least squares (ve) they are
//!   triangularised by a QR, with the residuals as one more column, and merged into the running
//!   factor R by a QR of `[R; R_block]`.
//! * **Scaling.** Parameters are scaled by the inverse column norms of the starting Jacobian, so
//!   millimetres and radians (whose columns differ by the lever arms, ~10³) weigh alike.
//! * **Constraints** by null-space elimination in the scaled coordinates: `p = D (s₀ + N z)`,
//!   with z free ([`crate::nullspace`]). Each step is added to the parameters themselves
//!   (`p + D N δ`), so a parameter that travels far keeps its absolute precision.
//! * **Steps** solve `(H + λ M) δ = −g`, M the largest diagonal of H seen in the step's
//!   coordinates (Moré's scaling, as MINPACK): by Cholesky (an SVD pseudo-inverse if it fails)
//!   for Φ; for least squares as `min ‖R δ + c‖² + λ‖M^½ δ‖²` by QR, which keeps the Jacobian's
//!   condition number instead of its square. The damping follows Nielsen's rule on the gain
//!   ratio.
//! * **Geodesic acceleration** ([`LevenbergMarquardt::geodesic_acceleration`], off by default): the step
//!   `δ + a/2` with `a = −(H + λM)⁻¹ Jᵀ W r''(δ, δ)`, the exact second directional derivative of
//!   the residuals by second-order duals; a step whose correction is too large is refused.
//! * **Unidentifiable directions** (curvature below [`LevenbergMarquardt::rank_tolerance`] of the largest)
//!   are read from the design, the unweighted normal matrix (current for ve; refreshed at each
//!   IRLS stage for Φ), and steps stay in the span of the others. A zero tolerance holds
//!   nothing.
//! * **Refinement** (nothing held): after convergence, for least squares undamped Gauss–Newton
//!   steps from the QR factor, while they contract and the cost is no worse than its rounding;
//!   for Φ Newton steps judged by the exact gradient ([`crate::engines::polish::settle`]): the optimum
//!   of Φ interpolates some points (a residual at the kink of its norm), where the damped steps
//!   slow down and stop on the objective-change test above it (5e-4 on test 1).
//! * **Objectives.** ve (eq. 1) is plain least squares. Φ (eq. 12) is minimised on the
//!   smoothed objective `Φ_ε = (1/n) Σ √(‖r_i‖² + ε²)` in two stages. The *majorising* stage
//!   weights point i by `1/√(‖r_i‖² + ε²)` with its full curvature `J_iᵀJ_i`: that quadratic
//!   model lies above Φ_ε, so its steps lower Φ whatever their size (iteratively reweighted
//!   least squares as a majorise–minimise method), with ε = [`Options::irls_initial_epsilon`] ×
//!   the current Φ. Once a step gains less than 1e-3 of the cost, the *Newton* stage takes over
//!   with ε = [`Options::irls_final_epsilon`] × Φ and the radial curvature reduced by
//!   `‖r_i‖²/(‖r_i‖² + ε²)` (Ceres' Triggs correction), the exact Gauss–Newton model of Φ_ε;
//!   only there do the convergence criteria stop the run. Φ_ε − Φ ≤ ε, so the final Φ is exact
//!   to that fraction. A Newton stage handed a point where its model fails (two trial steps in
//!   a row refused although they predicted a decrease above 1e-9 of the cost: a residual near
//!   the kink of its norm that the optimum does not interpolate, test 1 noisy) hands back to the
//!   majorising stage, which hands over again at a gain a hundred times smaller, down to 1e-6
//!   (from there on the Newton stage runs to the end). The majorising stage smooths the kinks
//!   (ε is a tenth of Φ) and so also chooses among the local minima of a noisy fit: handing
//!   over at 1e-2 took test 2 noisy (seed 22) to a minimum 2.8e-3 above the one 1e-3 and 1e-6
//!   find. On the bench's test 4 a fit takes 10 steps (9 of the LM, every one accepted, 1 of
//!   the polish, which stops once a Newton step moves the error functions by less than 1e-10
//!   of their size).
//! * **Ranges alone** ([`Residuals::scalar`] for every point: a range's module is its absolute
//!   value, so Φ is an L1 fit, whose optimum is a vertex where as many ranges are interpolated as
//!   there are free coordinates). Smoothing sees only the residuals within ε of zero, so the Newton
//!   stages crawl towards a vertex (a continuation in ε from 1e-2 Φ down to 1e-6 Φ took 80–150
//!   steps on test 4's ranges from four stations, then the Newton polish forty more of 0.5 s each,
//!   and ended 4e-7 … 1.5e-6 above the optimum). Instead, once the majorising stage has slowed
//!   down, the vertex is found exactly by sequential linear programmes
//!   ([`crate::engines::polish::settle`] on scalar residuals: the simplex method of L1 regression,
//!   then Newton's steps on the interpolated ranges), and the run ends there on the
//!   parameter-change test (its last step negligible): 10 LM steps and 3 linear programmes
//!   (140–260 pivots in the first, a few after) on those ranges, in less time than ve's fit of the
//!   same data, whether or not [`LevenbergMarquardt::polish`] is set. Should the linear programmes
//!   fail (the rows not spanning the free coordinates, a singular basis, a limit), the Newton
//!   stages go on, with ε lowered tenfold each time one converges, down to 1e-6 Φ, and try again
//!   where each converges.
//!
//! ```
//! use volver_core::machine::Machine;
//! use volver_core::model::ErrorModelSpec;
//! use volver_core::noise::TrackerNoise;
//! use volver_core::plan::Plan;
//! use volver_core::problem::Problem;
//! use volver_core::simulate::{Magnitudes, Simulation, Truth};
//! use volver_solvers::{lm::LevenbergMarquardt, Options, Silent, Solver, Task};
//! let m = Machine::default_xcfz();
//! let truth = Truth::random(&m, &ErrorModelSpec::complete(&m), &Magnitudes::default(), 1).unwrap();
//! let mut sim = Simulation::new(Plan::preset(&m, "test3").unwrap(), truth, 1);
//! sim.noise = TrackerNoise::NONE;
//! let data = sim.run().unwrap().measurements;
//! let model = volver_core::model::Model::default_xcfz();
//! let problem = Problem::new(&model, &data).unwrap();
//! let sol = LevenbergMarquardt::default().solve(&Task::new(problem), &model.initial_params(),
//!                                    &Options::default(), &mut Silent);
//! assert!(sol.summary.termination.converged());
//! assert!(sol.summary.reached.stats.emm_um < 1e-6 * sol.summary.initial.stats.emm_um);
//! ```

mod damping;
mod finish;
mod geodesic;
pub(crate) mod irls;
mod restrict;
#[cfg(test)]
mod tests;
mod threads;

use crate::engines::coordinates::Free;
use crate::engines::kernels::{
    accumulate, accumulate_weighted, damped_lstsq, normal_solve, solve_spd,
};
use crate::engines::loss::{cost_of, norms_of, weight_of};
use crate::engines::run::{Started, begin};
use crate::options::{ACCELERATION_RATIO, Objective, Options};
use crate::summary::{At, Failure, Termination};
use crate::{Iteration, Observer, Solution, Solver, Task};
use damping::Damping;
use faer::Mat;
use geodesic::curvature_gradient;
use irls::{Irls, Stage};
use restrict::Restricted;
use volver_core::problem::{Residuals, norm};
use volver_core::units::UM_PER_MM;

/// Gauss–Newton refinements of a converged least-squares fit, at most.
const REFINEMENTS: usize = 100;

/// A trial step is accepted when it lowers the cost by more than this share of the decrease
/// its model predicted (the gain ratio ρ).
const ACCEPTANCE: f64 = 1e-4;

/// The native engine (always available), with the settings only it reads; the criteria every
/// engine shares are in [`Options`].
///
/// ```
/// use volver_solvers::lm::LevenbergMarquardt;
/// let mut lm = LevenbergMarquardt::default();
/// assert_eq!(lm.rank_tolerance, volver_solvers::identifiability::RANK_TOLERANCE);
/// lm.geodesic_acceleration = true;
/// assert_eq!(lm, LevenbergMarquardt::with_geodesic_acceleration(true));
/// ```
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
#[non_exhaustive]
pub struct LevenbergMarquardt {
    /// Directions of the scaled, unweighted normal matrix (the design; not the IRLS-weighted
    /// one) whose curvature is below this fraction of the largest are not identifiable from the
    /// data and are held (no step along them), so that nearly redundant parameters do not
    /// drift to meaningless values while Φ creeps down by fractions of a nanometre. Once Φ
    /// falls below 1e-4 of its start (a nearly exact fit, where the Gauss–Newton model is exact
    /// too) the fraction shrinks in proportion, so an exact fit may use every direction.
    /// Default [`crate::nullspace::RANK_TOLERANCE`], 1e-10 (a condition number of 10⁵ on
    /// the scaled Jacobian); zero holds nothing.
    pub rank_tolerance: f64,
    /// Correct each step by geodesic acceleration (Transtrum & Sethna 2012): the exact second
    /// directional derivative of the residuals along the step bends it along the curved valleys
    /// of strongly nonlinear models, and a step whose correction exceeds
    /// [`crate::options::ACCELERATION_RATIO`] of it (in the damping norm) is refused. It costs
    /// one Jacobian and one second-derivative pass per step tried. Default false: the machine
    /// models are mildly nonlinear; the NIST suite ([`crate::engines::nist_suite::lm`]) turns it on.
    pub geodesic_acceleration: bool,
    /// Φ: polish a converged fit with nothing held by Newton steps judged by the exact
    /// gradient ([`crate::engines::polish::settle`]), so that where the damped steps stopped along
    /// weakly identified directions does not show in the result (engines and starts then agree
    /// on the error functions to ~1e-9). On test 4 it is about half of a fit's time. Default
    /// true; Monte Carlo replicas ([`crate::analysis::uncertainty::monte_carlo`]) turn it off: their
    /// spread is the noise's, a million times larger. A Φ fit of ranges alone ends at the exact
    /// vertex of its L1 optimum whatever this says: that finish is how it converges, and it is
    /// faster than the continuation it replaces (see the module documentation).
    pub polish: bool,
    /// Threads of the solve's passes: `Some(n)` runs the solve on a rayon pool of `n` threads
    /// of its own (1 … [`crate::settings::MAX_THREADS`]), built for the solve and dropped after
    /// it; `None` uses rayon's global pool (`RAYON_NUM_THREADS`, else one thread per core).
    /// The result does not depend on it, to the bit: each pass reduces its blocks in a tree of
    /// fixed shape. Default `None`.
    pub threads: Option<usize>,
}

impl Default for LevenbergMarquardt {
    fn default() -> Self {
        LevenbergMarquardt {
            rank_tolerance: crate::nullspace::RANK_TOLERANCE,
            geodesic_acceleration: false,
            polish: true,
            threads: None,
        }
    }
}

impl LevenbergMarquardt {
    /// The engine with geodesic acceleration on or off (the rest default).
    pub fn with_geodesic_acceleration(geodesic_acceleration: bool) -> Self {
        LevenbergMarquardt {
            geodesic_acceleration,
            ..LevenbergMarquardt::default()
        }
    }
}

/// A trial step: the step in z (velocity plus half the acceleration) and the damped system's
/// velocity alone, for the predicted decrease.
struct Trial {
    total: Vec<f64>,
    delta: Vec<f64>,
}

/// The damped system's solution at one λ: the velocity `y` in the span's scaled coordinates,
/// the least-squares factor `R_λ` when the pass has one, and the damped normal matrix (the
/// Cholesky route's, and the acceleration's without a factor).
struct Velocity {
    y: Vec<f64>,
    lsq: Option<(Vec<f64>, Mat<f64>)>,
    damped: Mat<f64>,
}

/// A trial point: its parameters, its distance from the start in z, its residual modules and
/// its cost.
struct Candidate {
    p: Vec<f64>,
    z: Vec<f64>,
    norms: Vec<f64>,
    cost: f64,
}

/// What became of a trial step.
enum Verdict {
    /// Accepted, or the stage changed: the next Jacobian pass.
    NextPass,
    /// Refused: another trial with more damping.
    Retry,
}

/// The state of one native solve, in the manner of Ceres' `TrustRegionMinimizer`: each
/// iteration is a [`Lm::jacobian_pass`], its [`Lm::restrict`]ion to the identifiable directions,
/// then [`Lm::trial_step`]s, each [`Lm::judge`]d (accepted or refused) until one is accepted or
/// a criterion stops the run; [`Lm::next_stage`] changes the IRLS stage of a Φ fit and
/// [`Lm::refine`] polishes a converged least-squares fit. The damping and the IRLS schedule are
/// states of their own ([`Damping`], [`Irls`]).
struct Lm<'t, 'a, 'o> {
    run: crate::engines::run::Run<'t, 'a>,
    problem: &'t (dyn Residuals + 'a),
    options: &'o Options,
    settings: LevenbergMarquardt,
    objective: Objective,
    free: Free,
    /// Whether some constraint rows are dense (a gauge): steps then always go in the design's
    /// directions (a diagonal damping in z has no meaning).
    dense_rows: bool,
    /// The parameters, the step's distance from the start in the scaled free coordinates, and
    /// the residual modules at p (mm).
    p: Vec<f64>,
    z: Vec<f64>,
    norms: Vec<f64>,
    /// The IRLS stage and ε.
    irls: Irls,
    cost: f64,
    /// The first cost (the gradient test's scale) and Φ at the start (mm).
    cost0: f64,
    phi0: f64,
    damping: Damping,
    /// The design's curvatures and directions in z, how many times it was computed, and
    /// whether the next pass recomputes it (a new IRLS stage).
    design: (Vec<f64>, Mat<f64>),
    design_generation: usize,
    refresh: bool,
    /// The unweighted normal matrix whose design the next pass decomposes while it forms its
    /// own equations (on the other threads): the start's, then a new IRLS stage's.
    pending_design: Option<Mat<f64>>,
    /// Moré's scaling: the largest diagonal seen in the current coordinates, which ones, and
    /// whether the next pass starts it afresh.
    dmax: Vec<f64>,
    scale_coords: Option<(usize, usize)>,
    reset_scale: bool,
    /// Whether this is a Φ fit of scalar residuals alone (an L1 fit), which ends at the
    /// vertex of its optimum ([`Lm::vertex_finish`]), and whether the next pass tries it.
    l1: bool,
    vertex_due: bool,
}

impl<'t, 'a, 'o> Lm<'t, 'a, 'o> {
    /// The state at the start (its design is decomposed by the first pass).
    fn new(
        begun: Started<'t, 'a>,
        task: &'t Task<'a>,
        options: &'o Options,
        settings: LevenbergMarquardt,
    ) -> Self {
        let Started {
            run,
            free,
            start_normal,
            p0,
            norms0,
        } = begun;
        // What the data cannot identify is a property of the design: it is read from the
        // unweighted normal matrix (Marquardt-scaled, eigen-decomposed), not from the
        // IRLS-weighted matrices of a Φ fit, whose weights spread the curvatures by up to Φ/ε and
        // would hide identifiable directions near its end. For ve the current matrix is the
        // design; for Φ it is refreshed at the start of every IRLS stage (a nonlinear basis,
        // such as a sine's phase at zero amplitude, becomes identifiable as the fit moves).
        // The first pass decomposes it.
        let objective = options.objective.loss();
        let np = norms0.len();
        let phi0 = norms0.iter().sum::<f64>() / np as f64;
        let scalar = (0..task.problem.n_points()).any(|i| task.problem.scalar(i));
        let irls = Irls::new(options, scalar, phi0);
        let cost = cost_of(objective, &norms0, irls.eps());
        // A gauge's rows are dense combinations of every parameter, so the free coordinates z
        // mix them all and a diagonal damping in z has no meaning (measured on test 3: 214
        // iterations instead of 42). Steps are then taken in the design's directions, as when
        // some are held.
        let dense_rows = task
            .constraints
            .rows
            .iter()
            .any(|r| r.kind == volver_core::model::ConstraintKind::Gauge);
        Lm {
            problem: &*task.problem,
            run,
            options,
            settings,
            objective,
            z: vec![0.0; free.n_free()],
            free,
            dense_rows,
            p: p0,
            norms: norms0,
            irls,
            cost,
            cost0: cost,
            phi0,
            damping: Damping::new(options.initial_damping),
            design: (Vec::new(), Mat::new()),
            design_generation: 0,
            refresh: false,
            pending_design: Some(start_normal.h),
            dmax: Vec::new(),
            scale_coords: None,
            reset_scale: false,
            l1: objective == Objective::Phi && crate::engines::polish::all_scalar(&*task.problem),
            vertex_due: false,
        }
    }

    fn np(&self) -> usize {
        self.norms.len()
    }

    /// The evaluations a trial step takes: its residuals, and with geodesic acceleration the
    /// second-derivative pass.
    fn trial_evaluations(&self) -> usize {
        1 + usize::from(self.settings.geodesic_acceleration)
    }

    /// Whether the limits leave room for the worst case of a finish after convergence (the Φ
    /// polish, the vertex of an L1 fit: [`crate::engines::polish::FINISH_EVALUATIONS`] and
    /// [`crate::engines::polish::FINISH_STEPS`]); without it the finish is skipped, so that the
    /// counts stay within the limits.
    fn room_to_finish(&self) -> bool {
        let s = &self.run.summary;
        s.evaluations + crate::engines::polish::FINISH_EVALUATIONS <= self.options.max_evaluations
            && s.iterations + crate::engines::polish::FINISH_STEPS <= self.options.max_iterations
    }

    /// Φ at the current point (mm).
    fn phi(&self) -> f64 {
        self.norms.iter().sum::<f64>() / self.np() as f64
    }

    /// The cost at the current point under the current ε (after ε changed).
    fn recost(&mut self) {
        self.cost = cost_of(self.objective, &self.norms, self.irls.eps());
    }

    /// The progress report of a trial.
    fn report(&self, observer: &mut dyn Observer, damping: f64, step: f64, accepted: bool) {
        observer.iteration(&Iteration {
            iteration: self.run.summary.iterations,
            evaluations: self.run.summary.evaluations,
            cost: self.cost,
            emm_um: self.phi() * UM_PER_MM,
            damping,
            step,
            accepted,
        });
    }

    // The stopping tests.

    /// The gradient test (Newton stage only): the largest scaled gradient component below
    /// `gradient_tolerance` of the first cost.
    fn gradient_converged(&self, gmax: f64) -> bool {
        self.irls.stage() == Stage::Newton
            && (self.cost == 0.0 || gmax <= self.options.gradient_tolerance * self.cost0)
    }

    /// Criterion 1, minimum parameter change, for a step of length `step` in z.
    fn small_step(&self, step: f64) -> bool {
        let znorm = self.z.iter().map(|v| v * v).sum::<f64>().sqrt();
        let tol = self.options.parameter_tolerance;
        step <= tol * (znorm + tol)
    }

    /// Criterion 2, minimum objective change, for an accepted step from the cost `old`.
    fn small_change(&self, old: f64) -> bool {
        old - self.cost <= self.objective_tolerance() * old
    }

    /// Criterion 2 for a refused step (MINPACK's `ftol` test): the decrease the model predicted,
    /// `pred`, and the change measured, `actual`, are both within the objective-change
    /// tolerance of the cost. The step was refused on the cost's rounding, and a more damped one
    /// would predict less still: whatever it measured, an accepted step would stop the run on
    /// the objective-change test (on test 4 with the demo's data: four refused steps predicting
    /// 6e-16 of the cost while measuring ±1e-13, then one accepted).
    fn within_rounding(&self, pred: f64, actual: f64) -> bool {
        let tol = self.objective_tolerance() * self.cost;
        pred <= tol && actual.abs() <= tol
    }

    /// The objective-change test's tolerance: [`Options::objective_tolerance`], but for a Φ
    /// fit with scalar residuals no finer than a thousandth of the current ε's share of Φ (the
    /// smoothing moves Φ by up to ε: a stage has converged once its steps gain far less, and
    /// the next, smaller ε takes over).
    fn objective_tolerance(&self) -> f64 {
        self.irls
            .objective_tolerance(self.options.objective_tolerance)
    }

    /// Whether the majorising stage has slowed down: an accepted step from `old` gained less
    /// than the hand-over gain of the cost ([`Irls::majorising_slowed`]).
    fn majorising_slowed(&self, old: f64) -> bool {
        self.irls.majorising_slowed(old, self.cost)
    }

    // The named steps.

    /// One Jacobian pass at the current point: the majorising stage's ε moved to the current
    /// Φ, the weighted normal equations, and the design: the start's decomposed beside the
    /// first pass (which does not depend on it), a new stage's unweighted equations formed in
    /// the same pass as its weighted ones (one evaluation of each point's Jacobian), then
    /// decomposed.
    fn jacobian_pass(&mut self) -> Result<crate::engines::kernels::Normal, Termination> {
        let iterations = self.run.summary.iterations;
        // A pass is worth its evaluation only with room for a trial after it.
        if self.run.summary.evaluations + 1 + self.trial_evaluations()
            > self.options.max_evaluations
        {
            return Err(Termination::EvaluationLimit);
        }
        let decomposition_failed = |at| {
            Termination::NumericalFailure(Failure::Decomposition {
                matrix: "the design's normal matrix",
                at,
            })
        };
        // The start's design fails at the start; a new stage's at this iteration.
        let pending = self.pending_design.take();
        let at = if pending.is_some() {
            At::Start
        } else {
            At::Iteration(iterations)
        };
        let refresh = self.refresh && self.objective == Objective::Phi;
        self.refresh = false;
        if self.irls.follow(self.phi()) {
            self.recost();
        }
        let (design, normal) = self.weighted_pass(refresh, pending.as_ref());
        let Some(normal) = normal else {
            return Err(Termination::NumericalFailure(Failure::JacobianNotFinite(
                At::Iteration(iterations),
            )));
        };
        if let Some(design) = design {
            self.design = design.ok_or(decomposition_failed(at))?;
            self.design_generation += 1;
        }
        self.run.summary.evaluations += 1;
        self.run.summary.jacobian_evaluations += 1;
        Ok(normal)
    }

    /// The pass itself: the weighted normal equations at p and, when asked, a design (the
    /// unweighted equations of this very pass when `refresh`, else the `pending` matrix
    /// decomposed on the other threads); `None` where a decomposition or the pass failed.
    #[allow(clippy::type_complexity)]
    fn weighted_pass(
        &self,
        refresh: bool,
        pending: Option<&Mat<f64>>,
    ) -> (
        Option<Option<(Vec<f64>, Mat<f64>)>>,
        Option<crate::engines::kernels::Normal>,
    ) {
        let np = self.np();
        let weighted = |r: f64| self.irls.weight(r, np);
        if refresh {
            // A new stage: its design (unweighted) and its equations from one pass, then the
            // design decomposed.
            let both = accumulate_weighted(self.problem, &self.p, &weighted, true, false);
            match both {
                Some(mut both) => {
                    let normal = both.pop();
                    let plain = both.pop().map(|plain| plain.h);
                    (
                        plain.map(|h| crate::engines::coordinates::design_of(&self.free, &h)),
                        normal,
                    )
                }
                None => (None, None),
            }
        } else {
            rayon::join(
                || pending.map(|h| crate::engines::coordinates::design_of(&self.free, h)),
                || {
                    accumulate(
                        self.problem,
                        &self.p,
                        weighted,
                        self.objective == Objective::Ve,
                    )
                },
            )
        }
    }

    /// The damped step at the current λ, corrected by geodesic acceleration when asked;
    /// `Ok(None)` when the acceleration refuses it (λ has grown: try again).
    fn trial_step(
        &mut self,
        r: &Restricted,
        observer: &mut dyn Observer,
    ) -> Result<Option<Trial>, Termination> {
        let velocity = self.velocity(r);
        let delta = r.to_z(&velocity.y);
        if delta.iter().any(|v| !v.is_finite()) {
            return Err(Termination::NumericalFailure(Failure::StepNotFinite(
                At::Iteration(self.run.summary.iterations),
            )));
        }
        let mut total = delta.clone();
        if self.settings.geodesic_acceleration {
            let Some(a) = self.acceleration(r, &velocity, &delta, observer)? else {
                return Ok(None);
            };
            for (t, a) in total.iter_mut().zip(a) {
                *t += 0.5 * a;
            }
        }
        Ok(Some(Trial { total, delta }))
    }

    /// The damped system `(H' + λ I) y = −g'` solved at the current λ: with the factor, the QR
    /// of `[R'; √λ I]` (whose `R_λ` also gives `(H' + λI)⁻¹` for the acceleration); else
    /// Cholesky of the damped normal matrix (an SVD pseudo-inverse if it fails; NaN where both
    /// fail).
    fn velocity(&self, r: &Restricted) -> Velocity {
        let nr = r.gp.len();
        let lambda = self.damping.lambda();
        let damped = Mat::from_fn(nr, nr, |i, j| {
            r.hp[(i, j)] + if i == j { lambda } else { 0.0 }
        });
        let rhs: Vec<f64> = r.gp.iter().map(|g| -g).collect();
        let lsq = r
            .factor
            .as_ref()
            .and_then(|(_, rps, c)| damped_lstsq(rps, c, lambda));
        let y = match &lsq {
            Some((y, _)) => y.clone(),
            None => solve_spd(&damped, &rhs).unwrap_or_else(|| vec![f64::NAN; nr]),
        };
        Velocity { y, lsq, damped }
    }

    /// Geodesic acceleration of the velocity `delta` (z): `a = −(H + λM)⁻¹ Jᵀ W r''(δ, δ)` in
    /// z; `Ok(None)` (a refused trial, λ grown) when `2‖a‖ > α‖δ‖` in the damping norm, α =
    /// [`ACCELERATION_RATIO`].
    fn acceleration(
        &mut self,
        r: &Restricted,
        velocity: &Velocity,
        delta: &[f64],
        observer: &mut dyn Observer,
    ) -> Result<Option<Vec<f64>>, Termination> {
        let iterations = self.run.summary.iterations;
        let nr = r.gp.len();
        let ynorm = velocity.y.iter().map(|v| v * v).sum::<f64>().sqrt();
        let accel = (ynorm > 0.0)
            .then(|| {
                curvature_gradient(
                    self.problem,
                    &self.free,
                    &self.p,
                    delta,
                    self.objective,
                    self.irls.eps(),
                )
            })
            .flatten();
        self.run.summary.evaluations += 1;
        self.run.summary.jacobian_evaluations += 1;
        let Some(bz) = accel else {
            return Err(Termination::NumericalFailure(
                Failure::SecondDerivativeNotFinite(At::Iteration(iterations)),
            ));
        };
        let nf = self.free.n_free();
        let bq: Vec<f64> = match &r.q {
            None => bz,
            Some(q) => (0..nr)
                .map(|c| (0..nf).map(|k| q[(k, c)] * bz[k]).sum())
                .collect(),
        };
        let rhs: Vec<f64> = bq.iter().zip(&r.sc).map(|(b, s)| -b * s).collect();
        let ya = match &velocity.lsq {
            Some((_, rl)) => normal_solve(rl, &rhs),
            None => solve_spd(&velocity.damped, &rhs),
        }
        .unwrap_or_else(|| vec![f64::NAN; nr]);
        let anorm = ya.iter().map(|v| v * v).sum::<f64>().sqrt();
        // A NaN ratio refuses the step too.
        let small_enough = 2.0 * anorm <= ACCELERATION_RATIO * ynorm;
        if !small_enough {
            let step = delta.iter().map(|v| v * v).sum::<f64>().sqrt();
            self.report(observer, self.damping.lambda(), step, false);
            self.damping.rejected();
            if self.damping.exhausted() {
                return Err(Termination::NumericalFailure(
                    Failure::AccelerationRefusedEveryStep(At::Iteration(iterations)),
                ));
            }
            return Ok(None);
        }
        Ok(Some(r.to_z(&ya)))
    }

    /// Evaluates a trial and accepts or refuses it on the gain ratio, then applies the stopping
    /// tests and the stage change that follow.
    fn judge(
        &mut self,
        r: &Restricted,
        trial: Trial,
        observer: &mut dyn Observer,
    ) -> Result<Verdict, Termination> {
        let Trial { total, delta } = trial;
        let step = total.iter().map(|v| v * v).sum::<f64>().sqrt();
        let small_step = self.small_step(step);
        let pred = r.predicted_decrease(&delta);
        let p = self.free.step(&self.p, &total);
        let z: Vec<f64> = self.z.iter().zip(&total).map(|(a, b)| a + b).collect();
        let norms = norms_of(self.problem, &p);
        self.run.summary.evaluations += 1;
        let cost = cost_of(self.objective, &norms, self.irls.eps());
        if !cost.is_finite() {
            self.run.nonfinite_trial();
        }
        let rho = if cost.is_finite() && pred > 0.0 {
            (self.cost - cost) / pred
        } else {
            -1.0
        };
        if rho > ACCEPTANCE {
            let candidate = Candidate { p, z, norms, cost };
            self.accept(candidate, rho, step, small_step, observer)
        } else {
            self.refuse(pred, cost, step, small_step, observer)
        }
    }

    /// A refused trial (predicted decrease `pred`, cost measured `cost_new`, length `step`):
    /// more damping and another trial, unless the Newton stage failed (the majorising stage
    /// resumes), the step was small, the change within the cost's rounding or the damping
    /// exhausted (the run stops in the Newton stage; the majorising stage hands over).
    fn refuse(
        &mut self,
        pred: f64,
        cost_new: f64,
        step: f64,
        small_step: bool,
        observer: &mut dyn Observer,
    ) -> Result<Verdict, Termination> {
        self.report(observer, self.damping.lambda(), step, false);
        self.damping.rejected();
        // Only a refusal of a decrease well above the cost's rounding counts: near the
        // optimum refusals are how the damping finds the rounding.
        self.irls.refused(pred, self.cost);
        if self.irls.newton_failed() {
            self.majorising_again();
            return Ok(Verdict::NextPass);
        }
        let rounding = self.within_rounding(pred, self.cost - cost_new);
        if small_step || rounding || self.damping.exhausted() {
            if self.irls.stage() == Stage::Newton {
                return Err(if rounding {
                    Termination::ObjectiveChange
                } else {
                    Termination::ParameterChange
                });
            }
            self.next_stage(true);
            return Ok(Verdict::NextPass);
        }
        Ok(Verdict::Retry)
    }

    /// An accepted trial (gain ratio `rho`, length `step`): the point moves, λ follows
    /// Nielsen's rule, then the Newton stage's parameter- and objective-change tests, or the
    /// majorising stage's hand-over.
    fn accept(
        &mut self,
        candidate: Candidate,
        rho: f64,
        step: f64,
        small_step: bool,
        observer: &mut dyn Observer,
    ) -> Result<Verdict, Termination> {
        self.run.improved();
        self.irls.accepted();
        let old = self.cost;
        let Candidate { p, z, norms, cost } = candidate;
        self.p = p;
        self.z = z;
        self.norms = norms;
        self.cost = cost;
        self.report(observer, self.damping.lambda(), step, true);
        self.damping.accepted(rho);
        match self.irls.stage() {
            Stage::Newton if small_step => Err(Termination::ParameterChange),
            Stage::Newton if self.small_change(old) => Err(Termination::ObjectiveChange),
            Stage::Majorising if small_step || self.majorising_slowed(old) => {
                // The majorising stage has slowed down: Newton takes over.
                self.next_stage(false);
                Ok(Verdict::NextPass)
            }
            _ => Ok(Verdict::NextPass),
        }
    }

    /// Φ's Newton stage begins ([`Irls::hand_over`]), the design refreshed and Moré's scaling
    /// restarted at the next pass; `restart_damping` when the majorising stage ended on refused
    /// steps.
    fn next_stage(&mut self, restart_damping: bool) {
        self.vertex_due = self.l1;
        self.irls.hand_over(self.phi());
        self.refresh = true;
        self.reset_scale = true;
        self.recost();
        if restart_damping {
            self.damping.restart();
        }
    }

    /// A Φ fit with scalar residuals whose Newton stage converged above the final ε goes on
    /// from there with a smaller ε ([`Irls::shrink`], the damping kept); `false` when ε is
    /// already the final one, or for any other fit.
    fn shrink_epsilon(&mut self) -> bool {
        if !self.irls.shrink(self.phi()) {
            return false;
        }
        self.recost();
        true
    }

    /// Φ's majorising stage resumes (the Newton stage failed where it was handed the point,
    /// [`Irls::back_to_majorising`]): the design refreshed, Moré's scaling and the damping
    /// restarted.
    fn majorising_again(&mut self) {
        self.irls.back_to_majorising(self.phi());
        self.recost();
        self.refresh = true;
        self.reset_scale = true;
        self.damping.restart();
    }
}

impl Solver for LevenbergMarquardt {
    fn name(&self) -> &'static str {
        "lm"
    }

    fn solve(
        &self,
        task: &Task,
        start: &[f64],
        options: &Options,
        observer: &mut dyn Observer,
    ) -> Solution {
        // Invalid settings are refused by the solve itself, after the start's evaluation.
        if let Some(threads) = self.threads.filter(|_| self.validate().is_ok()) {
            let on_pool = threads::on_threads(threads, observer, |observer| {
                self.solve_here(task, start, options, observer)
            });
            // A pool the system refuses: the caller's threads give the same bits.
            if let Some(solution) = on_pool {
                return solution;
            }
        }
        self.solve_here(task, start, options, observer)
    }
}

impl LevenbergMarquardt {
    /// [`Solver::solve`] on the calling thread's rayon pool.
    fn solve_here(
        &self,
        task: &Task,
        start: &[f64],
        options: &Options,
        observer: &mut dyn Observer,
    ) -> Solution {
        let begun = match begin(self.name(), task, start, options) {
            Ok(b) => b,
            Err(solution) => return *solution,
        };
        if let Err(e) = self.validate() {
            let t = Termination::InvalidInput(crate::Invalid::Refused(e));
            return begun.run.finish(begun.p0, t);
        }
        let mut lm = Lm::new(begun, task, options, *self);
        let termination = 'passes: loop {
            if std::mem::take(&mut lm.vertex_due) && lm.vertex_finish() {
                break 'passes Termination::ParameterChange;
            }
            let restricted = match lm.jacobian_pass().and_then(|normal| lm.restrict(normal)) {
                Ok(r) => r,
                Err(t) if t.converged() && lm.vertex_finish() => break t,
                Err(t) if t.converged() && lm.shrink_epsilon() => continue 'passes,
                Err(t) => break t,
            };
            // Trial steps until one is accepted, the stage changes or a criterion stops the run.
            loop {
                let summary = &lm.run.summary;
                if summary.iterations >= options.max_iterations {
                    break 'passes Termination::IterationLimit;
                }
                if summary.evaluations + lm.trial_evaluations() > options.max_evaluations {
                    break 'passes Termination::EvaluationLimit;
                }
                lm.run.summary.iterations += 1;
                let verdict = lm
                    .trial_step(&restricted, observer)
                    .and_then(|trial| match trial {
                        Some(trial) => lm.judge(&restricted, trial, observer),
                        None => Ok(Verdict::Retry),
                    });
                match verdict {
                    Ok(Verdict::NextPass) => break,
                    Ok(Verdict::Retry) => {}
                    Err(t) if t.converged() && lm.vertex_finish() => break 'passes t,
                    Err(t) if t.converged() && lm.shrink_epsilon() => continue 'passes,
                    Err(t) => break 'passes t,
                }
            }
        };
        if options.objective.loss() == Objective::Ve
            && termination.converged()
            && lm.run.summary.unidentifiable == 0
        {
            lm.refine(observer);
        }
        if options.objective.loss() == Objective::Phi
            && self.polish
            && !lm.run.summary.polished
            && termination.converged()
            && lm.run.summary.unidentifiable == 0
        {
            lm.polish(task);
        }
        let Lm { run, p, .. } = lm;
        run.finish(p, termination)
    }
}
