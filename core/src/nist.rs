//! NIST's Statistical Reference Datasets for nonlinear regression (StRD): the 27 problems of
//! lower, average and higher difficulty on which least-squares software is judged, with
//! certified parameters and residual sums of squares.
//!
//! The files are embedded (`core/data/nist/`, public domain, from NIST/ITL) and read from the
//! file itself: the line ranges of the starting values, certified values and data come from each
//! file's header. The model formulas are written once, generic over the scalar, so that the
//! dual-number Jacobian applies ([`Dataset::residual`]).
//!
//! ```
//! use volver_core::nist;
//! let ds = nist::dataset("Misra1a").unwrap();
//! assert_eq!(ds.y.len(), 14);
//! assert_eq!(ds.starts[0], vec![500.0, 1e-4]);
//! // The certified parameters reproduce the certified residual sum of squares.
//! let rss = ds.rss(&ds.certified);
//! assert!((rss / ds.certified_rss - 1.0).abs() < 1e-9);
//! assert!(nist::lre(1.2345, 1.2345) >= 11.0);
//! ```

use crate::error::{Error, Place, Result};
use crate::scalar::Real;

/// The 27 problems, in NIST's order of difficulty (lower, average, higher).
pub const NAMES: [&str; 27] = [
    "Misra1a", "Chwirut2", "Chwirut1", "Lanczos3", "Gauss1", "Gauss2", "DanWood", "Misra1b",
    "Kirby2", "Hahn1", "Nelson", "MGH17", "Lanczos1", "Lanczos2", "Gauss3", "Misra1c", "Misra1d",
    "Roszman1", "ENSO", "MGH09", "Thurber", "BoxBOD", "Rat42", "MGH10", "Eckerle4", "Rat43",
    "Bennett5",
];

macro_rules! embedded {
    ($($name:literal),* $(,)?) => {
        /// The embedded file of a problem.
        fn embedded(name: &str) -> Option<&'static str> {
            match name {
                $($name => Some(include_str!(concat!("../data/nist/", $name, ".dat"))),)*
                _ => None,
            }
        }
    };
}

embedded!(
    "Misra1a", "Chwirut2", "Chwirut1", "Lanczos3", "Gauss1", "Gauss2", "DanWood", "Misra1b",
    "Kirby2", "Hahn1", "Nelson", "MGH17", "Lanczos1", "Lanczos2", "Gauss3", "Misra1c", "Misra1d",
    "Roszman1", "ENSO", "MGH09", "Thurber", "BoxBOD", "Rat42", "MGH10", "Eckerle4", "Rat43",
    "Bennett5",
);

/// NIST's level of difficulty.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Difficulty {
    /// Lower.
    Lower,
    /// Average.
    Average,
    /// Higher.
    Higher,
}

/// One StRD problem, as its file gives it.
#[derive(Clone, Debug, PartialEq)]
pub struct Dataset {
    /// Its name (`Misra1a`).
    pub name: String,
    /// Level of difficulty.
    pub difficulty: Difficulty,
    /// Start 1 and start 2.
    pub starts: [Vec<f64>; 2],
    /// Certified parameters.
    pub certified: Vec<f64>,
    /// Their certified standard deviations.
    pub certified_sd: Vec<f64>,
    /// Certified residual sum of squares.
    pub certified_rss: f64,
    /// Responses.
    pub y: Vec<f64>,
    /// Predictors: one row per observation (one value, two for Nelson).
    pub x: Vec<Vec<f64>>,
}

/// The embedded problem called `name` (one of [`NAMES`]).
pub fn dataset(name: &str) -> Result<Dataset> {
    let text = embedded(name).ok_or_else(|| {
        Error::input(
            Place::file("nist").at_field("name"),
            format!(
                "unknown StRD problem '{name}'; the problems are {}",
                NAMES.join(", ")
            ),
        )
    })?;
    Dataset::parse(name, text, &format!("{name}.dat"))
}

/// Every embedded problem, in [`NAMES`] order.
pub fn all() -> Result<Vec<Dataset>> {
    NAMES.iter().map(|n| dataset(n)).collect()
}

/// The log relative error `−log10(|q − c| / |c|)` of `q` against the certified `c`, capped at 11
/// digits (NIST's and the Ceres/MINPACK studies' measure; `−log10 |q|` when `c = 0`); 0 for a
/// result that is not finite or has no correct digit.
pub fn lre(q: f64, c: f64) -> f64 {
    if !q.is_finite() {
        return 0.0;
    }
    let e = if c == 0.0 {
        q.abs()
    } else {
        (q - c).abs() / c.abs()
    };
    if e == 0.0 {
        11.0
    } else {
        (-e.log10()).clamp(0.0, 11.0)
    }
}

/// Numbers of the header's `(lines A to B)` after `key`.
fn line_range(text: &str, key: &str, label: &str) -> Result<(usize, usize)> {
    for (i, line) in text.lines().enumerate() {
        if let Some(pos) = line.find(key) {
            let rest = &line[pos + key.len()..];
            let nums: Vec<usize> = rest
                .split(|c: char| !c.is_ascii_digit())
                .filter(|s| !s.is_empty())
                .filter_map(|s| s.parse().ok())
                .collect();
            if let [a, b, ..] = nums[..] {
                return Ok((a, b));
            }
            return Err(Error::input(
                Place::file(label).at_line(i + 1).at_field(key),
                "expected '(lines A to B)'",
            ));
        }
    }
    Err(Error::input(
        Place::file(label).at_field(key),
        format!("no '{key}' line in the header"),
    ))
}

fn number(s: &str, label: &str, line: usize, field: &str) -> Result<f64> {
    let v: f64 = s.parse().map_err(|_| {
        Error::input(
            Place::file(label).at_line(line).at_field(field),
            format!("'{s}' is not a number"),
        )
    })?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(Error::input(
            Place::file(label).at_line(line).at_field(field),
            format!("'{s}' is not finite"),
        ))
    }
}

/// The level of difficulty a StRD file states.
fn difficulty(text: &str, label: &str) -> Result<Difficulty> {
    if text.contains("Lower Level of Difficulty") {
        Ok(Difficulty::Lower)
    } else if text.contains("Average Level of Difficulty") {
        Ok(Difficulty::Average)
    } else if text.contains("Higher Level of Difficulty") {
        Ok(Difficulty::Higher)
    } else {
        Err(Error::input(
            Place::file(label).at_field("difficulty"),
            "no 'Level of Difficulty' line",
        ))
    }
}

/// The lines of a StRD file, read section by section at the lines its header gives.
struct Strd<'a> {
    /// The file's lines.
    lines: Vec<&'a str>,
    /// The file's name, for errors.
    label: &'a str,
}

impl Strd<'_> {
    /// Line `n` (1-based), or the error that the header points past the end.
    fn line(&self, n: usize) -> Result<&str> {
        self.lines.get(n.wrapping_sub(1)).copied().ok_or_else(|| {
            Error::input(
                Place::file(self.label).at_line(n),
                format!(
                    "the header points past the end ({} lines)",
                    self.lines.len()
                ),
            )
        })
    }

    /// The parameter lines `first..=last` (`bK = start1 start2 certified sd`): the two starts,
    /// the certified values and their standard deviations.
    fn parameters(&self, first: usize, last: usize) -> Result<[Vec<f64>; 4]> {
        let label = self.label;
        let mut columns: [Vec<f64>; 4] = Default::default();
        for n in first..=last {
            let line = self.line(n)?;
            let (lhs, rhs) = line.split_once('=').ok_or_else(|| {
                Error::input(
                    Place::file(label).at_line(n),
                    "expected 'bK = start1 start2 certified sd'",
                )
            })?;
            let field = lhs.trim();
            let v: Vec<&str> = rhs.split_whitespace().collect();
            if v.len() != 4 {
                return Err(Error::input(
                    Place::file(label).at_line(n).at_field(field),
                    format!(
                        "expected 4 numbers (two starts, certified value, sd), found {}",
                        v.len()
                    ),
                ));
            }
            for (column, s) in columns.iter_mut().zip(&v) {
                column.push(number(s, label, n, field)?);
            }
        }
        Ok(columns)
    }

    /// The certified residual sum of squares, in lines `first..=last`.
    fn certified_rss(&self, first: usize, last: usize) -> Result<f64> {
        let mut certified_rss = None;
        for n in first..=last {
            let line = self.line(n)?;
            if let Some(rest) = line.trim_start().strip_prefix("Residual Sum of Squares:") {
                certified_rss = Some(number(
                    rest.trim(),
                    self.label,
                    n,
                    "Residual Sum of Squares",
                )?);
            }
        }
        certified_rss.ok_or_else(|| {
            Error::input(
                Place::file(self.label).at_field("Residual Sum of Squares"),
                format!("not found in lines {first} to {last}"),
            )
        })
    }

    /// The data lines `first..=last`: y and the predictors x1, x2 … of each observation.
    fn data(&self, first: usize, last: usize) -> Result<(Vec<f64>, Vec<Vec<f64>>)> {
        let label = self.label;
        let (mut y, mut x) = (vec![], vec![]);
        let mut width = None;
        for n in first..=last {
            let line = self.line(n)?;
            let v: Vec<&str> = line.split_whitespace().collect();
            if v.len() < 2 || width.is_some_and(|w| w != v.len()) {
                return Err(Error::input(
                    Place::file(label).at_line(n),
                    format!("expected y and the predictors, found {} values", v.len()),
                ));
            }
            width = Some(v.len());
            y.push(number(v[0], label, n, "y")?);
            x.push(
                v[1..]
                    .iter()
                    .enumerate()
                    .map(|(k, s)| number(s, label, n, &format!("x{}", k + 1)))
                    .collect::<Result<Vec<f64>>>()?,
            );
        }
        Ok((y, x))
    }
}

impl Dataset {
    /// Reads a StRD file (`label` names it in errors).
    pub fn parse(name: &str, text: &str, label: &str) -> Result<Dataset> {
        let (p_first, p_last) = line_range(text, "Starting Values", label)?;
        let (_, c_last) = line_range(text, "Certified Values", label)?;
        let (d_first, d_last) = line_range(text, "Data ", label)?;
        let strd = Strd {
            lines: text.lines().collect(),
            label,
        };
        let difficulty = difficulty(text, label)?;
        let [s1, s2, cert, sd] = strd.parameters(p_first, p_last)?;
        let certified_rss = strd.certified_rss(p_last + 1, c_last)?;
        let (y, x) = strd.data(d_first, d_last)?;
        let ds = Dataset {
            name: name.to_string(),
            difficulty,
            starts: [s1, s2],
            certified: cert,
            certified_sd: sd,
            certified_rss,
            y,
            x,
        };
        let expected = ds.n_params_of_model().ok_or_else(|| {
            Error::input(
                Place::file(label).at_field("name"),
                format!("no model is written for '{name}'"),
            )
        })?;
        if expected != ds.certified.len() {
            return Err(Error::input(
                Place::file(label).at_field("parameters"),
                format!(
                    "{name} has {expected} parameters, the file {}",
                    ds.certified.len()
                ),
            ));
        }
        Ok(ds)
    }

    /// Number of observations.
    pub fn n_obs(&self) -> usize {
        self.y.len()
    }

    /// Number of parameters.
    pub fn n_params(&self) -> usize {
        self.certified.len()
    }

    fn n_params_of_model(&self) -> Option<usize> {
        Some(match self.name.as_str() {
            "Misra1a" | "Misra1b" | "Misra1c" | "Misra1d" | "DanWood" | "BoxBOD" => 2,
            "Chwirut1" | "Chwirut2" | "Nelson" | "MGH10" | "Rat42" | "Eckerle4" | "Bennett5" => 3,
            "Roszman1" | "MGH09" | "Rat43" => 4,
            "Kirby2" | "MGH17" => 5,
            "Lanczos1" | "Lanczos2" | "Lanczos3" => 6,
            "Hahn1" | "Thurber" => 7,
            "Gauss1" | "Gauss2" | "Gauss3" => 8,
            "ENSO" => 9,
            _ => return None,
        })
    }

    /// The model's value at observation `i` for parameters `b` (for Nelson, of log y).
    pub fn model<T: Real>(&self, i: usize, b: &[T]) -> T {
        let x = self.x[i][0];
        let c = |v: f64| T::from(v);
        let e = |t: T| t.exp();
        match self.name.as_str() {
            "Misra1a" | "BoxBOD" => b[0] * (c(1.0) - e(-b[1] * x)),
            "Chwirut1" | "Chwirut2" => e(-b[0] * x) / (b[1] + b[2] * x),
            "DanWood" => b[0] * e(b[1] * x.ln()),
            "Misra1b" => b[0] * (c(1.0) - (c(1.0) + b[1] * (x / 2.0)).powi(-2)),
            "Misra1c" => b[0] * (c(1.0) - (c(1.0) + b[1] * (2.0 * x)).powf(-0.5)),
            "Misra1d" => b[0] * b[1] * x / (c(1.0) + b[1] * x),
            "Kirby2" => (b[0] + b[1] * x + b[2] * (x * x)) / (c(1.0) + b[3] * x + b[4] * (x * x)),
            "Hahn1" | "Thurber" => {
                (b[0] + b[1] * x + b[2] * (x * x) + b[3] * (x * x * x))
                    / (c(1.0) + b[4] * x + b[5] * (x * x) + b[6] * (x * x * x))
            }
            "Nelson" => b[0] - b[1] * x * e(-b[2] * self.x[i][1]),
            "MGH17" => b[0] + b[1] * e(-b[3] * x) + b[2] * e(-b[4] * x),
            "Lanczos1" | "Lanczos2" | "Lanczos3" => {
                b[0] * e(-b[1] * x) + b[2] * e(-b[3] * x) + b[4] * e(-b[5] * x)
            }
            "Gauss1" | "Gauss2" | "Gauss3" => {
                let g = |a: T, m: T, w: T| a * e(-((c(x) - m) * (c(x) - m)) / (w * w));
                b[0] * e(-b[1] * x) + g(b[2], b[3], b[4]) + g(b[5], b[6], b[7])
            }
            "Roszman1" => {
                // NIST's certified values need arctan in [0, π): the angle of the point
                // (x − b4, b3) (x − b4 is negative on the whole data set).
                let d = c(x) - b[3];
                let mut a = (b[2] / d).atan();
                if d.re() < 0.0 {
                    a += std::f64::consts::PI;
                }
                b[0] - b[1] * x - a / std::f64::consts::PI
            }
            "ENSO" => {
                let tau = 2.0 * std::f64::consts::PI * x;
                let w12 = tau / 12.0;
                b[0] + b[1] * w12.cos()
                    + b[2] * w12.sin()
                    + b[4] * (b[3].recip() * tau).cos()
                    + b[5] * (b[3].recip() * tau).sin()
                    + b[7] * (b[6].recip() * tau).cos()
                    + b[8] * (b[6].recip() * tau).sin()
            }
            "MGH09" => b[0] * (c(x * x) + b[1] * x) / (c(x * x) + b[2] * x + b[3]),
            "MGH10" => b[0] * e(b[1] / (c(x) + b[2])),
            "Rat42" => b[0] / (c(1.0) + e(b[1] - b[2] * x)),
            "Rat43" => b[0] / (c(1.0) + e(b[1] - b[2] * x)).powd(b[3].recip()),
            "Eckerle4" => {
                let z = (c(x) - b[2]) / b[1];
                b[0] / b[1] * e(z * z * (-0.5))
            }
            "Bennett5" => b[0] * (b[1] + x).powd(-b[2].recip()),
            // `parse` refuses a name without a model.
            _ => c(f64::NAN),
        }
    }

    /// Observation `i` as the model predicts it: y (for Nelson, ln y).
    pub fn observation(&self, i: usize) -> f64 {
        if self.name == "Nelson" {
            self.y[i].ln()
        } else {
            self.y[i]
        }
    }

    /// Residual of observation `i`: model − y (for Nelson, model − ln y).
    pub fn residual<T: Real>(&self, i: usize, b: &[T]) -> T {
        self.model(i, b) - self.observation(i)
    }

    /// Residual sum of squares at `b`.
    pub fn rss(&self, b: &[f64]) -> f64 {
        (0..self.n_obs()).map(|i| self.residual(i, b).powi(2)).sum()
    }
}
