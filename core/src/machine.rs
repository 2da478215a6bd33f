//! Machine description (TOML): the chain, each axis' travel range, offsets and reference (home)
//! position, the reflectors, and where the tracker stands.
//!
//! ```toml
//! name = "XCFZ grinder"
//! chain = "XCFZ"
//!
//! [axes.X]
//! range = [0.0, 1400.0]           # mm for X, Y, Z; degrees for A, B, C
//! offset = [0.0, 0.0, 0.0]        # mm: this axis' origin in the frame of the axis it rides on
//! reference = 0.0                 # home position; linear-axis errors vanish there
//!
//! [axes.C]
//! range = [0.0, 360.0]
//!
//! [axes.Z]
//! range = [0.0, 600.0]
//! offset = [1000.0, 25.0, 1500.0]
//!
//! [[reflector]]
//! id = "R1"
//! offset = [-50.0, 50.0, -50.0]   # mm, in the frame of the last tool-side axis
//!
//! [tracker]
//! mount = "workpiece"             # on the workpiece end of the chain, or "frame"
//! position = [0.0, 0.0, 0.0]      # mm: nominal T_LT, the start of its identification
//! orientation_deg = [0.0, 0.0, 0.0] # base rotation R0 = Rz·Ry·Rx (degrees) under the small angles
//! noise = "uniform:30,30,4,0.8"   # optional: the tracker's noise, as `--noise` reads it
//! ```
//!
//! A `[clearance]` table gives the position the measuring program (`volver plan --gcode`)
//! retracts to between poses: the axes that take the reflectors away from the workpiece and the
//! tracker, in file units (here the tool-carrying Z at its top):
//!
//! ```toml
//! [clearance]
//! Z = 600.0                       # mm (degrees for a rotary axis); within the axis' travel
//! ```
//!
//! For multilateration, `[[station]]` tables replace the tracker's pose (the `[tracker]` table
//! then gives only the default noise); each measurement names its station:
//!
//! ```toml
//! [[station]]
//! id = "S1"
//! mount = "workpiece"
//! position = [353.55, 353.55, 0.0]
//! observes = "range"                # "point" (a tracker) or "range" (a tracing interferometer)
//! noise = "normal:0,0,0.1,0.15"     # optional: its own noise, else the [tracker] table's
//! ```
//!
//! Each station's own noise is the one the generator draws, the noise-weighted fits whiten
//! by, the diagnosis judges its residuals against, and the design and the uncertainty weigh it
//! by: a tracker and a tracing interferometer in one fit each count by their own model.
//!
//! Internally every length is in mm and every angle in rad; degrees exist only in files.

use crate::chain::{Chain, MAX_AXES, Side};
use crate::error::{Error, Place, Result, from_toml, line_of_text};
use crate::iso::Axis;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

mod validate;

/// The largest magnitude of a range, offset or position in a machine file (mm or degrees): 1 km,
/// beyond any machine; larger numbers are a wrong unit or garbage (and would be written back as
/// hundreds of digits).
pub const MAX_DIMENSION: f64 = 1e6;

/// The embedded default machine: the paper's XCFZ grinder (tables 2, 3 and 7; C 0–360°).
pub const DEFAULT_MACHINE_TOML: &str = include_str!("../data/xcfz.toml");

/// Label used in messages for the embedded default machine.
pub const DEFAULT_MACHINE_LABEL: &str = "<embedded XCFZ machine>";

/// One axis as written in the machine file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisSpec {
    /// Travel `[min, max]`: mm for linear axes, degrees for rotary axes.
    pub range: [f64; 2],
    /// Origin of this axis in the frame of the axis it is mounted on (mm).
    #[serde(default)]
    pub offset: [f64; 3],
    /// Reference (home) position, mm or degrees, inside the range. Linear-axis errors vanish here.
    #[serde(default)]
    pub reference: f64,
}

/// One reflector as written in the machine file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReflectorSpec {
    /// Identifier used by the measurement file's `reflector` column.
    pub id: String,
    /// Position in the frame of the last tool-side axis (the frame if there is none), mm.
    pub offset: [f64; 3],
}

/// Where the tracker stands.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[non_exhaustive]
pub enum TrackerMount {
    /// On the workpiece end of the chain (the paper: on the turntable of XCFZ); it moves with the
    /// workpiece-side axes and measures the tool relative to the workpiece.
    #[default]
    Workpiece,
    /// On the machine frame; workpiece-side axes then do not move the measured point.
    Frame,
}

/// The tracker as written in the machine file.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackerSpec {
    /// Where the tracker stands.
    #[serde(default)]
    pub mount: TrackerMount,
    /// Nominal translation T_LT (mm): the starting value of the tracker's x, y, z parameters.
    #[serde(default)]
    pub position: [f64; 3],
    /// Base orientation R0 = Rz(rz)·Ry(ry)·Rx(rx) as `[rx, ry, rz]` in degrees. The identified
    /// small angles (eq. 9) act on top of it; the paper's set-up has it zero.
    #[serde(default)]
    pub orientation_deg: [f64; 3],
    /// The tracker's noise as `--noise` reads it ([`crate::noise::TrackerNoise::from_text`]:
    /// `uniform:30,30,4,0.8`, `normal:…`, `mpe:15,6` …): what `volver diagnose` compares the fit
    /// with; with `[[station]]` tables, the noise of every station that states none of its own.
    /// Absent (and no station's own): the diagnosis can only estimate the noise from repeated
    /// points.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise: Option<String>,
}

/// The most tracker stations a machine may have (each measures the whole plan).
pub const MAX_STATIONS: usize = 1000;

/// A machine description as written in the TOML file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MachineSpec {
    /// Human-readable name.
    pub name: String,
    /// Chain notation, e.g. `XCFZ`.
    pub chain: String,
    /// One entry per axis of the chain, keyed by its letter.
    pub axes: BTreeMap<String, AxisSpec>,
    /// The reflectors (at least one).
    #[serde(rename = "reflector")]
    pub reflectors: Vec<ReflectorSpec>,
    /// The tracker.
    #[serde(default)]
    pub tracker: TrackerSpec,
    /// The clearance position of the measuring program (`volver plan --gcode`): axis letter =
    /// position (mm for X, Y, Z; degrees for A, B, C) of the axes that take the reflectors away
    /// from the workpiece and the tracker, e.g. `Z = 600.0`. Between poses the program moves
    /// these axes there first, then the others, then these back to the pose. Optional; every
    /// axis named must be the machine's and the value within its travel.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clearance: Option<BTreeMap<String, f64>>,
    /// Tracker stations, for multilateration (several positions of one instrument, or several
    /// instruments): when any is given they replace the `[tracker]` table's pose, the first being
    /// the reference station, and every measurement names its station.
    #[serde(default, rename = "station", skip_serializing_if = "Vec::is_empty")]
    pub stations: Vec<StationSpec>,
}

/// A station layout file: `[[station]]` tables as in a machine file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct LayoutFile {
    #[serde(rename = "station")]
    stations: Vec<StationSpec>,
}

impl StationSpec {
    /// Reads a station layout (TOML: `[[station]]` tables as in a machine file); `file` names
    /// it in messages. At least one station.
    pub fn layout_from_toml_str(text: &str, file: &str) -> Result<Vec<StationSpec>> {
        let text = crate::error::without_bom(text);
        let layout: LayoutFile = toml::from_str(text).map_err(|e| from_toml(file, text, e))?;
        if layout.stations.is_empty() {
            return Err(Error::input(
                Place::file(file).at_field("station"),
                "a station layout needs at least one [[station]] table",
            ));
        }
        Ok(layout.stations)
    }

    /// A default layout of `n` stations S1 … Sn around `machine`'s tracker, mounted as it is,
    /// observing `observes`: on a circle of 500 mm radius about its nominal position (the first
    /// at 45°), every other one raised by 400 mm, so that the stations see the volume from
    /// directions spread in azimuth and in elevation.
    pub fn default_layout(machine: &Machine, n: usize, observes: Observes) -> Vec<StationSpec> {
        let t = machine.tracker();
        let [rx, ry, rz] = rotation_angles_deg(&t.base_rotation);
        (0..n)
            .map(|k| {
                let a = std::f64::consts::FRAC_PI_4 + std::f64::consts::TAU * k as f64 / n as f64;
                let lift = if k % 2 == 1 { 400.0 } else { 0.0 };
                let round = |v: f64| (v * 1e6).round() / 1e6;
                StationSpec {
                    id: format!("S{}", k + 1),
                    mount: t.mount,
                    position: [
                        round(t.position[0] + 500.0 * a.cos()),
                        round(t.position[1] + 500.0 * a.sin()),
                        t.position[2] + lift,
                    ],
                    orientation_deg: [rx, ry, rz],
                    observes,
                    noise: None,
                }
            })
            .collect()
    }
}

/// The angles `[rx, ry, rz]` (degrees) of a rotation Rz·Ry·Rx ([`base_rotation`]'s inverse).
fn rotation_angles_deg(r: &[[f64; 3]; 3]) -> [f64; 3] {
    let ry = (-r[2][0]).clamp(-1.0, 1.0).asin();
    let rx = r[2][1].atan2(r[2][2]);
    let rz = r[1][0].atan2(r[0][0]);
    [rx, ry, rz].map(|v| (v.to_degrees() * 1e9).round() / 1e9)
}

/// What a station observes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Observes {
    /// A laser tracker: points (its angles and range), or any of its ranges alone.
    #[default]
    Point,
    /// A tracing interferometer: ranges only. Its orientation means nothing and is held.
    Range,
}

/// One tracker station as written in the machine file (`[[station]]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StationSpec {
    /// Identifier used by the measurement file's `station` column.
    pub id: String,
    /// Where it stands.
    #[serde(default)]
    pub mount: TrackerMount,
    /// Nominal position (mm): the start of its identification.
    #[serde(default)]
    pub position: [f64; 3],
    /// Base orientation `[rx, ry, rz]` (degrees), as the tracker's.
    #[serde(default)]
    pub orientation_deg: [f64; 3],
    /// What it observes (`point` or `range`).
    #[serde(default)]
    pub observes: Observes,
    /// Its noise as `--noise` reads it; absent: the tracker's default (`--noise`, or the
    /// `[tracker]` table's). `normal:0,0,0.1,0.15` is an interferometer of U(k = 2) = 0.2 µm +
    /// 0.3 µm/m. Each station's own noise is used by the generator, the noise-weighted fits
    /// (`ml`, `phi-w`), the diagnosis (its noise verdict per station), the design and the
    /// uncertainty ([`Machine::station_own_noise`]); a range takes its range part alone.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise: Option<String>,
}

/// An axis of a validated machine, in internal units (mm, rad).
#[derive(Clone, Debug, PartialEq)]
pub struct MachineAxis {
    /// The axis letter.
    pub axis: Axis,
    /// Workpiece or tool side.
    pub side: Side,
    /// Lower travel limit (mm or rad).
    pub min: f64,
    /// Upper travel limit (mm or rad).
    pub max: f64,
    /// Reference (home) position (mm or rad).
    pub reference: f64,
    /// Origin in the frame of the axis it rides on (mm).
    pub offset: [f64; 3],
}

impl MachineAxis {
    /// Whether the axis is rotary with a travel of exactly one turn (its ends the same angle).
    pub fn is_full_turn(&self) -> bool {
        self.axis.is_rotary() && (self.max - self.min - std::f64::consts::TAU).abs() < 1e-9
    }

    /// Position mapped to [−1, 1] over the travel range (the argument of polynomial bases).
    pub fn normalise(&self, position: f64) -> f64 {
        self.normalise_at(position)
    }

    /// [`MachineAxis::normalise`] for any scalar of the forward model (a dual number carries
    /// the derivative along the position).
    pub fn normalise_at<S: crate::scalar::Real>(&self, position: S) -> S {
        (position - self.min) * 2.0 / (self.max - self.min) - 1.0
    }

    /// Converts a position from file units (mm, or degrees for rotary axes) to internal units.
    pub fn from_file_units(&self, value: f64) -> f64 {
        if self.axis.is_rotary() {
            value.to_radians()
        } else {
            value
        }
    }

    /// Converts a position from internal units to file units (mm, or degrees).
    pub fn to_file_units(&self, value: f64) -> f64 {
        if self.axis.is_rotary() {
            value.to_degrees()
        } else {
            value
        }
    }

    /// Unit name of positions in files: `mm` or `deg`.
    pub fn file_unit(&self) -> &'static str {
        if self.axis.is_rotary() { "deg" } else { "mm" }
    }

    /// A position read from a file (file units) in internal units, or the message saying it is
    /// outside the travel (a tolerance of 1e-9 of the travel).
    ///
    /// ```
    /// let m = volver_core::machine::Machine::default_xcfz();
    /// let x = &m.axes()[0];
    /// assert_eq!(x.position_from_file(1400.0), Ok(1400.0));
    /// assert_eq!(
    ///     x.position_from_file(1500.0).unwrap_err().to_string(),
    ///     "1500 mm is outside the travel range [0, 1400] of axis X"
    /// );
    /// ```
    pub fn position_from_file(&self, v: f64) -> std::result::Result<f64, OutOfTravel> {
        let (lo, hi) = (self.to_file_units(self.min), self.to_file_units(self.max));
        let tol = 1e-9 * (hi - lo).abs().max(1.0);
        if v < lo - tol || v > hi + tol {
            return Err(OutOfTravel {
                value: v,
                unit: self.file_unit(),
                lo,
                hi,
                axis: self.axis,
            });
        }
        Ok(self.from_file_units(v))
    }
}

/// A position outside an axis' travel (in the file's units: mm or deg).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{value} {unit} is outside the travel range [{lo}, {hi}] of axis {axis}")]
pub struct OutOfTravel {
    /// The position given.
    pub value: f64,
    /// Its unit: `mm` or `deg`.
    pub unit: &'static str,
    /// The travel's lower end.
    pub lo: f64,
    /// The travel's upper end.
    pub hi: f64,
    /// The axis.
    pub axis: Axis,
}

impl From<OutOfTravel> for String {
    fn from(e: OutOfTravel) -> String {
        e.to_string()
    }
}

/// A reflector or station a measurement names that the machine cannot give.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum NameError {
    /// No reflector of that id.
    #[error("reflector '{id}' is not in the machine file (known: {})", known.join(", "))]
    UnknownReflector {
        /// The id given.
        id: String,
        /// The machine's reflector ids.
        known: Vec<String>,
    },
    /// No station of that id.
    #[error("station '{id}' is not in the machine file (known: {})", known.join(", "))]
    UnknownStation {
        /// The id given.
        id: String,
        /// The machine's station ids.
        known: Vec<String>,
    },
    /// No station named although the machine has several.
    #[error(
        "no station given: the machine file has {stations} stations, so every measurement names \
         its own"
    )]
    StationNotGiven {
        /// The machine's number of stations.
        stations: usize,
    },
}

impl From<NameError> for String {
    fn from(e: NameError) -> String {
        e.to_string()
    }
}

/// A reflector of a validated machine.
#[derive(Clone, Debug, PartialEq)]
pub struct Reflector {
    /// Identifier.
    pub id: String,
    /// Offset in the frame of the last tool-side axis (mm).
    pub offset: [f64; 3],
}

/// The tracker of a validated machine.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackerSetup {
    /// Where it stands.
    pub mount: TrackerMount,
    /// Nominal translation T_LT (mm).
    pub position: [f64; 3],
    /// Base rotation R0 (row-major 3×3), applied as R0ᵀ before the small rotation of eq. 9.
    pub base_rotation: [[f64; 3]; 3],
    /// Its noise, when the machine file states it: a station's own, else the `[tracker]`
    /// table's ([`Machine::default_noise`] is the latter alone).
    pub noise: Option<crate::noise::TrackerNoise>,
}

/// A tracker station of a validated machine.
#[derive(Clone, Debug, PartialEq)]
pub struct Station {
    /// Identifier (empty for the `[tracker]` of a machine without `[[station]]` tables).
    pub id: String,
    /// Its pose and noise.
    pub setup: TrackerSetup,
    /// What it observes.
    pub observes: Observes,
}

/// A validated machine in internal units. Build it with [`Machine::from_toml_str`],
/// [`Machine::load`] or [`Machine::default_xcfz`].
///
/// ```
/// use volver_core::machine::Machine;
/// let m = Machine::default_xcfz();
/// assert_eq!(m.chain().to_string(), "XCFZ");
/// assert_eq!(m.axes().len(), 3);
/// assert_eq!(m.reflector_index("R2"), Some(1));
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct Machine {
    spec: MachineSpec,
    chain: Chain,
    axes: Vec<MachineAxis>,
    reflectors: Vec<Reflector>,
    stations: Vec<Station>,
    clearance: Vec<(usize, f64)>,
}

impl Machine {
    /// The embedded default machine (the paper's XCFZ grinder).
    pub fn default_xcfz() -> Machine {
        Machine::from_toml_str(DEFAULT_MACHINE_TOML, DEFAULT_MACHINE_LABEL)
            .expect("the embedded machine is valid")
    }

    /// Reads and validates a machine file.
    pub fn load(path: &Path) -> Result<Machine> {
        let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Machine::from_toml_str(&text, &path.display().to_string())
    }

    /// Parses and validates machine TOML; `file` names the source in error messages.
    pub fn from_toml_str(text: &str, file: &str) -> Result<Machine> {
        let text = crate::error::without_bom(text);
        let spec: MachineSpec = toml::from_str(text).map_err(|e| from_toml(file, text, e))?;
        Machine::from_spec_located(spec, file, Some(text))
    }

    /// Validates a machine specification (e.g. one read back from a results file).
    pub fn from_spec(spec: MachineSpec, label: &str) -> Result<Machine> {
        Machine::from_spec_located(spec, label, None)
    }

    /// The specification this machine was built from (what files store).
    pub fn spec(&self) -> &MachineSpec {
        &self.spec
    }

    /// The chain.
    pub fn chain(&self) -> &Chain {
        &self.chain
    }

    /// The axes in chain order (see [`Chain::axes`]).
    pub fn axes(&self) -> &[MachineAxis] {
        &self.axes
    }

    /// The axis with a given letter and its chain position.
    pub fn axis(&self, axis: Axis) -> Option<(usize, &MachineAxis)> {
        self.axes.iter().enumerate().find(|(_, a)| a.axis == axis)
    }

    /// The axis a file names by its letter (`"X"`, `"C"`), as [`Machine::axis`]; `None` for
    /// anything but one letter of an axis of this machine.
    ///
    /// ```
    /// let m = volver_core::machine::Machine::default_xcfz();
    /// assert_eq!(m.axis_named("C").map(|(k, _)| k), Some(1));
    /// assert!(m.axis_named("Y").is_none() && m.axis_named("XC").is_none());
    /// ```
    pub fn axis_named(&self, name: &str) -> Option<(usize, &MachineAxis)> {
        let mut letters = name.chars();
        match (letters.next().and_then(Axis::from_letter), letters.next()) {
            (Some(a), None) => self.axis(a),
            _ => None,
        }
    }

    /// The reflectors.
    pub fn reflectors(&self) -> &[Reflector] {
        &self.reflectors
    }

    /// Index of a reflector by id.
    pub fn reflector_index(&self, id: &str) -> Option<usize> {
        self.reflectors.iter().position(|r| r.id == id)
    }

    /// The index of the reflector `id`, or the message naming the ones the machine has.
    ///
    /// ```
    /// let m = volver_core::machine::Machine::default_xcfz();
    /// assert_eq!(m.reflector_named("R2"), Ok(1));
    /// assert_eq!(
    ///     m.reflector_named("R9").unwrap_err().to_string(),
    ///     "reflector 'R9' is not in the machine file (known: R1, R2)"
    /// );
    /// ```
    pub fn reflector_named(&self, id: &str) -> std::result::Result<usize, NameError> {
        self.reflector_index(id)
            .ok_or_else(|| NameError::UnknownReflector {
                id: id.to_string(),
                known: self.reflectors.iter().map(|r| r.id.clone()).collect(),
            })
    }

    /// This machine measured from `stations` instead of its tracker (or its stations): the
    /// `[tracker]` table keeps only its noise, the default of the stations'.
    ///
    /// ```
    /// use volver_core::machine::{Machine, Observes, StationSpec};
    /// let m = Machine::default_xcfz();
    /// let layout = StationSpec::default_layout(&m, 4, Observes::Range);
    /// let multi = m.with_stations(layout).unwrap();
    /// assert_eq!(multi.stations().len(), 4);
    /// assert_eq!(multi.station_named(Some("S3")), Ok(2));
    /// assert!(multi.station_named(None).unwrap_err().to_string().contains("4 stations"));
    /// ```
    pub fn with_stations(&self, stations: Vec<StationSpec>) -> Result<Machine> {
        let mut spec = self.spec.clone();
        spec.tracker.position = [0.0; 3];
        spec.tracker.orientation_deg = [0.0; 3];
        spec.stations = stations;
        Machine::from_spec(spec, "station layout")
    }

    /// The tracker set-up: the reference station's (the first `[[station]]`, or the
    /// `[tracker]` table).
    pub fn tracker(&self) -> &TrackerSetup {
        &self.stations[0].setup
    }

    /// The tracker stations: one, the `[tracker]` table, unless the machine file gives
    /// `[[station]]` tables.
    pub fn stations(&self) -> &[Station] {
        &self.stations
    }

    /// The noise station `k`'s own `[[station]]` table states; `None` when it states none (or
    /// the machine has no `[[station]]` tables): the tracker's default noise — the `[tracker]`
    /// table's or `--noise` — is then the station's.
    ///
    /// ```
    /// use volver_core::machine::Machine;
    /// let m = Machine::default_xcfz();
    /// assert_eq!(m.station_own_noise(0), None);
    /// ```
    pub fn station_own_noise(&self, k: usize) -> Option<crate::noise::TrackerNoise> {
        let stated = self.spec.stations.get(k)?.noise.is_some();
        stated.then(|| self.stations.get(k)?.setup.noise).flatten()
    }

    /// The tracker's default noise: the `[tracker]` table's, which every station without its
    /// own takes; `None` when the table states none. Not [`Machine::tracker`]'s noise, which
    /// is the first station's own when it states one.
    ///
    /// ```
    /// use volver_core::machine::{Machine, Observes, StationSpec};
    /// use volver_core::noise::TrackerNoise;
    /// let m = Machine::default_xcfz();
    /// assert_eq!(m.default_noise(), Some(TrackerNoise::PAPER));
    /// let mut layout = StationSpec::default_layout(&m, 2, Observes::Range);
    /// layout[0].noise = Some("normal:0,0,0.1,0.15".into());
    /// let multi = m.with_stations(layout).unwrap();
    /// assert_eq!(multi.default_noise(), Some(TrackerNoise::PAPER));
    /// assert_eq!(multi.tracker().noise.unwrap().to_string(), "normal:0,0,0.1,0.15");
    /// assert_eq!(multi.station_noise_or(1, TrackerNoise::PAPER), TrackerNoise::PAPER);
    /// ```
    pub fn default_noise(&self) -> Option<crate::noise::TrackerNoise> {
        // Validated with the machine: a noise it states reads.
        let text = self.spec.tracker.noise.as_deref()?;
        crate::noise::TrackerNoise::from_text(text).ok()
    }

    /// Station `k`'s noise: its own ([`Machine::station_own_noise`]), else `default` (the
    /// tracker's: the `[tracker]` table's or `--noise`).
    pub fn station_noise_or(
        &self,
        k: usize,
        default: crate::noise::TrackerNoise,
    ) -> crate::noise::TrackerNoise {
        self.station_own_noise(k).unwrap_or(default)
    }

    /// Whether the machine file gives `[[station]]` tables (measurements then name their
    /// station).
    pub fn has_stations(&self) -> bool {
        !self.spec.stations.is_empty()
    }

    /// The index of the station a measurement names (`None`: no station given), or the message
    /// saying why it cannot be used. Without `[[station]]` tables every measurement is the
    /// tracker's, whatever its label; with them a station must be named when there are several.
    ///
    /// ```
    /// let m = volver_core::machine::Machine::default_xcfz();
    /// assert_eq!(m.station_named(Some("anything")), Ok(0));
    /// ```
    pub fn station_named(&self, id: Option<&str>) -> std::result::Result<usize, NameError> {
        if !self.has_stations() {
            return Ok(0);
        }
        match id {
            None if self.stations.len() == 1 => Ok(0),
            None => Err(NameError::StationNotGiven {
                stations: self.stations.len(),
            }),
            Some(id) => self
                .stations
                .iter()
                .position(|s| s.id == id)
                .ok_or_else(|| NameError::UnknownStation {
                    id: id.to_string(),
                    known: self.stations.iter().map(|s| s.id.clone()).collect(),
                }),
        }
    }

    /// The clearance position of the machine file's `[clearance]` table: (chain index of the
    /// axis, position in internal units: mm, rad), in chain order; empty when the file has none.
    ///
    /// ```
    /// let m = volver_core::machine::Machine::default_xcfz();
    /// assert_eq!(m.clearance(), &[(2, 600.0)]); // Z (the tool) at its top
    /// ```
    pub fn clearance(&self) -> &[(usize, f64)] {
        &self.clearance
    }

    /// A clearance position written as `--clearance` takes it: `AXIS=VALUE` pairs separated by
    /// commas, values in file units (mm, degrees), e.g. `Z=600` or `Z=400,A=0`; the result as
    /// [`Machine::clearance`], or the message naming the pair that is wrong.
    ///
    /// ```
    /// let m = volver_core::machine::Machine::default_xcfz();
    /// assert_eq!(m.clearance_from_text("Z=550"), Ok(vec![(2, 550.0)]));
    /// assert!(m.clearance_from_text("Z=700").unwrap_err().contains("travel range [0, 600]"));
    /// assert!(m.clearance_from_text("Y=0").unwrap_err().contains("no axis Y"));
    /// ```
    pub fn clearance_from_text(
        &self,
        text: &str,
    ) -> std::result::Result<Vec<(usize, f64)>, String> {
        clearance_of(&self.axes, axis_value_pairs(text)?.into_iter()).map_err(|(_, m)| m)
    }

    /// Commands from positions in file units (mm, degrees) given in chain order.
    pub fn commands_from_file_units(&self, positions: &[f64]) -> Commands {
        let mut c = Commands::default();
        for (i, (a, &v)) in self.axes.iter().zip(positions).enumerate() {
            c.0[i] = a.from_file_units(v);
        }
        c
    }
}

/// The `AXIS=VALUE` pairs of an option such as `--clearance Z=600,A=0` or `--start X=0,Z=600`
/// (comma-separated; values in file units, not yet checked against any machine), or the
/// message naming the pair at fault.
///
/// ```
/// use volver_core::machine::axis_value_pairs;
/// assert_eq!(axis_value_pairs("Z=600, A=0").unwrap(), vec![("Z", 600.0), ("A", 0.0)]);
/// assert!(axis_value_pairs("Z").unwrap_err().contains("expected AXIS=VALUE"));
/// ```
pub fn axis_value_pairs(text: &str) -> std::result::Result<Vec<(&str, f64)>, String> {
    text.split(',')
        .map(str::trim)
        .map(|item| {
            let Some((k, v)) = item.split_once('=') else {
                return Err(format!(
                    "'{item}': expected AXIS=VALUE (mm or degrees), e.g. Z=600"
                ));
            };
            let value = v
                .trim()
                .parse::<f64>()
                .map_err(|_| format!("'{item}': '{}' is not a number (mm or degrees)", v.trim()))?;
            Ok((k.trim(), value))
        })
        .collect()
}

/// A clearance position from (axis letter, value in file units) pairs: (chain index, internal
/// units) in chain order, or the key at fault and the message. Each axis must be one of `axes`,
/// named once, its value finite and within its travel; at least one axis is needed.
fn clearance_of<'a>(
    axes: &[MachineAxis],
    pairs: impl Iterator<Item = (&'a str, f64)>,
) -> std::result::Result<Vec<(usize, f64)>, (String, String)> {
    let mut out: Vec<(usize, f64)> = Vec::new();
    for (key, value) in pairs {
        let fail = |m: String| (key.to_string(), format!("clearance {key} = {value}: {m}"));
        let mut letters = key.chars();
        let found = match (letters.next().and_then(Axis::from_letter), letters.next()) {
            (Some(a), None) => axes.iter().position(|x| x.axis == a),
            _ => None,
        };
        let Some(k) = found else {
            let known: Vec<String> = axes.iter().map(|a| a.axis.to_string()).collect();
            return Err(fail(format!(
                "the machine has no axis {key} (its axes: {})",
                known.join(", ")
            )));
        };
        if !value.is_finite() {
            return Err(fail(format!(
                "a finite position ({}) is needed",
                axes[k].file_unit()
            )));
        }
        if out.iter().any(|(j, _)| *j == k) {
            return Err(fail(format!("axis {key} is given twice")));
        }
        out.push((
            k,
            axes[k]
                .position_from_file(value)
                .map_err(|e| fail(e.to_string()))?,
        ));
    }
    if out.is_empty() {
        return Err((
            String::new(),
            "the clearance names no axis: give at least one, e.g. Z = 600".to_string(),
        ));
    }
    out.sort_by_key(|(k, _)| *k);
    Ok(out)
}

/// Whether `id` can be a cell of a CSV file and a word of messages: non-empty, no comma,
/// semicolon, quote, control character or surrounding space.
fn valid_id(id: &str) -> bool {
    !id.is_empty()
        && id.trim() == id
        && !id
            .chars()
            .any(|c| matches!(c, ',' | '"' | ';') || c.is_control())
}

/// Rz(rz)·Ry(ry)·Rx(rx), row-major.
fn base_rotation(rx: f64, ry: f64, rz: f64) -> [[f64; 3]; 3] {
    let (sx, cx) = rx.sin_cos();
    let (sy, cy) = ry.sin_cos();
    let (sz, cz) = rz.sin_cos();
    [
        [cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx],
        [sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx],
        [-sy, cy * sx, cy * cx],
    ]
}

/// Commanded positions of one measurement in chain order, internal units (mm, rad). Unused
/// trailing slots are zero.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Commands(pub [f64; MAX_AXES]);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lookups_fail_with_typed_errors() {
        let m = Machine::default_xcfz();
        let e = m.axes()[0].position_from_file(-1.0).unwrap_err();
        assert_eq!((e.lo, e.hi, e.unit, e.axis), (0.0, 1400.0, "mm", Axis::X));
        assert_eq!(
            m.reflector_named("R7"),
            Err(NameError::UnknownReflector {
                id: "R7".into(),
                known: vec!["R1".into(), "R2".into()]
            })
        );
        let layout = StationSpec::default_layout(&m, 3, Observes::Range);
        let multi = m.with_stations(layout).unwrap();
        assert_eq!(
            multi.station_named(None),
            Err(NameError::StationNotGiven { stations: 3 })
        );
        assert_eq!(
            multi.station_named(Some("S9")).unwrap_err().to_string(),
            "station 'S9' is not in the machine file (known: S1, S2, S3)"
        );
    }

    #[test]
    fn default_machine_is_the_paper_grinder() {
        let m = Machine::default_xcfz();
        assert_eq!(m.chain().to_string(), "XCFZ");
        let (i, z) = m.axis(Axis::Z).unwrap();
        assert_eq!(i, 2);
        assert_eq!(z.offset, [1000.0, 25.0, 1500.0]);
        assert_eq!(z.side, Side::Tool);
        let (_, c) = m.axis(Axis::C).unwrap();
        assert!((c.max - std::f64::consts::TAU).abs() < 1e-15);
        assert_eq!(m.reflectors()[1].offset, [-10.0, 100.0, 50.0]);
        assert_eq!(m.tracker().mount, TrackerMount::Workpiece);
    }

    #[test]
    fn errors_name_file_line_and_field() {
        let bad = DEFAULT_MACHINE_TOML.replace("range = [0.0, 600.0]", "range = [600.0, 0.0]");
        let e = Machine::from_toml_str(&bad, "m.toml")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("m.toml:22: field 'axes.Z'"), "{e}");
        assert!(e.contains("min < max"), "{e}");

        let bad = DEFAULT_MACHINE_TOML.replace("chain = \"XCFZ\"", "chain = \"XCZ\"");
        let e = Machine::from_toml_str(&bad, "m.toml")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("m.toml:10: field 'chain'"), "{e}");

        let bad = DEFAULT_MACHINE_TOML.replace("[axes.C]", "[axes.Y]");
        let e = Machine::from_toml_str(&bad, "m.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("axis 'Y' is not in the chain XCFZ"), "{e}");

        let bad = DEFAULT_MACHINE_TOML.replace("offset = [1000.0", "ofset = [1000.0");
        let e = Machine::from_toml_str(&bad, "m.toml")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("m.toml:24"), "{e}");
        assert!(e.contains("ofset"), "{e}");

        let bad = DEFAULT_MACHINE_TOML.replace("id = \"R2\"", "id = \"R1\"");
        let e = Machine::from_toml_str(&bad, "m.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("used twice"), "{e}");
    }

    #[test]
    fn clearance_tables_are_validated_and_written_only_when_set() {
        let e = |from: &str, to: &str| {
            let text = DEFAULT_MACHINE_TOML.replace(from, to);
            Machine::from_toml_str(&text, "m.toml")
                .unwrap_err()
                .to_string()
        };
        let line = DEFAULT_MACHINE_TOML
            .lines()
            .position(|l| l == "[clearance]")
            .unwrap()
            + 1;
        let msg = e("Z = 600.0", "Z = 700.0");
        assert!(
            msg.starts_with(&format!("m.toml:{line}: field 'clearance.Z'"))
                && msg.contains("outside the travel range [0, 600]"),
            "{msg}"
        );
        let msg = e("Z = 600.0", "Y = 0.0");
        assert!(
            msg.contains("'clearance.Y'") && msg.contains("no axis Y (its axes: X, C, Z)"),
            "{msg}"
        );
        let msg = e("Z = 600.0", "Z = nan");
        assert!(msg.contains("finite"), "{msg}");
        let msg = e("Z = 600.0", "ZZ = 1.0");
        assert!(msg.contains("no axis ZZ"), "{msg}");
        let msg = e("Z = 600.0", "");
        assert!(msg.contains("names no axis"), "{msg}");
        let msg = e("Z = 600.0", "Z = \"top\"");
        assert!(msg.starts_with("m.toml:"), "{msg}");
        // Written back as read, and not at all when absent.
        let m = Machine::default_xcfz();
        let text = toml::to_string(m.spec()).unwrap();
        assert!(text.contains("[clearance]\nZ = 600.0"), "{text}");
        assert_eq!(Machine::from_toml_str(&text, "back").unwrap(), m);
        let mut spec = m.spec().clone();
        spec.clearance = None;
        let bare = Machine::from_spec(spec, "bare").unwrap();
        assert!(bare.clearance().is_empty());
        assert!(!toml::to_string(bare.spec()).unwrap().contains("clearance"));
        assert_eq!(
            m.clearance_from_text("Z=0, X = 1400"),
            Ok(vec![(0, 1400.0), (2, 0.0)])
        );
        assert!(
            m.clearance_from_text("C=90,C=0")
                .unwrap_err()
                .contains("given twice")
        );
        assert!(
            m.clearance_from_text("Z=inf")
                .unwrap_err()
                .contains("finite")
        );
        assert!(
            m.clearance_from_text("Z=x")
                .unwrap_err()
                .contains("not a number")
        );
    }

    /// Every embedded machine's clearance is the end of its axis' travel that takes each
    /// reflector highest above the workpiece side's face (its frame's z: the tables' faces are
    /// at z = 0), the other axes at their reference.
    #[test]
    fn each_embedded_machines_clearance_is_its_safe_end() {
        use crate::kinematics::{PointErrors, tool_in_workpiece};
        for preset in crate::presets::PRESETS {
            let m = preset.machine().unwrap();
            assert!(!m.clearance().is_empty(), "{}", preset.name);
            let reference = Commands(std::array::from_fn(|k| {
                m.axes().get(k).map_or(0.0, |a| a.reference)
            }));
            let e = PointErrors::<f64>::zero();
            for &(k, clear) in m.clearance() {
                let ax = &m.axes()[k];
                for r in m.reflectors() {
                    let z = |v: f64| {
                        let mut c = reference;
                        c.0[k] = v;
                        tool_in_workpiece(&m, &c.0, &r.offset, &e)[2]
                    };
                    for i in 0..=10 {
                        let v = ax.min + (ax.max - ax.min) * i as f64 / 10.0;
                        assert!(
                            z(clear) >= z(v) - 1e-9,
                            "{}: {} at {v} puts {} higher than the clearance",
                            preset.name,
                            ax.axis,
                            r.id
                        );
                    }
                }
            }
        }
    }
}
