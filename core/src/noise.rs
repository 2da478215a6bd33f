//! Laser-tracker noise in the tracker's own spherical coordinates (paper, section 6.2): normal
//! noise on the azimuth and the elevation (µrad) and on the range (µm plus µm per metre of range).
//! The paper's tracker: 30 µrad, 30 µrad, 4 µm + 0.8 µm/m.
//!
//! ```
//! use volver_core::noise::TrackerNoise;
//! use volver_core::random::Rng;
//! let mut rng = Rng::new(1);
//! let p = [1000.0, 500.0, 300.0];
//! let q = TrackerNoise::PAPER.apply(p, &mut rng);
//! let d = ((q[0]-p[0]).powi(2) + (q[1]-p[1]).powi(2) + (q[2]-p[2]).powi(2)).sqrt();
//! assert!(d < 0.5); // mm: a few σ of 30 µrad at 1.16 m
//! assert_eq!(TrackerNoise::NONE.apply(p, &mut rng), p);
//! ```

use crate::random::Rng;
use serde::{Deserialize, Serialize};

/// Standard deviations of the tracker's noise.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackerNoise {
    /// Azimuth (angle about the tracker's z axis), µrad.
    pub azimuth_urad: f64,
    /// Elevation (angle above the tracker's xy plane), µrad.
    pub elevation_urad: f64,
    /// Range, constant part, µm.
    pub range_um: f64,
    /// Range, part proportional to the range, µm per m.
    pub range_um_per_m: f64,
}

impl TrackerNoise {
    /// The paper's tracker: 30 µrad, 30 µrad, 4 µm + 0.8 µm/m.
    pub const PAPER: TrackerNoise = TrackerNoise {
        azimuth_urad: 30.0,
        elevation_urad: 30.0,
        range_um: 4.0,
        range_um_per_m: 0.8,
    };

    /// No noise.
    pub const NONE: TrackerNoise = TrackerNoise {
        azimuth_urad: 0.0,
        elevation_urad: 0.0,
        range_um: 0.0,
        range_um_per_m: 0.0,
    };

    /// Reads `paper`, `none`, or four σ `AZ_URAD,EL_URAD,RANGE_UM,RANGE_UM_PER_M` (the CLI's
    /// `--noise`).
    ///
    /// ```
    /// use volver_core::noise::TrackerNoise;
    /// assert_eq!(TrackerNoise::from_text("paper").unwrap(), TrackerNoise::PAPER);
    /// assert_eq!(TrackerNoise::from_text("10,10,2,0.5").unwrap().range_um, 2.0);
    /// assert!(TrackerNoise::from_text("10,10").is_err());
    /// ```
    pub fn from_text(text: &str) -> crate::Result<TrackerNoise> {
        match text.trim() {
            "paper" => return Ok(TrackerNoise::PAPER),
            "none" => return Ok(TrackerNoise::NONE),
            _ => {}
        }
        let v: Vec<f64> = text
            .split(',')
            .map(|s| {
                s.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite() && *v >= 0.0)
            })
            .collect::<Option<_>>()
            .filter(|v: &Vec<f64>| v.len() == 4)
            .ok_or_else(|| {
                crate::Error::input(
                    crate::Place::file("--noise").at_field(text.to_string()),
                    "expected paper, none, or four σ ≥ 0: AZ_URAD,EL_URAD,RANGE_UM,RANGE_UM_PER_M",
                )
            })?;
        Ok(TrackerNoise {
            azimuth_urad: v[0],
            elevation_urad: v[1],
            range_um: v[2],
            range_um_per_m: v[3],
        })
    }

    /// Standard deviation of the range at a range of `r_mm`, in mm.
    pub fn range_sigma_mm(&self, r_mm: f64) -> f64 {
        (self.range_um + self.range_um_per_m * r_mm * 1e-3) * 1e-3
    }

    /// A noisy reading of the point `p` (tracker frame, mm). Draws three normal deviates, in the
    /// order azimuth, elevation, range, whatever the σ (so the stream stays aligned when a σ is 0).
    pub fn apply(&self, p: [f64; 3], rng: &mut Rng) -> [f64; 3] {
        let (na, ne, nr) = (rng.normal(), rng.normal(), rng.normal());
        if *self == TrackerNoise::NONE {
            return p;
        }
        let rho = p[0].hypot(p[1]);
        let r = rho.hypot(p[2]);
        let az = p[1].atan2(p[0]) + self.azimuth_urad * 1e-6 * na;
        let el = p[2].atan2(rho) + self.elevation_urad * 1e-6 * ne;
        let r = r + self.range_sigma_mm(r) * nr;
        let (sa, ca) = az.sin_cos();
        let (se, ce) = el.sin_cos();
        [r * ce * ca, r * ce * sa, r * se]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 100 000 draws: the spread of azimuth, elevation and range matches the requested σ within 2 %.
    #[test]
    fn noise_statistics_match_the_requested_sigma() {
        let noise = TrackerNoise::PAPER;
        let p: [f64; 3] = [1200.0, -700.0, 900.0];
        let rho = p[0].hypot(p[1]);
        let (az0, el0, r0) = (p[1].atan2(p[0]), p[2].atan2(rho), rho.hypot(p[2]));
        let mut rng = Rng::new(2024);
        let n = 100_000;
        let mut sums = [0.0; 3];
        let mut sq = [0.0; 3];
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
            }
        }
        let want = [
            noise.azimuth_urad,
            noise.elevation_urad,
            noise.range_sigma_mm(r0) * 1e3,
        ];
        for k in 0..3 {
            let mean = sums[k] / n as f64;
            let sd = (sq[k] / n as f64 - mean * mean).sqrt();
            assert!(
                (sd / want[k] - 1.0).abs() < 0.02,
                "component {k}: σ {sd} vs {}",
                want[k]
            );
            assert!(mean.abs() < 0.02 * want[k], "component {k}: mean {mean}");
        }
    }
}
