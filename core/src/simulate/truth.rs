//! The true errors of a synthetic machine: random within [`Magnitudes`], read from a results
//! file, or given.

use super::*;

/// True error functions and tracker pose: an error model and its parameter values. The model's
/// tracker pose has all six values free (a tilted tracker is part of the truth).
#[derive(Clone, Debug)]
pub struct Truth {
    /// The model (machine + error functions).
    pub model: Model,
    /// Parameter values, satisfying the model's constraints.
    pub params: Vec<f64>,
}

impl Truth {
    /// A truth with the structure `structure` (which errors, which bases) drawn at random with
    /// the given magnitudes (see the module documentation).
    pub fn random(
        machine: &Machine,
        structure: &ErrorModelSpec,
        magnitudes: &Magnitudes,
        seed: u64,
    ) -> Result<Truth> {
        magnitudes.validate()?;
        let mut spec = structure.clone();
        if spec.squareness == SquarenessRule::FromStraightness {
            spec.squareness = SquarenessRule::Separate;
        }
        spec.tracker = TrackerModelSpec {
            range_offset: machine.has_stations(),
            ..TrackerModelSpec::default()
        };
        let model = Model::new(machine.clone(), spec)?;
        let mut rng = stream(seed, Stream::Errors);
        let mut p = model.initial_params();
        let mut targets = Vec::with_capacity(model.terms().len());
        for t in model.terms() {
            let b = &t.basis;
            for (j, idx) in t.params.clone().enumerate() {
                let harmonic = j.div_ceil(2).max(1) as f64;
                p[idx] = match b.kind() {
                    BasisKind::Constant => {
                        if rng.uniform() < 0.5 {
                            -1.0
                        } else {
                            1.0
                        }
                    }
                    BasisKind::Monomial | BasisKind::Legendre => rng.normal() / (j + 1) as f64,
                    BasisKind::Chebyshev => rng.normal(),
                    BasisKind::Fourier => rng.normal() / harmonic,
                    BasisKind::Sine if b.is_phase(j) => PI * (2.0 * rng.uniform() - 1.0),
                    BasisKind::Sine => rng.normal() / harmonic,
                };
            }
            targets.push(magnitudes.for_error(t.id) * (0.5 + 0.5 * rng.uniform()));
        }
        project(&model, &mut p)?;
        for (t, target) in model.terms().iter().zip(targets) {
            let peak = peak_value(&model, t.id, &p);
            let factor = if peak > 0.0 { target / peak } else { 0.0 };
            for (j, idx) in t.params.clone().enumerate() {
                if !t.basis.is_phase(j) {
                    p[idx] *= factor;
                }
            }
        }
        project(&model, &mut p)?;
        let mut rng = stream(seed, Stream::Tracker);
        let dir = [rng.normal(), rng.normal(), rng.normal()];
        let norm = dir.iter().map(|v| v * v).sum::<f64>().sqrt();
        let dist = magnitudes.tracker_mm * (0.5 + 0.5 * rng.uniform());
        if norm > 0.0 {
            for (k, d) in dir.iter().enumerate() {
                p[model.tracker_start() + k] += dist * d / norm;
            }
        }
        // Further stations stand as far from their nominal positions as the tracker; each
        // station's range offset (the dead path, when modelled) is up to ±0.1 mm. Drawn after
        // the tracker, so that one station draws what it always did.
        for (s, block) in model.stations().iter().enumerate() {
            if s > 0 {
                let dir = [rng.normal(), rng.normal(), rng.normal()];
                let norm = dir.iter().map(|v| v * v).sum::<f64>().sqrt();
                let dist = magnitudes.tracker_mm * (0.5 + 0.5 * rng.uniform());
                for (k, d) in dir.iter().enumerate() {
                    p[block.pose + k] += dist * d / norm.max(f64::MIN_POSITIVE);
                }
            }
            if let Some(o) = block.offset {
                p[o] = 0.1 * (2.0 * rng.uniform() - 1.0);
            }
        }
        Ok(Truth { model, params: p })
    }

    /// [`Truth::random`] with every error of the machine ([`ErrorModelSpec::complete`]).
    pub fn random_complete(machine: &Machine, magnitudes: &Magnitudes, seed: u64) -> Result<Truth> {
        Truth::random(
            machine,
            &ErrorModelSpec::complete(machine),
            magnitudes,
            seed,
        )
    }

    /// The truth held in a results file (`file` names it in messages).
    pub fn from_results(results: &ResultsFile, file: &str) -> Result<Truth> {
        let (model, params) = results.to_model(file)?;
        let violation = model.constraints().max_violation(&params);
        if violation > 1e-9 {
            return Err(Error::input(
                Place::file(file).at_field("parameters"),
                format!(
                    "the values break the error model's constraints by {violation:.3e} \
                     (a truth must satisfy them)"
                ),
            ));
        }
        Truth::with_free_tracker(model, params)
    }

    pub(super) fn with_free_tracker(model: Model, params: Vec<f64>) -> Result<Truth> {
        let mut spec = model.spec().clone();
        spec.tracker = TrackerModelSpec {
            range_offset: spec.tracker.range_offset,
            ..TrackerModelSpec::default()
        };
        let model = Model::new(model.machine().clone(), spec)?;
        Ok(Truth { model, params })
    }

    /// The truth as a results file.
    pub fn to_results(&self) -> Result<ResultsFile> {
        ResultsFile::from_model(&self.model, &self.params)
    }

    /// The true tracker pose (x, y, z mm; rx, ry, rz rad).
    pub fn tracker_pose(&self) -> [f64; TRACKER_DOF] {
        let s = self.model.tracker_start();
        std::array::from_fn(|k| self.params[s + k])
    }

    /// The truth with harmonics `order+1 ..= max_order` added to every periodic error, each of
    /// amplitude `translation_mm` or `rotation_rad` and a phase drawn from `rng`.
    pub(super) fn with_harmonics(
        &self,
        max_order: usize,
        translation_mm: f64,
        rotation_rad: f64,
        rng: &mut Rng,
    ) -> Result<Truth> {
        let mut spec = self.model.spec().clone();
        let mut periodic = false;
        for entry in &mut spec.errors {
            if entry.basis.is_some_and(BasisKind::is_periodic) {
                entry.order = Some(entry.order.unwrap_or(1).max(max_order));
                periodic = true;
            }
        }
        if !periodic {
            return Err(Error::input(
                Place::file("effects").at_field("rotary-harmonics"),
                "the true errors have no periodic (Fourier or sine) rotary-axis error to extend",
            ));
        }
        let model = Model::new(self.model.machine().clone(), spec)?;
        let mut p = model.initial_params();
        for (info, &v) in self.model.params().iter().zip(&self.params) {
            let idx = model
                .param_index(&info.name)
                .expect("raising an order keeps every parameter");
            p[idx] = v;
        }
        for t in model.terms() {
            let kind = t.basis.kind();
            if !kind.is_periodic() {
                continue;
            }
            let before = self.model.term(t.id).map_or(0, |old| old.basis.degree());
            let amp = if t.id.unit() == Unit::Mm {
                translation_mm
            } else {
                rotation_rad
            };
            for h in before + 1..=t.basis.degree() {
                let phase = PI * (2.0 * rng.uniform() - 1.0);
                let idx = |suffix: String| {
                    model
                        .param_index(&format!("{}.{suffix}", t.id))
                        .expect("harmonic parameter exists")
                };
                // A·sin(hθ + φ) = A cos φ · sin hθ + A sin φ · cos hθ.
                if kind == BasisKind::Fourier {
                    p[idx(format!("a{h}"))] = amp * phase.cos();
                    p[idx(format!("b{h}"))] = amp * phase.sin();
                } else {
                    p[idx(format!("a{h}"))] = amp;
                    p[idx(format!("phi{h}"))] = phase;
                }
            }
        }
        Ok(Truth { model, params: p })
    }
}

/// Largest |value| of an error over its axis' travel (sampled).
pub(super) fn peak_value(model: &Model, id: ErrorId, p: &[f64]) -> f64 {
    let term = model.term(id).expect("the error is modelled");
    let ax = &model.machine().axes()[term.axis];
    (0..=PEAK_SAMPLES)
        .map(|i| {
            let u = ax.min + (ax.max - ax.min) * i as f64 / PEAK_SAMPLES as f64;
            model.error_value(id, u, p).map_or(0.0, f64::abs)
        })
        .fold(0.0, f64::max)
}

/// Moves `p` to the nearest point (least change) that satisfies the model's constraints.
pub(super) fn project(model: &Model, p: &mut [f64]) -> Result<()> {
    use nalgebra::{DMatrix, DVector};
    let n = p.len();
    let rows = &model.constraints().rows;
    if rows.is_empty() {
        return Ok(());
    }
    let (a, b) = model.constraints().dense(n);
    let a = DMatrix::from_row_slice(rows.len(), n, &a);
    let r = &a * DVector::from_column_slice(p) - DVector::from_column_slice(&b);
    let aat = &a * a.transpose();
    let svd = aat.svd(true, true);
    let eps = 1e-12 * svd.singular_values.max();
    let lambda = svd.solve(&r, eps).map_err(|e| Error::Singular {
        message: format!("projecting onto the constraints: {e}"),
    })?;
    let correction = a.transpose() * lambda;
    for (v, c) in p.iter_mut().zip(correction.iter()) {
        *v -= c;
    }
    // Held parameters take their values exactly, not to rounding.
    for row in rows.iter().filter(|r| r.kind == ConstraintKind::Fixed) {
        if let [(j, c)] = row.coeffs.as_slice() {
            p[*j] = row.rhs / c;
        }
    }
    let violation = model.constraints().max_violation(p);
    if violation > 1e-9 {
        return Err(Error::ContradictoryConstraints {
            message: format!(
                "the error model's constraints contradict each other (left unsatisfied by \
                 {violation:.3e})"
            ),
        });
    }
    Ok(())
}
