//! The coordinates every normal-equation engine steps in: the parameters scaled by the inverse
//! column norms of the Jacobian (millimetres and radians, whose columns differ by the lever
//! arms, weigh alike) and freed of the linear constraints, `p = D (s₀ + N z)`; and the design,
//! the unweighted normal matrix in those coordinates, whose weak directions the data cannot
//! identify.

use crate::engines::kernels::accumulate;
use crate::nullspace::NullSpace;
use faer::{Mat, Side};
use volver_core::model::Constraints;
use volver_core::units::TINY;

/// The scaled, constraint-free parametrisation `p = D (s₀ + N z)`.
pub(crate) struct Free {
    /// Column scaling D.
    pub(crate) d: Vec<f64>,
    /// Null space of the scaled constraints.
    pub(crate) ns: NullSpace,
    /// Parameters held at a value: set exactly, not to rounding.
    pub(crate) fixed: Vec<(usize, f64)>,
}

impl Free {
    pub(crate) fn new(d: Vec<f64>, ns: NullSpace, constraints: &Constraints) -> Free {
        Free {
            d,
            ns,
            fixed: held_values(constraints),
        }
    }

    pub(crate) fn n_free(&self) -> usize {
        self.ns.n_free()
    }

    /// The parameters at free coordinates `z`.
    pub(crate) fn params(&self, z: &[f64]) -> Vec<f64> {
        let mut p: Vec<f64> = self
            .ns
            .expand(z)
            .iter()
            .zip(&self.d)
            .map(|(s, d)| s * d)
            .collect();
        for &(j, v) in &self.fixed {
            p[j] = v;
        }
        p
    }

    /// `p + D N dz`: a step of `dz` in the free coordinates taken from `p` itself (held
    /// parameters stay exact). Unlike [`Free::params`] of an accumulated z, it keeps every
    /// parameter's absolute precision: z counts the distance from the anchor, and a parameter
    /// that travels far from its start (MGH10's b1, from 2 to 10⁻⁵⁰ and back) would otherwise be
    /// known only to the rounding of that distance.
    pub(crate) fn step(&self, p: &[f64], dz: &[f64]) -> Vec<f64> {
        let b = self.ns.basis();
        let mut out: Vec<f64> = (0..p.len())
            .map(|i| p[i] + self.d[i] * (0..dz.len()).map(|k| b[(i, k)] * dz[k]).sum::<f64>())
            .collect();
        for &(j, v) in &self.fixed {
            out[j] = v;
        }
        out
    }

    /// `D N dz`: the change of the parameters along a step `dz` in the free coordinates.
    pub(crate) fn direction(&self, dz: &[f64]) -> Vec<f64> {
        let b = self.ns.basis();
        (0..self.d.len())
            .map(|i| self.d[i] * (0..dz.len()).map(|k| b[(i, k)] * dz[k]).sum::<f64>())
            .collect()
    }

    /// `M = D N` (n × free): `∂p/∂z`.
    #[cfg(any(feature = "nlopt", feature = "clarabel"))]
    pub(crate) fn tangent(&self) -> faer::Mat<f64> {
        let b = self.ns.basis();
        faer::Mat::from_fn(b.nrows(), b.ncols(), |i, k| self.d[i] * b[(i, k)])
    }
}

/// Parameters a constraint holds at a value (a single coefficient).
pub(crate) fn held_values(constraints: &Constraints) -> Vec<(usize, f64)> {
    constraints
        .rows
        .iter()
        .filter_map(|r| match r.coeffs.as_slice() {
            [(j, c)] if *c != 0.0 => Some((*j, r.rhs / c)),
            _ => None,
        })
        .collect()
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
    // blown up to unit norm: column norms are floored at 1e-12 of the typical one (the median
    // of the columns the data see). Not of the largest: a time term's column grows with the
    // unit of the time stamps to the power of its degree (t² in µs: 1e24 × in hours), and one
    // such column would lift the floor over every ordinary column.
    let typical = typical_column(h);
    let d: Vec<f64> = (0..n)
        .map(|j| {
            let c = h[(j, j)].max(1e-24 * typical);
            if c > 0.0 { 1.0 / c.sqrt() } else { 1.0 }
        })
        .collect();
    let ns = null_space_scaled_by(&d, constraints, anchor);
    (d, ns)
}

/// The typical squared column norm of `h = JᵀJ`: the median of the diagonal's positive entries
/// (the columns the data see); 0 when there is none.
pub(crate) fn typical_column(h: &Mat<f64>) -> f64 {
    let mut seen: Vec<f64> = (0..h.nrows())
        .map(|j| h[(j, j)])
        .filter(|c| *c > 0.0)
        .collect();
    seen.sort_by(f64::total_cmp);
    seen.get(seen.len() / 2).copied().unwrap_or(0.0)
}

/// The null space of the constraints in the coordinates `s = p / D` for a given column scaling
/// `d`, anchored at `anchor`.
pub(crate) fn null_space_scaled_by(
    d: &[f64],
    constraints: &volver_core::model::Constraints,
    anchor: &[f64],
) -> Result<NullSpace, crate::nullspace::ConstraintError> {
    let n = anchor.len();
    let (a, b) = constraints.dense(n);
    let a_scaled: Vec<f64> = (0..b.len() * n).map(|k| a[k] * d[k % n]).collect();
    let anchor_scaled: Vec<f64> = anchor.iter().zip(d).map(|(p, d)| p / d).collect();
    NullSpace::new(&a_scaled, &b, &anchor_scaled)
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

/// Normal equations in the parameters reduced to the scaled free coordinates
/// `p = D (s₀ + N z)`: `H_z = Nᵀ D H D N` and, with `g`, `g_z = Nᵀ D g`.
pub(crate) fn reduce(
    d: &[f64],
    basis: faer::MatRef<'_, f64>,
    h: &Mat<f64>,
    g: Option<&[f64]>,
) -> (Mat<f64>, Vec<f64>) {
    let (n, nf) = (d.len(), basis.ncols());
    let hs = Mat::from_fn(n, n, |i, j| d[i] * h[(i, j)] * d[j]);
    let hz = crate::engines::kernels::sandwich(hs.as_ref(), basis);
    let gz = g.map_or_else(Vec::new, |g| {
        (0..nf)
            .map(|k| (0..n).map(|i| basis[(i, k)] * d[i] * g[i]).sum())
            .collect()
    });
    (hz, gz)
}

/// [`Reduced`] normal equations; `None` when the Jacobian is not finite or the constraints
/// cannot be eliminated.
pub(crate) fn reduced_normal(task: &crate::Task, params: &[f64]) -> Option<Reduced> {
    reduced_normal_under(task, params, &|_| (1.0, 0.0))
}

/// [`reduced_normal`] of the least squares weighted per point by `weight(‖r_i‖)`, as
/// [`accumulate`] takes it (the constraints' scaling still from those weighted equations).
pub(crate) fn reduced_normal_under(
    task: &crate::Task,
    params: &[f64],
    weight: &(dyn Fn(f64) -> (f64, f64) + Sync),
) -> Option<Reduced> {
    let normal = accumulate(&*task.problem, params, weight, false)?;
    let (d, ns) = scaled_null_space(&normal.h, &task.constraints, params);
    let ns = ns.ok()?;
    let (hz, gz) = reduce(&d, ns.basis(), &normal.h, Some(&normal.g));
    Some(Reduced { d, ns, hz, gz })
}

/// The design's curvatures (ascending, Marquardt-scaled) and their directions in the free
/// coordinates z, from a normal matrix `h` in the parameters.
pub(crate) fn design_of(free: &Free, h: &Mat<f64>) -> Option<(Vec<f64>, Mat<f64>)> {
    design_from_reduced(&reduce(&free.d, free.ns.basis(), h, None).0)
}

/// [`design_of`] from the reduced normal matrix `H_z`.
pub(crate) fn design_from_reduced(h0: &Mat<f64>) -> Option<(Vec<f64>, Mat<f64>)> {
    let nf = h0.nrows();
    let dmax = (0..nf).map(|i| h0[(i, i)]).fold(0.0_f64, f64::max);
    let s0: Vec<f64> = (0..nf)
        .map(|i| 1.0 / h0[(i, i)].max(1e-12 * dmax).max(TINY).sqrt())
        .collect();
    let hp0 = Mat::from_fn(nf, nf, |i, j| s0[i] * h0[(i, j)] * s0[j]);
    let evd = hp0.self_adjoint_eigen(Side::Lower).ok()?;
    let mu: Vec<f64> = (0..nf).map(|i| evd.S().column_vector()[i]).collect();
    let u = evd.U();
    // Directions in z: S₀ v.
    Some((mu, Mat::from_fn(nf, nf, |k, i| s0[k] * u[(k, i)])))
}
