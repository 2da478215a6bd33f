//! G-code programs (ISO 6983 / RS-274 subset): the moves of an NC program, for compensation.
//!
//! What is read, with RS-274/NGC's semantics (as LinuxCNC documents them):
//! - linear moves `G0`/`G1` and arcs `G2`/`G3` (centre by `I J K`, incremental from the start,
//!   or radius `R`; helical arcs move the third axis linearly), with the modal motion code;
//! - `G90`/`G91` (absolute/incremental), `G17`/`G18`/`G19` (arc plane XY, ZX, YZ), `G21` (mm);
//!   modal words apply to the whole block wherever they stand in it (`G1 X10 G91` is an
//!   incremental move), and two words of one modal group in a block are refused;
//! - numbers with an optional sign, digits and one optional decimal point (`X-.5`, `X5.`,
//!   `G091`, `G 91`); exponents are not G-code (`X1e2` is refused: a control reads X1 and E2);
//! - axis words for the machine's axes (mm, degrees), comments `( … )` and `; …`, block delete
//!   `/`, block numbers `N`, program numbers `O`, `%` lines, and any other word (`F`, `S`,
//!   `M`, `T` …), which is kept as it is;
//! - lines ended by LF, CR LF or CR alone.
//!
//! What is refused, with the file, line and word: `G20` and `G70` (inches: convert the program
//! to mm first; `G70` is also a Fanuc lathe cycle), axis words of axes the machine lacks, two
//! words for one axis in a block, `G28`/`G30`/`G53`/`G92` with axis words (moves in another
//! frame), scaling, mirroring and rotation of the coordinates (`G51`, `G51.1`, `G68`), canned
//! cycles (`G72`–`G76`, `G81`–`G89`: moves the program does not state), tilted working planes
//! (`G68.2`, `G68.3`), tool-centre-point mode (`G43.4`, `G43.5`, `G234`, `M128`, `TCPM`,
//! `TRAORI`, `RTCP`: the control does the inverse kinematics there, see
//! [`TOOL_CENTRE_POINT_WORDS`]), arcs whose plane axes the machine lacks or whose end is off the
//! circle, malformed numbers. The program's coordinates are taken as the machine's axis
//! positions (no work offset); axes not yet programmed start at their reference position.
//!
//! Arcs are linearised into chords whose sagitta is at most the chord tolerance (compensation
//! bends a path, so an arc stays an arc only on the nominal machine); long linear moves can be
//! split too (`max_segment_mm`) so that the compensated path follows the bent one between
//! points. [`Program::compensate`] writes the program back as absolute `G1`/`G0` moves through
//! compensated commands, under one explicit modal state and without the input's mode words
//! that would change their meaning, and verifies every written command through the forward
//! model.

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
}

/// One line of a program.
#[derive(Clone, Debug, PartialEq)]
pub struct Block {
    /// 1-based line number.
    pub line: usize,
    /// The line as written.
    pub source: String,
    /// Block delete: the block starts with `/` (a control skips it when its switch is on).
    pub optional: bool,
    /// Its block number as written (`N20`).
    pub number: Option<String>,
    /// Its words other than the block number, mode words, motion codes, axis words and arc
    /// words, as written (`F500`, `S1000`, `M3`, `O1000` …).
    pub kept: Vec<String>,
    /// Its comments as written, with their delimiters (`(roughing)`, `; end`).
    pub comments: Vec<String>,
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
    /// With the tool's orientation compensated: the largest angle of the uncompensated tool
    /// direction from its target (rad).
    pub max_direction_error_rad: f64,
    /// … of the compensated commands' directions away from the singularity, as solved (rad).
    pub max_direction_deviation_rad: f64,
    /// … of those commands as written (rad).
    pub max_written_direction_deviation_rad: f64,
    /// Lines (1-based) of points whose compensated command passes near the singularity
    /// ([`crate::compensate::OrientationResult::near_singularity`]: the direction is met there
    /// only as far as the tilt axis can).
    pub near_singularity: Vec<usize>,
    /// The largest angle left there (rad).
    pub max_singular_direction_deviation_rad: f64,
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

/// The words that switch a control into tool-centre-point mode, where it does the five-axis
/// inverse kinematics itself (the programmed coordinates are then the tool tip and direction in
/// the workpiece, not machine-axis positions), with the controls that use them.
pub const TOOL_CENTRE_POINT_WORDS: [(&str, &str); 7] = [
    (
        "G43.4",
        "Fanuc, Mazak, Hurco, Mitsubishi: tool centre point control",
    ),
    (
        "G43.5",
        "Fanuc: tool centre point control with tool-axis vectors",
    ),
    ("G234", "Haas: tool centre point control (TCPC)"),
    ("M128", "Heidenhain (ISO programs): TCPM"),
    ("TCPM", "Heidenhain: FUNCTION TCPM"),
    ("TRAORI", "Siemens: orientation transformation"),
    ("RTCP", "RTCP mode (Fidia, Okuma and others)"),
];

/// Refuses a block that switches tool-centre-point mode on ([`TOOL_CENTRE_POINT_WORDS`]),
/// naming the word: volver compensates machine-axis positions, and in that mode the control
/// computes them from the program.
fn refuse_tool_centre_point(code: &str, place: &Place) -> Result<()> {
    let upper: String = code
        .chars()
        .filter(|c| !c.is_whitespace())
        .collect::<String>()
        .to_ascii_uppercase();
    for (word, control) in TOOL_CENTRE_POINT_WORDS {
        for (at, _) in upper.match_indices(word) {
            // A whole word: G43.4 not G43.45 nor G43.4 inside G143.4 (a word starts at a letter no
            // letter precedes: X10M128 is M128), TRAORI not the start of a longer name.
            let numeric = word.ends_with(|c: char| c.is_ascii_digit());
            let ends = match upper[at + word.len()..].chars().next() {
                None => true,
                Some(c) if numeric => !(c.is_ascii_digit() || c == '.'),
                Some(c) => !c.is_ascii_alphanumeric(),
            };
            let starts = !upper[..at]
                .chars()
                .last()
                .is_some_and(|c| c.is_ascii_alphabetic());
            if ends && starts {
                return Err(Error::input(
                    place.clone().at_field(word),
                    format!(
                        "{word} switches on tool-centre-point mode ({control}): the control then does \
                         the five-axis inverse kinematics itself, so the program's coordinates are not \
                         machine-axis positions that volver can compensate; post-process the program \
                         into machine-axis coordinates (TCP off) and compensate that"
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// The words of a block's code (comments removed). Numbers follow RS-274/NGC: an optional sign,
/// digits and at most one decimal point, no exponent; spaces may stand between a letter and its
/// number (`G 91`) and inside neither.
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
        if i < chars.len() && matches!(chars[i], '+' | '-') {
            i += 1;
        }
        while i < chars.len() && (chars[i].is_ascii_digit() || chars[i] == '.') {
            i += 1;
        }
        let num: String = chars[num_start..i].iter().collect();
        let digits = num.chars().filter(char::is_ascii_digit).count();
        let points = num.matches('.').count();
        let value: f64 = match num.parse() {
            Ok(v) if digits > 0 && points <= 1 => v,
            _ => {
                return Err(Error::input(
                    place.clone().at_field(letter.to_string()),
                    format!("word '{letter}' needs a number, found \"{num}\""),
                ));
            }
        };
        // `X1e2` is X1 followed by a word E2 to a control: G-code numbers have no exponent.
        if i + 1 < chars.len()
            && matches!(chars[i], 'e' | 'E')
            && (chars[i + 1].is_ascii_digit() || matches!(chars[i + 1], '+' | '-' | '.'))
        {
            let tail: String = chars[i..]
                .iter()
                .take_while(|c| !c.is_whitespace())
                .collect();
            return Err(Error::input(
                place.clone().at_field(letter.to_string()),
                format!(
                    "{letter}{num}{tail} is not a G-code number (G-code has no exponent; a \
                     control reads {letter}{num} and then a word {tail}): write the number out in \
                     full, or put a space before a real E word"
                ),
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

/// A line split into its code and its comments (as written, each with its delimiters), or an
/// error for an unclosed comment.
fn split_comments(line: &str, place: &Place) -> Result<(String, Vec<String>)> {
    let mut code = String::new();
    let mut comments = Vec::new();
    let mut depth = 0;
    let mut current = String::new();
    for (i, c) in line.char_indices() {
        match c {
            '(' => {
                depth += 1;
                current.push(c);
            }
            ')' if depth > 0 => {
                depth -= 1;
                current.push(c);
                if depth == 0 {
                    comments.push(std::mem::take(&mut current));
                }
            }
            ';' if depth == 0 => {
                comments.push(line[i..].to_string());
                break;
            }
            _ if depth == 0 => code.push(c),
            _ => current.push(c),
        }
    }
    if depth > 0 {
        return Err(Error::input(
            place.clone(),
            "a comment '(' is not closed on its line",
        ));
    }
    Ok((code, comments))
}

/// The lines of a program, whatever their endings (LF, CR LF or CR alone).
fn program_lines(text: &str) -> Vec<&str> {
    let mut lines = Vec::new();
    let mut rest = text;
    while let Some(i) = rest.find(['\n', '\r']) {
        lines.push(&rest[..i]);
        let skip = if rest[i..].starts_with("\r\n") { 2 } else { 1 };
        rest = &rest[i + skip..];
    }
    if !rest.is_empty() {
        lines.push(rest);
    }
    lines
}

/// The modal groups of RS-274/NGC that volver reads (two words of one group in one block are an
/// error): motion, plane, distance mode, units.
fn modal_group(g: i64) -> Option<&'static str> {
    match g {
        0 | 10 | 20 | 30 => Some("motion (G0, G1, G2, G3)"),
        170 | 180 | 190 => Some("plane (G17, G18, G19)"),
        900 | 910 => Some("distance mode (G90, G91)"),
        200 | 210 => Some("units (G20, G21)"),
        _ => None,
    }
}

/// The modal state the reader starts in and the writer states at the top of its output:
/// absolute, mm, XY plane.
pub const START_STATE: &str = "G90 G21 G17";

impl Program {
    /// Reads a program for `machine`; `file` names it in messages.
    ///
    /// Modal words apply to the whole block, whatever their place in it (RS-274/NGC): `G1 X10
    /// G91` moves X by 10. Two words of one modal group, or two words for one axis, in one block
    /// are refused.
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
        for (i, raw) in program_lines(text).into_iter().enumerate() {
            let place = Place::file(file).at_line(i + 1);
            let trimmed = raw.trim();
            if trimmed.starts_with('%') {
                blocks.push(Block {
                    line: i + 1,
                    source: raw.to_string(),
                    optional: false,
                    number: None,
                    kept: Vec::new(),
                    comments: Vec::new(),
                    motion: None,
                });
                continue;
            }
            let optional = trimmed.starts_with('/');
            let (code, comments) = split_comments(trimmed.trim_start_matches('/'), &place)?;
            refuse_tool_centre_point(&code, &place)?;
            let ws = words(&code, &place)?;
            // Modal words first: they apply to the whole block.
            let mut groups: Vec<(&str, &str)> = Vec::new();
            let mut block_mode = None;
            let mut other_frame = None;
            let mut kept = Vec::new();
            let mut number = None;
            for w in &ws {
                if w.letter == 'N' {
                    if number.is_some() {
                        return Err(Error::input(
                            place.at_field(&w.text),
                            "two block numbers (N) in one block",
                        ));
                    }
                    number = Some(w.text.clone());
                    continue;
                }
                if w.letter != 'G' {
                    continue;
                }
                let g = (w.value * 10.0).round() as i64;
                if let Some(group) = modal_group(g) {
                    if let Some((_, first)) = groups.iter().find(|(gr, _)| *gr == group) {
                        return Err(Error::input(
                            place.at_field(&w.text),
                            format!(
                                "{first} and {} are both in the {group} modal group: a block may \
                                 hold one of them",
                                w.text
                            ),
                        ));
                    }
                    groups.push((group, &w.text));
                }
                match g {
                    0 => block_mode = Some(Mode::Rapid),
                    10 => block_mode = Some(Mode::Linear),
                    20 => block_mode = Some(Mode::Clockwise),
                    30 => block_mode = Some(Mode::Counter),
                    // Plane words are kept: they mean nothing to volver's G1 moves but matter
                    // to the control's cutter compensation.
                    170 | 180 | 190 => {
                        plane = ((g - 170) / 10) as usize;
                        kept.push(w.text.clone());
                    }
                    900 => absolute = true,
                    910 => absolute = false,
                    // Arc-centre distance modes (G90.1, G91.1): volver writes no arcs.
                    901 | 911 | 210 => {}
                    200 => {
                        return Err(Error::input(
                            place.at_field(&w.text),
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
                    510 | 511 | 680 | 682 | 683 => {
                        return Err(Error::input(
                            place.at_field(&w.text),
                            "scaling, mirroring or rotating the coordinate system \
                             (G51, G51.1, G68, a tilted working plane G68.2/G68.3) changes \
                             where the programmed points go: expand it into the program's \
                             coordinates first",
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
            // Then the axis and arc words, in the block's modes.
            let mut target = pos;
            let mut seen = [false; MAX_AXES];
            let mut moved = false;
            let mut centre = [None::<f64>; 3];
            let mut radius = None;
            for w in &ws {
                match w.letter {
                    'G' | 'N' => {}
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
                        if std::mem::replace(&mut seen[k], true) {
                            return Err(Error::input(
                                place.at_field(&w.text),
                                format!("two words for axis {} in one block", w.letter),
                            ));
                        }
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
                })
            } else {
                if has_arc_words {
                    return Err(Error::input(
                        place,
                        "arc words (I, J, K, R) without axis words or a motion code",
                    ));
                }
                None
            };
            blocks.push(Block {
                line: i + 1,
                source: raw.to_string(),
                optional,
                number,
                kept,
                comments,
                motion,
            });
        }
        Ok(Program {
            file: file.to_string(),
            blocks,
        })
    }

    /// The program with every point replaced by its compensated command, written for a
    /// control: the header comment and one explicit modal state ([`START_STATE`]: absolute, mm,
    /// XY plane) after any leading `%` and program number (`O…`); motion blocks become absolute
    /// `G1` (or `G0`) moves with every axis in the conventional order X Y Z A B C, written with
    /// `decimals` decimals; every other block keeps its words but the mode words whose meaning
    /// volver's absolute moves replace (`G90`, `G91`, `G90.1`, `G91.1`, `G21`, and motion codes
    /// without axis words). Block delete (`/`), block numbers (`N`, first in the block) and
    /// comments stay in place. Each written command is verified through the forward model.
    pub fn compensate(
        &self,
        comp: &Compensator,
        machine: &Machine,
        decimals: usize,
        header: &str,
    ) -> Result<(String, Report)> {
        if decimals > MAX_DECIMALS {
            return Err(Error::Model(format!(
                "{decimals} decimals: at most {MAX_DECIMALS} (1e-{MAX_DECIMALS} mm is far below \
                 any machine's resolution)"
            )));
        }
        let axes = machine.axes();
        let mut order: Vec<usize> = (0..axes.len()).collect();
        order.sort_by_key(|&k| Axis::ALL.iter().position(|&a| a == axes[k].axis));
        let mut out = String::new();
        // Leading tape marks (%) and program numbers (O…) stay first.
        let lead = self
            .blocks
            .iter()
            .take_while(|b| {
                b.source.trim_start().starts_with('%')
                    || (b.motion.is_none()
                        && b.number.is_none()
                        && !b.optional
                        && b.kept.len() == 1
                        && b.kept[0].starts_with('O'))
            })
            .count();
        for b in &self.blocks[..lead] {
            out.push_str(&b.rewritten(""));
            out.push('\n');
        }
        for l in header.lines() {
            out.push_str(&format!("({})\n", l.replace(['(', ')'], "")));
        }
        out.push_str(START_STATE);
        out.push('\n');
        let mut rep = Report::default();
        for b in &self.blocks[lead..] {
            let Some(m) = &b.motion else {
                let line = b.rewritten("");
                if !line.is_empty() || b.source.trim().is_empty() {
                    out.push_str(&line);
                    out.push('\n');
                }
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
                let mut moves = String::from(if m.rapid { "G0" } else { "G1" });
                for &k in &order {
                    moves.push_str(&format!(" {}{}", axes[k].axis.letter(), texts[k]));
                }
                let line = if j == 0 {
                    b.rewritten(&moves)
                } else {
                    let prefix = if b.optional { "/" } else { "" };
                    format!("{prefix}{moves}")
                };
                out.push_str(&line);
                if j + 1 == m.points.len() {
                    out.push_str(&format!(" (line {})", b.line));
                }
                out.push('\n');
                let written_dev = comp.deviation_mm(&written, c.target);
                rep.points += 1;
                rep.max_error_mm = rep.max_error_mm.max(c.error_mm);
                rep.max_deviation_mm = rep.max_deviation_mm.max(c.deviation_mm);
                rep.max_written_deviation_mm = rep.max_written_deviation_mm.max(written_dev);
                if !c.outside_travel.is_empty() && rep.outside_travel.last() != Some(&b.line) {
                    rep.outside_travel.push(b.line);
                }
                if let Some(o) = &c.orientation {
                    rep.max_direction_error_rad = rep.max_direction_error_rad.max(o.error_rad);
                    if o.near_singularity {
                        rep.max_singular_direction_deviation_rad = rep
                            .max_singular_direction_deviation_rad
                            .max(o.deviation_rad);
                        if rep.near_singularity.last() != Some(&b.line) {
                            rep.near_singularity.push(b.line);
                        }
                    } else {
                        let wd = comp.direction_deviation_rad(&written, o.target);
                        rep.max_direction_deviation_rad =
                            rep.max_direction_deviation_rad.max(o.deviation_rad);
                        rep.max_written_direction_deviation_rad =
                            rep.max_written_direction_deviation_rad.max(wd);
                    }
                }
            }
        }
        Ok((out, rep))
    }

    /// Every point the program moves through, in order (file units, chain order), with whether
    /// it is a rapid move and whether its block is optional (block delete).
    pub fn points(&self) -> Vec<([f64; MAX_AXES], bool, bool)> {
        self.blocks
            .iter()
            .filter_map(|b| b.motion.as_ref().map(|m| (b, m)))
            .flat_map(|(b, m)| m.points.iter().map(move |p| (*p, m.rapid, b.optional)))
            .collect()
    }
}

impl Block {
    /// The block as volver writes it: block delete, block number, `moves` (when not empty), the
    /// kept words and the comments. A tape-mark line (`%`) is copied.
    fn rewritten(&self, moves: &str) -> String {
        if self.source.trim_start().starts_with('%') {
            return self.source.trim().to_string();
        }
        let mut parts: Vec<&str> = Vec::new();
        if let Some(n) = &self.number {
            parts.push(n);
        }
        if !moves.is_empty() {
            parts.push(moves);
        }
        parts.extend(self.kept.iter().map(String::as_str));
        parts.extend(self.comments.iter().map(String::as_str));
        let body = parts.join(" ");
        if self.optional && !body.is_empty() {
            format!("/{body}")
        } else {
            body
        }
    }
}

/// The most decimals [`Program::compensate`] writes.
pub const MAX_DECIMALS: usize = 12;

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
