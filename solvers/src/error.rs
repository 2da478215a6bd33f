//! What the solvers crate refuses before a solve starts, as one typed error. A run that starts
//! and then fails is not an error but a [`crate::Termination`] in its summary.

/// Why a solve, an engine or a setting cannot be had.
///
/// ```
/// use volver_solvers::{Error, Options};
/// let bad = Options { max_iterations: 0, ..Options::default() };
/// assert_eq!(bad.validate(), Err(Error::NoLimit));
/// assert!(matches!(volver_solvers::engine("simplex"), Err(Error::UnknownEngine { .. })));
/// ```
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// No engine of this name in this build; `feature` names the Cargo feature that has it.
    #[error(
        "unknown solver '{name}'{}: this build has {}",
        feature.map(|f| format!(" ('{name}' needs the Cargo feature `{f}`)")).unwrap_or_default(),
        built.join(", ")
    )]
    UnknownEngine {
        /// The name asked for.
        name: String,
        /// The feature of a known engine this build lacks.
        feature: Option<&'static str>,
        /// The engines this build has.
        built: Vec<&'static str>,
    },
    /// An option outside its range.
    #[error("options.{field} = {value}: expected a finite number {expected}")]
    OutOfRange {
        /// The option's field in [`crate::Options`].
        field: &'static str,
        /// Its value.
        value: f64,
        /// The range, in words (`≥ 0`, `> 0`).
        expected: &'static str,
    },
    /// An engine's own setting outside its range.
    #[error("{engine}.{field} = {value}: expected a finite number {expected}")]
    SettingOutOfRange {
        /// The engine (`lm`, …).
        engine: &'static str,
        /// The setting's field.
        field: &'static str,
        /// Its value.
        value: f64,
        /// The range, in words.
        expected: &'static str,
    },
    /// An engine's own count setting (threads, iterations) outside its bounds.
    #[error("{engine}.{field} = {value}: expected {min} … {max}")]
    SettingCount {
        /// The engine's section (`lm`, `ceres`, …).
        engine: &'static str,
        /// The setting's field.
        field: &'static str,
        /// Its value.
        value: usize,
        /// The smallest allowed.
        min: usize,
        /// The largest allowed.
        max: usize,
    },
    /// An engine-settings text (TOML) that cannot be read: the parser's words.
    #[error("engine settings: {0}")]
    SettingsFile(String),
    /// The final IRLS ε above the initial one.
    #[error(
        "options.irls_final_epsilon = {final_epsilon} exceeds irls_initial_epsilon = {initial_epsilon}"
    )]
    EpsilonOrder {
        /// `irls_initial_epsilon`.
        initial_epsilon: f64,
        /// `irls_final_epsilon`.
        final_epsilon: f64,
    },
    /// An iteration or evaluation limit of zero.
    #[error("options.max_iterations and max_evaluations must be ≥ 1")]
    NoLimit,
    /// An evaluation limit below what every solve takes at its start.
    #[error(
        "options.max_evaluations = {value}: a solve takes up to {min} evaluations at its start \
         (the start's residuals and Jacobian, the residuals of the start projected onto the \
         constraints): give at least {min}"
    )]
    TooFewEvaluations {
        /// The limit asked for.
        value: usize,
        /// The smallest limit ([`crate::options::MIN_EVALUATIONS`]).
        min: usize,
    },
    /// A noise-weighted objective (`ml`, `phi-w`) asked of residuals that are not whitened.
    #[error(
        "objective {0} weighs the residuals by their noise, but these are not whitened: give the \
         engine Problem::whitened residuals (the identification does, from --noise or the \
         machine file's noise)"
    )]
    NotWhitened(String),
    /// An objective name that is not `phi`, `ve`, `ml` or `phi-w`.
    #[error("unknown objective '{0}': phi, ve, ml or phi-w")]
    UnknownObjective(String),
    /// A phasing name not in [`crate::engines::strategy::PHASINGS`].
    #[error("unknown phasing '{name}': {}", known.join(", "))]
    UnknownPhasing {
        /// The name asked for.
        name: String,
        /// The phasings there are.
        known: &'static [&'static str],
    },
    /// A count outside its bounds (Monte Carlo replicas, …): checked before anything is
    /// allocated.
    #[error("{what} {value}: give {min} … {max}")]
    CountOutOfRange {
        /// The count, in words (`--monte-carlo`).
        what: &'static str,
        /// The count asked for.
        value: usize,
        /// The smallest meaningful count.
        min: usize,
        /// The largest count allowed.
        max: usize,
    },
    /// The tracker's rigid fit cannot be made (collinear points, a rotation beyond the small
    /// angles of eq. 9, an SVD that did not converge); the text says which.
    #[error("{0}")]
    TrackerFit(String),
}
