//! Squareness signs (issue 47): every export writes each of the six squareness names with ISO
//! 230-1's sign — the angle by which the axis' line of motion is turned, right-handed about the
//! named rotation axis — whatever sign volver's model gives its parameter.
//!
//! The independent value: with one hand-set squareness and nothing else, the model moves the
//! tool (relative to the workpiece) along a line as the axis' command changes; the ISO angle of
//! that line about R is read geometrically, `d·(e_R × e_K) / d·e_K`, with no use of volver's
//! sign rule. Each export's text is read for the name's value by the format's own layout (ISG:
//! a header row of names over a row of values; Etalon: `[NAME]` then `VALUE = v`; plain CSV:
//! `NAME,AXIS,,,value,urad`) and compared with it. Four machines: the XCFZ grinder (X on the
//! workpiece side, Z on the tool side) and the three five-axis presets; both signs and two sizes.

use volver::core::iso::{Axis, ErrorId};
use volver::core::machine::{Commands, Machine};
use volver::core::model::Model;
use volver::core::presets;
use volver::core::tables::ErrorTables;

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn unit(d: usize) -> [f64; 3] {
    let mut e = [0.0; 3];
    e[d] = 1.0;
    e
}

/// The ISO angle about `r` of linear axis `k`'s line of motion in `model` with `params`: the
/// tool's displacement relative to the workpiece as `k` moves over 40 % of its travel, every
/// other linear axis at its reference and every rotary axis at 0.
fn iso_angle(model: &Model, params: &[f64], k: Axis, r: Axis) -> f64 {
    let m = model.machine();
    let mut c = Commands::default();
    let mut slot = 0;
    for (i, a) in m.axes().iter().enumerate() {
        c.0[i] = if a.axis.is_rotary() { 0.0 } else { a.reference };
        if a.axis == k {
            slot = i;
        }
    }
    let ax = &m.axes()[slot];
    let mut moved = c;
    moved.0[slot] += 0.4
        * (ax.max - ax.min)
        * if ax.reference > 0.5 * (ax.min + ax.max) {
            -1.0
        } else {
            1.0
        };
    let tool = [10.0, -20.0, -150.0];
    let (a, b) = (
        model.tool_point(&c.0, &tool, params),
        model.tool_point(&moved.0, &tool, params),
    );
    let d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let (er, ek) = (unit(r.direction()), unit(k.direction()));
    dot(d, cross(er, ek)) / dot(d, ek)
}

/// The value of `name` in each export's text, as that format lays it out (rad).
fn exported(t: &ErrorTables, name: &str) -> [f64; 3] {
    let isg = t.to_isg_csv();
    let lines: Vec<&str> = isg.lines().filter(|l| !l.starts_with("//")).collect();
    let header = lines
        .iter()
        .position(|l| l.split_whitespace().any(|w| w == name))
        .unwrap();
    let col = lines[header]
        .split_whitespace()
        .position(|w| w == name)
        .unwrap();
    let isg_v: f64 = lines[header + 1]
        .split_whitespace()
        .nth(col)
        .unwrap()
        .parse()
        .unwrap();
    let etalon = t.to_etalon();
    let el: Vec<&str> = etalon.lines().collect();
    let at = el.iter().position(|l| *l == format!("[{name}]")).unwrap();
    let etalon_v: f64 = el[at + 1]
        .trim_start_matches("VALUE =")
        .trim()
        .parse()
        .unwrap();
    let plain = t.to_plain_csv();
    let row = plain
        .lines()
        .find(|l| l.starts_with(&format!("{name},")))
        .unwrap();
    let f: Vec<&str> = row.split(',').collect();
    assert_eq!(f[5], "urad", "{row}");
    let plain_v = f[4].parse::<f64>().unwrap() * 1e-6;
    [isg_v, etalon_v, plain_v]
}

fn machines() -> Vec<(&'static str, Machine)> {
    presets::PRESETS
        .iter()
        .map(|p| (p.name, p.machine().unwrap()))
        .collect()
}

#[test]
fn every_export_writes_each_squareness_with_iso_230_1_sign() {
    let mut checked = Vec::new();
    for (name, machine) in machines() {
        let linear: Vec<Axis> = machine
            .axes()
            .iter()
            .map(|a| a.axis)
            .filter(|a| !a.is_rotary())
            .collect();
        for &k in &linear {
            for r in [Axis::A, Axis::B, Axis::C] {
                if r.direction() == k.direction() {
                    continue;
                }
                let sq = format!("{r}0{k}");
                let text = format!("squareness = \"separate\"\n[[error]]\nname = \"{sq}\"\n");
                let model = Model::from_toml_str(machine.clone(), &text, "m.toml").unwrap();
                for theta in [85e-6, -40e-6] {
                    let mut p = model.initial_params();
                    p[model.param_index(&sq).unwrap()] = theta;
                    let iso = iso_angle(&model, &p, k, r);
                    // The geometric reading is exact to first order: 1e-3 of the angle.
                    assert!(
                        (iso.abs() - theta.abs()).abs() < 1e-3 * theta.abs(),
                        "{name} {sq}: line turned by {iso} for a parameter of {theta}"
                    );
                    let t = ErrorTables::from_model(&model, &p, 50.0, 10.0).unwrap();
                    for (format, v) in ["ISG", "Etalon", "plain CSV"].iter().zip(exported(&t, &sq))
                    {
                        assert!(
                            (v - iso).abs() < 2e-3 * theta.abs(),
                            "{name} {format} {sq}: exported {v}, ISO 230-1 angle {iso}"
                        );
                    }
                    let id: ErrorId = sq.parse().unwrap();
                    assert_eq!(id.iso_sign(), (iso / theta).signum(), "{name} {sq}");
                }
                checked.push(format!("{name}:{sq}"));
            }
        }
    }
    println!("checked {}: {checked:?}", checked.len());
    // Every one of the six names on at least one machine.
    for sq in ["C0X", "B0X", "C0Y", "A0Y", "B0Z", "A0Z"] {
        assert!(
            checked.iter().any(|c| c.ends_with(sq)),
            "{sq} never checked"
        );
    }
}

/// The tables as a control applies them give the model's tool point with a squareness of each
/// sign: writing ISO's sign and applying it are the same rule (no double flip).
#[test]
fn tables_with_iso_squareness_give_the_models_tool_point() {
    for (name, machine) in machines() {
        let text = "squareness = \"separate\"\n[[error]]\nname = [\"B0Z\", \"A0Z\"]\n";
        let Ok(model) = Model::from_toml_str(machine.clone(), text, "m.toml") else {
            continue; // a machine without Z
        };
        let mut p = model.initial_params();
        p[model.param_index("B0Z").unwrap()] = 60e-6;
        p[model.param_index("A0Z").unwrap()] = -30e-6;
        let t = ErrorTables::from_model(&model, &p, 50.0, 10.0).unwrap();
        let back = ErrorTables::from_isg_csv(&t.to_isg_csv(), "x.csv").unwrap();
        let mut c = Commands::default();
        for (i, a) in machine.axes().iter().enumerate() {
            c.0[i] = if a.axis.is_rotary() { 0.0 } else { a.max };
        }
        let tool = [0.0, 0.0, -100.0];
        let want = model.tool_point(&c.0, &tool, &p);
        let got = back.tool_point(&model, &c, &tool).unwrap();
        for i in 0..3 {
            assert!(
                (want[i] - got[i]).abs() < 1e-9,
                "{name}: {want:?} vs {got:?}"
            );
        }
    }
}
