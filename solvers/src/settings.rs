//! One way to configure the engines: [`Settings`] holds a section per engine (`lm`, `clarabel`,
//! `ceres`, `nlopt`) with what only that engine reads, and [`crate::engine_with`] builds the
//! engine of a name from it. The criteria every engine shares (objective, tolerances, limits)
//! stay in [`crate::Options`].
//!
//! Every section exists in every build, whatever the Cargo features, so code that configures
//! Ceres compiles in a build without it (and [`crate::engine_with`] then says which feature the
//! engine needs). Each section has a `Default` (the engines' defaults), `with_*` builders and a
//! `validate` whose typed error names the engine and the field; [`Settings::validate`] checks
//! them all and [`crate::engine_with`] refuses invalid settings before anything is solved.
//! `Settings` reads from and writes to TOML or JSON (serde), each field optional:
//!
//! ```toml
//! [lm]
//! threads = 2
//! geodesic_acceleration = true
//!
//! [ceres]
//! linear_solver = "dense-normal-cholesky"
//! threads = 2
//! ```
//!
//! ```
//! use volver_solvers::settings::{CeresSettings, LinearSolver, Settings};
//! use volver_solvers::{engine_with, lm::LevenbergMarquardt};
//! let mut settings = Settings::default();
//! settings.lm = LevenbergMarquardt::default().with_threads(2);
//! settings.ceres = CeresSettings::default()
//!     .with_linear_solver(LinearSolver::DenseNormalCholesky)
//!     .with_threads(2);
//! settings.clarabel.socp_max_iterations = 100;
//! assert!(settings.validate().is_ok());
//! assert_eq!(engine_with("lm", &settings).unwrap().name(), "lm");
//! // Zero threads is refused, naming the engine and the field.
//! settings.ceres.threads = 0;
//! let e = settings.validate().unwrap_err();
//! assert_eq!(e.to_string(), "ceres.threads = 0: expected 1 … 1024");
//! assert!(engine_with("lm", &settings).is_err());
//! ```

pub use crate::engines::sections::{
    CeresSettings, ClarabelSettings, LinearSolver, MAX_THREADS, NloptSettings, Settings,
};
