//! Compiling an [`ErrorModelSpec`] for a machine into a [`Model`]: terms, parameter layout,
//! constraints and the groups of terms that share their basis values.

use super::*;
use crate::basis::BasisError;

impl Model {
    pub(super) fn build(
        machine: Machine,
        spec: ErrorModelSpec,
        file: &str,
        source: Option<&str>,
    ) -> Result<Model> {
        let place = |needle: &str, field: &str| {
            let mut p = Place::file(file).at_field(field);
            if let Some(line) = source.and_then(|s| line_of_text(s, needle)) {
                p = p.at_line(line);
            }
            p
        };
        let mut terms: Vec<Term> = Vec::new();
        let mut params: Vec<ParamInfo> = Vec::new();
        for entry in &spec.errors {
            for raw in entry.name.names() {
                let bad = |m: String| Error::input(place(raw, "error.name"), m);
                let id: ErrorId = raw.parse().map_err(bad)?;
                let Some((axis, ax)) = machine.axis(id.axis()) else {
                    return Err(bad(format!(
                        "{id} belongs to axis {}, which the machine's chain {} does not have",
                        id.axis(),
                        machine.chain()
                    )));
                };
                if terms.iter().any(|t| t.id == id) {
                    return Err(bad(format!("{id} is listed twice")));
                }
                let basis =
                    term_basis(id, ax.axis.is_rotary(), entry).map_err(|e| bad(e.to_string()))?;
                let start = params.len();
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
                    params.push(ParamInfo {
                        name,
                        unit,
                        group: id.group(),
                        owner: Owner::Term {
                            term: terms.len(),
                            coeff: c,
                        },
                    });
                }
                terms.push(Term {
                    id,
                    axis,
                    basis,
                    params: start..params.len(),
                });
            }
        }
        if terms.len() + TRACKER_DOF > MAX_SLOTS {
            return Err(Error::TooManyParameters {
                message: format!(
                    "{} errors are modelled; at most {} fit beside the tracker pose",
                    terms.len(),
                    MAX_SLOTS - TRACKER_DOF
                ),
            });
        }
        let tracker_start = params.len();
        let station_prefix = |s: usize| {
            if machine.has_stations() {
                format!("station.{}", machine.stations()[s].id)
            } else {
                "tracker".to_string()
            }
        };
        for (k, n) in TRACKER_NAMES.iter().enumerate() {
            params.push(ParamInfo {
                name: format!("{}.{n}", station_prefix(0)),
                unit: if k < 3 { Unit::Mm } else { Unit::Rad },
                group: Group::Tracker,
                owner: Owner::Tracker(k),
            });
        }
        let mut effects: Vec<(EffectSlot, usize)> = Vec::new();
        {
            let fx = &spec.effects;
            let mut push =
                |slot: EffectSlot, names: &[(String, Unit)], params: &mut Vec<ParamInfo>| {
                    let k = effects.len();
                    effects.push((slot, params.len()));
                    for (name, unit) in names {
                        params.push(ParamInfo {
                            name: name.clone(),
                            unit: *unit,
                            group: Group::Other,
                            owner: Owner::Effect(k),
                        });
                    }
                };
            if fx.thermal_drift {
                for (c, x) in ["x", "y", "z"].iter().enumerate() {
                    push(
                        EffectSlot::Drift(c),
                        &[(format!("drift.{x}"), Unit::MmPerHour)],
                        &mut params,
                    );
                }
            }
            for id in &fx.reflector_offset {
                let Some(r) = machine.reflector_index(id) else {
                    return Err(Error::input(
                        place(id, "effects.reflector_offset"),
                        format!("no reflector '{id}' in the machine"),
                    ));
                };
                for (c, x) in ["x", "y", "z"].iter().enumerate() {
                    push(
                        EffectSlot::Reflector { reflector: r, c },
                        &[(format!("reflector.{id}.{x}"), Unit::Mm)],
                        &mut params,
                    );
                }
            }
            if fx.range_scale {
                push(
                    EffectSlot::RangeScale,
                    &[("range.scale".to_string(), Unit::Ppm)],
                    &mut params,
                );
            }
            // The axis `name` names, rotary or linear as the effect needs.
            let axis_of_kind = |name: &str, rotary: bool, field: &str| {
                machine
                    .axis_named(name)
                    .filter(|(_, ax)| ax.axis.is_rotary() == rotary)
                    .ok_or_else(|| {
                        let kind = if rotary { "rotary" } else { "linear" };
                        Error::input(
                            place(name, field),
                            format!("'{name}' is not a {kind} axis of {}", machine.chain()),
                        )
                    })
            };
            for b in &fx.ball_screw {
                let (k, ax) = axis_of_kind(&b.axis, false, "effects.ball_screw.axis")?;
                let (lo, hi) = PERIOD_RANGE_MM;
                if !(lo..=hi).contains(&b.period_mm) {
                    return Err(Error::input(
                        place(&b.axis, "effects.ball_screw.period_mm"),
                        format!(
                            "the period {} mm is outside {lo} … {hi:e} mm (a period of a screw's \
                             pitch error, in mm)",
                            crate::error::number(b.period_mm)
                        ),
                    ));
                }
                push(
                    EffectSlot::Screw {
                        k,
                        dir: ax.axis.direction(),
                        period_mm: b.period_mm,
                        reference: ax.reference,
                    },
                    &[
                        (format!("screw.{}.a", b.axis), Unit::Mm),
                        (format!("screw.{}.b", b.axis), Unit::Mm),
                    ],
                    &mut params,
                );
            }
            for name in &fx.thermal_scale {
                let (k, ax) = axis_of_kind(name, false, "effects.thermal_scale")?;
                push(
                    EffectSlot::ThermalScale {
                        k,
                        dir: ax.axis.direction(),
                    },
                    &[(format!("thermal.{name}"), Unit::PpmPerHour)],
                    &mut params,
                );
            }
            for name in &fx.location_drift {
                let (k, ax) = axis_of_kind(name, true, "effects.location_drift")?;
                // The two translations across the axis' line (X0C, Y0C for C).
                for c in (0..3).filter(|&c| c != ax.axis.direction()) {
                    let letter = ["x", "y", "z"][c];
                    push(
                        EffectSlot::LocationDrift { k, c },
                        &[(format!("locdrift.{name}.{letter}"), Unit::MmPerHour)],
                        &mut params,
                    );
                }
            }
            if fx.tracker_drift {
                for (k, x) in ["rx", "ry", "rz"].iter().enumerate() {
                    push(
                        EffectSlot::TrackerDrift(3 + k),
                        &[(format!("trackerdrift.{x}"), Unit::RadPerHour)],
                        &mut params,
                    );
                }
            }
            if fx.station_drift {
                if !machine.has_stations() {
                    return Err(Error::input(
                        place("station_drift", "effects.station_drift"),
                        "station_drift needs a machine with [[station]] tables (one tracker \
                         drifting in position is thermal_drift)",
                    ));
                }
                for (s, st) in machine.stations().iter().enumerate() {
                    for (c, x) in ["x", "y", "z"].iter().enumerate() {
                        push(
                            EffectSlot::StationDrift { station: s, c },
                            &[(format!("stationdrift.{}.{x}", st.id), Unit::MmPerHour)],
                            &mut params,
                        );
                    }
                }
            }
            for id in &fx.field {
                let vars = field_vars(&machine, id)
                    .map_err(|why| Error::input(place(id, "effects.field"), why))?;
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
                    push(
                        EffectSlot::Field {
                            c,
                            vars: [v0, v1],
                            pair,
                        },
                        &names,
                        &mut params,
                    );
                }
            }
        }
        if terms.len() + TRACKER_DOF + effects.len() > MAX_SLOTS {
            return Err(Error::TooManyParameters {
                message: format!(
                    "{} errors and {} effect values are modelled; at most {} fit beside the \
                     tracker pose",
                    terms.len(),
                    effects.len(),
                    MAX_SLOTS - TRACKER_DOF
                ),
            });
        }
        // The further stations' poses, then every station's range offset: after the effects,
        // so that a one-station model's layout is the tracker's alone.
        let mut stations = vec![StationBlock {
            pose: tracker_start,
            offset: None,
        }];
        for s in 1..machine.stations().len() {
            stations.push(StationBlock {
                pose: params.len(),
                offset: None,
            });
            for (k, n) in TRACKER_NAMES.iter().enumerate() {
                params.push(ParamInfo {
                    name: format!("{}.{n}", station_prefix(s)),
                    unit: if k < 3 { Unit::Mm } else { Unit::Rad },
                    group: Group::Tracker,
                    owner: Owner::Station {
                        station: s,
                        value: k,
                    },
                });
            }
        }
        if spec.tracker.range_offset {
            for (s, block) in stations.iter_mut().enumerate() {
                block.offset = Some(params.len());
                params.push(ParamInfo {
                    name: format!("{}.offset", station_prefix(s)),
                    unit: Unit::Mm,
                    group: Group::Tracker,
                    owner: Owner::Station {
                        station: s,
                        value: TRACKER_DOF,
                    },
                });
            }
        }
        let slot_of = params
            .iter()
            .map(|p| match p.owner {
                Owner::Term { term, .. } => term,
                Owner::Tracker(k) => terms.len() + k,
                Owner::Station { value, .. } => terms.len() + value.min(TRACKER_DOF - 1),
                Owner::Effect(k) => terms.len() + TRACKER_DOF + k,
            })
            .collect();
        let mut has_location = [false; MAX_AXES];
        for t in &terms {
            if matches!(t.id, ErrorId::Location { .. }) {
                has_location[t.axis] = true;
            }
        }
        for (slot, _) in &effects {
            if let EffectSlot::LocationDrift { k, .. } = *slot {
                has_location[k] = true;
            }
        }
        let mut initial = vec![0.0; params.len()];
        for (st, block) in machine.stations().iter().zip(&stations) {
            initial[block.pose..block.pose + 3].copy_from_slice(&st.setup.position);
        }

        // Constraints.
        let mut rows = Vec::new();
        if spec.reference_constraint {
            for t in &terms {
                let ax = &machine.axes()[t.axis];
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
                rows.push(Constraint {
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
        if spec.squareness != SquarenessRule::None {
            for t in terms.iter().filter(|t| t.id.is_squareness()) {
                let partner = t.id.squareness_partner().expect("squareness has a partner");
                let Some(p) = terms.iter().find(|q| q.id == partner) else {
                    continue;
                };
                if p.basis.kind().is_periodic()
                    || p.basis.kind() == BasisKind::Constant
                    || p.basis.degree() == 0
                {
                    continue;
                }
                rows.push(match spec.squareness {
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
        let mut fixed: BTreeMap<usize, (f64, String)> = BTreeMap::new();
        for name in &spec.tracker.identify {
            if !TRACKER_NAMES.contains(&name.as_str()) {
                return Err(Error::input(
                    place(name, "tracker.identify"),
                    format!(
                        "'{name}' is not a tracker pose value; expected some of x, y, z, rx, ry, rz"
                    ),
                ));
            }
        }
        for (s, (st, block)) in machine.stations().iter().zip(&stations).enumerate() {
            for (k, n) in TRACKER_NAMES.iter().enumerate() {
                let j = block.pose + k;
                let name = &params[j].name;
                if st.observes == Observes::Range && k >= 3 {
                    fixed.insert(
                        j,
                        (
                            initial[j],
                            format!("{name} held: a range-only station has no orientation"),
                        ),
                    );
                } else if s == 0 && !spec.tracker.identify.iter().any(|s| s == n) {
                    fixed.insert(j, (initial[j], format!("{name} held at its nominal value")));
                }
            }
        }
        for (name, &value) in &spec.fixed {
            let Some(j) = params.iter().position(|p| &p.name == name) else {
                return Err(Error::input(
                    place(name, &format!("fixed.{name}")),
                    format!(
                        "there is no parameter '{name}' in this model (names look like EYX.c2, ECC.a1, B0Z, tracker.rx)"
                    ),
                ));
            };
            if !value.is_finite() {
                return Err(Error::input(
                    place(name, &format!("fixed.{name}")),
                    "a fixed value must be a finite number",
                ));
            }
            let unit = params[j].unit;
            let max = match unit {
                Unit::Rad | Unit::RadPerHour => MAX_FIXED.1,
                _ => MAX_FIXED.0,
            };
            if value.abs() > max {
                return Err(Error::input(
                    place(name, &format!("fixed.{name}")),
                    format!(
                        "{} {unit} is beyond any machine's error or tracker pose (at most \
                         {max:e} {unit}): fixed values are in the parameter's unit (mm, rad …)",
                        crate::error::number(value)
                    ),
                ));
            }
            fixed.insert(j, (value, format!("{name} fixed")));
        }
        for (j, (value, label)) in fixed {
            initial[j] = value;
            rows.push(Constraint {
                kind: ConstraintKind::Fixed,
                label: format!("{label} = {value} {}", params[j].unit),
                coeffs: vec![(j, 1.0)],
                rhs: value,
            });
        }
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
