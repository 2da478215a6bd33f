//! Effects outside the standard error model that a simulation can hide in its data
//! ([`EFFECTS`]).

use super::*;
use crate::units::PPM;

/// The largest value of an effect's parameter, in its unit (µm, µm/h, µrad, ppm, mm).
pub const MAX_EFFECT_VALUE: f64 = 1e6;

/// A physical effect outside the standard model (see the module documentation for formulas).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "effect", rename_all = "kebab-case")]
#[non_exhaustive]
pub enum Effect {
    /// Thermal drift of the tool point in the machine frame.
    ThermalDrift {
        /// Drift rate along x, y, z (µm/h).
        rate_um_per_h: [f64; 3],
    },
    /// Higher harmonics of every periodic rotary-axis error.
    RotaryHarmonics {
        /// Highest harmonic added (2 ..= 15).
        max_order: usize,
        /// Amplitude of each added harmonic of a translation error (µm).
        translation_um: f64,
        /// Amplitude of each added harmonic of a rotation error (µrad).
        rotation_urad: f64,
    },
    /// A tracker mounted tilted.
    TrackerTilt {
        /// Rotation about the tracker's x axis (µrad).
        rx_urad: f64,
        /// Rotation about the tracker's y axis (µrad).
        ry_urad: f64,
    },
    /// A periodic positioning error of a linear axis (ball-screw pitch error).
    BallScrew {
        /// The linear axis.
        axis: Axis,
        /// Period (mm).
        period_mm: f64,
        /// Amplitude (µm).
        amplitude_um: f64,
    },
    /// A reflector whose true offset differs from the machine file's.
    ReflectorOffset {
        /// Reflector id.
        reflector: String,
        /// True offset minus nominal offset (µm).
        delta_um: [f64; 3],
    },
    /// A tracker whose ranges are scaled.
    RangeScale {
        /// Scale error (parts per million).
        ppm: f64,
    },
    /// The scale of a linear axis growing with time (thermal expansion of its drive).
    ThermalScale {
        /// The linear axis.
        axis: Axis,
        /// Growth rate (ppm per hour).
        ppm_per_h: f64,
    },
    /// The line of a rotary axis drifting with time.
    LocationDrift {
        /// The rotary axis.
        axis: Axis,
        /// Drift rates of its two location translations (µm/h): X0C and Y0C for C, Y0A and
        /// Z0A for A, X0B and Z0B for B.
        rate_um_per_h: [f64; 2],
    },
    /// The tracker's orientation drifting with time.
    TrackerDrift {
        /// Rates of its small rotations about x, y, z (µrad/h).
        rate_urad_per_h: [f64; 3],
    },
    /// A station's position drifting with time (its stand growing as it warms).
    StationDrift {
        /// The station's id (a `[[station]]` of the machine file).
        station: String,
        /// Drift rates of its position along x, y, z of the frame it is mounted in (µm/h).
        rate_um_per_h: [f64; 3],
    },
    /// A non-rigid coupling: a component error of one axis that changes with the position of
    /// another.
    Coupling {
        /// The axis whose error changes (linear).
        axis: Axis,
        /// The translation component of its error (X, Y or Z).
        component: Axis,
        /// The axis whose position it changes with.
        by: Axis,
        /// Amplitude (µm).
        amplitude_um: f64,
    },
    /// The reversal value B of an axis (ISO 230-2; backlash, lost motion): its positioning
    /// error is `+B/2` where it arrived moving in its positive direction and `−B/2` moving in
    /// its negative ([`crate::approach`]).
    Reversal {
        /// The axis (linear or rotary).
        axis: Axis,
        /// B in µm for a linear axis, µrad for a rotary one.
        value: f64,
    },
}

/// The effects: id, CLI syntax and meaning, in the order `volver simulate --help` lists them.
pub const EFFECTS: [(&str, &str, &str); 12] = [
    (
        "thermal-drift",
        "thermal-drift=VX,VY,VZ",
        "tool point drifts in the machine frame, µm/h",
    ),
    (
        "rotary-harmonics",
        "rotary-harmonics=H[,AMP_UM,AMP_URAD]",
        "rotary-axis errors get harmonics up to H (default 5 µm, 10 µrad each)",
    ),
    (
        "tracker-tilt",
        "tracker-tilt=RX,RY",
        "tracker mounted tilted, µrad",
    ),
    (
        "ball-screw",
        "ball-screw=AXIS,PERIOD_MM,AMP_UM",
        "periodic positioning error of a linear axis",
    ),
    (
        "reflector-offset",
        "reflector-offset=ID,DX,DY,DZ",
        "reflector off its nominal offset, µm",
    ),
    (
        "range-scale",
        "range-scale=PPM",
        "tracker range scale error, ppm",
    ),
    (
        "thermal-scale",
        "thermal-scale=AXIS,PPM_PER_H",
        "scale of a linear axis growing with time: EXX += α·x·t",
    ),
    (
        "location-drift",
        "location-drift=AXIS,V1_UM_PER_H,V2_UM_PER_H",
        "line of a rotary axis drifting with time (X0C, Y0C for C)",
    ),
    (
        "tracker-drift",
        "tracker-drift=RX,RY,RZ",
        "tracker's orientation drifting with time, µrad/h",
    ),
    (
        "station-drift",
        "station-drift=ID,VX,VY,VZ",
        "a station's position drifting with time, µm/h",
    ),
    (
        "coupling",
        "coupling=AXIS,COMPONENT,BY,AMP_UM",
        "error E{COMPONENT}{AXIS} changing with the position of BY: A·sin(πξ)·η",
    ),
    (
        "reversal",
        "reversal=AXIS,B_UM",
        "ISO 230-2's reversal value B of an axis (µm; µrad for a rotary axis): the tool ±B/2 \
         along it by its direction of approach",
    ),
];

impl Effect {
    /// The effect's stable id (`thermal-drift` …).
    pub fn id(&self) -> &'static str {
        match self {
            Effect::ThermalDrift { .. } => "thermal-drift",
            Effect::RotaryHarmonics { .. } => "rotary-harmonics",
            Effect::TrackerTilt { .. } => "tracker-tilt",
            Effect::BallScrew { .. } => "ball-screw",
            Effect::ReflectorOffset { .. } => "reflector-offset",
            Effect::RangeScale { .. } => "range-scale",
            Effect::ThermalScale { .. } => "thermal-scale",
            Effect::LocationDrift { .. } => "location-drift",
            Effect::Coupling { .. } => "coupling",
            Effect::TrackerDrift { .. } => "tracker-drift",
            Effect::StationDrift { .. } => "station-drift",
            Effect::Reversal { .. } => "reversal",
        }
    }

    /// Parses the CLI syntax of [`EFFECTS`], e.g. `thermal-drift=0,0,20`.
    ///
    /// ```
    /// use volver_core::simulate::Effect;
    /// let e = Effect::parse("ball-screw=X,10,3").unwrap();
    /// assert_eq!(e.to_string(), "ball-screw=X,10,3");
    /// assert!(Effect::parse("ball-screw=X,10").unwrap_err().to_string().contains("AXIS,PERIOD_MM,AMP_UM"));
    /// ```
    pub fn parse(text: &str) -> Result<Effect> {
        let ids: Vec<&str> = EFFECTS.iter().map(|e| e.0).collect();
        let (id, args) = text.split_once('=').unwrap_or((text, ""));
        let id = id.trim();
        let Some(&(_, syntax, _)) = EFFECTS.iter().find(|e| e.0 == id) else {
            return Err(Error::input(
                effect_place(text),
                format!("unknown effect '{id}'; effects are {}", ids.join(", ")),
            ));
        };
        let args = Args {
            text,
            syntax,
            values: args
                .split(',')
                .map(str::trim)
                .filter(|s| !s.is_empty())
                .collect(),
        };
        match args.tracker_effect(id)? {
            Some(effect) => Ok(effect),
            None => args.machine_effect(id),
        }
    }

    /// Checks the effect against a machine.
    pub fn validate(&self, machine: &Machine) -> Result<()> {
        let check = Check {
            machine,
            id: self.id(),
        };
        match self {
            Effect::ThermalDrift { .. }
            | Effect::TrackerDrift { .. }
            | Effect::StationDrift { .. }
            | Effect::TrackerTilt { .. }
            | Effect::ReflectorOffset { .. }
            | Effect::RangeScale { .. } => self.validate_tracker_side(&check),
            Effect::Reversal { axis, value } => {
                if machine.axis(*axis).is_none() {
                    check.fail(format!("{axis} is not an axis of {}", machine.chain()))
                } else if !value.is_finite() {
                    check.fail("the reversal value must be finite")
                } else {
                    Ok(())
                }
            }
            _ => self.validate_machine_side(&check),
        }
    }

    /// [`Effect::validate`] for the effects on the tracker, its stations and reflectors.
    fn validate_tracker_side(&self, check: &Check) -> Result<()> {
        let machine = check.machine;
        match self {
            Effect::ThermalDrift { rate_um_per_h } if !finite(rate_um_per_h) => {
                check.fail("the drift rate must be finite")
            }
            Effect::TrackerDrift { rate_urad_per_h } if !finite(rate_urad_per_h) => {
                check.fail("the drift rates must be finite")
            }
            Effect::StationDrift {
                station,
                rate_um_per_h,
            } => {
                if !machine.has_stations() {
                    check.fail(format!(
                        "the machine {} has no [[station]] tables: a tracker drifting in \
                         position is thermal-drift",
                        machine.chain()
                    ))
                } else if let Err(why) = machine.station_named(Some(station)) {
                    check.fail(why.to_string())
                } else if !finite(rate_um_per_h) {
                    check.fail("the drift rates must be finite")
                } else {
                    Ok(())
                }
            }
            Effect::TrackerTilt { rx_urad, ry_urad } if !finite(&[*rx_urad, *ry_urad]) => {
                check.fail("the tilt must be finite")
            }
            Effect::ReflectorOffset {
                reflector,
                delta_um,
            } => {
                if machine.reflector_index(reflector).is_none() {
                    let ids: Vec<&str> =
                        machine.reflectors().iter().map(|r| r.id.as_str()).collect();
                    check.fail(format!(
                        "no reflector '{reflector}' in the machine (it has {})",
                        ids.join(", ")
                    ))
                } else if !finite(delta_um) {
                    check.fail("the offset error must be finite")
                } else {
                    Ok(())
                }
            }
            Effect::RangeScale { ppm } if !(ppm.is_finite() && *ppm > -PPM) => {
                check.fail(format!("{ppm} ppm is not a finite scale above −10⁶ ppm"))
            }
            _ => Ok(()),
        }
    }

    /// [`Effect::validate`] for the effects on the machine's axes.
    fn validate_machine_side(&self, check: &Check) -> Result<()> {
        let machine = check.machine;
        match self {
            Effect::RotaryHarmonics {
                max_order,
                translation_um,
                rotation_urad,
            } => {
                if !(2..=MAX_HARMONIC).contains(max_order) {
                    check.fail(format!(
                        "highest harmonic {max_order} is outside 2..={MAX_HARMONIC}"
                    ))
                } else if !finite(&[*translation_um, *rotation_urad]) {
                    check.fail("the amplitudes must be finite")
                } else if !machine.axes().iter().any(|a| a.axis.is_rotary()) {
                    check.fail(format!(
                        "the machine {} has no rotary axis",
                        machine.chain()
                    ))
                } else {
                    Ok(())
                }
            }
            Effect::BallScrew {
                axis,
                period_mm,
                amplitude_um,
            } => {
                check.axis_of_kind(*axis, false)?;
                if !(period_mm.is_finite() && *period_mm > 0.0) {
                    check.fail(format!("the period {period_mm} mm must be positive"))
                } else if !amplitude_um.is_finite() {
                    check.fail("the amplitude must be finite")
                } else {
                    Ok(())
                }
            }
            Effect::ThermalScale { axis, ppm_per_h } => {
                check.axis_of_kind(*axis, false)?;
                if ppm_per_h.is_finite() {
                    Ok(())
                } else {
                    check.fail("the growth rate must be finite")
                }
            }
            Effect::LocationDrift {
                axis,
                rate_um_per_h,
            } => {
                check.axis_of_kind(*axis, true)?;
                if finite(rate_um_per_h) {
                    Ok(())
                } else {
                    check.fail("the drift rates must be finite")
                }
            }
            Effect::Coupling {
                axis,
                component,
                by,
                amplitude_um,
            } => {
                check.axis_of_kind(*axis, false)?;
                if component.is_rotary() {
                    check.fail(format!(
                        "{component} is not a translation component (X, Y or Z)"
                    ))
                } else if machine.axis(*by).is_none() || by == axis {
                    check.fail(format!("{by} is not another axis of {}", machine.chain()))
                } else if !amplitude_um.is_finite() {
                    check.fail("the amplitude must be finite")
                } else {
                    Ok(())
                }
            }
            _ => Ok(()),
        }
    }
}

/// Whether every value is finite.
fn finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Where an `--effect` argument's error is: the argument itself.
fn effect_place(text: &str) -> Place {
    Place::file("--effect").at_field(text.to_string())
}

/// The values of one `--effect` argument, with the readers that say what was expected.
struct Args<'a> {
    /// The whole argument (`ball-screw=X,10,3`).
    text: &'a str,
    /// The effect's syntax, for errors.
    syntax: &'static str,
    /// The comma-separated values, trimmed, empty ones dropped.
    values: Vec<&'a str>,
}

impl Args<'_> {
    /// An error saying `why` and the syntax expected.
    fn bad(&self, why: String) -> Error {
        Error::input(
            effect_place(self.text),
            format!("{why}; expected {}", self.syntax),
        )
    }

    /// A value: finite and within [`MAX_EFFECT_VALUE`] of its unit (µm, µm/h, µrad, ppm, mm):
    /// a metre, a radian, a whole scale, beyond any machine's error.
    fn num(&self, s: &str) -> Result<f64> {
        let v = s
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| self.bad(format!("'{s}' is not a finite number")))?;
        if v.abs() > MAX_EFFECT_VALUE {
            return Err(self.bad(format!(
                "{} is beyond any machine's error (at most {MAX_EFFECT_VALUE:e} in the \
                 effect's unit)",
                crate::error::number(v)
            )));
        }
        Ok(v)
    }

    /// The values from index `from` on, as numbers.
    fn nums(&self, from: usize) -> Result<Vec<f64>> {
        self.values[from..].iter().map(|s| self.num(s)).collect()
    }

    /// Value `i` as an axis letter.
    fn letter(&self, i: usize) -> Result<Axis> {
        let s = self.values[i];
        let mut letters = s.chars();
        match (letters.next().and_then(Axis::from_letter), letters.next()) {
            (Some(a), None) => Ok(a),
            _ => Err(self.bad(format!("'{s}' is not an axis letter"))),
        }
    }

    /// Checks that there are `n` values.
    fn count(&self, n: usize) -> Result<()> {
        if self.values.len() == n {
            Ok(())
        } else {
            Err(self.bad(format!("{} values given", self.values.len())))
        }
    }

    /// The effects on the tracker, its stations and reflectors (`None`: `id` is another's).
    fn tracker_effect(&self, id: &str) -> Result<Option<Effect>> {
        let args = &self.values;
        Ok(Some(match id {
            "thermal-drift" => {
                self.count(3)?;
                let v = self.nums(0)?;
                Effect::ThermalDrift {
                    rate_um_per_h: [v[0], v[1], v[2]],
                }
            }
            "tracker-tilt" => {
                self.count(2)?;
                let v = self.nums(0)?;
                Effect::TrackerTilt {
                    rx_urad: v[0],
                    ry_urad: v[1],
                }
            }
            "reflector-offset" => {
                self.count(4)?;
                let v = self.nums(1)?;
                Effect::ReflectorOffset {
                    reflector: args[0].to_string(),
                    delta_um: [v[0], v[1], v[2]],
                }
            }
            "tracker-drift" => {
                self.count(3)?;
                let v = self.nums(0)?;
                Effect::TrackerDrift {
                    rate_urad_per_h: [v[0], v[1], v[2]],
                }
            }
            "station-drift" => {
                self.count(4)?;
                let v = self.nums(1)?;
                Effect::StationDrift {
                    station: args[0].to_string(),
                    rate_um_per_h: [v[0], v[1], v[2]],
                }
            }
            "range-scale" => {
                self.count(1)?;
                Effect::RangeScale {
                    ppm: self.num(args[0])?,
                }
            }
            _ => return Ok(None),
        }))
    }

    /// The effects on the machine's axes (`id` is one of [`EFFECTS`]).
    fn machine_effect(&self, id: &str) -> Result<Effect> {
        let args = &self.values;
        Ok(match id {
            "rotary-harmonics" => {
                if args.len() != 1 && args.len() != 3 {
                    return Err(self.bad(format!("{} values given", args.len())));
                }
                let max_order = args[0]
                    .parse::<usize>()
                    .map_err(|_| self.bad(format!("'{}' is not a whole number", args[0])))?;
                let amps = self.nums(1)?;
                Effect::RotaryHarmonics {
                    max_order,
                    translation_um: amps.first().copied().unwrap_or(5.0),
                    rotation_urad: amps.get(1).copied().unwrap_or(10.0),
                }
            }
            "ball-screw" => {
                self.count(3)?;
                let axis = self.letter(0)?;
                let v = self.nums(1)?;
                let (lo, hi) = crate::model::PERIOD_RANGE_MM;
                if !(lo..=hi).contains(&v[0]) {
                    return Err(self.bad(format!(
                        "the period {} mm is outside {lo} … {hi:e} mm",
                        crate::error::number(v[0])
                    )));
                }
                Effect::BallScrew {
                    axis,
                    period_mm: v[0],
                    amplitude_um: v[1],
                }
            }
            "thermal-scale" => {
                self.count(2)?;
                Effect::ThermalScale {
                    axis: self.letter(0)?,
                    ppm_per_h: self.num(args[1])?,
                }
            }
            "reversal" => {
                self.count(2)?;
                Effect::Reversal {
                    axis: self.letter(0)?,
                    value: self.num(self.values[1])?,
                }
            }
            "location-drift" => {
                self.count(3)?;
                let v = self.nums(1)?;
                Effect::LocationDrift {
                    axis: self.letter(0)?,
                    rate_um_per_h: [v[0], v[1]],
                }
            }
            _ => {
                self.count(4)?;
                Effect::Coupling {
                    axis: self.letter(0)?,
                    component: self.letter(1)?,
                    by: self.letter(2)?,
                    amplitude_um: self.num(args[3])?,
                }
            }
        })
    }
}

/// An effect checked against a machine.
struct Check<'a> {
    /// The machine.
    machine: &'a Machine,
    /// The effect's id, the field of its errors.
    id: &'static str,
}

impl Check<'_> {
    /// The error `m` at the effect.
    fn fail(&self, m: impl Into<String>) -> Result<()> {
        Err(Error::input(
            Place::file("effects").at_field(self.id),
            m.into(),
        ))
    }

    /// Checks that `axis` is one of the machine's, rotary or linear as the effect needs.
    fn axis_of_kind(&self, axis: Axis, rotary: bool) -> Result<()> {
        if axis.is_rotary() == rotary && self.machine.axis(axis).is_some() {
            Ok(())
        } else {
            let kind = if rotary { "rotary" } else { "linear" };
            self.fail(format!(
                "{axis} is not a {kind} axis of {}",
                self.machine.chain()
            ))
        }
    }
}

impl fmt::Display for Effect {
    /// The CLI syntax, which [`Effect::parse`] reads back.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}=", self.id())?;
        match self {
            Effect::ThermalDrift { rate_um_per_h: v } => write!(f, "{},{},{}", v[0], v[1], v[2]),
            Effect::RotaryHarmonics {
                max_order,
                translation_um,
                rotation_urad,
            } => write!(f, "{max_order},{translation_um},{rotation_urad}"),
            Effect::TrackerTilt { rx_urad, ry_urad } => write!(f, "{rx_urad},{ry_urad}"),
            Effect::BallScrew {
                axis,
                period_mm,
                amplitude_um,
            } => write!(f, "{axis},{period_mm},{amplitude_um}"),
            Effect::ReflectorOffset {
                reflector,
                delta_um: d,
            } => write!(f, "{reflector},{},{},{}", d[0], d[1], d[2]),
            Effect::RangeScale { ppm } => write!(f, "{ppm}"),
            Effect::ThermalScale { axis, ppm_per_h } => write!(f, "{axis},{ppm_per_h}"),
            Effect::LocationDrift {
                axis,
                rate_um_per_h: v,
            } => write!(f, "{axis},{},{}", v[0], v[1]),
            Effect::Coupling {
                axis,
                component,
                by,
                amplitude_um,
            } => write!(f, "{axis},{component},{by},{amplitude_um}"),
            Effect::TrackerDrift { rate_urad_per_h: v } => write!(f, "{},{},{}", v[0], v[1], v[2]),
            Effect::StationDrift {
                station,
                rate_um_per_h: v,
            } => write!(f, "{station},{},{},{}", v[0], v[1], v[2]),
            Effect::Reversal { axis, value } => write!(f, "{axis},{value}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn effect_arguments_are_read_and_refused_with_their_syntax() {
        assert_eq!(
            Effect::parse("thermal-scale=Z,5").unwrap(),
            Effect::ThermalScale {
                axis: Axis::Z,
                ppm_per_h: 5.0
            }
        );
        assert_eq!(
            Effect::parse("range-scale=2").unwrap(),
            Effect::RangeScale { ppm: 2.0 }
        );
        let e = Effect::parse("coupling=X,Y,Z").unwrap_err().to_string();
        assert!(
            e.ends_with("3 values given; expected coupling=AXIS,COMPONENT,BY,AMP_UM"),
            "{e}"
        );
        let e = Effect::parse("ball-screw=Q,10,3").unwrap_err().to_string();
        assert!(e.contains("'Q' is not an axis letter"), "{e}");
        let e = Effect::parse("tracker-tilt=1,2e7").unwrap_err().to_string();
        assert!(e.contains("beyond any machine's error"), "{e}");
    }

    #[test]
    fn effects_are_checked_against_the_machine() {
        let m = Machine::default_xcfz();
        let rotary_screw = Effect::BallScrew {
            axis: Axis::C,
            period_mm: 10.0,
            amplitude_um: 1.0,
        };
        let e = rotary_screw.validate(&m).unwrap_err().to_string();
        assert!(e.contains("C is not a linear axis of XCFZ"), "{e}");
        let drift = Effect::StationDrift {
            station: "S1".into(),
            rate_um_per_h: [1.0, 0.0, 0.0],
        };
        let e = drift.validate(&m).unwrap_err().to_string();
        assert!(e.contains("has no [[station]] tables"), "{e}");
        let r = Effect::parse("reversal=C,-20").unwrap();
        assert_eq!(r.to_string(), "reversal=C,-20");
        assert!(r.validate(&m).is_ok());
        let e = Effect::parse("reversal=Y,5")
            .unwrap()
            .validate(&m)
            .unwrap_err();
        assert!(e.to_string().contains("Y is not an axis of XCFZ"), "{e}");
        assert!(Effect::RangeScale { ppm: -2e6 }.validate(&m).is_err());
        assert!(Effect::RangeScale { ppm: 3.0 }.validate(&m).is_ok());
    }
}
