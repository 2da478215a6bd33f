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
            emm_um: sum / n as f64 * 1e3,
            emax_um: max * 1e3,
        }
    }
}
