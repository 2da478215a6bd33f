//! What a layout (machine, tracker mount, reflectors, error model and plan) can and cannot
//! measure, in words a metrologist acts on: axes whose motion the tracker cannot see, errors
//! that need more positions than the plan has, reversals (ISO 230-2's B) the measuring order
//! cannot separate from the positioning error (no position reached from both sides), pairs of
//! parameters that are the same motion on this layout, and combinations the data cannot
//! identify — each with what would fix it.
//!
//! It needs no measurement: [`nominal_data`] turns a plan into the points a perfect machine
//! would give, and the design (the Jacobian at the model's start) decides the rest. `volver
//! layout --plan` prints it, and `volver identify` prints it for the data it fits.
//!
//! ```
//! use volver_core::model::Model;
//! use volver_core::plan::Plan;
//! use volver_solvers::observability::{nominal_data, observe};
//! let model = Model::default_xcfz();
//! let plan = Plan::parse_grid(model.machine(), "X=0:1400:700,C=0:330:30,Z=0:600:300").unwrap();
//! let data = nominal_data(&model, &plan);
//! let findings = observe(&model, &data, &model.initial_params());
//! // Three positions of X and of Z cannot fix a cubic.
//! assert!(findings.iter().any(|f| f.what.contains("at least 4 positions of X")));
//! ```

use crate::Task;
use crate::analysis::identifiability::{Identifiability, analyse};
use volver_core::basis::BasisKind;
use volver_core::chain::Side;
use volver_core::iso::Axis;
use volver_core::machine::TrackerMount;
use volver_core::measure::{Measurement, MeasurementSet};
use volver_core::model::Model;
use volver_core::plan::Plan;
use volver_core::problem::{Problem, Residuals};

mod reversal;
pub use reversal::reversal_lines;

/// Correlation above which two parameters are called interchangeable.
pub const INTERCHANGEABLE: f64 = 0.99;

/// The kind of a finding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Kind {
    /// An axis whose errors move no measured point.
    Unseen,
    /// Errors that need more positions of their axis than the plan has.
    TooFewPositions,
    /// Two parameters that are nearly the same motion on this layout.
    Interchangeable,
    /// A combination of parameters the data cannot identify.
    Unidentified,
    /// An axis whose reversal the data cannot separate from its positioning error: no position
    /// of it is reached from both sides ([`reversal_lines`]).
    OneSided,
}

/// One statement about the layout.
#[derive(Clone, Debug, PartialEq)]
pub struct Finding {
    /// Its kind.
    pub kind: Kind,
    /// The axis it is about (unseen axes, too few positions), if one.
    pub axis: Option<Axis>,
    /// What cannot be measured, in words.
    pub what: String,
    /// What would fix it.
    pub fix: String,
}

/// The points a perfect machine (the model at its start: errors zero, the tracker at its
/// nominal pose) gives for every measurement of `plan`, in its measuring order, time-stamped
/// [`volver_core::simulate::DEFAULT_SECONDS_PER_POINT`] apart. A machine with `[[station]]`
/// tables is measured from each station in turn, as the generator does (all the plan from the
/// first, then from the next), each observing what it observes (a point, or a range alone).
pub fn nominal_data(model: &Model, plan: &Plan) -> MeasurementSet {
    let p = model.initial_params();
    let machine = model.machine();
    let steps = plan.steps();
    let mut points = Vec::with_capacity(steps.len() * machine.stations().len());
    let approaches = plan.approaches(machine.stations().len());
    for (k, st) in machine.stations().iter().enumerate() {
        for (i, s) in steps.iter().enumerate() {
            let at = k * steps.len() + i;
            let mut m = Measurement {
                commands: plan.positions[s.position],
                reflector: s.reflector,
                measured: [0.0; 3],
                observation: match st.observes {
                    volver_core::machine::Observes::Point => {
                        volver_core::measure::Observation::Point
                    }
                    volver_core::machine::Observes::Range => {
                        volver_core::measure::Observation::Range
                    }
                },
                t_s: Some(at as f64 * volver_core::simulate::DEFAULT_SECONDS_PER_POINT),
                station: machine.has_stations().then(|| st.id.clone()),
                station_index: k,
                line: at + 2,
                approach: approaches[at],
            };
            m.measured = model.observe(&m, &p);
            points.push(m);
        }
    }
    MeasurementSet {
        points,
        time_origin_s: 0.0,
        approach_stated: Default::default(),
    }
}

fn join(names: &[String]) -> String {
    match names.len() {
        0 => String::new(),
        1 => names[0].clone(),
        n => format!("{} and {}", names[..n - 1].join(", "), names[n - 1]),
    }
}

/// Positions an error function needs to be determined: a polynomial of degree d needs d + 1,
/// Chebyshev with m nodes m, a periodic series of order K 2K + 1 angles, a constant 1.
fn positions_needed(kind: BasisKind, degree: usize) -> usize {
    match kind {
        BasisKind::Constant => 1,
        BasisKind::Fourier | BasisKind::Sine => 2 * degree + 1,
        _ => degree + 1,
    }
}

fn basis_words(kind: BasisKind, degree: usize) -> String {
    match (kind, degree) {
        (BasisKind::Fourier | BasisKind::Sine, k) => format!("{k} harmonic(s)"),
        (_, 1) => "linear".into(),
        (_, 2) => "quadratic".into(),
        (_, 3) => "cubic".into(),
        (_, d) => format!("degree {d}"),
    }
}

/// The findings for `model` on `data` at `params` (the start of a fit, or the model's start
/// for a plan): unseen axes, too few positions, reversals the measuring order cannot separate
/// from the positioning error, interchangeable pairs, unidentified combinations, in that order.
pub fn observe(model: &Model, data: &MeasurementSet, params: &[f64]) -> Vec<Finding> {
    let Ok(problem) = Problem::new(model, data) else {
        return Vec::new();
    };
    let col = column_norms(&problem, params);
    let (unseen, mut out) = unseen_axes(model, &col);
    out.extend(too_few_positions(model, data, &unseen));
    out.extend(reversal::findings(model, data));
    // The design: interchangeable pairs and unidentified combinations.
    let task = Task::new(problem);
    let Some(a) = analyse(&task, params, 1e-10, INTERCHANGEABLE) else {
        return out;
    };
    let design = Design::new(model, &a, &unseen);
    out.extend(design.interchangeable());
    out.extend(design.unidentified());
    out
}

/// The squared norm of each column of the Jacobian at `params` over the problem's points
/// (mm² per parameter unit squared).
fn column_norms(problem: &Problem, params: &[f64]) -> Vec<f64> {
    let n = params.len();
    let mut col = vec![0.0; n];
    let mut jac = vec![0.0; 3 * n];
    for i in 0..problem.n_points() {
        problem.residual_and_jacobian(i, params, &mut jac);
        for (j, c) in col.iter_mut().enumerate() {
            *c += jac[j].powi(2) + jac[n + j].powi(2) + jac[2 * n + j].powi(2);
        }
    }
    col
}

/// The axes (their indices in the chain) whose modelled errors move no measured point (every
/// column of theirs at most 1e-18 of the largest, `col` the squared column norms), and a
/// finding for each: what cannot be measured and what would fix it.
fn unseen_axes(model: &Model, col: &[f64]) -> (Vec<usize>, Vec<Finding>) {
    let machine = model.machine();
    let cmax = col.iter().cloned().fold(0.0, f64::max);
    let mut unseen = Vec::new();
    let mut out = Vec::new();
    for (k, ax) in machine.axes().iter().enumerate() {
        let terms: Vec<_> = model.terms().iter().filter(|t| t.axis == k).collect();
        if terms.is_empty() {
            continue;
        }
        let seen = terms
            .iter()
            .any(|t| t.params.clone().any(|j| col[j] > 1e-18 * cmax));
        if seen {
            continue;
        }
        unseen.push(k);
        let names: Vec<String> = terms.iter().map(|t| t.id.to_string()).collect();
        let frame = machine.tracker().mount == TrackerMount::Frame;
        let (what, fix) = if frame && ax.side == Side::Workpiece {
            (
                format!(
                    "the tracker stands on the machine frame and the reflectors ride on the tool, \
                     so the motion of workpiece-side axis {} moves nothing it measures: its errors \
                     ({}) cannot be measured",
                    ax.axis,
                    join(&names)
                ),
                format!(
                    "put the tracker on the workpiece side (on the table that {} carries), or \
                     leave {}'s errors out of the model",
                    ax.axis, ax.axis
                ),
            )
        } else {
            (
                format!(
                    "the errors of axis {} ({}) move no measured point of this plan",
                    ax.axis,
                    join(&names)
                ),
                format!(
                    "move {} in the plan, or leave its errors out of the model",
                    ax.axis
                ),
            )
        };
        out.push(Finding {
            axis: Some(ax.axis),
            kind: Kind::Unseen,
            what,
            fix,
        });
    }
    (unseen, out)
}

/// The distinct positions of axis `k` in the data (a rotary axis' in rad, a turn apart being
/// one pose), sorted.
fn distinct_positions(data: &MeasurementSet, k: usize, rotary: bool) -> Vec<f64> {
    let mut pos: Vec<f64> = data.points.iter().map(|p| p.commands.0[k]).collect();
    if rotary {
        // C = 0° and 360° are one pose.
        for v in &mut pos {
            *v = v.rem_euclid(std::f64::consts::TAU);
            if (*v - std::f64::consts::TAU).abs() < 1e-9 {
                *v = 0.0;
            }
        }
    }
    pos.sort_by(f64::total_cmp);
    pos.dedup_by(|a, b| (*a - *b).abs() <= 1e-9 * (1.0 + b.abs()));
    pos
}

/// A finding for each group of error functions (same basis and degree) of a seen axis that
/// needs more positions of its axis than the data have ([`positions_needed`]).
fn too_few_positions(model: &Model, data: &MeasurementSet, unseen: &[usize]) -> Vec<Finding> {
    let mut out = Vec::new();
    for (k, ax) in model.machine().axes().iter().enumerate() {
        if unseen.contains(&k) {
            continue;
        }
        let have = distinct_positions(data, k, ax.axis.is_rotary()).len();
        let mut groups: Vec<(BasisKind, usize, usize, Vec<String>)> = Vec::new();
        for t in model.terms().iter().filter(|t| t.axis == k) {
            let (kind, degree) = (t.basis.kind(), t.basis.degree());
            let need = positions_needed(kind, degree);
            if need <= have {
                continue;
            }
            match groups.iter_mut().find(|g| g.0 == kind && g.1 == degree) {
                Some(g) => g.3.push(t.id.to_string()),
                None => groups.push((kind, degree, need, vec![t.id.to_string()])),
            }
        }
        for (kind, degree, need, names) in groups {
            let lower = match kind {
                BasisKind::Fourier | BasisKind::Sine => (have.saturating_sub(1) / 2).max(1),
                _ => have.saturating_sub(1).max(1),
            };
            out.push(Finding {
                axis: Some(ax.axis),
                kind: Kind::TooFewPositions,
                what: format!(
                    "{} ({}) need at least {need} positions of {}; the plan has {have}",
                    join(&names),
                    basis_words(kind, degree),
                    ax.axis
                ),
                fix: format!(
                    "measure {} at {need} or more positions, or lower their {} to {lower}",
                    ax.axis,
                    if kind.is_periodic() {
                        "order"
                    } else {
                        "degree"
                    }
                ),
            });
        }
    }
    out
}

/// What the design analysis says of the parameters, for the findings on interchangeable pairs
/// and unidentified combinations.
struct Design<'a> {
    /// The model.
    model: &'a Model,
    /// The analysis of its design at the parameters.
    analysis: &'a Identifiability,
    /// The axes whose errors move no measured point (their parameters are reported there).
    unseen: &'a [usize],
    /// How much of each parameter the data leave undetermined: the norm of its row in the
    /// unidentified directions (scaled coordinates, 0 … 1).
    undetermined: Vec<f64>,
}

impl<'a> Design<'a> {
    /// The design of `model` analysed as `analysis`, with the unseen axes `unseen`.
    fn new(model: &'a Model, analysis: &'a Identifiability, unseen: &'a [usize]) -> Design<'a> {
        let mut undetermined = vec![0.0_f64; model.n_params()];
        for w in &analysis.weak {
            for &(j, share) in &w.parameters {
                undetermined[j] = undetermined[j].hypot(share);
            }
        }
        Design {
            model,
            analysis,
            unseen,
            undetermined,
        }
    }

    /// The name of parameter `j`.
    fn name(&self, j: usize) -> String {
        self.model.params()[j].name.clone()
    }

    /// Whether parameter `j` belongs to an error function of an unseen axis.
    fn unseen_param(&self, j: usize) -> bool {
        self.model
            .terms()
            .iter()
            .any(|t| t.params.contains(&j) && self.unseen.contains(&t.axis))
    }

    /// The chain side of the axis whose error function parameter `j` belongs to, if any.
    fn side_of(&self, j: usize) -> Option<Side> {
        self.model
            .terms()
            .iter()
            .find(|t| t.params.contains(&j))
            .map(|t| self.model.machine().axes()[t.axis].side)
    }

    /// The first eight strongly correlated pairs of parameters of different error functions
    /// (coefficients of one function are tied by its constraints, zero at the reference:
    /// c0 = c1 for a line, which is no property of the layout), but for unseen parameters and
    /// pairs both mostly undetermined (their combination is reported as unidentified).
    fn interchangeable(&self) -> Vec<Finding> {
        let model = self.model;
        let undetermined = &self.undetermined;
        let term_of = |j: usize| model.terms().iter().position(|t| t.params.contains(&j));
        let mut out = Vec::new();
        for &(i, j, c) in self
            .analysis
            .correlations
            .iter()
            .filter(|&&(i, j, _)| term_of(i).is_none() || term_of(i) != term_of(j))
            .take(8)
        {
            if self.unseen_param(i)
                || self.unseen_param(j)
                || (undetermined[i] > 0.3 && undetermined[j] > 0.3)
            {
                continue;
            }
            out.push(Finding {
                axis: None,
                kind: Kind::Interchangeable,
                what: format!(
                    "{} and {} are nearly the same motion on this layout (correlation {c:+.3})",
                    self.name(i),
                    self.name(j)
                ),
                fix: "hold one of them (a [fixed] entry, or the squareness rule), or add a \
                      measurement that moves them differently (another reflector, another \
                      tracker position, more positions of their axes)"
                    .into(),
            });
        }
        out
    }

    /// The parameters `keep` accepts that the data leave mostly undetermined (share above 0.3,
    /// unseen ones aside), most undetermined first, at most ten, each with its share in %.
    fn listed(&self, keep: &dyn Fn(usize) -> bool) -> Vec<String> {
        let undetermined = &self.undetermined;
        let mut js: Vec<usize> = (0..self.model.n_params())
            .filter(|&j| undetermined[j] > 0.3 && !self.unseen_param(j) && keep(j))
            .collect();
        js.sort_by(|&a, &b| undetermined[b].total_cmp(&undetermined[a]));
        js.iter()
            .take(10)
            .map(|&j| {
                format!(
                    "{} ({:.0} %)",
                    self.name(j),
                    100.0 * undetermined[j].min(1.0)
                )
            })
            .collect()
    }

    /// The unidentified combinations, by cause: the tool's turn about the line through two
    /// reflectors (tool-side errors), and the tracker's pose against the rest; the first
    /// finding says how many combinations there are.
    fn unidentified(&self) -> Vec<Finding> {
        let mut out = Vec::new();
        if self.analysis.weak.is_empty() {
            return out;
        }
        let tool = self.listed(&|j| self.side_of(j) == Some(Side::Tool));
        let rest = self.listed(&|j| self.side_of(j) != Some(Side::Tool));
        if !tool.is_empty() {
            out.push(Finding {
                axis: None,
                kind: Kind::Unidentified,
                what: format!(
                    "the tool-side errors are not all determined (the share of each that the \
                     data leave open): {}",
                    join(&tool)
                ),
                fix: tool_side_fix(self.model.machine().reflectors().len()).into(),
            });
        }
        if !rest.is_empty() {
            out.push(self.trading(&rest));
        }
        if let Some(first) = out.first_mut() {
            first.what = format!(
                "{} combination(s) of parameters cannot be identified from these \
                 positions{}; {}",
                self.analysis.weak.len(),
                if self.unseen.is_empty() {
                    ""
                } else {
                    " (the unseen axes' errors among them)"
                },
                first.what
            );
        }
        out
    }

    /// The finding on the undetermined parameters `rest` off the tool side: the tracker's pose
    /// trading with machine errors when one of its parameters is undetermined, errors trading
    /// with each other otherwise.
    fn trading(&self, rest: &[String]) -> Finding {
        let model = self.model;
        let tracker = (0..model.n_params())
            .any(|j| self.undetermined[j] > 0.3 && model.params()[j].name.starts_with("tracker"));
        Finding {
            axis: None,
            kind: Kind::Unidentified,
            what: format!(
                "{}: {}",
                if tracker {
                    "the tracker's pose trades with machine errors"
                } else {
                    "these errors trade with each other"
                },
                join(rest)
            ),
            fix: if tracker {
                "a second tracker position (or station), or hold that part of the pose in \
                 the model; what compensation needs is the tool relative to the workpiece, \
                 which does not depend on it"
                    .into()
            } else {
                "more positions of their axes, or hold the combination".into()
            },
        }
    }
}

/// What would determine the tool-side errors, by the number of reflectors on the tool.
fn tool_side_fix(reflectors: usize) -> &'static str {
    match reflectors {
        1 => "a second reflector at another offset on the tool",
        2 => {
            "a third reflector off the line through the two reflectors (or one at \
             the tool's length): two reflectors cannot see the tool turn about \
             that line"
        }
        _ => {
            "reflectors further apart on the tool, or more positions of the \
             tool-side axes"
        }
    }
}

/// A parameter the data cannot tell from a combination of the others: holding it at its value
/// loses nothing the data determine.
#[derive(Clone, Debug, PartialEq)]
pub struct Redundancy {
    /// The parameter (index in the model's layout).
    pub param: usize,
    /// The motion it makes with the others: moving it by 1 (its unit) and every `(k, c)` here by
    /// `c` (parameter k's unit) changes no measured point, to first order. Coefficients above
    /// 1e-3 of the largest (in the Jacobian's scaling), largest first.
    pub with: Vec<(usize, f64)>,
}

/// The order in which [`redundant_parameters`] holds parameters, first held first: what a
/// metrologist reads least from a verification goes first — squareness errors (the model's
/// rule already holds most), then the rotary axes' component errors (their constants, then
/// their first harmonics or slopes, then the rest: what the location errors and the tracker's
/// pose also describe), then the linear axes' component errors from the highest coefficient
/// down, then the rotary axes' location errors (X0C, B0A …: the ISO 230-7 quantities a
/// five-axis user knows), then the effects; the tracker's pose and the stations last (a set-up
/// takes whatever a workpiece's own set-up would absorb).
pub fn hold_order(model: &Model) -> Vec<usize> {
    use volver_core::iso::ErrorId;
    use volver_core::model::Owner;
    let machine = model.machine();
    let rank = |j: usize| -> (u32, i64) {
        match model.params()[j].owner {
            Owner::Term { term, coeff } => {
                let t = &model.terms()[term];
                let rotary = machine.axes()[t.axis].axis.is_rotary();
                match (t.id, rotary) {
                    (ErrorId::Location { .. }, false) => (0, 0),
                    (ErrorId::Location { .. }, true) => (6, 0),
                    (_, true) => {
                        let order = match t.basis.kind() {
                            BasisKind::Fourier | BasisKind::Sine => coeff.div_ceil(2),
                            _ => coeff,
                        };
                        (1 + order.min(2) as u32, 0)
                    }
                    (_, false) => (4, -(coeff as i64)),
                }
            }
            Owner::Effect(_) => (7, 0),
            Owner::Tracker(_) | Owner::Station { .. } => (8, 0),
            // An owner to come: held last, with the tracker.
            _ => (8, 0),
        }
    };
    let mut order: Vec<usize> = (0..model.n_params()).collect();
    order.sort_by_key(|&j| (rank(j), j));
    order
}

/// The parameters of `task` to hold so that what is left is identifiable at `params`, chosen
/// greedily in `order` ([`hold_order`] for a machine model): each is held when holding it
/// leaves one combination fewer that the design cannot identify (relative curvature below
/// [`crate::analysis::identifiability::RANK_TOLERANCE`] in the engine's scaled coordinates), until none is
/// left. Each comes with the motion it makes with the others. Empty when the task is already
/// identifiable; `None` when the Jacobian is not finite or a decomposition fails.
///
/// ```
/// use volver_core::model::Model;
/// use volver_core::plan::Plan;
/// use volver_core::problem::Problem;
/// use volver_solvers::Task;
/// use volver_solvers::observability::{hold_order, nominal_data, redundant_parameters};
/// let model = Model::default_xcfz();
/// let data = nominal_data(&model, &Plan::preset(model.machine(), "test3").unwrap());
/// let task = Task::new(Problem::new(&model, &data).unwrap());
/// let held = redundant_parameters(&task, &model.initial_params(), &hold_order(&model)).unwrap();
/// // The paper's model is identifiable on test 3 but for the tool's turn about the line through
/// // the two reflectors, which each linear axis' angular errors describe along it.
/// assert!(held.iter().all(|r| model.params()[r.param].name.starts_with('E')));
/// ```
pub fn redundant_parameters(
    task: &Task,
    params: &[f64],
    order: &[usize],
) -> Option<Vec<Redundancy>> {
    use volver_core::model::{Constraint, ConstraintKind};
    let normal =
        crate::engines::kernels::accumulate(&*task.problem, params, |_| (1.0, 0.0), false)?;
    let design = WeakDesign {
        h: &normal.h,
        params,
    };
    let mut constraints = task.constraints.clone();
    let mut current = design.weak(&constraints)?;
    let mut out = Vec::new();
    for &j in order {
        if current.is_empty() {
            break;
        }
        // Only a parameter the weak directions move can take one of them away.
        let Some(best) = current
            .iter()
            .filter(|dir| design.share(dir, j) > 1e-6)
            .max_by(|a, b| design.share(a, j).total_cmp(&design.share(b, j)))
            .cloned()
        else {
            continue;
        };
        let mut trial = constraints.clone();
        trial.rows.push(Constraint {
            kind: ConstraintKind::Fixed,
            label: format!("parameter {j} held: redundant"),
            coeffs: vec![(j, 1.0)],
            rhs: params[j],
        });
        let Some(left) = design.weak(&trial) else {
            continue;
        };
        if left.len() >= current.len() {
            continue;
        }
        out.push(Redundancy {
            param: j,
            with: design.motion(&best, j),
        });
        constraints = trial;
        current = left;
    }
    Some(out)
}

/// The unweighted normal matrix of a design at `params`, for the weak directions under a set
/// of constraints ([`redundant_parameters`]).
struct WeakDesign<'a> {
    /// `JᵀJ` at `params`.
    h: &'a faer::Mat<f64>,
    /// Where the design is taken.
    params: &'a [f64],
}

impl WeakDesign<'_> {
    /// The norm of column `k` of the Jacobian.
    fn col(&self, k: usize) -> f64 {
        self.h[(k, k)].max(0.0).sqrt()
    }

    /// The directions (in the parameters' units) the design cannot identify under
    /// `constraints`: relative curvature at most [`crate::analysis::identifiability::RANK_TOLERANCE`] in
    /// the engine's scaled coordinates. `None` when a decomposition fails.
    fn weak(&self, constraints: &volver_core::model::Constraints) -> Option<Vec<Vec<f64>>> {
        use crate::engines::coordinates::{reduce, scaled_null_space};
        let n = self.params.len();
        let (d, ns) = scaled_null_space(self.h, constraints, self.params);
        let ns = ns.ok()?;
        let nf = ns.n_free();
        if nf == 0 {
            return Some(vec![]);
        }
        let (hz, _) = reduce(&d, ns.basis(), self.h, None);
        let evd = hz.self_adjoint_eigen(faer::Side::Lower).ok()?;
        let (mu, v) = (evd.S().column_vector(), evd.U());
        let mu_max = mu[nf - 1].max(f64::MIN_POSITIVE);
        let basis = ns.basis();
        Some(
            (0..nf)
                .filter(|&i| mu[i] <= crate::analysis::identifiability::RANK_TOLERANCE * mu_max)
                .map(|i| {
                    (0..n)
                        .map(|j| d[j] * (0..nf).map(|k| basis[(j, k)] * v[(k, i)]).sum::<f64>())
                        .collect()
                })
                .collect(),
        )
    }

    /// The share of parameter `j` in the direction `dir`, in the Jacobian's scaling (a
    /// coefficient times its column's norm, over the largest such).
    fn share(&self, dir: &[f64], j: usize) -> f64 {
        let big = (0..dir.len())
            .map(|k| (dir[k] * self.col(k)).abs())
            .fold(0.0_f64, f64::max);
        (dir[j] * self.col(j)).abs() / big.max(f64::MIN_POSITIVE)
    }

    /// The motion parameter `j` makes with the others along `dir`, with its own coefficient 1:
    /// terms below 1e-3 of the largest (scaled by the columns' norms) left out, largest first.
    fn motion(&self, dir: &[f64], j: usize) -> Vec<(usize, f64)> {
        let n = dir.len();
        let big = (0..n)
            .map(|k| (dir[k] * self.col(k)).abs())
            .fold(0.0_f64, f64::max);
        let mut with: Vec<(usize, f64)> = (0..n)
            .filter(|&k| k != j && (dir[k] * self.col(k)).abs() > 1e-3 * big)
            .map(|k| (k, dir[k] / dir[j]))
            .collect();
        with.sort_by(|a, b| {
            (b.1 * self.col(b.0))
                .abs()
                .total_cmp(&(a.1 * self.col(a.0)).abs())
        });
        with
    }
}
