//! The linear algebra of compensation's Newton steps: dense solves of a few unknowns and the
//! five-axis step that meets the point and steers the direction.

/// One Gauss–Newton step of the five-axis compensation, split: the tool point's three
/// linearised equations met exactly (the least-norm step `s_p`), the direction's residual
/// minimised over what they leave free (`s = s_p + N α`, N an orthonormal basis of the
/// point's Jacobian's null space over the active axes), α damped by `λ` in Marquardt's manner.
pub(super) struct ConstrainedStep {
    m: usize,
    sp: Vec<f64>,
    /// The null space's basis, one vector (length m) per column.
    n: Vec<Vec<f64>>,
    /// `NᵀJ_dᵀJ_d N` (k × k) and `NᵀJ_dᵀ(J_d s_p + r_d)`.
    g: Vec<f64>,
    h: Vec<f64>,
}

impl ConstrainedStep {
    /// From the residuals `r` and their Jacobian `jac` (6 × m, row-major) over the `active`
    /// axes (the others do not move); `None` when the point's equations are singular.
    pub(super) fn new(
        jac: &[f64],
        r: &[f64; 6],
        m: usize,
        active: &[usize],
    ) -> Option<ConstrainedStep> {
        let row = |c: usize| -> Vec<f64> {
            (0..m)
                .map(|i| {
                    if active.contains(&i) {
                        jac[c * m + i]
                    } else {
                        0.0
                    }
                })
                .collect()
        };
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        let jp: Vec<Vec<f64>> = (0..3).map(row).collect();
        let jd: Vec<Vec<f64>> = (3..6).map(row).collect();
        // s_p = J_pᵀ (J_p J_pᵀ)⁻¹ (r_p): the least-norm step meeting the point.
        let mut gram: Vec<f64> = (0..9).map(|k| dot(&jp[k / 3], &jp[k % 3])).collect();
        let mut y = vec![r[0], r[1], r[2]];
        let y = solve_dense(&mut gram, &mut y, 3)?;
        let sp: Vec<f64> = (0..m)
            .map(|i| (0..3).map(|c| jp[c][i] * y[c]).sum())
            .collect();
        // The null space: the active unit vectors with the point's rows (orthonormalised)
        // projected out, orthonormalised in turn.
        let mut basis: Vec<Vec<f64>> = Vec::new();
        for v in &jp {
            let mut v = v.clone();
            for b in &basis {
                let c = dot(&v, b);
                v.iter_mut().zip(b).for_each(|(x, y)| *x -= c * y);
            }
            let len = dot(&v, &v).sqrt();
            v.iter_mut().for_each(|x| *x /= len);
            basis.push(v);
        }
        let mut n: Vec<Vec<f64>> = Vec::new();
        for &i in active {
            let mut v = vec![0.0; m];
            v[i] = 1.0;
            for b in basis.iter().chain(&n) {
                let c = dot(&v, b);
                v.iter_mut().zip(b).for_each(|(x, y)| *x -= c * y);
            }
            let len = dot(&v, &v).sqrt();
            if len > 1e-6 {
                v.iter_mut().for_each(|x| *x /= len);
                n.push(v);
            }
        }
        let k = n.len();
        // The direction's part: J_d N and J_d s_p − r_d (steps are subtracted from q).
        let jdn: Vec<Vec<f64>> = (0..3)
            .map(|c| n.iter().map(|v| dot(&jd[c], v)).collect())
            .collect();
        let rest: Vec<f64> = (0..3).map(|c| r[3 + c] - dot(&jd[c], &sp)).collect();
        let g = (0..k * k)
            .map(|e| (0..3).map(|c| jdn[c][e / k] * jdn[c][e % k]).sum())
            .collect();
        let h = (0..k)
            .map(|a| (0..3).map(|c| jdn[c][a] * rest[c]).sum())
            .collect();
        Some(ConstrainedStep { m, sp, n, g, h })
    }

    /// The step (to subtract from the commands) at damping `lambda`; `None` when the
    /// direction's system is singular.
    pub(super) fn step(&self, lambda: f64) -> Option<Vec<f64>> {
        let k = self.n.len();
        let mut alpha = vec![0.0; k];
        if k > 0 {
            let gmax = (0..k).map(|i| self.g[i * k + i]).fold(0.0_f64, f64::max);
            let mut g = self.g.clone();
            for i in 0..k {
                g[i * k + i] += lambda * g[i * k + i].max(1e-12 * gmax);
            }
            alpha = solve_dense(&mut g, &mut self.h.clone(), k)?;
        }
        Some(
            (0..self.m)
                .map(|i| self.sp[i] + (0..k).map(|a| self.n[a][i] * alpha[a]).sum::<f64>())
                .collect(),
        )
    }
}

/// The Newton step `s` with `J s = r` when there are as many equations as free axes (three),
/// or the least-squares step `JᵀJ s = Jᵀ r` (fewer free axes). `None` when the system is
/// singular.
pub(super) fn solve_step(jac: &[f64], r: &[f64], m: usize) -> Option<Vec<f64>> {
    let rows = r.len();
    if rows == m {
        return solve_dense(&mut jac.to_vec(), &mut r.to_vec(), m);
    }
    let mut a = vec![0.0; m * m];
    let mut b = vec![0.0; m];
    for i in 0..m {
        for j in 0..m {
            a[i * m + j] = (0..rows).map(|c| jac[c * m + i] * jac[c * m + j]).sum();
        }
        b[i] = (0..rows).map(|c| jac[c * m + i] * r[c]).sum();
    }
    solve_dense(&mut a, &mut b, m)
}

/// Solves the m × m system `a x = b` (row-major; both overwritten) by Gaussian elimination with
/// partial pivoting; `None` when a pivot is not finite or below 1e-14 of the largest entry (a
/// singular system). For the few unknowns of a Newton step.
///
/// ```
/// let mut a = vec![2.0, 1.0, 1.0, 3.0];
/// let mut b = vec![3.0, 5.0];
/// let x = volver_core::compensate::solve_dense(&mut a, &mut b, 2).unwrap();
/// assert!((x[0] - 0.8).abs() < 1e-15 && (x[1] - 1.4).abs() < 1e-15);
/// assert!(volver_core::compensate::solve_dense(&mut vec![1.0, 2.0, 2.0, 4.0], &mut vec![1.0, 1.0], 2).is_none());
/// ```
pub fn solve_dense(a: &mut [f64], b: &mut [f64], m: usize) -> Option<Vec<f64>> {
    let scale = a.iter().map(|v| v.abs()).fold(0.0, f64::max);
    for col in 0..m {
        let piv =
            (col..m).max_by(|&i, &j| a[i * m + col].abs().total_cmp(&a[j * m + col].abs()))?;
        if a[piv * m + col].abs() <= 1e-14 * scale || !a[piv * m + col].is_finite() {
            return None;
        }
        if piv != col {
            for j in 0..m {
                a.swap(piv * m + j, col * m + j);
            }
            b.swap(piv, col);
        }
        for i in col + 1..m {
            let f = a[i * m + col] / a[col * m + col];
            for j in col..m {
                a[i * m + j] -= f * a[col * m + j];
            }
            b[i] -= f * b[col];
        }
    }
    let mut x = vec![0.0; m];
    for i in (0..m).rev() {
        let s: f64 = (i + 1..m).map(|j| a[i * m + j] * x[j]).sum();
        x[i] = (b[i] - s) / a[i * m + i];
    }
    Some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_step_solves_small_systems() {
        let jac = [2.0, 1.0, 0.0, 1.0, 3.0, 1.0, 0.0, 1.0, 4.0];
        let r = [3.0, 5.0, 5.0];
        let s = solve_step(&jac, &r, 3).unwrap();
        for c in 0..3 {
            let v: f64 = (0..3).map(|j| jac[c * 3 + j] * s[j]).sum();
            assert!((v - r[c]).abs() < 1e-12);
        }
        assert!(solve_step(&[1.0, 2.0, 2.0, 4.0, 0.0, 0.0], &r, 2).is_none());
    }
}
