//! One noise source (issue 44, item 5), through the binary: `simulate` uses the machine file's
//! `[tracker] noise` unless `--noise` is given (and then says both), its three files state the
//! same noise, and `identify --truth` names the field where the truth's machine differs.

mod common;
use common::volver;

use std::path::{Path, PathBuf};
use volver::core::noise::TrackerNoise;

/// A small FYXZ gantry whose machine file states the tracker's noise as `mpe:15,6`.
const GANTRY: &str = r#"name = "FYXZ gantry"
chain = "FYXZ"
[axes.Y]
range = [0.0, 2000.0]
[axes.X]
range = [0.0, 3000.0]
[axes.Z]
range = [0.0, 800.0]
offset = [0.0, 0.0, 1200.0]
[[reflector]]
id = "R1"
offset = [0.0, 0.0, -150.0]
[[reflector]]
id = "R2"
offset = [80.0, 0.0, -250.0]
[tracker]
mount = "workpiece"
position = [1500.0, 1000.0, 0.0]
noise = "mpe:15,6"
"#;

/// A fresh folder with the gantry's machine file, named after `name`.
fn folder(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("volver-noise-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("gantry.toml"), GANTRY).unwrap();
    dir
}

/// `volver simulate` of the gantry into `dir/sim` with `extra` arguments; its standard output.
fn simulate(dir: &Path, extra: &[&str]) -> String {
    let (machine, out) = (dir.join("gantry.toml"), dir.join("sim"));
    let mut args = vec![
        "simulate",
        "--machine",
        machine.to_str().unwrap(),
        "--plan",
        "X=0:3000:1000,Y=0:2000:1000,Z=0:800:400",
        "--seed",
        "3",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let o = volver(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8(o.stdout).unwrap()
}

/// The noise each file written by `simulate` into `dir/sim` states: simulation.json's,
/// machine.toml's `[tracker] noise`, truth.json's machine's.
fn stated(dir: &Path) -> [TrackerNoise; 3] {
    let sim = dir.join("sim");
    let read = |f: &str| std::fs::read_to_string(sim.join(f)).unwrap();
    let record: serde_json::Value = serde_json::from_str(&read("simulation.json")).unwrap();
    let record: TrackerNoise = serde_json::from_value(record["noise"].clone()).unwrap();
    let machine: toml::Value = toml::from_str(&read("machine.toml")).unwrap();
    let machine = TrackerNoise::from_text(machine["tracker"]["noise"].as_str().unwrap()).unwrap();
    let truth: serde_json::Value = serde_json::from_str(&read("truth.json")).unwrap();
    let truth =
        TrackerNoise::from_text(truth["machine"]["tracker"]["noise"].as_str().unwrap()).unwrap();
    [record, machine, truth]
}

#[test]
fn simulate_uses_the_machine_files_noise_and_its_files_agree() {
    let dir = folder("file");
    let text = simulate(&dir, &[]);
    assert!(
        text.contains("from the machine file's [tracker] noise"),
        "the output says where the noise comes from:\n{text}"
    );
    let want = TrackerNoise::from_text("mpe:15,6").unwrap();
    for (file, n) in ["simulation.json", "machine.toml", "truth.json"]
        .iter()
        .zip(stated(&dir))
    {
        assert_eq!(n, want, "{file} states the machine file's noise");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_explicit_noise_wins_says_both_and_every_file_states_it() {
    let dir = folder("given");
    let text = simulate(&dir, &["--noise", "paper"]);
    assert!(
        text.contains("from --noise, over the machine file's [tracker] noise"),
        "the output names both noises:\n{text}"
    );
    for (file, n) in ["simulation.json", "machine.toml", "truth.json"]
        .iter()
        .zip(stated(&dir))
    {
        assert_eq!(n, TrackerNoise::PAPER, "{file} states --noise");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_truths_machine_agrees_and_a_different_one_is_named_by_its_field() {
    let dir = folder("truth");
    simulate(&dir, &[]);
    let sim = dir.join("sim");
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/mill/cubic.toml");
    let identify = |machine: &Path| {
        volver(&[
            "identify",
            "--machine",
            machine.to_str().unwrap(),
            "--model",
            model.to_str().unwrap(),
            "--data",
            sim.join("measurements.csv").to_str().unwrap(),
            "--truth",
            sim.join("truth.json").to_str().unwrap(),
            "--no-history",
            "--accept",
        ])
    };
    // The files simulate wrote belong together, and the original machine file (its noise as
    // written, mpe:15,6) is the same machine.
    for machine in [sim.join("machine.toml"), dir.join("gantry.toml")] {
        let o = identify(&machine);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let other = dir.join("longer.toml");
    std::fs::write(
        &other,
        GANTRY.replace("range = [0.0, 3000.0]", "range = [0.0, 3100.0]"),
    )
    .unwrap();
    let o = identify(&other);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("axes.X.range: [0.0,3000.0] against [0.0,3100.0]"),
        "the message names the field and both values: {err}"
    );
    // `simulate --truth` with a machine file: a different geometry is named the same way; the
    // same geometry with another noise is accepted, and that file's noise is simulated and
    // stated by every file written.
    let again = |machine: &Path, out: &Path| {
        volver(&[
            "simulate",
            "--machine",
            machine.to_str().unwrap(),
            "--truth",
            sim.join("truth.json").to_str().unwrap(),
            "--plan",
            "X=0:3000:1000,Y=0:2000:1000,Z=0:800:400",
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let o = again(&other, &dir.join("other"));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("axes.X.range"), "{err}");
    let noisier = dir.join("noisier.toml");
    std::fs::write(&noisier, GANTRY.replace("mpe:15,6", "mpe:30,6")).unwrap();
    let re = dir.join("re");
    let o = again(&noisier, &re.join("sim"));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let want = TrackerNoise::from_text("mpe:30,6").unwrap();
    assert_eq!(
        stated(&re),
        [want; 3],
        "the noise of --machine, in every file"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A small error model for the gantry: quadratic positioning errors and the squareness.
const SMALL_MODEL: &str = r#"name = "positioning and squareness"
squareness = "separate"
[[error]]
name = ["EXX", "EYY", "EZZ"]
basis = "legendre"
degree = 2
[[error]]
name = ["A0Z", "B0Z", "C0Y"]
"#;

#[test]
fn identify_and_uncertainty_say_which_noise_they_used() {
    let dir = folder("used");
    simulate(&dir, &[]);
    std::fs::write(dir.join("model.toml"), SMALL_MODEL).unwrap();
    let (machine, model) = (dir.join("gantry.toml"), dir.join("model.toml"));
    let data = dir.join("sim/measurements.csv");
    let run = |command: &str, extra: &[&str]| {
        let mut args = vec![
            command,
            "--machine",
            machine.to_str().unwrap(),
            "--model",
            model.to_str().unwrap(),
            "--data",
            data.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let o = volver(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8(o.stdout).unwrap()
    };
    let file_noise = TrackerNoise::from_text("mpe:15,6").unwrap();
    // identify --json: the machine file's noise, stated with its source.
    let json: serde_json::Value =
        serde_json::from_str(&run("identify", &["--no-history", "--accept", "--json"])).unwrap();
    let used = &json["noise_used"];
    assert_eq!(
        used["source"], "the machine file's [tracker] noise",
        "{used}"
    );
    assert_eq!(used["model"], format!("tracker {file_noise}"), "{used}");
    // identify with --noise: it wins, and the statement names the file's too.
    let text = run(
        "identify",
        &["--no-history", "--accept", "--noise", "paper"],
    );
    assert!(
        text.contains(&format!(
            "  noise: tracker {}, from --noise, over the machine file's [tracker] noise {file_noise}",
            TrackerNoise::PAPER
        )),
        "{text}"
    );
    // uncertainty, text and --json.
    let text = run("uncertainty", &[]);
    assert!(
        text.contains(&format!(
            "  noise: tracker {file_noise}, from the machine file's [tracker] noise"
        )),
        "{text}"
    );
    let json: serde_json::Value = serde_json::from_str(&run("uncertainty", &["--json"])).unwrap();
    assert_eq!(
        json["noise_used"]["source"], "the machine file's [tracker] noise",
        "{json}"
    );
    // compensate states the noise of the U it vouches with, as identify recorded it.
    let fit = dir.join("fit.json");
    run(
        "identify",
        &["--no-history", "--accept", "--out", fit.to_str().unwrap()],
    );
    let points = dir.join("points.csv");
    std::fs::write(
        &points,
        "id,Y,X,Z
a,1000,1500,400
",
    )
    .unwrap();
    let o = volver(&[
        "compensate",
        "--results",
        fit.to_str().unwrap(),
        "--points",
        points.to_str().unwrap(),
        "--out",
        dir.join("corrected.csv").to_str().unwrap(),
        "--force",
    ]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success() && text.contains(&format!("noise: tracker {file_noise}, as the fit")),
        "{text}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let _ = std::fs::remove_dir_all(&dir);
}
