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
//! let socp = ProxLinear.solve(&task, &model.initial_params(), &Options::default(), &mut Silent);
//! assert!(!socp.summary.termination.failed(), "{}", socp.summary.termination);
//! // The SOCP reaches Φ's optimum exactly; the LM's IRLS stops at or above it.
//! let (a, b) = (lm.summary.reached.phi_mm, socp.summary.reached.phi_mm);
//! assert!(b <= a * (1.0 + 1e-9) && b > 0.99 * a, "Φ: LM {a}, SOCP {b}");
//! ```

use crate::lm::LevenbergMarquardt;
use crate::options::{Objective, Options};
use crate::run::{Started, begin};
use crate::summary::Termination;
use crate::{Iteration, Observer, Solution, Solver, Task};
use ::clarabel::algebra::CscMatrix;
use ::clarabel::solver::{
    DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
};
use faer::Mat;
use volver_core::problem::norm;

/// The prox-linear engine (`clarabel`).
#[derive(Clone, Copy, Debug, Default)]
pub struct ProxLinear;

/// The native LM followed by a prox-linear polish (`lm+clarabel`).
#[derive(Clone, Copy, Debug, Default)]
pub struct Polished;

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

/// Solves the sub-problem (data scaled by `scale`); the step, or Clarabel's status.
fn step(
    objective: Objective,
    lin: &Linearisation,
    k: usize,
    mu: f64,
    radius: f64,
    scale: f64,
) -> Result<Vec<f64>, String> {
    let np = lin.r.len() / 3;
    let nn = np as f64;
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .max_iter(200)
        .tol_gap_abs(1e-10)
        .tol_gap_rel(1e-10)
        .tol_feas(1e-10)
        .build()
        .map_err(|e| format!("Clarabel settings: {e:?}"))?;
    // Column-by-column CSC of A; rows as documented in the module.
    let mut colptr = vec![0usize];
    let mut rowval = Vec::new();
    let mut nzval = Vec::new();
    match objective {
        Objective::Phi => {
            let nvar = k + np;
            let m = 4 * np + k + 1;
            for c in 0..k {
                for i in 0..np {
                    for d in 0..3 {
                        let v = lin.jz[(3 * i + d) * k + c];
                        if v != 0.0 {
                            rowval.push(4 * i + 1 + d);
                            nzval.push(-v / scale);
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
            let mut bv = vec![0.0; m];
            for i in 0..np {
                for d in 0..3 {
                    bv[4 * i + 1 + d] = lin.r[3 * i + d] / scale;
                }
            }
            bv[4 * np] = radius;
            let mut cv: Vec<SupportedConeT<f64>> = vec![SupportedConeT::SecondOrderConeT(4); np];
            cv.push(SupportedConeT::SecondOrderConeT(k + 1));
            let mut qv = vec![0.0; nvar];
            for qi in qv.iter_mut().skip(k) {
                *qi = 1.0 / nn;
            }
            let pdiag: Vec<f64> = (0..k).map(|_| mu).collect();
            let pm = CscMatrix::new(
                nvar,
                nvar,
                (0..=nvar).map(|c| c.min(k)).collect(),
                (0..k).collect(),
                pdiag,
            );
            solve_cone(pm, qv, a, bv, cv, settings, k)
        }
        Objective::Ve => {
            // P = (2/n) Jᵀ J / scale + μ I (upper triangle), q = (2/n) Jᵀ r / scale.
            let jm = Mat::from_fn(3 * np, k, |i, c| lin.jz[i * k + c]);
            let jtj = jm.transpose() * &jm;
            let mut pc = vec![0usize];
            let mut pr = Vec::new();
            let mut pv = Vec::new();
            for c in 0..k {
                for rr in 0..=c {
                    let v = 2.0 / nn * jtj[(rr, c)] / scale + if rr == c { mu } else { 0.0 };
                    if v != 0.0 {
                        pr.push(rr);
                        pv.push(v);
                    }
                }
                pc.push(pr.len());
            }
            let p_mat = CscMatrix::new(k, k, pc, pr, pv);
            let q = (0..k)
                .map(|c| {
                    2.0 / nn
                        * (0..3 * np)
                            .map(|i| lin.jz[i * k + c] * lin.r[i])
                            .sum::<f64>()
                        / scale
                })
                .collect();
            for c in 0..k {
                rowval.push(1 + c);
                nzval.push(-1.0);
                colptr.push(rowval.len());
            }
            let a = CscMatrix::new(k + 1, k, colptr, rowval, nzval);
            let mut b = vec![0.0; k + 1];
            b[0] = radius;
            let cones = vec![SupportedConeT::SecondOrderConeT(k + 1)];
            solve_cone(p_mat, q, a, b, cones, settings, k)
        }
    }
}

fn solve_cone(
    p: CscMatrix<f64>,
    q: Vec<f64>,
    a: CscMatrix<f64>,
    b: Vec<f64>,
    cones: Vec<SupportedConeT<f64>>,
    settings: ::clarabel::solver::DefaultSettings<f64>,
    k: usize,
) -> Result<Vec<f64>, String> {
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
        sum += match objective {
            Objective::Phi => m,
            Objective::Ve => m * m,
        };
    }
    sum / np as f64
}

fn objective_value(objective: Objective, norms: &[f64]) -> f64 {
    crate::loss::cost_of(objective, norms, 0.0)
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
        let Started {
            mut run,
            free,
            p0: mut p,
            norms0: mut norms,
            ..
        } = match begin(self.name(), task, start, options) {
            Ok(b) => b,
            Err(solution) => return *solution,
        };
        let problem = &*task.problem;
        let np = problem.n_points();
        let k = free.n_free();
        let objective = options.objective;
        let mut z = vec![0.0; k];
        let tangent = free.tangent();
        let mut cost = objective_value(objective, &norms);
        let ve0 = norms.iter().map(|r| r * r).sum::<f64>() / np as f64;
        // Scaled coordinates: a unit of z moves the residual vector by ~1 mm. A first step may
        // change the residuals by up to ten times their norm.
        let mut radius = (10.0 * (np as f64 * ve0).sqrt()).max(1e-6);
        let mu_floor = 1e-12;
        let mut mu = options.initial_damping;
        let termination = 'outer: loop {
            if cost == 0.0 {
                break Termination::Gradient;
            }
            if run.summary.evaluations >= options.max_evaluations {
                break Termination::EvaluationLimit;
            }
            let Some(lin) = linearise(task, &p, &tangent) else {
                break Termination::NumericalFailure(crate::Failure::JacobianNotFinite(
                    crate::At::Iteration(run.summary.iterations),
                ));
            };
            run.summary.evaluations += 1;
            run.summary.jacobian_evaluations += 1;
            loop {
                if run.summary.iterations >= options.max_iterations {
                    break 'outer Termination::IterationLimit;
                }
                if run.summary.evaluations >= options.max_evaluations {
                    break 'outer Termination::EvaluationLimit;
                }
                run.summary.iterations += 1;
                // μ is relative to the scaled sub-problem (objective ≈ 1 at δ = 0).
                let delta = match step(objective, &lin, k, mu, radius, cost) {
                    Ok(d) => d,
                    Err(e) => {
                        // A sub-problem Clarabel cannot solve: shrink the region and retry.
                        if mu > 1e20 || radius < 1e-300 {
                            break 'outer Termination::NumericalFailure(crate::Failure::Reported(
                                e,
                            ));
                        }
                        mu = (mu * 10.0).max(1e-6);
                        radius /= 4.0;
                        continue;
                    }
                };
                let step_norm = delta.iter().map(|v| v * v).sum::<f64>().sqrt();
                let znorm = z.iter().map(|v| v * v).sum::<f64>().sqrt();
                let small_step = step_norm
                    <= options.parameter_tolerance * (znorm + options.parameter_tolerance);
                let pred = cost - model_value(objective, &lin, k, &delta);
                if pred <= options.objective_tolerance * cost {
                    break 'outer if small_step {
                        Termination::ParameterChange
                    } else {
                        Termination::ObjectiveChange
                    };
                }
                let p_new = free.step(&p, &delta);
                let z_new: Vec<f64> = z.iter().zip(&delta).map(|(a, b)| a + b).collect();
                run.summary.evaluations += 1;
                let new = crate::loss::norms(problem, &p_new);
                let cost_new = new
                    .as_ref()
                    .map(|v| objective_value(objective, v))
                    .unwrap_or(f64::INFINITY);
                if new.is_none() {
                    run.nonfinite_trial();
                }
                let rho = (cost - cost_new) / pred;
                let accepted = rho > 1e-4;
                if accepted {
                    run.improved();
                }
                let emm_new = new
                    .as_ref()
                    .map(|v| v.iter().sum::<f64>() / np as f64 * 1e3)
                    .unwrap_or(f64::NAN);
                observer.iteration(&Iteration {
                    iteration: run.summary.iterations,
                    evaluations: run.summary.evaluations,
                    cost: if accepted { cost_new } else { cost },
                    emm_um: if accepted {
                        emm_new
                    } else {
                        norms.iter().sum::<f64>() / np as f64 * 1e3
                    },
                    damping: mu,
                    step: step_norm,
                    accepted,
                });
                if accepted {
                    let old = cost;
                    p = p_new;
                    z = z_new;
                    norms = new.unwrap_or_default();
                    cost = cost_new;
                    if rho > 0.75 {
                        mu = (mu / 3.0).max(mu_floor);
                        radius = radius.max(3.0 * step_norm);
                    } else if rho < 0.25 {
                        mu *= 2.0;
                        radius = radius.min(step_norm.max(1e-300));
                    }
                    if small_step {
                        break 'outer Termination::ParameterChange;
                    }
                    if old - cost <= options.objective_tolerance * old {
                        break 'outer Termination::ObjectiveChange;
                    }
                    break;
                }
                mu = (mu * 4.0).max(mu_floor);
                radius = step_norm / 4.0;
                if small_step {
                    break 'outer Termination::ParameterChange;
                }
            }
        };
        run.finish(p, termination)
    }
}

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
        let first = LevenbergMarquardt::default().solve(task, start, options, observer);
        if first.summary.termination.failed() {
            let mut s = first;
            s.summary.solver = self.name().to_string();
            return s;
        }
        let mut second = ProxLinear.solve(task, &first.params, options, observer);
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
