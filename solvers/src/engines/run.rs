//! What every engine shares at the start and end of a run: validation of the options and the
//! start, the initial and final evaluations, the summary, the scaled free coordinates and the
//! start projected onto the constraints, and the watch for trial points where the model is not
//! finite.

use crate::engines::coordinates::{Free, scaled_null_space};
use crate::engines::kernels::{Normal, accumulate};
use crate::engines::loss::norms;
use crate::engines::stationarity;
use crate::options::Options;
use crate::summary::{At, Failure, Invalid, Summary, Termination};
use crate::{Solution, Task};
use std::time::Instant;
use volver_core::problem::Residuals;

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
pub(crate) struct FiniteEdge {
    /// Non-finite trial evaluations.
    pub(crate) count: usize,
    /// The last [`EDGE_WINDOW`] of them, oldest first.
    recent: Vec<usize>,
    /// The last evaluation that lowered the cost (or began a stage).
    pub(crate) improved: usize,
}

/// See [`FiniteEdge`].
const EDGE_WINDOW: usize = 20;
/// See [`FiniteEdge`].
const EDGE_RECENT: usize = 5;

impl FiniteEdge {
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
    pub(crate) fn shifted(&self, base: usize) -> FiniteEdge {
        FiniteEdge {
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
            Termination::Stalled(crate::Stall::AtFiniteEdge {
                last,
                count: self.count,
                window,
                of: EDGE_WINDOW,
            })
        } else {
            termination
        }
    }
}

/// The bookkeeping of one solve: validation, the initial evaluation, the summary, the end.
pub(crate) struct Run<'t, 'a> {
    pub(crate) problem: &'t (dyn Residuals + 'a),
    pub(crate) summary: Summary,
    /// Non-finite trial points met on the way.
    pub(crate) edge: FiniteEdge,
    t0: Instant,
    /// The residual modules at the start (the initial evaluation's), until [`begin`] takes
    /// them.
    start_norms: Vec<f64>,
    /// The constraints, for the check of a claimed convergence ([`stationarity`]).
    constraints: &'t volver_core::model::Constraints,
    /// The objective and the final smoothing of Φ (a fraction of Φ), for the same check.
    objective: crate::Objective,
    epsilon: f64,
    /// The loss's value at the start the engine steps from (projected onto the constraints);
    /// infinite until [`begin`] has it.
    start_cost: f64,
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
        let problem = &*task.problem;
        let n = problem.n_params();
        let mut run = Run {
            problem,
            summary: Summary {
                solver: solver.to_string(),
                objective: options.objective,
                phase: task.phase.clone(),
                free_parameters: 0,
                unidentifiable: 0,
                observations: (0..problem.n_points())
                    .map(|i| if problem.scalar(i) { 1 } else { 3 })
                    .sum(),
                points: problem.n_points(),
                initial: Default::default(),
                reached: Default::default(),
                iterations: 0,
                evaluations: 0,
                jacobian_evaluations: 0,
                time_s: 0.0,
                termination: Termination::NoFreeParameters,
                polished: false,
                stationarity: None,
                ignored_options: Vec::new(),
            },
            edge: FiniteEdge::default(),
            t0: Instant::now(),
            start_norms: Vec::new(),
            constraints: &task.constraints,
            objective: options.objective,
            epsilon: options.irls_final_epsilon,
            start_cost: f64::INFINITY,
        };
        if let Err(e) = task.constraints.check_indices(n) {
            let e = crate::nullspace::ConstraintError::from_fault(e, n);
            return Err(Box::new(run.finish(
                start.to_vec(),
                Termination::InvalidInput(Invalid::Constraints(e)),
            )));
        }
        if options.objective.whitened() && !problem.whitened() {
            let e = crate::Error::NotWhitened(options.objective.to_string());
            return Err(Box::new(run.finish(
                start.to_vec(),
                Termination::InvalidInput(Invalid::Refused(e)),
            )));
        }
        if let Err(e) = options.validate() {
            return Err(Box::new(run.finish(
                start.to_vec(),
                Termination::InvalidInput(Invalid::Refused(e)),
            )));
        }
        if start.len() != n || start.iter().any(|v| !v.is_finite()) {
            let t = Termination::InvalidInput(Invalid::Start {
                values: start.len(),
                finite: start.iter().all(|v| v.is_finite()),
                params: n,
            });
            return Err(Box::new(run.finish(start.to_vec(), t)));
        }
        run.start_norms = crate::engines::loss::norms_of(problem, start);
        run.summary.initial = crate::evaluation_with(problem, &run.start_norms, start);
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
        // The caller's pass when it formed one at this very point (the gauge at its reference).
        let known = task
            .plain
            .as_ref()
            .filter(|k| crate::same_bits(&k.at, start))
            .map(|k| k.normal.clone());
        let first = match known {
            Some(normal) => normal,
            None => {
                let Some(first) = accumulate(run.problem, start, |_| (1.0, 0.0), false) else {
                    let t = Termination::NumericalFailure(Failure::JacobianNotFinite(At::Start));
                    return Err(Box::new(run.finish(start.to_vec(), t)));
                };
                run.summary.evaluations += 1;
                run.summary.jacobian_evaluations += 1;
                first
            }
        };
        let (d, ns) = scaled_null_space(&first.h, &task.constraints, start);
        match ns {
            Ok(ns) => {
                let free = Free::new(d, ns, &task.constraints);
                run.summary.free_parameters = free.n_free();
                Ok((run, free, first))
            }
            Err(e) => Err(Box::new(run.finish(
                start.to_vec(),
                Termination::InvalidInput(Invalid::Constraints(e)),
            ))),
        }
    }

    /// The solution at `params`, evaluated, with the termination.
    pub(crate) fn finish(mut self, params: Vec<f64>, termination: Termination) -> Solution {
        // A start of the wrong length cannot be evaluated: it ends as invalid input.
        // The residual modules at the end, for the report and the check alike.
        let mut norms = Vec::new();
        if params.len() == self.problem.n_params() {
            // The report's evaluation, not the engine's: not counted against the limit.
            norms = crate::engines::loss::norms_of(self.problem, &params);
            self.summary.reached = crate::evaluation_with(self.problem, &norms, &params);
        } else {
            self.summary.reached.phi_mm = f64::NAN;
            self.summary.reached.ve_mm2 = f64::NAN;
        }
        // Never report success with a non-finite result, nor a stop at the edge of the finite
        // region as convergence.
        let termination = if !self.summary.reached.phi_mm.is_finite() && !termination.failed() {
            Termination::NumericalFailure(Failure::ObjectiveNotFinite(At::End))
        } else {
            let termination = self.edge.verdict(termination, self.summary.evaluations);
            self.check(&params, &norms, termination)
        };
        self.summary.termination = termination;
        self.summary.time_s = self.t0.elapsed().as_secs_f64();
        Solution {
            params,
            summary: self.summary,
        }
    }
}

impl Run<'_, '_> {
    /// The shared check of the point reached ([`stationarity`]) on a run that did not fail and
    /// had something free: it records what it measured and the directions the design cannot
    /// identify, and turns a claimed convergence at a point that fails it into
    /// [`Stall::NotStationary`](crate::Stall::NotStationary).
    fn check(&mut self, params: &[f64], norms: &[f64], termination: Termination) -> Termination {
        if termination.failed()
            || termination == Termination::NoFreeParameters
            || !self.start_cost.is_finite()
        {
            return termination;
        }
        let Some(measured) = stationarity::measure(
            self.problem,
            self.constraints,
            params,
            norms,
            self.objective,
            self.epsilon,
            self.start_cost,
        ) else {
            return termination;
        };
        self.summary.unidentifiable = measured.unidentifiable;
        self.summary.stationarity = Some(measured.stationarity);
        if termination.converged() && !measured.stationarity.stationary() {
            Termination::Stalled(crate::Stall::NotStationary {
                claimed: termination.to_string(),
                measured: measured.stationarity,
            })
        } else {
            termination
        }
    }
}

/// Where every engine starts: the run, the scaled free coordinates, the unweighted normal
/// equations at `start`, the start projected onto the constraints (held values exact) and its
/// residual modules.
pub(crate) struct Started<'t, 'a> {
    pub(crate) run: Run<'t, 'a>,
    pub(crate) free: Free,
    /// The unweighted normal equations at the start.
    pub(crate) start_normal: Normal,
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
) -> Result<Started<'t, 'a>, Box<Solution>> {
    let run = Run::start(solver, task, start, options)?;
    let (mut run, free, start_normal) = run.free_and_normal(task, start)?;
    // A start on the constraints (to their rounding) is taken as it is, with its evaluation;
    // another is projected onto them.
    let on_constraints = satisfies(&task.constraints, start);
    let p0 = if on_constraints {
        start.to_vec()
    } else {
        free.params(&vec![0.0; free.n_free()])
    };
    if free.n_free() == 0 {
        return Err(Box::new(run.finish(p0, Termination::NoFreeParameters)));
    }
    let start_norms = std::mem::take(&mut run.start_norms);
    let norms0 = if on_constraints {
        start_norms
            .iter()
            .all(|v| v.is_finite())
            .then_some(start_norms)
    } else {
        run.summary.evaluations += 1;
        norms(run.problem, &p0)
    };
    let Some(norms0) = norms0 else {
        let t = Termination::NumericalFailure(Failure::ResidualsNotFinite(At::Start));
        return Err(Box::new(run.finish(p0, t)));
    };
    let n = norms0.len().max(1) as f64;
    run.start_cost = match options.objective.loss() {
        crate::Objective::Phi => norms0.iter().sum::<f64>() / n,
        _ => norms0.iter().map(|m| m * m).sum::<f64>() / n,
    };
    Ok(Started {
        run,
        free,
        start_normal,
        p0,
        norms0,
    })
}

/// Whether `p` satisfies every row of `constraints` to its rounding (64 ε of the row's terms'
/// size; a held value exactly).
fn satisfies(constraints: &volver_core::model::Constraints, p: &[f64]) -> bool {
    constraints.rows.iter().all(|row| {
        let (mut sum, mut size) = (-row.rhs, row.rhs.abs());
        for &(j, c) in &row.coeffs {
            let Some(&v) = p.get(j) else {
                return false;
            };
            sum += c * v;
            size += (c * v).abs();
        }
        match row.coeffs.as_slice() {
            [(j, c)] => p[*j] == row.rhs / c,
            _ => sum.abs() <= 64.0 * f64::EPSILON * size,
        }
    })
}

#[cfg(test)]
mod tests {
    use super::satisfies;
    use volver_core::model::{Constraint, ConstraintKind, Constraints};

    fn row(kind: ConstraintKind, coeffs: Vec<(usize, f64)>, rhs: f64) -> Constraint {
        Constraint {
            kind,
            label: String::new(),
            coeffs,
            rhs,
        }
    }

    #[test]
    fn a_start_satisfies_rows_to_their_rounding_and_held_values_exactly() {
        // 0.1 + 0.2 ≠ 0.3 in binary, by one ulp: within the rounding.
        let c = Constraints {
            rows: vec![
                row(ConstraintKind::Gauge, vec![(0, 1.0), (1, 1.0)], 0.3),
                row(ConstraintKind::Fixed, vec![(2, 2.0)], 5.0),
            ],
        };
        assert!(satisfies(&c, &[0.1, 0.2, 2.5]));
        // A row off by 1e-12 of its size, a held value off by one ulp, a missing parameter.
        assert!(!satisfies(&c, &[0.1, 0.2 + 3e-13, 2.5]));
        assert!(!satisfies(&c, &[0.1, 0.2, 2.5_f64.next_up()]));
        assert!(!satisfies(&c, &[0.1, 0.2]));
        assert!(satisfies(&Constraints::default(), &[1.0]));
    }
}
