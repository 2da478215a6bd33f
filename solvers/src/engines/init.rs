//! The tracker pose's starting value. On real data the tracker's pose is unknown: it is
//! initialised by a rigid best fit (Horn/Kabsch) of the predicted points to the measured ones,
//! then identified with the errors.
//!
//! With the current parameters the model predicts `q_i = R⁻¹(w)·R0ᵀ·(p_i − T)` (eq. 9); the fit
//! finds the rotation `R_f` and translation `t` with `m_i ≈ R_f q_i + t` (least squares), and the
//! pose that reproduces it is `R⁻¹(w') ≈ R_f·R⁻¹(w)` (small angles), `T' = T − R0·R(w')·t`.
//! When the model holds any of the tracker's angles only the translation is fitted.
//!
//! ```
//! use volver_core::machine::Machine;
//! use volver_core::model::{ErrorModelSpec, Model};
//! use volver_core::noise::TrackerNoise;
//! use volver_core::plan::Plan;
//! use volver_core::problem::Problem;
//! use volver_core::simulate::{Magnitudes, Simulation, Truth};
//! use volver_solvers::init::init_tracker;
//! let m = Machine::default_xcfz();
//! let mut mags = Magnitudes::ZERO;
//! mags.tracker_mm = 20.0; // the true tracker is 10–20 mm from its nominal position
//! let truth = Truth::random(&m, &ErrorModelSpec::complete(&m), &mags, 3).unwrap();
//! let mut sim = Simulation::new(Plan::preset(&m, "test3").unwrap(), truth.clone(), 3);
//! sim.noise = TrackerNoise::NONE;
//! let data = sim.run().unwrap().measurements;
//! let model = Model::default_xcfz();
//! let problem = Problem::new(&model, &data).unwrap();
//! let p = init_tracker(&problem, &model.initial_params()).unwrap();
//! let t = model.tracker_start();
//! for k in 0..3 {
//!     assert!((p[t + k] - truth.tracker_pose()[k]).abs() < 1e-9);
//! }
//! ```

use faer::Mat;
use volver_core::model::{ConstraintKind, Owner};
use volver_core::problem::{Problem, Residuals};

/// Which tracker pose values the model holds (Fixed constraints on a single parameter).
pub fn held_tracker_values(problem: &Problem) -> [bool; 6] {
    let model = problem.model();
    let mut held = [false; 6];
    for row in &model.constraints().rows {
        if row.kind == ConstraintKind::Fixed
            && let [(j, _)] = row.coeffs.as_slice()
            && let Owner::Tracker(k) = model.params()[*j].owner
        {
            held[k] = true;
        }
    }
    held
}

/// `params` with the tracker pose replaced by the rigid best fit of the predicted to the
/// measured points (the translation alone when the model holds an angle). Errs when the fit
/// needs a rotation too large for the small angles of eq. 9 (more than 0.05 rad): the
/// machine file's tracker `orientation_deg` is then wrong.
pub fn init_tracker(problem: &Problem, params: &[f64]) -> Result<Vec<f64>, crate::Error> {
    // A start from the points themselves (mm), whatever weighting the fit applies.
    let problem = &problem.plain();
    let model = problem.model();
    if model.stations().len() > 1 || (0..problem.n_points()).any(|i| problem.scalar(i)) {
        return Ok(init_stations(problem, params));
    }
    let ts = model.tracker_start();
    let held = held_tracker_values(problem);
    let r0 = model.machine().tracker().base_rotation;
    let mut p = params.to_vec();
    let fit_rotation = !held[3] && !held[4] && !held[5];
    if fit_rotation {
        let (q, m) = points(problem, &p);
        let rf = kabsch(&q, &m).map_err(crate::Error::TrackerFit)?;
        // Small-angle vector of R_f ≈ I + [w_f]×.
        let wf = [
            0.5 * (rf[2][1] - rf[1][2]),
            0.5 * (rf[0][2] - rf[2][0]),
            0.5 * (rf[1][0] - rf[0][1]),
        ];
        let angle = (wf[0] * wf[0] + wf[1] * wf[1] + wf[2] * wf[2]).sqrt();
        if angle > 0.05 {
            return Err(crate::Error::TrackerFit(format!(
                "the measured points are turned by {:.2}° from the model's: correct the tracker's \
                 orientation_deg in the machine file (the identified angles are small, eq. 9)",
                angle.to_degrees()
            )));
        }
        for k in 0..3 {
            p[ts + 3 + k] += wf[k];
        }
    }
    // Translation: m_i − q_i is constant when only T is wrong.
    let (q, m) = points(problem, &p);
    let n = q.len() as f64;
    let t: [f64; 3] =
        std::array::from_fn(|c| q.iter().zip(&m).map(|(q, m)| m[c] - q[c]).sum::<f64>() / n);
    let w = [p[ts + 3], p[ts + 4], p[ts + 5]];
    // R(w)·t with R(w) = I − [w]× (eq. 4), then R0·(…).
    let rt = [
        t[0] - (w[1] * t[2] - w[2] * t[1]),
        t[1] - (w[2] * t[0] - w[0] * t[2]),
        t[2] - (w[0] * t[1] - w[1] * t[0]),
    ];
    for k in 0..3 {
        if !held[k] {
            p[ts + k] -= (0..3).map(|j| r0[k][j] * rt[j]).sum::<f64>();
        }
    }
    Ok(p)
}

/// Gauss–Newton iterations at most per station in [`init_stations`].
const STATION_STEPS: usize = 30;

/// `params` with every station's free values (its position, its orientation when it observes
/// points and the model frees it, its range offset when modelled) fitted to that station's own
/// measurements, the machine's errors held: Gauss–Newton on the exact Jacobian, each step halved
/// until the squared residuals decrease, until a step moves less than 1e-9 mm or rad. What
/// [`init_tracker`] does for several stations or for ranges alone (a rigid fit of all the
/// points at once would mix the stations' frames).
pub fn init_stations(problem: &Problem, params: &[f64]) -> Vec<f64> {
    let model = problem.model();
    let n = model.n_params();
    let held: Vec<bool> = {
        let mut h = vec![false; n];
        for row in &model.constraints().rows {
            if let [(j, _)] = row.coeffs.as_slice() {
                h[*j] = true;
            }
        }
        h
    };
    let mut p = params.to_vec();
    let data = problem.data();
    for (s, block) in model.stations().iter().enumerate() {
        let rows: Vec<usize> = (0..problem.n_points())
            .filter(|&i| data.points[i].station_index == s)
            .collect();
        let cols: Vec<usize> = (block.pose..block.pose + 6)
            .chain(block.offset)
            .filter(|&j| !held[j])
            .collect();
        if rows.is_empty() || cols.is_empty() {
            continue;
        }
        let cost = |p: &[f64]| -> f64 {
            rows.iter()
                .map(|&i| {
                    let r = problem.residual(i, p);
                    r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
                })
                .sum()
        };
        let k = cols.len();
        let mut jac = vec![0.0; 3 * n];
        let mut current = cost(&p);
        for _ in 0..STATION_STEPS {
            // Normal equations over the station's columns.
            let mut h = vec![0.0; k * k];
            let mut g = vec![0.0; k];
            for &i in &rows {
                let r = problem.residual_and_jacobian(i, &p, &mut jac);
                for c in 0..3 {
                    for (a, &ja) in cols.iter().enumerate() {
                        let va = jac[c * n + ja];
                        g[a] += va * r[c];
                        for (b, &jb) in cols.iter().enumerate() {
                            h[a * k + b] += va * jac[c * n + jb];
                        }
                    }
                }
            }
            let Some(step) = volver_core::compensate::solve_dense(&mut h, &mut g, k) else {
                break;
            };
            let mut t = 1.0;
            let mut moved = false;
            for _ in 0..20 {
                let mut q = p.clone();
                for (a, &j) in cols.iter().enumerate() {
                    q[j] -= t * step[a];
                }
                let c = cost(&q);
                if c.is_finite() && c < current {
                    p = q;
                    current = c;
                    moved = true;
                    break;
                }
                t *= 0.5;
            }
            let size = step.iter().fold(0.0_f64, |m, v| m.max(v.abs())) * t;
            if !moved || size < 1e-9 {
                break;
            }
        }
    }
    p
}

/// Predicted and measured points.
type Points = Vec<[f64; 3]>;

fn points(problem: &Problem, p: &[f64]) -> (Points, Points) {
    use rayon::prelude::*;
    let data = problem.data();
    // On every core, collected in point order.
    let q = (0..problem.n_points())
        .into_par_iter()
        .with_min_len(64)
        .map(|i| {
            let r = problem.residual(i, p);
            let m = data.points[i].measured;
            [m[0] + r[0], m[1] + r[1], m[2] + r[2]]
        })
        .collect();
    let m = data.points.iter().map(|pt| pt.measured).collect();
    (q, m)
}

/// The rotation R minimising Σ‖R(q_i − q̄) − (m_i − m̄)‖² (Kabsch, with the reflection fix).
fn kabsch(q: &[[f64; 3]], m: &[[f64; 3]]) -> Result<[[f64; 3]; 3], String> {
    let n = q.len() as f64;
    let mean = |v: &[[f64; 3]]| -> [f64; 3] {
        std::array::from_fn(|c| v.iter().map(|x| x[c]).sum::<f64>() / n)
    };
    let (qc, mc) = (mean(q), mean(m));
    // H = Σ (q − q̄)(m − m̄)ᵀ
    let h = Mat::from_fn(3, 3, |i, j| {
        q.iter()
            .zip(m)
            .map(|(a, b)| (a[i] - qc[i]) * (b[j] - mc[j]))
            .sum::<f64>()
    });
    let svd = h
        .svd()
        .map_err(|_| "the SVD of the Kabsch covariance did not converge".to_string())?;
    let (u, s, v) = (svd.U(), svd.S().column_vector(), svd.V());
    if s[1] <= 1e-12 * s[0] {
        return Err(
            "the measured points are collinear: the tracker's rotation cannot be fitted".into(),
        );
    }
    let r0: [[f64; 3]; 3] = std::array::from_fn(|i| {
        std::array::from_fn(|j| (0..3).map(|k| v[(i, k)] * u[(j, k)]).sum())
    });
    let det = r0[0][0] * (r0[1][1] * r0[2][2] - r0[1][2] * r0[2][1])
        - r0[0][1] * (r0[1][0] * r0[2][2] - r0[1][2] * r0[2][0])
        + r0[0][2] * (r0[1][0] * r0[2][1] - r0[1][1] * r0[2][0]);
    let dsign = if det < 0.0 { -1.0 } else { 1.0 };
    Ok(std::array::from_fn(|i| {
        std::array::from_fn(|j| {
            (0..3)
                .map(|k| v[(i, k)] * u[(j, k)] * if k == 2 { dsign } else { 1.0 })
                .sum()
        })
    }))
}
