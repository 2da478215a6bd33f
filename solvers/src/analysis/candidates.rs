//! What is missing: a library of candidate effects the model could add, each ranked by how much
//! it would lower the error given what the model already explains.
//!
//! The score of a candidate is one Gauss–Newton step of the extended model from the current
//! solution (the new parameters start at zero, so the start is the current fit): it measures the
//! residual the candidate's Jacobian columns explain beyond the current ones — a score
//! (Lagrange-multiplier) test — and the predicted EMM is the extended model evaluated after that
//! step. Significance is ΔBIC = m·ln(RSS′/RSS) + Δk·ln m over the m = 3n residual coordinates
//! (Δk the extra identified directions): below −10 is strong evidence. Candidates are ranked by
//! ΔBIC, most negative first.
//!
//! **Sizes are of what is new.** The step changes the model's own parameters too, and a
//! candidate's raw coefficients include what the model already expresses (a field over X and
//! Z carries the products the angular errors of X make with the lever arm of Z: metres of
//! coefficients against metres of those errors for a few hundred µm of new displacement). A
//! candidate's size and plausibility are therefore measured on the part of its change of the
//! measured points that the current model cannot make (the projection out of the span of its
//! Jacobian's identified directions): a field's size is the largest displacement
//! of that part at a measured point; every other kind's is its own quantity (µm/h, ppm, µrad …)
//! of the smallest change of its new parameters alone that adds the same.
//!
//! **The EMM predicted** is the EMM a refit (Φ: the mean module) would reach to first order,
//! never above the current one; the verdict recommends only a candidate
//! with strong evidence that lowers it ([`recommended`]) and says why when the candidate with
//! the strongest evidence does not. A significant field is shown with the physical candidates
//! over its variables ([`sharing`]).
//!
//! Candidate ids (stable):
//!
//! | id | what it adds |
//! |---|---|
//! | `add:EAC` | an ISO 230 error the model leaves out (linear axes: Legendre of the model's polynomial degree, default 3; rotary: first-harmonic Fourier; location and squareness errors: a constant) |
//! | `raise:EXX` | the next degree (polynomial) or harmonic (periodic) of one modelled error |
//! | `raise-axis:C` | the next degree or harmonic of every modelled error of one axis |
//! | `tracker-tilt` | the tracker's small rotations about its x and y axes, when the model holds them |
//! | `thermal-drift` | drift of the tool point with time (`[effects] thermal_drift`; needs `t_s`) |
//! | `reflector-offset:R1` | reflector R1 off its nominal offset |
//! | `range-scale` | a scale error of the tracker's range |
//! | `range-offset` | each station's range offset, the dead path (`[tracker] range_offset`) |
//! | `station-drift` | each station's position drifting with time (`[effects] station_drift`; machines with `[[station]]` tables) |
//! | `ball-screw:X:700` | a periodic positioning error of X with period 700 mm (travel/2 … travel/8 are tried) |
//! | `reversal:X` | a reversal value of X, ISO 230-2's B (backlash: ±B/2 on its positioning error by the direction of approach; `[effects] reversal`); offered only when some points arrived at X from each side ([`offered`]) |
//! | `thermal-scale:X` | the scale of linear axis X growing with time: EXX += α·x·t (`[effects] thermal_scale`; needs `t_s`) |
//! | `tracker-drift` | the tracker's small rotations drifting with time (`[effects] tracker_drift`) |
//! | `location-drift:C` | the line of rotary axis C drifting with time: X0C, Y0C += v·t (`[effects] location_drift`) |
//! | `field:X`, `field:X*Z`, `field:X*t` | a generic displacement of the tool point over one variable or jointly over two (axes and time `t`; `[effects] field`): names what the misfit depends on when no physical candidate explains it |

use volver_core::model::ErrorModelSpec;

mod library;
mod novelty;
mod scoring;
mod sizes;
mod verdict;

pub use library::{SCREW_PERIODS, library, offered};
pub use scoring::{carry_over, rank};
pub use verdict::{EMM_GAIN, axis_of, lowers, recommended, sharing, um, variables, verdict};

/// A candidate: an extension of the error model.
#[derive(Clone, Debug, PartialEq)]
pub struct Candidate {
    /// Stable id (see the module table).
    pub id: String,
    /// What it means, in words.
    pub description: String,
    /// The extended error model.
    pub spec: ErrorModelSpec,
}

/// A ranked candidate.
#[derive(Clone, Debug, PartialEq)]
pub struct Score {
    /// Candidate id.
    pub id: String,
    /// What it means.
    pub description: String,
    /// Extra directions the data identify with it.
    pub added: usize,
    /// Predicted EMM after adding it (µm).
    pub emm_um: f64,
    /// ΔBIC against the current model (negative: the data support it).
    pub delta_bic: f64,
    /// Size of what the candidate adds beyond what the current model expresses (see the module
    /// documentation), by kind: for a field the largest displacement of that new part at a
    /// measured point (µm); for the others, of the smallest change of the new parameters alone
    /// that adds it, the norm of a new effect's parameters (a drift in µm/h, a periodic error's
    /// amplitude in µm, a reflector offset in µm, a range scale in ppm), the tilt
    /// `tracker-tilt` frees (µrad), or the largest value over the travel of the added part of
    /// an added or raised error function (µm or µrad).
    pub size: f64,
    /// Unit of `size` (`µm`, `µrad`, `µm/h` or `ppm`).
    pub size_unit: &'static str,
    /// Candidates the data cannot tell from this one: as many added directions and a ΔBIC
    /// within 2 of it ("not worth more than a bare mention" on Kass and Raftery's scale), e.g. a
    /// tilt of the tracker standing on the table and a tilt motion of the table. Listed under
    /// the better of them.
    pub equivalent: Vec<String>,
    /// Why it is not a finding, when it is not plausible: its size beyond the physical bound
    /// of its kind, or evidence only along a nearly unidentifiable direction. A flagged
    /// candidate is never ranked first.
    pub flag: Option<String>,
    /// Why it could not be scored (its model or problem cannot be built, or its step is
    /// singular or not finite), when it could not: it is then listed last with no figures
    /// (NaN), never dropped.
    pub failed: Option<String>,
}

impl Score {
    /// A candidate that could not be scored, and why.
    fn failed(id: String, description: String, why: String) -> Score {
        Score {
            id,
            description,
            added: 0,
            emm_um: f64::NAN,
            delta_bic: f64::NAN,
            size: f64::NAN,
            size_unit: "",
            equivalent: Vec::new(),
            flag: None,
            failed: Some(why),
        }
    }
}

impl Score {
    /// `true` when the candidate adds a direction the data identify; one that adds none cannot
    /// be seen in these data (its ΔBIC and size mean nothing).
    pub fn seen(&self) -> bool {
        self.added > 0
    }

    /// Strong evidence on Kass and Raftery's scale: ΔBIC below −10, for a plausible candidate
    /// (not flagged) the data see.
    pub fn strong(&self) -> bool {
        self.seen() && self.flag.is_none() && self.delta_bic < -10.0
    }
}
