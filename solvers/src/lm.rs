//! The native Levenberg–Marquardt engine on `faer`.
//!
//! * **Row blocks.** Each pass runs over the points in blocks of [`BLOCK`] points; no dense
//!   Jacobian of the whole problem is kept. For Φ the block's weighted Jacobian rows (3 per
//!   point) are multiplied into the lower triangle of `JᵀWJ`; for least squares (ve) they update
//!   the triangular factor R of the rows by a QR of `[R; block]` (a sequential QR), with the
//!   residuals as one more column.
//! * **Scaling.** Parameters are scaled by the inverse column norms of the starting Jacobian, so
//!   millimetres and radians (whose columns differ by the lever arms, ~10³) weigh alike.
//! * **Constraints** by null-space elimination in the scaled coordinates: `p = D (s₀ + N z)`,
//!   with z free ([`crate::nullspace`]). Each step is added to the parameters themselves
//!   (`p + D N δ`), so a parameter that travels far keeps its absolute precision.
//! * **Steps** solve `(H + λ M) δ = −g`, M the largest diagonal of H seen in the step's
//!   coordinates (Moré's scaling, as MINPACK): by Cholesky (an SVD pseudo-inverse if it fails)
//!   for Φ; for least squares as `min ‖R δ + c‖² + λ‖M^½ δ‖²` by QR, which keeps the Jacobian's
//!   condition number instead of its square. The damping follows Nielsen's rule on the gain
//!   ratio.
//! * **Geodesic acceleration** ([`Options::geodesic_acceleration`], off by default): the step
//!   `δ + a/2` with `a = −(H + λM)⁻¹ Jᵀ W r''(δ, δ)`, the exact second directional derivative of
//!   the residuals by second-order duals; a step whose correction is too large is refused.
//! * **Unidentifiable directions** (curvature below [`Options::rank_tolerance`] of the largest)
//!   are read from the design, the unweighted normal matrix (current for ve; refreshed at each
//!   IRLS stage for Φ), and steps stay in the span of the others. A zero tolerance holds
//!   nothing.
//! * **Refinement** (least squares, nothing held): after convergence, undamped Gauss–Newton
//!   steps from the QR factor, while they contract and the cost is no worse than its rounding.
//! * **Objectives.** ve (eq. 1) is plain least squares. Φ (eq. 12) is minimised on the
//!   smoothed objective `Φ_ε = (1/n) Σ √(‖r_i‖² + ε²)` in two stages. The *majorising* stage
//!   weights point i by `1/√(‖r_i‖² + ε²)` with its full curvature `J_iᵀJ_i`: that quadratic
//!   model lies above Φ_ε, so its steps lower Φ whatever their size (iteratively reweighted
//!   least squares as a majorise–minimise method), with ε = [`Options::irls_initial_epsilon`] ×
//!   the current Φ. Once a step gains less than 1e-6 of the cost, the *Newton* stage takes over
//!   with ε = [`Options::irls_final_epsilon`] × Φ and the radial curvature reduced by
//!   `‖r_i‖²/(‖r_i‖² + ε²)` (Ceres' Triggs correction), the exact Gauss–Newton model of Φ_ε;
//!   only there do the convergence criteria stop the run. Φ_ε − Φ ≤ ε, so the final Φ is exact
//!   to that fraction.
//!
//! ```
//! use volver_core::machine::Machine;
//! use volver_core::model::ErrorModelSpec;
//! use volver_core::noise::TrackerNoise;
//! use volver_core::plan::Plan;
//! use volver_core::problem::Problem;
//! use volver_core::simulate::{Magnitudes, Simulation, Truth};
//! use volver_solvers::{lm::LevenbergMarquardt, Options, Silent, Solver, Task};
//! let m = Machine::default_xcfz();
//! let truth = Truth::random(&m, &ErrorModelSpec::complete(&m), &Magnitudes::default(), 1).unwrap();
//! let mut sim = Simulation::new(Plan::preset(&m, "test3").unwrap(), truth, 1);
//! sim.noise = TrackerNoise::NONE;
//! let data = sim.run().unwrap().measurements;
//! let model = volver_core::model::Model::default_xcfz();
//! let problem = Problem::new(&model, &data).unwrap();
//! let sol = LevenbergMarquardt.solve(&Task::new(problem), &model.initial_params(),
//!                                    &Options::default(), &mut Silent);
//! assert!(sol.summary.termination.converged());
//! assert!(sol.summary.final_.stats.emm_um < 1e-6 * sol.summary.initial.stats.emm_um);
//! ```

use crate::free::{Begun, begin, cost_of, weight_of};
use crate::nullspace::NullSpace;
use crate::options::{ACCELERATION_RATIO, Objective, Options};
use crate::summary::Termination;
use crate::{Iteration, Observer, Solution, Solver, Task};
use faer::linalg::matmul::triangular::{BlockStructure, matmul as triangular_matmul};
use faer::prelude::*;
use faer::{Accum, Mat, Par, Side};
use volver_core::problem::{Problem, norm};

/// Points per block of the normal-equation accumulation.
pub const BLOCK: usize = 512;

/// The majorising stage of a Φ fit hands over to Newton once a step gains less than this
/// fraction of the cost.
const MAJORISING_GAIN: f64 = 1e-6;

/// Gauss–Newton refinements of a converged least-squares fit, at most.
const REFINEMENTS: usize = 100;

/// The native engine (always available).
#[derive(Clone, Copy, Debug, Default)]
pub struct LevenbergMarquardt;

/// Normal equations of one pass at a point: `H` and `g`, and on request the triangular factor
/// they come from.
pub(crate) struct Normal {
    pub(crate) h: Mat<f64>,
    pub(crate) g: Vec<f64>,
    /// With `factor`: see [`Factor`].
    pub(crate) factor: Option<Factor>,
}

/// The triangular factor of a pass, for plain least squares (no radial correction on any
/// point).
pub(crate) struct Factor {
    /// R (n × n) of the weighted Jacobian rows `W^½ J`, accumulated block by block (a
    /// sequential QR: only R is kept, never the rows): `H = RᵀR`.
    pub(crate) r: Mat<f64>,
    /// `c = Qᵀ W^½ r`: the cost's quadratic model is `½‖R δ + c‖²` up to a constant and
    /// `g = Rᵀ c`. Solving with R and c instead of H and g keeps the condition number of the
    /// Jacobian instead of its square (as MINPACK and Ceres' dense QR do).
    pub(crate) c: Vec<f64>,
}

/// `H = Σ J_iᵀ W_i J_i` and `g = Σ w_i J_iᵀ r_i`, where `weight(‖r_i‖)` gives `(w_i, c_i)` and
/// `W_i = w_i (I − c_i r̂_i r̂_iᵀ)` (the exact Gauss–Newton Hessian of the loss on each point:
/// `c = 0` for ve; for Φ_ε the radial direction carries less curvature than the tangential ones,
/// Ceres' "Triggs correction"). H is accumulated block by block from the rows `W_i^½ J_i`:
/// with `factor` (least squares only) as `RᵀR`, R updated by a QR of `[R; block]`, else by a
/// rank-k update. `None` when a residual or Jacobian entry is not finite, or when `factor` is
/// asked of a pass that is not plain least squares.
pub(crate) fn accumulate(
    problem: &Problem,
    p: &[f64],
    weight: impl Fn(f64) -> (f64, f64),
    factor: bool,
) -> Option<Normal> {
    let n = p.len();
    let np = problem.n_points();
    let mut g = vec![0.0; n];
    let mut h = Mat::<f64>::zeros(n, n);
    // With `factor`: R and the residual column (column-major, (n+1)²). A block's rows
    // (column-major, the weighted residuals in column n).
    let nc = n + 1;
    let mut rf = vec![0.0; if factor { nc * nc } else { 0 }];
    let mut blk = vec![0.0; 3 * BLOCK * nc];
    let mut row = vec![0.0; 3 * n];
    let mut start = 0;
    while start < np {
        let m = (np - start).min(BLOCK);
        let rows = 3 * m;
        for b in 0..m {
            let r = problem.residual_and_jacobian(start + b, p, &mut row);
            let nr = norm(r);
            if !nr.is_finite() || row.iter().any(|v| !v.is_finite()) {
                return None;
            }
            let (w, c) = weight(nr);
            if factor && c != 0.0 {
                return None;
            }
            // W^½ = √w (I − k r̂ r̂ᵀ) with (1 − k)² = 1 − c.
            let k = 1.0 - (1.0 - c).max(0.0).sqrt();
            let rhat = if nr > 0.0 {
                r.map(|v| v / nr)
            } else {
                [0.0; 3]
            };
            let sw = w.sqrt();
            for j in 0..n {
                let col = [row[j], row[n + j], row[2 * n + j]];
                let radial = rhat[0] * col[0] + rhat[1] * col[1] + rhat[2] * col[2];
                g[j] += w * (col[0] * r[0] + col[1] * r[1] + col[2] * r[2]);
                for c in 0..3 {
                    blk[j * rows + 3 * b + c] = sw * (col[c] - k * rhat[c] * radial);
                }
            }
            if factor {
                for c in 0..3 {
                    blk[n * rows + 3 * b + c] = sw * r[c];
                }
            }
        }
        if factor {
            qr_update(&mut rf, nc, &mut blk[..rows * nc], rows);
        } else {
            let jv =
                faer::MatRef::from_column_major_slice(&blk[..rows * nc], rows, nc).subcols(0, n);
            triangular_matmul(
                h.as_mut(),
                BlockStructure::TriangularLower,
                Accum::Add,
                jv.transpose(),
                BlockStructure::Rectangular,
                jv,
                BlockStructure::Rectangular,
                1.0,
                Par::Seq,
            );
        }
        start += m;
    }
    let factor = factor.then(|| {
        let r = Mat::from_fn(n, n, |i, j| rf[j * nc + i]);
        h = r.transpose() * &r;
        Factor {
            r,
            c: (0..n).map(|i| rf[n * nc + i]).collect(),
        }
    });
    for j in 0..n {
        for i in 0..j {
            h[(i, j)] = h[(j, i)];
        }
    }
    Some(Normal { h, g, factor })
}

/// `Σ aᵢ bᵢ` with four running sums (so that the loop vectorises).
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0; 4];
    let (ac, bc) = (a.chunks_exact(4), b.chunks_exact(4));
    let tail: f64 = ac
        .remainder()
        .iter()
        .zip(bc.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ac.zip(bc) {
        for k in 0..4 {
            acc[k] += x[k] * y[k];
        }
    }
    acc[0] + acc[1] + acc[2] + acc[3] + tail
}

/// One step of a sequential QR: the upper-triangular `r` (`nc` × `nc`, column-major) becomes
/// the R factor of `[r; b]`, where `b` holds `rows` rows (column-major); `b` is overwritten.
/// Householder reflections that exploit r's zeros: only row j of r and the block change when
/// column j is eliminated, so the cost is about twice that of adding `bᵀb` to a normal matrix.
fn qr_update(r: &mut [f64], nc: usize, b: &mut [f64], rows: usize) {
    for j in 0..nc {
        let (left, right) = b.split_at_mut((j + 1) * rows);
        let x = &mut left[j * rows..];
        let sigma = dot(x, x);
        if sigma == 0.0 {
            continue;
        }
        let x0 = r[j * nc + j];
        let alpha = -x0.signum() * (x0 * x0 + sigma).sqrt();
        let v0 = x0 - alpha;
        let beta = 2.0 / (v0 * v0 + sigma);
        r[j * nc + j] = alpha;
        for col in j + 1..nc {
            let y = &mut right[(col - j - 1) * rows..(col - j) * rows];
            let rj = &mut r[col * nc + j];
            let s = beta * (v0 * *rj + dot(x, y));
            *rj -= s * v0;
            for (yi, xi) in y.iter_mut().zip(x.iter()) {
                *yi -= s * xi;
            }
        }
        x.iter_mut().for_each(|v| *v = 0.0);
    }
}

/// The Gauss–Newton normal equations of `½ Σ ‖r_i‖²` at `params`: `JᵀJ` (n × n) and `Jᵀr`,
/// accumulated over row blocks of [`BLOCK`] points exactly as the native engine forms them (no
/// dense Jacobian is held). `None` when a residual or Jacobian entry is not finite. For
/// identifiability studies and benchmarks.
///
/// ```
/// use volver_core::{model::Model, plan::Plan, problem::Problem};
/// use volver_core::simulate::{Magnitudes, Simulation, Truth};
/// let m = volver_core::machine::Machine::default_xcfz();
/// let truth = Truth::random_complete(&m, &Magnitudes::default(), 1).unwrap();
/// let data = Simulation::new(Plan::preset(&m, "test3").unwrap(), truth, 1).run().unwrap().measurements;
/// let model = Model::default_xcfz();
/// let problem = Problem::new(&model, &data).unwrap();
/// let (jtj, jtr) = volver_solvers::lm::normal_equations(&problem, &model.initial_params()).unwrap();
/// assert_eq!((jtj.nrows(), jtr.len()), (model.n_params(), model.n_params()));
/// ```
pub fn normal_equations(problem: &Problem, params: &[f64]) -> Option<(Mat<f64>, Vec<f64>)> {
    accumulate(problem, params, |_| (1.0, 0.0), false).map(|n| (n.h, n.g))
}

/// Column scaling `D` (inverse column norms of the Jacobian, from the diagonal of `JᵀJ`; 1 for
/// a parameter the data do not see) and the null space of the constraints in the scaled
/// coordinates `s = p / D`, anchored at `anchor`.
pub(crate) fn scaled_null_space(
    h: &Mat<f64>,
    constraints: &volver_core::model::Constraints,
    anchor: &[f64],
) -> (
    Vec<f64>,
    Result<NullSpace, crate::nullspace::ConstraintError>,
) {
    let n = anchor.len();
    // A column at rounding level (a sinusoid the mesh samples only at its zeros) must not be
    // blown up to unit norm: column norms are floored at 1e-12 of the largest.
    let cmax = (0..n).map(|j| h[(j, j)]).fold(0.0_f64, f64::max);
    let d: Vec<f64> = (0..n)
        .map(|j| {
            let c = h[(j, j)].max(1e-24 * cmax);
            if c > 0.0 { 1.0 / c.sqrt() } else { 1.0 }
        })
        .collect();
    let (a, b) = constraints.dense(n);
    let a_scaled: Vec<f64> = (0..b.len() * n).map(|k| a[k] * d[k % n]).collect();
    let anchor_scaled: Vec<f64> = anchor.iter().zip(&d).map(|(p, d)| p / d).collect();
    let ns = NullSpace::new(&a_scaled, &b, &anchor_scaled);
    (d, ns)
}

/// The least-squares normal equations of a task at `params`, reduced to the scaled free
/// coordinates: `p = D (s₀ + N z)`, `H_z = Nᵀ D JᵀJ D N`, `g_z = Nᵀ D Jᵀ r`.
pub(crate) struct Reduced {
    /// Column scaling D.
    pub(crate) d: Vec<f64>,
    /// Null space of the scaled constraints.
    pub(crate) ns: NullSpace,
    /// Reduced normal matrix.
    pub(crate) hz: Mat<f64>,
    /// Reduced gradient of ½‖r‖².
    pub(crate) gz: Vec<f64>,
}

/// [`Reduced`] normal equations; `None` when the Jacobian is not finite or the constraints
/// cannot be eliminated.
pub(crate) fn reduced_normal(task: &crate::Task, params: &[f64]) -> Option<Reduced> {
    let n = params.len();
    let normal = accumulate(&task.problem, params, |_| (1.0, 0.0), false)?;
    let (d, ns) = scaled_null_space(&normal.h, &task.constraints, params);
    let ns = ns.ok()?;
    let nf = ns.n_free();
    let basis = ns.basis();
    let hs = Mat::from_fn(n, n, |i, j| d[i] * normal.h[(i, j)] * d[j]);
    let hz = basis.transpose() * (&hs * basis);
    let gz: Vec<f64> = (0..nf)
        .map(|k| (0..n).map(|i| basis[(i, k)] * d[i] * normal.g[i]).sum())
        .collect();
    Some(Reduced { d, ns, hz, gz })
}

/// The design's curvatures (ascending, Marquardt-scaled) and their directions in the free
/// coordinates z, from a normal matrix `h` in the parameters.
fn design_of(free: &crate::free::Free, h: &Mat<f64>) -> Option<(Vec<f64>, Mat<f64>)> {
    let n = h.nrows();
    let dv = &free.d;
    let basis = free.ns.basis();
    let hs = Mat::from_fn(n, n, |i, j| dv[i] * h[(i, j)] * dv[j]);
    design_from_reduced(&(basis.transpose() * (&hs * basis)))
}

/// [`design_of`] from the reduced normal matrix `H_z`.
pub(crate) fn design_from_reduced(h0: &Mat<f64>) -> Option<(Vec<f64>, Mat<f64>)> {
    let nf = h0.nrows();
    let dmax = (0..nf).map(|i| h0[(i, i)]).fold(0.0_f64, f64::max);
    let s0: Vec<f64> = (0..nf)
        .map(|i| 1.0 / h0[(i, i)].max(1e-12 * dmax).max(1e-300).sqrt())
        .collect();
    let hp0 = Mat::from_fn(nf, nf, |i, j| s0[i] * h0[(i, j)] * s0[j]);
    let evd = hp0.self_adjoint_eigen(Side::Lower).ok()?;
    let mu: Vec<f64> = (0..nf).map(|i| evd.S().column_vector()[i]).collect();
    let u = evd.U();
    // Directions in z: S₀ v.
    Some((mu, Mat::from_fn(nf, nf, |k, i| s0[k] * u[(k, i)])))
}

/// Geodesic acceleration's right-hand side in the free coordinates z: `Nᵀ D Σ J_iᵀ W_i r_i''`,
/// where `r_i''` is the exact second derivative of residual i along the step `delta` (z) and
/// `W_i` its Gauss–Newton weight (as in [`accumulate`]). One Jacobian and one second-derivative
/// pass; `None` when a value is not finite.
fn curvature_gradient(
    problem: &Problem,
    free: &crate::free::Free,
    p: &[f64],
    delta: &[f64],
    objective: Objective,
    eps: f64,
) -> Option<Vec<f64>> {
    let n = p.len();
    let np = problem.n_points();
    let basis = free.ns.basis();
    let nf = basis.ncols();
    let dir: Vec<f64> = (0..n)
        .map(|i| free.d[i] * (0..nf).map(|k| basis[(i, k)] * delta[k]).sum::<f64>())
        .collect();
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

/// The damped least-squares step `argmin ‖R' y + c‖² + λ‖y‖²` by a QR of `[R'; √λ I]`, and that
/// QR's triangular factor `R_λ` (`R_λᵀ R_λ = R'ᵀR' + λI`); `None` if not finite.
fn damped_lstsq(rps: &Mat<f64>, c: &[f64], lambda: f64) -> Option<(Vec<f64>, Mat<f64>)> {
    let (n, nr) = (rps.nrows(), rps.ncols());
    let sl = lambda.sqrt();
    let a = Mat::from_fn(n + nr, nr, |i, j| {
        if i < n {
            rps[(i, j)]
        } else if i - n == j {
            sl
        } else {
            0.0
        }
    });
    let b = Mat::from_fn(n + nr, 1, |i, _| if i < n { -c[i] } else { 0.0 });
    let qr = a.qr();
    let y = qr.solve_lstsq(&b);
    let y: Vec<f64> = (0..nr).map(|i| y[(i, 0)]).collect();
    let rl = qr.thin_R().to_owned();
    y.iter().all(|v| v.is_finite()).then_some((y, rl))
}

/// `(R_λᵀ R_λ)⁻¹ rhs` by two triangular solves; `None` if not finite.
fn normal_solve(rl: &Mat<f64>, rhs: &[f64]) -> Option<Vec<f64>> {
    use faer::linalg::triangular_solve::{
        solve_lower_triangular_in_place, solve_upper_triangular_in_place,
    };
    let k = rhs.len();
    let mut x = Mat::from_fn(k, 1, |i, _| rhs[i]);
    solve_lower_triangular_in_place(rl.transpose(), x.as_mut(), Par::Seq);
    solve_upper_triangular_in_place(rl.as_ref(), x.as_mut(), Par::Seq);
    let x: Vec<f64> = (0..k).map(|i| x[(i, 0)]).collect();
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Solves `a x = rhs` for symmetric positive semi-definite `a`: Cholesky, or an SVD
/// pseudo-inverse that drops directions below 1e-14 of the largest singular value.
fn solve_spd(a: &Mat<f64>, rhs: &[f64]) -> Option<Vec<f64>> {
    let k = rhs.len();
    let b = Mat::from_fn(k, 1, |i, _| rhs[i]);
    if let Ok(llt) = a.llt(Side::Lower) {
        let x = llt.solve(&b);
        let v: Vec<f64> = (0..k).map(|i| x[(i, 0)]).collect();
        if v.iter().all(|x| x.is_finite()) {
            return Some(v);
        }
    }
    let svd = a.svd().ok()?;
    let (u, s, v) = (svd.U(), svd.S().column_vector(), svd.V());
    let smax = (0..k).map(|i| s[i]).fold(0.0, f64::max);
    let mut x = vec![0.0; k];
    for r in 0..k {
        if s[r] > 1e-14 * smax {
            let c = (0..k).map(|i| u[(i, r)] * rhs[i]).sum::<f64>() / s[r];
            for (j, xj) in x.iter_mut().enumerate() {
                *xj += v[(j, r)] * c;
            }
        }
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

impl Solver for LevenbergMarquardt {
    fn name(&self) -> &'static str {
        "lm"
    }

    fn solve(
        &self,
        task: &Task,
        start: &[f64],
        options: &Options,
        observer: &mut dyn Observer,
    ) -> Solution {
        let Begun {
            mut run,
            free,
            first,
            p0: mut p,
            norms0: mut norms,
        } = match begin(self.name(), task, start, options) {
            Ok(b) => b,
            Err(solution) => return *solution,
        };
        let problem = &task.problem;
        let n = problem.n_params();
        let objective = options.objective;
        let nf = free.n_free();
        // A gauge's rows are dense combinations of every parameter, so the free coordinates z
        // mix them all and a diagonal damping in z has no meaning (measured on test 3: 214
        // iterations instead of 42). Steps are then taken in the design's directions, as when
        // some are held.
        let dense_rows = task
            .constraints
            .rows
            .iter()
            .any(|r| r.kind == volver_core::model::ConstraintKind::Gauge);
        // The step's distance from the start in the scaled free coordinates (the parameter
        // criterion's scale); the parameters themselves are stepped from p (Free::step).
        let mut z = vec![0.0; nf];
        // What the data cannot identify is a property of the design: it is read from the
        // unweighted normal matrix (Marquardt-scaled, eigen-decomposed), not from the
        // IRLS-weighted matrices of a Φ fit, whose weights spread the curvatures by up to Φ/ε and
        // would hide identifiable directions near its end. For ve the current matrix is the
        // design; for Φ it is refreshed at the start of every IRLS stage (a nonlinear basis,
        // such as a sine's phase at zero amplitude, becomes identifiable as the fit moves).
        let Some(mut design) = design_of(&free, &first.h) else {
            return run.finish(
                p,
                Termination::NumericalFailure(
                    "the eigen-decomposition of the design's normal matrix failed".into(),
                ),
            );
        };
        let mut refresh = false;

        let phi0 = norms.iter().sum::<f64>() / norms.len() as f64;
        let eps_final = |phi: f64| (options.irls_final_epsilon * phi).max(1e-300);
        let eps_first = |phi: f64| (options.irls_initial_epsilon * phi).max(1e-300);
        // Φ runs in two stages. First the majorising stage: weights 1/√(‖r_i‖² + ε²) with the
        // full curvature JᵢᵀJᵢ on every point (no radial reduction), whose quadratic model lies
        // above Φ_ε everywhere (‖r‖ ≤ (‖r‖² + ‖r₀‖²)/(2‖r₀‖)), so that its steps decrease Φ
        // whatever their size: no step is refused while the fit is far from the minimum. ε
        // follows Φ (ε = irls_initial_epsilon · Φ) and only bounds the weight of a point whose
        // residual nearly vanishes. Its convergence is linear: once a step gains less than
        // MAJORISING_GAIN of the cost, the Newton stage takes over: ε = irls_final_epsilon · Φ
        // and the exact Gauss–Newton model of Φ_ε (the radial curvature reduced by
        // ‖r‖²/(‖r‖² + ε²), Ceres' Triggs correction), which converges fast near the minimum;
        // the convergence criteria stop the run only there. Least squares has one stage.
        let mut newton = objective == Objective::Ve;
        let mut eps = eps_first(phi0);
        let mut cost = cost_of(objective, &norms, eps);
        let cost0 = cost;
        let mut lambda = options.initial_damping;
        let mut nu = 2.0;
        let mut dmax: Vec<f64> = Vec::new();
        let mut reset_scale = false;
        let mut scale_coords: Option<(usize, usize)> = None;
        let mut design_generation = 0_usize;
        let np = problem.n_points();
        let termination = 'outer: loop {
            // One Jacobian pass at the current point.
            if run.summary.evaluations >= options.max_evaluations {
                break Termination::EvaluationLimit;
            }
            if refresh && objective == Objective::Phi {
                refresh = false;
                let refreshed = accumulate(problem, &p, |_| (1.0, 0.0), false)
                    .and_then(|h| design_of(&free, &h.h));
                run.summary.evaluations += 1;
                run.summary.jacobian_evaluations += 1;
                match refreshed {
                    Some(d) => {
                        design = d;
                        design_generation += 1;
                    }
                    None => {
                        break Termination::NumericalFailure(format!(
                            "the design's normal matrix failed at iteration {}",
                            run.summary.iterations
                        ));
                    }
                }
            }
            if !newton {
                // The majorising stage's ε follows Φ.
                eps = eps_first(norms.iter().sum::<f64>() / np as f64);
                cost = cost_of(objective, &norms, eps);
            }
            let Some(normal) = accumulate(
                problem,
                &p,
                |r| {
                    let (w, c) = weight_of(objective, r, eps, np);
                    (w, if newton { c } else { 0.0 })
                },
                objective == Objective::Ve,
            ) else {
                break Termination::NumericalFailure(format!(
                    "the Jacobian is not finite at iteration {}",
                    run.summary.iterations
                ));
            };
            run.summary.evaluations += 1;
            run.summary.jacobian_evaluations += 1;
            // Reduce to the free coordinates: Hz = Nᵀ D H D N, gz = Nᵀ D g.
            let dv = &free.d;
            let hs = Mat::from_fn(n, n, |i, j| dv[i] * normal.h[(i, j)] * dv[j]);
            let basis = free.ns.basis();
            let t = &hs * basis;
            let hz = basis.transpose() * &t;
            let gz: Vec<f64> = (0..nf)
                .map(|k| (0..n).map(|i| basis[(i, k)] * dv[i] * normal.g[i]).sum())
                .collect();
            let gmax = gz.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
            if newton && (cost == 0.0 || gmax <= options.gradient_tolerance * cost0) {
                break Termination::Gradient;
            }
            // Directions whose design curvature is below rank_tolerance × the largest are not
            // identifiable from the data: steps stay in the span q of the others. The
            // Gauss–Newton model neglects Σ r_i ∇²r_i, which grows with the residuals: once Φ is
            // below 1e-4 Φ_start (a nearly exact fit, where that model is exact too) the
            // tolerance relaxes in proportion, so such a fit may use every direction.
            let phi_now = norms.iter().sum::<f64>() / np as f64;
            let tolerance = options.rank_tolerance * (1e4 * phi_now / phi0).min(1.0);
            if objective == Objective::Ve {
                // Uniform weights: the current matrix is the design.
                let Some(d) = design_from_reduced(&hz) else {
                    break Termination::NumericalFailure(format!(
                        "the eigen-decomposition of the normal matrix failed at iteration {}",
                        run.summary.iterations
                    ));
                };
                design = d;
                design_generation += 1;
            }
            let (mu0, dirs0) = (&design.0, &design.1);
            let mu0_max = mu0[nf - 1].max(0.0);
            // A zero tolerance holds nothing (not even a direction whose curvature rounds to ≤ 0).
            let keep: Vec<usize> = (0..nf)
                .filter(|&i| tolerance == 0.0 || mu0[i] > tolerance * mu0_max)
                .collect();
            run.summary.unidentifiable = nf - keep.len();
            let q = (keep.len() < nf || dense_rows)
                .then(|| Mat::from_fn(nf, keep.len(), |k, c| dirs0[(k, keep[c])]));
            let (hq, gq) = match &q {
                None => (hz.clone(), gz.clone()),
                Some(q) => {
                    let hq = q.transpose() * (&hz * q);
                    let gq: Vec<f64> = (0..q.ncols())
                        .map(|c| (0..nf).map(|k| q[(k, c)] * gz[k]).sum())
                        .collect();
                    (hq, gq)
                }
            };
            // Damping: λ M with M the diagonal of the largest diag(H) seen in the step's
            // coordinates (Moré's scaling, as MINPACK: it never shrinks, so a parameter whose
            // column fades as the fit runs into a flat region is still damped at its earlier
            // scale). The maximum runs while the coordinates stay the same: z, or the span q of
            // the identifiable design directions until the design is refreshed (every iteration
            // for ve, every IRLS stage for Φ); a new IRLS stage also restarts it (a new cost).
            let nr = gq.len();
            let coords = q.as_ref().map(|_| (design_generation, nr));
            if reset_scale || coords != scale_coords || dmax.len() != nr {
                reset_scale = false;
                scale_coords = coords;
                dmax = vec![0.0; nr];
            }
            for (i, v) in dmax.iter_mut().enumerate() {
                *v = (*v).max(hq[(i, i)]);
            }
            // A direction the data have never seen is damped at unit scale (MINPACK's rule); no
            // floor relative to the others, whose curvatures may legitimately span 10²⁰ along
            // the path of a strongly nonlinear model (MGH10).
            // Scaled by S = M^-½: H' = S H S, g' = S g, and the damping is λ I.
            let sc: Vec<f64> = dmax
                .iter()
                .map(|&v| 1.0 / if v > 0.0 { v } else { 1.0 }.sqrt())
                .collect();
            let hp = Mat::from_fn(nr, nr, |i, j| sc[i] * hq[(i, j)] * sc[j]);
            let gp: Vec<f64> = (0..nr).map(|i| sc[i] * gq[i]).collect();
            // Least squares: the factor in the same coordinates, R_z = R D N and R' = R_z Q S,
            // so that each step solves min ‖R' y + c‖² + λ‖y‖² by QR.
            let factor = normal.factor.as_ref().map(|f| {
                let rd = Mat::from_fn(n, n, |i, j| f.r[(i, j)] * dv[j]);
                let rz = &rd * basis;
                let rq = match &q {
                    None => rz.clone(),
                    Some(q) => &rz * q,
                };
                let rps = Mat::from_fn(n, nr, |i, j| rq[(i, j)] * sc[j]);
                (rz, rps, &f.c)
            });
            // From the scaled span coordinates back to z.
            let to_z = |y: &[f64]| -> Vec<f64> {
                let y: Vec<f64> = y.iter().zip(&sc).map(|(y, s)| y * s).collect();
                match &q {
                    None => y,
                    Some(q) => (0..nf)
                        .map(|k| (0..nr).map(|c| q[(k, c)] * y[c]).sum())
                        .collect(),
                }
            };
            // Try steps until one is accepted or a criterion stops the run.
            loop {
                if run.summary.iterations >= options.max_iterations {
                    break 'outer Termination::IterationLimit;
                }
                if run.summary.iterations > 0 && run.summary.evaluations >= options.max_evaluations
                {
                    break 'outer Termination::EvaluationLimit;
                }
                run.summary.iterations += 1;
                // Cholesky of the damped system (an SVD pseudo-inverse if it fails).
                let damped = Mat::from_fn(nr, nr, |i, j| {
                    hp[(i, j)] + if i == j { lambda } else { 0.0 }
                });
                let rhs: Vec<f64> = gp.iter().map(|g| -g).collect();
                // With the factor: the QR of [R'; √λ I], whose R_λ also gives (H' + λI)⁻¹ for
                // the acceleration; else Cholesky of the damped normal matrix.
                let lsq = factor
                    .as_ref()
                    .and_then(|(_, rps, c)| damped_lstsq(rps, c, lambda));
                let y = match &lsq {
                    Some((y, _)) => y.clone(),
                    None => solve_spd(&damped, &rhs).unwrap_or_else(|| vec![f64::NAN; nr]),
                };
                let delta = to_z(&y);
                if delta.iter().any(|v| !v.is_finite()) {
                    break 'outer Termination::NumericalFailure(format!(
                        "the step is not finite at iteration {}",
                        run.summary.iterations
                    ));
                }
                // Geodesic acceleration: a = −(H + λM)⁻¹ Jᵀ W r''(δ, δ); the step is δ + a/2,
                // refused (as a failed step) when 2‖a‖ > α‖δ‖ in the damping norm.
                let mut total = delta.clone();
                if options.geodesic_acceleration {
                    let ynorm = y.iter().map(|v| v * v).sum::<f64>().sqrt();
                    let accel = (ynorm > 0.0)
                        .then(|| curvature_gradient(problem, &free, &p, &delta, objective, eps))
                        .flatten();
                    run.summary.evaluations += 1;
                    run.summary.jacobian_evaluations += 1;
                    let Some(bz) = accel else {
                        break 'outer Termination::NumericalFailure(format!(
                            "the second derivative along the step is not finite at iteration {}",
                            run.summary.iterations
                        ));
                    };
                    let bq: Vec<f64> = match &q {
                        None => bz,
                        Some(q) => (0..nr)
                            .map(|c| (0..nf).map(|k| q[(k, c)] * bz[k]).sum())
                            .collect(),
                    };
                    let rhs: Vec<f64> = bq.iter().zip(&sc).map(|(b, s)| -b * s).collect();
                    let ya = match &lsq {
                        Some((_, rl)) => normal_solve(rl, &rhs),
                        None => solve_spd(&damped, &rhs),
                    }
                    .unwrap_or_else(|| vec![f64::NAN; nr]);
                    let anorm = ya.iter().map(|v| v * v).sum::<f64>().sqrt();
                    // A NaN ratio refuses the step too.
                    let small_enough = 2.0 * anorm <= ACCELERATION_RATIO * ynorm;
                    if !small_enough {
                        observer.iteration(&Iteration {
                            iteration: run.summary.iterations,
                            evaluations: run.summary.evaluations,
                            cost,
                            emm_um: norms.iter().sum::<f64>() / np as f64 * 1e3,
                            damping: lambda,
                            step: delta.iter().map(|v| v * v).sum::<f64>().sqrt(),
                            accepted: false,
                        });
                        lambda *= nu;
                        nu *= 2.0;
                        if !lambda.is_finite() || lambda > 1e30 {
                            break 'outer Termination::NumericalFailure(format!(
                                "geodesic acceleration refused every step up to damping 1e30 at iteration {}",
                                run.summary.iterations
                            ));
                        }
                        continue;
                    }
                    for (t, a) in total.iter_mut().zip(to_z(&ya)) {
                        *t += 0.5 * a;
                    }
                }
                let step = total.iter().map(|v| v * v).sum::<f64>().sqrt();
                let znorm = z.iter().map(|v| v * v).sum::<f64>().sqrt();
                let small_step =
                    step <= options.parameter_tolerance * (znorm + options.parameter_tolerance);
                // Predicted decrease of the quadratic model along δ (the velocity; the
                // acceleration only bends the path): from the factor, −(cᵀv + ½‖v‖²) with
                // v = R_z δ, else from H_z and g_z.
                let pred = match &factor {
                    Some((rz, _, c)) => {
                        let v: Vec<f64> = (0..n)
                            .map(|i| (0..nf).map(|k| rz[(i, k)] * delta[k]).sum())
                            .collect();
                        -(0..n).map(|i| c[i] * v[i] + 0.5 * v[i] * v[i]).sum::<f64>()
                    }
                    None => {
                        let hd: Vec<f64> = (0..nf)
                            .map(|i| (0..nf).map(|j| hz[(i, j)] * delta[j]).sum())
                            .collect();
                        -(0..nf)
                            .map(|i| gz[i] * delta[i] + 0.5 * delta[i] * hd[i])
                            .sum::<f64>()
                    }
                };
                let p_new = free.step(&p, &total);
                let z_new: Vec<f64> = z.iter().zip(&total).map(|(a, b)| a + b).collect();
                let norms_new: Vec<f64> =
                    (0..np).map(|i| norm(problem.residual(i, &p_new))).collect();
                run.summary.evaluations += 1;
                let cost_new = cost_of(objective, &norms_new, eps);
                if !cost_new.is_finite() {
                    run.nonfinite_trial();
                }
                let rho = if cost_new.is_finite() && pred > 0.0 {
                    (cost - cost_new) / pred
                } else {
                    -1.0
                };
                let accepted = rho > 1e-4;
                if accepted {
                    run.improved();
                }
                observer.iteration(&Iteration {
                    iteration: run.summary.iterations,
                    evaluations: run.summary.evaluations,
                    cost: if accepted { cost_new } else { cost },
                    emm_um: if accepted {
                        norms_new.iter().sum::<f64>() / np as f64 * 1e3
                    } else {
                        norms.iter().sum::<f64>() / np as f64 * 1e3
                    },
                    damping: lambda,
                    step,
                    accepted,
                });
                if accepted {
                    let old = cost;
                    p = p_new;
                    z = z_new;
                    norms = norms_new;
                    cost = cost_new;
                    lambda *= (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0);
                    nu = 2.0;
                    let small_change = old - cost <= options.objective_tolerance * old;
                    let phi = norms.iter().sum::<f64>() / np as f64;
                    if newton && (small_step || small_change) {
                        break 'outer if small_step {
                            Termination::ParameterChange
                        } else {
                            Termination::ObjectiveChange
                        };
                    }
                    if !newton && (small_step || old - cost <= MAJORISING_GAIN * old) {
                        // The majorising stage has slowed down: Newton takes over.
                        newton = true;
                        eps = eps_final(phi);
                        refresh = true;
                        reset_scale = true;
                        cost = cost_of(objective, &norms, eps);
                    }
                    break;
                }
                lambda *= nu;
                nu *= 2.0;
                if small_step || !lambda.is_finite() || lambda > 1e30 {
                    let phi = norms.iter().sum::<f64>() / np as f64;
                    if newton {
                        break 'outer Termination::ParameterChange;
                    }
                    newton = true;
                    eps = eps_final(phi);
                    refresh = true;
                    reset_scale = true;
                    cost = cost_of(objective, &norms, eps);
                    lambda = options.initial_damping;
                    nu = 2.0;
                    break;
                }
            }
        };
        // Least squares: Gauss–Newton refinement of the converged point. The damped steps
        // stop once the cost can no longer tell better from worse (steps refused at rounding
        // raise λ until the step is negligible); the undamped steps from the QR factor go on to
        // the minimum (to the Jacobian's condition, not its square) while they contract and the
        // cost is no worse than its own rounding. Skipped when directions are held as
        // unidentifiable.
        if objective == Objective::Ve && termination.converged() && run.summary.unidentifiable == 0
        {
            // The cost's rounding: each residual is rounded to a few ε of its observation.
            let rounding = 8.0 * f64::EPSILON * 2.0 / np as f64
                * (0..np)
                    .map(|i| norms[i] * (norms[i] + problem.observation_scale(i)))
                    .sum::<f64>();
            let mut last_step = f64::INFINITY;
            for _ in 0..REFINEMENTS {
                if run.summary.iterations >= options.max_iterations
                    || run.summary.evaluations + 2 > options.max_evaluations
                {
                    break;
                }
                let Some(f) = accumulate(problem, &p, |r| weight_of(objective, r, eps, np), true)
                    .and_then(|normal| normal.factor)
                else {
                    break;
                };
                run.summary.evaluations += 1;
                run.summary.jacobian_evaluations += 1;
                run.summary.iterations += 1;
                let rz = &Mat::from_fn(n, n, |i, j| f.r[(i, j)] * free.d[j]) * free.ns.basis();
                let Some((dz, _)) = damped_lstsq(&rz, &f.c, 0.0) else {
                    break;
                };
                // Gauss–Newton converges linearly on a problem with residuals: go on while the
                // steps contract and are not negligible.
                let step = dz.iter().map(|v| v * v).sum::<f64>().sqrt();
                let znorm = z.iter().map(|v| v * v).sum::<f64>().sqrt();
                let contracting = step < last_step;
                if !contracting
                    || step <= options.parameter_tolerance * (znorm + options.parameter_tolerance)
                {
                    break;
                }
                last_step = step;
                let p_new = free.step(&p, &dz);
                let norms_new: Vec<f64> =
                    (0..np).map(|i| norm(problem.residual(i, &p_new))).collect();
                run.summary.evaluations += 1;
                let cost_new = cost_of(objective, &norms_new, eps);
                let accepted = cost_new <= cost + rounding;
                observer.iteration(&Iteration {
                    iteration: run.summary.iterations,
                    evaluations: run.summary.evaluations,
                    cost: if accepted { cost_new } else { cost },
                    emm_um: if accepted { &norms_new } else { &norms }
                        .iter()
                        .sum::<f64>()
                        / np as f64
                        * 1e3,
                    damping: 0.0,
                    step,
                    accepted,
                });
                if !accepted {
                    break;
                }
                z.iter_mut().zip(&dz).for_each(|(a, b)| *a += b);
                p = p_new;
                norms = norms_new;
                cost = cost_new;
            }
        }
        run.finish(p, termination)
    }
}
