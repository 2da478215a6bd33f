//! One CSV layer for every file volver reads as CSV: measurement files, import profiles'
//! exports, plan files, point lists and plain error tables.
//!
//! A file is read in three steps: [`read`] prepares the text (a byte-order mark dropped, CR LF
//! and CR-only line ends read as LF, `#` comment lines blanked when the [`Format`] has them) and
//! takes its first non-blank line as the [`Header`]; the header maps names to columns
//! ([`Header::find`], [`Header::require`]), with the unit a name may carry (`C [deg]`,
//! [`split_unit`]) checked against the one volver reads ([`Header::check_unit`]); then
//! [`Table::rows`] hands out each non-blank [`Row`] with its line, whose cells are read as text
//! or as finite numbers ([`Row::number`]). Quoted cells are read as the `csv` crate reads them
//! (`"R1"` is `R1`, `"a,b"` one cell), cells are trimmed, and every error names the file, the
//! 1-based line and the column ([`Place`]).
//!
//! ```
//! use volver_core::csvio::{self, Format};
//! let text = "\u{feff}id,X [mm]\r\n\"p,1\",12.5\r\n\r\np2,abc\r\n";
//! let mut table = csvio::read(text, "pts.csv", Format::default()).unwrap().unwrap();
//! let x = table.header().require("X", || "missing column 'X'".into()).unwrap();
//! table.header().check_unit(x, "mm").unwrap();
//! let mut rows = table.rows();
//! let first = rows.next().unwrap().unwrap();
//! assert_eq!((first.line(), first.text(0), first.number(x, "mm").unwrap()), (2, "p,1", 12.5));
//! let e = rows.next().unwrap().unwrap().number(x, "mm").unwrap_err().to_string();
//! assert_eq!(e, "pts.csv:4: field 'X': expected a number (mm), found \"abc\"");
//! ```

use crate::error::{Error, Place, Result};

/// How a file's CSV is written: what [`read`] accepts besides plain comma-separated cells.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Format {
    /// The byte between cells (`b','` by default).
    pub delimiter: u8,
    /// Whether a line whose first non-blank character is `#` is a comment (blanked, so that
    /// line numbers stay the file's).
    pub comments: bool,
    /// Whether a header name may carry its unit in brackets or parentheses (`C [deg]`): the
    /// column's name is then the name without it ([`split_unit`]).
    pub units_in_header: bool,
    /// Whether a row may have fewer or more cells than the header (a missing cell reads as
    /// empty); otherwise such a row is refused.
    pub ragged: bool,
    /// The file's line number of the text's first line (1, or more when the caller cut lines
    /// off the top of the file).
    pub first_line: usize,
}

impl Default for Format {
    /// Comma-separated, no comments, units in the header, every row as wide as the header.
    fn default() -> Self {
        Format {
            delimiter: b',',
            comments: false,
            units_in_header: true,
            ragged: false,
            first_line: 1,
        }
    }
}

/// Splits a column header into its name and an optional unit annotation in brackets or
/// parentheses: `C [deg]` and `C(deg)` are column `C` in `deg`.
///
/// ```
/// use volver_core::csvio::split_unit;
/// assert_eq!(split_unit("meas_x [mm]"), ("meas_x", Some("mm")));
/// assert_eq!(split_unit("C(deg)"), ("C", Some("deg")));
/// assert_eq!(split_unit("X"), ("X", None));
/// ```
pub fn split_unit(header: &str) -> (&str, Option<&str>) {
    let h = header.trim();
    for (open, close) in [('[', ']'), ('(', ')')] {
        if let Some(body) = h.strip_suffix(close)
            && let Some(i) = body.rfind(open)
        {
            return (body[..i].trim_end(), Some(body[i + 1..].trim()));
        }
    }
    (h, None)
}

/// Checks a column's unit annotation `found` against the unit volver reads that column in
/// (`mm`, `deg` or `s`); the error, at `place`, says what was found and expected. volver
/// converts nothing: a column in other units must be converted before it is read, so that a file
/// in metres or radians is never taken for one in mm or degrees.
///
/// ```
/// use volver_core::csvio::check_unit;
/// use volver_core::error::Place;
/// assert!(check_unit("°", "deg", Place::file("f")).is_ok());
/// assert!(check_unit("MM", "mm", Place::file("f")).is_ok());
/// let e = check_unit("rad", "deg", Place::file("f").at_line(1)).unwrap_err().to_string();
/// assert!(e.starts_with("f:1: unit 'rad', expected deg"), "{e}");
/// ```
pub fn check_unit(found: &str, expected: &str, place: Place) -> Result<()> {
    let f = found.to_ascii_lowercase();
    let same = match expected {
        "deg" => matches!(f.as_str(), "deg" | "°" | "degree" | "degrees"),
        "s" => matches!(f.as_str(), "s" | "sec" | "seconds"),
        _ => f == expected,
    };
    if same {
        return Ok(());
    }
    Err(Error::input(
        place,
        format!(
            "unit '{found}', expected {expected}: volver reads linear positions and coordinates \
             in mm, rotary positions in degrees and times in seconds, and converts nothing"
        ),
    ))
}

/// `text` read as a finite number; the error, at `place`, names `what` the number is (a unit,
/// "seconds"; nothing when empty) and tells a cell that is not a number from one that is not
/// finite (`NaN`, `inf`, `1e999`).
///
/// ```
/// use volver_core::csvio::finite_number;
/// use volver_core::error::Place;
/// assert_eq!(finite_number(" -2.5e3", Place::file("f"), "mm").unwrap(), -2500.0);
/// let e = finite_number("inf", Place::file("f"), "").unwrap_err().to_string();
/// assert_eq!(e, "f: expected a finite number, found \"inf\"");
/// ```
pub fn finite_number(text: &str, place: Place, what: &str) -> Result<f64> {
    let what = if what.is_empty() {
        String::new()
    } else {
        format!(" ({what})")
    };
    match text.trim().parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(Error::input(
            place,
            format!("expected a finite number{what}, found \"{text}\""),
        )),
        Err(_) => Err(Error::input(
            place,
            format!("expected a number{what}, found \"{text}\""),
        )),
    }
}

/// `text` as one CSV cell for a writer: as it is, or in double quotes (its quotes doubled) when
/// it holds a delimiter `,` or `;`, a quote, a line end or a leading `#`, so that [`read`] gives
/// it back (cells are read trimmed: blanks at either end are not kept).
///
/// ```
/// use volver_core::csvio::cell;
/// assert_eq!(cell("R1"), "R1");
/// assert_eq!(cell("a,b"), "\"a,b\"");
/// assert_eq!(cell("say \"hi\""), "\"say \"\"hi\"\"\"");
/// ```
pub fn cell(text: &str) -> std::borrow::Cow<'_, str> {
    let needs = text.starts_with('#') || text.contains([',', ';', '"', '\n', '\r']);
    if needs {
        std::borrow::Cow::Owned(format!("\"{}\"", text.replace('"', "\"\"")))
    } else {
        std::borrow::Cow::Borrowed(text)
    }
}

/// A file's header: the column names in file order, each with the unit it carries.
#[derive(Clone, Debug, PartialEq)]
pub struct Header {
    file: String,
    line: usize,
    written: Vec<String>,
    names: Vec<String>,
    units: Vec<Option<String>>,
}

impl Header {
    /// The header of `file` at `line` from its cells as written; units split off when the
    /// format has them.
    fn new(file: &str, line: usize, cells: &csv::StringRecord, units_in_header: bool) -> Header {
        let written: Vec<String> = cells.iter().map(str::to_string).collect();
        let (names, units) = written
            .iter()
            .map(|h| match split_unit(h) {
                (name, unit) if units_in_header => (name.to_string(), unit.map(str::to_string)),
                _ => (h.clone(), None),
            })
            .unzip();
        Header {
            file: file.to_string(),
            line,
            written,
            names,
            units,
        }
    }

    /// The file's name (or label) for messages.
    pub fn file(&self) -> &str {
        &self.file
    }

    /// The header's 1-based line in the file.
    pub fn line(&self) -> usize {
        self.line
    }

    /// The number of columns.
    pub fn len(&self) -> usize {
        self.names.len()
    }

    /// Whether the header has no columns (never, for a header [`read`] found).
    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }

    /// The columns' names (without their units), in file order.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Column `col`'s name as written, its unit included (`C [deg]`).
    pub fn written(&self, col: usize) -> &str {
        self.written.get(col).map_or("", String::as_str)
    }

    /// Column `col`'s unit annotation, when it has one.
    pub fn unit(&self, col: usize) -> Option<&str> {
        self.units.get(col).and_then(|u| u.as_deref())
    }

    /// The header's place at `field` (a column name, present or missing).
    pub fn place(&self, field: &str) -> Place {
        Place::file(&self.file).at_line(self.line).at_field(field)
    }

    /// Every column named `name`, in file order.
    pub fn columns_named(&self, name: &str) -> Vec<usize> {
        (0..self.names.len())
            .filter(|&i| self.names[i] == name)
            .collect()
    }

    /// The column named `name`, `None` when there is none; a name that appears twice is refused
    /// (which one to read cannot be told).
    pub fn find(&self, name: &str) -> Result<Option<usize>> {
        match self.columns_named(name)[..] {
            [] => Ok(None),
            [i] => Ok(Some(i)),
            _ => Err(Error::input(
                self.place(name),
                format!("column '{name}' appears twice in the header"),
            )),
        }
    }

    /// The column named `name`; when there is none, the error at the header says `missing`.
    pub fn require(&self, name: &str, missing: impl FnOnce() -> String) -> Result<usize> {
        self.find(name)?
            .ok_or_else(|| Error::input(self.place(name), missing()))
    }

    /// Checks column `col`'s unit, when it carries one, against `expected` ([`check_unit`]); the
    /// error names the column as written.
    pub fn check_unit(&self, col: usize, expected: &str) -> Result<()> {
        match self.unit(col) {
            Some(u) => check_unit(u, expected, self.place(self.written(col))),
            None => Ok(()),
        }
    }
}

/// A file read as CSV: its header and, through [`Table::rows`], its rows.
pub struct Table {
    header: Header,
    reader: csv::Reader<std::io::Cursor<Vec<u8>>>,
    format: Format,
}

/// Reads `text` (the file `file`, for messages) as CSV in `format`: `None` when it has no
/// header (no line with a non-empty cell), else its [`Table`].
pub fn read(text: &str, file: &str, format: Format) -> Result<Option<Table>> {
    let text = crate::error::lf_lines(crate::error::without_bom(text));
    let body = if format.comments {
        without_comments(&text)
    } else {
        text.into_owned()
    };
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .delimiter(format.delimiter)
        .trim(csv::Trim::All)
        .flexible(true)
        .from_reader(std::io::Cursor::new(body.into_bytes()));
    let mut cells = csv::StringRecord::new();
    loop {
        let more = reader
            .read_record(&mut cells)
            .map_err(|e| not_csv(file, format, &e))?;
        if !more {
            return Ok(None);
        }
        if !is_blank(&cells) {
            break;
        }
    }
    let line = line_of(&cells, reader.get_ref().get_ref(), format);
    Ok(Some(Table {
        header: Header::new(file, line, &cells, format.units_in_header),
        reader,
        format,
    }))
}

/// `text` with its comment lines (first non-blank character `#`) blanked, not removed, so that
/// the lines keep their numbers.
fn without_comments(text: &str) -> String {
    let kept: Vec<&str> = text
        .split('\n')
        .map(|l| {
            if l.trim_start().starts_with('#') {
                ""
            } else {
                l
            }
        })
        .collect();
    kept.join("\n")
}

/// Whether a record has no non-empty cell (an empty line, a line of blanks or of delimiters).
fn is_blank(cells: &csv::StringRecord) -> bool {
    cells.iter().all(str::is_empty)
}

/// The file's 1-based line of a record read from `body`. The `csv` crate places a record where
/// the previous one ended, before the empty lines it skips: they are counted here.
fn line_of(cells: &csv::StringRecord, body: &[u8], format: Format) -> usize {
    let Some(p) = cells.position() else {
        return format.first_line;
    };
    let start = usize::try_from(p.byte()).map_or(body.len(), |b| b.min(body.len()));
    let empty = body[start..].iter().take_while(|&&b| b == b'\n').count();
    p.line() as usize + empty + format.first_line - 1
}

/// A `csv` crate error as an input error at its line.
fn not_csv(file: &str, format: Format, e: &csv::Error) -> Error {
    let mut place = Place::file(file);
    if let Some(p) = e.position() {
        place = place.at_line(p.line() as usize + format.first_line - 1);
    }
    Error::input(place, format!("not valid CSV: {e}"))
}

impl Table {
    /// The file's header.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The rows after the header, blank ones skipped, in file order. A row with another number
    /// of cells than the header is an error unless the format is [`Format::ragged`].
    pub fn rows(&mut self) -> Rows<'_> {
        Rows {
            header: &self.header,
            records: self.reader.records(),
            format: self.format,
        }
    }
}

/// The rows of a [`Table`] (see [`Table::rows`]).
pub struct Rows<'t> {
    header: &'t Header,
    records: csv::StringRecordsIter<'t, std::io::Cursor<Vec<u8>>>,
    format: Format,
}

impl<'t> Iterator for Rows<'t> {
    type Item = Result<Row<'t>>;

    fn next(&mut self) -> Option<Self::Item> {
        let header = self.header;
        for record in self.records.by_ref() {
            let cells = match record {
                Ok(cells) => cells,
                Err(e) => return Some(Err(not_csv(&header.file, self.format, &e))),
            };
            if is_blank(&cells) {
                continue;
            }
            let body = self.records.reader().get_ref().get_ref();
            let line = line_of(&cells, body, self.format);
            if !self.format.ragged && cells.len() != header.len() {
                return Some(Err(Error::input(
                    Place::file(&header.file).at_line(line),
                    format!(
                        "not valid CSV: {} fields where the header has {}",
                        cells.len(),
                        header.len()
                    ),
                )));
            }
            return Some(Ok(Row {
                header,
                cells,
                line,
            }));
        }
        None
    }
}

/// One non-blank row of a [`Table`]: its cells and its line.
#[derive(Clone, Debug)]
pub struct Row<'t> {
    header: &'t Header,
    cells: csv::StringRecord,
    line: usize,
}

impl Row<'_> {
    /// The row's 1-based line in the file (where it starts, for a quoted cell over lines).
    pub fn line(&self) -> usize {
        self.line
    }

    /// Cell `col`, trimmed: empty when the row has no such cell (a ragged row).
    pub fn text(&self, col: usize) -> &str {
        self.cells.get(col).unwrap_or("")
    }

    /// Whether cell `col` holds anything.
    pub fn filled(&self, col: usize) -> bool {
        !self.text(col).is_empty()
    }

    /// The place of cell `col`: the file, the row's line and the column's name.
    pub fn place(&self, col: usize) -> Place {
        let name = self.header.names.get(col).map_or("", String::as_str);
        self.place_at(name)
    }

    /// The row's place at `field` (a column the file may lack, such as an optional one).
    pub fn place_at(&self, field: &str) -> Place {
        Place::file(&self.header.file)
            .at_line(self.line)
            .at_field(field)
    }

    /// The row's place without a column.
    pub fn place_of_row(&self) -> Place {
        Place::file(&self.header.file).at_line(self.line)
    }

    /// An input error at cell `col`.
    pub fn error(&self, col: usize, message: impl std::fmt::Display) -> Error {
        Error::input(self.place(col), message.to_string())
    }

    /// The file's header.
    pub fn header(&self) -> &Header {
        self.header
    }

    /// Cell `col` as a finite number ([`finite_number`]); `what` says what it is in messages.
    pub fn number(&self, col: usize, what: &str) -> Result<f64> {
        finite_number(self.text(col), self.place(col), what)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The table of `text` with the default format, which must have a header.
    fn table(text: &str, format: Format) -> Table {
        read(text, "t.csv", format).unwrap().unwrap()
    }

    /// Every row's (line, cells), or the first error's text.
    fn rows(text: &str, format: Format) -> std::result::Result<Vec<(usize, Vec<String>)>, String> {
        let mut t = table(text, format);
        let n = t.header().len();
        t.rows()
            .map(|r| {
                r.map(|r| (r.line(), (0..n).map(|c| r.text(c).to_string()).collect()))
                    .map_err(|e| e.to_string())
            })
            .collect()
    }

    fn cells(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn quoted_cells_are_one_cell_without_their_quotes() {
        let got = rows(
            "a,b\n\"x, y\",\"say \"\"hi\"\"\"\n\"R1\" , 2 \n",
            Format::default(),
        );
        assert_eq!(
            got.unwrap(),
            vec![
                (2, cells(&["x, y", "say \"hi\""])),
                (3, cells(&["R1", "2"]))
            ]
        );
        // A quoted cell over two lines: the row is where it starts, the next row's line is its
        // own.
        let got = rows("a,b\n\"two\nlines\",1\nz,2\n", Format::default()).unwrap();
        assert_eq!(got[0], (2, cells(&["two\nlines", "1"])));
        assert_eq!(got[1].0, 4);
    }

    #[test]
    fn a_bom_crlf_cr_and_blank_lines_keep_the_files_line_numbers() {
        for text in [
            "\u{feff}a,b\r\n1,2\r\n\r\n  \r\n,\r\n3,4\r\n",
            "\u{feff}a,b\r1,2\r\r  \r,\r3,4\r",
            "\n\na,b\n1,2\n\n  \n,\n3,4\n",
        ] {
            let t = table(text, Format::default());
            let head = t.header().clone();
            assert_eq!(head.names(), ["a", "b"], "{text:?}");
            let got = rows(text, Format::default()).unwrap();
            let first = head.line();
            assert_eq!(
                got,
                vec![
                    (first + 1, cells(&["1", "2"])),
                    (first + 5, cells(&["3", "4"]))
                ],
                "{text:?}"
            );
        }
        assert!(read("", "t.csv", Format::default()).unwrap().is_none());
        assert!(
            read("\u{feff}\r\n , \n", "t.csv", Format::default())
                .unwrap()
                .is_none()
        );
    }

    #[test]
    fn comments_are_blank_lines_when_the_format_has_them() {
        let with = Format {
            comments: true,
            ..Format::default()
        };
        let text = "# a plan\na,b\n  # note\n1,2\n";
        assert_eq!(rows(text, with).unwrap(), vec![(4, cells(&["1", "2"]))]);
        assert_eq!(table(text, with).header().line(), 2);
        // Without comments the first line is the header.
        let t = table(text, Format::default());
        assert_eq!(t.header().names(), ["# a plan"]);
    }

    #[test]
    fn a_ragged_row_is_refused_at_its_line_unless_the_format_allows_it() {
        let e = rows("a,b,c\n1,2,3\n4,5\n", Format::default()).unwrap_err();
        assert_eq!(e, "t.csv:3: not valid CSV: 2 fields where the header has 3");
        let e = rows("a,b\n\"1,2\",3,4\n", Format::default()).unwrap_err();
        assert_eq!(e, "t.csv:2: not valid CSV: 3 fields where the header has 2");
        let ragged = Format {
            ragged: true,
            first_line: 3,
            ..Format::default()
        };
        let got = rows("a,b,c\n4,5\n6,7,8,9\n", ragged).unwrap();
        assert_eq!(
            got,
            vec![(4, cells(&["4", "5", ""])), (5, cells(&["6", "7", "8"]))]
        );
    }

    #[test]
    fn duplicate_and_missing_headers_are_named() {
        let t = table("X,Y [mm],Y,z\n1,2,3,4\n", Format::default());
        let h = t.header();
        assert_eq!(h.find("X").unwrap(), Some(0));
        assert_eq!(h.find("z").unwrap(), Some(3));
        assert_eq!(h.find("Z").unwrap(), None);
        let e = h.find("Y").unwrap_err().to_string();
        assert_eq!(
            e,
            "t.csv:1: field 'Y': column 'Y' appears twice in the header"
        );
        assert_eq!(h.columns_named("Y"), [1, 2]);
        let e = h.require("Q", || "missing column 'Q'".into()).unwrap_err();
        assert_eq!(e.to_string(), "t.csv:1: field 'Q': missing column 'Q'");
        // Without units in the header a bracket is part of the name.
        let raw = Format {
            units_in_header: false,
            ..Format::default()
        };
        let t = table("X,Y [mm],Y,z\n1,2,3,4\n", raw);
        assert_eq!(t.header().find("Y [mm]").unwrap(), Some(1));
        assert_eq!(t.header().find("Y").unwrap(), Some(2));
    }

    #[test]
    fn units_in_the_header_are_checked_not_converted() {
        let t = table(
            "X [mm],C (°),t_s[h],meas_y (m),Z\n1,2,3,4,5\n",
            Format::default(),
        );
        let h = t.header();
        assert_eq!(h.names(), ["X", "C", "t_s", "meas_y", "Z"]);
        assert!(h.check_unit(0, "mm").is_ok());
        assert!(h.check_unit(1, "deg").is_ok());
        assert!(h.check_unit(4, "mm").is_ok());
        let e = h.check_unit(2, "s").unwrap_err().to_string();
        assert!(
            e.starts_with("t.csv:1: field 't_s[h]': unit 'h', expected s"),
            "{e}"
        );
        let e = h.check_unit(3, "mm").unwrap_err().to_string();
        assert!(
            e.starts_with("t.csv:1: field 'meas_y (m)': unit 'm', expected mm"),
            "{e}"
        );
    }

    #[test]
    fn numbers_are_finite_and_errors_name_file_line_and_column() {
        let mut t = table(
            "name,v\na,1.5\nb,NaN\nc,-inf\nd,1e999\ne,\nf,1 2\ng,\"7\"\n",
            Format::default(),
        );
        let got: Vec<String> = t
            .rows()
            .map(|r| {
                let r = r.unwrap();
                match r.number(1, "mm") {
                    Ok(v) => v.to_string(),
                    Err(e) => e.to_string(),
                }
            })
            .collect();
        assert_eq!(
            got,
            [
                "1.5",
                "t.csv:3: field 'v': expected a finite number (mm), found \"NaN\"",
                "t.csv:4: field 'v': expected a finite number (mm), found \"-inf\"",
                "t.csv:5: field 'v': expected a finite number (mm), found \"1e999\"",
                "t.csv:6: field 'v': expected a number (mm), found \"\"",
                "t.csv:7: field 'v': expected a number (mm), found \"1 2\"",
                "7",
            ]
        );
    }

    #[test]
    fn written_cells_read_back_as_they_were() {
        let ids = [
            "R1",
            "a,b",
            "x;y",
            "say \"hi\"",
            "two\nlines",
            "#1",
            "",
            "µ",
        ];
        let mut text = String::from("id,n\n");
        for (i, id) in ids.iter().enumerate() {
            text.push_str(&format!("{},{i}\n", cell(id)));
        }
        let with_comments = Format {
            comments: true,
            ..Format::default()
        };
        for format in [Format::default(), with_comments] {
            let got = rows(&text, format).unwrap();
            let back: Vec<&str> = got.iter().map(|(_, c)| c[0].as_str()).collect();
            // The empty id's row is blank only if every cell is: `n` is not.
            assert_eq!(back, ids, "{text}");
        }
    }

    #[test]
    fn another_delimiter_splits_cells() {
        let semi = Format {
            delimiter: b';',
            ..Format::default()
        };
        let got = rows("a;b\n1,5;\"x;y\"\n", semi).unwrap();
        assert_eq!(got, vec![(2, cells(&["1,5", "x;y"]))]);
    }
}
