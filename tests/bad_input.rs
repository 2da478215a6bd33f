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
    // The file with the measured coordinates divided by `divisor` (another length unit).
    let scaled = |divisor: f64| -> Vec<String> {
        std::iter::once(header.clone())
            .chain(lines.iter().map(|r| {
                let mut c: Vec<String> = r.split(',').map(String::from).collect();
                for v in &mut c[4..7] {
                    *v = format!("{}", v.parse::<f64>().unwrap() / divisor);
                }
                c.join(",")
            }))
            .collect()
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
        (
            "beyond-reach.csv",
            with_first(replace_cell(4, "2e6")),
            vec![":2:", "meas_x", "beyond any laser tracker"],
        ),
        (
            "unit-rad.csv",
            with_first(first.clone())
                .into_iter()
                .enumerate()
                .map(|(i, l)| {
                    if i == 0 {
                        l.replacen("C,", "C [rad],", 1)
                    } else {
                        l
                    }
                })
                .collect(),
            vec![":1:", "C [rad]", "expected deg"],
        ),
        (
            "unit-m.csv",
            with_first(first.clone())
                .into_iter()
                .enumerate()
                .map(|(i, l)| {
                    if i == 0 {
                        l.replace("meas_y", "meas_y (m)")
                    } else {
                        l
                    }
                })
                .collect(),
            vec![":1:", "meas_y (m)", "expected mm"],
        ),
        (
            "metres.csv",
            scaled(1000.0),
            vec!["metres.csv", "look like metres"],
        ),
        (
            "inches.csv",
            scaled(25.4),
            vec!["inches.csv", "look like inches"],
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
            vec!["5 distinct poses (5 points) give 15 equations", "too small"],
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

/// Units written on the header are accepted when they are volver's (mm, degrees, seconds), in
/// brackets or parentheses; nothing is converted.
#[test]
fn header_units_in_volvers_units_are_accepted() {
    use volver::core::machine::Machine;
    use volver::core::measure::MeasurementSet;
    let m = Machine::default_xcfz();
    let plain = "X,C,Z,reflector,meas_x,meas_y,meas_z,t_s\n100,90,50,R1,950,75,1450,1\n";
    let marked = "X [mm],C (°),Z(mm),reflector,meas_x [mm],meas_y [MM],meas_z (mm),t_s [s]\n\
                  100,90,50,R1,950,75,1450,1\n";
    let a = MeasurementSet::from_csv_str(&m, plain, "plain.csv").unwrap();
    let b = MeasurementSet::from_csv_str(&m, marked, "marked.csv").unwrap();
    assert_eq!(a, b);
    let err = MeasurementSet::from_csv_str(&m, &marked.replace("t_s [s]", "t_s [h]"), "h.csv")
        .unwrap_err()
        .to_string();
    assert!(err.contains("h.csv:1:") && err.contains("t_s [h]"), "{err}");
    let pts = volver::core::compensate::read_points("X [mm],C [deg],Z\n1,2,3\n", "p.csv", &m);
    assert_eq!(pts.unwrap().len(), 1);
    let err = volver::core::compensate::read_points("X [in],C,Z\n1,2,3\n", "p.csv", &m)
        .unwrap_err()
        .to_string();
    assert!(err.contains("p.csv:1:") && err.contains("X [in]") && err.contains("expected mm"));
}

/// Broken results files (the input of `volver tables`, `compensate`, `report --truth`) are
/// refused with the file and the line or field named.
#[test]
fn broken_results_files_are_refused_with_the_place_named() {
    let dir = fixture("json");
    let good = std::fs::read_to_string(dir.join("truth.json")).unwrap();
    let value: serde_json::Value = serde_json::from_str(&good).unwrap();
    let edit = |f: &dyn Fn(&mut serde_json::Value)| {
        let mut v = value.clone();
        f(&mut v);
        serde_json::to_string_pretty(&v).unwrap()
    };
    let out = dir.join("tables");
    let out = out.to_str().unwrap();
    // A simulation's truth carries no uncertainty: --force writes its tables.
    let ok = volver(&[
        "tables",
        "--results",
        dir.join("truth.json").to_str().unwrap(),
        "--out",
        out,
        "--force",
    ]);
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    let cut = good.lines().take(12).collect::<Vec<_>>().join("\n");
    let cases: Vec<(&str, String, Vec<&str>)> = vec![
        (
            "empty.json",
            String::new(),
            vec!["empty.json:1:", "not a volver results file"],
        ),
        ("cut.json", cut, vec!["cut.json:12:", "EOF"]),
        (
            "not-results.json",
            edit(&|v| v["format"] = "volver-model".into()),
            vec!["not-results.json", "'format'", "volver-results"],
        ),
        (
            "version.json",
            edit(&|v| v["version"] = 7.into()),
            vec!["version.json", "'version'", "version 7"],
        ),
        (
            "renamed.json",
            edit(&|v| v["parameters"][2]["name"] = "EXX.c9".into()),
            vec!["renamed.json", "parameters[2]", "EXX.c9"],
        ),
        (
            "missing-parameter.json",
            edit(&|v| {
                v["parameters"].as_array_mut().unwrap().pop();
            }),
            vec!["missing-parameter.json", "'parameters'", "parameters, but"],
        ),
        (
            "string-value.json",
            edit(&|v| v["parameters"][0]["value"] = "0.1".into()),
            vec!["string-value.json:", "expected f64"],
        ),
        (
            "huge-value.json",
            good.replacen("\"value\": ", "\"value\": 1e999, \"x\": ", 1),
            vec!["huge-value.json:", "out of range"],
        ),
        (
            "unknown-field.json",
            edit(&|v| v["colour"] = "red".into()),
            vec!["unknown-field.json:", "colour"],
        ),
    ];
    for (name, text, needles) in cases {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        let r = volver(&["tables", "--results", path.to_str().unwrap(), "--out", out]);
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success(), "{name} accepted");
        assert!(!err.contains("panicked"), "{name}: {err}");
        for n in &needles {
            assert!(err.contains(n), "{name}: '{n}' not in {err}");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A reader that closes the pipe early is not a crash: `volver layout | head -1` exits like a
/// process stopped by SIGPIPE (status 141), with no panic message; `--decimals` beyond 12 is
/// refused by the argument parser instead of panicking.
#[test]
fn a_closed_pipe_and_absurd_decimals_are_not_crashes() {
    use std::process::{Command, Stdio};
    let mut child = Command::new(env!("CARGO_BIN_EXE_volver"))
        .arg("layout")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take()); // the reader goes away before volver writes
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert_ne!(out.status.code(), Some(101), "{err}");
    let out = common::volver(&[
        "compensate",
        "--results",
        "x.json",
        "--points",
        "p.csv",
        "--out",
        "o.csv",
        "--decimals",
        "70000",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && !err.contains("panicked"), "{err}");
    assert!(err.contains("--decimals"), "{err}");
}

/// An output path that names an input is refused before anything is written, and the input is
/// intact: `identify --out DATA`, `report --out DATA`, `compensate --out RESULTS`; a NaN
/// verification tolerance is refused instead of disabling the verification.
#[test]
fn outputs_never_overwrite_inputs() {
    let dir = std::env::temp_dir().join(format!("volver-overwrite-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let d = |n: &str| dir.join(n).display().to_string();
    common::simulate(&d("sim"), &["--plan", "test3", "--seed", "3"]);
    let data = d("sim/measurements.csv");
    let before = std::fs::read(&data).unwrap();
    for args in [
        vec!["identify", "--data", &data, "--out", &data, "--no-history"],
        vec!["report", "--data", &data, "--out", &data],
        vec![
            "report",
            "--data",
            &data,
            "--out",
            &d("r.html"),
            "--results",
            &data,
        ],
    ] {
        let out = common::volver(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?}");
        assert!(
            err.contains("is an input of this command"),
            "{args:?}: {err}"
        );
        assert_eq!(
            std::fs::read(&data).unwrap(),
            before,
            "{args:?} touched the data"
        );
    }
    let truth = d("sim/truth.json");
    std::fs::write(d("p.csv"), "X,C,Z\n100,0,50\n").unwrap();
    let truth_before = std::fs::read(&truth).unwrap();
    let out = common::volver(&[
        "compensate",
        "--results",
        &truth,
        "--points",
        &d("p.csv"),
        "--out",
        &truth,
    ]);
    assert!(!out.status.success());
    assert_eq!(std::fs::read(&truth).unwrap(), truth_before);
    let out = common::volver(&[
        "compensate",
        "--results",
        &truth,
        "--points",
        &d("p.csv"),
        "--out",
        &d("o.csv"),
        "--tolerance",
        "nan",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("--tolerance"),
        "{err}"
    );
    assert!(!dir.join("o.csv").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// Every size read from input is bounded before anything is allocated, and refused with the
/// limit named: an error model's order of 2⁶³ − 1 or 2⁶³ (which wrapped the coefficient count),
/// a degree of 2⁶⁴ − 1, a Chebyshev with 2⁶⁴ nodes (which wrapped to "0 nodes"), a plan step of
/// 1e-9 mm, a table step of 1e-6 mm.
#[test]
fn sizes_from_input_are_bounded() {
    use volver::core::machine::Machine;
    use volver::core::model::Model;
    use volver::core::plan::Plan;
    use volver::core::tables::ErrorTables;
    let m = Machine::default_xcfz();
    for (text, what) in [
        (
            "[[error]]\nname = \"ECC\"\nbasis = \"fourier\"\norder = 9223372036854775807\n",
            "order 2^63-1",
        ),
        (
            "[[error]]\nname = \"EXX\"\nbasis = \"legendre\"\ndegree = 9223372036854775807\n",
            "degree 2^63-1",
        ),
        (
            "[[error]]\nname = \"EXX\"\nbasis = \"chebyshev\"\nnodes = 9223372036854775807\n",
            "nodes 2^63-1",
        ),
    ] {
        let e = Model::from_toml_str(m.clone(), text, "big.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("at most 32 coefficients"), "{what}: {e}");
    }
    // Through JSON (a results file's model), where u64 reaches 2⁶³ and 2⁶⁴ − 1.
    let spec = |entry: &str| format!("{{\"name\":\"big\",\"error\":[{entry}]}}");
    for entry in [
        "{\"name\":\"ECC\",\"basis\":\"fourier\",\"order\":9223372036854775808}",
        "{\"name\":\"EXX\",\"basis\":\"legendre\",\"degree\":18446744073709551615}",
        "{\"name\":\"EXX\",\"basis\":\"chebyshev\",\"degree\":18446744073709551615}",
    ] {
        let s: volver::core::model::ErrorModelSpec = serde_json::from_str(&spec(entry)).unwrap();
        let e = Model::new(m.clone(), s).unwrap_err().to_string();
        assert!(e.contains("at most 32 coefficients"), "{entry}: {e}");
    }
    let e = Plan::parse_grid(&m, "X=0:1400:1e-9,C=0,Z=0")
        .unwrap_err()
        .to_string();
    assert!(e.contains("at most 1000000 positions"), "{e}");
    let e = Plan::parse_grid(&m, "X=0:1400:0.01,C=0:360:0.001,Z=0:600:1")
        .unwrap_err()
        .to_string();
    assert!(e.contains("at most 1000000"), "{e}");
    let model = Model::default_xcfz();
    let p = model.initial_params();
    let e = ErrorTables::from_model(&model, &p, 1e-6, 5.0)
        .unwrap_err()
        .to_string();
    assert!(e.contains("at most 100000"), "{e}");
    assert!(ErrorTables::from_model(&model, &p, f64::INFINITY, 5.0).is_err());
}

/// Honest exits: a fit whose determined sizes no machine has (a 2 mm typo in the Z offset, the
/// meas_x and meas_y columns swapped, i.e. a mirrored tracker frame) or that stopped on a limit
/// exits non-zero and writes no results, unless --accept; correct data pass (the values along
/// the directions test 4 cannot identify are not held against it). `tables` refuses a results
/// file with a gross size.
#[test]
fn implausible_or_unfinished_fits_exit_non_zero_and_write_nothing() {
    let dir = std::env::temp_dir().join(format!("volver-plausible-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let d = |n: &str| dir.join(n).display().to_string();
    common::simulate(&d("sim"), &["--plan", "test4", "--seed", "3"]);
    let data = d("sim/measurements.csv");
    let machine = std::fs::read_to_string(d("sim/machine.toml")).unwrap();
    let typo = machine.replace("[1000.0, 25.0, 1500.0]", "[1000.0, 27.0, 1500.0]");
    assert_ne!(typo, machine);
    std::fs::write(d("typo.toml"), typo).unwrap();
    let csv = std::fs::read_to_string(&data).unwrap();
    std::fs::write(
        d("swapped.csv"),
        csv.replacen("meas_x,meas_y", "meas_y,meas_x", 1),
    )
    .unwrap();
    let model = "core/data/xcfz-paper-model.toml";
    let fit = |extra: &[&str], out_name: &str| {
        let out_path = d(out_name);
        let mut args = vec!["identify", "--no-history", "--out", &out_path];
        args.extend_from_slice(extra);
        let out = common::volver(&args);
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stderr).to_string(),
            dir.join(out_name).exists(),
        )
    };
    let (ok, err, written) = fit(&["--data", &data], "good.json");
    assert!(ok && written, "correct data refused: {err}");
    let typo_args = [
        "--machine",
        &d("typo.toml"),
        "--model",
        model,
        "--data",
        &data,
    ];
    let (ok, err, written) = fit(&typo_args, "typo.json");
    assert!(!ok && !written, "{err}");
    assert!(
        err.contains("implausible sizes") && err.contains("EYC"),
        "{err}"
    );
    assert!(err.contains("check the machine file"), "{err}");
    let mut accepted = typo_args.to_vec();
    accepted.push("--accept");
    let (ok, err, written) = fit(&accepted, "typo-accepted.json");
    assert!(ok && written, "{err}");
    let (ok, err, written) = fit(&["--data", &d("swapped.csv")], "swapped.json");
    assert!(!ok && !written, "{err}");
    assert!(err.contains("implausible sizes"), "{err}");
    let (ok, err, written) = fit(&["--data", &data, "--max-iterations", "2"], "short.json");
    assert!(!ok && !written, "{err}");
    assert!(
        err.contains("not converged") && err.contains("--accept"),
        "{err}"
    );
    let (ok, err, written) = fit(
        &["--data", &data, "--max-iterations", "2", "--accept"],
        "short-accepted.json",
    );
    assert!(ok && written, "{err}");
    // A results file with 20 mm of radial error: `tables` refuses it.
    let m = volver::core::model::Model::default_xcfz();
    let mut p = m.initial_params();
    p[m.param_index("EYC.d").unwrap()] = 20.0;
    volver::core::results::ResultsFile::from_model(&m, &p)
        .unwrap()
        .save(&dir.join("gross.json"))
        .unwrap();
    let out = common::volver(&["tables", "--results", &d("gross.json"), "--out", &d("t")]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("implausible"),
        "{err}"
    );
    assert!(!dir.join("t").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// A reflector id that cannot sit in a CSV cell, and machine dimensions of 1e300 (written back
/// as 300-digit numbers), are refused with their place; a rotary command far outside its travel
/// is reported, as a linear one is.
#[test]
fn ids_dimensions_and_rotary_travel_are_checked() {
    use volver::core::compensate::Compensator;
    use volver::core::machine::{DEFAULT_MACHINE_TOML, Machine};
    use volver::core::model::Model;
    for (from, to, needle) in [
        ("id = \"R1\"", "id = \"R1,a\"", "comma"),
        ("id = \"R1\"", "id = \" R1\"", "surrounding space"),
        (
            "range = [0.0, 1400.0]",
            "range = [0.0, 1e300]",
            "at most 1e6",
        ),
        (
            "offset = [-50.0, 50.0, -50.0]",
            "offset = [-50.0, 1e300, -50.0]",
            "at most 1e6",
        ),
    ] {
        let text = DEFAULT_MACHINE_TOML.replacen(from, to, 1);
        assert_ne!(text, DEFAULT_MACHINE_TOML, "{from}");
        let e = Machine::from_toml_str(&text, "m.toml")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("m.toml") && e.contains(needle), "{to}: {e}");
    }
    let model = Model::default_xcfz();
    let p = model.initial_params();
    let comp = Compensator::new(&model, &p, [0.0; 3]).unwrap();
    let far = model
        .machine()
        .commands_from_file_units(&[100.0, 100_000.0, 50.0]);
    let c = comp.compensate(&far).unwrap();
    assert_eq!(c.outside_travel, vec![1], "C at 100 000° is outside 0–360°");
}

/// A row copied exactly is refused (it would fake a small repeat noise); data whose points all
/// sit at one pose are refused by the mesh check, which counts distinct poses; `--truth` takes
/// the noise error from the simulation record only for the measurements written beside it.
#[test]
fn copied_rows_one_pose_and_foreign_records_are_caught() {
    use volver::core::machine::Machine;
    use volver::core::measure::MeasurementSet;
    let m = Machine::default_xcfz();
    let rows = "X,C,Z,reflector,meas_x,meas_y,meas_z\n\
                100,90,50,R1,950.1,75.2,1450.3\n\
                200,90,50,R1,850.1,75.2,1450.3\n\
                100,90,50,R1,950.1,75.2,1450.3\n";
    let e = MeasurementSet::from_csv_str(&m, rows, "d.csv")
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("d.csv:4") && e.contains("repeats line 2"),
        "{e}"
    );
    // A true repeat (another reading of the same pose) is kept.
    let again = format!("{}1450.3004\n", rows.strip_suffix("1450.3\n").unwrap());
    assert_ne!(again, rows);
    assert_eq!(
        MeasurementSet::from_csv_str(&m, &again, "d.csv")
            .unwrap()
            .points
            .len(),
        3
    );

    let dir = std::env::temp_dir().join(format!("volver-onepose-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let d = |n: &str| dir.join(n).display().to_string();
    let mut one = String::from("X,C,Z,reflector,meas_x,meas_y,meas_z\n");
    for i in 0..200 {
        one.push_str(&format!(
            "100,90,50,R1,950.1,75.2,{:.4}\n",
            1450.0 + i as f64 * 1e-4
        ));
    }
    std::fs::write(d("one.csv"), one).unwrap();
    let out = common::volver(&["identify", "--data", &d("one.csv"), "--no-history"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("1 distinct poses (200 points)"),
        "{err}"
    );
    assert!(!String::from_utf8_lossy(&out.stdout).contains("NaN"));

    // Two simulations; the truth of A with the data of B.
    for (name, seed) in [("a", "1"), ("b", "2")] {
        common::simulate(&d(name), &["--plan", "test3", "--seed", seed]);
    }
    let noise_of = |data: &str, truth: &str| {
        let out = common::volver(&[
            "identify",
            "--data",
            data,
            "--truth",
            truth,
            "--json",
            "--no-history",
        ]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        v["noise_error_um"].as_f64().unwrap()
    };
    let record = |name: &str| -> f64 {
        let t = std::fs::read_to_string(dir.join(name).join("simulation.json")).unwrap();
        let v: serde_json::Value = serde_json::from_str(&t).unwrap();
        v["noise_error"]["emm_um"].as_f64().unwrap()
    };
    let own = noise_of(&d("a/measurements.csv"), &d("a/truth.json"));
    assert_eq!(own, record("a"));
    let foreign = noise_of(&d("b/measurements.csv"), &d("a/truth.json"));
    assert_ne!(foreign, record("a"), "A's record used for B's data");
    let _ = std::fs::remove_dir_all(&dir);
}
