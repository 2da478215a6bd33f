//! The controller files of `volver tables --format`: which tables each control takes (the
//! leadscrew projection for LinuxCNC and a Siemens control without cross-axis compensation,
//! the joint leadscrew + cross-axis projection for Siemens with `$AN_CEC`), their file names
//! and texts, and what a control cannot take, said before anything is written.

use super::PerAxisComparison;
use crate::error::{Error, Result};
use std::fmt;
use std::str::FromStr;
use volver_core::machine::Machine;
use volver_core::tables::linuxcnc::linuxcnc_files;
use volver_core::tables::per_axis::PerAxisTables;
use volver_core::tables::siemens::{SiemensOptions, siemens_cec_with, siemens_lec_with};

/// One output format of `volver tables`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// `errors-isg.csv`: the errors for an ISG-kernel volumetric compensation.
    Isg,
    /// `errors-etalon.txt`: the errors in Etalon's exchange style.
    Etalon,
    /// `errors.csv` (and `errors-u95.csv`): the errors, plain CSV.
    Csv,
    /// `compX.txt` per axis and `linuxcnc-ini.txt`: LinuxCNC's per-joint compensation files of
    /// the leadscrew projection.
    Linuxcnc,
    /// `siemens-lec-AX_EEC.INI`: SINUMERIK leadscrew error compensation of the leadscrew
    /// projection, for a control without cross-axis compensation (plus
    /// `siemens-lec-NC_CEC.INI` when an axis' tables depend on the direction: the halves of
    /// its reversal).
    SiemensLec,
    /// `siemens-cec-AX_EEC.INI` and `siemens-cec-NC_CEC.INI`: the leadscrew and cross-axis
    /// tables of the joint projection, loaded together.
    SiemensCec,
}

impl Format {
    /// Every format, the order `volver tables` writes them.
    pub const ALL: [Format; 6] = [
        Format::Isg,
        Format::Etalon,
        Format::Csv,
        Format::Linuxcnc,
        Format::SiemensLec,
        Format::SiemensCec,
    ];

    /// Whether the format is a control's per-axis table (a projection of the volumetric
    /// error) rather than the error tables themselves.
    pub fn is_controller(self) -> bool {
        matches!(
            self,
            Format::Linuxcnc | Format::SiemensLec | Format::SiemensCec
        )
    }

    /// Every file the format may write in the output folder (for LinuxCNC, the file of any
    /// axis), so that they can be claimed before anything is read.
    pub fn file_names(self) -> Vec<String> {
        match self {
            Format::Isg => vec!["errors-isg.csv".into()],
            Format::Etalon => vec!["errors-etalon.txt".into()],
            Format::Csv => vec!["errors.csv".into(), "errors-u95.csv".into()],
            Format::Linuxcnc => "XYZABC"
                .chars()
                .map(|c| format!("comp{c}.txt"))
                .chain(["linuxcnc-ini.txt".to_string()])
                .collect(),
            Format::SiemensLec | Format::SiemensCec => ["AX_EEC", "NC_CEC"]
                .iter()
                .map(|part| siemens_file(self, part))
                .collect(),
        }
    }

    /// The name `--format` takes.
    pub fn name(self) -> &'static str {
        match self {
            Format::Isg => "isg",
            Format::Etalon => "etalon",
            Format::Csv => "csv",
            Format::Linuxcnc => "linuxcnc",
            Format::SiemensLec => "siemens-lec",
            Format::SiemensCec => "siemens-cec",
        }
    }
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Format {
    type Err = Error;

    /// A name of [`Format::name`] (any case).
    fn from_str(s: &str) -> Result<Format> {
        Format::ALL
            .into_iter()
            .find(|f| f.name().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| {
                let names: Vec<&str> = Format::ALL.iter().map(|f| f.name()).collect();
                Error::Request(format!(
                    "--format {s}: not a format; they are {}",
                    names.join(", ")
                ))
            })
    }
}

/// The formats of `--format LIST` (comma-separated; `all` for every one), in
/// [`Format::ALL`]'s order, each once.
///
/// ```
/// use volver::compensation::{Format, parse_formats};
/// assert_eq!(parse_formats("linuxcnc, isg").unwrap(), vec![Format::Isg, Format::Linuxcnc]);
/// assert_eq!(parse_formats("all").unwrap().len(), 6);
/// assert!(parse_formats("fanuc").is_err());
/// ```
///
/// # Errors
/// A name that is not a format, or an empty list.
pub fn parse_formats(list: &str) -> Result<Vec<Format>> {
    if list.trim().eq_ignore_ascii_case("all") {
        return Ok(Format::ALL.to_vec());
    }
    let asked = list
        .split(',')
        .filter(|s| !s.trim().is_empty())
        .map(str::parse)
        .collect::<Result<Vec<Format>>>()?;
    if asked.is_empty() {
        return Err(Error::Request("--format: no format given".into()));
    }
    Ok(Format::ALL
        .into_iter()
        .filter(|f| asked.contains(f))
        .collect())
}

/// A format's files — (file name, text) each — or why the control cannot take its tables.
pub type Files = std::result::Result<Vec<(String, String)>, String>;

/// The files of the controller formats among `formats`: (file name, text) per file, from the
/// projections of `c` (leadscrew for LinuxCNC and `siemens-lec`, the joint projection for
/// `siemens-cec`), and for each format a control cannot take, its reason (a limit of the
/// control: too many points, a value at the reference point …) instead of files.
pub fn controller_files(
    c: &PerAxisComparison,
    machine: &Machine,
    formats: &[Format],
    siemens: &SiemensOptions,
) -> Vec<(Format, Files)> {
    formats
        .iter()
        .filter(|f| f.is_controller())
        .map(|&f| {
            let files = match f {
                Format::Linuxcnc => linuxcnc(&c.leadscrew.0, machine),
                Format::SiemensLec => siemens_pair(&c.leadscrew.0, machine, siemens, f),
                Format::SiemensCec => siemens_pair(&c.cross_axis.0, machine, siemens, f),
                _ => unreachable!("controller formats only"),
            };
            (f, files.map_err(|e| e.to_string()))
        })
        .collect()
}

/// LinuxCNC's files: one `compX.txt` per axis and `linuxcnc-ini.txt` with the INI lines and
/// the sign convention (the compensation files themselves take no comment).
fn linuxcnc(t: &PerAxisTables, machine: &Machine) -> Result<Vec<(String, String)>> {
    let files = linuxcnc_files(t, machine)?;
    let mut ini = String::from(
        "# volver: LinuxCNC per-joint compensation files (COMP_FILE_TYPE 1: trims ADDED to the\n\
         # joint's command, nominal forward reverse per line, mm or degrees). The files hold no\n\
         # comment: LinuxCNC's reader stops at the first line that is not three numbers.\n\
         # Add to the [JOINT_n] section of the joint that drives each axis:\n",
    );
    for f in &files {
        ini.push_str(&f.ini_lines());
    }
    let mut out: Vec<(String, String)> = files.into_iter().map(|f| (f.file_name, f.text)).collect();
    out.push(("linuxcnc-ini.txt".to_string(), ini));
    Ok(out)
}

/// The file of Siemens format `f` holding `part` (`AX_EEC`, `NC_CEC`): `siemens-lec-AX_EEC.INI` …
fn siemens_file(f: Format, part: &str) -> String {
    format!("{}-{part}.INI", f.name())
}

/// Siemens format `f`'s files of one projection: the LEC file, and the CEC file when the
/// projection has cross-axis tables or a table that depends on the direction.
fn siemens_pair(
    t: &PerAxisTables,
    machine: &Machine,
    opts: &SiemensOptions,
    f: Format,
) -> Result<Vec<(String, String)>> {
    let mut out = vec![(
        siemens_file(f, "AX_EEC"),
        siemens_lec_with(t, machine, opts)?,
    )];
    if t.tables
        .iter()
        .any(|x| !x.is_leadscrew() || x.is_directional())
    {
        out.push((
            siemens_file(f, "NC_CEC"),
            siemens_cec_with(t, machine, opts)?,
        ));
    }
    Ok(out)
}
