//! The sizes of random true errors, per kind of error ([`MAGNITUDE_KINDS`]).

use super::*;

/// The error kinds of [`Magnitudes`]: name, unit and which errors it covers.
pub const MAGNITUDE_KINDS: [(&str, &str, &str); 11] = [
    (
        "positioning",
        "µm",
        "positioning error of a linear axis (EXX, EYY, EZZ)",
    ),
    (
        "straightness",
        "µm",
        "straightness of a linear axis (EYX, EZX, EXZ …)",
    ),
    (
        "angular",
        "µrad",
        "roll, pitch and yaw of a linear axis (EAX, EBX, ECX …)",
    ),
    (
        "squareness",
        "µrad",
        "squareness of a linear axis (A0Z, B0Z, C0Y …)",
    ),
    (
        "radial",
        "µm",
        "radial motion of a rotary axis (EXC, EYC for C)",
    ),
    ("axial", "µm", "axial motion of a rotary axis (EZC for C)"),
    (
        "tilt",
        "µrad",
        "tilt motion of a rotary axis (EAC, EBC for C)",
    ),
    (
        "angular-positioning",
        "µrad",
        "angular positioning error of a rotary axis (ECC for C)",
    ),
    (
        "location",
        "µm",
        "position of a rotary axis' line (X0C, Y0C for C)",
    ),
    (
        "location-tilt",
        "µrad",
        "orientation of a rotary axis' line (A0C, B0C for C)",
    ),
    (
        "tracker",
        "mm",
        "distance of the true tracker position from its nominal one",
    ),
];

/// Size of the randomly drawn true errors, per kind (see [`MAGNITUDE_KINDS`]): the largest
/// absolute value an error function reaches over its axis' travel is this magnitude times a
/// factor drawn in [0.5, 1].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Magnitudes {
    /// EXX, EYY, EZZ (µm).
    pub positioning_um: f64,
    /// EYX, EZX, EXZ … (µm).
    pub straightness_um: f64,
    /// EAX, EBX, ECX … of linear axes (µrad).
    pub angular_urad: f64,
    /// A0Z, B0Z, C0Y … (µrad).
    pub squareness_urad: f64,
    /// EXC, EYC … (µm).
    pub radial_um: f64,
    /// EZC … (µm).
    pub axial_um: f64,
    /// EAC, EBC … (µrad).
    pub tilt_urad: f64,
    /// ECC … (µrad).
    pub angular_positioning_urad: f64,
    /// X0C, Y0C … (µm).
    pub location_um: f64,
    /// A0C, B0C … (µrad).
    pub location_tilt_urad: f64,
    /// Distance of the true tracker position from the nominal one (mm).
    pub tracker_mm: f64,
}

impl Default for Magnitudes {
    /// Errors of a large, uncompensated machine tool: tens of µm and µrad.
    fn default() -> Self {
        Magnitudes {
            positioning_um: 50.0,
            straightness_um: 30.0,
            angular_urad: 50.0,
            squareness_urad: 50.0,
            radial_um: 20.0,
            axial_um: 10.0,
            tilt_urad: 30.0,
            angular_positioning_urad: 50.0,
            location_um: 30.0,
            location_tilt_urad: 30.0,
            tracker_mm: 0.0,
        }
    }
}

impl Magnitudes {
    /// Every magnitude zero: the true machine is the nominal one.
    pub const ZERO: Magnitudes = Magnitudes {
        positioning_um: 0.0,
        straightness_um: 0.0,
        angular_urad: 0.0,
        squareness_urad: 0.0,
        radial_um: 0.0,
        axial_um: 0.0,
        tilt_urad: 0.0,
        angular_positioning_urad: 0.0,
        location_um: 0.0,
        location_tilt_urad: 0.0,
        tracker_mm: 0.0,
    };

    pub(super) fn slot(&mut self, kind: &str) -> Option<&mut f64> {
        Some(match kind {
            "positioning" => &mut self.positioning_um,
            "straightness" => &mut self.straightness_um,
            "angular" => &mut self.angular_urad,
            "squareness" => &mut self.squareness_urad,
            "radial" => &mut self.radial_um,
            "axial" => &mut self.axial_um,
            "tilt" => &mut self.tilt_urad,
            "angular-positioning" => &mut self.angular_positioning_urad,
            "location" => &mut self.location_um,
            "location-tilt" => &mut self.location_tilt_urad,
            "tracker" => &mut self.tracker_mm,
            _ => return None,
        })
    }

    /// The magnitude of one kind (a name of [`MAGNITUDE_KINDS`], in its unit); zero for a name
    /// that is not one.
    ///
    /// ```
    /// use volver_core::simulate::Magnitudes;
    /// assert_eq!(Magnitudes::default().get("axial"), 10.0);
    /// ```
    pub fn get(&self, kind: &str) -> f64 {
        let mut m = *self;
        m.slot(kind).map_or(0.0, |v| *v)
    }

    /// Sets one kind from text `KIND=VALUE` (the value in the kind's unit), as the CLI's
    /// `--magnitude` option takes it.
    ///
    /// ```
    /// use volver_core::simulate::Magnitudes;
    /// let mut m = Magnitudes::ZERO;
    /// m.set_from_text("straightness=12.5").unwrap();
    /// assert_eq!(m.straightness_um, 12.5);
    /// assert!(m.set_from_text("wobble=1").is_err());
    /// ```
    pub fn set_from_text(&mut self, text: &str) -> Result<()> {
        self.set_from_option(text, "--magnitude")
    }

    /// As [`Magnitudes::set_from_text`], for the command-line option `option` (which errors
    /// name).
    pub fn set_from_option(&mut self, text: &str, option: &str) -> Result<()> {
        let place = || Place::file(option).at_field(text.to_string());
        let (kind, value) = text
            .split_once('=')
            .ok_or_else(|| Error::input(place(), "expected KIND=VALUE, e.g. straightness=20"))?;
        let value: f64 = value
            .trim()
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite() && *v >= 0.0)
            .ok_or_else(|| {
                Error::input(place(), format!("'{value}' is not a finite number ≥ 0"))
            })?;
        let kinds: Vec<&str> = MAGNITUDE_KINDS.iter().map(|k| k.0).collect();
        let slot = self.slot(kind.trim()).ok_or_else(|| {
            Error::input(
                place(),
                format!("unknown kind '{kind}'; kinds are {}", kinds.join(", ")),
            )
        })?;
        *slot = value;
        Ok(())
    }

    /// Every magnitude multiplied by `k`.
    ///
    /// ```
    /// use volver_core::simulate::Magnitudes;
    /// let m = Magnitudes::default().scaled(2.0);
    /// assert_eq!(m.angular_urad, 2.0 * Magnitudes::default().angular_urad);
    /// ```
    pub fn scaled(&self, k: f64) -> Magnitudes {
        let mut m = *self;
        for (kind, _, _) in MAGNITUDE_KINDS {
            *m.slot(kind).expect("every kind has a slot") *= k;
        }
        m
    }

    /// The kind of an error (a name of [`MAGNITUDE_KINDS`]).
    pub fn kind_of(id: ErrorId) -> &'static str {
        let own = id.component().direction() == id.axis().direction();
        match (id, id.axis().is_rotary(), id.component().is_rotary()) {
            (ErrorId::Location { .. }, false, _) => "squareness",
            (ErrorId::Location { .. }, true, false) => "location",
            (ErrorId::Location { .. }, true, true) => "location-tilt",
            (ErrorId::Component { .. }, false, false) if own => "positioning",
            (ErrorId::Component { .. }, false, false) => "straightness",
            (ErrorId::Component { .. }, false, true) => "angular",
            (ErrorId::Component { .. }, true, false) if own => "axial",
            (ErrorId::Component { .. }, true, false) => "radial",
            (ErrorId::Component { .. }, true, true) if own => "angular-positioning",
            (ErrorId::Component { .. }, true, true) => "tilt",
        }
    }

    /// The magnitude for an error in internal units (mm or rad).
    pub fn for_error(&self, id: ErrorId) -> f64 {
        let mut m = *self;
        let v = *m
            .slot(Magnitudes::kind_of(id))
            .expect("every kind has a slot");
        // An ISO error is in mm or rad.
        if id.unit() == Unit::Mm {
            v * super::MM_PER_UM
        } else {
            v * super::RAD_PER_URAD
        }
    }

    pub(super) fn validate(&self) -> Result<()> {
        let mut m = *self;
        for (kind, _, _) in MAGNITUDE_KINDS {
            let v = *m.slot(kind).expect("every kind has a slot");
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::input(
                    Place::file("magnitudes").at_field(kind),
                    format!("{v} is not a finite number ≥ 0"),
                ));
            }
        }
        Ok(())
    }
}
