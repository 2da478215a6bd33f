//! Constraint elimination by the null space: every `p` with `A p = b` is `p₀ + N z`, where the
//! columns of `N` are an orthonormal basis of the null space of `A` and `z` is free. Engines
//! without native equality constraints optimise over `z`.
//!
//! The rank of `A` is found by an SVD, so redundant but consistent constraints (a parameter fixed
//! twice at the same value) are accepted and counted; inconsistent ones are an error.
//!
//! ```
//! use volver_core::model::Model;
//! use volver_solvers::nullspace::NullSpace;
//! let model = Model::default_xcfz();
//! let ns = NullSpace::for_model(&model).unwrap();
//! assert_eq!(ns.n_free(), 74 - 17);
//! let z = vec![1e-3; ns.n_free()];
//! let p = ns.expand(&z);
//! assert!(model.constraints().max_violation(&p) < 1e-12);
//! ```

use faer::Mat;
use volver_core::model::{Constraints, Model};

/// The relative curvature of the scaled design below which a direction counts as not
/// identified by the data: the analyses' default
/// ([`crate::identifiability::RANK_TOLERANCE`] re-exports it) and the native LM's
/// ([`crate::engines::lm::LevenbergMarquardt::rank_tolerance`]).
pub const RANK_TOLERANCE: f64 = 1e-10;

/// Why a constraint set cannot be eliminated.
#[derive(Clone, Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum ConstraintError {
    /// No parameter vector satisfies every constraint.
    #[error("the constraints contradict each other: the closest point misses them by {residual:e}")]
    Inconsistent {
        /// Largest |A p − b| at the least-squares point.
        residual: f64,
    },
    /// The SVD of the constraint matrix did not converge.
    #[error("the SVD of the constraint matrix did not converge")]
    Svd,
    /// A constraint names a parameter the problem does not have.
    #[error(
        "constraint {row} (\"{label}\") names parameter {index}, but the problem has {params} \
         parameters (indices 0 … {params} − 1)"
    )]
    UnknownParameter {
        /// The constraint's row (from 0).
        row: usize,
        /// The constraint's label.
        label: String,
        /// The parameter index it names.
        index: usize,
        /// The problem's parameters.
        params: usize,
    },
    /// A constraint's coefficient or value is not finite.
    #[error("constraint {row} (\"{label}\") has a coefficient or value that is not finite")]
    NotFinite {
        /// The constraint's row (from 0).
        row: usize,
        /// The constraint's label.
        label: String,
    },
    /// Sizes do not match.
    #[error("constraint matrix is {rows}×{cols} but {expected} values were given")]
    Shape {
        /// Rows of A.
        rows: usize,
        /// Columns of A.
        cols: usize,
        /// Length of the offending vector.
        expected: usize,
    },
}

impl ConstraintError {
    /// The error for a row [`Constraints::check_indices`] refused, in a problem of `params`
    /// parameters.
    pub fn from_fault(fault: volver_core::model::ConstraintFault, params: usize) -> Self {
        use volver_core::model::ConstraintFault;
        match fault {
            ConstraintFault::UnknownParameter { row, label, index } => {
                ConstraintError::UnknownParameter {
                    row,
                    label,
                    index,
                    params,
                }
            }
            ConstraintFault::NotFinite { row, label } => ConstraintError::NotFinite { row, label },
        }
    }
}

/// The affine parametrisation `p = p₀ + N z` of the constraint set.
#[derive(Clone, Debug)]
pub struct NullSpace {
    p0: Vec<f64>,
    /// n × (n − rank), orthonormal columns.
    basis: Mat<f64>,
    rank: usize,
    redundant: usize,
}

impl NullSpace {
    /// Elimination of a model's constraints, anchored at its initial parameters.
    pub fn for_model(model: &Model) -> Result<NullSpace, ConstraintError> {
        NullSpace::from_constraints(model.constraints(), &model.initial_params())
    }

    /// Elimination of `constraints`; `p₀` is the point of the constraint set nearest to `anchor`.
    pub fn from_constraints(
        constraints: &Constraints,
        anchor: &[f64],
    ) -> Result<NullSpace, ConstraintError> {
        let n = anchor.len();
        constraints
            .check_indices(n)
            .map_err(|e| ConstraintError::from_fault(e, n))?;
        let (a, b) = constraints.dense(n);
        NullSpace::new(&a, &b, anchor)
    }

    /// Elimination of `A p = b` (`a` row-major, `b.len()` rows, `anchor.len()` columns).
    pub fn new(a: &[f64], b: &[f64], anchor: &[f64]) -> Result<NullSpace, ConstraintError> {
        let (k, n) = (b.len(), anchor.len());
        if a.len() != k * n {
            return Err(ConstraintError::Shape {
                rows: k,
                cols: n,
                expected: a.len(),
            });
        }
        if k == 0 {
            return Ok(NullSpace {
                p0: anchor.to_vec(),
                basis: Mat::identity(n, n),
                rank: 0,
                redundant: 0,
            });
        }
        // Each row (with its value) is divided by its norm first: rows of very different sizes
        // (a parameter fixed in scaled coordinates beside a dense gauge combination) would
        // otherwise make the SVD's rank test and the consistency test answer the largest row's
        // rounding instead of the question. A zero row constrains nothing if its value is zero.
        let mut ae = vec![0.0; k * n];
        let mut be = vec![0.0; k];
        for i in 0..k {
            let row = &a[i * n..(i + 1) * n];
            let norm = row.iter().map(|v| v * v).sum::<f64>().sqrt();
            if norm > 0.0 {
                for (e, v) in ae[i * n..(i + 1) * n].iter_mut().zip(row) {
                    *e = v / norm;
                }
                be[i] = b[i] / norm;
            } else if b[i] != 0.0 {
                return Err(ConstraintError::Inconsistent {
                    residual: b[i].abs(),
                });
            }
        }
        let am = Mat::from_fn(k, n, |i, j| ae[i * n + j]);
        let svd = am.svd().map_err(|_| ConstraintError::Svd)?;
        let s = svd.S().column_vector();
        let smax = (0..k.min(n)).map(|i| s[i]).fold(0.0, f64::max);
        let tol = smax * f64::EPSILON * (k.max(n) as f64) * 16.0;
        let rank = (0..k.min(n)).filter(|&i| s[i] > tol).count();
        let (u, v) = (svd.U(), svd.V());
        // p0 = anchor − A⁺ (A anchor − b)
        let resid: Vec<f64> = (0..k)
            .map(|i| (0..n).map(|j| ae[i * n + j] * anchor[j]).sum::<f64>() - be[i])
            .collect();
        let mut p0 = anchor.to_vec();
        for r in 0..rank {
            let coef = (0..k).map(|i| u[(i, r)] * resid[i]).sum::<f64>() / s[r];
            for (j, pj) in p0.iter_mut().enumerate() {
                *pj -= v[(j, r)] * coef;
            }
        }
        // Consistency in the normalised rows: each row's miss against what its evaluation
        // rounds (its value and the size of the terms it sums).
        let misses = (0..k).any(|i| {
            let row = &ae[i * n..(i + 1) * n];
            let value: f64 = row.iter().zip(&p0).map(|(a, p)| a * p).sum();
            let size: f64 = row.iter().zip(&p0).map(|(a, p)| (a * p).abs()).sum();
            (value - be[i]).abs() > 1e-9 * (1.0 + be[i].abs() + size)
        });
        if misses {
            let residual = (0..k)
                .map(|i| ((0..n).map(|j| a[i * n + j] * p0[j]).sum::<f64>() - b[i]).abs())
                .fold(0.0, f64::max);
            return Err(ConstraintError::Inconsistent { residual });
        }
        let basis = Mat::from_fn(n, n - rank, |i, j| v[(i, rank + j)]);
        Ok(NullSpace {
            p0,
            basis,
            rank,
            redundant: k - rank,
        })
    }

    /// Number of free directions (`n − rank A`).
    pub fn n_free(&self) -> usize {
        self.basis.ncols()
    }

    /// Rank of the constraint matrix.
    pub fn rank(&self) -> usize {
        self.rank
    }

    /// Constraints that repeat others (rows − rank).
    pub fn redundant(&self) -> usize {
        self.redundant
    }

    /// The anchor point p₀ (satisfies every constraint).
    pub fn p0(&self) -> &[f64] {
        &self.p0
    }

    /// The basis N (n × n_free, orthonormal columns).
    pub fn basis(&self) -> faer::MatRef<'_, f64> {
        self.basis.as_ref()
    }

    /// `p = p₀ + N z`.
    pub fn expand(&self, z: &[f64]) -> Vec<f64> {
        assert_eq!(z.len(), self.n_free(), "z has the wrong length");
        let n = self.p0.len();
        (0..n)
            .map(|i| self.p0[i] + (0..z.len()).map(|j| self.basis[(i, j)] * z[j]).sum::<f64>())
            .collect()
    }

    /// `z = Nᵀ (p − p₀)`: the free coordinates of the constrained point nearest to `p`.
    pub fn reduce(&self, p: &[f64]) -> Vec<f64> {
        assert_eq!(p.len(), self.p0.len(), "p has the wrong length");
        (0..self.n_free())
            .map(|j| {
                (0..p.len())
                    .map(|i| self.basis[(i, j)] * (p[i] - self.p0[i]))
                    .sum()
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eliminates_consistent_redundant_constraints() {
        // p0 + p1 = 1, p2 = 2, p2 = 2 (again), 4 parameters.
        let a = [1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        let b = [1.0, 2.0, 2.0];
        let ns = NullSpace::new(&a, &b, &[0.0; 4]).unwrap();
        assert_eq!((ns.rank(), ns.redundant(), ns.n_free()), (2, 1, 2));
        let p = ns.expand(&[0.3, -0.7]);
        assert!((p[0] + p[1] - 1.0).abs() < 1e-14 && (p[2] - 2.0).abs() < 1e-14);
        // Round trip z → p → z.
        let z = ns.reduce(&p);
        assert!((z[0] - 0.3).abs() < 1e-14 && (z[1] + 0.7).abs() < 1e-14);
        // p0 is the nearest constrained point to the anchor.
        assert!((ns.p0()[0] - 0.5).abs() < 1e-14 && ns.p0()[3].abs() < 1e-14);
    }

    /// Rows 10¹¹ apart in size (a parameter fixed in scaled coordinates beside small dense
    /// combinations) are eliminated, each to its own rounding.
    #[test]
    fn accepts_rows_of_very_different_sizes() {
        let n = 12;
        let truth: Vec<f64> = (0..n).map(|j| 0.1 * (j as f64 - 5.5)).collect();
        let mut a = Vec::new();
        for i in 0..2 {
            let mut row = vec![0.0; n];
            row[i] = 4.6e7;
            a.push(row);
        }
        for i in 0..7 {
            a.push(
                (0..n)
                    .map(|j| 1e-4 * (((i * 7 + j * 3) % 11) as f64 - 5.0) / 5.0)
                    .collect(),
            );
        }
        let b: Vec<f64> = a
            .iter()
            .map(|row| row.iter().zip(&truth).map(|(x, y)| x * y).sum())
            .collect();
        let flat: Vec<f64> = a.concat();
        let ns = NullSpace::new(&flat, &b, &[0.3; 12]).unwrap();
        assert_eq!(ns.n_free(), n - 9);
        let p = ns.expand(&[0.1, -0.2, 0.3]);
        for (row, bi) in a.iter().zip(&b) {
            let size: f64 = row.iter().map(|v| v.abs()).sum();
            let v: f64 = row.iter().zip(&p).map(|(x, y)| x * y).sum();
            assert!((v - bi).abs() <= 1e-12 * size, "{v} against {bi}");
        }
    }

    #[test]
    fn rejects_contradictions() {
        let a = [1.0, 0.0, 1.0, 0.0];
        let b = [1.0, 2.0];
        assert!(matches!(
            NullSpace::new(&a, &b, &[0.0; 2]),
            Err(ConstraintError::Inconsistent { .. })
        ));
    }
}
