//! The residuals split by the direction of approach of each axis: where a reversal (ISO 230-2's
//! B: backlash, lost motion; [`crate::approach`]) the model lacks shows.
//!
//! For chain axis `k`, each point's residual is read along what the axis' positioning error
//! moves at that point: `u_i`, the derivative of the point the station observes with respect to
//! the positioning error (EXX for a linear axis, in mm per mm: the axis' own direction; ECC for
//! a rotary one, in mm per rad: the tangent at the reflector times its distance from the
//! axis), taken on the nominal chain with the fitted pose of the point's station. The points
//! that arrived moving forward (+) and those that arrived moving in reverse (−) each give the
//! least-squares common positioning error that their residuals show beyond the model,
//! `a = Σ uᵢ·(mᵢ − pᵢ) / Σ |uᵢ|²` (µm, or µrad for a rotary axis; `m` measured, `p` predicted),
//! (times the axis' side sign, −1 for an axis that moves the workpiece: the tool's deviation
//! relative to the workpiece along the command, as ISO 230-2 reads it), with its standard
//! error from the points' own scatter (`√(Σ (uᵢ·(mᵢ − pᵢ) − |uᵢ|² a)²) /
//! Σ |uᵢ|²`, scaled by `√(n/(n − 1))`: no noise model is assumed). A reversal B the model lacks
//! puts `+B/2` on one side and `−B/2` on the other; but the direction also depends on the
//! position (an axis reaches its lowest position only moving in reverse, its highest only
//! forward: in a random order the share of forward arrivals grows along the travel), and the
//! model's positioning error takes that part of the reversal. What no function of the position
//! can take is the **difference at the same position**: forward less reverse at each position
//! reached from both sides, weighed by `W₊W₋/(W₊ + W₋)` (`W` a side's `Σ|uᵢ|²`) over those
//! positions. That is the reversal value the residuals show, in the sign of the model's
//! `reversal.X.b` ([`DirectionSplit::difference`]); its standard error comes from each point's
//! deviation from its side's value at its position. Points measured before their axis first
//! moved ([`before_first_move`]: their direction is assumed or unknown) are left out. A range alone counts by its line of sight.
//!
//! **What the data can separate** ([`coverage`]): the reversal of an axis moves the points by
//! `s·B/2` (`s` the direction), which at one position is a constant and so is the axis'
//! positioning error there. Only the positions reached from both sides tell the two apart; when
//! every position is reached from one side only, a reversal is a step of the positioning error
//! between the positions reached from + and those reached from −, separated from it by the
//! shape the model gives that error (not by the data), and when every point arrives from one
//! side it is a constant offset of the positioning error, which the model's constants and the
//! tracker's pose absorb.
//!
//! ```
//! use volver_core::diagnose::{by_direction, coverage};
//! use volver_core::measure::MeasurementSet;
//! use volver_core::model::{ErrorModelSpec, Model};
//! use volver_core::problem::{Problem, Residuals};
//! let plain = Model::default_xcfz();
//! let spec = ErrorModelSpec::from_toml_str("[effects]\nreversal = [\"X\"]", "m.toml").unwrap();
//! let reversing = Model::new(plain.machine().clone(), spec).unwrap();
//! let mut truth = reversing.initial_params();
//! truth[reversing.param_index("reversal.X.b").unwrap()] = 0.008; // B = 8 µm
//! // X at 0 and 1400 mm, each reached from both sides (stated by an approach_X column).
//! let mut rows = String::from("reflector,X,C,Z,meas_x,meas_y,meas_z,approach_X\n");
//! let visits = [(0, 1), (1400, 1), (0, -1), (1400, -1), (0, 1), (1400, -1)];
//! for (i, (x, s)) in visits.iter().enumerate() {
//!     rows += &format!("R1,{x},90,0,0,0,{i},{s}\n"); // placeholders, replaced below
//! }
//! let mut data = MeasurementSet::from_csv_str(plain.machine(), &rows, "inline.csv").unwrap();
//! for m in &mut data.points {
//!     m.measured = reversing.observe(m, &truth);
//! }
//! // The model without the reversal, at the truth's other values (all zero here).
//! let problem = Problem::new(&plain, &data).unwrap();
//! let p = plain.initial_params();
//! let split = &by_direction(&problem, &p, &problem.residuals(&p))[0];
//! // The first point, measured before X first moved, is left out of the split.
//! assert_eq!((split.axis, split.unit, split.forward.count, split.reverse.count), (0, "µm", 2, 3));
//! assert!((split.difference() - 8.0).abs() < 1e-6, "{}", split.difference());
//! // Both positions of X were reached from both sides: the data separate it there.
//! let c = coverage(plain.machine(), &data.points, 0);
//! assert_eq!((c.positions, c.positions_both, c.forward, c.reverse), (2, 2, 3, 3));
//! assert!(c.separable());
//! ```

use crate::kinematics::{PointErrors, TRACKER_DOF, predict_with_errors_jacobian};
use crate::machine::Machine;
use crate::measure::{Measurement, Observation, position_key};
use crate::problem::Problem;
use crate::units::{UM_PER_MM, URAD_PER_RAD};
use std::collections::BTreeMap;

/// How the points of one axis arrived: the counts by direction, and its distinct positions
/// (a rotary axis' a turn apart being one) with how many of them were reached from both sides.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Coverage {
    /// Points that arrived moving in the axis' positive direction.
    pub forward: usize,
    /// Points that arrived moving in its negative direction.
    pub reverse: usize,
    /// Points with no known direction (0: an axis that never moves, or a file's 0).
    pub unknown: usize,
    /// Distinct positions of the axis.
    pub positions: usize,
    /// Positions with points reached from each side.
    pub positions_both: usize,
}

impl Coverage {
    /// Whether some points arrived from each side: a reversal of the axis moves the points
    /// differently from its positioning error (the data can see it).
    pub fn both_sides(&self) -> bool {
        self.forward > 0 && self.reverse > 0
    }

    /// Whether the data separate a reversal of the axis from its positioning error by
    /// themselves: some position reached from both sides.
    pub fn separable(&self) -> bool {
        self.positions_both > 0
    }
}

/// Which of `points` were measured before chain axis `k` first moved, in measuring order
/// ([`crate::measure::measuring_order`]): their direction on that axis is an assumption (the
/// first move's, [`crate::approach`]) or unknown, so they show nothing of a reversal by
/// themselves and no position counts as reached from both sides through them.
pub fn before_first_move(points: &[Measurement], k: usize) -> Vec<bool> {
    let order = crate::measure::measuring_order(points);
    let mut out = vec![false; points.len()];
    let Some(&first) = order.first() else {
        return out;
    };
    let start = points[first].commands.0[k];
    for &i in &order {
        if (points[i].commands.0[k] - start).abs() > crate::approach::MOVE_TOLERANCE {
            break;
        }
        out[i] = true;
    }
    out
}

/// How the `points` arrived at chain axis `k` of `machine` ([`Coverage`]); the points measured
/// before the axis first moved ([`before_first_move`]) count by their side but reach no
/// position "from both sides".
pub fn coverage(machine: &Machine, points: &[Measurement], k: usize) -> Coverage {
    let ax = &machine.axes()[k];
    let mut out = Coverage::default();
    let mut sides: BTreeMap<i64, (bool, bool)> = BTreeMap::new();
    let assumed = before_first_move(points, k);
    for (i, p) in points.iter().enumerate() {
        let mut ignored = (false, false);
        let side = if assumed[i] {
            &mut ignored
        } else {
            sides.entry(position_key(ax, p.commands.0[k])).or_default()
        };
        match p.approach.0[k] {
            1 => {
                out.forward += 1;
                side.0 = true;
            }
            -1 => {
                out.reverse += 1;
                side.1 = true;
            }
            _ => out.unknown += 1,
        }
    }
    let mut all: Vec<i64> = points
        .iter()
        .map(|p| position_key(ax, p.commands.0[k]))
        .collect();
    all.sort_unstable();
    all.dedup();
    out.positions = all.len();
    out.positions_both = sides.values().filter(|s| s.0 && s.1).count();
    out
}

/// The residuals of the points that arrived at an axis from one side, read along its
/// positioning error (see the module documentation).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SideMean {
    /// The points.
    pub count: usize,
    /// The common positioning error their measurements show beyond the model (measured −
    /// predicted; µm for a linear axis, µrad for a rotary one).
    pub mean: f64,
    /// Its standard error (same unit), from the points' scatter.
    pub standard_error: f64,
}

/// The residuals of one axis split by direction of approach ([`by_direction`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DirectionSplit {
    /// The axis (its index in the chain).
    pub axis: usize,
    /// `µm` (a linear axis) or `µrad` (a rotary one).
    pub unit: &'static str,
    /// All the points that arrived moving forward (+).
    pub forward: SideMean,
    /// All the points that arrived moving in reverse (−).
    pub reverse: SideMean,
    /// Forward less reverse at the same position, over the positions reached from both sides
    /// (µm or µrad): the reversal value the residuals show, in the sign of the model's
    /// `reversal.X.b`; `None` when no position was reached from both sides.
    pub within: Option<f64>,
    /// Its standard error (same unit), from the points' scatter.
    pub within_standard_error: f64,
    /// How the points arrived at the axis.
    pub coverage: Coverage,
}

impl DirectionSplit {
    /// The reversal value the residuals show (µm or µrad): forward less reverse at the same
    /// position ([`DirectionSplit::within`]), else over all the points (which then mixes a
    /// reversal with the positioning error).
    pub fn difference(&self) -> f64 {
        self.within.unwrap_or(self.forward.mean - self.reverse.mean)
    }

    /// The standard error of [`DirectionSplit::difference`].
    pub fn standard_error(&self) -> f64 {
        match self.within {
            Some(_) => self.within_standard_error,
            None => self
                .forward
                .standard_error
                .hypot(self.reverse.standard_error),
        }
    }

    /// How many standard errors the difference lies from zero.
    pub fn z(&self) -> f64 {
        self.difference() / self.standard_error().max(f64::MIN_POSITIVE)
    }
}

/// The fewest points on each side an axis needs for its split.
pub const MIN_SIDE_POINTS: usize = 2;

/// One point's part in an axis' split: its position, its side (0 forward, 1 reverse), and its
/// residual read along the axis' positioning error, `(−u·r, |u|²)` (measured − predicted).
#[derive(Clone, Copy)]
struct Term {
    position: i64,
    side: usize,
    dot: f64,
    w: f64,
}

/// The least-squares common value of `terms` (`Σ dot / Σ w`) and its standard error from their
/// scatter.
fn side_mean(terms: &[&Term], scale: f64) -> SideMean {
    let w: f64 = terms.iter().map(|t| t.w).sum();
    if terms.is_empty() || w <= 0.0 {
        return SideMean::default();
    }
    let a = terms.iter().map(|t| t.dot).sum::<f64>() / w;
    let n = terms.len() as f64;
    let spread = terms
        .iter()
        .map(|t| (t.dot - t.w * a).powi(2))
        .sum::<f64>()
        .sqrt();
    SideMean {
        count: terms.len(),
        mean: a * scale,
        standard_error: spread / w * (n / (n - 1.0).max(1.0)).sqrt() * scale,
    }
}

/// Forward less reverse at the same position, over the positions with points from both sides:
/// each position's difference of its two sides' common values, weighed by `W₊W₋/(W₊ + W₋)`
/// (`W` a side's `Σ|u|²`: the inverse variance for equal noise); its standard error from each
/// point's deviation from its side's value there. `None` without such a position.
fn within_positions(terms: &[Term]) -> Option<(f64, f64)> {
    // Per position: Σ dot and Σ w of each side.
    let mut cells: BTreeMap<i64, [(f64, f64); 2]> = BTreeMap::new();
    for t in terms {
        let c = &mut cells.entry(t.position).or_default()[t.side];
        c.0 += t.dot;
        c.1 += t.w;
    }
    cells.retain(|_, c| c[0].1 > 0.0 && c[1].1 > 0.0);
    let weight = |c: &[(f64, f64); 2]| c[0].1 * c[1].1 / (c[0].1 + c[1].1);
    let total: f64 = cells.values().map(weight).sum();
    if cells.is_empty() || total <= 0.0 {
        return None;
    }
    let value = |c: &[(f64, f64); 2], side: usize| c[side].0 / c[side].1;
    let d = cells
        .values()
        .map(|c| weight(c) * (value(c, 0) - value(c, 1)))
        .sum::<f64>()
        / total;
    let (mut var, mut n) = (0.0, 0usize);
    for t in terms {
        let Some(c) = cells.get(&t.position) else {
            continue;
        };
        let sign = if t.side == 0 { 1.0 } else { -1.0 };
        let coefficient = sign * weight(c) / total / c[t.side].1;
        var += (coefficient * (t.dot - t.w * value(c, t.side))).powi(2);
        n += 1;
    }
    // Degrees of freedom: the points less the two values of each position.
    let dof = n.saturating_sub(2 * cells.len()).max(1) as f64;
    Some((d, (var * n as f64 / dof).sqrt()))
}

/// The residuals `residuals` of `problem`'s fit at `params` split by direction of approach, for
/// every axis with at least [`MIN_SIDE_POINTS`] points arriving from each side, in chain order
/// (see the module documentation).
pub fn by_direction(
    problem: &Problem,
    params: &[f64],
    residuals: &[[f64; 3]],
) -> Vec<DirectionSplit> {
    let machine = problem.model().machine();
    let points = &problem.data().points;
    let axes: Vec<(usize, Coverage)> = (0..machine.axes().len())
        .map(|k| (k, coverage(machine, points, k)))
        .filter(|(_, c)| c.forward >= MIN_SIDE_POINTS && c.reverse >= MIN_SIDE_POINTS)
        .collect();
    if axes.is_empty() {
        return Vec::new();
    }
    let terms = terms(problem, params, residuals, &axes);
    axes.iter()
        .zip(&terms)
        .map(|(&(k, coverage), terms)| {
            let rotary = machine.axes()[k].axis.is_rotary();
            let (scale, unit) = if rotary {
                (URAD_PER_RAD, "µrad")
            } else {
                (UM_PER_MM, "µm")
            };
            let side = |s: usize| -> Vec<&Term> { terms.iter().filter(|t| t.side == s).collect() };
            let within = within_positions(terms);
            DirectionSplit {
                axis: k,
                unit,
                forward: side_mean(&side(0), scale),
                reverse: side_mean(&side(1), scale),
                within: within.map(|w| w.0 * scale),
                within_standard_error: within.map_or(0.0, |w| w.1 * scale),
                coverage,
            }
        })
        .collect()
}

/// Each point's [`Term`] for each of `axes` (its points with a known direction).
fn terms(
    problem: &Problem,
    params: &[f64],
    residuals: &[[f64; 3]],
    axes: &[(usize, Coverage)],
) -> Vec<Vec<Term>> {
    let model = problem.model();
    let machine = model.machine();
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let mut out: Vec<Vec<Term>> = axes.iter().map(|_| Vec::new()).collect();
    let points = &problem.data().points;
    let assumed: Vec<Vec<bool>> = axes
        .iter()
        .map(|&(k, _)| before_first_move(points, k))
        .collect();
    for (i, (p, r)) in points.iter().zip(residuals).enumerate() {
        let mut e = PointErrors::<f64>::zero();
        let pose = model.stations()[p.station_index].pose;
        e.tracker.copy_from_slice(&params[pose..pose + TRACKER_DOF]);
        e.station = p.station_index;
        let offset = &machine.reflectors()[p.reflector].offset;
        let (x, jac) = predict_with_errors_jacobian(machine, &p.commands, offset, &e);
        for ((&(k, _), terms), assumed) in axes.iter().zip(out.iter_mut()).zip(&assumed) {
            if assumed[i] {
                continue;
            }
            let side = match p.approach.0[k] {
                1 => 0,
                -1 => 1,
                _ => continue,
            };
            let ax = &machine.axes()[k];
            let u = jac.component[k][ax.axis.direction() + if ax.axis.is_rotary() { 3 } else { 0 }];
            // Measured − predicted (the residuals are predicted − measured), times the axis'
            // side: the tool's deviation relative to the workpiece along the command, whose
            // forward − reverse is ISO 230-2's B (an error of a workpiece-side axis moves the
            // workpiece, so the tool the other way).
            let sigma = ax.side.sign();
            let (dot, w) = match p.observation {
                Observation::Point => (-sigma * dot(u, *r), dot(u, u)),
                Observation::Range => {
                    let len = dot(x, x).sqrt().max(f64::MIN_POSITIVE);
                    let along = dot(u, x.map(|v| v / len));
                    (-sigma * along * r[0], along * along)
                }
            };
            terms.push(Term {
                position: position_key(ax, p.commands.0[k]),
                side,
                dot,
                w,
            });
        }
    }
    out
}
