//! The forward model: commands + error values + tracker pose + reflector → predicted point in the
//! tracker frame. One function, generic over the scalar: `f64` to evaluate, `num-dual` duals to
//! differentiate.
//!
//! Every axis k maps a point `q` in its own frame to the frame it rides on:
//!
//! * linear axis along direction a: `q ↦ O_k + t_k + R⁻¹(k)·q`, with
//!   `t_k = (EXk, EYk, EZk) + s·u·e_a` plus the squareness terms
//!   (`B0Z` adds `−s·(u − u_ref)·B0Z` along x, `A0Z` along y: eq. 8);
//! * rotary axis about direction a: `q ↦ O_k + (EXk, EYk, EZk) + R⁻¹(k)·(L + Ω⁻¹·Rg(s·θ)·Ω·(q − L))`,
//!   where `L` holds the position location errors (X0C, Y0C) and `Ω` the orientation location
//!   errors (A0C, B0C) as a small rotation; with them zero this is eq. 11's `R⁻¹(c)·Rg⁻¹(c)`.
//!
//! `O_k` is the axis offset, `s` = −1 on the workpiece side and +1 on the tool side,
//! `R(k) = I − [w]×` is eq. 4 with `w = (EAk, EBk, ECk)` and `R⁻¹` its **exact** inverse
//! `(I + [w]× + w wᵀ)/(1 + |w|²)`, `Rg` is the nominal rotation (eq. 5 for C).
//!
//! The reflector offset is carried outward through the tool-side axes into the frame, then inward
//! through the workpiece-side axes into the frame of the last one (unless the tracker stands on
//! the frame), and finally into the tracker frame: `X_LT = R⁻¹(LT)·R0ᵀ·(p − T_LT)`. For `XCFZ`
//! this is exactly eq. 11 as read in the project notes:
//! `X_LT = R⁻¹(LT)·(Rg(c)·R(c)·R(x)·((Z_O + Z̄) + R⁻¹(z)·T − X̄ − R⁻¹(x)·(C_O + C̄)) − T_LT)`.

use crate::chain::{MAX_AXES, Side};
use crate::machine::{Commands, Machine, TrackerMount};

mod jacobian;
pub use jacobian::{
    ErrorsJacobian, predict_with_errors_jacobian, tool_in_workpiece_with_errors_jacobian,
};

/// The scalar of the forward model, re-exported from [`crate::scalar`] where it lives (kept at
/// this path for existing users).
pub use crate::scalar::Real;

/// Number of tracker pose values: x, y, z (mm) and the small angles rx, ry, rz (rad).
pub const TRACKER_DOF: usize = 6;

/// Names of the tracker pose values, in order.
pub const TRACKER_NAMES: [&str; TRACKER_DOF] = ["x", "y", "z", "rx", "ry", "rz"];

/// The values of every error at one measurement, per chain position, plus the tracker pose.
#[derive(Clone, Copy, Debug)]
pub struct PointErrors<S> {
    /// Component errors by chain position, in ISO order EX, EY, EZ, EA, EB, EC (mm, rad).
    pub component: [[S; 6]; MAX_AXES],
    /// Location errors by chain position, indexed by component: X0·, Y0·, Z0·, A0·, B0·, C0·
    /// (mm, rad). For a linear axis only the squareness slots (rotations) are used.
    pub location: [[S; 6]; MAX_AXES],
    /// Whether an axis has any location error in the model (otherwise that work is skipped).
    pub has_location: [bool; MAX_AXES],
    /// Tracker pose: T_LT x, y, z (mm) and the small angles R_LTx, R_LTy, R_LTz (rad, eq. 9),
    /// of the station that measures the point.
    pub tracker: [S; TRACKER_DOF],
    /// Which of the machine's stations measures the point ([`Machine::stations`]: its mount and
    /// base rotation); 0 for the tracker.
    pub station: usize,
    /// Effects outside the ISO 230 model: a displacement of the tool point in the machine frame
    /// (mm, e.g. thermal drift), applied after the tool-side axes.
    pub tool_shift: [S; 3],
    /// The reflector's offset error (mm, frame of the last tool-side axis).
    pub reflector_delta: [S; 3],
    /// The tracker's range scale error (relative: the point is scaled by 1 + this).
    pub range_scale: S,
    /// Sine and cosine of each rotary axis' nominal chain angle at the commands these values
    /// belong to, when the caller computed them once for its point (`crate::model::Regressors`);
    /// `None`: the chain computes them from the commands. Only set by the model's `f64` paths,
    /// for the very commands it is evaluated at.
    pub(crate) rotary_sin_cos: Option<[[f64; 2]; MAX_AXES]>,
}

impl<S: Real> PointErrors<S> {
    /// Every error zero and the tracker at the origin with no rotation.
    pub fn zero() -> Self {
        let z = S::zero();
        PointErrors {
            component: [[z; 6]; MAX_AXES],
            location: [[z; 6]; MAX_AXES],
            has_location: [false; MAX_AXES],
            tracker: [z; TRACKER_DOF],
            station: 0,
            tool_shift: [z; 3],
            reflector_delta: [z; 3],
            range_scale: z,
            rotary_sin_cos: None,
        }
    }
}

type V3<S> = [S; 3];

#[inline]
fn add<S: Real>(a: V3<S>, b: V3<S>) -> V3<S> {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

#[inline]
fn sub<S: Real>(a: V3<S>, b: V3<S>) -> V3<S> {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline]
fn cross<S: Real>(a: V3<S>, b: V3<S>) -> V3<S> {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// `R(w)·v` with eq. 4's `R = I − [w]×`.
#[inline]
fn rot_err<S: Real>(w: V3<S>, v: V3<S>) -> V3<S> {
    sub(v, cross(w, v))
}

/// `R(w)⁻¹·v`, the exact inverse `(v + w×v + w(w·v))/(1 + |w|²)`.
#[inline]
fn rot_err_inv<S: Real>(w: V3<S>, v: V3<S>) -> V3<S> {
    let wv = w[0] * v[0] + w[1] * v[1] + w[2] * v[2];
    let inv = (S::one() + w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).recip();
    let c = cross(w, v);
    [
        (v[0] + c[0] + w[0] * wv) * inv,
        (v[1] + c[1] + w[1] * wv) * inv,
        (v[2] + c[2] + w[2] * wv) * inv,
    ]
}

/// Nominal right-handed rotation about coordinate direction `dir` with precomputed sin/cos.
#[inline]
fn rot_nominal<S: Real>(dir: usize, sin: S, cos: S, v: V3<S>) -> V3<S> {
    let (b, c) = ((dir + 1) % 3, (dir + 2) % 3);
    let mut out = v;
    out[b] = v[b] * cos - v[c] * sin;
    out[c] = v[b] * sin + v[c] * cos;
    out
}

#[inline]
fn tail3<S: Real>(a: &[S; 6]) -> V3<S> {
    [a[3], a[4], a[5]]
}

#[inline]
fn head3<S: Real>(a: &[S; 6]) -> V3<S> {
    [a[0], a[1], a[2]]
}

/// Translation part `O_k + t_k` of axis `k` (everything but the rotations).
#[inline]
fn axis_translation<S: Real>(machine: &Machine, k: usize, u: S, e: &PointErrors<S>) -> V3<S> {
    let ax = &machine.axes()[k];
    let s = ax.side.sign();
    let c = &e.component[k];
    let mut t = [
        c[0] + ax.offset[0],
        c[1] + ax.offset[1],
        c[2] + ax.offset[2],
    ];
    if !ax.axis.is_rotary() {
        let a = ax.axis.direction();
        t[a] += u * s;
        if e.has_location[k] {
            let rel = (u - ax.reference) * s;
            for r in (0..3).filter(|&r| r != a) {
                t[3 - r - a] -= e.location[k][3 + r] * rel;
            }
        }
    }
    t
}

/// Nominal rotation by `angle` about rotary axis k's line: through the position location errors
/// `L` (X0C, Y0C) and tilted by the orientation location errors `Ω` (A0C, B0C),
/// `L + Ω⁻¹·Rg(angle)·Ω·(v − L)`; plain `Rg(angle)·v` when the axis has no location error.
/// Its inverse is the same map with `−angle`.
#[inline]
fn rotate_about_axis_line<S: Real>(
    dir: usize,
    angle: S,
    e: &PointErrors<S>,
    k: usize,
    v: V3<S>,
) -> V3<S> {
    let (sin, cos) = match e.rotary_sin_cos {
        Some(t) => (S::from(t[k][0]), S::from(t[k][1])),
        None => angle.sin_cos(),
    };
    if !e.has_location[k] {
        return rot_nominal(dir, sin, cos, v);
    }
    let l = head3(&e.location[k]);
    let om = tail3(&e.location[k]);
    add(
        l,
        rot_err_inv(om, rot_nominal(dir, sin, cos, rot_err(om, sub(v, l)))),
    )
}

/// Axis k's own frame → the frame it rides on.
#[inline]
fn axis_forward<S: Real>(machine: &Machine, k: usize, u: S, e: &PointErrors<S>, q: V3<S>) -> V3<S> {
    let ax = &machine.axes()[k];
    let t = axis_translation(machine, k, u, e);
    let w = tail3(&e.component[k]);
    let inner = if ax.axis.is_rotary() {
        rotate_about_axis_line(ax.axis.direction(), u * ax.side.sign(), e, k, q)
    } else {
        q
    };
    add(t, rot_err_inv(w, inner))
}

/// The frame axis k rides on → axis k's own frame (exact inverse of [`axis_forward`]).
#[inline]
fn axis_inverse<S: Real>(machine: &Machine, k: usize, u: S, e: &PointErrors<S>, p: V3<S>) -> V3<S> {
    let ax = &machine.axes()[k];
    let t = axis_translation(machine, k, u, e);
    let w = tail3(&e.component[k]);
    let inner = rot_err(w, sub(p, t));
    if ax.axis.is_rotary() {
        rotate_about_axis_line(ax.axis.direction(), u * -ax.side.sign(), e, k, inner)
    } else {
        inner
    }
}

/// Predicted reflector position in the tracker frame (mm).
///
/// `commands` are in chain order and internal units (mm, rad); `reflector` is the reflector's
/// offset in the frame of the last tool-side axis (mm).
///
/// ```
/// use volver_core::kinematics::{predict, PointErrors};
/// use volver_core::machine::Machine;
/// let m = Machine::default_xcfz();
/// // X = 700 mm, C = 90°, Z = 300 mm, reflector R2, no errors: the nominal point.
/// let cmd = m.commands_from_file_units(&[700.0, 90.0, 300.0]);
/// let p = predict(&m, &cmd, &m.reflectors()[1].offset, &PointErrors::<f64>::zero());
/// assert!((p[0] + 125.0).abs() < 1e-9 && (p[1] - 1690.0).abs() < 1e-9 && (p[2] - 1850.0).abs() < 1e-9);
/// ```
pub fn predict<S: Real>(
    machine: &Machine,
    commands: &Commands,
    reflector: &[f64; 3],
    errors: &PointErrors<S>,
) -> [S; 3] {
    predict_with_tool_shift(machine, commands, reflector, errors, None)
}

/// [`predict`] with the tool point displaced by `shift` (mm) in the machine frame, after the
/// tool-side axes and before the workpiece-side ones: a displacement of the tool relative to
/// the machine's frame that no axis error describes, such as thermal drift of the spindle.
/// `None` is exactly [`predict`].
///
/// ```
/// use volver_core::kinematics::{predict, predict_with_tool_shift, PointErrors};
/// use volver_core::machine::Machine;
/// let m = Machine::default_xcfz();
/// let cmd = m.commands_from_file_units(&[700.0, 0.0, 300.0]); // C = 0: frame ∥ tracker
/// let e = PointErrors::<f64>::zero();
/// let a = predict(&m, &cmd, &m.reflectors()[0].offset, &e);
/// let b = predict_with_tool_shift(&m, &cmd, &m.reflectors()[0].offset, &e, Some([0.0, 0.0, 0.02]));
/// assert!((b[2] - a[2] - 0.02).abs() < 1e-12);
/// ```
pub fn predict_with_tool_shift<S: Real>(
    machine: &Machine,
    commands: &Commands,
    reflector: &[f64; 3],
    errors: &PointErrors<S>,
    shift: Option<[f64; 3]>,
) -> [S; 3] {
    let u = commands.0.map(S::from);
    let tracker = &machine.stations()[errors.station].setup;
    let p = chain_point(
        machine,
        &u,
        reflector,
        errors,
        shift,
        tracker.mount == TrackerMount::Workpiece,
    );
    let d = sub(p, head3(&errors.tracker));
    let r0 = &tracker.base_rotation;
    // R0ᵀ·d
    let local = [0, 1, 2].map(|j| d[0] * r0[0][j] + d[1] * r0[1][j] + d[2] * r0[2][j]);
    let x = rot_err_inv(tail3(&errors.tracker), local);
    let scale = S::one() + errors.range_scale;
    [x[0] * scale, x[1] * scale, x[2] * scale]
}

/// Where a point of the tool sits relative to the workpiece: `tool` (mm, in the frame of the
/// last tool-side axis, like a reflector offset) carried outward through the tool-side axes into
/// the machine frame, then inward through the workpiece-side axes into the workpiece frame (the
/// frame of the last workpiece-side axis, or the machine frame when there is none). No tracker,
/// no reflector error, no range scale: this is the point compensation steers.
///
/// The commands are scalars too (internal units, chain order), so that dual numbers over the
/// commands give the exact ∂(tool point)/∂(commands) for the inverse model.
///
/// ```
/// use volver_core::kinematics::{tool_in_workpiece, PointErrors};
/// use volver_core::machine::Machine;
/// let m = Machine::default_xcfz();
/// let e = PointErrors::<f64>::zero();
/// let at = |c: f64| tool_in_workpiece(&m, &m.commands_from_file_units(&[700.0, c, 300.0]).0, &[0.0; 3], &e);
/// let (a, b) = (at(0.0), at(90.0));
/// // Seen from the table, C = +90° turns the tool point (x, y) into (−y, x).
/// assert!((b[0] + a[1]).abs() < 1e-9 && (b[1] - a[0]).abs() < 1e-9 && (b[2] - a[2]).abs() < 1e-12);
/// ```
pub fn tool_in_workpiece<S: Real>(
    machine: &Machine,
    commands: &[S; MAX_AXES],
    tool: &[f64; 3],
    errors: &PointErrors<S>,
) -> [S; 3] {
    chain_point(machine, commands, tool, errors, None, true)
}

/// The chain shared by [`predict_with_tool_shift`] and [`tool_in_workpiece`]: the point `start`
/// (plus the reflector error) out through the tool-side axes, shifted, then, when
/// `into_workpiece`, in through the workpiece-side axes.
#[inline]
fn chain_point<S: Real>(
    machine: &Machine,
    u: &[S; MAX_AXES],
    start: &[f64; 3],
    errors: &PointErrors<S>,
    shift: Option<[f64; 3]>,
    into_workpiece: bool,
) -> V3<S> {
    let axes = machine.axes();
    let mut p: V3<S> = add(start.map(S::from), errors.reflector_delta);
    // Tool side: from the axis carrying the tool inward to the frame.
    for k in (0..axes.len())
        .rev()
        .filter(|&k| axes[k].side == Side::Tool)
    {
        p = axis_forward(machine, k, u[k], errors, p);
    }
    p = add(p, errors.tool_shift);
    if let Some(d) = shift {
        p = add(p, d.map(S::from));
    }
    if into_workpiece {
        // Workpiece side: from the frame outward to the axis carrying the workpiece.
        for k in (0..axes.len()).filter(|&k| axes[k].side == Side::Workpiece) {
            p = axis_inverse(machine, k, u[k], errors, p);
        }
    }
    p
}
