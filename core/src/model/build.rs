//! Compiling an [`ErrorModelSpec`] for a machine into a [`Model`]: terms, parameter layout,
//! constraints and the groups of terms that share their basis values.

use super::*;
use crate::basis::BasisError;
use crate::machine::MachineAxis;

impl Model {
    pub(super) fn build(
        machine: Machine,
        spec: ErrorModelSpec,
        file: &str,
        source: Option<&str>,
    ) -> Result<Model> {
        let mut b = Builder {
            machine: &machine,
            spec: &spec,
            file,
            source,
            terms: Vec::new(),
            params: Vec::new(),
            effects: Vec::new(),
            stations: Vec::new(),
            rows: Vec::new(),
            tracker_start: 0,
            initial: Vec::new(),
        };
        b.terms()?;
        b.tracker();
        b.effects()?;
        b.stations();
        b.initial_values();
        b.reference_constraints();
        b.squareness_constraints();
        b.fixed_constraints()?;
        let Builder {
            terms,
            params,
            effects,
            stations,
            rows,
            tracker_start,
            initial,
            ..
        } = b;
        let slot_of = slots(&terms, &params);
        let has_location = location_axes(&terms, &effects);
        let places = terms
            .iter()
            .map(|t| TermPlace {
                axis: t.axis,
                location: matches!(t.id, ErrorId::Location { .. }),
                component: t.id.component().index(),
            })
            .collect();
        let groups = term_groups(&terms);
        Ok(Model {
            machine,
            spec,
            terms,
            params,
            slot_of,
            places,
            groups,
            tracker_start,
            stations,
            has_location,
            constraints: Constraints { rows },
            initial,
            effects,
        })
    }
}

/// The state of [`Model::build`]: the terms, parameters, effects, stations and constraints laid
/// out so far, pass after pass, in the order of the parameter vector.
struct Builder<'a> {
    /// The machine the model is for.
    machine: &'a Machine,
    /// The error-model file's content.
    spec: &'a ErrorModelSpec,
    /// The file's name, for errors.
    file: &'a str,
    /// The file's text, when known: errors then give the line of the offending name.
    source: Option<&'a str>,
    /// The modelled errors.
    terms: Vec<Term>,
    /// Every parameter, in vector order.
    params: Vec<ParamInfo>,
    /// The effects' slots and their first parameter.
    effects: Vec<(EffectSlot, usize)>,
    /// Every station's pose and range-offset parameters.
    stations: Vec<StationBlock>,
    /// The constraints.
    rows: Vec<Constraint>,
    /// The tracker pose's first parameter.
    tracker_start: usize,
    /// Initial parameter values (stations at their nominal positions, fixed values).
    initial: Vec<f64>,
}

impl<'a> Builder<'a> {
    /// The place of `needle` (its line in the source, when found) at `field`.
    fn place(&self, needle: &str, field: &str) -> Place {
        let mut p = Place::file(self.file).at_field(field);
        if let Some(line) = self.source.and_then(|s| line_of_text(s, needle)) {
            p = p.at_line(line);
        }
        p
    }

    /// The prefix of station `s`'s parameter names: `station.<id>`, or `tracker` without
    /// `[[station]]` tables.
    fn station_prefix(&self, s: usize) -> String {
        if self.machine.has_stations() {
            format!("station.{}", self.machine.stations()[s].id)
        } else {
            "tracker".to_string()
        }
    }

    /// Pass 1: one term per error named in the `[[error]]` entries, with its coefficients'
    /// parameters (mm or rad; rad for the phases of a sine series).
    fn terms(&mut self) -> Result<()> {
        let spec = self.spec;
        for entry in &spec.errors {
            for raw in entry.name.names() {
                self.term(entry, raw)
                    .map_err(|m| Error::input(self.place(raw, "error.name"), m))?;
            }
        }
        if self.terms.len() + TRACKER_DOF > MAX_SLOTS {
            return Err(Error::TooManyParameters {
                message: format!(
                    "{} errors are modelled; at most {} fit beside the tracker pose",
                    self.terms.len(),
                    MAX_SLOTS - TRACKER_DOF
                ),
            });
        }
        Ok(())
    }

    /// The term of error `raw` of `entry`, or the message saying why it cannot be modelled.
    fn term(&mut self, entry: &ErrorTermSpec, raw: &str) -> std::result::Result<(), String> {
        let machine = self.machine;
        let id: ErrorId = raw.parse()?;
        let Some((axis, ax)) = machine.axis(id.axis()) else {
            return Err(format!(
                "{id} belongs to axis {}, which the machine's chain {} does not have",
                id.axis(),
                machine.chain()
            ));
        };
        if self.terms.iter().any(|t| t.id == id) {
            return Err(format!("{id} is listed twice"));
        }
        let basis = term_basis(id, ax.axis.is_rotary(), entry).map_err(|e| e.to_string())?;
        let start = self.params.len();
        let suffixes = basis.suffixes();
        for (c, suffix) in suffixes.iter().enumerate() {
            let name = if suffix.is_empty() {
                id.to_string()
            } else {
                format!("{id}.{suffix}")
            };
            let unit = if basis.is_phase(c) {
                Unit::Rad
            } else {
                id.unit()
            };
            self.params.push(ParamInfo {
                name,
                unit,
                group: id.group(),
                owner: Owner::Term {
                    term: self.terms.len(),
                    coeff: c,
                },
            });
        }
        self.terms.push(Term {
            id,
            axis,
            basis,
            params: start..self.params.len(),
        });
        Ok(())
    }

    /// Pass 2: the tracker pose (x, y, z in mm, rx, ry, rz in rad) of the first station.
    fn tracker(&mut self) {
        self.tracker_start = self.params.len();
        let prefix = self.station_prefix(0);
        for (k, n) in TRACKER_NAMES.iter().enumerate() {
            self.params.push(ParamInfo {
                name: format!("{prefix}.{n}"),
                unit: if k < 3 { Unit::Mm } else { Unit::Rad },
                group: Group::Tracker,
                owner: Owner::Tracker(k),
            });
        }
    }

    /// One effect slot with its parameters (names and units).
    fn push_effect(&mut self, slot: EffectSlot, names: &[(String, Unit)]) {
        let k = self.effects.len();
        self.effects.push((slot, self.params.len()));
        for (name, unit) in names {
            self.params.push(ParamInfo {
                name: name.clone(),
                unit: *unit,
                group: Group::Other,
                owner: Owner::Effect(k),
            });
        }
    }

    /// Pass 3: the effects outside the ISO 230 model, in the file's fixed order, then the check
    /// that they fit beside the errors and the tracker pose.
    fn effects(&mut self) -> Result<()> {
        self.drift_and_reflector_effects()?;
        self.axis_effects()?;
        self.tracker_and_station_drift()?;
        self.field_effects()?;
        self.reversal_effects()?;
        if self.terms.len() + TRACKER_DOF + self.effects.len() > MAX_SLOTS {
            return Err(Error::TooManyParameters {
                message: format!(
                    "{} errors and {} effect values are modelled; at most {} fit beside the \
                     tracker pose",
                    self.terms.len(),
                    self.effects.len(),
                    MAX_SLOTS - TRACKER_DOF
                ),
            });
        }
        Ok(())
    }

    /// Thermal drift of the tool point (mm/h), reflector offsets (mm) and the range scale (ppm).
    fn drift_and_reflector_effects(&mut self) -> Result<()> {
        let spec = self.spec;
        let fx = &spec.effects;
        if fx.thermal_drift {
            for (c, x) in ["x", "y", "z"].iter().enumerate() {
                self.push_effect(
                    EffectSlot::Drift(c),
                    &[(format!("drift.{x}"), Unit::MmPerHour)],
                );
            }
        }
        for id in &fx.reflector_offset {
            let Some(r) = self.machine.reflector_index(id) else {
                return Err(Error::input(
                    self.place(id, "effects.reflector_offset"),
                    format!("no reflector '{id}' in the machine"),
                ));
            };
            for (c, x) in ["x", "y", "z"].iter().enumerate() {
                self.push_effect(
                    EffectSlot::Reflector { reflector: r, c },
                    &[(format!("reflector.{id}.{x}"), Unit::Mm)],
                );
            }
        }
        if fx.range_scale {
            self.push_effect(
                EffectSlot::RangeScale,
                &[("range.scale".to_string(), Unit::Ppm)],
            );
        }
        Ok(())
    }

    /// The axis `name` names, rotary or linear as the effect at `field` needs.
    fn axis_of_kind(
        &self,
        name: &str,
        rotary: bool,
        field: &str,
    ) -> Result<(usize, &'a MachineAxis)> {
        let machine = self.machine;
        machine
            .axis_named(name)
            .filter(|(_, ax)| ax.axis.is_rotary() == rotary)
            .ok_or_else(|| {
                let kind = if rotary { "rotary" } else { "linear" };
                Error::input(
                    self.place(name, field),
                    format!("'{name}' is not a {kind} axis of {}", machine.chain()),
                )
            })
    }

    /// Effects of one axis: ball-screw pitch errors (mm), thermal scale (ppm/h) and the drift of
    /// a rotary axis' location (mm/h).
    fn axis_effects(&mut self) -> Result<()> {
        let spec = self.spec;
        let fx = &spec.effects;
        for b in &fx.ball_screw {
            let (k, ax) = self.axis_of_kind(&b.axis, false, "effects.ball_screw.axis")?;
            let (lo, hi) = PERIOD_RANGE_MM;
            if !(lo..=hi).contains(&b.period_mm) {
                return Err(Error::input(
                    self.place(&b.axis, "effects.ball_screw.period_mm"),
                    format!(
                        "the period {} mm is outside {lo} … {hi:e} mm (a period of a screw's \
                         pitch error, in mm)",
                        crate::error::number(b.period_mm)
                    ),
                ));
            }
            let slot = EffectSlot::Screw {
                k,
                dir: ax.axis.direction(),
                period_mm: b.period_mm,
                reference: ax.reference,
            };
            self.push_effect(
                slot,
                &[
                    (format!("screw.{}.a", b.axis), Unit::Mm),
                    (format!("screw.{}.b", b.axis), Unit::Mm),
                ],
            );
        }
        for name in &fx.thermal_scale {
            let (k, ax) = self.axis_of_kind(name, false, "effects.thermal_scale")?;
            let dir = ax.axis.direction();
            self.push_effect(
                EffectSlot::ThermalScale { k, dir },
                &[(format!("thermal.{name}"), Unit::PpmPerHour)],
            );
        }
        for name in &fx.location_drift {
            let (k, ax) = self.axis_of_kind(name, true, "effects.location_drift")?;
            let dir = ax.axis.direction();
            // The two translations across the axis' line (X0C, Y0C for C).
            for c in (0..3).filter(|&c| c != dir) {
                let letter = ["x", "y", "z"][c];
                self.push_effect(
                    EffectSlot::LocationDrift { k, c },
                    &[(format!("locdrift.{name}.{letter}"), Unit::MmPerHour)],
                );
            }
        }
        Ok(())
    }

    /// The tracker's orientation drift (rad/h) and every station's position drift (mm/h).
    fn tracker_and_station_drift(&mut self) -> Result<()> {
        let spec = self.spec;
        let fx = &spec.effects;
        if fx.tracker_drift {
            for (k, x) in ["rx", "ry", "rz"].iter().enumerate() {
                self.push_effect(
                    EffectSlot::TrackerDrift(3 + k),
                    &[(format!("trackerdrift.{x}"), Unit::RadPerHour)],
                );
            }
        }
        if fx.station_drift {
            let machine = self.machine;
            if !machine.has_stations() {
                return Err(Error::input(
                    self.place("station_drift", "effects.station_drift"),
                    "station_drift needs a machine with [[station]] tables (one tracker \
                     drifting in position is thermal_drift)",
                ));
            }
            for (s, st) in machine.stations().iter().enumerate() {
                for (c, x) in ["x", "y", "z"].iter().enumerate() {
                    self.push_effect(
                        EffectSlot::StationDrift { station: s, c },
                        &[(format!("stationdrift.{}.{x}", st.id), Unit::MmPerHour)],
                    );
                }
            }
        }
        Ok(())
    }

    /// Error fields over one or two axes: per component x, y, z, one coefficient (mm) per
    /// product of the variables' functions.
    fn field_effects(&mut self) -> Result<()> {
        let spec = self.spec;
        let fx = &spec.effects;
        for id in &fx.field {
            let vars = field_vars(self.machine, id)
                .map_err(|why| Error::input(self.place(id, "effects.field"), why))?;
            let pair = vars.len() == 2;
            let (v0, v1) = (vars[0], vars[vars.len() - 1]);
            let products: Vec<String> = if pair {
                (0..2)
                    .flat_map(|a| (0..2).map(move |b| format!("{}_{}", v0.code(a), v1.code(b))))
                    .collect()
            } else {
                (0..v0.functions())
                    .map(|q| v0.code(q).to_string())
                    .collect()
            };
            for (c, letter) in ["x", "y", "z"].iter().enumerate() {
                let names: Vec<(String, Unit)> = products
                    .iter()
                    .map(|q| (format!("field.{id}.{letter}_{q}"), Unit::Mm))
                    .collect();
                let slot = EffectSlot::Field {
                    c,
                    vars: [v0, v1],
                    pair,
                };
                self.push_effect(slot, &names);
            }
        }
        Ok(())
    }

    /// Reversals of the axes: per axis `reversal.X.b` (and `reversal.X.b1` … for a function),
    /// in mm for a linear axis, rad for a rotary one.
    fn reversal_effects(&mut self) -> Result<()> {
        let spec = self.spec;
        let fx = &spec.effects;
        for (i, r) in fx.reversal.iter().enumerate() {
            let name = r.axis();
            let field = "effects.reversal";
            let Some((k, ax)) = self.machine.axis_named(name) else {
                return Err(Error::input(
                    self.place(name, field),
                    format!("'{name}' is not an axis of {}", self.machine.chain()),
                ));
            };
            if fx.reversal[..i].iter().any(|o| o.axis() == name) {
                return Err(Error::input(
                    self.place(name, field),
                    format!("the reversal of {name} is listed twice"),
                ));
            }
            let degree = r.degree();
            if degree > MAX_REVERSAL_DEGREE {
                return Err(Error::input(
                    self.place(name, field),
                    format!(
                        "degree {degree} of the reversal of {name} is above \
                         {MAX_REVERSAL_DEGREE} (ISO 230-2 reports B at a few targets)"
                    ),
                ));
            }
            let rotary = ax.axis.is_rotary();
            let dir = ax.axis.direction() + if rotary { 3 } else { 0 };
            let unit = if rotary { Unit::Rad } else { Unit::Mm };
            let names: Vec<(String, Unit)> = (0..=degree)
                .map(|q| {
                    let code = if q == 0 {
                        "b".to_string()
                    } else {
                        format!("b{q}")
                    };
                    (format!("reversal.{name}.{code}"), unit)
                })
                .collect();
            self.push_effect(EffectSlot::Reversal { k, dir, degree }, &names);
        }
        Ok(())
    }

    /// Pass 4: the further stations' poses, then every station's range offset (mm): after the
    /// effects, so that a one-station model's layout is the tracker's alone.
    fn stations(&mut self) {
        self.stations = vec![StationBlock {
            pose: self.tracker_start,
            offset: None,
        }];
        for s in 1..self.machine.stations().len() {
            self.stations.push(StationBlock {
                pose: self.params.len(),
                offset: None,
            });
            let prefix = self.station_prefix(s);
            for (k, n) in TRACKER_NAMES.iter().enumerate() {
                self.params.push(ParamInfo {
                    name: format!("{prefix}.{n}"),
                    unit: if k < 3 { Unit::Mm } else { Unit::Rad },
                    group: Group::Tracker,
                    owner: Owner::Station {
                        station: s,
                        value: k,
                    },
                });
            }
        }
        if self.spec.tracker.range_offset {
            for s in 0..self.stations.len() {
                self.stations[s].offset = Some(self.params.len());
                let name = format!("{}.offset", self.station_prefix(s));
                self.params.push(ParamInfo {
                    name,
                    unit: Unit::Mm,
                    group: Group::Tracker,
                    owner: Owner::Station {
                        station: s,
                        value: TRACKER_DOF,
                    },
                });
            }
        }
    }

    /// Pass 5: initial values: zero, every station at its nominal position (mm).
    fn initial_values(&mut self) {
        self.initial = vec![0.0; self.params.len()];
        for (st, block) in self.machine.stations().iter().zip(&self.stations) {
            self.initial[block.pose..block.pose + 3].copy_from_slice(&st.setup.position);
        }
    }

    /// Pass 6: with `reference_constraint`, every linear axis' component errors vanish at its
    /// reference position.
    fn reference_constraints(&mut self) {
        if !self.spec.reference_constraint {
            return;
        }
        for t in &self.terms {
            let ax = &self.machine.axes()[t.axis];
            if ax.axis.is_rotary() || !matches!(t.id, ErrorId::Component { .. }) {
                continue;
            }
            let n = t.basis.n_params();
            let mut g = [0.0; MAX_COEFFS];
            t.basis.eval(
                ax.normalise(ax.reference),
                &[0.0; MAX_COEFFS][..n],
                &mut g[..n],
            );
            self.rows.push(Constraint {
                kind: ConstraintKind::Reference,
                label: format!(
                    "{}({} = {} {}) = 0",
                    t.id,
                    ax.axis,
                    ax.to_file_units(ax.reference),
                    ax.file_unit()
                ),
                coeffs: t
                    .params
                    .clone()
                    .zip(g[..n].iter().copied())
                    .filter(|(_, v)| *v != 0.0)
                    .collect(),
                rhs: 0.0,
            });
        }
    }

    /// Pass 7: the squareness rule: a squareness error and its partner straightness' slope are
    /// not both identifiable; one of them is held at zero.
    fn squareness_constraints(&mut self) {
        let rule = self.spec.squareness;
        if rule == SquarenessRule::None {
            return;
        }
        for t in self.terms.iter().filter(|t| t.id.is_squareness()) {
            let Some(partner) = t.id.squareness_partner() else {
                continue;
            };
            let Some(p) = self.terms.iter().find(|q| q.id == partner) else {
                continue;
            };
            if p.basis.kind().is_periodic()
                || p.basis.kind() == BasisKind::Constant
                || p.basis.degree() == 0
            {
                continue;
            }
            self.rows.push(match rule {
                SquarenessRule::FromStraightness => Constraint {
                    kind: ConstraintKind::Squareness,
                    label: format!("{} = 0 (taken from the slope of {partner})", t.id),
                    coeffs: vec![(t.params.start, 1.0)],
                    rhs: 0.0,
                },
                _ => Constraint {
                    kind: ConstraintKind::Squareness,
                    label: format!("slope of {partner} = 0 (carried by {})", t.id),
                    coeffs: p
                        .params
                        .clone()
                        .zip(p.basis.linear_component())
                        .filter(|(_, v)| v.abs() > 1e-14)
                        .collect(),
                    rhs: 0.0,
                },
            });
        }
    }

    /// Pass 8: held values: the tracker pose values not identified, a range-only station's
    /// orientation, and the file's `[fixed]` values (in the parameter's unit); each becomes a
    /// constraint and the parameter's initial value.
    fn fixed_constraints(&mut self) -> Result<()> {
        let mut fixed = self.held_tracker_values()?;
        let spec = self.spec;
        for (name, &value) in &spec.fixed {
            let j = self.fixed_value(name, value)?;
            fixed.insert(j, (value, format!("{name} fixed")));
        }
        for (j, (value, label)) in fixed {
            self.initial[j] = value;
            self.rows.push(Constraint {
                kind: ConstraintKind::Fixed,
                label: format!("{label} = {value} {}", self.params[j].unit),
                coeffs: vec![(j, 1.0)],
                rhs: value,
            });
        }
        Ok(())
    }

    /// The tracker pose values held: those `tracker.identify` does not name (first station),
    /// and the orientation of range-only stations; by parameter, with value and reason.
    fn held_tracker_values(&self) -> Result<BTreeMap<usize, (f64, String)>> {
        let identify = &self.spec.tracker.identify;
        for name in identify {
            if !TRACKER_NAMES.contains(&name.as_str()) {
                return Err(Error::input(
                    self.place(name, "tracker.identify"),
                    format!(
                        "'{name}' is not a tracker pose value; expected some of x, y, z, rx, ry, rz"
                    ),
                ));
            }
        }
        let mut fixed = BTreeMap::new();
        let stations = self.machine.stations().iter().zip(&self.stations);
        for (s, (st, block)) in stations.enumerate() {
            for (k, n) in TRACKER_NAMES.iter().enumerate() {
                let j = block.pose + k;
                let name = &self.params[j].name;
                if st.observes == Observes::Range && k >= 3 {
                    let why = format!("{name} held: a range-only station has no orientation");
                    fixed.insert(j, (self.initial[j], why));
                } else if s == 0 && !identify.iter().any(|s| s == n) {
                    let why = format!("{name} held at its nominal value");
                    fixed.insert(j, (self.initial[j], why));
                }
            }
        }
        Ok(fixed)
    }

    /// The parameter a `[fixed]` entry names, after checking its value is finite and within
    /// [`MAX_FIXED`] (mm or rad).
    fn fixed_value(&self, name: &str, value: f64) -> Result<usize> {
        let at = || self.place(name, &format!("fixed.{name}"));
        let Some(j) = self.params.iter().position(|p| p.name == name) else {
            return Err(Error::input(
                at(),
                format!(
                    "there is no parameter '{name}' in this model (names look like EYX.c2, ECC.a1, B0Z, tracker.rx)"
                ),
            ));
        };
        if !value.is_finite() {
            return Err(Error::input(at(), "a fixed value must be a finite number"));
        }
        let unit = self.params[j].unit;
        let max = match unit {
            Unit::Rad | Unit::RadPerHour => MAX_FIXED.1,
            _ => MAX_FIXED.0,
        };
        if value.abs() > max {
            return Err(Error::input(
                at(),
                format!(
                    "{} {unit} is beyond any machine's error or tracker pose (at most \
                     {max:e} {unit}): fixed values are in the parameter's unit (mm, rad …)",
                    crate::error::number(value)
                ),
            ));
        }
        Ok(j)
    }
}

/// The slot of every parameter: its term, the tracker pose value (stations share the tracker's
/// slots) or the effect.
fn slots(terms: &[Term], params: &[ParamInfo]) -> Vec<usize> {
    params
        .iter()
        .map(|p| match p.owner {
            Owner::Term { term, .. } => term,
            Owner::Tracker(k) => terms.len() + k,
            Owner::Station { value, .. } => terms.len() + value.min(TRACKER_DOF - 1),
            Owner::Effect(k) => terms.len() + TRACKER_DOF + k,
        })
        .collect()
}

/// The axes with a location error or a location drift in the model.
fn location_axes(terms: &[Term], effects: &[(EffectSlot, usize)]) -> [bool; MAX_AXES] {
    let mut has_location = [false; MAX_AXES];
    for t in terms {
        if matches!(t.id, ErrorId::Location { .. }) {
            has_location[t.axis] = true;
        }
    }
    for (slot, _) in effects {
        if let EffectSlot::LocationDrift { k, .. } = *slot {
            has_location[k] = true;
        }
    }
    has_location
}

/// Groups consecutive terms of one axis in one basis linear in its coefficients, with
/// consecutive coefficients (see [`TermGroup`]).
pub(super) fn term_groups(terms: &[Term]) -> Vec<TermGroup> {
    let mut groups: Vec<TermGroup> = Vec::new();
    for (i, t) in terms.iter().enumerate() {
        if let Some(g) = groups.last_mut() {
            let prev = &terms[i - 1];
            if prev.axis == t.axis
                && prev.basis == t.basis
                && t.basis.is_linear()
                && prev.params.end == t.params.start
                && g.terms.len() < MAX_GROUP
            {
                g.terms.end = i + 1;
                continue;
            }
        }
        groups.push(TermGroup {
            terms: i..i + 1,
            len: t.params.len(),
            params: t.params.start,
        });
    }
    groups
}

/// Why an `[[error]]` entry's basis is not meaningful for its error.
#[derive(Debug, thiserror::Error)]
pub(super) enum TermBasisError {
    /// A location or squareness error given a basis other than `constant`.
    #[error("{id} is a location/squareness error, a constant: give it no basis (found '{found}')")]
    ConstantWithBasis { id: ErrorId, found: BasisKind },
    /// A component error without a basis.
    #[error(
        "{id} needs a basis: monomial, legendre or chebyshev with a degree, fourier or sine with an order, or constant"
    )]
    MissingBasis { id: ErrorId },
    /// A periodic series on a linear axis.
    #[error(
        "{id}: a {kind} series is periodic in an angle; {} is a linear axis (use monomial, legendre or chebyshev)",
        id.axis()
    )]
    PeriodicOnLinear { id: ErrorId, kind: BasisKind },
    /// A periodic series without `order`.
    #[error("{id}: a {kind} series needs `order` (the number of harmonics)")]
    MissingOrder { id: ErrorId, kind: BasisKind },
    /// Chebyshev with `nodes = 0`.
    #[error("{id}: chebyshev needs at least one node")]
    NoNodes { id: ErrorId },
    /// Chebyshev with both `degree` and `nodes`.
    #[error("{id}: give chebyshev either `degree` or `nodes`, not both")]
    DegreeAndNodes { id: ErrorId },
    /// Chebyshev with neither `degree` nor `nodes`.
    #[error("{id}: chebyshev needs `nodes` (or `degree` = nodes − 1)")]
    MissingNodes { id: ErrorId },
    /// A polynomial without `degree`.
    #[error("{id}: a {kind} polynomial needs `degree`")]
    MissingDegree { id: ErrorId, kind: BasisKind },
    /// A basis that cannot be built (too many coefficients, no harmonics).
    #[error("{id}: {source}")]
    Basis { id: ErrorId, source: BasisError },
}

/// The basis of one `[[error]]` entry for an error, with the checks that make it meaningful.
pub(super) fn term_basis(
    id: ErrorId,
    rotary_axis: bool,
    e: &ErrorTermSpec,
) -> std::result::Result<Basis, TermBasisError> {
    let basis = |kind, degree| {
        Basis::new(kind, degree).map_err(|source| TermBasisError::Basis { id, source })
    };
    if let ErrorId::Location { .. } = id {
        return match e.basis {
            None | Some(BasisKind::Constant) => basis(BasisKind::Constant, 0),
            Some(found) => Err(TermBasisError::ConstantWithBasis { id, found }),
        };
    }
    let Some(kind) = e.basis else {
        return Err(TermBasisError::MissingBasis { id });
    };
    if kind.is_periodic() && !rotary_axis {
        return Err(TermBasisError::PeriodicOnLinear { id, kind });
    }
    let degree = match kind {
        BasisKind::Constant => 0,
        BasisKind::Fourier | BasisKind::Sine => {
            e.order.ok_or(TermBasisError::MissingOrder { id, kind })?
        }
        BasisKind::Chebyshev => match (e.degree, e.nodes) {
            (Some(d), None) => d,
            (None, Some(m)) if m >= 1 => m - 1,
            (None, Some(_)) => return Err(TermBasisError::NoNodes { id }),
            (Some(_), Some(_)) => return Err(TermBasisError::DegreeAndNodes { id }),
            (None, None) => return Err(TermBasisError::MissingNodes { id }),
        },
        BasisKind::Monomial | BasisKind::Legendre => {
            e.degree.ok_or(TermBasisError::MissingDegree { id, kind })?
        }
    };
    basis(kind, degree)
}

/// The variables of a field id (`X`, `X*Z`, `C*t`): one or two distinct axes of `machine` or
/// `t`; the reason when it is not one.
pub(super) fn field_vars(
    machine: &Machine,
    id: &str,
) -> std::result::Result<Vec<FieldVar>, String> {
    let parts: Vec<&str> = id.split('*').map(str::trim).collect();
    if parts.is_empty() || parts.len() > 2 || (parts.len() == 2 && parts[0] == parts[1]) {
        return Err(format!(
            "'{id}' is not a field: expected one or two distinct variables joined by '*' (X, X*Z, C*t)"
        ));
    }
    parts
        .iter()
        .map(|p| {
            if *p == "t" {
                return Ok(FieldVar::Time);
            }
            let Some((k, ax)) = machine.axis_named(p) else {
                return Err(format!(
                    "'{p}' in field '{id}' is neither an axis of {} nor t",
                    machine.chain()
                ));
            };
            let full_turn =
                ax.axis.is_rotary() && ax.max - ax.min >= 2.0 * std::f64::consts::PI - 1e-9;
            Ok(if full_turn {
                FieldVar::Periodic(k)
            } else {
                FieldVar::Linear(k)
            })
        })
        .collect()
}
