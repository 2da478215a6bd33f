//! LinuxCNC per-joint compensation files (`[JOINT_n] COMP_FILE`, `COMP_FILE_TYPE`).
//!
//! The rules, from LinuxCNC's repository (`github.com/LinuxCNC/linuxcnc`; see `vendor-notes.md`,
//! "Controller table formats", for the lines):
//! - `docs/src/config/ini-config.adoc` (`COMP_FILE`, `COMP_FILE_TYPE`): one line per point,
//!   `nominal forward reverse` separated by spaces, in machine units (the joint's: mm, or
//!   degrees for an angular joint), starting at the smallest nominal and ascending, at most 256
//!   triplets per joint; values between nominals are interpolated. `COMP_FILE_TYPE` 0 lists
//!   the actual positions, 1 the trims.
//! - `src/emc/motion/usrmotintf.cc`, `usrmotLoadComp`: reads the file line by line with
//!   `sscanf(buffer, "%lf %lf %lf", …)` and **stops at the first line that does not give three
//!   numbers** — a header or comment line silently leaves the joint without compensation, so
//!   these files have none. Type 0 is turned into trims `nominal − actual`; type 1 is taken as
//!   trims.
//! - `src/emc/ini/inijoint.cc`: `COMP_FILE_TYPE` defaults to 0 when absent.
//! - `src/emc/motion/command.c`, `EMCMOT_SET_JOINT_COMP`: more than 256 entries ("too many
//!   compensation entries") and a nominal not above the previous one ("compensation values
//!   must increase") are refused one by one.
//! - `src/emc/motion/control.c`, `compute_screw_comp` and `output_to_hal`: the trim of the
//!   commanded position, linearly interpolated (the first trim held below the table, the last
//!   held above it), forward while the commanded velocity is positive, reverse while it is
//!   negative, unchanged while it is zero, is **added to the commanded position** sent to the
//!   motor (`motor_pos_cmd = pos_cmd + backlash_filt + motor_offset`).
//!
//! So volver writes **type 1**: its corrections (what is added to the axis' command, see
//! [`super::per_axis`]) are LinuxCNC's trims as they are. Only leadscrew tables: LinuxCNC has
//! no cross-axis compensation, and a cross-axis table is refused (fit with
//! [`super::per_axis::Family::Leadscrew`]).
//!
//! ```
//! use volver_core::machine::Machine;
//! use volver_core::tables::linuxcnc::linuxcnc_files;
//! use volver_core::tables::per_axis::{AxisCorrection, Family, PerAxisTables};
//! use volver_core::iso::Axis;
//! let t = PerAxisTables {
//!     family: Family::Leadscrew,
//!     tools: vec![[0.0; 3]],
//!     tables: vec![AxisCorrection {
//!         input: Axis::X,
//!         output: Axis::X,
//!         positions: vec![0.0, 700.0, 1400.0],
//!         forward: vec![0.0, -0.004, -0.008],
//!         reverse: vec![0.0, -0.004, -0.008],
//!     }],
//! };
//! let files = linuxcnc_files(&t, &Machine::default_xcfz()).unwrap();
//! assert_eq!(files[0].comp_file_type, 1);
//! assert!(files[0].text.starts_with("0.000000000 0.000000000 0.000000000\n"));
//! ```

use super::controller::{check_table, label, machine_axis, refuse};
use super::per_axis::PerAxisTables;
use crate::error::{Result, number};
use crate::iso::Axis;
use crate::machine::Machine;

/// The most triplets LinuxCNC keeps per joint (`EMCMOT_COMP_SIZE` in
/// `src/emc/motion/motion.h`).
pub const MAX_LINES: usize = 256;

/// The longest line LinuxCNC's reader takes in one piece (`LINELEN` in `src/emc/linuxcnc.h`,
/// the buffer of `fgets`), characters including the line break.
pub const MAX_LINE_CHARS: usize = 255;

/// The name of the file format in messages.
const FORMAT: &str = "LinuxCNC compensation file";

/// One joint's compensation file.
#[derive(Clone, Debug, PartialEq)]
pub struct CompFile {
    /// The axis the file compensates (LinuxCNC's joint number is not known to volver: the
    /// joint that drives this axis).
    pub axis: Axis,
    /// A file name made of letters, digits and one dot (`compX.txt`), as
    /// `ini-config.adoc` asks of `COMP_FILE` names.
    pub file_name: String,
    /// The file's text: `nominal forward reverse` per line, nothing else.
    pub text: String,
    /// The `COMP_FILE_TYPE` the text is written for: always 1 (trims added to the command).
    pub comp_file_type: u8,
}

impl CompFile {
    /// The INI lines that make LinuxCNC read the file, to go in the `[JOINT_n]` section of the
    /// joint that drives [`CompFile::axis`] (`n` is the machine's: volver does not know it).
    /// Both lines are needed: without `COMP_FILE_TYPE` LinuxCNC reads type 0 and takes the
    /// trims for actual positions.
    pub fn ini_lines(&self) -> String {
        format!(
            "# [JOINT_n] of the joint that drives axis {}\nCOMP_FILE = {}\nCOMP_FILE_TYPE = {}\n",
            self.axis, self.file_name, self.comp_file_type
        )
    }
}

/// One LinuxCNC compensation file per leadscrew table of `t`, in `t`'s order: positions and
/// trims in the axis' file units (mm, degrees), nine decimals.
///
/// Refused, with the table named: a cross-axis table (LinuxCNC has none), two tables of one
/// axis, an axis the machine lacks, more than [`MAX_LINES`] points (the message gives the
/// step that fits), positions not strictly ascending, a value that is not finite.
pub fn linuxcnc_files(t: &PerAxisTables, machine: &Machine) -> Result<Vec<CompFile>> {
    let mut files: Vec<CompFile> = Vec::new();
    for table in &t.tables {
        if !table.is_leadscrew() {
            return Err(refuse(
                FORMAT,
                format!(
                    "table {} corrects axis {} as a function of axis {}: LinuxCNC compensates \
                     each joint by its own position only; fit leadscrew tables (Family::Leadscrew)",
                    label(table),
                    table.output,
                    table.input
                ),
            ));
        }
        if files.iter().any(|f| f.axis == table.input) {
            return Err(refuse(
                FORMAT,
                format!("two tables for axis {}: a joint has one file", table.input),
            ));
        }
        let a = machine_axis(machine, table.input, FORMAT, table)?;
        check_table(table, FORMAT)?;
        let n = table.positions.len();
        if n > MAX_LINES {
            let span = table.positions[n - 1] - table.positions[0];
            return Err(refuse(
                FORMAT,
                format!(
                    "table {} has {n} points; LinuxCNC keeps at most {MAX_LINES} per joint \
                     (the rest would be refused): a step of at least {} {} over its {} {} gives \
                     at most {MAX_LINES}",
                    label(table),
                    number((span / (MAX_LINES - 1) as f64 * 1e3).ceil() / 1e3),
                    a.file_unit(),
                    number(span),
                    a.file_unit()
                ),
            ));
        }
        let mut text = String::new();
        for ((p, f), r) in table
            .positions
            .iter()
            .zip(&table.forward)
            .zip(&table.reverse)
        {
            let line = format!("{p:.9} {f:.9} {r:.9}\n");
            if line.len() > MAX_LINE_CHARS {
                return Err(refuse(
                    FORMAT,
                    format!(
                        "table {}: the line for position {} would be {} characters; LinuxCNC \
                         reads at most {MAX_LINE_CHARS}",
                        label(table),
                        number(*p),
                        line.len()
                    ),
                ));
            }
            text.push_str(&line);
        }
        files.push(CompFile {
            axis: table.input,
            file_name: format!("comp{}.txt", table.input),
            text,
            comp_file_type: 1,
        });
    }
    Ok(files)
}
