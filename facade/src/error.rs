//! The library's one error type: what the workflows (identify, diagnose, plan, compensate,
//! report …) return.
//!
//! [`Error`] wraps the metrology core's and the engines' errors unchanged and adds the
//! failures of the workflows themselves, each as its own variant, so that a caller can tell a bad
//! request from a fit that failed or a singular design without reading text. Every variant
//! prints the same text the CLI prints; [`Error::Context`] adds what was being done (the CLI
//! prints it as `Error: …` followed by `Caused by: …`).
//!
//! ```
//! use volver::{Context, Error};
//! let missing = std::path::Path::new("/no/such/machine.toml");
//! let e = volver::core::machine::Machine::load(missing)
//!     .context("reading the machine file")
//!     .unwrap_err();
//! assert_eq!(e.to_string(), "reading the machine file");
//! // What happened, typed: the core's I/O error, with the file it names.
//! assert!(matches!(e.root(), Error::Core(volver::core::Error::Io { .. })));
//! ```

/// The result of the library's workflows.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// What a workflow of the library can fail with.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A failure of the metrology core: bad input (with its file, line and field), a model that
    /// cannot be built, a file that cannot be read or written.
    #[error(transparent)]
    Core(#[from] volver_core::Error),
    /// A failure of an engine or of the solvers' analyses: options out of range, an unknown
    /// engine, a decomposition that failed.
    #[error(transparent)]
    Solver(#[from] volver_solvers::Error),
    /// An operating-system error whose file is named by the [`Error::Context`] around it.
    #[error(transparent)]
    Os(#[from] std::io::Error),
    /// A JSON document that could not be written or read (a results or history record).
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// A request that cannot be served as asked: an option out of its range, options that
    /// exclude each other, a name that is none of the choices. The text names the option
    /// (`--monte-carlo 1: give 2 … 100000 replicas …`).
    #[error("{0}")]
    Request(String),
    /// Inputs that do not belong together: a truth for another machine, a candidate that the
    /// model does not have, a reflector named twice.
    #[error("{0}")]
    Mismatch(String),
    /// An identification (or a refit inside a workflow) that did not converge; the text says
    /// which criterion stopped it.
    #[error("{0}")]
    NotSolved(String),
    /// A matrix that could not be factorised or inverted: a singular information matrix, a
    /// covariance that could not be computed, Jacobians that are not finite.
    #[error("{0}")]
    Singular(String),
    /// Identified sizes beyond the stated physical limits, refused where they would reach a
    /// machine (compensation) unless accepted explicitly.
    #[error("{0}")]
    Implausible(String),
    /// The U gate: a compensation refused because its expanded uncertainty or the fit's check
    /// does not allow it.
    #[error("{0}")]
    Refused(String),
    /// What was being done when the error in `source` happened.
    #[error("{context}")]
    Context {
        /// What was being done (`reading the machine file`).
        context: String,
        /// The error it met.
        #[source]
        source: Box<Error>,
    },
}

impl Error {
    /// This error inside a description of what was being done.
    pub fn context(self, context: impl Into<String>) -> Error {
        Error::Context {
            context: context.into(),
            source: Box::new(self),
        }
    }

    /// The innermost error, past every [`Error::Context`].
    pub fn root(&self) -> &Error {
        match self {
            Error::Context { source, .. } => source.root(),
            e => e,
        }
    }
}

/// Adds what was being done to an error, as `anyhow::Context` does (but typed).
pub trait Context<T> {
    /// Wraps the error in [`Error::Context`] with `context`.
    fn context(self, context: impl Into<String>) -> Result<T>;
    /// Wraps the error in [`Error::Context`] with the text `f` makes (only on error).
    fn with_context<C: Into<String>>(self, f: impl FnOnce() -> C) -> Result<T>;
}

impl<T, E: Into<Error>> Context<T> for std::result::Result<T, E> {
    fn context(self, context: impl Into<String>) -> Result<T> {
        self.map_err(|e| e.into().context(context))
    }

    fn with_context<C: Into<String>>(self, f: impl FnOnce() -> C) -> Result<T> {
        self.map_err(|e| e.into().context(f()))
    }
}
