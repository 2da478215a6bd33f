//! The effects outside the ISO 230 model at a point: their values, their derivatives with
//! respect to their parameters, and where they enter the chain's [`PointErrors`].

use super::*;
use crate::units::{PPM, S_PER_H};

/// A field's variables, its functions' values at a point for each (a second set for a pair),
/// and how many the first has.
type FieldValues<S> = ([FieldVar; 2], [S; 4], [S; 4], usize);

/// A ratio in one ppm (`1e-6`, bit for bit).
const RATIO_PER_PPM: f64 = 1.0 / PPM;

/// Where the effects are evaluated: the point's commands (internal units), reflector, station
/// and time (s), the field functions computed last, and where ∂value/∂p goes when asked.
struct EffectPoint<'a, S> {
    /// Commanded positions, chain order (mm, rad).
    commands: &'a [S; MAX_AXES],
    /// The reflector measured.
    reflector: usize,
    /// The station measuring.
    station: usize,
    /// The time stamp (s).
    t_s: f64,
    /// Each axis' direction of approach.
    approach: crate::approach::Approach,
    /// The last field's functions (shared by its three components).
    field: Option<FieldValues<S>>,
    /// ∂value/∂p by parameter, when asked.
    jac: Option<&'a mut [f64]>,
}

impl<S> EffectPoint<'_, S> {
    /// Writes ∂value/∂p of parameter `p`, when asked.
    #[inline]
    fn set(&mut self, p: usize, g: f64) {
        if let Some(jac) = self.jac.as_deref_mut() {
            jac[p] = g;
        }
    }
}

impl Model {
    /// Places the effects' values (`value(i)` for the i-th effect) into [`PointErrors`].
    #[inline]
    pub(super) fn place_effects<S: Real>(
        &self,
        e: &mut PointErrors<S>,
        value: impl Fn(usize) -> S,
    ) {
        for (i, (slot, _)) in self.effects.iter().enumerate() {
            let v = value(i);
            match *slot {
                EffectSlot::Drift(c) | EffectSlot::Field { c, .. } => e.tool_shift[c] += v,
                EffectSlot::Reflector { c, .. } => e.reflector_delta[c] += v,
                EffectSlot::RangeScale => e.range_scale = v,
                EffectSlot::Screw { k, dir, .. }
                | EffectSlot::ThermalScale { k, dir }
                | EffectSlot::Reversal { k, dir, .. } => e.component[k][dir] += v,
                EffectSlot::LocationDrift { k, c } => e.location[k][c] += v,
                EffectSlot::TrackerDrift(k) => e.tracker[k] += v,
                EffectSlot::StationDrift { c, .. } => e.tracker[c] += v,
            }
        }
    }

    /// Whether the model needs the measurements' time stamps (thermal drift, scale growth,
    /// location drift, a field over `t`).
    pub fn needs_time(&self) -> bool {
        self.effects.iter().any(|(slot, _)| match slot {
            EffectSlot::Drift(_) | EffectSlot::ThermalScale { .. } => true,
            EffectSlot::LocationDrift { .. }
            | EffectSlot::TrackerDrift(_)
            | EffectSlot::StationDrift { .. } => true,
            EffectSlot::Field { vars, pair, .. } => {
                vars[0] == FieldVar::Time || (*pair && vars[1] == FieldVar::Time)
            }
            _ => false,
        })
    }

    /// The functions of a field variable at a point into `out` (its count returned).
    #[inline]
    fn field_functions<S: Real>(
        &self,
        var: FieldVar,
        commands: &[S; MAX_AXES],
        t_h: f64,
        out: &mut [S; 4],
    ) -> usize {
        match var {
            FieldVar::Linear(k) => {
                let x = self.machine.axes()[k].normalise_at(commands[k]);
                let x2 = x * x;
                out[0] = x;
                out[1] = (x2 * 3.0 - 1.0) * 0.5;
                out[2] = (x2 * 5.0 - 3.0) * x * 0.5;
                3
            }
            FieldVar::Periodic(k) => {
                let (s1, c1) = commands[k].sin_cos();
                let (s2, c2) = (commands[k] * 2.0).sin_cos();
                *out = [c1, s1, c2, s2];
                4
            }
            FieldVar::Time => {
                out[0] = S::from(t_h);
                out[1] = S::from(t_h * t_h);
                2
            }
        }
    }

    /// Effect values at a point into `vals` (slots after the tracker's) and, when `jac` is
    /// given, each effect parameter's ∂value/∂p into `jac[parameter]`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn effect_values<S: Real>(
        &self,
        commands: &[S; MAX_AXES],
        reflector: usize,
        station: usize,
        state: PointState,
        params: &[f64],
        vals: &mut [S],
        jac: Option<&mut [f64]>,
    ) {
        let base = self.terms.len() + TRACKER_DOF;
        let mut at = EffectPoint {
            commands,
            reflector,
            station,
            t_s: state.t_s,
            approach: state.approach,
            field: None,
            jac,
        };
        for (i, &(slot, j)) in self.effects.iter().enumerate() {
            vals[base + i] = self.effect_value(slot, j, params, &mut at);
        }
    }

    /// The value of the effect in `slot`, its first parameter `j`, at `at` (whose ∂value/∂p it
    /// writes when asked).
    #[inline]
    fn effect_value<S: Real>(
        &self,
        slot: EffectSlot,
        j: usize,
        params: &[f64],
        at: &mut EffectPoint<S>,
    ) -> S {
        match slot {
            EffectSlot::Drift(_)
            | EffectSlot::LocationDrift { .. }
            | EffectSlot::TrackerDrift(_) => {
                let t_h = at.t_s / S_PER_H;
                at.set(j, t_h);
                S::from(params[j] * t_h)
            }
            EffectSlot::Reflector { reflector: r, .. } => {
                let on = if r == at.reflector { 1.0 } else { 0.0 };
                at.set(j, on);
                S::from(params[j] * on)
            }
            EffectSlot::RangeScale => {
                at.set(j, RATIO_PER_PPM);
                S::from(params[j] * RATIO_PER_PPM)
            }
            EffectSlot::Screw {
                k,
                period_mm,
                reference,
                ..
            } => {
                let phase = (at.commands[k] - reference) * (2.0 * std::f64::consts::PI) / period_mm;
                let (sn, cs) = phase.sin_cos();
                at.set(j, sn.re());
                at.set(j + 1, cs.re());
                sn * params[j] + cs * params[j + 1]
            }
            EffectSlot::ThermalScale { k, .. } => {
                let g = RATIO_PER_PPM * at.t_s / S_PER_H;
                at.set(j, at.commands[k].re() * g);
                at.commands[k] * (params[j] * g)
            }
            EffectSlot::StationDrift { station: s, .. } => {
                let t_h = if s == at.station {
                    at.t_s / S_PER_H
                } else {
                    0.0
                };
                at.set(j, t_h);
                S::from(params[j] * t_h)
            }
            EffectSlot::Field { vars, pair, .. } => self.field_value(vars, pair, j, params, at),
            EffectSlot::Reversal { k, degree, .. } => self.reversal_value(k, degree, j, params, at),
        }
    }

    /// The reversal value B (mm, or rad for a rotary axis) of chain axis `k` at `position`
    /// (internal units): ISO 230-2's, the deviation of the tool relative to the workpiece along
    /// the command on forward approach minus the one on reverse approach (on a workpiece-side
    /// axis the axis' own positioning error reverses by −B), `None` when the model has no
    /// reversal of that axis. When `grad` is given
    /// (one value per parameter), ∂B/∂p is written there (zero for every other parameter).
    ///
    /// # Panics
    /// When `params` or `grad` is not one value per parameter.
    pub fn reversal_at(
        &self,
        k: usize,
        position: f64,
        params: &[f64],
        grad: Option<&mut [f64]>,
    ) -> Option<f64> {
        self.check_len(params);
        let &(slot, j) = self
            .effects
            .iter()
            .find(|(s, _)| matches!(s, EffectSlot::Reversal { k: a, .. } if *a == k))?;
        let EffectSlot::Reversal { degree, .. } = slot else {
            return None;
        };
        let mut commands = [0.0; MAX_AXES];
        commands[k] = position;
        let mut approach = crate::approach::Approach::UNKNOWN;
        approach.0[k] = 1;
        let mut jac = grad;
        if let Some(g) = jac.as_deref_mut() {
            assert_eq!(g.len(), params.len(), "one gradient value per parameter");
            g.fill(0.0);
        }
        let mut at = EffectPoint {
            commands: &commands,
            reflector: usize::MAX,
            station: 0,
            t_s: 0.0,
            approach,
            field: None,
            jac: jac.as_deref_mut(),
        };
        // The forward approach's value is +B/2.
        // The forward approach adds σ·B/2 to the positioning error (σ the axis' side).
        let sigma = self.machine.axes()[k].side.sign();
        let half = self.reversal_value(k, degree, j, params, &mut at) * sigma;
        if let Some(g) = jac {
            g[j..=j + degree].iter_mut().for_each(|v| *v *= 2.0 * sigma);
        }
        Some(2.0 * half)
    }

    /// The axes with a reversal in the model: (chain axis, its parameters).
    pub fn reversal_axes(&self) -> Vec<(usize, Range<usize>)> {
        self.effects
            .iter()
            .filter_map(|&(slot, j)| match slot {
                EffectSlot::Reversal { k, degree, .. } => Some((k, j..j + degree + 1)),
                _ => None,
            })
            .collect()
    }

    /// The value the reversal of chain axis `k` adds to its positioning error at a point:
    /// `σ·s/2 · B(u)`, `s` the axis' direction of approach (+1, −1, 0), `B(u) = Σ_q b_q P_q(û)`
    /// with `b_q = params[j + q]` and `P_q` the Legendre polynomials of the position normalised
    /// over the travel (P₀ = 1), and `σ` the axis' side ([`crate::chain::Side::sign`]): B is
    /// ISO 230-2's, a deviation of the tool relative to the workpiece along the command, which
    /// a workpiece-side axis' error moves the other way (eq. 6: `−x + EXX`).
    #[inline]
    fn reversal_value<S: Real>(
        &self,
        k: usize,
        degree: usize,
        j: usize,
        params: &[f64],
        at: &mut EffectPoint<S>,
    ) -> S {
        let half = 0.5 * at.approach.sign(k) * self.machine.axes()[k].side.sign();
        let x = if degree > 0 {
            self.machine.axes()[k].normalise_at(at.commands[k])
        } else {
            S::zero()
        };
        let (mut p0, mut p1) = (S::one(), x);
        let mut v = S::zero();
        for q in 0..=degree {
            let phi = match q {
                0 => S::one(),
                1 => x,
                _ => {
                    // (q)P_q = (2q − 1) x P_{q−1} − (q − 1) P_{q−2}
                    let p = (x * p1 * (2 * q - 1) as f64 - p0 * (q - 1) as f64) * (1.0 / q as f64);
                    p0 = p1;
                    p1 = p;
                    p
                }
            } * half;
            at.set(j + q, phi.re());
            v += phi * params[j + q];
        }
        v
    }

    /// The value of one component of an error field over `vars` (`pair`: two distinct
    /// variables; else one, held twice), its first parameter `j`. A field's functions are
    /// computed once for its three components' slots (which follow one another).
    #[inline]
    fn field_value<S: Real>(
        &self,
        vars: [FieldVar; 2],
        pair: bool,
        j: usize,
        params: &[f64],
        at: &mut EffectPoint<S>,
    ) -> S {
        let (a, b, na) = match at.field {
            Some((v, a, b, na)) if v == vars => (a, b, na),
            _ => {
                let t_h = at.t_s / S_PER_H;
                let (mut a, mut b) = ([S::zero(); 4], [S::zero(); 4]);
                let na = self.field_functions(vars[0], at.commands, t_h, &mut a);
                if pair {
                    self.field_functions(vars[1], at.commands, t_h, &mut b);
                }
                at.field = Some((vars, a, b, na));
                (a, b, na)
            }
        };
        let mut v = S::zero();
        if pair {
            for (q, (x, y)) in [(0, 0), (0, 1), (1, 0), (1, 1)].into_iter().enumerate() {
                let phi = a[x] * b[y];
                at.set(j + q, phi.re());
                v += phi * params[j + q];
            }
        } else {
            for (q, phi) in a[..na].iter().enumerate() {
                at.set(j + q, phi.re());
                v += *phi * params[j + q];
            }
        }
        v
    }
}
