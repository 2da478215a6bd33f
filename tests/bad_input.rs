//! Bad input through the CLI: every class of broken measurement file, error model and machine
//! file gets an error naming the file, the line and the field (or the reason), a non-zero exit
//! and no panic.

mod common;

use common::volver;
use std::path::{Path, PathBuf};

/// A directory with a good simulated test-3 measurement file.
fn fixture(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("volver-bad-{tag}-{}", std::process::id()));
    let out = volver(&[
        "simulate",
        "--plan",
        "test3",
        "--seed",
        "3",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success());
    dir
}

/// Runs identify on `data` (plus `extra` arguments) and returns stderr; asserts failure without
/// a panic.
fn refused(data: &Path, extra: &[&str]) -> String {
    let mut args = vec!["identify", "--data", data.to_str().unwrap(), "--no-history"];
    args.extend_from_slice(extra);
    let out = volver(&args);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "accepted {}: {err}", data.display());
    assert!(
        !err.contains("panicked"),
        "panic on {}: {err}",
        data.display()
    );
    err
}

#[test]
fn broken_measurement_files_are_refused_with_the_place_named() {
    let dir = fixture("csv");
    let text = std::fs::read_to_string(dir.join("measurements.csv")).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let header = lines.remove(0);
    let first = lines[0].clone();
    let cells: Vec<&str> = first.split(',').collect();
    let with_first = |row: String| -> Vec<String> {
        let mut v = vec![header.clone(), row];
        v.extend(lines[1..].iter().cloned());
        v
    };
    let replace_cell = |k: usize, value: &str| -> String {
        let mut c = cells.clone();
        c[k] = value;
        c.join(",")
    };
    // (file, its lines, what the message must contain)
    let cases: Vec<(&str, Vec<String>, Vec<&str>)> = vec![
        (
            "missing-column.csv",
            std::iter::once(header.replace(",meas_z", ""))
                .chain(lines.iter().map(|r| {
                    let c: Vec<&str> = r.split(',').collect();
                    [&c[..6], &c[7..]].concat().join(",")
                }))
                .collect(),
            vec![":1:", "meas_z", "missing column"],
        ),
        (
            "duplicate-column.csv",
            std::iter::once(format!("{header},meas_x"))
                .chain(lines.iter().map(|r| format!("{r},1.0")))
                .collect(),
            vec![":1:", "meas_x", "appears twice"],
        ),
        (
            "axis-not-in-machine.csv",
            std::iter::once(header.replacen("X,", "X,Y,", 1))
                .chain(lines.iter().map(|r| r.replacen(',', ",0,", 1)))
                .collect(),
            vec![":1:", "'Y'", "does not have"],
        ),
        (
            "axis-missing.csv",
            std::iter::once(header.replacen("Z,", "", 1))
                .chain(lines.iter().map(|r| {
                    let c: Vec<&str> = r.split(',').collect();
                    [&c[..2], &c[3..]].concat().join(",")
                }))
                .collect(),
            vec![":1:", "'Z'", "missing column"],
        ),
        (
            "unknown-reflector.csv",
            with_first(replace_cell(3, "R9")),
            vec![":2:", "reflector", "R9"],
        ),
        (
            "not-a-number.csv",
            with_first(replace_cell(4, "abc")),
            vec![":2:", "meas_x", "abc"],
        ),
        (
            "nan.csv",
            with_first(replace_cell(5, "NaN")),
            vec![":2:", "meas_y", "finite"],
        ),
        (
            "infinite.csv",
            with_first(replace_cell(6, "-inf")),
            vec![":2:", "meas_z", "finite"],
        ),
        (
            "out-of-range.csv",
            with_first(replace_cell(0, "99999")),
            vec![":2:", "'X'", "outside the travel range"],
        ),
        ("empty.csv", vec![], vec!["empty.csv", "empty file"]),
        (
            "header-only.csv",
            vec![header.clone()],
            vec!["header-only.csv", "no measurement rows"],
        ),
        (
            "too-few-points.csv",
            std::iter::once(header.clone())
                .chain(lines[..5].iter().cloned())
                .collect(),
            vec!["5 points give 15 equations", "too small"],
        ),
    ];
    for (name, content, needles) in cases {
        let path = dir.join(name);
        std::fs::write(&path, content.join("\n") + "\n").unwrap();
        let err = refused(&path, &[]);
        if needles[0].starts_with(':') {
            assert!(
                err.contains(&format!("{name}{}", needles[0])),
                "{name}: no file:line in {err}"
            );
        }
        for n in &needles {
            assert!(err.contains(n), "{name}: '{n}' not in {err}");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn broken_models_and_machines_are_refused_with_the_place_named() {
    let dir = fixture("toml");
    let data = dir.join("measurements.csv");
    let model = dir.join("model.toml");
    std::fs::write(
        &model,
        "[[error]]\nname = \"EQX\"\nbasis = \"monomial\"\ndegree = 2\n",
    )
    .unwrap();
    let err = refused(&data, &["--model", model.to_str().unwrap()]);
    assert!(
        err.contains("model.toml:2:") && err.contains("error.name") && err.contains("EQX"),
        "{err}"
    );
    let machine = dir.join("machine.toml");
    let good = std::fs::read_to_string(dir.join("machine.toml")).unwrap_or_default();
    let bad = if good.contains("chain = \"XCFZ\"") {
        good.replace("chain = \"XCFZ\"", "chain = \"XCQZ\"")
    } else {
        "name = \"broken\"\nchain = \"XCQZ\"\n".to_string()
    };
    std::fs::write(&machine, bad).unwrap();
    let err = refused(&data, &["--machine", machine.to_str().unwrap()]);
    assert!(
        err.contains("machine.toml:") && err.contains("field 'chain'"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
