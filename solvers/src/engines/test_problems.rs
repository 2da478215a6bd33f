//! Problems whose optima are known by hand, for the engines' unit tests.

use std::borrow::Cow;
use volver_core::model::Constraints;
use volver_core::problem::Residuals;

/// One parameter p and observations y_i: residual i is `(p − y_i, 0, 0)`. Least squares'
/// optimum is the mean, Φ's the median.
#[derive(Debug)]
pub(crate) struct Location {
    /// The observations.
    pub(crate) y: Vec<f64>,
    /// Whether each point is one scalar (a range) rather than three coordinates.
    pub(crate) scalar: bool,
}

impl Residuals for Location {
    fn n_params(&self) -> usize {
        1
    }

    fn n_points(&self) -> usize {
        self.y.len()
    }

    fn param_names(&self) -> Vec<String> {
        vec!["p".into()]
    }

    fn constraints(&self) -> Cow<'_, Constraints> {
        Cow::Owned(Constraints::default())
    }

    fn residual(&self, i: usize, params: &[f64]) -> [f64; 3] {
        [params[0] - self.y[i], 0.0, 0.0]
    }

    fn residual_and_jacobian(&self, i: usize, params: &[f64], jac: &mut [f64]) -> [f64; 3] {
        jac.copy_from_slice(&[1.0, 0.0, 0.0]);
        self.residual(i, params)
    }

    fn residual_second_directional(&self, _: usize, _: &[f64], _: &[f64]) -> [f64; 3] {
        [0.0; 3]
    }

    fn observation_scale(&self, i: usize) -> f64 {
        self.y[i].abs()
    }

    fn scalar(&self, _: usize) -> bool {
        self.scalar
    }
}
