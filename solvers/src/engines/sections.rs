//! Each engine's own section of [`crate::Settings`] (re-exported from [`crate::settings`]),
//! in every build whatever the features, with their validation.

use crate::Error;
use crate::engines::lm::LevenbergMarquardt;
use serde::{Deserialize, Serialize};

/// Every engine's own settings, one section per engine (see [`crate::settings`]).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[non_exhaustive]
pub struct Settings {
    /// The native Levenberg–Marquardt (`lm`, and the first stage of `lm+clarabel`).
    pub lm: LevenbergMarquardt,
    /// The prox-linear engine on Clarabel (`clarabel`, and the polish of `lm+clarabel`).
    pub clarabel: ClarabelSettings,
    /// Ceres (`ceres`).
    pub ceres: CeresSettings,
    /// NLopt (`nlopt-lbfgs`, `nlopt-slsqp`, `nlopt-mma`, `nlopt-bobyqa`).
    pub nlopt: NloptSettings,
}

impl Settings {
    /// Checks every section; the error names the engine and the field.
    pub fn validate(&self) -> Result<(), Error> {
        self.lm.validate()?;
        self.clarabel.validate()?;
        self.ceres.validate()?;
        self.nlopt.validate()
    }

    /// The settings in a TOML text (the sections and fields of [`crate::settings`]' example, each
    /// optional), validated.
    ///
    /// ```
    /// use volver_solvers::settings::Settings;
    /// let s = Settings::from_toml_str("[nlopt]\nmax_restarts = 3\n").unwrap();
    /// assert_eq!(s.nlopt.max_restarts, 3);
    /// assert!(Settings::from_toml_str("[nlopt]\nrestarts = 3\n").is_err());
    /// assert!(Settings::from_toml_str("[lm]\nthreads = 0\n").is_err());
    /// ```
    pub fn from_toml_str(text: &str) -> Result<Settings, Error> {
        let settings: Settings =
            toml::from_str(text).map_err(|e| Error::SettingsFile(e.message().to_string()))?;
        settings.validate()?;
        Ok(settings)
    }
}

/// `value` finite and `ok` (its range, in words `expected`), or the error naming `engine.field`.
fn check_range(
    engine: &'static str,
    field: &'static str,
    value: f64,
    ok: bool,
    expected: &'static str,
) -> Result<(), Error> {
    if value.is_finite() && ok {
        Ok(())
    } else {
        Err(Error::SettingOutOfRange {
            engine,
            field,
            value,
            expected,
        })
    }
}

/// A count in `[min, max]`, or the error naming `engine.field`.
fn check_count(
    engine: &'static str,
    field: &'static str,
    value: usize,
    (min, max): (usize, usize),
) -> Result<(), Error> {
    if (min..=max).contains(&value) {
        Ok(())
    } else {
        Err(Error::SettingCount {
            engine,
            field,
            value,
            min,
            max,
        })
    }
}

/// The most threads an engine's setting may ask for.
pub const MAX_THREADS: usize = 1024;

impl LevenbergMarquardt {
    /// Checks the settings; the error names `lm` and the field (`rank_tolerance` finite and
    /// ≥ 0, `threads` 1 … [`MAX_THREADS`] when set).
    ///
    /// ```
    /// use volver_solvers::lm::LevenbergMarquardt;
    /// assert!(LevenbergMarquardt::default().with_threads(1).validate().is_ok());
    /// assert!(LevenbergMarquardt::default().with_threads(0).validate().is_err());
    /// ```
    pub fn validate(&self) -> Result<(), Error> {
        let r = self.rank_tolerance;
        check_range("lm", "rank_tolerance", r, r >= 0.0, "≥ 0")?;
        match self.threads {
            Some(n) => check_count("lm", "threads", n, (1, MAX_THREADS)),
            None => Ok(()),
        }
    }

    /// The engine solving on a pool of `threads` threads of its own (see
    /// [`LevenbergMarquardt::threads`]); 0 is refused by [`LevenbergMarquardt::validate`].
    pub fn with_threads(self, threads: usize) -> Self {
        LevenbergMarquardt {
            threads: Some(threads),
            ..self
        }
    }

    /// The engine with the Newton polish of a converged Φ fit on or off
    /// ([`LevenbergMarquardt::polish`]).
    pub fn with_polish(self, polish: bool) -> Self {
        LevenbergMarquardt { polish, ..self }
    }

    /// The engine holding directions whose curvature is below `rank_tolerance` of the largest
    /// ([`LevenbergMarquardt::rank_tolerance`]).
    pub fn with_rank_tolerance(self, rank_tolerance: f64) -> Self {
        LevenbergMarquardt {
            rank_tolerance,
            ..self
        }
    }
}

/// The prox-linear engine's own settings (`clarabel`; the polish of `lm+clarabel`): what volver
/// passes to Clarabel for each second-order cone sub-problem, and the acceptance of its steps.
/// The outer iteration's tolerances and limits are [`crate::Options`]' (parameter and objective
/// change, iterations: sub-problems solved, evaluations).
///
/// ```
/// use volver_solvers::settings::ClarabelSettings;
/// let s = ClarabelSettings::default().with_tolerances(1e-9);
/// assert_eq!((s.tol_gap_abs, s.tol_gap_rel, s.tol_feas), (1e-9, 1e-9, 1e-9));
/// assert!(s.validate().is_ok());
/// assert!(ClarabelSettings::default().with_tolerances(0.0).validate().is_err());
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[non_exhaustive]
pub struct ClarabelSettings {
    /// Clarabel's iteration limit for one sub-problem (its `max_iter`). Default 200.
    pub socp_max_iterations: u32,
    /// Clarabel's absolute duality-gap tolerance (`tol_gap_abs`), on the sub-problem scaled by
    /// the current objective. Default 1e-10.
    pub tol_gap_abs: f64,
    /// Clarabel's relative duality-gap tolerance (`tol_gap_rel`). Default 1e-10.
    pub tol_gap_rel: f64,
    /// Clarabel's feasibility tolerance (`tol_feas`). Default 1e-10.
    pub tol_feas: f64,
    /// A step is accepted when the objective falls by more than this share of the decrease
    /// the sub-problem predicted (the gain ratio ρ), in (0, 1). Default 1e-4.
    pub acceptance: f64,
}

impl Default for ClarabelSettings {
    fn default() -> Self {
        ClarabelSettings {
            socp_max_iterations: 200,
            tol_gap_abs: 1e-10,
            tol_gap_rel: 1e-10,
            tol_feas: 1e-10,
            acceptance: 1e-4,
        }
    }
}

impl ClarabelSettings {
    /// Checks the settings; the error names `clarabel` and the field.
    pub fn validate(&self) -> Result<(), Error> {
        let n = self.socp_max_iterations as usize;
        check_count("clarabel", "socp_max_iterations", n, (1, u32::MAX as usize))?;
        for (field, v) in [
            ("tol_gap_abs", self.tol_gap_abs),
            ("tol_gap_rel", self.tol_gap_rel),
            ("tol_feas", self.tol_feas),
        ] {
            check_range("clarabel", field, v, v > 0.0, "> 0")?;
        }
        let a = self.acceptance;
        check_range("clarabel", "acceptance", a, a > 0.0 && a < 1.0, "in (0, 1)")
    }

    /// The three tolerances of the sub-problems (gap absolute and relative, feasibility) set to
    /// `tolerance`.
    pub fn with_tolerances(self, tolerance: f64) -> Self {
        ClarabelSettings {
            tol_gap_abs: tolerance,
            tol_gap_rel: tolerance,
            tol_feas: tolerance,
            ..self
        }
    }

    /// The iteration limit of one sub-problem.
    pub fn with_socp_max_iterations(self, socp_max_iterations: u32) -> Self {
        ClarabelSettings {
            socp_max_iterations,
            ..self
        }
    }
}

/// Linear solver of Ceres' trust-region step (Ceres' `linear_solver_type`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum LinearSolver {
    /// Dense QR of the Jacobian (Ceres' default for small problems).
    #[default]
    DenseQr,
    /// Cholesky of the dense normal equations.
    DenseNormalCholesky,
    /// Sparse Cholesky of the normal equations (SuiteSparse).
    SparseNormalCholesky,
    /// Conjugate gradients on the normal equations.
    Cgnr,
}

/// Ceres' own settings (`ceres`). Its tolerances and limits are [`crate::Options`]'.
///
/// ```
/// use volver_solvers::settings::{CeresSettings, LinearSolver};
/// let s = CeresSettings::default().with_threads(4).with_linear_solver(LinearSolver::Cgnr);
/// assert!(s.validate().is_ok());
/// assert!(CeresSettings::default().with_threads(0).validate().is_err());
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[non_exhaustive]
pub struct CeresSettings {
    /// Linear solver of the trust-region step. Default dense QR, Ceres' default for dense
    /// problems.
    pub linear_solver: LinearSolver,
    /// Threads evaluating residual blocks and the linear solver's (Ceres' `num_threads`),
    /// 1 … [`MAX_THREADS`]. Default 1.
    pub threads: usize,
}

impl Default for CeresSettings {
    fn default() -> Self {
        CeresSettings {
            linear_solver: LinearSolver::DenseQr,
            threads: 1,
        }
    }
}

impl CeresSettings {
    /// Checks the settings; the error names `ceres` and the field.
    pub fn validate(&self) -> Result<(), Error> {
        check_count("ceres", "threads", self.threads, (1, MAX_THREADS))
    }

    /// The settings with `threads` threads.
    pub fn with_threads(self, threads: usize) -> Self {
        CeresSettings { threads, ..self }
    }

    /// The settings with `linear_solver`.
    pub fn with_linear_solver(self, linear_solver: LinearSolver) -> Self {
        CeresSettings {
            linear_solver,
            ..self
        }
    }
}

/// NLopt's own settings (`nlopt-*`). The stopping criteria volver gives NLopt come from
/// [`crate::Options`]: `ftol_rel` is [`crate::Options::objective_tolerance`] (no finer than the
/// smoothing's share of Φ before the last ε), `xtol_rel` is
/// [`crate::Options::parameter_tolerance`] and `maxeval` the evaluations
/// [`crate::Options::max_evaluations`] leaves; NLopt counts no iterations, so
/// [`crate::Options::max_iterations`] is not read (the summary says so when it is set).
///
/// ```
/// use volver_solvers::settings::NloptSettings;
/// let s = NloptSettings::default().with_max_restarts(0);
/// assert!(s.validate().is_ok());
/// let mut bad = NloptSettings::default();
/// bad.initial_step = -1.0;
/// assert_eq!(bad.validate().unwrap_err().to_string(),
///            "nlopt.initial_step = -1: expected a finite number > 0");
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[non_exhaustive]
pub struct NloptSettings {
    /// Restarts of the last solve, at most, while each still halves the cost (L-BFGS' internal
    /// tests are absolute and stop early on exact fits). Default 10.
    pub max_restarts: usize,
    /// BOBYQA's first trust-region radius in the scaled free coordinates (a unit moves the
    /// residuals by ~1 mm). Default 1e-3.
    pub initial_step: f64,
    /// SLSQP's tolerance on each equality constraint, relative to `1 + |b|`. Default 1e-12.
    pub equality_tolerance: f64,
    /// L-BFGS' stored corrections (NLopt's `vector_storage`); `None`: NLopt's heuristic.
    /// Default `None`.
    pub vector_storage: Option<usize>,
}

impl Default for NloptSettings {
    fn default() -> Self {
        NloptSettings {
            max_restarts: 10,
            initial_step: 1e-3,
            equality_tolerance: 1e-12,
            vector_storage: None,
        }
    }
}

impl NloptSettings {
    /// Checks the settings; the error names `nlopt` and the field.
    pub fn validate(&self) -> Result<(), Error> {
        let s = self.initial_step;
        check_range("nlopt", "initial_step", s, s > 0.0, "> 0")?;
        let t = self.equality_tolerance;
        check_range("nlopt", "equality_tolerance", t, t > 0.0, "> 0")?;
        match self.vector_storage {
            Some(m) => check_count("nlopt", "vector_storage", m, (1, 1000)),
            None => Ok(()),
        }
    }

    /// The settings with at most `max_restarts` restarts of the last solve.
    pub fn with_max_restarts(self, max_restarts: usize) -> Self {
        NloptSettings {
            max_restarts,
            ..self
        }
    }
}

/// The fields among `unread` (those an engine does not read) that `options` sets away from
/// their defaults, by name: what [`crate::Summary::ignored_options`] states.
#[cfg(any(feature = "clarabel", feature = "nlopt"))]
pub(crate) fn ignored(options: &crate::Options, unread: &[&'static str]) -> Vec<String> {
    let d = crate::Options::default();
    let changed = |field: &str| match field {
        "max_iterations" => options.max_iterations != d.max_iterations,
        "gradient_tolerance" => options.gradient_tolerance != d.gradient_tolerance,
        "initial_damping" => options.initial_damping != d.initial_damping,
        "irls_initial_epsilon" => options.irls_initial_epsilon != d.irls_initial_epsilon,
        "irls_final_epsilon" => options.irls_final_epsilon != d.irls_final_epsilon,
        _ => false,
    };
    unread
        .iter()
        .filter(|f| changed(f))
        .map(|f| f.to_string())
        .collect()
}
