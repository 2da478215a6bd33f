//! The paper's error metrics: EMM, the mean error in module (eq. 12 evaluated), and EMax, the
//! largest error module, both reported in µm.
//!
//! ```
//! use volver_core::metrics::ErrorStats;
//! let a = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
//! let b = [[0.003, 0.004, 0.0], [1.0, 0.0, 0.001]];
//! let s = ErrorStats::between(&a, &b);
//! assert!((s.emm_um - 3.0).abs() < 1e-9 && (s.emax_um - 5.0).abs() < 1e-9);
//! ```

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

/// Mean and largest error module of a set of point differences.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ErrorStats {
    /// EMM: mean of ‖a_i − b_i‖, µm.
    pub emm_um: f64,
    /// EMax: largest ‖a_i − b_i‖, µm.
    pub emax_um: f64,
}

/// The expanded uncertainty (k = 2, µm) of an EMM as the mean of `modules` (mm): twice their
/// standard deviation over the square root of their number — how far the EMM of these points
/// would scatter had their noise been drawn again. Zero for fewer than two modules.
///
/// ```
/// use volver_core::metrics::emm_u95_um;
/// // Modules 1, 2, 3 µm: s = 1 µm, U = 2 × 1 / √3 µm.
/// let u = emm_u95_um(&[0.001, 0.002, 0.003]);
/// assert!((u - 2.0 / 3f64.sqrt()).abs() < 1e-12);
/// ```
pub fn emm_u95_um(modules: &[f64]) -> f64 {
    let n = modules.len();
    if n < 2 {
        return 0.0;
    }
    let mean = modules.iter().sum::<f64>() / n as f64;
    let var = modules.iter().map(|m| (m - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    2.0 * (var / n as f64).sqrt() * crate::units::UM_PER_MM
}

impl ErrorStats {
    /// Statistics of the differences between two equally long lists of points (mm). Zero for
    /// empty lists.
    ///
    /// # Panics
    /// When the lists differ in length (a programming error).
    pub fn between(a: &[[f64; 3]], b: &[[f64; 3]]) -> ErrorStats {
        assert_eq!(a.len(), b.len(), "point lists differ in length");
        ErrorStats::of_modules(a.iter().zip(b).map(|(p, q)| {
            ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
        }))
    }

    /// Statistics of the differences left after the best rigid transform of `a` onto `b`
    /// ([`rigid_fit`]): what a workpiece set-up does not absorb (a constant translation and
    /// rotation of the tool relative to the table is no error of the machine for machining).
    ///
    /// ```
    /// use volver_core::metrics::ErrorStats;
    /// // b is a turned and shifted copy of a, plus 2 µm on one point.
    /// let a = [[0.0, 0.0, 0.0], [100.0, 0.0, 0.0], [0.0, 100.0, 0.0], [0.0, 0.0, 100.0]];
    /// let (c, s) = (1e-3f64.cos(), 1e-3f64.sin());
    /// let mut b: Vec<[f64; 3]> = a.iter().map(|p| [c * p[0] - s * p[1] + 0.05, s * p[0] + c * p[1], p[2] - 0.02]).collect();
    /// assert!(ErrorStats::between(&a, &b).emm_um > 20.0);
    /// assert!(ErrorStats::after_rigid(&a, &b).emax_um < 1e-6);
    /// b[3][0] += 0.002;
    /// assert!(ErrorStats::after_rigid(&a, &b).emax_um < 2.0);
    /// ```
    pub fn after_rigid(a: &[[f64; 3]], b: &[[f64; 3]]) -> ErrorStats {
        let (r, t) = rigid_fit(a, b);
        let moved: Vec<[f64; 3]> = a
            .iter()
            .map(|p| std::array::from_fn(|i| (0..3).map(|j| r[i][j] * p[j]).sum::<f64>() + t[i]))
            .collect();
        ErrorStats::between(&moved, b)
    }

    /// Statistics of error modules given in mm.
    pub fn of_modules(modules: impl IntoIterator<Item = f64>) -> ErrorStats {
        let (mut sum, mut max, mut n) = (0.0, 0.0_f64, 0usize);
        for e in modules {
            sum += e;
            max = max.max(e);
            n += 1;
        }
        if n == 0 {
            return ErrorStats::default();
        }
        ErrorStats {
            emm_um: sum / n as f64 * crate::units::UM_PER_MM,
            emax_um: max * crate::units::UM_PER_MM,
        }
    }
}

/// The rigid transform (rotation `R`, translation `t`) that moves the points `a` closest to `b`
/// in the least-squares sense, `min Σ ‖R a_i + t − b_i‖²` (Kabsch, with the reflection fix).
/// The identity for fewer than three points or a degenerate (collinear) set.
pub fn rigid_fit(a: &[[f64; 3]], b: &[[f64; 3]]) -> ([[f64; 3]; 3], [f64; 3]) {
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let n = a.len().min(b.len());
    if n == 0 {
        return (identity, [0.0; 3]);
    }
    let mean = |v: &[[f64; 3]]| -> Vector3<f64> {
        Vector3::from_fn(|c, _| v[..n].iter().map(|x| x[c]).sum::<f64>() / n as f64)
    };
    let (ca, cb) = (mean(a), mean(b));
    let mut h = Matrix3::zeros();
    for (p, q) in a[..n].iter().zip(&b[..n]) {
        h += (Vector3::from(*p) - ca) * (Vector3::from(*q) - cb).transpose();
    }
    let svd = h.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return (identity, std::array::from_fn(|i| cb[i] - ca[i]));
    };
    let sv = svd.singular_values;
    let mut sorted = [sv[0], sv[1], sv[2]];
    sorted.sort_by(|x, y| y.total_cmp(x));
    if n < 3 || sorted[1] <= 1e-12 * sorted[0].max(f64::MIN_POSITIVE) {
        return (identity, std::array::from_fn(|i| cb[i] - ca[i]));
    }
    let v = vt.transpose();
    // A reflection is turned into the nearest rotation by flipping the direction of the
    // smallest singular value (whatever the order the SVD returns them in).
    let d = (v * u.transpose()).determinant().signum();
    let smallest = (0..3).min_by(|&i, &j| sv[i].total_cmp(&sv[j])).unwrap_or(2);
    let flip = Vector3::from_fn(|i, _| if i == smallest { d } else { 1.0 });
    let r = v * Matrix3::from_diagonal(&flip) * u.transpose();
    let t = cb - r * ca;
    (
        std::array::from_fn(|i| std::array::from_fn(|j| r[(i, j)])),
        std::array::from_fn(|i| t[i]),
    )
}
