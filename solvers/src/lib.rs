//! # volver-solvers
//!
//! The optimisation side of volver. Every engine minimises the model's objective under the linear
//! equality constraints `A p = b` that travel with the parameter layout
//! ([`volver_core::model::Constraints`]). This crate holds what they share; the engines (native
//! Levenberg–Marquardt, NLopt, Ceres, Clarabel) arrive with the identification and back-end
//! issues.
//!
//! - [`nullspace`]: constraint elimination, `p = p₀ + N z`, for engines without native equality
//!   constraints.
#![deny(missing_docs)]

pub mod nullspace;
