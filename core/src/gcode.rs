//! G-code programs (ISO 6983 / RS-274 subset): the moves of an NC program, for compensation.
//!
//! What is read:
//! - linear moves `G0`/`G1` and arcs `G2`/`G3` (centre by `I J K`, incremental from the start,
//!   or radius `R`; helical arcs move the third axis linearly), with the modal motion code;
//! - `G90`/`G91` (absolute/incremental), `G17`/`G18`/`G19` (arc plane XY, ZX, YZ), `G21` (mm);
//! - axis words for the machine's axes (mm, degrees), comments `( … )` and `; …`, block numbers
//!   `N`, `%` lines, and any other word (`F`, `S`, `M`, `T` …), which is kept as it is.
//!
//! What is refused, with the file, line and word: `G20` and `G70` (inches: convert the program
//! to mm first; `G70` is also a Fanuc lathe cycle), axis words of axes the machine lacks,
//! `G28`/`G30`/`G53`/`G92` with axis words (moves in another frame), scaling, mirroring and
//! rotation of the coordinates (`G51`, `G51.1`, `G68`), canned cycles (`G72`–`G76`,
//! `G81`–`G89`: moves the program does not state), arcs whose plane axes the machine lacks or
//! whose end is off the circle, malformed numbers. The program's coordinates are taken as the machine's axis positions (no
//! work offset); axes not yet programmed start at their reference position.
//!
//! Arcs are linearised into chords whose sagitta is at most the chord tolerance (compensation
//! bends a path, so an arc stays an arc only on the nominal machine); long linear moves can be
//! split too (`max_segment_mm`) so that the compensated path follows the bent one between
//! points. [`Program::compensate`] writes the program back as absolute `G1`/`G0` moves through
//! compensated commands and verifies every written command through the forward model.

use crate::chain::MAX_AXES;
use crate::compensate::Compensator;
use crate::error::{Error, Place, Result};
use crate::iso::Axis;
use crate::machine::{Commands, Machine};

/// How arcs and long moves are cut into points.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Linearise {
    /// Largest distance between an arc and its chords (mm).
    pub chord_tolerance_mm: f64,
    /// Longest linear segment (mm, over the linear axes); `None` keeps linear moves whole.
    pub max_segment_mm: Option<f64>,
}

impl Default for Linearise {
    fn default() -> Self {
        Linearise {
            chord_tolerance_mm: 0.001,
            max_segment_mm: None,
        }
    }
}

/// A motion block's points.
#[derive(Clone, Debug, PartialEq)]
pub struct Motion {
    /// `G0` (rapid) rather than a feed move.
    pub rapid: bool,
    /// Whether the block was an arc (linearised).
    pub arc: bool,
    /// The points to pass through, the last being the block's end (file units: mm, degrees;
    /// chain order).
    pub points: Vec<[f64; MAX_AXES]>,
    /// The block's words other than motion codes, axis words and arc words (`F500 S1000` …).
    pub kept: String,
}

/// One line of a program.
#[derive(Clone, Debug, PartialEq)]
pub struct Block {
    /// 1-based line number.
    pub line: usize,
    /// The line as written.
    pub source: String,
    /// Its move, if it has one.
    pub motion: Option<Motion>,
}

/// A program read for one machine.
#[derive(Clone, Debug, PartialEq)]
pub struct Program {
    /// The file it came from (for messages).
    pub file: String,
    /// Its lines.
    pub blocks: Vec<Block>,
}

/// What [`Program::compensate`] measured.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Report {
    /// Motion blocks read.
    pub moves: usize,
    /// Arcs among them.
    pub arcs: usize,
    /// Points written (each a compensated command).
    pub points: usize,
    /// Largest distance between the uncompensated tool point and its target (mm).
    pub max_error_mm: f64,
    /// Largest deviation of the compensated commands as solved (mm).
    pub max_deviation_mm: f64,
    /// Largest deviation of the commands as written, rounded to the output's decimals (mm).
    pub max_written_deviation_mm: f64,
    /// Lines (1-based) of points whose compensated command leaves an axis' travel.
    pub outside_travel: Vec<usize>,
}

#[derive(Clone, Copy, PartialEq)]
enum Mode {
    Rapid,
    Linear,
    Clockwise,
    Counter,
}

struct Word {
    letter: char,
    value: f64,
    text: String,
}

fn words(code: &str, place: &Place) -> Result<Vec<Word>> {
    let mut out = Vec::new();
    let chars: Vec<char> = code.chars().collect();
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        if c.is_whitespace() {
            i += 1;
            continue;
        }
        if !c.is_ascii_alphabetic() {
            return Err(Error::input(
                place.clone().at_field(c.to_string()),
                format!("expected a word (a letter and a number), found '{c}'"),
            ));
        }
        let letter = c.to_ascii_uppercase();
        i += 1;
        while i < chars.len() && chars[i].is_whitespace() {
            i += 1;
        }
        let num_start = i;
        while i < chars.len() && (chars[i].is_ascii_digit() || matches!(chars[i], '.' | '+' | '-'))
        {
            i += 1;
        }
        let num: String = chars[num_start..i].iter().collect();
        let value: f64 = num.parse().map_err(|_| {
            Error::input(
                place.clone().at_field(letter.to_string()),
                format!("word '{letter}' needs a number, found \"{num}\""),
            )
        })?;
        if !value.is_finite() {
            return Err(Error::input(
                place.clone().at_field(letter.to_string()),
                "the number is not finite",
            ));
        }
        out.push(Word {
            letter,
            value,
            text: format!("{letter}{num}"),
        });
    }
    Ok(out)
}

/// The code of a line without its comments, or an error for an unclosed comment.
fn strip_comments(line: &str, place: &Place) -> Result<String> {
    let mut out = String::new();
    let mut depth = 0;
    for c in line.chars() {
        match c {
            '(' => depth += 1,
            ')' if depth > 0 => depth -= 1,
            ';' if depth == 0 => break,
            _ if depth == 0 => out.push(c),
            _ => {}
        }
    }
    if depth > 0 {
        return Err(Error::input(
            place.clone(),
            "a comment '(' is not closed on its line",
        ));
    }
    Ok(out)
}

impl Program {
    /// Reads a program for `machine`; `file` names it in messages.
    pub fn parse(text: &str, file: &str, machine: &Machine, lin: &Linearise) -> Result<Program> {
        if !(lin.chord_tolerance_mm > 0.0 && lin.chord_tolerance_mm.is_finite()) {
            return Err(Error::Model(
                "the chord tolerance must be a positive length (mm)".into(),
            ));
        }
        let axes = machine.axes();
        let mut pos = [0.0; MAX_AXES];
        for (k, a) in axes.iter().enumerate() {
            pos[k] = a.to_file_units(a.reference);
        }
        let (mut mode, mut absolute, mut plane) = (None::<Mode>, true, 0usize);
        let mut blocks = Vec::new();
        let mut total_points = 0;
        for (i, raw) in text.lines().enumerate() {
            let place = Place::file(file).at_line(i + 1);
            let trimmed = raw.trim();
            let code = if trimmed.starts_with('%') {
                String::new()
            } else {
                strip_comments(trimmed.trim_start_matches('/'), &place)?
            };
            let ws = words(&code, &place)?;
            let mut target = pos;
            let mut moved = false;
            let mut centre = [None::<f64>; 3];
            let mut radius = None;
            let mut block_mode = None;
            let mut other_frame = None;
            let mut kept = Vec::new();
            for w in &ws {
                match w.letter {
                    'G' => {
                        let g = (w.value * 10.0).round() as i64;
                        match g {
                            0 => block_mode = Some(Mode::Rapid),
                            10 => block_mode = Some(Mode::Linear),
                            20 => block_mode = Some(Mode::Clockwise),
                            30 => block_mode = Some(Mode::Counter),
                            170 => plane = 0,
                            180 => plane = 1,
                            190 => plane = 2,
                            900 => absolute = true,
                            910 => absolute = false,
                            210 => {}
                            200 => {
                                return Err(Error::input(
                                    place.at_field("G20"),
                                    "inch programs (G20) are not read: convert the program to mm (G21)",
                                ));
                            }
                            700 => {
                                return Err(Error::input(
                                    place.at_field(&w.text),
                                    "G70 is read as inches on Siemens controls and as a \
                                     finishing cycle on Fanuc lathes; neither can be compensated \
                                     point by point: convert the program to mm and expand cycles",
                                ));
                            }
                            510 | 511 | 680 => {
                                return Err(Error::input(
                                    place.at_field(&w.text),
                                    "scaling, mirroring or rotating the coordinate system \
                                     (G51, G51.1, G68) changes where the programmed points go: \
                                     expand it into the program's coordinates first",
                                ));
                            }
                            720..=760 | 810..=890 if g % 10 == 0 => {
                                return Err(Error::input(
                                    place.at_field(&w.text),
                                    "a canned cycle (G72–G76, G81–G89) makes moves the program \
                                     does not state, which cannot be compensated point by point: \
                                     expand it into G0/G1 moves first",
                                ));
                            }
                            280 | 300 | 530 | 920 => other_frame = Some(w.text.clone()),
                            _ => kept.push(w.text.clone()),
                        }
                    }
                    'X' | 'Y' | 'Z' | 'A' | 'B' | 'C' => {
                        let axis = Axis::from_letter(w.letter).expect("axis letter");
                        let Some((k, _)) = machine.axis(axis) else {
                            return Err(Error::input(
                                place.at_field(w.letter.to_string()),
                                format!(
                                    "axis word {} for an axis the machine ({}) does not have",
                                    w.text,
                                    machine.chain()
                                ),
                            ));
                        };
                        target[k] = if absolute {
                            w.value
                        } else {
                            target[k] + w.value
                        };
                        if !target[k].is_finite() || target[k].abs() > MAX_AXIS_VALUE {
                            return Err(Error::input(
                                place.at_field(w.letter.to_string()),
                                format!(
                                    "{} puts axis {} at {:e}, beyond any machine's travel \
                                     (|value| ≤ {MAX_AXIS_VALUE:e} mm or degrees)",
                                    w.text, w.letter, target[k]
                                ),
                            ));
                        }
                        moved = true;
                    }
                    'U' | 'V' | 'W' => {
                        return Err(Error::input(
                            place.at_field(w.letter.to_string()),
                            format!("axis word {}: secondary axes U, V, W are not read", w.text),
                        ));
                    }
                    'I' => centre[0] = Some(w.value),
                    'J' => centre[1] = Some(w.value),
                    'K' => centre[2] = Some(w.value),
                    'R' => radius = Some(w.value),
                    _ => kept.push(w.text.clone()),
                }
            }
            let has_arc_words = centre.iter().any(Option::is_some) || radius.is_some();
            if let Some(g) = other_frame {
                if moved || has_arc_words {
                    return Err(Error::input(
                        place.at_field(g.clone()),
                        format!(
                            "{g} with axis words moves in another frame; volver compensates programs in one frame"
                        ),
                    ));
                }
                kept.push(g);
            }
            if block_mode.is_some() {
                mode = block_mode;
            }
            let motion = if moved || (has_arc_words && block_mode.is_some()) {
                let Some(m) = mode else {
                    return Err(Error::input(
                        place,
                        "axis words before any motion code (G0, G1, G2, G3)",
                    ));
                };
                let points = match m {
                    Mode::Rapid | Mode::Linear => {
                        linear_points(machine, &pos, &target, lin, &place)?
                    }
                    Mode::Clockwise | Mode::Counter => arc_points(
                        machine,
                        &pos,
                        &target,
                        plane,
                        centre,
                        radius,
                        m == Mode::Clockwise,
                        lin.chord_tolerance_mm,
                        &place,
                    )?,
                };
                total_points += points.len();
                if total_points > MAX_PROGRAM_POINTS {
                    return Err(Error::input(
                        place,
                        format!(
                            "the program needs more than {MAX_PROGRAM_POINTS} points at this \
                             chord tolerance and segment length: raise them, or split the program"
                        ),
                    ));
                }
                pos = target;
                Some(Motion {
                    rapid: m == Mode::Rapid,
                    arc: matches!(m, Mode::Clockwise | Mode::Counter),
                    points,
                    kept: kept.join(" "),
                })
            } else {
                None
            };
            blocks.push(Block {
                line: i + 1,
                source: raw.to_string(),
                motion,
            });
        }
        Ok(Program {
            file: file.to_string(),
            blocks,
        })
    }

    /// The program with every point replaced by its compensated command: motion blocks become
    /// absolute `G1` (or `G0`) moves with every axis, written with `decimals` decimals; other
    /// lines are copied (with `G91` turned into `G90`, since every move is now absolute).
    /// Each written command is verified through the forward model.
    pub fn compensate(
        &self,
        comp: &Compensator,
        machine: &Machine,
        decimals: usize,
        header: &str,
    ) -> Result<(String, Report)> {
        let axes = machine.axes();
        let mut out = String::new();
        // A leading tape mark (%) stays the first line.
        let skip = usize::from(
            self.blocks
                .first()
                .is_some_and(|b| b.source.trim_start().starts_with('%')),
        );
        if skip == 1 {
            out.push_str(&self.blocks[0].source);
            out.push('\n');
        }
        for l in header.lines() {
            out.push_str(&format!("({})\n", l.replace(['(', ')'], "")));
        }
        out.push_str("G90 G21\n");
        let mut rep = Report::default();
        for b in &self.blocks[skip..] {
            let Some(m) = &b.motion else {
                out.push_str(&b.source.replace("G91", "G90").replace("g91", "G90"));
                out.push('\n');
                continue;
            };
            rep.moves += 1;
            rep.arcs += usize::from(m.arc);
            for (j, p) in m.points.iter().enumerate() {
                let mut programmed = Commands::default();
                for (k, a) in axes.iter().enumerate() {
                    programmed.0[k] = a.from_file_units(p[k]);
                }
                let c = comp.compensate(&programmed).map_err(|e| {
                    Error::input(Place::file(&self.file).at_line(b.line), e.to_string())
                })?;
                let (texts, written) = crate::compensate::written(machine, &c.commands, decimals);
                let mut line = String::from(if m.rapid { "G0" } else { "G1" });
                for (a, text) in axes.iter().zip(&texts) {
                    line.push_str(&format!(" {}{text}", a.axis.letter()));
                }
                if j == 0 && !m.kept.is_empty() {
                    line.push(' ');
                    line.push_str(&m.kept);
                }
                if j + 1 == m.points.len() {
                    line.push_str(&format!(" (line {})", b.line));
                }
                out.push_str(&line);
                out.push('\n');
                let written_dev = comp.deviation_mm(&written, c.target);
                rep.points += 1;
                rep.max_error_mm = rep.max_error_mm.max(c.error_mm);
                rep.max_deviation_mm = rep.max_deviation_mm.max(c.deviation_mm);
                rep.max_written_deviation_mm = rep.max_written_deviation_mm.max(written_dev);
                if !c.outside_travel.is_empty() && rep.outside_travel.last() != Some(&b.line) {
                    rep.outside_travel.push(b.line);
                }
            }
        }
        Ok((out, rep))
    }
}

/// Length of a move over the linear axes (mm).
fn linear_length(machine: &Machine, a: &[f64; MAX_AXES], b: &[f64; MAX_AXES]) -> f64 {
    machine
        .axes()
        .iter()
        .enumerate()
        .filter(|(_, ax)| !ax.axis.is_rotary())
        .map(|(k, _)| (b[k] - a[k]).powi(2))
        .sum::<f64>()
        .sqrt()
}

fn lerp(a: &[f64; MAX_AXES], b: &[f64; MAX_AXES], t: f64) -> [f64; MAX_AXES] {
    let mut p = *a;
    for k in 0..MAX_AXES {
        p[k] = a[k] + (b[k] - a[k]) * t;
    }
    p
}

/// The largest axis position read (mm or degrees): 1 km, beyond any machine's travel.
pub const MAX_AXIS_VALUE: f64 = 1e6;

/// The most points one move may be cut into.
pub const MAX_MOVE_POINTS: usize = 100_000;

/// The most points a program may be cut into (48 bytes each per axis set).
pub const MAX_PROGRAM_POINTS: usize = 5_000_000;

/// `n` points for one move, refused (with the place) beyond [`MAX_MOVE_POINTS`] or when `n` is
/// not a number: the move is absurdly long for its tolerance, or its coordinates are.
fn move_points(n: f64, place: &Place) -> Result<usize> {
    if n <= MAX_MOVE_POINTS as f64 {
        Ok((n as usize).max(1))
    } else {
        Err(Error::input(
            place.clone(),
            format!(
                "this move needs {n:.3e} points at the chord tolerance and segment length \
                 (at most {MAX_MOVE_POINTS}): check its coordinates, or raise the tolerances"
            ),
        ))
    }
}

fn linear_points(
    machine: &Machine,
    from: &[f64; MAX_AXES],
    to: &[f64; MAX_AXES],
    lin: &Linearise,
    place: &Place,
) -> Result<Vec<[f64; MAX_AXES]>> {
    let n = match lin.max_segment_mm {
        Some(s) if s > 0.0 => move_points((linear_length(machine, from, to) / s).ceil(), place)?,
        _ => 1,
    };
    Ok((1..=n)
        .map(|i| lerp(from, to, i as f64 / n as f64))
        .collect())
}

/// The points of an arc in plane 0 (XY), 1 (ZX) or 2 (YZ): chords with sagitta ≤ `tol`.
#[allow(clippy::too_many_arguments)]
fn arc_points(
    machine: &Machine,
    from: &[f64; MAX_AXES],
    to: &[f64; MAX_AXES],
    plane: usize,
    centre: [Option<f64>; 3],
    radius: Option<f64>,
    clockwise: bool,
    tol: f64,
    place: &Place,
) -> Result<Vec<[f64; MAX_AXES]>> {
    // Plane axes (first, second) in ISO direction indices, and the offset words' indices.
    let (d1, d2) = [(0, 1), (2, 0), (1, 2)][plane];
    let name = ["G17 (XY)", "G18 (ZX)", "G19 (YZ)"][plane];
    let k_of = |d: usize| -> Result<usize> {
        let axis = Axis::translation(d);
        machine.axis(axis).map(|(k, _)| k).ok_or_else(|| {
            Error::input(
                place.clone(),
                format!(
                    "an arc in plane {name} needs axis {axis}, which the machine ({}) lacks",
                    machine.chain()
                ),
            )
        })
    };
    let (k1, k2) = (k_of(d1)?, k_of(d2)?);
    let (s1, s2, e1, e2) = (from[k1], from[k2], to[k1], to[k2]);
    let (c1, c2) = match (centre[d1], centre[d2], radius) {
        (None, None, Some(r)) => {
            let (dx, dy) = (e1 - s1, e2 - s2);
            let chord = (dx * dx + dy * dy).sqrt();
            if chord == 0.0 || chord > 2.0 * r.abs() + tol {
                return Err(Error::input(
                    place.clone().at_field("R"),
                    format!("radius {r} mm cannot join points {chord:.4} mm apart"),
                ));
            }
            let h = (r * r - chord * chord / 4.0).max(0.0).sqrt();
            // The centre left of the chord for a counter-clockwise short arc.
            let side = if clockwise == (r > 0.0) { -1.0 } else { 1.0 };
            let (mx, my) = (s1 + dx / 2.0, s2 + dy / 2.0);
            (mx - side * h * dy / chord, my + side * h * dx / chord)
        }
        (a, b, None) if a.is_some() || b.is_some() => {
            (s1 + a.unwrap_or(0.0), s2 + b.unwrap_or(0.0))
        }
        _ => {
            return Err(Error::input(
                place.clone(),
                format!(
                    "an arc in plane {name} needs its centre ({}{} words) or a radius (R), not both",
                    ["I", "K", "J"][plane],
                    ["J", "I", "K"][plane]
                ),
            ));
        }
    };
    let r0 = ((s1 - c1).powi(2) + (s2 - c2).powi(2)).sqrt();
    let r1 = ((e1 - c1).powi(2) + (e2 - c2).powi(2)).sqrt();
    // CAM output rounds centres: 2 µm, or 1e-4 of the radius, of mismatch is accepted.
    if (r0 - r1).abs() > 0.002_f64.max(1e-4 * r0.max(r1)) {
        return Err(Error::input(
            place.clone(),
            format!(
                "the arc's end is off its circle: radius {r0:.4} mm at the start, {r1:.4} mm at the end"
            ),
        ));
    }
    let a0 = (s2 - c2).atan2(s1 - c1);
    let a1 = (e2 - c2).atan2(e1 - c1);
    let tau = std::f64::consts::TAU;
    let mut sweep = if clockwise { a0 - a1 } else { a1 - a0 };
    sweep = sweep.rem_euclid(tau);
    if sweep < 1e-12 {
        sweep = tau; // a full circle
    }
    let step = 2.0 * (1.0 - (tol / r0).min(1.0)).acos();
    let n = move_points((sweep / step.max(1e-9)).ceil(), place)?;
    let dir = if clockwise { -1.0 } else { 1.0 };
    Ok((1..=n)
        .map(|i| {
            let t = i as f64 / n as f64;
            let mut p = lerp(from, to, t);
            if i < n {
                let a = a0 + dir * sweep * t;
                let r = r0 + (r1 - r0) * t;
                p[k1] = c1 + r * a.cos();
                p[k2] = c2 + r * a.sin();
            }
            p
        })
        .collect())
}
