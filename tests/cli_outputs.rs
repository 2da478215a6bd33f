//! The command-line tool's outputs on fixed data, against files committed before a change that
//! was meant not to alter them (the library/CLI split of issue 19): `demo`'s text and the files
//! it writes, `identify --json`, `diagnose --json` and `compare --json`.
//!
//! Everything is compared byte for byte except what a clock decides: the `time_s` fields of the
//! JSON and the demo's "(0.02 s)". The files the demo writes are compared by size and FNV-1a
//! digest (the report and the results file are large). The figures are the same bits in debug
//! and release builds and on any number of threads (the passes reduce in a fixed order), so a
//! difference is a change of behaviour. After a change that is *meant* to alter them, rewrite
//! the expected files with `VOLVER_BLESS=1 cargo test --test cli_outputs` and say why in the
//! commit.

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

/// FNV-1a, 64 bits: a digest of a written file.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

/// Compares `actual` with the expected file `name` (or writes it when blessing); the message
/// names the first line that differs.
fn check(name: &str, actual: &str, failures: &mut Vec<String>) {
    let path = expected_dir().join(name);
    if std::env::var_os("VOLVER_BLESS").is_some() {
        std::fs::create_dir_all(expected_dir()).unwrap();
        std::fs::write(&path, actual).unwrap();
        return;
    }
    let expected = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("{}: {e} (VOLVER_BLESS=1 writes it)", path.display()));
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
    check("demo.txt", &mask_demo(&run(&dir, &["demo"])), &mut failures);
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
    let digests: String = written
        .iter()
        .map(|f| {
            let bytes = std::fs::read(dir.join("volver-demo").join(f)).unwrap();
            format!("{f} {} {:016x}\n", bytes.len(), fnv1a(&bytes))
        })
        .collect();
    check("demo-files.txt", &digests, &mut failures);

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
