//! Geodesic acceleration's second-order term (Transtrum & Sethna 2012).

use super::*;

/// Geodesic acceleration's right-hand side in the free coordinates z: `Nᵀ D Σ J_iᵀ W_i r_i''`,
/// where `r_i''` is the exact second derivative of residual i along the step `delta` (z) and
/// `W_i` its Gauss–Newton weight (as in [`accumulate`]). One Jacobian and one second-derivative
/// pass; `None` when a value is not finite.
pub(super) fn curvature_gradient(
    problem: &dyn Residuals,
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
    let dir = free.direction(delta);
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
