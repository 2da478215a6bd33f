//! Error models (TOML), the parameter layout, linear constraints, and the compiled [`Model`] that
//! evaluates the forward model and its structured Jacobian.
//!
//! ```toml
//! name = "cubic linear errors, first-harmonic rotary errors"
//! squareness = "from-straightness"   # or "separate", "none"
//!
//! [[error]]
//! name = ["EXX", "EYX"]              # one name or a list; letter O accepted for 0
//! basis = "legendre"                 # monomial | legendre | chebyshev | fourier | sine | constant
//! degree = 3                         # polynomials; chebyshev also takes nodes = m
//!
//! [[error]]
//! name = "ECC"
//! basis = "sine"
//! order = 2                          # periodic bases: number of harmonics
//!
//! [[error]]
//! name = ["A0Z", "B0Z", "X0C"]       # location / squareness errors are constants
//!
//! [tracker]
//! identify = ["x", "y", "z"]         # default: all six; the others are fixed
//!
//! [fixed]
//! "EXX.c3" = 0.0                     # any parameter, in its unit (mm, rad)
//! ```
//!
//! Errors not listed are zero. Parameters are named `<error>.<coefficient>` (`EYX.c2`,
//! `EXC.a1`, `ECC.phi1`, `EXX.n3` for the third Chebyshev node), a constant by its error name
//! (`B0Z`), the tracker `tracker.x … tracker.rz`.

use crate::basis::{Basis, BasisKind, MAX_COEFFS};
use crate::chain::MAX_AXES;
use crate::error::{Error, Place, Result, from_toml, line_of_text};
use crate::iso::{Axis, ErrorId, Group, Unit};
use crate::kinematics::{
    ErrorsJacobian, PointErrors, Real, TRACKER_DOF, TRACKER_NAMES, predict,
    predict_with_errors_jacobian, tool_in_workpiece_with_errors_jacobian,
};
use crate::machine::{Commands, Machine};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt;
use std::ops::Range;
use std::path::Path;

mod regressors;
use regressors::PointRegressors;
pub use regressors::Regressors;

/// The paper's error model for the embedded XCFZ machine.
pub const DEFAULT_MODEL_TOML: &str = include_str!("../data/xcfz-paper-model.toml");

/// Label used in messages for the embedded default error model.
pub const DEFAULT_MODEL_LABEL: &str = "<embedded paper error model>";

/// Most error values (modelled errors plus the tracker pose) one point may depend on.
pub const MAX_SLOTS: usize = 72;

/// What the reverse pass of [`Model`]'s exact Jacobian differentiates.
#[derive(Clone, Copy)]
enum JacobianTarget<'a> {
    /// The point a reflector at this offset (frame of the last tool-side axis) is measured at.
    Reflector(&'a [f64; 3]),
    /// The tool point at this offset, in the workpiece frame.
    Tool(&'a [f64; 3]),
}

/// How squareness and straightness share the slope they both describe (paper, section 6.1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
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
    /// Which of x, y, z, rx, ry, rz are identified; the others are fixed at their nominal value.
    pub identify: Vec<String>,
}

impl Default for TrackerModelSpec {
    fn default() -> Self {
        TrackerModelSpec {
            identify: TRACKER_NAMES.iter().map(|s| s.to_string()).collect(),
        }
    }
}

fn default_true() -> bool {
    true
}

fn is_true(b: &bool) -> bool {
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
/// [[effects.ball_screw]]
/// axis = "X"
/// period_mm = 700.0             # screw.X.a, screw.X.b (mm): a·sin φ + b·cos φ, φ = 2π(u − u_ref)/P
/// ```
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
}

fn is_false(b: &bool) -> bool {
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
enum EffectSlot {
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
}

impl ErrorModelSpec {
    /// Parses error-model TOML; `file` names the source in messages.
    pub fn from_toml_str(text: &str, file: &str) -> Result<ErrorModelSpec> {
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
            },
            fixed: BTreeMap::new(),
            effects: EffectsSpec::default(),
        }
    }
}

/// Which error value a parameter feeds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Owner {
    /// Coefficient `coeff` of modelled error `term` (index in [`Model::terms`]).
    Term {
        /// Index of the term.
        term: usize,
        /// Index of the coefficient in the term's basis.
        coeff: usize,
    },
    /// Tracker pose value (0..6: x, y, z, rx, ry, rz).
    Tracker(usize),
    /// An effect outside the ISO 230 model (index of its value slot among the effects).
    Effect(usize),
}

/// One parameter of the layout.
#[derive(Clone, Debug, PartialEq)]
pub struct ParamInfo {
    /// Name, e.g. `EYX.c2`, `B0Z`, `tracker.rx`.
    pub name: String,
    /// Unit of the value.
    pub unit: Unit,
    /// Group for phased strategies.
    pub group: Group,
    /// What it feeds.
    pub owner: Owner,
}

/// Why a constraint exists.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ConstraintKind {
    /// A linear-axis error vanishes at the reference position.
    Reference,
    /// The squareness-from-straightness rule.
    Squareness,
    /// A parameter held at a value.
    Fixed,
    /// A combination of parameters the data cannot identify, held at its value (gauge fixing,
    /// e.g. to compare engines on a well-posed problem).
    Gauge,
}

/// One linear equality `Σ coeffs[j].1 · p[coeffs[j].0] = rhs`.
#[derive(Clone, Debug, PartialEq)]
pub struct Constraint {
    /// Why it exists.
    pub kind: ConstraintKind,
    /// Human-readable statement, e.g. `EYX(X = 0 mm) = 0`.
    pub label: String,
    /// Sparse row: (parameter index, coefficient).
    pub coeffs: Vec<(usize, f64)>,
    /// Right-hand side.
    pub rhs: f64,
}

/// The linear equality constraints `A p = b` of a model.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Constraints {
    /// The rows.
    pub rows: Vec<Constraint>,
}

impl Constraints {
    /// Dense `A` (row-major, `rows × n_params`) and `b`.
    pub fn dense(&self, n_params: usize) -> (Vec<f64>, Vec<f64>) {
        let mut a = vec![0.0; self.rows.len() * n_params];
        for (i, row) in self.rows.iter().enumerate() {
            for &(j, v) in &row.coeffs {
                a[i * n_params + j] += v;
            }
        }
        (a, self.rows.iter().map(|r| r.rhs).collect())
    }

    /// Largest |A p − b| (0 when `p` satisfies every constraint exactly).
    pub fn max_violation(&self, p: &[f64]) -> f64 {
        self.rows
            .iter()
            .map(|r| (r.coeffs.iter().map(|&(j, v)| v * p[j]).sum::<f64>() - r.rhs).abs())
            .fold(0.0, f64::max)
    }
}

/// One modelled error: its ISO name, the chain position of its axis, its basis and parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct Term {
    /// The error.
    pub id: ErrorId,
    /// Chain position of its axis.
    pub axis: usize,
    /// Its basis.
    pub basis: Basis,
    /// Its parameters' indices in the layout.
    pub params: Range<usize>,
}

/// Where one term's value goes in [`PointErrors`], decided when the model is built.
#[derive(Clone, Copy, Debug)]
struct TermPlace {
    /// Chain position of its axis.
    axis: usize,
    /// A location (or squareness) error rather than a component error.
    location: bool,
    /// Its ISO component's index (EX… or X0… order).
    component: usize,
}

/// Most terms in one [`TermGroup`]: the six component errors and six location errors of an axis.
const MAX_GROUP: usize = 12;

/// Consecutive terms of one axis in one basis (EXX … ECX in a cubic, EXC … ECC in one harmonic),
/// with their coefficients consecutive in the layout: the basis' values at a point are computed
/// once and every term's value is their dot product with its coefficients. A basis that is not
/// linear in its coefficients (the sine series) makes a group of one.
#[derive(Clone, Debug)]
struct TermGroup {
    /// The terms' indices.
    terms: Range<usize>,
    /// Coefficients per term.
    len: usize,
    /// The first term's first parameter; term `terms.start + i` starts at `params + i·len`.
    params: usize,
}

/// A machine plus an error model, compiled: parameter layout, constraints, evaluation.
///
/// ```
/// use volver_core::model::Model;
/// let model = Model::default_xcfz();
/// assert_eq!(model.n_params(), 74);
/// assert_eq!(model.constraints().rows.len(), 12 + 2 + 3); // reference, squareness, tracker angles
/// let p = model.initial_params();
/// let cmd = model.machine().commands_from_file_units(&[0.0, 0.0, 0.0]);
/// let x = model.predict(&cmd, 0, &p);
/// assert_eq!(x, [950.0, 75.0, 1450.0]); // Z offset + reflector R1
/// ```
#[derive(Clone, Debug)]
pub struct Model {
    machine: Machine,
    spec: ErrorModelSpec,
    terms: Vec<Term>,
    params: Vec<ParamInfo>,
    /// Error-value slot of each parameter: term index, or terms.len() + tracker index.
    slot_of: Vec<usize>,
    /// Per term: where its value goes.
    places: Vec<TermPlace>,
    /// The terms in groups that share their basis' values at a point.
    groups: Vec<TermGroup>,
    tracker_start: usize,
    has_location: [bool; MAX_AXES],
    constraints: Constraints,
    initial: Vec<f64>,
    /// Effect slots (after the tracker's) and the index of their first parameter.
    effects: Vec<(EffectSlot, usize)>,
}

impl Model {
    /// The embedded XCFZ machine with the paper's error model.
    pub fn default_xcfz() -> Model {
        let spec = ErrorModelSpec::from_toml_str(DEFAULT_MODEL_TOML, DEFAULT_MODEL_LABEL)
            .expect("embedded model parses");
        Model::new(Machine::default_xcfz(), spec).expect("embedded model is valid")
    }

    /// Reads an error-model file and compiles it for `machine`.
    pub fn load(machine: Machine, path: &Path) -> Result<Model> {
        let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Model::from_toml_str(machine, &text, &path.display().to_string())
    }

    /// Parses error-model TOML and compiles it for `machine`; `file` names it in messages.
    pub fn from_toml_str(machine: Machine, text: &str, file: &str) -> Result<Model> {
        let spec = ErrorModelSpec::from_toml_str(text, file)?;
        Model::build(machine, spec, file, Some(text))
    }

    /// Compiles an error-model specification (e.g. one read back from a results file).
    pub fn new(machine: Machine, spec: ErrorModelSpec) -> Result<Model> {
        Model::build(machine, spec, "error model", None)
    }

    fn build(
        machine: Machine,
        spec: ErrorModelSpec,
        file: &str,
        source: Option<&str>,
    ) -> Result<Model> {
        let place = |needle: &str, field: &str| {
            let mut p = Place::file(file).at_field(field);
            if let Some(line) = source.and_then(|s| line_of_text(s, needle)) {
                p = p.at_line(line);
            }
            p
        };
        let mut terms: Vec<Term> = Vec::new();
        let mut params: Vec<ParamInfo> = Vec::new();
        for entry in &spec.errors {
            for raw in entry.name.names() {
                let bad = |m: String| Error::input(place(raw, "error.name"), m);
                let id: ErrorId = raw.parse().map_err(bad)?;
                let Some((axis, ax)) = machine.axis(id.axis()) else {
                    return Err(bad(format!(
                        "{id} belongs to axis {}, which the machine's chain {} does not have",
                        id.axis(),
                        machine.chain()
                    )));
                };
                if terms.iter().any(|t| t.id == id) {
                    return Err(bad(format!("{id} is listed twice")));
                }
                let basis = term_basis(id, ax.axis.is_rotary(), entry).map_err(bad)?;
                let start = params.len();
                let suffixes = basis.suffixes();
                for (c, suffix) in suffixes.iter().enumerate() {
                    let name = if suffix.is_empty() {
                        id.to_string()
                    } else {
                        format!("{id}.{suffix}")
                    };
                    let unit = if basis.is_phase(c) {
                        Unit::Rad
                    } else {
                        id.unit()
                    };
                    params.push(ParamInfo {
                        name,
                        unit,
                        group: id.group(),
                        owner: Owner::Term {
                            term: terms.len(),
                            coeff: c,
                        },
                    });
                }
                terms.push(Term {
                    id,
                    axis,
                    basis,
                    params: start..params.len(),
                });
            }
        }
        if terms.len() + TRACKER_DOF > MAX_SLOTS {
            return Err(Error::Model(format!(
                "{} errors are modelled; at most {} fit beside the tracker pose",
                terms.len(),
                MAX_SLOTS - TRACKER_DOF
            )));
        }
        let tracker_start = params.len();
        for (k, n) in TRACKER_NAMES.iter().enumerate() {
            params.push(ParamInfo {
                name: format!("tracker.{n}"),
                unit: if k < 3 { Unit::Mm } else { Unit::Rad },
                group: Group::Tracker,
                owner: Owner::Tracker(k),
            });
        }
        let mut effects: Vec<(EffectSlot, usize)> = Vec::new();
        {
            let fx = &spec.effects;
            let mut push =
                |slot: EffectSlot, names: &[(String, Unit)], params: &mut Vec<ParamInfo>| {
                    let k = effects.len();
                    effects.push((slot, params.len()));
                    for (name, unit) in names {
                        params.push(ParamInfo {
                            name: name.clone(),
                            unit: *unit,
                            group: Group::Other,
                            owner: Owner::Effect(k),
                        });
                    }
                };
            if fx.thermal_drift {
                for (c, x) in ["x", "y", "z"].iter().enumerate() {
                    push(
                        EffectSlot::Drift(c),
                        &[(format!("drift.{x}"), Unit::MmPerHour)],
                        &mut params,
                    );
                }
            }
            for id in &fx.reflector_offset {
                let Some(r) = machine.reflector_index(id) else {
                    return Err(Error::input(
                        place(id, "effects.reflector_offset"),
                        format!("no reflector '{id}' in the machine"),
                    ));
                };
                for (c, x) in ["x", "y", "z"].iter().enumerate() {
                    push(
                        EffectSlot::Reflector { reflector: r, c },
                        &[(format!("reflector.{id}.{x}"), Unit::Mm)],
                        &mut params,
                    );
                }
            }
            if fx.range_scale {
                push(
                    EffectSlot::RangeScale,
                    &[("range.scale".to_string(), Unit::Ppm)],
                    &mut params,
                );
            }
            for b in &fx.ball_screw {
                let axis = b
                    .axis
                    .chars()
                    .next()
                    .filter(|_| b.axis.len() == 1)
                    .and_then(crate::iso::Axis::from_letter);
                let Some((k, ax)) = axis
                    .and_then(|a| machine.axis(a))
                    .filter(|(_, ax)| !ax.axis.is_rotary())
                else {
                    return Err(Error::input(
                        place(&b.axis, "effects.ball_screw.axis"),
                        format!("'{}' is not a linear axis of {}", b.axis, machine.chain()),
                    ));
                };
                if !(b.period_mm.is_finite() && b.period_mm > 0.0) {
                    return Err(Error::input(
                        place(&b.axis, "effects.ball_screw.period_mm"),
                        format!("the period {} mm must be positive", b.period_mm),
                    ));
                }
                push(
                    EffectSlot::Screw {
                        k,
                        dir: ax.axis.direction(),
                        period_mm: b.period_mm,
                        reference: ax.reference,
                    },
                    &[
                        (format!("screw.{}.a", b.axis), Unit::Mm),
                        (format!("screw.{}.b", b.axis), Unit::Mm),
                    ],
                    &mut params,
                );
            }
        }
        if terms.len() + TRACKER_DOF + effects.len() > MAX_SLOTS {
            return Err(Error::Model(format!(
                "{} errors and {} effect values are modelled; at most {} fit beside the tracker pose",
                terms.len(),
                effects.len(),
                MAX_SLOTS - TRACKER_DOF
            )));
        }
        let slot_of = params
            .iter()
            .map(|p| match p.owner {
                Owner::Term { term, .. } => term,
                Owner::Tracker(k) => terms.len() + k,
                Owner::Effect(k) => terms.len() + TRACKER_DOF + k,
            })
            .collect();
        let mut has_location = [false; MAX_AXES];
        for t in &terms {
            if matches!(t.id, ErrorId::Location { .. }) {
                has_location[t.axis] = true;
            }
        }
        let mut initial = vec![0.0; params.len()];
        initial[tracker_start..tracker_start + 3].copy_from_slice(&machine.tracker().position);

        // Constraints.
        let mut rows = Vec::new();
        if spec.reference_constraint {
            for t in &terms {
                let ax = &machine.axes()[t.axis];
                if ax.axis.is_rotary() || !matches!(t.id, ErrorId::Component { .. }) {
                    continue;
                }
                let n = t.basis.n_params();
                let mut g = [0.0; MAX_COEFFS];
                t.basis.eval(
                    ax.normalise(ax.reference),
                    &[0.0; MAX_COEFFS][..n],
                    &mut g[..n],
                );
                rows.push(Constraint {
                    kind: ConstraintKind::Reference,
                    label: format!(
                        "{}({} = {} {}) = 0",
                        t.id,
                        ax.axis,
                        ax.to_file_units(ax.reference),
                        ax.file_unit()
                    ),
                    coeffs: t
                        .params
                        .clone()
                        .zip(g[..n].iter().copied())
                        .filter(|(_, v)| *v != 0.0)
                        .collect(),
                    rhs: 0.0,
                });
            }
        }
        if spec.squareness != SquarenessRule::None {
            for t in terms.iter().filter(|t| t.id.is_squareness()) {
                let partner = t.id.squareness_partner().expect("squareness has a partner");
                let Some(p) = terms.iter().find(|q| q.id == partner) else {
                    continue;
                };
                if p.basis.kind().is_periodic()
                    || p.basis.kind() == BasisKind::Constant
                    || p.basis.degree() == 0
                {
                    continue;
                }
                rows.push(match spec.squareness {
                    SquarenessRule::FromStraightness => Constraint {
                        kind: ConstraintKind::Squareness,
                        label: format!("{} = 0 (taken from the slope of {partner})", t.id),
                        coeffs: vec![(t.params.start, 1.0)],
                        rhs: 0.0,
                    },
                    _ => Constraint {
                        kind: ConstraintKind::Squareness,
                        label: format!("slope of {partner} = 0 (carried by {})", t.id),
                        coeffs: p
                            .params
                            .clone()
                            .zip(p.basis.linear_component())
                            .filter(|(_, v)| v.abs() > 1e-14)
                            .collect(),
                        rhs: 0.0,
                    },
                });
            }
        }
        let mut fixed: BTreeMap<usize, (f64, String)> = BTreeMap::new();
        for name in &spec.tracker.identify {
            if !TRACKER_NAMES.contains(&name.as_str()) {
                return Err(Error::input(
                    place(name, "tracker.identify"),
                    format!(
                        "'{name}' is not a tracker pose value; expected some of x, y, z, rx, ry, rz"
                    ),
                ));
            }
        }
        for (k, n) in TRACKER_NAMES.iter().enumerate() {
            if !spec.tracker.identify.iter().any(|s| s == n) {
                let j = tracker_start + k;
                fixed.insert(
                    j,
                    (initial[j], format!("tracker.{n} held at its nominal value")),
                );
            }
        }
        for (name, &value) in &spec.fixed {
            let Some(j) = params.iter().position(|p| &p.name == name) else {
                return Err(Error::input(
                    place(name, &format!("fixed.{name}")),
                    format!(
                        "there is no parameter '{name}' in this model (names look like EYX.c2, ECC.a1, B0Z, tracker.rx)"
                    ),
                ));
            };
            if !value.is_finite() {
                return Err(Error::input(
                    place(name, &format!("fixed.{name}")),
                    "a fixed value must be a finite number",
                ));
            }
            fixed.insert(j, (value, format!("{name} fixed")));
        }
        for (j, (value, label)) in fixed {
            initial[j] = value;
            rows.push(Constraint {
                kind: ConstraintKind::Fixed,
                label: format!("{label} = {value} {}", params[j].unit),
                coeffs: vec![(j, 1.0)],
                rhs: value,
            });
        }
        let places = terms
            .iter()
            .map(|t| TermPlace {
                axis: t.axis,
                location: matches!(t.id, ErrorId::Location { .. }),
                component: t.id.component().index(),
            })
            .collect();
        let groups = term_groups(&terms);
        Ok(Model {
            machine,
            spec,
            terms,
            params,
            slot_of,
            places,
            groups,
            tracker_start,
            has_location,
            constraints: Constraints { rows },
            initial,
            effects,
        })
    }

    /// The machine.
    pub fn machine(&self) -> &Machine {
        &self.machine
    }

    /// The error-model specification (what files store).
    pub fn spec(&self) -> &ErrorModelSpec {
        &self.spec
    }

    /// The modelled errors, in layout order.
    pub fn terms(&self) -> &[Term] {
        &self.terms
    }

    /// The parameter layout.
    pub fn params(&self) -> &[ParamInfo] {
        &self.params
    }

    /// Number of parameters.
    pub fn n_params(&self) -> usize {
        self.params.len()
    }

    /// Index of a parameter by name.
    pub fn param_index(&self, name: &str) -> Option<usize> {
        self.params.iter().position(|p| p.name == name)
    }

    /// Index of the first tracker parameter (`tracker.x`).
    pub fn tracker_start(&self) -> usize {
        self.tracker_start
    }

    /// The linear equality constraints.
    pub fn constraints(&self) -> &Constraints {
        &self.constraints
    }

    /// Starting parameters: every error zero, the tracker at its nominal pose, fixed parameters
    /// at their values. They satisfy every constraint.
    pub fn initial_params(&self) -> Vec<f64> {
        self.initial.clone()
    }

    /// Which of the six component errors of chain axis `k` (EX, EY, EZ, EA, EB, EC of that axis)
    /// the model describes: a modelled term, or a ball-screw effect on it.
    pub fn modelled_components(&self, k: usize) -> [bool; 6] {
        let mut out = [false; 6];
        for t in self.terms.iter().filter(|t| t.axis == k) {
            if let ErrorId::Component { component, .. } = t.id {
                out[component.index()] = true;
            }
        }
        for (slot, _) in &self.effects {
            if let EffectSlot::Screw { k: a, dir, .. } = *slot
                && a == k
            {
                out[dir] = true;
            }
        }
        out
    }

    /// The modelled error with a given ISO name.
    pub fn term(&self, id: ErrorId) -> Option<&Term> {
        self.terms.iter().find(|t| t.id == id)
    }

    /// Argument of a term's basis for a command: the angle (rad) for periodic bases, otherwise
    /// the position normalised to [−1, 1] over the axis range.
    #[inline]
    fn argument(&self, t: &Term, commands: &Commands) -> f64 {
        self.argument_at(t, &commands.0)
    }

    /// [`Model::argument`] for commands of any scalar.
    #[inline]
    fn argument_at<S: Real>(&self, t: &Term, commands: &[S; MAX_AXES]) -> S {
        let u = commands[t.axis];
        if t.basis.kind().is_periodic() {
            u
        } else {
            self.machine.axes()[t.axis].normalise_at(u)
        }
    }

    /// Value of a modelled error at an axis position (internal units: mm or rad), in mm or rad.
    pub fn error_value(&self, id: ErrorId, position: f64, params: &[f64]) -> Option<f64> {
        let t = self.term(id)?;
        let mut cmd = Commands::default();
        cmd.0[t.axis] = position;
        Some(
            t.basis
                .value(self.argument(t, &cmd), &params[t.params.clone()]),
        )
    }

    /// [`Model::error_value`] and its exact gradient with respect to the error's own
    /// coefficients (written to `grad`, one value per coefficient of the term, in the order of
    /// [`Term::params`]). The sine series' phases get their derivative at `params`.
    ///
    /// # Panics
    /// When `grad` is shorter than the term's coefficients.
    pub fn error_value_gradient(
        &self,
        id: ErrorId,
        position: f64,
        params: &[f64],
        grad: &mut [f64],
    ) -> Option<f64> {
        let t = self.term(id)?;
        let mut cmd = Commands::default();
        cmd.0[t.axis] = position;
        let k = t.params.len();
        Some(t.basis.eval(
            self.argument(t, &cmd),
            &params[t.params.clone()],
            &mut grad[..k],
        ))
    }

    /// The values of a group's terms at `commands` into `vals[..n]` (n terms), the basis'
    /// values (its derivatives with respect to the first term's coefficients) into `g`.
    #[inline]
    fn group_values<S: Real>(
        &self,
        grp: &TermGroup,
        commands: &[S; MAX_AXES],
        params: &[f64],
        g: &mut [S; MAX_COEFFS],
        vals: &mut [S],
    ) {
        let (len, n) = (grp.len, grp.terms.len());
        let x = self.argument_at(&self.terms[grp.terms.start], commands);
        let first = &params[grp.params..grp.params + len];
        vals[0] = self.terms[grp.terms.start]
            .basis
            .eval_at(x, first, &mut g[..len]);
        let block = &params[grp.params + len..grp.params + n * len];
        dots(&g[..len], block, &mut vals[1..n], |v| v);
    }

    /// [`Model::group_values`] from the basis' values `values` at the point ([`Regressors`]),
    /// with the same arithmetic (each value a dot product from zero, in coefficient order), so
    /// the same bits.
    #[inline]
    fn group_values_cached<S: Real>(
        &self,
        grp: &TermGroup,
        params: &[f64],
        values: &[f64],
        vals: &mut [S],
    ) {
        let block = &params[grp.params..grp.params + grp.terms.len() * grp.len];
        dots(values, block, vals, S::from);
    }

    fn check_len(&self, params: &[f64]) {
        assert_eq!(
            params.len(),
            self.params.len(),
            "parameter vector has the wrong length"
        );
    }

    /// Places error values (one per slot: terms, then the tracker pose) into [`PointErrors`].
    #[inline]
    fn point_errors<S: Real>(&self, value: impl Fn(usize) -> S) -> PointErrors<S> {
        let mut e = PointErrors::zero();
        e.has_location = self.has_location;
        for (i, t) in self.terms.iter().enumerate() {
            let c = t.id.component().index();
            match t.id {
                ErrorId::Component { .. } => e.component[t.axis][c] = value(i),
                ErrorId::Location { .. } => e.location[t.axis][c] = value(i),
            }
        }
        for k in 0..TRACKER_DOF {
            e.tracker[k] = value(self.terms.len() + k);
        }
        let base = self.terms.len() + TRACKER_DOF;
        self.place_effects(&mut e, |i| value(base + i));
        e
    }

    /// Places the effects' values (`value(i)` for the i-th effect) into [`PointErrors`].
    #[inline]
    fn place_effects<S: Real>(&self, e: &mut PointErrors<S>, value: impl Fn(usize) -> S) {
        for (i, (slot, _)) in self.effects.iter().enumerate() {
            let v = value(i);
            match *slot {
                EffectSlot::Drift(c) => e.tool_shift[c] = v,
                EffectSlot::Reflector { c, .. } => e.reflector_delta[c] += v,
                EffectSlot::RangeScale => e.range_scale = v,
                EffectSlot::Screw { k, dir, .. } => e.component[k][dir] += v,
            }
        }
    }

    /// Whether the model needs the measurements' time stamps (thermal drift).
    pub fn needs_time(&self) -> bool {
        self.spec.effects.thermal_drift
    }

    /// Effect values at a point into `vals` (slots after the tracker's) and, when `jac` is
    /// given, each effect parameter's ∂value/∂p into `jac[parameter]`.
    fn effect_values<S: Real>(
        &self,
        commands: &[S; MAX_AXES],
        reflector: usize,
        t_s: f64,
        params: &[f64],
        vals: &mut [S],
        mut jac: Option<&mut [f64]>,
    ) {
        let base = self.terms.len() + TRACKER_DOF;
        for (i, &(slot, j)) in self.effects.iter().enumerate() {
            let mut set = |p: usize, g: f64| {
                if let Some(jac) = jac.as_deref_mut() {
                    jac[p] = g;
                }
            };
            vals[base + i] = match slot {
                EffectSlot::Drift(_) => {
                    let t_h = t_s / 3600.0;
                    set(j, t_h);
                    S::from(params[j] * t_h)
                }
                EffectSlot::Reflector { reflector: r, .. } => {
                    let on = if r == reflector { 1.0 } else { 0.0 };
                    set(j, on);
                    S::from(params[j] * on)
                }
                EffectSlot::RangeScale => {
                    set(j, 1e-6);
                    S::from(params[j] * 1e-6)
                }
                EffectSlot::Screw {
                    k,
                    period_mm,
                    reference,
                    ..
                } => {
                    let phase =
                        (commands[k] - reference) * (2.0 * std::f64::consts::PI) / period_mm;
                    let (sn, cs) = phase.sin_cos();
                    set(j, sn.re());
                    set(j + 1, cs.re());
                    sn * params[j] + cs * params[j + 1]
                }
            };
        }
    }

    /// Predicted reflector position in the tracker frame (mm) for `commands` (chain order,
    /// internal units) and reflector index.
    ///
    /// # Panics
    /// When `params.len() != n_params()` or the reflector index is out of range: both are
    /// programming errors (input files are validated when they are read).
    pub fn predict(&self, commands: &Commands, reflector: usize, params: &[f64]) -> [f64; 3] {
        self.predict_at(commands, reflector, 0.0, params)
    }

    /// [`Model::predict`] at time `t_s` (s since the test started), for models with thermal
    /// drift.
    ///
    /// # Panics
    /// As [`Model::predict`].
    pub fn predict_at(
        &self,
        commands: &Commands,
        reflector: usize,
        t_s: f64,
        params: &[f64],
    ) -> [f64; 3] {
        self.predict_with(commands, reflector, t_s, params, None)
    }

    /// [`Model::predict_at`] with the point's [`Regressors`] when the caller has them.
    fn predict_with(
        &self,
        commands: &Commands,
        reflector: usize,
        t_s: f64,
        params: &[f64],
        cached: Option<PointRegressors<'_>>,
    ) -> [f64; 3] {
        let e = self.errors_with(&commands.0, reflector, t_s, params, cached);
        predict(
            &self.machine,
            commands,
            &self.machine.reflectors()[reflector].offset,
            &e,
        )
    }

    /// The value of every modelled error at `commands` and the tracker pose, laid out for
    /// [`crate::kinematics::predict`] (errors the model leaves out are zero). The synthetic
    /// generator adds effects outside the model to these values.
    ///
    /// # Panics
    /// When `params.len() != n_params()`.
    pub fn errors_at(&self, commands: &Commands, params: &[f64]) -> PointErrors<f64> {
        self.errors_at_point(commands, usize::MAX, 0.0, params)
    }

    /// [`Model::errors_at`] for a measured point: with the effects that depend on the reflector
    /// and on the time stamp `t_s` (s).
    ///
    /// # Panics
    /// When `params.len() != n_params()`.
    pub fn errors_at_point(
        &self,
        commands: &Commands,
        reflector: usize,
        t_s: f64,
        params: &[f64],
    ) -> PointErrors<f64> {
        self.errors_with_commands(&commands.0, reflector, t_s, params)
    }

    /// [`Model::errors_at_point`] with commands of any scalar: with dual numbers over the
    /// commands, every error value carries its exact derivative along them (for the inverse
    /// model, [`crate::compensate`]).
    ///
    /// # Panics
    /// When `params.len() != n_params()`.
    pub fn errors_with_commands<S: Real>(
        &self,
        commands: &[S; MAX_AXES],
        reflector: usize,
        t_s: f64,
        params: &[f64],
    ) -> PointErrors<S> {
        self.errors_with(commands, reflector, t_s, params, None)
    }

    /// [`Model::errors_with_commands`], with the point's [`Regressors`] when the caller has
    /// them (`f64` only in practice: the cached values carry no derivative along the commands).
    fn errors_with<S: Real>(
        &self,
        commands: &[S; MAX_AXES],
        reflector: usize,
        t_s: f64,
        params: &[f64],
        cached: Option<PointRegressors<'_>>,
    ) -> PointErrors<S> {
        self.check_len(params);
        let mut e = PointErrors::zero();
        e.has_location = self.has_location;
        e.rotary_sin_cos = cached.map(|c| c.sin_cos);
        let mut g = [S::zero(); MAX_COEFFS];
        let mut v = [S::zero(); MAX_GROUP];
        let mut at = 0;
        for grp in &self.groups {
            match cached.and_then(|c| c.group(grp, &self.terms, &mut at)) {
                Some(values) => self.group_values_cached(grp, params, values, &mut v),
                None => self.group_values(grp, commands, params, &mut g, &mut v),
            }
            for (i, v) in grp.terms.clone().zip(v) {
                let place = self.places[i];
                if place.location {
                    e.location[place.axis][place.component] = v;
                } else {
                    e.component[place.axis][place.component] = v;
                }
            }
        }
        for (k, v) in params[self.tracker_start..self.tracker_start + TRACKER_DOF]
            .iter()
            .enumerate()
        {
            e.tracker[k] = S::from(*v);
        }
        if !self.effects.is_empty() {
            let mut vals = [S::zero(); MAX_SLOTS];
            self.effect_values(commands, reflector, t_s, params, &mut vals, None);
            let base = self.terms.len() + TRACKER_DOF;
            self.place_effects(&mut e, |i| vals[base + i]);
        }
        e
    }

    /// Where the tool point `tool` (mm, in the frame of the last tool-side axis) sits relative
    /// to the workpiece at `commands` (any scalar, internal units) with the errors of `params`:
    /// [`crate::kinematics::tool_in_workpiece`] with the model's error values at those commands.
    /// Effects that belong to the measurement (tracker pose, reflector offsets, range scale,
    /// thermal drift over the test's time) are left out; ball-screw errors stay.
    ///
    /// # Panics
    /// When `params.len() != n_params()`.
    pub fn tool_point<S: Real>(
        &self,
        commands: &[S; MAX_AXES],
        tool: &[f64; 3],
        params: &[f64],
    ) -> [S; 3] {
        let mut e = self.errors_with_commands(commands, usize::MAX, 0.0, params);
        e.tool_shift = [S::zero(); 3];
        e.reflector_delta = [S::zero(); 3];
        e.range_scale = S::zero();
        crate::kinematics::tool_in_workpiece(&self.machine, commands, tool, &e)
    }

    /// [`Model::tool_point`] and its exact Jacobian with respect to every parameter, written to
    /// `jac` (row-major 3 × n_params): the chain's derivative with respect to the error values at
    /// the commands, then the bases' derivatives, as [`Model::predict_with_jacobian`]. The measurement's
    /// parameters (tracker pose, reflector offsets, range scale, drift) get zero columns.
    ///
    /// # Panics
    /// When `params.len() != n_params()` or `jac.len() != 3 * n_params()`.
    pub fn tool_point_with_jacobian(
        &self,
        commands: &Commands,
        tool: &[f64; 3],
        params: &[f64],
        jac: &mut [f64],
    ) -> [f64; 3] {
        self.point_with_jacobian(
            commands,
            JacobianTarget::Tool(tool),
            usize::MAX,
            0.0,
            params,
            None,
            jac,
        )
    }

    /// Predicted point and its exact Jacobian with respect to every parameter, written to `jac`
    /// (row-major 3 × n_params: row c holds ∂x_c/∂p).
    ///
    /// The chain is differentiated with respect to the few error *values* at the point (one per
    /// modelled error, plus the tracker pose) by its hand-derived reverse pass
    /// ([`crate::kinematics::predict_with_errors_jacobian`], tested against forward-mode dual
    /// numbers), then multiplied by each basis' derivative with respect to its coefficients (the
    /// basis values; for the sine series also the derivative with respect to the phases). No
    /// finite differences.
    ///
    /// # Panics
    /// As [`Model::predict`], and when `jac.len() != 3 * n_params()`.
    pub fn predict_with_jacobian(
        &self,
        commands: &Commands,
        reflector: usize,
        params: &[f64],
        jac: &mut [f64],
    ) -> [f64; 3] {
        self.predict_with_jacobian_at(commands, reflector, 0.0, params, jac)
    }

    /// [`Model::predict_with_jacobian`] at time `t_s` (s).
    ///
    /// # Panics
    /// As [`Model::predict_with_jacobian`].
    pub fn predict_with_jacobian_at(
        &self,
        commands: &Commands,
        reflector: usize,
        t_s: f64,
        params: &[f64],
        jac: &mut [f64],
    ) -> [f64; 3] {
        self.reflector_with_jacobian(commands, reflector, t_s, params, None, jac)
    }

    /// [`Model::predict_with_jacobian_at`] with the point's [`Regressors`] when the caller has
    /// them.
    fn reflector_with_jacobian(
        &self,
        commands: &Commands,
        reflector: usize,
        t_s: f64,
        params: &[f64],
        cached: Option<PointRegressors<'_>>,
        jac: &mut [f64],
    ) -> [f64; 3] {
        let refl = &self.machine.reflectors()[reflector].offset;
        self.point_with_jacobian(
            commands,
            JacobianTarget::Reflector(refl),
            reflector,
            t_s,
            params,
            cached,
            jac,
        )
    }

    /// The exact Jacobian shared by [`Model::predict_with_jacobian_at`] and
    /// [`Model::tool_point_with_jacobian`]: the error values and their bases' derivatives, the
    /// chain's reverse pass over the values for `target`, then the chain rule.
    #[allow(clippy::too_many_arguments)]
    fn point_with_jacobian(
        &self,
        commands: &Commands,
        target: JacobianTarget,
        reflector: usize,
        t_s: f64,
        params: &[f64],
        cached: Option<PointRegressors<'_>>,
        jac: &mut [f64],
    ) -> [f64; 3] {
        self.check_len(params);
        let n = self.params.len();
        assert_eq!(
            jac.len(),
            3 * n,
            "Jacobian buffer must hold 3 × n_params values"
        );
        // Row 0 first holds ∂value(slot)/∂p_j for each parameter: a term's basis values.
        let mut vals = [0.0; MAX_SLOTS];
        let mut g = [0.0; MAX_COEFFS];
        let mut at = 0;
        for grp in &self.groups {
            let out = &mut vals[grp.terms.clone()];
            let block = &mut jac[grp.params..grp.params + grp.terms.len() * grp.len];
            match cached.and_then(|c| c.group(grp, &self.terms, &mut at)) {
                Some(values) => {
                    self.group_values_cached(grp, params, values, out);
                    spread(values, block);
                }
                None => {
                    self.group_values(grp, &commands.0, params, &mut g, out);
                    spread(&g[..grp.len], block);
                }
            }
        }
        let m = self.terms.len() + TRACKER_DOF;
        vals[self.terms.len()..m]
            .copy_from_slice(&params[self.tracker_start..self.tracker_start + TRACKER_DOF]);
        jac[self.tracker_start..self.tracker_start + TRACKER_DOF].fill(1.0);
        let m = m + self.effects.len();
        self.effect_values(&commands.0, reflector, t_s, params, &mut vals, Some(jac));
        let mut e = self.point_errors(|i| vals[i]);
        e.rotary_sin_cos = cached.map(|c| c.sin_cos);
        let (point, de) = match target {
            JacobianTarget::Reflector(refl) => {
                predict_with_errors_jacobian(&self.machine, commands, refl, &e)
            }
            JacobianTarget::Tool(tool) => {
                tool_in_workpiece_with_errors_jacobian(&self.machine, commands, tool, &e)
            }
        };
        let g = self.slot_columns(&de, m);
        let (r0, rest) = jac.split_at_mut(n);
        let (r1, r2) = rest.split_at_mut(n);
        for j in 0..n {
            let s = self.slot_of[j];
            let d = r0[j];
            r0[j] = g[0][s] * d;
            r1[j] = g[1][s] * d;
            r2[j] = g[2][s] * d;
        }
        point
    }

    /// Second derivative of the predicted point along the parameter direction `dir`:
    /// `d²/dt² x(params + t·dir)` at t = 0 (mm per unit of t², the direction in the parameters'
    /// units). Exact: each error value and its first and second derivatives along `dir` (the
    /// basis values, and the sine series' curvature in amplitude and phase) enter the chain as
    /// second-order dual numbers. The curvature term of geodesic acceleration.
    ///
    /// # Panics
    /// As [`Model::predict`], and when `dir.len() != n_params()`.
    pub fn predict_second_directional_at(
        &self,
        commands: &Commands,
        reflector: usize,
        t_s: f64,
        params: &[f64],
        dir: &[f64],
    ) -> [f64; 3] {
        self.check_len(params);
        self.check_len(dir);
        let mut vals = [0.0; MAX_SLOTS];
        let mut d1 = [0.0; MAX_SLOTS];
        let mut d2 = [0.0; MAX_SLOTS];
        let mut grad = [0.0; MAX_COEFFS];
        for (i, t) in self.terms.iter().enumerate() {
            let r = t.params.clone();
            let x = self.argument(t, commands);
            let g = &mut grad[..r.len()];
            vals[i] = t.basis.eval(x, &params[r.clone()], g);
            d1[i] = g.iter().zip(&dir[r.clone()]).map(|(a, b)| a * b).sum();
            d2[i] = t.basis.second_directional(x, &params[r.clone()], &dir[r]);
        }
        let k = self.terms.len();
        let ts = self.tracker_start;
        vals[k..k + TRACKER_DOF].copy_from_slice(&params[ts..ts + TRACKER_DOF]);
        d1[k..k + TRACKER_DOF].copy_from_slice(&dir[ts..ts + TRACKER_DOF]);
        // Effects are linear in their parameters: their derivative along dir is their value
        // at dir, and their second derivative is zero.
        self.effect_values(&commands.0, reflector, t_s, params, &mut vals, None);
        self.effect_values(&commands.0, reflector, t_s, dir, &mut d1, None);
        let e = self.point_errors(|i| num_dual::Dual2_64::new(vals[i], d1[i], d2[i]));
        let refl = &self.machine.reflectors()[reflector].offset;
        let x = predict(&self.machine, commands, refl, &e);
        [x[0].v2, x[1].v2, x[2].v2]
    }

    /// ∂point/∂(error value) of every slot (terms, tracker, effects: the first `m`), by rows,
    /// from the derivative with respect to the fields of [`PointErrors`] (the placement of
    /// [`Model::point_errors`]).
    #[inline]
    fn slot_columns(&self, de: &ErrorsJacobian, m: usize) -> [[f64; MAX_SLOTS]; 3] {
        let mut g = [[0.0; MAX_SLOTS]; 3];
        let mut put = |s: usize, col: [f64; 3]| {
            for c in 0..3 {
                g[c][s] = col[c];
            }
        };
        for (i, t) in self.terms.iter().enumerate() {
            let c = t.id.component().index();
            put(
                i,
                match t.id {
                    ErrorId::Component { .. } => de.component[t.axis][c],
                    ErrorId::Location { .. } => de.location[t.axis][c],
                },
            );
        }
        let base = self.terms.len();
        for k in 0..TRACKER_DOF {
            put(base + k, de.tracker[k]);
        }
        let base = base + TRACKER_DOF;
        for (i, (slot, _)) in self.effects.iter().enumerate() {
            put(
                base + i,
                match *slot {
                    EffectSlot::Drift(c) => de.tool_shift[c],
                    EffectSlot::Reflector { c, .. } => de.reflector_delta[c],
                    EffectSlot::RangeScale => de.range_scale,
                    EffectSlot::Screw { k, dir, .. } => de.component[k][dir],
                },
            );
        }
        debug_assert_eq!(base + self.effects.len(), m);
        g
    }

    /// The size of each effect outside ISO 230 (the parameters of group "other", grouped by
    /// their name without its last part: `drift.x/y/z`, `screw.X.200.a/b`,
    /// `reflector.R1.x/y/z`, `range.scale`): the norm of its parameters, in the unit volver
    /// prints ([`Unit::micro`]: µm, µm/h, ppm, µrad), with that unit and the parameters' own.
    /// Only parameters for which `keep` is true count.
    pub fn effect_sizes(
        &self,
        params: &[f64],
        keep: impl Fn(usize) -> bool,
    ) -> Vec<(String, f64, &'static str, Unit)> {
        let mut groups: Vec<(String, f64, &'static str, Unit)> = Vec::new();
        for (j, info) in self.params.iter().enumerate() {
            if info.group != Group::Other || !keep(j) {
                continue;
            }
            let (scale, shown) = info.unit.micro();
            let key = info
                .name
                .rsplit_once('.')
                .map_or(info.name.as_str(), |(k, _)| k)
                .to_string();
            let v = params[j] * scale;
            match groups.iter_mut().find(|g| g.0 == key) {
                Some(g) => g.1 = g.1.hypot(v),
                None => groups.push((key, v.abs(), shown, info.unit)),
            }
        }
        groups
    }

    /// The squareness of every linear axis implied by the parameters, whatever the rule: the
    /// squareness parameter (if modelled) plus the slope of its straightness partner's best-fit
    /// line (if modelled), in rad. With the paper's rule the first is zero and this is the
    /// squareness "taken from the straightness".
    pub fn squareness(&self, params: &[f64]) -> Vec<(ErrorId, f64)> {
        let mut out = Vec::new();
        for ax in self.machine.axes() {
            if ax.axis.is_rotary() {
                continue;
            }
            for name in ErrorId::location_names(ax.axis) {
                let id: ErrorId = name.parse().expect("valid name");
                let partner = id.squareness_partner().expect("squareness");
                let own = self.term(id).map(|t| params[t.params.start]);
                let slope = self
                    .term(partner)
                    .filter(|p| !p.basis.kind().is_periodic())
                    .map(|p| {
                        let w = p.basis.linear_component();
                        let per_unit: f64 = w
                            .iter()
                            .zip(&params[p.params.clone()])
                            .map(|(a, b)| a * b)
                            .sum();
                        // y −= s·u·A0Z  ⇔  dEYZ/du = −s·A0Z
                        -ax.side.sign() * per_unit * 2.0 / (ax.max - ax.min)
                    });
                if own.is_some() || slope.is_some() {
                    out.push((id, own.unwrap_or(0.0) + slope.unwrap_or(0.0)));
                }
            }
        }
        out
    }
}

/// Each term's value `Σ_j g_j c_j` (from zero, in coefficient order) for the basis values `g`
/// and the terms' coefficients one after another in `block`, into `out` (one per term). The
/// basis values are of the forward model's scalar (`to` the identity) or the `f64` of a point's
/// [`Regressors`] (`to` = `S::from`); the usual lengths are unrolled: a cubic (4), one harmonic
/// (3), a constant (1).
#[inline]
fn dots<T: Real, S: Real>(g: &[T], block: &[f64], out: &mut [S], to: impl Fn(T) -> S) {
    #[inline]
    fn fixed<T: Real, S: Real, const L: usize>(
        g: &[T],
        block: &[f64],
        out: &mut [S],
        to: impl Fn(T) -> S,
    ) {
        let g: [T; L] = std::array::from_fn(|j| g[j]);
        for (v, coeffs) in out.iter_mut().zip(block.chunks_exact(L)) {
            let mut acc = T::zero();
            for j in 0..L {
                acc += g[j] * coeffs[j];
            }
            *v = to(acc);
        }
    }
    match g.len() {
        1 => fixed::<T, S, 1>(g, block, out, to),
        3 => fixed::<T, S, 3>(g, block, out, to),
        4 => fixed::<T, S, 4>(g, block, out, to),
        len => {
            for (v, coeffs) in out.iter_mut().zip(block.chunks_exact(len)) {
                let mut acc = T::zero();
                for (b, c) in g.iter().zip(coeffs) {
                    acc += *b * *c;
                }
                *v = to(acc);
            }
        }
    }
}

/// The basis values `g` (one term's coefficients' derivatives) into every term's columns of a
/// group's stretch of a Jacobian row (`block`: the terms' coefficients one after another).
#[inline]
fn spread(g: &[f64], block: &mut [f64]) {
    fn fixed<const L: usize>(g: &[f64], block: &mut [f64]) {
        let g: [f64; L] = std::array::from_fn(|j| g[j]);
        for chunk in block.chunks_exact_mut(L) {
            chunk.copy_from_slice(&g);
        }
    }
    match g.len() {
        1 => fixed::<1>(g, block),
        3 => fixed::<3>(g, block),
        4 => fixed::<4>(g, block),
        len => {
            for chunk in block.chunks_exact_mut(len) {
                chunk.copy_from_slice(g);
            }
        }
    }
}

/// Groups consecutive terms of one axis in one basis linear in its coefficients, with
/// consecutive coefficients (see [`TermGroup`]).
fn term_groups(terms: &[Term]) -> Vec<TermGroup> {
    let mut groups: Vec<TermGroup> = Vec::new();
    for (i, t) in terms.iter().enumerate() {
        if let Some(g) = groups.last_mut() {
            let prev = &terms[i - 1];
            if prev.axis == t.axis
                && prev.basis == t.basis
                && t.basis.is_linear()
                && prev.params.end == t.params.start
                && g.terms.len() < MAX_GROUP
            {
                g.terms.end = i + 1;
                continue;
            }
        }
        groups.push(TermGroup {
            terms: i..i + 1,
            len: t.params.len(),
            params: t.params.start,
        });
    }
    groups
}

/// The basis of one `[[error]]` entry for an error, with the checks that make it meaningful.
fn term_basis(
    id: ErrorId,
    rotary_axis: bool,
    e: &ErrorTermSpec,
) -> std::result::Result<Basis, String> {
    if let ErrorId::Location { .. } = id {
        return match e.basis {
            None | Some(BasisKind::Constant) => Basis::new(BasisKind::Constant, 0),
            Some(b) => Err(format!(
                "{id} is a location/squareness error, a constant: give it no basis (found '{b}')"
            )),
        };
    }
    let Some(kind) = e.basis else {
        return Err(format!(
            "{id} needs a basis: monomial, legendre or chebyshev with a degree, fourier or sine with an order, or constant"
        ));
    };
    if kind.is_periodic() && !rotary_axis {
        return Err(format!(
            "{id}: a {kind} series is periodic in an angle; {} is a linear axis (use monomial, legendre or chebyshev)",
            id.axis()
        ));
    }
    let degree = match kind {
        BasisKind::Constant => 0,
        BasisKind::Fourier | BasisKind::Sine => e.order.ok_or_else(|| {
            format!("{id}: a {kind} series needs `order` (the number of harmonics)")
        })?,
        BasisKind::Chebyshev => match (e.degree, e.nodes) {
            (Some(d), None) => d,
            (None, Some(m)) if m >= 1 => m - 1,
            (None, Some(_)) => return Err(format!("{id}: chebyshev needs at least one node")),
            (Some(_), Some(_)) => {
                return Err(format!(
                    "{id}: give chebyshev either `degree` or `nodes`, not both"
                ));
            }
            (None, None) => {
                return Err(format!(
                    "{id}: chebyshev needs `nodes` (or `degree` = nodes − 1)"
                ));
            }
        },
        BasisKind::Monomial | BasisKind::Legendre => e
            .degree
            .ok_or_else(|| format!("{id}: a {kind} polynomial needs `degree`"))?,
    };
    Basis::new(kind, degree).map_err(|m| format!("{id}: {m}"))
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
