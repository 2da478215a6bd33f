//! The ISO 230-1 error catalogue: axis letters, component errors (EXX … ECC), location errors of
//! rotary axes (X0C, Y0C, A0C, B0C …) and squareness errors of linear axes (A0Z, B0Z, C0Y …).
//!
//! Names are written with the digit zero (`X0C`); the letter O (`XOC`, the paper's spelling) and
//! a leading `E` (`EX0C`, `EB0Z`) are accepted on input. Translations are in mm, rotations in rad.

use crate::units::{UM_PER_MM, URAD_PER_RAD};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// One of the six ISO letters. As a machine axis: X, Y, Z are linear axes along x, y, z; A, B, C
/// rotary axes about x, y, z. As an error component: X, Y, Z are translations along x, y, z
/// (mm); A, B, C rotations about x, y, z (rad).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Axis {
    /// Linear along x / translation along x.
    X,
    /// Linear along y / translation along y.
    Y,
    /// Linear along z / translation along z.
    Z,
    /// Rotary about x / rotation about x.
    A,
    /// Rotary about y / rotation about y.
    B,
    /// Rotary about z / rotation about z.
    C,
}

impl Axis {
    /// All six letters in ISO order.
    pub const ALL: [Axis; 6] = [Axis::X, Axis::Y, Axis::Z, Axis::A, Axis::B, Axis::C];

    /// `true` for A, B, C.
    pub fn is_rotary(self) -> bool {
        matches!(self, Axis::A | Axis::B | Axis::C)
    }

    /// The coordinate direction, 0 = x, 1 = y, 2 = z (X and A → 0, Y and B → 1, Z and C → 2).
    pub fn direction(self) -> usize {
        match self {
            Axis::X | Axis::A => 0,
            Axis::Y | Axis::B => 1,
            Axis::Z | Axis::C => 2,
        }
    }

    /// Index in [`Axis::ALL`]: X 0, Y 1, Z 2, A 3, B 4, C 5.
    pub fn index(self) -> usize {
        self as usize
    }

    /// The letter.
    pub fn letter(self) -> char {
        match self {
            Axis::X => 'X',
            Axis::Y => 'Y',
            Axis::Z => 'Z',
            Axis::A => 'A',
            Axis::B => 'B',
            Axis::C => 'C',
        }
    }

    /// The axis of a letter (upper or lower case).
    pub fn from_letter(c: char) -> Option<Axis> {
        match c.to_ascii_uppercase() {
            'X' => Some(Axis::X),
            'Y' => Some(Axis::Y),
            'Z' => Some(Axis::Z),
            'A' => Some(Axis::A),
            'B' => Some(Axis::B),
            'C' => Some(Axis::C),
            _ => None,
        }
    }

    /// The translation letter of a direction (0 → X, 1 → Y, 2 → Z).
    pub fn translation(direction: usize) -> Axis {
        [Axis::X, Axis::Y, Axis::Z][direction]
    }

    /// The rotation letter of a direction (0 → A, 1 → B, 2 → C).
    pub fn rotation(direction: usize) -> Axis {
        [Axis::A, Axis::B, Axis::C][direction]
    }
}

impl fmt::Display for Axis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.letter())
    }
}

/// The parameter group of an error, used by phased strategies (paper, table 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[non_exhaustive]
pub enum Group {
    /// Squareness errors of linear axes (A0Z, B0Z, C0Y …).
    Squareness,
    /// Translational errors: EX*, EY*, EZ* and rotary-axis position errors (X0C …).
    Translation,
    /// Rotational errors: EA*, EB*, EC* and rotary-axis orientation errors (A0C …).
    Rotation,
    /// The laser tracker's pose.
    Tracker,
    /// Anything else (extra physical effects added by the diagnosis loop).
    Other,
}

impl fmt::Display for Group {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Group::Squareness => "squareness",
            Group::Translation => "translation",
            Group::Rotation => "rotation",
            Group::Tracker => "tracker",
            Group::Other => "other",
        })
    }
}

/// Unit of a parameter or error value.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[non_exhaustive]
pub enum Unit {
    /// Millimetres.
    #[serde(rename = "mm")]
    Mm,
    /// Radians.
    #[serde(rename = "rad")]
    Rad,
    /// Millimetres per hour (thermal drift rates).
    #[serde(rename = "mm/h")]
    MmPerHour,
    /// Parts per million (scale errors).
    #[serde(rename = "ppm")]
    Ppm,
    /// Parts per million per hour (a scale growing with time).
    #[serde(rename = "ppm/h")]
    PpmPerHour,
    /// Radians per hour (an orientation drifting with time).
    #[serde(rename = "rad/h")]
    RadPerHour,
}

impl Unit {
    /// The factor to the unit volver prints values of this unit in, and that unit: µm for mm,
    /// µrad for rad, µm/h for mm/h, ppm for ppm, ppm/h for ppm/h, µrad/h for rad/h.
    pub fn micro(self) -> (f64, &'static str) {
        match self {
            Unit::Mm => (UM_PER_MM, "µm"),
            Unit::Rad => (URAD_PER_RAD, "µrad"),
            Unit::MmPerHour => (UM_PER_MM, "µm/h"),
            Unit::Ppm => (1.0, "ppm"),
            Unit::PpmPerHour => (1.0, "ppm/h"),
            Unit::RadPerHour => (URAD_PER_RAD, "µrad/h"),
        }
    }
}

impl fmt::Display for Unit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Unit::Mm => "mm",
            Unit::Rad => "rad",
            Unit::MmPerHour => "mm/h",
            Unit::Ppm => "ppm",
            Unit::PpmPerHour => "ppm/h",
            Unit::RadPerHour => "rad/h",
        })
    }
}

/// A location error that does not exist for its axis ([`ErrorId::validate`]); the message says
/// what is allowed.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum InvalidErrorId {
    /// An offset along or a rotation about a rotary axis itself.
    #[error(
        "{id} is not a location error of {axis}: a rotary axis' location errors are the positions \
         and orientations perpendicular to it ({allowed}); an offset along or about the axis \
         itself is the constant term of E{component}{axis}"
    )]
    AlongRotaryAxis {
        /// The error named.
        id: ErrorId,
        /// Its component.
        component: Axis,
        /// Its (rotary) axis.
        axis: Axis,
        /// The axis' location errors, comma-separated.
        allowed: String,
    },
    /// A position offset of a linear axis.
    #[error(
        "{id} is not an error of linear axis {axis}: a position offset of a linear axis is \
         absorbed by the axis offsets; its location errors are the squareness errors {allowed}"
    )]
    LinearAxisOffset {
        /// The error named.
        id: ErrorId,
        /// Its (linear) axis.
        axis: Axis,
        /// The axis' squareness errors, comma-separated.
        allowed: String,
    },
    /// A rotation of a linear axis about itself (its roll, not a squareness).
    #[error(
        "{id} is not a squareness error: a rotation of {axis} about itself is its roll \
         E{component}{axis}; the squareness errors of {axis} are {allowed}"
    )]
    SelfSquareness {
        /// The error named.
        id: ErrorId,
        /// Its component.
        component: Axis,
        /// Its (linear) axis.
        axis: Axis,
        /// The axis' squareness errors, comma-separated.
        allowed: String,
    },
}

impl From<InvalidErrorId> for String {
    fn from(e: InvalidErrorId) -> String {
        e.to_string()
    }
}

/// An ISO 230 geometric error of one machine axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ErrorId {
    /// `E{component}{axis}`: the component error of an axis, a function of that axis' position.
    /// EXX is the positioning error of X, EYX and EZX its straightness, EAX/EBX/ECX its roll, pitch
    /// and yaw; EXC/EYC radial, EZC axial, EAC/EBC tilt and ECC angular positioning of C.
    Component {
        /// Translation (X, Y, Z) or rotation (A, B, C) component.
        component: Axis,
        /// The machine axis.
        axis: Axis,
    },
    /// `{component}0{axis}`: a constant location error. For a rotary axis the position of its line
    /// (X0C, Y0C) or its orientation (A0C, B0C); for a linear axis its squareness (B0Z: Z's
    /// line turned about y, moving the tool along x; A0Z: about x, along y; C0Y: Y's line about
    /// z, along x). The model's sign rule and ISO 230-1's reading: [`ErrorId::iso_sign`].
    Location {
        /// Translation (X, Y, Z) or rotation (A, B, C) component.
        component: Axis,
        /// The machine axis.
        axis: Axis,
    },
}

impl ErrorId {
    /// The machine axis the error belongs to.
    pub fn axis(self) -> Axis {
        match self {
            ErrorId::Component { axis, .. } | ErrorId::Location { axis, .. } => axis,
        }
    }

    /// The component letter (what moves: X/Y/Z translation, A/B/C rotation).
    pub fn component(self) -> Axis {
        match self {
            ErrorId::Component { component, .. } | ErrorId::Location { component, .. } => component,
        }
    }

    /// mm for translations, rad for rotations.
    pub fn unit(self) -> Unit {
        if self.component().is_rotary() {
            Unit::Rad
        } else {
            Unit::Mm
        }
    }

    /// Squareness of a linear axis (a rotation-type location error of a linear axis).
    pub fn is_squareness(self) -> bool {
        matches!(self, ErrorId::Location { axis, .. } if !axis.is_rotary())
    }

    /// The parameter group of the error.
    pub fn group(self) -> Group {
        if self.is_squareness() {
            Group::Squareness
        } else if self.component().is_rotary() {
            Group::Rotation
        } else {
            Group::Translation
        }
    }

    /// For a squareness error `R0K`, the straightness error of K that its effect shares: the
    /// deviation along the direction perpendicular to both R and K (B0Z → EXZ, A0Z → EYZ,
    /// C0Y → EXY, A0Y → EZY, C0X → EYX, B0X → EZX). `None` for other errors.
    pub fn squareness_partner(self) -> Option<ErrorId> {
        if !self.is_squareness() {
            return None;
        }
        let (r, k) = (self.component().direction(), self.axis().direction());
        let j = 3 - r - k;
        Some(ErrorId::Component {
            component: Axis::translation(j),
            axis: self.axis(),
        })
    }

    /// The factor that turns volver's value of this error into ISO 230-1's right-hand reading:
    /// −1 for the squareness errors **C0X, A0Y and B0Z**, +1 for every other error.
    ///
    /// volver's model applies one rule to every squareness `R0K` of a linear axis K (the
    /// paper's eq. 8, written for B0Z): moving K by `u − u_ref` moves the tool relative to the
    /// workpiece by `−R0K·(u − u_ref)` along the third direction j (B0Z along x, A0Z along y,
    /// C0Y along x, A0Y along z, C0X along y, B0X along z), whichever side of the chain K is
    /// on. ISO 230-1 reads a squareness as the angle, right-handed about R, by which K's line
    /// of motion is turned from its nominal direction, which moves the tool by
    /// `R0K·(e_R × e_K)·(u − u_ref)`; `e_R × e_K` is `+e_j` for B0Z,
    /// C0X and A0Y (R, K, j in cyclic order) and `−e_j` for A0Z, B0X and C0Y. So the two
    /// readings agree for A0Z, B0X and C0Y and are opposite for C0X, A0Y and B0Z. Every export
    /// and table in volver writes the ISO reading (`value × iso_sign`).
    ///
    /// ```
    /// use volver_core::iso::ErrorId;
    /// let sign = |n: &str| n.parse::<ErrorId>().unwrap().iso_sign();
    /// assert_eq!((sign("B0Z"), sign("C0X"), sign("A0Y")), (-1.0, -1.0, -1.0));
    /// assert_eq!((sign("A0Z"), sign("B0X"), sign("C0Y")), (1.0, 1.0, 1.0));
    /// assert_eq!((sign("X0C"), sign("EXX")), (1.0, 1.0));
    /// ```
    pub fn iso_sign(self) -> f64 {
        if !self.is_squareness() {
            return 1.0;
        }
        let (r, k) = (self.component().direction(), self.axis().direction());
        // (r, k, j) in cyclic order x → y → z: e_r × e_k = +e_j.
        if (r + 1) % 3 == k { -1.0 } else { 1.0 }
    }

    /// For a squareness error, its rule in words: volver's model and ISO 230-1's reading
    /// ([`ErrorId::iso_sign`]), e.g. "B0Z: moving Z by Δ from its reference moves the tool
    /// relative to the workpiece by −B0Z·Δ along x in volver's model; ISO 230-1's B0Z … has
    /// the opposite sign". `None` for other errors.
    pub fn squareness_rule(self) -> Option<String> {
        let j = self.squareness_partner()?.component();
        let (k, r) = (self.axis(), self.component());
        let axis_name = |d: usize| ["x", "y", "z"][d];
        let iso = if self.iso_sign() < 0.0 {
            "the opposite sign"
        } else {
            "the same sign"
        };
        Some(format!(
            "{self}: moving {k} by Δ from its reference moves the tool relative to the workpiece \
             by −{self}·Δ along {} in volver's model; ISO 230-1's {self} (the turn of {k}'s line of motion, right-handed about \
             {}) has {iso}",
            axis_name(j.direction()),
            axis_name(r.direction()),
        ))
    }

    /// Checks that the error exists for its axis: every component error does; location errors of
    /// a rotary axis are the two positions and two orientations perpendicular to it (X0C, Y0C,
    /// A0C, B0C for C); a linear axis has the two squareness errors perpendicular to it (A0Z,
    /// B0Z for Z). The message says what is allowed.
    pub fn validate(self) -> Result<(), InvalidErrorId> {
        let ErrorId::Location { component, axis } = self else {
            return Ok(());
        };
        let allowed = || Self::location_names(axis).join(", ");
        let same_direction = component.direction() == axis.direction();
        if axis.is_rotary() {
            if same_direction {
                return Err(InvalidErrorId::AlongRotaryAxis {
                    id: self,
                    component,
                    axis,
                    allowed: allowed(),
                });
            }
        } else if !component.is_rotary() {
            return Err(InvalidErrorId::LinearAxisOffset {
                id: self,
                axis,
                allowed: allowed(),
            });
        } else if same_direction {
            return Err(InvalidErrorId::SelfSquareness {
                id: self,
                component,
                axis,
                allowed: allowed(),
            });
        }
        Ok(())
    }

    /// The valid location/squareness names of an axis, e.g. `["X0C", "Y0C", "A0C", "B0C"]`.
    pub fn location_names(axis: Axis) -> Vec<String> {
        Axis::ALL
            .iter()
            .map(|&component| ErrorId::Location { component, axis })
            .filter(|e| {
                let same = e.component().direction() == axis.direction();
                !same && (axis.is_rotary() || e.component().is_rotary())
            })
            .map(|e| e.to_string())
            .collect()
    }

    /// The six component errors of an axis, in ISO order (EX, EY, EZ, EA, EB, EC).
    pub fn components_of(axis: Axis) -> [ErrorId; 6] {
        Axis::ALL.map(|component| ErrorId::Component { component, axis })
    }
}

impl fmt::Display for ErrorId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ErrorId::Component { component, axis } => write!(f, "E{component}{axis}"),
            ErrorId::Location { component, axis } => write!(f, "{component}0{axis}"),
        }
    }
}

impl FromStr for ErrorId {
    type Err = String;

    /// Parses `EXX`, `X0C`, `XOC`, `EX0C`, `B0Z`, `EBOZ` (case-insensitive) and checks the error
    /// exists for its axis.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let up: Vec<char> = s.trim().to_ascii_uppercase().chars().collect();
        let bad = || {
            format!(
                "'{s}' is not an ISO 230 error name (expected E<component><axis> such as EXX, EYC, \
                 or <component>0<axis> such as X0C, B0Z; components and axes are X Y Z A B C)"
            )
        };
        let letter = |c: char| Axis::from_letter(c).ok_or_else(bad);
        let id = match up.as_slice() {
            ['E', c, a] => ErrorId::Component {
                component: letter(*c)?,
                axis: letter(*a)?,
            },
            ['E', c, '0' | 'O', a] | [c, '0' | 'O', a] => ErrorId::Location {
                component: letter(*c)?,
                axis: letter(*a)?,
            },
            _ => return Err(bad()),
        };
        id.validate()?;
        Ok(id)
    }
}

impl Serialize for ErrorId {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for ErrorId {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let s = String::deserialize(deserializer)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn invalid_location_errors_say_what_is_allowed() {
        let id = ErrorId::Location {
            component: Axis::X,
            axis: Axis::Z,
        };
        let e = id.validate().unwrap_err();
        assert!(matches!(
            e,
            InvalidErrorId::LinearAxisOffset { axis: Axis::Z, .. }
        ));
        assert_eq!(
            e.to_string(),
            "X0Z is not an error of linear axis Z: a position offset of a linear axis is absorbed \
             by the axis offsets; its location errors are the squareness errors A0Z, B0Z"
        );
        let roll = ErrorId::Location {
            component: Axis::C,
            axis: Axis::Z,
        };
        assert!(matches!(
            roll.validate(),
            Err(InvalidErrorId::SelfSquareness { .. })
        ));
        let along = ErrorId::Location {
            component: Axis::Z,
            axis: Axis::C,
        };
        assert!(matches!(
            along.validate(),
            Err(InvalidErrorId::AlongRotaryAxis { .. })
        ));
    }

    #[test]
    fn names_round_trip_with_digit_zero() {
        for s in [
            "EXX", "EYC", "ECZ", "X0C", "Y0C", "A0C", "B0C", "B0Z", "A0Z", "C0Y",
        ] {
            let id: ErrorId = s.parse().unwrap();
            assert_eq!(id.to_string(), s);
        }
    }

    #[test]
    fn letter_o_and_e_prefix_accepted_on_input() {
        let a: ErrorId = "XOC".parse().unwrap();
        let b: ErrorId = "EX0C".parse().unwrap();
        let c: ErrorId = "eboz".parse().unwrap();
        assert_eq!(a.to_string(), "X0C");
        assert_eq!(b.to_string(), "X0C");
        assert_eq!(c.to_string(), "B0Z");
    }

    #[test]
    fn invalid_names_are_explained() {
        assert!(
            "EQX"
                .parse::<ErrorId>()
                .unwrap_err()
                .contains("not an ISO 230")
        );
        assert!(
            "Z0C"
                .parse::<ErrorId>()
                .unwrap_err()
                .contains("constant term of EZC")
        );
        assert!(
            "C0C"
                .parse::<ErrorId>()
                .unwrap_err()
                .contains("X0C, Y0C, A0C, B0C")
        );
        assert!("X0Z".parse::<ErrorId>().unwrap_err().contains("A0Z, B0Z"));
        assert!("C0Z".parse::<ErrorId>().unwrap_err().contains("roll ECZ"));
    }

    #[test]
    fn groups_units_and_partners() {
        let id = |s: &str| s.parse::<ErrorId>().unwrap();
        assert_eq!(id("EXX").group(), Group::Translation);
        assert_eq!(id("EBX").group(), Group::Rotation);
        assert_eq!(id("X0C").group(), Group::Translation);
        assert_eq!(id("A0C").group(), Group::Rotation);
        assert_eq!(id("B0Z").group(), Group::Squareness);
        assert_eq!(id("B0Z").unit(), Unit::Rad);
        assert_eq!(id("EYZ").unit(), Unit::Mm);
        assert_eq!(id("B0Z").squareness_partner(), Some(id("EXZ")));
        assert_eq!(id("A0Z").squareness_partner(), Some(id("EYZ")));
        assert_eq!(id("C0Y").squareness_partner(), Some(id("EXY")));
        assert_eq!(id("C0X").squareness_partner(), Some(id("EYX")));
        assert_eq!(id("X0C").squareness_partner(), None);
    }
}
