//! The G-code corpus of `tests/data/gcode/` judged by LinuxCNC's interpreter `rs274` (issue 42):
//! each program runs through rs274 before and after `volver compensate`, and
//!
//! 1. the compensated program runs without an interpreter error;
//! 2. it visits the input's end points in order, each where volver's point compensation puts
//!    it (a compensated move) or exactly there (a reference or machine-coordinate move), within
//!    rs274's printed resolution (1e-4 of the program's unit);
//! 3. it never strays from the input's path (its lines and arcs, over the linear axes) by more
//!    than the chord tolerance plus the largest compensation;
//! 4. its dwells, tool changes, spindle words and stops are the input's, in order; its feed
//!    rates per minute are the input's, and in inverse time (`G93`) its moves take the input's
//!    time;
//! 5. run scaled by 10 000 (every position word, offset and tool length: rs274 prints 4
//!    decimals, so the scaled run resolves 1e-8 mm, 2.5e-8 mm in an inch program), its end
//!    points equal volver's point compensation at the same machine positions to 1e-6 mm
//!    (programs without canned cycles, whose peck clearance does not scale: those to rs274's
//!    plain resolution, item 2).
//!
//! The programs volver refuses are refused with the file, the line and the word.

mod common;

use common::rs274::{self, Event, FeedMode, Run};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use volver::core::compensate::Compensator;
use volver::core::iso::Axis;
use volver::core::machine::{Commands, Machine};
use volver::core::model::Model;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/gcode");

/// The machines of the corpus.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Kind {
    /// `mill.toml` with `mill.var` and `mill.tbl` (inches, as the standalone rs274 reads them).
    Mill,
    /// The XCFZ grinder with `xcfz.var` (a C offset).
    Xcfz,
    /// The `table-table` five-axis preset, no offsets.
    Five,
}

/// Simulated truths (noise-free results files) of the three machines, once per run.
fn truths() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("volver-rs274-{}", std::process::id()));
        let s = |d: &str| dir.join(d).display().to_string();
        let mill = format!("{DATA}/mill.toml");
        let cubic = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/mill/cubic.toml");
        common::simulate(
            &s("mill"),
            &[
                "--machine",
                &mill,
                "--truth-model",
                cubic,
                "--noise",
                "none",
                "--seed",
                "3",
                "--plan",
                "X=0:800:400,Y=0:500:250,Z=-400:0:200",
            ],
        );
        common::simulate(
            &s("xcfz"),
            &[
                "--noise",
                "none",
                "--seed",
                "4",
                "--plan",
                "X=0:1400:700,C=0:270:90,Z=0:600:300",
            ],
        );
        common::simulate(
            &s("five"),
            &["--machine", "table-table", "--noise", "none", "--seed", "5"],
        );
        dir
    })
}

impl Kind {
    fn dir(self) -> PathBuf {
        truths().join(match self {
            Kind::Mill => "mill",
            Kind::Xcfz => "xcfz",
            Kind::Five => "five",
        })
    }

    /// rs274's tool table and parameter file.
    fn rs274_files(self) -> (Option<PathBuf>, Option<PathBuf>) {
        let f = |n: &str| Some(Path::new(DATA).join(n));
        match self {
            Kind::Mill => (f("mill.tbl"), f("mill.var")),
            Kind::Xcfz => (None, f("xcfz.var")),
            Kind::Five => (None, None),
        }
    }

    /// volver's arguments for the same files.
    fn args(self) -> Vec<String> {
        let f = |n: &str| format!("{DATA}/{n}");
        match self {
            Kind::Mill => vec![
                "--offsets".into(),
                f("mill.var"),
                "--tool-table".into(),
                f("mill.tbl"),
                "--offset-units".into(),
                "inch".into(),
                "--gauge-point=0,0,0".into(),
            ],
            Kind::Xcfz => vec![
                "--offsets".into(),
                f("xcfz.var"),
                "--offset-units".into(),
                "inch".into(),
            ],
            Kind::Five => vec![],
        }
    }

    /// Tool lengths of `mill.tbl` (mm).
    fn tool_length(self, tool: i64) -> f64 {
        match (self, tool) {
            (Kind::Mill, 1) => 4.0 * 25.4,
            (Kind::Mill, 2) => 3.0 * 25.4,
            (Kind::Mill, 3) => 5.0 * 25.4,
            _ => 0.0,
        }
    }
}

/// A program of the corpus that volver compensates.
struct Case {
    file: &'static str,
    kind: Kind,
    args: &'static [&'static str],
}

const fn case(file: &'static str, kind: Kind) -> Case {
    Case {
        file,
        kind,
        args: &[],
    }
}

/// The corpus: each feature of issue 42 on the machines it applies to.
const CASES: &[Case] = &[
    case("01-work-offset.ngc", Kind::Mill),
    case("02-arcs-g55.ngc", Kind::Mill),
    case("03-helix.ngc", Kind::Mill),
    case("04-planes.ngc", Kind::Mill),
    case("05-absolute-centres.ngc", Kind::Mill),
    case("06-incremental.ngc", Kind::Mill),
    case("07-inches.ngc", Kind::Mill),
    case("08-inverse-time.ngc", Kind::Mill),
    case("09-feed-per-rev.ngc", Kind::Mill),
    case("10-tool-changes.ngc", Kind::Mill),
    case("11-drill-g81.ngc", Kind::Mill),
    case("12-spot-g82.ngc", Kind::Mill),
    case("13-peck-g83.ngc", Kind::Mill),
    case("14-chip-break-g73.ngc", Kind::Mill),
    case("15-bore-g85-g89.ngc", Kind::Mill),
    case("16-bore-g86.ngc", Kind::Mill),
    case("17-repeats.ngc", Kind::Mill),
    case("18-words-kept.ngc", Kind::Mill),
    case("19-reference-g28.ngc", Kind::Mill),
    case("20-machine-g53.ngc", Kind::Mill),
    case("21-g10-after-motion.ngc", Kind::Mill),
    case("22-local-g52.ngc", Kind::Mill),
    Case {
        file: "23-g92-at-start.ngc",
        kind: Kind::Mill,
        args: &["--start", "X=0,Y=0,Z=0"],
    },
    Case {
        file: "24-g10-l20.ngc",
        kind: Kind::Mill,
        args: &["--start", "X=0,Y=0,Z=0"],
    },
    case("25-framing.ngc", Kind::Mill),
    Case {
        file: "26-long-moves.ngc",
        kind: Kind::Mill,
        args: &["--max-segment", "25"],
    },
    case("27-reference-g30.ngc", Kind::Mill),
    case("28-xcfz.ngc", Kind::Xcfz),
    case("29-xcfz-inches.ngc", Kind::Xcfz),
    case("30-five-axis.ngc", Kind::Five),
    case("31-five-axis-inverse-time.ngc", Kind::Five),
    case("32-readme-part.ngc", Kind::Xcfz),
    case("33-cycle-retracts.ngc", Kind::Mill),
    case("34-stored-position.ngc", Kind::Mill),
    case("35-inverse-time-g53.ngc", Kind::Mill),
];

/// The compensators of a results file, per tool (the mill's tools at the gauge point 0,0,0
/// plus their lengths down the spindle; no tool: the reflectors' centroid), as the CLI builds
/// them.
struct Reference {
    model: Model,
    params: Vec<f64>,
    kind: Kind,
}

impl Reference {
    fn load(kind: Kind) -> Reference {
        let (model, params, _) =
            volver::compensation::load_results(&kind.dir().join("truth.json"), false).unwrap();
        Reference {
            model,
            params,
            kind,
        }
    }

    fn compensator(&self, tool: Option<i64>) -> Compensator<'_> {
        let point = match tool {
            Some(t) if self.kind == Kind::Mill => [0.0, 0.0, -self.kind.tool_length(t)],
            _ => volver::compensation::reflector_centroid(&self.model),
        };
        volver::compensation::compensator(&self.model, &self.params, point, None, None).unwrap()
    }

    /// volver's point compensation of a machine position (X Y Z A B C order, mm and degrees).
    fn compensate(&self, tool: Option<i64>, p: &[f64; 6]) -> [f64; 6] {
        let m = self.model.machine();
        let mut c = Commands::default();
        for (k, a) in m.axes().iter().enumerate() {
            c.0[k] = a.from_file_units(p[letter(a.axis)]);
        }
        let q = self.compensator(tool).compensate(&c).unwrap().commands;
        let mut out = *p;
        for (k, a) in m.axes().iter().enumerate() {
            out[letter(a.axis)] = a.to_file_units(q.0[k]);
        }
        out
    }
}

/// The index of an axis in rs274's X Y Z A B C order.
fn letter(a: Axis) -> usize {
    Axis::ALL.iter().position(|&x| x == a).unwrap()
}

/// The largest difference over the axes the machine has.
fn gap(m: &Machine, a: &[f64; 6], b: &[f64; 6]) -> f64 {
    m.axes()
        .iter()
        .map(|x| (a[letter(x.axis)] - b[letter(x.axis)]).abs())
        .fold(0.0, f64::max)
}

/// The tool in the spindle at each move of a run (from its tool changes).
fn tools_at_moves(run: &Run) -> Vec<Option<i64>> {
    let mut tool = None;
    let mut out = Vec::new();
    for e in &run.events {
        match e {
            Event::ToolChange(t) => tool = Some(*t),
            Event::Traverse(_) | Event::Feed(..) | Event::Arc(_) => out.push(tool),
            _ => {}
        }
    }
    out
}

/// Runs `volver compensate` on a corpus program; the output path, or the message.
fn compensate(case: &Case, out: &Path, extra: &[&str]) -> Result<String, String> {
    let results = case.kind.dir().join("truth.json");
    let input = if case.file.starts_with('/') {
        case.file.to_string()
    } else {
        format!("{DATA}/{}", case.file)
    };
    let mut args: Vec<String> = vec![
        "compensate".into(),
        "--results".into(),
        results.display().to_string(),
        "--gcode".into(),
        input,
        "--decimals".into(),
        "9".into(),
        "--out".into(),
        out.display().to_string(),
        // A simulation's truth carries no uncertainty; what is judged here is the program.
        "--force".into(),
    ];
    args.extend(case.kind.args());
    args.extend(case.args.iter().map(|s| s.to_string()));
    args.extend(extra.iter().map(|s| s.to_string()));
    let a: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = common::volver(&a);
    let text = String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr);
    if o.status.success() {
        Ok(text)
    } else {
        Err(text)
    }
}

/// Matches the input's end points, in order, in the output's: each at volver's compensation of
/// it (compensated moves) or at itself (reference moves). Returns the output index of each with
/// whether it matched compensated, and how many matched uncompensated.
fn match_end_points(
    r: &Reference,
    before: &Run,
    after: &Run,
    tol: f64,
    file: &str,
) -> (Vec<(usize, bool)>, usize) {
    let m = r.model.machine();
    let (ein, eout) = (before.end_points(), after.end_points());
    let tools = tools_at_moves(before);
    let (mut j, mut idx, mut plain) = (0_usize, Vec::new(), 0);
    for (i, e) in ein.iter().enumerate() {
        let want = r.compensate(tools[i], e);
        // A reference move's intermediate point moves only its axes: each axis where
        // compensation puts it, where the program does, or where it stood.
        let stood = j.checked_sub(1).map(|p| eout[p]);
        let either = |k: usize| {
            m.axes().iter().all(|a| {
                let l = letter(a.axis);
                let near = |v: f64| (eout[k][l] - v).abs() <= tol;
                near(want[l]) || near(e[l]) || stood.is_some_and(|s| near(s[l]))
            })
        };
        let found = (j..eout.len()).find(|&k| either(k));
        let Some(k) = found else {
            panic!(
                "{file}: input end point {i} {e:?} (compensated {want:?}) is not visited after output point {j}"
            );
        };
        let compensated = gap(m, &eout[k], &want) <= tol;
        plain += usize::from(!compensated);
        idx.push((k, compensated));
        j = k + 1;
    }
    (idx, plain)
}

/// The input's path as straight pieces over X Y Z (arcs cut into 720 pieces a turn).
fn path(before: &Run) -> Vec<([f64; 3], [f64; 3])> {
    let mut pieces = Vec::new();
    let mut at: Option<[f64; 3]> = None;
    for e in &before.events {
        let end = match e {
            Event::Traverse(p) | Event::Feed(p, ..) => [p[0], p[1], p[2]],
            Event::Arc(a) => [a.end[0], a.end[1], a.end[2]],
            _ => continue,
        };
        if let Some(start) = at {
            match e {
                Event::Arc(a) => pieces.extend(arc_pieces(start, a)),
                _ => pieces.push((start, end)),
            }
        }
        at = Some(end);
    }
    pieces
}

/// The sweep (rad, signed) and radius of an arc from `start`.
fn sweep(start: [f64; 3], a: &rs274::Arc) -> (f64, f64) {
    let (d1, d2) = a.axes;
    let (c1, c2) = (a.centre[d1], a.centre[d2]);
    let a0 = (start[d2] - c2).atan2(start[d1] - c1);
    let a1 = (a.end[d2] - c2).atan2(a.end[d1] - c1);
    let turn = std::f64::consts::TAU;
    let mut s = if a.rotation > 0 {
        (a1 - a0).rem_euclid(turn)
    } else {
        -(a0 - a1).rem_euclid(turn)
    };
    if s.abs() < 1e-9 {
        s = turn * f64::from(a.rotation.signum());
    }
    s += turn * f64::from(a.rotation.abs() - 1) * f64::from(a.rotation.signum());
    (
        s,
        ((start[d1] - c1).powi(2) + (start[d2] - c2).powi(2)).sqrt(),
    )
}

fn arc_pieces(start: [f64; 3], a: &rs274::Arc) -> Vec<([f64; 3], [f64; 3])> {
    let (d1, d2) = a.axes;
    let d3 = 3 - d1 - d2;
    let (s, r) = sweep(start, a);
    let a0 = (start[d2] - a.centre[d2]).atan2(start[d1] - a.centre[d1]);
    let n = ((s.abs() / std::f64::consts::TAU) * 720.0).ceil().max(1.0) as usize;
    let point = |t: f64| {
        let mut p = [0.0; 3];
        p[d1] = a.centre[d1] + r * (a0 + s * t).cos();
        p[d2] = a.centre[d2] + r * (a0 + s * t).sin();
        p[d3] = start[d3] + (a.end[d3] - start[d3]) * t;
        p
    };
    (0..n)
        .map(|i| (point(i as f64 / n as f64), point((i + 1) as f64 / n as f64)))
        .collect()
}

fn distance_to_piece(p: [f64; 3], (a, b): ([f64; 3], [f64; 3])) -> f64 {
    let ab: Vec<f64> = (0..3).map(|k| b[k] - a[k]).collect();
    let len2: f64 = ab.iter().map(|v| v * v).sum();
    let t = if len2 == 0.0 {
        0.0
    } else {
        ((0..3).map(|k| (p[k] - a[k]) * ab[k]).sum::<f64>() / len2).clamp(0.0, 1.0)
    };
    (0..3)
        .map(|k| (p[k] - a[k] - t * ab[k]).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// The time (min) of a run's inverse-time feed moves: length / rate (the interpreter turns an
/// inverse-time F into a rate per minute for each move).
fn inverse_time_minutes(run: &Run) -> f64 {
    let mut at: Option<[f64; 3]> = None;
    let mut total = 0.0;
    for e in &run.events {
        let (end, len_rate) = match e {
            Event::Traverse(p) => ([p[0], p[1], p[2]], None),
            Event::Feed(p, mode, rate) => {
                let end = [p[0], p[1], p[2]];
                let len = at.map_or(0.0, |s| distance_to_piece(end, (s, s)));
                (
                    [p[0], p[1], p[2]],
                    (*mode == FeedMode::InverseTime).then_some((len, *rate)),
                )
            }
            Event::Arc(a) => {
                let end = [a.end[0], a.end[1], a.end[2]];
                let s = at.unwrap_or(end);
                let (sw, r) = sweep(s, a);
                let d3 = 3 - a.axes.0 - a.axes.1;
                let len = ((sw * r).powi(2) + (a.end[d3] - s[d3]).powi(2)).sqrt();
                (
                    end,
                    (a.mode == FeedMode::InverseTime).then_some((len, a.rate)),
                )
            }
            _ => continue,
        };
        if let Some((len, rate)) = len_rate {
            total += len / rate;
        }
        at = Some(end);
    }
    total
}

/// The feed rates per minute of a run's feed moves, consecutive repeats merged.
fn per_minute_rates(run: &Run) -> Vec<(FeedMode, f64)> {
    let mut out: Vec<(FeedMode, f64)> = Vec::new();
    for e in &run.events {
        let (mode, rate) = match e {
            Event::Feed(_, m, r) => (*m, *r),
            Event::Arc(a) => (a.mode, a.rate),
            _ => continue,
        };
        if mode != FeedMode::InverseTime && out.last() != Some(&(mode, rate)) {
            out.push((mode, rate));
        }
    }
    out
}

/// `text` with every position word (X Y Z A B C I J K R, outside comments) times `factor`.
fn scaled_program(text: &str, factor: f64) -> String {
    let mut out = String::new();
    for line in text.lines() {
        let mut depth = 0;
        let mut word = String::new();
        let flush = |word: &mut String, out: &mut String| {
            let mut chars = word.chars();
            if let Some(l) = chars.next()
                && "XYZABCIJKRxyzabcijkr".contains(l)
                && let Ok(v) = chars.as_str().trim().parse::<f64>()
            {
                out.push_str(&format!("{l}{:.9}", v * factor));
            } else {
                out.push_str(word);
            }
            word.clear();
        };
        let mut comment = false;
        for c in line.chars() {
            if comment || depth > 0 || c == '(' || c == ';' {
                if c == '(' {
                    depth += 1;
                }
                if c == ';' && depth == 0 {
                    comment = true;
                }
                flush(&mut word, &mut out);
                out.push(c);
                if c == ')' {
                    depth -= 1;
                }
                continue;
            }
            if c.is_ascii_alphabetic() {
                flush(&mut word, &mut out);
            }
            word.push(c);
        }
        flush(&mut word, &mut out);
        out.push('\n');
    }
    out
}

/// A parameter file or tool table with every offset times `factor` (the coordinate-system
/// number 5220 and pocket numbers kept).
fn scaled_file(path: &Path, factor: f64, var: bool) -> String {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .map(|l| {
            if var {
                let mut p = l.split_whitespace();
                let (n, v) = (p.next().unwrap(), p.next().unwrap().parse::<f64>().unwrap());
                if n == "5220" {
                    l.to_string()
                } else {
                    format!("{n}\t{:.9}", v * factor)
                }
            } else {
                l.split(';')
                    .next()
                    .unwrap()
                    .split_whitespace()
                    .map(|t| match t.strip_prefix('Z') {
                        Some(v) => format!("Z{:.9}", v.parse::<f64>().unwrap() * factor),
                        None => t.to_string(),
                    })
                    .collect::<Vec<_>>()
                    .join(" ")
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
        + "\n"
}

/// rs274's run of `program` scaled by 10 000, positions divided back.
fn scaled_run(kind: Kind, program: &Path, dir: &Path, name: &str) -> Run {
    const F: f64 = 1e4;
    let p = dir.join(format!("{name}.x100.ngc"));
    std::fs::write(
        &p,
        scaled_program(&std::fs::read_to_string(program).unwrap(), F),
    )
    .unwrap();
    let (tbl, var) = kind.rs274_files();
    let tbl = tbl.map(|t| {
        let q = dir.join(format!("{name}.x100.tbl"));
        std::fs::write(&q, scaled_file(&t, F, false)).unwrap();
        q
    });
    let var = var.map(|v| {
        let q = dir.join(format!("{name}.x100.var"));
        std::fs::write(&q, scaled_file(&v, F, true)).unwrap();
        q
    });
    let mut run = rs274::run(&p, tbl.as_deref(), var.as_deref()).unwrap();
    for e in &mut run.events {
        let p = match e {
            Event::Traverse(p) | Event::Feed(p, ..) => p,
            Event::Arc(a) => &mut a.end,
            _ => continue,
        };
        for v in p.iter_mut() {
            *v /= F;
        }
    }
    run
}

/// The farthest an output end point is from the input's path (mm, X Y Z).
fn stray(before: &Run, after: &Run) -> f64 {
    let pieces = path(before);
    let mut stray = 0.0_f64;
    for p in after.end_points() {
        let d = pieces
            .iter()
            .map(|pc| distance_to_piece([p[0], p[1], p[2]], *pc))
            .fold(f64::INFINITY, f64::min);
        stray = stray.max(d);
    }
    stray
}

/// Item 5: the scaled runs of the input and of its compensated program `out`; the largest
/// distance (mm) of a compensated end point from volver's point compensation, checked ≤ 1e-6.
fn precise(case: &Case, r: &Reference, idx: &[(usize, bool)], out: &Path, dir: &Path) -> f64 {
    let input = Path::new(DATA).join(case.file);
    let m = r.model.machine();
    let b = scaled_run(case.kind, &input, dir, &format!("{}-in", case.file));
    let a = scaled_run(case.kind, out, dir, &format!("{}-out", case.file));
    let (eb, ea, tb) = (b.end_points(), a.end_points(), tools_at_moves(&b));
    let mut worst = 0.0_f64;
    for (i, &(k, compensated)) in idx.iter().enumerate() {
        if compensated {
            worst = worst.max(gap(m, &ea[k], &r.compensate(tb[i], &eb[i])));
        }
    }
    assert!(
        worst <= 1e-6,
        "{}: end points {worst} mm from volver's point compensation",
        case.file
    );
    worst
}

/// What one program's judgement measured, for the summary table.
struct Judged {
    before: usize,
    after: usize,
    plain: usize,
    stray_mm: f64,
    precise_mm: Option<f64>,
}

fn judge(case: &Case, r: &Reference, dir: &Path) -> Judged {
    let input = Path::new(DATA).join(case.file);
    let out = dir.join(case.file.replace(".ngc", "-comp.ngc"));
    let said = compensate(case, &out, &[])
        .unwrap_or_else(|e| panic!("{}: volver refused: {e}", case.file));
    let (tbl, var) = case.kind.rs274_files();
    let before = rs274::run(&input, tbl.as_deref(), var.as_deref()).unwrap();
    let after = rs274::run(&out, tbl.as_deref(), var.as_deref())
        .unwrap_or_else(|e| panic!("{}: the compensated program: {e}\n{said}", case.file));
    let inch = std::fs::read_to_string(&input).unwrap().contains("G20");
    let res = if inch { 0.6e-4 * 25.4 } else { 0.6e-4 };
    let m = r.model.machine();
    let (idx, plain) = match_end_points(r, &before, &after, 2.0 * res, case.file);
    // 3. the path: every output point within the chord tolerance plus the largest compensation.
    let tools = tools_at_moves(&before);
    let largest = before
        .end_points()
        .iter()
        .zip(&tools)
        .map(|(e, t)| gap(m, &r.compensate(*t, e), e))
        .fold(0.0, f64::max);
    let stray = stray(&before, &after);
    let bound = 0.001 + largest * 3f64.sqrt() + 4.0 * res;
    assert!(
        stray <= bound,
        "{}: strays {stray} mm from the input's path (bound {bound})",
        case.file
    );
    // 4. words and feeds.
    assert_eq!(
        before.non_moves(),
        after.non_moves(),
        "{}: dwells, tools, spindle, stops",
        case.file
    );
    assert_eq!(
        per_minute_rates(&before),
        per_minute_rates(&after),
        "{}: feed rates",
        case.file
    );
    let (t0, t1) = (inverse_time_minutes(&before), inverse_time_minutes(&after));
    assert!(
        (t0 - t1).abs() <= 1e-3 * t0.max(1e-9),
        "{}: inverse-time minutes {t0} → {t1}",
        case.file
    );
    // 5. the scaled runs: 1e-6 mm.
    let text = std::fs::read_to_string(&input).unwrap();
    let cycles = ["G73", "G81", "G82", "G83", "G85", "G86", "G89"]
        .iter()
        .any(|c| text.contains(c));
    let precise = (!cycles).then(|| precise(case, r, &idx, &out, dir));
    Judged {
        before: before.end_points().len(),
        after: after.end_points().len(),
        plain,
        stray_mm: stray,
        precise_mm: precise,
    }
}

/// Every program of the corpus, judged by rs274 (see the module's docs); prints the table of
/// the closing note.
#[test]
fn the_corpus_runs_in_rs274_as_the_input_meant() {
    if !rs274::require() {
        return;
    }
    let dir = truths().join("corpus");
    std::fs::create_dir_all(&dir).unwrap();
    let refs: BTreeMap<&str, Reference> = [
        ("mill", Kind::Mill),
        ("xcfz", Kind::Xcfz),
        ("five", Kind::Five),
    ]
    .into_iter()
    .map(|(n, k)| (n, Reference::load(k)))
    .collect();
    println!(
        "| program | feature | rs274 moves before → after | uncompensated (reference) | strays mm | scaled check mm |"
    );
    for c in CASES {
        let r = match c.kind {
            Kind::Mill => &refs["mill"],
            Kind::Xcfz => &refs["xcfz"],
            Kind::Five => &refs["five"],
        };
        let j = judge(c, r, &dir);
        let reference = ["g28", "g30", "g53"].iter().any(|r| c.file.contains(r));
        assert_eq!(
            reference,
            j.plain > 0,
            "{}: {} end points matched uncompensated",
            c.file,
            j.plain
        );
        let text = std::fs::read_to_string(Path::new(DATA).join(c.file)).unwrap();
        let feature = text
            .lines()
            .find_map(|l| l.strip_prefix('(').and_then(|l| l.strip_suffix(')')))
            .unwrap_or("");
        println!(
            "| {} | {feature} | {} → {} | {} | {:.2e} | {} |",
            c.file,
            j.before,
            j.after,
            j.plain,
            j.stray_mm,
            j.precise_mm
                .map_or("(cycles: 1e-4)".into(), |v| format!("{v:.1e}"))
        );
    }
}

/// What volver refuses, it refuses with the file, the line and the word.
#[test]
fn the_corpus_refusals_name_the_line_and_word() {
    for (file, kind, line, word) in [
        ("40-probe.ngc", Kind::Mill, 5, "G38.2"),
        ("41-cutter-comp.ngc", Kind::Mill, 5, "G41"),
        ("42-fanuc-dwell.ngc", Kind::Mill, 5, "G4"),
        ("43-macro.ngc", Kind::Mill, 5, "G65"),
        ("44-tcp.ngc", Kind::Five, 4, "G043.4"),
        ("45-g92-after-move.ngc", Kind::Mill, 5, "G92"),
        ("46-unknown-start.ngc", Kind::Mill, 4, "axis Y"),
        ("47-tools-without-table.ngc", Kind::Five, 0, "T1, T2"),
        ("48-subprogram.ngc", Kind::Mill, 5, "M98"),
        ("49-threading.ngc", Kind::Mill, 6, "G33"),
        ("50-block-delete.ngc", Kind::Mill, 7, "optional line 6"),
    ] {
        let c = Case {
            file,
            kind,
            args: &[],
        };
        let out = truths().join(format!("refused-{file}"));
        let e = compensate(&c, &out, &[]).expect_err(file);
        let at = format!("{file}:{line}");
        assert!(line == 0 || e.contains(&at), "{file}: {e}");
        assert!(e.contains(word), "{file}: {e}");
        assert!(!out.exists(), "{file}: nothing is written");
    }
}

/// A compensated point past an axis' travel is refused, and with --allow-outside-travel
/// written with a comment on its line; rs274 runs the marked program.
#[test]
fn points_beyond_the_travel_are_refused_or_marked() {
    if !rs274::require() {
        return;
    }
    let r = Reference::load(Kind::Mill);
    let m = r.model.machine();
    // A corner at the top of Z whose compensated command leaves the travel (found, not assumed:
    // whichever way the errors push).
    let corner = [0.0, 800.0]
        .iter()
        .flat_map(|&x| [0.0, 500.0].map(|y| [x, y, 0.0, 0.0, 0.0, 0.0]))
        .find(|p| {
            let q = r.compensate(None, p);
            m.axes().iter().any(|a| {
                let v = q[letter(a.axis)];
                v < a.to_file_units(a.min) - 1e-7 || v > a.to_file_units(a.max) + 1e-7
            })
        })
        .expect("a corner of the travel that compensation leaves");
    let dir = truths().join("travel");
    std::fs::create_dir_all(&dir).unwrap();
    let program = dir.join("corner.ngc");
    std::fs::write(
        &program,
        format!(
            "G21 G90 G17\nG53 G0 X400 Y250 Z-100\nG0 X{} Y{} Z{}\nG0 X300 Y200 Z100\nM2\n",
            corner[0] - 4.0 * 25.4,
            corner[1] - 2.0 * 25.4,
            corner[2] + 14.0 * 25.4
        ),
    )
    .unwrap();
    let leaked: &'static str = Box::leak(program.display().to_string().into_boxed_str());
    let c = Case {
        file: leaked,
        kind: Kind::Mill,
        args: &[],
    };
    let out = dir.join("corner-comp.ngc");
    let e = compensate(&c, &out, &[]).expect_err("beyond the travel");
    assert!(
        e.contains("corner.ngc:3") && e.contains("beyond its travel"),
        "{e}"
    );
    compensate(&c, &out, &["--allow-outside-travel"]).unwrap();
    let text = std::fs::read_to_string(&out).unwrap();
    let marked: Vec<&str> = text
        .lines()
        .filter(|l| l.contains("beyond its travel"))
        .collect();
    assert_eq!(marked.len(), 1, "{text}");
    assert!(marked[0].contains("(line 3)"), "{text}");
    let (tbl, var) = Kind::Mill.rs274_files();
    rs274::run(&out, tbl.as_deref(), var.as_deref()).unwrap();
}
