//! The restriction of a Jacobian pass to the directions steps may take: the free coordinates'
//! normal equations, the gradient test, the span of the identifiable design directions and
//! Moré's scaling of the damping.

use super::*;
use crate::engines::coordinates::{design_from_reduced, reduce};
use crate::engines::kernels::{Factor, Normal, sandwich};

/// A Jacobian pass restricted to the directions steps may take: the free coordinates' normal
/// equations, the span of the identifiable design directions and the damping's scaling.
pub(super) struct Restricted {
    /// `H_z = Nᵀ D H D N` and `g_z = Nᵀ D g` in the free coordinates.
    pub(super) hz: Mat<f64>,
    pub(super) gz: Vec<f64>,
    /// The identifiable span (free coordinates × its dimension); `None`: all of z.
    pub(super) q: Option<Mat<f64>>,
    /// The scaling `S = M^-½` of the span's coordinates (Moré's M).
    pub(super) sc: Vec<f64>,
    /// `S H_q S` and `S g_q`.
    pub(super) hp: Mat<f64>,
    pub(super) gp: Vec<f64>,
    /// Least squares: `R_z = R D N`, `R' = R_z Q S` and `c` (see [`crate::engines::kernels::Factor`]).
    pub(super) factor: Option<(Mat<f64>, Mat<f64>, Vec<f64>)>,
}

impl Restricted {
    /// From the span's scaled coordinates back to z.
    pub(super) fn to_z(&self, y: &[f64]) -> Vec<f64> {
        let y: Vec<f64> = y.iter().zip(&self.sc).map(|(y, s)| y * s).collect();
        match &self.q {
            None => y,
            Some(q) => {
                let (nf, nr) = (q.nrows(), q.ncols());
                (0..nf)
                    .map(|k| (0..nr).map(|c| q[(k, c)] * y[c]).sum())
                    .collect()
            }
        }
    }

    /// The decrease of the quadratic model along `delta` (z; the velocity: the acceleration
    /// only bends the path): from the factor, `−(cᵀv + ½‖v‖²)` with `v = R_z δ`, else
    /// `−(g_zᵀδ + ½ δᵀH_zδ)`.
    pub(super) fn predicted_decrease(&self, delta: &[f64]) -> f64 {
        let nf = self.hz.nrows();
        match &self.factor {
            Some((rz, _, c)) => {
                let n = rz.nrows();
                let v: Vec<f64> = (0..n)
                    .map(|i| (0..nf).map(|k| rz[(i, k)] * delta[k]).sum())
                    .collect();
                -(0..n).map(|i| c[i] * v[i] + 0.5 * v[i] * v[i]).sum::<f64>()
            }
            None => {
                let hd: Vec<f64> = (0..nf)
                    .map(|i| (0..nf).map(|j| self.hz[(i, j)] * delta[j]).sum())
                    .collect();
                -(0..nf)
                    .map(|i| self.gz[i] * delta[i] + 0.5 * delta[i] * hd[i])
                    .sum::<f64>()
            }
        }
    }
}

/// `H_q = Qᵀ H_z Q` and `g_q = Qᵀ g_z` on the span `q` (copies of `hz`, `gz` without one).
fn project(hz: &Mat<f64>, gz: &[f64], q: Option<&Mat<f64>>) -> (Mat<f64>, Vec<f64>) {
    match q {
        None => (hz.clone(), gz.to_vec()),
        Some(q) => {
            let nf = hz.nrows();
            let hq = sandwich(hz.as_ref(), q.as_ref());
            let gq: Vec<f64> = (0..q.ncols())
                .map(|c| (0..nf).map(|k| q[(k, c)] * gz[k]).sum())
                .collect();
            (hq, gq)
        }
    }
}

impl Lm<'_, '_, '_> {
    /// The pass reduced to the free coordinates, the gradient test, and the restriction to the
    /// identifiable directions with Moré's scaling.
    pub(super) fn restrict(&mut self, normal: Normal) -> Result<Restricted, Termination> {
        // Reduce to the free coordinates: Hz = Nᵀ D H D N, gz = Nᵀ D g.
        let (hz, gz) = reduce(
            &self.free.d,
            self.free.ns.basis(),
            &normal.h,
            Some(&normal.g),
        );
        let gmax = gz.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        if self.gradient_converged(gmax) {
            return Err(Termination::Gradient);
        }
        let q = self.identifiable_span(&hz)?;
        let (hq, gq) = project(&hz, &gz, q.as_ref());
        let nr = gq.len();
        let sc = self.more_scaling(&hq, q.is_some());
        // Scaled by S = M^-½: H' = S H S, g' = S g, and the damping is λ I.
        let hp = Mat::from_fn(nr, nr, |i, j| sc[i] * hq[(i, j)] * sc[j]);
        let gp: Vec<f64> = (0..nr).map(|i| sc[i] * gq[i]).collect();
        let factor = normal
            .factor
            .map(|f| self.restricted_factor(f, q.as_ref(), &sc));
        Ok(Restricted {
            hz,
            gz,
            q,
            sc,
            hp,
            gp,
            factor,
        })
    }

    /// The span of the identifiable design directions in z (`None`: all of z, nothing held and
    /// no dense rows), the held count recorded in the summary.
    ///
    /// Directions whose design curvature is below rank_tolerance × the largest are not
    /// identifiable from the data: steps stay in the span q of the others. The Gauss–Newton
    /// model neglects Σ r_i ∇²r_i, which grows with the residuals: once Φ is below 1e-4 Φ_start
    /// (a nearly exact fit, where that model is exact too) the tolerance relaxes in proportion,
    /// so such a fit may use every direction.
    fn identifiable_span(&mut self, hz: &Mat<f64>) -> Result<Option<Mat<f64>>, Termination> {
        let nf = self.free.n_free();
        let tolerance = self.settings.rank_tolerance * (1e4 * self.phi() / self.phi0).min(1.0);
        if self.objective == Objective::Ve {
            // Uniform weights: the current matrix is the design.
            self.design = design_from_reduced(hz).ok_or({
                Termination::NumericalFailure(Failure::Decomposition {
                    matrix: "the normal matrix",
                    at: At::Iteration(self.run.summary.iterations),
                })
            })?;
            self.design_generation += 1;
        }
        let (mu0, dirs0) = (&self.design.0, &self.design.1);
        let mu0_max = mu0[nf - 1].max(0.0);
        // A zero tolerance holds nothing (not even a direction whose curvature rounds to ≤ 0).
        let keep: Vec<usize> = (0..nf)
            .filter(|&i| tolerance == 0.0 || mu0[i] > tolerance * mu0_max)
            .collect();
        self.run.summary.unidentifiable = nf - keep.len();
        Ok((keep.len() < nf || self.dense_rows)
            .then(|| Mat::from_fn(nf, keep.len(), |k, c| dirs0[(k, keep[c])])))
    }

    /// Moré's scaling `S = M^-½` of the step's coordinates from `hq` (on a span when `on_span`).
    ///
    /// Damping: λ M with M the diagonal of the largest diag(H) seen in the step's coordinates
    /// (Moré's scaling, as MINPACK: it never shrinks, so a parameter whose column fades as the
    /// fit runs into a flat region is still damped at its earlier scale). The maximum runs while
    /// the coordinates stay the same: z, or the span q of the identifiable design directions
    /// until the design is refreshed (every iteration for ve, every IRLS stage for Φ); a new
    /// IRLS stage also restarts it (a new cost).
    fn more_scaling(&mut self, hq: &Mat<f64>, on_span: bool) -> Vec<f64> {
        let nr = hq.nrows();
        let coords = on_span.then_some((self.design_generation, nr));
        if self.reset_scale || coords != self.scale_coords || self.dmax.len() != nr {
            self.reset_scale = false;
            self.scale_coords = coords;
            self.dmax = vec![0.0; nr];
        }
        for (i, v) in self.dmax.iter_mut().enumerate() {
            *v = (*v).max(hq[(i, i)]);
        }
        // A direction the data have never seen is damped at unit scale (MINPACK's rule); no
        // floor relative to the others, whose curvatures may legitimately span 10²⁰ along
        // the path of a strongly nonlinear model (MGH10).
        self.dmax
            .iter()
            .map(|&v| 1.0 / if v > 0.0 { v } else { 1.0 }.sqrt())
            .collect()
    }

    /// Least squares: the factor in the step's coordinates, `R_z = R D N` and `R' = R_z Q S`,
    /// so that each step solves `min ‖R' y + c‖² + λ‖y‖²` by QR.
    fn restricted_factor(
        &self,
        f: Factor,
        q: Option<&Mat<f64>>,
        sc: &[f64],
    ) -> (Mat<f64>, Mat<f64>, Vec<f64>) {
        let n = self.problem.n_params();
        let nr = sc.len();
        let dv = &self.free.d;
        let rd = Mat::from_fn(n, n, |i, j| f.r[(i, j)] * dv[j]);
        let rz = &rd * self.free.ns.basis();
        let rq = match q {
            None => rz.clone(),
            Some(q) => &rz * q,
        };
        let rps = Mat::from_fn(n, nr, |i, j| rq[(i, j)] * sc[j]);
        (rz, rps, f.c)
    }
}
