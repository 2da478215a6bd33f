//! Optimal experimental design of a verification: which poses and reflectors to measure, and how
//! often, so that the tool point the compensation needs is determined best.
//!
//! The candidates are every reflector at every pose of a fine grid. Each candidate point `i`
//! brings the information `F_i = A_iᵀ A_i`, with `A_i = W_i J_i N` its Jacobian at the nominal
//! machine (zero errors, the machine file's tracker pose), whitened by its station's noise at
//! that point ([`TrackerNoise::whitening`]: the range weighs far above the angles; a station
//! that states its own noise is weighed by it, so a noisier station brings less information)
//! and reduced to the free coordinates `N` of the model's constraints (a range alone, a scalar
//! residual, has rank-one information: one row). A design puts weights `w_i` (summing
//! to one) on the candidates; `m` points give `F(w) = R + m Σ w_i F_i`, where `R` is a weak
//! prior ([`crate::analysis::uncertainty::HELD_PRIOR_MM`] RMS in the function metric of
//! [`crate::engines::gauge`]) that keeps a direction no candidate sees from being infinitely uncertain:
//! a design that leaves one unidentified pays for it through the prior.
//!
//! - **I-optimal** ([`Criterion::I`]): the mean over a grid of the work volume of the variance
//!   of the tool point after the set-up's rigid transform, `tr(Q F⁻¹)` with
//!   `Q = (1/K) Σ_k G_kᵀ G_k` from the tool points' aligned Jacobians
//!   ([`crate::analysis::uncertainty::ToolGrid::jacobian`]): what compensation at that tool offset
//!   inherits from the noise.
//! - **V-optimal** ([`Criterion::V`]): the largest of those variances over the grid, approached
//!   by I-optimal designs whose grid points are reweighted towards the largest variances.
//! - **D-optimal** ([`Criterion::D`]): `log det F`, the volume of the parameters' confidence
//!   ellipsoid.
//!
//! The weights are found by the multiplicative algorithm (Silvey, Titterington and Torsney
//! 1978; for linear criteria Fellman 1974): `w_i ← w_i (d_i / Σ_j w_j d_j)^½` with
//! `d_i = tr(S F_i)`, `S = F⁻¹ Q F⁻¹` (I) or `F⁻¹` (D), which never increases the criterion and
//! reaches the optimum where every `d_i ≤ Σ_j w_j d_j` (the equivalence theorem of Kiefer and
//! Wolfowitz): [`Design::equivalence`] is `max_i d_i / Σ_j w_j d_j`, 1 at the optimum. The
//! weights are rounded to whole measurements by largest remainders.
//!
//! The information is that of the whitened least-squares estimate: it ranks designs. The
//! uncertainty of what volver's Φ estimate of a designed plan gives is
//! [`crate::analysis::uncertainty::linear`]'s, computed on the plan itself.

use crate::nullspace::NullSpace;
use faer::{Mat, Side};
use rayon::prelude::*;
use volver_core::machine::Commands;
use volver_core::model::Model;
use volver_core::noise::TrackerNoise;
use volver_core::plan::Plan;
use volver_core::problem::{Problem, Residuals};

/// What a design minimises.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[non_exhaustive]
pub enum Criterion {
    /// The mean variance of the tool point over the work volume, after the set-up's transform.
    I,
    /// The volume of the parameters' confidence ellipsoid.
    D,
    /// The largest variance of the tool point over the work volume, after the set-up's
    /// transform.
    V,
}

impl Criterion {
    /// The criterion's letter (`I`, `V`, `D`), as plans name it.
    pub fn letter(self) -> &'static str {
        match self {
            Criterion::I => "I",
            Criterion::V => "V",
            Criterion::D => "D",
        }
    }
}

impl std::str::FromStr for Criterion {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "i" | "I" => Ok(Criterion::I),
            "d" | "D" => Ok(Criterion::D),
            "v" | "V" => Ok(Criterion::V),
            _ => Err(format!(
                "unknown design criterion '{s}': i (I-optimal), v (V-optimal) or d (D-optimal)"
            )),
        }
    }
}

/// The candidates' information, ready for designs.
pub struct Space {
    /// The candidates' whitened rows in the free coordinates (`per` per candidate, in
    /// `candidates.steps()` order: from each station and each measurement of the candidate's
    /// group 3, or 1 where the station measures ranges alone).
    a: Mat<f64>,
    /// Rows per candidate: 3 per station of the machine and measurement of the group, 1 per
    /// station of ranges alone (a range's information has rank one: the two other rows would
    /// be zero, a third of the work of every iteration on a layout of ranges).
    per: usize,
    /// `Q` of the I-criterion (nf × nf).
    q: Mat<f64>,
    /// The tool points' aligned Jacobians in the free coordinates (3K × nf).
    gz: Mat<f64>,
    /// The prior `R` (nf × nf).
    r: Mat<f64>,
    /// Candidate points.
    m: usize,
}

/// A design: weights on the candidates and the measurements they round to.
#[derive(Clone, Debug, PartialEq)]
pub struct Design {
    /// The optimal weight of each candidate point (`candidates.steps()` order), summing to 1.
    pub weights: Vec<f64>,
    /// The measurements of each candidate point, summing to the design's size.
    pub counts: Vec<usize>,
    /// The criterion of the rounded design: `tr(Q F⁻¹)` (mm², the tool point's mean variance
    /// summed over its three coordinates) for I, `log det F` for D.
    pub value: f64,
    /// `max_i d_i / Σ_j w_j d_j` at the last iteration: 1 at the optimum.
    pub equivalence: f64,
    /// Iterations of the multiplicative algorithm.
    pub iterations: usize,
}

impl Space {
    /// The information of every candidate point of `candidates` (every step of the plan, from
    /// every station) under each station's noise — its own `[[station]]` table's, else the
    /// tracker's `noise` ([`Problem::whitened`]) — and the I-criterion's `Q` for the tool
    /// offset `tool` (mm, from the last tool-side axis) over the commands `grid`. `None` when
    /// a station's noise is zero (nothing to weigh by), a Jacobian is not finite or the
    /// model's constraints are inconsistent.
    pub fn new(
        model: &Model,
        candidates: &Plan,
        noise: &TrackerNoise,
        tool: [f64; 3],
        grid: &[Commands],
    ) -> Option<Space> {
        Space::grouped(model, (candidates, 1), noise, tool, grid)
    }

    /// [`Space::new`] for candidates of `group` consecutive steps of `candidates` each, measured
    /// together: a bidirectional plan's pair (the same reflector at the same pose approached
    /// from below, then from above, [`volver_core::plan::sides`]), whose information is the sum
    /// of both, the reversal's columns included. `None` as [`Space::new`], or when the steps
    /// do not divide into groups.
    pub fn grouped(
        model: &Model,
        (candidates, group): (&Plan, usize),
        noise: &TrackerNoise,
        tool: [f64; 3],
        grid: &[Commands],
    ) -> Option<Space> {
        let steps = candidates.n_points();
        if group == 0 || steps % group != 0 {
            return None;
        }
        let p0 = model.initial_params();
        let data = crate::analysis::observability::nominal_data(model, candidates);
        let problem = Problem::new(model, &data).ok()?;
        let whitened = problem.whitened(Some(noise)).ok()?;
        let ns = NullSpace::from_constraints(model.constraints(), &p0).ok()?;
        let (n, nf, rows_total) = (p0.len(), ns.n_free(), problem.n_points());
        let stations = model.machine().stations().len();
        let m = steps / group;
        let basis = ns.basis();
        // Each measurement's whitened Jacobian rows (n columns): three, or for a scalar
        // residual (a range) the one row that carries its information.
        let rows: Vec<Vec<f64>> = (0..rows_total)
            .into_par_iter()
            .map(|i| information_rows(&whitened, i, &p0))
            .collect();
        if rows.iter().flatten().any(|v| !v.is_finite()) {
            return None;
        }
        let (j, per) = stacked(&rows, n, (stations, steps, group));
        let a = crate::engines::kernels::product(j.as_ref(), basis);
        let tool_grid = crate::analysis::uncertainty::ToolGrid {
            commands: grid.to_vec(),
            tool,
        };
        let g = tool_grid.jacobian(model, &p0, true);
        let gz = crate::engines::kernels::product(g.as_ref(), basis);
        let k = grid.len().max(1) as f64;
        let q = Mat::from_fn(nf, nf, |r, c| {
            (0..gz.nrows())
                .map(|i| gz[(i, r)] * gz[(i, c)])
                .sum::<f64>()
                / k
        });
        let metric = crate::engines::gauge::function_metric(model, &p0);
        let prior = crate::analysis::uncertainty::HELD_PRIOR_MM;
        let mz = crate::engines::kernels::sandwich(metric.as_ref(), basis);
        let r = Mat::from_fn(nf, nf, |i, c| mz[(i, c)] / (prior * prior));
        Some(Space {
            a,
            per,
            q,
            gz,
            r,
            m,
        })
    }

    /// Candidate points.
    pub fn len(&self) -> usize {
        self.m
    }

    /// Whether there is no candidate.
    pub fn is_empty(&self) -> bool {
        self.m == 0
    }

    /// `F = R + Σ c_i F_i` for per-candidate multiplicities `c`.
    fn information(&self, c: &[f64]) -> Mat<f64> {
        let nf = self.r.nrows();
        let root: Vec<f64> = c
            .iter()
            .flat_map(|x| std::iter::repeat_n(x.max(0.0).sqrt(), self.per))
            .collect();
        let mut scaled = Mat::<f64>::zeros(self.a.nrows(), nf);
        for col in 0..nf {
            let rows = scaled.col_mut(col).iter_mut().zip(self.a.col(col).iter());
            for ((out, a), s) in rows.zip(&root) {
                *out = s * a;
            }
        }
        let ata = crate::engines::kernels::product(scaled.transpose(), scaled.as_ref());
        Mat::from_fn(nf, nf, |i, j| self.r[(i, j)] + ata[(i, j)])
    }

    /// `d_i = tr(S F_i)` of every candidate: the sum over its rows of `a S aᵀ`, each row's
    /// accumulated column by column (the matrices are column-major) over the halves of `A S`.
    fn leverages(&self, s: &Mat<f64>) -> Vec<f64> {
        let (left, right) = crate::engines::kernels::product_parts(self.a.as_ref(), s.as_ref());
        let mut by_row = vec![0.0; self.a.nrows()];
        let mut col = 0;
        for part in std::iter::once(&left).chain(right.as_ref()) {
            for k in 0..part.ncols() {
                let rows = by_row.iter_mut().zip(part.col(k).iter());
                for ((acc, p), a) in rows.zip(self.a.col(col).iter()) {
                    *acc += p * a;
                }
                col += 1;
            }
        }
        by_row
            .chunks(self.per)
            .map(|rows| rows.iter().sum())
            .collect()
    }

    /// `F⁻¹` and `log det F` (`None` when F is not positive definite).
    fn inverse(f: &Mat<f64>) -> Option<(Mat<f64>, f64)> {
        let e = f.self_adjoint_eigen(Side::Lower).ok()?;
        let (s, u) = (e.S().column_vector(), e.U());
        let nf = f.nrows();
        if (0..nf).any(|i| s[i].is_nan() || s[i] <= 0.0) {
            return None;
        }
        let scaled = Mat::from_fn(nf, nf, |r, c| u[(r, c)] / s[c]);
        let logdet = (0..nf).map(|i| s[i].ln()).sum();
        Some((
            crate::engines::kernels::product(scaled.as_ref(), u.transpose()),
            logdet,
        ))
    }

    /// The variance of each grid point's tool point (summed over its coordinates, mm²) under
    /// the information of multiplicities `c`.
    fn point_variances(&self, inv: &Mat<f64>) -> Vec<f64> {
        let p = crate::engines::kernels::product(self.gz.as_ref(), inv.as_ref());
        let nf = inv.nrows();
        (0..self.gz.nrows() / 3)
            .map(|k| {
                (3 * k..3 * k + 3)
                    .map(|row| {
                        (0..nf)
                            .map(|j| p[(row, j)] * self.gz[(row, j)])
                            .sum::<f64>()
                    })
                    .sum()
            })
            .collect()
    }

    /// `Σ_k ω_k G_kᵀ G_k` for grid weights `omega` (summing to 1).
    fn weighted_q(&self, omega: &[f64]) -> Mat<f64> {
        let nf = self.gz.ncols();
        let scaled = Mat::from_fn(self.gz.nrows(), nf, |row, col| {
            omega[row / 3].sqrt() * self.gz[(row, col)]
        });
        crate::engines::kernels::product(scaled.transpose(), scaled.as_ref())
    }

    /// The criterion of per-candidate multiplicities `c` (measurements of each candidate point):
    /// `tr(Q F⁻¹)` (mm²) for I, the largest grid point's variance (mm²) for V, `log det F` for
    /// D.
    pub fn value(&self, c: &[f64], criterion: Criterion) -> Option<f64> {
        let (inv, logdet) = Space::inverse(&self.information(c))?;
        Some(match criterion {
            Criterion::V => self.point_variances(&inv).into_iter().fold(0.0, f64::max),
            Criterion::I => (0..inv.nrows())
                .map(|i| {
                    (0..inv.nrows())
                        .map(|k| self.q[(i, k)] * inv[(k, i)])
                        .sum::<f64>()
                })
                .sum(),
            Criterion::D => logdet,
        })
    }

    /// The optimal design of `points` measurements: the multiplicative algorithm from uniform
    /// weights for at most `iterations` iterations (or until the equivalence ratio is within
    /// 1e-3 of 1), then rounded. V-optimality is approached by I-optimal designs whose grid
    /// points are reweighted towards the largest variances (ω_k ∝ ω_k v_k, eight rounds
    /// warm-started from the previous weights); its equivalence ratio is the last round's.
    pub fn design(&self, points: usize, criterion: Criterion, iterations: usize) -> Option<Design> {
        let m = self.m;
        let total = points as f64;
        let mut w = vec![1.0 / m as f64; m];
        let (equivalence, done) = match criterion {
            Criterion::I => self.iterate(&mut w, total, Some(&self.q), iterations)?,
            Criterion::D => self.iterate(&mut w, total, None, iterations)?,
            Criterion::V => {
                const ROUNDS: usize = 8;
                let k = self.gz.nrows() / 3;
                let mut omega = vec![1.0 / k as f64; k];
                let mut last = (f64::INFINITY, 0);
                let mut done = 0;
                for round in 0..ROUNDS {
                    let q = self.weighted_q(&omega);
                    let share = if round + 1 == ROUNDS {
                        iterations
                    } else {
                        (iterations / ROUNDS).max(1)
                    };
                    last = self.iterate(&mut w, total, Some(&q), share)?;
                    done += last.1;
                    let c: Vec<f64> = w.iter().map(|x| x * total).collect();
                    let (inv, _) = Space::inverse(&self.information(&c))?;
                    let v = self.point_variances(&inv);
                    let mean: f64 = omega.iter().zip(&v).map(|(a, b)| a * b).sum();
                    for (o, vk) in omega.iter_mut().zip(&v) {
                        *o *= vk / mean;
                    }
                    let sum: f64 = omega.iter().sum();
                    omega.iter_mut().for_each(|o| *o /= sum);
                }
                (last.0, done)
            }
        };
        let counts = round(&w, points);
        let c: Vec<f64> = counts.iter().map(|&k| k as f64).collect();
        Some(Design {
            value: self.value(&c, criterion)?,
            weights: w,
            counts,
            equivalence,
            iterations: done,
        })
    }

    /// The multiplicative algorithm on `w` for `tr(Q F⁻¹)` (with `q`) or `log det F`
    /// (without): at most `iterations` iterations, or until the equivalence ratio is within
    /// 1e-3 of 1. Returns that ratio and the iterations done.
    fn iterate(
        &self,
        w: &mut [f64],
        total: f64,
        q: Option<&Mat<f64>>,
        iterations: usize,
    ) -> Option<(f64, usize)> {
        let mut equivalence = f64::INFINITY;
        let mut done = 0;
        for it in 0..iterations {
            done = it + 1;
            let c: Vec<f64> = w.iter().map(|x| x * total).collect();
            let (inv, _) = Space::inverse(&self.information(&c))?;
            let s = match q {
                Some(q) => {
                    let qi = crate::engines::kernels::product(q.as_ref(), inv.as_ref());
                    crate::engines::kernels::product(inv.as_ref(), qi.as_ref())
                }
                None => inv,
            };
            let d = self.leverages(&s);
            let mean: f64 = w.iter().zip(&d).map(|(a, b)| a * b).sum();
            if !(mean > 0.0 && mean.is_finite()) {
                return None;
            }
            equivalence = d.iter().fold(0.0_f64, |a, &b| a.max(b)) / mean;
            if equivalence < 1.0 + 1e-3 {
                break;
            }
            for (wi, di) in w.iter_mut().zip(&d) {
                *wi *= (di / mean).max(0.0).sqrt();
            }
            let sum: f64 = w.iter().sum();
            w.iter_mut().for_each(|x| *x /= sum);
        }
        Some((equivalence, done))
    }
}

/// The candidates' rows stacked candidate-major (`rows`: each measurement's whitened rows, `n`
/// columns, station-major: `stations` × `steps`), each candidate `group` consecutive steps,
/// and the rows per candidate. A station whose every measurement is a scalar gives one row per
/// measurement, else three (a scalar measurement's row first, then zeros).
fn stacked(
    rows: &[Vec<f64>],
    n: usize,
    (stations, steps, group): (usize, usize, usize),
) -> (Mat<f64>, usize) {
    let m = steps / group;
    let widths: Vec<usize> = (0..stations)
        .map(|s| {
            if (0..steps).all(|i| rows[s * steps + i].len() == n) {
                1
            } else {
                3
            }
        })
        .collect();
    // A candidate's rows: from each station, each measurement of its group, each row.
    let place: Vec<(usize, usize, usize)> = widths
        .iter()
        .enumerate()
        .flat_map(|(s, &w)| (0..group).flat_map(move |g| (0..w).map(move |k| (s, g, k))))
        .collect();
    let per = place.len();
    // Candidate i's rows from station s are measurements s·steps + i·group + g's.
    let j = Mat::from_fn(per * m, n, |r, c| {
        let (i, (s, g, k)) = (r / per, place[r % per]);
        rows[s * steps + i * group + g]
            .get(k * n + c)
            .copied()
            .unwrap_or(0.0)
    });
    (j, per)
}

/// Measurement `i`'s whitened Jacobian rows at `p0` (row-major, `n` columns each): its three
/// rows, or for a scalar residual (a range, whose Jacobian's second and third rows are zero,
/// so that its whitened rows `W e₀ J₀` are all multiples of one) the single row `‖W e₀‖ J₀`
/// with the same information.
fn information_rows(whitened: &Problem<'_>, i: usize, p0: &[f64]) -> Vec<f64> {
    let n = p0.len();
    let mut row = vec![0.0; 3 * n];
    whitened.residual_and_jacobian(i, p0, &mut row);
    if !whitened.scalar(i) {
        return row;
    }
    let norms: Vec<f64> = row
        .chunks(n)
        .map(|r| r.iter().map(|v| v * v).sum::<f64>().sqrt())
        .collect();
    let (top, _) = norms.iter().enumerate().fold(
        (0, -1.0),
        |best, (k, &v)| if v > best.1 { (k, v) } else { best },
    );
    let total = norms.iter().map(|v| v * v).sum::<f64>().sqrt();
    let gain = if norms[top] > 0.0 {
        total / norms[top]
    } else {
        0.0
    };
    row[top * n..(top + 1) * n]
        .iter()
        .map(|v| v * gain)
        .collect()
}

/// Weights rounded to `points` whole measurements by largest remainders (ties to the earlier
/// candidate).
fn round(w: &[f64], points: usize) -> Vec<usize> {
    let total = points as f64;
    let mut counts: Vec<usize> = w.iter().map(|x| (x * total).floor() as usize).collect();
    let mut left = points.saturating_sub(counts.iter().sum());
    let mut order: Vec<usize> = (0..w.len()).collect();
    order.sort_by(|&a, &b| {
        let ra = w[a] * total - counts[a] as f64;
        let rb = w[b] * total - counts[b] as f64;
        rb.total_cmp(&ra).then(a.cmp(&b))
    });
    for &i in order.iter().cycle().take(w.len() * 2) {
        if left == 0 {
            break;
        }
        counts[i] += 1;
        left -= 1;
    }
    counts
}

#[cfg(test)]
mod tests {
    use super::*;
    use volver_core::machine::{Machine, Observes, StationSpec};

    /// The reflectors' centroid (mm).
    fn centroid(model: &Model) -> [f64; 3] {
        let r = model.machine().reflectors();
        std::array::from_fn(|c| r.iter().map(|x| x.offset[c]).sum::<f64>() / r.len() as f64)
    }

    /// The I (tool point at the reflectors' centroid) and D criteria of measuring a grid of 36
    /// poses (X 0–1400 mm by 700, C 0–270° by 90, Z 0–600 mm by 300) once from four range-only
    /// stations whose noises are `noises` (their own `[[station]]` noise).
    fn criteria(noises: [&str; 4]) -> (f64, f64) {
        let xcfz = Machine::default_xcfz();
        let mut layout = StationSpec::default_layout(&xcfz, 4, Observes::Range);
        for (st, n) in layout.iter_mut().zip(noises) {
            st.noise = Some(n.to_string());
        }
        let machine = xcfz.with_stations(layout).unwrap();
        let model = Model::new(machine, Model::default_xcfz().spec().clone()).unwrap();
        let plan =
            Plan::parse_grid(model.machine(), "X=0:1400:700,C=0:270:90,Z=0:600:300").unwrap();
        // The tracker's default noise: no station takes it.
        let space = Space::new(
            &model,
            &plan,
            &TrackerNoise::PAPER,
            centroid(&model),
            &plan.positions,
        )
        .unwrap();
        let once = vec![1.0; space.len()];
        (
            space.value(&once, Criterion::I).unwrap(),
            space.value(&once, Criterion::D).unwrap(),
        )
    }

    /// A station that states a noisier model brings less information: with one of four
    /// stations' σ doubled, the tool point's mean variance (I) is larger and log det F (D)
    /// smaller than with all four quiet, and both lie between that and all four doubled. The
    /// data, not the weak prior, determine the tool point here: all four doubled is 4 × the
    /// variance (to 5 %; measured 8.32e-7, 1.147e-6 with one doubled, 3.33e-6 mm²).
    #[test]
    fn a_noisier_station_weighs_less_in_the_design() {
        let (quiet, loud) = ("normal:0,0,0.1,0.15", "normal:0,0,0.2,0.3");
        let (i_quiet, d_quiet) = criteria([quiet; 4]);
        let (i_one, d_one) = criteria([quiet, loud, quiet, quiet]);
        let (i_loud, d_loud) = criteria([loud; 4]);
        assert!(
            i_quiet < i_one && i_one < i_loud,
            "I: {i_quiet} {i_one} {i_loud}"
        );
        assert!(
            d_quiet > d_one && d_one > d_loud,
            "D: {d_quiet} {d_one} {d_loud}"
        );
        assert!(
            (i_loud / i_quiet / 4.0 - 1.0).abs() < 0.05,
            "{i_quiet} {i_loud}"
        );
        // One station of four doubled costs less than all four: at most half the way.
        assert!(
            i_one - i_quiet < 0.5 * (i_loud - i_quiet),
            "I: {i_quiet} {i_one} {i_loud}"
        );
    }

    /// A group of measurements weighs as their sum: the same step twice, grouped by two, is
    /// one step measured twice (the I-criterion equal to 1e-6: measured 8e-9, the rounding of the
    /// nearly singular information), and a bidirectional pair (from
    /// below, then from above) brings what two measurements from one side cannot: the
    /// reversal value of X, the D-criterion (log det F) larger by more than 1 (measured 9.3: the
    /// pair's B is the data's, the one side's mostly the prior's).
    #[test]
    fn a_group_weighs_as_the_sum_of_its_measurements() {
        use volver_core::approach::Approach;
        use volver_core::model::ReversalSpec;
        let mut spec = Model::default_xcfz().spec().clone();
        spec.effects.reversal.push(ReversalSpec::Axis("X".into()));
        let model = Model::new(Machine::default_xcfz(), spec).unwrap();
        let plan =
            Plan::parse_grid(model.machine(), "X=0:1400:700,C=0:270:90,Z=0:600:300").unwrap();
        let (up, down) = (Approach::all(3, 1), Approach::all(3, -1));
        let doubled = |sides: [Approach; 2]| Plan {
            sequence: Some(plan.steps().iter().flat_map(|s| [*s, *s]).collect()),
            approach: Some((0..plan.n_points()).flat_map(|_| sides).collect()),
            ..plan.clone()
        };
        let (tool, noise) = (centroid(&model), TrackerNoise::PAPER);
        let one_side = Plan {
            approach: Some(vec![up; plan.n_points()]),
            ..plan.clone()
        };
        let space = |p: &Plan, group| {
            Space::grouped(&model, (p, group), &noise, tool, &plan.positions).unwrap()
        };
        let single = space(&one_side, 1);
        let same = space(&doubled([up, up]), 2);
        let both = space(&doubled([up, down]), 2);
        assert_eq!((same.len(), both.len()), (single.len(), single.len()));
        let once = vec![1.0; single.len()];
        let twice = vec![2.0; single.len()];
        let (a, b) = (
            same.value(&once, Criterion::I).unwrap(),
            single.value(&twice, Criterion::I).unwrap(),
        );
        assert!((a / b - 1.0).abs() < 1e-6, "{a} {b}");
        let (d_same, d_both) = (
            same.value(&once, Criterion::D).unwrap(),
            both.value(&once, Criterion::D).unwrap(),
        );
        assert!(d_both > d_same + 1.0, "{d_same} {d_both}");
        assert!(Space::grouped(&model, (&one_side, 5), &noise, tool, &plan.positions).is_none());
    }

    /// A range's one row carries the information of its three whitened rows, and a layout of
    /// ranges alone has one row per station and candidate.
    #[test]
    fn a_range_has_one_row_with_its_whole_information() {
        use volver_core::machine::{Machine, Observes, StationSpec};
        let xcfz = Machine::default_xcfz();
        let multi = xcfz
            .with_stations(StationSpec::default_layout(&xcfz, 2, Observes::Range))
            .unwrap();
        let text = volver_core::model::DEFAULT_MODEL_TOML.replace(
            "identify = [\"x\", \"y\", \"z\"]",
            "identify = [\"x\", \"y\", \"z\"]\nrange_offset = true",
        );
        let model = Model::from_toml_str(multi.clone(), &text, "ranges").unwrap();
        let plan = Plan::parse_grid(&multi, "X=0:1400:700,C=0:270:90,Z=0:600:300").unwrap();
        let data = crate::analysis::observability::nominal_data(&model, &plan);
        let problem = Problem::new(&model, &data).unwrap();
        let whitened = problem.whitened(Some(&TrackerNoise::PAPER)).unwrap();
        let p0 = model.initial_params();
        let n = p0.len();
        for i in [0, 7, data.points.len() - 1] {
            assert!(problem.scalar(i));
            let one = information_rows(&whitened, i, &p0);
            assert_eq!(one.len(), n);
            let mut three = vec![0.0; 3 * n];
            whitened.residual_and_jacobian(i, &p0, &mut three);
            let size = three.iter().map(|v| v * v).sum::<f64>();
            for (j, k) in [(0, 0), (3, 5), (10, 40), (n - 1, n - 2)] {
                let full: f64 = (0..3).map(|r| three[r * n + j] * three[r * n + k]).sum();
                assert!(
                    (one[j] * one[k] - full).abs() <= 1e-12 * size,
                    "{i} {j} {k}"
                );
            }
        }
        let grid = [volver_core::machine::Commands::default()];
        let space = Space::new(&model, &plan, &TrackerNoise::PAPER, [0.0; 3], &grid).unwrap();
        assert_eq!((space.per, space.a.nrows()), (2, 2 * plan.n_points()));
    }

    #[test]
    fn rounding_keeps_the_total_and_the_largest_remainders() {
        assert_eq!(round(&[0.5, 0.3, 0.2], 10), vec![5, 3, 2]);
        assert_eq!(round(&[0.45, 0.35, 0.2], 4), vec![2, 1, 1]);
        assert_eq!(round(&[1.0 / 3.0; 3], 4).iter().sum::<usize>(), 4);
    }
}
