//! Import profiles: a tracker software's export read as it is written, one row per measured
//! point with its name and X, Y, Z (or Hz, V, D, or a distance alone), through a TOML profile
//! that says which column is which, in what units, and how a point's name gives the machine's
//! axis positions and the reflector.
//!
//! ```toml
//! name = "tracker software CSV export"
//! delimiter = ";"                      # default ","
//! skip_lines = 2                       # lines before the header (a title, a date …)
//! point = "Point Name"                 # the column holding each point's name
//! pattern = "{reflector}_X{X}_C{C}_Z{Z}"  # what a name says: the axes in mm and degrees
//! station = "Station"                  # optional: the column naming the station …
//! # station_id = "S1"                  # … or one station for the whole file
//! time = "Time"                        # optional: seconds since the test started
//!
//! [coordinates]
//! x = "X"                              # Cartesian: x, y, z …
//! y = "Y"
//! z = "Z"
//! # hz = "Hz"  v = "V"  d = "D"        # … or spherical, or d alone (a range)
//! length_unit = "m"                    # mm (default), m, um, in
//! angle_unit = "gon"                   # deg (default), rad, gon
//! vertical = "zenith"                  # V from the zenith (default: elevation)
//! horizontal = "clockwise"             # Hz clockwise seen from above (default: from x to y)
//! ```
//!
//! Every value is converted once, here, at the file's boundary: lengths to mm, angles to rad,
//! spherical coordinates to a point in the station's frame (azimuth from x towards y, elevation
//! above the x–y plane). Errors name the file, the line and the column, in the profile or in the
//! export.
//!
//! ```
//! use volver_core::import::Profile;
//! use volver_core::machine::Machine;
//! let m = Machine::default_xcfz();
//! let profile = Profile::from_toml_str(
//!     "point = \"Name\"\npattern = \"{reflector}/{X}/{C}/{Z}\"\n[coordinates]\nx = \"X\"\ny = \"Y\"\nz = \"Z\"\nlength_unit = \"m\"\n",
//!     "p.toml",
//! )
//! .unwrap();
//! let set = profile.read(&m, "Name,X,Y,Z\nR1/0/0/0,0.95,0.075,1.45\n", "export.csv").unwrap();
//! assert!((set.points[0].measured[0] - 950.0).abs() < 1e-9);
//! ```

use crate::csvio::{self, Format, Header, Row};
use crate::error::{Error, Place, Result, from_toml};
use crate::machine::{Commands, Machine};
use crate::measure::{Measurement, MeasurementSet, Observation, from_spherical};
use crate::units::{MM_PER_M, UM_PER_MM};
use serde::Deserialize;
use std::path::Path;

/// The `[coordinates]` table of a profile.
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CoordinateColumns {
    /// Cartesian columns.
    #[serde(default)]
    pub x: Option<String>,
    /// Cartesian y.
    #[serde(default)]
    pub y: Option<String>,
    /// Cartesian z.
    #[serde(default)]
    pub z: Option<String>,
    /// Horizontal angle.
    #[serde(default)]
    pub hz: Option<String>,
    /// Vertical angle.
    #[serde(default)]
    pub v: Option<String>,
    /// Distance (with hz and v: spherical; alone: a range).
    #[serde(default)]
    pub d: Option<String>,
    /// `mm` (default), `m`, `um`, `in`.
    #[serde(default)]
    pub length_unit: Option<String>,
    /// `deg` (default), `rad`, `gon`.
    #[serde(default)]
    pub angle_unit: Option<String>,
    /// `elevation` (default: above the horizontal plane) or `zenith` (from the vertical).
    #[serde(default)]
    pub vertical: Option<String>,
    /// `counterclockwise` (default: from x towards y) or `clockwise`.
    #[serde(default)]
    pub horizontal: Option<String>,
}

/// An import profile as written in its TOML file.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProfileSpec {
    /// A name for messages.
    #[serde(default)]
    pub name: String,
    /// The field separator (one character); `,` by default, `\t` for a tab.
    #[serde(default)]
    pub delimiter: Option<String>,
    /// Lines before the header.
    #[serde(default)]
    pub skip_lines: usize,
    /// The column holding each point's name.
    pub point: String,
    /// What a name says: `{X}`, `{C}` … (the machine's axes, in mm and degrees), `{reflector}`
    /// and `{*}` (anything, ignored) between literal text.
    pub pattern: String,
    /// The column naming each point's station.
    #[serde(default)]
    pub station: Option<String>,
    /// One station for the whole file.
    #[serde(default)]
    pub station_id: Option<String>,
    /// The column of seconds since the test started.
    #[serde(default)]
    pub time: Option<String>,
    /// The observation's columns and units.
    pub coordinates: CoordinateColumns,
}

/// One piece of a name pattern.
#[derive(Clone, Debug, PartialEq)]
enum Piece {
    Literal(String),
    Field(String),
}

/// A validated import profile. Read one with [`Profile::load`] or [`Profile::from_toml_str`],
/// then an export with [`Profile::read`] or [`Profile::load_export`].
#[derive(Clone, Debug, PartialEq)]
pub struct Profile {
    spec: ProfileSpec,
    file: String,
    delimiter: u8,
    pieces: Vec<Piece>,
    length_mm: f64,
    angle_rad: f64,
}

/// What the export's rows observe.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Kind {
    Cartesian([usize; 3]),
    Spherical([usize; 3]),
    Range(usize),
}

impl Profile {
    /// Reads a profile file.
    pub fn load(path: &Path) -> Result<Profile> {
        let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Profile::from_toml_str(&text, &path.display().to_string())
    }

    /// Parses and checks a profile; `file` names it in messages.
    pub fn from_toml_str(text: &str, file: &str) -> Result<Profile> {
        let text = crate::error::without_bom(text);
        let spec: ProfileSpec = toml::from_str(text).map_err(|e| from_toml(file, text, e))?;
        let at = |field: &str| {
            let mut p = Place::file(file).at_field(field);
            if let Some(line) = crate::error::line_of_text(text, field) {
                p = p.at_line(line);
            }
            p
        };
        let delimiter = delimiter_of(spec.delimiter.as_deref(), || at("delimiter"))?;
        let c = &spec.coordinates;
        let length_mm = match c.length_unit.as_deref().unwrap_or("mm") {
            "mm" => 1.0,
            "m" => MM_PER_M,
            "um" | "µm" => 1.0 / UM_PER_MM,
            "in" => 25.4,
            u => {
                return Err(Error::input(
                    at("length_unit"),
                    format!("length unit '{u}': expected mm, m, um or in"),
                ));
            }
        };
        let angle_rad = match c.angle_unit.as_deref().unwrap_or("deg") {
            "deg" => std::f64::consts::PI / 180.0,
            "rad" => 1.0,
            "gon" => std::f64::consts::PI / 200.0,
            u => {
                return Err(Error::input(
                    at("angle_unit"),
                    format!("angle unit '{u}': expected deg, rad or gon"),
                ));
            }
        };
        if !matches!(c.vertical.as_deref(), None | Some("elevation" | "zenith")) {
            return Err(Error::input(
                at("vertical"),
                "vertical: expected elevation or zenith",
            ));
        }
        if !matches!(
            c.horizontal.as_deref(),
            None | Some("counterclockwise" | "clockwise")
        ) {
            return Err(Error::input(
                at("horizontal"),
                "horizontal: expected counterclockwise or clockwise",
            ));
        }
        if spec.station.is_some() && spec.station_id.is_some() {
            return Err(Error::input(
                at("station_id"),
                "give the station as a column (station) or one id (station_id), not both",
            ));
        }
        let pieces = parse_pattern(&spec.pattern, &at("pattern"))?;
        Ok(Profile {
            spec,
            file: file.to_string(),
            delimiter,
            pieces,
            length_mm,
            angle_rad,
        })
    }

    /// The unit the profile reads lengths in: its name as written (`mm` by default) and its size
    /// in mm.
    pub fn length_unit(&self) -> (&str, f64) {
        (
            self.spec.coordinates.length_unit.as_deref().unwrap_or("mm"),
            self.length_mm,
        )
    }

    /// Reads an export file through the profile.
    pub fn load_export(&self, machine: &Machine, path: &Path) -> Result<MeasurementSet> {
        let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        self.read(machine, &text, &path.display().to_string())
    }

    /// Reads an export's text through the profile; `file` names it in messages.
    pub fn read(&self, machine: &Machine, text: &str, file: &str) -> Result<MeasurementSet> {
        self.check_pattern(machine)?;
        let skip = self.spec.skip_lines;
        let body = export_body(text, skip, file, || self.place("skip_lines"))?;
        let format = Format {
            delimiter: self.delimiter,
            comments: false,
            units_in_header: false,
            ragged: true,
            first_line: skip + 1,
        };
        let Some(mut table) = csvio::read(&body, file, format)? else {
            let no_header = missing_column(&self.spec.point, &[], file, skip + 1);
            return Err(Error::input(self.place("point"), no_header));
        };
        let reader = ExportReader::new(self, machine, table.header())?;
        let no_rows = "the export has a header but no rows";
        crate::measure::read_rows(machine, &mut table, no_rows, |row| reader.measurement(row))
    }

    /// The profile's place at `field`.
    fn place(&self, field: &str) -> Place {
        Place::file(&self.file).at_field(field)
    }

    /// Checks the pattern's fields against `machine`: its axes, once each, and the reflector
    /// (which a machine with several reflectors needs).
    fn check_pattern(&self, machine: &Machine) -> Result<()> {
        for axis in machine.axes() {
            let letter = axis.axis.letter().to_string();
            if !self.pieces.contains(&Piece::Field(letter.clone())) {
                return Err(Error::input(
                    self.place("pattern"),
                    format!(
                        "the pattern names no {{{letter}}}: a point's name must give every axis of \
                         {} and the reflector",
                        machine.chain()
                    ),
                ));
            }
        }
        for piece in &self.pieces {
            if let Piece::Field(f) = piece
                && f != "reflector"
                && f != "*"
                && machine.axis_named(f).is_none()
            {
                return Err(Error::input(
                    self.place("pattern"),
                    format!(
                        "{{{f}}} is not an axis of {} (nor reflector or *)",
                        machine.chain()
                    ),
                ));
            }
        }
        let with_reflector = self.pieces.contains(&Piece::Field("reflector".into()));
        if !with_reflector && machine.reflectors().len() > 1 {
            return Err(Error::input(
                self.place("pattern"),
                "the pattern names no {reflector}, and the machine has several reflectors",
            ));
        }
        Ok(())
    }
}

/// Reads an export's rows through a profile: the columns the profile names, found in the
/// export's header.
struct ExportReader<'a> {
    profile: &'a Profile,
    machine: &'a Machine,
    point: usize,
    kind: Kind,
    station: Option<usize>,
    time: Option<usize>,
}

impl<'a> ExportReader<'a> {
    /// The columns of `header` that `profile` names, each once; the coordinates' columns one of
    /// the three kinds.
    fn new(profile: &'a Profile, machine: &'a Machine, header: &Header) -> Result<Self> {
        let spec = &profile.spec;
        let column = |name: &str, field: &str| -> Result<usize> {
            column_of(header, name, || profile.place(field))
        };
        let named =
            |v: &Option<String>, field: &str| v.as_deref().map(|n| column(n, field)).transpose();
        let c = &spec.coordinates;
        let kind = match (
            named(&c.x, "coordinates.x")?,
            named(&c.y, "coordinates.y")?,
            named(&c.z, "coordinates.z")?,
            named(&c.hz, "coordinates.hz")?,
            named(&c.v, "coordinates.v")?,
            named(&c.d, "coordinates.d")?,
        ) {
            (Some(x), Some(y), Some(z), None, None, None) => Kind::Cartesian([x, y, z]),
            (None, None, None, Some(h), Some(v), Some(d)) => Kind::Spherical([h, v, d]),
            (None, None, None, None, None, Some(d)) => Kind::Range(d),
            _ => {
                return Err(Error::input(
                    profile.place("coordinates"),
                    "give x, y and z, or hz, v and d, or d alone (a range)",
                ));
            }
        };
        Ok(ExportReader {
            profile,
            machine,
            point: column(&spec.point, "point")?,
            kind,
            station: named(&spec.station, "station")?,
            time: named(&spec.time, "time")?,
        })
    }

    /// The measurement of `row`: the point's name read through the pattern, the observation
    /// in mm, the station and the time.
    fn measurement(&self, row: &Row) -> Result<Measurement> {
        let (commands, reflector) = self.name_fields(row)?;
        let (measured, observation) = self.observation(row)?;
        let station = match (self.station, &self.profile.spec.station_id) {
            (Some(col), _) => Some(row.text(col).to_string()).filter(|s| !s.is_empty()),
            (None, Some(id)) => Some(id.clone()),
            (None, None) => None,
        };
        let station_at = || {
            self.station
                .map_or_else(|| row.place_at("station"), |c| row.place(c))
        };
        if observation == Observation::Range && station.is_none() {
            return Err(Error::input(
                station_at(),
                "a range alone needs the station that measured it (the profile's station or \
                 station_id)",
            ));
        }
        let t_s = match self.time {
            Some(col) if row.filled(col) => Some(row.number(col, "seconds")?),
            _ => None,
        };
        let (read, observed) = ((commands, reflector), (measured, observation));
        let line = row.line();
        crate::measure::located(
            self.machine,
            read,
            observed,
            (t_s, station),
            line,
            station_at,
        )
    }

    /// The commands and the reflector a row's point name gives through the pattern.
    fn name_fields(&self, row: &Row) -> Result<(Commands, usize)> {
        let col = self.point;
        let name = row.text(col);
        let fields = match_pattern(&self.profile.pieces, name).ok_or_else(|| {
            row.error(
                col,
                format!(
                    "point name \"{name}\" does not follow the profile's pattern \"{}\"",
                    self.profile.spec.pattern
                ),
            )
        })?;
        let mut commands = Commands::default();
        let mut reflector = 0;
        for (field, value) in &fields {
            match field.as_str() {
                "*" => continue,
                "reflector" => {
                    reflector = self
                        .machine
                        .reflector_named(value)
                        .map_err(|m| row.error(col, m))?;
                    continue;
                }
                _ => {}
            }
            // Every other field is an axis of the machine (checked with the pattern).
            let Some((k, ax)) = self.machine.axis_named(field) else {
                continue;
            };
            let v = value
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    row.error(
                        col,
                        format!(
                            "point name \"{name}\": {field} = \"{value}\" is not a number ({})",
                            ax.file_unit()
                        ),
                    )
                })?;
            commands.0[k] = ax
                .position_from_file(v)
                .map_err(|m| row.error(col, format!("point name \"{name}\": {m}")))?;
        }
        Ok((commands, reflector))
    }

    /// The row's observation in the station's frame (mm): a point, or a range alone.
    fn observation(&self, row: &Row) -> Result<([f64; 3], Observation)> {
        Ok(match self.kind {
            Kind::Cartesian([x, y, z]) => (
                [
                    self.length(row, x)?,
                    self.length(row, y)?,
                    self.length(row, z)?,
                ],
                Observation::Point,
            ),
            Kind::Spherical([h, v, d]) => {
                let (hz, el) = self.angles(row, h, v)?;
                (
                    from_spherical(hz, el, self.distance(row, d)?),
                    Observation::Point,
                )
            }
            Kind::Range(d) => ([self.distance(row, d)?, 0.0, 0.0], Observation::Range),
        })
    }

    /// A length in the profile's unit, converted to mm; beyond a tracker's reach is refused.
    fn length(&self, row: &Row, col: usize) -> Result<f64> {
        let v = row.number(col, "a length")? * self.profile.length_mm;
        if v.abs() > crate::measure::MAX_COORDINATE_MM {
            return Err(row.error(
                col,
                format!(
                    "{} mm is beyond any laser tracker's reach: check length_unit",
                    crate::error::number(v)
                ),
            ));
        }
        Ok(v)
    }

    /// A distance from the station (mm), not negative.
    fn distance(&self, row: &Row, col: usize) -> Result<f64> {
        let d = self.length(row, col)?;
        if d < 0.0 {
            return Err(row.error(
                col,
                format!("a distance from the station is ≥ 0; found {d} mm"),
            ));
        }
        Ok(d)
    }

    /// The azimuth (from x towards y) and elevation (above the x–y plane) in rad of the
    /// horizontal angle `h` and vertical angle `v` columns, as the profile states them.
    fn angles(&self, row: &Row, h: usize, v: usize) -> Result<(f64, f64)> {
        let c = &self.profile.spec.coordinates;
        let angle_rad = self.profile.angle_rad;
        let mut hz = row.number(h, "an angle")? * angle_rad;
        if c.horizontal.as_deref() == Some("clockwise") {
            hz = -hz;
        }
        let mut el = row.number(v, "an angle")? * angle_rad;
        if c.vertical.as_deref() == Some("zenith") {
            el = std::f64::consts::FRAC_PI_2 - el;
        }
        if el.abs() > std::f64::consts::FRAC_PI_2 + 1e-12 {
            return Err(row.error(
                v,
                "the vertical angle is beyond the vertical: check vertical and angle_unit",
            ));
        }
        Ok((hz, el))
    }
}

/// The byte a profile's `delimiter` names (`,` when absent; `"\\t"` or a tab for a tab): one
/// ASCII character that is not a line end or other control character, a quote, a letter, a
/// digit or a sign, which would split rows or numbers rather than fields. The error is at
/// `place` (the profile's `delimiter`).
fn delimiter_of(text: Option<&str>, place: impl FnOnce() -> Place) -> Result<u8> {
    match text {
        None => Ok(b','),
        Some("\\t" | "\t") => Ok(b'\t'),
        Some(d)
            if d.len() == 1
                && d.is_ascii()
                && !d.bytes().any(|b| {
                    b.is_ascii_control() || b.is_ascii_alphanumeric() || b"\".-+".contains(&b)
                }) =>
        {
            Ok(d.as_bytes()[0])
        }
        Some(d) => Err(Error::input(
            place(),
            format!(
                "delimiter {d:?}: one ASCII character that is not a line end, a quote, a letter, \
                 a digit or a sign (\",\", \";\", \"\\t\", \"|\" …)"
            ),
        )),
    }
}

/// The column `name` of an export's `header`: an error at `place` (the profile's field naming
/// it) when it is missing (listing the header, cut short) or repeated (which one to read cannot
/// be told).
fn column_of(header: &Header, name: &str, place: impl FnOnce() -> Place) -> Result<usize> {
    let (file, line) = (header.file(), header.line());
    let found = header.columns_named(name);
    let message = match found[..] {
        [i] => return Ok(i),
        [] => missing_column(name, header.names(), file, line),
        _ => format!(
            "column '{name}' appears {} times in the header of {file} (line {line}, columns \
             {}): which one to read cannot be told; rename the columns in the export",
            found.len(),
            found
                .iter()
                .map(|i| (i + 1).to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    Err(Error::input(place(), message))
}

/// The message on column `name` missing from the header `names` of `file` at `line`.
fn missing_column(name: &str, names: &[String], file: &str, line: usize) -> String {
    format!(
        "column '{name}' is not in the header of {file} (line {line}: {})",
        header_list(names)
    )
}

/// The export's text after its first `skip` lines: a byte-order mark removed, and CR LF and
/// CR-only line ends (some exports write CR alone) read as LF, so that lines are counted as the
/// export's viewer counts them. An error at `place` (the profile's `skip_lines`) when nothing is
/// left for the header.
fn export_body(
    text: &str,
    skip: usize,
    file: &str,
    place: impl FnOnce() -> Place,
) -> Result<String> {
    let text = crate::error::lf_lines(crate::error::without_bom(text));
    let lines = text.split_inclusive('\n').count();
    if skip >= lines {
        return Err(Error::input(
            place(),
            format!(
                "skip_lines = {skip}, but {file} has {lines} line(s): nothing is left for the \
                 header"
            ),
        ));
    }
    Ok(text.split_inclusive('\n').skip(skip).collect())
}

/// A header's column names for a message: at most 12, each cut to 40 characters (a wrong
/// delimiter makes the whole line one name; the export is never dumped into a message).
fn header_list(headers: &[String]) -> String {
    let cut = |h: &String| -> String {
        if h.chars().count() > 40 {
            format!("{}…", h.chars().take(40).collect::<String>())
        } else {
            h.clone()
        }
    };
    let mut list: Vec<String> = headers.iter().take(12).map(cut).collect();
    if headers.len() > 12 {
        list.push(format!("… ({} columns)", headers.len()));
    }
    list.join(", ")
}

/// The pieces of a name pattern: literal text and `{field}`s; two fields in a row cannot be
/// told apart, and a brace must close. The error is at `place` (the profile's `pattern`).
fn parse_pattern(pattern: &str, place: &Place) -> Result<Vec<Piece>> {
    let err = |m: String| Error::input(place.clone(), m);
    let mut pieces = Vec::new();
    let mut rest = pattern;
    while !rest.is_empty() {
        match rest.find('{') {
            Some(0) => {
                let end = rest
                    .find('}')
                    .ok_or_else(|| err(format!("pattern \"{pattern}\": a '{{' is not closed")))?;
                let field = rest[1..end].trim().to_string();
                if field.is_empty() {
                    return Err(err(format!("pattern \"{pattern}\": an empty {{}}")));
                }
                if matches!(pieces.last(), Some(Piece::Field(_))) {
                    return Err(err(format!(
                        "pattern \"{pattern}\": two fields in a row cannot be told apart; put text \
                         between them"
                    )));
                }
                if field != "*" && pieces.contains(&Piece::Field(field.clone())) {
                    return Err(err(format!(
                        "pattern \"{pattern}\": {{{field}}} appears twice"
                    )));
                }
                pieces.push(Piece::Field(field));
                rest = &rest[end + 1..];
            }
            Some(i) => {
                pieces.push(Piece::Literal(rest[..i].to_string()));
                rest = &rest[i..];
            }
            None => {
                pieces.push(Piece::Literal(rest.to_string()));
                rest = "";
            }
        }
    }
    if pieces.is_empty() {
        return Err(err("the pattern is empty".into()));
    }
    Ok(pieces)
}

/// The fields of `name` under `pieces` (each field up to the next literal's first occurrence;
/// the last one to the end), or `None` when it does not follow them.
fn match_pattern(pieces: &[Piece], name: &str) -> Option<Vec<(String, String)>> {
    let mut out = Vec::new();
    let mut rest = name;
    let mut i = 0;
    while i < pieces.len() {
        match &pieces[i] {
            Piece::Literal(l) => rest = rest.strip_prefix(l.as_str())?,
            Piece::Field(f) => {
                let value = match pieces.get(i + 1) {
                    Some(Piece::Literal(l)) => {
                        let end = rest.find(l.as_str())?;
                        let v = &rest[..end];
                        rest = &rest[end..];
                        v
                    }
                    _ => std::mem::take(&mut rest),
                };
                if value.is_empty() {
                    return None;
                }
                out.push((f.clone(), value.to_string()));
            }
        }
        i += 1;
    }
    rest.is_empty().then_some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns_split_names_into_fields() {
        let place = Place::file("p.toml").at_field("pattern");
        let p = parse_pattern("{reflector}_X{X}_C{C}_Z{Z}", &place).unwrap();
        let f = match_pattern(&p, "R1_X-12.5_C90_Z300").unwrap();
        assert_eq!(
            f,
            vec![
                ("reflector".into(), "R1".into()),
                ("X".into(), "-12.5".into()),
                ("C".into(), "90".into()),
                ("Z".into(), "300".into())
            ]
        );
        assert!(match_pattern(&p, "R1_X0_C0").is_none());
        assert!(match_pattern(&p, "R1_X0_C0_Z1_extra").is_some()); // Z takes the rest
        let e = |p: &str| parse_pattern(p, &place).unwrap_err().to_string();
        assert!(e("{X}{C}").contains("two fields in a row"));
        assert!(e("{X").starts_with("p.toml: field 'pattern': pattern \"{X\": a '{' is not"));
        assert!(e("{X}-{X}").contains("{X} appears twice"));
        assert!(e("").contains("empty"));
    }

    /// An export read through the CSV layer: lines skipped, another delimiter, a quoted name
    /// holding it, a short row, CR LF and blank lines; errors at the export's own line numbers.
    #[test]
    fn exports_are_read_through_the_csv_layer_at_their_own_lines() {
        let m = Machine::default_xcfz();
        let profile = Profile::from_toml_str(
            "delimiter = \";\"\nskip_lines = 2\npoint = \"Name\"\npattern = \"{reflector};{X};{C};{Z}\"\n\
             time = \"T\"\n[coordinates]\nx = \"X\"\ny = \"Y\"\nz = \"Z\"\nlength_unit = \"m\"\n",
            "p.toml",
        )
        .unwrap();
        let export = "title\r\ndate\r\nName;X;Y;Z;T\r\n\"R1;0;0;0\";0.95;0.075;1.45;3\r\n\r\n\
                      \"R2;700;90;300\";1;2;3\r\n";
        let set = profile.read(&m, export, "e.csv").unwrap();
        assert_eq!(set.points.len(), 2);
        assert_eq!((set.points[0].line, set.points[1].line), (4, 6));
        assert!((set.points[0].measured[0] - 950.0).abs() < 1e-9);
        assert_eq!((set.points[0].t_s, set.points[1].t_s), (Some(0.0), None));
        assert_eq!(set.points[1].reflector, 1);
        let bad = export.replace("0.075", "abc");
        let e = profile.read(&m, &bad, "e.csv").unwrap_err().to_string();
        assert_eq!(
            e,
            "e.csv:4: field 'Y': expected a number (a length), found \"abc\""
        );
        let e = profile.read(&m, "a\nb\n", "e.csv").unwrap_err().to_string();
        assert!(
            e.starts_with("p.toml: field 'skip_lines': skip_lines = 2"),
            "{e}"
        );
        let e = profile
            .read(&m, "a\nb\n\n", "e.csv")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("column 'Name' is not in the header of e.csv (line 3: )"),
            "{e}"
        );
        let twice = export.replace("Name;X;Y;Z;T", "Name;X;Y;Z;X");
        let e = profile.read(&m, &twice, "e.csv").unwrap_err().to_string();
        assert!(
            e.contains("column 'X' appears 2 times in the header of e.csv (line 3, columns 2, 5)"),
            "{e}"
        );
    }

    #[test]
    fn a_bad_delimiter_is_refused_at_its_line() {
        let e = Profile::from_toml_str(
            "delimiter = \"ab\"\npoint = \"N\"\npattern = \"{X}\"\n[coordinates]\nd = \"D\"\n",
            "p.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.starts_with("p.toml:1: field 'delimiter': delimiter \"ab\""),
            "{e}"
        );
    }
}
