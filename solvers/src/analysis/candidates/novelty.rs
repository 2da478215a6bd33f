//! What a candidate adds beyond what the current model already expresses.
//!
//! A candidate's step moves the measured points' predictions by `J δ` (its new parameters and,
//! in the same least-squares step, the model's own). Part of that change the current model can
//! make by itself: the span of its Jacobian's identified directions at the data points (the
//! tracker's pose included). What is left after projecting that span out is what the candidate
//! adds; a field over X and Z whose products `P₁(X)P₁(Z)` the angular errors of X already make
//! with the lever arm of Z can carry metres of coefficients against metres of those errors while
//! adding a few hundred µm. Sizes and plausibility are measured on this new part
//! ([`Expressible::novelty`]).

use crate::engines::coordinates::{held_values, reduced_normal};
use faer::{Mat, Side};
use volver_core::model::Model;
use volver_core::problem::{Problem, Residuals};

/// An orthonormal basis of what a model can express at the data points: the span of its
/// Jacobian's identified directions (relative curvature above the rank tolerance) over the
/// residual coordinates, unweighted (mm), row `3i + c` for component `c` of point `i`.
pub(super) struct Expressible {
    q: Mat<f64>,
}

/// The new part of a candidate's step: its largest displacement at a measured point (µm) and
/// the smallest change of the candidate's new parameters alone that adds the same.
pub(super) struct Novelty {
    /// The largest module of the new part over the measured points (µm).
    pub(super) peak_um: f64,
    /// The starting parameters with the new parameters moved by that smallest change (the
    /// model's own parameters unchanged).
    pub(super) representative: Vec<f64>,
    /// The parameters `model` lacks or holds at a value: the candidate's new ones.
    pub(super) fresh: Vec<usize>,
}

impl Novelty {
    /// [`Novelty::representative`] with the lower coefficients of an error function a
    /// candidate adds to or raises (`own`: every coefficient of that function; those among
    /// `fresh` are the new ones, already moved) changed by what they express of the new
    /// ones: the least-squares change at the data points, under the model's constraints
    /// among them (a function held to zero at its reference stays so). The function's change is
    /// then its added part as the data see it — for a raised degree, the new term less what the
    /// lower terms already make of it. `j` is the Jacobian at `start` over the data points.
    pub(super) fn own_functions(
        &self,
        extended: &Model,
        j: &Mat<f64>,
        start: &[f64],
        (own, fresh): (&[usize], &[usize]),
    ) -> Option<Vec<f64>> {
        let mut out = self.representative.clone();
        let lower: Vec<usize> = own.iter().copied().filter(|i| !fresh.contains(i)).collect();
        if lower.is_empty() {
            return Some(out);
        }
        // The function's own new coefficients' change.
        let x = Mat::from_fn(start.len(), 1, |k, _| {
            if own.contains(&k) {
                out[k] - start[k]
            } else {
                0.0
            }
        });
        // The constraints among these functions' coefficients: C_lower a = −C_new x.
        let rows: Vec<&volver_core::model::Constraint> = extended
            .constraints()
            .rows
            .iter()
            .filter(|r| r.coeffs.iter().all(|(i, _)| own.contains(i)))
            .filter(|r| r.coeffs.iter().any(|(i, _)| lower.contains(i)))
            .collect();
        let coeff = |r: usize, i: usize| -> f64 {
            rows[r]
                .coeffs
                .iter()
                .filter(|(k, _)| *k == i)
                .map(|(_, v)| v)
                .sum()
        };
        let c = Mat::from_fn(rows.len(), lower.len(), |r, k| coeff(r, lower[k]));
        let rhs = Mat::from_fn(rows.len(), 1, |r, _| {
            -rows[r]
                .coeffs
                .iter()
                .map(|(i, v)| v * x[(*i, 0)])
                .sum::<f64>()
        });
        let (particular, null) = constrained(&c, &rhs)?;
        // Minimise ‖J x + J_lower (a_p + N y)‖ over y.
        let jl = Mat::from_fn(j.nrows(), lower.len(), |r, k| j[(r, lower[k])]);
        let t = j * &x + &jl * &particular;
        let y = least_squares(&(&jl * &null), &t)?;
        let a = particular - &null * &y;
        for (k, &i) in lower.iter().enumerate() {
            out[i] += a[(k, 0)];
        }
        out.iter().all(|v| v.is_finite()).then_some(out)
    }
}

/// A particular solution of `c a = rhs` (least norm) and a basis of the null space of `c`.
fn constrained(c: &Mat<f64>, rhs: &Mat<f64>) -> Option<(Mat<f64>, Mat<f64>)> {
    let k = c.ncols();
    if c.nrows() == 0 {
        return Some((Mat::zeros(k, 1), Mat::identity(k, k)));
    }
    let svd = c.svd().ok()?;
    let (u, s, v) = (svd.U(), svd.S().column_vector(), svd.V());
    let smax = (0..s.nrows()).map(|i| s[i]).fold(0.0_f64, f64::max);
    let rank = (0..s.nrows()).filter(|&i| s[i] > 1e-12 * smax).count();
    let mut particular = Mat::zeros(k, 1);
    for r in 0..rank {
        let coef = (0..c.nrows()).map(|i| u[(i, r)] * rhs[(i, 0)]).sum::<f64>() / s[r];
        for i in 0..k {
            particular[(i, 0)] += v[(i, r)] * coef;
        }
    }
    Some((
        particular,
        Mat::from_fn(k, k - rank, |r, m| v[(r, rank + m)]),
    ))
}

/// The least-squares solution of `b y ≈ t` (directions below 1e-10 of the largest singular
/// value dropped).
fn least_squares(b: &Mat<f64>, t: &Mat<f64>) -> Option<Mat<f64>> {
    let mut y = Mat::zeros(b.ncols(), 1);
    if b.ncols() == 0 {
        return Some(y);
    }
    let svd = b.thin_svd().ok()?;
    let (u, s, v) = (svd.U(), svd.S().column_vector(), svd.V());
    let smax = (0..s.nrows()).map(|i| s[i]).fold(0.0_f64, f64::max);
    for r in 0..s.nrows() {
        if s[r] > 1e-10 * smax {
            let coef = (0..b.nrows()).map(|i| u[(i, r)] * t[(i, 0)]).sum::<f64>() / s[r];
            for i in 0..b.ncols() {
                y[(i, 0)] += v[(i, r)] * coef;
            }
        }
    }
    Some(y)
}

/// The Jacobian of `problem` at `params` over every point, row `3i + c`.
pub(super) fn jacobian(problem: &Problem, params: &[f64]) -> Mat<f64> {
    let n = params.len();
    let mut j = Mat::zeros(3 * problem.n_points(), n);
    let mut row = vec![0.0; 3 * n];
    for i in 0..problem.n_points() {
        problem.residual_and_jacobian(i, params, &mut row);
        for c in 0..3 {
            for k in 0..n {
                j[(3 * i + c, k)] = row[c * n + k];
            }
        }
    }
    j
}

impl Expressible {
    /// The span for `problem`'s model at `params` (its constraints eliminated); `None` when
    /// its normal equations cannot be formed.
    pub(super) fn new(problem: &Problem, params: &[f64], tolerance: f64) -> Option<Expressible> {
        let task = crate::Task::new(problem.clone());
        let reduced = reduced_normal(&task, params)?;
        let (d, basis) = (&reduced.d, reduced.ns.basis());
        let (n, nf) = (params.len(), reduced.ns.n_free());
        let dn = Mat::from_fn(n, nf, |j, k| d[j] * basis[(j, k)]);
        let a = jacobian(problem, params) * &dn;
        let h = a.transpose() * &a;
        let evd = h.self_adjoint_eigen(Side::Lower).ok()?;
        let (mu, v) = (evd.S().column_vector(), evd.U());
        let mu_max = (0..nf).map(|k| mu[k]).fold(0.0_f64, f64::max);
        let kept: Vec<usize> = (0..nf)
            .filter(|&k| mu[k] > tolerance * mu_max && mu[k] > 0.0)
            .collect();
        let vk = Mat::from_fn(nf, kept.len(), |r, c| v[(r, kept[c])] / mu[kept[c]].sqrt());
        let q = &a * &vk;
        let finite = q.col_iter().all(|c| c.iter().all(|x| x.is_finite()));
        finite.then_some(Expressible { q })
    }

    /// `m − Q Qᵀ m`, column by column: what the model cannot express of each column of `m`.
    fn project_out(&self, m: &Mat<f64>) -> Mat<f64> {
        let qt_m = self.q.transpose() * m;
        m - &self.q * &qt_m
    }

    /// What the step from `start` to `q` of `extended` (whose Jacobian at `start` over the
    /// data points is `j`, as [`jacobian`] gives it) adds beyond the current model `model`: the
    /// new part of the change of every point's prediction, its peak, and the smallest change of
    /// the new parameters (those `model` lacks or holds at a value) that adds the same,
    /// directions whose new part is below `√tolerance` of their column dropped. `None` when not
    /// finite.
    pub(super) fn novelty(
        &self,
        (model, extended): (&Model, &Model),
        j: &Mat<f64>,
        (start, q): (&[f64], &[f64]),
        tolerance: f64,
    ) -> Option<Novelty> {
        let held: Vec<usize> = held_values(model.constraints())
            .into_iter()
            .map(|(j, _)| j)
            .collect();
        let fresh: Vec<usize> = (0..extended.n_params())
            .filter(|&j| match model.param_index(&extended.params()[j].name) {
                None => true,
                Some(i) => held.contains(&i),
            })
            .collect();
        let step = Mat::from_fn(start.len(), 1, |k, _| q[k] - start[k]);
        let w = self.project_out(&(j * &step));
        let m = j.nrows();
        let peak_um = (0..m / 3)
            .map(|i| {
                (0..3)
                    .map(|c| w[(3 * i + c, 0)].powi(2))
                    .sum::<f64>()
                    .sqrt()
            })
            .fold(0.0_f64, f64::max)
            * volver_core::units::UM_PER_MM;
        // The new columns, scaled to unit norm before projection: a singular value of the
        // projected block is then the share of a direction that is new.
        let scale: Vec<f64> = fresh
            .iter()
            .map(|&k| {
                let norm = (0..m).map(|r| j[(r, k)].powi(2)).sum::<f64>().sqrt();
                if norm > 0.0 { 1.0 / norm } else { 0.0 }
            })
            .collect();
        let b = Mat::from_fn(m, fresh.len(), |r, c| j[(r, fresh[c])] * scale[c]);
        let b = self.project_out(&b);
        let mut representative = start.to_vec();
        if !fresh.is_empty() {
            let svd = b.thin_svd().ok()?;
            let (u, s, v) = (svd.U(), svd.S().column_vector(), svd.V());
            for r in 0..fresh.len() {
                if s[r] > tolerance.sqrt() {
                    let c = (0..m).map(|i| u[(i, r)] * w[(i, 0)]).sum::<f64>() / s[r];
                    for (k, &jk) in fresh.iter().enumerate() {
                        representative[jk] += scale[k] * v[(k, r)] * c;
                    }
                }
            }
        }
        (peak_um.is_finite() && representative.iter().all(|x| x.is_finite())).then_some(Novelty {
            peak_um,
            representative,
            fresh,
        })
    }
}
