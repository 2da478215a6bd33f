//! The forward model of eq. 11 at a point: error values from the coefficients, the predicted
//! reflector and tool points, and the exact Jacobian and second directional derivative.

use super::*;

impl Model {
    /// Argument of a term's basis for a command: the angle (rad) for periodic bases, otherwise
    /// the position normalised to [−1, 1] over the axis range.
    #[inline]
    pub(super) fn argument(&self, t: &Term, commands: &Commands) -> f64 {
        self.argument_at(t, &commands.0)
    }

    /// [`Model::argument`] for commands of any scalar.
    #[inline]
    pub(super) fn argument_at<S: Real>(&self, t: &Term, commands: &[S; MAX_AXES]) -> S {
        let u = commands[t.axis];
        if t.basis.kind().is_periodic() {
            u
        } else {
            self.machine.axes()[t.axis].normalise_at(u)
        }
    }

    /// Value of a modelled error at an axis position (internal units: mm or rad), in mm or rad.
    pub fn error_value(&self, id: ErrorId, position: f64, params: &[f64]) -> Option<f64> {
        let t = self.term(id)?;
        let mut cmd = Commands::default();
        cmd.0[t.axis] = position;
        Some(
            t.basis
                .value(self.argument(t, &cmd), &params[t.params.clone()]),
        )
    }

    /// [`Model::error_value`] and its exact gradient with respect to the error's own
    /// coefficients (written to `grad`, one value per coefficient of the term, in the order of
    /// [`Term::params`]). The sine series' phases get their derivative at `params`.
    ///
    /// # Panics
    /// When `grad` is shorter than the term's coefficients.
    pub fn error_value_gradient(
        &self,
        id: ErrorId,
        position: f64,
        params: &[f64],
        grad: &mut [f64],
    ) -> Option<f64> {
        let t = self.term(id)?;
        let mut cmd = Commands::default();
        cmd.0[t.axis] = position;
        let k = t.params.len();
        Some(t.basis.eval(
            self.argument(t, &cmd),
            &params[t.params.clone()],
            &mut grad[..k],
        ))
    }

    /// The values of a group's terms at `commands` into `vals[..n]` (n terms), the basis'
    /// values (its derivatives with respect to the first term's coefficients) into `g`.
    #[inline]
    pub(super) fn group_values<S: Real>(
        &self,
        grp: &TermGroup,
        commands: &[S; MAX_AXES],
        params: &[f64],
        g: &mut [S; MAX_COEFFS],
        vals: &mut [S],
    ) {
        let (len, n) = (grp.len, grp.terms.len());
        let x = self.argument_at(&self.terms[grp.terms.start], commands);
        let first = &params[grp.params..grp.params + len];
        vals[0] = self.terms[grp.terms.start]
            .basis
            .eval_at(x, first, &mut g[..len]);
        let block = &params[grp.params + len..grp.params + n * len];
        dots(&g[..len], block, &mut vals[1..n], |v| v);
    }

    /// [`Model::group_values`] from the basis' values `values` at the point ([`Regressors`]),
    /// with the same arithmetic (each value a dot product from zero, in coefficient order), so
    /// the same bits.
    #[inline]
    pub(super) fn group_values_cached<S: Real>(
        &self,
        grp: &TermGroup,
        params: &[f64],
        values: &[f64],
        vals: &mut [S],
    ) {
        let block = &params[grp.params..grp.params + grp.terms.len() * grp.len];
        dots(values, block, vals, S::from);
    }

    pub(super) fn check_len(&self, params: &[f64]) {
        assert_eq!(
            params.len(),
            self.params.len(),
            "parameter vector has the wrong length"
        );
    }

    /// Places error values (one per slot: terms, then the tracker pose) into [`PointErrors`].
    #[inline]
    pub(super) fn point_errors<S: Real>(&self, value: impl Fn(usize) -> S) -> PointErrors<S> {
        let mut e = PointErrors::zero();
        e.has_location = self.has_location;
        for (i, t) in self.terms.iter().enumerate() {
            let c = t.id.component().index();
            match t.id {
                ErrorId::Component { .. } => e.component[t.axis][c] = value(i),
                ErrorId::Location { .. } => e.location[t.axis][c] = value(i),
            }
        }
        for k in 0..TRACKER_DOF {
            e.tracker[k] = value(self.terms.len() + k);
        }
        let base = self.terms.len() + TRACKER_DOF;
        self.place_effects(&mut e, |i| value(base + i));
        e
    }

    /// Predicted reflector position in the tracker frame (mm) for `commands` (chain order,
    /// internal units) and reflector index.
    ///
    /// # Panics
    /// When `params.len() != n_params()` or the reflector index is out of range: both are
    /// programming errors (input files are validated when they are read).
    pub fn predict(&self, commands: &Commands, reflector: usize, params: &[f64]) -> [f64; 3] {
        self.predict_at(commands, reflector, 0.0, params)
    }

    /// [`Model::predict`] at time `t_s` (s since the test started), for models with thermal
    /// drift.
    ///
    /// # Panics
    /// As [`Model::predict`].
    pub fn predict_at(
        &self,
        commands: &Commands,
        reflector: usize,
        t_s: f64,
        params: &[f64],
    ) -> [f64; 3] {
        self.predict_in(commands, reflector, PointState::at(t_s), params)
    }

    /// [`Model::predict`] in `state`: at its time, each axis arriving from its direction of
    /// approach (the reversal effect's sign, [`crate::approach`]).
    ///
    /// # Panics
    /// As [`Model::predict`].
    pub fn predict_in(
        &self,
        commands: &Commands,
        reflector: usize,
        state: PointState,
        params: &[f64],
    ) -> [f64; 3] {
        self.predict_with(commands, reflector, 0, state, params, None)
    }

    /// [`Model::predict_at`] with the point's [`Regressors`] when the caller has them.
    pub(super) fn predict_with(
        &self,
        commands: &Commands,
        reflector: usize,
        station: usize,
        state: PointState,
        params: &[f64],
        cached: Option<PointRegressors<'_>>,
    ) -> [f64; 3] {
        let e = self.errors_with(&commands.0, reflector, station, state, params, cached);
        predict(
            &self.machine,
            commands,
            &self.machine.reflectors()[reflector].offset,
            &e,
        )
    }

    /// The value of every modelled error at `commands` and the tracker pose, laid out for
    /// [`crate::kinematics::predict`] (errors the model leaves out are zero). The synthetic
    /// generator adds effects outside the model to these values.
    ///
    /// # Panics
    /// When `params.len() != n_params()`.
    pub fn errors_at(&self, commands: &Commands, params: &[f64]) -> PointErrors<f64> {
        self.errors_at_point(commands, usize::MAX, 0.0, params)
    }

    /// [`Model::errors_at`] for a measured point: with the effects that depend on the reflector
    /// and on the time stamp `t_s` (s).
    ///
    /// # Panics
    /// When `params.len() != n_params()`.
    pub fn errors_at_point(
        &self,
        commands: &Commands,
        reflector: usize,
        t_s: f64,
        params: &[f64],
    ) -> PointErrors<f64> {
        self.errors_with_commands(&commands.0, reflector, t_s, params)
    }

    /// [`Model::errors_at_point`] with commands of any scalar: with dual numbers over the
    /// commands, every error value carries its exact derivative along them (for the inverse
    /// model, [`crate::compensate`]).
    ///
    /// # Panics
    /// When `params.len() != n_params()`.
    pub fn errors_with_commands<S: Real>(
        &self,
        commands: &[S; MAX_AXES],
        reflector: usize,
        t_s: f64,
        params: &[f64],
    ) -> PointErrors<S> {
        self.errors_in(commands, reflector, PointState::at(t_s), params)
    }

    /// [`Model::errors_with_commands`] in `state` (its time and directions of approach).
    ///
    /// # Panics
    /// When `params.len() != n_params()`.
    pub fn errors_in<S: Real>(
        &self,
        commands: &[S; MAX_AXES],
        reflector: usize,
        state: PointState,
        params: &[f64],
    ) -> PointErrors<S> {
        self.errors_with(commands, reflector, 0, state, params, None)
    }

    /// [`Model::errors_with_commands`], with the point's [`Regressors`] when the caller has
    /// them (`f64` only in practice: the cached values carry no derivative along the commands).
    pub(super) fn errors_with<S: Real>(
        &self,
        commands: &[S; MAX_AXES],
        reflector: usize,
        station: usize,
        state: PointState,
        params: &[f64],
        cached: Option<PointRegressors<'_>>,
    ) -> PointErrors<S> {
        self.check_len(params);
        let mut e = PointErrors::zero();
        e.has_location = self.has_location;
        e.rotary_sin_cos = cached.map(|c| c.sin_cos);
        let mut g = [S::zero(); MAX_COEFFS];
        let mut v = [S::zero(); MAX_GROUP];
        let mut at = 0;
        for grp in &self.groups {
            match cached.and_then(|c| c.group(grp, &self.terms, &mut at)) {
                Some(values) => self.group_values_cached(grp, params, values, &mut v),
                None => self.group_values(grp, commands, params, &mut g, &mut v),
            }
            for (i, v) in grp.terms.clone().zip(v) {
                let place = self.places[i];
                if place.location {
                    e.location[place.axis][place.component] = v;
                } else {
                    e.component[place.axis][place.component] = v;
                }
            }
        }
        let pose = self.stations[station].pose;
        for (k, v) in params[pose..pose + TRACKER_DOF].iter().enumerate() {
            e.tracker[k] = S::from(*v);
        }
        e.station = station;
        if !self.effects.is_empty() {
            let mut vals = [S::zero(); MAX_SLOTS];
            self.effect_values(commands, reflector, station, state, params, &mut vals, None);
            let base = self.terms.len() + TRACKER_DOF;
            self.place_effects(&mut e, |i| vals[base + i]);
        }
        e
    }

    /// Where the tool point `tool` (mm, in the frame of the last tool-side axis) sits relative
    /// to the workpiece at `commands` (any scalar, internal units) with the errors of `params`:
    /// [`crate::kinematics::tool_in_workpiece`] with the model's error values at those commands.
    /// Effects that belong to the measurement (tracker pose, reflector offsets, range scale) are
    /// left out; those that change with time (drift, scale growth, a field over `t`) take their
    /// value at the test's start (zero); ball-screw errors and fields over axes stay.
    ///
    /// # Panics
    /// When `params.len() != n_params()`.
    pub fn tool_point<S: Real>(
        &self,
        commands: &[S; MAX_AXES],
        tool: &[f64; 3],
        params: &[f64],
    ) -> [S; 3] {
        self.tool_point_at(commands, tool, 0.0, params)
    }

    /// [`Model::tool_point`] `t_s` seconds after the test's start: what grows with time (a
    /// scale, a rotary axis' line, a field over `t`) at its value then; the measurement's
    /// effects left out as there (a drift of the tool point, also a tool shift, is the same
    /// in two tool points at one time and cancels in their difference).
    ///
    /// # Panics
    /// When `params.len() != n_params()`.
    pub fn tool_point_at<S: Real>(
        &self,
        commands: &[S; MAX_AXES],
        tool: &[f64; 3],
        t_s: f64,
        params: &[f64],
    ) -> [S; 3] {
        self.tool_point_in(commands, tool, PointState::at(t_s), params)
    }

    /// [`Model::tool_point_at`] in `state`: at its time, and with each axis' reversal on the
    /// side its direction of approach puts it (the mean of both sides where it is unknown).
    ///
    /// # Panics
    /// When `params.len() != n_params()`.
    pub fn tool_point_in<S: Real>(
        &self,
        commands: &[S; MAX_AXES],
        tool: &[f64; 3],
        state: PointState,
        params: &[f64],
    ) -> [S; 3] {
        let mut e = self.errors_in(commands, usize::MAX, state, params);
        e.reflector_delta = [S::zero(); 3];
        e.range_scale = S::zero();
        crate::kinematics::tool_in_workpiece(&self.machine, commands, tool, &e)
    }

    /// [`Model::tool_point`] and its exact Jacobian with respect to every parameter, written to
    /// `jac` (row-major 3 × n_params): the chain's derivative with respect to the error values at
    /// the commands, then the bases' derivatives, as [`Model::predict_with_jacobian`]. The measurement's
    /// parameters (tracker pose, reflector offsets, range scale, drift) get zero columns.
    ///
    /// # Panics
    /// When `params.len() != n_params()` or `jac.len() != 3 * n_params()`.
    pub fn tool_point_with_jacobian(
        &self,
        commands: &Commands,
        tool: &[f64; 3],
        params: &[f64],
        jac: &mut [f64],
    ) -> [f64; 3] {
        self.tool_point_with_jacobian_in(commands, tool, PointState::default(), params, jac)
    }

    /// [`Model::tool_point_with_jacobian`] in `state` (its time and each axis' direction of
    /// approach, as [`Model::tool_point_in`]).
    ///
    /// # Panics
    /// As [`Model::tool_point_with_jacobian`].
    pub fn tool_point_with_jacobian_in(
        &self,
        commands: &Commands,
        tool: &[f64; 3],
        state: PointState,
        params: &[f64],
        jac: &mut [f64],
    ) -> [f64; 3] {
        self.point_with_jacobian(
            commands,
            JacobianTarget::Tool(tool),
            usize::MAX,
            0,
            state,
            params,
            None,
            jac,
        )
    }

    /// Predicted point and its exact Jacobian with respect to every parameter, written to `jac`
    /// (row-major 3 × n_params: row c holds ∂x_c/∂p).
    ///
    /// The chain is differentiated with respect to the few error *values* at the point (one per
    /// modelled error, plus the tracker pose) by its hand-derived reverse pass
    /// ([`crate::kinematics::predict_with_errors_jacobian`], tested against forward-mode dual
    /// numbers), then multiplied by each basis' derivative with respect to its coefficients (the
    /// basis values; for the sine series also the derivative with respect to the phases). No
    /// finite differences.
    ///
    /// # Panics
    /// As [`Model::predict`], and when `jac.len() != 3 * n_params()`.
    pub fn predict_with_jacobian(
        &self,
        commands: &Commands,
        reflector: usize,
        params: &[f64],
        jac: &mut [f64],
    ) -> [f64; 3] {
        self.predict_with_jacobian_at(commands, reflector, 0.0, params, jac)
    }

    /// [`Model::predict_with_jacobian`] at time `t_s` (s).
    ///
    /// # Panics
    /// As [`Model::predict_with_jacobian`].
    pub fn predict_with_jacobian_at(
        &self,
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
            None,
            jac,
        )
    }

    /// [`Model::predict_with_jacobian_at`] with the point's [`Regressors`] when the caller has
    /// them.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn reflector_with_jacobian(
        &self,
        commands: &Commands,
        reflector: usize,
        station: usize,
        state: PointState,
        params: &[f64],
        cached: Option<PointRegressors<'_>>,
        jac: &mut [f64],
    ) -> [f64; 3] {
        let refl = &self.machine.reflectors()[reflector].offset;
        self.point_with_jacobian(
            commands,
            JacobianTarget::Reflector(refl),
            reflector,
            station,
            state,
            params,
            cached,
            jac,
        )
    }

    /// The exact Jacobian shared by [`Model::predict_with_jacobian_at`] and
    /// [`Model::tool_point_with_jacobian`]: the error values and their bases' derivatives, the
    /// chain's reverse pass over the values for `target`, then the chain rule.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn point_with_jacobian(
        &self,
        commands: &Commands,
        target: JacobianTarget,
        reflector: usize,
        station: usize,
        state: PointState,
        params: &[f64],
        cached: Option<PointRegressors<'_>>,
        jac: &mut [f64],
    ) -> [f64; 3] {
        self.check_len(params);
        let n = self.params.len();
        assert_eq!(
            jac.len(),
            3 * n,
            "Jacobian buffer must hold 3 × n_params values"
        );
        // Row 0 first holds ∂value(slot)/∂p_j for each parameter: a term's basis values.
        let mut vals = [0.0; MAX_SLOTS];
        self.term_values_and_bases(commands, params, cached, &mut vals, jac);
        self.tracker_values_and_bases(station, params, &mut vals, jac);
        let m = self.terms.len() + TRACKER_DOF + self.effects.len();
        self.effect_values(
            &commands.0,
            reflector,
            station,
            state,
            params,
            &mut vals,
            Some(jac),
        );
        let mut e = self.point_errors(|i| vals[i]);
        e.rotary_sin_cos = cached.map(|c| c.sin_cos);
        e.station = station;
        let (point, de) = match target {
            JacobianTarget::Reflector(refl) => {
                predict_with_errors_jacobian(&self.machine, commands, refl, &e)
            }
            JacobianTarget::Tool(tool) => {
                tool_in_workpiece_with_errors_jacobian(&self.machine, commands, tool, &e)
            }
        };
        let g = self.slot_columns(&de, m);
        let (r0, rest) = jac.split_at_mut(n);
        let (r1, r2) = rest.split_at_mut(n);
        for j in 0..n {
            let s = self.slot_of[j];
            let d = r0[j];
            r0[j] = g[0][s] * d;
            r1[j] = g[1][s] * d;
            r2[j] = g[2][s] * d;
        }
        point
    }

    /// The terms' values into `vals` and, into row 0 of `jac`, each term parameter's
    /// ∂value/∂p: its basis value at the point (from `cached` regressors when given).
    fn term_values_and_bases(
        &self,
        commands: &Commands,
        params: &[f64],
        cached: Option<PointRegressors<'_>>,
        vals: &mut [f64; MAX_SLOTS],
        jac: &mut [f64],
    ) {
        let mut g = [0.0; MAX_COEFFS];
        let mut at = 0;
        for grp in &self.groups {
            let out = &mut vals[grp.terms.clone()];
            let block = &mut jac[grp.params..grp.params + grp.terms.len() * grp.len];
            match cached.and_then(|c| c.group(grp, &self.terms, &mut at)) {
                Some(values) => {
                    self.group_values_cached(grp, params, values, out);
                    spread(values, block);
                }
                None => {
                    self.group_values(grp, &commands.0, params, &mut g, out);
                    spread(&g[..grp.len], block);
                }
            }
        }
    }

    /// The pose of `station` into the tracker slots of `vals` and, into row 0 of `jac`, 1 for
    /// its parameters and 0 for the other stations' poses and every range offset (which do not
    /// move this point: the offset enters after the chain, in the observation).
    fn tracker_values_and_bases(
        &self,
        station: usize,
        params: &[f64],
        vals: &mut [f64; MAX_SLOTS],
        jac: &mut [f64],
    ) {
        let m = self.terms.len() + TRACKER_DOF;
        let pose = self.stations[station].pose;
        vals[self.terms.len()..m].copy_from_slice(&params[pose..pose + TRACKER_DOF]);
        if self.stations.len() > 1 || self.stations[0].offset.is_some() {
            for b in &self.stations {
                jac[b.pose..b.pose + TRACKER_DOF].fill(0.0);
                if let Some(o) = b.offset {
                    jac[o] = 0.0;
                }
            }
        }
        jac[pose..pose + TRACKER_DOF].fill(1.0);
    }

    /// Second derivative of the predicted point along the parameter direction `dir`:
    /// `d²/dt² x(params + t·dir)` at t = 0 (mm per unit of t², the direction in the parameters'
    /// units). Exact: each error value and its first and second derivatives along `dir` (the
    /// basis values, and the sine series' curvature in amplitude and phase) enter the chain as
    /// second-order dual numbers. The curvature term of geodesic acceleration.
    ///
    /// # Panics
    /// As [`Model::predict`], and when `dir.len() != n_params()`.
    pub fn predict_second_directional_at(
        &self,
        commands: &Commands,
        reflector: usize,
        t_s: f64,
        params: &[f64],
        dir: &[f64],
    ) -> [f64; 3] {
        let x = self.predict_dual2(commands, reflector, 0, PointState::at(t_s), params, dir);
        [x[0].v2, x[1].v2, x[2].v2]
    }

    /// The predicted point as second-order dual numbers along `dir` (value, first and second
    /// derivative), for the point's station.
    pub(super) fn predict_dual2(
        &self,
        commands: &Commands,
        reflector: usize,
        station: usize,
        state: PointState,
        params: &[f64],
        dir: &[f64],
    ) -> [num_dual::Dual2_64; 3] {
        self.check_len(params);
        self.check_len(dir);
        let mut vals = [0.0; MAX_SLOTS];
        let mut d1 = [0.0; MAX_SLOTS];
        let mut d2 = [0.0; MAX_SLOTS];
        let mut grad = [0.0; MAX_COEFFS];
        for (i, t) in self.terms.iter().enumerate() {
            let r = t.params.clone();
            let x = self.argument(t, commands);
            let g = &mut grad[..r.len()];
            vals[i] = t.basis.eval(x, &params[r.clone()], g);
            d1[i] = g.iter().zip(&dir[r.clone()]).map(|(a, b)| a * b).sum();
            d2[i] = t.basis.second_directional(x, &params[r.clone()], &dir[r]);
        }
        let k = self.terms.len();
        let ts = self.stations[station].pose;
        vals[k..k + TRACKER_DOF].copy_from_slice(&params[ts..ts + TRACKER_DOF]);
        d1[k..k + TRACKER_DOF].copy_from_slice(&dir[ts..ts + TRACKER_DOF]);
        // Effects are linear in their parameters: their derivative along dir is their value
        // at dir, and their second derivative is zero.
        self.effect_values(
            &commands.0,
            reflector,
            station,
            state,
            params,
            &mut vals,
            None,
        );
        self.effect_values(&commands.0, reflector, station, state, dir, &mut d1, None);
        let mut e = self.point_errors(|i| num_dual::Dual2_64::new(vals[i], d1[i], d2[i]));
        e.station = station;
        let refl = &self.machine.reflectors()[reflector].offset;
        predict(&self.machine, commands, refl, &e)
    }

    /// ∂point/∂(error value) of every slot (terms, tracker, effects: the first `m`), by rows,
    /// from the derivative with respect to the fields of [`PointErrors`] (the placement of
    /// [`Model::point_errors`]).
    #[inline]
    pub(super) fn slot_columns(&self, de: &ErrorsJacobian, m: usize) -> [[f64; MAX_SLOTS]; 3] {
        let mut g = [[0.0; MAX_SLOTS]; 3];
        let mut put = |s: usize, col: [f64; 3]| {
            for c in 0..3 {
                g[c][s] = col[c];
            }
        };
        for (i, t) in self.terms.iter().enumerate() {
            let c = t.id.component().index();
            put(
                i,
                match t.id {
                    ErrorId::Component { .. } => de.component[t.axis][c],
                    ErrorId::Location { .. } => de.location[t.axis][c],
                },
            );
        }
        let base = self.terms.len();
        for k in 0..TRACKER_DOF {
            put(base + k, de.tracker[k]);
        }
        let base = base + TRACKER_DOF;
        for (i, (slot, _)) in self.effects.iter().enumerate() {
            put(
                base + i,
                match *slot {
                    EffectSlot::Drift(c) | EffectSlot::Field { c, .. } => de.tool_shift[c],
                    EffectSlot::Reflector { c, .. } => de.reflector_delta[c],
                    EffectSlot::RangeScale => de.range_scale,
                    EffectSlot::Screw { k, dir, .. }
                    | EffectSlot::ThermalScale { k, dir }
                    | EffectSlot::Reversal { k, dir, .. } => de.component[k][dir],
                    EffectSlot::LocationDrift { k, c } => de.location[k][c],
                    EffectSlot::TrackerDrift(k) => de.tracker[k],
                    EffectSlot::StationDrift { c, .. } => de.tracker[c],
                },
            );
        }
        debug_assert_eq!(base + self.effects.len(), m);
        g
    }

    /// The size of each effect outside ISO 230 (the parameters of group "other", grouped by
    /// their name without its last part: `drift.x/y/z`, `screw.X.200.a/b`,
    /// `reflector.R1.x/y/z`, `range.scale`): the norm of its parameters, in the unit volver
    /// prints ([`Unit::micro`]: µm, µm/h, ppm, µrad), with that unit and the parameters' own.
    /// Only parameters for which `keep` is true count.
    pub fn effect_sizes(
        &self,
        params: &[f64],
        keep: impl Fn(usize) -> bool,
    ) -> Vec<(String, f64, &'static str, Unit)> {
        let mut groups: Vec<(String, f64, &'static str, Unit)> = Vec::new();
        for (j, info) in self.params.iter().enumerate() {
            if info.group != Group::Other || !keep(j) {
                continue;
            }
            let (scale, shown) = info.unit.micro();
            let key = info
                .name
                .rsplit_once('.')
                .map_or(info.name.as_str(), |(k, _)| k)
                .to_string();
            let v = params[j] * scale;
            match groups.iter_mut().find(|g| g.0 == key) {
                Some(g) => g.1 = g.1.hypot(v),
                None => groups.push((key, v.abs(), shown, info.unit)),
            }
        }
        groups
    }

    /// The squareness of every linear axis implied by the parameters, whatever the rule: the
    /// squareness parameter (if modelled) plus the slope of its straightness partner's best-fit
    /// line (if modelled), in rad. With the paper's rule the first is zero and this is the
    /// squareness "taken from the straightness". In the model's sign: ISO 230-1's reading is
    /// each value times [`ErrorId::iso_sign`] (the opposite for C0X, A0Y and B0Z).
    pub fn squareness(&self, params: &[f64]) -> Vec<(ErrorId, f64)> {
        let mut out = Vec::new();
        for ax in self.machine.axes() {
            if ax.axis.is_rotary() {
                continue;
            }
            for name in ErrorId::location_names(ax.axis) {
                let id: ErrorId = name.parse().expect("valid name");
                let partner = id.squareness_partner().expect("squareness");
                let own = self.term(id).map(|t| params[t.params.start]);
                let slope = self
                    .term(partner)
                    .filter(|p| !p.basis.kind().is_periodic())
                    .map(|p| {
                        let w = p.basis.linear_component();
                        let per_unit: f64 = w
                            .iter()
                            .zip(&params[p.params.clone()])
                            .map(|(a, b)| a * b)
                            .sum();
                        // y −= s·u·A0Z  ⇔  dEYZ/du = −s·A0Z
                        -ax.side.sign() * per_unit * 2.0 / (ax.max - ax.min)
                    });
                if own.is_some() || slope.is_some() {
                    out.push((id, own.unwrap_or(0.0) + slope.unwrap_or(0.0)));
                }
            }
        }
        out
    }
}

/// Each term's value `Σ_j g_j c_j` (from zero, in coefficient order) for the basis values `g`
/// and the terms' coefficients one after another in `block`, into `out` (one per term). The
/// basis values are of the forward model's scalar (`to` the identity) or the `f64` of a point's
/// [`Regressors`] (`to` = `S::from`); the usual lengths are unrolled: a cubic (4), one harmonic
/// (3), a constant (1).
#[inline]
pub(super) fn dots<T: Real, S: Real>(g: &[T], block: &[f64], out: &mut [S], to: impl Fn(T) -> S) {
    #[inline]
    pub(super) fn fixed<T: Real, S: Real, const L: usize>(
        g: &[T],
        block: &[f64],
        out: &mut [S],
        to: impl Fn(T) -> S,
    ) {
        let g: [T; L] = std::array::from_fn(|j| g[j]);
        for (v, coeffs) in out.iter_mut().zip(block.chunks_exact(L)) {
            let mut acc = T::zero();
            for j in 0..L {
                acc += g[j] * coeffs[j];
            }
            *v = to(acc);
        }
    }
    match g.len() {
        1 => fixed::<T, S, 1>(g, block, out, to),
        3 => fixed::<T, S, 3>(g, block, out, to),
        4 => fixed::<T, S, 4>(g, block, out, to),
        len => {
            for (v, coeffs) in out.iter_mut().zip(block.chunks_exact(len)) {
                let mut acc = T::zero();
                for (b, c) in g.iter().zip(coeffs) {
                    acc += *b * *c;
                }
                *v = to(acc);
            }
        }
    }
}

/// The basis values `g` (one term's coefficients' derivatives) into every term's columns of a
/// group's stretch of a Jacobian row (`block`: the terms' coefficients one after another).
#[inline]
pub(super) fn spread(g: &[f64], block: &mut [f64]) {
    pub(super) fn fixed<const L: usize>(g: &[f64], block: &mut [f64]) {
        let g: [f64; L] = std::array::from_fn(|j| g[j]);
        for chunk in block.chunks_exact_mut(L) {
            chunk.copy_from_slice(&g);
        }
    }
    match g.len() {
        1 => fixed::<1>(g, block),
        3 => fixed::<3>(g, block),
        4 => fixed::<4>(g, block),
        len => {
            for chunk in block.chunks_exact_mut(len) {
                chunk.copy_from_slice(g);
            }
        }
    }
}
