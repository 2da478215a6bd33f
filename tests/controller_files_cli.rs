//! `volver tables --format …` end to end (issue 47, item 4): a hand-set model of the XCFZ
//! grinder whose per-axis tables are known by hand — a positioning error of X and of Z, a
//! straightness of Z along x and a pitch of Z with the tool 200 mm below Z's frame (its Abbe
//! offset) — is identified nowhere: its results file goes through `volver tables`, and each
//! controller file is re-read by a reader written from that control's rules
//! (`common::controllers`: LinuxCNC's `usrmotintf.cc` / `control.c`, SINUMERIK K3). The
//! correction each control then adds to each axis' command must be the hand value.
//!
//! Hand values (mm; x, z in mm; references 0; X carries the workpiece, Z the tool):
//! - EXX(x) = 1.5e-5·x: X moves the workpiece, so its command corrects by +EXX (commanding X
//!   by c moves the tool relative to the workpiece by +c);
//! - EZZ(z) = −2e-5·z: Z moves the tool, so its command corrects by −EZZ;
//! - EXZ(z) = 0.008·((2z/600 − 1)² − 1): the tool moves by +EXZ along x, corrected by X's
//!   command by −EXZ (a cross-axis table Z → X);
//! - EBZ(z) = 4e-5·z/600 rad about y, tool at (0, 0, −200) mm in Z's frame: ISO 230-1's
//!   right-hand turn moves the tool by EBZ·(e_y × (0, 0, −200)) = −200·EBZ along x, corrected by
//!   X's command by +200·EBZ (the same cross-axis table).
//!
//! So LinuxCNC (leadscrew tables only) gets X: +EXX(x) and Z: −EZZ(z), and cannot carry the
//! rest; Siemens with cross-axis tables gets X: +EXX(x) from LEC plus −EXZ(z) + 200·EBZ(z) from
//! the CEC table Z → X, and Z: −EZZ(z).

mod common;

use common::controllers::{LinuxCncJoint, lec_correction, parse_siemens, siemens_cec, siemens_lec};
use common::volver;
use std::collections::BTreeMap;
use volver::core::machine::Machine;
use volver::core::model::Model;
use volver::core::results::ResultsFile;

const MODEL: &str = r#"
name = "hand-set per-axis tables"
squareness = "none"
[[error]]
name = ["EXX", "EZZ", "EBZ"]
basis = "monomial"
degree = 1
[[error]]
name = "EXZ"
basis = "monomial"
degree = 2
"#;

fn exx(x: f64) -> f64 {
    1.5e-5 * x
}
fn ezz(z: f64) -> f64 {
    -2e-5 * z
}
fn exz(z: f64) -> f64 {
    let xi = 2.0 * z / 600.0 - 1.0;
    0.008 * (xi * xi - 1.0)
}
fn ebz(z: f64) -> f64 {
    4e-5 * z / 600.0
}

/// The results file of the hand-set model in a fresh folder; without `cross`, EXZ and EBZ are
/// zero (leadscrew tables alone can then carry the whole error: with them, the leadscrew
/// projection of X also takes the part of their x error that is the same over Z, from its first
/// position on, its value at the reference being held at zero).
fn hand_set(tag: &str, cross: bool) -> std::path::PathBuf {
    let d = common::scratch_dir("controller-files", tag);
    let model = Model::from_toml_str(Machine::default_xcfz(), MODEL, "hand.toml").unwrap();
    let mut p = model.initial_params();
    let mut set = |n: &str, v: f64| p[model.param_index(n).unwrap()] = v;
    // Monomials of ξ = 2u/L − 1 (ξ = −1 at the reference): c0 = c1 puts a line through zero.
    set("EXX.c0", 0.0105);
    set("EXX.c1", 0.0105); // 1.5e-5 × 1400 / 2
    set("EZZ.c0", -0.006);
    set("EZZ.c1", -0.006); // −2e-5 × 600 / 2
    set("EBZ.c0", 20e-6);
    set("EBZ.c1", 20e-6); // 4e-5 / 2 rad
    if cross {
        set("EXZ.c0", -0.008);
        set("EXZ.c2", 0.008);
    } else {
        set("EBZ.c0", 0.0);
        set("EBZ.c1", 0.0);
    }
    ResultsFile::from_model(&model, &p)
        .unwrap()
        .save(&d.join("hand.json"))
        .unwrap();
    d
}

fn tables(d: &std::path::Path, format: &str) -> std::process::Output {
    let s = |p: &str| d.join(p).display().to_string();
    volver(&[
        "tables",
        "--results",
        &s("hand.json"),
        "--out",
        &s("out"),
        "--format",
        format,
        "--step",
        "50",
        "--rotary-step",
        "30",
        "--tool-offset",
        "0,0,-200",
        "--force",
    ])
}

fn read(d: &std::path::Path, name: &str) -> String {
    std::fs::read_to_string(d.join("out").join(name)).unwrap_or_else(|e| panic!("{name}: {e}"))
}

fn close(got: f64, want: f64, what: &str) {
    // 1 nm: the projection is exact at the tables' positions for errors that are sums of
    // functions of one axis; LinuxCNC keeps its trims as float (7 digits of 0.03 mm).
    assert!(
        (got - want).abs() < 1e-6,
        "{what}: {got} mm, by hand {want} mm"
    );
}

#[test]
fn linuxcnc_files_carry_the_hand_set_leadscrew_corrections() {
    let d = hand_set("linuxcnc", false);
    let o = tables(&d, "linuxcnc");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ini = read(&d, "linuxcnc-ini.txt");
    assert!(ini.contains("COMP_FILE = compX.txt") && ini.contains("COMP_FILE_TYPE = 1"));
    let (mut x, mut z) = (
        LinuxCncJoint::load(&read(&d, "compX.txt"), 1),
        LinuxCncJoint::load(&read(&d, "compZ.txt"), 1),
    );
    assert!(x.refused.is_empty() && z.refused.is_empty());
    for i in 0..=28 {
        let p = 50.0 * i as f64;
        for v in [1.0, -1.0] {
            close(x.trim(p, v), exx(p), &format!("LinuxCNC X at {p}"));
        }
    }
    for i in 0..=12 {
        let p = 50.0 * i as f64;
        close(z.trim(p, 1.0), -ezz(p), &format!("LinuxCNC Z at {p}"));
    }
    // Nothing else written: the other formats were not asked for.
    assert!(!d.join("out/errors-isg.csv").exists());
    assert!(!d.join("out/siemens-cec-NC_CEC.INI").exists());
}

#[test]
fn siemens_files_carry_the_hand_set_leadscrew_and_cross_axis_corrections() {
    // Leadscrew tables alone, on the model they can carry whole: LEC only (no direction, no
    // cross-axis table: no CEC file).
    let d = hand_set("siemens-lec", false);
    let o = tables(&d, "siemens-lec");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let lec = siemens_lec(
        &parse_siemens(&read(&d, "siemens-lec-AX_EEC.INI")).unwrap(),
        0,
        200,
    )
    .unwrap();
    assert!(!d.join("out/siemens-lec-NC_CEC.INI").exists());
    let d = hand_set("siemens-cec", true);
    let o = tables(&d, "siemens-cec");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // The joint projection: LEC + CEC, loaded together.
    let joint = siemens_lec(
        &parse_siemens(&read(&d, "siemens-cec-AX_EEC.INI")).unwrap(),
        0,
        200,
    )
    .unwrap();
    let cec = siemens_cec(
        &parse_siemens(&read(&d, "siemens-cec-NC_CEC.INI")).unwrap(),
        200,
    )
    .unwrap();
    for i in 0..=28 {
        for j in 0..=12 {
            let (x, z) = (50.0 * i as f64, 50.0 * j as f64);
            let at: BTreeMap<String, f64> = [("X1", x), ("C1", 90.0), ("Z1", z)]
                .into_iter()
                .map(|(k, v)| (k.to_string(), v))
                .collect();
            let moving: BTreeMap<String, i8> = at
                .keys()
                .map(|k| (k.clone(), 1))
                .collect::<BTreeMap<_, _>>();
            close(lec_correction(&lec, "X1", x), exx(x), "LEC alone, X");
            close(lec_correction(&lec, "Z1", z), -ezz(z), "LEC alone, Z");
            let want_x = exx(x) - exz(z) + 200.0 * ebz(z);
            let got_x = lec_correction(&joint, "X1", x) + cec.correction("X1", &at, &moving, -1.0);
            close(got_x, want_x, &format!("LEC + CEC, X at x = {x}, z = {z}"));
            let got_z = lec_correction(&joint, "Z1", z) + cec.correction("Z1", &at, &moving, -1.0);
            close(got_z, -ezz(z), &format!("LEC + CEC, Z at z = {z}"));
        }
    }
}

/// A control format named in --format whose limits the tables exceed is an error naming the
/// limit and the step that fits, and nothing is written; left to the default, it is skipped
/// with a warning and the rest is written.
#[test]
fn a_control_limit_refuses_a_named_format_and_skips_a_default_one() {
    let d = hand_set("limits", true);
    let s = |p: &str| d.join(p).display().to_string();
    let run = |format: Option<&str>| {
        let mut args = vec![
            "tables".to_string(),
            "--results".into(),
            s("hand.json"),
            "--out".into(),
            s("out"),
            "--step".into(),
            "5".into(), // 281 positions over X's 1400 mm: more than 256 and 200
            "--force".into(),
        ];
        if let Some(f) = format {
            args.extend(["--format".to_string(), f.to_string()]);
        }
        let refs: Vec<&str> = args.iter().map(String::as_str).collect();
        volver(&refs)
    };
    let o = run(Some("isg,linuxcnc"));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("--format linuxcnc") && err.contains("256"),
        "{err}"
    );
    assert!(
        !d.join("out/errors-isg.csv").exists(),
        "written before the refusal"
    );
    let o = run(None);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in ["linuxcnc", "siemens-lec", "siemens-cec"] {
        assert!(
            out.contains(&format!("warning: {f} not written")),
            "{f}: {out}"
        );
    }
    assert!(d.join("out/errors-isg.csv").exists());
    assert!(!d.join("out/compX.txt").exists());
    let bad = run(Some("fanuc"));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("not a format"));
}

/// An axis whose reference is not on a round position (X at 705 mm of 0 … 1 400): the tables
/// keep the step asked for (141 positions every 10 mm, the reference between 700 and 710 with
/// the interpolated correction zero there) rather than a 5 mm spacing through the reference
/// (281 positions, more than either control takes), and the controls' readers give back the
/// hand correction EXX(x) = 1.5e-5·(x − 705) at every position.
#[test]
fn a_reference_between_table_positions_keeps_the_step_and_the_controls_take_the_tables() {
    let d = common::scratch_dir("controller-files", "reference");
    let text = volver::core::presets::named("xcfz")
        .unwrap()
        .machine_toml
        .replacen("reference = 0.0", "reference = 705.0", 1);
    let machine = Machine::from_toml_str(&text, "m.toml").unwrap();
    let model = Model::from_toml_str(machine, MODEL, "hand.toml").unwrap();
    let mut p = model.initial_params();
    // EXX = c0 + c1·ξ, ξ = 2x/1400 − 1: zero at 705 mm (ξ = 0.00714…).
    let c1 = 1.5e-5 * 700.0;
    p[model.param_index("EXX.c1").unwrap()] = c1;
    p[model.param_index("EXX.c0").unwrap()] = -c1 * (2.0 * 705.0 / 1400.0 - 1.0);
    ResultsFile::from_model(&model, &p)
        .unwrap()
        .save(&d.join("hand.json"))
        .unwrap();
    let s = |f: &str| d.join(f).display().to_string();
    let o = volver(&[
        "tables",
        "--results",
        &s("hand.json"),
        "--out",
        &s("out"),
        "--format",
        "linuxcnc,siemens-lec",
        "--force",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = read(&d, "compX.txt");
    assert_eq!(text.lines().count(), 141, "{text}");
    let mut x = LinuxCncJoint::load(&text, 1);
    let lec = siemens_lec(
        &parse_siemens(&read(&d, "siemens-lec-AX_EEC.INI")).unwrap(),
        0,
        200,
    )
    .unwrap();
    for i in 0..=140 {
        let p = 10.0 * i as f64;
        let want = 1.5e-5 * (p - 705.0);
        close(x.trim(p, 1.0), want, &format!("LinuxCNC X at {p}"));
        close(
            lec_correction(&lec, "X1", p),
            want,
            &format!("Siemens X at {p}"),
        );
    }
    close(
        lec_correction(&lec, "X1", 705.0),
        0.0,
        "Siemens X at the reference",
    );
}

/// Siemens axis names are identifiers, each axis and each name once, and the limits at least
/// one table of two points: anything else is refused before a file is written.
#[test]
fn bad_siemens_options_are_refused_before_anything_is_written() {
    let d = hand_set("siemens-options", false);
    let s = |p: &str| d.join(p).display().to_string();
    for (flag, value, says) in [
        ("--siemens-axes", "X=AX1;C=AX4", "not a Siemens axis name"),
        ("--siemens-axes", "X=AX1,C=AX1", "given twice"),
        ("--siemens-axes", "X=AX1,X=AX2", "given twice"),
        ("--siemens-axes", "Y=AX2", "not an axis of the machine"),
        ("--siemens-max-points", "1", "at least 2 points"),
        ("--siemens-max-tables", "0", "at least 1 table"),
    ] {
        let o = volver(&[
            "tables",
            "--results",
            &s("hand.json"),
            "--out",
            &s("out"),
            "--force",
            flag,
            value,
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            !o.status.success() && err.contains(says),
            "{flag} {value}: {err}"
        );
        assert!(!d.join("out").exists(), "{flag} {value}: wrote files");
    }
}
