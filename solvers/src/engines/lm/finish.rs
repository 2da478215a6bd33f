//! What follows convergence: the least-squares refinement and the Φ polish.

use super::*;

impl Lm<'_, '_, '_> {
    /// Least squares: Gauss–Newton refinement of the converged point. The damped steps stop
    /// once the cost can no longer tell better from worse (steps refused at rounding raise λ
    /// until the step is negligible); the undamped steps from the QR factor go on to the
    /// minimum (to the Jacobian's condition, not its square) while they contract and the cost
    /// is no worse than its own rounding. Skipped when directions are held as unidentifiable.
    pub(super) fn refine(&mut self, observer: &mut dyn Observer) {
        let problem = self.problem;
        let np = self.np();
        let n = problem.n_params();
        // The cost's rounding: each residual is rounded to a few ε of its observation.
        let rounding = 8.0 * f64::EPSILON * 2.0 / np as f64
            * (0..np)
                .map(|i| self.norms[i] * (self.norms[i] + problem.observation_scale(i)))
                .sum::<f64>();
        let mut last_step = f64::INFINITY;
        for _ in 0..REFINEMENTS {
            let summary = &self.run.summary;
            if summary.iterations >= self.options.max_iterations
                || summary.evaluations + 2 > self.options.max_evaluations
            {
                break;
            }
            let (objective, eps) = (self.objective, self.irls.eps());
            let Some(f) = accumulate(problem, &self.p, |r| weight_of(objective, r, eps, np), true)
                .and_then(|normal| normal.factor)
            else {
                break;
            };
            self.run.summary.evaluations += 1;
            self.run.summary.jacobian_evaluations += 1;
            self.run.summary.iterations += 1;
            let rz =
                &Mat::from_fn(n, n, |i, j| f.r[(i, j)] * self.free.d[j]) * self.free.ns.basis();
            let Some((dz, _)) = damped_lstsq(&rz, &f.c, 0.0) else {
                break;
            };
            // Gauss–Newton converges linearly on a problem with residuals: go on while the
            // steps contract and are not negligible.
            let step = dz.iter().map(|v| v * v).sum::<f64>().sqrt();
            let contracting = step < last_step;
            if !contracting || self.small_step(step) {
                break;
            }
            last_step = step;
            let p_new = self.free.step(&self.p, &dz);
            let norms_new = norms_of(problem, &p_new);
            self.run.summary.evaluations += 1;
            let cost_new = cost_of(self.objective, &norms_new, self.irls.eps());
            let accepted = cost_new <= self.cost + rounding;
            if accepted {
                self.z.iter_mut().zip(&dz).for_each(|(a, b)| *a += b);
                self.p = p_new;
                self.norms = norms_new;
                self.cost = cost_new;
            }
            self.report(observer, 0.0, step, accepted);
            if !accepted {
                break;
            }
        }
    }
}

impl Lm<'_, '_, '_> {
    /// Φ: Newton polish of the converged point ([`crate::engines::polish::settle`]).
    pub(super) fn polish(&mut self, task: &Task) {
        // The vertex of an L1 fit needs its worst case; Newton steps stop within what is left.
        let vertex = self.objective == crate::Objective::Phi
            && crate::engines::polish::all_scalar(&*task.problem);
        let s = &self.run.summary;
        let left = (
            self.options.max_iterations.saturating_sub(s.iterations),
            self.options.max_evaluations.saturating_sub(s.evaluations),
        );
        // A start (a Jacobian pass and an evaluation) and one full step, or nothing.
        if (vertex && !self.room_to_finish()) || left.0 == 0 || left.1 < 36 {
            return;
        }
        if let Ok((q, report)) = crate::engines::polish::settle_scaled(
            task,
            &self.p,
            Some(&self.free.d),
            self.objective,
            self.options.irls_final_epsilon,
            (!vertex).then_some(left),
        ) {
            self.run.summary.iterations += report.steps;
            self.run.summary.jacobian_evaluations += report.jacobian_evaluations;
            self.run.summary.evaluations += report.evaluations + report.jacobian_evaluations;
            self.run.summary.polished = true;
            self.p = q;
        }
    }
}

impl Lm<'_, '_, '_> {
    /// A Φ fit of scalar residuals alone (an L1 fit): the exact vertex of its optimum from the
    /// current point ([`crate::engines::polish::vertex`]); `true` when it was reached (the point
    /// moved there, the fit polished), `false` (nothing changed) when the fit is not one, holds
    /// unidentifiable directions, or the finish did not reach a vertex.
    pub(super) fn vertex_finish(&mut self) -> bool {
        if !self.l1 || self.run.summary.unidentifiable != 0 || !self.room_to_finish() {
            return false;
        }
        let outcome = crate::engines::polish::vertex(self.problem, &self.free, self.p.clone());
        let Ok((q, report)) = outcome else {
            return false;
        };
        self.run.summary.jacobian_evaluations += report.jacobian_evaluations;
        self.run.summary.evaluations += report.evaluations + report.jacobian_evaluations;
        if report.stop != crate::engines::polish::SettleStop::Vertex {
            return false;
        }
        self.run.summary.iterations += report.steps;
        self.run.summary.polished = true;
        self.norms = norms_of(self.problem, &q);
        self.run.summary.evaluations += 1;
        self.p = q;
        self.recost();
        true
    }
}
