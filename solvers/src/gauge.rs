//! The gauge: a stated rule for the values the data do not determine.
//!
//! Along a direction the data cannot identify (the tracker's pose against the table's errors,
//! the turn of the tool about the line through two reflectors …) every value fits the data
//! equally well, so an engine would leave it wherever its iteration stopped. volver fixes those
//! values by a rule the user can read ([`crate::strategy::Strategy::gauge`], on by default):
//!
//! > the combinations of parameters the design cannot identify are held at their reference
//! > values: the solution has no component along them, in the function metric, away from the
//! > reference (zero errors and the tracker's rigid fit).
//!
//! That is the minimum-norm solution in the function metric [`function_metric`]: the mean
//! square over its travel of every error function (lengths in mm, angles in rad times
//! [`LEVER_MM`], so that 1 µrad weighs as 1 µm), plus the tracker's pose and the other effects'
//! parameters in the same units. The unidentified directions are the generalised eigenvectors
//! of `(JᵀJ, M)` on the constraint set whose curvature is below [`TOLERANCE`] × the largest,
//! with the Jacobian taken at the reference: they are a property of the design (model, plan,
//! set-up), known before any engine runs and the same whatever it does. The engine solves
//! under them as linear constraints, from the start moved onto them; [`settle`] then polishes
//! the result to the optimum with Newton steps judged by the gradient (the cost's rounding,
//! ~1e-13 of Φ, would leave the weakest identified directions undetermined at ~1e-6). Both the
//! metric and the generalised eigenproblem transform with the parameters (and are computed
//! Jacobi-scaled), so the rule names the same *functions* whatever the basis they are written
//! in. Measured on test 4 of the paper's model (`tests/gauge.rs`): every engine, two other
//! starts and the monomial basis end on the same error functions to 2e-11 relative.
//!
//! ```
//! use volver_core::model::Model;
//! use volver_solvers::gauge::function_metric;
//! let model = Model::default_xcfz();
//! let n = model.n_params();
//! let m = function_metric(&model, &model.initial_params());
//! // EXX.c1 (the linear Legendre term, ξ over [−1, 1]): mean of ξ² over 65 positions ≈ 1/3.
//! let j = model.param_index("EXX.c1").unwrap();
//! assert!((m[(j, j)] - 0.34).abs() < 0.01);
//! ```

use crate::Task;
use faer::{Mat, Side};
use volver_core::iso::Unit;
use volver_core::model::{Constraint, ConstraintKind, Model};
use volver_core::problem::Problem;

/// The lever that turns an angle into a length in the metric (mm): 1 µrad weighs as 1 µm.
pub const LEVER_MM: f64 = 1000.0;

/// Relative curvature (generalised eigenvalue of `(JᵀJ, M)` over the largest) below which a
/// direction is not identified and the gauge holds it.
pub const TOLERANCE: f64 = 1e-9;

/// Positions sampled over each error function's travel by the metric.
const SAMPLES: usize = 65;

/// The rule, as printed in every output that depends on it.
pub const RULE: &str = "minimum norm in the function metric: the combinations the design cannot \
    identify (relative curvature below 1e-9 in the function metric, at the reference) are held at \
    their reference values, zero errors and the tracker's rigid fit (mean square of each error \
    function over its travel, angles × 1000 mm); the rest is the optimum under them";

/// The function metric `M` (n × n) at `params`: `pᵀ M p` is the sum over the error functions of
/// the mean square of their values at 65 evenly spaced positions of their travel (mm², angles
/// times [`LEVER_MM`]), plus the squares of the tracker's pose and of the other effects'
/// parameters in the same units (µm/h and ppm weigh as µm). The error functions are linear in
/// their coefficients except the sine series' phases, whose derivative is taken at `params`.
pub fn function_metric(model: &Model, params: &[f64]) -> Mat<f64> {
    weighted_metric(
        model,
        params,
        |id| {
            if id.unit() == Unit::Mm { 1.0 } else { LEVER_MM }
        },
        |info| match info.unit {
            Unit::Rad => LEVER_MM,
            Unit::Ppm => 1e-3,
            Unit::Mm | Unit::MmPerHour => 1.0,
        },
    )
}

/// A metric of the same form as [`function_metric`] with other weights: `pᵀ M p` is the sum
/// over the error functions of the mean square of `term_scale(id) × value` at 65 evenly spaced
/// positions of their travel, plus `(other_scale(info) × p_j)²` for every parameter no error
/// function covers. A scale of zero leaves its part out. [`crate::prior`] weighs each function
/// by one over its prior magnitude with it.
pub fn weighted_metric(
    model: &Model,
    params: &[f64],
    term_scale: impl Fn(volver_core::iso::ErrorId) -> f64,
    other_scale: impl Fn(&volver_core::model::ParamInfo) -> f64,
) -> Mat<f64> {
    let n = model.n_params();
    let mut m = Mat::<f64>::zeros(n, n);
    let mut covered = vec![false; n];
    let mut grad = vec![0.0; n];
    for t in model.terms() {
        let ax = &model.machine().axes()[t.axis];
        let scale = term_scale(t.id);
        let range: Vec<usize> = t.params.clone().collect();
        for &j in &range {
            covered[j] = true;
        }
        if scale == 0.0 {
            continue;
        }
        for s in 0..SAMPLES {
            let u = ax.min + (ax.max - ax.min) * s as f64 / (SAMPLES - 1) as f64;
            if model
                .error_value_gradient(t.id, u, params, &mut grad)
                .is_none()
            {
                continue;
            }
            for (a, &ja) in range.iter().enumerate() {
                for (b, &jb) in range.iter().enumerate() {
                    m[(ja, jb)] += grad[a] * grad[b] * scale * scale / SAMPLES as f64;
                }
            }
        }
    }
    for (j, info) in model.params().iter().enumerate() {
        if covered[j] {
            continue;
        }
        let w = other_scale(info);
        m[(j, j)] = w * w;
    }
    m
}

/// One combination of parameters the design does not identify, held by the gauge.
#[derive(Clone, Debug, PartialEq)]
pub struct Held {
    /// Its curvature relative to the best-determined direction, in the function metric.
    pub relative_curvature: f64,
    /// The direction in the parameters (their units), unit length in the function metric:
    /// moving the parameters by `t ·` this changes the error functions by `t` mm RMS.
    pub direction: Vec<f64>,
    /// The parameters it moves most: (index, share of the direction in the metric, sign
    /// included), largest first, shares above 0.1.
    pub parameters: Vec<(usize, f64)>,
    /// The constraint that holds it: `Σ c_j p_j = Σ c_j reference_j` with `c = M d` scaled to
    /// a largest coefficient of 1.
    pub constraint: Constraint,
}

/// The gauge of a problem: the rule, its reference, and the combinations it holds.
#[derive(Clone, Debug)]
pub struct Gauge {
    /// The reference the held combinations keep (zero errors and the tracker's rigid fit).
    pub reference: Vec<f64>,
    /// The combinations held, weakest first.
    pub held: Vec<Held>,
    /// The function metric at the reference.
    pub metric: Mat<f64>,
}

impl Gauge {
    /// `task` with the gauge's constraints added (phases that hold parameters too: a row that
    /// their holds already imply is redundant, and the null space accepts it).
    pub fn apply<'a>(&self, task: &Task<'a>) -> Task<'a> {
        let mut t = task.clone();
        t.constraints
            .rows
            .extend(self.held.iter().map(|h| h.constraint.clone()));
        t
    }

    /// `params` moved along the held directions onto the gauge (the point of the gauge nearest
    /// `params` in the function metric): for a solution found without the gauge. Every residual
    /// is unchanged to the extent the held directions are flat.
    pub fn project(&self, params: &[f64]) -> Vec<f64> {
        // The directions are M-orthonormal: the component along d_i is its offset.
        let mut p = params.to_vec();
        for (h, c) in self.held.iter().zip(self.offsets(params)) {
            for (pj, dj) in p.iter_mut().zip(&h.direction) {
                *pj -= c * dj;
            }
        }
        p
    }

    /// The value of each held combination at `params`: `d_iᵀ M (p − reference)` (mm RMS of the
    /// error functions). Zero on the gauge.
    pub fn offsets(&self, params: &[f64]) -> Vec<f64> {
        let n = params.len();
        self.held
            .iter()
            .map(|h| {
                (0..n)
                    .map(|i| {
                        h.direction[i]
                            * (0..n)
                                .map(|j| self.metric[(i, j)] * (params[j] - self.reference[j]))
                                .sum::<f64>()
                    })
                    .sum()
            })
            .collect()
    }
}

/// The gauge of `task` with reference `reference` (which must satisfy its constraints),
/// linearised at `at` (the reference itself for the stated rule, so that the held
/// combinations do not depend on any engine's solution): the directions of the constraint
/// set whose curvature `dᵀJᵀJd / dᵀMd` at `at` is below `tolerance` × the largest
/// ([`TOLERANCE`] by default). Directions the metric does not see there (a sine series' phases
/// while its amplitude is zero) are left free. `None` when the Jacobian is not finite or a
/// decomposition fails.
pub fn gauge(task: &Task, reference: &[f64], at: &[f64], tolerance: f64) -> Option<Gauge> {
    let problem: &Problem = &task.problem;
    let n = reference.len();
    let (h, _) = crate::kernels::normal_equations(problem, at)?;
    let metric = if problem.machine().is_some() {
        function_metric(problem.model(), at)
    } else {
        Mat::from_fn(n, n, |i, j| if i == j { 1.0 } else { 0.0 })
    };
    // Jacobi scaling by the metric's diagonal (by the Jacobian's where the metric sees nothing):
    // bases whose coefficients differ in scale by many orders (a monomial's x³ over 1 400 mm)
    // then give the same directions as well-scaled ones, to rounding.
    let hmax = (0..n).map(|j| h[(j, j)]).fold(0.0_f64, f64::max);
    let scale: Vec<f64> = (0..n)
        .map(|j| {
            let m = metric[(j, j)];
            if m > 0.0 {
                1.0 / m.sqrt()
            } else if h[(j, j)] > 1e-24 * hmax {
                1.0 / h[(j, j)].sqrt()
            } else {
                1.0
            }
        })
        .collect();
    let (a, b) = task.constraints.dense(n);
    let a_scaled: Vec<f64> = (0..b.len() * n).map(|k| a[k] * scale[k % n]).collect();
    let anchor: Vec<f64> = reference.iter().zip(&scale).map(|(p, s)| p / s).collect();
    let ns = crate::nullspace::NullSpace::new(&a_scaled, &b, &anchor).ok()?;
    let nf = ns.n_free();
    let none = |metric| {
        Some(Gauge {
            reference: reference.to_vec(),
            held: vec![],
            metric,
        })
    };
    if nf == 0 {
        return none(metric);
    }
    // The null space's basis in the parameters: p = D N_s z.
    let basis = Mat::from_fn(n, nf, |j, k| scale[j] * ns.basis()[(j, k)]);
    let mz = basis.transpose() * (&metric * &basis);
    let hz = basis.transpose() * (&h * &basis);
    // The part of the free space the metric sees: M_z = Q diag(m) Qᵀ, kept where m > 1e-12 max.
    let evm = mz.self_adjoint_eigen(Side::Lower).ok()?;
    let (mv, q) = (evm.S().column_vector(), evm.U());
    let mmax = (0..nf).map(|i| mv[i]).fold(0.0_f64, f64::max);
    if mmax <= 0.0 {
        return none(metric);
    }
    let seen: Vec<usize> = (0..nf).filter(|&i| mv[i] > 1e-12 * mmax).collect();
    let k = seen.len();
    // Whitened: W = Q_s diag(1/√m), C = Wᵀ H_z W; eigenvectors y give M-orthonormal d = W y.
    let w = Mat::from_fn(nf, k, |r, c| q[(r, seen[c])] / mv[seen[c]].sqrt());
    let c = w.transpose() * (&hz * &w);
    let evc = c.self_adjoint_eigen(Side::Lower).ok()?;
    let (mu, y) = (evc.S().column_vector(), evc.U());
    let mu_max = mu[k - 1].max(f64::MIN_POSITIVE);
    // Parameters a constraint fixes on its own: exactly still (the null space leaves rounding
    // there).
    let mut fixed = vec![false; n];
    for row in &task.constraints.rows {
        if let [(j, _)] = row.coeffs.as_slice() {
            fixed[*j] = true;
        }
    }
    let mut held = Vec::new();
    for i in (0..k).filter(|&i| mu[i] <= tolerance * mu_max) {
        let dz = &w * y.col(i);
        let d: Vec<f64> = (0..n)
            .map(|j| {
                if fixed[j] {
                    0.0
                } else {
                    (0..nf).map(|r| basis[(j, r)] * dz[r]).sum()
                }
            })
            .collect();
        let md: Vec<f64> = (0..n)
            .map(|a| (0..n).map(|b| metric[(a, b)] * d[b]).sum())
            .collect();
        // Shares of the direction in the metric: d_j (M d)_j sums to 1.
        let mut parameters: Vec<(usize, f64)> = (0..n)
            .map(|j| (j, d[j] * md[j]))
            .filter(|(_, s)| s.abs() > 0.1)
            .collect();
        parameters.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
        let cmax = md.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        let coeffs: Vec<(usize, f64)> = md
            .iter()
            .enumerate()
            .filter(|(_, v)| v.abs() > 1e-14 * cmax)
            .map(|(j, v)| (j, v / cmax))
            .collect();
        let rhs = coeffs.iter().map(|&(j, c)| c * reference[j]).sum();
        let curvature = mu[i].max(0.0) / mu_max;
        held.push(Held {
            relative_curvature: curvature,
            direction: d,
            parameters,
            constraint: Constraint {
                kind: ConstraintKind::Gauge,
                label: format!(
                    "gauge: unidentified combination {} held at the reference (relative \
                     curvature {curvature:.1e})",
                    held.len() + 1
                ),
                coeffs,
                rhs,
            },
        });
    }
    Some(Gauge {
        reference: reference.to_vec(),
        held,
        metric,
    })
}

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
/// the cost's change is within its rounding) two steps in a row find no smaller predicted
/// decrease: the result is then the point of smallest predicted decrease.
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
    use crate::loss::{cost_of, norms, weight_of};
    let problem = &task.problem;
    let np = problem.n_points();
    let n = p.len();
    let plain = crate::kernels::accumulate(problem, p, |_| (1.0, 0.0), false)?;
    let (d, ns) = crate::coordinates::scaled_null_space(&plain.h, &task.constraints, p);
    let ns = ns.ok()?;
    let nf = ns.n_free();
    let basis = ns.basis();
    // Parameters a constraint fixes on its own stay exactly at their value (the null space
    // leaves rounding there).
    let fixed: Vec<(usize, f64)> = task
        .constraints
        .rows
        .iter()
        .filter_map(|row| match row.coeffs.as_slice() {
            [(j, c)] if *c != 0.0 => Some((*j, row.rhs / c)),
            _ => None,
        })
        .collect();
    let at = |z: &[f64]| -> Vec<f64> {
        let s = ns.expand(z);
        let mut x: Vec<f64> = s.iter().zip(&d).map(|(s, d)| s * d).collect();
        for &(j, v) in &fixed {
            x[j] = v;
        }
        x
    };
    let mut z = vec![0.0; nf];
    let mut x = at(&z);
    let eps = irls_final_epsilon * problem.phi(&x);
    let mut cost = cost_of(objective, &norms(problem, &x)?, eps);
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
    // Within the cost's rounding the cost cannot tell a better point from a worse one: there
    // the gradient decides. `best` is the point of smallest decrement seen since the cost last
    // fell by more than its rounding, `stale` the steps since it was found.
    let mut best: Option<(Vec<f64>, f64)> = None;
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
        let hs = Mat::from_fn(n, n, |i, j| d[i] * normal.h[(i, j)] * d[j]);
        let hz = basis.transpose() * (&hs * basis);
        let gz: Vec<f64> = (0..nf)
            .map(|k| (0..n).map(|i| basis[(i, k)] * d[i] * normal.g[i]).sum())
            .collect();
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
                problem, &x, &d, basis, &hz, objective, eps,
            )?)?
        } else {
            newton(&hz)?
        };
        if !exact && previous.is_some_and(|d0| decrement > SLOW * d0) {
            exact = true;
            (dz, decrement) = newton(&weak_second_order(
                problem, &x, &d, basis, &hz, objective, eps,
            )?)?;
        }
        match &best {
            Some((_, d0)) if decrement >= *d0 => {
                stale += 1;
                if stale >= STALE_STEPS {
                    break;
                }
            }
            _ => {
                best = Some((x.clone(), decrement));
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
    if let Some((x0, d0)) = best {
        (x, report.decrement) = (x0, d0);
    }
    Some((x, report))
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
/// ([`Problem::residual_second_directional`]), `k (k + 1) / 2` passes for `k` directions.
fn weak_second_order(
    problem: &Problem,
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
