//! Point lists: programmed points to compensate, read as CSV through [`crate::csvio`], and the
//! text a controller gets for a command.

use crate::csvio::{self, Format, Header, Row};
use crate::error::{Error, Place, Result};
use crate::iso::Axis;
use crate::machine::{Commands, Machine};

/// The largest axis position read (mm or degrees): 1 km, beyond any machine's travel. Point
/// lists and G-code programs refuse larger values.
pub const MAX_AXIS_VALUE: f64 = 1e6;

/// One programmed point of a point list.
#[derive(Clone, Debug, PartialEq)]
pub struct ListedPoint {
    /// 1-based line in the file.
    pub line: usize,
    /// The `id` column, when there is one.
    pub id: Option<String>,
    /// The programmed command (internal units, chain order).
    pub commands: Commands,
}

/// Reads a point list: CSV with one column per machine axis, named by its letter (file units:
/// mm, degrees), and an optional `id` column. A header may carry its unit (`C [deg]`), which
/// must be the one volver reads ([`crate::csvio::check_unit`]). Any other column, a missing or
/// repeated axis, another unit, a value that is not a finite number or an empty list is refused
/// with the file, line and column.
///
/// ```
/// use volver_core::compensate::read_points;
/// use volver_core::machine::Machine;
/// let m = Machine::default_xcfz();
/// let pts = read_points("id,X,C,Z\np1,100,90,50\n\"p,2\",1,2,3\n", "pts.csv", &m).unwrap();
/// assert_eq!((pts[0].line, pts[1].id.as_deref()), (2, Some("p,2")));
/// assert!((pts[0].commands.0[1] - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
/// let err = read_points("X,C\n1,2\n", "pts.csv", &m).unwrap_err().to_string();
/// assert!(err.contains("pts.csv:1") && err.contains("'Z'"));
/// ```
pub fn read_points(text: &str, file: &str, machine: &Machine) -> Result<Vec<ListedPoint>> {
    let Some(mut table) = csvio::read(text, file, Format::default())? else {
        return Err(Error::input(
            Place::file(file),
            "empty file: expected a header with one column per axis (and an optional id)",
        ));
    };
    let columns = PointColumns::of(machine, table.header())?;
    let mut out = Vec::new();
    for row in table.rows() {
        out.push(columns.point(machine, &row?)?);
    }
    if out.is_empty() {
        return Err(Error::input(
            Place::file(file).at_line(table.header().line()),
            "a header but no points",
        ));
    }
    Ok(out)
}

/// The columns of a point list.
struct PointColumns {
    /// The axes' columns, in chain order.
    axes: Vec<usize>,
    id: Option<usize>,
}

impl PointColumns {
    /// The columns of `header`: the machine's axes and an optional `id`, nothing else.
    fn of(machine: &Machine, header: &Header) -> Result<PointColumns> {
        let is_axis = |n: &str| {
            let mut ch = n.chars();
            match (ch.next(), ch.next()) {
                (Some(l), None) => Axis::from_letter(l).is_some_and(|a| machine.axis(a).is_some()),
                _ => false,
            }
        };
        if let Some(n) = header.names().iter().find(|n| *n != "id" && !is_axis(n)) {
            return Err(Error::input(
                header.place(n),
                format!(
                    "unexpected column '{n}': expected the axes of {} and an optional id",
                    machine.chain()
                ),
            ));
        }
        Ok(PointColumns {
            id: header.find("id")?,
            axes: crate::measure::axis_columns(machine, header)?,
        })
    }

    /// The point of `row`: each axis a finite number of at most [`MAX_AXIS_VALUE`] in its
    /// file unit (not checked against the travel: a point list may reach beyond it).
    fn point(&self, machine: &Machine, row: &Row) -> Result<ListedPoint> {
        let mut commands = Commands::default();
        for (k, (a, &c)) in machine.axes().iter().zip(&self.axes).enumerate() {
            let text = row.text(c);
            let v = text
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite() && v.abs() <= MAX_AXIS_VALUE)
                .ok_or_else(|| {
                    row.error(
                        c,
                        format!(
                            "expected a finite number in {} of at most {MAX_AXIS_VALUE:e} in \
                             magnitude (beyond any machine's travel), found \"{text}\"",
                            a.file_unit(),
                        ),
                    )
                })?;
            commands.0[k] = a.from_file_units(v);
        }
        Ok(ListedPoint {
            line: row.line(),
            id: self.id.map(|c| row.text(c).to_string()),
            commands,
        })
    }
}

/// `commands` as a controller gets them: each axis in file units (mm, degrees) with `decimals`
/// decimals, and the commands those texts stand for (internal units), so that what is written
/// can be verified.
pub fn written(machine: &Machine, commands: &Commands, decimals: usize) -> (Vec<String>, Commands) {
    let mut out = *commands;
    let texts = machine
        .axes()
        .iter()
        .enumerate()
        .map(|(k, a)| {
            let t = format!("{:.decimals$}", a.to_file_units(commands.0[k]));
            // A formatted number always parses (NaN and infinities too).
            out.0[k] = a.from_file_units(t.parse().unwrap_or(f64::NAN));
            t
        })
        .collect();
    (texts, out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str) -> std::result::Result<Vec<ListedPoint>, String> {
        read_points(text, "p.csv", &Machine::default_xcfz()).map_err(|e| e.to_string())
    }

    #[test]
    fn quoted_cells_crlf_and_blank_lines_are_read() {
        let pts =
            read("\u{feff}\"id\",X,C [deg],Z\r\n\r\n\"a, b\",\"1.5\",90,0\r\n,,,\r\nc,0,0,0\r\n")
                .unwrap();
        assert_eq!(pts.len(), 2);
        assert_eq!((pts[0].line, pts[0].id.as_deref()), (3, Some("a, b")));
        assert_eq!(pts[0].commands.0[0], 1.5);
        assert_eq!((pts[1].line, pts[1].id.as_deref()), (5, Some("c")));
    }

    #[test]
    fn bad_lists_name_file_line_and_column() {
        let cases = [
            ("", "p.csv: empty file"),
            (
                "X,C,Z,Q\n1,2,3,4\n",
                "p.csv:1: field 'Q': unexpected column 'Q'",
            ),
            (
                "X,C,Z,X\n1,2,3,4\n",
                "p.csv:1: field 'X': column 'X' appears twice",
            ),
            (
                "X,C,Z [in]\n1,2,3\n",
                "p.csv:1: field 'Z [in]': unit 'in', expected mm",
            ),
            (
                "X,C,Z\n1,2\n",
                "p.csv:2: not valid CSV: 2 fields where the header has 3",
            ),
            (
                "X,C,Z\n1,2,x\n",
                "p.csv:2: field 'Z': expected a finite number in mm",
            ),
            (
                "X,C,Z\n1,2e6,3\n",
                "p.csv:2: field 'C': expected a finite number in deg",
            ),
            ("\nX,C,Z\n", "p.csv:2: a header but no points"),
        ];
        for (text, want) in cases {
            let e = read(text).unwrap_err();
            assert!(e.starts_with(want), "{text:?}: {e}");
        }
    }
}
