//! Measurement files (CSV with a header).
//!
//! One column per machine axis named by its letter (`X`, `C`, `Z`: linear axes in mm, rotary
//! axes in degrees), `reflector` (an id from the machine file), and per row one observation:
//! * a point: `meas_x`, `meas_y`, `meas_z` (mm, in the station's frame);
//! * a point in the station's spherical coordinates: `az_deg` (azimuth from x towards y),
//!   `el_deg` (elevation above the x–y plane), `range_mm` — converted to a point when read;
//! * a range alone: `range_mm` with the other observation cells empty (a tracing
//!   interferometer, or a tracker's range): it needs its `station`.
//!
//! Optional: `t_s` (seconds since the test started) and `station` (a station id of the machine
//! file's `[[station]]` tables; without them every row is the tracker's). Column order is free
//! and extra columns are ignored, except a single-letter axis column for an axis the machine does
//! not have, which is an error. A header may carry its unit in brackets or parentheses (`C [deg]`,
//! `meas_x (mm)`); a unit other than the one volver reads is refused
//! ([`crate::csvio::check_unit`]), not converted. Measured coordinates beyond 1 km
//! ([`MAX_COORDINATE_MM`]) are refused as not being in mm. The file is read through
//! [`crate::csvio`]: cells may be quoted, blank lines are skipped, and every error names the
//! file, the line and the column.
//!
//! ```
//! use volver_core::machine::Machine;
//! use volver_core::measure::MeasurementSet;
//! let m = Machine::default_xcfz();
//! let csv = "reflector,X,C,Z,meas_x,meas_y,meas_z\nR1,0,0,0,950,75,1450\n";
//! let set = MeasurementSet::from_csv_str(&m, csv, "inline.csv").unwrap();
//! assert_eq!(set.points.len(), 1);
//! assert_eq!(set.points[0].measured, [950.0, 75.0, 1450.0]);
//! ```

use crate::approach::{self, Approach};
use crate::chain::MAX_AXES;
use crate::csvio::{self, Format};
use crate::error::{Error, Place, Result};
use crate::machine::{Commands, Machine};
use crate::units::S_PER_H;
use std::fmt::Write as _;
use std::path::Path;

mod read;
pub(crate) use read::{approach_columns, axis_columns, read_commands};

/// What one measurement observed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Observation {
    /// A point: `measured` is its position in the station's frame (mm).
    #[default]
    Point,
    /// A range alone: `measured[0]` is the distance from the station (mm), the other two zero.
    Range,
}

/// One measured point.
#[derive(Clone, Debug, PartialEq)]
pub struct Measurement {
    /// Commanded positions in chain order, internal units (mm, rad).
    pub commands: Commands,
    /// Index of the reflector in the machine's list.
    pub reflector: usize,
    /// Measured position in the station's frame (mm); for a range, `[range, 0, 0]`.
    pub measured: [f64; 3],
    /// What was observed.
    pub observation: Observation,
    /// Seconds since the test started, when recorded: since the set's earliest stamp
    /// ([`MeasurementSet::time_origin_s`]) once read, whatever the file's origin.
    pub t_s: Option<f64>,
    /// Tracker station id, when recorded.
    pub station: Option<String>,
    /// Index of the station in the machine's list ([`Machine::stations`]; 0 without
    /// `[[station]]` tables).
    pub station_index: usize,
    /// Line of the source file (1-based), for messages.
    pub line: usize,
    /// The direction of approach of each axis ([`crate::approach`]): stated by the file's
    /// `approach_<AXIS>` columns, else derived from the measuring order when the set is read.
    pub approach: Approach,
}

/// A key equal for two measurements of one pose from one station: the commands rounded to 1e-6
/// (mm, rad) with rotary positions a full turn apart taken as one (C = 0° and 360°), the
/// reflector and the station (the same pose seen from two stations is not a repeat). It says
/// nothing of the direction each axis arrived from: [`repeat_key`] does.
pub fn pose_key(machine: &Machine, p: &Measurement) -> Vec<i64> {
    let mut k: Vec<i64> = machine
        .axes()
        .iter()
        .enumerate()
        .map(|(j, ax)| position_key(ax, p.commands.0[j]))
        .collect();
    k.push(p.reflector as i64);
    k.push(p.station_index as i64);
    k
}

/// A key equal for two positions `u` of axis `ax` (internal units: mm, rad) that are one
/// position: rounded to 1e-6, a rotary axis' taken modulo a turn (C = 0° and 360° are one).
pub fn position_key(ax: &crate::machine::MachineAxis, u: f64) -> i64 {
    let mut u = u;
    if ax.axis.is_rotary() {
        u = u.rem_euclid(std::f64::consts::TAU);
        if (u - std::f64::consts::TAU).abs() < 1e-9 {
            u = 0.0;
        }
    }
    (u * 1e6).round() as i64
}

/// A key equal for two measurements that are **repeats**: one pose ([`pose_key`]) reached with
/// every axis arriving from the same side ([`Measurement::approach`]: +1, −1, or 0 for an axis
/// that had not moved yet). Two readings of one pose reached from opposite sides of an axis
/// differ by that axis' reversal (ISO 230-2's B, [`crate::approach`]) besides the noise, so
/// they are not repeats: in test 4's own order C = 360° arrives moving + and C = 0° (after the
/// turn back) moving −, and on a machine whose table has backlash their difference is its
/// reversal, not the tracker's noise.
pub fn repeat_key(machine: &Machine, p: &Measurement) -> Vec<i64> {
    let mut k = pose_key(machine, p);
    let n = machine.axes().len().min(MAX_AXES);
    k.extend(p.approach.0[..n].iter().map(|&s| i64::from(s)));
    k
}

/// The measurements of one test.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MeasurementSet {
    /// The points in file order.
    pub points: Vec<Measurement>,
    /// The file's time stamp (s) that the points' `t_s` count from: its earliest, so that a fit
    /// and its diagnosis do not depend on the clock's origin (an epoch time, a time of day) and
    /// a drift's value at `t_s = 0` is the one at the test's start. Zero for a set made in
    /// memory (a simulation starts at zero).
    pub time_origin_s: f64,
    /// The axes whose directions of approach the file stated (`approach_<AXIS>` columns, chain
    /// order); the others' were derived from the measuring order. None for a set made in memory.
    pub approach_stated: [bool; MAX_AXES],
}

/// The largest measured coordinate accepted (mm): 1 km, beyond the reach of any laser
/// tracker. A larger value is not in mm (or is garbage) and would overflow the squares of
/// the objective.
pub const MAX_COORDINATE_MM: f64 = 1e6;

/// Refuses a row that repeats another exactly (commands, reflector, station, every measured
/// coordinate to the last digit): a copy, not a second reading. Two tracker readings never agree
/// to the file's resolution, and a copy would fake a small repeat noise. Sorting by the bits:
/// `n log n`.
pub(crate) fn refuse_copies(points: &[Measurement], file: &str) -> Result<()> {
    let key = |p: &Measurement| {
        let mut k: Vec<u64> = p.commands.0.iter().map(|v| v.to_bits()).collect();
        k.extend(p.measured.iter().map(|v| v.to_bits()));
        k.push(p.reflector as u64);
        k.push(p.station_index as u64);
        // Readings stated to come from different sides (`approach_<AXIS>`) are not copies.
        k.extend(p.approach.0.iter().map(|&s| s as u64));
        k
    };
    let mut order: Vec<usize> = (0..points.len()).collect();
    order.sort_by_key(|&i| (key(&points[i]), i));
    for w in order.windows(2) {
        let (a, b) = (&points[w[0]], &points[w[1]]);
        if key(a) == key(b) {
            return Err(Error::input(
                Place::file(file).at_line(b.line),
                format!(
                    "this row repeats line {} exactly (same position, reflector and measured \
                     point to the last digit): a copied row, not a second reading",
                    a.line
                ),
            ));
        }
    }
    Ok(())
}

/// Refuses station ids a machine without `[[station]]` tables cannot place: every row would be
/// read as the one tracker's, and two stations' points mixed as one tracker's give a wrong fit
/// (or a misleading scale error). One id throughout is the one tracker, named.
pub(crate) fn refuse_unknown_stations(
    machine: &Machine,
    points: &[Measurement],
    file: &str,
) -> Result<()> {
    if machine.has_stations() {
        return Ok(());
    }
    let mut ids: Vec<(&str, usize)> = Vec::new();
    for p in points {
        if let Some(s) = p.station.as_deref()
            && !ids.iter().any(|(id, _)| *id == s)
        {
            ids.push((s, p.line));
        }
    }
    if ids.len() < 2 {
        return Ok(());
    }
    let names: Vec<&str> = ids.iter().take(8).map(|(id, _)| *id).collect();
    let more = if ids.len() > 8 { ", …" } else { "" };
    Err(Error::input(
        Place::file(file).at_line(ids[1].1).at_field("station"),
        format!(
            "the station column names {} stations ({}{more}) that the machine lacks: its file \
             has no [[station]] tables, so every row would be read as one tracker's. Pass the \
             machine file with their [[station]] tables (`volver simulate --stations` writes one \
             into its machine.toml)",
            ids.len(),
            names.join(", ")
        ),
    ))
}

/// A point from spherical coordinates in a station's frame: azimuth from x towards y and
/// elevation above the x–y plane (rad), range (mm).
///
/// ```
/// use volver_core::measure::from_spherical;
/// let p = from_spherical(std::f64::consts::FRAC_PI_2, 0.0, 1000.0);
/// assert!(p[0].abs() < 1e-12 && (p[1] - 1000.0).abs() < 1e-12 && p[2] == 0.0);
/// ```
pub fn from_spherical(az: f64, el: f64, range: f64) -> [f64; 3] {
    let (se, ce) = el.sin_cos();
    let (sa, ca) = az.sin_cos();
    [range * ce * ca, range * ce * sa, range * se]
}

/// [`from_spherical`]'s inverse: `[az, el, range]` (rad, rad, mm).
pub fn to_spherical(p: [f64; 3]) -> [f64; 3] {
    let h = p[0].hypot(p[1]);
    [p[1].atan2(p[0]), p[2].atan2(h), h.hypot(p[2])]
}

/// A measurement a file reader read from its `line`: its commands and reflector, its
/// observation, its time and station id; the station found in `machine` and checked to give the
/// observation (the errors at `place`, the row's station).
pub(crate) fn located(
    machine: &Machine,
    (commands, reflector): (Commands, usize),
    (measured, observation): ([f64; 3], Observation),
    (t_s, station): (Option<f64>, Option<String>),
    line: usize,
    place: impl Fn() -> Place,
) -> Result<Measurement> {
    let station_index = machine
        .station_named(station.as_deref())
        .map_err(|m| Error::input(place(), m.to_string()))?;
    observable(machine, station_index, observation, place)?;
    Ok(Measurement {
        commands,
        reflector,
        measured,
        observation,
        t_s,
        station,
        station_index,
        line,
        approach: Approach::UNKNOWN,
    })
}

/// The measurement set of `table`'s rows, each read by `read`; a file without rows is refused
/// (`no_rows` says so), and so are copied rows and stations the machine cannot place.
pub(crate) fn read_rows(
    machine: &Machine,
    table: &mut csvio::Table,
    no_rows: &str,
    read: impl Fn(&csvio::Row) -> Result<Measurement>,
) -> Result<MeasurementSet> {
    read_rows_stated(machine, table, no_rows, [false; MAX_AXES], read)
}

/// [`read_rows`] for a file whose `approach_<AXIS>` columns state the direction of approach of
/// the axes marked in `stated` (their values already in each point's `approach`); the others'
/// directions are derived from the measuring order ([`fill_approach`]).
pub(crate) fn read_rows_stated(
    machine: &Machine,
    table: &mut csvio::Table,
    no_rows: &str,
    stated: [bool; MAX_AXES],
    read: impl Fn(&csvio::Row) -> Result<Measurement>,
) -> Result<MeasurementSet> {
    let mut points = Vec::new();
    for row in table.rows() {
        points.push(read(&row?)?);
    }
    let file = table.header().file().to_string();
    if points.is_empty() {
        return Err(Error::input(Place::file(&file), no_rows));
    }
    refuse_copies(&points, &file)?;
    refuse_unknown_stations(machine, &points, &file)?;
    refuse_unknown_order(&points, &file)?;
    fill_approach(&mut points, stated);
    Ok(MeasurementSet {
        approach_stated: stated,
        ..MeasurementSet::from_file_times(points)
    })
}

/// Refuses a file whose measuring order cannot be told: rows out of time order (the stamps say
/// they were sorted after the test) with some row without a stamp, which the time order cannot
/// place. The order gives each axis' direction of approach ([`fill_approach`]); read in the
/// rows' order instead, it would be wrong without a word.
fn refuse_unknown_order(points: &[Measurement], file: &str) -> Result<()> {
    let Some(blank) = points.iter().find(|p| p.t_s.is_none()) else {
        return Ok(());
    };
    let stamped: Vec<&Measurement> = points.iter().filter(|p| p.t_s.is_some()).collect();
    let Some(w) = stamped.windows(2).find(|w| w[1].t_s < w[0].t_s) else {
        return Ok(());
    };
    Err(Error::input(
        Place::file(file).at_line(blank.line).at_field("t_s"),
        format!(
            "no time stamp, while the rows are not in time order (line {} was measured before \
             line {}): the measuring order, which gives each axis' direction of approach, \
             cannot be told; give every row its t_s, or put the rows in measuring order",
            w[1].line, w[0].line
        ),
    ))
}

/// The measuring order of `points`: their time stamps' order when every point has one (ties in
/// file order), else the file's order.
pub fn measuring_order(points: &[Measurement]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..points.len()).collect();
    if points.iter().all(|p| p.t_s.is_some()) {
        order.sort_by(|&a, &b| {
            let (ta, tb) = (points[a].t_s.unwrap_or(0.0), points[b].t_s.unwrap_or(0.0));
            ta.total_cmp(&tb)
        });
    }
    order
}

/// Every point's direction of approach on the axes not `stated` by the file, from the measuring
/// order ([`measuring_order`], [`approach::from_order`]).
pub fn fill_approach(points: &mut [Measurement], stated: [bool; MAX_AXES]) {
    let order = measuring_order(points);
    let commands: Vec<Commands> = order.iter().map(|&i| points[i].commands).collect();
    let derived = approach::from_order(&commands, MAX_AXES);
    for (&i, a) in order.iter().zip(derived) {
        for k in (0..MAX_AXES).filter(|&k| !stated[k]) {
            points[i].approach.0[k] = a.0[k];
        }
    }
}

/// Whether station `station` of `machine` can give `observation`: a range-only station gives
/// no point; the error is at `place` (the row's station).
pub(crate) fn observable(
    machine: &Machine,
    station: usize,
    observation: Observation,
    place: impl FnOnce() -> Place,
) -> Result<()> {
    let st = &machine.stations()[station];
    if observation == Observation::Point && st.observes == crate::machine::Observes::Range {
        return Err(Error::input(
            place(),
            format!(
                "station '{}' observes ranges only (observes = \"range\" in the machine file), \
                 but this row gives a point",
                st.id
            ),
        ));
    }
    Ok(())
}

/// How [`MeasurementSet::to_csv_with`] writes points.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PointColumns {
    /// `meas_x`, `meas_y`, `meas_z` (mm).
    #[default]
    Cartesian,
    /// `az_deg`, `el_deg`, `range_mm`.
    Spherical,
}

impl MeasurementSet {
    /// Reads a measurement file for `machine`.
    pub fn load(machine: &Machine, path: &Path) -> Result<MeasurementSet> {
        let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        MeasurementSet::from_csv_str(machine, &text, &path.display().to_string())
    }

    /// Parses measurement CSV for `machine`; `file` names the source in messages.
    pub fn from_csv_str(machine: &Machine, text: &str, file: &str) -> Result<MeasurementSet> {
        let Some(mut table) = csvio::read(text, file, Format::default())? else {
            return Err(Error::input(
                Place::file(file),
                "empty file: expected a header line with the axis columns, reflector, meas_x, \
                 meas_y, meas_z",
            ));
        };
        let reader = read::RowReader {
            machine,
            columns: read::Columns::of(machine, table.header())?,
        };
        let no_rows = "the file has a header but no measurement rows";
        let stated = reader.columns.stated();
        read_rows_stated(machine, &mut table, no_rows, stated, |row| {
            reader.measurement(row)
        })
    }

    /// A set of points whose `t_s` are the file's stamps: counted from the earliest from now on,
    /// which becomes [`MeasurementSet::time_origin_s`] (the difference is exact for stamps within
    /// a factor of two of each other, an epoch time's for instance, and to an ulp of the
    /// largest otherwise).
    pub fn from_file_times(mut points: Vec<Measurement>) -> MeasurementSet {
        let origin = points
            .iter()
            .filter_map(|p| p.t_s)
            .fold(f64::INFINITY, f64::min);
        let time_origin_s = if origin.is_finite() { origin } else { 0.0 };
        for p in &mut points {
            if let Some(t) = p.t_s.as_mut() {
                *t -= time_origin_s;
            }
        }
        MeasurementSet {
            points,
            time_origin_s,
            approach_stated: [false; MAX_AXES],
        }
    }

    /// The time the points span (s): the latest `t_s` (they count from the earliest); `None`
    /// without time stamps.
    pub fn time_span_s(&self) -> Option<f64> {
        let (lo, hi) = self
            .points
            .iter()
            .filter_map(|p| p.t_s)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), t| {
                (lo.min(t), hi.max(t))
            });
        (hi >= lo).then_some(hi - lo)
    }

    /// A warning when the time stamps do not look like seconds: the mean time between two
    /// points below 0.05 s (hours or minutes?) or above 3 h (ms or µs?). A fit does not depend on
    /// the unit (the time origin is the first stamp and the gauge's metric weighs a rate by the
    /// test's span), but the rates it reports are per hour of a `t_s` read in seconds.
    pub fn time_unit_warning(&self, file: &str) -> Option<String> {
        let n = self.points.iter().filter(|p| p.t_s.is_some()).count();
        let span = self.time_span_s()?;
        if n < 2 || span <= 0.0 {
            return None;
        }
        let step = span / (n - 1) as f64;
        let guess = if step < 0.05 {
            "hours or minutes"
        } else if step > 3.0 * S_PER_H {
            "milliseconds or microseconds"
        } else {
            return None;
        };
        Some(format!(
            "{file}: t_s spans {} s over {n} points ({} s a point): are the stamps in {guess}? \
             They are read as seconds; the fit is the same in any unit, but the rates it reports \
             (mm/h, ppm/h, rad/h) are per hour of seconds",
            crate::error::number(span),
            crate::error::number(step)
        ))
    }

    /// Writes the set as measurement CSV (axis columns in chain order, positions in mm and
    /// degrees, coordinates with 9 decimals; `t_s` and `station` when any point has them,
    /// `range_mm` when any is a range alone).
    pub fn to_csv_string(&self, machine: &Machine) -> String {
        self.to_csv_with(machine, PointColumns::Cartesian)
    }

    /// [`MeasurementSet::to_csv_string`] with the points written in `columns` (spherical: the
    /// angles in degrees with 12 decimals, the range with 9).
    pub fn to_csv_with(&self, machine: &Machine, columns: PointColumns) -> String {
        let layout = Layout::of(self, columns);
        let mut out = layout.header(machine);
        for p in &self.points {
            layout.row(&mut out, machine, p, self.time_origin_s);
        }
        out
    }
}

/// The columns a measurement file is written with.
struct Layout {
    /// Points as `az_deg`, `el_deg`, `range_mm`.
    spherical: bool,
    /// Cartesian point columns (some point is a point, or no point is a range).
    with_point: bool,
    /// A `range_mm` column for ranges alone.
    with_range: bool,
    with_t: bool,
    with_station: bool,
    /// `approach_<AXIS>` columns: the axes whose directions the measuring order does not give.
    approach: [bool; MAX_AXES],
}

impl Layout {
    /// The columns `set` needs, its points written in `columns`.
    fn of(set: &MeasurementSet, columns: PointColumns) -> Layout {
        let any = |f: fn(&Measurement) -> bool| set.points.iter().any(f);
        let with_range = any(|p| p.observation == Observation::Range);
        Layout {
            spherical: columns == PointColumns::Spherical,
            with_point: !with_range || any(|p| p.observation == Observation::Point),
            with_range,
            with_t: any(|p| p.t_s.is_some()),
            with_station: any(|p| p.station.is_some()),
            approach: stated_axes(&set.points),
        }
    }

    /// The header line: the axes in chain order, the reflector, the observation, time and
    /// station columns.
    fn header(&self, machine: &Machine) -> String {
        let mut out = String::new();
        for ax in machine.axes() {
            let _ = write!(out, "{},", ax.axis);
        }
        out.push_str("reflector");
        if self.spherical {
            out.push_str(",az_deg,el_deg,range_mm");
        } else {
            if self.with_point {
                out.push_str(",meas_x,meas_y,meas_z");
            }
            if self.with_range {
                out.push_str(",range_mm");
            }
        }
        if self.with_t {
            out.push_str(",t_s");
        }
        if self.with_station {
            out.push_str(",station");
        }
        for (k, ax) in machine.axes().iter().enumerate() {
            if self.approach[k] {
                let _ = write!(out, ",{}", approach::column_name(ax.axis.letter()));
            }
        }
        out.push('\n');
        out
    }

    /// Writes point `p`'s row: positions in file units, ids quoted when they need it
    /// ([`csvio::cell`]), the file's time stamp (`time_origin_s` added back).
    fn row(&self, out: &mut String, machine: &Machine, p: &Measurement, time_origin_s: f64) {
        for (k, ax) in machine.axes().iter().enumerate() {
            let _ = write!(out, "{},", round_file(ax.to_file_units(p.commands.0[k])));
        }
        out.push_str(&csvio::cell(&machine.reflectors()[p.reflector].id));
        let m = p.measured;
        match (p.observation, self.spherical) {
            (Observation::Range, true) => {
                let _ = write!(out, ",,,{:.9}", m[0]);
            }
            (Observation::Range, false) => {
                let empty = if self.with_point { ",,," } else { "" };
                let _ = write!(out, "{empty},{:.9}", m[0]);
            }
            (Observation::Point, true) => {
                let [az, el, d] = to_spherical(m);
                let (az, el) = (az.to_degrees(), el.to_degrees());
                let _ = write!(out, ",{az:.12},{el:.12},{d:.9}");
            }
            (Observation::Point, false) => {
                let _ = write!(out, ",{:.9},{:.9},{:.9}", m[0], m[1], m[2]);
                if self.with_range {
                    out.push(',');
                }
            }
        }
        if self.with_t {
            let t = p
                .t_s
                .map_or(String::new(), |t| format!("{:.3}", t + time_origin_s));
            let _ = write!(out, ",{t}");
        }
        if self.with_station {
            let _ = write!(out, ",{}", csvio::cell(p.station.as_deref().unwrap_or("")));
        }
        for k in (0..machine.axes().len()).filter(|&k| self.approach[k]) {
            let _ = write!(out, ",{:+}", p.approach.0[k]);
        }
        out.push('\n');
    }
}

/// The axes whose directions of approach differ somewhere from those the measuring order gives
/// ([`fill_approach`]): a file must state them (`approach_<AXIS>` columns) to be read back the
/// same.
fn stated_axes(points: &[Measurement]) -> [bool; MAX_AXES] {
    let mut derived = points.to_vec();
    fill_approach(&mut derived, [false; MAX_AXES]);
    let mut out = [false; MAX_AXES];
    for (p, d) in points.iter().zip(&derived) {
        for (k, o) in out.iter_mut().enumerate() {
            *o |= p.approach.0[k] != d.approach.0[k];
        }
    }
    out
}

/// Positions converted from radians back to degrees carry rounding noise (89.99999999999999);
/// write them with at most 9 decimals.
fn round_file(v: f64) -> f64 {
    (v * 1e9).round() / 1e9
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m() -> Machine {
        Machine::default_xcfz()
    }

    #[test]
    fn directions_of_approach_come_from_the_order_or_the_columns() {
        // Rows out of time order: the time stamps give the measuring order.
        let csv = "X,C,Z,reflector,meas_x,meas_y,meas_z,t_s\n\
                   500,0,0,R1,1,2,3,20\n\
                   100,0,0,R1,1,2,4,0\n\
                   300,0,0,R1,1,2,5,10\n";
        let s = MeasurementSet::from_csv_str(&m(), csv, "d.csv").unwrap();
        let x: Vec<i8> = s.points.iter().map(|p| p.approach.0[0]).collect();
        assert_eq!(x, [1, 1, 1]);
        assert_eq!(s.points[0].approach.0[1], 0, "C never moves: unknown");
        // A column wins for its axis; the others still come from the order.
        let csv = "X,C,Z,reflector,meas_x,meas_y,meas_z,approach_X\n\
                   100,0,0,R1,1,2,3,-1\n\
                   100,0,0,R1,1,2,4,+1\n\
                   100,0,50,R1,1,2,5,-\n";
        let s = MeasurementSet::from_csv_str(&m(), csv, "d.csv").unwrap();
        let x: Vec<i8> = s.points.iter().map(|p| p.approach.0[0]).collect();
        assert_eq!(x, [-1, 1, -1]);
        assert_eq!(s.points[0].approach.0[2], 1);
        // Written back with the column (the order does not give it) and read the same.
        let text = s.to_csv_string(&m());
        assert!(
            text.lines().next().unwrap().ends_with(",approach_X"),
            "{text}"
        );
        let back = MeasurementSet::from_csv_str(&m(), &text, "again.csv").unwrap();
        assert_eq!(
            back.points,
            s.points
                .iter()
                .map(|p| Measurement {
                    line: p.line,
                    ..p.clone()
                })
                .collect::<Vec<_>>()
        );
        // A file the order describes is written without it.
        let plain = "X,C,Z,reflector,meas_x,meas_y,meas_z\n100,0,0,R1,1,2,3\n200,0,0,R1,1,2,4\n";
        let s = MeasurementSet::from_csv_str(&m(), plain, "d.csv").unwrap();
        assert!(!s.to_csv_string(&m()).contains("approach"));
    }

    #[test]
    fn rows_out_of_time_order_need_every_stamp() {
        let csv = "X,C,Z,reflector,meas_x,meas_y,meas_z,t_s\n\
                   500,0,0,R1,1,2,3,20\n\
                   100,0,0,R1,1,2,4,\n\
                   300,0,0,R1,1,2,5,10\n";
        let e = MeasurementSet::from_csv_str(&m(), csv, "d.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("d.csv:3") && e.contains("cannot be told"), "{e}");
        // In time order, a blank stamp is accepted (the rows' order is the measuring order).
        let csv = csv.replace(",20\n", ",5\n");
        assert!(MeasurementSet::from_csv_str(&m(), &csv, "d.csv").is_ok());
    }

    #[test]
    fn bad_directions_of_approach_are_refused_where_they_are() {
        let read = |csv: &str| {
            MeasurementSet::from_csv_str(&m(), csv, "d.csv")
                .unwrap_err()
                .to_string()
        };
        let e = read("X,C,Z,reflector,meas_x,meas_y,meas_z,approach_Y\n1,0,0,R1,1,2,3,1\n");
        assert!(
            e.contains("d.csv") && e.contains("'approach_Y' names no axis"),
            "{e}"
        );
        let e = read("X,C,Z,reflector,meas_x,meas_y,meas_z,approach_X\n1,0,0,R1,1,2,3,up\n");
        assert!(
            e.contains("d.csv:2") && e.contains("'up' is no direction of approach"),
            "{e}"
        );
        let e = read(
            "X,C,Z,reflector,meas_x,meas_y,meas_z,approach_C\n1,0,0,R1,1,2,3,1\n2,0,0,R1,1,2,4,\n",
        );
        assert!(e.contains("d.csv:3") && e.contains("on every row"), "{e}");
    }

    #[test]
    fn reads_any_column_order_and_ignores_extras() {
        let csv = "note,meas_z,Z,reflector,C,X,meas_y,meas_x,t_s,station\n\
                   a,1450,0,R1,90,700,75,950,12.5,S1\n\
                   b,1,600,R2,360,1400,2,3,,\n";
        let s = MeasurementSet::from_csv_str(&m(), csv, "d.csv").unwrap();
        assert_eq!(s.points.len(), 2);
        let p = &s.points[0];
        assert_eq!(p.commands.0[0], 700.0);
        assert!((p.commands.0[1] - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
        assert_eq!(p.reflector, 0);
        assert_eq!(p.measured, [950.0, 75.0, 1450.0]);
        // Times count from the earliest stamp, which the set keeps.
        assert_eq!(p.t_s, Some(0.0));
        assert_eq!(s.time_origin_s, 12.5);
        assert_eq!(p.station.as_deref(), Some("S1"));
        assert_eq!(p.line, 2);
        assert_eq!(s.points[1].t_s, None);
        // Round trip through the writer.
        let again =
            MeasurementSet::from_csv_str(&m(), &s.to_csv_string(&m()), "again.csv").unwrap();
        assert_eq!(again.points.len(), 2);
        assert_eq!(again.points[0].commands, p.commands);
        assert_eq!(
            (again.time_origin_s, again.points[0].t_s),
            (12.5, Some(0.0))
        );
    }

    fn err(csv: &str) -> String {
        MeasurementSet::from_csv_str(&m(), csv, "d.csv")
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn errors_name_file_line_and_column() {
        let h = "X,C,Z,reflector,meas_x,meas_y,meas_z\n";
        let e = err(&format!("{h}0,0,0,R1,950,75,1450\n0,abc,0,R1,1,2,3\n"));
        assert!(
            e.starts_with("d.csv:3: field 'C': expected a number (deg)"),
            "{e}"
        );
        let e = err(&format!("{h}0,0,0,R9,950,75,1450\n"));
        assert!(
            e.starts_with("d.csv:2: field 'reflector'") && e.contains("R1, R2"),
            "{e}"
        );
        let e = err(&format!("{h}0,0,0,R1,NaN,75,1450\n"));
        assert!(
            e.starts_with("d.csv:2: field 'meas_x': expected a finite number"),
            "{e}"
        );
        let e = err(&format!("{h}1500,0,0,R1,950,75,1450\n"));
        assert!(e.contains("outside the travel range [0, 1400]"), "{e}");
        let e = err("X,C,reflector,meas_x,meas_y,meas_z\n0,0,R1,1,2,3\n");
        assert!(e.starts_with("d.csv:1: field 'Z': missing column"), "{e}");
        let e = err("X,Y,C,Z,reflector,meas_x,meas_y,meas_z\n0,0,0,0,R1,1,2,3\n");
        assert!(
            e.contains("'Y' is an axis the machine (XCFZ) does not have"),
            "{e}"
        );
        let e = err("X,C,Z,reflector,meas_x,meas_x,meas_y,meas_z\n");
        assert!(e.contains("appears twice"), "{e}");
        let e = err(h);
        assert!(e.contains("no measurement rows"), "{e}");
        let e = err("");
        assert!(e.contains("empty file"), "{e}");
        let e = err(&format!("{h}0,0,0,R1,950,75\n"));
        assert!(
            e.starts_with("d.csv:2") && e.contains("not valid CSV"),
            "{e}"
        );
    }

    /// Quoted cells, CR LF, blank and whitespace-only lines: read through the CSV layer, each
    /// point at its own line; a station id that needs quotes is written quoted and read back.
    #[test]
    fn quoted_cells_and_blank_lines_are_read_and_ids_written_back() {
        let csv = "X,C,Z,reflector,meas_x,meas_y,meas_z,station\r\n\r\n\
                   0,0,0,\"R1\",950,75,1450,\"S 1, left\"\r\n   \r\n,,,,,,,\r\n\
                   700,90,300,R2,1,2,3,\"S 1, left\"\r\n";
        let s = MeasurementSet::from_csv_str(&m(), csv, "d.csv").unwrap();
        assert_eq!((s.points[0].line, s.points[1].line), (3, 6));
        assert_eq!(s.points[0].station.as_deref(), Some("S 1, left"));
        let written = s.to_csv_string(&m());
        assert!(written.contains(",\"S 1, left\"\n"), "{written}");
        let again = MeasurementSet::from_csv_str(&m(), &written, "w.csv").unwrap();
        assert_eq!(again.points[1].station, s.points[1].station);
        let e = err("X,C,Z,reflector,meas_x,meas_y,meas_z\n\n0,0,0,R1,1,2\n");
        assert_eq!(e, "d.csv:3: not valid CSV: 6 fields where the header has 7");
    }
}
