//! Reading the tables back: ISG CSV and the Etalon style line by line (whitespace-separated,
//! `//` comments), the plain CSV through the CSV layer ([`crate::csvio`]).

use super::{AxisTable, ErrorTables};
use crate::csvio::{self, Format, Row};
use crate::error::{Error, Place, Result};
use crate::iso::{Axis, ErrorId};
use crate::units::{UM_PER_MM, URAD_PER_RAD};

/// The plain CSV's header; with a reversal, [`DIRECTION_COLUMNS`] follow.
const PLAIN_COLUMNS: [&str; 6] = [
    "error",
    "axis",
    "position",
    "position_unit",
    "value",
    "value_unit",
];

/// The plain CSV's columns of the values on forward and reverse approach.
const DIRECTION_COLUMNS: [&str; 2] = ["forward", "reverse"];

/// How far (µm or µrad) a plain CSV's value may be from the mean of its forward and reverse
/// values: the rounding of their decimals, far below any error.
const MEAN_TOLERANCE: f64 = 1e-6;

impl ErrorTables {
    /// Reads [`ErrorTables::to_isg_csv`]'s format back; `file` names it in messages.
    pub fn from_isg_csv(text: &str, file: &str) -> Result<ErrorTables> {
        let mut reader = IsgReader::default();
        each_line(text, file, |line, place| reader.line(line, place))?;
        reader.end_block();
        Ok(reader.out)
    }

    /// Reads [`ErrorTables::to_etalon`]'s format back; `file` names it in messages.
    pub fn from_etalon(text: &str, file: &str) -> Result<ErrorTables> {
        let mut reader = EtalonReader::default();
        each_line(text, file, |line, place| reader.line(line, place))?;
        if reader.grid.is_some() {
            return Err(Error::input(
                Place::file(file),
                "the file ends inside a Gridpoints block (no closing '}')",
            ));
        }
        Ok(reader.out)
    }

    /// Reads [`ErrorTables::to_plain_csv`]'s format back, with or without its `forward` and
    /// `reverse` columns; `file` names it in messages.
    pub fn from_plain_csv(text: &str, file: &str) -> Result<ErrorTables> {
        let format = Format {
            units_in_header: false,
            ..Format::default()
        };
        let table = csvio::read(text, file, format)?;
        let directed = |names: &[String]| {
            names.len() == 8 && names[..6] == PLAIN_COLUMNS && names[6..] == DIRECTION_COLUMNS
        };
        let (mut table, directed) = match table {
            Some(t) if t.header().names() == PLAIN_COLUMNS => (t, false),
            Some(t) if directed(t.header().names()) => (t, true),
            other => {
                let line = other.map_or(1, |t| t.header().line());
                return Err(Error::input(
                    Place::file(file).at_line(line),
                    "expected the header error,axis,position,position_unit,value,value_unit \
                     (and forward,reverse with a reversal)",
                ));
            }
        };
        let mut out = ErrorTables {
            constants: Vec::new(),
            axes: Vec::new(),
        };
        for row in table.rows() {
            let row = row?;
            plain_row(&mut out, &row)?;
            if directed {
                direction_cells(&mut out, &row)?;
            }
        }
        Ok(out)
    }
}

/// Calls `read` with each line of `text` that is not empty once its `//` comment is removed,
/// trimmed, at its place in `file`.
fn each_line(
    text: &str,
    file: &str,
    mut read: impl FnMut(&str, Place) -> Result<()>,
) -> Result<()> {
    for (i, raw) in text.lines().enumerate() {
        let line = raw.split("//").next().unwrap_or("").trim();
        if !line.is_empty() {
            read(line, Place::file(file).at_line(i + 1))?;
        }
    }
    Ok(())
}

/// An ISG CSV block being read: its header's names and, for an axis' block, its table.
struct Block {
    names: Vec<String>,
    table: Option<AxisTable>,
}

/// The state of an ISG CSV reader: the tables read and the block open.
#[derive(Default)]
struct IsgReader {
    out: ErrorTables,
    block: Option<Block>,
}

impl IsgReader {
    /// Reads one line (comment removed, not empty) at `place`: a block's end (`#`), its header
    /// or a row of values.
    fn line(&mut self, line: &str, place: Place) -> Result<()> {
        if line == "#" {
            self.end_block();
            return Ok(());
        }
        let cells: Vec<&str> = line.split_whitespace().collect();
        let Some(block) = &mut self.block else {
            self.block = Some(isg_header(&cells, &place)?);
            return Ok(());
        };
        if cells.len() != block.names.len() {
            return Err(Error::input(
                place,
                format!(
                    "{} values for the header's {} names",
                    cells.len(),
                    block.names.len()
                ),
            ));
        }
        let vals = cells
            .iter()
            .zip(&block.names)
            .map(|(c, n)| parse_number(c, &place, n))
            .collect::<Result<Vec<f64>>>()?;
        match &mut block.table {
            Some(t) => {
                t.positions.push(vals[0]);
                for (e, v) in t.errors.iter_mut().zip(&vals[1..]) {
                    e.1.push(*v);
                }
            }
            None => (self.out.constants).extend(block.names.iter().cloned().zip(vals)),
        }
        Ok(())
    }

    /// Closes the open block: an axis' table joins the tables.
    fn end_block(&mut self) {
        if let Some(Block {
            table: Some(t),
            names: _,
        }) = self.block.take()
        {
            self.out.axes.push(t);
        }
    }
}

/// The block an ISG CSV header opens: an axis letter and its error names (a table over the
/// axis), or the constants' names.
fn isg_header(cells: &[&str], place: &Place) -> Result<Block> {
    let names: Vec<String> = cells.iter().map(|c| c.to_string()).collect();
    for n in &names[1.min(names.len())..] {
        n.parse::<ErrorId>().map_err(|e| {
            Error::input(
                place.clone().at_field(n.clone()),
                format!("not an ISO 230-1 error name: {e}"),
            )
        })?;
    }
    let first = names.first().map_or("", String::as_str);
    let table = match single_axis(first) {
        Some(axis) => Some(AxisTable {
            axis,
            positions: Vec::new(),
            errors: names[1..].iter().map(|n| (n.clone(), Vec::new())).collect(),
            reversal: None,
        }),
        None => {
            first.parse::<ErrorId>().map_err(|e| {
                Error::input(
                    place.clone().at_field(first),
                    format!("expected an axis letter or an ISO 230-1 error name: {e}"),
                )
            })?;
            None
        }
    };
    Ok(Block { names, table })
}

/// The state of an Etalon-style reader: the tables read, the section (`[EXX]`) and the
/// `Gridpoints` block open (its error, positions and values).
#[derive(Default)]
struct EtalonReader {
    out: ErrorTables,
    section: Option<ErrorId>,
    grid: Option<(ErrorId, Vec<f64>, Vec<f64>)>,
}

impl EtalonReader {
    /// Reads one line (comment removed, not empty) at `place`: a grid's row or end, a section
    /// or a `KEY = value`.
    fn line(&mut self, line: &str, place: Place) -> Result<()> {
        if let Some((_, pos, vals)) = &mut self.grid {
            if line.starts_with('}') {
                return self.close_grid(place);
            }
            let cells: Vec<&str> = line.split_whitespace().collect();
            if cells.len() != 2 {
                return Err(Error::input(
                    place,
                    "expected 'position value' in Gridpoints",
                ));
            }
            pos.push(parse_number(cells[0], &place, "position")?);
            vals.push(parse_number(cells[1], &place, "value")?);
            return Ok(());
        }
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            self.section = Some(name.parse::<ErrorId>().map_err(|e| {
                Error::input(
                    place.clone().at_field(name),
                    format!("not an ISO 230-1 error name: {e}"),
                )
            })?);
            return Ok(());
        }
        self.key_value(line, place)
    }

    /// A section's `VALUE = …` (a constant) or `Gridpoints = {` (a grid opens).
    fn key_value(&mut self, line: &str, place: Place) -> Result<()> {
        let Some(id) = self.section else {
            return Err(Error::input(place, "a value before any [NAME] section"));
        };
        let expected = "expected 'VALUE = …' or 'Gridpoints = {'";
        let Some((key, value)) = line.split_once('=').map(|(k, v)| (k.trim(), v.trim())) else {
            return Err(Error::input(place, expected));
        };
        match key {
            "VALUE" => {
                let v = parse_number(value, &place, "VALUE")?;
                self.out.constants.push((id.to_string(), v));
            }
            "Gridpoints" if value == "{" => self.grid = Some((id, Vec::new(), Vec::new())),
            _ => return Err(Error::input(place.at_field(key), expected)),
        }
        Ok(())
    }

    /// Closes the open grid: its error joins its axis' table (the last one, when it is of the
    /// same axis: its positions must be the grid's), or opens the axis' table.
    fn close_grid(&mut self, place: Place) -> Result<()> {
        let Some((id, pos, vals)) = self.grid.take() else {
            return Ok(());
        };
        let axis = id.axis();
        match self.out.axes.last_mut() {
            Some(t) if t.axis == axis => {
                if t.positions.len() != pos.len()
                    || t.positions
                        .iter()
                        .zip(&pos)
                        .any(|(a, b)| (a - b).abs() > 1e-9)
                {
                    return Err(Error::input(
                        place,
                        format!("{id}'s positions differ from the other errors of axis {axis}"),
                    ));
                }
                t.errors.push((id.to_string(), vals));
            }
            _ => self.out.axes.push(AxisTable {
                axis,
                positions: pos,
                errors: vec![(id.to_string(), vals)],
                reversal: None,
            }),
        }
        Ok(())
    }
}

/// Adds a plain CSV row to `out`: a constant (no position) or one position's value of an
/// error, in mm or rad (the row's µm or µrad converted).
fn plain_row(out: &mut ErrorTables, row: &Row) -> Result<()> {
    let name = row.text(0);
    let id: ErrorId = name
        .parse()
        .map_err(|e| row.error(0, format!("not an ISO 230-1 error name: {e}")))?;
    let scale = plain_scale(row, id)?;
    let v = row.number(4, "")? * scale;
    if !row.filled(2) {
        out.constants.push((id.to_string(), v));
        return Ok(());
    }
    let p = row.number(2, "")?;
    let axis = id.axis();
    if out.axes.last().is_none_or(|t| t.axis != axis) {
        out.axes.push(AxisTable {
            axis,
            positions: Vec::new(),
            errors: Vec::new(),
            reversal: None,
        });
    }
    let Some(t) = out.axes.last_mut() else {
        return Ok(()); // pushed above
    };
    if t.errors.last().is_none_or(|e| e.0 != name) {
        t.errors.push((id.to_string(), Vec::new()));
    }
    let n = t.errors.len();
    if n == 1 {
        t.positions.push(p);
    } else if t
        .positions
        .get(t.errors[n - 1].1.len())
        .is_none_or(|q| (q - p).abs() > 1e-9)
    {
        return Err(row.error(
            2,
            format!("{id}'s positions differ from the other errors of axis {axis}"),
        ));
    }
    t.errors[n - 1].1.push(v);
    Ok(())
}

/// A plain CSV row's `forward` and `reverse` cells (after [`plain_row`] read it into `out`):
/// empty on an error that does not depend on the direction, filled — on every row of it, with
/// `value` their mean — on the positioning error (EXX for X, ECC for C) of an axis with a
/// reversal, whose B (`forward − reverse`) joins the axis' table.
fn direction_cells(out: &mut ErrorTables, row: &Row) -> Result<()> {
    let id: ErrorId = row.text(0).parse().map_err(|e| row.error(0, e))?;
    let filled = (row.filled(6), row.filled(7));
    let constant = !row.filled(2);
    let positioning = matches!(id, ErrorId::Component { component, axis } if component == axis);
    match filled {
        (false, false) => {
            let open = out.axes.last().is_some_and(|t| t.reversal.is_some());
            if positioning && !constant && open {
                return Err(row.error(
                    6,
                    format!("{id}: forward and reverse are given on its other rows: give them on every row"),
                ));
            }
            return Ok(());
        }
        (true, true) => {}
        (f, _) => {
            return Err(row.error(
                if f { 7 } else { 6 },
                "forward and reverse go together: give both or neither",
            ));
        }
    }
    if constant || !positioning {
        return Err(row.error(
            6,
            format!(
                "{id} does not depend on the direction of approach: only an axis' positioning \
                 error (EXX for X, ECC for C) has forward and reverse values; leave them empty"
            ),
        ));
    }
    let scale = plain_scale(row, id)?;
    let (fw, rv, v) = (row.number(6, "")?, row.number(7, "")?, row.number(4, "")?);
    if (v - 0.5 * (fw + rv)).abs() > MEAN_TOLERANCE {
        return Err(row.error(
            4,
            format!(
                "the value {v} is not the mean of forward {fw} and reverse {rv} ({})",
                0.5 * (fw + rv)
            ),
        ));
    }
    let Some(t) = out.axes.last_mut() else {
        return Ok(()); // plain_row opened the axis' table
    };
    let first = t.errors.last().is_some_and(|e| e.1.len() == 1);
    match (&mut t.reversal, first) {
        (None, true) => t.reversal = Some(vec![(fw - rv) * scale]),
        (Some(b), false) => b.push((fw - rv) * scale),
        _ => {
            return Err(row.error(
                6,
                format!("{id}: forward and reverse are missing on its other rows: give them on every row"),
            ));
        }
    }
    Ok(())
}

/// The factor from a plain CSV row's `value_unit` to volver's units: µm to mm, µrad to rad; the
/// unit must be the error's kind (a length or an angle).
fn plain_scale(row: &Row, id: ErrorId) -> Result<f64> {
    let unit = row.text(5);
    let scale = match unit {
        "um" => 1.0 / UM_PER_MM,
        "urad" => 1.0 / URAD_PER_RAD,
        other => {
            return Err(row.error(5, format!("expected um or urad, found \"{other}\"")));
        }
    };
    let rotary = id.component().is_rotary();
    if (unit == "urad") != rotary {
        let kind = if rotary {
            "an angle (urad)"
        } else {
            "a length (um)"
        };
        return Err(row.error(5, format!("{id} is {kind}")));
    }
    Ok(scale)
}

/// The axis a one-letter name is, if it is one.
fn single_axis(s: &str) -> Option<Axis> {
    let mut it = s.chars();
    match (it.next(), it.next()) {
        (Some(c), None) => Axis::from_letter(c),
        _ => None,
    }
}

/// Cell `s` at `place` in `field` as a finite number.
fn parse_number(s: &str, place: &Place, field: &str) -> Result<f64> {
    csvio::finite_number(s, place.clone().at_field(field), "")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_csv_reads_quoted_cells_crlf_and_blank_lines_in_mm_and_rad() {
        let text = "\u{feff}error,axis,position,position_unit,value,value_unit\r\n\
                    \"B0Z\",Z,,,\"2.5\",urad\r\n\r\n\
                    EXX,X,0,mm,100,um\r\n,,,,,\r\nEXX,X,700,mm,-4,um\r\n\
                    EYX,X,0,mm,1,um\r\nEYX,X,700,mm,2,um\r\n";
        let t = ErrorTables::from_plain_csv(text, "p.csv").unwrap();
        assert_eq!(t.constants, vec![("B0Z".to_string(), 2.5 * 1e-6)]);
        assert_eq!(t.axes.len(), 1);
        assert_eq!(t.axes[0].positions, [0.0, 700.0]);
        assert_eq!(t.axes[0].errors[0], ("EXX".to_string(), vec![0.1, -0.004]));
        assert_eq!(t.axes[0].errors[1], ("EYX".to_string(), vec![0.001, 0.002]));
    }

    #[test]
    fn plain_csv_errors_name_line_and_column() {
        let h = "error,axis,position,position_unit,value,value_unit\n";
        let e = |body: &str| {
            ErrorTables::from_plain_csv(&format!("{h}{body}"), "p.csv")
                .unwrap_err()
                .to_string()
        };
        assert_eq!(
            e("EXX,X,0,mm,1,mm\n"),
            "p.csv:2: field 'value_unit': expected um or urad, found \"mm\""
        );
        assert_eq!(
            e("EXX,X,0,mm,1,urad\n"),
            "p.csv:2: field 'value_unit': EXX is a length (um)"
        );
        assert_eq!(
            e("\nEXX,X,0,mm,abc,um\n"),
            "p.csv:3: field 'value': expected a number, found \"abc\""
        );
        assert_eq!(
            e("EXX,X,0,mm,1,um\nEYX,X,0,mm,1,um\nEYX,X,5,mm,1,um\n"),
            "p.csv:4: field 'position': EYX's positions differ from the other errors of axis X"
        );
        assert!(e("EXX,X,0,mm,1\n").starts_with("p.csv:2: not valid CSV: 5 fields"));
        assert!(e("QXX,X,0,mm,1,um\n").starts_with("p.csv:2: field 'error': not an ISO"));
        let wrong = ErrorTables::from_plain_csv("error,axis\n", "p.csv").unwrap_err();
        assert!(
            wrong
                .to_string()
                .starts_with("p.csv:1: expected the header error,axis,")
        );
    }

    #[test]
    fn plain_csv_forward_and_reverse_columns() {
        let h = "error,axis,position,position_unit,value,value_unit,forward,reverse\n";
        let ok = format!(
            "{h}B0Z,Z,,,2.5,urad,,\nEXX,X,0,mm,1,um,8.5,-6.5\nEXX,X,700,mm,2,um,9,-5\n\
             EYX,X,0,mm,1,um,,\nEYX,X,700,mm,2,um,,\n"
        );
        let t = ErrorTables::from_plain_csv(&ok, "p.csv").unwrap();
        let b = t.axes[0].reversal.as_ref().unwrap();
        assert!((b[0] - 0.015).abs() < 1e-15 && (b[1] - 0.014).abs() < 1e-15);
        assert!((t.directional(Axis::X, 350.0).unwrap().forward - 0.00875).abs() < 1e-15);
        let e = |body: &str| {
            ErrorTables::from_plain_csv(&format!("{h}{body}"), "p.csv")
                .unwrap_err()
                .to_string()
        };
        assert_eq!(
            e("EXX,X,0,mm,1,um,8.5,\n"),
            "p.csv:2: field 'reverse': forward and reverse go together: give both or neither"
        );
        assert!(
            e("EYX,X,0,mm,1,um,2,0\n")
                .starts_with("p.csv:2: field 'forward': EYX does not depend on the direction")
        );
        assert!(
            e("EXX,X,0,mm,1,um,3,0\n")
                .starts_with("p.csv:2: field 'value': the value 1 is not the mean of forward 3")
        );
        assert!(e("EXX,X,0,mm,1,um,2,0\nEXX,X,5,mm,1,um,,\n").starts_with(
            "p.csv:3: field 'forward': EXX: forward and reverse are given on its other rows"
        ));
        assert!(e("EXX,X,0,mm,1,um,,\nEXX,X,5,mm,1,um,2,0\n").starts_with(
            "p.csv:3: field 'forward': EXX: forward and reverse are missing on its other rows"
        ));
        assert!(e("B0Z,Z,,,1,urad,1,1\n").contains("B0Z does not depend on the direction"));
    }

    #[test]
    fn isg_and_etalon_errors_name_the_line() {
        let e = ErrorTables::from_isg_csv("X EXX\n0 1\n10 x\n", "i.csv").unwrap_err();
        assert_eq!(
            e.to_string(),
            "i.csv:3: field 'EXX': expected a number, found \"x\""
        );
        let e = ErrorTables::from_isg_csv("X EXX\n0 1 2\n", "i.csv").unwrap_err();
        assert_eq!(e.to_string(), "i.csv:2: 3 values for the header's 2 names");
        let t = ErrorTables::from_isg_csv("X0C\n1e-6\n#\nX EXX // c\n0 1\n5 2\n", "i.csv").unwrap();
        assert_eq!(t.constants, vec![("X0C".to_string(), 1e-6)]);
        assert_eq!(t.axes[0].positions, [0.0, 5.0]);
        let grid = "[EXX]\nGridpoints = {\n0 1\n5 2\n}\n[EYX]\nGridpoints = {\n0 1\n6 2\n}\n";
        let e = ErrorTables::from_etalon(grid, "e.txt").unwrap_err();
        assert_eq!(
            e.to_string(),
            "e.txt:10: EYX's positions differ from the other errors of axis X"
        );
        let e = ErrorTables::from_etalon("[EXX]\nGridpoints = {\n0 1\n", "e.txt").unwrap_err();
        assert!(e.to_string().contains("ends inside a Gridpoints block"));
        let e = ErrorTables::from_etalon("VALUE = 1\n", "e.txt").unwrap_err();
        assert_eq!(e.to_string(), "e.txt:1: a value before any [NAME] section");
    }
}
