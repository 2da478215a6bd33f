//! LinuxCNC's RS274NGC interpreter `rs274` (Debian `linuxcnc-uspace`) as the judge of G-code:
//! runs a program through it and reads the canonical machining commands it prints.
//!
//! `rs274` prints each canonical command with the program's position in the units in force
//! (`USE_LENGTH_UNITS`), to 4 decimals, and the offsets apart (`SET_G5X_OFFSET`,
//! `SET_G92_OFFSET`, `USE_TOOL_LENGTH_OFFSET`): the machine position of a point is the program
//! position plus the work offset, the G92/G52 offset and the tool length offset (no XY rotation
//! is used here). The standalone interpreter reads its parameter file (`-v`) and tool table
//! (`-t`) in inches whatever the program's units (seen: `5221 100` gives a G54 X offset of
//! 2540 mm), so the tests write those files in inches.

#![allow(dead_code)]

use std::path::Path;
use std::process::Command;

/// One canonical command that matters to the tests, positions as machine positions in mm
/// (linear axes) and degrees (rotary axes), in the order X Y Z A B C.
#[derive(Clone, Debug, PartialEq)]
pub enum Event {
    /// `STRAIGHT_TRAVERSE`: a rapid move to the position.
    Traverse([f64; 6]),
    /// `STRAIGHT_FEED`: a feed move to the position, with the feed mode in force and the rate
    /// (units per minute, inverse time converted by the interpreter).
    Feed([f64; 6], FeedMode, f64),
    /// `ARC_FEED`: an arc (or helix) ending at the position, with its centre (machine, mm, in
    /// the plane's two axes, the third left at NaN), its rotation (+1 counter-clockwise, −1
    /// clockwise, more for several turns), the plane's axes (indices 0–2), the feed mode and
    /// rate in force.
    Arc(Arc),
    /// `DWELL` (s).
    Dwell(f64),
    /// `CHANGE_TOOL` (the pocket or tool number printed).
    ToolChange(i64),
    /// Spindle words: `START_SPINDLE_CLOCKWISE`, `…_COUNTERCLOCKWISE`, `STOP_SPINDLE_TURNING`,
    /// `SET_SPINDLE_SPEED`, as printed.
    Spindle(String),
    /// `PROGRAM_STOP`, `OPTIONAL_PROGRAM_STOP`, `PROGRAM_END`.
    Stop(String),
}

/// An arc of `ARC_FEED`.
#[derive(Clone, Debug, PartialEq)]
pub struct Arc {
    /// Its end (machine, mm and degrees).
    pub end: [f64; 6],
    /// Its centre (machine, mm) in the plane's two axes, NaN in the third.
    pub centre: [f64; 3],
    /// +1 counter-clockwise, −1 clockwise (more for several turns).
    pub rotation: i32,
    /// The plane's first and second axes (0 X, 1 Y, 2 Z).
    pub axes: (usize, usize),
    /// The feed mode in force.
    pub mode: FeedMode,
    /// The rate (units per minute).
    pub rate: f64,
}

/// The feed mode in force.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FeedMode {
    /// Units per minute (`G94`).
    PerMinute,
    /// Inverse time (`G93`): the rate is 1 / minutes of the move.
    InverseTime,
    /// Units per revolution (`G95`).
    PerRevolution,
}

/// What the interpreter made of a program.
#[derive(Debug)]
pub struct Run {
    /// The events in order.
    pub events: Vec<Event>,
    /// Everything it printed (stdout), for messages.
    pub canon: String,
}

impl Run {
    /// The end points of every move, in order.
    pub fn end_points(&self) -> Vec<[f64; 6]> {
        self.events
            .iter()
            .filter_map(|e| match e {
                Event::Traverse(p) | Event::Feed(p, ..) => Some(*p),
                Event::Arc(a) => Some(a.end),
                _ => None,
            })
            .collect()
    }

    /// The dwells (s), in order.
    pub fn dwells(&self) -> Vec<f64> {
        self.events
            .iter()
            .filter_map(|e| match e {
                Event::Dwell(t) => Some(*t),
                _ => None,
            })
            .collect()
    }

    /// Every event that is not a move, in order (dwells, tool changes, spindle, stops).
    pub fn non_moves(&self) -> Vec<Event> {
        self.events
            .iter()
            .filter(|e| !matches!(e, Event::Traverse(_) | Event::Feed(..) | Event::Arc(_)))
            .cloned()
            .collect()
    }
}

/// Whether `rs274` is on the PATH (looked up as a file: running it to ask was seen to fail
/// once under load, failing a test for the wrong reason).
pub fn available() -> bool {
    std::env::var_os("PATH")
        .is_some_and(|path| std::env::split_paths(&path).any(|dir| dir.join("rs274").is_file()))
}

/// Panics with how to install `rs274` when it is missing (the README's test command installs
/// it; set `VOLVER_NO_RS274=1` to skip these tests knowingly).
pub fn require() -> bool {
    if available() {
        return true;
    }
    if std::env::var_os("VOLVER_NO_RS274").is_some() {
        eprintln!("rs274 missing: skipped (VOLVER_NO_RS274 is set)");
        return false;
    }
    panic!(
        "LinuxCNC's interpreter rs274 is not installed: `apt-get install linuxcnc-uspace` \
         (scripts/test does it), or set VOLVER_NO_RS274=1 to skip the G-code judge"
    );
}

/// Runs `program` through `rs274` with an optional tool table and parameter file (inches, see
/// the module's docs). An interpreter error is returned as `Err` with its message and line.
///
/// rs274 writes the parameter file back when it ends (`G10`, `G92`, `G28.1` persist, as on a
/// control, and the old file is kept as `.bak`): it is given a private copy in a folder of its
/// own under the system's temporary folder, so that runs do not leak into each other or into
/// the test data.
pub fn run(program: &Path, tools: Option<&Path>, vars: Option<&Path>) -> Result<Run, String> {
    let mut cmd = Command::new("rs274");
    cmd.arg("-g");
    if let Some(t) = tools {
        cmd.arg("-t").arg(t);
    }
    if let Some(v) = vars {
        static RUNS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let n = RUNS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let dir =
            std::env::temp_dir().join(format!("volver-rs274-vars-{}-{n}", std::process::id()));
        std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        let copy = dir.join("params.var");
        std::fs::copy(v, &copy).map_err(|e| format!("copying {}: {e}", v.display()))?;
        cmd.arg("-v").arg(copy);
    }
    let out = cmd
        .arg(program)
        .output()
        .map_err(|e| format!("rs274: {e}"))?;
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    let complaints: Vec<&str> = stderr
        .lines()
        .filter(|l| !l.trim().is_empty() && l.trim() != "executing")
        .collect();
    if !out.status.success() || !complaints.is_empty() {
        return Err(format!(
            "rs274 refused {} (exit {:?}): {}",
            program.display(),
            out.status.code(),
            complaints.join(" | ")
        ));
    }
    Ok(Run {
        events: parse(&stdout)?,
        canon: stdout,
    })
}

/// The numbers between the parentheses of a canonical call (commas or spaces between them).
fn numbers(args: &str) -> Vec<f64> {
    args.split([',', ' '])
        .filter_map(|t| t.trim().parse::<f64>().ok())
        .collect()
}

/// The interpreter's state while its output is read.
struct State {
    mm_per_unit: f64,
    g5x: [f64; 6],
    g92: [f64; 6],
    tool: [f64; 6],
    plane: usize,
    feed: f64,
    mode: FeedMode,
}

impl State {
    /// Machine position (mm, degrees) of a program position in the units in force (the
    /// offsets are kept in mm: rs274 prints them in the units in force when they are set).
    fn machine(&self, p: &[f64]) -> [f64; 6] {
        std::array::from_fn(|k| {
            let unit = if k < 3 { self.mm_per_unit } else { 1.0 };
            p[k] * unit + self.g5x[k] + self.g92[k] + self.tool[k]
        })
    }

    /// Offsets as printed (units in force) in mm and degrees.
    fn mm(&self, v: &[f64]) -> [f64; 6] {
        std::array::from_fn(|k| if k < 3 { v[k] * self.mm_per_unit } else { v[k] })
    }
}

/// The events of `rs274`'s output.
pub fn parse(canon: &str) -> Result<Vec<Event>, String> {
    let mut s = State {
        mm_per_unit: 1.0,
        g5x: [0.0; 6],
        g92: [0.0; 6],
        tool: [0.0; 6],
        plane: 0,
        feed: 0.0,
        mode: FeedMode::PerMinute,
    };
    let mut events = Vec::new();
    for line in canon.lines() {
        // "   21 N30    STRAIGHT_TRAVERSE(…)": a count, the block number (N….. when none), the
        // call.
        let mut parts = line.trim_start().splitn(3, char::is_whitespace);
        let (Some(count), Some(n), Some(call)) = (parts.next(), parts.next(), parts.next()) else {
            continue;
        };
        if count.parse::<u64>().is_err() || !n.starts_with('N') {
            continue;
        }
        let call = call.trim();
        let (name, rest) = call.split_once('(').unwrap_or((call, ""));
        let args = rest.trim_end_matches(')');
        let v = numbers(args);
        match name {
            "USE_LENGTH_UNITS" => {
                s.mm_per_unit = if args.contains("INCHES") { 25.4 } else { 1.0 };
            }
            "SET_G5X_OFFSET" => s.g5x = s.mm(&v[1..7]),
            "SET_G92_OFFSET" => s.g92 = s.mm(&v[..6]),
            "USE_TOOL_LENGTH_OFFSET" => s.tool = s.mm(&v[..6]),
            "SET_XY_ROTATION" if v.first().is_some_and(|r| *r != 0.0) => {
                return Err(format!("XY rotation is not read: {line}"));
            }
            "SELECT_PLANE" => {
                s.plane = match args {
                    a if a.contains("XZ") => 1,
                    a if a.contains("YZ") => 2,
                    _ => 0,
                }
            }
            "SET_FEED_RATE" => s.feed = v[0],
            // The interpreter turns an inverse-time F into a rate per minute for each move
            // (SET_FEED_RATE before it) and says which mode it is in by a comment.
            "COMMENT" if args.contains("feed mode set to") => {
                s.mode = if args.contains("inverse time") {
                    FeedMode::InverseTime
                } else if args.contains("per revolution") {
                    FeedMode::PerRevolution
                } else {
                    FeedMode::PerMinute
                }
            }
            "STRAIGHT_TRAVERSE" => events.push(Event::Traverse(s.machine(&v[..6]))),
            "STRAIGHT_FEED" => events.push(Event::Feed(s.machine(&v[..6]), s.mode, s.feed)),
            "ARC_FEED" => events.push(arc(&s, &v)),
            "DWELL" => events.push(Event::Dwell(v[0])),
            "CHANGE_TOOL" => events.push(Event::ToolChange(v[0] as i64)),
            "START_SPINDLE_CLOCKWISE"
            | "START_SPINDLE_COUNTERCLOCKWISE"
            | "STOP_SPINDLE_TURNING"
            | "SET_SPINDLE_SPEED" => events.push(Event::Spindle(call.to_string())),
            "PROGRAM_STOP" | "OPTIONAL_PROGRAM_STOP" | "PROGRAM_END" => {
                events.push(Event::Stop(name.to_string()))
            }
            _ => {}
        }
    }
    Ok(events)
}

/// `ARC_FEED(first_end, second_end, first_axis, second_axis, rotation, axis_end, a, b, c, …)`:
/// first and second are X, Y in G17, Z, X in G18, Y, Z in G19.
fn arc(s: &State, v: &[f64]) -> Event {
    let (d1, d2, d3) = [(0, 1, 2), (2, 0, 1), (1, 2, 0)][s.plane];
    let mut p = [0.0; 6];
    p[d1] = v[0];
    p[d2] = v[1];
    p[d3] = v[5];
    p[3..6].copy_from_slice(&v[6..9]);
    let end = s.machine(&p);
    let mut c = [0.0; 6];
    c[d1] = v[2];
    c[d2] = v[3];
    // The centre's third coordinate is not printed: only the plane's two are used.
    let centre = s.machine(&c);
    let mut centre3 = [f64::NAN; 3];
    centre3[d1] = centre[d1];
    centre3[d2] = centre[d2];
    Event::Arc(Arc {
        end,
        centre: centre3,
        rotation: v[4] as i32,
        axes: (d1, d2),
        mode: s.mode,
        rate: s.feed,
    })
}

/// rs274's machine-position order of the axes in its canonical events.
#[allow(dead_code)]
pub const AXES: [char; 6] = ['X', 'Y', 'Z', 'A', 'B', 'C'];

/// rs274 prints 4 decimals: positions agree to this (mm or degrees).
#[allow(dead_code)]
pub const TOL: f64 = 2e-4;

/// The canonical events of `program` (with the parameter file `vars` when given), failing with
/// the program when rs274 refuses it.
#[allow(dead_code)]
pub fn interpret(program: &Path, vars: Option<&Path>) -> Vec<Event> {
    match run(program, None, vars) {
        Ok(run) => run.events,
        Err(e) => panic!("{e}\n{}", std::fs::read_to_string(program).unwrap()),
    }
}
