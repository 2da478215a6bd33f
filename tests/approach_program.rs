//! Plans that measure reversal (issue 49): bidirectional plans and the measuring program's
//! approach moves, judged by LinuxCNC's RS274NGC interpreter `rs274` (tests/common/rs274.rs),
//! and the directions of approach carried from the plan file through `simulate` into the
//! measurement file.
//!
//! The judge reads the plan file independently of volver (its `approach_<AXIS>` columns) and
//! follows rs274's canonical moves: at every wait the machine is at the visit's pose, and each
//! axis whose direction the plan states arrived there moving in that direction over at least
//! the overrun, never leaving its travel; the clearance rules of the measuring program hold
//! (no rapid moves a clearance axis and another axis at once; the other axes move, rapid or at
//! feed, only with the clearance axes at the clearance; a feed move of a clearance axis moves
//! it alone; no rapid takes a clearance axis beyond the next pose, away from the clearance).

mod common;

use common::rs274::{self, AXES, Event, TOL};
use common::{ok, volver};
use std::path::{Path, PathBuf};
use volver::core::machine::Machine;
use volver::core::measure::MeasurementSet;
use volver::core::plan::Plan;
use volver::core::plan::sides::Overrun;

/// A fresh directory for one test.
fn dir(tag: &str) -> PathBuf {
    common::scratch_dir("approach", tag)
}

/// One visit of the plan file, read independently of volver: its pose (rs274's order) and
/// each axis' stated direction (rs274's order, 0: none).
#[derive(Clone, Debug, PartialEq)]
struct Visit {
    pose: [f64; 6],
    sides: [i8; 6],
}

/// The visits of a plan file: runs of rows at one pose with the same stated directions, each
/// reflector once per run.
fn visits_of(csv: &str) -> Vec<Visit> {
    let mut lines = csv.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name);
    let refl = column("reflector").unwrap();
    let mut out: Vec<(Visit, Vec<String>)> = Vec::new();
    for l in lines.filter(|l| !l.trim().is_empty()) {
        let f: Vec<&str> = l.split(',').collect();
        let mut v = Visit {
            pose: [0.0; 6],
            sides: [0; 6],
        };
        for (k, a) in AXES.iter().enumerate() {
            if let Some(c) = column(&a.to_string()) {
                v.pose[k] = f[c].parse().unwrap();
            }
            if let Some(c) = column(&format!("approach_{a}")) {
                v.sides[k] = f[c].trim_start_matches('+').parse().unwrap();
            }
        }
        let id = f[refl].to_string();
        match out.last_mut() {
            Some((last, ids)) if *last == v && !ids.contains(&id) => ids.push(id),
            _ => out.push((v, vec![id])),
        }
    }
    out.into_iter().map(|(v, _)| v).collect()
}

/// What the program must do.
struct Expect {
    visits: Vec<Visit>,
    /// The clearance position: (rs274 index, value).
    clearance: Vec<(usize, f64)>,
    /// Each axis' overrun (rs274's order: mm, degrees).
    overrun: [f64; 6],
    /// Each axis' travel (rs274's order).
    travel: [(f64, f64); 6],
}

/// What the judge saw.
#[derive(Debug, Default)]
struct Seen {
    /// Stated directions checked at the waits.
    approaches: usize,
    feeds: usize,
    waits: usize,
}

/// Each axis' current monotone run of motion: its direction and where it began.
#[derive(Clone, Copy, Default)]
struct Run {
    dir: i8,
    start: f64,
}

/// Judges rs274's events against `e`; the first violation is the error.
fn judge(events: &[Event], e: &Expect) -> Result<Seen, String> {
    let is_clear = |k: usize| e.clearance.iter().any(|c| c.0 == k);
    let at_clearance = |p: &[f64; 6]| e.clearance.iter().all(|&(k, v)| (p[k] - v).abs() < TOL);
    let mut seen = Seen::default();
    let mut pos = [0.0; 6];
    let mut runs = [Run::default(); 6];
    let mut first = true;
    for (i, ev) in events.iter().enumerate() {
        let (to, feed) = match ev {
            Event::Traverse(p) => (*p, false),
            Event::Feed(p, ..) => (*p, true),
            Event::Arc(_) => return Err(format!("event {i}: an arc")),
            Event::Dwell(_) | Event::Stop(_) if !matches!(ev, Event::Stop(s) if s == "PROGRAM_END") =>
            {
                let v = e
                    .visits
                    .get(seen.waits)
                    .ok_or(format!("event {i}: a wait too many"))?;
                arrived(v, &pos, &runs, e, i)?;
                seen.approaches += v.sides.iter().filter(|&&s| s != 0).count();
                seen.waits += 1;
                continue;
            }
            _ => continue,
        };
        let moved: Vec<usize> = (0..6).filter(|&k| (to[k] - pos[k]).abs() >= TOL).collect();
        let clear = moved.iter().filter(|&&k| is_clear(k)).count();
        if clear > 0 && clear < moved.len() {
            return Err(format!(
                "event {i}: a move from {pos:?} to {to:?} moves a clearance axis and another at once"
            ));
        }
        if clear == 0 && !moved.is_empty() && !at_clearance(&pos) && !first {
            return Err(format!(
                "event {i}: a move from {pos:?} to {to:?} moves the other axes away from the clearance"
            ));
        }
        if clear > 0 && !feed && !first {
            // No rapid beyond the next pose, away from the clearance.
            let next = &e.visits[seen.waits.min(e.visits.len() - 1)].pose;
            for &(k, c) in e.clearance.iter().filter(|c| moved.contains(&c.0)) {
                let beyond = if (c - next[k]).abs() < TOL {
                    (to[k] - next[k]).abs() >= TOL
                } else {
                    (to[k] - next[k]) * (c - next[k]) < -TOL
                };
                if beyond {
                    return Err(format!(
                        "event {i}: a rapid of axis {} to {} beyond the pose {}",
                        AXES[k], to[k], next[k]
                    ));
                }
            }
        }
        for &k in &moved {
            let (lo, hi) = e.travel[k];
            if to[k] < lo - TOL || to[k] > hi + TOL {
                return Err(format!(
                    "event {i}: axis {} to {} leaves its travel",
                    AXES[k], to[k]
                ));
            }
            let dir = if to[k] > pos[k] { 1 } else { -1 };
            if dir != runs[k].dir || first {
                runs[k] = Run { dir, start: pos[k] };
            }
        }
        seen.feeds += usize::from(feed);
        // rs274 starts at its origin, the machine anywhere: the first move is the retract.
        first = first && moved.iter().all(|&k| is_clear(k));
        pos = to;
    }
    if seen.waits != e.visits.len() {
        return Err(format!(
            "{} of {} visits measured",
            seen.waits,
            e.visits.len()
        ));
    }
    Ok(seen)
}

/// At the wait of visit `v` (event `i`): the machine at its pose, each stated axis arrived in
/// its direction over at least its overrun.
fn arrived(v: &Visit, pos: &[f64; 6], runs: &[Run; 6], e: &Expect, i: usize) -> Result<(), String> {
    if (0..6).any(|k| (pos[k] - v.pose[k]).abs() >= TOL) {
        return Err(format!(
            "event {i}: waits at {pos:?}, the pose is {:?}",
            v.pose
        ));
    }
    for k in (0..6).filter(|&k| v.sides[k] != 0) {
        let r = runs[k];
        let travelled = (pos[k] - r.start).abs();
        if r.dir != v.sides[k] || travelled < e.overrun[k] - TOL {
            return Err(format!(
                "event {i}: axis {} arrived at {} moving {:+} over {travelled}, the plan states {:+} over at least {}",
                AXES[k], pos[k], r.dir, v.sides[k], e.overrun[k]
            ));
        }
    }
    Ok(())
}

/// rs274's events of `program`.
/// `letters` (the machine's axes) with their overruns and travels in rs274's order.
fn layout(letters: &[(char, f64, f64)], mm: f64, deg: f64) -> ([f64; 6], [(f64, f64); 6]) {
    let mut overrun = [0.0; 6];
    let mut travel = [(0.0, 0.0); 6];
    for &(l, lo, hi) in letters {
        let k = AXES.iter().position(|a| *a == l).unwrap();
        overrun[k] = if "ABC".contains(l) { deg } else { mm };
        travel[k] = (lo, hi);
    }
    (overrun, travel)
}

/// A designed bidirectional plan on the XCFZ grinder (default overrun 5 mm and 1°): its plan
/// file states every axis' direction, each pose reached from below then from above (X, C and
/// Z moving), and rs274 sees every measurement made with each axis arriving in the stated
/// direction over at least the overrun, within the travel, the clearance rules kept. Its Fanuc
/// program moves the same; the program with the approach moves removed is refused by the
/// judge.
#[test]
fn a_bidirectional_plans_program_arrives_from_the_stated_sides() {
    if !rs274::require() {
        return;
    }
    let d = dir("xcfz");
    let p = |n: &str| d.join(n).to_string_lossy().into_owned();
    let out = ok(&[
        "plan",
        "--points",
        "40",
        "--per-axis",
        "4",
        "--repeats",
        "2",
        "--bidirectional",
        "--out",
        &p("plan.csv"),
        "--gcode",
        &p("plan.nc"),
    ]);
    assert!(
        out.contains("the measuring time doubled") && out.contains("80 measurements"),
        "{out}"
    );
    let csv = std::fs::read_to_string(p("plan.csv")).unwrap();
    let (overrun, travel) = layout(
        &[('X', 0.0, 1400.0), ('C', 0.0, 360.0), ('Z', 0.0, 600.0)],
        5.0,
        1.0,
    );
    let expect = Expect {
        visits: visits_of(&csv),
        clearance: vec![(2, 600.0)],
        overrun,
        travel,
    };
    // From below then from above: both signs on every moving axis.
    for k in [0, 2, 5] {
        assert!(
            expect.visits.iter().any(|v| v.sides[k] == 1)
                && expect.visits.iter().any(|v| v.sides[k] == -1)
        );
    }
    let events = rs274::interpret(Path::new(&p("plan.nc")), None);
    let seen = judge(&events, &expect).unwrap();
    assert_eq!(seen.approaches, 3 * expect.visits.len(), "{seen:?}");
    // The Fanuc program (decimal points, G01, G04 P in ms) moves the same once its number
    // line is dropped and its dwells are read in milliseconds.
    ok(&[
        "plan",
        "--plan-file",
        &p("plan.csv"),
        "--gcode",
        &p("fanuc.nc"),
        "--dialect",
        "fanuc",
    ]);
    let fanuc = std::fs::read_to_string(p("fanuc.nc")).unwrap();
    assert!(fanuc.contains("\nG91 G01 X5. ") || fanuc.contains("\nG91 G01 X-5. "));
    let translated: String = fanuc
        .lines()
        .filter(|l| !l.starts_with("O0"))
        .map(|l| match l.strip_prefix("G04 P") {
            Some(rest) => {
                let (ms, comment) = rest.split_once(' ').unwrap_or((rest, ""));
                format!("G4 P{} {comment}\n", ms.parse::<f64>().unwrap() / 1000.0)
            }
            None => format!("{l}\n"),
        })
        .collect();
    std::fs::write(p("fanuc.ngc"), translated).unwrap();
    assert_eq!(rs274::interpret(Path::new(&p("fanuc.ngc")), None), events);
    // Without its approach moves (the feed blocks), the program is refused.
    let nc = std::fs::read_to_string(p("plan.nc")).unwrap();
    let bare: String = nc
        .lines()
        .filter(|l| !l.starts_with("G91") && *l != "G90")
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(p("bare.nc"), bare).unwrap();
    let e = judge(&rs274::interpret(Path::new(&p("bare.nc")), None), &expect).unwrap_err();
    assert!(e.contains("arrived at") || e.contains("waits at"), "{e}");
    let _ = std::fs::remove_dir_all(&d);
}

/// A hand-written plan file on the head–head preset with a two-axis clearance (Z = 550 and the
/// rotary A = 0) and an overrun of 2 mm and 0.5°: some axes stated, some not, the rotary
/// clearance axis approached from both sides, a pose at the top of Z approached from below,
/// one at A's clearance value approached from each side, a stated direction repeated at one pose
/// (no move between) — rs274 sees each stated axis arrive as stated over its overrun.
#[test]
fn a_plan_file_with_stated_sides_on_the_head_head_preset() {
    if !rs274::require() {
        return;
    }
    let d = dir("head-head");
    let p = |n: &str| d.join(n).to_string_lossy().into_owned();
    let csv = "X,Y,Z,C,A,reflector,approach_X,approach_Z,approach_A\n\
               1000,600,300,0,30,R1,+1,+1,-1\n\
               1000,600,300,0,30,R2,+1,+1,-1\n\
               1000,600,300,0,30,R1,-1,-1,+1\n\
               500,200,600,90,0,R1,+1,+1,+1\n\
               500,200,600,90,0,R2,-1,+1,-1\n\
               500,200,100,-90,0,R3,0,-1,0\n\
               2000,1200,0,45,-100,R1,+1,-1,-1\n";
    std::fs::write(p("plan.csv"), csv).unwrap();
    let out = ok(&[
        "plan",
        "--machine",
        "head-head",
        "--plan-file",
        &p("plan.csv"),
        "--gcode",
        &p("plan.nc"),
        "--clearance",
        "Z=550,A=0",
        "--overrun",
        "2",
        "--overrun-deg",
        "0.5",
        "--approach-feed",
        "800",
    ]);
    assert!(out.contains("states directions of approach"), "{out}");
    let (overrun, travel) = layout(
        &[
            ('X', 0.0, 2000.0),
            ('Y', 0.0, 1200.0),
            ('Z', 0.0, 600.0),
            ('C', -180.0, 180.0),
            ('A', -100.0, 100.0),
        ],
        2.0,
        0.5,
    );
    let expect = Expect {
        visits: visits_of(csv),
        clearance: vec![(2, 550.0), (3, 0.0)],
        overrun,
        travel,
    };
    let events = rs274::interpret(Path::new(&p("plan.nc")), None);
    let seen = judge(&events, &expect).unwrap();
    assert_eq!(expect.visits.len(), 6);
    assert_eq!(seen.approaches, 3 + 3 + 3 + 3 + 1 + 3, "{seen:?}");
    // Every feed move is at the approach feed.
    assert!(
        events
            .iter()
            .all(|e| !matches!(e, Event::Feed(_, _, f) if (*f - 800.0).abs() > 1e-9))
    );
    // An approach that would leave the travel is refused, naming the row and the axis.
    std::fs::write(
        p("bad.csv"),
        "X,Y,Z,C,A,reflector,approach_X\n0,0,0,0,0,R1,+1\n",
    )
    .unwrap();
    let o = volver(&[
        "plan",
        "--machine",
        "head-head",
        "--plan-file",
        &p("bad.csv"),
        "--gcode",
        &p("bad.nc"),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("plan row 1: axis X at 0 mm"),
        "{err}"
    );
    assert!(!Path::new(&p("bad.nc")).exists());
    let _ = std::fs::remove_dir_all(&d);
}

/// The directions a plan file states reach the measurement file: a bidirectional plan written
/// by `volver plan`, measured by `simulate --plan-file`, read back: every point's direction is
/// the plan's row's (the measurement file carries them in approach_<AXIS> columns, which its
/// order alone would not give). `simulate --plan test3 --order bidirectional` carries the
/// directions of the bidirectional test 3 into its file the same way.
#[test]
fn stated_directions_survive_the_round_trip_through_simulate() {
    let d = dir("round-trip");
    let p = |n: &str| d.join(n).to_string_lossy().into_owned();
    ok(&[
        "plan",
        "--points",
        "30",
        "--per-axis",
        "4",
        "--repeats",
        "2",
        "--bidirectional",
        "--out",
        &p("plan.csv"),
    ]);
    let csv = std::fs::read_to_string(p("plan.csv")).unwrap();
    common::simulate(&p("sim"), &["--plan-file", &p("plan.csv"), "--seed", "5"]);
    let meas = std::fs::read_to_string(d.join("sim/measurements.csv")).unwrap();
    let machine = Machine::default_xcfz();
    let plan = volver::core::plan::file::from_csv_str(&machine, &csv, "plan.csv").unwrap();
    let set = MeasurementSet::from_csv_str(&machine, &meas, "measurements.csv").unwrap();
    let stated = plan.approaches(1);
    let read: Vec<_> = set.points.iter().map(|p| p.approach).collect();
    assert_eq!(read, stated);
    assert!(
        meas.lines().any(|l| l.contains("approach_X")
            && l.contains("approach_C")
            && l.contains("approach_Z"))
    );
    // A preset measured from both sides by simulate itself: the directions of
    // Plan::bidirectional, in the file.
    common::simulate(
        &p("both"),
        &["--plan", "test3", "--order", "bidirectional", "--seed", "5"],
    );
    let meas = std::fs::read_to_string(d.join("both/measurements.csv")).unwrap();
    let set = MeasurementSet::from_csv_str(&machine, &meas, "measurements.csv").unwrap();
    let both = Plan::preset(&machine, "test3")
        .unwrap()
        .bidirectional(&machine, &Overrun::default())
        .unwrap();
    let read: Vec<_> = set.points.iter().map(|p| p.approach).collect();
    assert_eq!(read, both.approaches(1));
    assert_eq!(read.len(), 2 * 216 * 2);
    let _ = std::fs::remove_dir_all(&d);
}

/// A bidirectional test 3 (each of its 432 measurements made from below, then from above: 864)
/// with a reversal value of 12 µm hidden on X (seed 4, the truth of the paper's model, normal
/// noise σ = 2 µrad, 2 µrad, 1 µm + 0.2 µm/m), identified with the paper's model and
/// `[effects] reversal = ["X"]`: the identified B is within its U (k = 2) of 12 µm, and that U
/// is below 1 µm (a B the data did not determine would not pass; test 3 in its grid order gives 10.7 ± 10.4 µm).
#[test]
fn a_bidirectional_test_recovers_a_hidden_reversal_within_its_u() {
    let d = dir("reversal");
    let p = |n: &str| d.join(n).to_string_lossy().into_owned();
    let noise = "normal:2,2,1,0.2";
    let paper = "core/data/xcfz-paper-model.toml";
    common::simulate(
        &p("sim"),
        &[
            "--plan",
            "test3",
            "--order",
            "bidirectional",
            "--seed",
            "4",
            "--effect",
            "reversal=X,12",
            "--noise",
            noise,
            "--truth-model",
            paper,
        ],
    );
    let model = std::fs::read_to_string(paper).unwrap() + "\n[effects]\nreversal = [\"X\"]\n";
    std::fs::write(p("m.toml"), model).unwrap();
    ok(&[
        "identify",
        "--data",
        &p("sim/measurements.csv"),
        "--machine",
        &p("sim/machine.toml"),
        "--model",
        &p("m.toml"),
        "--noise",
        noise,
        "--out",
        &p("fit.json"),
    ]);
    let fit: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(p("fit.json")).unwrap()).unwrap();
    let params = fit["parameters"].as_array().unwrap();
    let j = params
        .iter()
        .position(|q| q["name"] == "reversal.X.b")
        .unwrap();
    let b_um = params[j]["value"].as_f64().unwrap() * 1e3;
    let u = &fit["uncertainty"];
    let variance: f64 = ["data_factor", "held_factor"]
        .iter()
        .flat_map(|f| u[f].as_array().unwrap())
        .map(|col| col[j].as_f64().unwrap().powi(2))
        .sum();
    let u95_um = 2.0 * variance.sqrt() * 1e3;
    assert!(
        (b_um - 12.0).abs() <= u95_um && u95_um < 1.0,
        "B = {b_um:.2} µm, U = {u95_um:.2} µm, truth 12 µm"
    );
    let _ = std::fs::remove_dir_all(&d);
}
