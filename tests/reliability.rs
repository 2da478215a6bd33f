//! Issue 43 (reliability III), one test per case through the CLI: counts bounded before anything
//! is allocated, no output over an input or over another output of the same run, readers that
//! refuse what they cannot interpret, and messages that name the file, line and field without
//! dumping input or a backtrace. Fixtures in `tests/data/reliability/`.

mod common;

use common::volver;
use std::path::{Path, PathBuf};

/// A fixture of `tests/data/reliability/`.
fn data(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/reliability")
        .join(name)
        .display()
        .to_string()
}

/// A fresh temporary folder for one test.
fn scratch(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("volver-i43-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A simulated test 3 (432 points) in `dir/sim`; returns its folder.
fn simulated(dir: &Path) -> PathBuf {
    let sim = dir.join("sim");
    common::simulate(sim.to_str().unwrap(), &["--plan", "test3", "--seed", "3"]);
    sim
}

/// Runs `args`; asserts a refusal (exit 1, no panic, no backtrace) and returns stderr.
fn refused(args: &[&str]) -> String {
    let out = volver(args);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(
        out.status.code(),
        Some(1),
        "{args:?} was not refused: {err}"
    );
    assert!(!err.contains("panicked"), "{args:?} panics: {err}");
    assert!(!err.to_lowercase().contains("backtrace"), "{args:?}: {err}");
    err
}

/// Every absurd replica count is refused before the fit with the bound named: no capacity
/// overflow, no 24 TB allocation, no run until killed, and no "0 of 1 replicas failed".
#[test]
fn monte_carlo_counts_are_bounded_before_the_fit() {
    let dir = scratch("mc");
    let sim = simulated(&dir);
    let d = sim.join("measurements.csv").display().to_string();
    for n in ["18446744073709551615", "4294967296", "100000000", "1", "0"] {
        let err = refused(&["uncertainty", "--data", &d, "--monte-carlo", n]);
        assert!(
            err.contains(&format!("--monte-carlo {n}")) && err.contains("2 … 100000"),
            "{n}: {err}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The inputs the overwrite cases name, beside a simulated test 3 in `dir/sim`: a machine file
/// named as plan's derived `tool2.machine.toml`, candidate reflectors `r3.toml` and their copy
/// `cand.machine.toml`, `D/machine.toml`, a hard link `hard.toml` to the machine file, a results
/// file `T/errors.csv` named as a table, a symbolic link `link.csv` to the measurements. Returns
/// the simulation's folder and the files that must stay untouched.
fn overwrite_fixtures(dir: &Path) -> (PathBuf, Vec<String>) {
    let sim = simulated(dir);
    let p = |n: &str| dir.join(n).display().to_string();
    let machine = sim.join("machine.toml");
    std::fs::copy(&machine, p("tool2.machine.toml")).unwrap();
    std::fs::write(
        p("r3.toml"),
        "[[reflector]]\nid = \"R3\"\noffset = [0.0, 0.0, -250.0]\n",
    )
    .unwrap();
    std::fs::copy(p("r3.toml"), p("cand.machine.toml")).unwrap();
    std::fs::create_dir_all(p("D")).unwrap();
    std::fs::copy(&machine, p("D/machine.toml")).unwrap();
    std::fs::hard_link(&machine, p("hard.toml")).unwrap();
    std::fs::create_dir_all(p("T")).unwrap();
    std::fs::copy(sim.join("truth.json"), p("T/errors.csv")).unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink(sim.join("measurements.csv"), p("link.csv")).unwrap();
    let watched = vec![
        p("tool2.machine.toml"),
        p("cand.machine.toml"),
        p("D/machine.toml"),
        p("T/errors.csv"),
        sim.join("measurements.csv").display().to_string(),
        machine.display().to_string(),
    ];
    (sim, watched)
}

/// The overwrite cases on [`overwrite_fixtures`]: each command and what its refusal names.
fn overwrite_cases(dir: &Path, sim: &Path) -> Vec<(Vec<String>, &'static str)> {
    let p = |n: &str| dir.join(n).display().to_string();
    let data = sim.join("measurements.csv").display().to_string();
    let model = format!(
        "{}/core/data/xcfz-paper-model.toml",
        env!("CARGO_MANIFEST_DIR")
    );
    let (tool2, r3, cand) = (
        p("tool2.machine.toml"),
        p("r3.toml"),
        p("cand.machine.toml"),
    );
    vec![
        (
            vec![
                "plan",
                "--machine",
                &tool2,
                "--model",
                &model,
                "--reflectors",
                &r3,
            ]
            .into_iter()
            .map(String::from)
            .chain(["--out".into(), p("tool2.csv")])
            .collect(),
            "tool2.machine.toml is an input",
        ),
        (
            vec![
                "plan".into(),
                "--reflectors".into(),
                cand.clone(),
                "--out".into(),
                p("cand.csv"),
            ],
            "cand.machine.toml is an input",
        ),
        (
            vec![
                "plan".into(),
                "--out".into(),
                p("same.csv"),
                "--gcode".into(),
                p("same.csv"),
            ],
            "another output of this command",
        ),
        (
            [
                "simulate",
                "--machine",
                &p("D/machine.toml"),
                "--out",
                &p("D"),
            ]
            .map(String::from)
            .to_vec(),
            "machine.toml is an input",
        ),
        (
            [
                "simulate",
                "--machine",
                &p("hard.toml"),
                "--out",
                sim.to_str().unwrap(),
            ]
            .map(String::from)
            .to_vec(),
            "hard.toml is an input",
        ),
        (
            [
                "identify",
                "--data",
                &data,
                "--out",
                &p("fit.json"),
                "--history",
                &p("fit.json"),
            ]
            .map(String::from)
            .to_vec(),
            "another output of this command",
        ),
        (
            ["tables", "--results", &p("T/errors.csv"), "--out", &p("T")]
                .map(String::from)
                .to_vec(),
            "errors.csv is an input",
        ),
    ]
}

/// Every derived output path goes through the same check as --out: inputs (also as hard and
/// symbolic links) and other outputs of the same run are refused, and the input is untouched.
#[test]
fn no_output_overwrites_an_input_or_another_output() {
    let dir = scratch("outputs");
    let (sim, watched) = overwrite_fixtures(&dir);
    let p = |n: &str| dir.join(n).display().to_string();
    let data = sim.join("measurements.csv").display().to_string();
    let before: Vec<Vec<u8>> = watched.iter().map(|f| std::fs::read(f).unwrap()).collect();
    let cases = overwrite_cases(&dir, &sim);
    for (args, what) in &cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let err = refused(&args);
        assert!(err.contains(what), "{args:?}: {err}");
    }
    #[cfg(unix)]
    {
        let err = refused(&[
            "identify",
            "--data",
            &data,
            "--out",
            &p("link.csv"),
            "--no-history",
        ]);
        assert!(
            err.contains("is an input") && err.contains("link.csv"),
            "{err}"
        );
    }
    for (f, b) in watched.iter().zip(&before) {
        assert_eq!(&std::fs::read(f).unwrap(), b, "{f} was touched");
    }
    assert!(!dir.join("same.csv").exists() && !dir.join("tool2.csv").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// Station ids a machine without [[station]] tables cannot place are refused, naming them and
/// what to pass; one id throughout is the one tracker.
#[test]
fn stations_the_machine_lacks_are_named() {
    let dir = scratch("stations");
    let sim = simulated(&dir);
    let text = std::fs::read_to_string(sim.join("measurements.csv")).unwrap();
    let with = |ids: &[&str]| -> String {
        let mut out = String::new();
        for (i, l) in text.lines().enumerate() {
            let id = if i == 0 {
                "station"
            } else {
                ids[i % ids.len()]
            };
            out.push_str(&format!("{l},{id}\n"));
        }
        out
    };
    let four = dir.join("four.csv");
    std::fs::write(&four, with(&["S1", "S2", "S3", "S4"])).unwrap();
    let err = refused(&["identify", "--data", four.to_str().unwrap(), "--no-history"]);
    assert!(
        err.contains("4 stations (S2, S3, S4, S1)")
            && err.contains("[[station]]")
            && err.contains("four.csv:3"),
        "{err}"
    );
    assert!(!err.contains("chain and reflector offsets"), "{err}");
    let one = dir.join("one.csv");
    std::fs::write(&one, with(&["T1"])).unwrap();
    let out = volver(&["identify", "--data", one.to_str().unwrap(), "--no-history"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Writes `sim`'s measurements as a tracker export: point names `P-R1-X-C-Z`, X, Y, Z in mm,
/// each row `copies` times; returns its path.
fn export(sim: &Path, name: &str, copies: usize) -> String {
    let text = std::fs::read_to_string(sim.join("measurements.csv")).unwrap();
    let mut out = String::from("Name,X,Y,Z\n");
    for l in text.lines().skip(1) {
        let c: Vec<&str> = l.split(',').collect();
        for _ in 0..copies {
            out.push_str(&format!(
                "P-{}-{}-{}-{},{},{},{}\n",
                c[3], c[0], c[1], c[2], c[4], c[5], c[6]
            ));
        }
    }
    let path = sim.join(name);
    std::fs::write(&path, out).unwrap();
    path.display().to_string()
}

/// Import profiles: repeated columns, copied rows and a wrong length unit are refused with the
/// place and what to do; a newline delimiter never dumps the export; CR-only exports with
/// skip_lines are read; a skip_lines beyond the file says so.
#[test]
fn import_profiles_refuse_what_they_cannot_interpret() {
    let dir = scratch("import");
    let sim = simulated(&dir);
    let ident = |d: &str, profile: &str| -> Vec<String> {
        [
            "identify",
            "--data",
            d,
            "--import",
            &data(profile),
            "--no-history",
        ]
        .map(String::from)
        .to_vec()
    };
    let run = |args: Vec<String>| refused(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let err = run(ident(
        &data("export-repeated-columns.csv"),
        "profile-mm.toml",
    ));
    assert!(
        err.contains("column 'X' appears 2 times") && err.contains("columns 2, 5"),
        "{err}"
    );
    let twice = export(&sim, "twice.csv", 2);
    let err = run(ident(&twice, "profile-mm.toml"));
    assert!(
        err.contains("twice.csv:3") && err.contains("repeats line 2"),
        "{err}"
    );
    let once = export(&sim, "once.csv", 1);
    let err = run(ident(&once, "profile-um.toml"));
    assert!(
        err.contains("look like mm") && err.contains("length_unit = \"mm\""),
        "{err}"
    );
    assert!(!err.contains("metres"), "{err}");
    let err = run(ident(&once, "profile-newline.toml"));
    assert!(err.contains("delimiter") && err.len() < 600, "{err}");
    // A title line, then the export with CR line ends only.
    let cr = sim.join("cr.csv");
    let text = std::fs::read_to_string(&once).unwrap();
    std::fs::write(
        &cr,
        format!("exported by a tracker\r\r{}", text.replace('\n', "\r")),
    )
    .unwrap();
    let out = volver(&["identify", "--data", cr.to_str().unwrap(), "--import"])
        .status
        .code();
    assert_eq!(out, Some(2), "clap wants the profile");
    let ok = volver(
        &ident(cr.to_str().unwrap(), "profile-skip2.toml")
            .iter()
            .map(String::as_str)
            .collect::<Vec<_>>(),
    );
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    let err = run(ident(&once, "profile-skip-huge.toml"));
    assert!(
        err.contains("skip_lines = 1000000") && err.contains("433 line(s)"),
        "{err}"
    );
    assert!(!err.contains("line 0"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A row filling both meas_x… and az_deg… is refused with both columns named.
#[test]
fn a_row_with_two_observations_is_refused() {
    let err = refused(&[
        "identify",
        "--data",
        &data("both-observations.csv"),
        "--no-history",
    ]);
    assert!(
        err.contains("both-observations.csv:2") && err.contains("'meas_x' and 'az_deg'"),
        "{err}"
    );
}

/// Results files: an emptied covariance record, and negative σ or held prior, are refused by
/// every reader of results (here tables), naming the field; deleting the record is accepted.
#[test]
fn emptied_or_negative_covariance_records_are_refused() {
    let dir = scratch("covariance");
    let sim = simulated(&dir);
    let fit = dir.join("fit.json");
    let out = volver(&[
        "identify",
        "--data",
        sim.join("measurements.csv").to_str().unwrap(),
        "--out",
        fit.to_str().unwrap(),
        "--no-history",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&fit).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let edited = |f: &dyn Fn(&mut serde_json::Value)| -> String {
        let mut j = json.clone();
        f(&mut j);
        let p = dir.join("edited.json");
        std::fs::write(&p, serde_json::to_string(&j).unwrap()).unwrap();
        p.display().to_string()
    };
    let tables = |results: &str| {
        let out = dir.join("tables").display().to_string();
        ["tables", "--results", results, "--out", &out, "--force"].map(String::from)
    };
    for (what, f) in [
        (
            "uncertainty.data_factor",
            Box::new(|j: &mut serde_json::Value| {
                j["uncertainty"]["data_factor"] = serde_json::json!([])
            }) as Box<dyn Fn(&mut serde_json::Value)>,
        ),
        (
            "uncertainty.sigma_mm",
            Box::new(|j: &mut serde_json::Value| {
                j["uncertainty"]["sigma_mm"] = serde_json::json!(-0.05)
            }),
        ),
        (
            "uncertainty.held_prior_mm",
            Box::new(|j: &mut serde_json::Value| {
                j["uncertainty"]["held_prior_mm"] = serde_json::json!(-5.0)
            }),
        ),
    ] {
        let path = edited(&*f);
        let args = tables(&path);
        let err = refused(&args.iter().map(String::as_str).collect::<Vec<_>>());
        assert!(err.contains(what), "{what}: {err}");
    }
    let without = edited(&|j| {
        j.as_object_mut().unwrap().remove("uncertainty");
    });
    let args = tables(&without);
    let out = volver(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(!text.contains("U up to 0.00"), "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Options that are accepted but meaningless are refused with the bound named: --per-axis 0
/// and 1, --hours 1e300, --step 1e300, a zero or tiny prior, repeated reflectors and empty
/// lists in --compare, a tiny ball-screw period (option and model file), a huge [fixed] value.
#[test]
fn meaningless_options_are_refused_with_the_bound() {
    let dir = scratch("options");
    let sim = simulated(&dir);
    let d = sim.join("measurements.csv").display().to_string();
    let out = dir.join("p.csv").display().to_string();
    let truth = sim.join("truth.json").display().to_string();
    let t = dir.join("t").display().to_string();
    let bs = dir.join("bs").display().to_string();
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec!["plan", "--per-axis", "0", "--out", &out],
            "--per-axis 0: at least 2",
        ),
        (
            vec!["plan", "--per-axis", "1", "--out", &out],
            "--per-axis 1: at least 2",
        ),
        (
            vec!["plan", "--hours", "1e300", "--out", &out],
            "1 … 1000000",
        ),
        (
            vec![
                "tables",
                "--results",
                &truth,
                "--out",
                &t,
                "--step",
                "1e300",
            ],
            "a step of 1e300 mm exceeds",
        ),
        (
            vec![
                "identify",
                "--data",
                &d,
                "--no-history",
                "--prior",
                "angular=0",
            ],
            "angular=flat",
        ),
        (
            vec![
                "identify",
                "--data",
                &d,
                "--no-history",
                "--prior",
                "angular=1e-300",
            ],
            "1e-300 µrad is outside",
        ),
        (
            vec!["plan", "--compare", "test4/R1+R1"],
            "R1 is named twice",
        ),
        (vec!["plan", "--compare", ","], "no plan named"),
        (
            vec![
                "simulate",
                "--effect",
                "ball-screw=X,1e-300,3",
                "--out",
                &bs,
            ],
            "1e-300 mm is outside",
        ),
    ];
    for (args, what) in &cases {
        let err = refused(args);
        assert!(err.contains(what), "{args:?}: {err}");
        assert!(err.len() < 600, "{args:?}: {err}");
    }
    assert!(!dir.join("p.csv").exists() && !dir.join("bs").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// Model files beyond their bounds: a [fixed] value of 1e300 gets its own message (not the
/// scale check's), a ball-screw period of 1e-300 mm is refused naming the field.
#[test]
fn model_values_beyond_their_bounds_are_refused() {
    let dir = scratch("models");
    let sim = simulated(&dir);
    let d = sim.join("measurements.csv").display().to_string();
    let fixed = data("model-fixed-huge.toml");
    let err = refused(&["identify", "--data", &d, "--model", &fixed, "--no-history"]);
    assert!(
        err.contains("fixed.EXX.c1") && err.contains("1e300"),
        "{err}"
    );
    assert!(!err.contains("spread"), "the scale check's text: {err}");
    let screw = data("model-screw-tiny.toml");
    let err = refused(&["identify", "--data", &d, "--model", &screw, "--no-history"]);
    assert!(err.contains("period_mm") && err.contains("1e-300"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// One torn line of a history leaves the other records readable, and is named.
#[test]
fn a_torn_history_line_is_skipped_and_named() {
    let out = volver(&["history", "--file", &data("history-torn.jsonl")]);
    let (text, err) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert!(out.status.success(), "{err}");
    assert!(
        text.contains("2 fits") && text.contains("raise-axis:C"),
        "{text}"
    );
    assert!(err.contains("line(s) 2 skipped"), "{err}");
}

/// Byte-order marks are stripped from plan files and point lists as from measurement files.
#[test]
fn byte_order_marks_are_not_column_names() {
    let dir = scratch("bom");
    let out = volver(&[
        "simulate",
        "--plan-file",
        &data("plan-bom.csv"),
        "--out",
        dir.join("sim").to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(data("points-bom.csv")).unwrap();
    let m = volver::core::machine::Machine::default_xcfz();
    let points = volver::core::compensate::read_points(&text, "points-bom.csv", &m).unwrap();
    assert_eq!(points.len(), 2);
    let _ = std::fs::remove_dir_all(&dir);
}

/// With RUST_BACKTRACE=1 (as many Rust users have it) a user error prints its message and no
/// stack backtrace; the exit status stays 1.
#[test]
fn user_errors_print_no_backtrace() {
    for backtrace in ["1", "full"] {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_volver"))
            .args(["identify", "--data", "no-such-file.csv", "--no-history"])
            .env("RUST_BACKTRACE", backtrace)
            .env("RUST_LIB_BACKTRACE", backtrace)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1));
        assert!(err.starts_with("Error: reading the measurements"), "{err}");
        assert!(err.contains("no-such-file.csv"), "{err}");
        assert!(!err.to_lowercase().contains("backtrace"), "{err}");
    }
}

/// Found by the red-team pass after issue 43: a station count that exhausts memory, an effect
/// of 1e300 µm written with exit 0 (and then a 300-digit number in the reader's message), a
/// measuring time per point below the waits' resolution, and CR-only plan and point files read
/// as one line.
#[test]
fn red_team_findings_are_refused_or_read() {
    let dir = scratch("red-team");
    let d = |n: &str| dir.join(n).display().to_string();
    let e = refused(&[
        "simulate",
        "--plan",
        "test4",
        "--stations",
        "100000",
        "--out",
        &d("s"),
    ]);
    assert!(e.contains("at most 1000 stations"), "{e}");
    let e = refused(&[
        "simulate",
        "--plan",
        "test4",
        "--effect",
        "ball-screw=X,10,1e300",
        "--out",
        &d("s"),
    ]);
    assert!(e.contains("1e300") && !e.contains("000000000000"), "{e}");
    let e = refused(&[
        "plan",
        "--points",
        "60",
        "--seconds-per-point",
        "0.0004",
        "--out",
        &d("p.csv"),
        "--gcode",
        &d("p.nc"),
    ]);
    assert!(
        e.contains("seconds_per_point") || e.contains("seconds-per-point"),
        "{e}"
    );
    // CR-only line ends: a plan file and a point list read as their lines.
    let sim = simulated(&dir);
    std::fs::write(
        d("cr.csv"),
        "order,X,C,Z,reflector\r1,100,0,0,R1\r2,700,90,300,R2\r",
    )
    .unwrap();
    let out = volver(&[
        "simulate",
        "--plan-file",
        &d("cr.csv"),
        "--out",
        &d("crsim"),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::fs::write(d("pts.csv"), "id,X,C,Z\rp1,100,0,100\rp2,700,90,300\r").unwrap();
    let out = volver(&[
        "compensate",
        "--results",
        &format!("{}/truth.json", sim.display()),
        "--points",
        &d("pts.csv"),
        "--out",
        &d("pts-comp.csv"),
        "--force", // a simulation's truth carries no uncertainty
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(d("pts-comp.csv")).unwrap();
    assert_eq!(text.lines().count(), 3, "{text}");
}
