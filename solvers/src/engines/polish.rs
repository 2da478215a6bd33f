//! Newton polish of an optimum under linear constraints: [`settle`] takes a point near the
//! optimum of Φ (or ve) under a task's constraints, as an engine left it, to the optimum itself,
//! to the resolution the cost's and the gradient's rounding allow. The identification settles
//! every engine's result on its gauge with it (so that the result does not depend on where an
//! engine stopped along weakly identified directions), and the native LM polishes a converged
//! Φ fit with it.

use crate::Task;
use crate::engines::coordinates::Free;
use crate::engines::loss::{cost_of, norms, weight_of};
use crate::options::Objective;
use faer::{Mat, Side};
use volver_core::problem::Residuals;

mod l1;

/// What [`settle`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct Settled {
    /// Newton steps taken.
    pub steps: usize,
    /// Jacobian passes.
    pub jacobian_evaluations: usize,
    /// Objective passes (line search included).
    pub evaluations: usize,
    /// Simplex pivots of the linear programmes (Φ on scalar residuals; zero otherwise).
    pub pivots: usize,
    /// The objective's predicted decrease left at the end (the Newton decrement `½ gᵀH⁻¹g`),
    /// relative to the objective.
    pub decrement: f64,
    /// Why it stopped.
    pub stop: SettleStop,
}

/// Why [`settle`] stopped (each a predicate of its own in the source).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum SettleStop {
    /// No free parameter: the point is the constraints' only one.
    NoFreeParameters,
    /// Within the cost's rounding, the Newton step would move the error functions by less than
    /// 1e-10 of their size: the point is kept.
    Negligible,
    /// Two Newton steps in a row found no smaller predicted decrease: the result is the point of
    /// smallest predicted decrease.
    Stale,
    /// The predicted decrease fell below 1e-30 of the objective.
    Decrement,
    /// No step along the Newton direction (halved down to 2⁻²⁹ of it) lowered the objective.
    NoDecrease,
    /// The Newton steps allowed (40) are spent.
    StepLimit,
    /// Φ on scalar residuals (an L1 fit): the linear programme at the point is optimal and its
    /// step negligible, with a predicted decrease within the cost's rounding — the basic
    /// residuals vanish to rounding and every multiplier is within ±1, the first-order
    /// conditions of the L1 optimum (see [`settle`]).
    Vertex,
}

/// Why [`settle`] could not run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum Unsettled {
    /// A residual or a Jacobian entry is not finite (at the start or at a Jacobian pass).
    #[error("a residual or Jacobian entry is not finite")]
    NotFinite,
    /// The constraints cannot be eliminated at the point.
    #[error("the constraints cannot be eliminated at the point")]
    Constraints,
    /// An eigen-decomposition of the Newton matrix failed, or its exact second-order term is not
    /// finite.
    #[error("the Newton matrix could not be decomposed")]
    Decomposition,
}

/// Newton steps allowed to [`settle`].
const SETTLE_STEPS: usize = 40;

/// The most steps of [`settle`] (and of the vertex of an L1 fit, whose linear programmes are
/// as many).
pub(crate) const FINISH_STEPS: usize = SETTLE_STEPS;

/// The most evaluations [`settle`] counts from a given scaling (its start's residuals, then per
/// step a Jacobian pass, a cut-back and the line search's [`HALVINGS`]), which also bounds the
/// vertex of an L1 fit (a Jacobian pass and at most [`HALVINGS`] passes per programme).
pub(crate) const FINISH_EVALUATIONS: usize = 1 + SETTLE_STEPS * (HALVINGS + 2);

/// [`settle`] stops after this many Newton steps in a row find no decrement smaller than the
/// best seen.
const STALE_STEPS: usize = 2;

/// A step of [`settle`] within the cost's rounding whose end has a positive slope above this
/// share of its start's went past the minimum along its line.
const OVERSHOOT: f64 = 0.5;

/// A Gauss–Newton step of [`settle`] that leaves more than this share of the predicted decrease
/// is slow: the exact second-order term joins from then on.
const SLOW: f64 = 0.1;

/// [`settle`] stops once the predicted decrease is below this share of the objective.
const DECREMENT_FLOOR: f64 = 1e-30;

/// Directions of the Newton matrix whose curvature is below this share of the largest are left
/// out of the step (the gauge holds the flat ones; rounding is all that is left there).
const FLAT: f64 = 1e-14;

/// Halvings of a Newton step the line search tries.
const HALVINGS: usize = 30;

/// The optimum of the objective under `task`'s constraints (the gauge's among them), from a
/// point `p` near it: Newton steps on the smoothed objective (`Φ_ε = mean √(‖r‖² + ε²)` with
/// `ε = irls_final_epsilon × Φ`, or ve), each with the exact Gauss–Newton Hessian of the loss
/// (the radial direction of a Φ point carries less curvature than the tangential ones) and,
/// once Gauss–Newton steps converge slowly, the residuals' own second derivatives on the
/// weakest directions, in the Jacobi-scaled free coordinates, with a backtracking line search;
/// until the predicted decrease is below 1e-30 of the objective, no step lowers it, or (once
/// the cost's change is within its rounding) the Newton step would move the error functions by
/// less than 1e-10 of their size (the point is kept), or two steps in a row find no
/// smaller predicted decrease (the result is then the point of smallest predicted decrease):
/// [`Settled::stop`] says which.
///
/// Φ of scalar residuals alone (ranges: an L1 fit, whose optimum is a vertex where as many
/// residuals vanish as there are free coordinates, and where the smoothed Newton steps crawl)
/// goes to that vertex exactly instead: sequential linear programmes, each the L1 regression
/// of the residuals linearised at the point, solved by the simplex method of L1 regression
/// (Barrodale and Roberts) from the previous basis, its step taken where Φ falls; once the basis
/// is the optimum's these are Newton's steps on the interpolated residuals, and the run stops
/// at [`SettleStop::Vertex`] (the Newton steps above when the programmes fail).
///
/// This is what makes the gauge a rule rather than a neighbourhood: engines stop at different
/// places in the nearly flat directions that remain identified (curvature 1e-9 … 1e-4 of the
/// largest), and polishing them to the same optimum makes the result independent of the engine
/// and the start. [`Unsettled`] when a residual or Jacobian is not finite, the constraints
/// cannot be eliminated at `p` or a Newton matrix cannot be decomposed.
pub fn settle(
    task: &Task,
    p: &[f64],
    objective: Objective,
    irls_final_epsilon: f64,
) -> Result<(Vec<f64>, Settled), Unsettled> {
    settle_scaled(task, p, None, objective, irls_final_epsilon, None)
}

/// [`settle`] in the column scaling `scale` when the caller has one for this task (the native
/// LM's, from its start: the Jacobi scaling need not be fresh, and it saves a pass); else the
/// scaling from the Jacobian at `p`. With `budget` (steps, evaluations with the Jacobian
/// passes), the Newton steps stop before one could overrun it (each step takes at most
/// [`HALVINGS`] + 2 evaluations): an engine's limits then hold however far it has gone.
pub(crate) fn settle_scaled(
    task: &Task,
    p: &[f64],
    scale: Option<&[f64]>,
    objective: Objective,
    irls_final_epsilon: f64,
    budget: Option<(usize, usize)>,
) -> Result<(Vec<f64>, Settled), Unsettled> {
    let free = free_coordinates(task, p, scale)?;
    if objective.loss() == Objective::Phi && free.n_free() > 0 && l1::all_scalar(&*task.problem) {
        let x = free.params(&vec![0.0; free.n_free()]);
        if let Ok(done) = vertex(&*task.problem, &free, x) {
            return Ok(done);
        }
    }
    let mut settle = Settle::start(&*task.problem, free, objective.loss(), irls_final_epsilon)?;
    if settle.free.n_free() == 0 {
        settle.report.decrement = 0.0;
        settle.report.stop = SettleStop::NoFreeParameters;
        return Ok((settle.x, settle.report));
    }
    settle.report.stop = SettleStop::StepLimit;
    let (steps, evaluations) = budget.unwrap_or((SETTLE_STEPS, usize::MAX));
    for _ in 0..SETTLE_STEPS.min(steps) {
        let used = settle.report.evaluations + settle.report.jacobian_evaluations;
        if used.saturating_add(HALVINGS + 2) > evaluations {
            break;
        }
        if let Some(stop) = settle.step()? {
            settle.report.stop = stop;
            break;
        }
    }
    let Settle {
        mut x,
        mut report,
        best,
        ..
    } = settle;
    if let Some((x0, d0, _)) = best {
        (x, report.decrement) = (x0, d0);
    }
    Ok((x, report))
}

/// The L1 optimum of Φ on scalar residuals alone (the vertex of [`settle`]) from `x` in the
/// free coordinates `free`.
pub(crate) fn vertex(
    problem: &dyn Residuals,
    free: &Free,
    x: Vec<f64>,
) -> Result<(Vec<f64>, Settled), Unsettled> {
    l1::settle(problem, free, x, phi_rounding(problem))
}

pub(crate) use l1::all_scalar;

/// The rounding of Φ (mm): each residual is rounded relative to what its point measured (mm from
/// the tracker), not to itself, and the mean of n of them by 1/√n of that: 16 ε of the largest
/// over √n, a margin of ~15 over what is seen (3e-13 of Φ on test 4).
fn phi_rounding(problem: &dyn Residuals) -> f64 {
    let np = problem.n_points();
    let scale = (0..np)
        .map(|i| problem.observation_scale(i))
        .fold(0.0_f64, f64::max);
    16.0 * f64::EPSILON * scale / (np as f64).sqrt()
}

/// The Jacobi-scaled free coordinates of `task` at `p`, in `scale` when given. Parameters a
/// constraint fixes on its own stay exactly at their value (the null space leaves rounding
/// there).
fn free_coordinates(task: &Task, p: &[f64], scale: Option<&[f64]>) -> Result<Free, Unsettled> {
    let problem = &*task.problem;
    let (d, ns) = match scale {
        Some(d) => (
            d.to_vec(),
            crate::engines::coordinates::null_space_scaled_by(d, &task.constraints, p),
        ),
        None => {
            let plain = crate::engines::kernels::accumulate(problem, p, |_| (1.0, 0.0), false)
                .ok_or(Unsettled::NotFinite)?;
            crate::engines::coordinates::scaled_null_space(&plain.h, &task.constraints, p)
        }
    };
    let ns = ns.map_err(|_| Unsettled::Constraints)?;
    Ok(Free::new(d, ns, &task.constraints))
}

/// The state of a [`settle`] run: the point (z, p and the cost), what was done, and what the
/// judgement of the next steps needs.
struct Settle<'t> {
    problem: &'t dyn Residuals,
    objective: Objective,
    /// The smoothing (mm), fixed for the run.
    eps: f64,
    free: Free,
    /// The cost's rounding (see [`Settle::start`]).
    floor: f64,
    negligible: Negligible,
    z: Vec<f64>,
    x: Vec<f64>,
    cost: f64,
    report: Settled,
    /// Within the cost's rounding the cost cannot tell a better point from a worse one: there
    /// the gradient decides. `best` is the point of smallest decrement (with its decrement and
    /// cost) seen since the cost last fell by more than its rounding, `stale` the steps since
    /// it was found.
    best: Option<(Vec<f64>, f64, f64)>,
    stale: usize,
    /// Whether the exact second-order term is in, and the last decrement whose step was taken
    /// above the cost's rounding.
    exact: bool,
    previous: Option<f64>,
    /// The last step taken within the cost's rounding: where from, along what, and the slope
    /// of the cost there.
    level_step: Option<(Vec<f64>, Vec<f64>, f64)>,
}

impl<'t> Settle<'t> {
    /// The run at the start of `free` (z = 0).
    fn start(
        problem: &'t dyn Residuals,
        free: Free,
        objective: Objective,
        irls_final_epsilon: f64,
    ) -> Result<Settle<'t>, Unsettled> {
        let np = problem.n_points();
        let z = vec![0.0; free.n_free()];
        let x = free.params(&z);
        let norms0 = norms(problem, &x).ok_or(Unsettled::NotFinite)?;
        let eps = irls_final_epsilon * norms0.iter().sum::<f64>() / np as f64;
        let cost = cost_of(objective, &norms0, eps);
        let floor = phi_rounding(problem)
            * if objective.loss() == Objective::Ve {
                2.0 * cost.sqrt()
            } else {
                1.0
            };
        // What a step changes that any output can see: the error functions (and the tracker
        // pose) in the gauge's function metric, against the size of the error functions
        // themselves (the tracker's position, metres from the machine, is left out of the
        // size); the parameters themselves for a curve fit.
        let negligible = Negligible::at(problem, &x);
        Ok(Settle {
            problem,
            objective,
            eps,
            free,
            floor,
            negligible,
            z,
            x,
            cost,
            report: Settled {
                steps: 0,
                jacobian_evaluations: 0,
                evaluations: 1,
                pivots: 0,
                decrement: f64::INFINITY,
                stop: SettleStop::StepLimit,
            },
            best: None,
            stale: 0,
            exact: false,
            previous: None,
            level_step: None,
        })
    }

    /// The cost at the free coordinates `z` (and the parameters there); `None` where the
    /// residuals are not finite. Counts an evaluation.
    fn cost_at(&mut self, z: &[f64]) -> (Vec<f64>, Option<f64>) {
        let x = self.free.params(z);
        self.report.evaluations += 1;
        let cost = norms(self.problem, &x).map(|r| cost_of(self.objective, &r, self.eps));
        (x, cost)
    }

    /// One Jacobian pass and what follows it: a level step's overshoot cut back, or a Newton
    /// step judged and taken; `Some` reason when the run stops.
    fn step(&mut self) -> Result<Option<SettleStop>, Unsettled> {
        let (problem, objective, eps) = (self.problem, self.objective, self.eps);
        let np = problem.n_points();
        let normal = crate::engines::kernels::accumulate(
            problem,
            &self.x,
            |r| weight_of(objective, r, eps, np),
            false,
        )
        .ok_or(Unsettled::NotFinite)?;
        self.report.jacobian_evaluations += 1;
        let (hz, gz) = crate::engines::coordinates::reduce(
            &self.free.d,
            self.free.ns.basis(),
            &normal.h,
            Some(&normal.g),
        );
        if self.cut_overshoot(&gz)? {
            return Ok(None);
        }
        let (dz, decrement) = self.newton_step(&hz, &gz)?;
        if self.settled(decrement, &dz) {
            self.best = None;
            self.report.decrement = decrement;
            return Ok(Some(SettleStop::Negligible));
        }
        if self.stale(decrement) {
            return Ok(Some(SettleStop::Stale));
        }
        if decrement < DECREMENT_FLOOR {
            return Ok(Some(SettleStop::Decrement));
        }
        if !self.line_search(&dz, &gz, decrement) {
            return Ok(Some(SettleStop::NoDecrease));
        }
        self.report.steps += 1;
        Ok(None)
    }

    /// A step taken within the cost's rounding is judged by the slope of the cost along it,
    /// which the exact gradient `gz` gives to a much finer rounding than the cost's: when the
    /// slope at its end is positive and above [`OVERSHOOT`] of its start's, the step went past
    /// the minimum along its line and is cut back to where the slope's secant vanishes (`true`:
    /// the point moved, the next pass judges it).
    fn cut_overshoot(&mut self, gz: &[f64]) -> Result<bool, Unsettled> {
        let Some((z0, dz0, slope0)) = self.level_step.take() else {
            return Ok(false);
        };
        let slope1: f64 = gz.iter().zip(&dz0).map(|(g, d)| g * d).sum();
        if !(slope0 < 0.0 && slope1 > OVERSHOOT * -slope0) {
            return Ok(false);
        }
        let t = slope0 / (slope0 - slope1);
        let zt: Vec<f64> = z0.iter().zip(&dz0).map(|(a, b)| a + t * b).collect();
        let (xt, c) = self.cost_at(&zt);
        let c = c.ok_or(Unsettled::NotFinite)?;
        (self.z, self.x, self.cost) = (zt, xt, c);
        Ok(true)
    }

    /// The Newton step and its decrement relative to the cost.
    ///
    /// The Gauss–Newton matrix leaves out Σ ψ_iᵀ ∂²r_i (ψ_i the loss' gradient in r_i), small
    /// against the strong curvatures but not always against the weakest (measured 1e-6 … 1e-3
    /// of them on tests 3 and 4). Newton steps on it converge at the rate of that ratio; once a
    /// step above the cost's rounding leaves more than [`SLOW`] of the predicted decrease, the
    /// term is added exactly on the weak directions (second-order dual numbers, k (k + 1) / 2
    /// passes for k directions) for the rest of the run.
    fn newton_step(&mut self, hz: &Mat<f64>, gz: &[f64]) -> Result<(Vec<f64>, f64), Unsettled> {
        let exact_matrix = |s: &Self| {
            weak_second_order(
                s.problem,
                &s.x,
                &s.free.d,
                s.free.ns.basis(),
                hz,
                s.objective,
                s.eps,
            )
            .ok_or(Unsettled::Decomposition)
        };
        let (mut dz, mut decrement) = if self.exact {
            newton(&exact_matrix(self)?, gz, self.cost)?
        } else {
            newton(hz, gz, self.cost)?
        };
        if !self.exact && self.previous.is_some_and(|d0| decrement > SLOW * d0) {
            self.exact = true;
            (dz, decrement) = newton(&exact_matrix(self)?, gz, self.cost)?;
        }
        Ok((dz, decrement))
    }

    /// Within the cost's rounding, a Newton step `dz` that moves no error function by more
    /// than [`NEGLIGIBLE`] of their size leaves nothing any output can see: the point is
    /// settled. (Gauss–Newton steps there overshoot along the weak directions rather than fall
    /// short, so the step bounds the distance left; the engines' results then agree to about
    /// twice NEGLIGIBLE, far inside what the gauge promises.) A converged LM fit of test 4
    /// stops here at once instead of taking six steps in the rounding.
    fn settled(&self, decrement: f64, dz: &[f64]) -> bool {
        decrement * self.cost <= self.floor && self.negligible.step(&self.free, dz)
    }

    /// Whether [`STALE_STEPS`] steps in a row found no decrement smaller than the best's at a
    /// cost no lower than its by more than the rounding; else the point becomes the best when
    /// it is.
    fn stale(&mut self, decrement: f64) -> bool {
        match &self.best {
            // Below the best's cost by more than the rounding: better, whatever its decrement
            // (steps each within the rounding add up).
            Some((_, d0, c0)) if decrement >= *d0 && self.cost >= c0 - self.floor => {
                self.stale += 1;
                self.stale >= STALE_STEPS
            }
            _ => {
                self.best = Some((self.x.clone(), decrement, self.cost));
                self.stale = 0;
                false
            }
        }
    }

    /// The backtracking line search along `dz` (halved up to [`HALVINGS`] times); `false` when
    /// no step lowered the cost.
    ///
    /// Near the optimum the cost's change falls to its rounding, which resolves the parameters
    /// only to the square root of it over the weakest curvature: once the predicted decrease is
    /// below that rounding, a full step whose cost is equal to it is taken on the gradient's
    /// word. The decrement need not fall at every Newton step (it rose once in five steps on
    /// test 3), so the run goes on until [`STALE_STEPS`] steps in a row find none smaller than
    /// the best, and ends at the best.
    fn line_search(&mut self, dz: &[f64], gz: &[f64], decrement: f64) -> bool {
        let (cost, floor) = (self.cost, self.floor);
        let predicted = decrement * cost;
        self.previous = (predicted > floor).then_some(decrement);
        let mut t = 1.0;
        for _ in 0..HALVINGS {
            let zt: Vec<f64> = self.z.iter().zip(dz).map(|(a, b)| a + t * b).collect();
            if let (xt, Some(c)) = self.cost_at(&zt) {
                let level = t == 1.0 && predicted <= floor && c <= cost + floor && c.is_finite();
                if c < cost || level {
                    if c < cost - floor {
                        // A decrease the rounding cannot explain: the new point is better
                        // whatever its decrement.
                        self.best = None;
                    } else {
                        let taken: Vec<f64> = dz.iter().map(|d| t * d).collect();
                        let slope0 = gz.iter().zip(&taken).map(|(g, d)| g * d).sum();
                        self.level_step = Some((self.z.clone(), taken, slope0));
                    }
                    (self.z, self.x, self.cost) = (zt, xt, c);
                    return true;
                }
            }
            t *= 0.5;
        }
        false
    }
}

/// `dz = −H⁺ g` in the free coordinates, directions below [`FLAT`] of the largest curvature
/// left out (the gauge holds the flat ones; rounding is all that is left there), and directions
/// of negative curvature too (no Newton step along them); and the predicted decrease ½ gᵀH⁺g
/// relative to `cost` (weight_of's w is twice the loss' derivative in ‖r‖², so H is the cost's
/// Hessian).
fn newton(hz: &Mat<f64>, gz: &[f64], cost: f64) -> Result<(Vec<f64>, f64), Unsettled> {
    let nf = gz.len();
    let eh = hz
        .self_adjoint_eigen(Side::Lower)
        .map_err(|_| Unsettled::Decomposition)?;
    let (sv, v) = (eh.S().column_vector(), eh.U());
    let smax = (0..nf).map(|i| sv[i]).fold(0.0_f64, f64::max);
    let mut dz = vec![0.0; nf];
    let mut decrement = 0.0;
    for k in 0..nf {
        if sv[k] <= FLAT * smax {
            continue;
        }
        let c = (0..nf).map(|i| v[(i, k)] * gz[i]).sum::<f64>() / sv[k];
        decrement += c * c * sv[k];
        for (i, dzi) in dz.iter_mut().enumerate() {
            *dzi -= c * v[(i, k)];
        }
    }
    Ok((dz, 0.5 * decrement / cost.max(f64::MIN_POSITIVE)))
}

/// A step of [`settle`] within the cost's rounding that changes the error functions by less than
/// this share of their size (in the gauge's function metric) is negligible.
const NEGLIGIBLE: f64 = 1e-10;

/// The test of a negligible step ([`NEGLIGIBLE`]) from a point p: for a machine problem,
/// `‖Δp‖_M ≤ NEGLIGIBLE · ‖p_f‖_M` in the gauge's function metric M, where `p_f` is `p`
/// without the tracker pose; for a curve fit, `‖Δp‖ ≤ NEGLIGIBLE · ‖p‖`. Never when the size
/// is zero.
struct Negligible {
    /// The gauge's function metric (a machine problem), else the parameters' own norm.
    metric: Option<Mat<f64>>,
    /// The size of the error functions (or parameters) at p.
    size: f64,
}

impl Negligible {
    /// The test at `p`.
    fn at(problem: &dyn Residuals, p: &[f64]) -> Negligible {
        let n = p.len();
        match problem.machine() {
            Some(machine) => {
                let model = machine.model();
                let m = crate::engines::gauge::problem_metric(machine, p);
                let t = model.tracker_start();
                let pf: Vec<f64> = (0..n)
                    .map(|j| if (t..t + 6).contains(&j) { 0.0 } else { p[j] })
                    .collect();
                let size = quadratic(&m, &pf).sqrt();
                Negligible {
                    metric: Some(m),
                    size,
                }
            }
            None => Negligible {
                metric: None,
                size: p.iter().map(|v| v * v).sum::<f64>().sqrt(),
            },
        }
    }

    /// Whether the step `dz` in `free`'s coordinates is negligible.
    fn step(&self, free: &Free, dz: &[f64]) -> bool {
        let dp = free.direction(dz);
        let step = match &self.metric {
            Some(m) => quadratic(m, &dp).sqrt(),
            None => dp.iter().map(|v| v * v).sum::<f64>().sqrt(),
        };
        self.size > 0.0 && step <= NEGLIGIBLE * self.size
    }
}

/// `vᵀ M v`.
fn quadratic(m: &Mat<f64>, v: &[f64]) -> f64 {
    let n = v.len();
    (0..n)
        .map(|i| v[i] * (0..n).map(|j| m[(i, j)] * v[j]).sum::<f64>())
        .sum()
}

/// Directions of the Gauss–Newton matrix whose curvature is below this share of the largest
/// get the exact second-order term in [`settle`].
const WEAK: f64 = 1e-3;

/// At most this many weak directions get it (the weakest).
const MAX_WEAK: usize = 16;

/// `hz` (the Gauss–Newton matrix of the cost in the scaled free coordinates, `p = D (s₀ + N z)`)
/// with the exact second-order term `Σ_i ψ_iᵀ ∂²r_i` added on the span of its weakest
/// eigenvectors (curvature below [`WEAK`] of the largest, at most [`MAX_WEAK`]): each entry by
/// polarisation of exact second directional derivatives of the residuals
/// ([`Residuals::residual_second_directional`]), `k (k + 1) / 2` passes for `k` directions.
fn weak_second_order(
    problem: &dyn Residuals,
    x: &[f64],
    d: &[f64],
    basis: faer::MatRef<'_, f64>,
    hz: &Mat<f64>,
    objective: Objective,
    eps: f64,
) -> Option<Mat<f64>> {
    let (n, nf, np) = (x.len(), hz.nrows(), problem.n_points());
    let eh = hz.self_adjoint_eigen(Side::Lower).ok()?;
    let (sv, v) = (eh.S().column_vector(), eh.U());
    let smax = (0..nf).map(|i| sv[i]).fold(0.0_f64, f64::max);
    let weak: Vec<usize> = (0..nf)
        .filter(|&i| sv[i] < WEAK * smax)
        .take(MAX_WEAK)
        .collect();
    let k = weak.len();
    if k == 0 {
        return Some(hz.clone());
    }
    let dirs: Vec<Vec<f64>> = weak
        .iter()
        .map(|&c| {
            (0..n)
                .map(|i| d[i] * (0..nf).map(|r| basis[(i, r)] * v[(r, c)]).sum::<f64>())
                .collect()
        })
        .collect();
    // ψ_i = w_i r_i, the cost's gradient in r_i.
    let psi: Vec<[f64; 3]> = (0..np)
        .map(|i| {
            let r = problem.residual(i, x);
            let (w, _) = weight_of(objective, volver_core::problem::norm(r), eps, np);
            r.map(|c| w * c)
        })
        .collect();
    // q(u) = Σ_i ψ_iᵀ d²r_i/dt² along u.
    let q = |u: &[f64]| -> f64 {
        (0..np)
            .map(|i| {
                let r2 = problem.residual_second_directional(i, x, u);
                psi[i][0] * r2[0] + psi[i][1] * r2[1] + psi[i][2] * r2[2]
            })
            .sum()
    };
    let diag: Vec<f64> = dirs.iter().map(|u| q(u)).collect();
    let mut s = Mat::<f64>::zeros(k, k);
    for a in 0..k {
        s[(a, a)] = diag[a];
        for b in 0..a {
            let sum: Vec<f64> = dirs[a].iter().zip(&dirs[b]).map(|(p, q)| p + q).collect();
            let e = 0.5 * (q(&sum) - diag[a] - diag[b]);
            s[(a, b)] = e;
            s[(b, a)] = e;
        }
    }
    if (0..k).any(|a| (0..k).any(|b| !s[(a, b)].is_finite())) {
        return None;
    }
    let vw = Mat::from_fn(nf, k, |r, c| v[(r, weak[c])]);
    Some(hz + &vw * (&s * vw.transpose()))
}

#[cfg(test)]
mod tests;
