//! The exact optimum of Φ on scalar residuals (ranges alone, [`Residuals::scalar`]): there Φ is
//! an L1 fit, `Φ = (1/n) Σ |r_i|`, whose optimum is a *vertex*: as many residuals vanish as
//! there are free coordinates (the *basis*), and every other one keeps its sign. Smoothing the
//! kinks (`Φ_ε`) and taking Newton steps on it, as [`super::settle`] does for points, sees only
//! the residuals within ε of zero and crawls (forty steps and more on test 4's ranges from four
//! stations, each with the second-order term on the weak directions); a vertex is found by a few
//! sequential linear programmes instead:
//!
//! 1. at the point, the residuals and their Jacobian rows in the scaled free coordinates (one
//!    pass) give the linearised fit `min Σ |r_i + a_i·δ|`, an L1 regression;
//! 2. [`vertex`] solves it exactly by the simplex method of L1 regression (Barrodale and
//!    Roberts 1973), from the previous basis (at first, the independent rows of the smallest
//!    residuals): the basic step `δ = −A_B⁻¹ r_B` makes the basic residuals vanish; the
//!    multipliers `u = −A_B⁻ᵀ Σ_{i∉B} σ_i a_i` of the basic points (σ_i = ±1 the side of zero
//!    of the linearised residual ρ_i) say whether it is the optimum (every |u_k| ≤ 1); else
//!    the basic point of largest |u_k| leaves, along the edge
//!    where it alone moves off zero, as far as the piecewise-linear objective falls (its
//!    breakpoints, where other residuals cross zero, walked in order), and the point at that
//!    breakpoint enters;
//! 3. the step δ is taken if Φ itself falls (halved until it does); at the new point the next
//!    linear programme starts from the basis found.
//!
//! Once the basis is the optimum's, each step is Newton's on `r_B(z) = 0` (square, exact
//! Jacobian): the steps contract quadratically, and the run stops when the linear programme's
//! step is negligible (it moves no error function by more than 1e-10 of their size) with its
//! predicted decrease within the cost's rounding — every basic residual zero to rounding and
//! every multiplier within ±1: the first-order conditions of the L1 optimum, exactly
//! (see [`SettleStop::Vertex`]).

use super::{Negligible, SettleStop, Settled, Unsettled};
use crate::engines::coordinates::Free;
use crate::engines::kernels::dot;
use faer::Mat;
use faer::linalg::solvers::{PartialPivLu, Solve};
use rayon::prelude::*;
use volver_core::problem::Residuals;

/// Sequential linear programmes allowed.
const STEPS: usize = 40;

/// Simplex pivots allowed per linear programme, per free coordinate.
const PIVOTS_PER_COORDINATE: usize = 20;

/// A basis is optimal once every multiplier is within 1 + this (the multipliers' rounding).
const MULTIPLIER_ROUNDING: f64 = 1e-9;

/// The residuals the simplex pivots see are perturbed by up to 1.5 times this share of their
/// mean module (see [`vertex`]).
const PERTURBATION: f64 = 1e-10;

/// A row enters the first basis when the part of it independent of the rows already in is
/// above this share of its norm.
const INDEPENDENT: f64 = 1e-6;

/// Halvings of a step the line search tries.
const HALVINGS: usize = 30;

/// Whether every residual of `problem` is a scalar (the L1 case).
pub(crate) fn all_scalar(problem: &dyn Residuals) -> bool {
    let np = problem.n_points();
    np > 0 && (0..np).all(|i| problem.scalar(i))
}

/// The residuals at `x` and their Jacobian rows in the free coordinates of `free` (n × m,
/// row-major): `a_i = J_i D N`, each point's alone (the bits do not depend on the threads);
/// `None` where one is not finite.
fn rows(problem: &dyn Residuals, free: &Free, x: &[f64]) -> Option<(Vec<f64>, Vec<f64>)> {
    let (np, n, m) = (problem.n_points(), problem.n_params(), free.n_free());
    let basis = free.ns.basis();
    // M = D N, row-major n × m.
    let dn: Vec<f64> = (0..n * m)
        .map(|k| free.d[k / m] * basis[(k / m, k % m)])
        .collect();
    let mut r = vec![0.0; np];
    let mut a = vec![0.0; np * m];
    a.par_chunks_mut(m.max(1))
        .zip(r.par_iter_mut())
        .enumerate()
        .with_min_len(64)
        .for_each_init(
            || vec![0.0; 3 * n],
            |jac, (i, (ai, ri))| {
                *ri = problem.residual_and_jacobian(i, x, jac)[0];
                for (j, &jj) in jac[..n].iter().enumerate() {
                    if jj != 0.0 {
                        for (ak, mk) in ai.iter_mut().zip(&dn[j * m..(j + 1) * m]) {
                            *ak += jj * mk;
                        }
                    }
                }
            },
        );
    (r.iter().chain(&a).all(|v| v.is_finite())).then_some((r, a))
}

/// The first basis: the rows of the smallest residuals, each kept when it is independent of
/// those already kept (Gram–Schmidt, twice), until there are `m`; `None` when the rows do not
/// span the free coordinates.
fn first_basis(a: &[f64], r: &[f64], m: usize) -> Option<Vec<usize>> {
    let mut order: Vec<usize> = (0..r.len()).collect();
    order.sort_by(|&i, &j| r[i].abs().total_cmp(&r[j].abs()).then(i.cmp(&j)));
    let mut q: Vec<Vec<f64>> = Vec::with_capacity(m);
    let mut basis = Vec::with_capacity(m);
    for i in order {
        if basis.len() == m {
            break;
        }
        let row = &a[i * m..(i + 1) * m];
        let size = dot(row, row).sqrt();
        let mut v = row.to_vec();
        for _ in 0..2 {
            for qk in &q {
                let c = dot(qk, &v);
                v.iter_mut().zip(qk).for_each(|(x, y)| *x -= c * y);
            }
        }
        let left = dot(&v, &v).sqrt();
        if size > 0.0 && left > INDEPENDENT * size {
            v.iter_mut().for_each(|x| *x /= left);
            q.push(v);
            basis.push(i);
        }
    }
    (basis.len() == m).then_some(basis)
}

/// The optimum of a linearised L1 fit: the step, the linearised residuals there and the
/// pivots taken.
#[derive(Debug)]
struct Lp {
    delta: Vec<f64>,
    rho: Vec<f64>,
    pivots: usize,
}

/// `min_δ Σ |r_i + a_i·δ|` (a: n × m row-major) by the simplex method of L1 regression
/// ([`simplex`]), from `basis` (m independent rows), which becomes the optimum's; `None` when a
/// basis matrix is singular, the programme unbounded (the rows do not span) or the pivots are
/// spent.
///
/// A degenerate programme (a non-basic residual at zero at a vertex: two ranges of one pose
/// measured twice, a noise-free fit, where every residual is at the data's rounding) lets the
/// simplex method pivot without moving and come back to a basis it left (measured: a cycle of
/// three on test 4's noise-free ranges). The residuals the pivots see are perturbed by
/// distinct amounts ([`PERTURBATION`] of their mean module, far above their rounding and far
/// below anything Φ can tell), so that no two vertices tie and every pivot lowers the
/// objective; the optimum's basis is the unperturbed programme's too (its multipliers do not
/// depend on the residuals, only on which side of zero each lies, and a side changed by the
/// perturbation is a residual at zero, where either side is), and the step and the linearised
/// residuals returned are the unperturbed ones.
fn vertex(a: &[f64], r: &[f64], basis: &mut [usize]) -> Option<Lp> {
    let n = r.len();
    let size = PERTURBATION * r.iter().map(|v| v.abs()).sum::<f64>() / n as f64;
    let perturbed: Vec<f64> = r
        .iter()
        .enumerate()
        .map(|(i, v)| v + size * tie_breaker(i))
        .collect();
    let pivots = simplex(a, &perturbed, basis)?;
    let (delta, rho, _) = basic_solution(a, r, basis)?;
    Some(Lp { delta, rho, pivots })
}

/// Distinct numbers in [0.5, 1.5), one per row (the golden ratio's multiples modulo one).
fn tie_breaker(i: usize) -> f64 {
    const GOLDEN: f64 = 0.618_033_988_749_894_9;
    0.5 + ((i as f64 + 1.0) * GOLDEN).fract()
}

/// The basic solution of `basis`: the step `δ = −A_B⁻¹ r_B`, the linearised residuals
/// `ρ = r + A δ` (zero on the basis) and the factorised basis matrix; `None` when the step is
/// not finite (a singular basis).
fn basic_solution(
    a: &[f64],
    r: &[f64],
    basis: &[usize],
) -> Option<(Vec<f64>, Vec<f64>, PartialPivLu<f64>)> {
    let m = basis.len();
    let lu = Mat::from_fn(m, m, |k, j| a[basis[k] * m + j]).partial_piv_lu();
    let db = lu.solve(Mat::from_fn(m, 1, |k, _| -r[basis[k]]));
    let delta: Vec<f64> = (0..m).map(|j| db[(j, 0)]).collect();
    if delta.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let mut rho: Vec<f64> = (0..r.len())
        .map(|i| r[i] + dot(&a[i * m..(i + 1) * m], &delta))
        .collect();
    basis.iter().for_each(|&i| rho[i] = 0.0);
    Some((delta, rho, lu))
}

/// The simplex method of L1 regression on `r` from `basis`, which becomes the optimum's: the
/// pivots taken; `None` as [`vertex`].
///
/// Each non-basic row keeps its side σ_i = ±1 of zero from the start (the sign of its
/// linearised residual there) and changes it only where a pivot carries it across zero: a side
/// read afresh from a residual at zero would be its rounding's.
fn simplex(a: &[f64], r: &[f64], basis: &mut [usize]) -> Option<usize> {
    let (n, m) = (r.len(), basis.len());
    let mut is_basic = vec![false; n];
    basis.iter().for_each(|&i| is_basic[i] = true);
    let mut sigma: Option<Vec<f64>> = None;
    for pivots in 0..=PIVOTS_PER_COORDINATE * m {
        let (_, rho, lu) = basic_solution(a, r, basis)?;
        let sigma = sigma.get_or_insert_with(|| {
            rho.iter()
                .map(|v| if *v < 0.0 { -1.0 } else { 1.0 })
                .collect()
        });
        // u = −A_B⁻ᵀ g, g = Σ_{i∉B} σ_i a_i.
        let mut g = Mat::<f64>::zeros(m, 1);
        for i in (0..n).filter(|&i| !is_basic[i]) {
            for j in 0..m {
                g[(j, 0)] -= sigma[i] * a[i * m + j];
            }
        }
        let u = lu.solve_transpose(&g);
        let (k, umax) = (0..m)
            .map(|k| (k, u[(k, 0)].abs()))
            .fold((0, -1.0), |best, c| if c.1 > best.1 { c } else { best });
        if !umax.is_finite() {
            return None;
        }
        if umax <= 1.0 + MULTIPLIER_ROUNDING {
            return Some(pivots);
        }
        // The edge on which basic point k alone moves off zero, towards the sign of u_k.
        let t = u[(k, 0)].signum();
        let d = lu.solve(Mat::from_fn(m, 1, |j, _| if j == k { t } else { 0.0 }));
        let dv: Vec<f64> = (0..m).map(|j| d[(j, 0)]).collect();
        let (entering, crossed) = ratio_test(a, &rho, sigma, &is_basic, &dv, 1.0 - umax)?;
        for i in crossed {
            sigma[i] = -sigma[i];
        }
        sigma[basis[k]] = t;
        is_basic[basis[k]] = false;
        is_basic[entering] = true;
        basis[k] = entering;
    }
    None
}

/// The point that enters the basis along the edge `d` from the linearised residuals `rho` on
/// their sides `sigma`, the objective's slope there `slope0` (< 0), and the rows carried across
/// zero before it: the breakpoints (a non-basic residual moving towards zero reaches it, and
/// the slope rises by 2|a_i·d|) walked in order until the slope is no longer negative; `None`
/// when it never is (unbounded).
fn ratio_test(
    a: &[f64],
    rho: &[f64],
    sigma: &[f64],
    is_basic: &[bool],
    d: &[f64],
    slope0: f64,
) -> Option<(usize, Vec<usize>)> {
    let m = d.len();
    let mut breaks: Vec<(f64, usize, f64)> = (0..rho.len())
        .filter(|&i| !is_basic[i])
        .filter_map(|i| {
            let c = dot(&a[i * m..(i + 1) * m], d);
            // On its side σ, moving towards zero: it gets there at |ρ|/|c| (0 where its
            // rounding put it on the other side already).
            (sigma[i] * c < 0.0).then(|| ((sigma[i] * rho[i]).max(0.0) / c.abs(), i, 2.0 * c.abs()))
        })
        .collect();
    breaks.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
    let mut slope = slope0;
    for (walked, &(_, i, jump)) in breaks.iter().enumerate() {
        slope += jump;
        if slope >= 0.0 {
            return Some((i, breaks[..walked].iter().map(|b| b.1).collect()));
        }
    }
    None
}

/// Φ from residuals.
fn phi_of(r: &[f64]) -> f64 {
    r.iter().map(|v| v.abs()).sum::<f64>() / r.len() as f64
}

/// A point of the run: the parameters, the residuals, their rows and Φ.
type Point = (Vec<f64>, Vec<f64>, Vec<f64>, f64);

/// The L1 optimum of `problem` (every residual scalar, Φ) in the free coordinates `free`
/// from `x`, `floor` the cost's rounding (see the module documentation); the point reached and
/// the report. [`Unsettled::NotFinite`] when the start's residuals or rows are not finite,
/// [`Unsettled::Decomposition`] when the rows do not span the free coordinates or a linear
/// programme fails (a singular basis, its pivots spent).
pub(crate) fn settle(
    problem: &dyn Residuals,
    free: &Free,
    x: Vec<f64>,
    floor: f64,
) -> Result<(Vec<f64>, Settled), Unsettled> {
    let m = free.n_free();
    let negligible = Negligible::at(problem, &x);
    let mut report = Settled {
        steps: 0,
        jacobian_evaluations: 1,
        evaluations: 0,
        pivots: 0,
        decrement: f64::INFINITY,
        stop: SettleStop::StepLimit,
    };
    let (r, a) = rows(problem, free, &x).ok_or(Unsettled::NotFinite)?;
    let phi = phi_of(&r);
    let mut point: Point = (x, r, a, phi);
    let mut basis = first_basis(&point.2, &point.1, m).ok_or(Unsettled::Decomposition)?;
    for _ in 0..STEPS {
        let (x, r, a, phi) = &point;
        let lp = vertex(a, r, &mut basis).ok_or(Unsettled::Decomposition)?;
        report.pivots += lp.pivots;
        let predicted = (phi - phi_of(&lp.rho)).max(0.0);
        report.decrement = predicted / phi.max(f64::MIN_POSITIVE);
        let level = predicted <= floor;
        if level && negligible.step(free, &lp.delta) {
            report.stop = SettleStop::Vertex;
            return Ok((point.0, report));
        }
        let tolerance = if level { floor } else { 0.0 };
        match line_search(problem, free, (x, *phi), &lp.delta, tolerance, &mut report) {
            Some(next) => point = next,
            None => {
                report.stop = SettleStop::NoDecrease;
                return Ok((point.0, report));
            }
        }
        report.steps += 1;
    }
    Ok((point.0, report))
}

/// The step `delta` from `x` (Φ = `phi`), halved until Φ falls (or, for the full step, rises by
/// no more than `tolerance`: the cost's rounding when the linear programme predicts a decrease
/// within it, else zero); `None` when no step does. The full step is judged by a Jacobian pass
/// (near the optimum it is taken), a halved one by an objective pass first.
fn line_search(
    problem: &dyn Residuals,
    free: &Free,
    (x, phi): (&[f64], f64),
    delta: &[f64],
    tolerance: f64,
    report: &mut Settled,
) -> Option<Point> {
    let xt = free.step(x, delta);
    report.jacobian_evaluations += 1;
    if let Some((r, a)) = rows(problem, free, &xt) {
        let phit = phi_of(&r);
        if phit < phi || (tolerance > 0.0 && phit <= phi + tolerance) {
            return Some((xt, r, a, phit));
        }
    }
    let mut t = 1.0;
    for _ in 1..HALVINGS {
        t *= 0.5;
        let dz: Vec<f64> = delta.iter().map(|v| t * v).collect();
        let xt = free.step(x, &dz);
        report.evaluations += 1;
        let lower = crate::engines::loss::norms(problem, &xt)
            .is_some_and(|r| r.iter().sum::<f64>() / (r.len() as f64) < phi);
        if lower {
            report.jacobian_evaluations += 1;
            let (r, a) = rows(problem, free, &xt)?;
            let phit = phi_of(&r);
            return Some((xt, r, a, phit));
        }
    }
    None
}

#[cfg(test)]
mod tests;
