//! The directions of approach of real data taken by a bidirectional plan (issue 49): a tracker's
//! export records no direction, and the order of its rows (each pose measured twice, from below
//! then from above, with an overrun between) does not give them. `--plan-file` takes them from
//! the plan file the data were taken by. Here a bidirectional grid plan's file is written,
//! `simulate --plan-file` measures it with hidden reversals of X (12 µm) and C (−25 µrad), and
//! its `approach_<AXIS>` columns are stripped as a tracker's export would lack them:
//!
//! - without `--plan-file` the directions are the rows' order's and wrong: B is not found and
//!   the fit stays far above the noise;
//! - with it, `identify` finds each B within its U (k = 2) and ends where the simulator's own
//!   columns end (the same EMM to 1e-6 µm);
//! - data that are not the plan's rows in its order, and a measurement file's direction that
//!   contradicts the plan's, are refused at their line.

mod common;

use common::volver;
use std::path::{Path, PathBuf};
use volver::core::machine::Machine;
use volver::core::plan::sides::Overrun;
use volver::core::plan::{Plan, file};

/// A scratch directory of its own for each test: the two run in parallel in one process.
fn dir(tag: &str) -> PathBuf {
    common::scratch_dir("plan-directions", tag)
}

/// `identify` of `data` with the reversal model, `extra` arguments: its stdout (or stderr when
/// it fails) and whether it succeeded.
fn identify(d: &Path, data: &str, extra: &[&str]) -> (bool, String) {
    let p = |f: &str| d.join(f).display().to_string();
    let mut args = vec![
        "identify".to_string(),
        "--machine".into(),
        p("sim/machine.toml"),
        "--model".into(),
        p("model.toml"),
        "--data".into(),
        p(data),
        "--out".into(),
        p("fit.json"),
    ];
    args.extend(extra.iter().map(|s| s.to_string()));
    let a: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = volver(&a);
    let text = if o.status.success() {
        &o.stdout
    } else {
        &o.stderr
    };
    (
        o.status.success(),
        String::from_utf8_lossy(text).to_string(),
    )
}

/// The final EMM (µm) an identify output prints.
fn final_emm(out: &str) -> f64 {
    let line = out
        .lines()
        .find(|l| l.trim_start().starts_with("final:"))
        .unwrap();
    line.split("EMM")
        .nth(1)
        .unwrap()
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap()
}

/// The fit's reversal values: (X in µm, C in µrad) and their U (k = 2) from the results file.
fn reversals(d: &Path) -> [(f64, f64); 2] {
    let r = volver::core::results::ResultsFile::load(&d.join("fit.json")).unwrap();
    let (model, p) = r.clone().to_model("fit.json").unwrap();
    let cov = r.uncertainty.as_ref();
    ["reversal.X.b", "reversal.C.b"].map(|name| {
        let j = model.param_index(name).unwrap();
        let scale = if name.contains(".C.") { 1e6 } else { 1e3 };
        // U (k = 2) from the record's factors (columns, data and held: the covariance F Fᵀ).
        let u = cov.map_or(f64::NAN, |u| {
            let sq = |f: &Vec<Vec<f64>>| f.iter().map(|col| col[j] * col[j]).sum::<f64>();
            2.0 * (sq(&u.data_factor) + sq(&u.held_factor)).sqrt()
        });
        (p[j] * scale, u * scale)
    })
}

/// A measurement file with its `approach_` columns removed, as a tracker's export.
fn strip(text: &str) -> String {
    let rows: Vec<Vec<&str>> = text.lines().map(|l| l.split(',').collect()).collect();
    let keep: Vec<usize> = (0..rows[0].len())
        .filter(|&i| !rows[0][i].starts_with("approach_"))
        .collect();
    rows.iter()
        .map(|r| keep.iter().map(|&i| r[i]).collect::<Vec<_>>().join(",") + "\n")
        .collect()
}

#[test]
fn the_plan_file_gives_an_exports_directions_of_approach() {
    let d = dir("export");
    let m = Machine::default_xcfz();
    let grid = Plan::parse_grid(&m, "X=0:1400:200,C=0:300:60,Z=0:600:300").unwrap();
    let plan = grid.bidirectional(&m, &Overrun::default()).unwrap();
    std::fs::write(
        d.join("plan.csv"),
        file::to_csv(&plan, &m, "bidirectional grid"),
    )
    .unwrap();
    let model = format!(
        "{}\n[effects]\nreversal = [\"X\", \"C\"]\n",
        volver::core::model::DEFAULT_MODEL_TOML
    );
    std::fs::write(d.join("model.toml"), model).unwrap();
    let p = |f: &str| d.join(f).display().to_string();
    common::simulate(
        &p("sim"),
        &[
            "--plan-file",
            &p("plan.csv"),
            "--seed",
            "6",
            "--effect",
            "reversal=X,12",
            "--effect",
            "reversal=C,-25",
            "--noise",
            "normal:2,2,1,0.2",
        ],
    );
    let stated = std::fs::read_to_string(d.join("sim/measurements.csv")).unwrap();
    assert!(stated.lines().next().unwrap().contains("approach_X"));
    std::fs::write(d.join("export.csv"), strip(&stated)).unwrap();

    let (ok, own) = identify(&d, "sim/measurements.csv", &[]);
    assert!(ok, "{own}");
    let (ok, blind) = identify(&d, "export.csv", &[]);
    assert!(ok, "{blind}");
    let [(bx, _), _] = reversals(&d);
    let (ok, planned) = identify(&d, "export.csv", &["--plan-file", &p("plan.csv")]);
    assert!(ok, "{planned}");
    let [(x, ux), (c, uc)] = reversals(&d);
    let (e_own, e_blind, e_plan) = (final_emm(&own), final_emm(&blind), final_emm(&planned));
    println!(
        "{} measurements; EMM: the simulator's columns {e_own} µm, the export alone {e_blind} µm (B_X {bx:.2} µm), \
         with --plan-file {e_plan} µm; B_X {x:.2} ± {ux:.2} µm, B_C {c:.2} ± {uc:.2} µrad",
        stated.lines().count() - 1
    );
    assert!((e_plan - e_own).abs() < 1e-6, "{e_plan} against {e_own}");
    assert!(e_blind > 2.0 * e_plan, "{e_blind} against {e_plan}");
    assert!((bx - 12.0).abs() > 5.0, "the export's order found B_X {bx}");
    assert!((x - 12.0).abs() <= ux && ux < 2.0, "B_X {x} ± {ux}");
    assert!((c + 25.0).abs() <= uc && uc < 4.0, "B_C {c} ± {uc}");

    // Not this plan's rows: another grid's plan file.
    let other = Plan::parse_grid(&m, "X=0:1400:100,C=0:300:60,Z=0:600:300")
        .unwrap()
        .bidirectional(&m, &Overrun::default())
        .unwrap();
    std::fs::write(d.join("other.csv"), file::to_csv(&other, &m, "another")).unwrap();
    let (ok, e) = identify(&d, "export.csv", &["--plan-file", &p("other.csv")]);
    assert!(
        !ok && e.contains("measurements") && e.contains("the plan"),
        "{e}"
    );
    // The plan's rows in the reverse order: the data's first row is not the plan's first.
    let reversed_rows = Plan {
        sequence: Some(plan.steps().into_iter().rev().collect()),
        approach: plan
            .approach
            .as_ref()
            .map(|a| a.iter().rev().copied().collect()),
        ..plan.clone()
    };
    std::fs::write(
        d.join("reversed.csv"),
        file::to_csv(&reversed_rows, &m, "reversed"),
    )
    .unwrap();
    let (ok, e) = identify(&d, "export.csv", &["--plan-file", &p("reversed.csv")]);
    assert!(
        !ok && e.contains("export.csv:2") && e.contains("not taken by this plan"),
        "{e}"
    );

    // A measurement file's direction the plan contradicts: X's first row flipped.
    let mut lines: Vec<String> = stated.lines().map(String::from).collect();
    let col = lines[0].split(',').position(|h| h == "approach_X").unwrap();
    let mut cells: Vec<String> = lines[1].split(',').map(String::from).collect();
    cells[col] = if cells[col] == "+1" {
        "-1".into()
    } else {
        "+1".into()
    };
    lines[1] = cells.join(",");
    std::fs::write(d.join("contra.csv"), lines.join("\n") + "\n").unwrap();
    let (ok, e) = identify(&d, "contra.csv", &["--plan-file", &p("plan.csv")]);
    assert!(
        !ok && e.contains("contra.csv:2") && e.contains("contradicting directions"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&d);
}

/// A plan that states no direction is measured as volver's measuring program moves: its
/// clearance axis Z, retracted between poses, arrives from the clearance's side whatever the
/// plan's order says. Judged by LinuxCNC's `rs274`: the program `plan --gcode` writes is
/// interpreted, and at each wait (one per pose, its reflectors measured there) each axis'
/// direction is the sign of its last move in rs274's canonical moves; the directions
/// `simulate --plan-file` gives the measurements (its file's `approach_` columns, else the
/// order's, read back) are those, for every axis of every measurement after the axis' first move.
#[test]
fn a_plan_is_measured_in_the_directions_its_program_moves() {
    if !common::rs274::require() {
        return;
    }
    let d = dir("program");
    let m = Machine::default_xcfz();
    // Z up and down with X and C changing: the order's Z directions are both, the program's
    // only from the clearance (Z = 600) down, but at Z = 600 itself.
    let plan = Plan::parse_grid(
        &m,
        "X=0,C=0,Z=0;X=700,C=90,Z=300;X=0,C=180,Z=150;X=1400,C=90,Z=450;X=700,C=0,Z=600;X=0,C=90,Z=300",
    )
    .unwrap();
    std::fs::write(d.join("plan.csv"), file::to_csv(&plan, &m, "no direction")).unwrap();
    let p = |f: &str| d.join(f).display().to_string();
    common::ok(&[
        "plan",
        "--plan-file",
        &p("plan.csv"),
        "--gcode",
        &p("plan.nc"),
    ]);
    common::simulate(&p("sim"), &["--plan-file", &p("plan.csv"), "--seed", "2"]);
    let data =
        volver::core::measure::MeasurementSet::load(&m, &d.join("sim/measurements.csv")).unwrap();
    let events = common::rs274::interpret(&d.join("plan.nc"), None);
    // rs274's order is X Y Z A B C; the machine's chain XCFZ.
    let slot = |k: usize| match m.axes()[k].axis.letter() {
        'X' => 0,
        'Z' => 2,
        _ => 5,
    };
    let (mut now, mut dir, mut waits) = ([f64::NAN; 6], [0i8; 6], Vec::new());
    for e in &events {
        use common::rs274::Event;
        match e {
            Event::Traverse(to) | Event::Feed(to, _, _) => {
                for j in 0..6 {
                    if (to[j] - now[j]).abs() > 1e-6 {
                        dir[j] = if to[j] > now[j] { 1 } else { -1 };
                    }
                }
                now = *to;
            }
            Event::Dwell(_) => waits.push(dir),
            _ => {}
        }
    }
    assert_eq!(waits.len(), plan.positions.len(), "one wait per pose");
    println!(
        "rs274: {} waits, Z directions {:?}",
        waits.len(),
        waits.iter().map(|w| w[2]).collect::<Vec<_>>()
    );
    let mut order_z_both = [false; 2];
    for (i, pt) in data.points.iter().enumerate() {
        let seen = waits[i / 2]; // two reflectors at each pose
        for k in 0..3 {
            if i / 2 == 0 && seen[slot(k)] == 0 {
                continue; // before the axis' first move: assumed
            }
            assert_eq!(
                pt.approach.0[k],
                seen[slot(k)],
                "line {}: axis {} arrived {} in rs274's moves",
                pt.line,
                m.axes()[k].axis,
                seen[slot(k)]
            );
        }
    }
    for a in plan.approaches(1) {
        order_z_both[usize::from(a.0[2] > 0)] = true;
    }
    assert_eq!(
        order_z_both,
        [true, true],
        "the order alone would give Z both sides"
    );
}
