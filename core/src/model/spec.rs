//! The error model as written in TOML: which errors, in which bases, the squareness rule,
//! the tracker's identified components, fixed values and the effects beyond ISO 230.

use super::*;

/// How squareness and straightness share the slope they both describe (paper, section 6.1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum SquarenessRule {
    /// The paper's rule: a squareness whose straightness partner is modelled (B0Z ↔ EXZ) is held
    /// at zero; the squareness is read from the straightness' slope ([`Model::squareness`]).
    #[default]
    FromStraightness,
    /// The straightness partner's best-fit slope (its Legendre P1 component) is held at zero and
    /// the squareness parameter carries it: the ISO 230-1 split.
    Separate,
    /// No rule: squareness and the straightness slope are interchangeable (not identifiable).
    None,
}

/// A name or a list of names.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum OneOrMany {
    /// One name.
    One(String),
    /// Several names.
    Many(Vec<String>),
}

impl OneOrMany {
    /// The names.
    pub fn names(&self) -> Vec<&str> {
        match self {
            OneOrMany::One(s) => vec![s.as_str()],
            OneOrMany::Many(v) => v.iter().map(String::as_str).collect(),
        }
    }
}

/// One `[[error]]` entry of an error model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ErrorTermSpec {
    /// ISO 230 name(s) of the error(s).
    pub name: OneOrMany,
    /// Basis (absent for location and squareness errors, which are constants).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub basis: Option<BasisKind>,
    /// Degree of a polynomial basis (Chebyshev: nodes − 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub degree: Option<usize>,
    /// Number of Chebyshev nodes (alternative to `degree`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nodes: Option<usize>,
    /// Number of harmonics of a periodic basis.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub order: Option<usize>,
}

/// The `[tracker]` table of an error model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackerModelSpec {
    /// Which of x, y, z, rx, ry, rz of the tracker (the reference station) are identified; the
    /// others are fixed at their nominal value. Further stations identify their whole pose (a
    /// range-only station its position).
    pub identify: Vec<String>,
    /// Each station's range offset (mm, the dead path): a range is `|x| + offset`, a point is
    /// moved by the offset along its line of sight. Parameters `tracker.offset` or
    /// `station.<id>.offset`.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub range_offset: bool,
}

impl Default for TrackerModelSpec {
    fn default() -> Self {
        TrackerModelSpec {
            identify: TRACKER_NAMES.iter().map(|s| s.to_string()).collect(),
            range_offset: false,
        }
    }
}

pub(super) fn default_true() -> bool {
    true
}

pub(super) fn is_true(b: &bool) -> bool {
    *b
}

/// An error model as written in its TOML file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ErrorModelSpec {
    /// Human-readable name.
    #[serde(default)]
    pub name: String,
    /// Squareness rule.
    #[serde(default)]
    pub squareness: SquarenessRule,
    /// Linear-axis errors vanish at the axis' reference position (section 5.1). Default true.
    #[serde(default = "default_true", skip_serializing_if = "is_true")]
    pub reference_constraint: bool,
    /// The modelled errors.
    #[serde(default, rename = "error")]
    pub errors: Vec<ErrorTermSpec>,
    /// Tracker pose identification.
    #[serde(default)]
    pub tracker: TrackerModelSpec,
    /// Parameters held at a value (name → value in the parameter's unit).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub fixed: BTreeMap<String, f64>,
    /// Effects outside the ISO 230 model.
    #[serde(default, skip_serializing_if = "EffectsSpec::is_empty")]
    pub effects: EffectsSpec,
}

/// The range of a periodic error's period (mm): from 0.1 mm (a tenth harmonic of a 1 mm pitch)
/// to [`crate::machine::MAX_DIMENSION`]; a shorter period is not resolved by any plan, and one
/// of 1e-300 mm would make the phase overflow.
pub const PERIOD_RANGE_MM: (f64, f64) = (0.1, crate::machine::MAX_DIMENSION);

/// The largest magnitude of a `[fixed]` value: [`crate::machine::MAX_DIMENSION`] for a length
/// (mm), 10 rad for an angle, beyond which no machine's error or tracker pose lies.
pub const MAX_FIXED: (f64, f64) = (crate::machine::MAX_DIMENSION, 10.0);

/// A periodic positioning error of a linear axis (e.g. a ball screw's pitch error).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BallScrewSpec {
    /// The linear axis (letter).
    pub axis: String,
    /// The period (mm).
    pub period_mm: f64,
}

/// The `[effects]` table of an error model: physical effects outside the ISO 230 errors, each
/// with its parameters in group `other`. Formulas as in the synthetic generator
/// ([`crate::simulate`]).
///
/// ```toml
/// [effects]
/// thermal_drift = true          # drift.x, drift.y, drift.z (mm/h): tool point, machine frame, × t_s
/// reflector_offset = ["R1"]     # reflector.R1.x … (mm): the reflector off its nominal offset
/// range_scale = true            # range.scale (ppm): points scaled about the tracker
/// thermal_scale = ["X"]         # thermal.X (ppm/h): EXX += α·10⁻⁶·x·t, the scale of X growing with time
/// location_drift = ["C"]        # locdrift.C.x, locdrift.C.y (mm/h): X0C, Y0C += v·t
/// tracker_drift = true          # trackerdrift.rx, .ry, .rz (rad/h): the tracker's small rotations += ω·t
/// station_drift = true          # stationdrift.S1.x … (mm/h): each station's position += v·t
/// field = ["X*Z", "X*t"]        # field.X*Z.x_1_1 … (mm): a smooth displacement of the tool point
/// reversal = ["X", "C"]         # reversal.X.b (mm; rad for a rotary axis): ISO 230-2's B, the tool ±B/2 by the direction of approach
/// # reversal = [{ axis = "X", degree = 1 }]   # B(x) = b + b1·P₁(x̂): a reversal varying along the axis
/// [[effects.ball_screw]]
/// axis = "X"
/// period_mm = 700.0             # screw.X.a, screw.X.b (mm): a·sin φ + b·cos φ, φ = 2π(u − u_ref)/P
/// ```
///
/// A **field** is a generic displacement of the tool point relative to the workpiece, in the
/// machine frame, that depends on one variable or jointly on two: axis positions and the time
/// `t` (h). Each variable has its functions: a linear axis (or a rotary one with less than a
/// turn) the Legendre polynomials P₁, P₂, P₃ of its position normalised over the travel, a
/// full-turn rotary axis cos θ, sin θ, cos 2θ, sin 2θ, the time t and t². A field over one
/// variable uses all of them, one over two (`X*Z`) the products of the first two of each
/// (P₁P₁, P₁P₂, P₂P₁, P₂P₂): what the rigid-body model cannot express. Each product has a
/// coefficient per component x, y, z. It names what the misfit depends on when no physical
/// effect explains it; the time's origin is the test's start, and [`super::Model::tool_point`]
/// keeps a field's value there.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EffectsSpec {
    /// Thermal drift of the tool point with time (needs `t_s` in the measurements).
    #[serde(skip_serializing_if = "is_false")]
    pub thermal_drift: bool,
    /// Reflectors whose offset is identified.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub reflector_offset: Vec<String>,
    /// The tracker's range scale error.
    #[serde(skip_serializing_if = "is_false")]
    pub range_scale: bool,
    /// Periodic positioning errors.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub ball_screw: Vec<BallScrewSpec>,
    /// Linear axes whose scale grows with time (thermal expansion of the drive or the scale).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub thermal_scale: Vec<String>,
    /// Rotary axes whose location (the position of their line) drifts with time.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub location_drift: Vec<String>,
    /// The tracker's orientation drifting with time (its stand turning as it warms).
    #[serde(skip_serializing_if = "is_false")]
    pub tracker_drift: bool,
    /// Each station's position drifting with time (machines with `[[station]]` tables).
    #[serde(skip_serializing_if = "is_false")]
    pub station_drift: bool,
    /// Generic displacement fields, by their variables (`X`, `X*Z`, `C*t`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub field: Vec<String>,
    /// Axes with a reversal value (ISO 230-2's B: backlash, lost motion; the tool's deviation
    /// relative to the workpiece along the command, forward approach minus reverse), entering
    /// their positioning error as `σ · s · B / 2` by the point's direction of approach `s`
    /// ([`crate::approach`]) and the axis' side `σ` (−1 for a workpiece-side axis, whose error
    /// moves the workpiece).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub reversal: Vec<ReversalSpec>,
}

/// The highest degree of a reversal function ([`ReversalSpec`]).
pub const MAX_REVERSAL_DEGREE: usize = 3;

/// The reversal of one axis: its letter alone (a constant reversal value B, parameter
/// `reversal.X.b`), or a table `{ axis = "X", degree = d }` for a reversal varying along the
/// axis as ISO 230-2 reports B(x): `B = b + b1·P₁(x̂) + … + bd·P_d(x̂)` (Legendre polynomials of
/// the position normalised over the travel; parameters `reversal.X.b`, `reversal.X.b1` …).
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(untagged)]
pub enum ReversalSpec {
    /// A constant reversal value of the axis of this letter.
    Axis(String),
    /// A reversal function of the axis.
    Function(ReversalFunction),
}

/// A reversal function's table ([`ReversalSpec::Function`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReversalFunction {
    /// The axis' letter.
    pub axis: String,
    /// The degree of B's polynomial (0 … [`MAX_REVERSAL_DEGREE`]).
    pub degree: usize,
}

impl<'de> Deserialize<'de> for ReversalSpec {
    /// An axis letter, or a table with `axis` and `degree`; anything else is refused naming
    /// what a reversal takes (an untagged enum would only say that no variant matched).
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = ReversalSpec;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str(
                    "a reversal: an axis letter (\"X\") or a table { axis = \"X\", degree = 1 }",
                )
            }
            fn visit_str<E: serde::de::Error>(
                self,
                v: &str,
            ) -> std::result::Result<Self::Value, E> {
                Ok(ReversalSpec::Axis(v.to_string()))
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                map: A,
            ) -> std::result::Result<Self::Value, A::Error> {
                let f = ReversalFunction::deserialize(
                    serde::de::value::MapAccessDeserializer::new(map),
                )
                .map_err(|e| {
                    serde::de::Error::custom(format!("a reversal table takes axis and degree: {e}"))
                })?;
                Ok(ReversalSpec::Function(f))
            }
        }
        d.deserialize_any(Visitor)
    }
}

impl ReversalSpec {
    /// The axis' letter.
    pub fn axis(&self) -> &str {
        match self {
            ReversalSpec::Axis(a) => a,
            ReversalSpec::Function(f) => &f.axis,
        }
    }

    /// The degree of B's polynomial (0: constant).
    pub fn degree(&self) -> usize {
        match self {
            ReversalSpec::Axis(_) => 0,
            ReversalSpec::Function(f) => f.degree,
        }
    }
}

/// A variable of a field ([`EffectsSpec::field`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum FieldVar {
    /// The position of chain axis k, normalised over its travel (Legendre P₁, P₂, P₃).
    Linear(usize),
    /// The angle of full-turn rotary chain axis k (cos θ, sin θ, cos 2θ, sin 2θ).
    Periodic(usize),
    /// The time in hours (t, t²).
    Time,
}

impl FieldVar {
    /// How many functions the variable has alone.
    pub(super) fn functions(self) -> usize {
        match self {
            FieldVar::Linear(_) => 3,
            FieldVar::Periodic(_) => 4,
            FieldVar::Time => 2,
        }
    }

    /// The code of its function `q` in parameter names.
    pub(super) fn code(self, q: usize) -> &'static str {
        match self {
            FieldVar::Linear(_) | FieldVar::Time => ["1", "2", "3"][q],
            FieldVar::Periodic(_) => ["c1", "s1", "c2", "s2"][q],
        }
    }
}

pub(super) fn is_false(b: &bool) -> bool {
    !*b
}

impl EffectsSpec {
    /// No effect.
    pub fn is_empty(&self) -> bool {
        *self == EffectsSpec::default()
    }
}

/// One effect value at a point (a slot after the tracker's).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum EffectSlot {
    /// Tool shift component c: value = drift rate × t (h).
    Drift(usize),
    /// Reflector offset component c of reflector r: value = δ when r is measured.
    Reflector { reflector: usize, c: usize },
    /// Range scale: value = s × 1e-6.
    RangeScale,
    /// Positioning error added to chain axis k along `dir`: a·sin φ + b·cos φ.
    Screw {
        k: usize,
        dir: usize,
        period_mm: f64,
        reference: f64,
    },
    /// Scale growth of linear chain axis k (direction `dir`): value = α × 10⁻⁶ × u × t (h).
    ThermalScale { k: usize, dir: usize },
    /// Location drift of chain axis k, component c: value = v × t (h).
    LocationDrift { k: usize, c: usize },
    /// Drift of the tracker's small rotation k (3, 4, 5: rx, ry, rz): value = ω × t (h).
    TrackerDrift(usize),
    /// Drift of station `station`'s position component c: value = v × t (h) at its points,
    /// zero at the other stations'.
    StationDrift { station: usize, c: usize },
    /// Tool shift component c from a field over `vars` (the second unused when not `pair`):
    /// value = Σ_q φ_q coefficient_q.
    Field {
        c: usize,
        vars: [FieldVar; 2],
        pair: bool,
    },
    /// Reversal of chain axis k, added to its positioning error (component `dir`: EXX 0 … ECC
    /// 5): value = s/2 · Σ_{q ≤ degree} b_q P_q(û), s its direction of approach.
    Reversal { k: usize, dir: usize, degree: usize },
}

impl EffectSlot {
    /// What the slot's parameters describe. Exhaustive on purpose: a new effect must say
    /// whether it is the machine's (and whether tables carry it) before anything compiles.
    pub(super) fn role(self) -> super::Role {
        use super::Role;
        match self {
            EffectSlot::Screw { .. } | EffectSlot::Reversal { .. } => Role::Geometry,
            EffectSlot::ThermalScale { .. } | EffectSlot::LocationDrift { .. } => Role::Thermal,
            EffectSlot::Field { vars, pair, .. } => {
                let time = vars[0] == FieldVar::Time || (pair && vars[1] == FieldVar::Time);
                let axis = vars[0] != FieldVar::Time || (pair && vars[1] != FieldVar::Time);
                match (axis, time) {
                    (true, false) => Role::Field,
                    (true, true) => Role::Thermal,
                    (false, _) => Role::Measurement,
                }
            }
            EffectSlot::Drift(_)
            | EffectSlot::Reflector { .. }
            | EffectSlot::RangeScale
            | EffectSlot::TrackerDrift(_)
            | EffectSlot::StationDrift { .. } => Role::Measurement,
        }
    }

    /// The effect's name in outputs (`param`: the name of one of its parameters).
    pub(super) fn label(self, machine: &Machine, param: &str) -> String {
        let axis = |k: usize| machine.axes()[k].axis;
        match self {
            EffectSlot::Drift(_) => "thermal drift of the tool point".to_string(),
            EffectSlot::Reflector { reflector, .. } => {
                format!("offset of reflector {}", machine.reflectors()[reflector].id)
            }
            EffectSlot::RangeScale => "range scale".to_string(),
            EffectSlot::Screw { k, .. } => format!("ball screw of {}", axis(k)),
            EffectSlot::Reversal { k, .. } => format!("reversal of {}", axis(k)),
            EffectSlot::ThermalScale { k, .. } => format!("thermal scale of {}", axis(k)),
            EffectSlot::LocationDrift { k, .. } => format!("location drift of {}", axis(k)),
            EffectSlot::TrackerDrift(_) => "tracker drift".to_string(),
            EffectSlot::StationDrift { station, .. } => {
                format!("drift of station {}", machine.stations()[station].id)
            }
            EffectSlot::Field { .. } => {
                format!("field {}", param.split('.').nth(1).unwrap_or(param))
            }
        }
    }
}

impl ErrorModelSpec {
    /// Parses error-model TOML; `file` names the source in messages.
    pub fn from_toml_str(text: &str, file: &str) -> Result<ErrorModelSpec> {
        let text = crate::error::without_bom(text);
        toml::from_str(text).map_err(|e| from_toml(file, text, e))
    }

    /// Every geometric error of a machine in the paper's bases: the six component errors of each
    /// linear axis as Legendre cubics, those of each rotary axis as first-harmonic Fourier series
    /// (their constant absorbs the rotary location errors), the squareness errors of every linear
    /// axis but the first one in X, Y, Z order, and the tracker translation. For the embedded
    /// XCFZ machine this is the paper's model.
    ///
    /// ```
    /// use volver_core::machine::Machine;
    /// use volver_core::model::{ErrorModelSpec, Model};
    /// let m = Machine::default_xcfz();
    /// let full = Model::new(m, ErrorModelSpec::complete(&Machine::default_xcfz())).unwrap();
    /// assert_eq!(full.n_params(), Model::default_xcfz().n_params());
    /// ```
    pub fn complete(machine: &Machine) -> ErrorModelSpec {
        let names = |axis: Axis| -> Vec<String> {
            ErrorId::components_of(axis)
                .iter()
                .map(ToString::to_string)
                .collect()
        };
        let mut linear = Vec::new();
        let mut rotary = Vec::new();
        for ax in machine.axes() {
            if ax.axis.is_rotary() {
                rotary.extend(names(ax.axis));
            } else {
                linear.extend(names(ax.axis));
            }
        }
        let first_linear = machine
            .axes()
            .iter()
            .map(|a| a.axis)
            .filter(|a| !a.is_rotary())
            .min();
        let squareness: Vec<String> = machine
            .axes()
            .iter()
            .map(|a| a.axis)
            .filter(|&a| !a.is_rotary() && Some(a) != first_linear)
            .flat_map(ErrorId::location_names)
            .collect();
        let entry = |names: Vec<String>, basis, degree, order| ErrorTermSpec {
            name: OneOrMany::Many(names),
            basis,
            degree,
            nodes: None,
            order,
        };
        let mut errors = Vec::new();
        if !linear.is_empty() {
            errors.push(entry(linear, Some(BasisKind::Legendre), Some(3), None));
        }
        if !rotary.is_empty() {
            errors.push(entry(rotary, Some(BasisKind::Fourier), None, Some(1)));
        }
        if !squareness.is_empty() {
            errors.push(entry(squareness, None, None, None));
        }
        ErrorModelSpec {
            name: "complete: cubic linear-axis errors, first-harmonic rotary errors, squareness"
                .to_string(),
            squareness: SquarenessRule::FromStraightness,
            reference_constraint: true,
            errors,
            tracker: TrackerModelSpec {
                identify: TRACKER_NAMES[..3].iter().map(|s| s.to_string()).collect(),
                range_offset: false,
            },
            fixed: BTreeMap::new(),
            effects: EffectsSpec::default(),
        }
    }
}

impl fmt::Display for SquarenessRule {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SquarenessRule::FromStraightness => "from-straightness",
            SquarenessRule::Separate => "separate",
            SquarenessRule::None => "none",
        })
    }
}
