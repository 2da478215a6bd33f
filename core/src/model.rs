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
use crate::machine::{Commands, Machine, Observes};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt;
use std::ops::Range;
use std::path::Path;

mod build;
mod effect_values;
mod evaluate;
mod observe;
mod regressors;
mod spec;
use regressors::PointRegressors;
pub use regressors::Regressors;
pub use spec::{
    BallScrewSpec, EffectsSpec, ErrorModelSpec, ErrorTermSpec, MAX_FIXED, MAX_REVERSAL_DEGREE,
    OneOrMany, PERIOD_RANGE_MM, ReversalFunction, ReversalSpec, SquarenessRule, TrackerModelSpec,
};
use spec::{EffectSlot, FieldVar};

/// The paper's error model for the embedded XCFZ machine.
pub const DEFAULT_MODEL_TOML: &str = include_str!("../data/xcfz-paper-model.toml");

/// Label used in messages for the embedded default error model.
pub const DEFAULT_MODEL_LABEL: &str = "<embedded paper error model>";

/// Most error values (modelled errors plus the tracker pose) one point may depend on.
pub const MAX_SLOTS: usize = 72;

/// What a point's effects read beside its commands: the time it was measured at (s since the
/// test's start) and the direction each axis arrived from ([`crate::approach`]; the reversal
/// effect's sign).
///
/// ```
/// use volver_core::approach::Approach;
/// use volver_core::model::{ErrorModelSpec, Model, PointState};
/// use volver_core::machine::Machine;
/// let m = Machine::default_xcfz();
/// let spec = ErrorModelSpec::from_toml_str("[effects]\nreversal = [\"X\"]", "m.toml").unwrap();
/// let model = Model::new(m, spec).unwrap();
/// let mut p = model.initial_params();
/// p[model.param_index("reversal.X.b").unwrap()] = 0.010; // B = 10 µm
/// let cmd = model.machine().commands_from_file_units(&[700.0, 0.0, 300.0]);
/// let at = |s: i8| PointState { t_s: 0.0, approach: Approach::all(3, s) };
/// let (up, down) = (model.predict_in(&cmd, 0, at(1), &p), model.predict_in(&cmd, 0, at(-1), &p));
/// assert!(((up[0] - down[0]).abs() - 0.010).abs() < 1e-12);
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PointState {
    /// Seconds since the test's start.
    pub t_s: f64,
    /// Each axis' direction of approach.
    pub approach: crate::approach::Approach,
}

impl PointState {
    /// At time `t_s` (s), no axis' direction known.
    pub fn at(t_s: f64) -> PointState {
        PointState {
            t_s,
            approach: crate::approach::Approach::UNKNOWN,
        }
    }

    /// The state of a measured point: its time stamp (0 without one) and its directions.
    pub fn of(m: &crate::measure::Measurement) -> PointState {
        PointState {
            t_s: m.t_s.unwrap_or(0.0),
            approach: m.approach,
        }
    }
}

/// What the reverse pass of [`Model`]'s exact Jacobian differentiates.
#[derive(Clone, Copy)]
enum JacobianTarget<'a> {
    /// The point a reflector at this offset (frame of the last tool-side axis) is measured at.
    Reflector(&'a [f64; 3]),
    /// The tool point at this offset, in the workpiece frame.
    Tool(&'a [f64; 3]),
}

/// Which error value a parameter feeds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Owner {
    /// Coefficient `coeff` of modelled error `term` (index in [`Model::terms`]).
    Term {
        /// Index of the term.
        term: usize,
        /// Index of the coefficient in the term's basis.
        coeff: usize,
    },
    /// Tracker pose value (0..6: x, y, z, rx, ry, rz): the reference station's.
    Tracker(usize),
    /// A station's value: a further station's pose (`value` 0..6) or any station's range
    /// offset (`value` 6).
    Station {
        /// The station's index in [`Machine::stations`].
        station: usize,
        /// 0..6: x, y, z, rx, ry, rz; 6: the range offset.
        value: usize,
    },
    /// An effect outside the ISO 230 model (index of its value slot among the effects).
    Effect(usize),
}

/// What a parameter describes ([`Model::role`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum Role {
    /// A geometric error of the machine that per-axis controller tables carry: an ISO 230 term
    /// (a component error as a function of its axis, a location or squareness constant) or a
    /// ball-screw error (added to the positioning error it belongs to).
    Geometry,
    /// A displacement of the tool point over the machine's axes that is not a function of one
    /// axis' position in the ISO sense (a `field` over axes): the machine's, but per-axis
    /// tables cannot carry it.
    Field,
    /// Machine geometry that changes with time (a scale growing, a rotary axis' line drifting, a
    /// field over an axis and `t`): zero at the test's start, where the tool point is taken;
    /// static tables cannot carry its growth.
    Thermal,
    /// The measurement, not the machine: the tracker's and stations' poses, reflector offsets,
    /// the range scale, a drift of the tool point, the tracker or a station over the test, a
    /// field over time alone.
    Measurement,
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
#[non_exhaustive]
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

/// What is wrong with a constraint row ([`Constraints::check_indices`]).
#[derive(Clone, Debug, PartialEq)]
pub enum ConstraintFault {
    /// The row names a parameter index beyond the problem's.
    UnknownParameter {
        /// The row (from 0).
        row: usize,
        /// Its label.
        label: String,
        /// The index it names.
        index: usize,
    },
    /// A coefficient or the value of the row is not finite.
    NotFinite {
        /// The row (from 0).
        row: usize,
        /// Its label.
        label: String,
    },
}

impl Constraints {
    /// Checks that every row names parameters below `n_params` and has finite coefficients and
    /// value: what [`Constraints::dense`] and [`Constraints::max_violation`] assume.
    ///
    /// ```
    /// use volver_core::model::{Constraint, ConstraintFault, ConstraintKind, Constraints};
    /// let c = Constraints {
    ///     rows: vec![Constraint {
    ///         kind: ConstraintKind::Fixed,
    ///         label: "p7 held".into(),
    ///         coeffs: vec![(7, 1.0)],
    ///         rhs: 0.0,
    ///     }],
    /// };
    /// assert!(c.check_indices(8).is_ok());
    /// assert!(matches!(
    ///     c.check_indices(4),
    ///     Err(ConstraintFault::UnknownParameter { row: 0, index: 7, .. })
    /// ));
    /// ```
    pub fn check_indices(&self, n_params: usize) -> std::result::Result<(), ConstraintFault> {
        for (row, r) in self.rows.iter().enumerate() {
            if let Some(&(index, _)) = r.coeffs.iter().find(|(j, _)| *j >= n_params) {
                return Err(ConstraintFault::UnknownParameter {
                    row,
                    label: r.label.clone(),
                    index,
                });
            }
            if !r.rhs.is_finite() || r.coeffs.iter().any(|(_, v)| !v.is_finite()) {
                return Err(ConstraintFault::NotFinite {
                    row,
                    label: r.label.clone(),
                });
            }
        }
        Ok(())
    }

    /// Dense `A` (row-major, `rows × n_params`) and `b`.
    ///
    /// # Panics
    /// When a row names a parameter at or beyond `n_params`: check first with
    /// [`Constraints::check_indices`] (every engine does).
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

/// Where one station's parameters are in the layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StationBlock {
    /// Its pose's first parameter (x; then y, z, rx, ry, rz): the tracker's for station 0.
    pub pose: usize,
    /// Its range offset's parameter, when modelled.
    pub offset: Option<usize>,
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
    /// Per station ([`Machine::stations`]): where its parameters are.
    stations: Vec<StationBlock>,
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
        let text = crate::error::without_bom(text);
        let spec = ErrorModelSpec::from_toml_str(text, file)?;
        Model::build(machine, spec, file, Some(text))
    }

    /// Compiles an error-model specification (e.g. one read back from a results file).
    pub fn new(machine: Machine, spec: ErrorModelSpec) -> Result<Model> {
        Model::build(machine, spec, "error model", None)
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

    /// Where each station's parameters are ([`Machine::stations`] order; station 0's pose is
    /// the tracker's, at [`Model::tracker_start`]).
    pub fn stations(&self) -> &[StationBlock] {
        &self.stations
    }

    /// Whether parameter `j` belongs to a station (a pose value or a range offset): what the
    /// measurement set-up, not the machine, is.
    pub fn is_station_param(&self, j: usize) -> bool {
        matches!(
            self.params[j].owner,
            Owner::Tracker(_) | Owner::Station { .. }
        )
    }

    /// What parameter `j` describes ([`Role`]): whether it belongs to the machine or to the
    /// measurement, and whether per-axis controller tables can carry it. Every output that uses
    /// part of a model decides by this one rule (tables, their list of what they cannot carry,
    /// the tool point's time-independent part).
    ///
    /// ```
    /// use volver_core::model::{Model, Role};
    /// let m = Model::default_xcfz();
    /// assert_eq!(m.role(m.param_index("EXX.c1").unwrap()), Role::Geometry);
    /// assert_eq!(m.role(m.param_index("tracker.x").unwrap()), Role::Measurement);
    /// ```
    pub fn role(&self, j: usize) -> Role {
        match self.params[j].owner {
            Owner::Term { .. } => Role::Geometry,
            Owner::Tracker(_) | Owner::Station { .. } => Role::Measurement,
            Owner::Effect(i) => self.effects[i].0.role(),
        }
    }

    /// The name of the effect (or error, or station) that parameter `j` belongs to, as outputs
    /// group parameters: `field X*Z`, `thermal scale of X`, `EXX`, `tracker pose` …
    ///
    /// ```
    /// use volver_core::model::Model;
    /// let m = Model::default_xcfz();
    /// assert_eq!(m.part_name(m.param_index("EXX.c1").unwrap()), "EXX");
    /// ```
    pub fn part_name(&self, j: usize) -> String {
        match self.params[j].owner {
            Owner::Term { term, .. } => self.terms[term].id.to_string(),
            Owner::Tracker(_) => "tracker pose".to_string(),
            Owner::Station { station, .. } => {
                format!("station {}", self.machine.stations()[station].id)
            }
            Owner::Effect(i) => {
                // `field.X*Z.x_1_1` → `field X*Z`: the three components are one field.
                self.effects[i].0.label(&self.machine, &self.params[j].name)
            }
        }
    }

    /// Whether parameter `j` describes the measurement, not the machine: what
    /// [`Model::tool_point`] leaves out or takes at the test's start. The set-up (the tracker's
    /// and every station's pose and range offset, the reflectors' offsets, the range scale) and
    /// every term that changes with time during one test (tool drift, scale growth, location
    /// drift, the tracker's and stations' drift, a field over `t`: each zero at the start).
    /// The machine's geometry is the rest: the ISO 230 errors, ball-screw errors and fields over
    /// axes alone. Cross-validation refits exactly these on a reference test, and compensation
    /// uses exactly the others.
    ///
    /// ```
    /// let model = volver_core::model::Model::default_xcfz();
    /// let t = model.tracker_start();
    /// assert!(model.is_measurement_param(t));
    /// assert!(!model.is_measurement_param(0));
    /// ```
    ///
    /// # Panics
    /// When `j >= n_params()`.
    pub fn is_measurement_param(&self, j: usize) -> bool {
        matches!(self.role(j), Role::Measurement | Role::Thermal)
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

    /// The power of time (hours) parameter `j` multiplies in the forward model: 1 for a drift
    /// rate (tool, location, tracker, station, an axis' scale growth) and a field's `t`, 2 for a
    /// field's `t²`, 0 for every other parameter. The gauge's metric weighs a parameter of power
    /// `p` by the RMS of `tᵖ` over the test's span, so that a fit does not depend on the unit of
    /// the time stamps.
    pub fn time_power(&self, j: usize) -> u32 {
        for &(slot, first) in &self.effects {
            match slot {
                EffectSlot::Drift(_)
                | EffectSlot::ThermalScale { .. }
                | EffectSlot::LocationDrift { .. }
                | EffectSlot::TrackerDrift(_)
                | EffectSlot::StationDrift { .. }
                    if j == first =>
                {
                    return 1;
                }
                EffectSlot::Field { vars, pair, .. } if j >= first => {
                    let q = j - first;
                    let power = |var: FieldVar, code: usize| {
                        if var == FieldVar::Time {
                            code as u32 + 1
                        } else {
                            0
                        }
                    };
                    if pair && q < 4 {
                        return power(vars[0], q / 2) + power(vars[1], q % 2);
                    }
                    if !pair && q < vars[0].functions() {
                        return power(vars[0], q);
                    }
                }
                _ => {}
            }
        }
        0
    }

    /// The modelled error with a given ISO name.
    pub fn term(&self, id: ErrorId) -> Option<&Term> {
        self.terms.iter().find(|t| t.id == id)
    }
}
