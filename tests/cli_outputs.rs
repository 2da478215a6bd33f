//! The command-line tool's outputs on fixed data, against files committed before a change that
//! was meant not to alter them (the library/CLI split of issue 19): `demo`'s text and the files
//! it writes, `identify --json`, `diagnose --json` and `compare --json`.
//!
//! Everything is compared as text, line by line, except what a clock decides: the `time_s`
//! fields of the JSON and the demo's "(0.02 s)". The files the demo writes are stored as they
//! are (the report as its visible text, tags stripped), so that a change can be read in review.
//! The figures are the same bits in debug and release builds and on any number of threads (the
//! passes reduce in a fixed order), so a difference is a change of behaviour. Beside the
//! comparison, the demo's meaning is asserted from its figures (the missing effect found, the
//! final fit at the noise, what compensation gains), so that a blessing cannot freeze a wrong
//! conclusion.
//!
//! After a change that is *meant* to alter the outputs, `VOLVER_BLESS=1 cargo test --test
//! cli_outputs` rewrites the expected files, prints what changed and fails (a blessing run never
//! passes; refused when `CI` is set); review the diff, say why in the commit, and run again.

use std::path::{Path, PathBuf};
use std::process::Command;

/// Where the expected outputs live.
fn expected_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/cli")
}

/// Runs the CLI in `dir` and returns its standard output; panics with its standard error when
/// it fails.
fn run(dir: &Path, args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_volver"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("the volver binary runs");
    assert!(
        out.status.success(),
        "volver {} failed: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("UTF-8 output")
}

/// The demo's text without its wall-clock figures ("(0.02 s)").
fn mask_demo(text: &str) -> String {
    text.lines()
        .map(|line| match (line.rfind(" ("), line.ends_with(" s)")) {
            (Some(at), true)
                if line[at + 2..line.len() - 3]
                    .chars()
                    .all(|c| c.is_ascii_digit() || c == '.') =>
            {
                format!("{} (… s)", &line[..at])
            }
            _ => line.to_string(),
        })
        .collect::<Vec<_>>()
        .join("\n")
        + "\n"
}

/// A JSON output without its wall-clock fields, pretty-printed as the CLI prints it.
fn mask_json(text: &str) -> String {
    fn strip(v: &mut serde_json::Value) {
        match v {
            serde_json::Value::Object(map) => {
                map.remove("time_s");
                map.values_mut().for_each(strip);
            }
            serde_json::Value::Array(items) => items.iter_mut().for_each(strip),
            _ => {}
        }
    }
    let mut v: serde_json::Value = serde_json::from_str(text).expect("the output is JSON");
    strip(&mut v);
    serde_json::to_string_pretty(&v).expect("JSON prints") + "\n"
}

/// A written file as stored: text as it is, the JSON results without wall-clock fields, the
/// HTML report as its visible text (one line per text node, SVG labels included).
fn stored(name: &str, bytes: &[u8]) -> String {
    let text = String::from_utf8_lossy(bytes).into_owned();
    if name.ends_with(".json") {
        mask_json(&text)
    } else if name.ends_with(".html") {
        visible_text(&text)
    } else {
        text
    }
}

/// The text nodes of an HTML document, one a line (tags, styles and empty nodes dropped).
fn visible_text(html: &str) -> String {
    let mut out = String::new();
    let mut inside = false;
    let mut style = false;
    let mut node = String::new();
    let mut tag = String::new();
    for c in html.chars() {
        match c {
            '<' => {
                let t = node.split_whitespace().collect::<Vec<_>>().join(" ");
                if !t.is_empty() && !style {
                    out.push_str(&t);
                    out.push('\n');
                }
                node.clear();
                tag.clear();
                inside = true;
            }
            '>' if inside => {
                inside = false;
                let name = tag
                    .trim_start_matches('/')
                    .split_whitespace()
                    .next()
                    .unwrap_or("");
                if name.eq_ignore_ascii_case("style") {
                    style = !tag.starts_with('/');
                }
            }
            _ if inside => tag.push(c),
            _ => node.push(c),
        }
    }
    out
}

/// The lines of `old` and `new` that differ (at most 40 of each), as `-` and `+` lines.
fn diff(old: &str, new: &str) -> String {
    let (a, b): (Vec<&str>, Vec<&str>) = (old.lines().collect(), new.lines().collect());
    let removed: Vec<String> = a
        .iter()
        .filter(|l| !b.contains(l))
        .take(40)
        .map(|l| format!("  - {l}"))
        .collect();
    let added: Vec<String> = b
        .iter()
        .filter(|l| !a.contains(l))
        .take(40)
        .map(|l| format!("  + {l}"))
        .collect();
    [removed, added].concat().join("\n")
}

/// Compares `actual` with the expected file `name` (or writes it when blessing, and reports
/// what changed as a failure); the message names the first line that differs.
fn check(name: &str, actual: &str, failures: &mut Vec<String>) {
    let path = expected_dir().join(name);
    if std::env::var_os("VOLVER_BLESS").is_some() {
        assert!(
            std::env::var_os("CI").is_none(),
            "VOLVER_BLESS is refused when CI is set: expected outputs are blessed by a person"
        );
        let old = std::fs::read_to_string(&path).unwrap_or_default();
        if old != actual {
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(&path, actual).unwrap();
            failures.push(format!("blessed {name}:\n{}", diff(&old, actual)));
        }
        return;
    }
    let expected = match std::fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) => {
            failures.push(format!(
                "{}: {e} (VOLVER_BLESS=1 writes it)",
                path.display()
            ));
            return;
        }
    };
    if expected == actual {
        return;
    }
    let line = expected
        .lines()
        .zip(actual.lines())
        .position(|(a, b)| a != b)
        .unwrap_or_else(|| expected.lines().count().min(actual.lines().count()));
    failures.push(format!(
        "{name}: differs from line {}:\n  expected: {}\n  actual:   {}",
        line + 1,
        expected.lines().nth(line).unwrap_or("<end>"),
        actual.lines().nth(line).unwrap_or("<end>"),
    ));
}

#[test]
fn outputs_on_fixed_data_are_unchanged() {
    let dir = std::env::temp_dir().join(format!("volver-cli-outputs-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let mut failures = Vec::new();

    // The demo: its text and what it writes (the data the other commands read).
    let demo = mask_demo(&run(&dir, &["demo"]));
    demo_text_means_what_it_says(&demo, &mut failures);
    check("demo.txt", &demo, &mut failures);
    let written = [
        "fit.json",
        "report.html",
        "tables/errors-isg.csv",
        "tables/errors-etalon.txt",
        "tables/errors.csv",
        "tables/errors-u95.csv",
        "test4/machine.toml",
        "test4/measurements.csv",
        "test4/simulation.json",
        "test4/truth.json",
    ];
    for f in written {
        let bytes = std::fs::read(dir.join("volver-demo").join(f)).unwrap();
        let name = format!("demo/{f}").replace(".html", ".txt");
        check(&name, &stored(f, &bytes), &mut failures);
    }
    demo_means_what_it_says(&dir.join("volver-demo"), &mut failures);

    let data = "volver-demo/test4/measurements.csv";
    check(
        "identify.json",
        &mask_json(&run(&dir, &["identify", "--data", data, "--json"])),
        &mut failures,
    );
    check(
        "diagnose.json",
        &mask_json(&run(&dir, &["diagnose", "--data", data, "--json"])),
        &mut failures,
    );
    // The demo's problem (test 4 without the hidden effect), under the gauge so that every
    // engine converges; the engines of the default build.
    if cfg!(feature = "clarabel") {
        check(
            "compare.json",
            &mask_json(&run(
                &dir,
                &["compare", "--json", "--gauge", "--engines", "lm,clarabel"],
            )),
            &mut failures,
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The number after `marker` in `text` (the first).
fn after(text: &str, marker: &str) -> Option<f64> {
    let rest = &text[text.find(marker)? + marker.len()..];
    let num: String = rest
        .trim_start()
        .chars()
        .take_while(|c| c.is_ascii_digit() || *c == '.' || *c == '-')
        .collect();
    num.parse().ok()
}

/// The demo's conclusions against its own figures, whatever was blessed: the missing effect
/// found is the one hidden (a second harmonic of C: `raise-axis:C`), the first fit is above the
/// noise and says so, the final fit is at the noise error (0.97–1.05 of it: the fit absorbs
/// 86 of 3 120 coordinates, √(1 − 86/3120) = 0.986) and says so, and compensation takes at
/// least three quarters of the true tool-point error away.
fn demo_text_means_what_it_says(demo: &str, failures: &mut Vec<String>) {
    let mut fail = |m: String| failures.push(format!("demo.txt: {m}"));
    if !demo.contains("→ the missing effect: raise-axis:C") {
        fail("the missing effect found is not raise-axis:C (the hidden 2nd harmonic of C)".into());
    }
    let step2 = demo
        .lines()
        .skip_while(|l| !l.starts_with("2."))
        .take(3)
        .collect::<Vec<_>>();
    if !step2.iter().any(|l| l.contains(": something is missing")) {
        fail(format!(
            "step 2 does not conclude that something is missing: {step2:?}"
        ));
    }
    match after(demo, "µm parameters) — ").or_else(|| {
        let l = demo.lines().find(|l| l.starts_with("4."))?;
        after(l, ") — ")
    }) {
        Some(r) if (0.97..=1.05).contains(&r) => {}
        r => fail(format!(
            "the final fit over the noise error is {r:?}, not 0.97–1.05"
        )),
    }
    let step4 = demo.lines().find(|l| l.starts_with("4.")).unwrap_or("");
    if !step4.ends_with("the model explains everything but the noise") {
        fail(format!("step 4 does not conclude at the noise: {step4}"));
    }
    let comp = demo
        .lines()
        .find(|l| l.contains("true tool-point error EMM"))
        .unwrap_or("");
    match (after(comp, "EMM"), after(comp, "→")) {
        (Some(before), Some(after)) if after < 0.25 * before => {}
        r => fail(format!("compensation gains too little: {r:?} in {comp}")),
    }
}

/// The written files' meaning: the results file's final EMM equals the demo's, and the plain
/// error table holds every error of the final model.
fn demo_means_what_it_says(dir: &Path, failures: &mut Vec<String>) {
    let fit: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("fit.json")).unwrap()).unwrap();
    let spec = fit["error_model"]["error"].as_array().map_or(0, Vec::len);
    if spec == 0 {
        failures.push("fit.json: no error model".into());
    }
    let table = std::fs::read_to_string(dir.join("tables/errors.csv")).unwrap();
    for e in ["EXC", "EZC", "ECC", "EXX", "EZZ"] {
        if !table.lines().any(|l| l.starts_with(&format!("{e},"))) {
            failures.push(format!("tables/errors.csv: no row of {e}"));
        }
    }
}
