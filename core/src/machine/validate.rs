//! Validating a [`MachineSpec`] into a [`Machine`]: the chain, one pass per table (axes,
//! reflectors, stations, clearance), each error at the file, line and field it is about.

use super::*;
use crate::noise::TrackerNoise;

impl Machine {
    /// Validates `spec`, read from `file` (its text `source`, when known, gives the lines).
    pub(super) fn from_spec_located(
        spec: MachineSpec,
        file: &str,
        source: Option<&str>,
    ) -> Result<Machine> {
        let check = Checker {
            spec: &spec,
            file,
            source,
        };
        let chain = check.chain()?;
        let axes = check.axes(&chain)?;
        let reflectors = check.reflectors()?;
        let stations = check.stations()?;
        let clearance = check.clearance(&axes)?;
        Ok(Machine {
            spec,
            chain,
            axes,
            reflectors,
            stations,
            clearance,
        })
    }
}

/// The machine file being validated: its content, its name and its text.
struct Checker<'a> {
    /// The file's content.
    spec: &'a MachineSpec,
    /// The file's name, for errors.
    file: &'a str,
    /// The file's text, when known: errors then give the line of the offending name.
    source: Option<&'a str>,
}

impl Checker<'_> {
    /// The place of `needle` (its line in the source, when found) at `field`.
    fn place(&self, needle: &str, field: &str) -> Place {
        let mut p = Place::file(self.file).at_field(field);
        if let Some(line) = self.source.and_then(|s| line_of_text(s, needle)) {
            p = p.at_line(line);
        }
        p
    }

    /// The kinematic chain, e.g. `XCFZ`.
    fn chain(&self) -> Result<Chain> {
        let spec = self.spec;
        spec.chain
            .parse()
            .map_err(|m: String| Error::input(self.place(&spec.chain, "chain"), m))
    }

    /// The axes in chain order (internal units: mm, rad), after checking that every
    /// `[axes.<letter>]` table is an axis of the chain.
    fn axes(&self, chain: &Chain) -> Result<Vec<MachineAxis>> {
        for key in self.spec.axes.keys() {
            let known = key.len() == 1
                && key
                    .chars()
                    .next()
                    .and_then(Axis::from_letter)
                    .is_some_and(|a| chain.position(a).is_some());
            if !known {
                return Err(Error::input(
                    self.place(&format!("axes.{key}"), &format!("axes.{key}")),
                    format!(
                        "axis '{key}' is not in the chain {chain}; expected one [axes.<letter>] table per axis of the chain"
                    ),
                ));
            }
        }
        let mut axes = Vec::with_capacity(MAX_AXES);
        for (axis, side) in chain.axes() {
            axes.push(self.axis(chain, axis, side)?);
        }
        Ok(axes)
    }

    /// One axis of the chain from its `[axes.<letter>]` table: range, offset and reference
    /// finite and bounded, the reference within the range (file units: mm or degrees).
    fn axis(&self, chain: &Chain, axis: Axis, side: Side) -> Result<MachineAxis> {
        let key = axis.letter().to_string();
        let field = format!("axes.{key}");
        let Some(a) = self.spec.axes.get(&key) else {
            return Err(Error::input(
                Place::file(self.file).at_field(&field),
                format!(
                    "the chain {chain} has axis {axis} but there is no [axes.{axis}] table with its range"
                ),
            ));
        };
        let at = || self.place(&format!("[axes.{key}]"), &field);
        let finite = a
            .range
            .iter()
            .chain(&a.offset)
            .chain(std::iter::once(&a.reference))
            .all(|v| v.is_finite() && v.abs() <= MAX_DIMENSION);
        if !finite {
            return Err(Error::input(
                at(),
                format!(
                    "range, offset and reference must be finite numbers of at most \
                     {MAX_DIMENSION:e} (mm or degrees) in magnitude"
                ),
            ));
        }
        if a.range[0] >= a.range[1] {
            return Err(Error::input(
                at(),
                format!(
                    "range [{}, {}] must be [min, max] with min < max",
                    a.range[0], a.range[1]
                ),
            ));
        }
        if a.reference < a.range[0] || a.reference > a.range[1] {
            return Err(Error::input(
                at(),
                format!(
                    "reference {} lies outside the range [{}, {}] ({})",
                    a.reference,
                    a.range[0],
                    a.range[1],
                    if axis.is_rotary() { "degrees" } else { "mm" }
                ),
            ));
        }
        let conv = |v: f64| if axis.is_rotary() { v.to_radians() } else { v };
        Ok(MachineAxis {
            axis,
            side,
            min: conv(a.range[0]),
            max: conv(a.range[1]),
            reference: conv(a.reference),
            offset: a.offset,
        })
    }

    /// The reflectors: at least one, ids usable as CSV cells and distinct, offsets finite (mm).
    fn reflectors(&self) -> Result<Vec<Reflector>> {
        if self.spec.reflectors.is_empty() {
            return Err(Error::input(
                Place::file(self.file).at_field("reflector"),
                "at least one [[reflector]] with an id and an offset is needed",
            ));
        }
        let mut reflectors: Vec<Reflector> = Vec::new();
        for r in &self.spec.reflectors {
            let at = || self.place(&r.id, "reflector.id");
            if r.id.trim().is_empty() {
                return Err(Error::input(
                    Place::file(self.file).at_field("reflector.id"),
                    "reflector id is empty",
                ));
            }
            // The id is a cell of the measurement and point files (CSV) and a word of messages.
            if !valid_id(&r.id) {
                return Err(Error::input(
                    at(),
                    format!(
                        "reflector id {:?}: an id is written in CSV files, so it may hold no \
                         comma, semicolon, quote, control character or surrounding space",
                        r.id
                    ),
                ));
            }
            if reflectors.iter().any(|q| q.id == r.id) {
                return Err(Error::input(
                    at(),
                    format!("reflector id '{}' is used twice", r.id),
                ));
            }
            if !r
                .offset
                .iter()
                .all(|v| v.is_finite() && v.abs() <= MAX_DIMENSION)
            {
                return Err(Error::input(
                    at(),
                    format!(
                        "reflector offset must be finite numbers of at most {MAX_DIMENSION:e} mm"
                    ),
                ));
            }
            reflectors.push(Reflector {
                id: r.id.clone(),
                offset: r.offset,
            });
        }
        Ok(reflectors)
    }

    /// The tracker noise a `noise` key gives (`None` when absent).
    fn noise_of(&self, text: &Option<String>, field: &str) -> Result<Option<TrackerNoise>> {
        let Some(text) = text else {
            return Ok(None);
        };
        TrackerNoise::from_text(text).map(Some).map_err(|_| {
            Error::input(
                self.place(text, field),
                format!(
                    "'{text}' is not a tracker noise: expected paper, none, \
                     normal:AZ_URAD,EL_URAD,RANGE_UM,RANGE_UM_PER_M, uniform:… or \
                     mpe:A_UM,B_UM_PER_M"
                ),
            )
        })
    }

    /// The stations: the `[tracker]` table alone, or the `[[station]]` tables (at most
    /// [`MAX_STATIONS`], the `[tracker]` table then giving only their default noise).
    fn stations(&self) -> Result<Vec<Station>> {
        let spec = self.spec;
        let t = &spec.tracker;
        let tracker_noise = self.noise_of(&t.noise, "tracker.noise")?;
        let mut stations: Vec<Station> = Vec::new();
        if spec.stations.is_empty() {
            let pose = Pose {
                position: t.position,
                orientation_deg: t.orientation_deg,
            };
            stations.push(Station {
                id: String::new(),
                setup: pose.setup(t.mount, tracker_noise, self.place("[tracker]", "tracker"))?,
                observes: Observes::Point,
            });
        } else if spec.stations.len() > MAX_STATIONS {
            return Err(Error::input(
                self.place("[[station]]", "station"),
                format!(
                    "{} stations: at most {MAX_STATIONS} (every station measures the whole plan)",
                    spec.stations.len()
                ),
            ));
        } else if t.position != [0.0; 3] || t.orientation_deg != [0.0; 3] {
            return Err(Error::input(
                self.place("[tracker]", "tracker"),
                "with [[station]] tables the stations carry the poses: the [tracker] table may \
                 only give the default noise (move its position and orientation_deg to the \
                 first station)",
            ));
        }
        for st in &spec.stations {
            let station = self.station(st, &stations, tracker_noise)?;
            stations.push(station);
        }
        Ok(stations)
    }

    /// One `[[station]]` table: an id usable as a CSV cell and not among `before`, its pose and
    /// its noise (`default_noise`, the `[tracker]` table's, when it gives none).
    fn station(
        &self,
        st: &StationSpec,
        before: &[Station],
        default_noise: Option<TrackerNoise>,
    ) -> Result<Station> {
        let at = || self.place(&st.id, "station.id");
        if !valid_id(&st.id) {
            return Err(Error::input(
                at(),
                format!(
                    "station id {:?}: an id is written in CSV files, so it must be non-empty \
                     and hold no comma, semicolon, quote, control character or surrounding \
                     space",
                    st.id
                ),
            ));
        }
        if before.iter().any(|q| q.id == st.id) {
            return Err(Error::input(
                at(),
                format!("station id '{}' is used twice", st.id),
            ));
        }
        let noise = self.noise_of(&st.noise, "station.noise")?.or(default_noise);
        let pose = Pose {
            position: st.position,
            orientation_deg: st.orientation_deg,
        };
        Ok(Station {
            id: st.id.clone(),
            setup: pose.setup(st.mount, noise, at())?,
            observes: st.observes,
        })
    }

    /// The `[clearance]` position (chain index, internal units), empty without the table.
    fn clearance(&self, axes: &[MachineAxis]) -> Result<Vec<(usize, f64)>> {
        let spec = self.spec;
        let table = spec.clearance.iter().flatten();
        clearance_of(axes, table.map(|(k, v)| (k.as_str(), *v))).or_else(|(key, m)| {
            match (key.as_str(), &spec.clearance) {
                (_, None) => Ok(Vec::new()),
                ("", _) => Err(Error::input(self.place("[clearance]", "clearance"), m)),
                (k, _) => Err(Error::input(
                    self.place("[clearance]", &format!("clearance.{k}")),
                    m,
                )),
            }
        })
    }
}

/// A station's pose as a machine file gives it.
struct Pose {
    /// Position T_LT (mm).
    position: [f64; 3],
    /// Orientation: rotations about x, y, z (degrees).
    orientation_deg: [f64; 3],
}

impl Pose {
    /// The tracker set-up of this pose, after checking it is finite and bounded (error at `at`).
    fn setup(
        &self,
        mount: TrackerMount,
        noise: Option<TrackerNoise>,
        at: Place,
    ) -> Result<TrackerSetup> {
        if !self
            .position
            .iter()
            .chain(&self.orientation_deg)
            .all(|v| v.is_finite() && v.abs() <= MAX_DIMENSION)
        {
            return Err(Error::input(
                at,
                format!(
                    "position (mm) and orientation_deg must be finite numbers of at most \
                     {MAX_DIMENSION:e} in magnitude"
                ),
            ));
        }
        let [rx, ry, rz] = self.orientation_deg.map(f64::to_radians);
        Ok(TrackerSetup {
            mount,
            position: self.position,
            base_rotation: base_rotation(rx, ry, rz),
            noise,
        })
    }
}
