//! The synthetic data generator (paper, section 4.1): a machine, a test plan, the reflectors, the
//! tracker pose, true error functions and a noise model in; a measurement file, a truth file and
//! the machine file out, with the "noise error" of tables 9–10.
//!
//! # The truth
//! The true error functions and tracker pose are a [`Truth`]: an error model with parameter
//! values, written as a results file (`truth.json`) that identification results can be compared
//! with. It is read from a results file ([`Truth::from_results`]) or drawn at random
//! ([`Truth::random`]) with a [`Magnitudes`] per error kind:
//!
//! * every polynomial error is drawn with random coefficients (Legendre and monomial coefficient
//!   k with standard deviation 1/(k+1), Chebyshev node values with 1, Fourier harmonic h with
//!   1/h, sine-series phases uniform), made to satisfy the model's constraints (zero at the
//!   reference position …), and scaled so that its largest absolute value over the axis travel is
//!   the kind's magnitude times a factor drawn uniformly in [0.5, 1];
//! * a constant error (squareness, rotary-axis location) is ± the magnitude times that factor;
//! * the tracker stands at its nominal position moved by the `tracker` magnitude times that
//!   factor in a random direction, with no rotation.
//!
//! A random truth holds squareness in the squareness parameters and keeps the straightness
//! errors free of a best-fit slope (the `separate` rule, the ISO 230-1 split), whatever rule the
//! structure names, so that the `squareness` magnitude means what it says. Both rules describe
//! the same machine. The truth's tracker pose has all six values free.
//!
//! # Effects outside the standard model
//! [`Effect`]s let a test hide a physical effect from the identification. Their ids are stable:
//!
//! | id | parameters | what it does to each point |
//! |---|---|---|
//! | `thermal-drift` | v = (vx, vy, vz) µm/h | the tool point moves by v·t in the machine frame, t = the point's time stamp `t_s` |
//! | `rotary-harmonics` | H; a µm, b µrad | every periodic error of a rotary axis gets the harmonics h = order+1 … H of the truth model, each `A·sin(h·θ + φ_h)` with A = a (translations) or b (rotations) and a random phase; they are written into `truth.json` |
//! | `tracker-tilt` | rx, ry µrad | the tracker's small rotation about its x and y axes (eq. 9), written into `truth.json` |
//! | `ball-screw` | axis, period P mm, amplitude A µm | the positioning error of a linear axis gets `A·sin(2π·(u − u_ref)/P)` (a mesh whose step is a multiple of P sees it nowhere) |
//! | `reflector-offset` | reflector id, δ µm | the reflector sits at its nominal offset + δ (frame of the last tool-side axis) |
//! | `range-scale` | s ppm | every point is scaled about the tracker's centre by 1 + s·10⁻⁶ before the noise |
//!
//! Points are measured in plan order, each reflector in turn at every position, evenly over the
//! test's duration: point i of n has `t_s = duration · i / (n − 1)`, rounded to the millisecond
//! written in the file.
//!
//! # Seeds
//! One seed drives independent streams for the true errors, the tracker position, the harmonics'
//! phases and the noise, so the same seed with and without an effect gives the same errors and
//! the same noise draws, and the same inputs give byte-identical files.
//!
//! ```
//! use volver_core::machine::Machine;
//! use volver_core::model::ErrorModelSpec;
//! use volver_core::noise::TrackerNoise;
//! use volver_core::plan::Plan;
//! use volver_core::simulate::{Magnitudes, Simulation, Truth};
//! let m = Machine::default_xcfz();
//! let plan = Plan::preset(&m, "table4").unwrap();
//! let truth = Truth::random(&m, &ErrorModelSpec::complete(&m), &Magnitudes::default(), 7).unwrap();
//! let mut sim = Simulation::new(plan, truth, 7);
//! sim.noise = TrackerNoise::PAPER;
//! let out = sim.run().unwrap();
//! assert_eq!(out.measurements.points.len(), 2 * 73);
//! assert!(out.record.noise_error.emm_um > 10.0);
//! ```

use crate::basis::BasisKind;
use crate::error::{Error, Place, Result};
use crate::iso::{Axis, ErrorId, Unit};
use crate::kinematics::{PointErrors, TRACKER_DOF, predict, predict_with_tool_shift};
use crate::machine::Machine;
use crate::measure::{Measurement, MeasurementSet};
use crate::metrics::ErrorStats;
use crate::model::{ConstraintKind, ErrorModelSpec, Model, SquarenessRule, TrackerModelSpec};
use crate::noise::TrackerNoise;
use crate::plan::Plan;
use crate::random::Rng;
use crate::results::ResultsFile;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::fmt;
use std::path::{Path, PathBuf};

/// The `format` field of a simulation record.
pub const SIMULATION_FORMAT: &str = "volver-simulation";

/// The current simulation-record version.
pub const SIMULATION_VERSION: u32 = 1;

/// Test duration used when none is given: this many seconds per measured point.
pub const DEFAULT_SECONDS_PER_POINT: f64 = 10.0;

/// Highest harmonic the `rotary-harmonics` effect accepts (a periodic basis holds at most 15).
pub const MAX_HARMONIC: usize = 15;

/// Points at which an error function is sampled to find its largest value over the travel.
const PEAK_SAMPLES: usize = 256;

/// Independent random streams derived from one seed.
#[derive(Clone, Copy)]
enum Stream {
    Errors = 1,
    Tracker = 2,
    Harmonics = 3,
    Noise = 4,
}

fn stream(seed: u64, s: Stream) -> Rng {
    Rng::new(seed ^ (s as u64).wrapping_mul(0xD1B5_4A32_D192_ED03))
}

/// The error kinds of [`Magnitudes`]: name, unit and which errors it covers.
pub const MAGNITUDE_KINDS: [(&str, &str, &str); 11] = [
    (
        "positioning",
        "µm",
        "positioning error of a linear axis (EXX, EYY, EZZ)",
    ),
    (
        "straightness",
        "µm",
        "straightness of a linear axis (EYX, EZX, EXZ …)",
    ),
    (
        "angular",
        "µrad",
        "roll, pitch and yaw of a linear axis (EAX, EBX, ECX …)",
    ),
    (
        "squareness",
        "µrad",
        "squareness of a linear axis (A0Z, B0Z, C0Y …)",
    ),
    (
        "radial",
        "µm",
        "radial motion of a rotary axis (EXC, EYC for C)",
    ),
    ("axial", "µm", "axial motion of a rotary axis (EZC for C)"),
    (
        "tilt",
        "µrad",
        "tilt motion of a rotary axis (EAC, EBC for C)",
    ),
    (
        "angular-positioning",
        "µrad",
        "angular positioning error of a rotary axis (ECC for C)",
    ),
    (
        "location",
        "µm",
        "position of a rotary axis' line (X0C, Y0C for C)",
    ),
    (
        "location-tilt",
        "µrad",
        "orientation of a rotary axis' line (A0C, B0C for C)",
    ),
    (
        "tracker",
        "mm",
        "distance of the true tracker position from its nominal one",
    ),
];

/// Size of the randomly drawn true errors, per kind (see [`MAGNITUDE_KINDS`]): the largest
/// absolute value an error function reaches over its axis' travel is this magnitude times a
/// factor drawn in [0.5, 1].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Magnitudes {
    /// EXX, EYY, EZZ (µm).
    pub positioning_um: f64,
    /// EYX, EZX, EXZ … (µm).
    pub straightness_um: f64,
    /// EAX, EBX, ECX … of linear axes (µrad).
    pub angular_urad: f64,
    /// A0Z, B0Z, C0Y … (µrad).
    pub squareness_urad: f64,
    /// EXC, EYC … (µm).
    pub radial_um: f64,
    /// EZC … (µm).
    pub axial_um: f64,
    /// EAC, EBC … (µrad).
    pub tilt_urad: f64,
    /// ECC … (µrad).
    pub angular_positioning_urad: f64,
    /// X0C, Y0C … (µm).
    pub location_um: f64,
    /// A0C, B0C … (µrad).
    pub location_tilt_urad: f64,
    /// Distance of the true tracker position from the nominal one (mm).
    pub tracker_mm: f64,
}

impl Default for Magnitudes {
    /// Errors of a large, uncompensated machine tool: tens of µm and µrad.
    fn default() -> Self {
        Magnitudes {
            positioning_um: 50.0,
            straightness_um: 30.0,
            angular_urad: 50.0,
            squareness_urad: 50.0,
            radial_um: 20.0,
            axial_um: 10.0,
            tilt_urad: 30.0,
            angular_positioning_urad: 50.0,
            location_um: 30.0,
            location_tilt_urad: 30.0,
            tracker_mm: 0.0,
        }
    }
}

impl Magnitudes {
    /// Every magnitude zero: the true machine is the nominal one.
    pub const ZERO: Magnitudes = Magnitudes {
        positioning_um: 0.0,
        straightness_um: 0.0,
        angular_urad: 0.0,
        squareness_urad: 0.0,
        radial_um: 0.0,
        axial_um: 0.0,
        tilt_urad: 0.0,
        angular_positioning_urad: 0.0,
        location_um: 0.0,
        location_tilt_urad: 0.0,
        tracker_mm: 0.0,
    };

    fn slot(&mut self, kind: &str) -> Option<&mut f64> {
        Some(match kind {
            "positioning" => &mut self.positioning_um,
            "straightness" => &mut self.straightness_um,
            "angular" => &mut self.angular_urad,
            "squareness" => &mut self.squareness_urad,
            "radial" => &mut self.radial_um,
            "axial" => &mut self.axial_um,
            "tilt" => &mut self.tilt_urad,
            "angular-positioning" => &mut self.angular_positioning_urad,
            "location" => &mut self.location_um,
            "location-tilt" => &mut self.location_tilt_urad,
            "tracker" => &mut self.tracker_mm,
            _ => return None,
        })
    }

    /// The magnitude of one kind (a name of [`MAGNITUDE_KINDS`], in its unit); zero for a name
    /// that is not one.
    ///
    /// ```
    /// use volver_core::simulate::Magnitudes;
    /// assert_eq!(Magnitudes::default().get("axial"), 10.0);
    /// ```
    pub fn get(&self, kind: &str) -> f64 {
        let mut m = *self;
        m.slot(kind).map_or(0.0, |v| *v)
    }

    /// Sets one kind from text `KIND=VALUE` (the value in the kind's unit), as the CLI's
    /// `--magnitude` option takes it.
    ///
    /// ```
    /// use volver_core::simulate::Magnitudes;
    /// let mut m = Magnitudes::ZERO;
    /// m.set_from_text("straightness=12.5").unwrap();
    /// assert_eq!(m.straightness_um, 12.5);
    /// assert!(m.set_from_text("wobble=1").is_err());
    /// ```
    pub fn set_from_text(&mut self, text: &str) -> Result<()> {
        self.set_from_option(text, "--magnitude")
    }

    /// As [`Magnitudes::set_from_text`], for the command-line option `option` (which errors
    /// name).
    pub fn set_from_option(&mut self, text: &str, option: &str) -> Result<()> {
        let place = || Place::file(option).at_field(text.to_string());
        let (kind, value) = text
            .split_once('=')
            .ok_or_else(|| Error::input(place(), "expected KIND=VALUE, e.g. straightness=20"))?;
        let value: f64 = value
            .trim()
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite() && *v >= 0.0)
            .ok_or_else(|| {
                Error::input(place(), format!("'{value}' is not a finite number ≥ 0"))
            })?;
        let kinds: Vec<&str> = MAGNITUDE_KINDS.iter().map(|k| k.0).collect();
        let slot = self.slot(kind.trim()).ok_or_else(|| {
            Error::input(
                place(),
                format!("unknown kind '{kind}'; kinds are {}", kinds.join(", ")),
            )
        })?;
        *slot = value;
        Ok(())
    }

    /// Every magnitude multiplied by `k`.
    ///
    /// ```
    /// use volver_core::simulate::Magnitudes;
    /// let m = Magnitudes::default().scaled(2.0);
    /// assert_eq!(m.angular_urad, 2.0 * Magnitudes::default().angular_urad);
    /// ```
    pub fn scaled(&self, k: f64) -> Magnitudes {
        let mut m = *self;
        for (kind, _, _) in MAGNITUDE_KINDS {
            *m.slot(kind).expect("every kind has a slot") *= k;
        }
        m
    }

    /// The kind of an error (a name of [`MAGNITUDE_KINDS`]).
    pub fn kind_of(id: ErrorId) -> &'static str {
        let own = id.component().direction() == id.axis().direction();
        match (id, id.axis().is_rotary(), id.component().is_rotary()) {
            (ErrorId::Location { .. }, false, _) => "squareness",
            (ErrorId::Location { .. }, true, false) => "location",
            (ErrorId::Location { .. }, true, true) => "location-tilt",
            (ErrorId::Component { .. }, false, false) if own => "positioning",
            (ErrorId::Component { .. }, false, false) => "straightness",
            (ErrorId::Component { .. }, false, true) => "angular",
            (ErrorId::Component { .. }, true, false) if own => "axial",
            (ErrorId::Component { .. }, true, false) => "radial",
            (ErrorId::Component { .. }, true, true) if own => "angular-positioning",
            (ErrorId::Component { .. }, true, true) => "tilt",
        }
    }

    /// The magnitude for an error in internal units (mm or rad).
    pub fn for_error(&self, id: ErrorId) -> f64 {
        let mut m = *self;
        let v = *m
            .slot(Magnitudes::kind_of(id))
            .expect("every kind has a slot");
        // An ISO error is in mm or rad.
        if id.unit() == Unit::Mm {
            v * 1e-3
        } else {
            v * 1e-6
        }
    }

    fn validate(&self) -> Result<()> {
        let mut m = *self;
        for (kind, _, _) in MAGNITUDE_KINDS {
            let v = *m.slot(kind).expect("every kind has a slot");
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::input(
                    Place::file("magnitudes").at_field(kind),
                    format!("{v} is not a finite number ≥ 0"),
                ));
            }
        }
        Ok(())
    }
}

/// True error functions and tracker pose: an error model and its parameter values. The model's
/// tracker pose has all six values free (a tilted tracker is part of the truth).
#[derive(Clone, Debug)]
pub struct Truth {
    /// The model (machine + error functions).
    pub model: Model,
    /// Parameter values, satisfying the model's constraints.
    pub params: Vec<f64>,
}

impl Truth {
    /// A truth with the structure `structure` (which errors, which bases) drawn at random with
    /// the given magnitudes (see the module documentation).
    pub fn random(
        machine: &Machine,
        structure: &ErrorModelSpec,
        magnitudes: &Magnitudes,
        seed: u64,
    ) -> Result<Truth> {
        magnitudes.validate()?;
        let mut spec = structure.clone();
        if spec.squareness == SquarenessRule::FromStraightness {
            spec.squareness = SquarenessRule::Separate;
        }
        spec.tracker = TrackerModelSpec::default();
        let model = Model::new(machine.clone(), spec)?;
        let mut rng = stream(seed, Stream::Errors);
        let mut p = model.initial_params();
        let mut targets = Vec::with_capacity(model.terms().len());
        for t in model.terms() {
            let b = &t.basis;
            for (j, idx) in t.params.clone().enumerate() {
                let harmonic = j.div_ceil(2).max(1) as f64;
                p[idx] = match b.kind() {
                    BasisKind::Constant => {
                        if rng.uniform() < 0.5 {
                            -1.0
                        } else {
                            1.0
                        }
                    }
                    BasisKind::Monomial | BasisKind::Legendre => rng.normal() / (j + 1) as f64,
                    BasisKind::Chebyshev => rng.normal(),
                    BasisKind::Fourier => rng.normal() / harmonic,
                    BasisKind::Sine if b.is_phase(j) => PI * (2.0 * rng.uniform() - 1.0),
                    BasisKind::Sine => rng.normal() / harmonic,
                };
            }
            targets.push(magnitudes.for_error(t.id) * (0.5 + 0.5 * rng.uniform()));
        }
        project(&model, &mut p)?;
        for (t, target) in model.terms().iter().zip(targets) {
            let peak = peak_value(&model, t.id, &p);
            let factor = if peak > 0.0 { target / peak } else { 0.0 };
            for (j, idx) in t.params.clone().enumerate() {
                if !t.basis.is_phase(j) {
                    p[idx] *= factor;
                }
            }
        }
        project(&model, &mut p)?;
        let mut rng = stream(seed, Stream::Tracker);
        let dir = [rng.normal(), rng.normal(), rng.normal()];
        let norm = dir.iter().map(|v| v * v).sum::<f64>().sqrt();
        let dist = magnitudes.tracker_mm * (0.5 + 0.5 * rng.uniform());
        if norm > 0.0 {
            for (k, d) in dir.iter().enumerate() {
                p[model.tracker_start() + k] += dist * d / norm;
            }
        }
        Ok(Truth { model, params: p })
    }

    /// [`Truth::random`] with every error of the machine ([`ErrorModelSpec::complete`]).
    pub fn random_complete(machine: &Machine, magnitudes: &Magnitudes, seed: u64) -> Result<Truth> {
        Truth::random(
            machine,
            &ErrorModelSpec::complete(machine),
            magnitudes,
            seed,
        )
    }

    /// The truth held in a results file (`file` names it in messages).
    pub fn from_results(results: &ResultsFile, file: &str) -> Result<Truth> {
        let (model, params) = results.to_model(file)?;
        let violation = model.constraints().max_violation(&params);
        if violation > 1e-9 {
            return Err(Error::input(
                Place::file(file).at_field("parameters"),
                format!(
                    "the values break the error model's constraints by {violation:.3e} \
                     (a truth must satisfy them)"
                ),
            ));
        }
        Truth::with_free_tracker(model, params)
    }

    fn with_free_tracker(model: Model, params: Vec<f64>) -> Result<Truth> {
        let mut spec = model.spec().clone();
        spec.tracker = TrackerModelSpec::default();
        let model = Model::new(model.machine().clone(), spec)?;
        Ok(Truth { model, params })
    }

    /// The truth as a results file.
    pub fn to_results(&self) -> Result<ResultsFile> {
        ResultsFile::from_model(&self.model, &self.params)
    }

    /// The true tracker pose (x, y, z mm; rx, ry, rz rad).
    pub fn tracker_pose(&self) -> [f64; TRACKER_DOF] {
        let s = self.model.tracker_start();
        std::array::from_fn(|k| self.params[s + k])
    }

    /// The truth with harmonics `order+1 ..= max_order` added to every periodic error, each of
    /// amplitude `translation_mm` or `rotation_rad` and a phase drawn from `rng`.
    fn with_harmonics(
        &self,
        max_order: usize,
        translation_mm: f64,
        rotation_rad: f64,
        rng: &mut Rng,
    ) -> Result<Truth> {
        let mut spec = self.model.spec().clone();
        let mut periodic = false;
        for entry in &mut spec.errors {
            if entry.basis.is_some_and(BasisKind::is_periodic) {
                entry.order = Some(entry.order.unwrap_or(1).max(max_order));
                periodic = true;
            }
        }
        if !periodic {
            return Err(Error::input(
                Place::file("effects").at_field("rotary-harmonics"),
                "the true errors have no periodic (Fourier or sine) rotary-axis error to extend",
            ));
        }
        let model = Model::new(self.model.machine().clone(), spec)?;
        let mut p = model.initial_params();
        for (info, &v) in self.model.params().iter().zip(&self.params) {
            let idx = model
                .param_index(&info.name)
                .expect("raising an order keeps every parameter");
            p[idx] = v;
        }
        for t in model.terms() {
            let kind = t.basis.kind();
            if !kind.is_periodic() {
                continue;
            }
            let before = self.model.term(t.id).map_or(0, |old| old.basis.degree());
            let amp = if t.id.unit() == Unit::Mm {
                translation_mm
            } else {
                rotation_rad
            };
            for h in before + 1..=t.basis.degree() {
                let phase = PI * (2.0 * rng.uniform() - 1.0);
                let idx = |suffix: String| {
                    model
                        .param_index(&format!("{}.{suffix}", t.id))
                        .expect("harmonic parameter exists")
                };
                // A·sin(hθ + φ) = A cos φ · sin hθ + A sin φ · cos hθ.
                if kind == BasisKind::Fourier {
                    p[idx(format!("a{h}"))] = amp * phase.cos();
                    p[idx(format!("b{h}"))] = amp * phase.sin();
                } else {
                    p[idx(format!("a{h}"))] = amp;
                    p[idx(format!("phi{h}"))] = phase;
                }
            }
        }
        Ok(Truth { model, params: p })
    }
}

/// Largest |value| of an error over its axis' travel (sampled).
fn peak_value(model: &Model, id: ErrorId, p: &[f64]) -> f64 {
    let term = model.term(id).expect("the error is modelled");
    let ax = &model.machine().axes()[term.axis];
    (0..=PEAK_SAMPLES)
        .map(|i| {
            let u = ax.min + (ax.max - ax.min) * i as f64 / PEAK_SAMPLES as f64;
            model.error_value(id, u, p).map_or(0.0, f64::abs)
        })
        .fold(0.0, f64::max)
}

/// Moves `p` to the nearest point (least change) that satisfies the model's constraints.
fn project(model: &Model, p: &mut [f64]) -> Result<()> {
    use nalgebra::{DMatrix, DVector};
    let n = p.len();
    let rows = &model.constraints().rows;
    if rows.is_empty() {
        return Ok(());
    }
    let (a, b) = model.constraints().dense(n);
    let a = DMatrix::from_row_slice(rows.len(), n, &a);
    let r = &a * DVector::from_column_slice(p) - DVector::from_column_slice(&b);
    let aat = &a * a.transpose();
    let svd = aat.svd(true, true);
    let eps = 1e-12 * svd.singular_values.max();
    let lambda = svd
        .solve(&r, eps)
        .map_err(|e| Error::Model(format!("projecting onto the constraints: {e}")))?;
    let correction = a.transpose() * lambda;
    for (v, c) in p.iter_mut().zip(correction.iter()) {
        *v -= c;
    }
    // Held parameters take their values exactly, not to rounding.
    for row in rows.iter().filter(|r| r.kind == ConstraintKind::Fixed) {
        if let [(j, c)] = row.coeffs.as_slice() {
            p[*j] = row.rhs / c;
        }
    }
    let violation = model.constraints().max_violation(p);
    if violation > 1e-9 {
        return Err(Error::Model(format!(
            "the error model's constraints contradict each other (left unsatisfied by {violation:.3e})"
        )));
    }
    Ok(())
}

/// A physical effect outside the standard model (see the module documentation for formulas).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "effect", rename_all = "kebab-case")]
pub enum Effect {
    /// Thermal drift of the tool point in the machine frame.
    ThermalDrift {
        /// Drift rate along x, y, z (µm/h).
        rate_um_per_h: [f64; 3],
    },
    /// Higher harmonics of every periodic rotary-axis error.
    RotaryHarmonics {
        /// Highest harmonic added (2 ..= 15).
        max_order: usize,
        /// Amplitude of each added harmonic of a translation error (µm).
        translation_um: f64,
        /// Amplitude of each added harmonic of a rotation error (µrad).
        rotation_urad: f64,
    },
    /// A tracker mounted tilted.
    TrackerTilt {
        /// Rotation about the tracker's x axis (µrad).
        rx_urad: f64,
        /// Rotation about the tracker's y axis (µrad).
        ry_urad: f64,
    },
    /// A periodic positioning error of a linear axis (ball-screw pitch error).
    BallScrew {
        /// The linear axis.
        axis: Axis,
        /// Period (mm).
        period_mm: f64,
        /// Amplitude (µm).
        amplitude_um: f64,
    },
    /// A reflector whose true offset differs from the machine file's.
    ReflectorOffset {
        /// Reflector id.
        reflector: String,
        /// True offset minus nominal offset (µm).
        delta_um: [f64; 3],
    },
    /// A tracker whose ranges are scaled.
    RangeScale {
        /// Scale error (parts per million).
        ppm: f64,
    },
}

/// The effects: id, CLI syntax and meaning, in the order `volver simulate --help` lists them.
pub const EFFECTS: [(&str, &str, &str); 6] = [
    (
        "thermal-drift",
        "thermal-drift=VX,VY,VZ",
        "tool point drifts in the machine frame, µm/h",
    ),
    (
        "rotary-harmonics",
        "rotary-harmonics=H[,AMP_UM,AMP_URAD]",
        "rotary-axis errors get harmonics up to H (default 5 µm, 10 µrad each)",
    ),
    (
        "tracker-tilt",
        "tracker-tilt=RX,RY",
        "tracker mounted tilted, µrad",
    ),
    (
        "ball-screw",
        "ball-screw=AXIS,PERIOD_MM,AMP_UM",
        "periodic positioning error of a linear axis",
    ),
    (
        "reflector-offset",
        "reflector-offset=ID,DX,DY,DZ",
        "reflector off its nominal offset, µm",
    ),
    (
        "range-scale",
        "range-scale=PPM",
        "tracker range scale error, ppm",
    ),
];

impl Effect {
    /// The effect's stable id (`thermal-drift` …).
    pub fn id(&self) -> &'static str {
        match self {
            Effect::ThermalDrift { .. } => "thermal-drift",
            Effect::RotaryHarmonics { .. } => "rotary-harmonics",
            Effect::TrackerTilt { .. } => "tracker-tilt",
            Effect::BallScrew { .. } => "ball-screw",
            Effect::ReflectorOffset { .. } => "reflector-offset",
            Effect::RangeScale { .. } => "range-scale",
        }
    }

    /// Parses the CLI syntax of [`EFFECTS`], e.g. `thermal-drift=0,0,20`.
    ///
    /// ```
    /// use volver_core::simulate::Effect;
    /// let e = Effect::parse("ball-screw=X,10,3").unwrap();
    /// assert_eq!(e.to_string(), "ball-screw=X,10,3");
    /// assert!(Effect::parse("ball-screw=X,10").unwrap_err().to_string().contains("AXIS,PERIOD_MM,AMP_UM"));
    /// ```
    pub fn parse(text: &str) -> Result<Effect> {
        let place = || Place::file("--effect").at_field(text.to_string());
        let ids: Vec<&str> = EFFECTS.iter().map(|e| e.0).collect();
        let (id, args) = text.split_once('=').unwrap_or((text, ""));
        let id = id.trim();
        let Some(&(_, syntax, _)) = EFFECTS.iter().find(|e| e.0 == id) else {
            return Err(Error::input(
                place(),
                format!("unknown effect '{id}'; effects are {}", ids.join(", ")),
            ));
        };
        let args: Vec<&str> = args
            .split(',')
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .collect();
        let bad = |why: String| Error::input(place(), format!("{why}; expected {syntax}"));
        let num = |s: &str| -> Result<f64> {
            s.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| bad(format!("'{s}' is not a finite number")))
        };
        let nums = |a: &[&str]| -> Result<Vec<f64>> { a.iter().map(|s| num(s)).collect() };
        let count = |n: usize| -> Result<()> {
            if args.len() == n {
                Ok(())
            } else {
                Err(bad(format!("{} values given", args.len())))
            }
        };
        Ok(match id {
            "thermal-drift" => {
                count(3)?;
                let v = nums(&args)?;
                Effect::ThermalDrift {
                    rate_um_per_h: [v[0], v[1], v[2]],
                }
            }
            "rotary-harmonics" => {
                if args.len() != 1 && args.len() != 3 {
                    return Err(bad(format!("{} values given", args.len())));
                }
                let max_order = args[0]
                    .parse::<usize>()
                    .map_err(|_| bad(format!("'{}' is not a whole number", args[0])))?;
                let amps = nums(&args[1..])?;
                Effect::RotaryHarmonics {
                    max_order,
                    translation_um: amps.first().copied().unwrap_or(5.0),
                    rotation_urad: amps.get(1).copied().unwrap_or(10.0),
                }
            }
            "tracker-tilt" => {
                count(2)?;
                let v = nums(&args)?;
                Effect::TrackerTilt {
                    rx_urad: v[0],
                    ry_urad: v[1],
                }
            }
            "ball-screw" => {
                count(3)?;
                let mut letters = args[0].chars();
                let axis = match (letters.next().and_then(Axis::from_letter), letters.next()) {
                    (Some(a), None) => a,
                    _ => return Err(bad(format!("'{}' is not an axis letter", args[0]))),
                };
                let v = nums(&args[1..])?;
                Effect::BallScrew {
                    axis,
                    period_mm: v[0],
                    amplitude_um: v[1],
                }
            }
            "reflector-offset" => {
                count(4)?;
                let v = nums(&args[1..])?;
                Effect::ReflectorOffset {
                    reflector: args[0].to_string(),
                    delta_um: [v[0], v[1], v[2]],
                }
            }
            _ => {
                count(1)?;
                Effect::RangeScale { ppm: num(args[0])? }
            }
        })
    }

    /// Checks the effect against a machine.
    pub fn validate(&self, machine: &Machine) -> Result<()> {
        let place = || Place::file("effects").at_field(self.id());
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        let fail = |m: String| Err(Error::input(place(), m));
        match self {
            Effect::ThermalDrift { rate_um_per_h } if !finite(rate_um_per_h) => {
                fail("the drift rate must be finite".into())
            }
            Effect::RotaryHarmonics {
                max_order,
                translation_um,
                rotation_urad,
            } => {
                if !(2..=MAX_HARMONIC).contains(max_order) {
                    fail(format!(
                        "highest harmonic {max_order} is outside 2..={MAX_HARMONIC}"
                    ))
                } else if !finite(&[*translation_um, *rotation_urad]) {
                    fail("the amplitudes must be finite".into())
                } else if !machine.axes().iter().any(|a| a.axis.is_rotary()) {
                    fail(format!(
                        "the machine {} has no rotary axis",
                        machine.chain()
                    ))
                } else {
                    Ok(())
                }
            }
            Effect::TrackerTilt { rx_urad, ry_urad } if !finite(&[*rx_urad, *ry_urad]) => {
                fail("the tilt must be finite".into())
            }
            Effect::BallScrew {
                axis,
                period_mm,
                amplitude_um,
            } => {
                if axis.is_rotary() || machine.axis(*axis).is_none() {
                    fail(format!(
                        "{axis} is not a linear axis of {}",
                        machine.chain()
                    ))
                } else if !(period_mm.is_finite() && *period_mm > 0.0) {
                    fail(format!("the period {period_mm} mm must be positive"))
                } else if !amplitude_um.is_finite() {
                    fail("the amplitude must be finite".into())
                } else {
                    Ok(())
                }
            }
            Effect::ReflectorOffset {
                reflector,
                delta_um,
            } => {
                if machine.reflector_index(reflector).is_none() {
                    let ids: Vec<&str> =
                        machine.reflectors().iter().map(|r| r.id.as_str()).collect();
                    fail(format!(
                        "no reflector '{reflector}' in the machine (it has {})",
                        ids.join(", ")
                    ))
                } else if !finite(delta_um) {
                    fail("the offset error must be finite".into())
                } else {
                    Ok(())
                }
            }
            Effect::RangeScale { ppm } if !(ppm.is_finite() && *ppm > -1e6) => {
                fail(format!("{ppm} ppm is not a finite scale above −10⁶ ppm"))
            }
            _ => Ok(()),
        }
    }
}

impl fmt::Display for Effect {
    /// The CLI syntax, which [`Effect::parse`] reads back.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}=", self.id())?;
        match self {
            Effect::ThermalDrift { rate_um_per_h: v } => write!(f, "{},{},{}", v[0], v[1], v[2]),
            Effect::RotaryHarmonics {
                max_order,
                translation_um,
                rotation_urad,
            } => write!(f, "{max_order},{translation_um},{rotation_urad}"),
            Effect::TrackerTilt { rx_urad, ry_urad } => write!(f, "{rx_urad},{ry_urad}"),
            Effect::BallScrew {
                axis,
                period_mm,
                amplitude_um,
            } => write!(f, "{axis},{period_mm},{amplitude_um}"),
            Effect::ReflectorOffset {
                reflector,
                delta_um: d,
            } => write!(f, "{reflector},{},{},{}", d[0], d[1], d[2]),
            Effect::RangeScale { ppm } => write!(f, "{ppm}"),
        }
    }
}

/// Where the truth came from, for the record.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "source", rename_all = "kebab-case")]
pub enum TruthSource {
    /// Drawn by [`Truth::random`].
    Random {
        /// Name of the error-model structure.
        structure: String,
        /// The magnitudes.
        magnitudes: Magnitudes,
    },
    /// Read from a results file.
    File {
        /// Its path as given.
        path: String,
    },
    /// Built by a library caller.
    Given,
}

/// Names of the files a simulation writes, relative to its output folder.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimulationFiles {
    /// The measurement CSV.
    pub measurements: String,
    /// The truth (results-file JSON).
    pub truth: String,
    /// The machine (TOML).
    pub machine: String,
}

impl Default for SimulationFiles {
    fn default() -> Self {
        SimulationFiles {
            measurements: "measurements.csv".into(),
            truth: "truth.json".into(),
            machine: "machine.toml".into(),
        }
    }
}

/// What a simulation did, written as `simulation.json` beside its files.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimulationRecord {
    /// Always [`SIMULATION_FORMAT`].
    pub format: String,
    /// [`SIMULATION_VERSION`].
    pub version: u32,
    /// The seed.
    pub seed: u64,
    /// Plan name (preset or grid text).
    pub plan: String,
    /// Commanded positions.
    pub positions: usize,
    /// Measured points (positions × reflectors).
    pub points: usize,
    /// Reflector ids measured at every position.
    pub reflectors: Vec<String>,
    /// Test duration (s).
    pub duration_s: f64,
    /// The tracker noise.
    pub noise: TrackerNoise,
    /// Where the truth came from.
    pub truth: TruthSource,
    /// Hidden effects, in the order applied.
    pub effects: Vec<Effect>,
    /// The noise alone: measured minus noise-free points (the paper's "noise error").
    pub noise_error: ErrorStats,
    /// The machine's error as the tracker sees it without noise: noise-free points minus the
    /// nominal machine's points seen from the true tracker pose (effects included).
    pub machine_error: ErrorStats,
    /// The files written.
    pub files: SimulationFiles,
}

/// The inputs of a simulation.
#[derive(Clone, Debug)]
pub struct Simulation {
    /// Commanded positions and reflectors.
    pub plan: Plan,
    /// True errors and tracker pose (their model carries the machine).
    pub truth: Truth,
    /// Where the truth came from (recorded).
    pub truth_source: TruthSource,
    /// Tracker noise.
    pub noise: TrackerNoise,
    /// Effects outside the standard model.
    pub effects: Vec<Effect>,
    /// Test duration (s); [`DEFAULT_SECONDS_PER_POINT`] per point when `None`.
    pub duration_s: Option<f64>,
    /// Seed of the noise and of the harmonics' phases.
    pub seed: u64,
}

/// The output of a simulation.
#[derive(Clone, Debug)]
pub struct Synthetic {
    /// The measured points (with noise), as a measurement file holds them.
    pub measurements: MeasurementSet,
    /// The same points without noise (tracker frame, mm).
    pub noise_free: Vec<[f64; 3]>,
    /// The truth, effects that the error model expresses included (harmonics, tracker tilt).
    pub truth: Truth,
    /// The record.
    pub record: SimulationRecord,
}

impl Simulation {
    /// A simulation with the paper's tracker noise, no effects and the default duration.
    pub fn new(plan: Plan, truth: Truth, seed: u64) -> Simulation {
        Simulation {
            plan,
            truth,
            truth_source: TruthSource::Given,
            noise: TrackerNoise::PAPER,
            effects: Vec::new(),
            duration_s: None,
            seed,
        }
    }

    fn validate(&self) -> Result<f64> {
        let machine = self.truth.model.machine();
        let place = |field: &str| Place::file("simulation").at_field(field.to_string());
        if self.plan.positions.is_empty() || self.plan.reflectors.is_empty() {
            return Err(Error::input(
                place("plan"),
                "the plan measures no point (no position or no reflector)",
            ));
        }
        if let Some(&r) = self
            .plan
            .reflectors
            .iter()
            .find(|&&r| r >= machine.reflectors().len())
        {
            return Err(Error::input(
                place("plan.reflectors"),
                format!(
                    "reflector index {r}, but the machine has {}",
                    machine.reflectors().len()
                ),
            ));
        }
        for (i, cmd) in self.plan.positions.iter().enumerate() {
            for (k, ax) in machine.axes().iter().enumerate() {
                let u = cmd.0[k];
                let tol = 1e-9 * (ax.max - ax.min).abs().max(1.0);
                if !(u.is_finite() && u >= ax.min - tol && u <= ax.max + tol) {
                    return Err(Error::input(
                        place("plan.positions"),
                        format!(
                            "position {i}: {} = {} {} is outside the travel [{}, {}]",
                            ax.axis,
                            ax.to_file_units(u),
                            ax.file_unit(),
                            ax.to_file_units(ax.min),
                            ax.to_file_units(ax.max)
                        ),
                    ));
                }
            }
        }
        let n = self.plan.n_points() as f64;
        let duration = self.duration_s.unwrap_or(DEFAULT_SECONDS_PER_POINT * n);
        if !(duration.is_finite() && duration >= 0.0) {
            return Err(Error::input(
                place("duration_s"),
                format!("{duration} s is not a finite duration ≥ 0"),
            ));
        }
        let nz = &self.noise;
        let sigmas = [
            nz.azimuth_urad,
            nz.elevation_urad,
            nz.range_um,
            nz.range_um_per_m,
        ];
        if sigmas.iter().any(|s| !(s.is_finite() && *s >= 0.0)) {
            return Err(Error::input(
                place("noise"),
                "every noise value (σ or bound) must be a finite number ≥ 0",
            ));
        }
        for e in &self.effects {
            e.validate(machine)?;
        }
        Ok(duration)
    }

    /// Generates the measurements.
    pub fn run(&self) -> Result<Synthetic> {
        let duration = self.validate()?;
        let mut truth = self.truth.clone();
        let ts = truth.model.tracker_start();
        let mut drift = [0.0; 3]; // mm/s
        let mut scale = 1.0;
        let mut screws = Vec::new(); // (chain position, direction, amplitude mm, period mm, ref)
        for e in &self.effects {
            match e {
                Effect::RotaryHarmonics {
                    max_order,
                    translation_um,
                    rotation_urad,
                } => {
                    let mut rng = stream(self.seed, Stream::Harmonics);
                    truth = truth.with_harmonics(
                        *max_order,
                        translation_um * 1e-3,
                        rotation_urad * 1e-6,
                        &mut rng,
                    )?;
                }
                Effect::TrackerTilt { rx_urad, ry_urad } => {
                    truth.params[ts + 3] += rx_urad * 1e-6;
                    truth.params[ts + 4] += ry_urad * 1e-6;
                }
                Effect::ThermalDrift { rate_um_per_h } => {
                    for k in 0..3 {
                        drift[k] += rate_um_per_h[k] * 1e-3 / 3600.0;
                    }
                }
                Effect::RangeScale { ppm } => scale *= 1.0 + ppm * 1e-6,
                Effect::BallScrew {
                    axis,
                    period_mm,
                    amplitude_um,
                } => {
                    let (k, ax) = truth
                        .model
                        .machine()
                        .axis(*axis)
                        .expect("validated: the axis exists");
                    screws.push((
                        k,
                        axis.direction(),
                        amplitude_um * 1e-3,
                        *period_mm,
                        ax.reference,
                    ));
                }
                Effect::ReflectorOffset { .. } => {}
            }
        }
        let machine = truth.model.machine().clone();
        let mut offsets: Vec<[f64; 3]> = machine.reflectors().iter().map(|r| r.offset).collect();
        for e in &self.effects {
            if let Effect::ReflectorOffset {
                reflector,
                delta_um,
            } = e
            {
                let r = machine
                    .reflector_index(reflector)
                    .expect("validated: the reflector exists");
                for k in 0..3 {
                    offsets[r][k] += delta_um[k] * 1e-3;
                }
            }
        }
        let has_drift = drift != [0.0; 3];
        let mut nominal_errors = PointErrors::<f64>::zero();
        nominal_errors.tracker = truth.tracker_pose();

        let n = self.plan.n_points();
        let mut noise_rng = stream(self.seed, Stream::Noise);
        let mut points = Vec::with_capacity(n);
        let mut noise_free = Vec::with_capacity(n);
        let mut nominal = Vec::with_capacity(n);
        for (j, cmd) in self.plan.positions.iter().enumerate() {
            let mut errors = truth.model.errors_at(cmd, &truth.params);
            for &(k, dir, amp, period, reference) in &screws {
                errors.component[k][dir] +=
                    amp * (2.0 * PI * (cmd.0[k] - reference) / period).sin();
            }
            for (ri, &r) in self.plan.reflectors.iter().enumerate() {
                let i = j * self.plan.reflectors.len() + ri;
                let t_s = if n > 1 {
                    (duration * i as f64 / (n - 1) as f64 * 1e3).round() / 1e3
                } else {
                    0.0
                };
                let shift = has_drift.then(|| drift.map(|v| v * t_s));
                let clean = predict_with_tool_shift(&machine, cmd, &offsets[r], &errors, shift)
                    .map(|v| v * scale);
                let measured = self.noise.apply(clean, &mut noise_rng);
                if measured.iter().any(|v| !v.is_finite()) {
                    return Err(Error::Model(format!(
                        "point {i} is not finite: the truth or an effect is out of bounds"
                    )));
                }
                nominal.push(predict(
                    &machine,
                    cmd,
                    &machine.reflectors()[r].offset,
                    &nominal_errors,
                ));
                noise_free.push(clean);
                points.push(Measurement {
                    commands: *cmd,
                    reflector: r,
                    measured,
                    t_s: Some(t_s),
                    station: None,
                    line: i + 2,
                });
            }
        }
        let measured: Vec<[f64; 3]> = points.iter().map(|p| p.measured).collect();
        let record = SimulationRecord {
            format: SIMULATION_FORMAT.into(),
            version: SIMULATION_VERSION,
            seed: self.seed,
            plan: self.plan.name.clone(),
            positions: self.plan.positions.len(),
            points: n,
            reflectors: self
                .plan
                .reflectors
                .iter()
                .map(|&r| machine.reflectors()[r].id.clone())
                .collect(),
            duration_s: duration,
            noise: self.noise,
            truth: self.truth_source.clone(),
            effects: self.effects.clone(),
            noise_error: ErrorStats::between(&measured, &noise_free),
            machine_error: ErrorStats::between(&noise_free, &nominal),
            files: SimulationFiles::default(),
        };
        Ok(Synthetic {
            measurements: MeasurementSet { points },
            noise_free,
            truth,
            record,
        })
    }
}

impl Synthetic {
    /// Writes the measurement file, the truth, the machine file and `simulation.json` into
    /// `dir` (created if missing; existing files of these names are replaced). Returns the
    /// paths written.
    pub fn write(&self, dir: &Path) -> Result<Vec<PathBuf>> {
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| Error::Io { path, source }
        };
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let machine = self.truth.model.machine();
        let files = &self.record.files;
        let measurements = dir.join(&files.measurements);
        crate::fsio::write_atomic(&measurements, self.measurements.to_csv_string(machine))
            .map_err(io(&measurements))?;
        let truth = dir.join(&files.truth);
        self.truth.to_results()?.save(&truth)?;
        let machine_path = dir.join(&files.machine);
        let toml_text = toml::to_string(machine.spec())
            .map_err(|e| Error::Model(format!("writing the machine file: {e}")))?;
        crate::fsio::write_atomic(
            &machine_path,
            format!(
                "# The machine used by `volver simulate` (seed {}, plan {}).\n{toml_text}",
                self.record.seed, self.record.plan
            ),
        )
        .map_err(io(&machine_path))?;
        let record = dir.join("simulation.json");
        let json = serde_json::to_string_pretty(&self.record).expect("record serialises");
        crate::fsio::write_atomic(&record, json + "\n").map_err(io(&record))?;
        Ok(vec![measurements, truth, machine_path, record])
    }
}
