//! Kinematic chain notation: `XCFZ`, `FXYZ`, `YFXZ`, `XYZFCA` …
//!
//! Letters left of `F` move the workpiece, letters right of it move the tool. Within each side the
//! axes are read left to right from the one mounted on the machine frame to the one that carries
//! the workpiece (left side) or the tool (right side). In the paper's `XCFZ` grinder, X is mounted
//! on the frame and the turntable C rides on X (the order of the paper's eq. 2); Z is mounted on
//! the frame and carries the tool.

use crate::iso::Axis;
use std::fmt;
use std::str::FromStr;

/// The most axes a chain may have.
pub const MAX_AXES: usize = 6;

/// Which end of the chain an axis moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Side {
    /// Left of `F`: the axis moves the workpiece (and a tracker mounted on it).
    Workpiece,
    /// Right of `F`: the axis moves the tool (and the reflector).
    Tool,
}

impl Side {
    /// Sign of the nominal motion in the frame: a workpiece-side axis moves the workpiece by
    /// `-command` so that the tool moves by `+command` relative to it (paper, eq. 6: `-x + EXX`).
    pub fn sign(self) -> f64 {
        match self {
            Side::Workpiece => -1.0,
            Side::Tool => 1.0,
        }
    }
}

/// A serial chain of up to six distinct axes from X, Y, Z, A, B, C around the frame `F`.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct Chain {
    /// Workpiece-side axes, from the one on the frame to the one carrying the workpiece.
    pub workpiece: Vec<Axis>,
    /// Tool-side axes, from the one on the frame to the one carrying the tool.
    pub tool: Vec<Axis>,
}

impl Chain {
    /// All axes in chain order: the workpiece side as written, then the tool side as written.
    /// This is the order of commands everywhere in volver ("chain positions").
    pub fn axes(&self) -> impl Iterator<Item = (Axis, Side)> + '_ {
        self.workpiece
            .iter()
            .map(|&a| (a, Side::Workpiece))
            .chain(self.tool.iter().map(|&a| (a, Side::Tool)))
    }

    /// Number of axes.
    pub fn len(&self) -> usize {
        self.workpiece.len() + self.tool.len()
    }

    /// `true` when the chain has no axis (never, for a parsed chain).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Chain position of an axis letter, if the chain has it.
    pub fn position(&self, axis: Axis) -> Option<usize> {
        self.axes().position(|(a, _)| a == axis)
    }
}

impl FromStr for Chain {
    type Err = String;

    /// Parses chain notation, e.g. `"XCFZ"` (case-insensitive; spaces and `-` are ignored).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let cleaned: String = s
            .chars()
            .filter(|c| !c.is_whitespace() && *c != '-')
            .map(|c| c.to_ascii_uppercase())
            .collect();
        let expect = "expected letters from X Y Z A B C around one F, e.g. XCFZ, FXYZ, YFXZ";
        let f_count = cleaned.matches('F').count();
        if f_count != 1 {
            return Err(format!(
                "chain '{s}' has {f_count} 'F' (the machine frame); {expect}"
            ));
        }
        let (left, right) = cleaned.split_once('F').expect("one F");
        let parse_side = |part: &str| -> Result<Vec<Axis>, String> {
            part.chars()
                .map(|c| {
                    Axis::from_letter(c).ok_or_else(|| {
                        format!("chain '{s}' has '{c}', which is not an axis letter; {expect}")
                    })
                })
                .collect()
        };
        let chain = Chain {
            workpiece: parse_side(left)?,
            tool: parse_side(right)?,
        };
        if chain.is_empty() {
            return Err(format!("chain '{s}' has no axis; {expect}"));
        }
        if chain.len() > MAX_AXES {
            return Err(format!(
                "chain '{s}' has {} axes; at most {MAX_AXES} are supported",
                chain.len()
            ));
        }
        let mut seen = [false; 6];
        for (a, _) in chain.axes() {
            if std::mem::replace(&mut seen[a.index()], true) {
                return Err(format!("chain '{s}' names axis {a} twice; {expect}"));
            }
        }
        Ok(chain)
    }
}

impl fmt::Display for Chain {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for a in &self.workpiece {
            write!(f, "{a}")?;
        }
        write!(f, "F")?;
        for a in &self.tool {
            write!(f, "{a}")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_usual_chains() {
        let c: Chain = "XCFZ".parse().unwrap();
        assert_eq!(c.workpiece, vec![Axis::X, Axis::C]);
        assert_eq!(c.tool, vec![Axis::Z]);
        assert_eq!(c.position(Axis::Z), Some(2));
        for s in [
            "FXYZ",
            "YFXZ",
            "XYZFCA",
            "xcfz",
            "wCBXFZYt".trim_matches(['w', 't']),
        ] {
            let c: Chain = s.parse().unwrap();
            assert_eq!(c.to_string(), s.to_ascii_uppercase());
        }
    }

    #[test]
    fn rejects_bad_chains_with_reasons() {
        assert!("XCZ".parse::<Chain>().unwrap_err().contains("0 'F'"));
        assert!("XFFZ".parse::<Chain>().unwrap_err().contains("2 'F'"));
        assert!("XQFZ".parse::<Chain>().unwrap_err().contains("'Q'"));
        assert!("XFX".parse::<Chain>().unwrap_err().contains("twice"));
        assert!("F".parse::<Chain>().unwrap_err().contains("no axis"));
    }
}
