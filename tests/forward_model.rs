//! The forward model against the independent eq.-11 reference vectors and hand-derived cases.

use volver::core::chain::MAX_AXES;
use volver::core::iso::{Axis, ErrorId};
use volver::core::kinematics::{PointErrors, predict};
use volver::core::machine::{Commands, Machine};
use volver::core::model::Model;

const REFERENCE: &str = include_str!("data/xcfz_eq11_vectors.csv");

/// Maps the reference file's error names to volver's: EAO/EBO are the squareness of Z (eq. 8).
fn reference_error(name: &str) -> Option<ErrorId> {
    match name {
        "none" => None,
        "EAO" => Some("A0Z".parse().unwrap()),
        "EBO" => Some("B0Z".parse().unwrap()),
        other => Some(other.parse().unwrap()),
    }
}

struct Row {
    case: usize,
    pos: [f64; 3],
    reflector: usize,
    error: Option<ErrorId>,
    value: f64,
    tracker: [f64; 6],
    pred: [f64; 3],
}

fn rows() -> Vec<Row> {
    let mut lines = REFERENCE.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |n: &str| header.iter().position(|h| *h == n).unwrap();
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let num = |n: &str| f[col(n)].parse::<f64>().unwrap();
            Row {
                case: num("case") as usize,
                pos: [num("X"), num("C"), num("Z")],
                reflector: if f[col("reflector")] == "R1" { 0 } else { 1 },
                error: reference_error(f[col("error")]),
                value: num("value"),
                tracker: [
                    "tracker_x",
                    "tracker_y",
                    "tracker_z",
                    "tracker_rx",
                    "tracker_ry",
                    "tracker_rz",
                ]
                .map(num),
                pred: ["pred_x", "pred_y", "pred_z"].map(num),
            }
        })
        .collect()
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Every reference row, through the bare forward model. volver uses the exact inverse of the
/// eq.-4 matrix for R⁻¹, like the reference, so agreement is at rounding level.
#[test]
fn reproduces_the_eq11_reference_vectors() {
    let m = Machine::default_xcfz();
    let all = rows();
    assert_eq!(all.len(), 69);
    let mut worst: f64 = 0.0;
    for r in &all {
        let cmd = m.commands_from_file_units(&r.pos);
        let mut e = PointErrors::<f64>::zero();
        if let Some(id) = r.error {
            let k = m.axis(id.axis()).unwrap().0;
            match id {
                ErrorId::Component { component, .. } => e.component[k][component.index()] = r.value,
                ErrorId::Location { component, .. } => {
                    e.location[k][component.index()] = r.value;
                    e.has_location[k] = true;
                }
            }
        }
        e.tracker = r.tracker;
        let p = predict(&m, &cmd, &m.reflectors()[r.reflector].offset, &e);
        let d = dist(p, r.pred);
        worst = worst.max(d);
        assert!(
            d < 1e-8,
            "case {}: {:?} vs {:?} ({d:e} mm)",
            r.case,
            p,
            r.pred
        );
    }
    eprintln!(
        "eq. 11 reference: largest deviation {worst:e} mm over {} rows",
        all.len()
    );
}

/// The same rows through a compiled model (every error a constant, the squareness of Z as a
/// location error): checks the parameter layout feeds the right slots.
#[test]
fn model_layout_feeds_the_forward_model() {
    let spec = r#"
        squareness = "none"
        reference_constraint = false
        [[error]]
        name = ["EXX","EYX","EZX","EAX","EBX","ECX","EXC","EYC","EZC","EAC","EBC","ECC","EXZ","EYZ","EZZ","EAZ","EBZ","ECZ"]
        basis = "constant"
        [[error]]
        name = ["AOZ", "BOZ"]
    "#;
    let model = Model::from_toml_str(Machine::default_xcfz(), spec, "spec.toml").unwrap();
    for r in rows() {
        let mut p = model.initial_params();
        if let Some(id) = r.error {
            p[model.term(id).unwrap().params.start] = r.value;
        }
        let t = model.tracker_start();
        p[t..t + 6].copy_from_slice(&r.tracker);
        let cmd = model.machine().commands_from_file_units(&r.pos);
        let x = model.predict(&cmd, r.reflector, &p);
        assert!(dist(x, r.pred) < 1e-8, "case {}", r.case);
    }
}

fn machine(chain: &str, axes: &str, tracker: &str) -> Machine {
    let text = format!(
        "name = \"test\"\nchain = \"{chain}\"\n{axes}\n[[reflector]]\nid = \"T\"\noffset = [10.0, -20.0, -100.0]\n{tracker}\n"
    );
    Machine::from_toml_str(&text, "test machine").unwrap()
}

fn xyz_axes() -> &'static str {
    "[axes.X]\nrange = [0.0, 1000.0]\n[axes.Y]\nrange = [0.0, 800.0]\n[axes.Z]\nrange = [0.0, 600.0]\n"
}

fn cmd(v: &[f64]) -> Commands {
    let mut c = [0.0; MAX_AXES];
    c[..v.len()].copy_from_slice(v);
    Commands(c)
}

fn with(f: impl FnOnce(&mut PointErrors<f64>)) -> PointErrors<f64> {
    let mut e = PointErrors::zero();
    f(&mut e);
    e
}

#[test]
fn zero_errors_give_the_nominal_geometry() {
    // XCFZ: X_LT = Rg(c)·(Z_O + (0, 0, z) + T + (x, 0, 0)) (eq. 11 with every error zero).
    let m = Machine::default_xcfz();
    for (x, c_deg, z) in [
        (0.0, 0.0, 0.0),
        (350.0, 30.0, 75.0),
        (1400.0, 225.0, 600.0),
        (1000.0, 359.0, 10.0),
    ] {
        let c = f64::to_radians(c_deg);
        for r in m.reflectors() {
            let v = [
                1000.0 + r.offset[0] + x,
                25.0 + r.offset[1],
                1500.0 + r.offset[2] + z,
            ];
            let expect = [
                c.cos() * v[0] - c.sin() * v[1],
                c.sin() * v[0] + c.cos() * v[1],
                v[2],
            ];
            let p = predict(&m, &cmd(&[x, c, z]), &r.offset, &PointErrors::<f64>::zero());
            assert!(dist(p, expect) < 1e-9, "{p:?} vs {expect:?}");
        }
    }
    // FXYZ (a gantry: everything moves the tool): offsets + commands + reflector.
    let m = machine("FXYZ", xyz_axes(), "");
    let p = predict(
        &m,
        &cmd(&[100.0, 200.0, 300.0]),
        &[10.0, -20.0, -100.0],
        &PointErrors::<f64>::zero(),
    );
    assert!(dist(p, [110.0, 180.0, 200.0]) < 1e-12);
}

#[test]
fn workpiece_and_tool_side_axes() {
    let t = [10.0, -20.0, -100.0];
    // Tool relative to workpiece is the same whichever side an axis is on.
    let tool = machine("FXYZ", xyz_axes(), "");
    let split = machine("YFXZ", xyz_axes(), "");
    let zero = PointErrors::<f64>::zero();
    let a = predict(&tool, &cmd(&[100.0, 200.0, 300.0]), &t, &zero);
    // YFXZ lists Y first (workpiece side), then X, Z.
    let b = predict(&split, &cmd(&[200.0, 100.0, 300.0]), &t, &zero);
    assert!(dist(a, b) < 1e-12, "{a:?} vs {b:?}");
    // A component error of a workpiece-side axis moves the workpiece, so the tool moves the
    // other way relative to it (eq. 6: X̄ = (−x + EXX, …) and reference case 1).
    let d = 0.01;
    let on_tool = predict(
        &tool,
        &cmd(&[100.0, 200.0, 300.0]),
        &t,
        &with(|e| e.component[1][0] = d),
    );
    let on_work = predict(
        &split,
        &cmd(&[200.0, 100.0, 300.0]),
        &t,
        &with(|e| e.component[0][0] = d),
    );
    assert!(dist(on_tool, [a[0] + d, a[1], a[2]]) < 1e-12);
    assert!(dist(on_work, [a[0] - d, a[1], a[2]]) < 1e-12);
    // A tracker on the frame does not see the workpiece-side axes.
    let framed = machine("YFXZ", xyz_axes(), "[tracker]\nmount = \"frame\"");
    let p0 = predict(&framed, &cmd(&[0.0, 100.0, 300.0]), &t, &zero);
    let p1 = predict(&framed, &cmd(&[500.0, 100.0, 300.0]), &t, &zero);
    assert!(dist(p0, p1) < 1e-12);
    assert!(dist(p0, [110.0, -20.0, 200.0]) < 1e-12);
}

#[test]
fn single_errors_move_the_point_as_derived_by_hand() {
    // FXYZ at (x, y, z) with reflector T = (10, −20, −100): each axis' rotation error w turns the
    // part of the chain it carries; to first order the point moves by w × (lever arm), because
    // R⁻¹(w)·v = v + w × v + O(w²). The lever arm of Z is T; of Y it is Z_nominal + T; of X it is
    // Y + Z + T (the axes it carries).
    let m = machine("FXYZ", xyz_axes(), "");
    let (x, y, z) = (100.0, 200.0, 300.0);
    let t = [10.0, -20.0, -100.0];
    let base = predict(&m, &cmd(&[x, y, z]), &t, &PointErrors::<f64>::zero());
    let cross = |w: [f64; 3], v: [f64; 3]| {
        [
            w[1] * v[2] - w[2] * v[1],
            w[2] * v[0] - w[0] * v[2],
            w[0] * v[1] - w[1] * v[0],
        ]
    };
    let lever = [[t[0], y + t[1], z + t[2]], [t[0], t[1], z + t[2]], t];
    let a = 1e-7;
    for (k, arm) in lever.iter().enumerate() {
        for r in 0..3 {
            let e = with(|e| e.component[k][3 + r] = a);
            let p = predict(&m, &cmd(&[x, y, z]), &t, &e);
            let mut w = [0.0; 3];
            w[r] = a;
            let dv = cross(w, *arm);
            let expect = [base[0] + dv[0], base[1] + dv[1], base[2] + dv[2]];
            assert!(
                dist(p, expect) < 1e-10,
                "axis {k} rotation {r}: {p:?} vs {expect:?}"
            );
        }
        // Translation errors move the point by themselves.
        for c in 0..3 {
            let e = with(|e| e.component[k][c] = 0.005);
            let p = predict(&m, &cmd(&[x, y, z]), &t, &e);
            let mut expect = base;
            expect[c] += 0.005;
            assert!(dist(p, expect) < 1e-12);
        }
    }
    // Squareness B0Z (eq. 8): x shifts by −z·B0Z; A0Z: y by −z·A0Z; C0Y: x by −y·C0Y.
    for (k, comp, axis_pos, shifted) in [(2, Axis::B, z, 0), (2, Axis::A, z, 1), (1, Axis::C, y, 0)]
    {
        let beta = 2e-5;
        let e = with(|e| {
            e.location[k][comp.index()] = beta;
            e.has_location[k] = true;
        });
        let p = predict(&m, &cmd(&[x, y, z]), &t, &e);
        let mut expect = base;
        expect[shifted] -= axis_pos * beta;
        assert!(dist(p, expect) < 1e-12, "{comp}0 on axis {k}");
    }
}

#[test]
fn squareness_means_the_same_on_either_side() {
    // C0Y on a workpiece-side Y gives the same relative deviation as on a tool-side Y.
    let t = [10.0, -20.0, -100.0];
    let tool = machine("FXYZ", xyz_axes(), "");
    let split = machine("YFXZ", xyz_axes(), "");
    let g = 3e-5;
    let a0 = predict(
        &tool,
        &cmd(&[100.0, 200.0, 300.0]),
        &t,
        &PointErrors::<f64>::zero(),
    );
    let a = predict(
        &tool,
        &cmd(&[100.0, 200.0, 300.0]),
        &t,
        &with(|e| {
            e.location[1][Axis::C.index()] = g;
            e.has_location[1] = true;
        }),
    );
    let b0 = predict(
        &split,
        &cmd(&[200.0, 100.0, 300.0]),
        &t,
        &PointErrors::<f64>::zero(),
    );
    let b = predict(
        &split,
        &cmd(&[200.0, 100.0, 300.0]),
        &t,
        &with(|e| {
            e.location[0][Axis::C.index()] = g;
            e.has_location[0] = true;
        }),
    );
    for i in 0..3 {
        assert!(((a[i] - a0[i]) - (b[i] - b0[i])).abs() < 1e-12);
    }
    assert!((a[0] - a0[0] + 200.0 * g).abs() < 1e-12);
}

#[test]
fn c_at_90_degrees_rotates_and_location_errors_act_about_the_displaced_axis() {
    let m = Machine::default_xcfz();
    let r1 = m.reflectors()[0].offset;
    let quarter = std::f64::consts::FRAC_PI_2;
    let p0 = predict(&m, &cmd(&[0.0, 0.0, 0.0]), &r1, &PointErrors::<f64>::zero());
    let p90 = predict(
        &m,
        &cmd(&[0.0, quarter, 0.0]),
        &r1,
        &PointErrors::<f64>::zero(),
    );
    // Rg(90°) maps (x, y, z) to (−y, x, z).
    assert!(dist(p90, [-p0[1], p0[0], p0[2]]) < 1e-9);
    // X0C = l: rotation about a line through (l, 0): the point moves by (I − Rg(c))·(l, 0, 0),
    // i.e. nothing at C = 0 and (l, −l, 0) at C = 90°.
    let l = 0.02;
    let e = with(|e| {
        e.location[1][Axis::X.index()] = l;
        e.has_location[1] = true;
    });
    assert!(dist(predict(&m, &cmd(&[0.0, 0.0, 0.0]), &r1, &e), p0) < 1e-12);
    let q = predict(&m, &cmd(&[0.0, quarter, 0.0]), &r1, &e);
    assert!(
        dist(q, [p90[0] + l, p90[1] - l, p90[2]]) < 1e-12,
        "{q:?} vs {p90:?}"
    );
    // A0C tilts the axis: no effect at C = 0; at C = 180° the tilt is seen twice over, to first
    // order a rotation by 2·A0C about x of the point: Δ = (0, −2a·z, 2a·y).
    let a = 1e-6;
    let e = with(|e| {
        e.location[1][Axis::A.index()] = a;
        e.has_location[1] = true;
    });
    assert!(dist(predict(&m, &cmd(&[0.0, 0.0, 0.0]), &r1, &e), p0) < 1e-12);
    let half = std::f64::consts::PI;
    let n = predict(
        &m,
        &cmd(&[0.0, half, 0.0]),
        &r1,
        &PointErrors::<f64>::zero(),
    );
    let t = predict(&m, &cmd(&[0.0, half, 0.0]), &r1, &e);
    let expect = [n[0], n[1] - 2.0 * a * n[2], n[2] + 2.0 * a * n[1]];
    assert!(dist(t, expect) < 1e-8, "{t:?} vs {expect:?}");
}

#[test]
fn tool_side_rotary_axes() {
    // A 5-axis head: FXYZCA, tool along −z. A = 90° turns (0, 0, −100) to (0, 100, 0);
    // then C = 90° turns that to (−100, 0, 0).
    let axes = format!(
        "{}[axes.C]\nrange = [-360.0, 360.0]\n[axes.A]\nrange = [-120.0, 120.0]\n",
        xyz_axes()
    );
    let m = machine("FXYZCA", &axes, "");
    let tool = [0.0, 0.0, -100.0];
    let q = std::f64::consts::FRAC_PI_2;
    let p = predict(
        &m,
        &cmd(&[1.0, 2.0, 3.0, 0.0, q]),
        &tool,
        &PointErrors::<f64>::zero(),
    );
    assert!(dist(p, [1.0, 102.0, 3.0]) < 1e-12, "{p:?}");
    let p = predict(
        &m,
        &cmd(&[1.0, 2.0, 3.0, q, q]),
        &tool,
        &PointErrors::<f64>::zero(),
    );
    assert!(dist(p, [-99.0, 2.0, 3.0]) < 1e-12, "{p:?}");
}

#[test]
fn tracker_pose_and_base_orientation() {
    // A tracker turned 90° about z sees frame x as its −y.
    let m = machine(
        "FXYZ",
        xyz_axes(),
        "[tracker]\nmount = \"frame\"\nposition = [5.0, 6.0, 7.0]\norientation_deg = [0.0, 0.0, 90.0]",
    );
    let mut e = PointErrors::<f64>::zero();
    e.tracker[..3].copy_from_slice(&[5.0, 6.0, 7.0]);
    let p = predict(&m, &cmd(&[100.0, 0.0, 0.0]), &[0.0; 3], &e);
    // Frame point (100, 0, 0) − T = (95, −6, −7); R0ᵀ with R0 = Rz(90°): (x, y) → (y, −x).
    assert!(dist(p, [-6.0, -95.0, -7.0]) < 1e-12, "{p:?}");
}
