//! An identification problem: a model and the measurements it must explain. Residuals are
//! `r_i = predicted_i − measured_i` (mm, tracker frame), one 3-vector per measured point.
//!
//! The two objectives of the paper:
//! * **Φ** (eq. 12): the mean error module, `Φ = (1/n) Σ ‖r_i‖` (mm) — the EMM;
//! * **ve** (eq. 1): the mean squared error module, `ve = (1/n) Σ ‖r_i‖²` (mm²).
//!
//! ```
//! use volver_core::machine::Machine;
//! use volver_core::measure::MeasurementSet;
//! use volver_core::model::Model;
//! use volver_core::problem::Problem;
//! let model = Model::default_xcfz();
//! let csv = "reflector,X,C,Z,meas_x,meas_y,meas_z\nR1,0,0,0,950.003,75.004,1450\n";
//! let data = MeasurementSet::from_csv_str(model.machine(), csv, "inline.csv").unwrap();
//! let problem = Problem::new(&model, &data).unwrap();
//! let p = model.initial_params();
//! assert!((problem.phi(&p) - 0.005).abs() < 1e-12);      // mm
//! assert!((problem.ve(&p) - 0.005f64.powi(2)).abs() < 1e-15); // mm²
//! ```

use crate::error::{Error, Result};
use crate::measure::MeasurementSet;
use crate::metrics::ErrorStats;
use crate::model::Model;

/// A model and measurements of the same machine.
#[derive(Clone, Copy, Debug)]
pub struct Problem<'a> {
    model: &'a Model,
    data: &'a MeasurementSet,
}

impl<'a> Problem<'a> {
    /// Pairs a model with measurements; refuses an empty set and reflector indices the
    /// model's machine does not have.
    pub fn new(model: &'a Model, data: &'a MeasurementSet) -> Result<Problem<'a>> {
        if data.points.is_empty() {
            return Err(Error::Model("no measured points".into()));
        }
        let n_refl = model.machine().reflectors().len();
        if model.needs_time()
            && let Some(p) = data.points.iter().find(|p| p.t_s.is_none())
        {
            return Err(Error::Model(format!(
                "the model has thermal drift, but the measurement of line {} has no t_s",
                p.line
            )));
        }
        if let Some(p) = data.points.iter().find(|p| p.reflector >= n_refl) {
            return Err(Error::Model(format!(
                "measurement of line {} uses reflector index {} but the machine has {n_refl}",
                p.line, p.reflector
            )));
        }
        Ok(Problem { model, data })
    }

    /// The model.
    pub fn model(&self) -> &'a Model {
        self.model
    }

    /// The measurements.
    pub fn data(&self) -> &'a MeasurementSet {
        self.data
    }

    /// Number of measured points.
    pub fn n_points(&self) -> usize {
        self.data.points.len()
    }

    /// Residual of point `i`: predicted minus measured (mm).
    pub fn residual(&self, i: usize, params: &[f64]) -> [f64; 3] {
        let m = &self.data.points[i];
        let x = self
            .model
            .predict_at(&m.commands, m.reflector, m.t_s.unwrap_or(0.0), params);
        [
            x[0] - m.measured[0],
            x[1] - m.measured[1],
            x[2] - m.measured[2],
        ]
    }

    /// Residual of point `i` and its Jacobian (row-major 3 × n_params) in `jac`.
    pub fn residual_and_jacobian(&self, i: usize, params: &[f64], jac: &mut [f64]) -> [f64; 3] {
        let m = &self.data.points[i];
        let x = self.model.predict_with_jacobian_at(
            &m.commands,
            m.reflector,
            m.t_s.unwrap_or(0.0),
            params,
            jac,
        );
        [
            x[0] - m.measured[0],
            x[1] - m.measured[1],
            x[2] - m.measured[2],
        ]
    }

    /// Every residual.
    pub fn residuals(&self, params: &[f64]) -> Vec<[f64; 3]> {
        (0..self.n_points())
            .map(|i| self.residual(i, params))
            .collect()
    }

    /// Φ, the mean error module (mm).
    pub fn phi(&self, params: &[f64]) -> f64 {
        (0..self.n_points())
            .map(|i| norm(self.residual(i, params)))
            .sum::<f64>()
            / self.n_points() as f64
    }

    /// ve, the mean squared error module (mm²).
    pub fn ve(&self, params: &[f64]) -> f64 {
        (0..self.n_points())
            .map(|i| norm(self.residual(i, params)).powi(2))
            .sum::<f64>()
            / self.n_points() as f64
    }

    /// EMM and EMax of the residuals (µm).
    pub fn stats(&self, params: &[f64]) -> ErrorStats {
        ErrorStats::of_modules((0..self.n_points()).map(|i| norm(self.residual(i, params))))
    }
}

/// Euclidean norm of a 3-vector.
pub fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}
