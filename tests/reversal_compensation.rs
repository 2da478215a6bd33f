//! Compensation in both directions of approach (issue 49): an axis with a reversal (ISO 230-2's
//! B) is compensated on the side each move puts it, and the tables carry forward and reverse
//! values.
//!
//! 1. **LinuxCNC's rs274 judges the compensated program.** A part program on the mill of the
//!    G-code corpus that reverses X (back and forth along X, and an arc that turns X at its
//!    extreme) is compensated by `volver compensate` with a model of hand-set errors: a
//!    reversal of X, a positioning error of X with a slope, straightnesses of X and Y and
//!    positioning errors of Y and Z. Only errors of the workpiece-side axes X, Y in the x and y
//!    directions and of the tool-side Z in z: each is then an offset of its command — the
//!    errors are deviations of the slides in the machine frame (ISO 230-1), a workpiece-side
//!    slide's moves the workpiece and so the tool the other way, and the command takes `+E`;
//!    a tool-side slide's command takes `−E` — to first order in the errors' slopes. X's
//!    direction at each point is read from rs274's own X positions by the documented rule (a
//!    move back of more than 1 µm from the furthest point reached reverses it): it is the
//!    programmed direction wherever the program moves X by more than 0.1 mm (checked), and the
//!    compensation alone may reverse it (the Y move, where Y's straightness moves X's command
//!    by 3.4 µm). The canonical positions rs274 prints at every point equal the programmed
//!    positions plus (X, Y) or minus (Z) the values of `volver tables`' plain CSV (read by hand
//!    here), forward on X when X arrives forward, reverse when it arrives in reverse, the mean
//!    before X's first move — within 0.1 µm: the output's and rs274's 4 decimals (5e-5 mm) and
//!    the errors evaluated at the compensated instead of the programmed command (below
//!    1e-6 mm). With lost motion (a slide B of +15 µm on X, which carries the workpiece: ISO
//!    230-2's B = −15 µm) every point is so, the arc's turning point included; with an
//!    overshooting X (slide B −15 µm, ISO 230-2 +15 µm) the points X would reach going back by
//!    less than 15 µm (and the tolerance) from where it turned are reported unsettled and X
//!    holds its command there, less than 16 µm off (the rule of
//!    `volver_core::compensate::Travel`: no command reaches them in one move); the number of
//!    X's reversals the command prints is the one counted on rs274's positions.
//! 2. **Compensate then predict in the same direction gives the program**: for random commands
//!    and random directions of each axis (a linear and a rotary axis with a reversal, the
//!    paper's errors at random), the compensated command's tool point in that state is the
//!    nominal machine's at the programmed command (1e-9 mm).
//! 3. **Tables**: hand-set reversal functions (not fitted) written to the plain CSV and read
//!    back give forward − reverse = B(x) at every position, and the model's forward and reverse
//!    errors (1e-11 mm or rad: the CSV's 9 decimals of µm, 6 of µrad); the ISG and Etalon files
//!    say the reversal is not carried and hold the mean. Also: the tables' tool point in a
//!    state is the model's; a point list is compensated in its rows' order; block delete that
//!    changes a direction is refused; `G53` moves set directions.

mod common;

use common::rs274;
use common::{Rng, volver};
use std::path::{Path, PathBuf};
use volver::core::approach::Approach;
use volver::core::compensate::Compensator;
use volver::core::gcode::{Program, Setup, Tooling, WriteOptions};
use volver::core::iso::Axis;
use volver::core::machine::{Commands, Machine};
use volver::core::model::{DEFAULT_MODEL_TOML, Model, PointState};
use volver::core::results::ResultsFile;
use volver::core::tables::{ErrorTables, TableFormat, uncarried_in};

const MILL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/gcode/mill.toml");

/// The part: the first move states every axis (directions unknown), X forward twice, back, a
/// Y move, forward, back, then an arc (centre X400 Y250, radius 100 mm, from −60° to +45°
/// counter-clockwise: no chord of equal steps would end at 0°) that turns X at X500, and a move
/// back.
const PART: &str = "%
(a part that reverses X)
G21 G90 G17
G0 X100 Y100 Z-50
G1 X400 F1000
G1 X700
G1 X250
G1 Y300
G1 X500
G1 X400
G0 X300 Y163.3975
G1 X450
G3 X470.7107 Y320.7107 I-50 J86.6025
G1 X120
M30
%
";

/// The error model of item 1: a reversal of X and errors that enter their commands as offsets.
const MILL_MODEL: &str = "name = \"reversal of X with translations\"
[[error]]
name = [\"EXX\", \"EYX\", \"EXY\", \"EYY\"]
basis = \"legendre\"
degree = 2
[[error]]
name = \"EZZ\"
basis = \"legendre\"
degree = 1
[effects]
reversal = [\"X\"]
";

/// The mill model with hand-set errors: the slide B of X `b_um` (µm: the reversal of X's own
/// positioning error EXX; X carries the workpiece, so ISO 230-2's B, the model's
/// `reversal.X.b`, is −`b_um`), the others some µm.
fn mill_truth(b_um: f64) -> (Model, Vec<f64>) {
    let machine = Machine::load(Path::new(MILL)).unwrap();
    let model = Model::from_toml_str(machine, MILL_MODEL, "mill-model.toml").unwrap();
    let mut p = model.initial_params();
    for (name, v) in [
        ("EXX.c0", 0.004),
        ("EXX.c1", 0.012),
        ("EXX.c2", -0.003),
        ("EYX.c1", 0.006),
        ("EYX.c2", 0.008),
        ("EXY.c2", -0.007),
        ("EYY.c1", -0.009),
        ("EZZ.c1", 0.005),
        ("reversal.X.b", -b_um * 1e-3),
    ] {
        p[model.param_index(name).unwrap_or_else(|| panic!("{name}"))] = v;
    }
    (model, p)
}

/// A folder of its own under the system's temporary folder.
fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("volver-reversal-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// One row of the plain CSV: an error over an axis' positions, with its forward and reverse
/// values where they are given (µm).
struct Rows {
    positions: Vec<f64>,
    value: Vec<f64>,
    forward: Vec<Option<f64>>,
    reverse: Vec<Option<f64>>,
}

/// Reads `errors.csv` by hand (no volver reader): each error's rows by name.
fn read_plain(text: &str) -> std::collections::BTreeMap<String, Rows> {
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(
        header,
        [
            "error",
            "axis",
            "position",
            "position_unit",
            "value",
            "value_unit",
            "forward",
            "reverse"
        ]
    );
    let mut out = std::collections::BTreeMap::new();
    for l in lines {
        let c: Vec<&str> = l.split(',').collect();
        assert_eq!(c[5], "um", "{l}");
        let r = out.entry(c[0].to_string()).or_insert(Rows {
            positions: vec![],
            value: vec![],
            forward: vec![],
            reverse: vec![],
        });
        r.positions.push(c[2].parse().unwrap());
        r.value.push(c[4].parse().unwrap());
        r.forward.push(c[6].parse().ok());
        r.reverse.push(c[7].parse().ok());
    }
    out
}

/// Linear interpolation of `v` over increasing `x` at `at` (µm).
fn interp(x: &[f64], v: &[f64], at: f64) -> f64 {
    let i = x.partition_point(|p| *p <= at).clamp(1, x.len() - 1);
    let w = (at - x[i - 1]) / (x[i] - x[i - 1]);
    v[i - 1] + w * (v[i] - v[i - 1])
}

/// The value of error `name` at `at` (mm) in direction `s` of X (µm): forward, reverse, or the
/// value (the mean) for 0 or an error without direction.
fn table_um(t: &std::collections::BTreeMap<String, Rows>, name: &str, at: f64, s: i8) -> f64 {
    let r = &t[name];
    let col: Vec<f64> = match s {
        1 if r.forward[0].is_some() => r.forward.iter().map(|v| v.unwrap()).collect(),
        -1 if r.reverse[0].is_some() => r.reverse.iter().map(|v| v.unwrap()).collect(),
        _ => r.value.clone(),
    };
    interp(&r.positions, &col, at)
}

/// Item 1 for one B: compensates the part through the command line, runs it through rs274 and
/// checks every point against the CSV's values; returns the command's standard output.
fn judged_by_rs274(b_um: f64) -> String {
    let dir = scratch(&format!("rs274-{b_um}"));
    let (model, p) = mill_truth(b_um);
    let results = dir.join("truth.json");
    ResultsFile::from_model(&model, &p)
        .unwrap()
        .save(&results)
        .unwrap();
    let part = dir.join("part.ngc");
    std::fs::write(&part, PART).unwrap();
    let out = dir.join("out.ngc");
    let s = |p: &Path| p.display().to_string();
    let o = volver(&[
        "compensate",
        "--results",
        &s(&results),
        "--gcode",
        &s(&part),
        "--out",
        &s(&out),
        "--tool",
        "0,0,0",
        "--force",
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(
        o.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let tables = dir.join("tables");
    let o = volver(&[
        "tables",
        "--results",
        &s(&results),
        "--out",
        &s(&tables),
        "--step",
        "10",
        "--force",
    ]);
    let tables_out = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        tables_out.contains("do NOT carry the reversal")
            && tables_out.contains(&format!("X (ISO 230-2 B = {:.3} µm)", -b_um)),
        "{tables_out}"
    );
    let csv = read_plain(&std::fs::read_to_string(tables.join("errors.csv")).unwrap());
    let prog = Program::read(PART, "part.ngc", model.machine(), &Setup::default()).unwrap();
    let programmed: Vec<[f64; 6]> = prog.points().iter().map(|p| p.0).collect();
    // The arc's turning point (X500 Y250, to the radius' rounding in the program) is a point
    // of the path.
    assert!(
        programmed
            .iter()
            .any(|q| (q[1] - 500.0).abs() < 1e-4 && (q[0] - 250.0).abs() < 1e-9),
        "{programmed:?}"
    );
    let run = rs274::run(&out, None, None).unwrap();
    let canon = run.end_points();
    assert_eq!(canon.len(), programmed.len(), "{}", run.canon);
    // Chain order Y X Z; rs274 prints X Y Z.
    let overshoot = b_um < 0.0;
    let b_mm = b_um.abs() * 1e-3;
    // The rule on the interpreter's X (what the drive sees): X's direction changes when it
    // goes back more than the default tolerance (1 µm) from the furthest point it reached.
    let tau = 1e-3;
    let (mut dir, mut ext, mut prev) = (0_i8, f64::NAN, f64::NAN);
    let mut count = [0usize; 3];
    let (mut unsettled, mut flips, mut worst) = (0, 0, 0.0_f64);
    for (i, (q, c)) in programmed.iter().zip(&canon).enumerate() {
        let (y, x, z) = (q[0], q[1], q[2]);
        let cx = c[0];
        if i > 0 {
            let before = dir;
            match dir {
                1 if cx < ext - tau => (dir, ext) = (-1, cx),
                1 => ext = ext.max(cx),
                -1 if cx > ext + tau => (dir, ext) = (1, cx),
                -1 => ext = ext.min(cx),
                _ if (cx - ext).abs() > tau => (dir, ext) = (if cx > ext { 1 } else { -1 }, cx),
                _ => {}
            }
            flips += usize::from(before != 0 && dir != before);
        } else {
            ext = cx;
        }
        // Where the program moves X by more than 0.1 mm, the drive moves it that way.
        let px = if i > 0 { programmed[i - 1][1] } else { x };
        if (x - px).abs() > 0.1 {
            assert_eq!(
                dir,
                if x > px { 1 } else { -1 },
                "B {b_um} µm, point {i}: {c:?}"
            );
        }
        let want_x = x + 1e-3 * (table_um(&csv, "EXX", x, dir) + table_um(&csv, "EXY", y, 0));
        let want_y = y + 1e-3 * (table_um(&csv, "EYX", x, 0) + table_um(&csv, "EYY", y, 0));
        let want_z = z - 1e-3 * table_um(&csv, "EZZ", z, 0);
        // An overshooting X going back by less than |B| (and the tolerance) from where it
        // turned holds its command (no command reaches the point in one move): off by less
        // than that there.
        if overshoot && cx == prev && (cx - want_x).abs() > 1e-4 {
            assert!(
                (cx - want_x).abs() < b_mm + tau + 1e-4,
                "B {b_um} µm, point {i}: held {} µm off",
                (cx - want_x) * 1e3
            );
            unsettled += 1;
            prev = cx;
            continue;
        }
        prev = cx;
        for (k, (got, want)) in [(cx, want_x), (c[1], want_y), (c[2], want_z)]
            .into_iter()
            .enumerate()
        {
            worst = worst.max((got - want).abs());
            assert!(
                (got - want).abs() <= 1e-4,
                "B {b_um} µm, point {i} (programmed X{x} Y{y} Z{z}, X moving {dir}): axis {k} \
                 at {got}, expected {want}"
            );
        }
        count[(dir + 1) as usize] += 1;
    }
    println!(
        "slide B {b_um} µm: {} points judged by rs274 (X reverse {}, unknown {}, forward {}; \
         {unsettled} held as unsettled; {flips} changes of X's direction), largest difference \
         from the CSV's values {:.1e} mm",
        canon.len(),
        count[0],
        count[1],
        count[2],
        worst
    );
    assert!(count[0] > 20 && count[2] > 20 && count[1] == 1, "{count:?}");
    assert!(
        stdout.contains(&format!("  {flips} reversal(s)")),
        "{stdout}"
    );
    if overshoot {
        assert!(
            unsettled > 0 && stdout.contains("holds its command there"),
            "{stdout}"
        );
    } else {
        assert_eq!(unsettled, 0);
        assert!(!stdout.contains("holds its command there"), "{stdout}");
    }
    stdout
}

/// Item 1 with lost motion (slide B = +15 µm, ISO 230-2 −15 µm: the usual backlash) and with an
/// overshooting X (slide B = −15 µm, ISO 230-2 +15 µm).
#[test]
fn rs274_puts_each_point_where_the_forward_or_reverse_table_says() {
    if !rs274::require() {
        return;
    }
    for b in [15.0, -15.0] {
        let out = judged_by_rs274(b);
        assert!(
            out.contains("reversal of X: each point compensated"),
            "{out}"
        );
        // X's direction is set by its first move (X400), changes at X700 (back), X250
        // (forward), X500 (back), X300 (forward), at the arc's turn, and wherever the
        // compensation alone moves it back by more than the tolerance (counted above).
        assert!(
            out.contains("reversal(s) of an axis with a reversal value"),
            "{out}"
        );
    }
}

/// The paper's model with a reversal of X and a reversal function of C, errors at random.
fn xcfz_with_reversals(rng: &mut Rng) -> (Model, Vec<f64>) {
    let text = format!(
        "{DEFAULT_MODEL_TOML}\n[effects]\nreversal = [\"X\", {{ axis = \"C\", degree = 1 }}]\n"
    );
    let model = Model::from_toml_str(Machine::default_xcfz(), &text, "m.toml").unwrap();
    let mut p = model.initial_params();
    for (j, v) in p.iter_mut().enumerate() {
        let info = &model.params()[j];
        if info.name.starts_with("tracker") {
            continue;
        }
        let size = match info.unit {
            volver::core::iso::Unit::Mm => 0.02,
            _ => 20e-6,
        };
        *v = size * rng.next();
    }
    p[model.param_index("reversal.X.b").unwrap()] = -0.015;
    p[model.param_index("reversal.C.b").unwrap()] = 25e-6;
    p[model.param_index("reversal.C.b1").unwrap()] = -8e-6;
    (model, p)
}

/// Item 2: compensate then predict in the same direction gives the program.
#[test]
fn compensating_in_a_direction_then_predicting_in_it_gives_the_program() {
    let mut rng = Rng(0x49c0);
    let (model, p) = xcfz_with_reversals(&mut rng);
    let tool = [20.0, -10.0, -120.0];
    let comp = Compensator::new(&model, &p, tool).unwrap();
    let m = model.machine();
    let mut worst: f64 = 0.0;
    let mut apart: f64 = 0.0;
    for _ in 0..40 {
        let cmd: Vec<f64> = m
            .axes()
            .iter()
            .map(|a| {
                let (lo, hi) = (a.to_file_units(a.min), a.to_file_units(a.max));
                lo + (hi - lo) * 0.5 * (rng.next() + 1.0)
            })
            .collect();
        let programmed = m.commands_from_file_units(&cmd);
        let target = comp.nominal_point(&programmed);
        let mut solved = Vec::new();
        for s in [1_i8, -1] {
            let mut a = Approach::UNKNOWN;
            for k in 0..m.axes().len() {
                a.0[k] = if rng.next() > 0.0 { s } else { -s };
            }
            let state = PointState {
                t_s: 0.0,
                approach: a,
            };
            let c = comp.in_state(state).compensate(&programmed).unwrap();
            let x = model.tool_point_in(&c.commands.0, &tool, state, &p);
            let d = (0..3)
                .map(|i| (x[i] - target[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            worst = worst.max(d);
            assert!(d < 1e-9, "{cmd:?} in {a:?}: {d:.3e} mm off");
            // Predicted in the other direction it misses: the state matters.
            let mut other = state;
            other.approach.0[0] = -a.0[0];
            let y = model.tool_point_in(&c.commands.0, &tool, other, &p);
            let miss = (0..3)
                .map(|i| (y[i] - target[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            assert!(miss > 0.014, "{miss}");
            solved.push((a, c.commands));
        }
        let dx = (solved[0].1.0[0] - solved[1].1.0[0]).abs();
        apart = apart.max(dx);
    }
    println!(
        "compensate → predict in the same state: largest {worst:.1e} mm off the program; X's \
         commands in two states up to {:.1} µm apart",
        apart * 1e3
    );
}

/// Item 3: hand-set reversal functions written and read back.
#[test]
fn the_plain_csv_carries_forward_minus_reverse_equal_to_b() {
    let text = format!(
        "{DEFAULT_MODEL_TOML}\n[effects]\nreversal = [{{ axis = \"X\", degree = 2 }}, {{ axis = \"C\", degree = 1 }}]\n"
    );
    let model = Model::from_toml_str(Machine::default_xcfz(), &text, "m.toml").unwrap();
    let mut p = model.initial_params();
    p[model.param_index("EXX.c1").unwrap()] = 0.006;
    let (b0, b1, b2) = (-0.014, 0.003, -0.002);
    let (c0, c1) = (30e-6, 6e-6);
    for (n, v) in [
        ("reversal.X.b", b0),
        ("reversal.X.b1", b1),
        ("reversal.X.b2", b2),
        ("reversal.C.b", c0),
        ("reversal.C.b1", c1),
    ] {
        p[model.param_index(n).unwrap()] = v;
    }
    let m = model.machine();
    let tables = ErrorTables::from_model(&model, &p, 25.0, 15.0).unwrap();
    let csv = tables.to_plain_csv();
    assert!(
        csv.starts_with("error,axis,position,position_unit,value,value_unit,forward,reverse\n")
    );
    let back = ErrorTables::from_plain_csv(&csv, "errors.csv").unwrap();
    assert!(tables.max_difference(&back).unwrap() < 1e-11);
    let mut n = 0;
    for (axis, b) in [
        (
            Axis::X,
            Box::new(move |u: f64| b0 + b1 * u + b2 * 0.5 * (3.0 * u * u - 1.0))
                as Box<dyn Fn(f64) -> f64>,
        ),
        (Axis::C, Box::new(move |u: f64| c0 + c1 * u)),
    ] {
        let (k, a) = m.axis(axis).unwrap();
        let rows = back.directional_rows(axis).unwrap();
        assert!(rows.len() > 10);
        for (pos, d) in rows {
            // Legendre polynomials of the position normalised over the travel, by hand.
            let u = 2.0 * (a.from_file_units(pos) - a.min) / (a.max - a.min) - 1.0;
            // The tables hold the axis' own errors: on an axis that carries the workpiece
            // (X and C here) forward − reverse is −B (ISO 230-2's B, the tool's deviation).
            let sigma = a.side.sign();
            assert!(
                (d.reversal() - sigma * b(u)).abs() < 1e-11,
                "{axis} at {pos}: forward − reverse {} against σ·B {}",
                d.reversal(),
                sigma * b(u)
            );
            // The model's own forward and reverse errors there.
            let mut cmd = Commands::default();
            cmd.0[k] = a.from_file_units(pos);
            let side = |s: i8| {
                let mut ap = Approach::UNKNOWN;
                ap.0[k] = s;
                let st = PointState {
                    t_s: 0.0,
                    approach: ap,
                };
                model.errors_in(&cmd.0, usize::MAX, st, &p).component[k][axis.index()]
            };
            assert!((d.forward - side(1)).abs() < 1e-11 && (d.reverse - side(-1)).abs() < 1e-11);
            n += 1;
        }
    }
    // The formats without a direction say so, and hold the mean.
    for text in [tables.to_isg_csv(), tables.to_etalon()] {
        assert!(
            text.contains("the reversal of X (ISO 230-2 B up to") && text.contains(", C (ISO"),
            "{text}"
        );
        assert!(text.contains("is NOT carried"));
    }
    let isg = ErrorTables::from_isg_csv(&tables.to_isg_csv(), "i.csv").unwrap();
    assert!(isg.axes.iter().all(|t| t.reversal.is_none()));
    let exx = |t: &ErrorTables| {
        t.axes[0]
            .errors
            .iter()
            .find(|e| e.0 == "EXX")
            .unwrap()
            .1
            .clone()
    };
    for (a, b) in exx(&isg).iter().zip(exx(&tables)) {
        assert!(
            (a - b).abs() < 1e-12,
            "the ISG file holds the mean: {a} against {b}"
        );
    }
    // What the mean leaves, for those formats alone.
    let grid = [m.commands_from_file_units(&[0.0, 0.0, 0.0])];
    let names = |f| {
        uncarried_in(f, &model, &p, &[0.0; 3], &grid)
            .into_iter()
            .map(|u| u.name)
            .collect::<Vec<_>>()
    };
    assert!(names(TableFormat::PlainCsv).is_empty());
    assert_eq!(names(TableFormat::Isg), ["reversal of X", "reversal of C"]);
    println!("{n} positions: forward − reverse = B(x) of the hand-set functions to 1e-11");
}

/// The tables' tool point with directions is the model's in the same state, at the tables'
/// positions.
#[test]
fn the_tables_tool_point_in_a_direction_is_the_models() {
    let mut rng = Rng(0x7a61);
    let (model, p) = xcfz_with_reversals(&mut rng);
    let tables = ErrorTables::from_model(&model, &p, 50.0, 10.0).unwrap();
    let back = ErrorTables::from_plain_csv(&tables.to_plain_csv(), "errors.csv").unwrap();
    let m = model.machine();
    let tool = [10.0, -25.0, -90.0];
    for i in 0..12 {
        let c = m.commands_from_file_units(&[50.0 * (i % 28) as f64, 10.0 * i as f64, 100.0]);
        let mut a = Approach::UNKNOWN;
        for k in 0..3 {
            a.0[k] = [1, -1, 0][(i + k) % 3];
        }
        let state = PointState {
            t_s: 0.0,
            approach: a,
        };
        let want = model.tool_point_in(&c.0, &tool, state, &p);
        for t in [&tables, &back] {
            let got = t.tool_point_in(&model, &c, &tool, a).unwrap();
            let d = (0..3)
                .map(|q| (got[q] - want[q]).powi(2))
                .sum::<f64>()
                .sqrt();
            assert!(d < 1e-8, "{a:?}: {d:.3e} mm");
        }
    }
}

/// An optional move (block delete) that changes the side X arrives from at the next point is
/// refused with both lines; one that does not is written.
#[test]
fn block_delete_that_changes_a_direction_is_refused() {
    let (model, p) = mill_truth(-15.0);
    let comp = Compensator::new(&model, &p, [0.0; 3]).unwrap();
    let m = model.machine();
    let write = |text: &str| {
        let prog = Program::read(text, "bd.ngc", m, &Setup::default()).unwrap();
        prog.compensate_with(
            &Tooling::single(comp.clone()),
            m,
            &WriteOptions::default(),
            "t",
        )
        .map(|_| ())
        .map_err(|e| e.to_string())
    };
    let e = write("G0 X100 Y100 Z-50\nG1 X300 F500\n/G1 X400\nG1 X350 Y100 Z-50\n").unwrap_err();
    assert!(
        e.starts_with("bd.ngc:4:")
            && e.contains("skips optional line 3")
            && e.contains(
                "X arrives in reverse if the control runs line 3, forward if it skips it"
            ),
        "{e}"
    );
    write("G0 X100 Y100 Z-50\nG1 X300 F500\n/G1 X400\nG1 X450 Y100 Z-50\n").unwrap();
    // Without a reversal the same program is written.
    let plain = Model::from_toml_str(
        m.clone(),
        "[[error]]\nname = \"EXX\"\nbasis = \"legendre\"\ndegree = 1\n",
        "p.toml",
    )
    .unwrap();
    let pp = plain.initial_params();
    let c2 = Compensator::new(&plain, &pp, [0.0; 3]).unwrap();
    let prog = Program::read(
        "G0 X100 Y100 Z-50\nG1 X300 F500\n/G1 X400\nG1 X350 Y100 Z-50\n",
        "bd.ngc",
        m,
        &Setup::default(),
    )
    .unwrap();
    prog.compensate(&c2, m, 4, "t").unwrap();
}

/// A move in machine coordinates (`G53`) sets the direction of the axes it moves.
#[test]
fn machine_coordinate_moves_set_directions() {
    let (model, p) = mill_truth(15.0);
    let comp = Compensator::new(&model, &p, [0.0; 3]).unwrap();
    let m = model.machine();
    let x_of = |text: &str| -> f64 {
        let prog = Program::read(text, "g53.ngc", m, &Setup::default()).unwrap();
        let (out, _) = prog.compensate(&comp, m, 4, "t").unwrap();
        let last = out.lines().rfind(|l| l.starts_with("G1")).unwrap();
        let w = last
            .split_whitespace()
            .find(|w| w.starts_with('X'))
            .unwrap();
        w[1..].parse().unwrap()
    };
    // X300 reached from X500 (G53 took X there): reverse; from X100: forward.
    let down = x_of("G0 X100 Y100 Z-50\nG53 G0 X500\nG1 X300 F500\n");
    let up = x_of("G0 X100 Y100 Z-50\nG53 G0 X50\nG1 X300 F500\n");
    // Lost motion of 15 µm (the slide's B +15 µm on X, which carries the workpiece): forward
    // the tool lands 7.5 µm short, so the command is 7.5 µm long; in reverse 7.5 µm short.
    assert!(
        ((up - down) - 0.015).abs() < 2e-4,
        "forward {up}, reverse {down}"
    );
}

/// A point list is visited in its rows' order: each point compensated in the direction X
/// arrives with, given in the output's `approach_X` column.
#[test]
fn a_point_list_is_compensated_in_its_order() {
    let dir = scratch("points");
    let (model, p) = mill_truth(15.0);
    let results = dir.join("truth.json");
    ResultsFile::from_model(&model, &p)
        .unwrap()
        .save(&results)
        .unwrap();
    let list = dir.join("points.csv");
    std::fs::write(
        &list,
        "id,X,Y,Z\na,100,100,-50\nb,400,100,-50\nf,300,100,-50\ng,200,100,-50\nh,300,100,-50\n",
    )
    .unwrap();
    let out = dir.join("out.csv");
    let s = |p: &Path| p.display().to_string();
    let o = volver(&[
        "compensate",
        "--results",
        &s(&results),
        "--points",
        &s(&list),
        "--out",
        &s(&out),
        "--tool",
        "0,0,0",
        "--force",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = std::fs::read_to_string(&out).unwrap();
    let mut rows = text.lines();
    let header: Vec<&str> = rows.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (x, ax) = (col("X"), col("approach_X"));
    let rows: Vec<Vec<&str>> = rows.map(|r| r.split(',').collect()).collect();
    let approach: Vec<&str> = rows.iter().map(|r| r[ax]).collect();
    assert_eq!(approach, ["0", "1", "-1", "-1", "1"], "{text}");
    // X300 reached in reverse (f) and forward (h): the slide's B apart (lost motion of 15 µm on
    // X, which carries the workpiece: the command is 7.5 µm long forward, 7.5 µm short back).
    let at = |i: usize| rows[i][x].parse::<f64>().unwrap();
    assert!(((at(4) - at(2)) - 0.015).abs() < 2e-4, "{text}");
}
