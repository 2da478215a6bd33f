//! What the data can identify: rank and condition of the design after the constraints, the
//! standard uncertainty of every parameter (from the Jacobian and the residual variance),
//! parameter correlations, and the combinations of parameters the data cannot separate.
//!
//! The analysis works in the scaled, constraint-free coordinates of the engine
//! ([`crate::engines::lm`]): `p = D (s₀ + N z)` with `D` the inverse column norms of the Jacobian. The
//! normal matrix `H_z = Nᵀ D JᵀJ D N` is eigen-decomposed; directions whose curvature is below
//! `tolerance` × the largest are not identifiable and are reported by the parameters they
//! move. The covariance of the rest is `σ² H_z⁺` with `σ²` the residual variance per
//! coordinate, `Σ‖r‖² / (3n − rank)`, mapped back to the parameters.

use crate::Task;
use crate::engines::coordinates::{Reduced, reduced_normal};
use faer::Side;
use volver_core::model::{Constraint, ConstraintKind};
use volver_core::units::TINY;

/// A combination of parameters the data cannot identify.
#[derive(Clone, Debug, PartialEq)]
pub struct WeakDirection {
    /// Its curvature relative to the best-determined direction.
    pub relative_curvature: f64,
    /// The parameters it moves most (index, share of the scaled direction, sign included),
    /// largest first, shares above 0.1.
    pub parameters: Vec<(usize, f64)>,
    /// The whole direction in the scaled parameters `p_j / D_j` (unit length).
    pub scaled: Vec<f64>,
}

/// The identifiability of a model on a data set at a parameter vector.
#[derive(Clone, Debug, PartialEq)]
pub struct Identifiability {
    /// Free directions after the constraints.
    pub free: usize,
    /// Directions the data identify (curvature above the tolerance).
    pub rank: usize,
    /// Condition number of the scaled Jacobian over the identified directions.
    pub condition: f64,
    /// Condition number over every free direction (∞ when one is exactly redundant).
    pub condition_all: f64,
    /// Residual standard deviation per coordinate (mm).
    pub sigma_mm: f64,
    /// Standard uncertainty of every parameter in its unit (0 for held parameters); only the
    /// identified directions contribute.
    pub uncertainty: Vec<f64>,
    /// Pairs of parameters whose correlation exceeds the threshold: (i, j, correlation).
    pub correlations: Vec<(usize, usize, f64)>,
    /// The directions that are not identified, weakest first.
    pub weak: Vec<WeakDirection>,
    /// The parameters' scales `D` (the inverse column norms of the Jacobian): the scaled
    /// parameters are `p_j / D_j`.
    pub scale: Vec<f64>,
    /// A factor `F` of the parameters' covariance, `Cov(p) = F Fᵀ`: one column (length
    /// n_params, in the parameters' units) per identified direction. The standard uncertainty
    /// of any linear function `gᵀp` is `‖Fᵀg‖` — of an error function at a position, say.
    pub covariance_factor: Vec<Vec<f64>>,
}

impl Identifiability {
    /// `params` moved along the unidentified directions to the point nearest `reference` in
    /// the scaled parameters: the minimum-norm representative of the solutions the data cannot
    /// tell apart (every identified combination, every constraint and the fit are unchanged).
    pub fn minimum_norm(&self, params: &[f64], reference: &[f64]) -> Vec<f64> {
        let mut p = params.to_vec();
        for w in &self.weak {
            let c: f64 = (0..p.len())
                .map(|j| w.scaled[j] * (p[j] - reference[j]) / self.scale[j])
                .sum();
            for (j, v) in p.iter_mut().enumerate() {
                *v -= c * w.scaled[j] * self.scale[j];
            }
        }
        p
    }

    /// Standard uncertainty of the linear function `gᵀp` of the parameters (identified
    /// directions only).
    pub fn uncertainty_of(&self, g: &[f64]) -> f64 {
        self.covariance_factor
            .iter()
            .map(|c| c.iter().zip(g).map(|(a, b)| a * b).sum::<f64>().powi(2))
            .sum::<f64>()
            .sqrt()
    }
}

pub use crate::nullspace::RANK_TOLERANCE;

/// Analyses `task` (its problem and constraints) at `params`. `tolerance` is the relative
/// curvature below which a direction counts as not identified ([`RANK_TOLERANCE`] by
/// default); correlations above `correlation` in absolute
/// value are listed. `None` when the Jacobian is not finite or a decomposition fails.
pub fn analyse(
    task: &Task,
    params: &[f64],
    tolerance: f64,
    correlation: f64,
) -> Option<Identifiability> {
    let problem = &*task.problem;
    let n = params.len();
    let Reduced { d, ns, hz, .. } = reduced_normal(task, params)?;
    let nf = ns.n_free();
    let basis = ns.basis();
    let residual_sq: f64 = problem
        .residuals(params)
        .iter()
        .map(|r| r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
        .sum();
    if nf == 0 {
        return Some(Identifiability {
            free: 0,
            rank: 0,
            condition: 1.0,
            condition_all: 1.0,
            sigma_mm: (residual_sq / (3 * problem.n_points()) as f64).sqrt(),
            uncertainty: vec![0.0; n],
            correlations: vec![],
            weak: vec![],
            scale: d.clone(),
            covariance_factor: vec![],
        });
    }
    let evd = hz.self_adjoint_eigen(Side::Lower).ok()?;
    let (mu, v) = (evd.S().column_vector(), evd.U());
    let mu_max = mu[nf - 1].max(f64::MIN_POSITIVE);
    let kept: Vec<usize> = (0..nf).filter(|&i| mu[i] > tolerance * mu_max).collect();
    let rank = kept.len();
    let dof = (3 * problem.n_points()).saturating_sub(rank).max(1);
    let sigma2 = residual_sq / dof as f64;
    let w = design_factor(&d, basis, (mu, v), &kept);
    let cov = |i: usize, j: usize| sigma2 * w.iter().map(|c| c[i] * c[j]).sum::<f64>();
    let uncertainty: Vec<f64> = (0..n).map(|j| cov(j, j).max(0.0).sqrt()).collect();
    let correlations = correlated_pairs(&w, n, correlation);
    let weak = weak_directions(basis, (mu, v), &kept);
    let mu_min_kept = kept.first().map_or(mu_max, |&i| mu[i]);
    Some(Identifiability {
        free: nf,
        rank,
        condition: (mu_max / mu_min_kept).sqrt(),
        condition_all: if mu[0] > 0.0 {
            (mu_max / mu[0]).sqrt()
        } else {
            f64::INFINITY
        },
        sigma_mm: sigma2.sqrt(),
        uncertainty,
        correlations,
        weak,
        scale: d.clone(),
        covariance_factor: w
            .iter()
            .map(|c| c.iter().map(|x| x * sigma2.sqrt()).collect())
            .collect(),
    })
}

/// The noise of one group of points as its residuals show it ([`variance_components`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Component {
    /// The factor of the group's stated noise its residuals show (1 at the noise).
    pub scale: f64,
    /// The group's residual coordinates less what the fit absorbs of them (the sum of its
    /// points' leverages): the degrees of freedom `scale` is estimated from.
    pub dof: f64,
    /// The group's residual coordinates (3 per point, 1 per range alone).
    pub coordinates: usize,
}

/// Variance components (Helmert's estimation, as Förstner 1979 iterates it): the factor of its
/// noise that each group of points shows, the points of group `groups[i]` weighed together by
/// the factors found. `task`'s residuals are whitened by each point's stated noise
/// ([`volver_core::problem::Problem::whitened`]), so a factor of 1 is the stated noise. From
/// `params` (a fit of any objective), the weighted least-squares fit is one Gauss–Newton step
/// over the identified directions (curvature above `tolerance` × the largest); each group's
/// factor is `√(Σ‖r_i + J_i δ‖² / (m − Σ h_i))` over its `m` coordinates, `h_i` the points'
/// leverages (the hat matrix's diagonal); the weights `1/factor²` and the step are renewed
/// until the factors settle. A group's factor is thus its own noise's, not raised by what a
/// noisier group pushes into the fit nor lowered by what the fit absorbs of it. One per group
/// `0 … max(groups)`; `None` when the Jacobian is not finite or a decomposition fails.
///
/// ```
/// use volver_solvers::identifiability::{RANK_TOLERANCE, variance_components};
/// let model = volver_core::model::Model::default_xcfz();
/// let plan = volver_core::plan::Plan::parse_grid(model.machine(), "X=0:1400:700,C=0:270:90,Z=0:600:300").unwrap();
/// let mut data = volver_solvers::observability::nominal_data(&model, &plan);
/// // Noise of 1 µm (σ per coordinate) on the first half of the points, 5 µm on the second.
/// let mut rng = volver_core::random::Rng::new(3);
/// let half = data.points.len() / 2;
/// for (i, p) in data.points.iter_mut().enumerate() {
///     let s = if i < half { 0.001 } else { 0.005 };
///     p.measured = p.measured.map(|x| x + s * rng.normal());
/// }
/// let problem = volver_core::problem::Problem::new(&model, &data).unwrap();
/// let task = volver_solvers::Task::new(problem);
/// let groups: Vec<usize> = (0..data.points.len()).map(|i| usize::from(i >= half)).collect();
/// let c = variance_components(&task, &model.initial_params(), RANK_TOLERANCE, &groups).unwrap();
/// // Unwhitened residuals in mm: the factors are the σ (mm), to within their spread.
/// assert!((c[0].scale / 0.001 - 1.0).abs() < 0.25 && (c[1].scale / 0.005 - 1.0).abs() < 0.25);
/// assert_eq!(c[0].coordinates, 3 * half);
/// ```
pub fn variance_components(
    task: &Task,
    params: &[f64],
    tolerance: f64,
    groups: &[usize],
) -> Option<Vec<Component>> {
    let problem = &*task.problem;
    let (n, np) = (params.len(), problem.n_points());
    let Reduced { d, ns, .. } = reduced_normal(task, params)?;
    let nf = ns.n_free();
    let n_groups = groups.iter().max().map_or(0, |g| g + 1);
    let mut coordinates = vec![0usize; n_groups];
    for i in 0..np {
        coordinates[groups[i]] += if problem.scalar(i) { 1 } else { 3 };
    }
    // Every residual and its Jacobian row in the scaled free coordinates: A = J D N.
    use rayon::prelude::*;
    let rows: Vec<([f64; 3], Vec<f64>)> = (0..np)
        .into_par_iter()
        .map(|i| {
            let mut jac = vec![0.0; 3 * n];
            let r = problem.residual_and_jacobian(i, params, &mut jac);
            (r, jac)
        })
        .collect();
    let j = faer::Mat::from_fn(3 * np, n, |row, c| {
        rows[row / 3].1[(row % 3) * n + c] * d[c]
    });
    let r: Vec<f64> = (0..3 * np).map(|row| rows[row / 3].0[row % 3]).collect();
    if r.iter().any(|v| !v.is_finite()) || (0..n).any(|c| !j.col(c).iter().all(|v| v.is_finite())) {
        return None;
    }
    let a = crate::engines::kernels::product(j.as_ref(), ns.basis());
    let mut weight = vec![1.0; n_groups];
    let mut out = Vec::new();
    for _ in 0..MAX_COMPONENT_ROUNDS {
        let next = component_round(&a, &r, groups, &weight, &coordinates, nf, tolerance)?;
        let settled = next
            .iter()
            .zip(&out)
            .all(|(x, y): (&Component, &Component)| (x.scale - y.scale).abs() <= 1e-4 * y.scale);
        weight = next
            .iter()
            .map(|c| 1.0 / c.scale.max(1e-12).powi(2))
            .collect();
        let done = settled && !out.is_empty();
        out = next;
        if done {
            break;
        }
    }
    Some(out)
}

/// The most rounds of reweighting [`variance_components`] takes (it settles in a handful).
const MAX_COMPONENT_ROUNDS: usize = 30;

/// One round of [`variance_components`]: the groups' factors under the weights `weight` (per
/// group), from the rows `a` (`3 × points` by `nf`, reduced) and residuals `r`.
fn component_round(
    a: &faer::Mat<f64>,
    r: &[f64],
    groups: &[usize],
    weight: &[f64],
    coordinates: &[usize],
    nf: usize,
    tolerance: f64,
) -> Option<Vec<Component>> {
    let rows = a.nrows();
    let w = |row: usize| weight[groups[row / 3]];
    let aw = faer::Mat::from_fn(rows, nf, |row, c| w(row).sqrt() * a[(row, c)]);
    let (mut sq, mut absorbed) = (vec![0.0; weight.len()], vec![0.0; weight.len()]);
    if nf == 0 {
        for (row, v) in r.iter().enumerate() {
            sq[groups[row / 3]] += v * v;
        }
    } else {
        let h = crate::engines::kernels::product(aw.transpose(), aw.as_ref());
        let g: Vec<f64> = (0..nf)
            .map(|c| (0..rows).map(|row| w(row) * a[(row, c)] * r[row]).sum())
            .collect();
        let evd = h.self_adjoint_eigen(Side::Lower).ok()?;
        let (mu, v) = (evd.S().column_vector(), evd.U());
        let mu_max = mu[nf - 1].max(f64::MIN_POSITIVE);
        let kept: Vec<usize> = (0..nf).filter(|&i| mu[i] > tolerance * mu_max).collect();
        let mut zeta = vec![0.0; nf];
        for &i in &kept {
            let c = -(0..nf).map(|k| v[(k, i)] * g[k]).sum::<f64>() / mu[i];
            for (k, z) in zeta.iter_mut().enumerate() {
                *z += v[(k, i)] * c;
            }
        }
        // Leverages: w_row Σ_kept (a_row · v_i)² / μ_i.
        let vk = faer::Mat::from_fn(nf, kept.len(), |k, c| v[(k, kept[c])] / mu[kept[c]].sqrt());
        let p = crate::engines::kernels::product(aw.as_ref(), vk.as_ref());
        for row in 0..rows {
            let lin = r[row] + (0..nf).map(|k| a[(row, k)] * zeta[k]).sum::<f64>();
            let group = groups[row / 3];
            sq[group] += lin * lin;
            absorbed[group] += (0..kept.len()).map(|c| p[(row, c)].powi(2)).sum::<f64>();
        }
    }
    Some(
        (0..weight.len())
            .map(|k| {
                let dof = (coordinates[k] as f64 - absorbed[k]).max(1.0);
                Component {
                    scale: (sq[k] / dof).sqrt(),
                    dof,
                    coordinates: coordinates[k],
                }
            })
            .collect(),
    )
}

/// The design's factor of the parameters' covariance, one column per identified direction `i`
/// of `kept`: `w_i = D N v_i / √μ_i` (the covariance is `σ² Σ w_i w_iᵀ`), `d` the scales `D`,
/// `basis` the null space `N`, `(mu, v)` the eigen-decomposition of `H_z`.
fn design_factor(
    d: &[f64],
    basis: faer::MatRef<f64>,
    (mu, v): (faer::ColRef<f64>, faer::MatRef<f64>),
    kept: &[usize],
) -> Vec<Vec<f64>> {
    let (n, nf) = (basis.nrows(), basis.ncols());
    // Covariance in the parameters: D N (Σ_kept v vᵀ / μ) Nᵀ D σ².
    // Columns: w_i = D N v_i / √μ_i.
    kept.iter()
        .map(|&i| {
            (0..n)
                .map(|j| {
                    d[j] * (0..nf).map(|k| basis[(j, k)] * v[(k, i)]).sum::<f64>() / mu[i].sqrt()
                })
                .collect()
        })
        .collect()
}

/// The pairs of the `n` parameters whose correlation exceeds `threshold` in absolute value,
/// strongest first, from the design's factor `w` ([`design_factor`]). Correlations do not
/// depend on σ²: from the design alone, so that noise-free (planned) data have them too.
fn correlated_pairs(w: &[Vec<f64>], n: usize, threshold: f64) -> Vec<(usize, usize, f64)> {
    let design_cov = |i: usize, j: usize| w.iter().map(|c| c[i] * c[j]).sum::<f64>();
    let design_sd: Vec<f64> = (0..n).map(|j| design_cov(j, j).max(0.0).sqrt()).collect();
    let mut correlations = Vec::new();
    for i in 0..n {
        for j in i + 1..n {
            let (si, sj) = (design_sd[i], design_sd[j]);
            if si > 0.0 && sj > 0.0 {
                let c = design_cov(i, j) / (si * sj);
                if c.abs() > threshold {
                    correlations.push((i, j, c));
                }
            }
        }
    }
    correlations.sort_by(|a, b| b.2.abs().total_cmp(&a.2.abs()));
    correlations
}

/// The free directions not in `kept` (not identified), weakest first, in the scaled
/// parameters (`basis` the null space `N`, `(mu, v)` the eigen-decomposition of `H_z`,
/// ascending).
fn weak_directions(
    basis: faer::MatRef<f64>,
    (mu, v): (faer::ColRef<f64>, faer::MatRef<f64>),
    kept: &[usize],
) -> Vec<WeakDirection> {
    let (n, nf) = (basis.nrows(), basis.ncols());
    let mu_max = mu[nf - 1].max(f64::MIN_POSITIVE);
    (0..nf)
        .filter(|i| !kept.contains(i))
        .map(|i| {
            let dir: Vec<f64> = (0..n)
                .map(|j| (0..nf).map(|k| basis[(j, k)] * v[(k, i)]).sum())
                .collect();
            let mut parameters: Vec<(usize, f64)> = dir
                .iter()
                .enumerate()
                .filter(|(_, x)| x.abs() > 0.1)
                .map(|(j, x)| (j, *x))
                .collect();
            parameters.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
            WeakDirection {
                relative_curvature: mu[i].max(0.0) / mu_max,
                parameters,
                scaled: dir,
            }
        })
        .collect()
}

/// `task` with its unidentifiable directions held: every free direction whose curvature at
/// `params` is below `tolerance` × the largest (in the engine's scaled coordinates) becomes a
/// [`ConstraintKind::Gauge`] constraint `Σ_j v_j p_j / D_j = Σ_j v_j params_j / D_j`. The
/// problem that is left is well posed, so engines that differ in how they treat flat
/// directions reach the same optimum. `None` when the Jacobian is not finite or a
/// decomposition fails.
pub fn hold_weak<'a>(task: &Task<'a>, params: &[f64], tolerance: f64) -> Option<Task<'a>> {
    // The native LM's own measure of identifiability (curvatures of the Jacobi-scaled reduced
    // normal matrix) depends on the free coordinates, which the new constraints change: hold
    // until the problem left has no direction below the tolerance (a few rounds at most).
    let mut held = task.clone();
    for _ in 0..4 {
        let before = held.constraints.rows.len();
        held = hold_weak_once(&held, params, tolerance)?;
        if held.constraints.rows.len() == before {
            break;
        }
    }
    Some(held)
}

fn hold_weak_once<'a>(task: &Task<'a>, params: &[f64], tolerance: f64) -> Option<Task<'a>> {
    let n = params.len();
    let Reduced { d, ns, hz, .. } = reduced_normal(task, params)?;
    let nf = ns.n_free();
    let mut held = task.clone();
    if nf == 0 {
        return Some(held);
    }
    let basis = ns.basis();
    let dmax = (0..nf).map(|i| hz[(i, i)]).fold(0.0_f64, f64::max);
    let s0: Vec<f64> = (0..nf)
        .map(|i| 1.0 / hz[(i, i)].max(1e-12 * dmax).max(TINY).sqrt())
        .collect();
    // The LM's design: curvatures μ and directions w = S₀ u in z. It steps only in the span of
    // the kept w; holding w_i means holding its coordinate c_i = (S₀⁻¹ u_i)ᵀ z.
    let (mu, w) = crate::engines::coordinates::design_from_reduced(&hz)?;
    let mu_max = mu[nf - 1].max(f64::MIN_POSITIVE);
    let counted = task
        .constraints
        .rows
        .iter()
        .filter(|r| r.kind == ConstraintKind::Gauge)
        .count();
    for (round, i) in (0..nf).filter(|&i| mu[i] <= tolerance * mu_max).enumerate() {
        let coeffs: Vec<(usize, f64)> = (0..n)
            .map(|j| {
                let dir: f64 = (0..nf)
                    .map(|k| basis[(j, k)] * w[(k, i)] / (s0[k] * s0[k]))
                    .sum();
                (j, dir / d[j])
            })
            .filter(|(_, c)| *c != 0.0)
            .collect();
        // Unit largest coefficient, so that the constraint matrix stays balanced.
        let cmax = coeffs.iter().fold(0.0_f64, |m, (_, c)| m.max(c.abs()));
        let coeffs: Vec<(usize, f64)> = coeffs.into_iter().map(|(j, c)| (j, c / cmax)).collect();
        let rhs = coeffs.iter().map(|&(j, c)| c * params[j]).sum();
        held.constraints.rows.push(Constraint {
            kind: ConstraintKind::Gauge,
            label: format!(
                "unidentifiable direction {} held (relative curvature {:.1e})",
                counted + round + 1,
                mu[i].max(0.0) / mu_max
            ),
            coeffs,
            rhs,
        });
    }
    Some(held)
}
