//! # volver
//!
//! Volumetric verification of multi-axis machine tools with a laser tracker. This crate is the
//! library: the facade over the workspace and the workflows every `volver` subcommand calls
//! (the command-line tool itself is the `volver-cli` package). Its functions return the typed
//! [`Error`].
//!
//! - [`core`] (`volver-core`): machines, the ISO 230 errors, bases, error models, the forward
//!   model and its exact Jacobian, measurement and results files;
//! - [`solvers`] (`volver-solvers`): what the optimisation engines share.
//!
//! ```
//! use volver::core::model::Model;
//! let model = Model::default_xcfz();
//! assert_eq!(model.machine().chain().to_string(), "XCFZ");
//! ```
#![deny(missing_docs)]

pub use volver_core as core;
pub use volver_solvers as solvers;

pub use error::{Context, Error, Result};

pub mod comparison;
pub mod compensation;
pub mod diagnosis;
pub mod error;
pub mod estimators;
pub mod history;
pub mod identification;
pub mod inputs;
pub mod machining;
pub mod planning;
pub mod plot;
pub mod report;
pub mod shared;
pub mod study;
pub mod uncertainty;

/// The README's Rust examples, compiled and run as doctests.
#[cfg(doctest)]
#[doc = include_str!("../../README.md")]
pub struct ReadmeDoctests;
