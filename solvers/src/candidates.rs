//! What is missing: a library of candidate effects the model could add, each ranked by how much
//! it would lower the error given what the model already explains.
//!
//! The score of a candidate is one Gauss–Newton step of the extended model from the current
//! solution (the new parameters start at zero, so the start is the current fit): it measures the
//! residual the candidate's Jacobian columns explain beyond the current ones — a score
//! (Lagrange-multiplier) test — and the predicted EMM is the extended model evaluated after that
//! step. Significance is ΔBIC = m·ln(RSS′/RSS) + Δk·ln m over the m = 3n residual coordinates
//! (Δk the extra identified directions): below −10 is strong evidence. Candidates are ranked by
//! ΔBIC, most negative first.
//!
//! **Sizes are of what is new.** The step changes the model's own parameters too, and a
//! candidate's raw coefficients include what the model already expresses (a field over X and
//! Z carries the products the angular errors of X make with the lever arm of Z: metres of
//! coefficients against metres of those errors for a few hundred µm of new displacement). A
//! candidate's size and plausibility are therefore measured on the part of its change of the
//! measured points that the current model cannot make (the projection out of the span of its
//! Jacobian's identified directions): a field's size is the largest displacement
//! of that part at a measured point; every other kind's is its own quantity (µm/h, ppm, µrad …)
//! of the smallest change of its new parameters alone that adds the same.
//!
//! **The EMM predicted** is the EMM a refit (Φ: the mean module) would reach to first order,
//! never above the current one; the verdict recommends only a candidate
//! with strong evidence that lowers it ([`recommended`]) and says why when the candidate with
//! the strongest evidence does not. A significant field is shown with the physical candidates
//! over its variables ([`sharing`]).
//!
//! Candidate ids (stable):
//!
//! | id | what it adds |
//! |---|---|
//! | `add:EAC` | an ISO 230 error the model leaves out (linear axes: Legendre of the model's polynomial degree, default 3; rotary: first-harmonic Fourier; location and squareness errors: a constant) |
//! | `raise:EXX` | the next degree (polynomial) or harmonic (periodic) of one modelled error |
//! | `raise-axis:C` | the next degree or harmonic of every modelled error of one axis |
//! | `tracker-tilt` | the tracker's small rotations about its x and y axes, when the model holds them |
//! | `thermal-drift` | drift of the tool point with time (`[effects] thermal_drift`; needs `t_s`) |
//! | `reflector-offset:R1` | reflector R1 off its nominal offset |
//! | `range-scale` | a scale error of the tracker's range |
//! | `range-offset` | each station's range offset, the dead path (`[tracker] range_offset`) |
//! | `station-drift` | each station's position drifting with time (`[effects] station_drift`; machines with `[[station]]` tables) |
//! | `ball-screw:X:700` | a periodic positioning error of X with period 700 mm (travel/2 … travel/8 are tried) |
//! | `thermal-scale:X` | the scale of linear axis X growing with time: EXX += α·x·t (`[effects] thermal_scale`; needs `t_s`) |
//! | `tracker-drift` | the tracker's small rotations drifting with time (`[effects] tracker_drift`) |
//! | `location-drift:C` | the line of rotary axis C drifting with time: X0C, Y0C += v·t (`[effects] location_drift`) |
//! | `field:X`, `field:X*Z`, `field:X*t` | a generic displacement of the tool point over one variable or jointly over two (axes and time `t`; `[effects] field`): names what the misfit depends on when no physical candidate explains it |

mod novelty;

use crate::Task;
use crate::coordinates::{Reduced, reduced_normal_under};
use faer::Side;
use novelty::Expressible;
use volver_core::basis::{BasisKind, chebyshev_nodes};
use volver_core::iso::{Axis, ErrorId};
use volver_core::model::{BallScrewSpec, ErrorModelSpec, ErrorTermSpec, Model, OneOrMany};

/// Periodic positioning errors are tried with periods travel/2 … travel/SCREW_PERIODS.
pub const SCREW_PERIODS: usize = 8;
use volver_core::iso::Unit;
use volver_core::noise::TrackerNoise;
use volver_core::plausibility::{RATE_SPAN_H, limit};
use volver_core::problem::{Problem, Residuals, Whitened};

/// A candidate: an extension of the error model.
#[derive(Clone, Debug, PartialEq)]
pub struct Candidate {
    /// Stable id (see the module table).
    pub id: String,
    /// What it means, in words.
    pub description: String,
    /// The extended error model.
    pub spec: ErrorModelSpec,
}

/// A ranked candidate.
#[derive(Clone, Debug, PartialEq)]
pub struct Score {
    /// Candidate id.
    pub id: String,
    /// What it means.
    pub description: String,
    /// Extra directions the data identify with it.
    pub added: usize,
    /// Predicted EMM after adding it (µm).
    pub emm_um: f64,
    /// ΔBIC against the current model (negative: the data support it).
    pub delta_bic: f64,
    /// Size of what the candidate adds beyond what the current model expresses (see the module
    /// documentation), by kind: for a field the largest displacement of that new part at a
    /// measured point (µm); for the others, of the smallest change of the new parameters alone
    /// that adds it, the norm of a new effect's parameters (a drift in µm/h, a periodic error's
    /// amplitude in µm, a reflector offset in µm, a range scale in ppm), the tilt
    /// `tracker-tilt` frees (µrad), or the largest value over the travel of the added part of
    /// an added or raised error function (µm or µrad).
    pub size: f64,
    /// Unit of `size` (`µm`, `µrad`, `µm/h` or `ppm`).
    pub size_unit: &'static str,
    /// Candidates the data cannot tell from this one: as many added directions and a ΔBIC
    /// within 2 of it ("not worth more than a bare mention" on Kass and Raftery's scale), e.g. a
    /// tilt of the tracker standing on the table and a tilt motion of the table. Listed under
    /// the better of them.
    pub equivalent: Vec<String>,
    /// Why it is not a finding, when it is not plausible: its size beyond the physical bound
    /// of its kind, or evidence only along a nearly unidentifiable direction. A flagged
    /// candidate is never ranked first.
    pub flag: Option<String>,
    /// Why it could not be scored (its model or problem cannot be built, or its step is
    /// singular or not finite), when it could not: it is then listed last with no figures
    /// (NaN), never dropped.
    pub failed: Option<String>,
}

impl Score {
    /// A candidate that could not be scored, and why.
    fn failed(id: String, description: String, why: String) -> Score {
        Score {
            id,
            description,
            added: 0,
            emm_um: f64::NAN,
            delta_bic: f64::NAN,
            size: f64::NAN,
            size_unit: "",
            equivalent: Vec::new(),
            flag: None,
            failed: Some(why),
        }
    }
}

fn polynomial_degree(spec: &ErrorModelSpec) -> usize {
    spec.errors
        .iter()
        .filter(|e| {
            matches!(
                e.basis,
                Some(BasisKind::Legendre | BasisKind::Monomial | BasisKind::Chebyshev)
            )
        })
        .map(|e| {
            e.degree
                .or(e.nodes.map(|n| n.saturating_sub(1)))
                .unwrap_or(3)
        })
        .max()
        .unwrap_or(3)
}

/// The spec with `id` moved to an entry of its own whose degree, nodes or order is raised by 1.
fn raised(spec: &ErrorModelSpec, id: ErrorId) -> Option<ErrorModelSpec> {
    let mut spec = spec.clone();
    let name = id.to_string();
    let pos = spec.errors.iter().position(|e| {
        e.name
            .names()
            .iter()
            .any(|n| n.parse::<ErrorId>().ok() == Some(id))
    })?;
    let mut entry = spec.errors[pos].clone();
    match entry.basis {
        None | Some(BasisKind::Constant) => return None,
        Some(BasisKind::Fourier | BasisKind::Sine) => {
            entry.order = Some(entry.order.unwrap_or(1) + 1);
        }
        Some(BasisKind::Chebyshev) if entry.nodes.is_some() => {
            entry.nodes = entry.nodes.map(|n| n + 1);
        }
        Some(_) => entry.degree = Some(entry.degree.unwrap_or(3) + 1),
    }
    let rest: Vec<String> = spec.errors[pos]
        .name
        .names()
        .iter()
        .filter(|n| n.parse::<ErrorId>().ok() != Some(id))
        .map(|s| s.to_string())
        .collect();
    if rest.is_empty() {
        spec.errors.remove(pos);
    } else {
        spec.errors[pos].name = OneOrMany::Many(rest);
    }
    entry.name = OneOrMany::One(name);
    spec.errors.push(entry);
    Some(spec)
}

/// The library of candidates for a model.
pub fn library(model: &Model) -> Vec<Candidate> {
    let spec = model.spec();
    let machine = model.machine();
    let mut out = Vec::new();
    // ISO errors left out.
    let degree = polynomial_degree(spec);
    for ax in machine.axes() {
        let mut ids: Vec<ErrorId> = ErrorId::components_of(ax.axis).to_vec();
        ids.extend(
            ErrorId::location_names(ax.axis)
                .iter()
                .map(|n| n.parse::<ErrorId>().expect("valid name")),
        );
        for id in ids {
            if model.term(id).is_some() {
                continue;
            }
            let (basis, degree, order, what) = match id {
                ErrorId::Location { .. } => (None, None, None, "a constant".to_string()),
                _ if ax.axis.is_rotary() => (
                    Some(BasisKind::Fourier),
                    None,
                    Some(1),
                    "a first-harmonic Fourier series".to_string(),
                ),
                _ => (
                    Some(BasisKind::Legendre),
                    Some(degree),
                    None,
                    format!("a Legendre polynomial of degree {degree}"),
                ),
            };
            let mut s = spec.clone();
            s.errors.push(ErrorTermSpec {
                name: OneOrMany::One(id.to_string()),
                basis,
                degree,
                nodes: None,
                order,
            });
            out.push(Candidate {
                id: format!("add:{id}"),
                description: format!("add the missing error {id} as {what}"),
                spec: s,
            });
        }
    }
    // The next degree or harmonic, per error and per axis.
    for ax in machine.axes() {
        let mut axis_spec = spec.clone();
        let mut any = false;
        for t in model.terms().iter().filter(|t| t.id.axis() == ax.axis) {
            if let Some(s) = raised(spec, t.id) {
                let what = if t.basis.kind().is_periodic() {
                    format!("harmonic {}", t.basis.degree() + 1)
                } else {
                    format!("degree {}", t.basis.degree() + 1)
                };
                out.push(Candidate {
                    id: format!("raise:{}", t.id),
                    description: format!("give {} its {what}", t.id),
                    spec: s,
                });
                if let Some(s) = raised(&axis_spec, t.id) {
                    axis_spec = s;
                    any = true;
                }
            }
        }
        if any {
            out.push(Candidate {
                id: format!("raise-axis:{}", ax.axis),
                description: format!("raise the degree or harmonic of every error of {}", ax.axis),
                spec: axis_spec,
            });
        }
    }
    // Effects outside the ISO 230 model.
    let fx = &spec.effects;
    if !fx.thermal_drift {
        let mut s = spec.clone();
        s.effects.thermal_drift = true;
        out.push(Candidate {
            id: "thermal-drift".into(),
            description: "thermal drift of the tool point with time (needs t_s)".into(),
            spec: s,
        });
    }
    for r in machine.reflectors() {
        if !fx.reflector_offset.contains(&r.id) {
            let mut s = spec.clone();
            s.effects.reflector_offset.push(r.id.clone());
            out.push(Candidate {
                id: format!("reflector-offset:{}", r.id),
                description: format!("reflector {} off its nominal offset", r.id),
                spec: s,
            });
        }
    }
    if !fx.range_scale {
        let mut s = spec.clone();
        s.effects.range_scale = true;
        out.push(Candidate {
            id: "range-scale".into(),
            description: "a scale error of the tracker's range".into(),
            spec: s,
        });
    }
    for ax in machine.axes().iter().filter(|a| !a.axis.is_rotary()) {
        let travel = ax.max - ax.min;
        for k in 2..=SCREW_PERIODS {
            let period = travel / k as f64;
            let period = (period * 1e3).round() / 1e3;
            let letter = ax.axis.to_string();
            if fx
                .ball_screw
                .iter()
                .any(|b| b.axis == letter && (b.period_mm - period).abs() < 1e-9)
            {
                continue;
            }
            let mut s = spec.clone();
            s.effects.ball_screw.push(BallScrewSpec {
                axis: letter.clone(),
                period_mm: period,
            });
            out.push(Candidate {
                id: format!("ball-screw:{letter}:{period}"),
                description: format!(
                    "a periodic positioning error of {letter} with a period of {period} mm"
                ),
                spec: s,
            });
        }
    }
    // Thermal growth of each linear axis' scale, drift of each rotary axis' line.
    for ax in machine.axes() {
        let letter = ax.axis.to_string();
        let mut s = spec.clone();
        let (id, description) = if ax.axis.is_rotary() {
            if fx.location_drift.contains(&letter) {
                continue;
            }
            s.effects.location_drift.push(letter.clone());
            (
                format!("location-drift:{letter}"),
                format!("the line of {letter} drifting with time (its location errors × t)"),
            )
        } else {
            if fx.thermal_scale.contains(&letter) {
                continue;
            }
            s.effects.thermal_scale.push(letter.clone());
            (
                format!("thermal-scale:{letter}"),
                format!(
                    "the scale of {letter} growing with time (E{letter}{letter} += α·{}·t)",
                    letter.to_lowercase()
                ),
            )
        };
        out.push(Candidate {
            id,
            description,
            spec: s,
        });
    }
    if !spec.tracker.range_offset {
        let mut s = spec.clone();
        s.tracker.range_offset = true;
        out.push(Candidate {
            id: "range-offset".into(),
            description: "each station's range offset (the dead path: every range too long or \
                          too short by a constant)"
                .into(),
            spec: s,
        });
    }
    if machine.has_stations() && !fx.station_drift {
        let mut s = spec.clone();
        s.effects.station_drift = true;
        out.push(Candidate {
            id: "station-drift".into(),
            description: "each station's position drifting with time (its stand growing as it \
                          warms; needs t_s)"
                .into(),
            spec: s,
        });
    }
    if !fx.tracker_drift {
        let mut s = spec.clone();
        s.effects.tracker_drift = true;
        out.push(Candidate {
            id: "tracker-drift".into(),
            description: "the tracker's orientation drifting with time (its stand turning as it \
                          warms; needs t_s)"
                .into(),
            spec: s,
        });
    }
    // Generic fields over every variable and every pair.
    for vars in field_variables(machine) {
        let name = vars.join("*");
        if fx.field.contains(&name) {
            continue;
        }
        let mut s = spec.clone();
        s.effects.field.push(name.clone());
        let description = if vars.len() == 1 {
            format!(
                "a smooth displacement of the tool point that depends on {name} (a generic field)"
            )
        } else {
            format!(
                "a displacement of the tool point that depends jointly on {} and {} (a generic \
                 field: a non-rigid effect)",
                vars[0], vars[1]
            )
        };
        out.push(Candidate {
            id: format!("field:{name}"),
            description,
            spec: s,
        });
    }
    // The tracker's tilt.
    let identify = &spec.tracker.identify;
    if !identify.iter().any(|n| n == "rx") && !identify.iter().any(|n| n == "ry") {
        let mut s = spec.clone();
        s.tracker
            .identify
            .extend(["rx".to_string(), "ry".to_string()]);
        out.push(Candidate {
            id: "tracker-tilt".into(),
            description: "identify the tracker's tilt (rx, ry)".into(),
            spec: s,
        });
    }
    out
}

/// The variables of the generic fields, alone and in pairs: every axis in chain order, then the
/// time `t`.
fn field_variables(machine: &volver_core::machine::Machine) -> Vec<Vec<String>> {
    let mut vars: Vec<String> = machine.axes().iter().map(|a| a.axis.to_string()).collect();
    vars.push("t".into());
    let mut out: Vec<Vec<String>> = vars.iter().map(|v| vec![v.clone()]).collect();
    for (i, a) in vars.iter().enumerate() {
        for b in &vars[i + 1..] {
            out.push(vec![a.clone(), b.clone()]);
        }
    }
    out
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
/// [`crate::kernels::accumulate`] takes it).
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
                let (extra, _) = crate::coordinates::reduce(&d, basis, &wm, None);
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

/// What the candidates are scored on: the problem's residuals, whitened by the tracker's noise
/// when it is known ([`Whitened`]: each point and direction weighed by its noise).
#[derive(Clone, Debug)]
enum Scored<'a> {
    Plain(Problem<'a>),
    Whitened(Whitened<'a>),
}

impl<'a> Scored<'a> {
    fn new(problem: Problem<'a>, noise: Option<&TrackerNoise>) -> Scored<'a> {
        match noise.and_then(|n| Whitened::new(problem.clone(), n)) {
            Some(w) => Scored::Whitened(w),
            None => Scored::Plain(problem),
        }
    }

    fn task(&self) -> Task<'a> {
        match self {
            Scored::Plain(p) => Task::new(p.clone()),
            Scored::Whitened(w) => Task::new(w.clone()),
        }
    }

    fn problem(&self) -> &Problem<'a> {
        match self {
            Scored::Plain(p) => p,
            Scored::Whitened(w) => w.problem(),
        }
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
                let scored = match self {
                    Scored::Plain(_) => lin,
                    Scored::Whitened(w) => w.apply(i, lin),
                };
                *rss += scored.iter().map(|v| v * v).sum::<f64>();
                *sum += volver_core::problem::norm(lin);
            }
        }
        let count = problem.n_points() as f64;
        sums.into_iter()
            .map(|(rss, sum)| (rss, sum / count * 1e3))
            .collect()
    }
}

/// The size of what the candidate adds, by its kind: for a new effect (drift, periodic
/// positioning error, reflector offset, range scale) the norm of its new parameters (µm/h, the
/// amplitude in µm, µm, ppm); for `tracker-tilt` the tilt it frees (µrad); for an added or raised
/// error function the largest change of that function over the travel (µm or µrad). Changes the
/// Gauss–Newton step makes to parameters the model already had (say the tracker's tilt, when the
/// model identifies it) are not the candidate's size.
fn implied_size(
    id: &str,
    model: &Model,
    params: &[f64],
    extended: &Model,
    q: &[f64],
) -> (f64, Unit) {
    // New effect parameters: the norm of each group (drift.x/y/z, screw.X.a/b …).
    let groups = extended.effect_sizes(q, |j| {
        model.param_index(&extended.params()[j].name).is_none()
    });
    if let Some(g) = groups.iter().max_by(|a, b| a.1.total_cmp(&b.1)) {
        return (g.1, g.3);
    }
    if id == "range-offset" {
        // The largest station offset, in µm.
        let largest = extended
            .stations()
            .iter()
            .filter_map(|b| b.offset)
            .map(|j| q[j].abs() * 1e3)
            .fold(0.0, f64::max);
        return (largest, Unit::Mm);
    }
    if id == "tracker-tilt" {
        let (ts, te) = (model.tracker_start(), extended.tracker_start());
        let tilt = ((q[te + 3] - params[ts + 3]).powi(2) + (q[te + 4] - params[ts + 4]).powi(2))
            .sqrt()
            * 1e6;
        return (tilt, Unit::Rad);
    }
    let mut best: (f64, Unit) = (0.0, Unit::Mm);
    for t in extended.terms() {
        if model.term(t.id).is_some_and(|old| old.basis == t.basis) {
            continue;
        }
        let ax = &extended.machine().axes()[t.axis];
        let scale = t.id.unit().micro();
        let peak = (0..=64)
            .map(|i| {
                let u = ax.min + (ax.max - ax.min) * i as f64 / 64.0;
                let new = extended.error_value(t.id, u, q).unwrap_or(0.0);
                let old = model.error_value(t.id, u, params).unwrap_or(0.0);
                (new - old).abs() * scale.0
            })
            .fold(0.0, f64::max);
        if peak > best.0 {
            best = (peak, t.id.unit());
        }
    }
    best
}

/// Scores every candidate of the library at the solution `params` of `problem`'s model and
/// ranks them by ΔBIC. `tolerance` is the rank tolerance (as the engine's). With the tracker's
/// `noise`, the residuals are whitened by it (each point and direction weighed by its own
/// noise: angular noise grows with the distance); without, every coordinate weighs the same.
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
        return library(model)
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
    let scores: Vec<Score> = library(model)
        .into_iter()
        .map(|c| {
            let (id, description) = (c.id.clone(), c.description.clone());
            let Some(expressible) = &expressible else {
                let why = "the current model's Jacobian is not finite, so what a candidate adds \
                           beyond it cannot be measured"
                    .to_string();
                return Score::failed(id, description, why);
            };
            score(
                &c,
                problem,
                params,
                tolerance,
                noise,
                (rank0, rss0, variance),
                expressible,
            )
            .unwrap_or_else(|why| Score::failed(id, description, why))
        })
        .collect();
    sort_and_merge(scores)
}

/// The plausible size of parameter `j` of `model` (in `unit`, [`limit`]); for a rate over time
/// (a drift, a field's `tᵖ`, [`Model::time_power`]) the rate that moves it by [`limit`] ×
/// ([`RATE_SPAN_H`] h)ᵖ over the data's span `T` (h), `limit × (24 / T)ᵖ`, so that the diagnosis
/// does not depend on the unit of the time stamps (the rule of
/// [`volver_core::plausibility::Context::time_span_h`]).
fn plausible(
    model: &Model,
    data: &volver_core::measure::MeasurementSet,
    j: usize,
    unit: Unit,
) -> f64 {
    let span_h = data.time_span_s().filter(|&t| t > 0.0).map(|t| t / 3600.0);
    match (span_h, j < model.n_params()) {
        (Some(t), true) if model.time_power(j) > 0 => {
            limit(unit) * (RATE_SPAN_H / t).powi(model.time_power(j) as i32)
        }
        _ => limit(unit),
    }
}

/// The score of candidate `c` against the current model's fit (`rank0` identified directions,
/// residual sum `rss0`, variance per coordinate `variance`), or why it cannot be scored.
fn score(
    c: &Candidate,
    problem: &Problem,
    params: &[f64],
    tolerance: f64,
    noise: Option<&TrackerNoise>,
    (rank0, rss0, variance): (usize, f64, f64),
    expressible: &Expressible,
) -> Result<Score, String> {
    let model = problem.model();
    let data = problem.data();
    let m = (3 * problem.n_points()) as f64;
    let singular = || "its Gauss-Newton step is singular or not finite".to_string();
    let extended = Model::new(model.machine().clone(), c.spec.clone())
        .map_err(|e| format!("its model cannot be built: {e}"))?;
    let problem =
        Problem::new(&extended, data).map_err(|e| format!("its problem cannot be built: {e}"))?;
    let ext = Scored::new(problem, noise);
    let start = carry_over(model, params, &extended);
    let ridge: Vec<f64> = extended
        .params()
        .iter()
        .enumerate()
        .map(|(j, info)| match model.param_index(&info.name) {
            Some(_) => 0.0,
            None => variance / plausible(&extended, data, j, info.unit).powi(2),
        })
        .collect();
    // The step held to plausible sizes, and the same step without the bound.
    let (steps, rank1) = gauss_newton_steps(&ext.task(), &start, tolerance, &[Some(&ridge), None])
        .ok_or_else(singular)?;
    let (q, qf) = (&steps[0], &steps[1]);
    let predicted = ext.linear_predictions(&start, &[q, qf]);
    let (rss1, rss_free) = (predicted[0].0, predicted[1].0);
    let jac = novelty::jacobian(ext.problem(), &start);
    let (on, models) = ((expressible, &jac), (model, &extended));
    let new_size = |q: &[f64]| {
        size_of_new(&c.id, models, params, on, (&start, q), tolerance).ok_or_else(singular)
    };
    let (size, unit) = new_size(q)?;
    let added = rank1.saturating_sub(rank0);
    let bic = |rss: f64| m * (rss / rss0).ln() + added as f64 * m.ln();
    let delta_bic = bic(rss1);
    let (scale, size_unit) = unit.micro();
    let first_new = (0..extended.n_params())
        .find(|&j| model.param_index(&extended.params()[j].name).is_none())
        .unwrap_or(usize::MAX);
    // A size in a rate's unit is judged as a rate (over the data's span); a size in a length
    // or an angle (a field's displacement, over t too) as that length or angle.
    let rate = matches!(unit, Unit::MmPerHour | Unit::RadPerHour | Unit::PpmPerHour);
    let bound = if rate {
        plausible(&extended, data, first_new, unit)
    } else {
        limit(unit)
    } * scale;
    let bic_free = bic(rss_free);
    let flag = if size > bound {
        Some(format!(
            "its size, {size:.0} {size_unit}, exceeds the plausible {bound:.0} {size_unit}"
        ))
    } else {
        let (size_free, _) = new_size(qf)?;
        (size_free > bound && bic_free < -10.0 && delta_bic - bic_free > 10.0).then(|| {
            format!(
                "nearly unidentifiable: the data support it only with a size of \
                         {size_free:.0} {size_unit} (ΔBIC {bic_free:.0}), beyond the plausible \
                         {bound:.0} {size_unit}"
            )
        })
    };
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

/// The size of what candidate `id` adds beyond `model` (fitted at `params`) when its
/// `extended` model steps from `start` to `q` ([`Score::size`]), `jac` the extended model's
/// Jacobian at `start` over the data points; `None` when not finite.
fn size_of_new(
    id: &str,
    (model, extended): (&Model, &Model),
    params: &[f64],
    (expressible, jac): (&Expressible, &faer::Mat<f64>),
    (start, q): (&[f64], &[f64]),
    tolerance: f64,
) -> Option<(f64, Unit)> {
    let new = expressible.novelty((model, extended), jac, (start, q), tolerance)?;
    if id.starts_with("field:") {
        return Some((new.peak_um, Unit::Mm));
    }
    // Each added or raised function's lower coefficients take what they express of its new
    // ones (one function at a time: no swap between functions).
    let mut own = new.representative.clone();
    for t in extended.terms() {
        if model.term(t.id).is_none_or(|old| old.basis != t.basis) {
            let coefficients: Vec<usize> = t.params.clone().collect();
            let q = new.own_functions(extended, jac, start, (&coefficients, &new.fresh))?;
            for k in coefficients {
                own[k] = q[k];
            }
        }
    }
    Some(implied_size(id, model, params, extended, &own))
}

/// The EMM (µm) a refit of `problem`'s model from `start` would reach, predicted to first
/// order. The engines minimise the EMM itself (Φ, the mean error module), not the squares the
/// evidence is scored on: the prediction is the lower of the linearised EMM after the
/// unweighted Gauss–Newton step and after one majorise–minimise step of Φ (least squares
/// weighted by `1/‖r_i‖`, which majorises `Σ‖r_i + J_i δ‖` and so never raises the linearised
/// EMM above the current one). A refit can reach at least as low; a candidate is never
/// predicted to raise the EMM of the Φ fit it extends.
fn predicted_emm(problem: &Problem, start: &[f64], tolerance: f64) -> Option<f64> {
    let plain = Scored::Plain(problem.clone());
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

impl Score {
    /// `true` when the candidate adds a direction the data identify; one that adds none cannot
    /// be seen in these data (its ΔBIC and size mean nothing).
    pub fn seen(&self) -> bool {
        self.added > 0
    }

    /// Strong evidence on Kass and Raftery's scale: ΔBIC below −10, for a plausible candidate
    /// (not flagged) the data see.
    pub fn strong(&self) -> bool {
        self.seen() && self.flag.is_none() && self.delta_bic < -10.0
    }
}

/// A one-line verdict on a ranked list (as [`rank`] returns it) for a fit of EMM `emm_um`:
/// the candidate to add, or that none is supported; candidates that could not be scored are
/// named with the reason (and when none could be, the verdict says so, not that none helps).
///
/// ```
/// use volver_solvers::candidates::{Score, verdict};
/// let failed = Score {
///     id: "add:EXC".into(),
///     description: "give EXC".into(),
///     added: 0,
///     emm_um: f64::NAN,
///     delta_bic: f64::NAN,
///     size: f64::NAN,
///     size_unit: "",
///     equivalent: vec![],
///     flag: None,
///     failed: Some("its step is singular".into()),
/// };
/// let v = verdict(&[failed], 50.0);
/// assert!(v.starts_with("no candidate could be scored"), "{v}");
/// ```
pub fn verdict(ranked: &[Score], emm_um: f64) -> String {
    let failed: Vec<&Score> = ranked.iter().filter(|s| s.failed.is_some()).collect();
    let Some(first) = failed.first() else {
        return verdict_scored(ranked, emm_um);
    };
    let why = format!("{}: {}", first.id, first.failed.as_deref().unwrap_or(""));
    if failed.len() == ranked.len() {
        return format!(
            "no candidate could be scored (EMM {} µm), so the diagnosis cannot say what is \
             missing: {why}",
            um(emm_um)
        );
    }
    format!(
        "{}; {} candidate(s) could not be scored ({why})",
        verdict_scored(ranked, emm_um),
        failed.len()
    )
}

/// The smallest relative drop of the EMM that counts as lowering it (0.1 %).
pub const EMM_GAIN: f64 = 1e-3;

/// `true` when adding `s` is predicted to lower the EMM `emm_um` of the Φ fit it extends by at
/// least [`EMM_GAIN`].
pub fn lowers(s: &Score, emm_um: f64) -> bool {
    s.emm_um < emm_um * (1.0 - EMM_GAIN)
}

/// The candidate the verdict recommends adding to a fit of EMM `emm_um`: the first of the
/// ranked list with strong evidence ([`Score::strong`]) that lowers the EMM ([`lowers`]). Strong
/// evidence is a drop of the squared residuals; the Φ fit minimises the mean module, and a
/// candidate that only reshapes the residuals (a few large ones smaller, many small ones larger)
/// has the first without the second: it is never recommended.
pub fn recommended(ranked: &[Score], emm_um: f64) -> Option<&Score> {
    ranked
        .iter()
        .filter(|s| s.failed.is_none())
        .find(|s| s.strong() && lowers(s, emm_um))
}

/// The variables a candidate depends on, by its id: the axis of an ISO error or of a
/// per-axis effect, `t` for an effect that grows with time, a field's own variables; none for a
/// candidate of the measurement (a reflector's offset, the tracker's range or tilt).
///
/// ```
/// use volver_solvers::candidates::variables;
/// assert_eq!(variables("raise:EZX"), vec!["X"]);
/// assert_eq!(variables("thermal-scale:X"), vec!["X", "t"]);
/// assert_eq!(variables("field:X*Z"), vec!["X", "Z"]);
/// assert!(variables("range-scale").is_empty());
/// ```
pub fn variables(id: &str) -> Vec<String> {
    if let Some(vars) = id.strip_prefix("field:") {
        return vars.split('*').map(str::to_string).collect();
    }
    let axis = axis_of(id).or_else(|| {
        let (kind, rest) = id.split_once(':')?;
        (kind == "ball-screw").then(|| rest.chars().next().and_then(Axis::from_letter))?
    });
    let mut out: Vec<String> = axis.map(|a: Axis| a.to_string()).into_iter().collect();
    let kind = id.split(':').next().unwrap_or(id);
    if matches!(
        kind,
        "thermal-drift" | "thermal-scale" | "location-drift" | "tracker-drift" | "station-drift"
    ) {
        out.push("t".into());
    }
    out
}

/// The physical candidates (not fields) seen in the data whose variables are among those of the
/// field `field` (`field:X*Z`: errors of X or of Z, a periodic error of either …), best first:
/// the physical effects the field may be.
pub fn sharing<'a>(ranked: &'a [Score], field: &str) -> Vec<&'a Score> {
    let vars = variables(field);
    ranked
        .iter()
        .filter(|p| !p.id.starts_with("field:") && p.seen() && p.failed.is_none())
        .filter(|p| {
            let own = variables(&p.id);
            !own.is_empty() && own.iter().all(|v| vars.contains(v))
        })
        .collect()
}

/// What the physical candidates over a field's variables say of it, in words.
fn physical_of_field(ranked: &[Score], field: &str) -> String {
    let vars = variables(field);
    let shared = sharing(ranked, field);
    let listed: Vec<String> = shared
        .iter()
        .take(3)
        .map(|p| {
            let flag = if p.flag.is_some() {
                ", implausible"
            } else {
                ""
            };
            format!("{} (ΔBIC {:.0}{flag})", p.id, p.delta_bic)
        })
        .collect();
    if listed.is_empty() {
        return format!(
            "; no physical candidate of the library depends on {} alone",
            vars.join(" or ")
        );
    }
    let joint = shared.iter().any(|p| variables(&p.id).len() == vars.len());
    let which = if joint || vars.len() == 1 {
        String::new()
    } else {
        format!(
            ", each of one variable: none couples {} (a coupling of the two is what the field \
             describes)",
            vars.join(" with ")
        )
    };
    format!(
        "; the physical candidates over {} are {}{which}",
        vars.join(" and "),
        listed.join(", ")
    )
}

/// Why the candidate with the strongest evidence is not the one recommended, when it is not.
fn not_lowering(ranked: &[Score], emm_um: f64) -> Option<String> {
    let best = ranked
        .first()
        .filter(|s| s.strong() && !lowers(s, emm_um))?;
    Some(format!(
        "{} has the strongest evidence (ΔBIC {:.0}) but would not lower the EMM of the Φ fit \
         ({} → about {} µm): its evidence is a drop of the squared residuals, which the Φ fit \
         (the mean module) does not minimise, so it would reshape the residuals rather than \
         shrink them",
        best.id,
        best.delta_bic,
        um(emm_um),
        um(best.emm_um)
    ))
}

/// [`verdict`] over the candidates that were scored.
fn verdict_scored(ranked: &[Score], emm_um: f64) -> String {
    let aside = not_lowering(ranked, emm_um);
    let chosen = recommended(ranked, emm_um);
    let text = match chosen {
        Some(s) => recommendation(ranked, s, emm_um),
        None if aside.is_some() => {
            return format!(
                "{}; no candidate with strong evidence lowers the EMM ({} µm): what is left is \
                 noise, outliers or an effect no candidate describes",
                aside.unwrap_or_default(),
                um(emm_um)
            );
        }
        None => match ranked.first() {
            Some(s) if s.seen() && s.delta_bic < 0.0 => format!(
                "no candidate has strong evidence; the best, {} (ΔBIC {:.1}), would bring the \
                 EMM from {} to about {} µm",
                s.id,
                s.delta_bic,
                um(emm_um),
                um(s.emm_um)
            ),
            _ => format!(
                "no candidate of the library lowers the error (EMM {} µm): what is left is noise \
                 or an effect no candidate describes",
                um(emm_um)
            ),
        },
    };
    match aside {
        Some(a) => format!("{a}. Instead, {text}"),
        None => text,
    }
}

/// The recommendation of `s` (strong evidence, lowers the EMM `emm_um`), in words.
fn recommendation(ranked: &[Score], s: &Score, emm_um: f64) -> String {
    let Some(vars) = s.id.strip_prefix("field:") else {
        return format!(
            "add {} (ΔBIC {:.0}, strong evidence): {}; it would bring the EMM from {} to about \
             {} µm — `volver identify … --add {}`",
            s.id,
            s.delta_bic,
            s.description,
            um(emm_um),
            um(s.emm_um),
            s.id
        );
    };
    let depends = match vars.split_once('*') {
        Some((a, b)) => format!(
            "the misfit depends jointly on {a} and {b}: a non-rigid effect the rigid-body model \
             cannot express"
        ),
        None => format!("the misfit depends on {vars} in a way no physical candidate describes"),
    };
    let physical = ranked
        .iter()
        .find(|p| !p.id.starts_with("field:") && p.seen() && p.flag.is_none())
        .map_or(String::new(), |p| {
            format!(
                " (the best physical candidate, {}, has ΔBIC {:.0})",
                p.id, p.delta_bic
            )
        });
    format!(
        "{depends}{physical}. Add {} (ΔBIC {:.0}, {} µm beyond what the model expresses) to \
         bring the EMM from {} to about {} µm while you look for the cause — `volver identify … \
         --add {}`{}",
        s.id,
        s.delta_bic,
        um(s.size),
        um(emm_um),
        um(s.emm_um),
        s.id,
        physical_of_field(ranked, &s.id)
    )
}

/// A length in µm with three significant figures (`0.178`, `1.86e-4`, `49.3`).
///
/// ```
/// use volver_solvers::candidates::um;
/// assert_eq!((um(49.31), um(0.000186)), ("49.310".to_string(), "1.86e-4".to_string()));
/// ```
pub fn um(v: f64) -> String {
    if v != 0.0 && v.abs() < 0.01 {
        format!("{v:.2e}")
    } else {
        format!("{v:.3}")
    }
}

/// The axis of a candidate id, when it names one (`add:EAC` → C, `raise-axis:X` → X).
pub fn axis_of(id: &str) -> Option<Axis> {
    let (_, what) = id.split_once(':')?;
    if let Ok(e) = what.parse::<ErrorId>() {
        return Some(e.axis());
    }
    let mut c = what.chars();
    match (c.next().and_then(Axis::from_letter), c.next()) {
        (Some(a), None) => Some(a),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scored(id: &str, delta_bic: f64, emm_um: f64) -> Score {
        Score {
            id: id.into(),
            description: format!("{id} in words"),
            added: 3,
            emm_um,
            delta_bic,
            size: 5.0,
            size_unit: "µm",
            equivalent: Vec::new(),
            flag: None,
            failed: None,
        }
    }

    /// The `--add` a verdict recommends, if any.
    fn added(verdict: &str) -> Option<&str> {
        let (_, rest) = verdict.split_once("--add ")?;
        rest.split(['`', ' ']).next()
    }

    /// The issue's case: the candidate with the strongest evidence would bring the EMM from
    /// 18.568 to 18.725 µm. It is never recommended; the verdict says why and recommends the
    /// next that lowers the EMM, or none. Whatever it recommends lowers the EMM.
    #[test]
    fn the_verdict_never_recommends_an_addition_that_raises_the_emm() {
        let emm = 18.568;
        let raising = scored("raise:EZX", -1510.0, 18.725);
        let flat = scored("raise:EXX", -300.0, emm * (1.0 - EMM_GAIN / 2.0));
        let lowering = scored("ball-screw:X:700", -120.0, 17.9);
        let weak = scored("add:EAC", -4.0, 18.0);
        let cases: [Vec<Score>; 4] = [
            vec![raising.clone(), lowering.clone(), weak.clone()],
            vec![raising.clone(), flat.clone(), lowering.clone()],
            vec![raising.clone(), weak.clone()],
            vec![lowering.clone(), raising.clone()],
        ];
        for ranked in &cases {
            let v = verdict(ranked, emm);
            println!("{v}");
            if let Some(id) = added(&v) {
                let s = ranked
                    .iter()
                    .find(|s| s.id == id)
                    .expect("a ranked candidate");
                assert!(
                    s.emm_um < emm,
                    "{id} is recommended but does not lower the EMM: {v}"
                );
            }
            if ranked[0].id == "raise:EZX" {
                assert!(
                    v.starts_with(
                        "raise:EZX has the strongest evidence (ΔBIC -1510) but would \
                                   not lower the EMM of the Φ fit (18.568 → about 18.725 µm)"
                    ),
                    "{v}"
                );
            }
        }
        assert_eq!(added(&verdict(&cases[0], emm)), Some("ball-screw:X:700"));
        assert_eq!(added(&verdict(&cases[1], emm)), Some("ball-screw:X:700"));
        let none = verdict(&cases[2], emm);
        assert!(added(&none).is_none(), "{none}");
        assert!(
            none.contains("no candidate with strong evidence lowers the EMM"),
            "{none}"
        );
        assert_eq!(added(&verdict(&cases[3], emm)), Some("ball-screw:X:700"));
        assert!(!verdict(&cases[3], emm).contains("would not lower"));
        assert_eq!(
            recommended(&cases[1], emm).map(|s| s.id.as_str()),
            Some("ball-screw:X:700")
        );
        assert!(recommended(&cases[2], emm).is_none());
    }

    /// A field is shown with the physical candidates over its variables, and only those.
    #[test]
    fn a_field_is_shown_with_the_physical_candidates_over_its_variables() {
        let ranked = vec![
            scored("field:X*Z", -1220.0, 8.5),
            scored("raise-axis:X", -630.0, 10.3),
            scored("thermal-scale:X", -200.0, 10.6),
            scored("ball-screw:Z:200", -50.0, 10.7),
            scored("range-scale", -40.0, 10.7),
            scored("add:EAC", -30.0, 10.7),
        ];
        let shared: Vec<&str> = sharing(&ranked, "field:X*Z")
            .iter()
            .map(|s| s.id.as_str())
            .collect();
        assert_eq!(shared, ["raise-axis:X", "ball-screw:Z:200"]);
        let v = verdict(&ranked, 10.8);
        assert!(
            v.contains(
                "the physical candidates over X and Z are raise-axis:X (ΔBIC -630), \
                        ball-screw:Z:200 (ΔBIC -50), each of one variable: none couples X with Z"
            ),
            "{v}"
        );
        let over_time: Vec<&str> = sharing(&ranked, "field:X*t")
            .iter()
            .map(|s| s.id.as_str())
            .collect();
        assert_eq!(over_time, ["raise-axis:X", "thermal-scale:X"]);
    }
}
