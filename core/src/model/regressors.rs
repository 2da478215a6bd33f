//! What a model's evaluation at a measured point needs that depends on the point's commands
//! alone: the basis values of every group of terms linear in its coefficients, and the sine and
//! cosine of each rotary axis' chain angle. An identification evaluates the same points at many
//! parameter vectors, so these are computed once per problem ([`crate::problem::Problem`]) instead
//! of at every pass: the fixed regressors of the paper's eq. 13, as a least-squares code keeps
//! its design matrix. The cached path gives the same bits as the direct one (tested).

use super::PointState;
use super::{Model, Term, TermGroup};
use crate::basis::MAX_COEFFS;
use crate::chain::{MAX_AXES, Side};
use crate::machine::Commands;

/// The fixed regressors of a model at a list of commands (see the module documentation).
///
/// ```
/// use volver_core::model::Model;
/// let model = Model::default_xcfz();
/// let cmd = model.machine().commands_from_file_units(&[700.0, 90.0, 300.0]);
/// let reg = model.regressors([&cmd]);
/// let p = model.initial_params();
/// assert_eq!(reg.len(), 1);
/// assert_eq!(model.predict_cached(&reg, 0, &cmd, 1, 0.0, &p), model.predict(&cmd, 1, &p));
/// ```
#[derive(Clone, Debug, Default)]
pub struct Regressors {
    /// Basis values per point (`stride` each): the linear groups' in group order.
    values: Vec<f64>,
    stride: usize,
    /// Per point: sine and cosine of each rotary axis' chain angle (zero for linear axes).
    sin_cos: Vec<[[f64; 2]; MAX_AXES]>,
}

impl Regressors {
    /// How many points.
    pub fn len(&self) -> usize {
        self.sin_cos.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.sin_cos.is_empty()
    }

    /// Point `i`'s share.
    pub(super) fn point(&self, i: usize) -> PointRegressors<'_> {
        PointRegressors {
            values: &self.values[i * self.stride..(i + 1) * self.stride],
            sin_cos: self.sin_cos[i],
        }
    }
}

/// One point's regressors.
#[derive(Clone, Copy, Debug)]
pub(super) struct PointRegressors<'r> {
    values: &'r [f64],
    pub(super) sin_cos: [[f64; 2]; MAX_AXES],
}

impl<'r> PointRegressors<'r> {
    /// The basis values of `grp` (the next group in order; `at` runs over the point's values),
    /// or `None` for a basis nonlinear in its coefficients (evaluated at every pass).
    #[inline]
    pub(super) fn group(
        &self,
        grp: &TermGroup,
        terms: &[Term],
        at: &mut usize,
    ) -> Option<&'r [f64]> {
        if !terms[grp.terms.start].basis.is_linear() {
            return None;
        }
        let values = &self.values[*at..*at + grp.len];
        *at += grp.len;
        Some(values)
    }
}

impl Model {
    /// The fixed regressors of this model at each of `commands` (see [`Regressors`]).
    pub fn regressors<'c>(&self, commands: impl IntoIterator<Item = &'c Commands>) -> Regressors {
        let stride: usize = self
            .groups
            .iter()
            .filter(|g| self.terms[g.terms.start].basis.is_linear())
            .map(|g| g.len)
            .sum();
        let mut out = Regressors {
            stride,
            ..Regressors::default()
        };
        let axes = self.machine.axes();
        let mut g = [0.0; MAX_COEFFS];
        for c in commands {
            for grp in &self.groups {
                let t = &self.terms[grp.terms.start];
                if !t.basis.is_linear() {
                    continue;
                }
                let x = self.argument_at(t, &c.0);
                // The coefficients do not matter to the basis values: zeros.
                t.basis
                    .eval_at(x, &[0.0; MAX_COEFFS][..grp.len], &mut g[..grp.len]);
                out.values.extend_from_slice(&g[..grp.len]);
            }
            // The angle exactly as the chain forms it: the tool side's axes carry their frame
            // forward (`u·s`), the workpiece side's are inverted (`−u·s`).
            let mut sc = [[0.0; 2]; MAX_AXES];
            for (k, ax) in axes.iter().enumerate() {
                if ax.axis.is_rotary() {
                    let s = ax.side.sign();
                    let angle = if ax.side == Side::Tool {
                        c.0[k] * s
                    } else {
                        c.0[k] * -s
                    };
                    let (sin, cos) = angle.sin_cos();
                    sc[k] = [sin, cos];
                }
            }
            out.sin_cos.push(sc);
        }
        out
    }

    /// [`Model::predict_at`] at point `i` of `regressors`, whose commands are `commands`: the
    /// same bits, without evaluating the bases or the rotary axes' sines again.
    ///
    /// # Panics
    /// As [`Model::predict`], and when `i` is not a point of `regressors`.
    pub fn predict_cached(
        &self,
        regressors: &Regressors,
        i: usize,
        commands: &Commands,
        reflector: usize,
        t_s: f64,
        params: &[f64],
    ) -> [f64; 3] {
        self.predict_with(
            commands,
            reflector,
            0,
            PointState::at(t_s),
            params,
            Some(regressors.point(i)),
        )
    }

    /// [`Model::predict_with_jacobian_at`] at point `i` of `regressors` (see
    /// [`Model::predict_cached`]).
    ///
    /// # Panics
    /// As [`Model::predict_with_jacobian`], and when `i` is not a point of `regressors`.
    #[allow(clippy::too_many_arguments)]
    pub fn predict_with_jacobian_cached(
        &self,
        regressors: &Regressors,
        i: usize,
        commands: &Commands,
        reflector: usize,
        t_s: f64,
        params: &[f64],
        jac: &mut [f64],
    ) -> [f64; 3] {
        self.reflector_with_jacobian(
            commands,
            reflector,
            0,
            PointState::at(t_s),
            params,
            Some(regressors.point(i)),
            jac,
        )
    }
}
