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
use crate::model::{Model, Regressors};

/// A model and measurements of the same machine.
///
/// A problem may also be a plain curve fit ([`Problem::curve`], one of NIST's StRD problems),
/// so that the engines can be judged on the public reference suite: each observation is then a
/// "point" whose residual is `(f(x_i; b) − y_i, 0, 0)`, Φ is the mean absolute residual and
/// `n · ve` the residual sum of squares. [`Problem::model`] and [`Problem::data`] exist only for
/// machine problems.
///
/// A machine problem computes the model's fixed regressors at its points once
/// ([`crate::model::Regressors`]: basis values, the rotary axes' sines), shared by its clones,
/// so that each evaluation is the chain and the dot products alone.
#[derive(Clone, Debug)]
pub struct Problem<'a> {
    source: Source<'a>,
}

#[derive(Clone, Debug)]
enum Source<'a> {
    Machine {
        model: &'a Model,
        data: &'a MeasurementSet,
        regressors: std::sync::Arc<Regressors>,
    },
    Curve(&'a crate::nist::Dataset),
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
        let regressors =
            std::sync::Arc::new(model.regressors(data.points.iter().map(|p| &p.commands)));
        Ok(Problem {
            source: Source::Machine {
                model,
                data,
                regressors,
            },
        })
    }

    /// A curve fit: one of NIST's StRD problems (see the type's documentation).
    ///
    /// ```
    /// use volver_core::{nist, problem::Problem};
    /// let ds = nist::dataset("Misra1a").unwrap();
    /// let p = Problem::curve(&ds);
    /// let rss = p.ve(&ds.certified) * p.n_points() as f64;
    /// assert!((rss / ds.certified_rss - 1.0).abs() < 1e-9);
    /// assert!(p.machine().is_none() && p.constraints().rows.is_empty());
    /// ```
    pub fn curve(dataset: &'a crate::nist::Dataset) -> Problem<'a> {
        Problem {
            source: Source::Curve(dataset),
        }
    }

    /// Checks that the measured points have the size the machine gives them, which catches a
    /// measurement file in the wrong units (metres or inches instead of mm, radians instead of
    /// degrees) or a machine file whose reflector offsets or chain do not describe the machine
    /// measured. It compares the RMS distance of the measured points from their centroid with
    /// that of the points the model predicts at its start: a rigid motion (the tracker's pose)
    /// changes neither, and geometric errors change the ratio by parts per thousand at most.
    /// A ratio outside [0.98, 1.02] is an error naming `file`. Curve fits, fewer than three
    /// points, and meshes whose nominal points spread less than 10 mm pass unchecked.
    ///
    /// ```
    /// use volver_core::measure::MeasurementSet;
    /// use volver_core::model::Model;
    /// use volver_core::problem::Problem;
    /// let model = Model::default_xcfz();
    /// let mm = "reflector,X,C,Z,meas_x,meas_y,meas_z
    /// R1,0,0,0,950,75,1450
    /// R1,1000,0,0,-50,75,1450
    /// R1,0,0,300,950,75,1750
    /// ";
    /// let data = MeasurementSet::from_csv_str(model.machine(), mm, "mm.csv").unwrap();
    /// assert!(Problem::new(&model, &data).unwrap().check_scale("mm.csv").is_ok());
    /// // The same points in metres.
    /// let m = "reflector,X,C,Z,meas_x,meas_y,meas_z
    /// R1,0,0,0,0.950,0.075,1.450
    /// R1,1000,0,0,-0.050,0.075,1.450
    /// R1,0,0,300,0.950,0.075,1.750
    /// ";
    /// let data = MeasurementSet::from_csv_str(model.machine(), m, "m.csv").unwrap();
    /// let err = Problem::new(&model, &data).unwrap().check_scale("m.csv").unwrap_err();
    /// assert!(err.to_string().starts_with("m.csv: ") && err.to_string().contains("metres"));
    /// ```
    pub fn check_scale(&self, file: &str) -> Result<()> {
        let Source::Machine { model, data, .. } = self.source else {
            return Ok(());
        };
        let n = data.points.len();
        if n < 3 {
            return Ok(());
        }
        let params = model.initial_params();
        let predicted: Vec<[f64; 3]> = (0..n)
            .map(|i| {
                let r = self.residual(i, &params);
                let m = data.points[i].measured;
                [r[0] + m[0], r[1] + m[1], r[2] + m[2]]
            })
            .collect();
        let measured: Vec<[f64; 3]> = data.points.iter().map(|p| p.measured).collect();
        let spread = |pts: &[[f64; 3]]| {
            let mut c = [0.0; 3];
            for p in pts {
                for k in 0..3 {
                    c[k] += p[k] / pts.len() as f64;
                }
            }
            let ss: f64 = pts
                .iter()
                .map(|p| (0..3).map(|k| (p[k] - c[k]).powi(2)).sum::<f64>())
                .sum();
            (ss / pts.len() as f64).sqrt()
        };
        let (nominal, seen) = (spread(&predicted), spread(&measured));
        if nominal.is_nan() || nominal < 10.0 {
            return Ok(());
        }
        let ratio = seen / nominal;
        if (0.98..=1.02).contains(&ratio) {
            return Ok(());
        }
        let hint = if (ratio * 1000.0 - 1.0).abs() < 0.02 {
            " (×0.001: the coordinates look like metres)".to_string()
        } else if (ratio * 25.4 - 1.0).abs() < 0.02 {
            " (×1/25.4: the coordinates look like inches)".to_string()
        } else if (ratio / 1000.0 - 1.0).abs() < 0.02 {
            " (×1000: the coordinates look like µm)".to_string()
        } else {
            String::new()
        };
        Err(Error::input(
            crate::error::Place::file(file),
            format!(
                "the measured points spread {ratio:.4} times as far as the machine puts its \
                 reflectors{hint}: RMS distance from their centroid {seen:.3} mm measured, \
                 {nominal:.3} mm nominal. volver reads coordinates in mm and rotary positions in \
                 degrees; if the units are right, check the machine file's chain and reflector \
                 offsets"
            ),
        ))
    }

    /// The model and measurements of a machine problem; `None` for a curve fit.
    pub fn machine(&self) -> Option<(&'a Model, &'a MeasurementSet)> {
        match self.source {
            Source::Machine { model, data, .. } => Some((model, data)),
            Source::Curve(_) => None,
        }
    }

    /// The model.
    ///
    /// # Panics
    /// For a curve fit ([`Problem::curve`]), which has none; see [`Problem::machine`].
    pub fn model(&self) -> &'a Model {
        match self.source {
            Source::Machine { model, .. } => model,
            Source::Curve(d) => panic!("the curve fit {} has no machine model", d.name),
        }
    }

    /// The measurements.
    ///
    /// # Panics
    /// For a curve fit ([`Problem::curve`]); see [`Problem::machine`].
    pub fn data(&self) -> &'a MeasurementSet {
        match self.source {
            Source::Machine { data, .. } => data,
            Source::Curve(d) => panic!("the curve fit {} has no measurement set", d.name),
        }
    }

    /// Number of parameters.
    pub fn n_params(&self) -> usize {
        match self.source {
            Source::Machine { model, .. } => model.n_params(),
            Source::Curve(d) => d.n_params(),
        }
    }

    /// The linear equality constraints: the model's; none for a curve fit.
    pub fn constraints(&self) -> std::borrow::Cow<'a, crate::model::Constraints> {
        match self.source {
            Source::Machine { model, .. } => std::borrow::Cow::Borrowed(model.constraints()),
            Source::Curve(_) => std::borrow::Cow::Owned(Default::default()),
        }
    }

    /// Names of the parameters (the model's; `b1`, `b2`, … for a curve fit).
    pub fn param_names(&self) -> Vec<String> {
        match self.source {
            Source::Machine { model, .. } => {
                model.params().iter().map(|p| p.name.clone()).collect()
            }
            Source::Curve(d) => (1..=d.n_params()).map(|k| format!("b{k}")).collect(),
        }
    }

    /// Number of measured points (observations of a curve fit).
    pub fn n_points(&self) -> usize {
        match self.source {
            Source::Machine { data, .. } => data.points.len(),
            Source::Curve(d) => d.n_obs(),
        }
    }

    /// Residual of point `i`: predicted minus measured (mm).
    pub fn residual(&self, i: usize, params: &[f64]) -> [f64; 3] {
        match self.source {
            Source::Machine {
                model,
                data,
                ref regressors,
            } => {
                let m = &data.points[i];
                let x = model.predict_cached(
                    regressors,
                    i,
                    &m.commands,
                    m.reflector,
                    m.t_s.unwrap_or(0.0),
                    params,
                );
                minus(x, m.measured)
            }
            Source::Curve(d) => [d.residual(i, params), 0.0, 0.0],
        }
    }

    /// The magnitude of what point `i` measured (mm; for a curve fit, the observation): a
    /// residual is rounded relative to it, not to itself, so a cost computed from residuals much
    /// smaller than their observations carries a rounding of about
    /// `ε · observation_scale / ‖r‖` relative.
    pub fn observation_scale(&self, i: usize) -> f64 {
        match self.source {
            Source::Machine { data, .. } => norm(data.points[i].measured),
            Source::Curve(d) => d.observation(i).abs(),
        }
    }

    /// Residual of point `i` and its Jacobian (row-major 3 × n_params) in `jac`.
    pub fn residual_and_jacobian(&self, i: usize, params: &[f64], jac: &mut [f64]) -> [f64; 3] {
        match self.source {
            Source::Machine {
                model,
                data,
                ref regressors,
            } => {
                let m = &data.points[i];
                let x = model.predict_with_jacobian_cached(
                    regressors,
                    i,
                    &m.commands,
                    m.reflector,
                    m.t_s.unwrap_or(0.0),
                    params,
                    jac,
                );
                minus(x, m.measured)
            }
            Source::Curve(d) => {
                // Forward-mode dual numbers, one direction per parameter (NIST's problems have
                // at most 9).
                let n = params.len();
                jac[n..3 * n].iter_mut().for_each(|v| *v = 0.0);
                let mut b: Vec<num_dual::Dual64> = params
                    .iter()
                    .map(|&v| num_dual::Dual64::from_re(v))
                    .collect();
                let mut r = f64::NAN;
                for k in 0..n {
                    b[k].eps = 1.0;
                    let v = d.residual(i, &b);
                    b[k].eps = 0.0;
                    jac[k] = v.eps;
                    r = v.re;
                }
                [r, 0.0, 0.0]
            }
        }
    }

    /// Second derivative of the residual of point `i` along the parameter direction `dir`,
    /// `d²/dt² r_i(params + t·dir)` at t = 0, exact (second-order dual numbers): the curvature
    /// that geodesic acceleration corrects a Gauss–Newton step by.
    pub fn residual_second_directional(&self, i: usize, params: &[f64], dir: &[f64]) -> [f64; 3] {
        match self.source {
            Source::Machine { model, data, .. } => {
                let m = &data.points[i];
                model.predict_second_directional_at(
                    &m.commands,
                    m.reflector,
                    m.t_s.unwrap_or(0.0),
                    params,
                    dir,
                )
            }
            Source::Curve(d) => {
                let b: Vec<num_dual::Dual2_64> = params
                    .iter()
                    .zip(dir)
                    .map(|(&p, &v)| num_dual::Dual2_64::new(p, v, 0.0))
                    .collect();
                [d.residual(i, &b).v2, 0.0, 0.0]
            }
        }
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

    /// The expanded uncertainty (k = 2, µm) of the residuals' EMM as a mean over the points
    /// ([`crate::metrics::emm_u95_um`]).
    pub fn emm_u95_um(&self, params: &[f64]) -> f64 {
        let modules: Vec<f64> = (0..self.n_points())
            .map(|i| norm(self.residual(i, params)))
            .collect();
        crate::metrics::emm_u95_um(&modules)
    }
}

/// `a − b`.
fn minus(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// Euclidean norm of a 3-vector.
pub fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}
