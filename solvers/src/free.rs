//! What every engine shares: the start and end of a run (validation, the initial and final
//! evaluations, the summary), the scaled constraint-free coordinates `p = D (s₀ + N z)`, the
//! smoothed objectives and their exact gradient from the dual-number Jacobian.

use crate::lm::{Normal, accumulate, scaled_null_space};
use crate::nullspace::NullSpace;
use crate::options::{Objective, Options};
use crate::summary::{Summary, Termination};
use crate::{Solution, Task, evaluate};
use std::time::Instant;
use volver_core::model::Constraints;
use volver_core::problem::Problem;

/// The scaled, constraint-free parametrisation `p = D (s₀ + N z)`.
pub(crate) struct Free {
    /// Column scaling D.
    pub(crate) d: Vec<f64>,
    /// Null space of the scaled constraints.
    pub(crate) ns: NullSpace,
    /// Parameters held at a value: set exactly, not to rounding.
    pub(crate) fixed: Vec<(usize, f64)>,
}

impl Free {
    pub(crate) fn new(d: Vec<f64>, ns: NullSpace, constraints: &Constraints) -> Free {
        Free {
            d,
            ns,
            fixed: held_values(constraints),
        }
    }

    pub(crate) fn n_free(&self) -> usize {
        self.ns.n_free()
    }

    /// The parameters at free coordinates `z`.
    pub(crate) fn params(&self, z: &[f64]) -> Vec<f64> {
        let mut p: Vec<f64> = self
            .ns
            .expand(z)
            .iter()
            .zip(&self.d)
            .map(|(s, d)| s * d)
            .collect();
        for &(j, v) in &self.fixed {
            p[j] = v;
        }
        p
    }

    /// `p + D N dz`: a step of `dz` in the free coordinates taken from `p` itself (held
    /// parameters stay exact). Unlike [`Free::params`] of an accumulated z, it keeps every
    /// parameter's absolute precision: z counts the distance from the anchor, and a parameter
    /// that travels far from its start (MGH10's b1, from 2 to 10⁻⁵⁰ and back) would otherwise be
    /// known only to the rounding of that distance.
    pub(crate) fn step(&self, p: &[f64], dz: &[f64]) -> Vec<f64> {
        let b = self.ns.basis();
        let mut out: Vec<f64> = (0..p.len())
            .map(|i| p[i] + self.d[i] * (0..dz.len()).map(|k| b[(i, k)] * dz[k]).sum::<f64>())
            .collect();
        for &(j, v) in &self.fixed {
            out[j] = v;
        }
        out
    }

    /// `M = D N` (n × free): `∂p/∂z`.
    #[cfg(any(feature = "nlopt", feature = "clarabel"))]
    pub(crate) fn tangent(&self) -> faer::Mat<f64> {
        let b = self.ns.basis();
        faer::Mat::from_fn(b.nrows(), b.ncols(), |i, k| self.d[i] * b[(i, k)])
    }
}

/// Parameters a constraint holds at a value (a single coefficient).
pub(crate) fn held_values(constraints: &Constraints) -> Vec<(usize, f64)> {
    constraints
        .rows
        .iter()
        .filter_map(|r| match r.coeffs.as_slice() {
            [(j, c)] if *c != 0.0 => Some((*j, r.rhs / c)),
            _ => None,
        })
        .collect()
}

/// The smoothed objective from residual modules: ve, or `Φ_ε = (1/n) Σ √(‖r‖² + ε²)`.
pub(crate) fn cost_of(objective: Objective, norms: &[f64], eps: f64) -> f64 {
    let n = norms.len() as f64;
    match objective {
        Objective::Ve => norms.iter().map(|r| r * r).sum::<f64>() / n,
        Objective::Phi => {
            norms
                .iter()
                .map(|r| (r * r + eps * eps).sqrt())
                .sum::<f64>()
                / n
        }
    }
}

/// Weight of a point in the Gauss–Newton model of the cost: twice the derivative of the
/// point's loss with respect to ‖r‖², over n (so that `Σ w_i J_iᵀ r_i` is the gradient), and the
/// radial reduction c of its Hessian.
pub(crate) fn weight_of(objective: Objective, r: f64, eps: f64, n: usize) -> (f64, f64) {
    match objective {
        Objective::Ve => (2.0 / n as f64, 0.0),
        Objective::Phi => {
            let s = r * r + eps * eps;
            (1.0 / (s.sqrt() * n as f64), r * r / s)
        }
    }
}

/// Residual modules at `p`; `None` if one is not finite.
pub(crate) fn norms(problem: &Problem, p: &[f64]) -> Option<Vec<f64>> {
    let v: Vec<f64> = (0..problem.n_points())
        .map(|i| volver_core::problem::norm(problem.residual(i, p)))
        .collect();
    v.iter().all(|x| x.is_finite()).then_some(v)
}

/// The smoothed cost at `p` and its exact gradient with respect to `p` (one dual-number
/// Jacobian pass, no normal matrix); `None` if a residual or Jacobian entry is not finite.
#[cfg(feature = "nlopt")]
pub(crate) fn cost_and_gradient(
    problem: &Problem,
    objective: Objective,
    eps: f64,
    p: &[f64],
) -> Option<(f64, Vec<f64>)> {
    let n = p.len();
    let np = problem.n_points();
    let mut g = vec![0.0; n];
    let mut row = vec![0.0; 3 * n];
    let mut norms = Vec::with_capacity(np);
    for i in 0..np {
        let r = problem.residual_and_jacobian(i, p, &mut row);
        let nr = volver_core::problem::norm(r);
        if !nr.is_finite() || row.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let (w, _) = weight_of(objective, nr, eps, np);
        for (j, gj) in g.iter_mut().enumerate() {
            *gj += w * (row[j] * r[0] + row[n + j] * r[1] + row[2 * n + j] * r[2]);
        }
        norms.push(nr);
    }
    Some((cost_of(objective, &norms, eps), g))
}

/// Where a solve met trial points whose residuals or Jacobian are not finite (evaluation
/// numbers as counted in the summary).
///
/// Such a trial is refused like any step that does not lower the cost, so an engine can end up
/// pressed against the edge of the region where the model is finite, shrinking its steps until
/// a step-size or cost-change test "converges", or creeping along that edge. [`Run::finish`]
/// reports either as [`Termination::Stalled`], naming the evaluation: a convergence claimed with
/// no improvement since the last non-finite trial, or with at least [`EDGE_RECENT`] non-finite
/// trials among the last [`EDGE_WINDOW`] evaluations, is the edge's, not a minimum's.
#[derive(Clone, Debug, Default)]
pub(crate) struct Edge {
    /// Non-finite trial evaluations.
    pub(crate) count: usize,
    /// The last [`EDGE_WINDOW`] of them, oldest first.
    recent: Vec<usize>,
    /// The last evaluation that lowered the cost (or began a stage).
    pub(crate) improved: usize,
}

/// See [`Edge`].
const EDGE_WINDOW: usize = 20;
/// See [`Edge`].
const EDGE_RECENT: usize = 5;

impl Edge {
    /// Records a non-finite trial at evaluation `k`.
    pub(crate) fn nonfinite_at(&mut self, k: usize) {
        self.count += 1;
        if self.recent.len() == EDGE_WINDOW {
            self.recent.remove(0);
        }
        self.recent.push(k);
    }

    /// The same record with every evaluation number moved by `base` (an engine that counts
    /// its own calls from zero).
    #[cfg(feature = "nlopt")]
    pub(crate) fn shifted(&self, base: usize) -> Edge {
        Edge {
            count: self.count,
            recent: self.recent.iter().map(|k| k + base).collect(),
            improved: self.improved + base,
        }
    }

    /// `termination`, or `Stalled` when it claims convergence at the edge (see the type)
    /// after `evaluations` evaluations.
    pub(crate) fn verdict(&self, termination: Termination, evaluations: usize) -> Termination {
        let Some(&last) = self.recent.last() else {
            return termination;
        };
        let window = self
            .recent
            .iter()
            .filter(|&&k| k + EDGE_WINDOW > evaluations)
            .count();
        let at_edge = last >= self.improved || window >= EDGE_RECENT;
        if at_edge && termination.converged() && termination != Termination::NoFreeParameters {
            Termination::Stalled(format!(
                "stopped at the edge of the region where the model is finite, not at a \
                 minimum: trial evaluation {last} was not finite ({} such, {window} of the \
                 last {EDGE_WINDOW})",
                self.count
            ))
        } else {
            termination
        }
    }
}

/// The bookkeeping of one solve: validation, the initial evaluation, the summary, the end.
pub(crate) struct Run<'t, 'a> {
    pub(crate) problem: &'t Problem<'a>,
    pub(crate) summary: Summary,
    /// Non-finite trial points met on the way.
    pub(crate) edge: Edge,
    t0: Instant,
}

impl<'t, 'a> Run<'t, 'a> {
    /// Records that the trial evaluation counted last was not finite.
    pub(crate) fn nonfinite_trial(&mut self) {
        self.edge.nonfinite_at(self.summary.evaluations);
    }

    /// Records that the evaluation counted last lowered the cost.
    pub(crate) fn improved(&mut self) {
        self.edge.improved = self.summary.evaluations;
    }

    /// Validates the options and the start and evaluates it; `Err` is the finished solution of
    /// a run that cannot start.
    pub(crate) fn start(
        solver: &str,
        task: &'t Task<'a>,
        start: &[f64],
        options: &Options,
    ) -> Result<Run<'t, 'a>, Box<Solution>> {
        let problem = &task.problem;
        let n = problem.n_params();
        let mut run = Run {
            problem,
            summary: Summary {
                solver: solver.to_string(),
                objective: options.objective,
                phase: task.phase.clone(),
                free_parameters: 0,
                unidentifiable: 0,
                points: problem.n_points(),
                initial: Default::default(),
                final_: Default::default(),
                iterations: 0,
                evaluations: 0,
                jacobian_evaluations: 0,
                time_s: 0.0,
                termination: Termination::NoFreeParameters,
            },
            edge: Edge::default(),
            t0: Instant::now(),
        };
        if let Err(e) = options.validate() {
            return Err(Box::new(
                run.finish(start.to_vec(), Termination::InvalidInput(e)),
            ));
        }
        if start.len() != n || start.iter().any(|v| !v.is_finite()) {
            let t = Termination::InvalidInput(format!(
                "the start has {} values (finite: {}), the model {n} parameters",
                start.len(),
                start.iter().all(|v| v.is_finite())
            ));
            return Err(Box::new(run.finish(start.to_vec(), t)));
        }
        run.summary.initial = evaluate(problem, start);
        run.summary.evaluations += 1;
        Ok(run)
    }

    /// The scaled free coordinates of `task` (column scaling from the Jacobian at `start`) and
    /// the unweighted normal equations there; `Err` is the finished solution when they cannot
    /// be built.
    fn free_and_normal(
        self,
        task: &Task,
        start: &[f64],
    ) -> Result<(Run<'t, 'a>, Free, Normal), Box<Solution>> {
        let mut run = self;
        let Some(first) = accumulate(run.problem, start, |_| (1.0, 0.0), false) else {
            let t = Termination::NumericalFailure("the Jacobian is not finite at the start".into());
            return Err(Box::new(run.finish(start.to_vec(), t)));
        };
        run.summary.evaluations += 1;
        run.summary.jacobian_evaluations += 1;
        let (d, ns) = scaled_null_space(&first.h, &task.constraints, start);
        match ns {
            Ok(ns) => {
                let free = Free::new(d, ns, &task.constraints);
                run.summary.free_parameters = free.n_free();
                Ok((run, free, first))
            }
            Err(e) => Err(Box::new(
                run.finish(start.to_vec(), Termination::InvalidInput(e.to_string())),
            )),
        }
    }

    /// The solution at `params`, evaluated, with the termination.
    pub(crate) fn finish(mut self, params: Vec<f64>, termination: Termination) -> Solution {
        // A start of the wrong length cannot be evaluated: it ends as invalid input.
        if params.len() == self.problem.n_params() {
            self.summary.final_ = evaluate(self.problem, &params);
            self.summary.evaluations += 1;
        } else {
            self.summary.final_.phi_mm = f64::NAN;
            self.summary.final_.ve_mm2 = f64::NAN;
        }
        // Never report success with a non-finite result, nor a stop at the edge of the finite
        // region as convergence.
        let termination = if !self.summary.final_.phi_mm.is_finite() && !termination.failed() {
            Termination::NumericalFailure("the objective is not finite at the end".into())
        } else {
            self.edge.verdict(termination, self.summary.evaluations)
        };
        self.summary.termination = termination;
        self.summary.time_s = self.t0.elapsed().as_secs_f64();
        Solution {
            params,
            summary: self.summary,
        }
    }
}

/// Where every engine starts: the run, the scaled free coordinates, the unweighted normal
/// equations at `start`, the start projected onto the constraints (held values exact) and its
/// residual modules.
pub(crate) struct Begun<'t, 'a> {
    pub(crate) run: Run<'t, 'a>,
    pub(crate) free: Free,
    pub(crate) first: Normal,
    pub(crate) p0: Vec<f64>,
    pub(crate) norms0: Vec<f64>,
}

/// Validates and evaluates the start, builds the free coordinates and projects the start;
/// `Err` is the finished solution of a run with nothing to do (no free parameter) or that
/// cannot start.
pub(crate) fn begin<'t, 'a>(
    solver: &str,
    task: &'t Task<'a>,
    start: &[f64],
    options: &Options,
) -> Result<Begun<'t, 'a>, Box<Solution>> {
    let run = Run::start(solver, task, start, options)?;
    let (mut run, free, first) = run.free_and_normal(task, start)?;
    let p0 = free.params(&vec![0.0; free.n_free()]);
    if free.n_free() == 0 {
        return Err(Box::new(run.finish(p0, Termination::NoFreeParameters)));
    }
    let Some(norms0) = norms(run.problem, &p0) else {
        let t = Termination::NumericalFailure("the residuals are not finite at the start".into());
        return Err(Box::new(run.finish(p0, t)));
    };
    run.summary.evaluations += 1;
    Ok(Begun {
        run,
        free,
        first,
        p0,
        norms0,
    })
}
