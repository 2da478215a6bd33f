//! # volver-core
//!
//! The metrology core of volver: everything about machines, errors and measurements, and no
//! optimiser.
//!
//! - [`chain`]: chain notation (`XCFZ`, `FXYZ` …);
//! - [`machine`]: the machine description (TOML) and the embedded XCFZ grinder;
//! - [`iso`]: the ISO 230 error catalogue (EXX … ECC, X0C, B0Z);
//! - [`approach`]: the direction of approach of each axis at a point (reversal errors);
//! - [`basis`]: monomial, Legendre, Chebyshev-by-nodes, Fourier and sine-phase bases;
//! - [`model`]: error models, parameter layout, linear constraints, evaluation and the exact
//!   structured Jacobian;
//! - [`kinematics`]: the scalar-generic forward model (eq. 11 of the paper for XCFZ);
//! - [`measure`]: measurement files (CSV);
//! - [`csvio`]: the CSV layer every CSV reader reads through (header names to columns, units in
//!   the header, a file, line and column for every bad cell);
//! - [`results`]: results files (JSON);
//! - [`plan`]: test plans (the paper's meshes and plain grids);
//! - [`plausibility`]: identified sizes checked against stated physical limits;
//! - [`noise`], [`random`]: the tracker's noise model and a seeded random source;
//! - [`simulate`]: the synthetic data generator (true errors, hidden effects, noise);
//! - [`metrics`]: EMM and EMax;
//! - [`diagnose`]: where a model fails (residual breakdowns, periodograms, repeat noise);
//! - [`problem`]: a model with its measurements: residuals, Φ, ve; your own residuals with
//!   exact dual-number derivatives ([`problem::AutoDiff`]);
//! - [`compensate`]: the inverse model: the command that puts the tool where it belongs;
//! - [`gcode`]: G-code programs, read and written back compensated;
//! - [`dialect`]: the words that differ between G-code dialects (LinuxCNC, Fanuc);
//! - [`tables`]: controller tables of the identified errors (ISG CSV, Etalon style, plain CSV);
//! - [`fsio`]: atomic file output;
//! - [`fuzz`]: harnesses for fuzzing the readers;
//! - [`units`]: named unit conversions (µm per mm, µrad per rad, s per h).
//!
//! Units: mm and rad everywhere; degrees only in files.
//!
//! ```
//! use volver_core::model::Model;
//! let model = Model::default_xcfz();
//! let p = model.initial_params();
//! let cmd = model.machine().commands_from_file_units(&[700.0, 90.0, 300.0]);
//! let mut jac = vec![0.0; 3 * model.n_params()];
//! let x = model.predict_with_jacobian(&cmd, 1, &p, &mut jac);
//! assert!((x[0] + 125.0).abs() < 1e-9);
//! // ∂x/∂tracker.x = −1: the tracker translation moves every point the other way.
//! assert_eq!(jac[model.param_index("tracker.x").unwrap()], -1.0);
//! ```
#![deny(missing_docs)]

pub mod approach;
pub mod basis;
pub mod chain;
pub mod compensate;
pub mod csvio;
pub mod diagnose;
pub mod dialect;
pub mod error;
pub mod fsio;
// Hidden: the fuzzing harnesses are public for the fuzz targets and tests/fuzz_seeds.rs, not as API.
#[doc(hidden)]
pub mod fuzz;
pub mod gcode;
pub mod import;
pub mod iso;
pub mod kinematics;
pub mod machine;
pub mod measure;
pub mod metrics;
pub mod model;
pub mod nist;
pub mod noise;
pub mod plan;
pub mod plausibility;
pub mod presets;
pub mod problem;
pub mod random;
pub mod results;
pub mod scalar;
pub mod simulate;
pub mod tables;
pub mod units;

pub use error::{Error, Place, Result};
/// The dual numbers of the exact derivatives (`num-dual`), re-exported so that a generic
/// residual ([`problem::PointResidual`]) and its callers use the version volver's [`scalar::Real`]
/// is built on.
pub use num_dual;
