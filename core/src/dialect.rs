//! G-code dialects: the words that differ between the controls volver writes programs for.
//!
//! Two dialects are known, each from its own specification:
//!
//! - [`Dialect::LinuxCnc`]: RS274NGC as LinuxCNC reads it (LinuxCNC's G-code reference; NIST
//!   RS274NGC v3). `G4 P` is a dwell in **seconds** (decimals allowed); a number without a
//!   decimal point is read in the program's units (`X100` is 100 mm under `G21`); a `%` first
//!   line needs a `%` last line; several M words of different modal groups may share a block.
//! - [`Dialect::Fanuc`]: Fanuc-style controls (Fanuc, and the many controls that read its
//!   format). `G04 P` is a dwell in **milliseconds** and takes no decimal point (`G04 X` is in
//!   seconds); an axis value without a decimal point is read in the least input increment
//!   (`X100` is 0.1 mm on a 1 µm control), so every axis value is written with one; the program
//!   is framed by `%` lines and starts with its number `O…`; many controls take one M word per
//!   block.
//!
//! Comments are in parentheses in both.
//!
//! ```
//! use volver_core::dialect::Dialect;
//! assert_eq!(Dialect::LinuxCnc.dwell_words(2.5), "G4 P2.5");
//! assert_eq!(Dialect::Fanuc.dwell_words(2.5), "G04 P2500");
//! assert_eq!(Dialect::Fanuc.value(100.0), "100.");
//! assert_eq!(Dialect::LinuxCnc.value(100.0), "100");
//! assert_eq!("fanuc".parse::<Dialect>(), Ok(Dialect::Fanuc));
//! ```

use std::fmt;
use std::str::FromStr;

/// The longest dwell a program may hold (s): 99 999.999 s, the largest `G04 P` of eight digits
/// in milliseconds that Fanuc-style controls accept (a little under 28 h).
pub const MAX_DWELL_S: f64 = 99_999.999;

/// The program number of the Fanuc dialect's `O` line.
pub const FANUC_PROGRAM_NUMBER: u32 = 1;

/// A G-code dialect (see the module's docs for the rules of each).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub enum Dialect {
    /// LinuxCNC / RS274NGC: dwell `G4 P<seconds>`.
    #[default]
    LinuxCnc,
    /// Fanuc-style: dwell `G04 P<milliseconds>`, `O` program number, decimal points on every
    /// axis value.
    Fanuc,
}

impl Dialect {
    /// The dwell block's words for `seconds` (finite, 0 to [`MAX_DWELL_S`]; rounded to the
    /// millisecond, the resolution both dialects state): `G4 P<s>` or `G04 P<ms>`.
    ///
    /// ```
    /// use volver_core::dialect::Dialect;
    /// assert_eq!(Dialect::LinuxCnc.dwell_words(30.0), "G4 P30");
    /// assert_eq!(Dialect::LinuxCnc.dwell_words(0.0004), "G4 P0");
    /// assert_eq!(Dialect::Fanuc.dwell_words(30.0), "G04 P30000");
    /// ```
    pub fn dwell_words(self, seconds: f64) -> String {
        debug_assert!(seconds.is_finite() && (0.0..=MAX_DWELL_S).contains(&seconds));
        let ms = (seconds * crate::units::MS_PER_S).round();
        match self {
            Dialect::LinuxCnc => format!("G4 P{}", ms / crate::units::MS_PER_S + 0.0),
            Dialect::Fanuc => format!("G04 P{}", ms as u64),
        }
    }

    /// An axis value (mm or degrees, rounded to 1e-6) as this dialect reads it: the shortest
    /// decimal for LinuxCNC, always with a decimal point for Fanuc (`100.`, `-0.5`).
    pub fn value(self, v: f64) -> String {
        self.decimal_point(format!("{}", (v * 1e6).round() / 1e6 + 0.0))
    }

    /// A number as written (`100`, `-0.5`) as this dialect needs it: with a decimal point for
    /// Fanuc, which reads a value without one in its least input increment (`100.`).
    ///
    /// ```
    /// use volver_core::dialect::Dialect;
    /// assert_eq!(Dialect::Fanuc.decimal_point("100".into()), "100.");
    /// assert_eq!(Dialect::LinuxCnc.decimal_point("100".into()), "100");
    /// ```
    pub fn decimal_point(self, mut text: String) -> String {
        if self == Dialect::Fanuc && !text.contains('.') {
            text.push('.');
        }
        text
    }

    /// The rapid-move word: `G0` or `G00`.
    pub fn rapid(self) -> &'static str {
        match self {
            Dialect::LinuxCnc => "G0",
            Dialect::Fanuc => "G00",
        }
    }

    /// The feed-move word: `G1` or `G01`.
    pub fn feed(self) -> &'static str {
        match self {
            Dialect::LinuxCnc => "G1",
            Dialect::Fanuc => "G01",
        }
    }

    /// The program stop word (`M0`, `M00`), or with `optional` the optional stop (`M1`, `M01`).
    pub fn stop(self, optional: bool) -> &'static str {
        match (self, optional) {
            (Dialect::LinuxCnc, false) => "M0",
            (Dialect::LinuxCnc, true) => "M1",
            (Dialect::Fanuc, false) => "M00",
            (Dialect::Fanuc, true) => "M01",
        }
    }

    /// The program's first lines: `%`, then for Fanuc the program number `O0001`.
    pub fn program_start(self) -> String {
        match self {
            Dialect::LinuxCnc => "%\n".to_string(),
            Dialect::Fanuc => format!("%\nO{FANUC_PROGRAM_NUMBER:04}\n"),
        }
    }

    /// The start block(s) that put the control in a known state: cutter compensation, tool
    /// length offset and canned cycles cancelled (`G40 G49 G80`), mm, absolute, XY plane, feed
    /// per minute (`G21 G90 G17 G94`), spindle and coolant off (`M5 M9`; one M word per block
    /// for Fanuc).
    pub fn start_blocks(self) -> &'static str {
        match self {
            Dialect::LinuxCnc => "G40 G49 G80\nG21 G90 G17 G94\nM5 M9\n",
            Dialect::Fanuc => "G40 G49 G80\nG21 G90 G17 G94\nM05\nM09\n",
        }
    }

    /// The program's end: `M30` (end and rewind), then `%`.
    pub fn program_end(self) -> &'static str {
        "M30\n%\n"
    }

    /// A comment with any parenthesis in `text` removed (neither dialect nests comments).
    pub fn comment(self, text: &str) -> String {
        format!("({})", text.replace(['(', ')'], ""))
    }
}

impl fmt::Display for Dialect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Dialect::LinuxCnc => "linuxcnc",
            Dialect::Fanuc => "fanuc",
        })
    }
}

impl FromStr for Dialect {
    type Err = String;

    /// `linuxcnc` (or `rs274ngc`) and `fanuc`, in any case.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "linuxcnc" | "rs274ngc" => Ok(Dialect::LinuxCnc),
            "fanuc" => Ok(Dialect::Fanuc),
            _ => Err(format!(
                "unknown G-code dialect '{s}': expected linuxcnc (RS274NGC, G4 P in seconds) or \
                 fanuc (G04 P in milliseconds)"
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dwells_are_in_each_dialects_unit_and_values_read_as_mm() {
        for (s, lc, fa) in [
            (0.0, "G4 P0", "G04 P0"),
            (10.0, "G4 P10", "G04 P10000"),
            (12.3456, "G4 P12.346", "G04 P12346"),
            (MAX_DWELL_S, "G4 P99999.999", "G04 P99999999"),
        ] {
            assert_eq!(Dialect::LinuxCnc.dwell_words(s), lc);
            assert_eq!(Dialect::Fanuc.dwell_words(s), fa);
        }
        assert_eq!(Dialect::Fanuc.value(-0.0), "0.");
        assert_eq!(Dialect::Fanuc.value(-12.5), "-12.5");
        assert_eq!(Dialect::LinuxCnc.value(1e-7), "0");
        assert!(Dialect::Fanuc.program_start().starts_with("%\nO0001\n"));
        assert!("haas".parse::<Dialect>().unwrap_err().contains("'haas'"));
        assert_eq!("LinuxCNC".parse::<Dialect>(), Ok(Dialect::LinuxCnc));
        assert_eq!(Dialect::Fanuc.comment("a (b) c"), "(a b c)");
    }
}
