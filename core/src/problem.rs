//! What the engines minimise: residuals, one 3-vector per point, behind the [`Residuals`] trait.
//! Two kinds implement it:
//! * [`Problem`], an identification problem: a model and the measurements it must explain, with
//!   residuals `r_i = predicted_i − measured_i` (mm, tracker frame), one per measured point;
//! * [`CurveFit`], one of NIST's StRD curve fits, so that the engines can be judged on the public
//!   reference suite;
//! * [`AutoDiff`], your own residual written once, generic over the scalar ([`PointResidual`],
//!   or [`ScalarResidual`] for a curve fit), with exact derivatives by dual numbers.
//!
//! The two objectives of the paper, provided by the trait for either:
//! * **Φ** (eq. 12): the mean error module, `Φ = (1/n) Σ ‖r_i‖` (mm) — the EMM;
//! * **ve** (eq. 1): the mean squared error module, `ve = (1/n) Σ ‖r_i‖²` (mm²).
//!
//! ```
//! use volver_core::machine::Machine;
//! use volver_core::measure::MeasurementSet;
//! use volver_core::model::Model;
//! use volver_core::problem::{Problem, Residuals};
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
use crate::model::{Constraints, Model, Regressors};
use crate::noise::TrackerNoise;
use std::borrow::Cow;

mod autodiff;
pub use autodiff::{AutoDiff, PointResidual, Scalar, ScalarResidual};

/// Residuals an engine can minimise: `n_points` 3-vectors that depend on `n_params`
/// parameters, with their exact Jacobian and curvature, under linear equality constraints.
///
/// The engines of `volver-solvers` take any implementation (`&dyn Residuals`); volver's own are
/// [`Problem`] (a machine and its measurements) and [`CurveFit`] (a NIST StRD curve). The
/// objectives Φ and ve and the error statistics are provided from [`Residuals::residual`].
///
/// Four methods are required: the two sizes, the residual and its exact Jacobian. The others have
/// defaults: parameters named `p0`, `p1` …, no constraints, zero curvature (the Gauss–Newton
/// model), observations of unit size, 3-vector residuals. Rather than writing the Jacobian by
/// hand, write the residual once generic over the scalar ([`PointResidual`]) and let
/// [`AutoDiff`] derive it, and the curvature, exactly.
///
/// ```
/// use volver_core::{nist, problem::{CurveFit, Residuals}};
/// let ds = nist::dataset("Misra1a").unwrap();
/// let fit = CurveFit::new(&ds);
/// // A curve fit's residuals are (f(x_i; b) − y_i, 0, 0): n·ve is the residual sum of squares.
/// let rss = fit.ve(&ds.certified) * fit.n_points() as f64;
/// assert!((rss / ds.certified_rss - 1.0).abs() < 1e-9);
/// assert!(fit.machine().is_none() && fit.constraints().rows.is_empty());
/// ```
pub trait Residuals: Send + Sync + std::fmt::Debug {
    /// Number of parameters.
    fn n_params(&self) -> usize;

    /// Number of points (observations of a curve fit).
    fn n_points(&self) -> usize;

    /// Names of the parameters, for reports: `p0`, `p1` … by default.
    fn param_names(&self) -> Vec<String> {
        (0..self.n_params()).map(|k| format!("p{k}")).collect()
    }

    /// The linear equality constraints the parameters must satisfy: none by default.
    fn constraints(&self) -> Cow<'_, Constraints> {
        Cow::Owned(Constraints::default())
    }

    /// Residual of point `i` (mm for a machine).
    fn residual(&self, i: usize, params: &[f64]) -> [f64; 3];

    /// Residual of point `i` and its exact Jacobian (row-major 3 × n_params) in `jac`.
    fn residual_and_jacobian(&self, i: usize, params: &[f64], jac: &mut [f64]) -> [f64; 3];

    /// Second derivative of the residual of point `i` along the parameter direction `dir`,
    /// `d²/dt² r_i(params + t·dir)` at t = 0, exact (second-order dual numbers): the curvature
    /// that geodesic acceleration corrects a Gauss–Newton step by, and that the Φ polish adds
    /// along weakly determined directions.
    ///
    /// Default: zero, the Gauss–Newton model (exact for residuals linear in the parameters):
    /// geodesic acceleration then changes no step and the polish uses the Gauss–Newton matrix.
    /// [`AutoDiff`] gives the exact value.
    fn residual_second_directional(&self, _i: usize, _params: &[f64], _dir: &[f64]) -> [f64; 3] {
        [0.0; 3]
    }

    /// The magnitude of what point `i` measured (mm; for a curve fit, the observation): a
    /// residual is rounded relative to it, not to itself, so a cost computed from residuals much
    /// smaller than their observations carries a rounding of about
    /// `ε · observation_scale / ‖r‖` relative. Default: 1 (observations of unit size); give
    /// the measured magnitude when it is large, or the engines' rounding estimates are too
    /// tight.
    fn observation_scale(&self, _i: usize) -> f64 {
        1.0
    }

    /// Whether point `i`'s residual is a scalar `(r, 0, 0)`, its module the absolute value (a
    /// range alone): its curvature in Φ's smoothed objective is all radial, ε²/(r² + ε²)^³ᐟ²,
    /// which the native LM reaches by continuation in ε. `false` by default.
    fn scalar(&self, _i: usize) -> bool {
        false
    }

    /// Whether the residuals are in units of the measuring noise ([`Problem::whitened`]): what
    /// the noise-weighted objectives (maximum likelihood, whitened Φ) minimise. `false` by
    /// default.
    fn whitened(&self) -> bool {
        false
    }

    /// The machine problem these residuals are, if they are one: what the engines read of the
    /// machine (the tracker's pose, the model's parameters) goes through it. `None` by default.
    fn machine(&self) -> Option<&Problem<'_>> {
        None
    }

    /// Every residual.
    fn residuals(&self, params: &[f64]) -> Vec<[f64; 3]> {
        (0..self.n_points())
            .map(|i| self.residual(i, params))
            .collect()
    }

    /// Φ, the mean error module (mm).
    fn phi(&self, params: &[f64]) -> f64 {
        (0..self.n_points())
            .map(|i| norm(self.residual(i, params)))
            .sum::<f64>()
            / self.n_points() as f64
    }

    /// ve, the mean squared error module (mm²).
    fn ve(&self, params: &[f64]) -> f64 {
        (0..self.n_points())
            .map(|i| norm(self.residual(i, params)).powi(2))
            .sum::<f64>()
            / self.n_points() as f64
    }

    /// EMM and EMax of the residuals (µm).
    fn stats(&self, params: &[f64]) -> ErrorStats {
        ErrorStats::of_modules((0..self.n_points()).map(|i| norm(self.residual(i, params))))
    }

    /// The expanded uncertainty (k = 2, µm) of the residuals' EMM as a mean over the points
    /// ([`crate::metrics::emm_u95_um`]).
    fn emm_u95_um(&self, params: &[f64]) -> f64 {
        let modules: Vec<f64> = (0..self.n_points())
            .map(|i| norm(self.residual(i, params)))
            .collect();
        crate::metrics::emm_u95_um(&modules)
    }
}

/// A model and measurements of the same machine.
///
/// The problem computes the model's fixed regressors at its points once
/// ([`crate::model::Regressors`]: basis values, the rotary axes' sines), shared by its clones,
/// so that each evaluation is the chain and the dot products alone.
#[derive(Clone, Debug)]
pub struct Problem<'a> {
    model: &'a Model,
    data: &'a MeasurementSet,
    regressors: std::sync::Arc<Regressors>,
    /// The whitening of every point's residual, when the problem is whitened
    /// ([`Problem::whitened`]).
    weights: Option<std::sync::Arc<Weights>>,
}

/// The whitening of a problem's residuals: one 3 × 3 matrix per point and the tracker's default
/// noise it was formed with.
#[derive(Debug)]
struct Weights {
    noise: Option<TrackerNoise>,
    rows: Vec<[[f64; 3]; 3]>,
}

impl<'a> Problem<'a> {
    /// Pairs a model with measurements; refuses an empty set and reflector indices the
    /// model's machine does not have.
    pub fn new(model: &'a Model, data: &'a MeasurementSet) -> Result<Problem<'a>> {
        if data.points.is_empty() {
            return Err(Error::NoData {
                message: "no measured points".into(),
            });
        }
        let n_refl = model.machine().reflectors().len();
        if model.needs_time()
            && let Some(p) = data.points.iter().find(|p| p.t_s.is_none())
        {
            return Err(Error::MeasurementMismatch {
                line: p.line,
                message: format!(
                    "the model has thermal drift, but the measurement of line {} has no t_s",
                    p.line
                ),
            });
        }
        let n_st = model.machine().stations().len();
        if let Some(p) = data.points.iter().find(|p| p.station_index >= n_st) {
            return Err(Error::MeasurementMismatch {
                line: p.line,
                message: format!(
                    "measurement of line {} uses station index {} but the machine has {n_st}",
                    p.line, p.station_index
                ),
            });
        }
        if let Some(p) = data.points.iter().find(|p| p.reflector >= n_refl) {
            return Err(Error::MeasurementMismatch {
                line: p.line,
                message: format!(
                    "measurement of line {} uses reflector index {} but the machine has {n_refl}",
                    p.line, p.reflector
                ),
            });
        }
        let regressors =
            std::sync::Arc::new(model.regressors(data.points.iter().map(|p| &p.commands)));
        Ok(Problem {
            model,
            data,
            regressors,
            weights: None,
        })
    }

    /// The same problem with its residuals in units of the measuring noise: each point's
    /// residual and Jacobian rows multiplied by the whitening of its station's noise at the
    /// measured point ([`TrackerNoise::whitening`]; a range by `1/σ` of its range), so that a
    /// least-squares fit weighs every point and direction by its noise — the maximum-likelihood
    /// estimate under normal noise — and Φ of these residuals is the mean Mahalanobis distance.
    /// Φ and ve of the whitened residuals are dimensionless.
    ///
    /// A station's noise is the one its own `[[station]]` table states
    /// ([`crate::machine::Machine::station_own_noise`]), else `default` (the tracker's: the
    /// `[tracker]` table's or `--noise`). `Err` names the station without any, a noise-free
    /// one (which weighs nothing), or one whose σ is zero for a quantity it measures (its angles
    /// or range for a point, its range for a range: that point would weigh infinitely).
    ///
    /// ```
    /// use volver_core::model::Model;
    /// use volver_core::noise::TrackerNoise;
    /// use volver_core::problem::{Problem, Residuals};
    /// let model = Model::default_xcfz();
    /// let data = volver_core::measure::MeasurementSet::from_csv_str(
    ///     model.machine(),
    ///     "reflector,X,C,Z,meas_x,meas_y,meas_z\nR1,0,0,0,950.01,75,1450\n",
    ///     "inline.csv",
    /// ).unwrap();
    /// let problem = Problem::new(&model, &data).unwrap();
    /// let noise = TrackerNoise::from_text("normal:10,10,2,0").unwrap();
    /// let w = problem.whitened(Some(&noise)).unwrap();
    /// let (p, r) = (model.initial_params(), problem.residual(0, &model.initial_params()));
    /// let (rw, axes) = (w.residual(0, &p), noise.axes(data.points[0].measured));
    /// for k in 0..3 {
    ///     let along = (0..3).map(|c| axes[k].0[c] * r[c]).sum::<f64>();
    ///     assert!((rw[k] - along / axes[k].1).abs() < 1e-9);
    /// }
    /// assert!(w.is_whitened() && !w.plain().is_whitened());
    /// assert!(problem.whitened(None).is_err()); // no noise stated anywhere
    /// // A point measured by a tracker whose angles have no noise: refused, naming the line.
    /// let exact_angles = TrackerNoise::from_text("normal:0,0,2,0").unwrap();
    /// let err = problem.whitened(Some(&exact_angles)).unwrap_err().to_string();
    /// assert!(err.contains("σ = 0") && err.contains("line 2"), "{err}");
    /// ```
    pub fn whitened(&self, default: Option<&TrackerNoise>) -> Result<Problem<'a>> {
        let machine = self.model.machine();
        let mut noises = Vec::with_capacity(machine.stations().len());
        for (k, st) in machine.stations().iter().enumerate() {
            let noise = machine.station_own_noise(k).or(default.copied());
            let named = || match st.id.as_str() {
                "" => "the tracker".to_string(),
                id => format!("station '{id}'"),
            };
            match noise {
                Some(n) if !n.is_none() => noises.push(n),
                Some(_) => {
                    return Err(Error::InvalidOption {
                        name: "noise",
                        message: format!(
                            "{} is noise-free: a noise-weighted fit needs its noise (σ > 0)",
                            named()
                        ),
                    });
                }
                None => {
                    return Err(Error::InvalidOption {
                        name: "noise",
                        message: format!(
                            "{} has no stated noise: a noise-weighted fit (objective ml or \
                             phi-w) needs it: give --noise, the machine file's [tracker] noise \
                             or the station's own noise",
                            named()
                        ),
                    });
                }
            }
        }
        if let Some(p) = self.data.points.iter().find(|p| {
            let range = p.observation == crate::measure::Observation::Range;
            !noises[p.station_index].measures(range, norm(p.measured))
        }) {
            let st = &machine.stations()[p.station_index];
            let whose = match st.id.as_str() {
                "" => "the tracker's noise".to_string(),
                id => format!("station '{id}''s noise"),
            };
            let what = match p.observation {
                crate::measure::Observation::Range => "its ranges",
                crate::measure::Observation::Point => "its angles and range",
            };
            return Err(Error::InvalidOption {
                name: "noise",
                message: format!(
                    "{whose} {} has σ = 0 for what it observes (line {} measures {what}): a \
                     noise-weighted fit would give that point infinite weight; state σ > 0 for \
                     every quantity the station measures (--noise, [tracker] noise or the \
                     station's noise)",
                    noises[p.station_index], p.line
                ),
            });
        }
        let rows = self
            .data
            .points
            .iter()
            .map(|p| noises[p.station_index].whitening(p.measured))
            .collect::<Option<Vec<_>>>()
            .ok_or_else(|| Error::NonFinite {
                message: "the noise's whitening is not finite at a measured point".into(),
            })?;
        Ok(Problem {
            weights: Some(std::sync::Arc::new(Weights {
                noise: default.copied(),
                rows,
            })),
            ..self.clone()
        })
    }

    /// The problem without its whitening (itself when it has none): residuals in mm.
    pub fn plain(&self) -> Problem<'a> {
        Problem {
            weights: None,
            ..self.clone()
        }
    }

    /// Whether the residuals are whitened ([`Problem::whitened`]).
    pub fn is_whitened(&self) -> bool {
        self.weights.is_some()
    }

    /// The tracker's default noise the problem was whitened with (`None`: plain, or every
    /// station states its own).
    pub fn noise(&self) -> Option<&TrackerNoise> {
        self.weights.as_ref().and_then(|w| w.noise.as_ref())
    }

    /// The whitening `W_i` of point `i` (row-major; the identity when the problem is plain).
    pub fn whitening_of(&self, i: usize) -> [[f64; 3]; 3] {
        match &self.weights {
            Some(w) => w.rows[i],
            None => [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        }
    }

    /// `W_i v`: the whitening of point `i` applied to `v` (mm); `v` itself when the problem is
    /// plain.
    pub fn whiten(&self, i: usize, v: [f64; 3]) -> [f64; 3] {
        match &self.weights {
            Some(w) => w.rows[i].map(|row| row[0] * v[0] + row[1] * v[1] + row[2] * v[2]),
            None => v,
        }
    }

    /// Checks that the measured points have the size the machine gives them, which catches a
    /// measurement file in the wrong units (metres or inches instead of mm, radians instead of
    /// degrees) or a machine file whose reflector offsets or chain do not describe the machine
    /// measured. It compares the RMS distance of the measured points from their centroid with
    /// that of the points the model predicts at its start: a rigid motion (the tracker's pose)
    /// changes neither, and geometric errors change the ratio by parts per thousand at most.
    /// A ratio outside [0.98, 1.02] is an error naming `file`. Fewer than three points, and
    /// meshes whose nominal points spread less than 10 mm pass unchecked.
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
        self.check_scale_in(file, None)
    }

    /// [`Problem::check_scale`] for coordinates converted from `read_in` (the unit's name and
    /// its size in mm, as an import profile's `length_unit` states it): the hint then names the
    /// unit the export's lengths look like instead of the profile's.
    pub fn check_scale_in(&self, file: &str, read_in: Option<(&str, f64)>) -> Result<()> {
        let (model, data) = (self.model, self.data);
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
        let hint = if let Some((unit, mm)) = read_in {
            // The unit the export's lengths are in, if it is one of the profile's units.
            [("mm", 1.0), ("m", 1000.0), ("in", 25.4), ("µm", 1e-3)]
                .into_iter()
                .find(|(_, size)| ((mm / ratio) / size - 1.0).abs() < 0.02)
                .map_or_else(String::new, |(name, _)| {
                    format!(
                        " (the export's lengths look like {name}, but the import profile reads \
                         them in {unit}: set its length_unit = \"{name}\")"
                    )
                })
        } else if (ratio * 1000.0 - 1.0).abs() < 0.02 {
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

    /// Where the model is not finite at `params`: the first point whose residual or Jacobian
    /// has a non-finite entry, named by its line in the data, reflector and station, with its
    /// distance from the station (a station at a reflector measures no direction). `None` when
    /// every point is finite there.
    pub fn first_non_finite(&self, params: &[f64]) -> Option<String> {
        let mut jac = vec![0.0; 3 * self.model.n_params()];
        let i = (0..self.data.points.len()).find(|&i| {
            jac.iter_mut().for_each(|v| *v = 0.0);
            let r = self.residual_and_jacobian(i, params, &mut jac);
            !(r.iter().all(|v| v.is_finite()) && jac.iter().all(|v| v.is_finite()))
        })?;
        let p = &self.data.points[i];
        let predicted = self.model.observe_cached(&self.regressors, i, p, params);
        let range = match p.observation {
            crate::measure::Observation::Range => predicted[0].abs(),
            crate::measure::Observation::Point => norm(predicted),
        };
        let station = p
            .station
            .as_deref()
            .map_or(String::new(), |s| format!(", station {s}"));
        let near = if range < 1e-6 {
            ": the reflector is at the station there (a range of 0 mm has no direction); move \
             the station off the reflector's path in the machine file"
        } else {
            ""
        };
        Some(format!(
            "line {} of the data (reflector {}{station}): the model is not finite there, \
             {range:.6} mm from the station{near}",
            p.line,
            self.model.machine().reflectors()[p.reflector].id
        ))
    }

    /// The model.
    pub fn model(&self) -> &'a Model {
        self.model
    }

    /// The measurements.
    pub fn data(&self) -> &'a MeasurementSet {
        self.data
    }
}

impl Residuals for Problem<'_> {
    fn n_params(&self) -> usize {
        self.model.n_params()
    }

    fn n_points(&self) -> usize {
        self.data.points.len()
    }

    fn param_names(&self) -> Vec<String> {
        self.model.params().iter().map(|p| p.name.clone()).collect()
    }

    fn constraints(&self) -> Cow<'_, Constraints> {
        Cow::Borrowed(self.model.constraints())
    }

    fn residual(&self, i: usize, params: &[f64]) -> [f64; 3] {
        let m = &self.data.points[i];
        let r = minus(
            self.model.observe_cached(&self.regressors, i, m, params),
            m.measured,
        );
        self.whiten(i, r)
    }

    fn residual_and_jacobian(&self, i: usize, params: &[f64], jac: &mut [f64]) -> [f64; 3] {
        let m = &self.data.points[i];
        let x = self
            .model
            .observe_with_jacobian_cached(&self.regressors, i, m, params, jac);
        if let Some(w) = &self.weights {
            whiten_rows(&w.rows[i], jac);
        }
        self.whiten(i, minus(x, m.measured))
    }

    fn residual_second_directional(&self, i: usize, params: &[f64], dir: &[f64]) -> [f64; 3] {
        let d = self
            .model
            .observe_second_directional(&self.data.points[i], params, dir);
        self.whiten(i, d)
    }

    fn observation_scale(&self, i: usize) -> f64 {
        let gain = match &self.weights {
            Some(w) => w.rows[i].iter().map(|row| norm(*row)).fold(0.0, f64::max),
            None => 1.0,
        };
        norm(self.data.points[i].measured) * gain
    }

    fn whitened(&self) -> bool {
        self.is_whitened()
    }

    fn scalar(&self, i: usize) -> bool {
        self.data.points[i].observation == crate::measure::Observation::Range
    }

    fn machine(&self) -> Option<&Problem<'_>> {
        Some(self)
    }
}

/// `jac` (row-major 3 × n) replaced by `w · jac`.
fn whiten_rows(w: &[[f64; 3]; 3], jac: &mut [f64]) {
    let n = jac.len() / 3;
    for j in 0..n {
        let col = [jac[j], jac[n + j], jac[2 * n + j]];
        for (c, row) in w.iter().enumerate() {
            jac[c * n + j] = row[0] * col[0] + row[1] * col[1] + row[2] * col[2];
        }
    }
}

/// A curve fit: one of NIST's StRD problems, so that the engines can be judged on the public
/// reference suite. Each observation is a scalar "point" whose residual is `(f(x_i; b) − y_i, 0,
/// 0)`, Φ is the mean absolute residual and `n · ve` the residual sum of squares; there are no
/// constraints. Its parameters are named `b1`, `b2`, … Its derivatives come from the dataset's
/// model written once, generic over the scalar ([`crate::nist::Dataset::residual`]), through
/// [`AutoDiff`].
pub type CurveFit<'a> = AutoDiff<Scalar<StrdCurve<'a>>>;

impl<'a> CurveFit<'a> {
    /// The curve fit of `dataset` (see the type's documentation).
    pub fn new(dataset: &'a crate::nist::Dataset) -> CurveFit<'a> {
        AutoDiff(Scalar(StrdCurve { dataset }))
    }

    /// The dataset.
    pub fn dataset(&self) -> &'a crate::nist::Dataset {
        self.0.0.dataset
    }
}

/// One of NIST's StRD problems as a [`ScalarResidual`] (see [`CurveFit`]).
#[derive(Clone, Copy, Debug)]
pub struct StrdCurve<'a> {
    dataset: &'a crate::nist::Dataset,
}

impl ScalarResidual for StrdCurve<'_> {
    fn n_params(&self) -> usize {
        self.dataset.n_params()
    }

    fn n_points(&self) -> usize {
        self.dataset.n_obs()
    }

    fn residual<S: crate::scalar::Real>(&self, i: usize, params: &[S]) -> S {
        self.dataset.residual(i, params)
    }

    fn param_names(&self) -> Vec<String> {
        (1..=self.n_params()).map(|k| format!("b{k}")).collect()
    }

    fn observation_scale(&self, i: usize) -> f64 {
        self.dataset.observation(i).abs()
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
