//! The expert Ceres program (`ceres/expert.cpp`): the paper's identification written for Ceres
//! Solver the way its experts write it, the reference the bench measures the native engine
//! against. This side prepares what an expert computes once before the solve (the fixed
//! regressors of every point, the model's constraints eliminated by substitution) and maps the
//! free coefficients back to the model's parameters.

// Linked for libceres and libglog, which the program needs (its build metadata gave the headers).
use volver_ceres_sys as _;

use std::ffi::CStr;
use std::os::raw::{c_char, c_int};
use std::time::Instant;
use volver_core::iso::ErrorId;
use volver_core::kinematics::TRACKER_DOF;
use volver_core::machine::TrackerMount;
use volver_core::problem::{Problem, Residuals};

/// Error values of the paper's XCFZ model (the program is written for that machine and model).
const ERRORS: usize = 20;
/// Values of a point: the errors, then the tracker pose.
const SLOTS: usize = ERRORS + TRACKER_DOF;

#[repr(C)]
struct RawProblem {
    offset: [[f64; 3]; 3],
    z_reference: f64,
    base_rotation: [[f64; 3]; 3],
    slot_axis: [c_int; ERRORS],
    slot_location: [c_int; ERRORS],
    slot_component: [c_int; ERRORS],
    points: c_int,
    free: c_int,
    commands: *const f64,
    reflectors: *const f64,
    measured: *const f64,
    constant: *const f64,
    regressor: *const f64,
    slot_of: *const c_int,
}

#[repr(C)]
struct RawResult {
    iterations: c_int,
    converged: c_int,
    solve_s: f64,
    initial_emm_mm: f64,
    final_emm_mm: f64,
    trace_len: c_int,
    trace_time_s: *mut f64,
    trace_cost: *mut f64,
    max_trace: c_int,
}

unsafe extern "C" {
    fn volver_expert_fit(
        p: *const RawProblem,
        z: *mut f64,
        threads: c_int,
        eps: f64,
        out: *mut RawResult,
    ) -> c_int;
    fn volver_expert_emm(p: *const RawProblem, z: *const f64) -> f64;
    fn volver_expert_message() -> *const c_char;
}

/// How a parameter of the model is expressed in the program's free coefficients.
#[derive(Clone, Debug)]
enum Role {
    /// Free: the k-th coefficient.
    Free(usize),
    /// Held at a value.
    Fixed(f64),
    /// Eliminated by the constraint `Σ a_j p_j = rhs` (its own coefficient `a`).
    Pivot {
        row: Vec<(usize, f64)>,
        rhs: f64,
        a: f64,
    },
}

/// The program's view of a problem, ready to fit.
pub struct Expert {
    roles: Vec<Role>,
    /// The model parameter of each free coefficient.
    free: Vec<usize>,
    commands: Vec<f64>,
    reflectors: Vec<f64>,
    measured: Vec<f64>,
    constant: Vec<f64>,
    regressor: Vec<f64>,
    slot_of: Vec<c_int>,
    raw: RawProblem,
    /// Time to prepare the regressors (s): part of the program's work.
    pub setup_s: f64,
}

/// One fit of the program.
#[derive(Clone, Debug)]
pub struct ExpertFit {
    /// The model's parameters at the end.
    pub params: Vec<f64>,
    /// Ceres' iterations (successful and unsuccessful steps).
    pub iterations: usize,
    /// Whether Ceres reports convergence.
    pub converged: bool,
    /// Wall time of Ceres' `Solve` with the problem's construction (s).
    pub solve_s: f64,
    /// Mean ‖r_i‖ at the start and at the end (mm), computed by the program.
    pub initial_emm_mm: f64,
    /// See `initial_emm_mm`.
    pub final_emm_mm: f64,
    /// Per iteration: Ceres' cumulative time (s) and EMM (mm, from its cost: within ε of the
    /// exact EMM).
    pub trace: Vec<(f64, f64)>,
    /// Ceres' termination message.
    pub message: String,
}

/// Errs unless `problem` is the paper's model on the XCFZ machine with the tracker on the
/// workpiece side (what the program is written for).
fn check_machine(problem: &Problem) -> Result<(), String> {
    let model = problem.model();
    let machine = model.machine();
    let chain: String = machine.axes().iter().map(|a| a.axis.letter()).collect();
    if chain != "XCZ" || machine.tracker().mount != TrackerMount::Workpiece {
        return Err(format!(
            "the expert program is written for XCFZ with the tracker on the workpiece side, \
             not {chain}"
        ));
    }
    let terms = model.terms();
    if terms.len() != ERRORS {
        return Err(format!(
            "the expert program is written for the paper's {ERRORS} errors, not {}",
            terms.len()
        ));
    }
    Ok(())
}

/// The value (error slot, then tracker pose) each parameter of `model` enters.
fn slots_of(model: &volver_core::model::Model) -> Result<Vec<usize>, String> {
    let n = model.params().len();
    let ts = model.tracker_start();
    let mut slot_of_param = vec![usize::MAX; n];
    for (s, t) in model.terms().iter().enumerate() {
        for j in t.params.clone() {
            slot_of_param[j] = s;
        }
    }
    for k in 0..TRACKER_DOF {
        slot_of_param[ts + k] = ERRORS + k;
    }
    if let Some(j) = slot_of_param.iter().position(|&s| s == usize::MAX) {
        return Err(format!("parameter {j} enters no value the program knows"));
    }
    Ok(slot_of_param)
}

/// Each parameter's role and the free ones, from the problem's constraints: a one-term row
/// holds its parameter, a longer one (all in one value) eliminates its largest coefficient's
/// parameter.
fn roles_of(problem: &Problem, slot_of_param: &[usize]) -> Result<(Vec<Role>, Vec<usize>), String> {
    let n = slot_of_param.len();
    let mut roles: Vec<Option<Role>> = vec![None; n];
    for row in &problem.constraints().rows {
        let (j, a) = row
            .coeffs
            .iter()
            .copied()
            .max_by(|x, y| x.1.abs().total_cmp(&y.1.abs()))
            .ok_or("an empty constraint row")?;
        if row
            .coeffs
            .iter()
            .any(|&(i, _)| slot_of_param[i] != slot_of_param[j] || roles[i].is_some())
        {
            return Err(format!(
                "constraint `{}` spans several values or shares a parameter",
                row.label
            ));
        }
        roles[j] = Some(if row.coeffs.len() == 1 {
            Role::Fixed(row.rhs / a)
        } else {
            Role::Pivot {
                row: row.coeffs.clone(),
                rhs: row.rhs,
                a,
            }
        });
    }
    let mut free = Vec::new();
    let roles: Vec<Role> = roles
        .into_iter()
        .enumerate()
        .map(|(j, r)| {
            r.unwrap_or_else(|| {
                free.push(j);
                Role::Free(free.len() - 1)
            })
        })
        .collect();
    Ok((roles, free))
}

/// The program's data of every point: its commands, reflector and measurement, the constant
/// part of each value and each free coefficient's regressor.
struct Regressors {
    commands: Vec<f64>,
    reflectors: Vec<f64>,
    measured: Vec<f64>,
    /// `SLOTS` per point.
    constant: Vec<f64>,
    /// `nf` per point.
    regressor: Vec<f64>,
}

impl Regressors {
    /// The data of `problem`'s points at the start `p`, with the parameters' `roles` and slots
    /// and `nf` free coefficients. The regressor of each parameter at each point is its
    /// value's derivative (the values are linear in their coefficients; checked at `p`).
    fn of(
        problem: &Problem,
        p: &[f64],
        roles: &[Role],
        slot_of_param: &[usize],
        nf: usize,
    ) -> Result<Regressors, String> {
        let (model, data) = (problem.model(), problem.data());
        let machine = model.machine();
        let n = roles.len();
        let np = data.points.len();
        let (mut unit, mut basis) = (vec![0.0; n], vec![0.0; n]);
        let mut out = Regressors {
            commands: Vec::with_capacity(3 * np),
            reflectors: Vec::with_capacity(3 * np),
            measured: Vec::with_capacity(3 * np),
            constant: vec![0.0; np * SLOTS],
            regressor: vec![0.0; np * nf],
        };
        for (i, m) in data.points.iter().enumerate() {
            value_basis(model, &m.commands.0[..], p, (&mut unit, &mut basis))?;
            let c = &mut out.constant[i * SLOTS..(i + 1) * SLOTS];
            let g = &mut out.regressor[i * nf..(i + 1) * nf];
            for (j, role) in roles.iter().enumerate() {
                let s = slot_of_param[j];
                match role {
                    Role::Free(k) => g[*k] += basis[j],
                    Role::Fixed(v) => c[s] += basis[j] * v,
                    // p_j = (rhs − Σ_{i≠j} a_i p_i) / a.
                    Role::Pivot { row, rhs, a } => {
                        c[s] += basis[j] * rhs / a;
                        for &(i, ai) in row.iter().filter(|(i, _)| *i != j) {
                            match roles[i] {
                                Role::Free(k) => g[k] -= basis[j] * ai / a,
                                _ => return Err("a pivot row holds a non-free parameter".into()),
                            }
                        }
                    }
                }
            }
            let refl = machine.reflectors()[m.reflector].offset;
            out.commands.extend_from_slice(&m.commands.0[..3]);
            out.reflectors.extend_from_slice(&refl);
            out.measured.extend_from_slice(&m.measured);
        }
        Ok(out)
    }
}

/// Each parameter's derivative of the value it enters at the axis positions `commands` into
/// `basis` (1 for the tracker pose), checking at `p` that the values are linear in their
/// coefficients; `unit` is zeros of the parameters' length (left so).
fn value_basis(
    model: &volver_core::model::Model,
    commands: &[f64],
    p: &[f64],
    (unit, basis): (&mut [f64], &mut [f64]),
) -> Result<(), String> {
    for (s, t) in model.terms().iter().enumerate() {
        let position = commands[t.axis];
        for j in t.params.clone() {
            unit[j] = 1.0;
            basis[j] = model
                .error_value(t.id, position, unit)
                .ok_or("an error the model does not hold")?;
            unit[j] = 0.0;
        }
        let direct = model.error_value(t.id, position, p).unwrap_or(f64::NAN);
        let linear: f64 = t.params.clone().map(|j| basis[j] * p[j]).sum();
        if (direct - linear).abs() > 1e-12 * (1.0 + direct.abs()) {
            return Err(format!(
                "error {s} is not linear in its coefficients: {direct} vs {linear}"
            ));
        }
    }
    let ts = model.tracker_start();
    for k in 0..TRACKER_DOF {
        basis[ts + k] = 1.0;
    }
    Ok(())
}

/// The program's problem header for `problem` with `nf` free coefficients (the data pointers
/// null until the buffers are in place).
fn raw_problem(problem: &Problem, nf: usize) -> RawProblem {
    let model = problem.model();
    let machine = model.machine();
    let axes = machine.axes();
    let mut raw = RawProblem {
        offset: [axes[0].offset, axes[1].offset, axes[2].offset],
        z_reference: axes[2].reference,
        base_rotation: machine.tracker().base_rotation,
        slot_axis: [0; ERRORS],
        slot_location: [0; ERRORS],
        slot_component: [0; ERRORS],
        points: problem.data().points.len() as c_int,
        free: nf as c_int,
        commands: std::ptr::null(),
        reflectors: std::ptr::null(),
        measured: std::ptr::null(),
        constant: std::ptr::null(),
        regressor: std::ptr::null(),
        slot_of: std::ptr::null(),
    };
    for (s, t) in model.terms().iter().enumerate() {
        raw.slot_axis[s] = t.axis as c_int;
        raw.slot_location[s] = matches!(t.id, ErrorId::Location { .. }) as c_int;
        raw.slot_component[s] = t.id.component().index() as c_int;
    }
    raw
}

impl Expert {
    /// Prepares `problem` (the paper's model on the XCFZ machine) from the start `p` (the
    /// tracker already fitted, as volver's identification does first). Errs on another machine
    /// or model, or a constraint the program does not eliminate (one spanning several errors).
    ///
    /// Nothing else is held: like Ceres users, the program leaves the combinations the data
    /// cannot identify to the damping (volver holds them by its gauge).
    pub fn new(problem: &Problem, p: &[f64]) -> Result<Expert, String> {
        let t0 = Instant::now();
        let model = problem.model();
        check_machine(problem)?;
        let slot_of_param = slots_of(model)?;
        let (roles, free) = roles_of(problem, &slot_of_param)?;
        let data = Regressors::of(problem, p, &roles, &slot_of_param, free.len())?;
        let slot_of: Vec<c_int> = free.iter().map(|&j| slot_of_param[j] as c_int).collect();
        let raw = raw_problem(problem, free.len());
        let mut e = Expert {
            roles,
            free,
            commands: data.commands,
            reflectors: data.reflectors,
            measured: data.measured,
            constant: data.constant,
            regressor: data.regressor,
            slot_of,
            raw,
            setup_s: 0.0,
        };
        e.raw.commands = e.commands.as_ptr();
        e.raw.reflectors = e.reflectors.as_ptr();
        e.raw.measured = e.measured.as_ptr();
        e.raw.constant = e.constant.as_ptr();
        e.raw.regressor = e.regressor.as_ptr();
        e.raw.slot_of = e.slot_of.as_ptr();
        e.setup_s = t0.elapsed().as_secs_f64();
        Ok(e)
    }

    /// The free coefficients of the model's parameters `p`.
    pub fn coefficients(&self, p: &[f64]) -> Vec<f64> {
        self.free.iter().map(|&j| p[j]).collect()
    }

    /// The model's parameters of the free coefficients `z`.
    pub fn params(&self, z: &[f64]) -> Vec<f64> {
        let mut p: Vec<f64> = self
            .roles
            .iter()
            .map(|r| match r {
                Role::Free(k) => z[*k],
                Role::Fixed(v) => *v,
                Role::Pivot { .. } => 0.0,
            })
            .collect();
        for (j, r) in self.roles.iter().enumerate() {
            if let Role::Pivot { row, rhs, a } = r {
                let rest: f64 = row
                    .iter()
                    .filter(|(i, _)| *i != j)
                    .map(|&(i, ai)| ai * p[i])
                    .sum();
                p[j] = (rhs - rest) / a;
            }
        }
        p
    }

    /// The EMM (mm) the program computes at the model's parameters `p`.
    pub fn emm(&self, p: &[f64]) -> f64 {
        let z = self.coefficients(p);
        // SAFETY: `raw` points into buffers `self` owns; `z` holds `free` values.
        unsafe { volver_expert_emm(&self.raw, z.as_ptr()) }
    }

    /// Fits from the model's parameters `start` on `threads` threads with the module loss
    /// smoothed at `eps` mm.
    pub fn fit(&self, start: &[f64], threads: usize, eps: f64) -> Result<ExpertFit, String> {
        let mut z = self.coefficients(start);
        let max_trace = 1000;
        let (mut times, mut costs) = (vec![0.0; max_trace], vec![0.0; max_trace]);
        let mut out = RawResult {
            iterations: 0,
            converged: 0,
            solve_s: 0.0,
            initial_emm_mm: 0.0,
            final_emm_mm: 0.0,
            trace_len: 0,
            trace_time_s: times.as_mut_ptr(),
            trace_cost: costs.as_mut_ptr(),
            max_trace: max_trace as c_int,
        };
        // SAFETY: every pointer is valid for the lengths the program reads (`raw` into buffers
        // `self` owns, `z` of `free` values, the trace of `max_trace`); the program does not keep
        // them after returning.
        let status = unsafe {
            volver_expert_fit(&self.raw, z.as_mut_ptr(), threads as c_int, eps, &mut out)
        };
        // SAFETY: the program returns a NUL-terminated string it owns (thread-local).
        let message = unsafe { CStr::from_ptr(volver_expert_message()) }
            .to_string_lossy()
            .into_owned();
        if status != 0 {
            return Err(message);
        }
        let np = self.measured.len() / 3;
        let trace = (0..out.trace_len as usize)
            // cost = Σ (‖r‖_ε − ε), so the smoothed EMM is cost / n + ε.
            .map(|k| (times[k], costs[k] / np as f64 + eps))
            .collect();
        Ok(ExpertFit {
            params: self.params(&z),
            iterations: out.iterations as usize,
            converged: out.converged != 0,
            solve_s: out.solve_s,
            initial_emm_mm: out.initial_emm_mm,
            final_emm_mm: out.final_emm_mm,
            trace,
            message,
        })
    }
}
