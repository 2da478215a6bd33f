//! Newton polish of an optimum under linear constraints: [`settle`] takes a point near the
//! optimum of Φ (or ve) under a task's constraints, as an engine left it, to the optimum itself,
//! to the resolution the cost's and the gradient's rounding allow. The identification settles
//! every engine's result on its gauge with it (so that the result does not depend on where an
//! engine stopped along weakly identified directions), and the native LM polishes a converged
//! Φ fit with it.

use crate::Task;
use faer::{Mat, Side};
use volver_core::problem::Residuals;

/// What [`settle`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settled {
    /// Newton steps taken.
    pub steps: usize,
    /// Jacobian passes.
    pub jacobian_evaluations: usize,
    /// Objective passes (line search included).
    pub evaluations: usize,
    /// The objective's predicted decrease left at the end (the Newton decrement `½ gᵀH⁻¹g`),
    /// relative to the objective.
    pub decrement: f64,
}

/// Newton steps allowed to [`settle`].
const SETTLE_STEPS: usize = 40;

/// [`settle`] stops after this many Newton steps in a row find no decrement smaller than the
/// best seen.
const STALE_STEPS: usize = 2;

/// A step of [`settle`] within the cost's rounding whose end has a positive slope above this
/// share of its start's went past the minimum along its line.
const OVERSHOOT: f64 = 0.5;

/// A Gauss–Newton step of [`settle`] that leaves more than this share of the predicted decrease
/// is slow: the exact second-order term joins from then on.
const SLOW: f64 = 0.1;

/// The optimum of the objective under `task`'s constraints (the gauge's among them), from a
/// point `p` near it: Newton steps on the smoothed objective (`Φ_ε = mean √(‖r‖² + ε²)` with
/// `ε = irls_final_epsilon × Φ`, or ve), each with the exact Gauss–Newton Hessian of the loss
/// (the radial direction of a Φ point carries less curvature than the tangential ones) and,
/// once Gauss–Newton steps converge slowly, the residuals' own second derivatives on the
/// weakest directions, in the Jacobi-scaled free coordinates, with a backtracking line search;
/// until the predicted decrease is below 1e-30 of the objective, no step lowers it, or (once
/// the cost's change is within its rounding) the Newton step would move the error functions by
/// less than 1e-10 of their size (the point is kept), or two steps in a row find no
/// smaller predicted decrease (the result is then the point of smallest predicted decrease).
///
/// This is what makes the gauge a rule rather than a neighbourhood: engines stop at different
/// places in the nearly flat directions that remain identified (curvature 1e-9 … 1e-4 of the
/// largest), and polishing them to the same optimum makes the result independent of the engine
/// and the start. `None` when a residual or Jacobian is not finite or the constraints cannot be
/// eliminated at `p`.
pub fn settle(
    task: &Task,
    p: &[f64],
    objective: crate::Objective,
    irls_final_epsilon: f64,
) -> Option<(Vec<f64>, Settled)> {
    settle_scaled(task, p, None, objective, irls_final_epsilon)
}

/// [`settle`] in the column scaling `scale` when the caller has one for this task (the native
/// LM's, from its start: the Jacobi scaling need not be fresh, and it saves a pass); else the
/// scaling from the Jacobian at `p`.
pub(crate) fn settle_scaled(
    task: &Task,
    p: &[f64],
    scale: Option<&[f64]>,
    objective: crate::Objective,
    irls_final_epsilon: f64,
) -> Option<(Vec<f64>, Settled)> {
    use crate::loss::{cost_of, norms, weight_of};
    let problem = &*task.problem;
    let np = problem.n_points();
    let (d, ns) = match scale {
        Some(d) => (
            d.to_vec(),
            crate::coordinates::null_space_scaled_by(d, &task.constraints, p),
        ),
        None => {
            let plain = crate::kernels::accumulate(problem, p, |_| (1.0, 0.0), false)?;
            crate::coordinates::scaled_null_space(&plain.h, &task.constraints, p)
        }
    };
    // Parameters a constraint fixes on its own stay exactly at their value (the null space
    // leaves rounding there).
    let free = crate::coordinates::Free::new(d, ns.ok()?, &task.constraints);
    let (d, nf, basis) = (&free.d, free.n_free(), free.ns.basis());
    let at = |z: &[f64]| free.params(z);
    let mut z = vec![0.0; nf];
    let mut x = at(&z);
    let norms0 = norms(problem, &x)?;
    let eps = irls_final_epsilon * norms0.iter().sum::<f64>() / np as f64;
    let mut cost = cost_of(objective, &norms0, eps);
    let mut report = Settled {
        steps: 0,
        jacobian_evaluations: 0,
        evaluations: 1,
        decrement: f64::INFINITY,
    };
    if nf == 0 {
        report.decrement = 0.0;
        return Some((x, report));
    }
    // The cost's rounding: each residual is rounded relative to what its point measured (mm
    // from the tracker), not to itself, and the mean of n of them by 1/√n of that: 16 ε of the
    // largest over √n, a margin of ~15 over what is seen (3e-13 of Φ on test 4).
    let scale = (0..np)
        .map(|i| problem.observation_scale(i))
        .fold(0.0_f64, f64::max);
    let floor = 16.0 * f64::EPSILON * scale / (np as f64).sqrt()
        * match objective {
            crate::Objective::Phi => 1.0,
            crate::Objective::Ve => 2.0 * cost.sqrt(),
        };
    // What a step changes that any output can see: the error functions (and the tracker pose)
    // in the gauge's function metric, against the size of the error functions themselves (the
    // tracker's position, metres from the machine, is left out of the size); the parameters
    // themselves for a curve fit.
    let negligible = negligible_step(problem, &x, &free);
    // Within the cost's rounding the cost cannot tell a better point from a worse one: there
    // the gradient decides. `best` is the point of smallest decrement (with its cost) seen since
    // the cost last fell by more than its rounding, `stale` the steps since it was found.
    let mut best: Option<(Vec<f64>, f64, f64)> = None;
    let mut stale = 0;
    // Whether the exact second-order term is in, and the last decrement whose step was taken
    // above the cost's rounding.
    let mut exact = false;
    let mut previous: Option<f64> = None;
    // The last step taken within the cost's rounding: where from, along what, and the slope
    // of the cost there.
    let mut level_step: Option<(Vec<f64>, Vec<f64>, f64)> = None;
    for _ in 0..SETTLE_STEPS {
        let normal =
            crate::kernels::accumulate(problem, &x, |r| weight_of(objective, r, eps, np), false)?;
        report.jacobian_evaluations += 1;
        let (hz, gz) = crate::coordinates::reduce(d, basis, &normal.h, Some(&normal.g));
        // A step taken within the cost's rounding is judged by the slope of the cost along it,
        // which the exact gradient gives to a much finer rounding than the cost's: when the
        // slope at its end is positive and above OVERSHOOT of its start's, the step went past
        // the minimum along its line and is cut back to where the slope's secant vanishes.
        if let Some((z0, dz0, slope0)) = level_step.take() {
            let slope1: f64 = gz.iter().zip(&dz0).map(|(g, d)| g * d).sum();
            if slope0 < 0.0 && slope1 > OVERSHOOT * -slope0 {
                let t = slope0 / (slope0 - slope1);
                let zt: Vec<f64> = z0.iter().zip(&dz0).map(|(a, b)| a + t * b).collect();
                let xt = at(&zt);
                report.evaluations += 1;
                let c = cost_of(objective, &norms(problem, &xt)?, eps);
                (z, x, cost) = (zt, xt, c);
                continue;
            }
        }
        // dz = −H_z⁺ g_z, directions below 1e-14 of the largest curvature left out (the gauge
        // holds the flat ones; rounding is all that is left there), and directions of negative
        // curvature too (no Newton step along them); and the predicted decrease ½ gᵀH⁺g
        // relative to the cost (weight_of's w is twice the loss' derivative in ‖r‖², so H is
        // the cost's Hessian).
        let newton = |hz: &Mat<f64>| -> Option<(Vec<f64>, f64)> {
            let eh = hz.self_adjoint_eigen(Side::Lower).ok()?;
            let (sv, v) = (eh.S().column_vector(), eh.U());
            let smax = (0..nf).map(|i| sv[i]).fold(0.0_f64, f64::max);
            let mut dz = vec![0.0; nf];
            let mut decrement = 0.0;
            for k in 0..nf {
                if sv[k] <= 1e-14 * smax {
                    continue;
                }
                let c = (0..nf).map(|i| v[(i, k)] * gz[i]).sum::<f64>() / sv[k];
                decrement += c * c * sv[k];
                for (i, dzi) in dz.iter_mut().enumerate() {
                    *dzi -= c * v[(i, k)];
                }
            }
            Some((dz, 0.5 * decrement / cost.max(f64::MIN_POSITIVE)))
        };
        // The Gauss–Newton matrix leaves out Σ ψ_iᵀ ∂²r_i (ψ_i the loss' gradient in r_i),
        // small against the strong curvatures but not always against the weakest (measured
        // 1e-6 … 1e-3 of them on tests 3 and 4). Newton steps on it converge at the rate of
        // that ratio; once a step above the cost's rounding leaves more than SLOW of the
        // predicted decrease, the term is added exactly on the weak directions (second-order
        // dual numbers, k (k + 1) / 2 passes for k directions) for the rest of the run.
        let (mut dz, mut decrement) = if exact {
            newton(&weak_second_order(
                problem, &x, d, basis, &hz, objective, eps,
            )?)?
        } else {
            newton(&hz)?
        };
        if !exact && previous.is_some_and(|d0| decrement > SLOW * d0) {
            exact = true;
            (dz, decrement) = newton(&weak_second_order(
                problem, &x, d, basis, &hz, objective, eps,
            )?)?;
        }
        // Within the cost's rounding, a Newton step that moves no error function by more than
        // NEGLIGIBLE of their size leaves nothing any output can see: the point is settled.
        // (Gauss–Newton steps there overshoot along the weak directions rather than fall
        // short, so the step bounds the distance left; the engines' results then agree to
        // about twice NEGLIGIBLE, far inside what the gauge promises.) A converged LM fit of
        // test 4 stops here at once instead of taking six steps in the rounding.
        if decrement * cost <= floor && negligible(&dz) {
            best = None;
            report.decrement = decrement;
            break;
        }
        match &best {
            // Below the best's cost by more than the rounding: better, whatever its decrement
            // (steps each within the rounding add up).
            Some((_, d0, c0)) if decrement >= *d0 && cost >= c0 - floor => {
                stale += 1;
                if stale >= STALE_STEPS {
                    break;
                }
            }
            _ => {
                best = Some((x.clone(), decrement, cost));
                stale = 0;
            }
        }
        if decrement < 1e-30 {
            break;
        }
        // Near the optimum the cost's change falls to its rounding, which resolves the
        // parameters only to the square root of it over the weakest curvature: once the
        // predicted decrease is below that rounding, a full step whose cost is equal to it is
        // taken on the gradient's word. The decrement need not fall at every Newton step (it
        // rose once in five steps on test 3), so the run goes on until STALE_STEPS steps in a
        // row find none smaller than the best, and ends at the best.
        let predicted = decrement * cost;
        previous = (predicted > floor).then_some(decrement);
        let mut t = 1.0;
        let mut moved = false;
        for _ in 0..30 {
            let zt: Vec<f64> = z.iter().zip(&dz).map(|(a, b)| a + t * b).collect();
            let xt = at(&zt);
            report.evaluations += 1;
            if let Some(r) = norms(problem, &xt) {
                let c = cost_of(objective, &r, eps);
                let level = t == 1.0 && predicted <= floor && c <= cost + floor && c.is_finite();
                if c < cost || level {
                    if c < cost - floor {
                        // A decrease the rounding cannot explain: the new point is better
                        // whatever its decrement.
                        best = None;
                    } else {
                        let taken: Vec<f64> = dz.iter().map(|d| t * d).collect();
                        let slope0 = gz.iter().zip(&taken).map(|(g, d)| g * d).sum();
                        level_step = Some((z.clone(), taken, slope0));
                    }
                    (z, x, cost, moved) = (zt, xt, c, true);
                    break;
                }
            }
            t *= 0.5;
        }
        if !moved {
            break;
        }
        report.steps += 1;
    }
    if let Some((x0, d0, _)) = best {
        (x, report.decrement) = (x0, d0);
    }
    Some((x, report))
}

/// A step of [`settle`] within the cost's rounding that changes the error functions by less than
/// this share of their size (in the gauge's function metric) is negligible.
const NEGLIGIBLE: f64 = 1e-10;

/// Whether a step `dz` in `free`'s coordinates from `p` is negligible ([`NEGLIGIBLE`]): for a
/// machine problem, `‖Δp‖_M ≤ NEGLIGIBLE · ‖p_f‖_M` in the gauge's function metric M, where
/// `p_f` is `p` without the tracker pose; for a curve fit, `‖Δp‖ ≤ NEGLIGIBLE · ‖p‖`. Never
/// when the size is zero.
fn negligible_step<'f>(
    problem: &dyn Residuals,
    p: &[f64],
    free: &'f crate::coordinates::Free,
) -> impl Fn(&[f64]) -> bool + 'f {
    let n = p.len();
    let (metric, size) = match problem.machine() {
        Some(machine) => {
            let model = machine.model();
            let m = crate::gauge::problem_metric(machine, p);
            let t = model.tracker_start();
            let pf: Vec<f64> = (0..n)
                .map(|j| if (t..t + 6).contains(&j) { 0.0 } else { p[j] })
                .collect();
            let size = quadratic(&m, &pf).sqrt();
            (Some(m), size)
        }
        None => (None, p.iter().map(|v| v * v).sum::<f64>().sqrt()),
    };
    move |dz: &[f64]| {
        let dp = free.direction(dz);
        let step = match &metric {
            Some(m) => quadratic(m, &dp).sqrt(),
            None => dp.iter().map(|v| v * v).sum::<f64>().sqrt(),
        };
        size > 0.0 && step <= NEGLIGIBLE * size
    }
}

/// `vᵀ M v`.
fn quadratic(m: &Mat<f64>, v: &[f64]) -> f64 {
    let n = v.len();
    (0..n)
        .map(|i| v[i] * (0..n).map(|j| m[(i, j)] * v[j]).sum::<f64>())
        .sum()
}

/// Directions of the Gauss–Newton matrix whose curvature is below this share of the largest
/// get the exact second-order term in [`settle`].
const WEAK: f64 = 1e-3;

/// At most this many weak directions get it (the weakest).
const MAX_WEAK: usize = 16;

/// `hz` (the Gauss–Newton matrix of the cost in the scaled free coordinates, `p = D (s₀ + N z)`)
/// with the exact second-order term `Σ_i ψ_iᵀ ∂²r_i` added on the span of its weakest
/// eigenvectors (curvature below [`WEAK`] of the largest, at most [`MAX_WEAK`]): each entry by
/// polarisation of exact second directional derivatives of the residuals
/// ([`Residuals::residual_second_directional`]), `k (k + 1) / 2` passes for `k` directions.
fn weak_second_order(
    problem: &dyn Residuals,
    x: &[f64],
    d: &[f64],
    basis: faer::MatRef<'_, f64>,
    hz: &Mat<f64>,
    objective: crate::Objective,
    eps: f64,
) -> Option<Mat<f64>> {
    use crate::loss::weight_of;
    let (n, nf, np) = (x.len(), hz.nrows(), problem.n_points());
    let eh = hz.self_adjoint_eigen(Side::Lower).ok()?;
    let (sv, v) = (eh.S().column_vector(), eh.U());
    let smax = (0..nf).map(|i| sv[i]).fold(0.0_f64, f64::max);
    let weak: Vec<usize> = (0..nf)
        .filter(|&i| sv[i] < WEAK * smax)
        .take(MAX_WEAK)
        .collect();
    let k = weak.len();
    if k == 0 {
        return Some(hz.clone());
    }
    let dirs: Vec<Vec<f64>> = weak
        .iter()
        .map(|&c| {
            (0..n)
                .map(|i| d[i] * (0..nf).map(|r| basis[(i, r)] * v[(r, c)]).sum::<f64>())
                .collect()
        })
        .collect();
    // ψ_i = w_i r_i, the cost's gradient in r_i.
    let psi: Vec<[f64; 3]> = (0..np)
        .map(|i| {
            let r = problem.residual(i, x);
            let (w, _) = weight_of(objective, volver_core::problem::norm(r), eps, np);
            r.map(|c| w * c)
        })
        .collect();
    // q(u) = Σ_i ψ_iᵀ d²r_i/dt² along u.
    let q = |u: &[f64]| -> f64 {
        (0..np)
            .map(|i| {
                let r2 = problem.residual_second_directional(i, x, u);
                psi[i][0] * r2[0] + psi[i][1] * r2[1] + psi[i][2] * r2[2]
            })
            .sum()
    };
    let diag: Vec<f64> = dirs.iter().map(|u| q(u)).collect();
    let mut s = Mat::<f64>::zeros(k, k);
    for a in 0..k {
        s[(a, a)] = diag[a];
        for b in 0..a {
            let sum: Vec<f64> = dirs[a].iter().zip(&dirs[b]).map(|(p, q)| p + q).collect();
            let e = 0.5 * (q(&sum) - diag[a] - diag[b]);
            s[(a, b)] = e;
            s[(b, a)] = e;
        }
    }
    if (0..k).any(|a| (0..k).any(|b| !s[(a, b)].is_finite())) {
        return None;
    }
    let vw = Mat::from_fn(nf, k, |r, c| v[(r, weak[c])]);
    Some(hz + &vw * (&s * vw.transpose()))
}
