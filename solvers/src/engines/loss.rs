//! The objectives as the engines see them (each by its [`Objective::loss`] on the residuals
//! given, whitened or not): the smoothed cost from the residual modules, each
//! point's weight in the Gauss–Newton model, the residual modules of a parameter vector and the
//! exact gradient of the cost.

use crate::options::Objective;
use rayon::prelude::*;
use volver_core::problem::Residuals;

/// The smoothed objective from residual modules: ve, or `Φ_ε = (1/n) Σ √(‖r‖² + ε²)`.
pub(crate) fn cost_of(objective: Objective, norms: &[f64], eps: f64) -> f64 {
    let n = norms.len() as f64;
    if objective.loss() == Objective::Ve {
        norms.iter().map(|r| r * r).sum::<f64>() / n
    } else {
        norms
            .iter()
            .map(|r| (r * r + eps * eps).sqrt())
            .sum::<f64>()
            / n
    }
}

/// Weight of a point in the Gauss–Newton model of the cost: twice the derivative of the
/// point's loss with respect to ‖r‖², over n (so that `Σ w_i J_iᵀ r_i` is the gradient), and the
/// radial reduction c of its Hessian.
pub(crate) fn weight_of(objective: Objective, r: f64, eps: f64, n: usize) -> (f64, f64) {
    if objective.loss() == Objective::Ve {
        (2.0 / n as f64, 0.0)
    } else {
        let s = r * r + eps * eps;
        (1.0 / (s.sqrt() * n as f64), r * r / s)
    }
}

/// Residual modules at `p`, point by point on every thread of rayon's pool (each module is
/// computed alone, so the bits do not depend on the threads); a module may be non-finite.
pub(crate) fn norms_of(problem: &dyn Residuals, p: &[f64]) -> Vec<f64> {
    (0..problem.n_points())
        .into_par_iter()
        .with_min_len(64)
        .map(|i| volver_core::problem::norm(problem.residual(i, p)))
        .collect()
}

/// [`norms_of`]; `None` if one is not finite.
pub(crate) fn norms(problem: &dyn Residuals, p: &[f64]) -> Option<Vec<f64>> {
    let v = norms_of(problem, p);
    v.iter().all(|x| x.is_finite()).then_some(v)
}

/// The smoothed cost at `p` and its exact gradient with respect to `p` (one dual-number
/// Jacobian pass, no normal matrix); `None` if a residual or Jacobian entry is not finite.
#[cfg(feature = "nlopt")]
pub(crate) fn cost_and_gradient(
    problem: &dyn Residuals,
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
