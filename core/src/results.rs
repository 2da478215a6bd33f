//! Results files (JSON): the machine, the error model and every parameter with its value, unit
//! and group — enough to rebuild the [`Model`] and evaluate every identified error function later.
//!
//! ```
//! use volver_core::model::Model;
//! use volver_core::results::ResultsFile;
//! let model = Model::default_xcfz();
//! let mut p = model.initial_params();
//! p[model.param_index("EXX.c1").unwrap()] = 0.012;
//! let json = ResultsFile::from_model(&model, &p).unwrap().to_json();
//! let (back, q) = ResultsFile::from_json_str(&json, "r.json").unwrap().to_model("r.json").unwrap();
//! assert_eq!(q, p);
//! assert_eq!(back.n_params(), model.n_params());
//! ```

use crate::error::{Error, Place, Result};
use crate::iso::{Group, Unit};
use crate::machine::{Machine, MachineSpec};
use crate::model::{ErrorModelSpec, Model};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// The `format` field of every results file.
pub const RESULTS_FORMAT: &str = "volver-results";

/// The current results-file version.
pub const RESULTS_VERSION: u32 = 1;

/// One parameter in a results file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParamRecord {
    /// Layout name (`EYX.c2`, `B0Z`, `tracker.x`).
    pub name: String,
    /// Value in `unit`.
    pub value: f64,
    /// Unit.
    pub unit: Unit,
    /// Group.
    pub group: Group,
}

/// A results file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResultsFile {
    /// Always [`RESULTS_FORMAT`].
    pub format: String,
    /// File version ([`RESULTS_VERSION`]).
    pub version: u32,
    /// The machine as specified.
    pub machine: MachineSpec,
    /// The error model as specified.
    pub error_model: ErrorModelSpec,
    /// Every parameter of the layout, in layout order.
    pub parameters: Vec<ParamRecord>,
    /// The uncertainty of the parameters, when the fit stated it (`volver identify --out`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncertainty: Option<UncertaintyRecord>,
    /// The measurements' time stamp (s, in their file's clock) that the model's time counts
    /// from ([`crate::measure::MeasurementSet::time_origin_s`]), for a model with effects over
    /// time: its drifts are zero there, and `predict`, `compensate` and `tables` give the
    /// machine at that instant, the test's start.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_origin_s: Option<f64>,
    /// What the values mean where a reader could take them the other way, by topic: written by
    /// [`ResultsFile::from_model`], not read back (older files have none). `squareness`: the
    /// sign rule of the model's squareness parameters and how ISO 230-1's reading relates
    /// ([`ErrorId::iso_sign`](crate::iso::ErrorId::iso_sign)), when the model has one.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub conventions: BTreeMap<String, String>,
}

/// The `conventions` entries of a results file of `model`: the squareness sign rule of each
/// squareness parameter the model has.
fn conventions(model: &Model) -> BTreeMap<String, String> {
    let rules: Vec<String> = model
        .terms()
        .iter()
        .filter_map(|t| t.id.squareness_rule())
        .collect();
    let mut c = BTreeMap::new();
    if !rules.is_empty() {
        c.insert(
            "squareness".to_string(),
            format!(
                "parameters in volver's sign; exports (tables, controller files, the report) \
                 give ISO 230-1's. {}",
                rules.join(". ")
            ),
        );
    }
    c
}

/// The covariance of a fit's parameters, as factors: `Cov(p) = D Dᵀ + H Hᵀ` (the data's part and
/// the gauge's held combinations' prior), so that later commands state the U of what they
/// derive (`volver_solvers::uncertainty::Covariance`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UncertaintyRecord {
    /// The gauge's rule.
    pub gauge: String,
    /// The noise model.
    pub noise: String,
    /// Residual standard deviation per coordinate (mm).
    pub sigma_mm: f64,
    /// The prior of each held combination (mm RMS of the error functions).
    pub held_prior_mm: f64,
    /// The held combinations: the parameters each moves most, as text (`tracker.z +0.50, …`).
    pub held: Vec<String>,
    /// Columns of `D`, each one value per parameter in layout order (parameters' units).
    pub data_factor: Vec<Vec<f64>>,
    /// Columns of `H`, one per held combination.
    pub held_factor: Vec<Vec<f64>>,
    /// Whether the fit was at the tracker's noise when the covariance was computed: the
    /// intervals assume a complete model, and say nothing where the fit is above the noise.
    /// Absent in files written before it existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model_check: Option<ModelCheck>,
}

/// The fit against what the tracker's noise leaves a complete model: the condition under which
/// an uncertainty means anything ([`UncertaintyRecord::model_check`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelCheck {
    /// The fit's EMM (µm).
    pub emm_um: f64,
    /// What the noise leaves a complete model's fit (µm); `None` when nothing says what the
    /// noise is (no specification, no repeated points).
    pub expected_um: Option<f64>,
    /// What the noise was judged from, in words.
    pub basis: String,
    /// `true` when the fit lies above what the noise explains: a part of the machine is missing
    /// from the model, and intervals computed as if it were complete do not hold.
    pub above_noise: bool,
}

impl ModelCheck {
    /// The fit's EMM over what the noise leaves, when that is known.
    pub fn ratio(&self) -> Option<f64> {
        self.expected_um.map(|e| self.emm_um / e)
    }

    /// One sentence for every output that states an uncertainty.
    ///
    /// ```
    /// use volver_core::results::ModelCheck;
    /// let c = ModelCheck {
    ///     emm_um: 20.0,
    ///     expected_um: Some(10.0),
    ///     basis: "the tracker's specification".into(),
    ///     above_noise: true,
    /// };
    /// assert!(c.statement().contains("2.00 × what the noise leaves"));
    /// assert!(c.statement().contains("volver diagnose"));
    /// ```
    pub fn statement(&self) -> String {
        match (self.above_noise, self.ratio()) {
            (true, Some(r)) => format!(
                "the fit (EMM {:.2} µm) is {r:.2} × what the noise leaves a complete model \
                 ({:.2} µm, from {}): something the model lacks is in the data, and the \
                 intervals, which assume a complete model, do not hold; `volver diagnose` \
                 finds what is missing",
                self.emm_um,
                self.expected_um.unwrap_or(f64::NAN),
                self.basis
            ),
            (false, Some(r)) => format!(
                "the fit (EMM {:.2} µm) is at the noise ({r:.2} × what it leaves a complete \
                 model, from {}): the intervals assume the model complete, and the data do not \
                 contradict it",
                self.emm_um, self.basis
            ),
            (_, None) => format!(
                "whether the fit (EMM {:.2} µm) is at the noise is unknown ({}): the intervals \
                 assume a complete model; state the tracker's noise (`[tracker] noise` or \
                 --noise) or measure repeated points to check it",
                self.emm_um, self.basis
            ),
        }
    }
}

impl ResultsFile {
    /// A results file for `params` of `model`. Non-finite values are refused.
    pub fn from_model(model: &Model, params: &[f64]) -> Result<ResultsFile> {
        if params.len() != model.n_params() {
            return Err(Error::ParameterCount {
                expected: model.n_params(),
                got: params.len(),
                message: format!(
                    "{} parameter values for a model of {} parameters",
                    params.len(),
                    model.n_params()
                ),
            });
        }
        if let Some((info, v)) = model
            .params()
            .iter()
            .zip(params)
            .find(|(_, v)| !v.is_finite())
        {
            return Err(Error::NonFinite {
                message: format!(
                    "parameter {} is {v}; a results file holds finite values only",
                    info.name
                ),
            });
        }
        Ok(ResultsFile {
            format: RESULTS_FORMAT.to_string(),
            version: RESULTS_VERSION,
            machine: model.machine().spec().clone(),
            error_model: model.spec().clone(),
            parameters: model
                .params()
                .iter()
                .zip(params)
                .map(|(i, &value)| ParamRecord {
                    name: i.name.clone(),
                    value,
                    unit: i.unit,
                    group: i.group,
                })
                .collect(),
            uncertainty: None,
            time_origin_s: None,
            conventions: conventions(model),
        })
    }

    /// Pretty JSON text.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("results serialise")
    }

    /// Parses a results file; `file` names it in messages.
    pub fn from_json_str(text: &str, file: &str) -> Result<ResultsFile> {
        let text = crate::error::without_bom(text);
        let r: ResultsFile = serde_json::from_str(text).map_err(|e| {
            let mut place = Place::file(file);
            if e.line() > 0 {
                place = place.at_line(e.line());
            }
            Error::input(place, format!("not a volver results file: {e}"))
        })?;
        if r.format != RESULTS_FORMAT {
            return Err(Error::input(
                Place::file(file).at_field("format"),
                format!("expected \"{RESULTS_FORMAT}\", found \"{}\"", r.format),
            ));
        }
        if r.version != RESULTS_VERSION {
            return Err(Error::input(
                Place::file(file).at_field("version"),
                format!(
                    "version {} is not supported (this volver reads version {RESULTS_VERSION})",
                    r.version
                ),
            ));
        }
        Ok(r)
    }

    /// Reads a results file.
    pub fn load(path: &Path) -> Result<ResultsFile> {
        let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        ResultsFile::from_json_str(&text, &path.display().to_string())
    }

    /// Writes the file (atomically: the old file or the new one, never half of one).
    pub fn save(&self, path: &Path) -> Result<()> {
        crate::fsio::write_atomic(path, self.to_json() + "\n").map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })
    }

    /// Rebuilds the model and the parameter vector; checks every parameter's name, unit and
    /// group against the rebuilt layout.
    pub fn to_model(&self, file: &str) -> Result<(Model, Vec<f64>)> {
        let machine = Machine::from_spec(self.machine.clone(), &format!("{file} (machine)"))?;
        let model = Model::new(machine, self.error_model.clone())?;
        if self.parameters.len() != model.n_params() {
            return Err(Error::input(
                Place::file(file).at_field("parameters"),
                format!(
                    "{} parameters, but the machine and error model define {}",
                    self.parameters.len(),
                    model.n_params()
                ),
            ));
        }
        let mut values = Vec::with_capacity(model.n_params());
        for (k, (rec, info)) in self.parameters.iter().zip(model.params()).enumerate() {
            if rec.name != info.name || rec.unit != info.unit || rec.group != info.group {
                return Err(Error::input(
                    Place::file(file).at_field(format!("parameters[{k}]")),
                    format!(
                        "found {} ({}, {}), expected {} ({}, {}) from the error model",
                        rec.name, rec.unit, rec.group, info.name, info.unit, info.group
                    ),
                ));
            }
            if !rec.value.is_finite() {
                return Err(Error::input(
                    Place::file(file).at_field(format!("parameters[{k}].value")),
                    "expected a finite number",
                ));
            }
            values.push(rec.value);
        }
        if let Some(u) = &self.uncertainty {
            u.check(model.n_params(), file)?;
        }
        Ok((model, values))
    }
}

impl UncertaintyRecord {
    /// Checks the record against a model of `n` parameters (`file` names where it comes from in
    /// the errors): finite columns of `n` values, at most `n` of them, at least one data column
    /// that is not zero (an emptied record would read as "U 0"; without the record the U is
    /// honestly unknown), a non-negative σ and held prior, and one name per held combination.
    pub fn check(&self, n: usize, file: &str) -> Result<()> {
        check_uncertainty(self, n, file)
    }
}

/// [`UncertaintyRecord::check`].
fn check_uncertainty(u: &UncertaintyRecord, n: usize, file: &str) -> Result<()> {
    let at = |field: &str| Place::file(file).at_field(format!("uncertainty.{field}"));
    for (field, v) in [("sigma_mm", u.sigma_mm), ("held_prior_mm", u.held_prior_mm)] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(Error::input(
                at(field),
                format!("{v}: a standard deviation is a finite number ≥ 0 mm"),
            ));
        }
    }
    if u.held_prior_mm == 0.0 && !u.held_factor.is_empty() {
        return Err(Error::input(
            at("held_prior_mm"),
            "0 mm for held combinations: their prior is what their U is (volver writes 0.1 mm)",
        ));
    }
    if u.data_factor.len() + u.held_factor.len() > n {
        return Err(Error::input(
            at("data_factor"),
            format!(
                "{} columns for a model of {n} parameters: at most one per parameter",
                u.data_factor.len() + u.held_factor.len()
            ),
        ));
    }
    if u.data_factor.iter().flatten().all(|v| *v == 0.0) {
        return Err(Error::input(
            at("data_factor"),
            "empty or zero: a fit's covariance has a column per identified direction, so this \
             record would claim U = 0; remove the uncertainty record to use the file without U",
        ));
    }
    let columns = u
        .data_factor
        .iter()
        .map(|c| ("data_factor", c))
        .chain(u.held_factor.iter().map(|c| ("held_factor", c)));
    for (k, (field, col)) in columns.enumerate() {
        if col.len() != n || col.iter().any(|v| !v.is_finite()) {
            return Err(Error::input(
                at(field),
                format!(
                    "column {k} must hold {n} finite values (one per parameter), it has {}",
                    col.len()
                ),
            ));
        }
    }
    if u.held.len() != u.held_factor.len() {
        return Err(Error::input(
            at("held"),
            format!(
                "{} names for {} held combinations",
                u.held.len(),
                u.held_factor.len()
            ),
        ));
    }
    Ok(())
}
