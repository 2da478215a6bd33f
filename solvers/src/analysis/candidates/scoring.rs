//! Scoring the candidates: one Gauss–Newton step of each extended model from the current fit,
//! its evidence (ΔBIC), its predicted EMM and its sizes; the ranking.

use super::novelty::{self, Expressible};
use super::sizes::{Sizing, plausible};
use super::{Candidate, Score, offered};
use crate::Task;
use crate::engines::coordinates::{Reduced, reduced_normal_under};
use faer::Side;
use volver_core::basis::{BasisKind, chebyshev_nodes};
use volver_core::model::Model;
use volver_core::noise::TrackerNoise;
use volver_core::problem::{Problem, Residuals};
use volver_core::units::UM_PER_MM;

/// Scores every candidate of the library the data can identify ([`offered`]) at the solution `params` of `problem`'s model and
/// ranks them by ΔBIC. `tolerance` is the rank tolerance (as the engine's). With the noise of
/// every station — its own `[[station]]` table's, else the tracker's `noise` — the residuals
/// are whitened by it (each point and direction weighed by its station's noise: angular noise
/// grows with the distance, a range counts by its range σ); without, every coordinate weighs
/// the same.
///
/// Each candidate's new parameters are held to plausible sizes
/// ([`volver_core::plausibility::limit`]) by a prior at that size, so a direction the data
/// barely see cannot carry a step of metres. A candidate is flagged ([`Score::flag`]) and never
/// ranked first when its size still exceeds the bound, or when its evidence needs a size beyond
/// the bound (nearly unidentifiable: the bound costs more than 10 in ΔBIC); both sizes are of
/// what the candidate adds beyond the current model ([`Score::size`]).
pub fn rank(
    problem: &Problem,
    params: &[f64],
    tolerance: f64,
    noise: Option<&TrackerNoise>,
) -> Vec<Score> {
    let model = problem.model();
    let m = (3 * problem.n_points()) as f64;
    let base = Scored::new(problem.clone(), noise);
    let Some((p0, rank0)) = gauss_newton_steps(&base.task(), params, tolerance, &[None]) else {
        // Nothing can be compared with a current model whose own step fails: every candidate
        // is listed with the reason, none dropped.
        return offered(model, problem.data())
            .into_iter()
            .map(|c| {
                let why = "the current model's Gauss-Newton step is singular or not finite, so \
                           no candidate can be compared with it"
                    .to_string();
                Score::failed(c.id, c.description, why)
            })
            .collect();
    };
    let rss0 = base.linear_predictions(params, &[&p0[0]])[0].0;
    // The residuals' variance per coordinate in the scoring's units: the prior's scale.
    let variance = rss0 / (m - rank0 as f64).max(1.0);
    let expressible = Expressible::new(problem, params, tolerance);
    let scores: Vec<Score> = offered(model, problem.data())
        .into_iter()
        .map(|c| {
            let (id, description) = (c.id.clone(), c.description.clone());
            let Some(expressible) = &expressible else {
                let why = "the current model's Jacobian is not finite, so what a candidate adds \
                           beyond it cannot be measured"
                    .to_string();
                return Score::failed(id, description, why);
            };
            let scoring = Scoring {
                problem,
                params,
                tolerance,
                noise,
                rank0,
                rss0,
                variance,
                expressible,
            };
            scoring
                .score(&c)
                .unwrap_or_else(|why| Score::failed(id, description, why))
        })
        .collect();
    sort_and_merge(scores)
}

/// What every candidate is scored against: the current model's problem and fit.
struct Scoring<'a, 'p> {
    /// The current model's problem.
    problem: &'a Problem<'p>,
    /// The current fit.
    params: &'a [f64],
    /// The rank tolerance (relative curvature).
    tolerance: f64,
    /// The tracker's noise the residuals are whitened by (with each station's own), when known.
    noise: Option<&'a TrackerNoise>,
    /// The directions the data identify in the current model.
    rank0: usize,
    /// The current model's residual sum of squares after its own step (the scoring's units).
    rss0: f64,
    /// The residuals' variance per coordinate (the scoring's units): the prior's scale.
    variance: f64,
    /// What the current model can express at the data points.
    expressible: &'a Expressible,
}

impl Scoring<'_, '_> {
    /// The score of candidate `c` against the current model's fit, or why it cannot be scored:
    /// the step of its extended model from the fit carried over, held to plausible sizes
    /// ([`Scoring::ridge`]) and free; its evidence, sizes, flag and predicted EMM.
    fn score(&self, c: &Candidate) -> Result<Score, String> {
        let (model, data, tolerance) = (self.problem.model(), self.problem.data(), self.tolerance);
        let singular = || "its Gauss-Newton step is singular or not finite".to_string();
        let extended = Model::new(model.machine().clone(), c.spec.clone())
            .map_err(|e| format!("its model cannot be built: {e}"))?;
        let problem = Problem::new(&extended, data)
            .map_err(|e| format!("its problem cannot be built: {e}"))?;
        let ext = Scored::new(problem, self.noise);
        let start = carry_over(model, self.params, &extended);
        let ridge = self.ridge(&extended);
        // The step held to plausible sizes, and the same step without the bound.
        let (steps, rank1) =
            gauss_newton_steps(&ext.task(), &start, tolerance, &[Some(&ridge), None])
                .ok_or_else(singular)?;
        let (q, qf) = (&steps[0], &steps[1]);
        let predicted = ext.linear_predictions(&start, &[q, qf]);
        let jac = novelty::jacobian(ext.problem(), &start);
        let sizing = Sizing {
            id: &c.id,
            model,
            extended: &extended,
            params: self.params,
            expressible: self.expressible,
            jac: &jac,
            start: &start,
            tolerance,
        };
        let (size, unit) = sizing.size(q).ok_or_else(singular)?;
        let added = rank1.saturating_sub(self.rank0);
        let delta_bic = self.delta_bic(predicted[0].0, added);
        let (_, size_unit) = unit.micro();
        let bound = sizing.bound(data, unit);
        let bic_free = self.delta_bic(predicted[1].0, added);
        let flag = sizing
            .flag((size, size_unit, bound), (qf, bic_free), delta_bic)
            .ok_or_else(singular)?;
        let emm_um = predicted_emm(ext.problem(), &start, tolerance).ok_or_else(singular)?;
        Ok(Score {
            id: c.id.clone(),
            description: c.description.clone(),
            added,
            emm_um,
            delta_bic,
            size,
            size_unit,
            equivalent: Vec::new(),
            flag,
            failed: None,
        })
    }

    /// The prior that holds a candidate's new parameters to plausible sizes, one weight per
    /// parameter of its `extended` model (the residuals' units squared per parameter unit
    /// squared): the variance per coordinate over the plausible size squared for a new
    /// parameter ([`plausible`]), zero for one the current model has.
    fn ridge(&self, extended: &Model) -> Vec<f64> {
        let (model, data) = (self.problem.model(), self.problem.data());
        extended
            .params()
            .iter()
            .enumerate()
            .map(|(j, info)| match model.param_index(&info.name) {
                Some(_) => 0.0,
                None => self.variance / plausible(extended, data, j, info.unit).powi(2),
            })
            .collect()
    }

    /// ΔBIC = m·ln(RSS′/RSS) + Δk·ln m of a residual sum `rss` with `added` more identified
    /// directions, over the m = 3n residual coordinates.
    fn delta_bic(&self, rss: f64, added: usize) -> f64 {
        let m = (3 * self.problem.n_points()) as f64;
        m * (rss / self.rss0).ln() + added as f64 * m.ln()
    }
}

/// `params` of `model` carried over to `extended` (a superset): by name, new parameters zero,
/// Chebyshev node values re-evaluated at the new nodes so every function is unchanged.
pub fn carry_over(model: &Model, params: &[f64], extended: &Model) -> Vec<f64> {
    let mut p = extended.initial_params();
    for (j, info) in extended.params().iter().enumerate() {
        if let Some(i) = model.param_index(&info.name) {
            p[j] = params[i];
        }
    }
    for t in extended.terms() {
        if t.basis.kind() != BasisKind::Chebyshev {
            continue;
        }
        let Some(old) = model.term(t.id) else {
            continue;
        };
        if old.basis.degree() == t.basis.degree() {
            continue;
        }
        let nodes = chebyshev_nodes(t.basis.degree() + 1);
        for (k, z) in nodes.iter().enumerate() {
            p[t.params.start + k] = old.basis.value(*z, &params[old.params.clone()]);
        }
    }
    p
}

/// Gauss–Newton steps of least squares from `params` under the task's constraints, one per
/// entry of `ridges`, from one pass of the normal equations: the parameters after each, and
/// the number of directions the data identify (relative curvature above `tolerance`). A ridge
/// (one weight per parameter, in the residuals' units squared per parameter unit squared) adds
/// `Σ ridge_j δ_j²` to the least squares: a prior that holds a candidate's new parameters to
/// plausible sizes along directions the data barely see. The identified directions are counted
/// without it.
fn gauss_newton_steps(
    task: &Task,
    params: &[f64],
    tolerance: f64,
    ridges: &[Option<&[f64]>],
) -> Option<(Vec<Vec<f64>>, usize)> {
    weighted_steps(task, params, tolerance, ridges, &|_| (1.0, 0.0))
}

/// [`gauss_newton_steps`] of the least squares weighted per point by `weight(‖r_i‖)` (as
/// [`crate::engines::kernels::accumulate`] takes it).
fn weighted_steps(
    task: &Task,
    params: &[f64],
    tolerance: f64,
    ridges: &[Option<&[f64]>],
    weight: &(dyn Fn(f64) -> (f64, f64) + Sync),
) -> Option<(Vec<Vec<f64>>, usize)> {
    let n = params.len();
    let Reduced { d, ns, hz, gz } = reduced_normal_under(task, params, weight)?;
    let nf = ns.n_free();
    if nf == 0 {
        return Some((vec![params.to_vec(); ridges.len()], 0));
    }
    let basis = ns.basis();
    let evd = hz.self_adjoint_eigen(Side::Lower).ok()?;
    let mu = evd.S().column_vector();
    let mu_max = mu[nf - 1].max(f64::MIN_POSITIVE);
    let rank = (0..nf).filter(|&i| mu[i] > tolerance * mu_max).count();
    let mut steps = Vec::with_capacity(ridges.len());
    for ridge in ridges {
        let ridged;
        let evd = match ridge {
            Some(w) => {
                let wm = faer::Mat::from_fn(n, n, |i, j| if i == j { w[i] } else { 0.0 });
                let (extra, _) = crate::engines::coordinates::reduce(&d, basis, &wm, None);
                ridged = (&hz + &extra).self_adjoint_eigen(Side::Lower).ok()?;
                &ridged
            }
            None => &evd,
        };
        // Directions are kept by the data's own curvature scale (the ridge can only raise a
        // curvature, and must not push the data's directions below the tolerance).
        let (mu, v) = (evd.S().column_vector(), evd.U());
        let mut zeta = vec![0.0; nf];
        for i in 0..nf {
            if mu[i] > tolerance * mu_max {
                let c = -(0..nf).map(|k| v[(k, i)] * gz[k]).sum::<f64>() / mu[i];
                for (k, z) in zeta.iter_mut().enumerate() {
                    *z += v[(k, i)] * c;
                }
            }
        }
        steps.push(
            (0..n)
                .map(|j| params[j] + d[j] * (0..nf).map(|k| basis[(j, k)] * zeta[k]).sum::<f64>())
                .collect(),
        );
    }
    Some((steps, rank))
}

/// What the candidates are scored on: the problem's residuals, whitened by each station's
/// noise when it is known ([`Problem::whitened`]: each point and direction weighed by its
/// noise), beside the plain problem (mm) the EMM is measured on.
#[derive(Clone, Debug)]
struct Scored<'a> {
    plain: Problem<'a>,
    scored: Problem<'a>,
}

impl<'a> Scored<'a> {
    fn new(problem: Problem<'a>, noise: Option<&TrackerNoise>) -> Scored<'a> {
        // Each station by its own noise, else the tracker's `noise`; unweighted when a station
        // has neither.
        let scored = problem.whitened(noise).unwrap_or_else(|_| problem.clone());
        Scored {
            plain: problem,
            scored,
        }
    }

    fn task(&self) -> Task<'a> {
        Task::new(self.scored.clone())
    }

    fn problem(&self) -> &Problem<'a> {
        &self.plain
    }

    /// The residuals' sum of squares (in the scoring's units) and EMM (µm) predicted to first
    /// order after moving from `params` to each of `qs`: `r_i + J_i (q − params)` (the score
    /// test is a linear prediction; a full nonlinear step could overshoot along nearly
    /// redundant directions). One pass over the points.
    fn linear_predictions(&self, params: &[f64], qs: &[&[f64]]) -> Vec<(f64, f64)> {
        let problem = self.problem();
        let n = params.len();
        let deltas: Vec<Vec<f64>> = qs
            .iter()
            .map(|q| q.iter().zip(params).map(|(a, b)| a - b).collect())
            .collect();
        let mut jac = vec![0.0; 3 * n];
        let mut sums = vec![(0.0, 0.0); qs.len()];
        for i in 0..problem.n_points() {
            let r = problem.residual_and_jacobian(i, params, &mut jac);
            for (delta, (rss, sum)) in deltas.iter().zip(sums.iter_mut()) {
                let lin: [f64; 3] = std::array::from_fn(|c| {
                    r[c] + (0..n).map(|j| jac[c * n + j] * delta[j]).sum::<f64>()
                });
                let scored = self.scored.whiten(i, lin);
                *rss += scored.iter().map(|v| v * v).sum::<f64>();
                *sum += volver_core::problem::norm(lin);
            }
        }
        let count = problem.n_points() as f64;
        sums.into_iter()
            .map(|(rss, sum)| (rss, sum / count * UM_PER_MM))
            .collect()
    }
}

/// The EMM (µm) a refit of `problem`'s model from `start` would reach, predicted to first
/// order. The engines minimise the EMM itself (Φ, the mean error module), not the squares the
/// evidence is scored on: the prediction is the lower of the linearised EMM after the
/// unweighted Gauss–Newton step and after one majorise–minimise step of Φ (least squares
/// weighted by `1/‖r_i‖`, which majorises `Σ‖r_i + J_i δ‖` and so never raises the linearised
/// EMM above the current one). A refit can reach at least as low; a candidate is never
/// predicted to raise the EMM of the Φ fit it extends.
fn predicted_emm(problem: &Problem, start: &[f64], tolerance: f64) -> Option<f64> {
    let plain = Scored {
        plain: problem.clone(),
        scored: problem.plain(),
    };
    let task = plain.task();
    let modules: Vec<f64> = problem
        .residuals(start)
        .iter()
        .map(|r| volver_core::problem::norm(*r))
        .collect();
    let mean = modules.iter().sum::<f64>() / modules.len().max(1) as f64;
    // A module at rounding level must not take every weight.
    let floor = (1e-6 * mean).max(f64::MIN_POSITIVE);
    let (ls, _) = gauss_newton_steps(&task, start, tolerance, &[None])?;
    let weight = move |r: f64| (1.0 / r.max(floor), 0.0);
    let (mm, _) = weighted_steps(&task, start, tolerance, &[None], &weight)?;
    let p = plain.linear_predictions(start, &[&ls[0], &mm[0]]);
    Some(p[0].1.min(p[1].1))
}

/// The scores in ranking order, candidates the data cannot tell apart merged.
fn sort_and_merge(mut scores: Vec<Score>) -> Vec<Score> {
    // Candidates that could not be scored go last; then that add no direction the data identify cannot be seen (a period equal to the
    // mesh step, a squareness the model already carries): they go last, whatever their ΔBIC;
    // flagged ones go after every plausible one that the data see.
    scores.sort_by(|a, b| {
        (a.failed.is_some())
            .cmp(&b.failed.is_some())
            .then((a.added == 0).cmp(&(b.added == 0)))
            .then(a.flag.is_some().cmp(&b.flag.is_some()))
            .then(a.delta_bic.total_cmp(&b.delta_bic))
    });
    // Merge candidates the data cannot tell apart: as many directions, ΔBIC within 2.
    let mut merged: Vec<Score> = Vec::new();
    for s in scores {
        if let Some(prev) = merged.iter_mut().find(|p| {
            p.added == s.added
                && s.added > 0
                && p.flag.is_none() == s.flag.is_none()
                && (p.delta_bic - s.delta_bic).abs() < 2.0
        }) {
            prev.equivalent.push(s.id);
        } else {
            merged.push(s);
        }
    }
    merged
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::candidates::library;
    use crate::analysis::observability::nominal_data;
    use volver_core::iso::ErrorId;
    use volver_core::plan::Plan;
    use volver_core::units::PPM;

    fn candidate(model: &Model, id: &str) -> Model {
        let c = library(model)
            .into_iter()
            .find(|c| c.id == id)
            .expect("a candidate of the library");
        Model::new(model.machine().clone(), c.spec).expect("its model builds")
    }

    /// The tracker measures a point x as x·(1 + s/10⁶) with the range scale s in ppm: the
    /// candidate's column at every measured point is that point over 10⁶ (mm per ppm), and the
    /// fit carried over leaves the nominal data's residuals at zero.
    #[test]
    fn the_range_scale_column_is_the_measured_point_per_ppm() {
        let model = Model::default_xcfz();
        let plan = Plan::parse_grid(model.machine(), "X=0:1400:700,C=0:330:30,Z=0:600:300")
            .expect("a grid");
        let data = nominal_data(&model, &plan);
        let extended = candidate(&model, "range-scale");
        let problem = Problem::new(&extended, &data).expect("a problem");
        let start = carry_over(&model, &model.initial_params(), &extended);
        let j = extended
            .param_index("range.scale")
            .expect("the new parameter");
        assert_eq!(start[j], 0.0);
        let n = extended.n_params();
        let mut jac = vec![0.0; 3 * n];
        for (i, m) in data.points.iter().enumerate() {
            let r = problem.residual_and_jacobian(i, &start, &mut jac);
            for c in 0..3 {
                let scale = 1.0 + m.measured[c].abs();
                assert!(r[c].abs() < 1e-9 * scale, "{r:?}");
                let want = m.measured[c] / PPM;
                assert!((jac[c * n + j] - want).abs() < 1e-12 * scale, "point {i}");
            }
        }
    }

    /// Raising EXX from degree 3 to 4 adds a coefficient that starts at zero: the carried-over
    /// parameters give every error function the values it had.
    #[test]
    fn carrying_over_keeps_every_error_function() {
        let model = Model::default_xcfz();
        let mut params = model.initial_params();
        for (j, p) in params.iter_mut().enumerate() {
            if model.params()[j].name.starts_with("EXX.") {
                *p = 1e-3 * (j % 7) as f64;
            }
        }
        let extended = candidate(&model, "raise:EXX");
        assert_eq!(extended.n_params(), model.n_params() + 1);
        let q = carry_over(&model, &params, &extended);
        let exx: ErrorId = "EXX".parse().expect("an ISO name");
        for k in 0..=14 {
            let x_mm = 100.0 * k as f64;
            let before = model.error_value(exx, x_mm, &params).expect("a value");
            let after = extended.error_value(exx, x_mm, &q).expect("a value");
            assert!((after - before).abs() < 1e-15, "at {x_mm} mm");
        }
    }

    fn scored(id: &str, added: usize, delta_bic: f64) -> Score {
        Score {
            id: id.into(),
            description: String::new(),
            added,
            emm_um: 1.0,
            delta_bic,
            size: 1.0,
            size_unit: "µm",
            equivalent: Vec::new(),
            flag: None,
            failed: None,
        }
    }

    /// Scored and seen first (by ΔBIC), then flagged, then unseen, then failed; candidates with
    /// as many directions and a ΔBIC within 2 listed under the better.
    #[test]
    fn the_ranking_puts_what_the_data_see_first_and_merges_ties() {
        let mut flagged = scored("flagged", 2, -500.0);
        flagged.flag = Some("too large".into());
        let failed = Score::failed("failed".into(), String::new(), "singular".into());
        let ranked = sort_and_merge(vec![
            failed,
            scored("unseen", 0, -900.0),
            flagged,
            scored("b", 2, -40.0),
            scored("a", 2, -41.5),
            scored("c", 1, -100.0),
        ]);
        let ids: Vec<&str> = ranked.iter().map(|s| s.id.as_str()).collect();
        assert_eq!(ids, ["c", "a", "flagged", "unseen", "failed"]);
        assert_eq!(ranked[1].equivalent, ["b"]);
    }
}
