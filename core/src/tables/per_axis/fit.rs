//! The least-squares projection of a model's volumetric error on per-axis tables ([`fit`]).
//!
//! **What is minimised.** A control applying per-axis tables commands `q + c(q)` for the
//! programmed `q`, with `c_j(q) = Σ_k T_{k→j}(q_k)`: each table `T_{k→j}` a function of input
//! axis `k`'s programmed position added to output axis `j`'s command, interpolated linearly
//! between its positions and held beyond them ([`Family::Leadscrew`]: `k = j` only;
//! [`Family::CrossAxis`]: every input `k` for every output `j`). The tables' values minimise
//! the mean over the sample commands `q` and the tool points `p` of
//!
//! ```text
//! |T(q + c(q), p) − T(q, 0)|²
//! ```
//!
//! (`T(q, p)` the tool point relative to the workpiece, [`Model::tool_point`], `T(q, 0)` the
//! nominal machine's), linearised with the exact Jacobian `∂T/∂q` from dual numbers:
//! `T(q, p) + J(q)·c(q)`, then re-linearised once at `q + c(q)` ([`GAUSS_NEWTON_PASSES`]). The
//! unknowns are the tables' values; the problem is linear in them and its normal equations are
//! solved densely (Cholesky, after scaling every unknown to a unit diagonal and adding
//! [`RIDGE`] to it, so that a value the data cannot tell — an output axis that does not move
//! the tool point — is zero instead of arbitrary). Internal units (mm, rad); the tables hold
//! file units (mm, degrees).
//!
//! **Gauge.** Every table is zero at its input axis' reference position (Siemens requires the
//! value 0 at the reference point; volver's errors are zero there too): the value of the node
//! at the reference is fixed at zero, or, when the reference falls between two nodes, the
//! nearer node's value follows from the other's so that the interpolated value there is zero.
//! A constant offset of the tool point over the whole travel is then no table's: what is left
//! of it is in the leftover. With a reversal, the mean of both directions is zero there, the
//! forward and reverse values ∓B/2.
//!
//! **Nodes.** Over each axis' travel the tables' positions are equally spaced from one end to
//! the other, every `linear_step` mm (`rotary_step` degrees) when the step divides the travel
//! and puts the reference position on a node, else the largest spacing below it that does if
//! that costs at most a third more positions; failing that, the largest spacing below the step
//! that divides the travel, with the reference between two nodes and the table's interpolated
//! value zero there (a reference at 705 mm of a 1 400 mm travel would otherwise need a 5 mm
//! spacing: 281 positions, more than LinuxCNC's 256 and Siemens' 200, whatever the step). A rotary axis whose travel is a full
//! turn has a periodic table: its last position is its first one turned once and holds the same
//! value.
//!
//! **The measure.** The sample commands put every axis on its nodes only, so that at a sample
//! each table's value is one node's value: an error that is a sum of functions of one axis
//! each, in the directions the output axes move the tool (a positioning error EXX(x)), is then
//! cancelled exactly at the nodes. A rotary axis' positioning error (ECC) is such an error to
//! first order only: volver's angular errors are ISO 230-1's small angles, a point moving by
//! `ε × r`, while a table turns the axis' command exactly, which leaves `½ε²ρ` at a distance
//! `ρ` from the axis (0.00005 µm for 10 µrad at 1 m). The samples are the tensor grid of
//! every axis' nodes (a full turn's last node is its first) when it has at most
//! [`SAMPLE_BUDGET`] commands. A larger grid is sampled in two parts. First a star design
//! that samples every node of every table: each axis keeps a subset `S_k` of `m` nodes evenly
//! spread (its ends and its reference among them), `m` as large as a quarter of the budget
//! allows, and the samples are the union over the axes `k` of all of `k`'s nodes times the
//! other axes' subsets, `N_k × Π_{j≠k} S_j`. Then, for the rest of the budget, a Latin design
//! of the nodes: each axis runs through all its nodes in turn, in an order shuffled per axis
//! with a fixed seed, so that every pair of axes meets over its whole plane (a star design
//! alone meets on a few lines: on a five-axis machine at 10 mm, 5° its subsets are 3 nodes and
//! cross-axis tables fitted on it left more than leadscrew tables alone over the evaluation
//! grid — the head-head demo's fit, EMM 59.5 against 54.9 µm; with the Latin part 11.3
//! against 53.4 µm). Every sample is weighed equally, every tool point too.
//!
//! **Reversal.** The leadscrew table of an axis with a reversal (ISO 230-2's B, the model's
//! `reversal.X.b`, [`crate::compensate::reversal_axes`]) holds the mean fit ± B/2 in command
//! units: arriving forward the tool stops `+B/2` along the axis from the mean relative to the
//! workpiece (on either side of the chain: [`crate::approach`]), so the forward values are the
//! mean less `B/2` and the reverse ones the mean plus `B/2`. Every other table's forward and
//! reverse values are equal.

use super::leftover::{Leftover, evaluation_grid, leftover};
use super::{AxisCorrection, Family, PerAxisTables, Request};
use crate::chain::MAX_AXES;
use crate::error::{Error, Result};
use crate::kinematics::{PointErrors, tool_in_workpiece};
use crate::machine::{Commands, Machine, MachineAxis};
use crate::model::{Model, PointState};
use nalgebra::{DMatrix, DVector};
use num_dual::DualSVec64;
use std::f64::consts::TAU;

/// The most sample commands of the projection (each used with every tool point): beyond it the
/// tensor grid of the nodes is thinned on the other axes (see the module documentation).
pub const SAMPLE_BUDGET: usize = 120_000;

/// Linearisations of the tool point: the first at the programmed commands, the second at the
/// commands the first tables give (a Gauss–Newton step).
pub const GAUSS_NEWTON_PASSES: usize = 2;

/// The ridge added to the normal equations scaled to a unit diagonal: what makes a value the
/// samples cannot tell zero; it moves the others by about this fraction.
pub const RIDGE: f64 = 1e-10;

/// Table values smaller than this (mm or degrees) are zero: a table of such values only is left
/// out.
pub const ZERO_VALUE: f64 = 1e-12;

/// The largest number of tables' values (unknowns) the dense solve takes.
pub const MAX_UNKNOWNS: usize = 6000;

/// The per-axis tables of `request.family` that best cancel the tool point's error of `model`
/// with errors `params` over the travel (see the module documentation for the measure, the
/// gauge and the reversal), and what they leave ([`Leftover`], over [`evaluation_grid`]).
///
/// ```
/// use volver_core::model::Model;
/// use volver_core::tables::per_axis::{Family, Request, fit};
/// let model = Model::default_xcfz();
/// let mut p = model.initial_params();
/// // A positioning error of X, 20 µm (P₂(ξ) − 1): zero at the reference X = 0 (ξ = −1).
/// p[model.param_index("EXX.c2").unwrap()] = 0.02;
/// p[model.param_index("EXX.c0").unwrap()] = -0.02;
/// let request = Request { family: Family::Leadscrew, tools: vec![[0.0, 0.0, -100.0]],
///                         linear_step: 100.0, rotary_step: 30.0 };
/// let (tables, left) = fit(&model, &p, &request).unwrap();
/// let x = &tables.tables[0];
/// assert!(x.is_leadscrew() && x.input == volver_core::iso::Axis::X);
/// // X carries the workpiece: its slide's error EXX moves the tool by −EXX along x, and the
/// // table adds to X's command the EXX where the corrected command takes the slide.
/// let exx = |x: f64| 0.02 * (1.5 * (x / 700.0 - 1.0).powi(2) - 1.5);
/// for (pos, v) in x.positions.iter().zip(&x.forward) {
///     assert!((v - exx(pos + v)).abs() < 1e-12);
///     assert!((v - exx(*pos)).abs() < 2e-6); // EXX's slope times the correction
/// }
/// // Left: the parabola between positions 100 mm apart, h²/8 · EXX'' = 0.153 µm at most.
/// assert!(left.before.emax_mm > 0.01 && left.tables.emax_mm < 0.000154);
/// ```
///
/// # Errors
/// Parameters that are not `model`'s, no tool point or a non-finite one, steps that are not
/// positive and finite or give more than [`crate::tables::MAX_TABLE_ROWS`] positions, more
/// than [`MAX_UNKNOWNS`] values, a singular or non-finite system.
pub fn fit(model: &Model, params: &[f64], request: &Request) -> Result<(PerAxisTables, Leftover)> {
    let tables = fit_tables(model, params, request, GAUSS_NEWTON_PASSES)?;
    let grid = evaluation_grid(model.machine());
    let left = leftover(model, params, &tables, &grid)?;
    Ok((tables, left))
}

/// [`fit`]'s tables alone, with `passes` linearisations (1: at the programmed commands only).
pub fn fit_tables(
    model: &Model,
    params: &[f64],
    request: &Request,
    passes: usize,
) -> Result<PerAxisTables> {
    check_request(model, params, request)?;
    let layout = Layout::new(model.machine(), request)?;
    let samples = layout.samples();
    let mut x = vec![0.0; layout.n_vars];
    for _ in 0..passes.max(1) {
        let (n, b) = layout.normal_equations(model, params, &samples, &request.tools, &x);
        let dx = solve(n, b)?;
        x.iter_mut().zip(&dx).for_each(|(v, d)| *v += d);
    }
    Ok(layout.tables(model, params, &x, request))
}

/// Refuses parameters of another model, no tool point, a non-finite one, and steps that are not
/// positive and finite.
fn check_request(model: &Model, params: &[f64], request: &Request) -> Result<()> {
    if params.len() != model.n_params() {
        return Err(Error::ParameterCount {
            expected: model.n_params(),
            got: params.len(),
            message: format!(
                "per-axis tables need {} parameters, got {}",
                model.n_params(),
                params.len()
            ),
        });
    }
    if request.tools.is_empty() || request.tools.iter().flatten().any(|v| !v.is_finite()) {
        return Err(Error::InvalidOption {
            name: "tool",
            message: "per-axis tables serve one tool point at least, each three finite \
                      coordinates (mm)"
                .into(),
        });
    }
    let usable = |s: f64| s > 0.0 && s.is_finite();
    if !(usable(request.linear_step) && usable(request.rotary_step)) {
        return Err(Error::InvalidOption {
            name: "step",
            message: "table steps must be positive and finite".into(),
        });
    }
    Ok(())
}

/// One axis' table positions (the nodes, internal units) and how each node's value follows
/// from the unknowns.
#[derive(Clone, Debug)]
struct Nodes {
    /// The first node (the start of the travel; mm or rad).
    lo: f64,
    /// The spacing (mm or rad).
    h: f64,
    /// Intervals: `n + 1` nodes.
    n: usize,
    /// A full turn: node `n` is node 0 turned once.
    periodic: bool,
    /// The node at (or nearest) the reference position.
    reference: usize,
    /// Per node, the unknown (index among the axis' own) and the factor the node's value is of
    /// it; `None`: zero (the reference).
    map: Vec<Option<(usize, f64)>>,
    /// Unknowns per table of this input axis.
    unknowns: usize,
}

impl Nodes {
    /// The nodes of axis `a` every `step` file units at most (see the module documentation).
    fn new(a: &MachineAxis, step: f64) -> Result<Nodes> {
        let travel = a.max - a.min;
        let step_internal = a.from_file_units(step);
        let fewest = (travel / step_internal - 1e-9).ceil().max(1.0);
        if fewest + 1.0 > crate::tables::MAX_TABLE_ROWS as f64 {
            return Err(Error::InvalidOption {
                name: "step",
                message: format!(
                    "a step of {} {} over axis {}'s travel gives {intervals:.3e} positions; a \
                     table has at most {}: use a larger step",
                    crate::error::number(step),
                    a.file_unit(),
                    a.axis,
                    crate::tables::MAX_TABLE_ROWS,
                    intervals = fewest + 1.0
                ),
            });
        }
        let n = intervals_through_reference(a, fewest as usize);
        let h = travel / n as f64;
        let periodic = a.is_full_turn() && n >= 2;
        let canonical = |i: usize| if periodic && i == n { 0 } else { i };
        let r = ((a.reference - a.min) / h).clamp(0.0, n as f64);
        let below = (r.floor() as usize).min(n - 1);
        let t = r - below as f64;
        // The pinned node, and with the reference between nodes the one it follows.
        let (pinned, follows) = if !(1e-9..=1.0 - 1e-9).contains(&t) {
            (canonical(r.round() as usize), None)
        } else if t > 0.5 {
            (
                canonical(below + 1),
                Some((canonical(below), -(1.0 - t) / t)),
            )
        } else {
            (
                canonical(below),
                Some((canonical(below + 1), -t / (1.0 - t))),
            )
        };
        let mut map = vec![None; n + 1];
        let mut unknowns = 0;
        for (i, slot) in map.iter_mut().enumerate() {
            if canonical(i) == i && i != pinned {
                *slot = Some((unknowns, 1.0));
                unknowns += 1;
            }
        }
        if let Some((other, factor)) = follows
            && other != pinned
        {
            map[pinned] = map[other].map(|(v, f)| (v, f * factor));
        }
        if periodic {
            map[n] = map[0];
        }
        let reference = if t > 0.5 { below + 1 } else { below };
        Ok(Nodes {
            lo: a.min,
            h,
            n,
            periodic,
            reference: canonical(reference),
            map,
            unknowns,
        })
    }

    /// Node `i`'s position (mm or rad).
    fn position(&self, i: usize) -> f64 {
        if i == self.n {
            self.lo + self.h * self.n as f64
        } else {
            self.lo + self.h * i as f64
        }
    }

    /// The nodes samples take: all but a full turn's last (its first).
    fn sampled(&self) -> usize {
        if self.periodic { self.n } else { self.n + 1 }
    }

    /// The two nodes around position `x` (mm or rad) and their weights in the linear
    /// interpolation, held at the end values beyond the nodes (a full turn wrapped into it).
    fn weights(&self, x: f64) -> [(usize, f64); 2] {
        let x = if self.periodic {
            self.lo + (x - self.lo).rem_euclid(TAU)
        } else {
            x
        };
        let r = ((x - self.lo) / self.h).clamp(0.0, self.n as f64);
        let i = (r.floor() as usize).min(self.n - 1);
        let t = r - i as f64;
        [(i, 1.0 - t), (i + 1, t)]
    }

    /// `m` of the sampled nodes evenly spread, both ends and the reference among them (all when
    /// `m` reaches their count); over a full turn evenly spread over the turn, from its start.
    fn thinned(&self, m: usize) -> Vec<usize> {
        let count = self.sampled();
        if m >= count {
            return (0..count).collect();
        }
        let mut v: Vec<usize> = (0..m)
            .map(|i| {
                if self.periodic {
                    ((i * count) as f64 / m as f64).round() as usize
                } else {
                    ((i * (count - 1)) as f64 / (m - 1).max(1) as f64).round() as usize
                }
            })
            .collect();
        v.push(self.reference);
        v.sort_unstable();
        v.dedup();
        v
    }
}

/// The tables of a request over a machine: each axis' nodes, the tables (input, output: chain
/// positions) and where each table's unknowns start.
struct Layout {
    nodes: Vec<Nodes>,
    tables: Vec<(usize, usize)>,
    offsets: Vec<usize>,
    n_vars: usize,
}

impl Layout {
    fn new(machine: &Machine, request: &Request) -> Result<Layout> {
        let axes = machine.axes();
        let nodes = axes
            .iter()
            .map(|a| {
                let step = if a.axis.is_rotary() {
                    request.rotary_step
                } else {
                    request.linear_step
                };
                Nodes::new(a, step)
            })
            .collect::<Result<Vec<_>>>()?;
        let n = axes.len();
        let mut tables: Vec<(usize, usize)> = (0..n).map(|k| (k, k)).collect();
        if request.family == Family::CrossAxis {
            for j in 0..n {
                tables.extend((0..n).filter(|&k| k != j).map(|k| (k, j)));
            }
        }
        let mut offsets = Vec::with_capacity(tables.len());
        let mut n_vars = 0;
        for &(k, _) in &tables {
            offsets.push(n_vars);
            n_vars += nodes[k].unknowns;
        }
        if n_vars > MAX_UNKNOWNS {
            return Err(Error::InvalidOption {
                name: "step",
                message: format!(
                    "{} tables of {n_vars} values in all; the projection takes at most \
                     {MAX_UNKNOWNS}: use larger steps",
                    tables.len()
                ),
            });
        }
        Ok(Layout {
            nodes,
            tables,
            offsets,
            n_vars,
        })
    }

    /// The nonzero terms of `c(q)`: (unknown, output axis, factor), appended to `out`.
    fn entries(&self, q: &Commands, out: &mut Vec<(usize, usize, f64)>) {
        out.clear();
        for (t, &(k, j)) in self.tables.iter().enumerate() {
            let nodes = &self.nodes[k];
            for (i, w) in nodes.weights(q.0[k]) {
                if w == 0.0 {
                    continue;
                }
                if let Some((v, f)) = nodes.map[i] {
                    out.push((self.offsets[t] + v, j, w * f));
                }
            }
        }
    }

    /// The sample commands (see the module documentation).
    fn samples(&self) -> Vec<Commands> {
        let counts: Vec<usize> = self.nodes.iter().map(Nodes::sampled).collect();
        let full = counts.iter().map(|&c| c as f64).product::<f64>();
        let largest = counts.iter().copied().max().unwrap_or(1);
        let size = |m: usize| -> f64 {
            let s: Vec<f64> = self
                .nodes
                .iter()
                .map(|n| n.thinned(m).len() as f64)
                .collect();
            let core: f64 = s.iter().product();
            core + (0..s.len())
                .map(|k| (counts[k] as f64 - s[k]) * core / s[k])
                .sum::<f64>()
        };
        // Beyond the budget: the star design that samples every node (its subsets as large as
        // a quarter of the budget allows), the rest of the budget a Latin design of the nodes.
        let m = if full <= SAMPLE_BUDGET as f64 {
            largest
        } else {
            (2..largest)
                .take_while(|&m| size(m) <= (SAMPLE_BUDGET / 4) as f64)
                .last()
                .unwrap_or(2)
        };
        let star = size(m) as usize;
        let thin: Vec<Vec<usize>> = self.nodes.iter().map(|n| n.thinned(m)).collect();
        let mut out = Vec::new();
        let mut push = |idx: &[usize]| {
            let mut q = Commands::default();
            for (k, &i) in idx.iter().enumerate() {
                q.0[k] = self.nodes[k].position(i);
            }
            out.push(q);
        };
        tensor(&thin, &mut push);
        for k in 0..self.nodes.len() {
            let mut lists = thin.clone();
            lists[k] = (0..counts[k]).filter(|i| !thin[k].contains(i)).collect();
            tensor(&lists, &mut push);
        }
        if full > SAMPLE_BUDGET as f64 {
            for idx in latin_nodes(&counts, &thin, SAMPLE_BUDGET.saturating_sub(star)) {
                push(&idx);
            }
        }
        out
    }

    /// The normal equations of the linearised problem at the tables `x`: `N δ = b` for the
    /// change `δ` of the unknowns (`N = AᵀA`, `b = −Aᵀr`, one row of `A` per sample, tool point
    /// and coordinate).
    fn normal_equations(
        &self,
        model: &Model,
        params: &[f64],
        samples: &[Commands],
        tools: &[[f64; 3]],
        x: &[f64],
    ) -> (Vec<f64>, Vec<f64>) {
        let nv = self.n_vars;
        let n_axes = self.nodes.len();
        let mut normal = vec![0.0; nv * nv];
        let mut rhs = vec![0.0; nv];
        let mut entries = Vec::new();
        for q in samples {
            self.entries(q, &mut entries);
            let mut moved = *q;
            for &(v, j, w) in &entries {
                moved.0[j] += w * x[v];
            }
            for tool in tools {
                let (e, jac) = error_and_jacobian(model, params, q, &moved, tool, n_axes);
                // G = JᵀJ and g = Jᵀe over the axes; A's row for unknown v is J[:, j]·w.
                let mut g = [[0.0; MAX_AXES]; MAX_AXES];
                let mut ge = [0.0; MAX_AXES];
                for a in 0..n_axes {
                    for b in 0..n_axes {
                        g[a][b] = (0..3).map(|c| jac[c][a] * jac[c][b]).sum();
                    }
                    ge[a] = (0..3).map(|c| jac[c][a] * e[c]).sum();
                }
                for &(va, ja, wa) in &entries {
                    rhs[va] -= wa * ge[ja];
                    let row = &mut normal[va * nv..(va + 1) * nv];
                    for &(vb, jb, wb) in &entries {
                        row[vb] += wa * wb * g[ja][jb];
                    }
                }
            }
        }
        (normal, rhs)
    }

    /// The tables of the unknowns `x` (file units), leadscrew tables with their reversal; tables
    /// of zeros left out.
    fn tables(&self, model: &Model, params: &[f64], x: &[f64], request: &Request) -> PerAxisTables {
        let axes = model.machine().axes();
        let reversal = crate::compensate::reversal_axes(model);
        let mut tables = Vec::new();
        for (t, &(k, j)) in self.tables.iter().enumerate() {
            let nodes = &self.nodes[k];
            let out = &axes[j];
            let positions: Vec<f64> = (0..=nodes.n)
                .map(|i| axes[k].to_file_units(nodes.position(i)))
                .collect();
            let mean: Vec<f64> = nodes
                .map
                .iter()
                .map(|m| out.to_file_units(m.map_or(0.0, |(v, f)| f * x[self.offsets[t] + v])))
                .collect();
            let half_b: Vec<f64> = if k == j && reversal.contains(&k) {
                (0..=nodes.n)
                    .map(|i| {
                        let b = model.reversal_at(k, nodes.position(i), params, None);
                        out.to_file_units(0.5 * b.unwrap_or(0.0))
                    })
                    .collect()
            } else {
                vec![0.0; mean.len()]
            };
            let forward: Vec<f64> = mean.iter().zip(&half_b).map(|(m, b)| m - b).collect();
            let reverse: Vec<f64> = mean.iter().zip(&half_b).map(|(m, b)| m + b).collect();
            if forward.iter().chain(&reverse).all(|v| v.abs() < ZERO_VALUE) {
                continue;
            }
            tables.push(AxisCorrection {
                input: axes[k].axis,
                output: out.axis,
                positions,
                forward,
                reverse,
            });
        }
        PerAxisTables {
            family: request.family,
            tools: request.tools.clone(),
            tables,
        }
    }
}

/// The fewest intervals from `fewest` to a third more that divide axis `a`'s travel with its
/// reference position on a node; `fewest` when none does (the reference between two nodes).
fn intervals_through_reference(a: &MachineAxis, fewest: usize) -> usize {
    let r = (a.reference - a.min) / (a.max - a.min);
    (fewest..=fewest + fewest.div_ceil(3))
        .find(|&n| {
            let x = r * n as f64;
            (x - x.round()).abs() < 1e-9 * n as f64
        })
        .unwrap_or(fewest)
}

/// Calls `f` with every multi-index of the tensor product of `lists` (none when one is empty).
/// At most `n` commands of a Latin design over the nodes (node indices per axis): each axis
/// runs through its `counts[k]` nodes in turn, as evenly as `n` allows, in an order shuffled
/// independently per axis (a fixed seed: the same tables every run), so that every pair of axes
/// meets over its whole plane rather than on a few lines. A command the star design `thin`
/// holds (every axis but at most one in its subset), or an earlier one, is left out: each
/// command once.
fn latin_nodes(counts: &[usize], thin: &[Vec<usize>], n: usize) -> Vec<Vec<usize>> {
    let mut rng = crate::random::Rng::new(0x5eed_4701);
    let columns: Vec<Vec<usize>> = counts
        .iter()
        .map(|&c| {
            let mut v: Vec<usize> = (0..n).map(|i| i % c.max(1)).collect();
            for i in (1..v.len()).rev() {
                let j = (rng.next_u64() % (i as u64 + 1)) as usize;
                v.swap(i, j);
            }
            v
        })
        .collect();
    let in_star = |idx: &[usize]| {
        (0..idx.len()).any(|k| (0..idx.len()).all(|j| j == k || thin[j].contains(&idx[j])))
    };
    let mut seen = std::collections::HashSet::new();
    (0..n)
        .map(|i| columns.iter().map(|col| col[i]).collect::<Vec<usize>>())
        .filter(|idx| !in_star(idx) && seen.insert(idx.clone()))
        .collect()
}

fn tensor(lists: &[Vec<usize>], f: &mut impl FnMut(&[usize])) {
    if lists.iter().any(Vec::is_empty) {
        return;
    }
    let mut pos = vec![0; lists.len()];
    let mut idx: Vec<usize> = lists.iter().map(|l| l[0]).collect();
    loop {
        f(&idx);
        let mut k = 0;
        loop {
            if k == lists.len() {
                return;
            }
            pos[k] += 1;
            if pos[k] < lists[k].len() {
                idx[k] = lists[k][pos[k]];
                break;
            }
            pos[k] = 0;
            idx[k] = lists[k][0];
            k += 1;
        }
    }
}

/// The tool point's error at the commanded `moved` against the nominal point of the programmed
/// `q`, `T(moved, p) − T(q, 0)` (mm), and its exact Jacobian over the first `n_axes` axes at
/// `moved` (rows: coordinates), from dual numbers.
fn error_and_jacobian(
    model: &Model,
    params: &[f64],
    q: &Commands,
    moved: &Commands,
    tool: &[f64; 3],
    n_axes: usize,
) -> ([f64; 3], [[f64; MAX_AXES]; 3]) {
    type D = DualSVec64<MAX_AXES>;
    let mut u = moved.0.map(D::from_re);
    for (k, v) in u.iter_mut().enumerate().take(n_axes) {
        *v = D::from_re(moved.0[k]).derivative(k);
    }
    let tip = model.tool_point_in(&u, tool, PointState::default(), params);
    let nominal = tool_in_workpiece(model.machine(), &q.0, tool, &PointErrors::<f64>::zero());
    let mut jac = [[0.0; MAX_AXES]; 3];
    let mut e = [0.0; 3];
    for c in 0..3 {
        e[c] = tip[c].re - nominal[c];
        if let Some(eps) = &tip[c].eps.0 {
            jac[c][..n_axes].copy_from_slice(&eps.as_slice()[..n_axes]);
        }
    }
    (e, jac)
}

/// Solves `N δ = b` (N symmetric, n × n row-major) scaled to a unit diagonal with [`RIDGE`]
/// added; an unknown with a zero diagonal (no sample moves it) is zero.
fn solve(normal: Vec<f64>, rhs: Vec<f64>) -> Result<Vec<f64>> {
    let n = rhs.len();
    if n == 0 {
        return Ok(Vec::new());
    }
    let scale: Vec<f64> = (0..n)
        .map(|i| {
            let d = normal[i * n + i];
            if d > 0.0 { 1.0 / d.sqrt() } else { 0.0 }
        })
        .collect();
    let mut m = DMatrix::from_row_slice(n, n, &normal);
    for i in 0..n {
        for j in 0..n {
            m[(i, j)] *= scale[i] * scale[j];
        }
        m[(i, i)] = if scale[i] > 0.0 {
            m[(i, i)] + RIDGE
        } else {
            1.0
        };
    }
    let b = DVector::from_iterator(n, (0..n).map(|i| rhs[i] * scale[i]));
    if !(m.iter().all(|v| v.is_finite()) && b.iter().all(|v| v.is_finite())) {
        return Err(Error::NonFinite {
            message: "per-axis tables: the tool point or its Jacobian is not finite over the \
                      travel"
                .into(),
        });
    }
    let chol = m.cholesky().ok_or_else(|| Error::Singular {
        message: "per-axis tables: the normal equations are not positive definite".into(),
    })?;
    let y = chol.solve(&b);
    Ok((0..n).map(|i| y[i] * scale[i]).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nodes_pin_the_reference_and_tie_a_full_turn() {
        let m = crate::machine::Machine::default_xcfz();
        let c = Nodes::new(&m.axes()[1], 30.0).unwrap();
        assert!(c.periodic && c.n == 12 && c.sampled() == 12);
        assert_eq!(c.map[0], None);
        assert_eq!(c.map[12], None);
        assert_eq!(c.unknowns, 11);
        // A reference between nodes: the interpolated value there is zero.
        let mut x = m.axes()[0].clone();
        x.reference = 130.0;
        let n = Nodes::new(&x, 100.0).unwrap();
        let vals: Vec<f64> = n
            .map
            .iter()
            .map(|s| s.map_or(0.0, |(v, f)| f * (v as f64 + 1.0)))
            .collect();
        let [(i, wi), (j, wj)] = n.weights(130.0);
        assert!((wi * vals[i] + wj * vals[j]).abs() < 1e-15);
        assert_eq!(n.unknowns, n.n);
    }

    #[test]
    fn a_thinned_sample_holds_every_node_once() {
        let model = Model::default_xcfz();
        let request = Request {
            family: Family::CrossAxis,
            tools: vec![[0.0; 3]],
            linear_step: 2.0,
            rotary_step: 2.0,
        };
        let layout = Layout::new(model.machine(), &request).unwrap();
        let s = layout.samples();
        assert!(s.len() <= SAMPLE_BUDGET && s.len() > SAMPLE_BUDGET / 3);
        let mut keys: Vec<[i64; 3]> = s
            .iter()
            .map(|q| std::array::from_fn(|k| (q.0[k] * 1e6).round() as i64))
            .collect();
        keys.sort_unstable();
        let n = keys.len();
        keys.dedup();
        assert_eq!(keys.len(), n);
        for (k, nodes) in layout.nodes.iter().enumerate() {
            for i in 0..nodes.sampled() {
                let p = nodes.position(i);
                assert!(
                    s.iter().any(|q| (q.0[k] - p).abs() < 1e-9),
                    "axis {k} node {i}"
                );
            }
        }
    }
}
