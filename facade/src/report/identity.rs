//! The report's identity fields: who the verification was for, on which machine, when, where,
//! with which instrument and by whom, in a `[report]` table of a TOML file
//! (`volver report --report-info FILE`) and/or command-line flags; and the header block a
//! customer signs.
//!
//! A field left out is shown as "—": nothing is invented, and the date has no default (a
//! reproducible output reads no clock).

use crate::error::{Error, Result};
use crate::plot::escape;
use serde::Deserialize;
use std::fmt::Write;
use volver_core::error::Place;

/// The identity of a verification, every field optional. Temperatures in °C.
///
/// ```
/// let id = volver::report::Identity::from_toml_str(
///     "[report]\ncustomer = \"ACME & Sons\"\nserial = \"SN-42\"\nair_temperature_c = 20.4\n",
///     "visit.toml",
/// )
/// .unwrap();
/// assert_eq!(id.customer.as_deref(), Some("ACME & Sons"));
/// assert_eq!(id.air_temperature_c, Some(20.4));
/// assert!(id.operator.is_none());
/// ```
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Identity {
    /// The customer (company, site).
    pub customer: Option<String>,
    /// The machine as the customer names it (make, model); the machine file's name when absent.
    pub machine: Option<String>,
    /// The machine's serial number.
    pub serial: Option<String>,
    /// The date of the measurement, as written (e.g. `"2026-11-27"`, or TOML's own date
    /// `2026-11-27` unquoted).
    #[serde(default, deserialize_with = "text_or_date")]
    pub date: Option<String>,
    /// Where the machine stands (site, hall).
    pub place: Option<String>,
    /// The measuring instrument (laser tracker make, model, serial).
    pub instrument: Option<String>,
    /// The instrument's calibration certificate (number, laboratory).
    pub calibration: Option<String>,
    /// The date of that calibration, as written (text or TOML date).
    #[serde(default, deserialize_with = "text_or_date")]
    pub calibration_date: Option<String>,
    /// Who measured.
    pub operator: Option<String>,
    /// The air temperature during the measurement (°C).
    pub air_temperature_c: Option<f64>,
    /// The machine's temperature during the measurement (°C).
    pub machine_temperature_c: Option<f64>,
    /// Free remarks (conditions, deviations from the plan).
    pub remarks: Option<String>,
}

/// A date field: a string as written, or a TOML date / date-time (`2026-11-27` unquoted) in its
/// own notation.
fn text_or_date<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<Option<String>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum TextOrDate {
        Text(String),
        Date(toml::value::Datetime),
    }
    Ok(Some(match TextOrDate::deserialize(d)? {
        TextOrDate::Text(s) => s,
        TextOrDate::Date(t) => t.to_string(),
    }))
}

/// The file: one `[report]` table.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    report: Identity,
}

impl Identity {
    /// Reads the `[report]` table of TOML `text`; `file` names the source in messages (an
    /// unknown field, a temperature that is not a number, a missing table).
    pub fn from_toml_str(text: &str, file: &str) -> Result<Identity> {
        let text = volver_core::error::without_bom(text);
        let parsed: File = toml::from_str(text).map_err(|e| {
            let mut place = Place::file(file);
            if let Some(span) = e.span() {
                let line = text
                    .get(..span.start)
                    .map_or(1, |t| t.matches('\n').count() + 1);
                place = place.at_line(line);
                // The key written on that line, when it is `key = value`.
                let key = text.lines().nth(line - 1).and_then(|l| l.split_once('='));
                if let Some((key, _)) = key {
                    place = place.at_field(format!("report.{}", key.trim()));
                }
            }
            Error::Core(volver_core::Error::input(
                place,
                format!("[report] table: {}", e.message().trim()),
            ))
        })?;
        let id = parsed.report;
        id.check_temperatures(file)?;
        Ok(id)
    }

    /// `Err` naming `source` and the field when a temperature is not one of a workshop
    /// (−100 … 200 °C, finite).
    pub fn check_temperatures(&self, source: &str) -> Result<()> {
        for (name, v) in [
            ("air_temperature_c", self.air_temperature_c),
            ("machine_temperature_c", self.machine_temperature_c),
        ] {
            if let Some(t) = v
                && !(-100.0..=200.0).contains(&t)
            {
                return Err(Error::Core(volver_core::Error::input(
                    Place::file(source).at_field(format!("report.{name}")),
                    format!("{t} °C is no workshop temperature (expected −100 … 200 °C)"),
                )));
            }
        }
        Ok(())
    }

    /// Reads the `[report]` table of the TOML file at `path`.
    pub fn load(path: &std::path::Path) -> Result<Identity> {
        let text = std::fs::read_to_string(path).map_err(|source| {
            Error::Core(volver_core::Error::Io {
                path: path.to_path_buf(),
                source,
            })
        })?;
        Identity::from_toml_str(&text, &path.display().to_string())
    }

    /// `self` with every field that `over` gives replaced by it (flags over the file). A text
    /// that is blank (empty or white space) counts as not given, in either: a signed document
    /// shows "—" there, never an empty cell.
    pub fn overridden_by(self, over: Identity) -> Identity {
        let given = |v: Option<String>| v.map(|s| s.trim().to_string()).filter(|s| !s.is_empty());
        let pick = |o: Option<String>, s: Option<String>| given(o).or(given(s));
        Identity {
            customer: pick(over.customer, self.customer),
            machine: pick(over.machine, self.machine),
            serial: pick(over.serial, self.serial),
            date: pick(over.date, self.date),
            place: pick(over.place, self.place),
            instrument: pick(over.instrument, self.instrument),
            calibration: pick(over.calibration, self.calibration),
            calibration_date: pick(over.calibration_date, self.calibration_date),
            operator: pick(over.operator, self.operator),
            air_temperature_c: over.air_temperature_c.or(self.air_temperature_c),
            machine_temperature_c: over.machine_temperature_c.or(self.machine_temperature_c),
            remarks: pick(over.remarks, self.remarks),
        }
    }

    /// The report's title: the machine (this identity's, else `machine_name`, the machine
    /// file's) with its serial, and the customer when known.
    ///
    /// ```
    /// let mut id = volver::report::Identity::default();
    /// assert_eq!(id.title("XCFZ grinder"), "Volumetric verification of XCFZ grinder");
    /// id.serial = Some("SN-42".into());
    /// id.customer = Some("ACME".into());
    /// assert_eq!(id.title("XCFZ grinder"), "Volumetric verification of XCFZ grinder (serial SN-42) for ACME");
    /// ```
    pub fn title(&self, machine_name: &str) -> String {
        let mut t = format!(
            "Volumetric verification of {}",
            self.machine.as_deref().unwrap_or(machine_name)
        );
        if let Some(s) = &self.serial {
            let _ = write!(t, " (serial {s})");
        }
        if let Some(c) = &self.customer {
            let _ = write!(t, " for {c}");
        }
        t
    }

    /// The rows of the identity block: (label, value), "—" for a field not given.
    pub fn rows(&self, machine_name: &str) -> Vec<(&'static str, String)> {
        let text = |v: &Option<String>| v.clone().unwrap_or_else(|| "—".into());
        let temp = |v: Option<f64>| v.map_or("—".into(), |t| format!("{t:.1} °C"));
        let calibration = match (&self.calibration, &self.calibration_date) {
            (None, None) => "—".to_string(),
            (Some(c), None) => c.clone(),
            (None, Some(d)) => format!("— (dated {d})"),
            (Some(c), Some(d)) => format!("{c} (dated {d})"),
        };
        vec![
            ("Customer", text(&self.customer)),
            (
                "Machine",
                self.machine.clone().unwrap_or_else(|| machine_name.into()),
            ),
            ("Serial number", text(&self.serial)),
            ("Date of measurement", text(&self.date)),
            ("Place", text(&self.place)),
            ("Instrument", text(&self.instrument)),
            ("Calibration certificate", calibration),
            ("Operator", text(&self.operator)),
            ("Air temperature", temp(self.air_temperature_c)),
            ("Machine temperature", temp(self.machine_temperature_c)),
            ("Remarks", text(&self.remarks)),
        ]
    }

    /// The header block: the identity fields (escaped) in a two-column table, and the lines a
    /// customer and the metrologist sign.
    pub fn header_html(&self, machine_name: &str) -> String {
        let mut s = String::from("<section class=\"identity\"><table class=\"identity\">\n");
        let rows = self.rows(machine_name);
        for pair in rows.chunks(2) {
            s.push_str("<tr>");
            for (label, value) in pair {
                let _ = write!(s, "<th>{}</th><td>{}</td>", escape(label), escape(value));
            }
            if pair.len() == 1 {
                s.push_str("<th></th><td></td>");
            }
            s.push_str("</tr>\n");
        }
        s.push_str(
            "</table>\n<table class=\"sign\"><tr><th>Measured by (name, signature, date)</th>\
             <th>Approved by the customer (name, signature, date)</th></tr>\
             <tr><td></td><td></td></tr></table></section>\n",
        );
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_field_not_given_is_a_dash_and_flags_win() {
        let file = Identity::from_toml_str(
            "[report]\ncustomer = \"A\"\noperator = \"B\"\n",
            "visit.toml",
        )
        .unwrap();
        let flags = Identity {
            operator: Some("C".into()),
            ..Identity::default()
        };
        let id = file.overridden_by(flags);
        assert_eq!(id.customer.as_deref(), Some("A"));
        assert_eq!(id.operator.as_deref(), Some("C"));
        let rows = id.rows("M");
        assert_eq!(rows[1], ("Machine", "M".to_string()));
        assert_eq!(rows[3], ("Date of measurement", "—".to_string()));
        // A blank field is not given: "—", and a blank flag does not hide the file's value.
        let file = Identity::from_toml_str(
            "[report]\ncustomer = \"\"\nserial = \"  \"\noperator = \"B\"\n",
            "visit.toml",
        )
        .unwrap();
        let flags = Identity {
            operator: Some(" ".into()),
            ..Identity::default()
        };
        let id = file.overridden_by(flags);
        assert_eq!((id.customer.as_deref(), id.serial.as_deref()), (None, None));
        assert_eq!(id.operator.as_deref(), Some("B"));
        assert_eq!(id.title("M"), "Volumetric verification of M");
        // TOML's own date, unquoted, is taken as written.
        let id = Identity::from_toml_str("[report]\ndate = 2026-11-27\n", "visit.toml").unwrap();
        assert_eq!(id.date.as_deref(), Some("2026-11-27"));
    }

    #[test]
    fn bad_fields_are_named_with_their_file() {
        let e = Identity::from_toml_str("[report]\ncustmer = \"A\"\n", "visit.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("visit.toml:2") && e.contains("custmer"), "{e}");
        let e = Identity::from_toml_str("[report]\nair_temperature_c = \"warm\"\n", "v.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("v.toml:2: field 'report.air_temperature_c'"),
            "{e}"
        );
        let e = Identity::from_toml_str("[report]\nair_temperature_c = 2000.0\n", "v.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("report.air_temperature_c"), "{e}");
        let e = Identity::from_toml_str("customer = \"A\"\n", "v.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("v.toml") && e.contains("report"), "{e}");
    }

    #[test]
    fn the_header_escapes_every_field() {
        let id = Identity {
            customer: Some("<b>A & B</b>".into()),
            remarks: Some("\"quoted\"".into()),
            ..Identity::default()
        };
        let h = id.header_html("M<1>");
        assert!(h.contains("&lt;b&gt;A &amp; B&lt;/b&gt;"), "{h}");
        assert!(h.contains("&quot;quoted&quot;") && h.contains("M&lt;1&gt;"));
        assert!(!h.contains("<b>"));
    }
}
