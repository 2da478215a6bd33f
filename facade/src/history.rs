//! The fit history of a diagnosis session: every `volver identify` appends one JSON line to a
//! history file (by default `volver-history.jsonl` beside the measurements), and
//! `volver history` shows EMM and Φ per model revision as a table and an SVG chart.

use crate::error::{Context, Error, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Name of the history file written beside the measurements.
pub const DEFAULT_NAME: &str = "volver-history.jsonl";

/// One fit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Record {
    /// Measurement file as given.
    pub data: String,
    /// Error-model name.
    pub model: String,
    /// Candidates added on the command line (`--add`).
    pub added: Vec<String>,
    /// Parameters of the model.
    pub parameters: usize,
    /// Free directions of the last phase.
    pub free: usize,
    /// EMM before and after (µm).
    pub emm_initial_um: f64,
    /// Final EMM (µm).
    pub emm_final_um: f64,
    /// Final EMax (µm).
    pub emax_final_um: f64,
    /// Final Φ (mm).
    pub phi_mm: f64,
    /// Noise error (µm): from the truth when one was given to `identify`, from the tracker's
    /// noise specification for the rounds of `diagnose --iterate`.
    pub noise_error_um: Option<f64>,
    /// How the fit ended.
    pub termination: String,
}

/// The default history file for a measurement file.
pub fn default_path(data: &Path) -> PathBuf {
    data.parent()
        .map_or_else(|| PathBuf::from("."), Path::to_path_buf)
        .join(DEFAULT_NAME)
}

/// Appends a record as one line, under an exclusive lock on the file, so that fits run at the
/// same time (two terminals, a script) never lose a record (the old read-rewrite-rename lost
/// one writer's record when two overlapped). A last line cut short by an older writer stays on
/// its own line; the new record starts on the next.
pub fn append(path: &Path, record: &Record) -> Result<()> {
    use std::io::{Read, Seek, SeekFrom, Write};
    let context = || format!("appending to the history file {}", path.display());
    let mut f = std::fs::OpenOptions::new()
        .read(true)
        .append(true)
        .create(true)
        .open(path)
        .with_context(context)?;
    // An exclusive lock for the whole append: concurrent fits (two terminals, a script) each
    // add their line, none is lost. Released when `f` is dropped.
    f.lock().with_context(context)?;
    let mut line = serde_json::to_string(record)?;
    line.push('\n');
    let len = f.metadata().with_context(context)?.len();
    if len > 0 {
        let mut last = [0u8; 1];
        f.seek(SeekFrom::Start(len - 1)).with_context(context)?;
        f.read_exact(&mut last).with_context(context)?;
        if last[0] != b'\n' {
            line.insert(0, '\n');
        }
    }
    f.write_all(line.as_bytes()).with_context(context)?;
    f.sync_all().with_context(context)?;
    Ok(())
}

/// The records of a history file, and the lines that are not whole records.
#[derive(Clone, Debug, PartialEq)]
pub struct History {
    /// Every whole record, in the file's order.
    pub records: Vec<Record>,
    /// The numbers (from 1) of the lines that are not records: a line torn by a writer that was
    /// killed, or edited by hand. The caller says so.
    pub skipped: Vec<usize>,
}

/// Reads every record. One torn line does not make the rest unreadable: unreadable lines are
/// skipped and numbered in [`History::skipped`]; a file without one record is an error naming
/// its first line.
pub fn read(path: &Path) -> Result<History> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading the history file {}", path.display()))?;
    let mut history = History {
        records: Vec::new(),
        skipped: Vec::new(),
    };
    let mut first_error = None;
    for (i, l) in text.lines().enumerate() {
        if l.trim().is_empty() {
            continue;
        }
        match serde_json::from_str(l) {
            Ok(r) => history.records.push(r),
            Err(e) => {
                history.skipped.push(i + 1);
                first_error.get_or_insert(e);
            }
        }
    }
    if let Some(e) = first_error.filter(|_| history.records.is_empty()) {
        return Err(Error::Json(e).context(format!(
            "{}, line {}: not a volver history record, and no line of the file is one",
            path.display(),
            history.skipped[0]
        )));
    }
    Ok(history)
}

/// The history as a table.
pub fn table(records: &[Record]) -> String {
    let mut s = format!(
        "  {:>3}  {:<34} {:<22} {:>6} {:>12} {:>10}  termination\n",
        "rev", "model", "added", "params", "EMM µm", "change"
    );
    let mut prev: Option<f64> = None;
    for (i, r) in records.iter().enumerate() {
        let change = prev.map_or(String::new(), |p| {
            format!("{:+.1} %", 100.0 * (r.emm_final_um / p - 1.0))
        });
        let model: String = r.model.chars().take(34).collect();
        s.push_str(&format!(
            "  {:>3}  {:<34} {:<22} {:>6} {:>12.4} {:>10}  {}\n",
            i + 1,
            model,
            if r.added.is_empty() {
                "—".to_string()
            } else {
                r.added.join(" ")
            },
            r.parameters,
            r.emm_final_um,
            change,
            r.termination
        ));
        prev = Some(r.emm_final_um);
    }
    if let Some(n) = records.iter().rev().find_map(|r| r.noise_error_um) {
        s.push_str(&format!(
            "  noise error (from the truth, or the tracker's specification for diagnose rounds): {n:.4} µm\n"
        ));
    }
    s
}

/// The history as an SVG chart: final EMM per revision (bars), the noise error as a dashed line
/// when known. Self-contained, no scripts.
pub fn svg(records: &[Record]) -> String {
    let (w, h, left, bottom, top) = (640.0, 360.0, 70.0, 60.0, 30.0);
    let plot_w = w - left - 20.0;
    let plot_h = h - bottom - top;
    let noise = records.iter().rev().find_map(|r| r.noise_error_um);
    let ymax = records
        .iter()
        .map(|r| r.emm_final_um)
        .chain(noise)
        .fold(0.0_f64, f64::max)
        .max(1e-9)
        * 1.1;
    let y = |v: f64| top + plot_h * (1.0 - v / ymax);
    let n = records.len().max(1) as f64;
    let bar = plot_w / n;
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\" font-family=\"sans-serif\" font-size=\"12\">\n\
         <rect width=\"{w}\" height=\"{h}\" fill=\"white\"/>\n\
         <text x=\"{left}\" y=\"18\" font-size=\"14\">Final EMM per model revision (µm)</text>\n\
         <line x1=\"{left}\" y1=\"{top}\" x2=\"{left}\" y2=\"{}\" stroke=\"black\"/>\n\
         <line x1=\"{left}\" y1=\"{}\" x2=\"{}\" y2=\"{}\" stroke=\"black\"/>\n",
        top + plot_h,
        top + plot_h,
        left + plot_w,
        top + plot_h
    );
    for k in 0..=4 {
        let v = ymax * k as f64 / 4.0;
        s.push_str(&format!(
            "<text x=\"{}\" y=\"{:.1}\" text-anchor=\"end\">{v:.1}</text>\n",
            left - 6.0,
            y(v) + 4.0
        ));
    }
    for (i, r) in records.iter().enumerate() {
        let x = left + bar * i as f64 + 0.15 * bar;
        let label = if r.added.is_empty() {
            format!("rev {}", i + 1)
        } else {
            r.added.join(" ")
        };
        s.push_str(&format!(
            "<rect class=\"revision\" x=\"{x:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"#4a7ab5\"><title>rev {}: {:.4} µm</title></rect>\n\
             <text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{:.2}</text>\n\
             <text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>\n",
            y(r.emm_final_um),
            0.7 * bar,
            top + plot_h - y(r.emm_final_um),
            i + 1,
            r.emm_final_um,
            x + 0.35 * bar,
            y(r.emm_final_um) - 4.0,
            r.emm_final_um,
            x + 0.35 * bar,
            top + plot_h + 16.0,
            escape(&label)
        ));
    }
    if let Some(v) = noise {
        s.push_str(&format!(
            "<line class=\"noise\" x1=\"{left}\" y1=\"{0:.1}\" x2=\"{1}\" y2=\"{0:.1}\" stroke=\"#c0392b\" stroke-dasharray=\"6 4\"/>\n\
             <text x=\"{1}\" y=\"{2:.1}\" text-anchor=\"end\" fill=\"#c0392b\">noise error {v:.2} µm</text>\n",
            y(v),
            left + plot_w,
            y(v) - 4.0
        ));
    }
    s.push_str("</svg>\n");
    s
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Eight writers appending 25 records each at once lose none.
    #[test]
    fn concurrent_appends_lose_no_record() {
        let dir =
            std::env::temp_dir().join(format!("volver-history-concurrent-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("h.jsonl");
        std::thread::scope(|s| {
            for w in 0..8 {
                let path = &path;
                s.spawn(move || {
                    for i in 0..25 {
                        append(path, &rec(&format!("w{w}-{i}"), &[], 1.0)).unwrap();
                    }
                });
            }
        });
        let records = read(&path).unwrap().records;
        assert_eq!(records.len(), 200);
        for w in 0..8 {
            for i in 0..25 {
                let name = format!("w{w}-{i}");
                assert!(records.iter().any(|r| r.model == name), "{name} lost");
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    fn rec(model: &str, added: &[&str], emm: f64) -> Record {
        Record {
            data: "m.csv".into(),
            model: model.into(),
            added: added.iter().map(|s| s.to_string()).collect(),
            parameters: 74,
            free: 57,
            emm_initial_um: 120.0,
            emm_final_um: emm,
            emax_final_um: 3.0 * emm,
            phi_mm: emm * 1e-3,
            noise_error_um: Some(8.0),
            termination: "converged".into(),
        }
    }

    #[test]
    fn history_round_trips_and_renders() {
        let dir = std::env::temp_dir().join(format!("volver-history-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(DEFAULT_NAME);
        let _ = std::fs::remove_file(&path);
        let a = rec("paper", &[], 93.5);
        let b = rec("paper", &["raise-axis:C"], 7.9);
        append(&path, &a).unwrap();
        append(&path, &b).unwrap();
        let back = read(&path).unwrap().records;
        assert_eq!(back, vec![a.clone(), b]);
        let t = table(&back);
        assert!(t.contains("raise-axis:C") && t.contains("-91.6 %"), "{t}");
        let s = svg(&back);
        assert_eq!(s.matches("class=\"revision\"").count(), 2);
        assert!(s.starts_with("<svg") && s.contains("class=\"noise\""));
        // The append writes in place under a lock: no temporary or lock file beside it.
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        std::fs::write(&path, "{not json}\n").unwrap();
        let e = format!("{:#}", read(&path).unwrap_err());
        assert!(e.contains("line 1"), "{e}");
        // A last line cut short (by an older volver, or an editor) stays on its own line and
        // is named; the new record is whole on the next one.
        std::fs::write(&path, "{\"data\": \"m.cs").unwrap();
        append(&path, &a).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(text.lines().count(), 2);
        let h = read(&path).unwrap();
        assert_eq!((h.records, h.skipped), (vec![a.clone()], vec![1]));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
