//! What a station observes of a predicted point: the point in the station's frame (moved along
//! its line of sight by the station's range offset, when modelled), or its range alone
//! `|x| + offset`. The residual of a range is `(range − measured range, 0, 0)`, so that Φ's
//! module of it is the range error and every engine takes it as it takes a point.

use super::*;
use crate::measure::{Measurement, Observation};

/// The observation of the point `x` (station frame) with the station's range offset `offset`:
/// `x + offset·x/|x|` for a point, `[|x| + offset, 0, 0]` for a range.
fn observed<S: Real>(x: [S; 3], offset: Option<S>, kind: Observation) -> [S; 3] {
    let len = || (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
    match (kind, offset) {
        (Observation::Point, None) => x,
        (Observation::Point, Some(o)) => {
            let f = S::one() + o / len();
            [x[0] * f, x[1] * f, x[2] * f]
        }
        (Observation::Range, o) => [len() + o.unwrap_or(S::zero()), S::zero(), S::zero()],
    }
}

impl Model {
    /// The range offset's value of station `s` in `params` (`None` when not modelled).
    fn offset_of(&self, s: usize, params: &[f64]) -> Option<f64> {
        self.stations[s].offset.map(|j| params[j])
    }

    /// What measurement `m` is predicted to observe with `params`: its point in its station's
    /// frame (mm), or `[range, 0, 0]` for a range ([`Measurement::observation`]).
    ///
    /// ```
    /// use volver_core::measure::{MeasurementSet, Observation};
    /// use volver_core::model::Model;
    /// let model = Model::default_xcfz();
    /// let csv = "reflector,X,C,Z,meas_x,meas_y,meas_z\nR1,0,0,0,950,75,1450\n";
    /// let data = MeasurementSet::from_csv_str(model.machine(), csv, "inline.csv").unwrap();
    /// let p = model.initial_params();
    /// assert_eq!(model.observe(&data.points[0], &p), [950.0, 75.0, 1450.0]);
    /// let mut range = data.points[0].clone();
    /// range.observation = Observation::Range;
    /// let r = model.observe(&range, &p)[0];
    /// assert!((r - (950f64.powi(2) + 75f64.powi(2) + 1450f64.powi(2)).sqrt()).abs() < 1e-9);
    /// ```
    ///
    /// # Panics
    /// As [`Model::predict`], and when the measurement's station is not the machine's.
    pub fn observe(&self, m: &Measurement, params: &[f64]) -> [f64; 3] {
        self.observe_with(m, params, None)
    }

    /// [`Model::observe`] with the point's [`Regressors`] when the caller has them.
    fn observe_with(
        &self,
        m: &Measurement,
        params: &[f64],
        cached: Option<PointRegressors<'_>>,
    ) -> [f64; 3] {
        let x = self.predict_with(
            &m.commands,
            m.reflector,
            m.station_index,
            PointState::of(m),
            params,
            cached,
        );
        observed(x, self.offset_of(m.station_index, params), m.observation)
    }

    /// [`Model::observe`] at point `i` of `regressors` (the same bits, see
    /// [`Model::predict_cached`]).
    ///
    /// # Panics
    /// As [`Model::observe`], and when `i` is not a point of `regressors`.
    pub fn observe_cached(
        &self,
        regressors: &Regressors,
        i: usize,
        m: &Measurement,
        params: &[f64],
    ) -> [f64; 3] {
        self.observe_with(m, params, Some(regressors.point(i)))
    }

    /// [`Model::observe_cached`] and its exact Jacobian (row-major 3 × n_params; a range's
    /// second and third rows are zero): the point's Jacobian, then the observation's chain
    /// rule by hand (∂|x| = x̂ᵀ∂x; ∂(o·x̂) = o(I − x̂x̂ᵀ)∂x/|x| + x̂ ∂o).
    ///
    /// # Panics
    /// As [`Model::predict_with_jacobian`], and when `i` is not a point of `regressors`.
    pub fn observe_with_jacobian_cached(
        &self,
        regressors: &Regressors,
        i: usize,
        m: &Measurement,
        params: &[f64],
        jac: &mut [f64],
    ) -> [f64; 3] {
        let x = self.reflector_with_jacobian(
            &m.commands,
            m.reflector,
            m.station_index,
            PointState::of(m),
            params,
            Some(regressors.point(i)),
            jac,
        );
        let block = self.stations[m.station_index];
        if m.observation == Observation::Point && block.offset.is_none() {
            return x;
        }
        let n = self.params.len();
        let len = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
        let u = [x[0] / len, x[1] / len, x[2] / len];
        let o = block.offset.map_or(0.0, |j| params[j]);
        let (r0, rest) = jac.split_at_mut(n);
        let (r1, r2) = rest.split_at_mut(n);
        match m.observation {
            Observation::Range => {
                for j in 0..n {
                    r0[j] = u[0] * r0[j] + u[1] * r1[j] + u[2] * r2[j];
                }
                r1.fill(0.0);
                r2.fill(0.0);
                if let Some(j) = block.offset {
                    r0[j] = 1.0;
                }
            }
            Observation::Point => {
                let f = o / len;
                for j in 0..n {
                    let d = [r0[j], r1[j], r2[j]];
                    let along = u[0] * d[0] + u[1] * d[1] + u[2] * d[2];
                    r0[j] = d[0] + f * (d[0] - u[0] * along);
                    r1[j] = d[1] + f * (d[1] - u[1] * along);
                    r2[j] = d[2] + f * (d[2] - u[2] * along);
                }
                if let Some(j) = block.offset {
                    r0[j] = u[0];
                    r1[j] = u[1];
                    r2[j] = u[2];
                }
            }
        }
        observed(x, block.offset.map(|_| o), m.observation)
    }

    /// Second derivative of [`Model::observe`] along the parameter direction `dir`, exact
    /// (second-order dual numbers through the chain and the observation).
    ///
    /// # Panics
    /// As [`Model::predict_second_directional_at`].
    pub fn observe_second_directional(
        &self,
        m: &Measurement,
        params: &[f64],
        dir: &[f64],
    ) -> [f64; 3] {
        let x = self.predict_dual2(
            &m.commands,
            m.reflector,
            m.station_index,
            PointState::of(m),
            params,
            dir,
        );
        let o = self.stations[m.station_index]
            .offset
            .map(|j| num_dual::Dual2_64::new(params[j], dir[j], 0.0));
        let y = observed(x, o, m.observation);
        [y[0].v2, y[1].v2, y[2].v2]
    }
}
