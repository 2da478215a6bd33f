//! The measuring program of `volver plan --gcode`, judged by LinuxCNC's RS274NGC interpreter
//! `rs274` (Debian `linuxcnc-uspace`, see tests/common/rs274.rs): for designed plans and plan
//! files on the XCFZ grinder and the five-axis presets, the interpreter runs it without an error,
//! reaches every visit's pose in the plan file's order, passes through the clearance position
//! between poses (no rapid moves a clearance axis and another axis at once; every move of the
//! other axes starts with the clearance axes at the clearance), waits at each pose the plan's
//! measuring time (the dwells add up to the plan's duration) or stops there, and ends retracted.
//! The Fanuc dialect is checked by Fanuc's own rules (framing, `G04 P` in integer milliseconds,
//! decimal points, one M word per block) and, translated to RS274NGC by those rules, runs as the
//! LinuxCNC program does.

mod common;

use common::rs274::{self, AXES, Event, TOL, interpret};
use common::{ok, volver};
use std::path::{Path, PathBuf};

/// A fresh directory for one test.
fn dir(tag: &str) -> PathBuf {
    common::scratch_dir("mprog", tag)
}

/// Runs volver with `args`, expecting a refusal; returns its stderr.
fn refused(args: &[&str]) -> String {
    let o = volver(args);
    assert!(!o.status.success(), "volver {args:?} was not refused");
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A position in rs274's order (X Y Z A B C) from letters and values; absent axes are 0.
fn six(letters: &[char], values: &[f64]) -> [f64; 6] {
    let mut p = [0.0; 6];
    for (l, v) in letters.iter().zip(values) {
        p[AXES.iter().position(|a| a == l).unwrap()] = *v;
    }
    p
}

/// The visits of a plan file read independently of volver: runs of rows at one pose, each
/// reflector once per run; each as (pose in rs274's order, reflectors measured).
fn visits_of(csv: &str) -> Vec<([f64; 6], usize)> {
    let mut lines = csv.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let axis_cols: Vec<(usize, char)> = header
        .iter()
        .enumerate()
        .filter_map(|(i, h)| {
            let c = h.chars().next()?;
            (h.len() == 1 && AXES.contains(&c)).then_some((i, c))
        })
        .collect();
    let refl = header.iter().position(|h| *h == "reflector").unwrap();
    let mut out: Vec<([f64; 6], Vec<String>)> = Vec::new();
    for l in lines.filter(|l| !l.trim().is_empty()) {
        let f: Vec<&str> = l.split(',').collect();
        let letters: Vec<char> = axis_cols.iter().map(|c| c.1).collect();
        let values: Vec<f64> = axis_cols.iter().map(|c| f[c.0].parse().unwrap()).collect();
        let pose = six(&letters, &values);
        let id = f[refl].to_string();
        match out.last_mut() {
            Some((p, ids)) if *p == pose && !ids.contains(&id) => ids.push(id),
            _ => out.push((pose, vec![id])),
        }
    }
    out.into_iter().map(|(p, ids)| (p, ids.len())).collect()
}

/// How the program is expected to wait at each visit.
#[derive(Clone, Copy, Debug)]
enum Waiting {
    /// A dwell of `settle + spp × reflectors` (s).
    Time { spp: f64, settle: f64 },
    /// A dwell of `settle` when positive, then a stop (`optional`: M1).
    Stop { optional: bool, settle: f64 },
}

/// What the program must do: the visits in order, the clearance (rs274 index, value), the waits.
struct Expect {
    visits: Vec<([f64; 6], usize)>,
    clearance: Vec<(usize, f64)>,
    waiting: Waiting,
}

/// What the judge saw.
#[derive(Debug, Default)]
struct Seen {
    traverses: usize,
    lateral: usize,
    dwell_s: f64,
    stops: usize,
}

/// Whether two positions agree to rs274's printed precision.
fn same(a: &[f64; 6], b: &[f64; 6]) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() < TOL)
}

/// Judges rs274's events of a measuring program against `e`; the first violation is the error.
fn judge(events: &[Event], e: &Expect) -> Result<Seen, String> {
    let is_clear = |k: usize| e.clearance.iter().any(|c| c.0 == k);
    let at_clearance = |p: &[f64; 6]| e.clearance.iter().all(|&(k, v)| (p[k] - v).abs() < TOL);
    let mut seen = Seen::default();
    // rs274 starts at its origin; the real machine is anywhere, so the first move that is not
    // a retract is a violation (the check below: it would not start at the clearance).
    let mut pos = [0.0; 6];
    let mut next_visit = 0;
    let mut pending_settle = false;
    for (i, ev) in events.iter().enumerate() {
        match ev {
            Event::Traverse(p) => {
                seen.traverses += 1;
                let moved: Vec<usize> = (0..6).filter(|&k| (p[k] - pos[k]).abs() >= TOL).collect();
                let clear = moved.iter().filter(|&&k| is_clear(k)).count();
                if clear > 0 && clear < moved.len() {
                    return Err(format!(
                        "event {i}: a rapid from {pos:?} to {p:?} moves a clearance axis and \
                         another at once"
                    ));
                }
                if clear == 0 && !moved.is_empty() {
                    seen.lateral += 1;
                    if !at_clearance(&pos) {
                        return Err(format!(
                            "event {i}: a rapid from {pos:?} to {p:?} moves the other axes \
                             away from the clearance"
                        ));
                    }
                }
                pos = *p;
            }
            Event::Feed(..) | Event::Arc(..) => {
                return Err(format!("event {i}: a feed move in a measuring program"));
            }
            Event::Dwell(t) => {
                seen.dwell_s += t;
                measure(e, &mut next_visit, &pos, i, Some(*t), &mut pending_settle)?;
            }
            Event::Stop(name) if name != "PROGRAM_END" => {
                seen.stops += 1;
                let optional = name == "OPTIONAL_PROGRAM_STOP";
                if !matches!(e.waiting, Waiting::Stop { optional: o, .. } if o == optional) {
                    return Err(format!("event {i}: {name} where {:?} was asked", e.waiting));
                }
                measure(e, &mut next_visit, &pos, i, None, &mut pending_settle)?;
            }
            _ => {}
        }
    }
    if next_visit != e.visits.len() || pending_settle {
        return Err(format!(
            "{next_visit} of {} visits measured",
            e.visits.len()
        ));
    }
    if !at_clearance(&pos) {
        return Err(format!("the program ends at {pos:?}, not at the clearance"));
    }
    Ok(seen)
}

/// One wait event (`dwell`: its seconds; `None`: a stop) at `pos`: it must be at the pose of
/// the next visit and last what the plan says.
fn measure(
    e: &Expect,
    next: &mut usize,
    pos: &[f64; 6],
    i: usize,
    dwell: Option<f64>,
    pending_settle: &mut bool,
) -> Result<(), String> {
    let Some(&(pose, reflectors)) = e.visits.get(*next) else {
        return Err(format!("event {i}: a wait after the last visit"));
    };
    if !same(pos, &pose) {
        return Err(format!(
            "event {i}: visit {} waits at {pos:?}, its pose is {pose:?}",
            *next + 1
        ));
    }
    let close = |t: f64, want: f64| (t - want).abs() < 5e-4;
    match (e.waiting, dwell) {
        (Waiting::Time { spp, settle }, Some(t)) => {
            if !close(t, settle + spp * reflectors as f64) {
                return Err(format!(
                    "event {i}: visit {} of {reflectors} reflectors dwells {t} s",
                    *next + 1
                ));
            }
            *next += 1;
        }
        (Waiting::Stop { settle, .. }, Some(t)) if settle > 0.0 && !*pending_settle => {
            if !close(t, settle) {
                return Err(format!(
                    "event {i}: a settling dwell of {t} s, not {settle}"
                ));
            }
            *pending_settle = true;
        }
        (Waiting::Stop { settle, .. }, None) if (settle > 0.0) == *pending_settle => {
            *pending_settle = false;
            *next += 1;
        }
        (w, d) => return Err(format!("event {i}: wait {d:?} where {w:?} was asked")),
    }
    Ok(())
}

/// Whether two runs' events are the same to rs274's printed precision (the machine positions
/// of a run with an offset carry the offset's rounding).
fn alike(a: &[Event], b: &[Event]) -> bool {
    a.len() == b.len()
        && a.iter().zip(b).all(|pair| match pair {
            (Event::Traverse(p), Event::Traverse(q)) => same(p, q),
            (x, y) => x == y,
        })
}

/// rs274's events of `program`, with the parameter file `vars` (a work offset) when given.
/// The plan's duration (s) that `plan --json` printed.
fn duration_s(json: &str) -> f64 {
    let v: serde_json::Value = serde_json::from_str(json).unwrap();
    v["duration_h"].as_f64().unwrap() * 3600.0
}

/// Checks a Fanuc-dialect program by Fanuc's rules and returns it translated to RS274NGC by
/// those rules (the `O` line dropped, `G04 P<ms>` as `G4 P<s>`), or the first rule broken.
/// The rules: `%` first and last, the program number `O` + 1–4 digits second, `M30` before the
/// last `%`; comments in parentheses, not nested; at most one M word per block; every axis
/// value with a decimal point (without one it is read in the least input increment); a dwell
/// is `G04 P` with an integer of milliseconds (P takes no decimal point), at most 8 digits.
fn fanuc_rules(text: &str) -> Result<String, String> {
    let lines: Vec<&str> = text.lines().collect();
    let n = lines.len();
    if n < 4 || lines[0] != "%" || lines[n - 1] != "%" || lines[n - 2] != "M30" {
        return Err("framing: % first, M30 then % last".into());
    }
    let number = lines[1].strip_prefix('O').unwrap_or("");
    if !(1..=4).contains(&number.len()) || !number.bytes().all(|b| b.is_ascii_digit()) {
        return Err(format!("line 2 '{}' is no program number O####", lines[1]));
    }
    let mut out = vec!["%".to_string()];
    for (i, line) in lines.iter().enumerate().take(n - 1).skip(2) {
        let (code, comment) = line.split_once('(').unwrap_or((line, ""));
        if !comment.is_empty() && (comment.matches(')').count() != 1 || !comment.ends_with(')'))
            || comment.contains('(')
        {
            return Err(format!("line {}: comment not closed once: {line}", i + 1));
        }
        let words: Vec<&str> = code.split_whitespace().collect();
        if words.iter().filter(|w| w.starts_with('M')).count() > 1 {
            return Err(format!("line {}: two M words in one block: {line}", i + 1));
        }
        let mut block: Vec<String> = Vec::new();
        for w in &words {
            let (letter, value) = w.split_at(1);
            if "XYZABC".contains(letter) && !value.contains('.') {
                return Err(format!("line {}: {w} has no decimal point", i + 1));
            }
            block.push(w.to_string());
        }
        if let Some(g) = words.iter().position(|w| *w == "G04" || *w == "G4") {
            let p = words.iter().find_map(|w| w.strip_prefix('P'));
            let ms = match p {
                Some(ms) if ms.bytes().all(|b| b.is_ascii_digit()) && ms.len() <= 8 => ms,
                _ => {
                    return Err(format!(
                        "line {}: a dwell needs P<integer ms>: {line}",
                        i + 1
                    ));
                }
            };
            block = vec![format!("G4 P{}", ms.parse::<f64>().unwrap() / 1000.0)];
            if words.len() != 2 || g != 0 {
                return Err(format!(
                    "line {}: a dwell block holds G04 P only: {line}",
                    i + 1
                ));
            }
        }
        if !comment.is_empty() {
            block.push(format!("({comment}"));
        }
        out.push(block.join(" "));
    }
    out.push("%".to_string());
    Ok(out.join("\n") + "\n")
}

/// The rs274 events of a Fanuc program, read by [`fanuc_rules`] (which it must pass).
fn interpret_fanuc(path: &Path) -> Vec<Event> {
    let text = std::fs::read_to_string(path).unwrap();
    let translated = fanuc_rules(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
    let out = path.with_extension("ngc");
    std::fs::write(&out, translated).unwrap();
    interpret(&out, None)
}

/// A hand-made plan file: the reference pose (the first of `poses`, values in `letters` order)
/// measured with every reflector first, in the middle and last; the other poses in a shuffled
/// order (seeded), each measuring some of `reflectors` in a rotated order; one visit repeated at
/// once (the same pose and reflector again) and one pose that differs from the one before only
/// in Z (+50 mm: the plan's Z values leave room).
fn plan_file(letters: &[char], poses: &[Vec<f64>], reflectors: &[&str], seed: u64) -> String {
    let mut order: Vec<usize> = (1..poses.len()).collect();
    let mut s = seed;
    for i in (1..order.len()).rev() {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        order.swap(i, (s >> 33) as usize % (i + 1));
    }
    let z = letters.iter().position(|&l| l == 'Z').unwrap();
    let mut rows: Vec<(Vec<f64>, &str)> =
        reflectors.iter().map(|r| (poses[0].clone(), *r)).collect();
    for (k, &p) in order.iter().enumerate() {
        let m = reflectors.len();
        let ids: Vec<&str> = (0..1 + k % m)
            .map(|j| reflectors[(k + m - j) % m])
            .collect();
        rows.extend(ids.iter().map(|r| (poses[p].clone(), *r)));
        if k == 1 {
            rows.push((poses[p].clone(), ids[0])); // the same visit again
        }
        if k == 2 {
            let mut up = poses[p].clone();
            up[z] += 50.0;
            rows.push((up, reflectors[0])); // only Z changes
        }
        if k == order.len() / 2 {
            rows.extend(reflectors.iter().map(|r| (poses[0].clone(), *r)));
        }
    }
    rows.extend(reflectors.iter().map(|r| (poses[0].clone(), *r)));
    let mut text = format!(
        "# a hand-made plan\norder,{},reflector\n",
        letters
            .iter()
            .map(char::to_string)
            .collect::<Vec<_>>()
            .join(",")
    );
    for (i, (pose, r)) in rows.iter().enumerate() {
        let v: Vec<String> = pose.iter().map(f64::to_string).collect();
        text.push_str(&format!("{},{},{r}\n", i + 1, v.join(",")));
    }
    text
}

/// The program of a designed plan on the XCFZ grinder (two reflectors, a shuffled order, the
/// reference pose visited five times): rs274 sees it retract Z to 600 before every move of X
/// and C, reach every visit's pose in the plan file's order, and dwell 10 s per reflector: the
/// plan's duration. The same plan through `--plan-file` gives the same machine motion, and its
/// Fanuc program passes Fanuc's rules and, read by them, moves and waits the same.
#[test]
fn a_designed_plan_on_the_xcfz_grinder_is_safe_and_takes_the_plans_time() {
    if !rs274::require() {
        return;
    }
    let d = dir("xcfz");
    let p = |n: &str| d.join(n).to_string_lossy().into_owned();
    let json = ok(&[
        "plan",
        "--points",
        "60",
        "--per-axis",
        "4",
        "--repeats",
        "3",
        "--out",
        &p("plan.csv"),
        "--gcode",
        &p("plan.nc"),
        "--json",
    ]);
    let csv = std::fs::read_to_string(p("plan.csv")).unwrap();
    let expect = Expect {
        visits: visits_of(&csv),
        clearance: vec![(2, 600.0)],
        waiting: Waiting::Time {
            spp: 10.0,
            settle: 0.0,
        },
    };
    let reference = expect.visits[0].0;
    assert!(expect.visits.iter().filter(|v| v.0 == reference).count() >= 5);
    let events = interpret(Path::new(&p("plan.nc")), None);
    let seen = judge(&events, &expect).unwrap();
    assert!((seen.dwell_s - duration_s(&json)).abs() < 1e-6, "{seen:?}");
    assert!(seen.lateral >= expect.visits.len() / 2, "{seen:?}");
    ok(&[
        "plan",
        "--plan-file",
        &p("plan.csv"),
        "--gcode",
        &p("again.nc"),
    ]);
    assert_eq!(interpret(Path::new(&p("again.nc")), None), events);
    ok(&[
        "plan",
        "--plan-file",
        &p("plan.csv"),
        "--gcode",
        &p("fanuc.nc"),
        "--dialect",
        "fanuc",
    ]);
    let fanuc = interpret_fanuc(Path::new(&p("fanuc.nc")));
    assert_eq!(fanuc, events);
    let _ = std::fs::remove_dir_all(&d);
}

/// A designed plan on the head–head preset (three reflectors, five axes) with a two-axis
/// clearance given on the command line (`Z=550,A=0`: it wins over the machine file's Z = 600)
/// and a settling wait of 2 s: rs274 sees Z and A at the clearance before every move of X, Y
/// and C, and the dwells add up to the plan's duration plus 2 s per visit.
#[test]
fn a_five_axis_plan_with_a_clearance_option_retracts_both_axes() {
    if !rs274::require() {
        return;
    }
    let d = dir("head-head");
    let p = |n: &str| d.join(n).to_string_lossy().into_owned();
    let json = ok(&[
        "plan",
        "--machine",
        "head-head",
        "--points",
        "80",
        "--per-axis",
        "3",
        "--repeats",
        "2",
        "--out",
        &p("plan.csv"),
        "--gcode",
        &p("plan.nc"),
        "--clearance",
        "Z=550,A=0",
        "--dwell-s",
        "2",
        "--json",
    ]);
    let csv = std::fs::read_to_string(p("plan.csv")).unwrap();
    let expect = Expect {
        visits: visits_of(&csv),
        clearance: vec![(2, 550.0), (3, 0.0)],
        waiting: Waiting::Time {
            spp: 10.0,
            settle: 2.0,
        },
    };
    for r in ["R1", "R2", "R3"] {
        assert!(csv.contains(&format!(",{r}\n")), "the plan measures {r}");
    }
    let events = interpret(Path::new(&p("plan.nc")), None);
    let seen = judge(&events, &expect).unwrap();
    let want = duration_s(&json) + 2.0 * expect.visits.len() as f64;
    assert!(
        (seen.dwell_s - want).abs() < 1e-6,
        "{seen:?} against {want}"
    );
    // Judged with the machine file's clearance instead, the program breaks the rule: the
    // option was used.
    let machine_file = Expect {
        clearance: vec![(2, 600.0)],
        ..expect
    };
    assert!(judge(&events, &machine_file).is_err());
    let _ = std::fs::remove_dir_all(&d);
}

/// A hand-made plan file on the head–table preset (three reflectors, a shuffled order, the
/// reference pose repeated, a visit repeated at once, a move of Z alone), the columns in an
/// order of their own, with program stops (the tracker operated by hand) after a settling
/// dwell of 1.5 s: rs274 sees a stop (M0, or M1 with `--wait m1`) at each visit's pose after
/// the machine file's clearance (Z = 450) between poses.
#[test]
fn a_plan_file_with_stops_on_the_head_table_preset() {
    if !rs274::require() {
        return;
    }
    let d = dir("head-table");
    let p = |n: &str| d.join(n).to_string_lossy().into_owned();
    let letters = ['X', 'Y', 'Z', 'B', 'C'];
    let poses = [
        vec![0.0, 0.0, 200.0, 0.0, 0.0],
        vec![-300.0, -250.0, 0.0, -90.0, 45.0],
        vec![300.0, 250.0, 400.0, 30.0, 315.0],
        vec![150.0, -100.0, 100.0, -45.0, 180.0],
        vec![-200.0, 200.0, 350.0, -120.0, 90.0],
        vec![0.0, 0.0, 50.0, 0.0, 270.0],
        vec![250.0, -250.0, 300.0, -60.0, 0.0],
        vec![100.0, 100.0, 200.0, 15.0, 135.0],
    ];
    let csv = plan_file(&letters, &poses, &["R1", "R2", "R3"], 11);
    std::fs::write(p("plan.csv"), &csv).unwrap();
    for (wait, optional) in [("m0", false), ("m1", true)] {
        let nc = p(&format!("{wait}.nc"));
        ok(&[
            "plan",
            "--machine",
            "head-table",
            "--plan-file",
            &p("plan.csv"),
            "--gcode",
            &nc,
            "--wait",
            wait,
            "--dwell-s",
            "1.5",
        ]);
        let expect = Expect {
            visits: visits_of(&csv),
            clearance: vec![(2, 450.0)],
            waiting: Waiting::Stop {
                optional,
                settle: 1.5,
            },
        };
        let seen = judge(&interpret(Path::new(&nc), None), &expect).unwrap();
        assert_eq!(seen.stops, expect.visits.len());
        assert!((seen.dwell_s - 1.5 * expect.visits.len() as f64).abs() < 1e-6);
        // The repeated visit and the ref pose's: visits at one pose with no rapid between.
        assert!(seen.traverses < 3 * expect.visits.len() + 1, "{seen:?}");
    }
    let _ = std::fs::remove_dir_all(&d);
}

/// A hand-made plan file on the table–table preset at 7.5 s per point, run with a G54 work
/// offset in force (the parameter file): the program's `G53` moves reach the plan's machine
/// positions whatever the offset, retract Z to 400 between poses, and dwell 7.5 s per
/// reflector: the plan's rows × 7.5 s. Its Fanuc program moves and waits the same.
#[test]
fn a_plan_file_on_the_table_table_preset_runs_in_machine_coordinates() {
    if !rs274::require() {
        return;
    }
    let d = dir("table-table");
    let p = |n: &str| d.join(n).to_string_lossy().into_owned();
    let letters = ['A', 'C', 'X', 'Y', 'Z'];
    let poses = [
        vec![0.0, 0.0, 0.0, 0.0, 200.0],
        vec![-90.0, 45.0, -250.0, 200.0, 0.0],
        vec![110.0, 300.0, 250.0, -250.0, 350.0],
        vec![45.0, 180.0, 0.0, 0.0, 100.0],
        vec![-110.0, 90.0, 200.0, 250.0, 300.0],
        vec![30.0, 0.0, -100.0, -100.0, 50.0],
        vec![0.0, 270.0, 300.0, 300.0, 250.0],
    ];
    let csv = plan_file(&letters, &poses, &["R1", "R2", "R3"], 5);
    std::fs::write(p("plan.csv"), &csv).unwrap();
    // A G54 offset of (101.6, −50.8, 25.4) mm, written in inches as rs274 reads it.
    std::fs::write(p("g54.var"), "5220 1\n5221 4\n5222 -2\n5223 1\n").unwrap();
    let args = |nc: &str, dialect: &str| {
        ok(&[
            "plan",
            "--machine",
            "table-table",
            "--plan-file",
            &p("plan.csv"),
            "--gcode",
            nc,
            "--seconds-per-point",
            "7.5",
            "--dialect",
            dialect,
        ])
    };
    args(&p("plan.nc"), "linuxcnc");
    let expect = Expect {
        visits: visits_of(&csv),
        clearance: vec![(2, 400.0)],
        waiting: Waiting::Time {
            spp: 7.5,
            settle: 0.0,
        },
    };
    let rows = csv
        .lines()
        .filter(|l| l.starts_with(|c: char| c.is_ascii_digit()))
        .count();
    let with_offset = interpret(Path::new(&p("plan.nc")), Some(Path::new(&p("g54.var"))));
    let seen = judge(&with_offset, &expect).unwrap();
    assert!(
        (seen.dwell_s - 7.5 * rows as f64).abs() < 1e-6,
        "{seen:?}, {rows} rows"
    );
    // Without the offset the same machine motion, once the first retract (from wherever the
    // interpreter starts: its origin, in program coordinates) has set the clearance.
    let after_first_move = |e: Vec<Event>| -> Vec<Event> {
        let k = e
            .iter()
            .position(|x| matches!(x, Event::Traverse(_)))
            .unwrap();
        e[k + 1..].to_vec()
    };
    let events = after_first_move(interpret(Path::new(&p("plan.nc")), None));
    assert!(alike(&events, &after_first_move(with_offset)));
    args(&p("fanuc.nc"), "fanuc");
    assert_eq!(
        after_first_move(interpret_fanuc(Path::new(&p("fanuc.nc")))),
        events
    );
    let _ = std::fs::remove_dir_all(&d);
}

/// The judge is not blind: the XCFZ program with its retracts removed, a dwell shortened, a
/// visit's wait dropped, or the old all-axes rapid (`G0 X… C… Z…` then `G4 P2`) is refused.
#[test]
fn the_judge_refuses_unsafe_or_short_programs() {
    if !rs274::require() {
        return;
    }
    let d = dir("judge");
    let p = |n: &str| d.join(n).to_string_lossy().into_owned();
    ok(&[
        "plan",
        "--points",
        "40",
        "--per-axis",
        "4",
        "--repeats",
        "2",
        "--out",
        &p("plan.csv"),
        "--gcode",
        &p("plan.nc"),
    ]);
    let csv = std::fs::read_to_string(p("plan.csv")).unwrap();
    let nc = std::fs::read_to_string(p("plan.nc")).unwrap();
    let expect = Expect {
        visits: visits_of(&csv),
        clearance: vec![(2, 600.0)],
        waiting: Waiting::Time {
            spp: 10.0,
            settle: 0.0,
        },
    };
    let run = |text: &str, name: &str| {
        std::fs::write(p(name), text).unwrap();
        judge(&interpret(Path::new(&p(name)), None), &expect)
    };
    run(&nc, "good.nc").unwrap();
    let no_retract: String = nc
        .lines()
        .filter(|l| !l.contains("(clearance)"))
        .map(|l| format!("{l}\n"))
        .collect();
    assert!(
        run(&no_retract, "a.nc")
            .unwrap_err()
            .contains("away from the clearance")
    );
    let short = nc.replacen("G4 P20", "G4 P2", 1);
    assert!(run(&short, "b.nc").unwrap_err().contains("dwells 2 s"));
    let first_wait = nc.lines().position(|l| l.starts_with("G4 P")).unwrap();
    let dropped: String = nc
        .lines()
        .enumerate()
        .filter(|(i, _)| *i != first_wait)
        .map(|(_, l)| format!("{l}\n"))
        .collect();
    assert!(
        run(&dropped, "c.nc")
            .unwrap_err()
            .contains("visit 1 waits at")
    );
    // The old program, retracted first so that its first fault is its rapids.
    let mut old = String::from("%\nG21 G90\nG0 Z600\n");
    for v in &expect.visits {
        old.push_str(&format!("G0 X{} C{} Z{}\nG4 P2\n", v.0[0], v.0[5], v.0[2]));
    }
    old.push_str("M30\n%\n");
    assert!(run(&old, "old.nc").unwrap_err().contains("at once"));
    let _ = std::fs::remove_dir_all(&d);
}

/// Without a clearance anywhere (a machine file without `[clearance]`) `--gcode` is refused,
/// saying how to give one, before any design; `--clearance` then makes it work.
#[test]
fn a_program_without_a_clearance_is_refused_with_the_fix() {
    let d = dir("refusals");
    let p = |n: &str| d.join(n).to_string_lossy().into_owned();
    let bare: String = volver::core::machine::DEFAULT_MACHINE_TOML
        .lines()
        .filter(|l| !l.starts_with("[clearance]") && !l.starts_with("Z = 600"))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(p("bare.toml"), bare).unwrap();
    std::fs::write(p("plan.csv"), "X,C,Z,reflector\n0,0,0,R1\n700,90,300,R2\n").unwrap();
    let (machine, plan, out) = (p("bare.toml"), p("plan.csv"), p("out.nc"));
    let base = [
        "plan",
        "--machine",
        &machine,
        "--plan-file",
        &plan,
        "--gcode",
        &out,
    ];
    let e = refused(&base);
    assert!(
        e.contains("clearance") && e.contains("--clearance Z=600") && e.contains("[clearance]"),
        "{e}"
    );
    let e = refused(&[
        "plan",
        "--machine",
        &machine,
        "--model",
        "core/data/xcfz-paper-model.toml",
        "--points",
        "40",
        "--out",
        &p("x.csv"),
        "--gcode",
        &p("x.nc"),
    ]);
    assert!(e.contains("--clearance"), "{e}");
    assert!(
        !Path::new(&p("x.csv")).exists(),
        "refused before the design"
    );
    let e = refused(&[&base[..], &["--clearance", "Z=700"]].concat());
    let want = "--clearance Z=700: clearance Z = 700: 700 mm is outside the travel range [0, 600]";
    assert!(e.contains(want), "{e}");
    assert!(!Path::new(&out).exists());
    ok(&[&base[..], &["--clearance", "Z=600"]].concat());
    let nc = std::fs::read_to_string(&out).unwrap();
    assert!(
        nc.contains("G53 G0 Z600 (clearance)")
            && nc.contains("G4 P10 (visit 2, pose 2: measure R2, plan row 2)"),
        "{nc}"
    );
    let _ = std::fs::remove_dir_all(&d);
}

/// Bad values of the program's options are refused naming the option and the value as given
/// (`1e300`, not its 301 digits): a clearance on an axis the machine lacks or not a number,
/// absurd waits, an unknown dialect or wait. Nothing is written.
#[test]
fn bad_program_options_are_refused_with_the_option() {
    let d = dir("options");
    let p = |n: &str| d.join(n).to_string_lossy().into_owned();
    std::fs::write(p("plan.csv"), "X,C,Z,reflector\n0,0,0,R1\n700,90,300,R2\n").unwrap();
    let (plan, out) = (p("plan.csv"), p("out.nc"));
    for (extra, needle) in [
        (
            &["--clearance", "Y=0"][..],
            "--clearance Y=0: clearance Y = 0: the machine has no axis Y",
        ),
        (&["--clearance", "Z=nan"], "finite"),
        (&["--clearance", "Z"], "expected AXIS=VALUE"),
        (
            &["--dwell-s", "1e300"],
            "--dwell-s 1e300: an extra settling wait of 0 to 3600 s",
        ),
        (&["--dwell-s=-1"], "--dwell-s -1.0"),
        (
            &["--seconds-per-point", "1e300"],
            "--seconds-per-point 1e300",
        ),
        (&["--dialect", "haas"], "unknown G-code dialect 'haas'"),
        (&["--wait", "m2"], "unknown wait 'm2'"),
    ] {
        let e = refused(&[&["plan", "--plan-file", &plan, "--gcode", &out][..], extra].concat());
        assert!(e.contains(needle), "{extra:?}: {e}");
    }
    assert!(!Path::new(&out).exists());
    let _ = std::fs::remove_dir_all(&d);
}
