//! Where a model fails: its residuals broken down by axis position, reflector, station, time
//! and tracker distance, split by each axis' direction of approach ([`by_direction`]: a
//! reversal the model lacks), periodograms against an axis, the largest outliers, the noise estimated
//! from repeated points, what the noise specification leaves at a set of points
//! ([`noise_level`], each point by its station's noise) and the noise each station's residuals
//! show against its own ([`station_noises`]). The first part of the diagnosis loop; candidates
//! for the missing effect come next.
//!
//! ```
//! use volver_core::diagnose::{by_axis, largest};
//! use volver_core::machine::Machine;
//! use volver_core::measure::MeasurementSet;
//! use volver_core::model::Model;
//! use volver_core::problem::{Problem, Residuals};
//! let model = Model::default_xcfz();
//! let p0 = model.initial_params();
//! let at = |x: f64| model.machine().commands_from_file_units(&[x, 0.0, 0.0]);
//! let (a, b) = (model.predict(&at(0.0), 0, &p0), model.predict(&at(1400.0), 0, &p0));
//! // Measured 3 µm off at X = 0 and 10 µm off at X = 1400.
//! let csv = format!(
//!     "reflector,X,C,Z,meas_x,meas_y,meas_z\nR1,0,0,0,{},{},{}\nR1,1400,0,0,{},{},{}\n",
//!     a[0] + 0.003, a[1], a[2], b[0] + 0.010, b[1], b[2]
//! );
//! let data = MeasurementSet::from_csv_str(model.machine(), &csv, "inline.csv").unwrap();
//! let problem = Problem::new(&model, &data).unwrap();
//! let r = problem.residuals(&model.initial_params());
//! let b = by_axis(&problem, &r, 0, 8);
//! assert_eq!(b.bins.len(), 2); // two distinct X positions
//! assert!((b.bins[1].stats.emm_um - 10.0).abs() < 1e-6);
//! assert_eq!(largest(&r, 1)[0].0, 1);
//! ```

use crate::kinematics::{PointErrors, predict_with_tool_shift};
use crate::metrics::ErrorStats;
use crate::noise::TrackerNoise;
use crate::problem::{Problem, norm};
use crate::units::UM_PER_MM;
use std::f64::consts::PI;

mod direction;
pub use direction::{
    Coverage, DirectionSplit, MIN_SIDE_POINTS, SideMean, before_first_move, by_direction, coverage,
};

/// Residuals of the points that fall in one bin.
#[derive(Clone, Debug, PartialEq)]
pub struct Bin {
    /// The bin's label (`0 … 200 mm`, `R1`).
    pub label: String,
    /// Lower end of the bin (in the breakdown's unit; the index for categories).
    pub from: f64,
    /// Upper end.
    pub to: f64,
    /// Points in the bin.
    pub count: usize,
    /// EMM and EMax of their residuals (µm).
    pub stats: ErrorStats,
    /// Mean residual vector (µm, tracker frame): a systematic offset the model misses.
    pub mean_um: [f64; 3],
    /// The indices of its points.
    pub points: Vec<usize>,
}

/// A breakdown of the residuals by one quantity.
#[derive(Clone, Debug, PartialEq)]
pub struct Breakdown {
    /// What the residuals are broken down by (`X`, `reflector`, `t_s` …).
    pub by: String,
    /// Its unit (`mm`, `deg`, `s`, or empty).
    pub unit: String,
    /// The bins in increasing order.
    pub bins: Vec<Bin>,
}

impl Breakdown {
    /// Largest bin EMM divided by the smallest (1 when uniform; ∞ if a bin is exact).
    pub fn spread(&self) -> f64 {
        let emms = self.bins.iter().map(|b| b.stats.emm_um);
        let (lo, hi) = emms.fold((f64::INFINITY, 0.0_f64), |(l, h), e| (l.min(e), h.max(e)));
        if self.bins.is_empty() { 1.0 } else { hi / lo }
    }
}

fn bin_of(label: String, from: f64, to: f64, points: Vec<usize>, residuals: &[[f64; 3]]) -> Bin {
    let n = points.len().max(1) as f64;
    let mean_um =
        [0, 1, 2].map(|c| points.iter().map(|&i| residuals[i][c]).sum::<f64>() / n * UM_PER_MM);
    Bin {
        label,
        from,
        to,
        count: points.len(),
        stats: ErrorStats::of_modules(points.iter().map(|&i| norm(residuals[i]))),
        mean_um,
        points,
    }
}

/// Breaks residuals down by a value per point: one bin per distinct value when there are at
/// most `max_bins` of them (mesh positions), otherwise `max_bins` equal-width bins.
pub fn by_values(
    by: &str,
    unit: &str,
    values: &[f64],
    residuals: &[[f64; 3]],
    max_bins: usize,
) -> Breakdown {
    assert_eq!(values.len(), residuals.len(), "one value per residual");
    let mut distinct: Vec<f64> = values.to_vec();
    distinct.sort_by(f64::total_cmp);
    distinct.dedup_by(|a, b| (*a - *b).abs() <= 1e-9 * b.abs().max(1.0));
    let members = |keep: &dyn Fn(f64) -> bool| -> Vec<usize> {
        (0..values.len()).filter(|&i| keep(values[i])).collect()
    };
    let mut bins = Vec::new();
    if distinct.len() <= max_bins.max(1) {
        for &v in &distinct {
            let points = members(&|x| (x - v).abs() <= 1e-9 * v.abs().max(1.0));
            bins.push(bin_of(label(v), v, v, points, residuals));
        }
    } else {
        let (lo, hi) = (distinct[0], distinct[distinct.len() - 1]);
        let width = (hi - lo) / max_bins as f64;
        for k in 0..max_bins {
            let (a, b) = (lo + k as f64 * width, lo + (k + 1) as f64 * width);
            let last = k + 1 == max_bins;
            let points = members(&|x| x >= a && (x < b || (last && x <= hi)));
            if !points.is_empty() {
                bins.push(bin_of(
                    format!("{} … {}", label(a), label(b)),
                    a,
                    b,
                    points,
                    residuals,
                ));
            }
        }
    }
    Breakdown {
        by: by.to_string(),
        unit: unit.to_string(),
        bins,
    }
}

/// A bin edge for labels: whole numbers as such, others to four significant digits.
fn label(v: f64) -> String {
    if (v - v.round()).abs() <= 1e-9 * v.abs().max(1.0) && v.abs() < 1e15 {
        format!("{v:.0}")
    } else {
        let digits = (3 - v.abs().log10().floor() as i32).clamp(0, 9) as usize;
        format!("{v:.digits$}")
    }
}

/// By the position of chain axis `k` (file units: mm or degrees).
pub fn by_axis(problem: &Problem, residuals: &[[f64; 3]], k: usize, max_bins: usize) -> Breakdown {
    let ax = &problem.model().machine().axes()[k];
    let values: Vec<f64> = problem
        .data()
        .points
        .iter()
        .map(|p| ax.to_file_units(p.commands.0[k]))
        .collect();
    by_values(
        &ax.axis.to_string(),
        ax.file_unit(),
        &values,
        residuals,
        max_bins,
    )
}

/// By reflector.
pub fn by_reflector(problem: &Problem, residuals: &[[f64; 3]]) -> Breakdown {
    let refl = problem.model().machine().reflectors();
    let bins = (0..refl.len())
        .filter_map(|r| {
            let points: Vec<usize> = (0..residuals.len())
                .filter(|&i| problem.data().points[i].reflector == r)
                .collect();
            (!points.is_empty())
                .then(|| bin_of(refl[r].id.clone(), r as f64, r as f64, points, residuals))
        })
        .collect();
    Breakdown {
        by: "reflector".into(),
        unit: String::new(),
        bins,
    }
}

/// By station (several tracker stations: multilateration), in the machine's order.
pub fn by_station(problem: &Problem, residuals: &[[f64; 3]]) -> Breakdown {
    let stations = problem.model().machine().stations();
    let bins = (0..stations.len())
        .filter_map(|k| {
            let points: Vec<usize> = (0..residuals.len())
                .filter(|&i| problem.data().points[i].station_index == k)
                .collect();
            (!points.is_empty()).then(|| {
                bin_of(
                    stations[k].id.clone(),
                    k as f64,
                    k as f64,
                    points,
                    residuals,
                )
            })
        })
        .collect();
    Breakdown {
        by: "station".into(),
        unit: String::new(),
        bins,
    }
}

/// By measurement time `t_s` (seconds), when every point has one.
pub fn by_time(problem: &Problem, residuals: &[[f64; 3]], max_bins: usize) -> Option<Breakdown> {
    let t: Option<Vec<f64>> = problem.data().points.iter().map(|p| p.t_s).collect();
    t.map(|t| by_values("t_s", "s", &t, residuals, max_bins))
}

/// By distance from the tracker (mm, of the measured point).
pub fn by_distance(problem: &Problem, residuals: &[[f64; 3]], max_bins: usize) -> Breakdown {
    let d: Vec<f64> = problem
        .data()
        .points
        .iter()
        .map(|p| norm(p.measured))
        .collect();
    by_values("distance", "mm", &d, residuals, max_bins)
}

/// Every breakdown `volver diagnose` and the report show: by each axis (up to 24 bins), by
/// reflector, by station when there are several, by time when every point has one, and by
/// distance (8 bins).
pub fn breakdowns(problem: &Problem, residuals: &[[f64; 3]]) -> Vec<Breakdown> {
    let machine = problem.model().machine();
    let n_axes = machine.axes().len();
    let mut all: Vec<Breakdown> = (0..n_axes)
        .map(|k| by_axis(problem, residuals, k, 24))
        .collect();
    all.push(by_reflector(problem, residuals));
    if machine.stations().len() > 1 {
        all.push(by_station(problem, residuals));
    }
    all.extend(by_time(problem, residuals, 8));
    all.push(by_distance(problem, residuals, 8));
    all
}

/// One line of a periodogram.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Line {
    /// Frequency in cycles per unit of the argument (per turn for a rotary axis).
    pub frequency: f64,
    /// Least-squares amplitude of `a cos 2πfx + b sin 2πfx` in each residual component (µm).
    pub amplitude_um: [f64; 3],
}

impl Line {
    /// Amplitude of the three components together (µm).
    pub fn total_um(&self) -> f64 {
        norm(self.amplitude_um)
    }
}

/// Periodogram of the residuals against `x`: for each frequency, the least-squares fit of a
/// sinusoid plus a constant to each residual component (Lomb–Scargle style, so uneven sampling
/// is fine). Frequencies the sampling cannot tell apart from a constant give zero.
pub fn periodogram(x: &[f64], residuals: &[[f64; 3]], frequencies: &[f64]) -> Vec<Line> {
    assert_eq!(x.len(), residuals.len(), "one argument per residual");
    frequencies
        .iter()
        .map(|&f| {
            let w = 2.0 * PI * f;
            // Normal equations of [1, cos, sin] per component.
            let mut m = [[0.0; 3]; 3];
            let mut rhs = [[0.0; 3]; 3];
            for (xi, r) in x.iter().zip(residuals) {
                let b = [1.0, (w * xi).cos(), (w * xi).sin()];
                for i in 0..3 {
                    for j in 0..3 {
                        m[i][j] += b[i] * b[j];
                    }
                    for c in 0..3 {
                        rhs[c][i] += b[i] * r[c];
                    }
                }
            }
            let amplitude_um =
                [0, 1, 2].map(|c| solve3(m, rhs[c]).map_or(0.0, |s| s[1].hypot(s[2]) * UM_PER_MM));
            Line {
                frequency: f,
                amplitude_um,
            }
        })
        .collect()
}

/// Solves a 3×3 symmetric system; `None` when singular.
fn solve3(m: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let det = |a: [[f64; 3]; 3]| {
        a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
            - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
    };
    // A sinusoid the sampling cannot see (aliased onto a constant, or a column of zeros).
    if m[1][1] <= 1e-9 * m[0][0] || m[2][2] <= 1e-9 * m[0][0] {
        return None;
    }
    let d = det(m);
    if d.abs() <= 1e-9 * (m[0][0] * m[1][1] * m[2][2]).abs() {
        return None;
    }
    Some(std::array::from_fn(|k| {
        let mut a = m;
        for i in 0..3 {
            a[i][k] = b[i];
        }
        det(a) / d
    }))
}

/// Periodogram against chain axis `k`: harmonics 1 … `max_order` per turn for a rotary axis
/// (argument in turns), per travel length for a linear one. Orders the positions cannot
/// resolve (more than half the number of distinct positions) are left out.
pub fn axis_periodogram(
    problem: &Problem,
    residuals: &[[f64; 3]],
    k: usize,
    max_order: usize,
) -> Vec<Line> {
    let ax = &problem.model().machine().axes()[k];
    let span = if ax.axis.is_rotary() {
        2.0 * PI
    } else {
        ax.max - ax.min
    };
    let x: Vec<f64> = problem
        .data()
        .points
        .iter()
        .map(|p| (p.commands.0[k] - ax.min) / span)
        .collect();
    let mut distinct = x.clone();
    distinct.sort_by(f64::total_cmp);
    distinct.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    let resolvable = (distinct.len().saturating_sub(1) / 2).min(max_order);
    let f: Vec<f64> = (1..=resolvable).map(|h| h as f64).collect();
    periodogram(&x, residuals, &f)
}

/// Residuals turned from the tracker frame into the machine frame: for a tracker standing on the
/// workpiece (on the table of XCFZ) the tracker frame turns with the workpiece-side axes, which
/// smears an error fixed in the machine over neighbouring harmonics; in the machine frame a
/// rotary error of harmonic h shows at h. The rotation is that of the nominal chain seen from
/// the tracker pose in `params` (each point's station's, for several; a range's residual taken
/// along its line of sight).
pub fn to_machine_frame(
    problem: &Problem,
    params: &[f64],
    residuals: &[[f64; 3]],
) -> Vec<[f64; 3]> {
    let model = problem.model();
    let machine = model.machine();
    problem
        .data()
        .points
        .iter()
        .zip(residuals)
        .map(|(p, r)| {
            // The point's own station's pose.
            let mut e = PointErrors::<f64>::zero();
            let t = model.stations()[p.station_index].pose;
            e.tracker.copy_from_slice(&params[t..t + 6]);
            e.station = p.station_index;
            let offset = &machine.reflectors()[p.reflector].offset;
            let base = predict_with_tool_shift(machine, &p.commands, offset, &e, None);
            // A range's residual lies along the line of sight.
            let r = match p.observation {
                crate::measure::Observation::Point => *r,
                crate::measure::Observation::Range => {
                    let len = norm(base);
                    base.map(|v| r[0] * v / len)
                }
            };
            // Columns of the map machine → tracker: the images of unit tool shifts.
            let cols: [[f64; 3]; 3] = std::array::from_fn(|j| {
                let mut d = [0.0; 3];
                d[j] = 1.0;
                let q = predict_with_tool_shift(machine, &p.commands, offset, &e, Some(d));
                [q[0] - base[0], q[1] - base[1], q[2] - base[2]]
            });
            // Rᵀ r (R is a rotation).
            std::array::from_fn(|j| cols[j][0] * r[0] + cols[j][1] * r[1] + cols[j][2] * r[2])
        })
        .collect()
}

/// The `k` largest residual modules: (point index, µm), largest first.
pub fn largest(residuals: &[[f64; 3]], k: usize) -> Vec<(usize, f64)> {
    let mut v: Vec<(usize, f64)> = residuals
        .iter()
        .enumerate()
        .map(|(i, r)| (i, norm(*r) * UM_PER_MM))
        .collect();
    v.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    v.truncate(k);
    v
}

/// The noise estimated from repeated points (same commands and reflector measured twice or
/// more with every axis arriving from the same side, [`repeat_pairs`]): EMM and EMax of
/// `(m₁ − m₂)/√2` over consecutive repeats, and the number of pairs. `None` without repeats.
///
/// For normal noise the difference of two readings divided by √2 has the noise's own
/// distribution, so this estimates the noise error without knowing the truth. Drift between the
/// readings counts as noise here.
pub fn repeat_noise(problem: &Problem) -> Option<(ErrorStats, usize)> {
    let pts = &problem.data().points;
    let diffs: Vec<f64> = repeat_pairs(problem)
        .into_iter()
        .map(|(a, b)| {
            let (a, b) = (pts[a].measured, pts[b].measured);
            norm([a[0] - b[0], a[1] - b[1], a[2] - b[2]]) / 2f64.sqrt()
        })
        .collect();
    (!diffs.is_empty()).then(|| (ErrorStats::of_modules(diffs.iter().copied()), diffs.len()))
}

/// The pairs of repeated points, each point with the next repeat of it: measured at the same
/// pose with the same reflector and station (rotary positions a full turn apart are the same
/// pose) **and with every axis arriving from the same side** ([`crate::measure::repeat_key`]),
/// leaving out the points measured before one of their axes first moved (their direction is
/// assumed there, [`before_first_move`]).
/// Two readings of one pose reached from opposite sides of an axis differ by its reversal
/// besides the noise (the C = 0° and C = 360° points of test 4, the first reached after the
/// table turned back, the second moving forward): they are not repeats, and the residuals'
/// split by direction of approach ([`by_direction`]) is where such a difference shows.
pub fn repeat_pairs(problem: &Problem) -> Vec<(usize, usize)> {
    let machine = problem.model().machine();
    let pts = &problem.data().points;
    let key = |i: usize| crate::measure::repeat_key(machine, &pts[i]);
    // A point measured before one of its axes first moved has an assumed direction there: it
    // repeats nothing for sure.
    let mut assumed = vec![false; pts.len()];
    for k in 0..machine.axes().len() {
        for (a, b) in assumed.iter_mut().zip(before_first_move(pts, k)) {
            *a |= b;
        }
    }
    let mut order: Vec<usize> = (0..pts.len()).filter(|&i| !assumed[i]).collect();
    order.sort_by_key(|&i| (key(i), i));
    order
        .windows(2)
        .filter(|w| key(w[0]) == key(w[1]))
        .map(|w| (w[0], w[1]))
        .collect()
}

/// What the tracker's noise alone leaves at a set of points, from its specification
/// ([`TrackerNoise::module_moments`] at each measured point, each by its station's noise).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseLevel {
    /// The expected EMM of the noise itself at these points (µm): the noise error.
    pub noise_emm_um: f64,
    /// The expected EMM a fit of a complete model leaves (µm): the noise error less what the
    /// fit's identified directions absorb, `× √(1 − k/m)` for k directions and m residual
    /// coordinates.
    pub fit_emm_um: f64,
    /// The standard deviation of that EMM over the noise (µm).
    pub sd_um: f64,
}

impl NoiseLevel {
    /// How many standard deviations `emm_um` lies above what the noise leaves.
    pub fn z(&self, emm_um: f64) -> f64 {
        (emm_um - self.fit_emm_um) / self.sd_um.max(1e-12)
    }

    /// `emm_um` over what the noise leaves.
    pub fn ratio(&self, emm_um: f64) -> f64 {
        emm_um / self.fit_emm_um
    }
}

/// The noise of station `k` of `problem`'s machine: its own `[[station]]` table's
/// ([`crate::machine::Machine::station_own_noise`]), else `default` (the tracker's: `--noise`
/// or the `[tracker]` table's); `None` when it has neither, or a noise-free one.
pub fn station_noise_of(
    problem: &Problem,
    k: usize,
    default: Option<&TrackerNoise>,
) -> Option<TrackerNoise> {
    let machine = problem.model().machine();
    machine
        .station_own_noise(k)
        .or(default.copied())
        .filter(|n| !n.is_none())
}

/// The mean and variance of the noise's module at every measured point of `problem` (mm, mm²),
/// each by its station's noise ([`station_noise_of`]: its own, else `default`), a range by the
/// range part alone; `None` when a point's station has no noise.
///
/// ```
/// use volver_core::diagnose::noise_moments;
/// use volver_core::noise::TrackerNoise;
/// let model = volver_core::model::Model::default_xcfz();
/// let data = volver_core::measure::MeasurementSet::from_csv_str(
///     model.machine(),
///     "reflector,X,C,Z,meas_x,meas_y,meas_z\nR1,0,0,0,950,75,1450\n",
///     "inline.csv",
/// ).unwrap();
/// let problem = volver_core::problem::Problem::new(&model, &data).unwrap();
/// let n = TrackerNoise::PAPER;
/// assert_eq!(noise_moments(&problem, Some(&n)).unwrap()[0], n.module_moments([950.0, 75.0, 1450.0]));
/// assert!(noise_moments(&problem, None).is_none());
/// ```
pub fn noise_moments(problem: &Problem, default: Option<&TrackerNoise>) -> Option<Vec<(f64, f64)>> {
    let stations = problem.model().machine().stations().len();
    let noises: Vec<Option<TrackerNoise>> = (0..stations)
        .map(|k| station_noise_of(problem, k, default))
        .collect();
    problem
        .data()
        .points
        .iter()
        .map(|p| {
            let noise = noises[p.station_index]?;
            Some(match p.observation {
                crate::measure::Observation::Point => noise.module_moments(p.measured),
                crate::measure::Observation::Range => noise.range_moments(p.measured[0]),
            })
        })
        .collect()
}

/// The noise one station's residuals show against its stated noise ([`station_noises`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StationNoise {
    /// The station (its index in the machine's stations).
    pub station: usize,
    /// Its stated noise: its own, else the tracker's default.
    pub noise: TrackerNoise,
    /// Whether that is its own `[[station]]` table's.
    pub own: bool,
    /// Its measurements.
    pub points: usize,
    /// Its residual coordinates (3 per point, 1 per range alone).
    pub coordinates: usize,
    /// What the fit leaves of them: its coordinates less its points' leverages.
    pub dof: f64,
    /// The stated noise's σ per residual coordinate at its points (µm, RMS over them).
    pub stated_um: f64,
    /// The factor of the stated noise its residuals show, 1 at the noise: `√(Σ‖W_i r_i‖² /
    /// dof)` over its points, the residuals whitened by the stated noise (`W_i`,
    /// [`TrackerNoise::whitening`]; a range by `1/σ` of its range) and left by a least-squares
    /// fit that weighs each station by its factor (variance components). Under normal noise,
    /// the maximum-likelihood factor of the stated σ.
    pub scale: f64,
    /// The standard deviation of `scale` over the noise: `√((κ − 1)/dof) / 2` for the
    /// distribution's kurtosis κ ([`crate::noise::Distribution::kurtosis`]).
    pub scale_sd: f64,
}

impl StationNoise {
    /// The σ per coordinate its residuals show (µm): `scale × stated_um`.
    pub fn shown_um(&self) -> f64 {
        self.scale * self.stated_um
    }

    /// How many standard deviations `scale` lies above 1.
    pub fn z(&self) -> f64 {
        (self.scale - 1.0) / self.scale_sd.max(1e-12)
    }
}

/// What each station's residuals show against its stated noise (its own, else `default`;
/// [`StationNoise`]), from `components`: per station of the machine, the factor of its stated
/// noise its residuals show and the degrees of freedom behind it (what
/// `volver_solvers::identifiability::variance_components` gives on [`Problem::whitened`], the
/// points grouped by station: a quiet station is not judged noisier for the noise a noisier one
/// pushes into the fit). One per station that measured, in the machine's order; `None` when
/// one of them has no noise.
///
/// ```
/// use volver_core::diagnose::station_noises;
/// use volver_core::noise::TrackerNoise;
/// let model = volver_core::model::Model::default_xcfz();
/// let data = volver_core::measure::MeasurementSet::from_csv_str(
///     model.machine(),
///     "reflector,X,C,Z,meas_x,meas_y,meas_z\nR1,0,0,0,950,75,1450\nR2,0,0,0,900,75,1400\n",
///     "inline.csv",
/// ).unwrap();
/// let problem = volver_core::problem::Problem::new(&model, &data).unwrap();
/// let noise = TrackerNoise::from_text("normal:10,10,2,0").unwrap();
/// // Residuals twice the stated noise, from 4.5 degrees of freedom of 6 coordinates.
/// let s = station_noises(&problem, Some(&noise), &[(2.0, 4.5)]).unwrap();
/// assert_eq!((s[0].points, s[0].coordinates, s[0].own, s[0].scale), (2, 6, false, 2.0));
/// assert!((s[0].shown_um() / s[0].stated_um - 2.0).abs() < 1e-12);
/// assert!((s[0].scale_sd - (2.0f64 / 4.5).sqrt() / 2.0).abs() < 1e-12); // normal: κ = 3
/// ```
pub fn station_noises(
    problem: &Problem,
    default: Option<&TrackerNoise>,
    components: &[(f64, f64)],
) -> Option<Vec<StationNoise>> {
    let machine = problem.model().machine();
    let points = &problem.data().points;
    let mut out = Vec::new();
    for k in 0..machine.stations().len() {
        let mine: Vec<&crate::measure::Measurement> =
            points.iter().filter(|p| p.station_index == k).collect();
        if mine.is_empty() {
            continue;
        }
        let noise = station_noise_of(problem, k, default)?;
        let &(scale, dof) = components.get(k)?;
        // Σ of stated variances (mm²) and coordinates.
        let (mut var, mut m) = (0.0, 0usize);
        for p in &mine {
            match p.observation {
                crate::measure::Observation::Range => {
                    var += noise.range_sigma_mm(p.measured[0]).powi(2);
                    m += 1;
                }
                crate::measure::Observation::Point => {
                    var += noise
                        .axes(p.measured)
                        .iter()
                        .map(|a| a.1 * a.1)
                        .sum::<f64>();
                    m += 3;
                }
            }
        }
        out.push(StationNoise {
            station: k,
            noise,
            own: machine.station_own_noise(k).is_some(),
            points: mine.len(),
            coordinates: m,
            dof,
            stated_um: (var / m as f64).sqrt() * UM_PER_MM,
            scale,
            scale_sd: ((noise.distribution.kurtosis() - 1.0) / dof.max(1.0)).sqrt() / 2.0,
        });
    }
    Some(out)
}

/// The noise level over the points `points` (indices into `moments`, as [`noise_moments`]
/// returns them), for a fit that identifies `rank` directions from `coordinates` residual
/// coordinates (3 per point).
///
/// ```
/// use volver_core::diagnose::noise_level;
/// // Four points whose module has mean 10 µm and σ 4 µm; a fit of 3 directions from 12.
/// let moments = vec![(0.010, 0.004f64.powi(2)); 4];
/// let level = noise_level(&moments, &[0, 1, 2, 3], 3, 12);
/// assert!((level.noise_emm_um - 10.0).abs() < 1e-9);
/// assert!((level.fit_emm_um - 10.0 * 0.75f64.sqrt()).abs() < 1e-9);
/// assert!((level.sd_um - 2.0 * 0.75f64.sqrt()).abs() < 1e-9);
/// ```
pub fn noise_level(
    moments: &[(f64, f64)],
    points: &[usize],
    rank: usize,
    coordinates: usize,
) -> NoiseLevel {
    let n = points.len().max(1) as f64;
    let mean = points.iter().map(|&i| moments[i].0).sum::<f64>() / n;
    let var = points.iter().map(|&i| moments[i].1).sum::<f64>() / (n * n);
    let keep = (1.0 - rank as f64 / coordinates.max(1) as f64)
        .max(0.0)
        .sqrt();
    NoiseLevel {
        noise_emm_um: mean * UM_PER_MM,
        fit_emm_um: mean * keep * UM_PER_MM,
        sd_um: var.sqrt() * keep * UM_PER_MM,
    }
}
