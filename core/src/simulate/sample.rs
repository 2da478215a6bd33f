//! Sampling a simulation: the truth with its static effects, then one measurement per station
//! and plan step (errors, drift, noise), then the record of what was simulated.

use super::*;
use crate::machine::Commands;
use crate::measure::Observation;
use crate::plan::Step;
use crate::units::{MS_PER_S, PPM, S_PER_H};

impl Simulation {
    /// Generates the measurements.
    pub fn run(&self) -> Result<Synthetic> {
        let duration = self.validate()?;
        let mut sampler = self.prepare()?;
        let steps = self.plan.steps();
        let stations = sampler.machine.stations().len();
        let n = steps.len() * stations;
        sampler.points.reserve(n);
        sampler.noise_free.reserve(n);
        sampler.nominal.reserve(n);
        // The errors of a position, computed once however many reflectors are measured there.
        let mut cached: Option<(usize, PointErrors<f64>)> = None;
        let approaches = self.plan.approaches(stations);
        let visits = (0..stations).flat_map(|s| steps.iter().map(move |step| (s, step)));
        for (i, (station, step)) in visits.enumerate() {
            let j = step.position;
            let errors = match &cached {
                Some((at, e)) if *at == j => *e,
                _ => {
                    let errors = sampler.errors_at(&self.plan.positions[j]);
                    cached = Some((j, errors));
                    errors
                }
            };
            let t_s = if n > 1 {
                (duration * i as f64 / (n - 1) as f64 * MS_PER_S).round() / MS_PER_S
            } else {
                0.0
            };
            let visit = Visit {
                i,
                station,
                step,
                approach: approaches[i],
            };
            sampler.measure(visit, errors, t_s)?;
        }
        Ok(sampler.finish(duration, n))
    }

    /// The sampler: the truth with the effects that change it once (rotary harmonics, tracker
    /// tilt), the drift rate (mm/s), range scale, screw errors and reflector offsets (mm).
    fn prepare(&self) -> Result<Sampler<'_>> {
        let mut truth = self.truth.clone();
        let ts = truth.model.tracker_start();
        let mut drift_mm_per_s = [0.0; 3];
        let mut scale = 1.0;
        let mut screws = Vec::new();
        for e in &self.effects {
            match e {
                Effect::RotaryHarmonics {
                    max_order,
                    translation_um,
                    rotation_urad,
                } => {
                    let mut rng = stream(self.seed, Stream::Harmonics);
                    truth = truth.with_harmonics(
                        *max_order,
                        translation_um * MM_PER_UM,
                        rotation_urad * RAD_PER_URAD,
                        &mut rng,
                    )?;
                }
                Effect::TrackerTilt { rx_urad, ry_urad } => {
                    truth.params[ts + 3] += rx_urad * RAD_PER_URAD;
                    truth.params[ts + 4] += ry_urad * RAD_PER_URAD;
                }
                Effect::ThermalDrift { rate_um_per_h } => {
                    for k in 0..3 {
                        drift_mm_per_s[k] += rate_um_per_h[k] * MM_PER_UM / S_PER_H;
                    }
                }
                Effect::RangeScale { ppm } => scale *= 1.0 + ppm * (1.0 / PPM),
                Effect::BallScrew {
                    axis,
                    period_mm,
                    amplitude_um,
                } => screws.push(Screw::new(&truth, *axis, *period_mm, *amplitude_um)?),
                _ => {}
            }
        }
        let machine = truth.model.machine().clone();
        let offsets_mm = self.reflector_offsets(&machine)?;
        let reversals = self.reversals(&machine);
        let mut nominal_errors = PointErrors::<f64>::zero();
        nominal_errors.tracker = truth.tracker_pose();
        Ok(Sampler {
            sim: self,
            truth,
            machine,
            drift_mm_per_s,
            scale,
            screws,
            reversals,
            offsets_mm,
            nominal_errors,
            noise_rng: stream(self.seed, Stream::Noise),
            points: Vec::new(),
            noise_free: Vec::new(),
            nominal: Vec::new(),
        })
    }

    /// The `reversal` effects: chain axis, component of its positioning error (EXX: 0, ECC: 5),
    /// B in mm or rad times the axis' side sign (what the error of the axis itself reverses by).
    fn reversals(&self, machine: &Machine) -> Vec<(usize, usize, f64)> {
        self.effects
            .iter()
            .filter_map(|e| match e {
                Effect::Reversal { axis, value } => {
                    let (k, ax) = machine.axis(*axis)?;
                    let comp = axis.direction() + if axis.is_rotary() { 3 } else { 0 };
                    let unit = if axis.is_rotary() {
                        RAD_PER_URAD
                    } else {
                        MM_PER_UM
                    };
                    // B is the tool's deviation relative to the workpiece: a workpiece-side
                    // axis' error moves it the other way.
                    Some((k, comp, value * unit * ax.side.sign()))
                }
                _ => None,
            })
            .collect()
    }

    /// Every reflector's offset (mm) with the `reflector-offset` effects added.
    fn reflector_offsets(&self, machine: &Machine) -> Result<Vec<[f64; 3]>> {
        let mut offsets: Vec<[f64; 3]> = machine.reflectors().iter().map(|r| r.offset).collect();
        for e in &self.effects {
            if let Effect::ReflectorOffset {
                reflector,
                delta_um,
            } = e
            {
                let r = machine
                    .reflector_named(reflector)
                    .map_err(|e| Error::input(Place::file("simulation").at_field("effects"), e))?;
                for k in 0..3 {
                    offsets[r][k] += delta_um[k] * MM_PER_UM;
                }
            }
        }
        Ok(offsets)
    }
}

/// A ball screw's periodic pitch error on one linear axis.
struct Screw {
    /// Chain position of the axis.
    k: usize,
    /// Component of the error (the axis' direction).
    dir: usize,
    /// Amplitude (mm).
    amplitude_mm: f64,
    /// Period (mm).
    period_mm: f64,
    /// The axis' reference position (mm), where the phase is zero.
    reference_mm: f64,
}

impl Screw {
    /// The screw of `axis` of the truth's machine.
    fn new(truth: &Truth, axis: Axis, period_mm: f64, amplitude_um: f64) -> Result<Screw> {
        let (k, ax) = truth
            .model
            .machine()
            .axis(axis)
            .ok_or_else(|| Error::MachineMismatch {
                message: format!("a ball screw on axis {axis}, which the machine lacks"),
            })?;
        Ok(Screw {
            k,
            dir: axis.direction(),
            amplitude_mm: amplitude_um * MM_PER_UM,
            period_mm,
            reference_mm: ax.reference,
        })
    }
}

/// One measurement to simulate: its index, its station and its plan step.
struct Visit<'a> {
    /// Index among all measurements (station after station).
    i: usize,
    /// The station measuring.
    station: usize,
    /// The position and reflector.
    step: &'a Step,
    /// Each axis' direction of approach.
    approach: crate::approach::Approach,
}

/// The state of a simulation run: the prepared truth and effects, the noise stream and the
/// points simulated so far.
struct Sampler<'a> {
    /// The simulation.
    sim: &'a Simulation,
    /// The truth with the static effects.
    truth: Truth,
    /// Its machine.
    machine: Machine,
    /// Thermal drift of the tool point (mm/s).
    drift_mm_per_s: [f64; 3],
    /// Range scale (1 + ppm · 1e-6).
    scale: f64,
    /// Ball-screw errors.
    screws: Vec<Screw>,
    /// Reversals: chain axis, component of its positioning error, B (mm or rad).
    reversals: Vec<(usize, usize, f64)>,
    /// Reflector offsets with their errors (mm).
    offsets_mm: Vec<[f64; 3]>,
    /// The errors of the nominal machine: only the tracker pose.
    nominal_errors: PointErrors<f64>,
    /// The noise's random stream.
    noise_rng: Rng,
    /// The measured points.
    points: Vec<Measurement>,
    /// The same without noise.
    noise_free: Vec<[f64; 3]>,
    /// What the nominal machine would have measured.
    nominal: Vec<[f64; 3]>,
}

impl Sampler<'_> {
    /// The truth's errors at `cmd` with the screws and the couplings.
    fn errors_at(&self, cmd: &Commands) -> PointErrors<f64> {
        let mut errors = self.truth.model.errors_at(cmd, &self.truth.params);
        for s in &self.screws {
            errors.component[s.k][s.dir] +=
                s.amplitude_mm * (2.0 * PI * (cmd.0[s.k] - s.reference_mm) / s.period_mm).sin();
        }
        self.sim.couple(&self.machine, cmd, &mut errors);
        errors
    }

    /// `errors` with the pose of `station` (its own for a further station).
    fn at_station(&self, mut errors: PointErrors<f64>, station: usize) -> PointErrors<f64> {
        if station > 0 {
            let pose = self.truth.model.stations()[station].pose;
            errors.tracker = std::array::from_fn(|k| self.truth.params[pose + k]);
            errors.station = station;
        }
        errors
    }

    /// Simulates one measurement at time `t_s` (s) with the position's `errors`.
    fn measure(&mut self, visit: Visit, errors: PointErrors<f64>, t_s: f64) -> Result<()> {
        let Visit {
            i,
            station,
            step,
            approach,
        } = visit;
        let (j, r) = (step.position, step.reflector);
        let cmd = &self.sim.plan.positions[j];
        let shift = (self.drift_mm_per_s != [0.0; 3]).then(|| self.drift_mm_per_s.map(|v| v * t_s));
        let mut errors = self.at_station(errors, station);
        for &(k, comp, b) in &self.reversals {
            errors.component[k][comp] += 0.5 * b * approach.sign(k);
        }
        let errors = self.sim.age(&self.machine, cmd, t_s, &errors);
        let point =
            predict_with_tool_shift(&self.machine, cmd, &self.offsets_mm[r], &errors, shift)
                .map(|v| v * self.scale);
        let offset = self.truth.model.stations()[station]
            .offset
            .map_or(0.0, |o| self.truth.params[o]);
        // Each station with its own noise when the machine file states one.
        let noise = self.machine.station_noise_or(station, self.sim.noise);
        let (clean, measured) = self.observe(point, offset, noise);
        if measured.iter().any(|v| !v.is_finite()) {
            return Err(Error::NonFinite {
                message: format!(
                    "point {i} is not finite: the truth or an effect is out of bounds"
                ),
            });
        }
        let nominal_errors = self.at_station(self.nominal_errors, station);
        let seen = predict(
            &self.machine,
            cmd,
            &self.machine.reflectors()[r].offset,
            &nominal_errors,
        );
        self.nominal.push(match self.sim.observe {
            Observation::Point => seen,
            Observation::Range => [seen.iter().map(|v| v * v).sum::<f64>().sqrt(), 0.0, 0.0],
        });
        self.noise_free.push(clean);
        self.points.push(Measurement {
            commands: *cmd,
            reflector: r,
            measured,
            observation: self.sim.observe,
            t_s: Some(t_s),
            station: self
                .machine
                .has_stations()
                .then(|| self.machine.stations()[station].id.clone()),
            station_index: station,
            line: i + 2,
            approach,
        });
        Ok(())
    }

    /// The observation of `point` (mm) by a station with range offset `offset` (mm): without
    /// and with noise.
    fn observe(
        &mut self,
        point: [f64; 3],
        offset: f64,
        noise: TrackerNoise,
    ) -> ([f64; 3], [f64; 3]) {
        match self.sim.observe {
            Observation::Point => {
                let clean = if offset == 0.0 {
                    point
                } else {
                    let len = point.iter().map(|v| v * v).sum::<f64>().sqrt();
                    point.map(|v| v * (1.0 + offset / len))
                };
                (clean, noise.apply(clean, &mut self.noise_rng))
            }
            Observation::Range => {
                // The noise's angles turn the point, its range part alone moves it along the
                // line of sight: the noisy reading's distance.
                let d = point.iter().map(|v| v * v).sum::<f64>().sqrt() + offset;
                let noisy = noise.apply([d, 0.0, 0.0], &mut self.noise_rng);
                let read = noisy.iter().map(|v| v * v).sum::<f64>().sqrt();
                ([d, 0.0, 0.0], [read, 0.0, 0.0])
            }
        }
    }

    /// The measurements, the truth and the record of a run of `n` points over `duration` s.
    fn finish(self, duration: f64, n: usize) -> Synthetic {
        let sim = self.sim;
        let machine = &self.machine;
        let measured: Vec<[f64; 3]> = self.points.iter().map(|p| p.measured).collect();
        let record = SimulationRecord {
            format: SIMULATION_FORMAT.into(),
            version: SIMULATION_VERSION,
            seed: sim.seed,
            plan: sim.plan.name.clone(),
            positions: sim.plan.positions.len(),
            points: n,
            reflectors: sim
                .plan
                .reflectors
                .iter()
                .map(|&r| machine.reflectors()[r].id.clone())
                .collect(),
            duration_s: duration,
            noise: sim.noise,
            truth: sim.truth_source.clone(),
            effects: sim.effects.clone(),
            noise_error: ErrorStats::between(&measured, &self.noise_free),
            machine_error: ErrorStats::between(&self.noise_free, &self.nominal),
            files: SimulationFiles::default(),
        };
        Synthetic {
            measurements: MeasurementSet {
                points: self.points,
                time_origin_s: 0.0,
                approach_stated: Default::default(),
            },
            noise_free: self.noise_free,
            truth: self.truth,
            record,
        }
    }
}
