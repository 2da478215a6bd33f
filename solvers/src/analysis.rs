//! What is computed about a fit or a plan, on top of the engines: which combinations the data
//! identify ([`identifiability`]) and what positions can measure ([`observability`]), the
//! uncertainty of parameters and tool points ([`uncertainty`]), priors ([`prior`]), the optimal
//! design of a test ([`design`]) and the effects a model misses ([`candidates`]). Every module is
//! re-exported at the crate root.

pub mod candidates;
pub mod design;
pub mod efficiency;
pub mod identifiability;
pub mod observability;
pub mod prior;
pub mod uncertainty;
