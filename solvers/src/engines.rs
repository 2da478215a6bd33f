//! The engines and what they share: the native Levenberg–Marquardt ([`lm`]), Clarabel, Ceres
//! and NLopt behind Cargo features, the normal-equation kernels, the robust losses, the
//! constraint-reduced coordinates, the run plumbing, the check of every claimed convergence
//! ([`stationarity`]), the polish ([`polish`]), the gauge
//! ([`gauge`]), the tracker's start ([`init`]), the identification strategies ([`strategy`]) and
//! the NIST suite ([`nist_suite`]). Every public module is re-exported at the crate root.

#[cfg(feature = "ceres")]
pub mod ceres;
#[cfg(feature = "clarabel")]
pub mod clarabel;
pub(crate) mod coordinates;
pub mod gauge;
pub mod init;
#[doc(hidden)]
pub mod kernels;
pub mod lm;
pub(crate) mod loss;
pub mod nist_suite;
#[cfg(feature = "nlopt")]
pub mod nlopt;
pub mod polish;
pub(crate) mod run;
pub(crate) mod sections;
pub mod stationarity;
pub mod strategy;
#[cfg(test)]
pub(crate) mod test_problems;
