//! Reading a measurement file: its columns found in the header, then one [`Measurement`] per
//! row, through the CSV layer ([`crate::csvio`]).

use super::{MAX_COORDINATE_MM, Measurement, Observation, from_spherical};
use crate::csvio::{Header, Row};
use crate::error::{Error, Place, Result};
use crate::iso::Axis;
use crate::machine::{Commands, Machine};

/// The point columns, in x, y, z order.
const POINT_COLUMNS: [&str; 3] = ["meas_x", "meas_y", "meas_z"];

/// What a header must have besides the axes, for the messages on a missing column.
const REQUIRED: &str = "required: axis letters, reflector, and meas_x, meas_y, meas_z or \
                        range_mm (with az_deg, el_deg for spherical points)";

/// The columns of the machine's axes in `header`, in chain order, each in its file unit (mm or
/// degrees; a unit on the header is checked): shared by measurement files, plan files and
/// point lists.
pub(crate) fn axis_columns(machine: &Machine, header: &Header) -> Result<Vec<usize>> {
    let mut cols = Vec::with_capacity(machine.axes().len());
    for ax in machine.axes() {
        let name = ax.axis.letter().to_string();
        let col = header.require(&name, || {
            format!(
                "missing column '{name}' (axis {name} of {}, in {})",
                machine.chain(),
                ax.file_unit()
            )
        })?;
        header.check_unit(col, ax.file_unit())?;
        cols.push(col);
    }
    Ok(cols)
}

/// The machine's commanded positions of `row`, its axes in `cols` (chain order, file units);
/// a position outside an axis' travel is refused at its cell.
pub(crate) fn read_commands(machine: &Machine, row: &Row, cols: &[usize]) -> Result<Commands> {
    let mut commands = Commands::default();
    for (k, (&col, ax)) in cols.iter().zip(machine.axes()).enumerate() {
        let v = row.number(col, ax.file_unit())?;
        commands.0[k] = ax.position_from_file(v).map_err(|m| row.error(col, m))?;
    }
    Ok(commands)
}

/// The columns of a measurement file, found in its header.
pub(super) struct Columns {
    /// The axes' columns, in chain order.
    axes: Vec<usize>,
    reflector: usize,
    /// `meas_x`, `meas_y`, `meas_z`, when the file has points.
    xyz: Option<[usize; 3]>,
    /// `az_deg`, `el_deg`, when the file has spherical points (`range_mm` is then present).
    spherical: Option<(usize, usize)>,
    /// `range_mm`: a spherical point's range, or a range alone.
    range: Option<usize>,
    t_s: Option<usize>,
    station: Option<usize>,
    /// `approach_<AXIS>` columns: (chain axis, column).
    approach: Vec<(usize, usize)>,
}

impl Columns {
    /// The columns of `header` for `machine`: every axis, the reflector and at least one
    /// observation's columns, each once, each unit on the header the one volver reads.
    pub(super) fn of(machine: &Machine, header: &Header) -> Result<Columns> {
        refuse_foreign_axes(machine, header)?;
        let axes = axis_columns(machine, header)?;
        let reflector = header.require("reflector", || {
            format!("missing column 'reflector'; {REQUIRED}")
        })?;
        let range = header.find("range_mm")?;
        let columns = Columns {
            axes,
            reflector,
            xyz: point_columns(header)?,
            spherical: spherical_columns(header, range)?,
            range,
            t_s: header.find("t_s")?,
            station: header.find("station")?,
            approach: approach_columns(machine, header)?,
        };
        if columns.xyz.is_none() && range.is_none() {
            return Err(Error::input(
                header.place("meas_x"),
                format!("missing column 'meas_x'; {REQUIRED}"),
            ));
        }
        columns.check_units(header)?;
        Ok(columns)
    }

    /// The axes whose direction of approach the file states.
    pub(super) fn stated(&self) -> [bool; crate::chain::MAX_AXES] {
        let mut out = [false; crate::chain::MAX_AXES];
        for &(k, _) in &self.approach {
            out[k] = true;
        }
        out
    }

    /// The units on the observations' and time's headers: mm, degrees and seconds.
    fn check_units(&self, header: &Header) -> Result<()> {
        let mut expected: Vec<(usize, &str)> = Vec::new();
        expected.extend(self.xyz.iter().flatten().map(|&c| (c, "mm")));
        expected.extend(self.range.map(|c| (c, "mm")));
        expected.extend(
            self.spherical
                .iter()
                .flat_map(|&(a, e)| [(a, "deg"), (e, "deg")]),
        );
        expected.extend(self.t_s.map(|c| (c, "s")));
        for (c, unit) in expected {
            header.check_unit(c, unit)?;
        }
        Ok(())
    }
}

/// Refuses a single-letter upper-case column naming an axis the machine does not have: a file
/// for another machine.
fn refuse_foreign_axes(machine: &Machine, header: &Header) -> Result<()> {
    for h in header.names() {
        let mut chars = h.chars();
        if let (Some(c), None) = (chars.next(), chars.next())
            && let Some(a) = Axis::from_letter(c)
            && c.is_ascii_uppercase()
            && machine.axis(a).is_none()
        {
            return Err(Error::input(
                header.place(h),
                format!(
                    "column '{h}' is an axis the machine ({}) does not have",
                    machine.chain()
                ),
            ));
        }
    }
    Ok(())
}

/// The `approach_<AXIS>` columns of `header`: (chain axis, column); a column for an axis the
/// machine lacks is refused.
pub(crate) fn approach_columns(machine: &Machine, header: &Header) -> Result<Vec<(usize, usize)>> {
    let mut out = Vec::new();
    for h in header.names() {
        let lower = h.to_ascii_lowercase();
        let Some(letter) = lower
            .strip_prefix("approach_")
            .map(|l| &h[h.len() - l.len()..])
        else {
            continue;
        };
        let mut chars = letter.chars();
        let axis = match (chars.next().and_then(Axis::from_letter), chars.next()) {
            (Some(a), None) => machine.axis(a),
            _ => None,
        };
        let Some((k, _)) = axis else {
            return Err(Error::input(
                header.place(h),
                format!(
                    "column '{h}' names no axis of the machine ({}): a direction of approach \
                     column is approach_ and an axis letter",
                    machine.chain()
                ),
            ));
        };
        let col = header.require(h, || format!("missing column '{h}'"))?;
        out.push((k, col));
    }
    Ok(out)
}

/// `meas_x`, `meas_y`, `meas_z`: all three or none.
fn point_columns(header: &Header) -> Result<Option<[usize; 3]>> {
    let mut xyz = [None; 3];
    for (k, name) in POINT_COLUMNS.iter().enumerate() {
        xyz[k] = header.find(name)?;
    }
    match xyz {
        [Some(a), Some(b), Some(c)] => Ok(Some([a, b, c])),
        [None, None, None] => Ok(None),
        _ => {
            let missing = POINT_COLUMNS
                .iter()
                .zip(xyz)
                .find(|(_, c)| c.is_none())
                .map_or("meas_x", |(n, _)| *n);
            Err(Error::input(
                header.place(missing),
                format!("missing column '{missing}': a point needs meas_x, meas_y and meas_z"),
            ))
        }
    }
}

/// `az_deg`, `el_deg`: both or none, and with `range_mm` (`range`).
fn spherical_columns(header: &Header, range: Option<usize>) -> Result<Option<(usize, usize)>> {
    let spherical = match (header.find("az_deg")?, header.find("el_deg")?) {
        (Some(a), Some(e)) => Some((a, e)),
        (None, None) => None,
        (a, _) => {
            let missing = if a.is_none() { "az_deg" } else { "el_deg" };
            return Err(Error::input(
                header.place(missing),
                format!("missing column '{missing}': a spherical point needs az_deg and el_deg"),
            ));
        }
    };
    if spherical.is_some() && range.is_none() {
        return Err(Error::input(
            header.place("range_mm"),
            "missing column 'range_mm': a spherical point needs az_deg, el_deg and range_mm",
        ));
    }
    Ok(spherical)
}

/// Reads rows of one file into measurements.
pub(super) struct RowReader<'m> {
    pub(super) machine: &'m Machine,
    pub(super) columns: Columns,
}

impl RowReader<'_> {
    /// The measurement of `row`: its commands, reflector, time, station and observation, each
    /// checked in that order.
    pub(super) fn measurement(&self, row: &Row) -> Result<Measurement> {
        let (machine, cols) = (self.machine, &self.columns);
        let commands = read_commands(machine, row, &cols.axes)?;
        let reflector = machine
            .reflector_named(row.text(cols.reflector))
            .map_err(|m| row.error(cols.reflector, m))?;
        let t_s = match cols.t_s {
            Some(c) if row.filled(c) => Some(row.number(c, "seconds")?),
            _ => None,
        };
        let station = cols
            .station
            .map(|c| row.text(c).to_string())
            .filter(|s| !s.is_empty());
        self.refuse_two_observations(row)?;
        let observed = self.observation(row, station.is_some())?;
        let place = || self.station_place(row);
        let (line, read) = (row.line(), (commands, reflector));
        let mut m = super::located(machine, read, observed, (t_s, station), line, place)?;
        for &(k, col) in &cols.approach {
            m.approach.0[k] = crate::approach::parse_sign(row.text(col)).ok_or_else(|| {
                row.error(
                    col,
                    format!(
                        "'{}' is no direction of approach: +1 (the axis arrived moving in its \
                         positive direction), -1 (negative) or 0 (unknown), on every row",
                        row.text(col)
                    ),
                )
            })?;
        }
        Ok(m)
    }

    /// Where a row's station is: its cell, or the missing column.
    fn station_place(&self, row: &Row) -> Place {
        self.columns
            .station
            .map_or_else(|| row.place_at("station"), |c| row.place(c))
    }

    /// Refuses a row that fills more than one observation's columns (`meas_x…` and `az_deg…`,
    /// or a point and a `range_mm` alone): which one was measured cannot be told, and reading
    /// one would silently drop the other.
    fn refuse_two_observations(&self, row: &Row) -> Result<()> {
        let cols = &self.columns;
        let filled = |c: Option<usize>| c.filter(|&c| row.filled(c));
        let spherical = filled(cols.spherical.map(|s| s.0));
        let given: Vec<usize> = [
            filled(cols.xyz.map(|c| c[0])),
            spherical,
            filled(cols.range).filter(|_| spherical.is_none()),
        ]
        .into_iter()
        .flatten()
        .collect();
        if let [first, second, ..] = given[..] {
            let names = row.header().names();
            return Err(row.error(
                second,
                format!(
                    "this row fills both '{}' and '{}': one observation per row (meas_x, meas_y, \
                     meas_z; or az_deg, el_deg, range_mm; or range_mm alone), so which was \
                     measured cannot be told; leave the other cells empty",
                    names[first], names[second]
                ),
            ));
        }
        Ok(())
    }

    /// The row's observation: a point (Cartesian or spherical) or a range alone, which needs
    /// its station (`with_station`).
    fn observation(&self, row: &Row, with_station: bool) -> Result<([f64; 3], Observation)> {
        let cols = &self.columns;
        if let Some(c) = cols.xyz.filter(|c| row.filled(c[0])) {
            let p = [
                coordinate(row, c[0])?,
                coordinate(row, c[1])?,
                coordinate(row, c[2])?,
            ];
            return Ok((p, Observation::Point));
        }
        if let (Some((a, e)), Some(r)) = (cols.spherical, cols.range)
            && row.filled(a)
        {
            return Ok((spherical_point(row, a, e, r)?, Observation::Point));
        }
        if let Some(c) = cols.range.filter(|&c| row.filled(c)) {
            if !with_station {
                return Err(Error::input(
                    self.station_place(row),
                    "a range alone needs the station that measured it: give its id in the \
                     station column",
                ));
            }
            return Ok(([range(row, c)?, 0.0, 0.0], Observation::Range));
        }
        let c = cols
            .xyz
            .map_or(cols.range.unwrap_or(cols.reflector), |c| c[0]);
        Err(row.error(
            c,
            "no observation: give meas_x, meas_y, meas_z, or az_deg, el_deg, range_mm, or \
             range_mm alone",
        ))
    }
}

/// A measured coordinate (mm), at most [`MAX_COORDINATE_MM`] in magnitude.
fn coordinate(row: &Row, col: usize) -> Result<f64> {
    let v = row.number(col, "mm")?;
    if v.abs() > MAX_COORDINATE_MM {
        return Err(row.error(
            col,
            format!(
                "{} mm is beyond any laser tracker's reach ({MAX_COORDINATE_MM} mm): \
                 coordinates are read in mm",
                crate::error::number(v)
            ),
        ));
    }
    Ok(v)
}

/// A range: a coordinate that is not negative (mm).
fn range(row: &Row, col: usize) -> Result<f64> {
    let v = coordinate(row, col)?;
    if v < 0.0 {
        return Err(row.error(
            col,
            format!("a range is a distance from the station, ≥ 0 mm; found {v}"),
        ));
    }
    Ok(v)
}

/// The point of azimuth `a`, elevation `e` (degrees, in [-90, 90]) and range `r` (mm) columns.
fn spherical_point(row: &Row, a: usize, e: usize, r: usize) -> Result<[f64; 3]> {
    let d = range(row, r)?;
    let (az, el) = (row.number(a, "degrees")?, row.number(e, "degrees")?);
    if el.abs() > 90.0 {
        return Err(row.error(
            e,
            format!("an elevation lies in [-90, 90] degrees; found {el}"),
        ));
    }
    Ok(from_spherical(az.to_radians(), el.to_radians(), d))
}
