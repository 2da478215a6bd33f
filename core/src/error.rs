//! One error type for everything the metrology core reads or builds.
//!
//! Input errors name the file, the line (1-based, when it is known) and the field or column, and
//! say what was expected: `data.csv:17: column 'C': expected a number in degrees, found "abc"`.

use std::fmt;
use std::path::PathBuf;

/// Where a piece of input came from: a file name (or a label such as `<embedded XCFZ>`), a line
/// and a field/column name.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Place {
    /// File name or label of the input.
    pub file: String,
    /// 1-based line number, when known.
    pub line: Option<usize>,
    /// Field (TOML key path, JSON key) or column (CSV header name), when known.
    pub field: Option<String>,
}

impl Place {
    /// A place that is a whole file.
    pub fn file(file: impl Into<String>) -> Self {
        Place {
            file: file.into(),
            line: None,
            field: None,
        }
    }

    /// This place at a given 1-based line.
    pub fn at_line(mut self, line: usize) -> Self {
        self.line = Some(line);
        self
    }

    /// This place at a given field or column.
    pub fn at_field(mut self, field: impl Into<String>) -> Self {
        self.field = Some(field.into());
        self
    }
}

impl fmt::Display for Place {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file)?;
        if let Some(line) = self.line {
            write!(f, ":{line}")?;
        }
        if let Some(field) = &self.field {
            write!(f, ": field '{field}'")?;
        }
        Ok(())
    }
}

/// Errors of the metrology core.
///
/// Every variant but [`Error::Io`] and [`Error::Input`] is a failure of a model, its data or its
/// options rather than of a file's text; their `message` is the complete text printed (the
/// variant says what kind of failure it is, for a caller that reacts to it).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating-system error.
        source: std::io::Error,
    },
    /// Input that does not say what it must: the place and what was expected.
    #[error("{place}: {message}")]
    Input {
        /// Where the bad input is.
        place: Place,
        /// What is wrong and what was expected.
        message: String,
    },
    /// More parameters than the model's fixed capacity beside the tracker pose.
    #[error("{message}")]
    TooManyParameters {
        /// What is modelled and the capacity.
        message: String,
    },
    /// A parameter vector whose length is not the model's parameter count.
    #[error("{message}")]
    ParameterCount {
        /// The model's parameter count.
        expected: usize,
        /// The length given.
        got: usize,
        /// The complete message (who needs the parameters).
        message: String,
    },
    /// A value that must be finite is not (a parameter, a simulated point, a tool point).
    #[error("{message}")]
    NonFinite {
        /// What is not finite, and where.
        message: String,
    },
    /// A linear system that cannot be solved (a singular Jacobian, a projection).
    #[error("{message}")]
    Singular {
        /// Which system, and where.
        message: String,
    },
    /// An option or argument outside its domain.
    #[error("{message}")]
    InvalidOption {
        /// The option's name (`decimals`, `chord_tol_mm`, `step`, `hold`, `tool_axis`, …).
        name: &'static str,
        /// What is wrong and what is accepted.
        message: String,
    },
    /// A request the machine cannot satisfy (an axis it lacks, an orientation it cannot set).
    #[error("{message}")]
    MachineMismatch {
        /// What the machine lacks.
        message: String,
    },
    /// A measurement the model cannot use: a station or reflector index the machine lacks, a
    /// missing `t_s` where the model has thermal drift.
    #[error("{message}")]
    MeasurementMismatch {
        /// The measurement's 1-based line in its file.
        line: usize,
        /// What does not match.
        message: String,
    },
    /// A name that is not an ISO 230 error name.
    #[error("'{name}' is not an ISO 230 error name")]
    UnknownErrorName {
        /// The name as given.
        name: String,
    },
    /// Constraints of an error model that no parameter vector satisfies.
    #[error("{message}")]
    ContradictoryConstraints {
        /// By how much they stay unsatisfied.
        message: String,
    },
    /// Nothing to work on (no measured points).
    #[error("{message}")]
    NoData {
        /// What is missing.
        message: String,
    },
    /// A value that could not be serialised (a machine file written back as TOML).
    #[error("{message}")]
    Serialize {
        /// What was written and the serialiser's error.
        message: String,
    },
}

impl Error {
    /// An input error at `place`.
    pub fn input(place: Place, message: impl Into<String>) -> Self {
        Error::Input {
            place,
            message: message.into(),
        }
    }
}

/// Result with the core's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

/// 1-based line of a byte offset in `source`.
pub(crate) fn line_of_offset(source: &str, offset: usize) -> usize {
    source[..offset.min(source.len())]
        .bytes()
        .filter(|&b| b == b'\n')
        .count()
        + 1
}

/// 1-based line of the first occurrence of `needle` (as a quoted string, else bare) in `source`.
/// Used to point semantic errors (an unknown ISO name, say) at the line that holds them.
pub(crate) fn line_of_text(source: &str, needle: &str) -> Option<usize> {
    let quoted = format!("\"{needle}\"");
    source
        .find(&quoted)
        .or_else(|| source.find(needle))
        .map(|off| line_of_offset(source, off))
}

/// Turns a `toml` deserialisation error into an [`Error::Input`] with file and line.
pub(crate) fn from_toml(file: &str, source: &str, err: toml::de::Error) -> Error {
    let mut place = Place::file(file);
    if let Some(span) = err.span() {
        place = place.at_line(line_of_offset(source, span.start));
    }
    Error::input(place, err.message().trim().to_string())
}

/// `text` without a leading UTF-8 byte-order mark (spreadsheets and some editors write one); an
/// invisible first character is not part of a file's first name or key.
///
/// ```
/// assert_eq!(volver_core::error::without_bom("\u{feff}name = 1"), "name = 1");
/// ```
pub fn without_bom(text: &str) -> &str {
    text.strip_prefix('\u{feff}').unwrap_or(text)
}

/// `text` with every line ending LF: CR LF and a lone CR (old Mac exports, some measuring
/// software) end lines too, so that a CR-only file is not read as one line.
///
/// ```
/// assert_eq!(volver_core::error::lf_lines("a\rb\r\nc"), "a\nb\nc");
/// ```
pub fn lf_lines(text: &str) -> std::borrow::Cow<'_, str> {
    if text.contains('\r') {
        std::borrow::Cow::Owned(text.replace("\r\n", "\n").replace('\r', "\n"))
    } else {
        std::borrow::Cow::Borrowed(text)
    }
}

/// A number for a message: as written for ordinary sizes, in scientific notation when tiny or
/// huge (`1e300`, not three hundred digits).
///
/// ```
/// use volver_core::error::number;
/// assert_eq!(number(2.5), "2.5");
/// assert_eq!(number(1e300), "1e300");
/// assert_eq!(number(-1e-300), "-1e-300");
/// assert_eq!(number(0.0), "0");
/// ```
pub fn number(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-4..1e9).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}
