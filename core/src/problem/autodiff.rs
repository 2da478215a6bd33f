//! Your own residuals with exact derivatives for free: write the residual of a point once,
//! generic over the scalar ([`PointResidual`], or [`ScalarResidual`] for a curve fit), and
//! [`AutoDiff`] makes it [`Residuals`] that every engine takes, with the exact Jacobian from
//! forward-mode dual numbers (`num_dual`'s `DualSVec64`, up to 16 parameters a pass) and the
//! exact second directional derivative from second-order dual numbers (`Dual2_64`), as volver's
//! machine model and NIST curves get theirs. No finite differences.
//!
//! ```
//! use volver_core::problem::{AutoDiff, PointResidual, Residuals};
//! use volver_core::scalar::Real;
//!
//! /// Points on a line through the origin: residual `p·t_i − y_i` (mm), one parameter p.
//! #[derive(Debug)]
//! struct Line {
//!     t: Vec<f64>,
//!     y: Vec<[f64; 3]>,
//! }
//!
//! impl PointResidual for Line {
//!     fn n_params(&self) -> usize {
//!         3
//!     }
//!     fn n_points(&self) -> usize {
//!         self.t.len()
//!     }
//!     fn residual<S: Real>(&self, i: usize, p: &[S]) -> [S; 3] {
//!         std::array::from_fn(|c| p[c] * self.t[i] - self.y[i][c])
//!     }
//! }
//!
//! let line = AutoDiff(Line { t: vec![1.0, 2.0], y: vec![[1.0, 2.0, 3.0], [2.0, 4.0, 6.5]] });
//! let mut jac = vec![0.0; 3 * 3];
//! let r = line.residual_and_jacobian(1, &[1.0, 2.0, 3.0], &mut jac);
//! assert_eq!(r, [0.0, 0.0, -0.5]);
//! assert_eq!(jac, [2.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 2.0]); // ∂r/∂p = t_i·I
//! assert_eq!(line.param_names(), ["p0", "p1", "p2"]);
//! ```

use super::Residuals;
use crate::model::Constraints;
use crate::scalar::Real;
use num_dual::{Dual2_64, DualSVec64};
use std::borrow::Cow;

/// A residual written once, generic over the scalar: `n_points` 3-vectors (mm for a machine)
/// that depend on `n_params` parameters. [`AutoDiff`] turns it into [`Residuals`] with exact
/// derivatives; the methods with a body have sensible defaults.
///
/// `residual` is called with `f64` and with dual numbers: write it with the operations of
/// [`Real`] (`+ − × ÷` between scalars and with `f64`, `sqrt`, `sin`, `exp`, `powi` …, and
/// `S::from(x)` for a constant), and branch only on values (`.re()`), never on a derivative.
pub trait PointResidual: Send + Sync + std::fmt::Debug {
    /// Number of parameters.
    fn n_params(&self) -> usize;

    /// Number of points.
    fn n_points(&self) -> usize;

    /// Residual of point `i` at `params` (`params.len() == n_params()`), in the scalar `S`:
    /// predicted − measured, by volver's convention.
    fn residual<S: Real>(&self, i: usize, params: &[S]) -> [S; 3];

    /// Names of the parameters, for reports: `p0`, `p1` … by default.
    fn param_names(&self) -> Vec<String> {
        default_names(self.n_params())
    }

    /// The linear equality constraints the parameters must satisfy: none by default.
    fn constraints(&self) -> Constraints {
        Constraints::default()
    }

    /// The magnitude of what point `i` measured (mm from the tracker for a point), the size a
    /// residual is rounded relative to ([`Residuals::observation_scale`]): 1 by default; give
    /// the measured point's distance from the origin when it is large, so that the engines'
    /// rounding estimates are not too tight.
    fn observation_scale(&self, _i: usize) -> f64 {
        1.0
    }

    /// Whether point `i`'s residual is a scalar `(r, 0, 0)` ([`Residuals::scalar`]): `false` by
    /// default. [`Scalar`] sets it for every point.
    fn scalar(&self, _i: usize) -> bool {
        false
    }
}

/// A scalar residual written once, generic over the scalar: a curve fit's `f(x_i; p) − y_i`.
/// [`Scalar`] makes it a [`PointResidual`] whose residuals are `(r, 0, 0)`, and
/// `AutoDiff(Scalar(..))` [`Residuals`] (Φ is then the mean absolute residual, `n · ve` the
/// residual sum of squares).
///
/// ```
/// use volver_core::problem::{AutoDiff, Residuals, Scalar, ScalarResidual};
/// use volver_core::scalar::Real;
///
/// /// y = a·exp(b·x).
/// #[derive(Debug)]
/// struct Growth {
///     x: Vec<f64>,
///     y: Vec<f64>,
/// }
///
/// impl ScalarResidual for Growth {
///     fn n_params(&self) -> usize {
///         2
///     }
///     fn n_points(&self) -> usize {
///         self.x.len()
///     }
///     fn residual<S: Real>(&self, i: usize, p: &[S]) -> S {
///         p[0] * (p[1] * self.x[i]).exp() - self.y[i]
///     }
///     fn param_names(&self) -> Vec<String> {
///         vec!["a".into(), "b".into()]
///     }
/// }
///
/// let fit = AutoDiff(Scalar(Growth { x: vec![0.0, 1.0], y: vec![2.0, 5.0] }));
/// let mut jac = vec![0.0; 3 * 2];
/// let r = fit.residual_and_jacobian(1, &[2.0, 0.5], &mut jac);
/// let e = 0.5f64.exp();
/// assert!((r[0] - (2.0 * e - 5.0)).abs() < 1e-15 && r[1] == 0.0 && fit.scalar(1));
/// assert!((jac[0] - e).abs() < 1e-15 && (jac[1] - 2.0 * e).abs() < 1e-15);
/// assert_eq!(&jac[2..], &[0.0; 4]);
/// ```
pub trait ScalarResidual: Send + Sync + std::fmt::Debug {
    /// Number of parameters.
    fn n_params(&self) -> usize;

    /// Number of observations.
    fn n_points(&self) -> usize;

    /// Residual of observation `i` at `params`, in the scalar `S`: model − observation.
    fn residual<S: Real>(&self, i: usize, params: &[S]) -> S;

    /// Names of the parameters, for reports: `p0`, `p1` … by default.
    fn param_names(&self) -> Vec<String> {
        default_names(self.n_params())
    }

    /// The linear equality constraints the parameters must satisfy: none by default.
    fn constraints(&self) -> Constraints {
        Constraints::default()
    }

    /// The magnitude of observation `i` (see [`PointResidual::observation_scale`]): 1 by
    /// default.
    fn observation_scale(&self, _i: usize) -> f64 {
        1.0
    }
}

/// A [`ScalarResidual`] as a [`PointResidual`]: residual `(r, 0, 0)`, every point scalar.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Scalar<R>(pub R);

impl<R: ScalarResidual> PointResidual for Scalar<R> {
    fn n_params(&self) -> usize {
        self.0.n_params()
    }

    fn n_points(&self) -> usize {
        self.0.n_points()
    }

    fn residual<S: Real>(&self, i: usize, params: &[S]) -> [S; 3] {
        [self.0.residual(i, params), S::from(0.0), S::from(0.0)]
    }

    fn param_names(&self) -> Vec<String> {
        self.0.param_names()
    }

    fn constraints(&self) -> Constraints {
        self.0.constraints()
    }

    fn observation_scale(&self, i: usize) -> f64 {
        self.0.observation_scale(i)
    }

    fn scalar(&self, _i: usize) -> bool {
        true
    }
}

/// A [`PointResidual`] as [`Residuals`], its derivatives exact by forward-mode dual numbers:
/// the Jacobian of a point in `⌈n_params / 16⌉` evaluations of the residual in `DualSVec64`
/// (one for up to 16 parameters, in duals of 2, 4, 8 or 16 directions), the second directional
/// derivative in one evaluation in `Dual2_64`. Usable by every engine (`Task::new(AutoDiff(..))` in
/// `volver-solvers`) and by the analyses that take a task (identifiability).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AutoDiff<R>(pub R);

impl<R: PointResidual> Residuals for AutoDiff<R> {
    fn n_params(&self) -> usize {
        self.0.n_params()
    }

    fn n_points(&self) -> usize {
        self.0.n_points()
    }

    fn param_names(&self) -> Vec<String> {
        self.0.param_names()
    }

    fn constraints(&self) -> Cow<'_, Constraints> {
        Cow::Owned(self.0.constraints())
    }

    fn residual(&self, i: usize, params: &[f64]) -> [f64; 3] {
        self.0.residual(i, params)
    }

    fn residual_and_jacobian(&self, i: usize, params: &[f64], jac: &mut [f64]) -> [f64; 3] {
        match params.len() {
            0 => self.0.residual(i, params),
            1..=2 => jacobian_in::<R, 2>(&self.0, i, params, jac),
            3..=4 => jacobian_in::<R, 4>(&self.0, i, params, jac),
            5..=8 => jacobian_in::<R, 8>(&self.0, i, params, jac),
            _ => jacobian_in::<R, 16>(&self.0, i, params, jac),
        }
    }

    fn residual_second_directional(&self, i: usize, params: &[f64], dir: &[f64]) -> [f64; 3] {
        let x: Vec<Dual2_64> = params
            .iter()
            .zip(dir)
            .map(|(&p, &v)| Dual2_64::new(p, v, 0.0))
            .collect();
        self.0.residual(i, &x).map(|y| y.v2)
    }

    fn observation_scale(&self, i: usize) -> f64 {
        self.0.observation_scale(i)
    }

    fn scalar(&self, i: usize) -> bool {
        self.0.scalar(i)
    }
}

/// `p0`, `p1` … `p{n−1}`.
fn default_names(n: usize) -> Vec<String> {
    (0..n).map(|k| format!("p{k}")).collect()
}

/// The residual of point `i` and its Jacobian (row-major 3 × n) in `jac`, `K` directions a pass.
fn jacobian_in<R: PointResidual, const K: usize>(
    r: &R,
    i: usize,
    params: &[f64],
    jac: &mut [f64],
) -> [f64; 3] {
    let n = params.len();
    let mut x: Vec<DualSVec64<K>> = params.iter().map(|&v| DualSVec64::from_re(v)).collect();
    let mut value = [f64::NAN; 3];
    for first in (0..n).step_by(K) {
        let last = (first + K).min(n);
        for (k, j) in (first..last).enumerate() {
            x[j] = DualSVec64::from_re(params[j]).derivative(k);
        }
        let y = r.residual(i, &x);
        for j in first..last {
            x[j] = DualSVec64::from_re(params[j]);
        }
        for (c, yc) in y.iter().enumerate() {
            value[c] = yc.re;
            let row = &mut jac[c * n + first..c * n + last];
            match &yc.eps.0 {
                Some(eps) => row.copy_from_slice(&eps.as_slice()[..last - first]),
                None => row.iter_mut().for_each(|v| *v = 0.0),
            }
        }
    }
    value
}
