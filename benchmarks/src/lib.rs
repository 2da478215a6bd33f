//! Shared code of volver's bench binaries: with the `ceres` feature, the expert Ceres program
//! the native engine is measured against ([`expert`]).

#[cfg(feature = "ceres")]
pub mod expert;
