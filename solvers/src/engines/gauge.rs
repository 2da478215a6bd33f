//! The gauge: a stated rule for the values the data do not determine.
//!
//! Along a direction the data cannot identify (the tracker's pose against the table's errors,
//! the turn of the tool about the line through two reflectors …) every value fits the data
//! equally well, so an engine would leave it wherever its iteration stopped. volver fixes those
//! values by a rule the user can read ([`crate::engines::strategy::Strategy::gauge`], on by default):
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
//! under them as linear constraints, from the start moved onto them; [`crate::engines::polish::settle`] then polishes
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
use crate::engines::kernels::sandwich;
use faer::{Mat, Side};
use volver_core::iso::Unit;
use volver_core::model::{Constraint, ConstraintKind, Model};
use volver_core::problem::Residuals;
use volver_core::units::{S_PER_H, UM_PER_MM, URAD_PER_RAD};

/// The lever that turns an angle into a length in the metric (mm): 1 µrad weighs as 1 µm
/// (1000 mm: µrad per rad over µm per mm).
pub const LEVER_MM: f64 = URAD_PER_RAD / UM_PER_MM;

/// Relative curvature (generalised eigenvalue of `(JᵀJ, M)` over the largest) below which a
/// direction is not identified and the gauge holds it.
pub const TOLERANCE: f64 = 1e-9;

/// Positions sampled over each error function's travel by the metric.
const SAMPLES: usize = 65;

/// The rule, as printed in every output that depends on it.
pub const RULE: &str = "minimum norm in the function metric: the combinations the design cannot \
    identify (relative curvature below 1e-9 in the function metric, at the reference) are held at \
    their reference values, zero errors and the tracker's rigid fit (mean square of each error \
    function over its travel, angles × 1000 mm, a drift over the test's span); the rest is the \
    optimum under them";

/// The function metric `M` (n × n) at `params`: `pᵀ M p` is the sum over the error functions of
/// the mean square of their values at 65 evenly spaced positions of their travel (mm², angles
/// times [`LEVER_MM`]), plus the squares of the tracker's pose and of the other effects'
/// parameters in the same units (µm/h, ppm and ppm/h weigh as µm). The error functions are linear in
/// their coefficients except the sine series' phases, whose derivative is taken at `params`.
/// A rate over time weighs as over one hour here; [`problem_metric`] weighs it over the test.
pub fn function_metric(model: &Model, params: &[f64]) -> Mat<f64> {
    function_metric_over(model, params, None)
}

/// [`function_metric`] of a problem: a parameter multiplying `tᵖ` (a drift rate, a field's
/// `t` and `t²`, [`Model::time_power`]) weighs as the RMS of its function over the test's span
/// `T` (from its first stamp, [`volver_core::measure::MeasurementSet::time_span_s`]),
/// `Tᵖ / √(2p + 1)` in hours, so that the gauge, and the fit, are the same whatever the unit
/// of the time stamps (a rate in the stamps' unit scales as `1/T`).
pub fn problem_metric(problem: &volver_core::problem::Problem, params: &[f64]) -> Mat<f64> {
    let span_h = problem
        .data()
        .time_span_s()
        .filter(|&t| t > 0.0)
        .map(|t| t / S_PER_H);
    function_metric_over(problem.model(), params, span_h)
}

/// [`function_metric`] with rates over time weighed over a span of `span_h` hours (over one
/// hour when `None`).
pub fn function_metric_over(model: &Model, params: &[f64], span_h: Option<f64>) -> Mat<f64> {
    let time = |j: usize| match (span_h, model.time_power(j)) {
        (Some(t), p) if p > 0 => t.powi(p as i32) / f64::from(2 * p + 1).sqrt(),
        _ => 1.0,
    };
    weighted_metric(
        model,
        params,
        |id| {
            if id.unit() == Unit::Mm { 1.0 } else { LEVER_MM }
        },
        |j, info| {
            let unit = match info.unit {
                Unit::Rad | Unit::RadPerHour => LEVER_MM,
                Unit::Ppm | Unit::PpmPerHour => 1.0 / UM_PER_MM,
                Unit::Mm | Unit::MmPerHour => 1.0,
                // A unit to come: weighted as a length.
                _ => 1.0,
            };
            unit * time(j)
        },
    )
}

/// A metric of the same form as [`function_metric`] with other weights: `pᵀ M p` is the sum
/// over the error functions of the mean square of `term_scale(id) × value` at 65 evenly spaced
/// positions of their travel, plus `(other_scale(j, info) × p_j)²` for every parameter `j` no
/// error function covers. A scale of zero leaves its part out. [`crate::analysis::prior`] weighs each
/// function by one over its prior magnitude with it.
pub fn weighted_metric(
    model: &Model,
    params: &[f64],
    term_scale: impl Fn(volver_core::iso::ErrorId) -> f64,
    other_scale: impl Fn(usize, &volver_core::model::ParamInfo) -> f64,
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
        let w = other_scale(j, info);
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
    /// The unweighted normal equations at the point the gauge was found at, handed to the
    /// tasks it is applied to ([`Gauge::apply`]).
    plain: Option<std::sync::Arc<crate::PlainNormal>>,
}

impl Gauge {
    /// `task` with the gauge's constraints added (phases that hold parameters too: a row that
    /// their holds already imply is redundant, and the null space accepts it).
    pub fn apply<'a>(&self, task: &Task<'a>) -> Task<'a> {
        let mut t = task.clone();
        t.constraints
            .rows
            .extend(self.held.iter().map(|h| h.constraint.clone()));
        if t.problem.n_params() == self.reference.len() {
            t.plain.clone_from(&self.plain);
        }
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
    let problem: &dyn Residuals = &*task.problem;
    let n = reference.len();
    // The design's pass and the metric (which does not depend on it) side by side.
    let (normal, metric) = rayon::join(
        || crate::engines::kernels::accumulate(problem, at, |_| (1.0, 0.0), false),
        || match problem.machine() {
            Some(machine) => problem_metric(machine, at),
            None => Mat::from_fn(n, n, |i, j| if i == j { 1.0 } else { 0.0 }),
        },
    );
    let normal = normal?;
    let h = normal.h.clone();
    let plain = Some(std::sync::Arc::new(crate::PlainNormal {
        at: at.to_vec(),
        normal,
    }));
    let scale = jacobi_scale(&h, &metric);
    let basis = free_basis(task, &scale, reference)?;
    let mut found = Gauge {
        reference: reference.to_vec(),
        held: vec![],
        metric,
        plain,
    };
    if basis.ncols() == 0 {
        return Some(found);
    }
    let fixed = fixed_by_constraints(task, n);
    for (dz, curvature) in weak_directions(&h, &found.metric, &basis, tolerance)? {
        let d: Vec<f64> = (0..n)
            .map(|j| {
                if fixed[j] {
                    0.0
                } else {
                    (0..basis.ncols()).map(|r| basis[(j, r)] * dz[r]).sum()
                }
            })
            .collect();
        let number = found.held.len() + 1;
        found
            .held
            .push(held(&found.metric, reference, d, curvature, number));
    }
    Some(found)
}

/// The Jacobi scaling of the parameters, one factor each: by the metric's diagonal (by the
/// Jacobian's, `h` = JᵀJ, where the metric sees nothing). Bases whose coefficients differ in
/// scale by many orders (a monomial's x³ over 1 400 mm) then give the same directions as
/// well-scaled ones, to rounding.
fn jacobi_scale(h: &Mat<f64>, metric: &Mat<f64>) -> Vec<f64> {
    let n = h.nrows();
    let hmax = (0..n).map(|j| h[(j, j)]).fold(0.0_f64, f64::max);
    (0..n)
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
        .collect()
}

/// A basis of the directions `task`'s constraints leave free, in the parameters (n × free):
/// `D N_s` with `D` the scaling `scale` and `N_s` the null space of the scaled constraints
/// anchored at `reference`. `None` when the null space cannot be formed.
fn free_basis(task: &Task, scale: &[f64], reference: &[f64]) -> Option<Mat<f64>> {
    let n = reference.len();
    let (a, b) = task.constraints.dense(n);
    let a_scaled: Vec<f64> = (0..b.len() * n).map(|k| a[k] * scale[k % n]).collect();
    let anchor: Vec<f64> = reference.iter().zip(scale).map(|(p, s)| p / s).collect();
    let ns = crate::nullspace::NullSpace::new(&a_scaled, &b, &anchor).ok()?;
    let nf = ns.n_free();
    Some(Mat::from_fn(n, nf, |j, k| scale[j] * ns.basis()[(j, k)]))
}

/// The directions of the free space `basis` (n × nf) whose curvature `dᵀ h d / dᵀ M d` is at
/// most `tolerance` × the largest, over the part of the free space the metric `M` sees
/// (eigenvalues of `Nᵀ M N` above 1e-12 of the largest): each as its coordinates `d_z` in the
/// free space (M-orthonormal `d = N d_z`) and its relative curvature, weakest first. Empty when
/// the metric sees nothing; `None` when a decomposition fails.
fn weak_directions(
    h: &Mat<f64>,
    metric: &Mat<f64>,
    basis: &Mat<f64>,
    tolerance: f64,
) -> Option<Vec<(faer::Col<f64>, f64)>> {
    let nf = basis.ncols();
    // The part of the free space the metric sees: M_z = Q diag(m) Qᵀ, kept where m > 1e-12 max
    // (decomposed while H_z is formed).
    let (evm, hz) = rayon::join(
        || sandwich(metric.as_ref(), basis.as_ref()).self_adjoint_eigen(Side::Lower),
        || sandwich(h.as_ref(), basis.as_ref()),
    );
    let evm = evm.ok()?;
    let (mv, q) = (evm.S().column_vector(), evm.U());
    let mmax = (0..nf).map(|i| mv[i]).fold(0.0_f64, f64::max);
    if mmax <= 0.0 {
        return Some(vec![]);
    }
    let seen: Vec<usize> = (0..nf).filter(|&i| mv[i] > 1e-12 * mmax).collect();
    let k = seen.len();
    // Whitened: W = Q_s diag(1/√m), C = Wᵀ H_z W; eigenvectors y give M-orthonormal d = W y.
    let w = Mat::from_fn(nf, k, |r, c| q[(r, seen[c])] / mv[seen[c]].sqrt());
    let c = sandwich(hz.as_ref(), w.as_ref());
    let evc = c.self_adjoint_eigen(Side::Lower).ok()?;
    let (mu, y) = (evc.S().column_vector(), evc.U());
    let mu_max = mu[k - 1].max(f64::MIN_POSITIVE);
    Some(
        (0..k)
            .filter(|&i| mu[i] <= tolerance * mu_max)
            .map(|i| (&w * y.col(i), mu[i].max(0.0) / mu_max))
            .collect(),
    )
}

/// The parameters a constraint of `task` fixes on its own (a row of one coefficient): exactly
/// still in a held direction (the null space leaves rounding there).
fn fixed_by_constraints(task: &Task, n: usize) -> Vec<bool> {
    let mut fixed = vec![false; n];
    for row in &task.constraints.rows {
        if let [(j, _)] = row.coeffs.as_slice() {
            fixed[*j] = true;
        }
    }
    fixed
}

/// The held combination number `number` along the direction `d` (the parameters' units, unit
/// length in the metric `metric`) of relative curvature `curvature`: its shares, and the
/// constraint `Σ c_j p_j = Σ c_j reference_j` with `c = M d` scaled to a largest coefficient
/// of 1 (coefficients below 1e-14 of it left out).
fn held(metric: &Mat<f64>, reference: &[f64], d: Vec<f64>, curvature: f64, number: usize) -> Held {
    let n = d.len();
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
    Held {
        relative_curvature: curvature,
        direction: d,
        parameters,
        constraint: Constraint {
            kind: ConstraintKind::Gauge,
            label: format!(
                "gauge: unidentified combination {number} held at the reference (relative \
                 curvature {curvature:.1e})"
            ),
            coeffs,
            rhs,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::borrow::Cow;
    use volver_core::model::Constraints;

    /// `r_i = (a + b + c·x_i − y_i, 0, 0)`: a and b enter only as their sum, so the one direction
    /// the data cannot identify is (1, −1, 0), whatever the data.
    #[derive(Debug)]
    struct SumOfTwo {
        points: Vec<(f64, f64)>,
        constraints: Constraints,
    }

    impl SumOfTwo {
        fn new(constraints: Constraints) -> SumOfTwo {
            let points = (0..6).map(|i| (i as f64, 2.0 + 0.5 * i as f64)).collect();
            SumOfTwo {
                points,
                constraints,
            }
        }
    }

    impl Residuals for SumOfTwo {
        fn n_params(&self) -> usize {
            3
        }
        fn n_points(&self) -> usize {
            self.points.len()
        }
        fn param_names(&self) -> Vec<String> {
            vec!["a".into(), "b".into(), "c".into()]
        }
        fn constraints(&self) -> Cow<'_, Constraints> {
            Cow::Borrowed(&self.constraints)
        }
        fn residual(&self, i: usize, p: &[f64]) -> [f64; 3] {
            let (x, y) = self.points[i];
            [p[0] + p[1] + p[2] * x - y, 0.0, 0.0]
        }
        fn residual_and_jacobian(&self, i: usize, p: &[f64], jac: &mut [f64]) -> [f64; 3] {
            jac.fill(0.0);
            jac[..3].copy_from_slice(&[1.0, 1.0, self.points[i].0]);
            self.residual(i, p)
        }
        fn residual_second_directional(&self, _: usize, _: &[f64], _: &[f64]) -> [f64; 3] {
            [0.0; 3]
        }
        fn observation_scale(&self, i: usize) -> f64 {
            self.points[i].1
        }
    }

    /// Without a machine the metric is the identity: the held direction is (1, −1, 0)/√2, its
    /// constraint a − b = reference's a − b, and projecting moves a and b by the same amount in
    /// opposite directions, leaving every residual as it was.
    #[test]
    fn the_gauge_holds_the_direction_written_by_hand() {
        let task = Task::new(SumOfTwo::new(Constraints::default()));
        let reference = [0.0; 3];
        let g = gauge(&task, &reference, &reference, TOLERANCE).expect("a gauge");
        assert_eq!(g.held.len(), 1);
        let h = &g.held[0];
        let half = std::f64::consts::FRAC_1_SQRT_2;
        let sign = h.direction[0].signum();
        for (d, want) in h.direction.iter().zip([half, -half, 0.0]) {
            assert!((d * sign - want).abs() < 1e-12, "{:?}", h.direction);
        }
        assert!(h.relative_curvature < 1e-12, "{}", h.relative_curvature);
        let mut coeffs = h.constraint.coeffs.clone();
        coeffs.retain(|(_, c)| c.abs() > 1e-12);
        let coeffs: Vec<(usize, f64)> = coeffs.iter().map(|&(j, c)| (j, c * sign)).collect();
        assert_eq!(coeffs.len(), 2, "{coeffs:?}");
        assert_eq!(coeffs[0].0, 0);
        assert!((coeffs[0].1 - 1.0).abs() < 1e-12 && (coeffs[1].1 + 1.0).abs() < 1e-12);
        assert_eq!(h.constraint.rhs, 0.0);
        // (1, 0, 0) is (½, ½, 0) on the gauge: the same sum a + b, a − b = 0.
        let p = g.project(&[1.0, 0.0, 0.3]);
        for (v, want) in p.iter().zip([0.5, 0.5, 0.3]) {
            assert!((v - want).abs() < 1e-12, "{p:?}");
        }
        assert!(g.offsets(&p)[0].abs() < 1e-12);
        assert!((g.offsets(&[1.0, 0.0, 0.3])[0] * sign - half).abs() < 1e-12);
    }

    /// A constraint that fixes b leaves nothing unidentified: no direction is held, and the
    /// tasks it applies to keep their own constraints only.
    #[test]
    fn a_fixed_parameter_leaves_nothing_to_hold() {
        let constraints = Constraints {
            rows: vec![Constraint {
                kind: ConstraintKind::Fixed,
                label: "b held".into(),
                coeffs: vec![(1, 1.0)],
                rhs: 0.0,
            }],
        };
        let task = Task::new(SumOfTwo::new(constraints));
        let reference = [0.0; 3];
        let g = gauge(&task, &reference, &reference, TOLERANCE).expect("a gauge");
        assert!(g.held.is_empty());
        assert_eq!(g.apply(&task).constraints.rows.len(), 1);
        assert_eq!(g.project(&[1.0, 0.0, 0.3]), vec![1.0, 0.0, 0.3]);
    }

    /// 1 µrad over the lever is 1 µm: 1e-6 rad × 1000 mm = 1e-3 mm.
    #[test]
    fn the_lever_weighs_a_microradian_as_a_micrometre() {
        assert_eq!(LEVER_MM, 1000.0);
        assert!((1e-6 * LEVER_MM - 1e-3).abs() < 1e-18);
    }
}
