//! The offsets a control keeps beside a program: work offsets (`G54`…`G59.3`), the `G92`/`G52`
//! offset, the `G28`/`G30` reference positions and the tool table, read from LinuxCNC's
//! parameter file (`.var`) and tool table (`.tbl`), or from a plain TOML file.
//!
//! Everything is stored in mm (linear axes) and degrees (rotary axes), per axis letter in the
//! order X Y Z A B C. LinuxCNC keeps these files in the machine's units (`[TRAJ] LINEAR_UNITS`
//! of its INI file); [`OffsetUnits`] says which.
//!
//! LinuxCNC's parameter numbers (its G-code reference, "Numbered Parameters"): 5161–5166 the
//! `G28` position, 5181–5186 the `G30` position, 5210 whether the `G92` offset is applied,
//! 5211–5216 the `G92` offset, 5220 the coordinate system in force (1 = `G54` … 9 = `G59.3`),
//! 5221 + 20 (n − 1) + 0…5 coordinate system n's X Y Z A B C offsets and + 9 its rotation about
//! Z (not read unless zero). Axes U, V, W are ignored. The tool table: one tool a line,
//! `T<n> P<pocket> X… Y… Z… A… B… C… D… ;comment` (LinuxCNC's "Tool Table Format").

use crate::error::{Error, Place, Result};
use std::collections::BTreeMap;

/// The names of the nine coordinate systems, in LinuxCNC's numbering (1 = `G54`).
pub const SYSTEMS: [&str; 9] = [
    "G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3",
];

/// The axis letters of every offset array, in order.
pub const LETTERS: [char; 6] = ['X', 'Y', 'Z', 'A', 'B', 'C'];

/// The unit of a control's offset files (LinuxCNC: the machine's units).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum OffsetUnits {
    /// Millimetres.
    #[default]
    Mm,
    /// Inches (25.4 mm).
    Inch,
}

impl OffsetUnits {
    /// mm per unit of a linear axis.
    pub fn mm(self) -> f64 {
        match self {
            OffsetUnits::Mm => 1.0,
            OffsetUnits::Inch => 25.4,
        }
    }

    /// Reads `mm` or `inch`.
    pub fn from_name(name: &str) -> Option<OffsetUnits> {
        match name.trim().to_ascii_lowercase().as_str() {
            "mm" => Some(OffsetUnits::Mm),
            "inch" | "in" => Some(OffsetUnits::Inch),
            _ => None,
        }
    }
}

/// The offsets a program runs with (mm and degrees, axis order [`LETTERS`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Offsets {
    /// Work offsets of `G54` … `G59.3`.
    pub work: [[f64; 6]; 9],
    /// The coordinate system in force at the start (0 = `G54`).
    pub active: usize,
    /// The `G92` (and `G52`) offset.
    pub g92: [f64; 6],
    /// The `G28` and `G30` positions (machine coordinates).
    pub home: [[f64; 6]; 2],
    /// Tool offsets by tool number (the tool length is the Z entry on a mill).
    pub tools: BTreeMap<i64, [f64; 6]>,
    /// Whether a tool table was given (without one, `G43` is refused).
    pub tool_table: bool,
    /// Whether any offset was given (without, the program's coordinates are machine positions).
    pub given: bool,
}

impl Default for Offsets {
    fn default() -> Self {
        Offsets {
            work: [[0.0; 6]; 9],
            active: 0,
            g92: [0.0; 6],
            home: [[0.0; 6]; 2],
            tools: BTreeMap::new(),
            tool_table: false,
            given: false,
        }
    }
}

/// The largest offset read (mm or degrees): beyond any machine.
pub const MAX_OFFSET: f64 = 1e6;

/// A number of an offset file, in mm or degrees, refused when not finite or beyond
/// [`MAX_OFFSET`].
fn value(text: &str, k: usize, units: OffsetUnits, place: &Place) -> Result<f64> {
    let v: f64 = text.trim().parse().map_err(|_| {
        Error::input(
            place.clone(),
            format!("expected a number, found \"{}\"", short(text)),
        )
    })?;
    let v = if k < 3 { v * units.mm() } else { v };
    if !v.is_finite() || v.abs() > MAX_OFFSET {
        return Err(Error::input(
            place.clone(),
            format!("{v:e} is not an offset (|value| ≤ {MAX_OFFSET:e} mm or degrees)"),
        ));
    }
    Ok(v)
}

/// At most 40 characters of `text`, for messages.
fn short(text: &str) -> String {
    let t: String = text.chars().take(40).collect();
    if t.len() < text.len() {
        format!("{t}…")
    } else {
        t
    }
}

impl Offsets {
    /// Reads LinuxCNC's parameter file (`.var`: a parameter number and its value per line) in
    /// `units`; `file` names it in messages. Parameters volver does not use are skipped; a
    /// coordinate system rotated about Z is refused.
    ///
    /// ```
    /// use volver_core::gcode::offsets::{OffsetUnits, Offsets};
    /// let o = Offsets::from_linuxcnc_var("5220 2\n5241 100\n5243 -300.5\n", "p.var", OffsetUnits::Mm).unwrap();
    /// assert_eq!(o.active, 1);
    /// assert_eq!(o.work[1][0], 100.0);
    /// assert_eq!(o.work[1][2], -300.5);
    /// ```
    pub fn from_linuxcnc_var(text: &str, file: &str, units: OffsetUnits) -> Result<Offsets> {
        let mut o = Offsets {
            given: true,
            ..Offsets::default()
        };
        for (i, line) in text.lines().enumerate() {
            let place = Place::file(file).at_line(i + 1);
            let line = line.trim_start_matches('\u{feff}').trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let mut parts = line.split_whitespace();
            let (Some(n), Some(v)) = (parts.next(), parts.next()) else {
                return Err(Error::input(
                    place,
                    "expected a parameter number and its value",
                ));
            };
            let n: u32 = n.parse().map_err(|_| {
                Error::input(
                    place.clone(),
                    format!("expected a parameter number, found \"{}\"", short(n)),
                )
            })?;
            o.set_parameter(n, v, units, &place.at_field(n.to_string()))?;
        }
        Ok(o)
    }

    /// One parameter of a `.var` file.
    fn set_parameter(&mut self, n: u32, v: &str, units: OffsetUnits, place: &Place) -> Result<()> {
        let k = |base: u32| (n - base) as usize;
        match n {
            5161..=5166 => self.home[0][k(5161)] = value(v, k(5161), units, place)?,
            5181..=5186 => self.home[1][k(5181)] = value(v, k(5181), units, place)?,
            5211..=5216 => self.g92[k(5211)] = value(v, k(5211), units, place)?,
            5220 => {
                let s = value(v, 3, OffsetUnits::Mm, place)?;
                if !(1.0..=9.0).contains(&s) || s.fract() != 0.0 {
                    return Err(Error::input(
                        place.clone(),
                        format!("coordinate system {s}: 1 (G54) … 9 (G59.3)"),
                    ));
                }
                self.active = s as usize - 1;
            }
            5221..=5400 => {
                let (sys, j) = (k(5221) / 20, k(5221) % 20);
                if j < 6 {
                    self.work[sys][j] = value(v, j, units, place)?;
                } else if j == 9 && value(v, 3, OffsetUnits::Mm, place)? != 0.0 {
                    return Err(Error::input(
                        place.clone(),
                        format!(
                            "{} is rotated about Z: rotated coordinate systems are not read \
                             (volver compensates positions in unrotated offsets)",
                            SYSTEMS[sys]
                        ),
                    ));
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// Adds LinuxCNC's tool table (`.tbl`) in `units`; `file` names it in messages. Tool numbers
    /// must be unique.
    ///
    /// ```
    /// use volver_core::gcode::offsets::{OffsetUnits, Offsets};
    /// let mut o = Offsets::default();
    /// o.add_linuxcnc_tools("T1 P1 Z25.0 D6 ;end mill\nT7 P2 Z1.5\n", "t.tbl", OffsetUnits::Inch).unwrap();
    /// assert_eq!(o.tools[&7][2], 1.5 * 25.4);
    /// ```
    pub fn add_linuxcnc_tools(&mut self, text: &str, file: &str, units: OffsetUnits) -> Result<()> {
        self.tool_table = true;
        self.given = true;
        for (i, line) in text.lines().enumerate() {
            let place = Place::file(file).at_line(i + 1);
            let code = line.split(';').next().unwrap_or("");
            let code = code.trim_start_matches('\u{feff}').trim();
            if code.is_empty() {
                continue;
            }
            let mut tool = None;
            let mut off = [0.0; 6];
            for token in code.split_whitespace() {
                let (letter, rest) = token.split_at(token.chars().next().map_or(0, char::len_utf8));
                let letter = letter.to_ascii_uppercase();
                let at = place.clone().at_field(letter.clone());
                match letter.as_str() {
                    "T" => {
                        let t: i64 = rest.parse().map_err(|_| {
                            Error::input(
                                at,
                                format!("expected a tool number, found \"{}\"", short(rest)),
                            )
                        })?;
                        tool = Some(t);
                    }
                    l => {
                        if let Some(k) = LETTERS.iter().position(|c| c.to_string() == l) {
                            off[k] = value(rest, k, units, &at)?;
                        }
                    }
                }
            }
            let Some(t) = tool else {
                return Err(Error::input(
                    place,
                    "a tool table line needs its tool number (T…)",
                ));
            };
            if self.tools.insert(t, off).is_some() {
                return Err(Error::input(
                    place.at_field("T"),
                    format!("tool {t} is listed twice"),
                ));
            }
        }
        Ok(())
    }

    /// Reads volver's offsets file (TOML, mm and degrees unless `units = "inch"`):
    ///
    /// ```toml
    /// units = "mm"          # or "inch"
    /// active = "G55"        # the coordinate system in force at the start (default G54)
    /// [work.G55]
    /// X = 100.0
    /// Z = -300.0
    /// [g92]
    /// X = 0.0
    /// [home.G28]
    /// Z = 0.0
    /// [tool.1]
    /// Z = 25.0              # tool 1's length
    /// ```
    ///
    /// ```
    /// use volver_core::gcode::offsets::Offsets;
    /// let o = Offsets::from_toml_str("active = \"G55\"\n[work.G55]\nX = 100.0\n[tool.3]\nZ = 42.0\n", "o.toml").unwrap();
    /// assert_eq!((o.active, o.work[1][0], o.tools[&3][2]), (1, 100.0, 42.0));
    /// ```
    pub fn from_toml_str(text: &str, file: &str) -> Result<Offsets> {
        #[derive(serde::Deserialize)]
        #[serde(deny_unknown_fields)]
        struct File {
            units: Option<String>,
            active: Option<String>,
            #[serde(default)]
            work: BTreeMap<String, BTreeMap<String, f64>>,
            #[serde(default)]
            g92: BTreeMap<String, f64>,
            #[serde(default)]
            home: BTreeMap<String, BTreeMap<String, f64>>,
            #[serde(default)]
            tool: BTreeMap<String, BTreeMap<String, f64>>,
        }
        let f: File = toml::from_str(text).map_err(|e| {
            Error::input(
                Place::file(file),
                e.to_string().lines().collect::<Vec<_>>().join(" "),
            )
        })?;
        let units = match &f.units {
            None => OffsetUnits::Mm,
            Some(u) => OffsetUnits::from_name(u).ok_or_else(|| {
                Error::input(
                    Place::file(file).at_field("units"),
                    format!("\"{}\": mm or inch", short(u)),
                )
            })?,
        };
        let mut o = Offsets {
            given: true,
            tool_table: !f.tool.is_empty(),
            ..Offsets::default()
        };
        if let Some(a) = &f.active {
            o.active = system(a).ok_or_else(|| {
                Error::input(
                    Place::file(file).at_field("active"),
                    format!("\"{}\": one of {}", short(a), SYSTEMS.join(", ")),
                )
            })?;
        }
        for (name, axes) in &f.work {
            let place = Place::file(file).at_field(format!("work.{name}"));
            let s = system(name).ok_or_else(|| {
                Error::input(
                    place.clone(),
                    format!("not a coordinate system: one of {}", SYSTEMS.join(", ")),
                )
            })?;
            o.work[s] = axis_values(axes, units, &place)?;
        }
        o.g92 = axis_values(&f.g92, units, &Place::file(file).at_field("g92"))?;
        for (name, axes) in &f.home {
            let place = Place::file(file).at_field(format!("home.{name}"));
            let h = match name.as_str() {
                "G28" => 0,
                "G30" => 1,
                _ => return Err(Error::input(place, "a reference position is G28 or G30")),
            };
            o.home[h] = axis_values(axes, units, &place)?;
        }
        for (name, axes) in &f.tool {
            let place = Place::file(file).at_field(format!("tool.{name}"));
            let t: i64 = name
                .parse()
                .map_err(|_| Error::input(place.clone(), "a tool is named by its number"))?;
            o.tools.insert(t, axis_values(axes, units, &place)?);
        }
        Ok(o)
    }

    /// The total offset of coordinate system `system` with the `G92` offset (mm, degrees).
    pub fn origin(&self, system: usize) -> [f64; 6] {
        std::array::from_fn(|k| self.work[system][k] + self.g92[k])
    }
}

/// The index of a coordinate system's name (`G54` → 0, `G59.3` → 8).
pub fn system(name: &str) -> Option<usize> {
    SYSTEMS
        .iter()
        .position(|s| s.eq_ignore_ascii_case(name.trim()))
}

/// A TOML table of axis letters and values, in mm and degrees.
fn axis_values(
    axes: &BTreeMap<String, f64>,
    units: OffsetUnits,
    place: &Place,
) -> Result<[f64; 6]> {
    let mut out = [0.0; 6];
    for (letter, v) in axes {
        let at = place.clone().at_field(format!(
            "{}.{letter}",
            place.field.clone().unwrap_or_default()
        ));
        let k = LETTERS
            .iter()
            .position(|c| c.to_string().eq_ignore_ascii_case(letter))
            .ok_or_else(|| Error::input(at.clone(), "an axis letter: X, Y, Z, A, B or C"))?;
        out[k] = value(&v.to_string(), k, units, &at)?;
    }
    Ok(out)
}
