//! # volver-solvers
//!
//! The optimisation side of volver. Every engine implements [`Solver`]: it minimises an
//! objective ([`Objective`]: Φ or ve) of a [`Problem`] under linear equality constraints
//! `A p = b` (the model's, plus the parameters a phase holds), from a start, with shared
//! [`Options`], and returns a [`Solution`] whose [`Summary`] says what happened. A failed run is a
//! status in the summary, never a panic.
//!
//! - [`lm`]: the native Levenberg–Marquardt engine on faer (always available);
//! - [`strategy`]: phases (table 1 of the paper), sub-loops, and the joint, independent,
//!   combined and cross-validation methods, for any engine;
//! - [`candidates`]: what the model misses, ranked by a score test;
//! - [`identifiability`]: rank, condition, uncertainties, correlations, inseparable parameters;
//! - [`init`]: the tracker pose's starting value by a rigid best fit (Kabsch);
//! - [`nullspace`]: constraint elimination, `p = p₀ + N z`;
//! - [`nist_suite`]: NIST's StRD nonlinear-regression suite, scored by the log relative error.
//!
//! The modules are grouped as [`engines`] (the engines, what they share — kernels, losses, the
//! constraint-reduced coordinates, the polish, the gauge — and the strategies that drive them)
//! and [`analysis`] (what is computed about a fit or a plan: identifiability, observability,
//! uncertainty, priors, optimal design, candidates); both are re-exported at the crate root. The
//! analyses use the engines, never the other way round.
#![deny(missing_docs)]

pub mod analysis;
pub mod engines;
mod error;
pub mod nullspace;
pub mod options;
pub mod settings;
pub mod summary;

// The curated surface: each engine and analysis at the path its users know it by
// (`volver_solvers::lm`, `volver_solvers::candidates` …), whichever group holds it.
pub use analysis::{
    candidates, design, efficiency, identifiability, observability, prior, uncertainty,
};
#[cfg(feature = "ceres")]
pub use engines::ceres;
#[cfg(feature = "clarabel")]
pub use engines::clarabel;
#[cfg(feature = "nlopt")]
pub use engines::nlopt;
// Hidden: the normal-equation kernels are public for the bench binary and the tests (kernel
// timings, block sizes), not as API.
#[doc(hidden)]
pub use engines::kernels;
pub use engines::{gauge, init, lm, nist_suite, polish, stationarity, strategy};
pub use error::Error;
pub use options::{Objective, Options};
pub use settings::Settings;
pub use summary::{At, Evaluation, Failure, Invalid, Stall, Summary, Termination};

// What this crate's API speaks in, from volver-core, so that a user depending on volver-solvers
// alone can write a fit: the residuals (your own through `AutoDiff`), the constraints, the
// scalar of generic residuals and its dual numbers; the whole of volver-core as `volver_core`.
pub use volver_core;
pub use volver_core::model::{Constraint, ConstraintKind, Constraints};
pub use volver_core::num_dual;
pub use volver_core::problem::{AutoDiff, PointResidual, Residuals, Scalar, ScalarResidual};
pub use volver_core::scalar::Real;

use volver_core::model::ParamInfo;
use volver_core::problem::Problem;

/// What to solve: residuals (a machine [`Problem`] or a NIST curve fit), the constraints to
/// honour and a label.
#[derive(Clone, Debug)]
pub struct Task<'a> {
    /// The residuals to minimise.
    pub problem: std::sync::Arc<dyn Residuals + 'a>,
    /// Every constraint: the model's, plus held parameters.
    pub constraints: Constraints,
    /// Label of the phase, for reports.
    pub phase: String,
    /// The unweighted normal equations at a point, when the caller already formed them there
    /// (the gauge, at its reference): an engine starting at that very point takes them instead
    /// of a pass of its own.
    pub(crate) plain: Option<std::sync::Arc<PlainNormal>>,
}

/// The unweighted normal equations (`JᵀJ`, `Jᵀr`) at the point `at` (see [`Task`]).
#[derive(Debug)]
pub(crate) struct PlainNormal {
    pub(crate) at: Vec<f64>,
    pub(crate) normal: kernels::Normal,
}

impl<'a> Task<'a> {
    /// The residuals under their own constraints (a machine problem's: its model's).
    pub fn new(problem: impl Residuals + 'a) -> Task<'a> {
        Task {
            constraints: problem.constraints().into_owned(),
            problem: std::sync::Arc::new(problem),
            phase: "all".to_string(),
            plain: None,
        }
    }

    /// The problem with every parameter for which `hold` is true held at its value in `at`.
    pub fn holding(
        problem: Problem<'a>,
        hold: impl Fn(usize, &ParamInfo) -> bool,
        at: &[f64],
        phase: &str,
    ) -> Task<'a> {
        let model = problem.model();
        let mut task = Task::new(problem);
        for (j, info) in model.params().iter().enumerate() {
            if hold(j, info) {
                task.constraints.rows.push(Constraint {
                    kind: ConstraintKind::Fixed,
                    label: format!("{} held by the phase", info.name),
                    coeffs: vec![(j, 1.0)],
                    rhs: at[j],
                });
            }
        }
        task.phase = phase.to_string();
        task
    }
}

/// The result of a solve.
#[derive(Clone, Debug)]
pub struct Solution {
    /// The parameters reached (every constraint satisfied).
    pub params: Vec<f64>,
    /// What happened.
    pub summary: Summary,
}

/// Progress of one iteration, for [`Observer`]s.
#[derive(Clone, Copy, Debug)]
pub struct Iteration {
    /// Steps tried so far.
    pub iteration: usize,
    /// Evaluations so far.
    pub evaluations: usize,
    /// Current objective (smoothed Φ_ε or ve).
    pub cost: f64,
    /// Current EMM (µm) of the residuals the engine is given: for whitened residuals
    /// (objectives ml, phi-w) their mean module × 1000, dimensionless.
    pub emm_um: f64,
    /// Damping λ used for the step.
    pub damping: f64,
    /// Length of the step in the scaled free coordinates.
    pub step: f64,
    /// Whether the step was accepted.
    pub accepted: bool,
}

/// Watches a solve (progress display, logging).
pub trait Observer {
    /// Called after every step tried.
    fn iteration(&mut self, _it: &Iteration) {}

    /// Whether [`Iteration::emm_um`] is read: engines whose own iteration reports lack the
    /// residual modules (Ceres) then spend a residual pass per iteration to compute it.
    fn wants_metrics(&self) -> bool {
        true
    }
}

/// An observer that does nothing.
#[derive(Clone, Copy, Debug, Default)]
pub struct Silent;

impl Observer for Silent {
    fn wants_metrics(&self) -> bool {
        false
    }
}

/// A minimisation engine.
pub trait Solver {
    /// Its name (`lm`, `nlopt`, `ceres`, `clarabel`).
    fn name(&self) -> &'static str;

    /// Minimises `options.objective` over the parameters that satisfy `task.constraints`,
    /// starting from `start` (projected onto the constraints if it misses them).
    fn solve(
        &self,
        task: &Task,
        start: &[f64],
        options: &Options,
        observer: &mut dyn Observer,
    ) -> Solution;
}

/// One engine of volver: its name, the Cargo feature that brings it, a line for people and, when
/// this build has it, its constructor. [`ENGINES`] lists them all; [`engine`],
/// [`engine_names`], the error naming a missing feature and the README's table all read it.
#[derive(Clone, Copy, Debug)]
#[non_exhaustive]
pub struct EngineInfo {
    /// Its name (`volver identify --solver NAME`).
    pub name: &'static str,
    /// The Cargo feature that brings it; `None`: always built.
    pub feature: Option<&'static str>,
    /// What it does, in one line.
    pub description: &'static str,
    /// Its constructor from the engines' [`Settings`] (it reads its own sections; checked by
    /// [`engine_with`]); `None` when this build lacks the feature.
    pub make: Option<MakeEngine>,
}

/// An engine's constructor from the engines' [`Settings`] ([`EngineInfo::make`]).
pub type MakeEngine = fn(&Settings) -> Box<dyn Solver>;

/// A constructor that exists only with a Cargo feature.
macro_rules! with_feature {
    ($name:ident, $feature:literal, |$s:ident| $engine:expr) => {
        #[cfg(feature = $feature)]
        const $name: Option<MakeEngine> =
            Some(|$s: &Settings| -> Box<dyn Solver> { Box::new($engine) });
        #[cfg(not(feature = $feature))]
        const $name: Option<MakeEngine> = None;
    };
}

with_feature!(LM_CLARABEL, "clarabel", |s| {
    crate::engines::clarabel::Polished::new(s.lm, s.clarabel)
});
with_feature!(CLARABEL, "clarabel", |s| {
    crate::engines::clarabel::ProxLinear::new(s.clarabel)
});
with_feature!(CERES, "ceres", |s| ceres::Ceres::new(s.ceres));
with_feature!(NLOPT_LBFGS, "nlopt", |s| {
    crate::engines::nlopt::Nlopt::with_settings(crate::engines::nlopt::Algorithm::Lbfgs, s.nlopt)
});
with_feature!(NLOPT_SLSQP, "nlopt", |s| {
    crate::engines::nlopt::Nlopt::with_settings(crate::engines::nlopt::Algorithm::Slsqp, s.nlopt)
});
with_feature!(NLOPT_MMA, "nlopt", |s| {
    crate::engines::nlopt::Nlopt::with_settings(crate::engines::nlopt::Algorithm::Mma, s.nlopt)
});
with_feature!(NLOPT_BOBYQA, "nlopt", |s| {
    crate::engines::nlopt::Nlopt::with_settings(crate::engines::nlopt::Algorithm::Bobyqa, s.nlopt)
});

/// Every engine volver knows, in the order [`engine_names`] and `volver compare` give them.
pub const ENGINES: &[EngineInfo] = &[
    EngineInfo {
        name: "lm",
        feature: None,
        description: "native Levenberg–Marquardt on faer",
        make: Some(|s: &Settings| -> Box<dyn Solver> { Box::new(s.lm) }),
    },
    EngineInfo {
        name: "lm+clarabel",
        feature: Some("clarabel"),
        description: "the LM, then Φ's second-order cone program as a polish",
        make: LM_CLARABEL,
    },
    EngineInfo {
        name: "clarabel",
        feature: Some("clarabel"),
        description: "Φ's convex sub-problem as a second-order cone program (Clarabel), iterated",
        make: CLARABEL,
    },
    EngineInfo {
        name: "ceres",
        feature: Some("ceres"),
        description: "Ceres Solver 2.1 through volver's own FFI crate",
        make: CERES,
    },
    EngineInfo {
        name: "nlopt-lbfgs",
        feature: Some("nlopt"),
        description: "NLopt's L-BFGS with the exact gradient",
        make: NLOPT_LBFGS,
    },
    EngineInfo {
        name: "nlopt-slsqp",
        feature: Some("nlopt"),
        description: "NLopt's SLSQP, the equality constraints taken natively",
        make: NLOPT_SLSQP,
    },
    EngineInfo {
        name: "nlopt-mma",
        feature: Some("nlopt"),
        description: "NLopt's MMA with the exact gradient",
        make: NLOPT_MMA,
    },
    EngineInfo {
        name: "nlopt-bobyqa",
        feature: Some("nlopt"),
        description: "NLopt's BOBYQA, derivative-free, for comparison",
        make: NLOPT_BOBYQA,
    },
];

/// Names of the engines this build has, in the order of [`ENGINES`]: `lm` always;
/// `lm+clarabel` and `clarabel` with the `clarabel` feature; `ceres` with `ceres`;
/// `nlopt-lbfgs`, `nlopt-slsqp`, `nlopt-mma` and `nlopt-bobyqa` with `nlopt`.
///
/// ```
/// let names = volver_solvers::engine_names();
/// assert_eq!(names[0], "lm");
/// for name in &names {
///     assert_eq!(volver_solvers::engine(name).unwrap().name(), *name);
/// }
/// assert!(volver_solvers::engine("simplex").is_err());
/// ```
pub fn engine_names() -> Vec<&'static str> {
    ENGINES
        .iter()
        .filter(|e| e.make.is_some())
        .map(|e| e.name)
        .collect()
}

/// The engine called `name` configured by `settings` (each engine reads its own sections:
/// `lm` the `lm` section, `lm+clarabel` the `lm` and `clarabel` sections, `ceres` the `ceres`
/// section, the `nlopt-*` engines the `nlopt` section; see [`settings`]). The one way to build
/// a configured engine. An error lists the engines of this build (and the Cargo feature that
/// brings a known engine this build lacks), or names the setting out of range: every section
/// is checked, whichever the engine reads.
///
/// ```
/// use volver_solvers::{engine_with, lm::LevenbergMarquardt, Settings};
/// let mut settings = Settings::default();
/// settings.lm = LevenbergMarquardt::with_geodesic_acceleration(true).with_threads(2);
/// assert_eq!(engine_with("lm", &settings).unwrap().name(), "lm");
/// assert!(engine_with("simplex", &settings).is_err());
/// settings.lm.threads = Some(0);
/// assert_eq!(engine_with("lm", &settings).err().unwrap().to_string(),
///            "lm.threads = 0: expected 1 … 1024");
/// ```
pub fn engine_with(name: &str, settings: &Settings) -> Result<Box<dyn Solver>, Error> {
    let known = ENGINES.iter().find(|e| e.name == name);
    let Some(make) = known.and_then(|e| e.make) else {
        return Err(Error::UnknownEngine {
            name: name.to_string(),
            feature: known.and_then(|e| e.feature),
            built: engine_names(),
        });
    };
    settings.validate()?;
    Ok(make(settings))
}

/// The engine called `name` with its default settings: [`engine_with`] with
/// [`Settings::default`].
pub fn engine(name: &str) -> Result<Box<dyn Solver>, Error> {
    engine_with(name, &Settings::default())
}

/// Makes the calling thread one of the threads of rayon's global pool (whose size still comes
/// from `RAYON_NUM_THREADS` or the number of cores), so that each parallel pass of an engine
/// started from it runs on it too instead of being handed to a pool thread while it waits: with
/// a pass every few milliseconds the hand-over shows (on the bench's 10 000 points, 20–25 ms of
/// 0.57 s on one thread, 15–25 ms of 0.36 s on two). Call it once, first thing in `main`, on
/// the thread that will run the solves; `false` when the global pool already exists (then
/// nothing changes). Results do not depend on it: the passes reduce in a fixed order.
///
/// ```
/// // In a program's main, before anything uses rayon.
/// let _ = volver_solvers::share_calling_thread();
/// ```
pub fn share_calling_thread() -> bool {
    rayon::ThreadPoolBuilder::new()
        .use_current_thread()
        .build_global()
        .is_ok()
}

/// Φ, ve, EMM and EMax of a problem at `params`.
pub fn evaluate(problem: &dyn Residuals, params: &[f64]) -> Evaluation {
    // The modules on every core, summed in point order: the same bits as one thread.
    evaluation_with(
        problem,
        &crate::engines::loss::norms_of(problem, params),
        params,
    )
}

/// [`evaluate`] from the residual modules of `problem` at `params` already computed: of
/// residuals in mm, those; of whitened ones, the objective values from them and Φ, ve and the
/// statistics from a pass over the plain residuals (mm).
pub(crate) fn evaluation_with(
    problem: &dyn Residuals,
    norms: &[f64],
    params: &[f64],
) -> Evaluation {
    match problem.machine().filter(|_| problem.whitened()) {
        Some(machine) => {
            let white = evaluation_of(norms);
            let plain = machine.plain();
            Evaluation {
                phi_w: Some(white.phi_mm),
                ve_w: Some(white.ve_mm2),
                ..evaluation_of(&crate::engines::loss::norms_of(&plain, params))
            }
        }
        None => evaluation_of(norms),
    }
}

/// Whether two parameter vectors are the same to the bit.
pub(crate) fn same_bits(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

/// [`evaluate`] from the residual modules (mm), in point order.
pub(crate) fn evaluation_of(norms: &[f64]) -> Evaluation {
    let n = norms.len() as f64;
    Evaluation {
        phi_mm: norms.iter().sum::<f64>() / n,
        ve_mm2: norms.iter().map(|r| r * r).sum::<f64>() / n,
        stats: volver_core::metrics::ErrorStats::of_modules(norms.iter().copied()),
        phi_w: None,
        ve_w: None,
    }
}
