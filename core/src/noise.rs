//! Laser-tracker noise in the tracker's own spherical coordinates (paper, section 6.2): noise on
//! the azimuth and the elevation (µrad) and on the range (µm plus µm per metre of range), either
//! normal (the four values are standard deviations) or uniform (the four values are bounds ±a,
//! σ = a/√3).
//!
//! **The paper's tracker is bounded.** The paper writes "a normal distribution of value (±30 µrad,
//! ±30 µrad, and ±4 µm ± 0.8 µm/m)". Read as σ of a normal distribution it gives a noise error far
//! above the paper's tables 9–10; read as the bounds of a uniform distribution it reproduces both
//! their mean and their maximum. Noise added to volver's noise-free table-4 and table-7 meshes
//! (seed 7, embedded machine, 20 draws):
//!
//! | mesh | reading | EMM µm | EMax µm | paper |
//! |---|---|---|---|---|
//! | table 4 | normal, σ = 30 µrad, 30 µrad, 4 µm + 0.8 µm/m | 53.0 | 169.3 | 31.3 / 57.8 (table 9) |
//! | table 4 | uniform on ±30 µrad, ±30 µrad, ±(4 µm + 0.8 µm/m) | 32.7 | 59.8 | 31.3 / 57.8 |
//! | table 7 | normal | 78.7 | 262.8 | 46.8 / 104.8 (table 10) |
//! | table 7 | uniform | 48.6 | 105.1 | 46.8 / 104.8 |
//!
//! The ratio EMax/EMM tells them apart: about 3.3 for a normal over these meshes, 1.8–2.2 in the
//! paper. [`TrackerNoise::PAPER`] is therefore the uniform reading; `normal:30,30,4,0.8` is the
//! literal one.
//!
//! ```
//! use volver_core::noise::TrackerNoise;
//! use volver_core::random::Rng;
//! let mut rng = Rng::new(1);
//! let p = [1000.0, 500.0, 300.0];
//! let q = TrackerNoise::PAPER.apply(p, &mut rng);
//! let d = ((q[0]-p[0]).powi(2) + (q[1]-p[1]).powi(2) + (q[2]-p[2]).powi(2)).sqrt();
//! assert!(d < 0.06); // mm: bounded by 30 µrad × 1.16 m in each angle plus 5 µm in range
//! assert_eq!(TrackerNoise::NONE.apply(p, &mut rng), p);
//! ```

use crate::random::Rng;
use crate::units::{MM_PER_M, UM_PER_MM, URAD_PER_RAD};

/// mm in one µm (`1e-3` bit for bit).
const MM_PER_UM: f64 = 1.0 / UM_PER_MM;

/// m in one mm (`1e-3` bit for bit).
const M_PER_MM: f64 = 1.0 / MM_PER_M;

/// rad in one µrad (`1e-6` bit for bit).
const RAD_PER_URAD: f64 = 1.0 / URAD_PER_RAD;
use serde::{Deserialize, Serialize};

/// The distribution of each of the tracker's three noise components.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Distribution {
    /// Normal; the values are standard deviations.
    #[default]
    Normal,
    /// Uniform on [−a, a]; the values are the bounds a (σ = a/√3).
    Uniform,
}

impl Distribution {
    /// The standard deviation of a component whose value (σ or bound) is `value`.
    pub fn sigma(self, value: f64) -> f64 {
        match self {
            Distribution::Normal => value,
            Distribution::Uniform => value / 3f64.sqrt(),
        }
    }

    /// The kurtosis `E[x⁴]/σ⁴` of a component: 3 for the normal, 9/5 for the uniform. The
    /// variance of a squared standardised deviate is `kurtosis − 1`: what the spread of a noise
    /// scale estimated from residuals ([`crate::diagnose::StationNoise`]) is made of.
    ///
    /// ```
    /// use volver_core::noise::Distribution;
    /// // The quadrature rule gets the normal's to 0.4 % (16 nodes), the uniform's exactly.
    /// for (d, within) in [(Distribution::Normal, 0.015), (Distribution::Uniform, 1e-12)] {
    ///     let (rule, s2) = (d.rule(), d.sigma(1.0).powi(2));
    ///     let fourth: f64 = rule.iter().map(|(x, w)| w * x.powi(4)).sum();
    ///     assert!((fourth / (s2 * s2) - d.kurtosis()).abs() < within, "{d:?} {fourth}");
    /// }
    /// ```
    pub fn kurtosis(self) -> f64 {
        match self {
            Distribution::Normal => 3.0,
            Distribution::Uniform => 9.0 / 5.0,
        }
    }

    /// The quadrature rule over one deviate (nodes, weights summing to 1), [`GAUSS_NODES`]
    /// nodes: Gauss–Legendre panels whose edges meet zero (where a module's integrand has its
    /// cusp), [−1, 0] and [0, 1] for the uniform distribution, [−6, −2], [−2, 0], [0, 2], [2, 6]
    /// weighted by the density for the normal one (renormalised: the tails beyond 6 σ hold
    /// 2e-9). Expectations over the tracker's noise are products of it over its three deviates:
    /// deterministic, with no sampling noise.
    ///
    /// ```
    /// use volver_core::noise::Distribution;
    /// for d in [Distribution::Normal, Distribution::Uniform] {
    ///     let rule = d.rule();
    ///     let (w, var): (f64, f64) = rule.iter().fold((0.0, 0.0), |a, (x, w)| (a.0 + w, a.1 + w * x * x));
    ///     assert!((w - 1.0).abs() < 1e-12);
    ///     // A deviate's variance: 1 for the normal (to 1.4e-4: 16 nodes), 1/3 for the uniform.
    ///     assert!((d.sigma(1.0).powi(2) - var).abs() < 2e-4, "{d:?}");
    /// }
    /// ```
    pub fn rule(self) -> Vec<(f64, f64)> {
        let edges: &[f64] = match self {
            Distribution::Uniform => &[-1.0, 0.0, 1.0],
            Distribution::Normal => &[-6.0, -2.0, 0.0, 2.0, 6.0],
        };
        let panels = edges.len() - 1;
        let base = crate::scalar::gauss_legendre(GAUSS_NODES / panels);
        let mut rule: Vec<(f64, f64)> = Vec::with_capacity(GAUSS_NODES);
        for p in edges.windows(2) {
            let (mid, half) = (0.5 * (p[0] + p[1]), 0.5 * (p[1] - p[0]));
            for &(z, w) in &base {
                let x = mid + half * z;
                let density = match self {
                    Distribution::Uniform => 0.5,
                    Distribution::Normal => (-0.5 * x * x).exp(),
                };
                // Gauss–Legendre weights sum to 2 on [−1, 1]: × half is the panel's.
                rule.push((x, half * w * density));
            }
        }
        let total: f64 = rule.iter().map(|r| r.1).sum();
        rule.iter().map(|&(x, w)| (x, w / total)).collect()
    }

    fn name(self) -> &'static str {
        match self {
            Distribution::Normal => "normal",
            Distribution::Uniform => "uniform",
        }
    }
}

/// Nodes per deviate of the Gauss rules over the tracker's noise ([`Distribution::rule`]).
pub const GAUSS_NODES: usize = 16;

/// The tracker's noise: a distribution and its four values (standard deviations for a normal,
/// bounds ±a for a uniform).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackerNoise {
    /// The distribution of each component (files written before it existed are normal).
    #[serde(default)]
    pub distribution: Distribution,
    /// Azimuth (angle about the tracker's z axis), µrad.
    pub azimuth_urad: f64,
    /// Elevation (angle above the tracker's xy plane), µrad.
    pub elevation_urad: f64,
    /// Range, constant part, µm.
    pub range_um: f64,
    /// Range, part proportional to the range, µm per m.
    pub range_um_per_m: f64,
}

impl std::fmt::Display for TrackerNoise {
    /// `uniform:30,30,4,0.8` — the form [`TrackerNoise::from_text`] reads.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}:{},{},{},{}",
            self.distribution.name(),
            self.azimuth_urad,
            self.elevation_urad,
            self.range_um,
            self.range_um_per_m
        )
    }
}

impl TrackerNoise {
    /// The paper's tracker, read as bounds (see the module documentation): uniform on ±30 µrad,
    /// ±30 µrad, ±(4 µm + 0.8 µm/m).
    pub const PAPER: TrackerNoise = TrackerNoise {
        distribution: Distribution::Uniform,
        azimuth_urad: 30.0,
        elevation_urad: 30.0,
        range_um: 4.0,
        range_um_per_m: 0.8,
    };

    /// No noise.
    pub const NONE: TrackerNoise = TrackerNoise {
        distribution: Distribution::Normal,
        azimuth_urad: 0.0,
        elevation_urad: 0.0,
        range_um: 0.0,
        range_um_per_m: 0.0,
    };

    /// Reads the CLI's `--noise`: `paper` ([`TrackerNoise::PAPER`]), `none`, or a distribution
    /// and four values `normal:AZ_URAD,EL_URAD,RANGE_UM,RANGE_UM_PER_M` (standard deviations) or
    /// `uniform:…` (bounds ±a); four values without a distribution are normal σ; or
    /// `mpe:A_UM,B_UM_PER_M`, a maximum permissible error ([`TrackerNoise::from_mpe`]).
    ///
    /// ```
    /// use volver_core::noise::{Distribution, TrackerNoise};
    /// assert_eq!(TrackerNoise::from_text("paper").unwrap(), TrackerNoise::PAPER);
    /// assert_eq!(TrackerNoise::from_text("uniform:30,30,4,0.8").unwrap(), TrackerNoise::PAPER);
    /// let n = TrackerNoise::from_text("normal:10,10,2,0.5").unwrap();
    /// assert_eq!((n.distribution, n.range_um), (Distribution::Normal, 2.0));
    /// assert_eq!(TrackerNoise::from_text("10,10,2,0.5").unwrap(), n);
    /// assert_eq!(TrackerNoise::from_text(&n.to_string()).unwrap(), n);
    /// assert!(TrackerNoise::from_text("10,10").is_err());
    /// assert!(TrackerNoise::from_text("cauchy:1,1,1,1").is_err());
    /// ```
    pub fn from_text(text: &str) -> crate::Result<TrackerNoise> {
        const EXPECTED: &str = "expected paper, none, normal:AZ_URAD,EL_URAD,RANGE_UM,RANGE_UM_PER_M \
             (σ ≥ 0), uniform:… (bounds ≥ 0) or mpe:A_UM,B_UM_PER_M (±(a + b·L) at k = 2)";
        let refuse = || {
            crate::Error::input(
                crate::Place::file("--noise").at_field(text.to_string()),
                EXPECTED,
            )
        };
        match text.trim() {
            "paper" => return Ok(TrackerNoise::PAPER),
            "none" => return Ok(TrackerNoise::NONE),
            _ => {}
        }
        // `count` values ≥ 0, comma-separated.
        let values = |text: &str, count: usize| -> crate::Result<Vec<f64>> {
            text.split(',')
                .map(|s| {
                    s.trim()
                        .parse::<f64>()
                        .ok()
                        .filter(|v| v.is_finite() && *v >= 0.0)
                })
                .collect::<Option<Vec<f64>>>()
                .filter(|v| v.len() == count)
                .ok_or_else(refuse)
        };
        if let Some(v) = text.trim().strip_prefix("mpe:") {
            let ab = values(v, 2)?;
            return Ok(TrackerNoise::from_mpe(ab[0], ab[1]));
        }
        let (distribution, four) = match text.trim().split_once(':') {
            Some(("normal", v)) => (Distribution::Normal, v),
            Some(("uniform", v)) => (Distribution::Uniform, v),
            Some(_) => return Err(refuse()),
            None => (Distribution::Normal, text),
        };
        let v = values(four, 4)?;
        Ok(TrackerNoise {
            distribution,
            azimuth_urad: v[0],
            elevation_urad: v[1],
            range_um: v[2],
            range_um_per_m: v[3],
        })
    }

    /// The noise of a tracker stated as a maximum permissible error `±(a + b·L)` (µm, µm per m
    /// of range L) on a point's coordinates at 95 % (k = 2), as a normal model: the range gets
    /// σ = a/2 + (b/2)·L and each angle σ = b/2 µrad, so that the transverse σ at L is (b/2)·L.
    /// The transverse share of `a` has no place in the spherical model and is left out (a
    /// fraction of the transverse noise at short range: state the angles directly when it
    /// matters).
    ///
    /// ```
    /// use volver_core::noise::{Distribution, TrackerNoise};
    /// let n = TrackerNoise::from_mpe(15.0, 6.0);
    /// assert_eq!((n.distribution, n.azimuth_urad, n.range_um, n.range_um_per_m), (Distribution::Normal, 3.0, 7.5, 3.0));
    /// assert_eq!(TrackerNoise::from_text("mpe:15,6").unwrap(), n);
    /// ```
    pub fn from_mpe(a_um: f64, b_um_per_m: f64) -> TrackerNoise {
        TrackerNoise {
            distribution: Distribution::Normal,
            azimuth_urad: b_um_per_m / 2.0,
            elevation_urad: b_um_per_m / 2.0,
            range_um: a_um / 2.0,
            range_um_per_m: b_um_per_m / 2.0,
        }
    }

    /// The noise's principal axes at the point `p` (tracker frame, mm), linearised: the unit
    /// vectors along the range, the azimuth and the elevation, each with the standard deviation
    /// of the displacement along it (mm): the range's σ, the azimuth's σ times the horizontal
    /// distance, the elevation's σ times the range.
    ///
    /// ```
    /// use volver_core::noise::TrackerNoise;
    /// let n = TrackerNoise::from_text("normal:10,20,5,0").unwrap();
    /// let axes = n.axes([0.0, 2000.0, 0.0]);
    /// assert!((axes[0].0[1] - 1.0).abs() < 1e-12 && (axes[0].1 - 0.005).abs() < 1e-12); // range
    /// assert!((axes[1].0[0] + 1.0).abs() < 1e-12 && (axes[1].1 - 0.020).abs() < 1e-12); // 10 µrad × 2 m
    /// assert!((axes[2].0[2] - 1.0).abs() < 1e-12 && (axes[2].1 - 0.040).abs() < 1e-12); // 20 µrad × 2 m
    /// ```
    pub fn axes(&self, p: [f64; 3]) -> [([f64; 3], f64); 3] {
        let rho = p[0].hypot(p[1]);
        let r = rho.hypot(p[2]);
        let (sa, ca) = p[1].atan2(p[0]).sin_cos();
        let (se, ce) = p[2].atan2(rho).sin_cos();
        let (s_az, s_el) = self.angle_sigmas_rad();
        [
            ([ce * ca, ce * sa, se], self.range_sigma_mm(r)),
            ([-sa, ca, 0.0], s_az * rho),
            ([-se * ca, -se * sa, ce], s_el * r),
        ]
    }

    /// The whitening of a residual `d` (mm) at the point `p`: its components along the noise's
    /// [`TrackerNoise::axes`], each divided by its σ, so that the noise itself becomes unit
    /// variance in every direction. A σ below 1e-6 of the largest is raised to it (a tracker
    /// without range noise still weighs its range); `None` for a noise-free tracker.
    pub fn whitening(&self, p: [f64; 3]) -> Option<[[f64; 3]; 3]> {
        let axes = self.axes(p);
        let top = axes.iter().map(|a| a.1).fold(0.0, f64::max);
        if !(top > 0.0 && top.is_finite()) {
            return None;
        }
        Some(axes.map(|(u, s)| {
            let s = s.max(1e-6 * top);
            u.map(|v| v / s)
        }))
    }

    /// The mean and the variance of the noise's module ‖e‖ at the point `p` (mm, mm²), by the
    /// product rule of [`Distribution::rule`] over the three deviates along the linearised
    /// [`TrackerNoise::axes`]: what the EMM of a fit at the noise is made of.
    ///
    /// ```
    /// use volver_core::noise::TrackerNoise;
    /// // Isotropic normal σ = 2 µm at 1 m: E‖e‖ = σ √(8/π), Var = σ² (3 − 8/π); the rule
    /// // gets the mean to 4e-4 and the variance to 4e-3.
    /// let n = TrackerNoise::from_text("normal:2,2,2,0").unwrap();
    /// let (m, v) = n.module_moments([1000.0, 0.0, 0.0]);
    /// let s = 0.002;
    /// assert!((m / (s * (8.0 / std::f64::consts::PI).sqrt()) - 1.0).abs() < 1e-3);
    /// assert!((v / (s * s * (3.0 - 8.0 / std::f64::consts::PI)) - 1.0).abs() < 1e-2);
    /// ```
    pub fn module_moments(&self, p: [f64; 3]) -> (f64, f64) {
        let axes = self.axes(p);
        // The deviates' scale: σ for a normal, the bound for a uniform (σ = bound/√3).
        let scale = match self.distribution {
            Distribution::Normal => 1.0,
            Distribution::Uniform => 3f64.sqrt(),
        };
        let v = axes.map(|a| (a.1 * scale).powi(2));
        let rule = self.distribution.rule();
        let mut mean = 0.0;
        for &(za, wa) in &rule {
            for &(zb, wb) in &rule {
                let partial = v[0] * za * za + v[1] * zb * zb;
                let w = wa * wb;
                for &(zc, wc) in &rule {
                    mean += w * wc * (partial + v[2] * zc * zc).sqrt();
                }
            }
        }
        let second: f64 = axes.iter().map(|a| a.1 * a.1).sum();
        (mean, (second - mean * mean).max(0.0))
    }

    /// The mean and the variance of the noise's module for a range alone measured at `r_mm`
    /// (mm, mm²): only the range part, `E|e| = σ √(2/π)` for a normal, `a/2` for a uniform on
    /// ±a.
    ///
    /// ```
    /// use volver_core::noise::TrackerNoise;
    /// let n = TrackerNoise::from_text("uniform:30,30,4,0").unwrap();
    /// let (m, v) = n.range_moments(2000.0);
    /// assert!((m - 0.002).abs() < 1e-15 && (v - (0.004f64.powi(2) / 3.0 - 0.002f64.powi(2))).abs() < 1e-15);
    /// ```
    pub fn range_moments(&self, r_mm: f64) -> (f64, f64) {
        let value = self.range_value_mm(r_mm);
        let sigma = self.range_sigma_mm(r_mm);
        let mean = match self.distribution {
            Distribution::Normal => value * (2.0 / std::f64::consts::PI).sqrt(),
            Distribution::Uniform => value / 2.0,
        };
        (mean, (sigma * sigma - mean * mean).max(0.0))
    }

    /// Standard deviations of azimuth and elevation, rad, whatever the distribution.
    pub fn angle_sigmas_rad(&self) -> (f64, f64) {
        (
            self.distribution.sigma(self.azimuth_urad) * RAD_PER_URAD,
            self.distribution.sigma(self.elevation_urad) * RAD_PER_URAD,
        )
    }

    /// The range's value (σ for a normal, bound for a uniform) at a range of `r_mm`, in mm.
    pub fn range_value_mm(&self, r_mm: f64) -> f64 {
        (self.range_um + self.range_um_per_m * r_mm * M_PER_MM) * MM_PER_UM
    }

    /// Standard deviation of the range at a range of `r_mm`, in mm, whatever the distribution.
    pub fn range_sigma_mm(&self, r_mm: f64) -> f64 {
        self.distribution.sigma(self.range_value_mm(r_mm))
    }

    /// Whether every quantity a reading at `r_mm` takes has σ > 0: the range alone when
    /// `range_only` (an interferometer's reading, a range), else the angles too. A weighted fit
    /// would give a reading of a quantity with σ = 0 infinite weight.
    ///
    /// ```
    /// use volver_core::noise::TrackerNoise;
    /// let interferometer = TrackerNoise::from_text("normal:0,0,0.1,0.15").unwrap();
    /// assert!(interferometer.measures(true, 2000.0) && !interferometer.measures(false, 2000.0));
    /// assert!(!TrackerNoise::NONE.measures(true, 2000.0));
    /// ```
    pub fn measures(&self, range_only: bool, r_mm: f64) -> bool {
        let (s_az, s_el) = self.angle_sigmas_rad();
        self.range_sigma_mm(r_mm) > 0.0 && (range_only || (s_az > 0.0 && s_el > 0.0))
    }

    /// `true` when every value is zero.
    pub fn is_none(&self) -> bool {
        self.azimuth_urad == 0.0
            && self.elevation_urad == 0.0
            && self.range_um == 0.0
            && self.range_um_per_m == 0.0
    }

    /// A noisy reading of the point `p` (tracker frame, mm). Draws three deviates (standard
    /// normal, or uniform on [−1, 1]), in the order azimuth, elevation, range, whatever the values
    /// (so the stream stays aligned when one is 0), and scales each by its value.
    pub fn apply(&self, p: [f64; 3], rng: &mut Rng) -> [f64; 3] {
        let mut draw = || match self.distribution {
            Distribution::Normal => rng.normal(),
            Distribution::Uniform => 2.0 * rng.uniform() - 1.0,
        };
        let deviates = [draw(), draw(), draw()];
        self.apply_deviates(p, deviates)
    }

    /// The reading of the point `p` (tracker frame, mm) for given deviates of azimuth, elevation
    /// and range (standard normal, or on [−1, 1] for a uniform noise), each scaled by its value:
    /// what [`TrackerNoise::apply`] draws, for quadratures over the noise.
    ///
    /// ```
    /// use volver_core::noise::TrackerNoise;
    /// let p = [1000.0, 0.0, 0.0];
    /// let q = TrackerNoise::PAPER.apply_deviates(p, [0.0, 0.0, 1.0]);
    /// // ±(4 µm + 0.8 µm/m) in range at 1 m: 4.8 µm.
    /// assert!((q[0] - 1000.0048).abs() < 1e-9 && q[1].abs() < 1e-12);
    /// ```
    pub fn apply_deviates(&self, p: [f64; 3], [na, ne, nr]: [f64; 3]) -> [f64; 3] {
        if self.is_none() {
            return p;
        }
        let rho = p[0].hypot(p[1]);
        let r = rho.hypot(p[2]);
        let az = p[1].atan2(p[0]) + self.azimuth_urad * RAD_PER_URAD * na;
        let el = p[2].atan2(rho) + self.elevation_urad * RAD_PER_URAD * ne;
        let r = r + self.range_value_mm(r) * nr;
        let (sa, ca) = az.sin_cos();
        let (se, ce) = el.sin_cos();
        [r * ce * ca, r * ce * sa, r * se]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 100 000 draws of each distribution: the spread of azimuth, elevation and range matches
    /// the σ it states within 2 %; a uniform one never exceeds its bounds.
    #[test]
    fn noise_statistics_match_the_requested_sigma() {
        let normal = TrackerNoise {
            distribution: Distribution::Normal,
            ..TrackerNoise::PAPER
        };
        for noise in [normal, TrackerNoise::PAPER] {
            check_statistics(noise);
        }
    }

    fn check_statistics(noise: TrackerNoise) {
        let p: [f64; 3] = [1200.0, -700.0, 900.0];
        let rho = p[0].hypot(p[1]);
        let (az0, el0, r0) = (p[1].atan2(p[0]), p[2].atan2(rho), rho.hypot(p[2]));
        let mut rng = Rng::new(2024);
        let n = 100_000;
        let mut sums = [0.0; 3];
        let mut sq = [0.0; 3];
        let mut peak = [0.0f64; 3];
        for _ in 0..n {
            let q = noise.apply(p, &mut rng);
            let rq = q[0].hypot(q[1]);
            let d = [
                (q[1].atan2(q[0]) - az0) * 1e6,
                (q[2].atan2(rq) - el0) * 1e6,
                (rq.hypot(q[2]) - r0) * 1e3,
            ];
            for k in 0..3 {
                sums[k] += d[k];
                sq[k] += d[k] * d[k];
                peak[k] = peak[k].max(d[k].abs());
            }
        }
        let (s_az, s_el) = noise.angle_sigmas_rad();
        let want = [s_az * 1e6, s_el * 1e6, noise.range_sigma_mm(r0) * 1e3];
        for k in 0..3 {
            let mean = sums[k] / n as f64;
            let sd = (sq[k] / n as f64 - mean * mean).sqrt();
            assert!(
                (sd / want[k] - 1.0).abs() < 0.02,
                "component {k}: σ {sd} vs {}",
                want[k]
            );
            assert!(mean.abs() < 0.02 * want[k], "component {k}: mean {mean}");
            // A uniform's largest draw reaches its bound √3 σ (within 0.1 %) and never passes it
            // (1e-6 for the rounding of the round trip through Cartesian coordinates); a
            // normal's passes √3 σ often.
            let bound = 3f64.sqrt() * want[k];
            match noise.distribution {
                Distribution::Uniform => assert!(
                    peak[k] <= bound * (1.0 + 1e-6) && peak[k] > 0.999 * bound,
                    "component {k}: peak {} vs bound {bound}",
                    peak[k]
                ),
                Distribution::Normal => assert!(peak[k] > 2.0 * bound, "component {k}"),
            }
        }
    }
}
