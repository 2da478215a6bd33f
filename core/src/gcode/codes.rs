//! The codes volver knows, compared by value (`G043.4` is `G43.4`, `M0128` is `M128`), with
//! the modal groups of RS274NGC (LinuxCNC's G-code reference, "Modal Groups"; NIST RS274NGC
//! version 3, table 4). What is not listed here is refused: a list of what is known, not of
//! what is forbidden.

use super::lex::Word;
use crate::error::{Error, Place, Result};

/// The G codes volver reads, as written in messages.
pub const KNOWN_G: &str = "G0 G1 G2 G3 G4 G10 (L1, L2, L20) G17 G18 G19 G20 G21 G28 G28.1 \
    G30 G30.1 G40 G43 G43.1 G49 G52 G53 G54–G59.3 G61 G61.1 G64 G73 G80 G81 G82 G83 G85 \
    G86 G89 G90 G91 G90.1 G91.1 G92 G92.1 G92.2 G92.3 G93 G94 G95 G96 G97 G98 G99";

/// The M codes volver reads, as written in messages.
pub const KNOWN_M: &str = "M0 M1 M2 M3 M4 M5 M6 M7 M8 M9 M19 M30 M48–M53 M60 M61 M62–M68";

/// A code's number in tenths (`G43.4` → 434), or `None` when it has a finer fraction
/// (`G43.45`), which no control knows.
pub(crate) fn tenths(w: &Word) -> Option<i64> {
    let t = w.value * 10.0;
    let r = t.round();
    ((t - r).abs() < 1e-6 && r.abs() < 1e7).then_some(r as i64)
}

/// The code as a control names it (`G43.4`, `M6`).
pub(crate) fn name(letter: char, tenths: i64) -> String {
    if tenths % 10 == 0 {
        format!("{letter}{}", tenths / 10)
    } else {
        format!("{letter}{}.{}", tenths / 10, (tenths % 10).abs())
    }
}

/// The RS274NGC modal group of a G code volver reads (0 for the non-modal codes), `None` when
/// volver does not read it.
pub(crate) fn g_group(g: i64) -> Option<u8> {
    Some(match g {
        40 | 100 | 280 | 281 | 300 | 301 | 520 | 530 | 920 | 921 | 922 | 923 => 0,
        0 | 10 | 20 | 30 | 730 | 800 | 810 | 820 | 830 | 850 | 860 | 890 => 1,
        170 | 180 | 190 => 2,
        900 | 910 => 3,
        901 | 911 => 4,
        930 | 940 | 950 => 5,
        200 | 210 => 6,
        400 => 7,
        430 | 431 | 490 => 8,
        980 | 990 => 10,
        540 | 550 | 560 | 570 | 580 | 590 | 591 | 592 | 593 => 12,
        610 | 611 | 640 => 13,
        960 | 970 => 14,
        _ => return None,
    })
}

/// The name of a modal group, for messages.
pub(crate) fn group_name(letter: char, group: u8) -> &'static str {
    match (letter, group) {
        ('G', 1) => "motion",
        ('G', 2) => "plane",
        ('G', 3) => "distance mode",
        ('G', 4) => "arc distance mode",
        ('G', 5) => "feed rate mode",
        ('G', 6) => "units",
        ('G', 7) => "cutter compensation",
        ('G', 8) => "tool length offset",
        ('G', 10) => "canned cycle return",
        ('G', 12) => "coordinate system",
        ('G', 13) => "path control",
        ('G', 14) => "spindle speed mode",
        ('M', 4) => "stopping",
        ('M', 6) => "tool change",
        ('M', 7) => "spindle",
        ('M', 9) => "override",
        _ => "same",
    }
}

/// The modal group of an M code volver reads, `None` when volver does not read it.
pub(crate) fn m_group(m: i64) -> Option<u8> {
    Some(match m {
        0 | 10 | 20 | 300 | 600 => 4,
        60 | 610 => 6,
        30 | 40 | 50 => 7,
        70 | 80 | 90 => 8,
        480..=530 => 9,
        190 => 11,
        620..=680 => 12,
        _ => return None,
    })
}

/// The tool-centre-point codes, with the controls that use them: the control then does the
/// five-axis inverse kinematics itself, so the program's coordinates are the tool's tip and
/// direction in the workpiece, not machine-axis positions.
pub const TOOL_CENTRE_POINT: [(char, i64, &str); 4] = [
    (
        'G',
        434,
        "Fanuc, Mazak, Hurco, Mitsubishi: tool centre point control",
    ),
    (
        'G',
        435,
        "Fanuc: tool centre point control with tool-axis vectors",
    ),
    ('G', 2340, "Haas: tool centre point control (TCPC)"),
    ('M', 1280, "Heidenhain (ISO programs): TCPM"),
];

/// Why a G code that volver recognises but does not compensate is refused, if it is one.
pub(crate) fn g_refusal(g: i64) -> Option<&'static str> {
    Some(match g {
        330 | 331 | 760 => {
            "spindle-synchronised motion (G33, G33.1, G76 threading): the control ties the move \
             to the spindle, and compensation would bend it; thread on a compensated start point \
             by hand"
        }
        380..=385 | 310 => {
            "a probing move (G38.x, G31): where it stops is not known in advance, so it cannot \
             be compensated; probe with the uncompensated program"
        }
        410 | 420 | 411 | 421 => {
            "cutter radius compensation (G41, G42): the control offsets the path it is given, \
             which compensation bends into chords; output the tool-centre path from the CAM \
             (G40) and compensate that"
        }
        432 => "G43.2 (an added tool offset) is not read: give the tool's length in the tool table",
        50..=53 => "splines and NURBS (G5, G5.1, G5.2, G5.3) are not read: output lines and arcs",
        70 | 71 => {
            "G7/G7.1 (lathe diameter mode, cylindrical interpolation): its words are not \
             positions of the machine's axes; volver compensates milling programs"
        }
        740 | 840 => {
            "a tapping cycle (G74, G84) is synchronised with the spindle and cannot be expanded \
             into compensated G1 moves"
        }
        870 | 880 => "back boring (G87) and G88 (hand retract) are not expanded",
        720..=760 => "Fanuc lathe cycles (G72–G76) make moves the program does not state",
        510 | 511 | 680 | 682 | 683 | 690 => {
            "scaling, mirroring or rotating the coordinate system (G51, G51.1, G68, a tilted \
             working plane G68.2/G68.3) changes where the programmed points go: expand it into \
             the program's coordinates first"
        }
        700 => {
            "G70 is read as inches on Siemens controls and as a finishing cycle on Fanuc lathes: \
             write G20 for inches, expand cycles"
        }
        _ => return None,
    })
}

/// Why an M code that volver recognises but does not read is refused, if it is one.
pub(crate) fn m_refusal(m: i64) -> Option<&'static str> {
    Some(match m {
        980 | 990 => {
            "subprogram calls and returns (M98, M99) run moves this file does not state: expand \
             the subprograms into the program"
        }
        700..=730 => "M70–M73 save and restore modal state, which volver does not follow",
        _ => return None,
    })
}

/// Refuses `w` (a G or M word) when it switches on tool-centre-point mode.
pub(crate) fn refuse_tool_centre_point(w: &Word, code: i64, place: &Place) -> Result<()> {
    for (letter, c, control) in TOOL_CENTRE_POINT {
        if letter == w.letter && c == code {
            let name = name(letter, c);
            return Err(Error::input(
                place.clone().at_field(&w.text),
                format!(
                    "{} ({name}) switches on tool-centre-point mode ({control}): the control \
                     then does the five-axis inverse kinematics itself, so the program's \
                     coordinates are not machine-axis positions that volver can compensate; \
                     post-process the program into machine-axis coordinates (TCP off) and \
                     compensate that",
                    w.text
                ),
            ));
        }
    }
    Ok(())
}

/// Tool-centre-point words of other controls' languages, which are no RS-274 words: refused
/// by name before the words are read.
pub const TOOL_CENTRE_POINT_NAMES: [(&str, &str); 3] = [
    ("TCPM", "Heidenhain: FUNCTION TCPM"),
    ("TRAORI", "Siemens: orientation transformation"),
    ("RTCP", "RTCP mode (Fidia, Okuma and others)"),
];

/// Refuses a line naming a tool-centre-point mode of another language
/// ([`TOOL_CENTRE_POINT_NAMES`]).
pub(crate) fn refuse_tool_centre_point_names(code: &str, place: &Place) -> Result<()> {
    let upper: String = code
        .chars()
        .filter(|c| !c.is_whitespace())
        .collect::<String>()
        .to_ascii_uppercase();
    for (word, control) in TOOL_CENTRE_POINT_NAMES {
        if upper.contains(word) {
            return Err(Error::input(
                place.clone().at_field(word),
                format!(
                    "{word} switches on tool-centre-point mode ({control}): the program's \
                     coordinates are then not machine-axis positions; post-process the program \
                     into machine-axis coordinates (TCP off) and compensate that"
                ),
            ));
        }
    }
    Ok(())
}
