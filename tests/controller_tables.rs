//! LinuxCNC and Siemens compensation files (issue 47, items 1 and 4): hand-set per-axis
//! corrections → volver's writer → a reader written from the control's rules
//! (`common::controllers`) → the correction the control then adds to the axis' command, which
//! must equal the hand value at the table's points and the hand chord between them. Bad tables
//! are refused with messages naming the table; the readers show why (a header line disables
//! LinuxCNC's compensation, the 257th line is refused).

mod common;

use common::controllers::{
    LinuxCncJoint, lec_correction, parse_siemens, siemens_cec as read_cec, siemens_lec as read_lec,
};
use std::collections::BTreeMap;
use volver::core::iso::Axis;
use volver::core::machine::Machine;
use volver::core::tables::linuxcnc::linuxcnc_files;
use volver::core::tables::per_axis::{AxisCorrection, Family, PerAxisTables};
use volver::core::tables::siemens::{
    CecSign, SiemensOptions, siemens_cec, siemens_cec_with, siemens_lec, siemens_lec_with,
};

/// A four-axis machine: X −100 … 900, Y 0 … 500, Z 0 … 400 mm, C 0 … 360°, references 0.
fn machine() -> Machine {
    Machine::from_toml_str(&machine_text(), "test.toml").expect("test machine")
}

fn machine_text() -> String {
    r#"
name = "test"
chain = "CYFXZ"
[axes.X]
range = [-100.0, 900.0]
[axes.Y]
range = [0.0, 500.0]
[axes.Z]
range = [0.0, 400.0]
[axes.C]
range = [0.0, 360.0]
[[reflector]]
id = "R1"
offset = [0.0, 0.0, 0.0]
[tracker]
"#
    .to_string()
}

/// The table of `output` over `input` at `positions`, forward `f` and reverse `r` by hand.
fn table(
    input: Axis,
    output: Axis,
    positions: Vec<f64>,
    f: impl Fn(f64) -> f64,
    r: impl Fn(f64) -> f64,
) -> AxisCorrection {
    AxisCorrection {
        input,
        output,
        forward: positions.iter().map(|&p| f(p)).collect(),
        reverse: positions.iter().map(|&p| r(p)).collect(),
        positions,
    }
}

fn grid(lo: f64, hi: f64, step: f64) -> Vec<f64> {
    let n = ((hi - lo) / step).round() as usize;
    (0..=n).map(|i| lo + step * i as f64).collect()
}

fn tables(family: Family, tables: Vec<AxisCorrection>) -> PerAxisTables {
    PerAxisTables {
        family,
        tools: vec![[0.0; 3]],
        tables,
    }
}

/// X's positioning correction by hand: −10 µm per metre from the reference X = 0.
fn x_positioning(x: f64) -> f64 {
    -1.0e-5 * x
}

/// Y's straightness correction along X by hand: k·x·(800 − x), zero at X = 0 and 800, 4 µm at
/// 400 mm; a chord between points of spacing Δ lies k·h·(Δ − h) below it at h from a point.
const K: f64 = 2.5e-8;
fn y_straightness(x: f64) -> f64 {
    K * x * (800.0 - x)
}

/// C's positioning correction by hand (degrees): 0.001° · sin θ, periodic.
fn c_positioning(theta: f64) -> f64 {
    1.0e-3 * theta.to_radians().sin()
}

/// Z's correction by hand: −20 µm/m mean, forward +2 µm, reverse −2 µm (a 4 µm reversal).
fn z_forward(z: f64) -> f64 {
    -2.0e-5 * z + 0.002
}
fn z_reverse(z: f64) -> f64 {
    -2.0e-5 * z - 0.002
}

fn close(a: f64, b: f64, tol: f64, what: &str) {
    assert!((a - b).abs() <= tol, "{what}: {a} against {b}");
}

#[test]
fn linuxcnc_applies_the_hand_corrections_at_points_between_them_beyond_the_ends_and_by_direction() {
    let t = tables(Family::Leadscrew, leadscrew_by_hand());
    let files = linuxcnc_files(&t, &machine()).unwrap();
    assert_eq!(files.len(), 3);
    assert!(
        files[0]
            .ini_lines()
            .contains("COMP_FILE = compX.txt\nCOMP_FILE_TYPE = 1\n")
    );
    let mut x = LinuxCncJoint::load(&files[0].text, files[0].comp_file_type);
    assert_eq!((x.kept(), x.refused.len()), (101, 0));
    // Linear: the control's interpolation gives the hand value anywhere on the table.
    for p in [-100.0, -95.0, 0.0, 3.7, 450.0, 899.0, 900.0] {
        close(
            x.trim(p, 1.0),
            x_positioning(p),
            1e-9,
            "X at a point or between",
        );
        close(x.trim(p, -1.0), x_positioning(p), 1e-9, "X reverse");
    }
    close(
        x.trim(-150.0, 1.0),
        x_positioning(-100.0),
        1e-9,
        "held below",
    );
    close(
        x.trim(1000.0, 1.0),
        x_positioning(900.0),
        1e-9,
        "held above",
    );
    let mut z = LinuxCncJoint::load(&files[1].text, 1);
    for p in [0.0, 12.5, 100.0, 387.0] {
        close(z.trim(p, 1.0), z_forward(p), 1e-9, "Z forward");
        close(z.trim(p, -1.0), z_reverse(p), 1e-9, "Z reverse");
    }
    // Standing still, LinuxCNC keeps the last correction (here arriving in reverse at 387).
    close(
        z.trim(387.0, 0.0),
        z_reverse(387.0),
        1e-9,
        "stopped: the last correction",
    );
    let mut c = LinuxCncJoint::load(&files[2].text, 1);
    for p in [0.0, 10.0, 90.0, 350.0] {
        close(
            c.trim(p, 1.0),
            c_positioning(p),
            1e-9,
            "C at its points (degrees)",
        );
    }
    let chord = (c_positioning(90.0) + c_positioning(100.0)) / 2.0;
    close(
        c.trim(95.0, 1.0),
        chord,
        1e-9,
        "C between points: the chord",
    );
    // No modulo in LinuxCNC: past 360° the last value is held, not the value at 10°.
    close(
        c.trim(370.0, 1.0),
        c_positioning(360.0),
        1e-9,
        "C held past 360°",
    );
}

#[test]
fn linuxcnc_type_matters_and_the_file_has_no_header_because_a_header_disables_compensation() {
    let t = tables(
        Family::Leadscrew,
        vec![table(
            Axis::X,
            Axis::X,
            grid(-100.0, 900.0, 10.0),
            x_positioning,
            x_positioning,
        )],
    );
    let f = &linuxcnc_files(&t, &machine()).unwrap()[0];
    assert!(f.text.lines().all(|l| l.split(' ').count() == 3));
    // Read as type 0 (COMP_FILE_TYPE left out) the trims become nominal − value: wrong.
    let mut as_type0 = LinuxCncJoint::load(&f.text, 0);
    // (stored as a float: 500 mm to 6e-5 mm)
    close(
        as_type0.trim(500.0, 1.0),
        500.0 - x_positioning(500.0),
        1e-4,
        "type 0",
    );
    // A header line stops LinuxCNC's reader at once: no compensation at all.
    let mut headed = LinuxCncJoint::load(&format!("# X compensation\n{}", f.text), 1);
    assert_eq!(headed.kept(), 0);
    assert_eq!(headed.trim(500.0, 1.0), 0.0);
    // A comment line in the middle drops everything after it (the end of X's travel).
    let lines: Vec<&str> = f.text.lines().collect();
    let cut = format!(
        "{}\n; comment\n{}\n",
        lines[..51].join("\n"),
        lines[51..].join("\n")
    );
    let mut half = LinuxCncJoint::load(&cut, 1);
    assert_eq!(half.kept(), 51);
    close(
        half.trim(800.0, 1.0),
        x_positioning(400.0),
        1e-9,
        "held from X = 400",
    );
    // So does a blank line, and commas (sscanf reads one number).
    assert_eq!(LinuxCncJoint::load(&format!("\n{}", f.text), 1).kept(), 0);
    assert_eq!(LinuxCncJoint::load("0,0,0\n10,0,0\n", 1).kept(), 0);
}

#[test]
fn linuxcnc_limits_are_refused_by_the_writer_and_by_the_control() {
    let m = machine();
    // 257 points over X's travel: the writer refuses and says which step fits.
    let p257 = grid(-100.0, 156.0, 1.0);
    assert_eq!(p257.len(), 257);
    let t = tables(
        Family::Leadscrew,
        vec![table(
            Axis::X,
            Axis::X,
            p257.clone(),
            x_positioning,
            x_positioning,
        )],
    );
    let e = linuxcnc_files(&t, &m).unwrap_err().to_string();
    assert!(e.contains("257 points") && e.contains("at most 256"), "{e}");
    assert!(e.contains("a step of at least 1.004 mm"), "{e}");
    // The control keeps 256 entries and refuses the 257th.
    let text: String = p257.iter().map(|p| format!("{p} 0 0\n")).collect();
    let j = LinuxCncJoint::load(&text, 1);
    assert_eq!(
        (j.kept(), j.refused.as_slice()),
        (256, &["too many compensation entries".to_string()][..])
    );
    // Positions not ascending: refused by the writer; the control skips the entry.
    let mut bad = table(
        Axis::X,
        Axis::X,
        vec![0.0, 20.0, 10.0],
        x_positioning,
        x_positioning,
    );
    let e = linuxcnc_files(&tables(Family::Leadscrew, vec![bad.clone()]), &m).unwrap_err();
    assert!(
        e.to_string().contains("position 10 does not follow 20"),
        "{e}"
    );
    let j = LinuxCncJoint::load("0 0 0\n20 0 0\n10 0 0\n30 0 0\n", 1);
    assert_eq!((j.kept(), j.refused.len()), (3, 1));
    bad.positions = vec![0.0, 10.0, 20.0];
    bad.forward[1] = f64::NAN;
    let e = linuxcnc_files(&tables(Family::Leadscrew, vec![bad]), &m).unwrap_err();
    assert!(
        e.to_string().contains("table X, point 1") && e.to_string().contains("finite"),
        "{e}"
    );
    // A cross-axis table: LinuxCNC has none.
    let cross = table(
        Axis::X,
        Axis::Y,
        grid(-100.0, 900.0, 10.0),
        y_straightness,
        y_straightness,
    );
    let e = linuxcnc_files(&tables(Family::CrossAxis, vec![cross]), &m).unwrap_err();
    assert!(
        e.to_string()
            .contains("table Y(X) corrects axis Y as a function of axis X"),
        "{e}"
    );
    // An axis the machine lacks.
    let a = table(Axis::A, Axis::A, vec![0.0, 90.0], |_| 0.0, |_| 0.0);
    let e = linuxcnc_files(&tables(Family::Leadscrew, vec![a]), &m).unwrap_err();
    assert!(e.to_string().contains("names axis A"), "{e}");
}

fn positions(x: f64, y: f64, z: f64, c: f64) -> BTreeMap<String, f64> {
    [("X1", x), ("Y1", y), ("Z1", z), ("C1", c)]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect()
}

fn moving(d: i8) -> BTreeMap<String, i8> {
    ["X1", "Y1", "Z1", "C1"]
        .into_iter()
        .map(|k| (k.to_string(), d))
        .collect()
}

fn hand_set() -> PerAxisTables {
    let mut all = leadscrew_by_hand();
    all.push(table(
        Axis::X,
        Axis::Y,
        grid(-100.0, 900.0, 20.0),
        y_straightness,
        y_straightness,
    ));
    tables(Family::CrossAxis, all)
}

/// The leadscrew tables by hand: X's positioning, Z's with its reversal, C's in degrees.
fn leadscrew_by_hand() -> Vec<AxisCorrection> {
    vec![
        table(
            Axis::X,
            Axis::X,
            grid(-100.0, 900.0, 10.0),
            x_positioning,
            x_positioning,
        ),
        table(
            Axis::Z,
            Axis::Z,
            grid(0.0, 400.0, 25.0),
            z_forward,
            z_reverse,
        ),
        table(
            Axis::C,
            Axis::C,
            grid(0.0, 360.0, 10.0),
            c_positioning,
            c_positioning,
        ),
    ]
}

#[test]
fn siemens_lec_applies_the_hand_corrections_with_modulo_on_a_full_turn() {
    let lec = siemens_lec(&hand_set(), &machine()).unwrap();
    assert!(lec.starts_with("%_N_AX_EEC_INI\nCHANDATA(1)\n") && lec.ends_with("M17\n"));
    assert!(lec.contains("$AA_ENC_COMP_IS_MODULO[0,C1]=1\n"), "{lec}");
    assert!(lec.contains("$AA_ENC_COMP_IS_MODULO[0,X1]=0\n"));
    assert!(!lec.contains("Y1"), "cross-axis tables are the CEC file's");
    let t = read_lec(&parse_siemens(&lec).unwrap(), 0, 200).unwrap();
    for p in [-100.0, -95.0, 0.0, 3.7, 450.0, 900.0] {
        close(lec_correction(&t, "X1", p), x_positioning(p), 1e-9, "X");
    }
    close(
        lec_correction(&t, "X1", -300.0),
        x_positioning(-100.0),
        1e-9,
        "held below MIN",
    );
    for p in [0.0, 10.0, 90.0, 350.0, 360.0] {
        close(
            lec_correction(&t, "C1", p),
            c_positioning(p),
            1e-9,
            "C at its points",
        );
    }
    let chord = (c_positioning(0.0) + c_positioning(10.0)) / 2.0;
    close(
        lec_correction(&t, "C1", 365.0),
        chord,
        1e-9,
        "C past 360°: the table again",
    );
    close(
        lec_correction(&t, "C1", 370.0),
        c_positioning(10.0),
        1e-9,
        "C at 370°",
    );
    close(
        lec_correction(&t, "C1", -20.0),
        c_positioning(340.0),
        1e-9,
        "C at −20°",
    );
    // Z's table holds the mean of both directions.
    close(
        lec_correction(&t, "Z1", 100.0),
        -2.0e-5 * 100.0,
        1e-9,
        "Z mean",
    );
}

#[test]
fn siemens_cec_applies_the_straightness_and_carries_the_direction_of_the_leadscrew_table() {
    let m = machine();
    let set = hand_set();
    let cec = siemens_cec(&set, &m).unwrap();
    assert!(cec.starts_with("%_N_NC_CEC_INI\nCHANDATA(1)\n") && cec.ends_with("M17\n"));
    assert!(
        cec.contains("NOT CITED"),
        "the CEC sign is said to be unverified"
    );
    let tables = read_cec(&parse_siemens(&cec).unwrap(), 200).unwrap();
    assert_eq!(
        tables.0.len(),
        3,
        "Y(X), then Z's forward and reverse halves"
    );
    let lec = read_lec(
        &parse_siemens(&siemens_lec(&set, &m).unwrap()).unwrap(),
        0,
        200,
    )
    .unwrap();
    let (go, back) = (moving(1), moving(-1));
    // Straightness: hand values at the points, the hand chord between them.
    for x in [-100.0, 0.0, 20.0, 400.0, 780.0, 900.0] {
        let got = tables.correction("Y1", &positions(x, 0.0, 0.0, 0.0), &go, -1.0);
        close(got, y_straightness(x), 1e-9, "Y(X) at a point");
    }
    for (x, h) in [(10.0, 10.0), (405.0, 5.0)] {
        let got = tables.correction("Y1", &positions(x, 0.0, 0.0, 0.0), &back, -1.0);
        close(
            got,
            y_straightness(x) - K * h * (20.0 - h),
            1e-9,
            "Y(X) between",
        );
    }
    // Z: LEC's mean plus the CEC half of the travel direction gives each direction's value.
    for z in [0.0, 25.0, 110.0, 400.0] {
        let at = positions(0.0, 0.0, z, 0.0);
        let up = lec_correction(&lec, "Z1", z) + tables.correction("Z1", &at, &go, -1.0);
        let down = lec_correction(&lec, "Z1", z) + tables.correction("Z1", &at, &back, -1.0);
        close(up, z_forward(z), 1e-9, "Z forward");
        close(down, z_reverse(z), 1e-9, "Z reverse");
    }
    // The other sign convention writes every CEC value negated.
    let opts = SiemensOptions {
        cec_sign: CecSign::Correction,
        ..SiemensOptions::default()
    };
    let flipped = read_cec(
        &parse_siemens(&siemens_cec_with(&set, &m, &opts).unwrap()).unwrap(),
        200,
    )
    .unwrap();
    let at = positions(400.0, 0.0, 0.0, 0.0);
    close(
        flipped.correction("Y1", &at, &go, 1.0),
        y_straightness(400.0),
        1e-9,
        "+ sign",
    );
}

#[test]
fn siemens_axis_names_limits_and_the_reference_point() {
    let m = machine();
    let set = hand_set();
    let opts = SiemensOptions {
        axis_names: vec![(Axis::X, "AX1".into()), (Axis::Y, "AX2".into())],
        ..SiemensOptions::default()
    };
    let cec = siemens_cec_with(&set, &m, &opts).unwrap();
    assert!(cec.contains("$AN_CEC_INPUT_AXIS[0]=(AX1)\n$AN_CEC_OUTPUT_AXIS[0]=(AX2)\n"));
    assert!(
        siemens_lec_with(&set, &m, &opts)
            .unwrap()
            .contains("$AA_ENC_COMP[0,0,AX1]=")
    );
    // More points than MD38000 allows: refused, naming the machine datum and a step that fits.
    let small = SiemensOptions {
        enc_comp_max_points: 100,
        ..SiemensOptions::default()
    };
    let e = siemens_lec_with(&set, &m, &small).unwrap_err().to_string();
    assert!(
        e.contains("table X has 101 points; MD38000") && e.contains("step of at least 10.1"),
        "{e}"
    );
    // The control refuses it too.
    let lec = siemens_lec(&set, &m).unwrap();
    assert!(read_lec(&parse_siemens(&lec).unwrap(), 0, 100).is_err());
    // Not zero at the reference point: refused, or shifted on request.
    let off = tables(
        Family::Leadscrew,
        vec![table(
            Axis::X,
            Axis::X,
            grid(-100.0, 900.0, 10.0),
            |x| x_positioning(x) + 0.003,
            |x| x_positioning(x) + 0.003,
        )],
    );
    let e = siemens_lec(&off, &m).unwrap_err().to_string();
    assert!(
        e.contains("reference point 0 mm of axis X is 0.003 mm, not zero"),
        "{e}"
    );
    let shift = SiemensOptions {
        shift_to_reference: true,
        ..SiemensOptions::default()
    };
    let lec = siemens_lec_with(&off, &m, &shift).unwrap();
    assert!(lec.contains("shifted by -0.003"), "{lec}");
    let t = read_lec(&parse_siemens(&lec).unwrap(), 0, 200).unwrap();
    close(
        lec_correction(&t, "X1", 500.0),
        x_positioning(500.0),
        1e-9,
        "shifted X",
    );
    // Unequal spacing: one STEP cannot hold it.
    let uneven = tables(
        Family::Leadscrew,
        vec![table(
            Axis::X,
            Axis::X,
            vec![0.0, 10.0, 30.0],
            |_| 0.0,
            |_| 0.0,
        )],
    );
    assert!(
        siemens_lec(&uneven, &m)
            .unwrap_err()
            .to_string()
            .contains("equally spaced")
    );
    // A C table that is not periodic is not written modulo, and says why.
    let ramp = tables(
        Family::Leadscrew,
        vec![table(
            Axis::C,
            Axis::C,
            grid(0.0, 360.0, 10.0),
            |c| 1e-5 * c,
            |c| 1e-5 * c,
        )],
    );
    let lec = siemens_lec(&ramp, &m).unwrap();
    assert!(
        lec.contains("IS_MODULO[0,C1]=0") && lec.contains("not modulo"),
        "{lec}"
    );
    let t = read_lec(&parse_siemens(&lec).unwrap(), 0, 200).unwrap();
    close(
        lec_correction(&t, "C1", 370.0),
        1e-5 * 360.0,
        1e-9,
        "held past 360°",
    );
    // Too many CEC tables for the control.
    let few = SiemensOptions {
        cec_max_tables: 2,
        ..SiemensOptions::default()
    };
    let e = siemens_cec_with(&set, &m, &few).unwrap_err().to_string();
    assert!(e.contains("3 tables") && e.contains("offers 2"), "{e}");
    // A directional cross-axis table cannot be carried.
    let dir = tables(
        Family::CrossAxis,
        vec![table(
            Axis::X,
            Axis::Y,
            grid(-100.0, 900.0, 20.0),
            y_straightness,
            |x| y_straightness(x) + 0.001,
        )],
    );
    assert!(
        siemens_cec(&dir, &m)
            .unwrap_err()
            .to_string()
            .contains("table Y(X) has different forward and reverse")
    );
}

/// A rotary table over −180° … 180° is written as Siemens' modulo tables run, from 0° to 360°
/// (808D p. 109), its values turned with it: the control then gives the hand correction at
/// every angle of the turn, read either way.
#[test]
fn siemens_writes_a_turn_from_minus_180_as_a_modulo_table_from_0_to_360() {
    let m = Machine::from_toml_str(
        &machine_text().replace("range = [0.0, 360.0]", "range = [-180.0, 180.0]"),
        "test.toml",
    )
    .unwrap();
    // A correction of C zero at its reference 0° (as Siemens asks), not symmetric in θ.
    let f = |t: f64| 1.0e-3 * (t.to_radians().sin() + 0.5 * (1.0 - t.to_radians().cos()));
    let t = tables(
        Family::Leadscrew,
        vec![table(Axis::C, Axis::C, grid(-180.0, 180.0, 10.0), f, f)],
    );
    let text = siemens_lec(&t, &m).unwrap();
    assert!(text.contains("$AA_ENC_COMP_MIN[0,C1]=0.0"), "{text}");
    assert!(text.contains("$AA_ENC_COMP_MAX[0,C1]=360.0"), "{text}");
    assert!(text.contains("$AA_ENC_COMP_IS_MODULO[0,C1]=1"), "{text}");
    let lec = read_lec(&parse_siemens(&text).unwrap(), 0, 200).unwrap();
    for i in 0..=72 {
        let theta = -180.0 + 5.0 * i as f64;
        let on_control = theta.rem_euclid(360.0);
        let want = if i % 2 == 0 {
            f(theta)
        } else {
            0.5 * (f(theta - 5.0) + f(theta + 5.0))
        };
        close(lec_correction(&lec, "C1", on_control), want, 2e-9, "C"); // 9 decimals
    }
}
