//! How far to trust what a fit determines: the covariance of the parameters, linearised (GUM)
//! or by Monte Carlo (GUM Supplement 1), propagated to any linear function of them (an error
//! function's value, a controller table's entry) and to the tool point at any command and tool
//! offset, raw or after the set-up's rigid transform.
//!
//! **Linearised.** The estimate solves `Σ_i J_iᵀ ψ(r_i) = 0` on the constraint set (the model's
//! constraints and the gauge's, [`crate::engines::gauge`]), with `ψ(r) = r/‖r‖` for Φ and `ψ(r) = r` for
//! ve. Its covariance is the sandwich `A⁻¹ B A⁻¹` of M-estimation, `A = Σ J_iᵀ E[∂ψ/∂r] J_i`,
//! `B = Σ J_iᵀ E[ψ ψᵀ] J_i`, reduced to the free coordinates, with the expectations taken over
//! the noise of each point: the tracker's spherical model ([`TrackerNoise`], azimuth, elevation
//! and range at the point's own distance, normal or uniform) when it is given, else an isotropic
//! normal with the residuals' variance. The expectations are in closed form for the isotropic
//! normal and a product Gauss rule over the tracker's three deviates, so the result is
//! deterministic and free of sampling noise.
//!
//! **The gauge's combinations.** The data say nothing about the combinations the gauge holds;
//! their values are the reference's by rule. A quantity that depends on one is not determined by
//! the data: its uncertainty carries a prior of [`HELD_PRIOR_MM`] RMS along each held
//! combination ([`Covariance::held`]), reported apart from the data's part so that the user can
//! see which combination a large value comes from.
//!
//! **Monte Carlo.** [`monte_carlo`] re-simulates the noise around the fitted model and solves
//! again N times (the same engine, constraints and gauge), seeded, on every core; the spread of
//! any quantity over the replicas is its Monte Carlo uncertainty.

use crate::engines::gauge::Gauge;
use crate::nullspace::NullSpace;
use crate::{Objective, Options, Silent, Task};
use faer::{Mat, Side};
use rayon::prelude::*;
use volver_core::machine::Commands;
use volver_core::measure::MeasurementSet;
use volver_core::model::Model;
use volver_core::noise::{Distribution, TrackerNoise};
use volver_core::problem::{Problem, Residuals};
use volver_core::random::Rng;
use volver_core::results::UncertaintyRecord;

/// Prior standard deviation (mm RMS of the error functions, angles × [`crate::engines::gauge::LEVER_MM`],
/// so 100 µm or 100 µrad) of each combination the gauge holds: the size a machine's unidentified
/// combination may plausibly have, for quantities that depend on one.
pub const HELD_PRIOR_MM: f64 = 0.1;

/// The coverage factor of every expanded uncertainty volver prints (k = 2, about 95 %).
pub const K: f64 = 2.0;

/// What the measurement noise is taken to be.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum NoiseModel {
    /// The tracker's spherical model, as `simulate --noise`.
    Tracker(TrackerNoise),
    /// Isotropic normal with the residuals' variance per coordinate.
    Residual,
}

impl std::fmt::Display for NoiseModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            NoiseModel::Tracker(t) => write!(f, "tracker {t}"),
            NoiseModel::Residual => write!(f, "isotropic normal, σ from the residuals"),
        }
    }
}

impl NoiseModel {
    /// One noisy reading of `x`, what the measurement `m` observes without noise (a point in its
    /// station's frame, or `[range, 0, 0]`), mm: the tracker's model of `m`'s station (its own
    /// noise when the machine file states one, `machine`), or the isotropic σ `sigma_mm` of
    /// [`NoiseModel::Residual`]; a range moves by the noise's range part alone, as the
    /// generator's.
    fn read(
        &self,
        machine: &volver_core::machine::Machine,
        m: &volver_core::measure::Measurement,
        x: [f64; 3],
        sigma_mm: f64,
        rng: &mut Rng,
    ) -> [f64; 3] {
        let range = m.observation == volver_core::measure::Observation::Range;
        match self {
            NoiseModel::Tracker(t) => {
                let t = machine.station_noise_or(m.station_index, *t);
                if range {
                    let y = t.apply([x[0], 0.0, 0.0], rng);
                    [volver_core::problem::norm(y), 0.0, 0.0]
                } else {
                    t.apply(x, rng)
                }
            }
            NoiseModel::Residual => {
                let e = [rng.normal(), rng.normal(), rng.normal()].map(|v| sigma_mm * v);
                if range {
                    [x[0] + e[0], 0.0, 0.0]
                } else {
                    [x[0] + e[0], x[1] + e[1], x[2] + e[2]]
                }
            }
        }
    }
}

/// The covariance of the parameters as factors: `Cov(p) = D Dᵀ + H Hᵀ`.
#[derive(Clone, Debug)]
pub struct Covariance {
    /// The data's part (n × k, parameters' units): from the noise through the fit.
    pub data: Mat<f64>,
    /// The gauge's part (n × h): one column per held combination, its direction times
    /// [`HELD_PRIOR_MM`].
    pub held: Mat<f64>,
    /// Residual standard deviation per coordinate (mm).
    pub sigma_mm: f64,
    /// The noise model used.
    pub noise: NoiseModel,
}

impl Covariance {
    /// Standard uncertainty of `gᵀp` from the data alone.
    pub fn u_data(&self, g: &[f64]) -> f64 {
        norm_of_product(&self.data, g)
    }

    /// Standard uncertainty of `gᵀp` from the held combinations' prior alone, and the index of
    /// the combination that contributes most (`None` when none does).
    pub fn u_held(&self, g: &[f64]) -> (f64, Option<usize>) {
        let mut sum = 0.0;
        let mut best = (0.0, None);
        for c in 0..self.held.ncols() {
            let v: f64 = (0..g.len()).map(|j| self.held[(j, c)] * g[j]).sum();
            sum += v * v;
            if v.abs() > best.0 {
                best = (v.abs(), Some(c));
            }
        }
        (sum.sqrt(), best.1)
    }

    /// Standard uncertainty of `gᵀp`: data and held combinations together.
    pub fn u(&self, g: &[f64]) -> f64 {
        self.u_data(g).hypot(self.u_held(g).0)
    }

    /// Standard uncertainty of every parameter: (from the data, from the held combinations'
    /// prior).
    pub fn parameter_parts(&self) -> Vec<(f64, f64)> {
        let row = |f: &Mat<f64>, j: usize| {
            (0..f.ncols())
                .map(|c| f[(j, c)] * f[(j, c)])
                .sum::<f64>()
                .sqrt()
        };
        (0..self.data.nrows())
            .map(|j| (row(&self.data, j), row(&self.held, j)))
            .collect()
    }

    /// Standard uncertainty of every parameter (data and held combinations).
    pub fn parameters(&self) -> Vec<f64> {
        self.parameter_parts()
            .into_iter()
            .map(|(d, h)| d.hypot(h))
            .collect()
    }

    /// The record a results file keeps; `held` names each held combination.
    pub fn to_record(&self, gauge: &str, held: Vec<String>) -> UncertaintyRecord {
        let cols = |f: &Mat<f64>| -> Vec<Vec<f64>> {
            (0..f.ncols())
                .map(|c| (0..f.nrows()).map(|j| f[(j, c)]).collect())
                .collect()
        };
        UncertaintyRecord {
            gauge: gauge.to_string(),
            noise: self.noise.to_string(),
            sigma_mm: self.sigma_mm,
            held_prior_mm: if self.held.ncols() > 0 {
                HELD_PRIOR_MM
            } else {
                0.0
            },
            held,
            data_factor: cols(&self.data),
            held_factor: cols(&self.held),
            model_check: None,
        }
    }

    /// The covariance a results file recorded (checked by `ResultsFile::to_model`); its noise
    /// model reads as the residuals' (the record keeps it as text).
    pub fn from_record(r: &UncertaintyRecord, n: usize) -> Covariance {
        let mat = |cols: &[Vec<f64>]| Mat::from_fn(n, cols.len(), |j, c| cols[c][j]);
        Covariance {
            data: mat(&r.data_factor),
            held: mat(&r.held_factor),
            sigma_mm: r.sigma_mm,
            noise: NoiseModel::Residual,
        }
    }
}

fn norm_of_product(f: &Mat<f64>, g: &[f64]) -> f64 {
    (0..f.ncols())
        .map(|c| (0..g.len()).map(|j| f[(j, c)] * g[j]).sum::<f64>().powi(2))
        .sum::<f64>()
        .sqrt()
}

/// The linearised covariance of the fit `params` of `problem` under `objective`, with the
/// gauge `gauge` (whose combinations get no variance from the data and [`HELD_PRIOR_MM`] in
/// [`Covariance::held`]) and the noise model `noise`. `None` when the Jacobian is not finite or
/// a decomposition fails.
///
/// ```
/// use volver_core::{machine::Machine, model::Model, plan::Plan, problem::Problem};
/// use volver_core::noise::TrackerNoise;
/// use volver_core::simulate::{Magnitudes, Simulation, Truth};
/// use volver_solvers::uncertainty::{NoiseModel, linear};
/// let m = Machine::default_xcfz();
/// let truth = Truth::random_complete(&m, &Magnitudes::default(), 2).unwrap();
/// let mut sim = Simulation::new(Plan::preset(&m, "test3").unwrap(), truth, 2);
/// sim.noise = TrackerNoise::PAPER;
/// let data = sim.run().unwrap().measurements;
/// let model = Model::default_xcfz();
/// let problem = Problem::new(&model, &data).unwrap();
/// let id = volver_solvers::strategy::fit(problem.clone());
/// let noise = NoiseModel::Tracker(TrackerNoise::PAPER);
/// let cov = linear(&problem, id.gauge.as_ref(), &id.params, Default::default(), noise).unwrap();
/// // EXX's linear term alone trades with nearly flat combinations on test 3: the data
/// // determine it only to about 20 µm (k = 1); the tool point they determine much better.
/// let mut g = vec![0.0; model.n_params()];
/// g[model.param_index("EXX.c1").unwrap()] = 1.0;
/// let u = cov.u_data(&g);
/// assert!(u > 1e-3 && u < 0.1, "{u}");
/// ```
pub fn linear(
    problem: &Problem,
    gauge: Option<&Gauge>,
    params: &[f64],
    objective: Objective,
    noise: NoiseModel,
) -> Option<Covariance> {
    let n = params.len();
    let npts = problem.n_points();
    let (plain, fitted) = fitted_residuals(problem, objective, noise)?;
    let mut task = Task::new(plain.clone());
    if let Some(g) = gauge {
        task = g.apply(&task);
    }
    let ns = NullSpace::from_constraints(&task.constraints, params).ok()?;
    let nf = ns.n_free();
    let basis = ns.basis();
    let residuals = plain.residuals(params);
    let sq: f64 = residuals
        .iter()
        .map(|r| r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
        .sum();
    // A range alone is one coordinate, a point three.
    let coordinates: usize = (0..npts)
        .map(|i| if problem.scalar(i) { 1 } else { 3 })
        .sum();
    let sigma_mm = (sq / coordinates.saturating_sub(nf).max(1) as f64).sqrt();
    let mut a = Mat::<f64>::zeros(nf, nf);
    let mut b = Mat::<f64>::zeros(nf, nf);
    // The Gauss rules over the tracker's deviates, once (the isotropic normal needs none).
    let rules = match noise {
        NoiseModel::Tracker(_) => [Distribution::Normal.rule(), Distribution::Uniform.rule()],
        NoiseModel::Residual => [Vec::new(), Vec::new()],
    };
    let mut jac = vec![0.0; 3 * n];
    let loss = objective.loss();
    for i in 0..npts {
        // The residuals the estimator weighs (whitened for ml and phi-w) and their Jacobian.
        fitted.residual_and_jacobian(i, params, &mut jac);
        if jac.iter().any(|v| !v.is_finite()) {
            return None;
        }
        // The point's Jacobian in the free coordinates (3 × nf).
        let jz = Mat::from_fn(3, nf, |c, k| {
            (0..n).map(|j| jac[c * n + j] * basis[(j, k)]).sum::<f64>()
        });
        let (ea, eb) = point_expectations(&fitted, i, (loss, noise), sigma_mm, &rules);
        let ea = Mat::from_fn(3, 3, |r, c| ea[r][c]);
        let eb = Mat::from_fn(3, 3, |r, c| eb[r][c]);
        a += jz.transpose() * (&ea * &jz);
        b += jz.transpose() * (&eb * &jz);
    }
    let fz = sandwich_factor(&a, &b)?;
    let data = basis * &fz;
    let held = match gauge {
        Some(g) => Mat::from_fn(n, g.held.len(), |j, c| {
            g.held[c].direction[j] * HELD_PRIOR_MM
        }),
        None => Mat::zeros(n, 0),
    };
    Some(Covariance {
        data,
        held,
        sigma_mm,
        noise,
    })
}

/// [`expectations`] (or [`range_expectations`]) at point `i` of `fitted` (the residuals the
/// estimator weighs): its own station's noise, and the whitening applied to it; `rules` are the
/// Gauss rules of the normal and the uniform distribution.
fn point_expectations(
    fitted: &Problem,
    i: usize,
    (loss, noise): (Objective, NoiseModel),
    sigma_mm: f64,
    rules: &[Vec<(f64, f64)>; 2],
) -> ([[f64; 3]; 3], [[f64; 3]; 3]) {
    let point = &fitted.data().points[i];
    let x = point.measured;
    let noise_i = match noise {
        NoiseModel::Tracker(t) => NoiseModel::Tracker(
            fitted
                .model()
                .machine()
                .station_noise_or(point.station_index, t),
        ),
        NoiseModel::Residual => NoiseModel::Residual,
    };
    let w = fitted.whitening_of(i);
    if fitted.scalar(i) {
        return range_expectations(loss, noise_i, x[0], sigma_mm, w[0][0]);
    }
    let rule = match noise_i {
        NoiseModel::Tracker(t) if t.distribution == Distribution::Uniform => &rules[1],
        _ => &rules[0],
    };
    expectations(loss, noise_i, x, sigma_mm, rule, &w)
}

/// The residuals in mm and those the estimator of `objective` weighs: the same for Φ and ve,
/// whitened by each station's noise for ml and phi-w (`None` without a tracker noise model to
/// whiten by, or when the whitening fails).
fn fitted_residuals<'a>(
    problem: &Problem<'a>,
    objective: Objective,
    noise: NoiseModel,
) -> Option<(Problem<'a>, Problem<'a>)> {
    let plain = problem.plain();
    let fitted = weighed(&plain, objective, noise).ok()?;
    Some((plain, fitted))
}

/// The residuals the estimator of `objective` weighs: `problem` itself for Φ and ve, whitened
/// for ml and phi-w by each station's noise — its own where the machine file states one, else
/// the tracker model of `noise` (with [`NoiseModel::Residual`], only the stations' own).
/// `Err` names a station without a usable noise.
pub fn weighed<'a>(
    problem: &Problem<'a>,
    objective: Objective,
    noise: NoiseModel,
) -> Result<Problem<'a>, volver_core::Error> {
    if !objective.whitened() {
        return Ok(problem.clone());
    }
    let default = match noise {
        NoiseModel::Tracker(t) => Some(t),
        NoiseModel::Residual => None,
    };
    problem.whitened(default.as_ref())
}

/// A factor `F` of the sandwich `A⁺ B A⁺ = F Fᵀ` (both `nf × nf`, symmetric, `B` positive
/// semi-definite): `F = A⁺ L` with `B = L Lᵀ`. `A`'s pseudo-inverse is taken after Jacobi
/// scaling (D = √diag A): in the parameters' own units (mm, rad, ppm/h side by side) a weak but
/// identified direction can fall below any relative threshold and would get no variance at
/// all; scaled, the threshold measures redundancy alone. `None` when a decomposition fails.
fn sandwich_factor(a: &Mat<f64>, b: &Mat<f64>) -> Option<Mat<f64>> {
    let nf = a.nrows();
    let d: Vec<f64> = (0..nf)
        .map(|k| {
            let v = a[(k, k)].max(0.0).sqrt();
            if v > 0.0 { v } else { 1.0 }
        })
        .collect();
    let a_scaled = Mat::from_fn(nf, nf, |r, c| a[(r, c)] / (d[r] * d[c]));
    let ea = a_scaled.self_adjoint_eigen(Side::Lower).ok()?;
    let (sa, va) = (ea.S().column_vector(), ea.U());
    let amax = (0..nf).map(|i| sa[i].abs()).fold(0.0_f64, f64::max);
    let eb = b.self_adjoint_eigen(Side::Lower).ok()?;
    let (sb, vb) = (eb.S().column_vector(), eb.U());
    let l = Mat::from_fn(nf, nf, |r, c| vb[(r, c)] * sb[c].max(0.0).sqrt() / d[r]);
    // A⁺ L = D⁻¹ V diag(1/s) Vᵀ D⁻¹ L, directions below 1e-15 of the largest left out
    // (exactly redundant: they carry no information and the gauge should have held them).
    let vtl = va.transpose() * &l;
    let scaled = Mat::from_fn(nf, nf, |r, c| {
        if sa[r] > 1e-15 * amax {
            vtl[(r, c)] / sa[r]
        } else {
            0.0
        }
    });
    let vz = va * &scaled;
    Some(Mat::from_fn(nf, nf, |r, c| vz[(r, c)] / d[r]))
}

/// [`expectations`] for a range alone measured at `range` (mm): only the first coordinate is a
/// residual, and only the noise's range part moves it. Least squares: `E[∂ψ/∂r] = 1`,
/// `E[ψ²] = σ²`; Φ (the absolute value, an L1 fit): `E[∂ψ/∂r] = 2 f(0)`, the density of the
/// range noise at zero (`1/(σ√(2π))` for a normal, `1/(2a)` for a uniform on ±a), and
/// `E[ψ²] = 1`. The estimator weighs the residual by `scale` (1/σ of the range for ml and
/// phi-w, 1 else): `E[∂ψ/∂r]` and `E[ψ²]` are then those of the scaled residual.
fn range_expectations(
    objective: Objective,
    noise: NoiseModel,
    range: f64,
    sigma_mm: f64,
    scale: f64,
) -> ([[f64; 3]; 3], [[f64; 3]; 3]) {
    let (sigma, density0) = match noise {
        NoiseModel::Residual => (
            sigma_mm,
            1.0 / (sigma_mm * (2.0 * std::f64::consts::PI).sqrt()),
        ),
        NoiseModel::Tracker(t) => {
            let value = t.range_value_mm(range).max(f64::MIN_POSITIVE);
            let density = match t.distribution {
                volver_core::noise::Distribution::Normal => {
                    1.0 / (value * (2.0 * std::f64::consts::PI).sqrt())
                }
                volver_core::noise::Distribution::Uniform => 1.0 / (2.0 * value),
            };
            (t.range_sigma_mm(range), density)
        }
    };
    let one = |v: f64| {
        let mut m = [[0.0; 3]; 3];
        m[0][0] = v;
        m
    };
    if objective.loss() == Objective::Ve {
        (one(1.0), one((scale * sigma).powi(2)))
    } else {
        (one(2.0 * density0 / scale), one(1.0))
    }
}

/// `E[∂ψ/∂r]` and `E[ψψᵀ]` at a point measured at `x` (the residual at the truth is minus the
/// noise). Least squares (ve, ml) in closed form: `I` and the noise's covariance `W Σ Wᵀ` at the
/// point (linearised along its axes; σ² I for the isotropic normal). For the isotropic normal `Φ` gives
/// `(2/3) E[1/‖r‖] I = (2/3) √(2/π)/σ I` and `I/3`. For the tracker's model, by a product Gauss
/// rule over its three deviates ([`volver_core::noise::Distribution::rule`], 16³ nodes; a deterministic
/// quadrature, within 1 % of sampled means in the tests). No random draws: noise in these expectations would not share the
/// normal matrix' structure, and the information matrix `A B⁻¹ A` that the priors
/// ([`crate::analysis::prior`]) combine with would carry it from the strong directions into the weak ones.
///
/// The estimator weighs the residual by `w` (its whitening for ml and phi-w, the identity
/// else): the expectations are those of `w r`.
fn expectations(
    objective: Objective,
    noise: NoiseModel,
    x: [f64; 3],
    sigma_mm: f64,
    rule: &[(f64, f64)],
    w: &[[f64; 3]; 3],
) -> ([[f64; 3]; 3], [[f64; 3]; 3]) {
    let diag = |v: f64| {
        let mut m = [[0.0; 3]; 3];
        for (i, row) in m.iter_mut().enumerate() {
            row[i] = v;
        }
        m
    };
    let tracker = match noise {
        // Weighted only with a tracker model (`fitted_residuals`): w is the identity here.
        NoiseModel::Residual if objective.loss() == Objective::Ve => {
            return (diag(1.0), diag(sigma_mm * sigma_mm));
        }
        NoiseModel::Residual => {
            return (
                diag(2.0 / 3.0 * (2.0 / std::f64::consts::PI).sqrt() / sigma_mm),
                diag(1.0 / 3.0),
            );
        }
        NoiseModel::Tracker(t) => t,
    };
    if objective.loss() == Objective::Ve {
        // Least squares: E[∂ψ/∂r] = I and E[ψψᵀ] = W Σ Wᵀ, Σ the noise's covariance at the
        // point along its linearised axes (σ² of each), in closed form.
        let mut eb = [[0.0; 3]; 3];
        for (u, s) in tracker.axes(x) {
            let wu = w.map(|row| row[0] * u[0] + row[1] * u[1] + row[2] * u[2]);
            for p in 0..3 {
                for q in 0..3 {
                    eb[p][q] += s * s * wu[p] * wu[q];
                }
            }
        }
        return (diag(1.0), eb);
    }
    let mut ea = [[0.0; 3]; 3];
    let mut eb = [[0.0; 3]; 3];
    for &(za, wa) in rule {
        for &(ze, we) in rule {
            for &(zr, wr) in rule {
                let weight = wa * we * wr;
                let y = tracker.apply_deviates(x, [za, ze, zr]);
                let d = [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
                let r = w.map(|row| row[0] * d[0] + row[1] * d[1] + row[2] * d[2]);
                match objective.loss() {
                    Objective::Phi => {
                        let nr = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
                        if nr == 0.0 {
                            continue;
                        }
                        let u = [r[0] / nr, r[1] / nr, r[2] / nr];
                        for p in 0..3 {
                            for q in 0..3 {
                                let id = if p == q { 1.0 } else { 0.0 };
                                ea[p][q] += weight * (id - u[p] * u[q]) / nr;
                                eb[p][q] += weight * u[p] * u[q];
                            }
                        }
                    }
                    _ => {
                        for p in 0..3 {
                            ea[p][p] += weight;
                            for q in 0..3 {
                                eb[p][q] += weight * r[p] * r[q];
                            }
                        }
                    }
                }
            }
        }
    }
    (ea, eb)
}

/// The most Monte Carlo replicas [`monte_carlo`] runs: 100 000 (GUM Supplement 1's 10⁵ for a
/// 95 % interval; about 15 min of test 4 on two cores, each replica's parameters kept).
pub const MAX_REPLICAS: usize = 100_000;

/// The parameters of `n` Monte Carlo replicas (2 ≤ `n` ≤ [`MAX_REPLICAS`], checked first): the noise `noise` re-simulated around the points
/// the fitted model `params` predicts (the same commands, reflectors and times as `data`; the
/// isotropic σ `sigma_mm` for [`NoiseModel::Residual`]), each replica solved again from
/// `params` by the engine named `engine` with `options`, under the model's constraints and the
/// gauge's (the same combinations held at the same reference: the gauge is part of what is
/// measured). Replica `r` draws from a generator seeded by `seed` and `r`, on every core, so the
/// result does not depend on the number of threads. `progress` is called with the number of
/// replicas done. Replicas whose solve failed are left out and counted.
#[allow(clippy::too_many_arguments)]
pub fn monte_carlo(
    engine: &str,
    model: &Model,
    data: &MeasurementSet,
    params: &[f64],
    noise: NoiseModel,
    sigma_mm: f64,
    gauge: Option<&Gauge>,
    options: &Options,
    n: usize,
    seed: u64,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<MonteCarlo, crate::Error> {
    // No Newton polish of each replica: it moves a fit by ~1e-9 of its error functions, a
    // millionth of the spread measured here, and costs half of a replica's time.
    let mut settings = crate::Settings::default();
    settings.lm.polish = false;
    if !(2..=MAX_REPLICAS).contains(&n) {
        return Err(crate::Error::CountOutOfRange {
            what: "Monte Carlo replicas",
            value: n,
            min: 2,
            max: MAX_REPLICAS,
        });
    }
    crate::engine_with(engine, &settings)?;
    let done = std::sync::atomic::AtomicUsize::new(0);
    // What each measurement observes (its station's point, or range) by the fitted model.
    let predicted: Vec<[f64; 3]> = data
        .points
        .iter()
        .map(|p| model.observe(p, params))
        .collect();

    let t0 = std::time::Instant::now();
    let runs: Vec<Option<Vec<f64>>> = (0..n)
        .into_par_iter()
        .map(|r| {
            let solver = crate::engine_with(engine, &settings).ok()?;
            let mut rng = Rng::new(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ (r as u64 + 1));
            let mut set = data.clone();
            for (p, x) in set.points.iter_mut().zip(&predicted) {
                p.measured = noise.read(model.machine(), p, *x, sigma_mm, &mut rng);
            }
            let out = Problem::new(model, &set).ok().and_then(|problem| {
                let task = Task::new(weighed(&problem, options.objective, noise).ok()?);
                let task = match gauge {
                    Some(g) => g.apply(&task),
                    None => task,
                };
                let sol = solver.solve(&task, params, options, &mut Silent);
                (!sol.summary.termination.failed()).then_some(sol.params)
            });
            progress(done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1);
            out
        })
        .collect();
    let failed = runs.iter().filter(|r| r.is_none()).count();
    Ok(MonteCarlo {
        samples: runs.into_iter().flatten().collect(),
        failed,
        time_s: t0.elapsed().as_secs_f64(),
    })
}

/// Replicas of a fit.
#[derive(Clone, Debug)]
pub struct MonteCarlo {
    /// The parameters each successful replica reached.
    pub samples: Vec<Vec<f64>>,
    /// Replicas whose identification failed.
    pub failed: usize,
    /// Wall time (s).
    pub time_s: f64,
}

impl MonteCarlo {
    /// Standard deviation of `f` over the replicas.
    pub fn std_of(&self, f: impl Fn(&[f64]) -> f64) -> f64 {
        let v: Vec<f64> = self.samples.iter().map(|p| f(p)).collect();
        std_dev(&v)
    }
}

/// Sample standard deviation (0 for fewer than two values).
pub fn std_dev(v: &[f64]) -> f64 {
    if v.len() < 2 {
        return 0.0;
    }
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
}

/// A grid of commands and a tool offset whose tool points (in the workpiece frame) are judged:
/// raw, or after the set-up's rigid transform (the best rigid fit of the deviations over the
/// grid, which the workpiece's set-up absorbs).
#[derive(Clone, Debug)]
pub struct ToolGrid {
    /// The commands, internal units.
    pub commands: Vec<Commands>,
    /// The tool offset from the last tool-side axis (mm).
    pub tool: [f64; 3],
}

/// The uncertainty of one tool point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointUncertainty {
    /// The tool point in the workpiece frame (mm).
    pub tool_point_mm: [f64; 3],
    /// Expanded uncertainty (k = 2) of each coordinate from the data (mm).
    pub u95_data_mm: [f64; 3],
    /// Expanded uncertainty (k = 2) of each coordinate from the held combinations' prior (mm).
    pub u95_held_mm: [f64; 3],
    /// The held combination that contributes most (index into the gauge's list).
    pub worst_held: Option<usize>,
}

impl PointUncertainty {
    /// The expanded uncertainty of each coordinate, data and held combinations (mm).
    pub fn u95_mm(&self) -> [f64; 3] {
        std::array::from_fn(|c| self.u95_data_mm[c].hypot(self.u95_held_mm[c]))
    }

    /// The largest coordinate's expanded uncertainty (mm).
    pub fn u95_max_mm(&self) -> f64 {
        self.u95_mm().into_iter().fold(0.0, f64::max)
    }
}

impl ToolGrid {
    /// The tool points of `params` (mm, workpiece frame).
    pub fn points(&self, model: &Model, params: &[f64]) -> Vec<[f64; 3]> {
        self.commands
            .iter()
            .map(|c| model.tool_point(&c.0, &self.tool, params))
            .collect()
    }

    /// The Jacobian of the tool points (3K × n, row 3k + c for coordinate c of point k),
    /// after the set-up's rigid transform when `aligned`.
    pub fn jacobian(&self, model: &Model, params: &[f64], aligned: bool) -> Mat<f64> {
        let n = params.len();
        let k = self.commands.len();
        let mut g = Mat::<f64>::zeros(3 * k, n);
        let mut jac = vec![0.0; 3 * n];
        for (i, c) in self.commands.iter().enumerate() {
            model.tool_point_with_jacobian(c, &self.tool, params, &mut jac);
            for r in 0..3 {
                for j in 0..n {
                    g[(3 * i + r, j)] = jac[r * n + j];
                }
            }
        }
        if aligned {
            let points = self.points(model, params);
            for j in 0..n {
                let mut col: Vec<f64> = (0..3 * k).map(|r| g[(r, j)]).collect();
                remove_rigid(&points, &mut col);
                for (r, v) in col.into_iter().enumerate() {
                    g[(r, j)] = v;
                }
            }
        }
        g
    }

    /// The expanded uncertainty of every tool point under `cov` (k = [`K`]), after the set-up's
    /// rigid transform when `aligned`.
    pub fn uncertainty(
        &self,
        model: &Model,
        params: &[f64],
        cov: &Covariance,
        aligned: bool,
    ) -> Vec<PointUncertainty> {
        let g = self.jacobian(model, params, aligned);
        let yd = &g * &cov.data;
        let yh = &g * &cov.held;
        let points = self.points(model, params);
        points
            .iter()
            .enumerate()
            .map(|(i, &p)| {
                let row_norm = |y: &Mat<f64>, r: usize| {
                    (0..y.ncols())
                        .map(|c| y[(r, c)] * y[(r, c)])
                        .sum::<f64>()
                        .sqrt()
                };
                let mut worst = (0.0, None);
                for c in 0..yh.ncols() {
                    let v = (0..3).map(|r| yh[(3 * i + r, c)].powi(2)).sum::<f64>();
                    if v > worst.0 {
                        worst = (v, Some(c));
                    }
                }
                PointUncertainty {
                    tool_point_mm: p,
                    u95_data_mm: std::array::from_fn(|r| K * row_norm(&yd, 3 * i + r)),
                    u95_held_mm: std::array::from_fn(|r| K * row_norm(&yh, 3 * i + r)),
                    worst_held: worst.1,
                }
            })
            .collect()
    }

    /// The Monte Carlo expanded uncertainty (k = [`K`] standard deviations over the replicas)
    /// of each tool-point coordinate (mm, 3K values, point-major), the deviations taken from
    /// `base` and after the set-up's transform when `aligned`.
    pub fn monte_carlo_u95(
        &self,
        model: &Model,
        mc: &MonteCarlo,
        base: &[[f64; 3]],
        aligned: bool,
    ) -> Vec<f64> {
        let devs: Vec<Vec<f64>> = mc
            .samples
            .iter()
            .map(|p| self.deviations(model, p, base, aligned))
            .collect();
        (0..3 * base.len())
            .map(|k| K * std_dev(&devs.iter().map(|d| d[k]).collect::<Vec<_>>()))
            .collect()
    }

    /// The deviations of the tool points of `params` from `base` (mm, 3K values), after the
    /// set-up's rigid transform when `aligned` (the deviations are small, so the transform is
    /// the linearised best fit).
    pub fn deviations(
        &self,
        model: &Model,
        params: &[f64],
        base: &[[f64; 3]],
        aligned: bool,
    ) -> Vec<f64> {
        let pts = self.points(model, params);
        let mut d: Vec<f64> = pts
            .iter()
            .zip(base)
            .flat_map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
            .collect();
        if aligned {
            remove_rigid(base, &mut d);
        }
        d
    }
}

/// Removes from the displacement field `d` (3K values at `points`) its least-squares small rigid
/// motion `t + ω × (x − x̄)`.
pub fn remove_rigid(points: &[[f64; 3]], d: &mut [f64]) {
    let k = points.len();
    if k == 0 {
        return;
    }
    let mut c = [0.0; 3];
    for p in points {
        for r in 0..3 {
            c[r] += p[r] / k as f64;
        }
    }
    // Columns of the rigid basis at point i: translations e_r, rotations ω_r × (x − c).
    let basis = |i: usize, col: usize| -> [f64; 3] {
        if col < 3 {
            let mut e = [0.0; 3];
            e[col] = 1.0;
            e
        } else {
            let x = [
                points[i][0] - c[0],
                points[i][1] - c[1],
                points[i][2] - c[2],
            ];
            match col {
                3 => [0.0, -x[2], x[1]],
                4 => [x[2], 0.0, -x[0]],
                _ => [-x[1], x[0], 0.0],
            }
        }
    };
    let mut rtr = Mat::<f64>::zeros(6, 6);
    let mut rtd = Mat::<f64>::zeros(6, 1);
    for i in 0..k {
        let cols: Vec<[f64; 3]> = (0..6).map(|col| basis(i, col)).collect();
        for a in 0..6 {
            for b in 0..6 {
                rtr[(a, b)] += (0..3).map(|r| cols[a][r] * cols[b][r]).sum::<f64>();
            }
            rtd[(a, 0)] += (0..3).map(|r| cols[a][r] * d[3 * i + r]).sum::<f64>();
        }
    }
    let Ok(e) = rtr.self_adjoint_eigen(Side::Lower) else {
        return;
    };
    let (s, v) = (e.S().column_vector(), e.U());
    let smax = (0..6).map(|i| s[i]).fold(0.0_f64, f64::max);
    let vtd = v.transpose() * &rtd;
    let coef = v * Mat::from_fn(6, 1, |r, _| {
        if s[r] > 1e-12 * smax {
            vtd[(r, 0)] / s[r]
        } else {
            0.0
        }
    });
    for i in 0..k {
        for col in 0..6 {
            let b = basis(i, col);
            for r in 0..3 {
                d[3 * i + r] -= coef[(col, 0)] * b[r];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

    /// Sample means of `E[∂ψ/∂r]` and `E[ψψᵀ]` over `draws` seeded draws of the noise, the
    /// residual weighed by `w`.
    fn sampled(
        objective: Objective,
        noise: NoiseModel,
        x: [f64; 3],
        sigma: f64,
        draws: usize,
        w: &[[f64; 3]; 3],
    ) -> ([[f64; 3]; 3], [[f64; 3]; 3]) {
        let mut rng = Rng::new(7);
        let (mut ea, mut eb) = ([[0.0; 3]; 3], [[0.0; 3]; 3]);
        let weight = 1.0 / draws as f64;
        for _ in 0..draws {
            let e = match noise {
                NoiseModel::Tracker(t) => {
                    let y = t.apply(x, &mut rng);
                    [y[0] - x[0], y[1] - x[1], y[2] - x[2]]
                }
                NoiseModel::Residual => {
                    [rng.normal(), rng.normal(), rng.normal()].map(|v| sigma * v)
                }
            };
            let r = w.map(|row| -(row[0] * e[0] + row[1] * e[1] + row[2] * e[2]));
            let nr = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
            for p in 0..3 {
                for q in 0..3 {
                    let id = if p == q { 1.0 } else { 0.0 };
                    if objective.loss() == Objective::Phi {
                        ea[p][q] += weight * (id - r[p] * r[q] / (nr * nr)) / nr;
                        eb[p][q] += weight * r[p] * r[q] / (nr * nr);
                    } else {
                        ea[p][q] += weight * id;
                        eb[p][q] += weight * r[p] * r[q];
                    }
                }
            }
        }
        (ea, eb)
    }

    /// The closed forms and the Gauss rules agree with 400 000 draws (within 1 % of each
    /// matrix' largest entry, the draws' own scatter being ~0.3 %), for every objective (ml and
    /// phi-w weighed by the tracker's whitening at the point), the isotropic normal and the
    /// tracker's normal and uniform models at a near and a far point.
    #[test]
    fn expectations_match_sampled_means() {
        let uniform = TrackerNoise::PAPER;
        let normal = TrackerNoise {
            distribution: volver_core::noise::Distribution::Normal,
            ..TrackerNoise::PAPER
        };
        for objective in Objective::ALL {
            for noise in [
                NoiseModel::Residual,
                NoiseModel::Tracker(uniform),
                NoiseModel::Tracker(normal),
            ] {
                for x in [[900.0, -400.0, 300.0], [3500.0, 1200.0, -800.0]] {
                    let sigma = 0.02;
                    let (rule, w) = match noise {
                        NoiseModel::Tracker(t) if objective.whitened() => {
                            (t.distribution.rule(), t.whitening(x).unwrap())
                        }
                        NoiseModel::Tracker(t) => (t.distribution.rule(), IDENTITY),
                        // The residuals' σ weighs nothing: the weighted objectives need a model.
                        NoiseModel::Residual if objective.whitened() => continue,
                        NoiseModel::Residual => (Vec::new(), IDENTITY),
                    };
                    let (qa, qb) = expectations(objective, noise, x, sigma, &rule, &w);
                    let (sa, sb) = sampled(objective, noise, x, sigma, 400_000, &w);
                    for (q, s) in [(qa, sa), (qb, sb)] {
                        let big = s.iter().flatten().fold(0.0_f64, |m, v| m.max(v.abs()));
                        for p in 0..3 {
                            for c in 0..3 {
                                assert!(
                                    (q[p][c] - s[p][c]).abs() <= 0.01 * big,
                                    "{objective:?} {noise} at {x:?}: [{p}][{c}] {} against \
                                     sampled {}",
                                    q[p][c],
                                    s[p][c]
                                );
                            }
                        }
                    }
                }
            }
        }
    }
}
