//! The native Levenberg–Marquardt engine on `faer`.
//!
//! * **Passes** ([`crate::kernels`]): each pass runs over the points in blocks of
//!   [`crate::kernels::BLOCK`] on every thread, reduced in block order (the same bits whatever
//!   the threads); no dense Jacobian of the whole problem is kept. For Φ each block's weighted
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
//! * **Geodesic acceleration** ([`Options::geodesic_acceleration`], off by default): the step
//!   `δ + a/2` with `a = −(H + λM)⁻¹ Jᵀ W r''(δ, δ)`, the exact second directional derivative of
//!   the residuals by second-order duals; a step whose correction is too large is refused.
//! * **Unidentifiable directions** (curvature below [`Options::rank_tolerance`] of the largest)
//!   are read from the design, the unweighted normal matrix (current for ve; refreshed at each
//!   IRLS stage for Φ), and steps stay in the span of the others. A zero tolerance holds
//!   nothing.
//! * **Refinement** (least squares, nothing held): after convergence, undamped Gauss–Newton
//!   steps from the QR factor, while they contract and the cost is no worse than its rounding.
//! * **Objectives.** ve (eq. 1) is plain least squares. Φ (eq. 12) is minimised on the
//!   smoothed objective `Φ_ε = (1/n) Σ √(‖r_i‖² + ε²)` in two stages. The *majorising* stage
//!   weights point i by `1/√(‖r_i‖² + ε²)` with its full curvature `J_iᵀJ_i`: that quadratic
//!   model lies above Φ_ε, so its steps lower Φ whatever their size (iteratively reweighted
//!   least squares as a majorise–minimise method), with ε = [`Options::irls_initial_epsilon`] ×
//!   the current Φ. Once a step gains less than 1e-6 of the cost, the *Newton* stage takes over
//!   with ε = [`Options::irls_final_epsilon`] × Φ and the radial curvature reduced by
//!   `‖r_i‖²/(‖r_i‖² + ε²)` (Ceres' Triggs correction), the exact Gauss–Newton model of Φ_ε;
//!   only there do the convergence criteria stop the run. Φ_ε − Φ ≤ ε, so the final Φ is exact
//!   to that fraction.
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
//! let sol = LevenbergMarquardt.solve(&Task::new(problem), &model.initial_params(),
//!                                    &Options::default(), &mut Silent);
//! assert!(sol.summary.termination.converged());
//! assert!(sol.summary.final_.stats.emm_um < 1e-6 * sol.summary.initial.stats.emm_um);
//! ```

use crate::coordinates::{Free, design_from_reduced, design_of};
use crate::kernels::{accumulate, damped_lstsq, normal_solve, solve_spd};
use crate::loss::{cost_of, norms_of, weight_of};
use crate::options::{ACCELERATION_RATIO, Objective, Options};
use crate::run::{Begun, begin};
use crate::summary::Termination;
use crate::{Iteration, Observer, Solution, Solver, Task};
use faer::Mat;
use volver_core::problem::{Problem, norm};

/// The majorising stage of a Φ fit hands over to Newton once a step gains less than this
/// fraction of the cost.
const MAJORISING_GAIN: f64 = 1e-6;

/// Gauss–Newton refinements of a converged least-squares fit, at most.
const REFINEMENTS: usize = 100;

/// The native engine (always available).
#[derive(Clone, Copy, Debug, Default)]
pub struct LevenbergMarquardt;

/// Geodesic acceleration's right-hand side in the free coordinates z: `Nᵀ D Σ J_iᵀ W_i r_i''`,
/// where `r_i''` is the exact second derivative of residual i along the step `delta` (z) and
/// `W_i` its Gauss–Newton weight (as in [`accumulate`]). One Jacobian and one second-derivative
/// pass; `None` when a value is not finite.
fn curvature_gradient(
    problem: &Problem,
    free: &Free,
    p: &[f64],
    delta: &[f64],
    objective: Objective,
    eps: f64,
) -> Option<Vec<f64>> {
    let n = p.len();
    let np = problem.n_points();
    let basis = free.ns.basis();
    let nf = basis.ncols();
    let dir: Vec<f64> = (0..n)
        .map(|i| free.d[i] * (0..nf).map(|k| basis[(i, k)] * delta[k]).sum::<f64>())
        .collect();
    let mut b = vec![0.0; n];
    let mut row = vec![0.0; 3 * n];
    for i in 0..np {
        let r = problem.residual_and_jacobian(i, p, &mut row);
        let rvv = problem.residual_second_directional(i, p, &dir);
        let nr = norm(r);
        let (w, c) = weight_of(objective, nr, eps, np);
        let radial = if nr > 0.0 {
            (r[0] * rvv[0] + r[1] * rvv[1] + r[2] * rvv[2]) / (nr * nr)
        } else {
            0.0
        };
        let wr: [f64; 3] = std::array::from_fn(|c3| w * (rvv[c3] - c * radial * r[c3]));
        for j in 0..n {
            b[j] += row[j] * wr[0] + row[n + j] * wr[1] + row[2 * n + j] * wr[2];
        }
    }
    let bz: Vec<f64> = (0..nf)
        .map(|k| (0..n).map(|i| basis[(i, k)] * free.d[i] * b[i]).sum())
        .collect();
    bz.iter().all(|v| v.is_finite()).then_some(bz)
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
        let Begun {
            mut run,
            free,
            first,
            p0: mut p,
            norms0: mut norms,
        } = match begin(self.name(), task, start, options) {
            Ok(b) => b,
            Err(solution) => return *solution,
        };
        let problem = &task.problem;
        let n = problem.n_params();
        let objective = options.objective;
        let nf = free.n_free();
        // A gauge's rows are dense combinations of every parameter, so the free coordinates z
        // mix them all and a diagonal damping in z has no meaning (measured on test 3: 214
        // iterations instead of 42). Steps are then taken in the design's directions, as when
        // some are held.
        let dense_rows = task
            .constraints
            .rows
            .iter()
            .any(|r| r.kind == volver_core::model::ConstraintKind::Gauge);
        // The step's distance from the start in the scaled free coordinates (the parameter
        // criterion's scale); the parameters themselves are stepped from p (Free::step).
        let mut z = vec![0.0; nf];
        // What the data cannot identify is a property of the design: it is read from the
        // unweighted normal matrix (Marquardt-scaled, eigen-decomposed), not from the
        // IRLS-weighted matrices of a Φ fit, whose weights spread the curvatures by up to Φ/ε and
        // would hide identifiable directions near its end. For ve the current matrix is the
        // design; for Φ it is refreshed at the start of every IRLS stage (a nonlinear basis,
        // such as a sine's phase at zero amplitude, becomes identifiable as the fit moves).
        let Some(mut design) = design_of(&free, &first.h) else {
            return run.finish(
                p,
                Termination::NumericalFailure(
                    "the eigen-decomposition of the design's normal matrix failed".into(),
                ),
            );
        };
        let mut refresh = false;

        let phi0 = norms.iter().sum::<f64>() / norms.len() as f64;
        let eps_final = |phi: f64| (options.irls_final_epsilon * phi).max(1e-300);
        let eps_first = |phi: f64| (options.irls_initial_epsilon * phi).max(1e-300);
        // Φ runs in two stages. First the majorising stage: weights 1/√(‖r_i‖² + ε²) with the
        // full curvature JᵢᵀJᵢ on every point (no radial reduction), whose quadratic model lies
        // above Φ_ε everywhere (‖r‖ ≤ (‖r‖² + ‖r₀‖²)/(2‖r₀‖)), so that its steps decrease Φ
        // whatever their size: no step is refused while the fit is far from the minimum. ε
        // follows Φ (ε = irls_initial_epsilon · Φ) and only bounds the weight of a point whose
        // residual nearly vanishes. Its convergence is linear: once a step gains less than
        // MAJORISING_GAIN of the cost, the Newton stage takes over: ε = irls_final_epsilon · Φ
        // and the exact Gauss–Newton model of Φ_ε (the radial curvature reduced by
        // ‖r‖²/(‖r‖² + ε²), Ceres' Triggs correction), which converges fast near the minimum;
        // the convergence criteria stop the run only there. Least squares has one stage.
        let mut newton = objective == Objective::Ve;
        let mut eps = eps_first(phi0);
        let mut cost = cost_of(objective, &norms, eps);
        let cost0 = cost;
        let mut lambda = options.initial_damping;
        let mut nu = 2.0;
        let mut dmax: Vec<f64> = Vec::new();
        let mut reset_scale = false;
        let mut scale_coords: Option<(usize, usize)> = None;
        let mut design_generation = 0_usize;
        let np = problem.n_points();
        let termination = 'outer: loop {
            // One Jacobian pass at the current point.
            if run.summary.evaluations >= options.max_evaluations {
                break Termination::EvaluationLimit;
            }
            if refresh && objective == Objective::Phi {
                refresh = false;
                let refreshed = accumulate(problem, &p, |_| (1.0, 0.0), false)
                    .and_then(|h| design_of(&free, &h.h));
                run.summary.evaluations += 1;
                run.summary.jacobian_evaluations += 1;
                match refreshed {
                    Some(d) => {
                        design = d;
                        design_generation += 1;
                    }
                    None => {
                        break Termination::NumericalFailure(format!(
                            "the design's normal matrix failed at iteration {}",
                            run.summary.iterations
                        ));
                    }
                }
            }
            if !newton {
                // The majorising stage's ε follows Φ.
                eps = eps_first(norms.iter().sum::<f64>() / np as f64);
                cost = cost_of(objective, &norms, eps);
            }
            let Some(normal) = accumulate(
                problem,
                &p,
                |r| {
                    let (w, c) = weight_of(objective, r, eps, np);
                    (w, if newton { c } else { 0.0 })
                },
                objective == Objective::Ve,
            ) else {
                break Termination::NumericalFailure(format!(
                    "the Jacobian is not finite at iteration {}",
                    run.summary.iterations
                ));
            };
            run.summary.evaluations += 1;
            run.summary.jacobian_evaluations += 1;
            // Reduce to the free coordinates: Hz = Nᵀ D H D N, gz = Nᵀ D g.
            let dv = &free.d;
            let hs = Mat::from_fn(n, n, |i, j| dv[i] * normal.h[(i, j)] * dv[j]);
            let basis = free.ns.basis();
            let t = &hs * basis;
            let hz = basis.transpose() * &t;
            let gz: Vec<f64> = (0..nf)
                .map(|k| (0..n).map(|i| basis[(i, k)] * dv[i] * normal.g[i]).sum())
                .collect();
            let gmax = gz.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
            if newton && (cost == 0.0 || gmax <= options.gradient_tolerance * cost0) {
                break Termination::Gradient;
            }
            // Directions whose design curvature is below rank_tolerance × the largest are not
            // identifiable from the data: steps stay in the span q of the others. The
            // Gauss–Newton model neglects Σ r_i ∇²r_i, which grows with the residuals: once Φ is
            // below 1e-4 Φ_start (a nearly exact fit, where that model is exact too) the
            // tolerance relaxes in proportion, so such a fit may use every direction.
            let phi_now = norms.iter().sum::<f64>() / np as f64;
            let tolerance = options.rank_tolerance * (1e4 * phi_now / phi0).min(1.0);
            if objective == Objective::Ve {
                // Uniform weights: the current matrix is the design.
                let Some(d) = design_from_reduced(&hz) else {
                    break Termination::NumericalFailure(format!(
                        "the eigen-decomposition of the normal matrix failed at iteration {}",
                        run.summary.iterations
                    ));
                };
                design = d;
                design_generation += 1;
            }
            let (mu0, dirs0) = (&design.0, &design.1);
            let mu0_max = mu0[nf - 1].max(0.0);
            // A zero tolerance holds nothing (not even a direction whose curvature rounds to ≤ 0).
            let keep: Vec<usize> = (0..nf)
                .filter(|&i| tolerance == 0.0 || mu0[i] > tolerance * mu0_max)
                .collect();
            run.summary.unidentifiable = nf - keep.len();
            let q = (keep.len() < nf || dense_rows)
                .then(|| Mat::from_fn(nf, keep.len(), |k, c| dirs0[(k, keep[c])]));
            let (hq, gq) = match &q {
                None => (hz.clone(), gz.clone()),
                Some(q) => {
                    let hq = q.transpose() * (&hz * q);
                    let gq: Vec<f64> = (0..q.ncols())
                        .map(|c| (0..nf).map(|k| q[(k, c)] * gz[k]).sum())
                        .collect();
                    (hq, gq)
                }
            };
            // Damping: λ M with M the diagonal of the largest diag(H) seen in the step's
            // coordinates (Moré's scaling, as MINPACK: it never shrinks, so a parameter whose
            // column fades as the fit runs into a flat region is still damped at its earlier
            // scale). The maximum runs while the coordinates stay the same: z, or the span q of
            // the identifiable design directions until the design is refreshed (every iteration
            // for ve, every IRLS stage for Φ); a new IRLS stage also restarts it (a new cost).
            let nr = gq.len();
            let coords = q.as_ref().map(|_| (design_generation, nr));
            if reset_scale || coords != scale_coords || dmax.len() != nr {
                reset_scale = false;
                scale_coords = coords;
                dmax = vec![0.0; nr];
            }
            for (i, v) in dmax.iter_mut().enumerate() {
                *v = (*v).max(hq[(i, i)]);
            }
            // A direction the data have never seen is damped at unit scale (MINPACK's rule); no
            // floor relative to the others, whose curvatures may legitimately span 10²⁰ along
            // the path of a strongly nonlinear model (MGH10).
            // Scaled by S = M^-½: H' = S H S, g' = S g, and the damping is λ I.
            let sc: Vec<f64> = dmax
                .iter()
                .map(|&v| 1.0 / if v > 0.0 { v } else { 1.0 }.sqrt())
                .collect();
            let hp = Mat::from_fn(nr, nr, |i, j| sc[i] * hq[(i, j)] * sc[j]);
            let gp: Vec<f64> = (0..nr).map(|i| sc[i] * gq[i]).collect();
            // Least squares: the factor in the same coordinates, R_z = R D N and R' = R_z Q S,
            // so that each step solves min ‖R' y + c‖² + λ‖y‖² by QR.
            let factor = normal.factor.as_ref().map(|f| {
                let rd = Mat::from_fn(n, n, |i, j| f.r[(i, j)] * dv[j]);
                let rz = &rd * basis;
                let rq = match &q {
                    None => rz.clone(),
                    Some(q) => &rz * q,
                };
                let rps = Mat::from_fn(n, nr, |i, j| rq[(i, j)] * sc[j]);
                (rz, rps, &f.c)
            });
            // From the scaled span coordinates back to z.
            let to_z = |y: &[f64]| -> Vec<f64> {
                let y: Vec<f64> = y.iter().zip(&sc).map(|(y, s)| y * s).collect();
                match &q {
                    None => y,
                    Some(q) => (0..nf)
                        .map(|k| (0..nr).map(|c| q[(k, c)] * y[c]).sum())
                        .collect(),
                }
            };
            // Try steps until one is accepted or a criterion stops the run.
            loop {
                if run.summary.iterations >= options.max_iterations {
                    break 'outer Termination::IterationLimit;
                }
                if run.summary.iterations > 0 && run.summary.evaluations >= options.max_evaluations
                {
                    break 'outer Termination::EvaluationLimit;
                }
                run.summary.iterations += 1;
                // Cholesky of the damped system (an SVD pseudo-inverse if it fails).
                let damped = Mat::from_fn(nr, nr, |i, j| {
                    hp[(i, j)] + if i == j { lambda } else { 0.0 }
                });
                let rhs: Vec<f64> = gp.iter().map(|g| -g).collect();
                // With the factor: the QR of [R'; √λ I], whose R_λ also gives (H' + λI)⁻¹ for
                // the acceleration; else Cholesky of the damped normal matrix.
                let lsq = factor
                    .as_ref()
                    .and_then(|(_, rps, c)| damped_lstsq(rps, c, lambda));
                let y = match &lsq {
                    Some((y, _)) => y.clone(),
                    None => solve_spd(&damped, &rhs).unwrap_or_else(|| vec![f64::NAN; nr]),
                };
                let delta = to_z(&y);
                if delta.iter().any(|v| !v.is_finite()) {
                    break 'outer Termination::NumericalFailure(format!(
                        "the step is not finite at iteration {}",
                        run.summary.iterations
                    ));
                }
                // Geodesic acceleration: a = −(H + λM)⁻¹ Jᵀ W r''(δ, δ); the step is δ + a/2,
                // refused (as a failed step) when 2‖a‖ > α‖δ‖ in the damping norm.
                let mut total = delta.clone();
                if options.geodesic_acceleration {
                    let ynorm = y.iter().map(|v| v * v).sum::<f64>().sqrt();
                    let accel = (ynorm > 0.0)
                        .then(|| curvature_gradient(problem, &free, &p, &delta, objective, eps))
                        .flatten();
                    run.summary.evaluations += 1;
                    run.summary.jacobian_evaluations += 1;
                    let Some(bz) = accel else {
                        break 'outer Termination::NumericalFailure(format!(
                            "the second derivative along the step is not finite at iteration {}",
                            run.summary.iterations
                        ));
                    };
                    let bq: Vec<f64> = match &q {
                        None => bz,
                        Some(q) => (0..nr)
                            .map(|c| (0..nf).map(|k| q[(k, c)] * bz[k]).sum())
                            .collect(),
                    };
                    let rhs: Vec<f64> = bq.iter().zip(&sc).map(|(b, s)| -b * s).collect();
                    let ya = match &lsq {
                        Some((_, rl)) => normal_solve(rl, &rhs),
                        None => solve_spd(&damped, &rhs),
                    }
                    .unwrap_or_else(|| vec![f64::NAN; nr]);
                    let anorm = ya.iter().map(|v| v * v).sum::<f64>().sqrt();
                    // A NaN ratio refuses the step too.
                    let small_enough = 2.0 * anorm <= ACCELERATION_RATIO * ynorm;
                    if !small_enough {
                        observer.iteration(&Iteration {
                            iteration: run.summary.iterations,
                            evaluations: run.summary.evaluations,
                            cost,
                            emm_um: norms.iter().sum::<f64>() / np as f64 * 1e3,
                            damping: lambda,
                            step: delta.iter().map(|v| v * v).sum::<f64>().sqrt(),
                            accepted: false,
                        });
                        lambda *= nu;
                        nu *= 2.0;
                        if !lambda.is_finite() || lambda > 1e30 {
                            break 'outer Termination::NumericalFailure(format!(
                                "geodesic acceleration refused every step up to damping 1e30 at iteration {}",
                                run.summary.iterations
                            ));
                        }
                        continue;
                    }
                    for (t, a) in total.iter_mut().zip(to_z(&ya)) {
                        *t += 0.5 * a;
                    }
                }
                let step = total.iter().map(|v| v * v).sum::<f64>().sqrt();
                let znorm = z.iter().map(|v| v * v).sum::<f64>().sqrt();
                let small_step =
                    step <= options.parameter_tolerance * (znorm + options.parameter_tolerance);
                // Predicted decrease of the quadratic model along δ (the velocity; the
                // acceleration only bends the path): from the factor, −(cᵀv + ½‖v‖²) with
                // v = R_z δ, else from H_z and g_z.
                let pred = match &factor {
                    Some((rz, _, c)) => {
                        let v: Vec<f64> = (0..n)
                            .map(|i| (0..nf).map(|k| rz[(i, k)] * delta[k]).sum())
                            .collect();
                        -(0..n).map(|i| c[i] * v[i] + 0.5 * v[i] * v[i]).sum::<f64>()
                    }
                    None => {
                        let hd: Vec<f64> = (0..nf)
                            .map(|i| (0..nf).map(|j| hz[(i, j)] * delta[j]).sum())
                            .collect();
                        -(0..nf)
                            .map(|i| gz[i] * delta[i] + 0.5 * delta[i] * hd[i])
                            .sum::<f64>()
                    }
                };
                let p_new = free.step(&p, &total);
                let z_new: Vec<f64> = z.iter().zip(&total).map(|(a, b)| a + b).collect();
                let norms_new = norms_of(problem, &p_new);
                run.summary.evaluations += 1;
                let cost_new = cost_of(objective, &norms_new, eps);
                if !cost_new.is_finite() {
                    run.nonfinite_trial();
                }
                let rho = if cost_new.is_finite() && pred > 0.0 {
                    (cost - cost_new) / pred
                } else {
                    -1.0
                };
                let accepted = rho > 1e-4;
                if accepted {
                    run.improved();
                }
                observer.iteration(&Iteration {
                    iteration: run.summary.iterations,
                    evaluations: run.summary.evaluations,
                    cost: if accepted { cost_new } else { cost },
                    emm_um: if accepted {
                        norms_new.iter().sum::<f64>() / np as f64 * 1e3
                    } else {
                        norms.iter().sum::<f64>() / np as f64 * 1e3
                    },
                    damping: lambda,
                    step,
                    accepted,
                });
                if accepted {
                    let old = cost;
                    p = p_new;
                    z = z_new;
                    norms = norms_new;
                    cost = cost_new;
                    lambda *= (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0);
                    nu = 2.0;
                    let small_change = old - cost <= options.objective_tolerance * old;
                    let phi = norms.iter().sum::<f64>() / np as f64;
                    if newton && (small_step || small_change) {
                        break 'outer if small_step {
                            Termination::ParameterChange
                        } else {
                            Termination::ObjectiveChange
                        };
                    }
                    if !newton && (small_step || old - cost <= MAJORISING_GAIN * old) {
                        // The majorising stage has slowed down: Newton takes over.
                        newton = true;
                        eps = eps_final(phi);
                        refresh = true;
                        reset_scale = true;
                        cost = cost_of(objective, &norms, eps);
                    }
                    break;
                }
                lambda *= nu;
                nu *= 2.0;
                if small_step || !lambda.is_finite() || lambda > 1e30 {
                    let phi = norms.iter().sum::<f64>() / np as f64;
                    if newton {
                        break 'outer Termination::ParameterChange;
                    }
                    newton = true;
                    eps = eps_final(phi);
                    refresh = true;
                    reset_scale = true;
                    cost = cost_of(objective, &norms, eps);
                    lambda = options.initial_damping;
                    nu = 2.0;
                    break;
                }
            }
        };
        // Least squares: Gauss–Newton refinement of the converged point. The damped steps
        // stop once the cost can no longer tell better from worse (steps refused at rounding
        // raise λ until the step is negligible); the undamped steps from the QR factor go on to
        // the minimum (to the Jacobian's condition, not its square) while they contract and the
        // cost is no worse than its own rounding. Skipped when directions are held as
        // unidentifiable.
        if objective == Objective::Ve && termination.converged() && run.summary.unidentifiable == 0
        {
            // The cost's rounding: each residual is rounded to a few ε of its observation.
            let rounding = 8.0 * f64::EPSILON * 2.0 / np as f64
                * (0..np)
                    .map(|i| norms[i] * (norms[i] + problem.observation_scale(i)))
                    .sum::<f64>();
            let mut last_step = f64::INFINITY;
            for _ in 0..REFINEMENTS {
                if run.summary.iterations >= options.max_iterations
                    || run.summary.evaluations + 2 > options.max_evaluations
                {
                    break;
                }
                let Some(f) = accumulate(problem, &p, |r| weight_of(objective, r, eps, np), true)
                    .and_then(|normal| normal.factor)
                else {
                    break;
                };
                run.summary.evaluations += 1;
                run.summary.jacobian_evaluations += 1;
                run.summary.iterations += 1;
                let rz = &Mat::from_fn(n, n, |i, j| f.r[(i, j)] * free.d[j]) * free.ns.basis();
                let Some((dz, _)) = damped_lstsq(&rz, &f.c, 0.0) else {
                    break;
                };
                // Gauss–Newton converges linearly on a problem with residuals: go on while the
                // steps contract and are not negligible.
                let step = dz.iter().map(|v| v * v).sum::<f64>().sqrt();
                let znorm = z.iter().map(|v| v * v).sum::<f64>().sqrt();
                let contracting = step < last_step;
                if !contracting
                    || step <= options.parameter_tolerance * (znorm + options.parameter_tolerance)
                {
                    break;
                }
                last_step = step;
                let p_new = free.step(&p, &dz);
                let norms_new = norms_of(problem, &p_new);
                run.summary.evaluations += 1;
                let cost_new = cost_of(objective, &norms_new, eps);
                let accepted = cost_new <= cost + rounding;
                observer.iteration(&Iteration {
                    iteration: run.summary.iterations,
                    evaluations: run.summary.evaluations,
                    cost: if accepted { cost_new } else { cost },
                    emm_um: if accepted { &norms_new } else { &norms }
                        .iter()
                        .sum::<f64>()
                        / np as f64
                        * 1e3,
                    damping: 0.0,
                    step,
                    accepted,
                });
                if !accepted {
                    break;
                }
                z.iter_mut().zip(&dz).for_each(|(a, b)| *a += b);
                p = p_new;
                norms = norms_new;
                cost = cost_new;
            }
        }
        run.finish(p, termination)
    }
}
