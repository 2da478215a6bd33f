//! Prior magnitudes per error kind, and the maximum a posteriori (MAP) solution they give.
//!
//! By default volver fixes what the data cannot determine by the gauge's rule ([`crate::engines::gauge`]:
//! the unidentified combinations held at the reference, minimum norm in the function metric).
//! A metrologist who knows how large a machine's errors of each kind plausibly are can say so
//! instead: [`Priors`] gives each ISO 230 error kind (positioning, straightness, angular,
//! squareness, radial, axial, tilt, angular positioning, location, location tilt; the kinds of
//! [`Magnitudes`]) a prior magnitude, the RMS of each such error function over its travel. The
//! prior is normal, centred on the reference (zero errors), with precision
//! `M_w = Σ_f (mean square of f over its travel) / s_f²` ([`Priors::metric`]); the tracker's
//! pose and the other effects' parameters have a flat prior unless `tracker` is given (mm, the
//! same for its angles times [`crate::engines::gauge::LEVER_MM`]).
//!
//! [`maximum_a_posteriori`] combines it with what the data say, linearised as in GUM: the data
//! give the estimate `p̂` (on the gauge) with covariance `D Dᵀ` ([`Covariance::data`]) and say
//! nothing along the held combinations `G`. Writing `p = p̂ + D a + G b`, the likelihood is
//! `exp(−½ aᵀa)` and the prior `exp(−½ (p − p₀)ᵀ M_w (p − p₀))`, so the posterior is normal with
//! precision `Λ = diag(I, 0) + Eᵀ M_w E` (`E = [D G]`) and mean `p̂ − E Λ⁻¹ Eᵀ M_w (p̂ − p₀)`,
//! its covariance `E Λ⁻¹ Eᵀ`. This is exact for a model linear in its parameters with normal
//! noise; otherwise it is the GUM linearisation around `p̂`. Along a combination the data
//! determine well the prior changes nothing; along one they do not determine, the prior decides
//! and its U is the prior's; in between (nearly flat directions) the two are weighed.

use crate::analysis::uncertainty::Covariance;
use crate::engines::gauge::{Gauge, LEVER_MM, weighted_metric};
use faer::{Mat, Side};
use volver_core::iso::Unit;
use volver_core::model::Model;
use volver_core::simulate::{MAGNITUDE_KINDS, Magnitudes};

/// The range of a prior magnitude in its kind's unit (µm, µrad; mm for the tracker): from 1 nm
/// (1 nrad) to 1 m (1 rad).
pub const PRIOR_RANGE: (f64, f64) = (1e-3, 1e6);

/// Prior magnitudes per error kind (µm, µrad as in [`Magnitudes`]; `tracker` in mm). A kind
/// whose magnitude is zero gets a flat prior.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Priors {
    /// The magnitude of each kind.
    pub magnitudes: Magnitudes,
}

impl Priors {
    /// The priors of texts as the CLI's `--prior` takes them: `typical` (the magnitudes of a
    /// large, uncompensated machine tool, [`Magnitudes::default`]) or `KIND=VALUE` in the kind's
    /// unit, applied in order over the typical magnitudes.
    ///
    /// ```
    /// use volver_solvers::prior::Priors;
    /// let p = Priors::parse(&["straightness=5".to_string()]).unwrap();
    /// assert_eq!(p.magnitudes.straightness_um, 5.0);
    /// assert_eq!(p.magnitudes.positioning_um, 50.0); // typical
    /// assert!(Priors::parse(&["wobble=1".to_string()]).is_err());
    /// ```
    ///
    /// `KIND=flat` gives a kind a flat prior. A magnitude must lie within
    /// [`PRIOR_RANGE`] of the kind's unit: zero is not a prior (it would silently mean "flat"),
    /// and a tiny one (`angular=1e-300`) would make the precision overflow.
    pub fn parse(texts: &[String]) -> volver_core::Result<Priors> {
        use volver_core::error::{Error, Place};
        let mut magnitudes = Magnitudes::default();
        for t in texts {
            if t.trim() == "typical" {
                continue;
            }
            if let Some((kind, v)) = t.split_once('=')
                && v.trim() == "flat"
            {
                magnitudes.set_from_option(&format!("{kind}=0"), "--prior")?;
                continue;
            }
            magnitudes.set_from_option(t, "--prior")?;
            let kind = t.split_once('=').map_or("", |(k, _)| k.trim());
            let v = magnitudes.get(kind);
            let unit = MAGNITUDE_KINDS
                .iter()
                .find(|k| k.0 == kind)
                .map_or("", |k| k.1);
            if !(PRIOR_RANGE.0..=PRIOR_RANGE.1).contains(&v) {
                return Err(Error::input(
                    Place::file("--prior").at_field(t.clone()),
                    format!(
                        "a prior magnitude of {} {unit} is outside {} … {} {unit}; write \
                         {kind}=flat for a flat prior",
                        volver_core::error::number(v),
                        PRIOR_RANGE.0,
                        PRIOR_RANGE.1
                    ),
                ));
            }
        }
        Ok(Priors { magnitudes })
    }

    /// The prior standard deviation of an error function (mm or rad RMS over its travel);
    /// zero for a flat prior.
    pub fn sigma_of(&self, id: volver_core::iso::ErrorId) -> f64 {
        self.magnitudes.for_error(id)
    }

    /// The prior's precision `M_w` at `params` (a sine series' phases are weighed at their
    /// amplitude there): each error function's mean square over its travel divided by its
    /// kind's magnitude squared; the tracker's position over `tracker` mm squared and its angles
    /// over (`tracker` / [`LEVER_MM`]) rad squared; every other parameter flat.
    pub fn metric(&self, model: &Model, params: &[f64]) -> Mat<f64> {
        let tracker_mm = self.magnitudes.tracker_mm;
        weighted_metric(
            model,
            params,
            |id| {
                let s = self.sigma_of(id);
                if s > 0.0 { 1.0 / s } else { 0.0 }
            },
            |_, info| match (info.group, info.unit) {
                (volver_core::iso::Group::Tracker, Unit::Mm) if tracker_mm > 0.0 => {
                    1.0 / tracker_mm
                }
                (volver_core::iso::Group::Tracker, Unit::Rad) if tracker_mm > 0.0 => {
                    LEVER_MM / tracker_mm
                }
                _ => 0.0,
            },
        )
    }

    /// The rule, as every output that depends on it prints it.
    pub fn rule(&self) -> String {
        let m = self.magnitudes;
        let parts: Vec<String> = MAGNITUDE_KINDS
            .iter()
            .map(|(kind, unit, _)| {
                let v = m.get(kind);
                let kind = if *kind == "tracker" {
                    "tracker pose"
                } else {
                    kind
                };
                if v > 0.0 {
                    format!("{kind} {v} {unit}")
                } else {
                    format!("{kind} flat")
                }
            })
            .collect();
        format!(
            "maximum a posteriori: normal priors centred on zero errors (the tracker's on its \
             rigid fit) with RMS over the travel {} (other effects flat), combined with the \
             data's estimate on the gauge and its linearised covariance",
            parts.join(", ")
        )
    }
}

/// The posterior of [`maximum_a_posteriori`].
#[derive(Clone, Debug)]
pub struct Posterior {
    /// The MAP parameters.
    pub params: Vec<f64>,
    /// Their covariance, all of it in [`Covariance::data`] (no combination is left to a
    /// separate prior: the priors decide the ones the data do not).
    pub covariance: Covariance,
    /// How far the priors moved the solution from the data's estimate, in the prior's metric
    /// (`√(Δpᵀ M_w Δp)`, in prior standard deviations).
    pub shift: f64,
}

/// The maximum a posteriori solution for priors `priors`, from the data's estimate `params`
/// (on the gauge `gauge`, whose reference is the prior's centre) and its linearised covariance
/// `cov` ([`crate::analysis::uncertainty::linear`]). `None` when a decomposition fails or a value is not
/// finite.
///
/// ```
/// use volver_core::{machine::Machine, model::Model, plan::Plan, problem::{Problem, Residuals}};
/// use volver_core::simulate::{Magnitudes, Simulation, Truth};
/// use volver_core::noise::TrackerNoise;
/// use volver_solvers::prior::{Priors, maximum_a_posteriori};
/// use volver_solvers::uncertainty::{NoiseModel, linear};
/// let m = Machine::default_xcfz();
/// let model = Model::default_xcfz();
/// let truth = Truth::random(&m, model.spec(), &Magnitudes::default(), 3).unwrap();
/// let mut sim = Simulation::new(Plan::preset(&m, "test4").unwrap(), truth, 3);
/// sim.noise = TrackerNoise::PAPER;
/// let data = sim.run().unwrap().measurements;
/// let problem = Problem::new(&model, &data).unwrap();
/// let id = volver_solvers::strategy::fit(problem.clone());
/// let cov = linear(&problem, id.gauge.as_ref(), &id.params, Default::default(),
///                  NoiseModel::Residual).unwrap();
/// let priors = Priors::parse(&["typical".to_string()]).unwrap();
/// let post = maximum_a_posteriori(&model, id.gauge.as_ref(), &id.params, &cov, &priors).unwrap();
/// // The data determine most of the model: the fit stays as good (Φ within 1 %), while the
/// // combinations the data leave open now have the priors' values and U.
/// assert!(problem.phi(&post.params) < 1.01 * problem.phi(&id.params));
/// assert!(post.shift.is_finite() && post.covariance.held.ncols() == 0);
/// ```
pub fn maximum_a_posteriori(
    model: &Model,
    gauge: Option<&Gauge>,
    params: &[f64],
    cov: &Covariance,
    priors: &Priors,
) -> Option<Posterior> {
    let n = params.len();
    let reference = prior_centre(model, gauge, params);
    let mw = priors.metric(model, params);
    let k = cov.data.ncols();
    let e = data_and_held(cov, gauge, n);
    let m = e.ncols();
    let mwe = &mw * &e;
    let mut lambda = e.transpose() * &mwe;
    for c in 0..k {
        lambda[(c, c)] += 1.0;
    }
    let dp: Vec<f64> = params.iter().zip(&reference).map(|(p, r)| p - r).collect();
    // rhs = −Eᵀ M_w (p̂ − p₀).
    let rhs: Vec<f64> = (0..m)
        .map(|c| -(0..n).map(|j| mwe[(j, c)] * dp[j]).sum::<f64>())
        .collect();
    if (0..m).any(|a| (0..m).any(|b| !lambda[(a, b)].is_finite()))
        || rhs.iter().any(|v| !v.is_finite())
    {
        return None;
    }
    // Λ⁺ by its eigen-decomposition: a direction neither the data nor the prior sees (a flat
    // prior on a held combination) stays where the data's estimate put it, with no variance
    // (the gauge's rule still holds it).
    let eig = lambda.self_adjoint_eigen(Side::Lower).ok()?;
    let (s, v) = (eig.S().column_vector(), eig.U());
    let smax = (0..m).map(|i| s[i]).fold(0.0_f64, f64::max);
    let kept: Vec<usize> = (0..m).filter(|&i| s[i] > 1e-12 * smax).collect();
    let z = spectral_solve((s, v), &kept, &rhs);
    let step: Vec<f64> = (0..n)
        .map(|j| (0..m).map(|c| e[(j, c)] * z[c]).sum())
        .collect();
    let post: Vec<f64> = params.iter().zip(&step).map(|(p, d)| p + d).collect();
    let shift = metric_norm(&mw, &step);
    // Posterior factor E V diag(1/√s).
    let ev = &e * v;
    let factor = Mat::from_fn(n, kept.len(), |j, c| ev[(j, kept[c])] / s[kept[c]].sqrt());
    if post.iter().any(|x| !x.is_finite()) || !shift.is_finite() {
        return None;
    }
    Some(Posterior {
        params: post,
        covariance: Covariance {
            data: factor,
            held: Mat::zeros(n, 0),
            sigma_mm: cov.sigma_mm,
            noise: cov.noise,
        },
        shift,
    })
}

/// The prior's centre: the gauge's reference (zero errors, the tracker's rigid fit); without
/// a gauge, zero errors and the fit's own tracker pose from `params` (the tracker's prior then
/// pulls nowhere).
fn prior_centre(model: &Model, gauge: Option<&Gauge>, params: &[f64]) -> Vec<f64> {
    match gauge {
        Some(g) => g.reference.clone(),
        None => {
            let mut r = model.initial_params();
            let t = model.tracker_start();
            r[t..t + volver_core::kinematics::TRACKER_DOF]
                .copy_from_slice(&params[t..t + volver_core::kinematics::TRACKER_DOF]);
            r
        }
    }
}

/// `E = [D G]` (n rows): the data's covariance factor `D` ([`Covariance::data`]), then the
/// combinations the gauge holds (no information from the data), one column each.
fn data_and_held(cov: &Covariance, gauge: Option<&Gauge>, n: usize) -> Mat<f64> {
    let k = cov.data.ncols();
    let held: Vec<&Vec<f64>> = gauge
        .map(|g| g.held.iter().map(|h| &h.direction).collect())
        .unwrap_or_default();
    let m = k + held.len();
    Mat::from_fn(n, m, |j, c| {
        if c < k {
            cov.data[(j, c)]
        } else {
            held[c - k][j]
        }
    })
}

/// `Λ⁺ rhs` over the eigenvectors `kept` of `Λ = V diag(s) Vᵀ`: `Σ_kept v_i (v_iᵀ rhs) / s_i`.
fn spectral_solve(
    (s, v): (faer::ColRef<f64>, faer::MatRef<f64>),
    kept: &[usize],
    rhs: &[f64],
) -> Vec<f64> {
    let m = rhs.len();
    let mut z = vec![0.0; m];
    for &i in kept {
        let c = (0..m).map(|r| v[(r, i)] * rhs[r]).sum::<f64>() / s[i];
        for (r, zr) in z.iter_mut().enumerate() {
            *zr += c * v[(r, i)];
        }
    }
    z
}

/// `√(xᵀ M x)` (a negative square from rounding counts as zero).
fn metric_norm(metric: &Mat<f64>, x: &[f64]) -> f64 {
    let n = x.len();
    (0..n)
        .map(|a| x[a] * (0..n).map(|b| metric[(a, b)] * x[b]).sum::<f64>())
        .sum::<f64>()
        .max(0.0)
        .sqrt()
}
