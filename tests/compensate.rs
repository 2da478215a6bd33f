//! Compensation (the inverse model), G-code programs and controller tables.

mod common;

use volver::core::chain::MAX_AXES;
use volver::core::compensate::Compensator;
use volver::core::gcode::{Linearise, Program};
use volver::core::machine::{Commands, Machine};
use volver::core::model::{ErrorModelSpec, Model};
use volver::core::random::Rng;
use volver::core::simulate::{Magnitudes, Truth};
use volver::core::tables::ErrorTables;

/// Random true errors of the paper's model on the XCFZ grinder (noise-free).
fn truth(seed: u64) -> Truth {
    let m = Machine::default_xcfz();
    let spec = Model::default_xcfz().spec().clone();
    Truth::random(&m, &spec, &Magnitudes::default(), seed).unwrap()
}

fn random_command(m: &Machine, rng: &mut Rng) -> Commands {
    let mut c = Commands::default();
    for (k, a) in m.axes().iter().enumerate() {
        c.0[k] = a.min + (a.max - a.min) * rng.uniform();
    }
    c
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// forward(compensated command) = target within 1e-9 mm over the whole work volume, for
/// several random machines, with the tool at the spindle and at a reflector's offset.
#[test]
fn compensated_commands_reach_the_nominal_tool_point() {
    for seed in 1..=4 {
        let t = truth(seed);
        let m = t.model.machine();
        let mut rng = Rng::new(100 + seed);
        for tool in [[0.0; 3], m.reflectors()[1].offset] {
            let comp = Compensator::new(&t.model, &t.params, tool).unwrap();
            assert_eq!(comp.free_axes(), &[0, 1, 2], "XCFZ: X, C, Z all free");
            let (mut worst, mut largest_error) = (0.0_f64, 0.0_f64);
            for _ in 0..200 {
                let q = random_command(m, &mut rng);
                let c = comp.compensate(&q).unwrap();
                // Verified independently here, not only by the compensator's own figure.
                let reached = t.model.tool_point(&c.commands.0, &tool, &t.params);
                let d = dist(reached, comp.nominal_point(&q));
                assert!(d < 1e-9, "seed {seed}: {d:e} mm off at {:?}", q.0);
                assert!((d - c.deviation_mm).abs() < 1e-12);
                assert!(c.steps <= 6, "Newton took {} steps", c.steps);
                worst = worst.max(d);
                largest_error = largest_error.max(c.error_mm);
            }
            // The test is not vacuous: the uncompensated machine misses by tens of µm.
            assert!(largest_error > 0.02, "largest error {largest_error} mm");
            assert!(worst < 1e-9);
        }
    }
}

/// With the machine's errors all zero the compensated command is the programmed one.
#[test]
fn a_perfect_machine_needs_no_compensation() {
    let model = Model::default_xcfz();
    let p = model.initial_params();
    let comp = Compensator::new(&model, &p, [0.0; 3]).unwrap();
    let q = model
        .machine()
        .commands_from_file_units(&[350.0, 123.0, 420.0]);
    let c = comp.compensate(&q).unwrap();
    assert_eq!(c.steps, 0);
    assert_eq!(c.commands, q);
    assert_eq!(c.error_mm, 0.0);
}

/// A pure positioning error is cancelled by moving that axis by minus the error (to first
/// order; exactly here since EXX is the only error and it varies slowly).
#[test]
fn a_positioning_error_is_cancelled_along_its_axis() {
    let model = Model::default_xcfz();
    let mut p = model.initial_params();
    p[model.param_index("EXX.c1").unwrap()] = 0.05;
    let comp = Compensator::new(&model, &p, [0.0; 3]).unwrap();
    let q = model
        .machine()
        .commands_from_file_units(&[1400.0, 0.0, 300.0]);
    let c = comp.compensate(&q).unwrap();
    let e = model
        .error_value("EXX".parse().unwrap(), q.0[0], &p)
        .unwrap();
    // X carries the workpiece in XCFZ: the command moves by the error itself (to first order;
    // the difference is EXX·dEXX/dX), and the other axes do not move.
    let dx = c.commands.0[0] - q.0[0];
    assert!((dx - e).abs() < 1e-3 * e.abs(), "dx {dx} against EXX {e}");
    assert!((c.commands.0[1] - q.0[1]).abs() < 1e-12 && (c.commands.0[2] - q.0[2]).abs() < 1e-9);
}

/// The dual-number Jacobian of the tool point with respect to the commands matches central
/// finite differences (errors of every kind differentiated along their axes).
#[test]
fn the_tool_point_jacobian_matches_finite_differences() {
    use num_dual::DualSVec64;
    let t = truth(9);
    let m = t.model.machine();
    let mut rng = Rng::new(5);
    let tool = m.reflectors()[0].offset;
    for _ in 0..20 {
        let q = random_command(m, &mut rng);
        for k in 0..m.axes().len() {
            let mut u = q.0.map(DualSVec64::<MAX_AXES>::from_re);
            u[k] = DualSVec64::<MAX_AXES>::from_re(q.0[k]).derivative(k);
            let x = t.model.tool_point(&u, &tool, &t.params);
            let h = if m.axes()[k].axis.is_rotary() {
                1e-6
            } else {
                1e-4
            };
            let (mut a, mut b) = (q, q);
            a.0[k] += h;
            b.0[k] -= h;
            let (xa, xb) = (
                t.model.tool_point(&a.0, &tool, &t.params),
                t.model.tool_point(&b.0, &tool, &t.params),
            );
            for c in 0..3 {
                let fd = (xa[c] - xb[c]) / (2.0 * h);
                let exact = x[c].eps.0.as_ref().map_or(0.0, |e| e[k]);
                assert!(
                    (fd - exact).abs() < 1e-6 * (1.0 + exact.abs()),
                    "axis {k} coordinate {c}: {exact} against {fd}"
                );
            }
        }
    }
}

/// The tool point with errors is the forward model's point before the tracker: with the
/// tracker at the identity pose and the tool at a reflector, both agree.
#[test]
fn the_tool_point_is_the_forward_model_without_the_tracker() {
    let t = truth(3);
    let m = t.model.machine();
    let mut p = t.params.clone();
    let ts = t.model.tracker_start();
    p[ts..ts + 6].fill(0.0);
    let mut rng = Rng::new(11);
    for _ in 0..50 {
        let q = random_command(m, &mut rng);
        let x = t.model.predict(&q, 0, &p);
        let r0 = &m.tracker().base_rotation;
        let tp = t.model.tool_point(&q.0, &m.reflectors()[0].offset, &p);
        // predict = R0ᵀ·(tool point) with the tracker at its origin.
        let expect = [0, 1, 2].map(|j| (0..3).map(|i| tp[i] * r0[i][j]).sum::<f64>());
        assert!(dist(x, expect) < 1e-9);
    }
}

const PROGRAM: &str = "%
(a test part on the XCFZ grinder)
N10 G21 G90 G18
N20 G0 X100 C0 Z50
N30 G1 X600 Z250 F800 ; feed move
N40 G2 X700 Z350 I0 K100 (quarter circle, centre at X600 Z350)
N50 G91 G1 C45
N60 G90 G3 X600 Z450 R100
N70 G1 X650 Z450 C90.0
N80 M30
%";

/// A program is read, linearised, compensated and verified: every written command reaches
/// its target through the forward model.
#[test]
fn a_gcode_program_is_compensated_and_verified() {
    let t = truth(2);
    let m = t.model.machine();
    let lin = Linearise {
        chord_tolerance_mm: 0.001,
        max_segment_mm: Some(50.0),
    };
    let prog = Program::parse(PROGRAM, "part.nc", m, &lin).unwrap();
    let moves: Vec<_> = prog.blocks.iter().flat_map(|b| b.motions()).collect();
    assert_eq!(moves.len(), 6);
    assert_eq!(moves.iter().filter(|m| m.arc).count(), 2);
    // The quarter circle of radius 100 mm at 1 µm sagitta: θ ≤ 2 acos(1 − 1e-5) ≈ 0.00894 rad.
    let quarter = &moves[2];
    assert!(quarter.points.len() >= 176, "{}", quarter.points.len());
    for w in quarter.points.windows(2) {
        let (a, b) = (w[0], w[1]);
        let mid = [(a[0] + b[0]) / 2.0, (a[2] + b[2]) / 2.0];
        let r = ((mid[0] - 600.0).powi(2) + (mid[1] - 350.0).powi(2)).sqrt();
        for p in [a, b] {
            let rp = ((p[0] - 600.0).powi(2) + (p[2] - 350.0).powi(2)).sqrt();
            assert!((rp - 100.0).abs() < 1e-9);
        }
        assert!(100.0 - r <= 0.001 + 1e-12, "sagitta {}", 100.0 - r);
    }
    let end = quarter.points.last().unwrap();
    assert!((end[0] - 700.0).abs() < 1e-12 && (end[2] - 350.0).abs() < 1e-12);
    // G2 from (X600, Z250) about (X600, Z350) to (X700, Z350): clockwise in the ZX plane
    // passes X > 600 with Z < 350.
    let mid = quarter.points[quarter.points.len() / 2];
    assert!(mid[0] > 650.0 && mid[2] < 300.0, "{mid:?}");
    // Incremental C45 after C0.
    assert!((moves[3].points[0][1] - 45.0).abs() < 1e-12);
    // R100 counter-clockwise (about +Y, from Z towards X) from (X700, Z350) to (X600, Z450):
    // the short arc is about (X700, Z450), through X < 700 and Z < 450.
    let r_arc = &moves[4];
    for p in &r_arc.points {
        let rp = ((p[0] - 700.0).powi(2) + (p[2] - 450.0).powi(2)).sqrt();
        assert!((rp - 100.0).abs() < 1e-9, "{p:?}");
    }
    let mid = r_arc.points[r_arc.points.len() / 2];
    assert!(
        (mid[0] - 629.3).abs() < 1.0 && (mid[2] - 379.3).abs() < 1.0,
        "{mid:?}"
    );
    let comp = Compensator::new(&t.model, &t.params, [0.0; 3]).unwrap();
    let (text, rep) = prog.compensate(&comp, m, 6, "test").unwrap();
    assert_eq!(rep.moves, 6);
    assert!(rep.max_deviation_mm < 1e-9, "{}", rep.max_deviation_mm);
    // Written with 6 decimals (1 nm; 1e-6°): the rounding stays well below a µm.
    assert!(
        rep.max_written_deviation_mm < 5e-5,
        "{}",
        rep.max_written_deviation_mm
    );
    assert!(rep.max_error_mm > 0.01);
    // The output reads back as a program with the same number of points.
    let back = Program::parse(&text, "out.nc", m, &Linearise::default()).unwrap();
    let n_back: usize = back
        .blocks
        .iter()
        .flat_map(|b| b.motions())
        .map(|m| m.points.len())
        .sum();
    assert_eq!(n_back, rep.points);
    assert!(text.contains("F800") && text.contains("M30") && !text.contains("G91"));
    assert!(
        text.starts_with("%\n(") && text.ends_with("%\n"),
        "the tape marks stay first and last"
    );
}

/// Bad programs are refused with the file, the line and the word.
#[test]
fn bad_gcode_names_the_place() {
    let m = Machine::default_xcfz();
    let lin = Linearise::default();
    for (text, line, field, what) in [
        ("G0 X1\nG04 X2.5", 2, Some("G4"), "without its dwell time P"),
        ("G0 X1\nG1 Y5", 2, Some("Y"), "does not have"),
        ("G0 X1\nG1 X1.2.3", 2, Some("X"), "number"),
        ("G0 X1 (open", 1, None, "not closed"),
        (
            "G18\nG0 X100 Z0\nG2 X300 Z0 I50 K0",
            3,
            None,
            "off its circle",
        ),
        (
            "G17\nG0 X100 Z0\nG2 X300 Z0 I100 J0",
            3,
            None,
            "needs axis Y",
        ),
        (
            "G0 X100 Z0\nG18 G2 X300 Z0 R50",
            2,
            Some("R"),
            "cannot join",
        ),
        ("X100", 1, None, "before any motion"),
        ("G0 X1\nG92 X0", 2, Some("G92"), "compensation has moved"),
        ("G21\nG70 G0 X1", 2, Some("G70"), "inches"),
        // Found by the fuzzer: G30 with an arc word became a motion line carrying G30.
        ("G0 X1\nG19 G0 R20 G30", 2, Some("G0"), "share the block"),
        // Found by the fuzzer: an arc of 1e30 mm asked for more points than memory holds.
        (
            "G0 X0 Z0\nG1 X1000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000000",
            2,
            Some("X"),
            "beyond",
        ),
        ("G0 X1\nG68 X0 Z0 R30", 2, Some("G68"), "rotating"),
        ("G0 X1\nG51.1 X0", 2, Some("G51.1"), "mirroring"),
        (
            "G0 X100 Z50\nG81 X200 Z10 R60 F100",
            2,
            Some("Y"),
            "no axis Y",
        ),
        ("G0 X100 Z50\nG76 X80 Z10", 2, Some("G76"), "threading"),
        ("G0 X1\nG043.4 X2", 2, Some("G043.4"), "tool-centre-point"),
        ("G0 X1\nM0128", 2, Some("M0128"), "tool-centre-point"),
        ("G0 X1\nG0234", 2, Some("G0234"), "tool-centre-point"),
        ("G0 X1\nG43.40 H1", 2, Some("G43.40"), "tool-centre-point"),
        (
            "G0 X1\nG65 P9810 X300 Z150",
            2,
            Some("G65"),
            "not a code volver reads",
        ),
        ("G0 X1\nG52 X50 Z10 G1", 2, Some("G1"), "share the block"),
        ("G0 X1\nM98 P100", 2, Some("M98"), "subprogram"),
        ("G0 X1\nG0 X10 N5", 2, Some("N5"), "stands first"),
        ("G0 X1\nG0 X10 D5", 2, Some("D5"), "no code of this block"),
        ("G0 X1\nM3 S-5", 2, Some("S-5"), "spindle speed"),
        ("G0 X1\nG0 X10 (a (nested) comment)", 2, None, "nested"),
        ("G0 X1\nG1 U3", 2, Some("U"), "secondary"),
        ("G0 X1\nG1 X#3", 2, Some("X"), "needs a number"),
        ("G0 X1\nG1 X3 $", 2, Some("$"), "expected a word"),
    ] {
        let _ = &lin;
        let err = match parse0(text, &m) {
            Ok(p) => panic!("{text:?} accepted ({} blocks)", p.blocks.len()),
            Err(e) => e.to_string(),
        };
        assert!(err.starts_with(&format!("p.nc:{line}")), "{err}");
        if let Some(f) = field {
            assert!(err.contains(&format!("field '{f}'")), "{err}");
        }
        assert!(err.contains(what), "{err}");
    }
}

/// A move cut into more points than [`MAX_MOVE_POINTS`] is refused, not allocated.
#[test]
fn a_move_needing_too_many_points_is_refused() {
    use volver::core::gcode::MAX_MOVE_POINTS;
    let m = Machine::default_xcfz();
    let fine = Linearise {
        chord_tolerance_mm: 1e-9,
        max_segment_mm: None,
    };
    // A full circle of radius 500 mm at 1e-9 mm: about 2.2 million chords.
    let text = "G18\nG0 X0 Z0 C0\nG2 X0 Z0 I500 K0";
    let err = match Program::parse(text, "fine.nc", &m, &fine) {
        Ok(p) => panic!("accepted ({} blocks)", p.blocks.len()),
        Err(e) => e.to_string(),
    };
    assert!(
        err.starts_with("fine.nc:3") && err.contains(&MAX_MOVE_POINTS.to_string()),
        "{err}"
    );
    // The same circle at 1 µm is read.
    let ok = Linearise {
        chord_tolerance_mm: 1e-3,
        max_segment_mm: None,
    };
    assert!(Program::parse(text, "ok.nc", &m, &ok).is_ok());
}

/// Every export parses back to the same tables, and the tables hold the model's error values.
#[test]
fn controller_tables_parse_back() {
    // A model with Fourier rotary errors, location errors and squareness constants.
    let t = truth(4);
    let tables = ErrorTables::from_model(&t.model, &t.params, 50.0, 15.0).unwrap();
    assert!(!tables.constants.is_empty());
    assert_eq!(tables.axes.len(), 3);
    let x = &tables.axes[0];
    assert_eq!(x.positions.first(), Some(&0.0));
    assert_eq!(x.positions.last(), Some(&1400.0));
    for (name, vals) in &x.errors {
        let id = name.parse().unwrap();
        for (p, v) in x.positions.iter().zip(vals) {
            let e = t.model.error_value(id, *p, &t.params).unwrap();
            assert!((e - v).abs() < 1e-15, "{name} at {p}");
        }
    }
    let isg = ErrorTables::from_isg_csv(&tables.to_isg_csv(), "t.csv").unwrap();
    let eta = ErrorTables::from_etalon(&tables.to_etalon(), "t.txt").unwrap();
    let csv = ErrorTables::from_plain_csv(&tables.to_plain_csv(), "p.csv").unwrap();
    assert!(tables.max_difference(&isg).unwrap() < 1e-12);
    assert!(tables.max_difference(&eta).unwrap() < 1e-12);
    assert!(tables.max_difference(&csv).unwrap() < 1e-12);
    // A wrong name is refused with its place.
    let bad = tables.to_etalon().replacen("[EXX]", "[EQX]", 1);
    let err = ErrorTables::from_etalon(&bad, "e.txt")
        .unwrap_err()
        .to_string();
    assert!(err.starts_with("e.txt:") && err.contains("EQX"), "{err}");
}

/// Ball-screw errors are part of the exported positioning error.
#[test]
fn tables_include_ball_screw_errors() {
    let m = Machine::default_xcfz();
    let mut spec: ErrorModelSpec = Model::default_xcfz().spec().clone();
    spec.effects.ball_screw = vec![volver::core::model::BallScrewSpec {
        axis: "X".into(),
        period_mm: 10.0,
    }];
    let model = Model::new(m, spec).unwrap();
    let mut p = model.initial_params();
    let j = model
        .params()
        .iter()
        .position(|q| q.name.starts_with("screw"))
        .unwrap();
    p[j] = 0.002;
    let tables = ErrorTables::from_model(&model, &p, 2.5, 30.0).unwrap();
    let exx = &tables.axes[0].errors[0];
    assert_eq!(exx.0, "EXX");
    let peak = exx.1.iter().fold(0.0_f64, |a, v| a.max(v.abs()));
    assert!((peak - 0.002).abs() < 1e-4, "{peak}");
}

/// How far a command written with 4 decimals may put the tool from its target (mm): half a unit
/// of the last decimal in X and Z (5e-5 mm each) and in C (5e-5° = 8.7e-7 rad, at most 1.2e-3 mm
/// at the 1.4 m the XCFZ volume's points lie from the C axis), with room to spare.
const WRITTEN_MM: f64 = 2e-3;

/// The commands end to end: simulate, identify, then `compensate` (points and G-code) and
/// `tables`; every output reads back and is the library's value for the fit the CLI wrote, and
/// a bad point list is refused with its place.
#[test]
fn compensate_and_tables_through_the_cli() {
    use common::volver;
    let dir = std::env::temp_dir().join(format!("volver-compensate-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let d = |n: &str| dir.join(n).display().to_string();
    common::simulate(&d("sim"), &["--plan", "test3", "--seed", "2"]);
    let out = volver(&[
        "identify",
        "--data",
        &d("sim/measurements.csv"),
        "--out",
        &d("fit.json"),
        "--no-history",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::fs::write(d("pts.csv"), "id,X,C,Z\na,100,0,50\nb,700,90,300\n").unwrap();
    let out = volver(&[
        "compensate",
        "--results",
        &d("fit.json"),
        "--points",
        &d("pts.csv"),
        "--out",
        &d("pts-out.csv"),
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("verified through the forward model"),
        "{text}"
    );
    let csv = std::fs::read_to_string(d("pts-out.csv")).unwrap();
    assert_eq!(csv.lines().count(), 3);
    assert!(csv.starts_with("line,id,X,C,Z,X_programmed"));
    let (model, params) = fitted(&d("fit.json"));
    let comp = Compensator::new(&model, &params, reflector_centroid(&model)).unwrap();
    points_are_the_library_s(&csv, &comp, model.machine());
    std::fs::write(d("part.nc"), PROGRAM).unwrap();
    let out = volver(&[
        "compensate",
        "--results",
        &d("fit.json"),
        "--gcode",
        &d("part.nc"),
        "--out",
        &d("part-out.nc"),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let nc = std::fs::read_to_string(d("part-out.nc")).unwrap();
    program_is_the_library_s(&nc, &comp);
    let out = volver(&["tables", "--results", &d("fit.json"), "--out", &d("tables")]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    tables_are_the_fit_s(&dir.join("tables"), &model, &params);
    bad_point_lists_are_refused(&dir);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The model and parameters of the results file `path`.
fn fitted(path: &str) -> (Model, Vec<f64>) {
    volver::core::results::ResultsFile::load(std::path::Path::new(path))
        .unwrap()
        .to_model("fit.json")
        .unwrap()
}

/// The reflectors' centroid (the CLI's default tool point), from the machine's offsets.
fn reflector_centroid(model: &Model) -> [f64; 3] {
    let r = model.machine().reflectors();
    std::array::from_fn(|c| r.iter().map(|x| x.offset[c]).sum::<f64>() / r.len() as f64)
}

/// What `compensate --points` wrote (`csv`, for the points (100, 0, 50) and (700, 90, 300)) is
/// `comp`'s compensation: each point's commands reach the nominal tool point of the programmed
/// ones through the results file's model, at the reflectors' centroid, and equal the
/// library's own solution, both within the 4 written decimals.
fn points_are_the_library_s(csv: &str, comp: &Compensator, m: &Machine) {
    for (line, programmed) in csv
        .lines()
        .skip(1)
        .zip([[100.0, 0.0, 50.0], [700.0, 90.0, 300.0]])
    {
        let cells: Vec<f64> = line
            .split(',')
            .skip(2)
            .take(3)
            .map(|v| v.parse().unwrap())
            .collect();
        let cmd = m.commands_from_file_units(&programmed);
        let solved = comp.compensate(&cmd).unwrap();
        let reached = comp.actual_point(&m.commands_from_file_units(&cells));
        let off = dist(reached, comp.nominal_point(&cmd));
        assert!(
            off < WRITTEN_MM,
            "{line}: {off} mm from the nominal tool point"
        );
        for (k, ax) in m.axes().iter().enumerate() {
            let lib = ax.to_file_units(solved.commands.0[k]);
            assert!(
                (cells[k] - lib).abs() <= 0.5e-4 + 1e-9,
                "{line}: {} vs {lib}",
                cells[k]
            );
        }
        // The compensation is not nothing: the uncompensated command misses by much more.
        assert!(dist(comp.actual_point(&cmd), comp.nominal_point(&cmd)) > 10.0 * WRITTEN_MM);
    }
}

/// Every point of the program `compensate --gcode` wrote (`nc`), in order, puts the tool,
/// through `comp`'s model, where [`PROGRAM`]'s point (cut into chords as the CLI cuts them,
/// 0.001 mm) puts it on the nominal machine.
fn program_is_the_library_s(nc: &str, comp: &Compensator) {
    let m = Machine::default_xcfz();
    let written = Program::parse(nc, "part-out.nc", &m, &Linearise::default())
        .unwrap()
        .points();
    let input = Program::parse(PROGRAM, "part.nc", &m, &Linearise::default())
        .unwrap()
        .points();
    assert_eq!(written.len(), input.len());
    for ((w, _, _), (p, _, _)) in written.iter().zip(&input) {
        let (w, p) = (
            m.commands_from_file_units(&w[..3]),
            m.commands_from_file_units(&p[..3]),
        );
        let off = dist(comp.actual_point(&w), comp.nominal_point(&p));
        assert!(off < WRITTEN_MM, "{w:?} for {p:?}: {off} mm");
    }
}

/// The tables `tables` wrote into `dir` read back alike in every format, and are the fit's
/// error functions at the default steps (10 mm, 5°).
fn tables_are_the_fit_s(dir: &std::path::Path, model: &Model, params: &[f64]) {
    let isg = ErrorTables::from_isg_csv(
        &std::fs::read_to_string(dir.join("errors-isg.csv")).unwrap(),
        "i",
    )
    .unwrap();
    let eta = ErrorTables::from_etalon(
        &std::fs::read_to_string(dir.join("errors-etalon.txt")).unwrap(),
        "e",
    )
    .unwrap();
    let csv = ErrorTables::from_plain_csv(
        &std::fs::read_to_string(dir.join("errors.csv")).unwrap(),
        "c",
    )
    .unwrap();
    assert!(isg.max_difference(&eta).unwrap() < 1e-12 && isg.max_difference(&csv).unwrap() < 1e-12);
    // The values are the fit's error functions at the default steps (10 mm, 5°).
    let lib = ErrorTables::from_model(model, params, 10.0, 5.0).unwrap();
    assert!(lib.max_difference(&isg).unwrap() < 1e-12);
    for t in &isg.axes {
        let (_, ax) = model.machine().axis(t.axis).unwrap();
        for (name, vals) in &t.errors {
            let id = name.parse().unwrap();
            for (p, v) in t.positions.iter().zip(vals) {
                let e = model
                    .error_value(id, ax.from_file_units(*p), params)
                    .unwrap();
                assert!((e - v).abs() < 1e-12, "{name} at {p}: {v} vs {e}");
            }
        }
    }
}

/// `compensate --points` refuses bad point lists naming the file, the line and the column.
fn bad_point_lists_are_refused(dir: &std::path::Path) {
    use common::volver;
    let d = |n: &str| dir.join(n).display().to_string();
    for (text, expect) in [
        ("id,X,C\na,1,2\n", ":1: field 'Z'"),
        ("X,C,Z\n1,2,abc\n", ":2: field 'Z'"),
        ("X,C,Z,Y\n1,2,3,4\n", ":1: field 'Y'"),
        ("X,C,Z\n", ":1"),
        ("X,C,Z\n1,NaN,3\n", ":2: field 'C'"),
    ] {
        std::fs::write(d("bad.csv"), text).unwrap();
        let out = volver(&[
            "compensate",
            "--results",
            &d("fit.json"),
            "--points",
            &d("bad.csv"),
            "--out",
            &d("x.csv"),
        ]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && !err.contains("panicked"), "{err}");
        assert!(err.contains(&format!("bad.csv{expect}")), "{text:?}: {err}");
    }
}

/// `volver report` writes one self-contained HTML file: inline SVG, no scripts, no network,
/// no NaN, with every section.
#[test]
fn the_report_is_one_self_contained_html_file() {
    use common::volver;
    let dir = std::env::temp_dir().join(format!("volver-report-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let d = |n: &str| dir.join(n).display().to_string();
    let out = volver(&[
        "simulate",
        "--plan",
        "test3",
        "--seed",
        "4",
        "--out",
        &d("sim"),
    ]);
    assert!(out.status.success());
    let out = volver(&[
        "simulate",
        "--plan",
        "test4",
        "--seed",
        "5",
        "--out",
        &d("ref"),
    ]);
    assert!(out.status.success());
    let out = volver(&[
        "report",
        "--data",
        &d("sim/measurements.csv"),
        "--truth",
        &d("sim/truth.json"),
        "--reference",
        &d("ref/measurements.csv"),
        "--add",
        "tracker-tilt",
        "--out",
        &d("r.html"),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let html = std::fs::read_to_string(d("r.html")).unwrap();
    assert!(html.starts_with("<!DOCTYPE html>") && html.ends_with("</html>\n"));
    for section in [
        "Machine and model",
        "Summary",
        "Error over the measured volume",
        "Identified error functions",
        "Diagnosis",
        "Identifiability",
        "Cross-validation",
    ] {
        assert!(html.contains(section), "missing {section}");
    }
    assert!(html.matches("<svg").count() >= 8);
    assert!(html.contains("class=\"truth\"") && html.contains("class=\"band\""));
    assert!(!html.contains("<script"));
    assert!(!html.contains("src=\"http") && !html.contains("href=\"http"));
    assert!(!html.contains("NaN") && !html.contains("inf µm"));
    // Every EMM of the summary with its U.
    assert!(html.contains("Each EMM carries its U (k = 2)"));
    let summary = &html[html.find("<h2>Summary</h2>").unwrap()..];
    let summary = &summary[..summary.find("</table>").unwrap()];
    assert!(summary.matches(" ± ").count() >= 2, "{summary}");
    // The U of the compensated tool point: stated for the reflectors' centroid by default; a
    // tool 100 mm below the reflectors (the turn of the tool about the line through them is
    // not measured) has a larger U, and the report says the exports would refuse it.
    let stated = |html: &str| -> f64 {
        let i = html
            .find("<h2>Uncertainty of the compensated tool point</h2>")
            .expect("the U section");
        let rest = &html[i..];
        let j = rest.find("U is at most <b>").unwrap() + "U is at most <b>".len();
        rest[j..].split(' ').next().unwrap().parse().unwrap()
    };
    let u_centroid = stated(&html);
    let out = volver(&[
        "report",
        "--data",
        &d("sim/measurements.csv"),
        "--tool-offset",
        "-30,75,-100",
        "--out",
        &d("far.html"),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let far = std::fs::read_to_string(d("far.html")).unwrap();
    let u_far = stated(&far);
    // Measured: 43.1 against 22.4 µm with the paper's noise of the machine file (1.9 ×).
    assert!(
        u_far > 1.5 * u_centroid && u_far > 25.0,
        "U {u_far} µm for the far tool against {u_centroid} µm at the centroid"
    );
    assert!(far.contains("they refuse this tool offset unless <code>--force</code>"));
    assert!(far.contains("U (k = 2) of the compensated tool point"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// A model whose errors are set by hand: EXX rises linearly by 0.2 µm per mm of X (2 µm at
/// X = 10 mm, 10 µm at 50 mm), ECC is a constant 5 µrad, and the squareness B0Z is 20 µrad
/// (the model's parameter: ISO 230-1's B0Z, which every export and the report give, is −20 µrad,
/// `ErrorId::iso_sign`).
fn hand_set() -> (Model, Vec<f64>) {
    let model = Model::from_toml_str(
        Machine::default_xcfz(),
        r#"
name = "hand-set"
[[error]]
name = "EXX"
basis = "monomial"
degree = 1
[[error]]
name = "ECC"
basis = "fourier"
order = 1
[[error]]
name = "B0Z"
# The tracker's angles held: it stands on the C axis, where its turn about z and a constant
# ECC are one motion.
[tracker]
identify = ["x", "y", "z"]
"#,
        "hand.toml",
    )
    .unwrap();
    let mut p = model.initial_params();
    // X travels 0–1400 mm, so ξ = 2x/1400 − 1 and EXX = c0 + c1·ξ; zero at x = 0 means c0 = c1,
    // and EXX(10 mm) = c1·20/1400 = 0.002 mm gives c1 = 0.14 mm.
    p[model.param_index("EXX.c0").unwrap()] = 0.14;
    p[model.param_index("EXX.c1").unwrap()] = 0.14;
    p[model.param_index("ECC.d").unwrap()] = 5e-6;
    p[model.param_index("B0Z").unwrap()] = 20e-6;
    (model, p)
}

/// Every table format states the hand-set errors as exactly those numbers in its stated unit:
/// the plain CSV in µm and µrad (EXX = 2 µm at 10 mm, not 2 098 µm or 2 000 µm), the ISG and
/// Etalon files in mm and rad. Checked on the text, through the library and through the CLI.
#[test]
fn tables_state_hand_set_errors_in_their_units() {
    let (model, p) = hand_set();
    let tables = ErrorTables::from_model(&model, &p, 10.0, 30.0).unwrap();
    let check = |plain: &str, isg: &str, etalon: &str| {
        for line in [
            "EXX,X,10.000000,mm,2.000000000,um",
            "EXX,X,50.000000,mm,10.000000000,um",
            "EXX,X,0.000000,mm,0.000000000,um",
            "ECC,C,30.000000,deg,5.000000,urad",
            "B0Z,Z,,,-20.000000,urad",
        ] {
            assert!(
                plain.lines().any(|l| l == line),
                "plain CSV lacks {line}:\n{plain}"
            );
        }
        // ISG: the X block's row at 10 mm holds 0.002 mm; the constants block B0Z −2e-5 rad (ISO).
        assert!(
            isg.lines().any(|l| l == "10.000000 0.002000000000"),
            "{isg}"
        );
        assert!(
            isg.lines().any(|l| l == "30.000000 0.000005000000"),
            "{isg}"
        );
        let b0z = isg.lines().position(|l| l == "B0Z").expect("B0Z header");
        assert_eq!(isg.lines().nth(b0z + 1), Some("-0.000020000000"));
        // Etalon: the same in its Gridpoints and VALUE lines.
        assert!(
            etalon.contains(
                "[EXX]\nGridpoints = {\n  0.000000 0.000000000000\n  10.000000 0.002000000000\n"
            ),
            "{etalon}"
        );
        assert!(
            etalon.contains("[B0Z]\nVALUE = -0.000020000000\n"),
            "{etalon}"
        );
        assert!(etalon.contains("  30.000000 0.000005000000\n"), "{etalon}");
    };
    check(
        &tables.to_plain_csv(),
        &tables.to_isg_csv(),
        &tables.to_etalon(),
    );
    // Read back, each format gives the same tables (not a check of the format on its own).
    let back = ErrorTables::from_plain_csv(&tables.to_plain_csv(), "p.csv").unwrap();
    assert!(tables.max_difference(&back).unwrap() < 1e-12);

    // Through the CLI, from a results file.
    let dir = std::env::temp_dir().join(format!("volver-hand-tables-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let results = dir.join("hand.json");
    volver::core::results::ResultsFile::from_model(&model, &p)
        .unwrap()
        .save(&results)
        .unwrap();
    let out = common::volver(&[
        "tables",
        "--results",
        results.to_str().unwrap(),
        "--out",
        dir.join("t").to_str().unwrap(),
        "--rotary-step",
        "30",
        "--force", // hand-set errors carry no uncertainty: nothing vouches for them
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let read = |n: &str| std::fs::read_to_string(dir.join("t").join(n)).unwrap();
    check(
        &read("errors.csv"),
        &read("errors-isg.csv"),
        &read("errors-etalon.txt"),
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The moves a program makes (file units, chain order), read by volver's reader.
/// A program read with the machine at its reference position at the start (every axis known).
fn parse0(text: &str, m: &Machine) -> volver::core::error::Result<Program> {
    let setup = volver::core::gcode::Setup {
        start: std::array::from_fn(|k| m.axes().get(k).map(|a| a.to_file_units(a.reference))),
        ..Default::default()
    };
    Program::read(text, "p.nc", m, &setup)
}

fn moves_of(text: &str, m: &Machine) -> Vec<Vec<f64>> {
    parse0(text, m)
        .unwrap()
        .points()
        .iter()
        .map(|(p, _, _)| p[..m.axes().len()].to_vec())
        .collect()
}

/// `text` compensated on a perfect machine (the identity): the output, which must re-read as
/// the same moves.
fn rewritten(text: &str, m: &Machine, model: &Model) -> String {
    let p = model.initial_params();
    let comp = Compensator::new(model, &p, [0.0; 3]).unwrap();
    let prog = parse0(text, m).unwrap();
    let (out, _) = prog.compensate(&comp, m, 4, "test").unwrap();
    let (a, b) = (moves_of(text, m), moves_of(&out, m));
    assert_eq!(a.len(), b.len(), "{out}");
    for (x, y) in a.iter().zip(&b) {
        for (u, v) in x.iter().zip(y) {
            assert!((u - v).abs() < 1e-4, "{x:?} became {y:?}:\n{out}");
        }
    }
    out
}

/// Mode words in every spelling a control accepts are read, and none reaches the output, whose
/// moves are absolute under one stated modal state: `G091` or `G 91` copied verbatim would make
/// a control run the absolute moves as increments (reliability II).
#[test]
fn gcode_mode_words_in_any_spelling_leave_no_trace() {
    let m = Machine::default_xcfz();
    let model = Model::default_xcfz();
    for g91 in ["G91", "G091", "G 91", "g91", "G91.0"] {
        let text = format!("G90 G1 X100 C0 Z100\n{g91}\nG1 X10\nG1 Z5\n");
        assert_eq!(moves_of(&text, &m)[2], vec![110.0, 0.0, 105.0], "{g91}");
        let out = rewritten(&text, &m, &model);
        let code: Vec<String> = out
            .lines()
            .map(|l| l.split('(').next().unwrap().to_uppercase().replace(' ', ""))
            .collect();
        assert!(
            code.iter()
                .all(|l| !l.contains("G91") && !l.contains("G091")),
            "{g91}:\n{out}"
        );
        assert!(out.contains("G90 G21 G17\n"), "{out}");
        assert!(out.contains("G1 X110.0000 Z105.0000 C0.0000"), "{out}");
    }
}

/// Modal words apply to the whole block, as RS-274/NGC says, wherever they stand in it.
#[test]
fn gcode_modal_words_apply_to_the_whole_block() {
    let m = Machine::default_xcfz();
    let at = |text: &str| moves_of(text, &m).last().unwrap()[0];
    assert_eq!(at("G1 X100 C0 Z0\nG1 X10 G91\n"), 110.0);
    assert_eq!(at("G91\nG1 X100\nG1 X500 G90\n"), 500.0);
    // Two words of one modal group, or of one axis, in a block are refused with their place.
    let err = |text: &str| parse0(text, &m).unwrap_err().to_string();
    let e = err("G1 X1\nG90 X10 G91\n");
    assert!(
        e.starts_with("p.nc:2") && e.contains("distance mode"),
        "{e}"
    );
    let e = err("G0 G1 X10\n");
    assert!(e.contains("motion"), "{e}");
    let e = err("G1 X10 X20\n");
    assert!(e.contains("two words for axis X"), "{e}");
}

/// Numbers in every form a control accepts, and a clear refusal of exponents (`X1e2` is X1 and
/// a word E2 to a control).
#[test]
fn gcode_numbers_are_read_as_a_control_reads_them() {
    let m = Machine::default_xcfz();
    let last = |text: &str| moves_of(text, &m).last().unwrap().clone();
    assert_eq!(last("G1 X-.5 C+10. Z007\n"), vec![-0.5, 10.0, 7.0]);
    assert_eq!(last("g1x12.5z3\n"), vec![12.5, 0.0, 3.0]);
    for bad in ["G1 X1e2\n", "G1 X1E+2\n", "G1 X1.5e-3 Z0\n"] {
        let e = parse0(bad, &m).unwrap_err().to_string();
        assert!(
            e.starts_with("p.nc:1") && e.contains("no exponent"),
            "{bad}: {e}"
        );
    }
    for bad in ["G1 X1.2.3\n", "G1 X--1\n", "G1 X.\n", "G1 X+\n"] {
        assert!(parse0(bad, &m).is_err(), "{bad}");
    }
    // A real E word after a space is read as a word, which no code of the block takes: refused
    // as a control refuses it.
    let e = parse0("G1 X1 E2\n", &m).unwrap_err().to_string();
    assert!(e.contains("field 'E2'"), "{e}");
}

/// LF, CR LF and CR alone end lines: a CR-only file is not one block.
#[test]
fn gcode_every_line_ending_is_read() {
    let m = Machine::default_xcfz();
    let lf = "G1 X10 C0 Z0\nG1 X20\nG1 Z30\n";
    let want = moves_of(lf, &m);
    assert_eq!(want.len(), 3);
    for text in [
        lf.replace('\n', "\r\n"),
        lf.replace('\n', "\r"),
        lf.trim_end().replace('\n', "\r"),
    ] {
        assert_eq!(moves_of(&text, &m), want, "{text:?}");
    }
    // Errors name the line whatever the ending.
    let e = parse0("G1 X1\rG1 Q\r", &m).unwrap_err().to_string();
    assert!(e.starts_with("p.nc:2"), "{e}");
}

/// Block delete, block numbers and program numbers stay in their place: `/` first on every line
/// of an optional block, `N` first in its block (LinuxCNC refuses a line number mid-block), the
/// header after `%` and `O1000`, and the axis words in the order X Y Z A B C.
#[test]
fn gcode_block_delete_and_numbers_keep_their_place() {
    let m = Machine::default_xcfz();
    let model = Model::default_xcfz();
    let text =
        "%\nO1000 (part)\nN10 G90 G1 X100 C0 Z10 F500\n/N20 G1 X200\nN30 M5 ; spindle off\n%\n";
    let out = rewritten(text, &m, &model);
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines[0], "%");
    assert_eq!(lines[1], "O1000 (part)");
    assert!(lines[2].starts_with("(test"), "{out}");
    assert!(
        out.contains("\nN10 G1 X100.0000 Z10.0000 C0.0000 F500 (line 3)\n"),
        "{out}"
    );
    assert!(
        out.contains("\n/N20 G1 X200.0000 Z10.0000 C0.0000 (line 4)\n"),
        "{out}"
    );
    assert!(out.contains("\nN30 M5 ; spindle off\n"), "{out}");
    assert!(out.ends_with("\n%\n"), "{out}");
    let prog = Program::parse(&out, "o.nc", &m, &Linearise::default()).unwrap();
    let flags: Vec<bool> = prog.points().iter().map(|p| p.2).collect();
    assert_eq!(flags, vec![false, true]);
    // A long optional move split into segments keeps the `/` on every segment.
    let lin = Linearise {
        chord_tolerance_mm: 0.001,
        max_segment_mm: Some(30.0),
    };
    let p = model.initial_params();
    let comp = Compensator::new(&model, &p, [0.0; 3]).unwrap();
    let prog = Program::parse("G1 X0 C0 Z0\n/G1 X100\n", "p.nc", &m, &lin).unwrap();
    let (out, _) = prog.compensate(&comp, &m, 3, "").unwrap();
    let optional: Vec<&str> = out
        .lines()
        .filter(|l| l.contains("X") && l.starts_with('/'))
        .collect();
    assert_eq!(optional.len(), 4, "{out}");
}

/// A five-axis program is written with its axis words in the conventional order X Y Z A B C,
/// not in the machine's chain order.
#[test]
fn gcode_axis_words_are_written_in_the_conventional_order() {
    let m = Machine::from_toml_str(
        r#"
        name = "five-axis"
        chain = "YACFXZ"
        [axes.Y]
        range = [-400.0, 400.0]
        offset = [0.0, 0.0, 0.0]
        [axes.A]
        range = [-110.0, 110.0]
        offset = [0.0, 0.0, 100.0]
        [axes.C]
        range = [-360.0, 360.0]
        offset = [0.0, 0.0, 50.0]
        [axes.X]
        range = [-500.0, 500.0]
        offset = [0.0, 0.0, 0.0]
        [axes.Z]
        range = [0.0, 600.0]
        offset = [0.0, 0.0, 800.0]
        [[reflector]]
        id = "R1"
        offset = [0.0, 0.0, -100.0]
        [tracker]
        mount = "frame"
        position = [2000.0, 0.0, 0.0]
        orientation_deg = [0.0, 0.0, 180.0]
        "#,
        "5ax.toml",
    )
    .unwrap();
    let model = Model::from_toml_str(m.clone(), "name = \"none\"\n", "none.toml").unwrap();
    let out = rewritten("G1 X1 Y2 Z3 A4 C5\n", &m, &model);
    assert!(
        out.contains("G1 X1.0000 Y2.0000 Z3.0000 A4.0000 C5.0000"),
        "{out}"
    );
}

/// Decimals beyond what any machine resolves are refused, not a panic.
#[test]
fn gcode_decimals_are_bounded() {
    let m = Machine::default_xcfz();
    let model = Model::default_xcfz();
    let p = model.initial_params();
    let comp = Compensator::new(&model, &p, [0.0; 3]).unwrap();
    let prog = parse0("G1 X1\n", &m).unwrap();
    let e = prog
        .compensate(&comp, &m, 70_000, "")
        .unwrap_err()
        .to_string();
    assert!(e.contains("at most 12"), "{e}");
}

/// The hand-set errors, measured without noise on test 4 with a model of their own structure,
/// come back as those numbers (to the 1e-9 mm of the measurement file) in `identify --json` (mm,
/// rad) and in the report's table of constants (µrad), and the report's results file holds them.
#[test]
fn hand_set_errors_appear_in_identify_json_and_the_report() {
    use volver::core::simulate::{Simulation, Truth};
    let (model, p) = hand_set();
    let dir = std::env::temp_dir().join(format!("volver-hand-report-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let truth = Truth {
        model: model.clone(),
        params: p.clone(),
    };
    let plan = volver::core::plan::Plan::preset(model.machine(), "test4").unwrap();
    let mut sim = Simulation::new(plan, truth, 1);
    sim.noise = volver::core::noise::TrackerNoise::NONE;
    sim.run().unwrap().write(&dir).unwrap();
    let model_toml = dir.join("hand.toml");
    std::fs::write(&model_toml, toml::to_string(model.spec()).unwrap()).unwrap();
    let d = |n: &str| dir.join(n).display().to_string();
    let inputs = [
        "--machine",
        &d("machine.toml"),
        "--model",
        &d("hand.toml"),
        "--data",
        &d("measurements.csv"),
    ];
    let mut args = vec!["identify", "--json", "--no-history"];
    args.extend_from_slice(&inputs);
    let out = common::volver(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let param = |name: &str| {
        v["parameters"]
            .as_array()
            .unwrap()
            .iter()
            .find(|q| q["name"] == name)
            .unwrap_or_else(|| panic!("{name}"))
            .clone()
    };
    for (name, want, unit) in [
        ("EXX.c1", 0.14, "mm"),
        ("ECC.d", 5e-6, "rad"),
        ("B0Z", 20e-6, "rad"),
    ] {
        let q = param(name);
        let got = q["value"].as_f64().unwrap();
        // The measurement file holds 1e-9 mm: the fit recovers each value to 1e-6 of itself.
        assert!((got / want - 1.0).abs() < 1e-6, "{name}: {got} vs {want}");
        assert_eq!(q["unit"], unit, "{name}");
    }
    let mut args = vec!["report", "--out"];
    let html_path = d("r.html");
    args.push(&html_path);
    args.extend_from_slice(&inputs);
    let out = common::volver(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let html = std::fs::read_to_string(&html_path).unwrap();
    // ISO 230-1's sign in the report: the parameter's negative for B0Z.
    assert!(html.contains("<td>B0Z</td><td>-20.000 ± "), "B0Z row");
    let (fit, q) = volver::core::results::ResultsFile::load(&dir.join("r.json"))
        .unwrap()
        .to_model("r.json")
        .unwrap();
    let e = fit.error_value("EXX".parse().unwrap(), 10.0, &q).unwrap();
    assert!((e - 0.002).abs() < 1e-9, "EXX(10 mm) = {e} mm");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `volver predict` puts two results files side by side: the hand-set model and the same
/// machine without errors differ at X = 10 mm, C = 0, Z = 0 (B0Z acts only away from Z's
/// reference) for a tool point that the X offset puts 10 mm from the C axis by the hand-set EXX
/// (2 µm) along x and by ECC's 5 µrad turn over that lever (0.05 µm) along y.
#[test]
fn predict_shows_a_hand_set_error_at_its_point() {
    let (model, p) = hand_set();
    let dir = std::env::temp_dir().join(format!("volver-predict-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let save = |name: &str, params: &[f64]| {
        let path = dir.join(name);
        volver::core::results::ResultsFile::from_model(&model, params)
            .unwrap()
            .save(&path)
            .unwrap();
        path.display().to_string()
    };
    let hand = save("hand.json", &p);
    let zero = save("zero.json", &model.initial_params());
    let run = |results: &str| -> serde_json::Value {
        let out = common::volver(&[
            "predict",
            "--results",
            results,
            "--grid",
            "X=10,C=0,Z=0",
            "--tool-offset",
            "-1000,-25,0",
            "--json",
        ]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_slice(&out.stdout).unwrap()
    };
    let (a, b) = (run(&hand), run(&zero));
    let pt = |v: &serde_json::Value| -> Vec<f64> {
        v["points"][0]["tool_point_mm"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    let (pa, pb) = (pt(&a), pt(&b));
    let d: Vec<f64> = pa.iter().zip(&pb).map(|(x, y)| x - y).collect();
    assert!((d[0].abs() - 0.002).abs() < 1e-9, "{d:?}");
    // The lever is the 10 mm less the 2 µm EXX takes off it.
    assert!(
        (d[1].abs() - 5e-6 * 9.998).abs() < 1e-11 && d[2].abs() < 1e-12,
        "{d:?}"
    );
    assert_eq!(a["points"][0]["commands"][0], 10.0);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Fanuc-style programs (`--dialect fanuc`): `G04 X2.5` is a dwell of 2.5 s and its X no
/// position; an axis value without a decimal point (read in the least input increment by the
/// control) and a canned cycle (retract and peck amounts in the control's parameters) are
/// refused; the output has a decimal point on every axis value, whatever the decimals.
#[test]
fn fanuc_programs_are_read_and_written_by_fanuc_rules() {
    use volver::core::dialect::Dialect;
    use volver::core::gcode::{Setup, Tooling, WriteOptions};
    let t = truth(3);
    let m = t.model.machine();
    let setup = Setup {
        dialect: Dialect::Fanuc,
        ..Setup::default()
    };
    let text =
        "%\nO0001\nG21 G90 G18\nG0 X100. C0. Z50.\nG04 X2.5\nG1 Z200. F300.\nG91 G28 Z0.\nM30\n%\n";
    let prog = Program::read(text, "f.nc", m, &setup).unwrap();
    let pts = prog.points();
    assert_eq!(pts.len(), 2, "the dwell's X is no move");
    assert_eq!(&pts[1].0[..3], &[100.0, 0.0, 200.0]);
    let comp = Compensator::new(&t.model, &t.params, [0.0; 3]).unwrap();
    let options = WriteOptions {
        decimals: 0,
        dialect: Dialect::Fanuc,
        ..WriteOptions::default()
    };
    let (out, _) = prog
        .compensate_with(&Tooling::single(comp), m, &options, "fanuc")
        .unwrap();
    assert!(out.contains("G04 X2.5"), "{out}");
    // The reference move's intermediate point, rewritten absolute, keeps a decimal point (a
    // Fanuc control would read G28 Z200 as 0.2 mm).
    assert!(out.contains("G28 Z200."), "{out}");
    for line in out
        .lines()
        .filter(|l| l.starts_with("G0") || l.starts_with("G1"))
    {
        for w in line
            .split_whitespace()
            .filter(|w| "XYZABC".contains(&w[..1]))
        {
            assert!(w.contains('.'), "{w} in {line}");
        }
    }
    // The same dwell under RS274NGC is refused (rs274 refuses it too), as are values without a
    // decimal point and cycles under Fanuc rules.
    let e = Program::read(text, "f.nc", m, &Setup::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("f.nc:5") && e.contains("G4"), "{e}");
    for (bad, word) in [
        ("G0 X100 C0. Z50.\n", "X100"),
        ("G0 X100. C0. Z50.\nG17 G81 X10. Z5. R20. F100.\n", "G81"),
    ] {
        let e = Program::read(bad, "f.nc", m, &setup)
            .unwrap_err()
            .to_string();
        assert!(e.contains(word), "{bad}: {e}");
    }
}
