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
//! | `thermal-scale` | axis, α ppm/h | the positioning error of a linear axis gets `α·10⁻⁶·u·t` (u its position in mm, t in h): its scale grows with time |
//! | `location-drift` | rotary axis, v₁, v₂ µm/h | its two location translations (X0C, Y0C for C) grow by `v·t` |
//! | `tracker-drift` | ω = (ωx, ωy, ωz) µrad/h | the tracker's small rotations (eq. 9) grow by `ω·t`: its stand turning as it warms |
//! | `station-drift` | station id, v = (vx, vy, vz) µm/h | that station's position grows by `v·t` in the frame it is mounted in (machines with `[[station]]` tables) |
//! | `coupling` | axis, component, by, A µm | the error E{component}{axis} gets `A·sin(π·ξ)·η`, ξ and η the positions of the axis and of `by` over their travels, 0 … 1: a straightness bow that grows with another axis' position, which no rigid-body error expresses |
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

/// mm in one µm (`1e-3` bit for bit: the nearest double to 1/1000).
pub(crate) const MM_PER_UM: f64 = 1.0 / crate::units::UM_PER_MM;

/// rad in one µrad (`1e-6` bit for bit).
pub(crate) const RAD_PER_URAD: f64 = 1.0 / crate::units::URAD_PER_RAD;

/// The `format` field of a simulation record.
pub const SIMULATION_FORMAT: &str = "volver-simulation";

/// The current simulation-record version.
pub const SIMULATION_VERSION: u32 = 1;

/// Test duration used when none is given, re-exported from [`crate::plan`] where it lives (kept
/// at this path for existing users).
pub use crate::plan::DEFAULT_SECONDS_PER_POINT;

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

mod effects;
mod magnitudes;
mod sample;
mod truth;
pub use effects::{EFFECTS, Effect};
pub use magnitudes::{MAGNITUDE_KINDS, Magnitudes};
pub use truth::Truth;

/// Where the truth came from, for the record.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "source", rename_all = "kebab-case")]
#[non_exhaustive]
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
    /// What every station observes: points (the tracker), or ranges alone (tracing
    /// interferometers, or a tracker's ranges). A machine with `[[station]]` tables is measured
    /// from each station in turn (one instrument moved between them: all the plan from the
    /// first, then from the next), with the noise's range part alone for a range.
    pub observe: crate::measure::Observation,
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
            observe: crate::measure::Observation::Point,
        }
    }

    /// Checks the simulation before it runs: its plan against the machine, the observation, the
    /// duration (s, returned), the noise and the effects.
    fn validate(&self) -> Result<f64> {
        self.validate_plan()?;
        let machine = self.truth.model.machine();
        let place = |field: &str| Place::file("simulation").at_field(field.to_string());
        let n = (self.plan.n_points() * machine.stations().len()) as f64;
        if self.observe == crate::measure::Observation::Point
            && let Some(st) = machine
                .stations()
                .iter()
                .find(|s| s.observes == crate::machine::Observes::Range)
        {
            return Err(Error::input(
                place("observe"),
                format!(
                    "station '{}' observes ranges only: simulate it with ranges (--observe range)",
                    st.id
                ),
            ));
        }
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

    /// Checks the plan against the machine: some point measured, every step's position and
    /// reflector, every reflector, every position within the travel.
    fn validate_plan(&self) -> Result<()> {
        let machine = self.truth.model.machine();
        let place = |field: &str| Place::file("simulation").at_field(field.to_string());
        if self.plan.positions.is_empty() || self.plan.n_points() == 0 {
            return Err(Error::input(
                place("plan"),
                "the plan measures no point (no position or no reflector)",
            ));
        }
        if let Some(sequence) = &self.plan.sequence
            && let Some((i, s)) = sequence.iter().enumerate().find(|(_, s)| {
                s.position >= self.plan.positions.len() || s.reflector >= machine.reflectors().len()
            })
        {
            return Err(Error::input(
                place("plan.sequence"),
                format!(
                    "step {i} measures reflector index {} at position {}, but the plan has {} \
                     positions and the machine {} reflectors",
                    s.reflector,
                    s.position,
                    self.plan.positions.len(),
                    machine.reflectors().len()
                ),
            ));
        }
        if let Some(a) = &self.plan.approach
            && a.len() != self.plan.n_points()
        {
            return Err(Error::input(
                place("plan.approach"),
                format!(
                    "{} stated directions of approach for {} measurements: one per measurement",
                    a.len(),
                    self.plan.n_points()
                ),
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
        Ok(())
    }
}

impl Simulation {
    /// Adds the `coupling` effects to the errors at `cmd`.
    fn couple(
        &self,
        machine: &Machine,
        cmd: &crate::machine::Commands,
        errors: &mut PointErrors<f64>,
    ) {
        for e in &self.effects {
            if let Effect::Coupling {
                axis,
                component,
                by,
                amplitude_um,
            } = e
            {
                let (k, ax) = machine.axis(*axis).expect("validated: the axis exists");
                let (kb, bx) = machine.axis(*by).expect("validated: the axis exists");
                let xi = (cmd.0[k] - ax.min) / (ax.max - ax.min);
                let eta = (cmd.0[kb] - bx.min) / (bx.max - bx.min);
                errors.component[k][component.direction()] +=
                    amplitude_um * MM_PER_UM * (PI * xi).sin() * eta;
            }
        }
    }

    /// The errors at `cmd` at time `t_s` (s): `errors` with the effects that grow with time
    /// (`thermal-scale`, `location-drift`, `tracker-drift`).
    fn age(
        &self,
        machine: &Machine,
        cmd: &crate::machine::Commands,
        t_s: f64,
        errors: &PointErrors<f64>,
    ) -> PointErrors<f64> {
        let mut out = *errors;
        let t_h = t_s / crate::units::S_PER_H;
        for e in &self.effects {
            match e {
                Effect::ThermalScale { axis, ppm_per_h } => {
                    let (k, _) = machine.axis(*axis).expect("validated: the axis exists");
                    out.component[k][axis.direction()] +=
                        ppm_per_h * (1.0 / crate::units::PPM) * cmd.0[k] * t_h;
                }
                Effect::TrackerDrift { rate_urad_per_h } => {
                    for (k, v) in rate_urad_per_h.iter().enumerate() {
                        out.tracker[3 + k] += v * RAD_PER_URAD * t_h;
                    }
                }
                Effect::StationDrift {
                    station,
                    rate_um_per_h,
                } if machine.station_named(Some(station)) == Ok(errors.station) => {
                    for (k, v) in rate_um_per_h.iter().enumerate() {
                        out.tracker[k] += v * MM_PER_UM * t_h;
                    }
                }
                Effect::LocationDrift {
                    axis,
                    rate_um_per_h,
                } => {
                    let (k, _) = machine.axis(*axis).expect("validated: the axis exists");
                    out.has_location[k] = true;
                    let across = (0..3).filter(|&c| c != axis.direction());
                    for (c, v) in across.zip(rate_um_per_h) {
                        out.location[k][c] += v * MM_PER_UM * t_h;
                    }
                }
                _ => {}
            }
        }
        out
    }
}

impl Synthetic {
    /// Writes the measurement file, the truth, the machine file and `simulation.json` into
    /// `dir` (created if missing; existing files of these names are replaced). Returns the
    /// paths written.
    pub fn write(&self, dir: &Path) -> Result<Vec<PathBuf>> {
        self.write_as(dir, crate::measure::PointColumns::Cartesian)
    }

    /// [`Synthetic::write`] with the measured points in `columns` (spherical: `az_deg`,
    /// `el_deg`, `range_mm`, as a tracker's software exports them).
    pub fn write_as(
        &self,
        dir: &Path,
        columns: crate::measure::PointColumns,
    ) -> Result<Vec<PathBuf>> {
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| Error::Io { path, source }
        };
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let machine = self.truth.model.machine();
        let files = &self.record.files;
        let measurements = dir.join(&files.measurements);
        crate::fsio::write_atomic(
            &measurements,
            self.measurements.to_csv_with(machine, columns),
        )
        .map_err(io(&measurements))?;
        let truth = dir.join(&files.truth);
        let machine_path = dir.join(&files.machine);
        // The machine file, and the truth's machine, state the tracker's noise the data were
        // made with: the files agree with each other and with simulation.json.
        let mut spec = machine.spec().clone();
        spec.tracker.noise = (!self.record.noise.is_none()).then(|| self.record.noise.to_string());
        let mut results = self.truth.to_results()?;
        results.machine.clone_from(&spec);
        results.save(&truth)?;
        let toml_text = toml::to_string(&spec).map_err(|e| Error::Serialize {
            message: format!("writing the machine file: {e}"),
        })?;
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
