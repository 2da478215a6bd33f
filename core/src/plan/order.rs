//! The measuring order of a plan: poses in a sequence that keeps time from aliasing onto any
//! axis, with a reference pose measured again at intervals.
//!
//! A thermal drift of the machine or the tracker grows with time. Measured in grid order (the
//! first axis slowest), time follows that axis and part of the drift is indistinguishable from its
//! errors (issue 5's finding). [`sequence`] draws random orders of the poses (seeded) and keeps
//! the one whose time is least correlated with any axis function ([`aliasing`]: each linear
//! axis' position and its square, each rotary axis' cosine and sine); repeated visits of one
//! reference pose, spread evenly from the first measurement to the last, let the noise and the
//! drift be estimated from the data (`diagnose`'s repeat check).

use super::Step;
use crate::machine::{Commands, Machine};
use crate::random::Rng;

/// One visit of a pose: the reflectors measured there, in order.
#[derive(Clone, Debug, PartialEq)]
pub struct Visit {
    /// Index into the plan's positions.
    pub position: usize,
    /// Reflector indices measured at this visit.
    pub reflectors: Vec<usize>,
}

/// The largest correlation, in absolute value, between the time of a measurement (its place in
/// the sequence) and a function of the axes over the sequence: each linear axis' position and
/// its square, each rotary axis' cosine and sine. With the function's name. 0 for a sequence
/// of fewer than 3 measurements or axes that do not move.
///
/// ```
/// use volver_core::machine::Machine;
/// use volver_core::plan::{Plan, order};
/// let m = Machine::default_xcfz();
/// let p = Plan::preset(&m, "test4").unwrap();
/// // In grid order time is X (the slowest axis).
/// let (r, what) = order::aliasing(&m, &p.positions, &p.steps());
/// assert!(r > 0.95 && what == "X", "{r} {what}");
/// ```
pub fn aliasing(machine: &Machine, positions: &[Commands], steps: &[Step]) -> (f64, String) {
    let n = steps.len();
    if n < 3 {
        return (0.0, String::new());
    }
    let t: Vec<f64> = (0..n).map(|i| i as f64).collect();
    let mut worst = (0.0, String::new());
    for (k, ax) in machine.axes().iter().enumerate() {
        let value = |s: &Step| positions[s.position].0[k];
        let span = (ax.max - ax.min).abs().max(f64::MIN_POSITIVE);
        let features: Vec<Feature> = if ax.axis.is_rotary() {
            vec![
                (format!("cos {}", ax.axis), Box::new(f64::cos)),
                (format!("sin {}", ax.axis), Box::new(f64::sin)),
            ]
        } else {
            let min = ax.min;
            vec![
                (ax.axis.to_string(), Box::new(move |u| (u - min) / span)),
                (
                    format!("{}²", ax.axis),
                    Box::new(move |u| ((u - min) / span).powi(2)),
                ),
            ]
        };
        for (name, f) in features {
            let y: Vec<f64> = steps.iter().map(|s| f(value(s))).collect();
            let r = correlation(&t, &y).abs();
            if r > worst.0 {
                worst = (r, name);
            }
        }
    }
    worst
}

/// A named function of an axis position.
type Feature = (String, Box<dyn Fn(f64) -> f64>);

/// Pearson's correlation of two series (0 when either is constant).
fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    if saa <= 0.0 || sbb <= crate::units::TINY {
        0.0
    } else {
        sab / (saa * sbb).sqrt()
    }
}

/// A measuring sequence of `visits`: of `draws` random orders (seeded by `seed`), the one with
/// the smallest [`aliasing`], with `reference` visited first, last, and `repeats` times more
/// at even intervals in between. Returns the steps and the aliasing of the chosen order.
///
/// ```
/// use volver_core::machine::Machine;
/// use volver_core::plan::{Plan, order::{self, Visit}};
/// let m = Machine::default_xcfz();
/// let p = Plan::preset(&m, "test4").unwrap();
/// let visits: Vec<Visit> = (1..p.positions.len())
///     .map(|position| Visit { position, reflectors: vec![0, 1] })
///     .collect();
/// let reference = Visit { position: 0, reflectors: vec![0, 1] };
/// let (steps, r) = order::sequence(&m, &p.positions, visits, Some((reference, 8)), 7, 20);
/// assert_eq!(steps.len(), 2 * (p.positions.len() - 1) + 2 * 10);
/// assert!(r < 0.1, "time aliases onto an axis: {r}");
/// ```
pub fn sequence(
    machine: &Machine,
    positions: &[Commands],
    visits: Vec<Visit>,
    reference: Option<(Visit, usize)>,
    seed: u64,
    draws: usize,
) -> (Vec<Step>, f64) {
    let mut rng = Rng::new(seed);
    let mut best: Option<(Vec<Step>, f64)> = None;
    for _ in 0..draws.max(1) {
        let mut order = visits.clone();
        for i in (1..order.len()).rev() {
            let j = ((rng.uniform() * (i + 1) as f64) as usize).min(i);
            order.swap(i, j);
        }
        let steps = with_reference(order, reference.as_ref());
        let (r, _) = aliasing(machine, positions, &steps);
        if best.as_ref().is_none_or(|b| r < b.1) {
            best = Some((steps, r));
        }
    }
    best.unwrap_or_default()
}

/// The steps of `order` with the reference visited first, last and `repeats` times at even
/// intervals in between.
fn with_reference(order: Vec<Visit>, reference: Option<&(Visit, usize)>) -> Vec<Step> {
    let steps_of = |v: &Visit| -> Vec<Step> {
        v.reflectors
            .iter()
            .map(|&reflector| Step {
                position: v.position,
                reflector,
            })
            .collect()
    };
    let Some((reference, repeats)) = reference else {
        return order.iter().flat_map(steps_of).collect();
    };
    let n = order.len();
    let gaps = repeats + 1;
    let mut out = steps_of(reference);
    for (i, v) in order.iter().enumerate() {
        out.extend(steps_of(v));
        // After visit i, a reference when i + 1 crosses a multiple of n / gaps.
        let before = (i * gaps) / n.max(1);
        let after = ((i + 1) * gaps) / n.max(1);
        if after > before && i + 1 < n {
            out.extend(steps_of(reference));
        }
    }
    out.extend(steps_of(reference));
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::Plan;

    #[test]
    fn references_are_spread_and_the_order_is_reproducible() {
        let m = Machine::default_xcfz();
        let p = Plan::preset(&m, "test3").unwrap();
        let visits: Vec<Visit> = (1..p.positions.len())
            .map(|position| Visit {
                position,
                reflectors: vec![0],
            })
            .collect();
        let reference = Visit {
            position: 0,
            reflectors: vec![0, 1],
        };
        let (a, ra) = sequence(
            &m,
            &p.positions,
            visits.clone(),
            Some((reference.clone(), 4)),
            3,
            10,
        );
        let (b, rb) = sequence(
            &m,
            &p.positions,
            visits.clone(),
            Some((reference, 4)),
            3,
            10,
        );
        assert_eq!((a.clone(), ra), (b, rb));
        // Every visit once, the reference 6 times (first, last, 4 between) at gaps within one
        // visit of even.
        let at: Vec<usize> = a
            .iter()
            .enumerate()
            .filter(|(_, s)| s.position == 0 && s.reflector == 1)
            .map(|(i, _)| i)
            .collect();
        assert_eq!(at.len(), 6);
        assert_eq!(a.len(), visits.len() + 12);
        let gaps: Vec<usize> = at.windows(2).map(|w| w[1] - w[0]).collect();
        let (lo, hi) = (gaps.iter().min().unwrap(), gaps.iter().max().unwrap());
        assert!(hi - lo <= 3, "{gaps:?}");
        // A different seed, a different order.
        let (c, _) = sequence(&m, &p.positions, visits, None, 4, 1);
        assert_ne!(c, a);
    }
}
