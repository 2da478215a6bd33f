//! The chain's exact derivative with respect to every error value at a point, by a hand-derived
//! reverse pass in `f64`: each map of the chain (an axis, the tracker) records its own 3 × 3
//! derivatives on the way out, and one backward sweep multiplies them by the derivative of
//! everything after it. This is what [`crate::model::Model::predict_with_jacobian`] runs per
//! point; the generic [`super::predict`] with dual numbers gives the same numbers (tested) at
//! several times the cost.
//!
//! The derivatives used (notation of the module above, `[v]×` the cross-product matrix):
//!
//! * `R(w)·v = v + [v]×·w`, so `∂(R(w)·v)/∂w = [v]×`;
//! * `R⁻¹(w)·v = N/D` with `N = v + w×v + w(w·v)`, `D = 1 + |w|²`:
//!   `∂(R⁻¹(w)·v)/∂w = ((w·v)·I − [v]× + w·vᵀ − 2·(R⁻¹(w)·v)·wᵀ)/D`;
//! * about a rotary axis' line, `y = L + R⁻¹(Ω)·Rg·R(Ω)·(v − L)`: `∂y/∂v = R⁻¹(Ω)·Rg·R(Ω)`,
//!   `∂y/∂L = I − ∂y/∂v`, `∂y/∂Ω = ∂(R⁻¹(Ω)·b)/∂Ω + R⁻¹(Ω)·Rg·[v − L]×` with `b = Rg·R(Ω)·(v − L)`.

use super::{PointErrors, TRACKER_DOF, V3, add, head3, rot_err, rot_err_inv, sub, tail3};
use crate::chain::{MAX_AXES, Side};
use crate::machine::{Commands, Machine, TrackerMount};

type M3 = [[f64; 3]; 3];

const IDENTITY: M3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
const ZERO3: M3 = [[0.0; 3]; 3];

/// ∂(point)/∂(error value) for every field of [`PointErrors`]: each entry is the column
/// `[∂x, ∂y, ∂z]` (mm per mm or per rad) of the point [`predict_with_errors_jacobian`] or
/// [`tool_in_workpiece_with_errors_jacobian`] returns. Entries of axes the chain does not have,
/// and of location errors an axis does not carry, are zero.
#[derive(Clone, Debug, PartialEq)]
pub struct ErrorsJacobian {
    /// By chain position and ISO component EX, EY, EZ, EA, EB, EC.
    pub component: [[[f64; 3]; 6]; MAX_AXES],
    /// By chain position and component X0·, Y0·, Z0·, A0·, B0·, C0·.
    pub location: [[[f64; 3]; 6]; MAX_AXES],
    /// The tracker pose x, y, z, rx, ry, rz.
    pub tracker: [[f64; 3]; TRACKER_DOF],
    /// The tool shift (machine frame) x, y, z.
    pub tool_shift: [[f64; 3]; 3],
    /// The reflector's offset error x, y, z.
    pub reflector_delta: [[f64; 3]; 3],
    /// The tracker's range scale.
    pub range_scale: [f64; 3],
}

impl ErrorsJacobian {
    fn zero() -> Self {
        ErrorsJacobian {
            component: [[[0.0; 3]; 6]; MAX_AXES],
            location: [[[0.0; 3]; 6]; MAX_AXES],
            tracker: [[0.0; 3]; TRACKER_DOF],
            tool_shift: [[0.0; 3]; 3],
            reflector_delta: [[0.0; 3]; 3],
            range_scale: [0.0; 3],
        }
    }
}

#[inline]
fn mat_mul(a: &M3, b: &M3) -> M3 {
    let mut out = ZERO3;
    for (i, row) in out.iter_mut().enumerate() {
        for (j, o) in row.iter_mut().enumerate() {
            *o = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    out
}

#[inline]
fn mat_vec(a: &M3, v: &V3<f64>) -> V3<f64> {
    [0, 1, 2].map(|i| a[i][0] * v[0] + a[i][1] * v[1] + a[i][2] * v[2])
}

#[inline]
fn column(a: &M3, j: usize) -> V3<f64> {
    [a[0][j], a[1][j], a[2][j]]
}

#[inline]
fn neg(a: &M3) -> M3 {
    a.map(|r| r.map(|x| -x))
}

/// `[v]×`: the matrix of `u ↦ v × u`.
#[inline]
fn skew(v: &V3<f64>) -> M3 {
    [[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]]
}

/// The matrix of `R(w) = I − [w]×` (eq. 4).
#[inline]
fn r_mat(w: &V3<f64>) -> M3 {
    [[1.0, w[2], -w[1]], [-w[2], 1.0, w[0]], [w[1], -w[0], 1.0]]
}

/// The matrix of `R⁻¹(w) = (I + [w]× + w·wᵀ)/(1 + |w|²)`.
#[inline]
fn r_inv_mat(w: &V3<f64>) -> M3 {
    let inv = 1.0 / (1.0 + w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    let s = skew(w);
    let mut m = ZERO3;
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = (IDENTITY[i][j] + s[i][j] + w[i] * w[j]) * inv;
        }
    }
    m
}

/// `∂(R⁻¹(w)·v)/∂w`.
#[inline]
fn d_r_inv(w: &V3<f64>, v: &V3<f64>) -> M3 {
    let d = 1.0 + w[0] * w[0] + w[1] * w[1] + w[2] * w[2];
    let wv = w[0] * v[0] + w[1] * v[1] + w[2] * v[2];
    let y = rot_err_inv(*w, *v);
    let sv = skew(v);
    let mut m = ZERO3;
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = (IDENTITY[i][j] * wv - sv[i][j] + w[i] * v[j] - 2.0 * y[i] * w[j]) / d;
        }
    }
    m
}

/// The matrix of the nominal rotation about coordinate direction `dir`.
#[inline]
fn rot_nominal_mat(dir: usize, sin: f64, cos: f64) -> M3 {
    let (b, c) = ((dir + 1) % 3, (dir + 2) % 3);
    let mut m = IDENTITY;
    m[b][b] = cos;
    m[b][c] = -sin;
    m[c][b] = sin;
    m[c][c] = cos;
    m
}

/// One map of the chain with its derivatives: with respect to its input point (`jq`), the
/// axis' translation errors EX·, EY·, EZ· (`jt`), its angular errors EA·, EB·, EC· (`jw`), and
/// its location errors (`jl`: X0·, Y0·, Z0·; `jo`: A0·, B0·, C0·, the squareness of a linear
/// axis or the orientation of a rotary one).
#[derive(Clone, Copy)]
struct Step {
    k: usize,
    jq: M3,
    jt: M3,
    jw: M3,
    jl: M3,
    jo: M3,
}

const NO_STEP: Step = Step {
    k: 0,
    jq: ZERO3,
    jt: ZERO3,
    jw: ZERO3,
    jl: ZERO3,
    jo: ZERO3,
};

/// Rotation by (sin, cos) about rotary axis k's line, `L + R⁻¹(Ω)·Rg·R(Ω)·(v − L)`, with its
/// derivatives (v, L, Ω).
#[inline]
fn line_rotation(
    dir: usize,
    sin: f64,
    cos: f64,
    e: &PointErrors<f64>,
    k: usize,
    v: V3<f64>,
) -> (V3<f64>, M3, M3, M3) {
    let rg = rot_nominal_mat(dir, sin, cos);
    if !e.has_location[k] {
        return (mat_vec(&rg, &v), rg, ZERO3, ZERO3);
    }
    let l = head3(&e.location[k]);
    let om = tail3(&e.location[k]);
    let vv = sub(v, l);
    let b = mat_vec(&rg, &rot_err(om, vv));
    let out = add(l, rot_err_inv(om, b));
    let ri = r_inv_mat(&om);
    let ri_rg = mat_mul(&ri, &rg);
    let jq = mat_mul(&ri_rg, &r_mat(&om));
    let mut jl = neg(&jq);
    for (i, row) in jl.iter_mut().enumerate() {
        row[i] += 1.0;
    }
    let d = d_r_inv(&om, &b);
    let t = mat_mul(&ri_rg, &skew(&vv));
    let mut jo = ZERO3;
    for i in 0..3 {
        for j in 0..3 {
            jo[i][j] = d[i][j] + t[i][j];
        }
    }
    (out, jq, jl, jo)
}

/// Translation `O_k + t_k` of axis k and the derivative of `t_k` with respect to the squareness
/// values `location[k][3..6]` (columns; zero for a rotary axis).
#[inline]
fn translation(machine: &Machine, k: usize, u: f64, e: &PointErrors<f64>) -> (V3<f64>, M3) {
    let ax = &machine.axes()[k];
    let t = super::axis_translation(machine, k, u, e);
    let mut sq = ZERO3;
    if !ax.axis.is_rotary() && e.has_location[k] {
        let a = ax.axis.direction();
        let rel = (u - ax.reference) * ax.side.sign();
        for r in (0..3).filter(|&r| r != a) {
            sq[3 - r - a][r] = -rel;
        }
    }
    (t, sq)
}

/// Sine and cosine of rotary axis k's chain angle: the point's own when it has them
/// ([`PointErrors::rotary_sin_cos`]), else computed.
#[inline]
fn sin_cos_of(e: &PointErrors<f64>, k: usize, angle: f64) -> (f64, f64) {
    match e.rotary_sin_cos {
        Some(t) => (t[k][0], t[k][1]),
        None => angle.sin_cos(),
    }
}

/// Axis k's own frame → the frame it rides on (tool side), with the step's derivatives.
fn forward_step(
    machine: &Machine,
    k: usize,
    u: f64,
    e: &PointErrors<f64>,
    q: V3<f64>,
) -> (V3<f64>, Step) {
    let ax = &machine.axes()[k];
    let (t, sq) = translation(machine, k, u, e);
    let w = tail3(&e.component[k]);
    let (inner, jr, jl, jo) = if ax.axis.is_rotary() {
        let (sin, cos) = sin_cos_of(e, k, u * ax.side.sign());
        line_rotation(ax.axis.direction(), sin, cos, e, k, q)
    } else {
        (q, IDENTITY, ZERO3, ZERO3)
    };
    let ri = r_inv_mat(&w);
    let step = Step {
        k,
        jq: mat_mul(&ri, &jr),
        jt: IDENTITY,
        jw: d_r_inv(&w, &inner),
        jl: mat_mul(&ri, &jl),
        jo: if ax.axis.is_rotary() {
            mat_mul(&ri, &jo)
        } else {
            sq
        },
    };
    // The value as the generic chain computes it (bit for bit), not through the matrix.
    (add(t, rot_err_inv(w, inner)), step)
}

/// The frame axis k rides on → axis k's own frame (workpiece side), with the step's derivatives.
fn inverse_step(
    machine: &Machine,
    k: usize,
    u: f64,
    e: &PointErrors<f64>,
    p: V3<f64>,
) -> (V3<f64>, Step) {
    let ax = &machine.axes()[k];
    let (t, sq) = translation(machine, k, u, e);
    let w = tail3(&e.component[k]);
    let d = sub(p, t);
    let y = rot_err(w, d);
    let (out, jr, jl, jo) = if ax.axis.is_rotary() {
        let (sin, cos) = sin_cos_of(e, k, u * -ax.side.sign());
        line_rotation(ax.axis.direction(), sin, cos, e, k, y)
    } else {
        (y, IDENTITY, ZERO3, ZERO3)
    };
    let jq = mat_mul(&jr, &r_mat(&w));
    let step = Step {
        k,
        jt: neg(&jq),
        jw: mat_mul(&jr, &skew(&d)),
        jl,
        // ∂out/∂t · ∂t/∂(squareness) for a linear axis.
        jo: if ax.axis.is_rotary() {
            jo
        } else {
            mat_mul(&neg(&jq), &sq)
        },
        jq,
    };
    (out, step)
}

/// Sweeps back through the recorded steps: `a` is ∂x/∂(output of the last step); each step's
/// error columns are `a · J`, then `a ← a · jq`. Returns ∂x/∂(input of the first step).
fn sweep_back(steps: &[Step], mut a: M3, e: &PointErrors<f64>, out: &mut ErrorsJacobian) -> M3 {
    for s in steps.iter().rev() {
        let (jt, jw) = (mat_mul(&a, &s.jt), mat_mul(&a, &s.jw));
        for c in 0..3 {
            out.component[s.k][c] = column(&jt, c);
            out.component[s.k][3 + c] = column(&jw, c);
        }
        if e.has_location[s.k] {
            let (jl, jo) = (mat_mul(&a, &s.jl), mat_mul(&a, &s.jo));
            for c in 0..3 {
                out.location[s.k][c] = column(&jl, c);
                out.location[s.k][3 + c] = column(&jo, c);
            }
        }
        a = mat_mul(&a, &s.jq);
    }
    a
}

/// The chain of [`super::chain_point`] with the derivative of its end point: returns the point
/// and fills the axes' (and, through `a_end`, the caller's) columns. `a_end` is ∂x/∂(chain end).
fn chain_with_jacobian(
    machine: &Machine,
    commands: &Commands,
    start: &[f64; 3],
    e: &PointErrors<f64>,
    into_workpiece: bool,
    tail: impl FnOnce(V3<f64>, &mut ErrorsJacobian) -> (V3<f64>, M3),
    out: &mut ErrorsJacobian,
) -> V3<f64> {
    let axes = machine.axes();
    let u = &commands.0;
    // One step per axis: the tool side's first, then the workpiece side's.
    let mut steps = [NO_STEP; MAX_AXES];
    let mut n = 0;
    let mut p = add(*start, e.reflector_delta);
    for k in (0..axes.len())
        .rev()
        .filter(|&k| axes[k].side == Side::Tool)
    {
        (p, steps[n]) = forward_step(machine, k, u[k], e, p);
        n += 1;
    }
    let n_tool = n;
    p = add(p, e.tool_shift);
    if into_workpiece {
        for k in (0..axes.len()).filter(|&k| axes[k].side == Side::Workpiece) {
            (p, steps[n]) = inverse_step(machine, k, u[k], e, p);
            n += 1;
        }
    }
    let (x, a_end) = tail(p, out);
    let a = sweep_back(&steps[n_tool..n], a_end, e, out);
    out.tool_shift = [0, 1, 2].map(|c| column(&a, c));
    let a = sweep_back(&steps[..n_tool], a, e, out);
    out.reflector_delta = [0, 1, 2].map(|c| column(&a, c));
    x
}

/// [`super::predict`] in `f64` and ∂(predicted point)/∂(every error value), exactly.
///
/// ```
/// use volver_core::kinematics::{predict, predict_with_errors_jacobian, PointErrors};
/// use volver_core::machine::Machine;
/// let m = Machine::default_xcfz();
/// let cmd = m.commands_from_file_units(&[700.0, 90.0, 300.0]);
/// let mut e = PointErrors::<f64>::zero();
/// e.component[0][0] = 0.01; // EXX = 10 µm
/// let (x, jac) = predict_with_errors_jacobian(&m, &cmd, &m.reflectors()[1].offset, &e);
/// assert_eq!(x, predict(&m, &cmd, &m.reflectors()[1].offset, &e));
/// // The tracker translation moves the point by minus itself (no tracker rotation here).
/// assert_eq!(jac.tracker[0], [-1.0, 0.0, 0.0]);
/// ```
pub fn predict_with_errors_jacobian(
    machine: &Machine,
    commands: &Commands,
    reflector: &[f64; 3],
    errors: &PointErrors<f64>,
) -> ([f64; 3], ErrorsJacobian) {
    let mut out = ErrorsJacobian::zero();
    let tracker = &machine.stations()[errors.station].setup;
    let into_workpiece = tracker.mount == TrackerMount::Workpiece;
    let e = errors;
    let x = chain_with_jacobian(
        machine,
        commands,
        reflector,
        e,
        into_workpiece,
        |p, out| {
            // x = (1 + s)·R⁻¹(r)·R0ᵀ·(p − T)
            let d = sub(p, head3(&e.tracker));
            let r0 = &tracker.base_rotation;
            let r0t: M3 = [0, 1, 2].map(|i| [r0[0][i], r0[1][i], r0[2][i]]);
            let local = mat_vec(&r0t, &d);
            let r = tail3(&e.tracker);
            let xr = rot_err_inv(r, local);
            let scale = 1.0 + e.range_scale;
            let a = mat_mul(&r_inv_mat(&r), &r0t).map(|row| row.map(|v| v * scale));
            let dr = d_r_inv(&r, &local);
            for c in 0..3 {
                out.tracker[c] = column(&a, c).map(|v| -v);
                out.tracker[3 + c] = column(&dr, c).map(|v| v * scale);
            }
            out.range_scale = xr;
            (xr.map(|v| v * scale), a)
        },
        &mut out,
    );
    (x, out)
}

/// [`super::tool_in_workpiece`] in `f64` and ∂(tool point)/∂(every error value), exactly, as
/// [`crate::model::Model::tool_point`] uses it: the measurement's values (tracker pose,
/// reflector offset, range scale) take no part (their values are ignored, their columns are
/// zero); the tool shift does, since a field over the axes is the machine's (a drift, also a
/// tool shift, is zero at the test's start where the model takes the tool point).
///
/// ```
/// use volver_core::kinematics::{tool_in_workpiece, tool_in_workpiece_with_errors_jacobian, PointErrors};
/// use volver_core::machine::Machine;
/// let m = Machine::default_xcfz();
/// let cmd = m.commands_from_file_units(&[700.0, 0.0, 300.0]);
/// let e = PointErrors::<f64>::zero();
/// let (x, jac) = tool_in_workpiece_with_errors_jacobian(&m, &cmd, &[0.0; 3], &e);
/// assert_eq!(x, tool_in_workpiece(&m, &cmd.0, &[0.0; 3], &e));
/// // EXX moves the workpiece: seen from it at C = 0 the tool moves by −EXX along x.
/// assert_eq!(jac.component[0][0], [-1.0, 0.0, 0.0]);
/// ```
pub fn tool_in_workpiece_with_errors_jacobian(
    machine: &Machine,
    commands: &Commands,
    tool: &[f64; 3],
    errors: &PointErrors<f64>,
) -> ([f64; 3], ErrorsJacobian) {
    let mut e = *errors;
    e.reflector_delta = [0.0; 3];
    let mut out = ErrorsJacobian::zero();
    let x = chain_with_jacobian(
        machine,
        commands,
        tool,
        &e,
        true,
        |p, _| (p, IDENTITY),
        &mut out,
    );
    out.reflector_delta = [[0.0; 3]; 3];
    (x, out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::{predict, tool_in_workpiece};
    use num_dual::DualSVec64;

    /// Every field of PointErrors as a list of (getter index) for the dual comparison.
    const N: usize = 2 * 6 * MAX_AXES + TRACKER_DOF + 3 + 3 + 1;

    fn seeded(e: &PointErrors<f64>) -> PointErrors<DualSVec64<N>> {
        let d = |v: f64, i: usize| DualSVec64::<N>::from_re(v).derivative(i);
        let mut out = PointErrors::<DualSVec64<N>>::zero();
        out.has_location = e.has_location;
        let mut i = 0;
        for k in 0..MAX_AXES {
            for c in 0..6 {
                out.component[k][c] = d(e.component[k][c], i);
                out.location[k][c] = d(e.location[k][c], i + 1);
                i += 2;
            }
        }
        for c in 0..TRACKER_DOF {
            out.tracker[c] = d(e.tracker[c], i);
            i += 1;
        }
        for c in 0..3 {
            out.tool_shift[c] = d(e.tool_shift[c], i);
            out.reflector_delta[c] = d(e.reflector_delta[c], i + 1);
            i += 2;
        }
        out.range_scale = d(e.range_scale, i);
        out
    }

    fn flatten(j: &ErrorsJacobian) -> Vec<[f64; 3]> {
        let mut v = Vec::new();
        for k in 0..MAX_AXES {
            for c in 0..6 {
                v.push(j.component[k][c]);
                v.push(j.location[k][c]);
            }
        }
        v.extend(j.tracker);
        for c in 0..3 {
            v.push(j.tool_shift[c]);
            v.push(j.reflector_delta[c]);
        }
        v.push(j.range_scale);
        v
    }

    fn from_duals(x: &[DualSVec64<N>; 3]) -> Vec<[f64; 3]> {
        (0..N)
            .map(|i| [0, 1, 2].map(|c| x[c].eps.0.as_ref().map_or(0.0, |v| v[i])))
            .collect()
    }

    fn random_errors(seed: &mut u64, machine: &Machine) -> PointErrors<f64> {
        let mut next = || {
            *seed ^= *seed << 13;
            *seed ^= *seed >> 7;
            *seed ^= *seed << 17;
            (*seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut e = PointErrors::<f64>::zero();
        for k in 0..machine.axes().len() {
            e.has_location[k] = next() > -0.2;
            for c in 0..6 {
                let scale = if c < 3 { 0.05 } else { 2e-4 };
                e.component[k][c] = scale * next();
                e.location[k][c] = if e.has_location[k] {
                    scale * next()
                } else {
                    0.0
                };
            }
        }
        for c in 0..3 {
            e.tracker[c] = 500.0 * next();
            e.tracker[3 + c] = 1e-3 * next();
            e.tool_shift[c] = 0.02 * next();
            e.reflector_delta[c] = 0.05 * next();
        }
        e.range_scale = 1e-5 * next();
        e
    }

    /// A machine with the chain's axes at skew offsets (linear travel −300…700 mm, referenced at
    /// 100 mm; rotary −180…180°), one reflector, the tracker on the workpiece or the frame.
    fn test_machine(chain: &str, on_frame: bool, orientation_deg: [f64; 3]) -> Machine {
        let mut toml = format!("name = \"test\"\nchain = \"{chain}\"\n");
        for (i, letter) in chain.chars().filter(|&c| c != 'F').enumerate() {
            let rotary = matches!(letter, 'A' | 'B' | 'C');
            let (range, reference) = if rotary {
                ("[-180.0, 180.0]", 10.0)
            } else {
                ("[-300.0, 700.0]", 100.0)
            };
            let f = i as f64 + 1.0;
            toml += &format!(
                "[axes.{letter}]\nrange = {range}\nreference = {reference}\noffset = [{}, {}, {}]\n",
                37.0 * f,
                -21.0 * f,
                55.0 * f
            );
        }
        toml += "[[reflector]]\nid = \"R1\"\noffset = [1.0, 2.0, 3.0]\n[tracker]\n";
        toml += &format!(
            "mount = \"{}\"\nposition = [100.0, 200.0, -50.0]\norientation_deg = {:?}\n",
            if on_frame { "frame" } else { "workpiece" },
            orientation_deg
        );
        Machine::from_toml_str(&toml, "test machine").expect("valid test machine")
    }

    /// The hand-derived reverse pass against forward-mode duals over every field, on chains
    /// with rotary axes on either side, location errors on some axes, a tracker on the frame
    /// and on the workpiece, large rotations of the tracker and random commands.
    #[test]
    fn reverse_pass_matches_duals() {
        let mut seed = 0x2545F4914F6CDD1D_u64;
        let chains = ["XCFZ", "FXYZ", "YFXZ", "XYZFCA", "CBXFZY", "FACXZ", "AFB"];
        for (n, chain) in chains.iter().enumerate() {
            let machine = test_machine(chain, n % 2 == 1, [10.0 * n as f64, -20.0, 35.0]);
            for trial in 0..8 {
                let e = random_errors(&mut seed, &machine);
                let mut cmd = Commands::default();
                for (k, a) in machine.axes().iter().enumerate() {
                    let f = (trial as f64 + 0.3 * k as f64) / 8.0;
                    cmd.0[k] = a.min + (a.max - a.min) * f.fract();
                }
                let refl = [12.0, -40.0, 85.0];
                let (x, jac) = predict_with_errors_jacobian(&machine, &cmd, &refl, &e);
                let xd = predict(&machine, &cmd, &refl, &seeded(&e));
                let tol = 1e-9 * (1.0 + x.iter().fold(0.0_f64, |m, v| m.max(v.abs())));
                for c in 0..3 {
                    assert!((x[c] - xd[c].re).abs() < tol, "{chain}: point");
                }
                for (i, (a, b)) in flatten(&jac).iter().zip(from_duals(&xd)).enumerate() {
                    for c in 0..3 {
                        assert!(
                            (a[c] - b[c]).abs() < tol,
                            "{chain} trial {trial}: field {i} row {c}: {} vs dual {}",
                            a[c],
                            b[c]
                        );
                    }
                }
                let (t, tj) = tool_in_workpiece_with_errors_jacobian(&machine, &cmd, &refl, &e);
                let mut e0 = seeded(&e);
                let zero = DualSVec64::<N>::from_re(0.0);
                e0.reflector_delta = [zero; 3];
                let cmd_d = cmd.0.map(DualSVec64::<N>::from_re);
                let td = tool_in_workpiece(&machine, &cmd_d, &refl, &e0);
                for (i, (a, b)) in flatten(&tj).iter().zip(from_duals(&td)).enumerate() {
                    for c in 0..3 {
                        assert!((t[c] - td[c].re).abs() < tol, "{chain}: tool point");
                        assert!(
                            (a[c] - b[c]).abs() < tol,
                            "{chain} trial {trial}: tool field {i} row {c}: {} vs dual {}",
                            a[c],
                            b[c]
                        );
                    }
                }
            }
        }
    }
}
