//! The report as a document to hand over (issue 47): its charts' labels neither overlap nor
//! leave their chart (measured in the SVG, `common::svg_text`), every chart fits an A4 page's
//! width and height, the identity fields appear escaped, and headless Chromium prints the
//! demo's report to A4 pages with no chart cut across two of them.

mod common;

use common::svg_text;
use std::path::{Path, PathBuf};
use std::process::Command;
use volver::plot::{self, Cell, FunctionPanel, LayoutView};

/// Runs volver in `dir` with `args` and returns its stdout; panics with its stderr.
fn run_in(dir: &Path, args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_volver"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("volver runs");
    assert!(
        out.status.success(),
        "volver {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// The demo, run once per test process in a scratch folder: the folder (its `volver-demo/`
/// holds the report and the data).
fn demo() -> &'static Path {
    static DIR: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    DIR.get_or_init(|| {
        let dir = common::scratch_dir("report-print", "demo");
        run_in(&dir, &["demo"]);
        dir
    })
}

/// The demo's measurements, relative to [`demo`]'s folder.
const DATA: &str = "volver-demo/test4/measurements.csv";

/// The checker can fail: two texts drawn over each other, one past the right edge and one
/// rotated out of the top are found; two side by side are not.
#[test]
fn the_measure_finds_overlaps_and_clipping() {
    let svg = r#"<svg viewBox="0 0 200 100" font-size="10">
        <text x="10" y="20">abcdef</text><text x="30" y="22">ghi</text>
        <text x="190" y="60" text-anchor="middle">wide label</text>
        <text transform="translate(100,5) rotate(-90)">up</text>
        <text x="10" y="90">left</text><text x="50" y="90">right</text></svg>"#;
    let p = svg_text::problems(svg, 0.5);
    assert_eq!(p.len(), 3, "{p:#?}");
    assert!(p[0].contains("\"abcdef\" overlaps \"ghi\""), "{p:#?}");
    assert!(p[1].contains("\"wide label\" leaves") && p[2].contains("\"up\" leaves"));
}

/// Every chart of the demo's report and of `volver report` with a cross-validation row (its
/// label is the data file's path and the model, the longest label a chart gets): no text box
/// overlaps another or leaves its chart's viewBox. On the report before issue 47 this found
/// 60 problems: the time and distance breakdowns' interval labels run into each other
/// ("7800 … 9100" over "9100 … 10400"), the model-revision chart's "noise error 49.94" over
/// the bar's value and its two labels over each other, the error functions' "not determined"
/// titles over their neighbours, tick labels and out of the chart, the U map's title out of
/// its chart, and `volver report`'s cross-validation label over the scale and cut.
#[test]
fn no_chart_label_overlaps_another_or_leaves_its_chart() {
    let dir = demo();
    let html = std::fs::read_to_string(dir.join("volver-demo/report.html")).unwrap();
    let charts = svg_text::charts(&html);
    assert!(charts.len() >= 10, "{} charts", charts.len());
    let mut problems = svg_text::problems(&html, 0.5);
    run_in(
        dir,
        &[
            "report",
            "--data",
            DATA,
            "--reference",
            DATA,
            "--out",
            "cv.html",
        ],
    );
    let cv = std::fs::read_to_string(dir.join("cv.html")).unwrap();
    assert!(cv.contains("Residual on the reference after compensation"));
    problems.extend(svg_text::problems(&cv, 0.5));
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// The identity fields: from `--report-info`'s `[report]` table, a flag over its field, every
/// field escaped (a customer with `<`, `&` and quotes), a field given nowhere as "—"; the
/// title is the machine, its serial and the customer, not a file path.
#[test]
fn the_identity_fields_appear_escaped_with_flags_over_the_file() {
    let dir = demo();
    std::fs::write(
        dir.join("visit.toml"),
        "[report]\ncustomer = \"Tool & Die <Nord> \\\"West\\\"\"\nserial = \"SN 4711\"\n\
         operator = \"from the file\"\ninstrument = \"Tracker AT-960\"\n\
         calibration = \"Cert. 12/345\"\ncalibration_date = \"2026-03-02\"\n\
         air_temperature_c = 20.4\nmachine_temperature_c = 21.3\n",
    )
    .unwrap();
    run_in(
        dir,
        &[
            "report",
            "--data",
            DATA,
            "--report-info",
            "visit.toml",
            "--operator",
            "A. <B>",
            "--date",
            "2026-11-27",
            "--out",
            "id.html",
        ],
    );
    let html = std::fs::read_to_string(dir.join("id.html")).unwrap();
    let title = "Volumetric verification of XCFZ grinder (Aguado et al. 2014) (serial SN 4711) \
                 for Tool &amp; Die &lt;Nord&gt; &quot;West&quot;";
    assert!(html.contains(&format!("<title>{title}</title>")), "title");
    assert!(html.contains(&format!("<h1>{title}</h1>")));
    for cell in [
        "<th>Operator</th><td>A. &lt;B&gt;</td>",
        "<th>Date of measurement</th><td>2026-11-27</td>",
        "<td>Tracker AT-960</td>",
        "<td>Cert. 12/345 (dated 2026-03-02)</td>",
        "<th>Air temperature</th><td>20.4 °C</td>",
        "<th>Machine temperature</th><td>21.3 °C</td>",
        "<th>Place</th><td>—</td>",
        "Approved by the customer",
    ] {
        assert!(html.contains(cell), "{cell}");
    }
    assert!(!html.contains("from the file") && !html.contains("<Nord>"));
}

/// A bad identity file is refused before anything runs, naming the file, the line and the
/// field; a temperature flag out of range names the flag; the identity file is an input that
/// `--out` may not overwrite.
#[test]
fn bad_identity_input_is_named_and_nothing_is_written() {
    let dir = common::scratch_dir("report-print", "bad");
    std::fs::write(
        dir.join("visit.toml"),
        "[report]\ncustomer = \"A\"\ncustmer = \"B\"\n",
    )
    .unwrap();
    let fails = |args: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_volver"))
            .args(args)
            .current_dir(&dir)
            .output()
            .unwrap();
        assert!(!out.status.success(), "{args:?}");
        String::from_utf8_lossy(&out.stderr).to_string()
    };
    let e = fails(&[
        "report",
        "--data",
        "none.csv",
        "--report-info",
        "visit.toml",
        "--out",
        "r.html",
    ]);
    assert!(e.contains("visit.toml:3") && e.contains("custmer"), "{e}");
    let e = fails(&[
        "report",
        "--data",
        "none.csv",
        "--air-temperature",
        "2000",
        "--out",
        "r.html",
    ]);
    assert!(e.contains("--air-temperature 2000"), "{e}");
    let e = fails(&[
        "report",
        "--data",
        "none.csv",
        "--report-info",
        "visit.toml",
        "--out",
        "visit.toml",
    ]);
    assert!(e.contains("visit.toml"), "{e}");
    assert!(
        std::fs::read_to_string(dir.join("visit.toml"))
            .unwrap()
            .contains("custmer")
    );
    assert!(!dir.join("r.html").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// Charts given what stresses their layout: 40 bars of long interval labels, one bar with a
/// 70-character label, a reference line at the top bar's height, error functions with long
/// "not determined" names and tiny values, colour maps of a negative range, a set-up with
/// stations 1 mm apart. No label overlaps another or leaves its chart.
#[test]
fn stressed_charts_keep_their_labels_apart_and_inside() {
    let mut svgs = Vec::new();
    for n in [1, 3, 8, 12, 40] {
        let data: Vec<(String, f64)> = (0..n)
            .map(|i| {
                let label = if n == 1 {
                    "volver-demo/test4/measurements.csv (model \"paper model\" + raise-axis:C)"
                        .to_string()
                } else {
                    format!("{} … {}", 1300 * i, 1300 * (i + 1))
                };
                (label, 40.0 + i as f64)
            })
            .collect();
        let top = 40.0 + n as f64 - 1.0;
        svgs.push(plot::bars(
            "Residual EMM by t_s s",
            "EMM (µm)",
            &data,
            Some(("noise error", top)),
        ));
    }
    let panels: Vec<FunctionPanel> = (0..7)
        .map(|i| FunctionPanel {
            name: format!(
                "E{i}Z — not determined by the data (held combination EAZ.c1 +0.35, ECZ.c3 +0.28, EXC.s1 -0.12)"
            ),
            xlabel: "Z (mm)".into(),
            unit: "µrad".into(),
            x: (0..11).map(|k| -800.0 + 100.0 * k as f64).collect(),
            value: (0..11).map(|k| -0.0123 * k as f64).collect(),
            sigma: vec![0.001; 11],
            truth: None,
        })
        .collect();
    svgs.push(plot::error_functions("Component errors", &panels));
    let cells: Vec<Cell> = (0..5)
        .flat_map(|i| {
            (0..4).map(move |j| Cell {
                x: -1500.0 + 300.0 * i as f64,
                y: -1200.0 + 0.5 * j as f64,
                a: (i * j) as f64,
                b: 0.5,
            })
        })
        .collect();
    svgs.push(plot::colour_maps(
        "U (k = 2) of the compensated tool point in the X–Y plane, largest over the other axes (µm)",
        "X (mm)",
        "Y (mm)",
        &[("after the set-up's rigid transform", cells.clone()), ("raw", cells.clone())],
    ));
    svgs.push(plot::vector_diagrams(
        "Error vectors",
        "X (mm)",
        "Y (mm)",
        2000.0,
        &[("before", cells)],
    ));
    let view = LayoutView {
        title: "plan (x–y)".into(),
        xlabel: "x (mm)".into(),
        ylabel: "y (mm)".into(),
        points: vec![[0.0, 0.0], [3000.0, 2000.0]],
        stations: vec![
            ("S1".into(), [1500.0, 1000.0]),
            ("S2-long-name".into(), [1501.0, 1000.5]),
            ("S3".into(), [1500.5, 999.5]),
        ],
    };
    svgs.push(plot::layout_views("The set-up", &[view]));
    let page = svgs.concat();
    assert_eq!(svg_text::charts(&page).len(), 9);
    let p = svg_text::problems(&page, 0.5);
    assert!(p.is_empty(), "{}", p.join("\n"));
}

/// Whether headless Chromium and poppler's `pdfinfo`/`pdftotext` can run; when they cannot,
/// a panic saying how to install them (`scripts/test` does), or `false` when
/// `VOLVER_NO_CHROMIUM` is set (the check skipped, said on stderr).
fn require_chromium() -> bool {
    let runs = |cmd: &str, arg: &str| {
        Command::new(cmd)
            .arg(arg)
            .output()
            .is_ok_and(|o| o.status.success())
    };
    if runs("chromium", "--version") && runs("pdfinfo", "-v") && runs("pdftotext", "-v") {
        return true;
    }
    if std::env::var_os("VOLVER_NO_CHROMIUM").is_some() {
        eprintln!("chromium or poppler-utils missing: skipped (VOLVER_NO_CHROMIUM is set)");
        return false;
    }
    panic!(
        "headless Chromium and poppler-utils are not installed: `apt-get install chromium \
         poppler-utils` (scripts/test does it), or set VOLVER_NO_CHROMIUM=1 to skip the print check"
    );
}

/// Runs headless Chromium on `page` with `args` (its profile in `profile`).
fn chromium(profile: &Path, page: &Path, args: &[&str]) {
    let out = Command::new("chromium")
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(args)
        .arg(format!("file://{}", page.display()))
        .output()
        .expect("chromium runs");
    assert!(
        out.status.success(),
        "chromium {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Headless Chromium prints the demo's report (its print style sheet) to between 6 and 16
/// pages (10 when written), every one A4 (595.28 × 841.89 pt within 1 pt), and takes a
/// screenshot; no chart is cut across two pages: the page that holds each chart's title (its
/// first text) holds every copy of its lowest text too (read back with pdftotext, page by
/// page). On the report before issue 47 (no print style sheet, 18 error functions in one
/// chart) this finds the error functions' last row ("C (deg)" 6 times, 3 on the title's page)
/// on the next page.
#[test]
fn chromium_prints_the_demos_report_on_a4_pages_with_no_chart_cut() {
    if !require_chromium() {
        return;
    }
    let dir = demo();
    let report = dir.join("volver-demo/report.html").canonicalize().unwrap();
    let (pdf, png) = (dir.join("report.pdf"), dir.join("report.png"));
    let profile = dir.join("chromium-profile");
    chromium(
        &profile,
        &report,
        &[
            "--no-pdf-header-footer",
            &format!("--print-to-pdf={}", pdf.display()),
        ],
    );
    chromium(
        &profile,
        &report,
        &[
            "--window-size=1400,4000",
            &format!("--screenshot={}", png.display()),
        ],
    );
    let shot = std::fs::read(&png).unwrap();
    assert!(
        shot.starts_with(b"\x89PNG") && shot.len() > 10_000,
        "{} bytes",
        shot.len()
    );
    let info = Command::new("pdfinfo")
        .args(["-l", "1000"])
        .arg(&pdf)
        .output()
        .unwrap();
    let info = String::from_utf8_lossy(&info.stdout).to_string();
    let pages: usize = info
        .lines()
        .find_map(|l| l.strip_prefix("Pages:"))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("no page count: {info}"));
    assert!((6..=16).contains(&pages), "{pages} pages");
    let sizes: Vec<(f64, f64)> = info
        .lines()
        .filter(|l| l.starts_with("Page") && l.contains(" size: "))
        .map(|l| {
            let v: Vec<f64> = l
                .split(" size: ")
                .nth(1)
                .unwrap()
                .split_whitespace()
                .filter_map(|w| w.parse().ok())
                .collect();
            (v[0], v[1])
        })
        .collect();
    assert_eq!(sizes.len(), pages, "{info}");
    for (w, h) in sizes {
        assert!(
            (w - 595.28).abs() < 1.0 && (h - 841.89).abs() < 1.0,
            "{w} × {h} pt"
        );
    }
    let text = Command::new("pdftotext")
        .args(["-layout"])
        .arg(&pdf)
        .arg("-")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&text.stdout).to_string();
    let by_page: Vec<&str> = text.split('\u{c}').collect();
    let html = std::fs::read_to_string(&report).unwrap();
    let mut cut = Vec::new();
    for chart in svg_text::charts(&html) {
        let title = &chart.boxes.first().unwrap().text;
        // The chart's lowest level text (the longest of those on its lowest line; rotated text
        // reads back unreliably) and how often the chart has it: its title's page holds it at
        // least as often, else the chart's bottom went to the next page.
        let level: Vec<&svg_text::TextBox> = chart
            .boxes
            .iter()
            .filter(|b| (b.corners[0][1] - b.corners[3][1]).abs() < 1e-6)
            .collect();
        let low = level
            .iter()
            .map(|b| b.corners[0][1])
            .fold(f64::MIN, f64::max);
        let last = &level
            .iter()
            .filter(|b| b.corners[0][1] > low - 1.0)
            .max_by_key(|b| b.text.chars().count())
            .unwrap()
            .text;
        let times = level.iter().filter(|b| &b.text == last).count();
        let Some(page) = by_page.iter().position(|p| p.contains(title.as_str())) else {
            cut.push(format!("\"{title}\" is on no page"));
            continue;
        };
        if by_page[page].matches(last.as_str()).count() < times {
            cut.push(format!(
                "\"{title}\" (page {}): its lowest text \"{last}\" ({times} times) is not all on its page",
                page + 1
            ));
        }
    }
    assert!(cut.is_empty(), "{}", cut.join("\n"));
}

/// The demo on each five-axis preset (three linear axes: maps in the X–Y, X–Z and Y–Z planes,
/// two rotary axes): no chart label overlaps another or leaves its chart, and the print style
/// sheet and identity block are there.
#[test]
fn five_axis_reports_keep_their_labels_apart_and_inside() {
    let mut problems = Vec::new();
    for preset in ["table-table", "head-head", "head-table"] {
        let dir = common::scratch_dir("report-print", preset);
        run_in(&dir, &["demo", "--machine", preset]);
        let html = std::fs::read_to_string(dir.join("volver-demo/report.html")).unwrap();
        for plane in ["X–Y", "X–Z", "Y–Z"] {
            assert!(
                html.contains(&format!("Error module in the {plane} plane")),
                "{preset} {plane}"
            );
        }
        assert!(html.contains("@page{size:A4") && html.contains("Approved by the customer"));
        problems.extend(
            svg_text::problems(&html, 0.5)
                .into_iter()
                .map(|p| format!("{preset}: {p}")),
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
