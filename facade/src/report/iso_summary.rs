//! The summary in ISO 230-1 terms, before and after compensation: the volumetric error of the
//! tool point over the measured positions (EMM, EMax) and each axis' positioning, straightness
//! and angular ranges, each with its U (k = 2) from the fit's covariance.

use super::figures::{micro, table};
use super::{Page, Result};
use std::fmt::Write;
use volver_core::iso::ErrorId;
use volver_core::machine::Commands;
use volver_core::model::Model;
use volver_core::problem::norm;
use volver_core::units::UM_PER_MM;
use volver_solvers::uncertainty::{Covariance, K, ToolGrid};

/// Positions sampled along each axis' travel for the ranges.
const SAMPLES: usize = 61;

/// The section: the volumetric rows and one row per component error.
pub(super) fn section(p: &Page, s: &mut String) -> Result<()> {
    let Some(cov) = &p.cov else {
        return Ok(());
    };
    let tool = p.input.tool;
    let _ = writeln!(
        s,
        "<h2>Summary in ISO 230-1 terms</h2><p>Before compensation: what the identified errors \
         make of the machine. The volumetric rows are the deviation of the tool point at ({:.1}, \
         {:.1}, {:.1}) mm from the last tool-side axis from where the nominal machine puts it, \
         over the {} measured positions, in the workpiece frame and after the set-up's rigid \
         transform (which a workpiece set-up absorbs). Each axis' row is the range (maximum − \
         minimum over its travel) of one component error: positioning (ISO 230-2's systematic \
         deviation) and angular errors as identified, straightness about its least-squares \
         reference line (its slope is squareness: see below). U (k = 2) from the fit's \
         covariance (linearised, the held combinations' prior included).</p>",
        tool[0],
        tool[1],
        tool[2],
        distinct_commands(p).len()
    );
    let mut rows = volumetric_rows(p, cov, tool);
    rows.extend(axis_rows(p.model, p.params, cov));
    s.push_str(
        &table(
            &[
                "ISO 230-1",
                "quantity",
                "before compensation ± U (k = 2)",
                "after compensation (left)",
            ],
            &rows,
        )
        .replacen("<table>", "<table class=\"iso\">", 1),
    );
    let _ = writeln!(
        s,
        "<p><b>After compensation</b> means what compensation with these errors cannot remove. \
         Volumetric: the residual of the measured points against the identified model (what \
         the model does not explain, the measuring noise included: EMM or EMax over the \
         measured points) plus the largest U (k = 2) of the compensated tool point over those \
         positions; a bound at 95 %, not a measurement after compensation. An axis' error: \
         compensation removes the identified function, leaving its estimation error, which lies \
         within ± U at each position: the range left is at most twice the largest U along the \
         travel. Verify with a second measurement after compensation.</p>"
    );
    Ok(())
}

/// The data's distinct commands (the points of one pose at several reflectors counted once).
fn distinct_commands(p: &Page) -> Vec<Commands> {
    let mut out: Vec<Commands> = Vec::new();
    for pt in &p.problem.data().points {
        if !out.iter().any(|c| c.0 == pt.commands.0) {
            out.push(pt.commands);
        }
    }
    out
}

/// EMM and EMax of the tool point, raw and after the set-up's transform: before (the
/// identified errors, with U from the gradient of the mean / the worst point's module), after
/// (the residual EMM / EMax plus the tool point's largest U).
fn volumetric_rows(p: &Page, cov: &Covariance, tool: [f64; 3]) -> Vec<Vec<String>> {
    let grid = ToolGrid {
        commands: distinct_commands(p),
        tool,
    };
    let (model, params) = (p.model, p.params);
    let base = grid.points(model, &model.initial_params());
    let residual: Vec<f64> = p.after.iter().map(|r| norm(*r) * UM_PER_MM).collect();
    let res_emm = residual.iter().sum::<f64>() / residual.len().max(1) as f64;
    let res_emax = residual.iter().copied().fold(0.0, f64::max);
    let mut rows = Vec::new();
    for (aligned, frame) in [
        (false, "workpiece frame"),
        (true, "after the set-up's transform"),
    ] {
        let d = grid.deviations(model, params, &base, aligned);
        let jac = grid.jacobian(model, params, aligned);
        let u_tool = grid
            .uncertainty(model, params, cov, aligned)
            .iter()
            .map(|u| u.u95_max_mm() * UM_PER_MM)
            .fold(0.0, f64::max);
        let k = grid.commands.len();
        let module = |i: usize| norm([d[3 * i], d[3 * i + 1], d[3 * i + 2]]);
        // The gradient of point i's module: its unit direction through the Jacobian's rows.
        let gradient = |i: usize, g: &mut [f64], w: f64| {
            let m = module(i).max(1e-15);
            for r in 0..3 {
                let e = d[3 * i + r] / m * w;
                for (j, gj) in g.iter_mut().enumerate() {
                    *gj += e * jac[(3 * i + r, j)];
                }
            }
        };
        let mut g = vec![0.0; params.len()];
        (0..k).for_each(|i| gradient(i, &mut g, 1.0 / k as f64));
        let emm = (0..k).map(module).sum::<f64>() / k.max(1) as f64 * UM_PER_MM;
        let u_emm = K * cov.u(&g) * UM_PER_MM;
        let worst = (0..k).max_by(|&a, &b| module(a).total_cmp(&module(b)));
        let mut g = vec![0.0; params.len()];
        if let Some(i) = worst {
            gradient(i, &mut g, 1.0);
        }
        let emax = worst.map_or(0.0, module) * UM_PER_MM;
        let u_emax = K * cov.u(&g) * UM_PER_MM;
        for (name, v, u, left) in [
            ("EMM", emm, u_emm, res_emm),
            ("EMax", emax, u_emax, res_emax),
        ] {
            rows.push(vec![
                format!("volumetric {name}"),
                format!("tool point, {frame}"),
                format!("{v:.1} ± {u:.1} µm"),
                format!(
                    "≤ {:.1} µm (residual {left:.1} + U {u_tool:.1})",
                    left + u_tool
                ),
            ]);
        }
    }
    rows
}

/// What an axis' component error is called (ISO 230-1).
fn kind(id: ErrorId) -> String {
    let (c, a) = (id.component(), id.axis());
    if a.is_rotary() {
        return match (c.is_rotary(), c == a) {
            (true, true) => "angular positioning".into(),
            (true, false) => format!("tilt about {c}"),
            (false, _) => format!("error motion along {c}"),
        };
    }
    match (c.is_rotary(), c == a) {
        (false, true) => "positioning".into(),
        (false, false) => format!("straightness, {c} direction"),
        (true, _) if c.direction() == a.direction() => format!("roll (angular about {c})"),
        (true, _) => format!("angular about {c}"),
    }
}

/// Whether `id` is a straightness (a linear axis' error across its own direction).
fn is_straightness(id: ErrorId) -> bool {
    let (c, a) = (id.component(), id.axis());
    !a.is_rotary() && !c.is_rotary() && c != a
}

/// One row per component error: its range over the travel with U, and what compensation leaves
/// (at most twice its largest U along the travel).
fn axis_rows(model: &Model, params: &[f64], cov: &Covariance) -> Vec<Vec<String>> {
    let m = model.machine();
    let mut rows = Vec::new();
    for t in model.terms() {
        let ErrorId::Component { .. } = t.id else {
            continue;
        };
        let ax = &m.axes()[t.axis];
        let n = params.len();
        let mut x = Vec::with_capacity(SAMPLES);
        let mut v = Vec::with_capacity(SAMPLES);
        let mut g: Vec<Vec<f64>> = Vec::with_capacity(SAMPLES);
        for i in 0..SAMPLES {
            let u = ax.min + (ax.max - ax.min) * i as f64 / (SAMPLES - 1) as f64;
            let mut gi = vec![0.0; n];
            let Some(value) =
                model.error_value_gradient(t.id, u, params, &mut gi[t.params.clone()])
            else {
                continue;
            };
            x.push(u);
            v.push(value);
            g.push(gi);
        }
        if is_straightness(t.id) {
            remove_line(&x, &mut v, &mut g);
        }
        let (imax, imin) = extremes(&v);
        let range = v[imax] - v[imin];
        let dg: Vec<f64> = g[imax].iter().zip(&g[imin]).map(|(a, b)| a - b).collect();
        let u_range = K * cov.u(&dg);
        let u_max = g.iter().map(|gi| K * cov.u(gi)).fold(0.0, f64::max);
        let (scale, unit) = micro(t.id);
        rows.push(vec![
            t.id.to_string(),
            format!("{} of {}, range", kind(t.id), ax.axis),
            format!("{:.1} ± {:.1} {unit}", range * scale, u_range * scale),
            format!("≤ {:.1} {unit}", 2.0 * u_max * scale),
        ]);
    }
    rows
}

/// The indices of the largest and the smallest value.
fn extremes(v: &[f64]) -> (usize, usize) {
    let imax = (0..v.len())
        .max_by(|&a, &b| v[a].total_cmp(&v[b]))
        .unwrap_or(0);
    let imin = (0..v.len())
        .min_by(|&a, &b| v[a].total_cmp(&v[b]))
        .unwrap_or(0);
    (imax, imin)
}

/// `v` and its gradients `g` less their least-squares line over `x` (ISO 230-1's reference
/// straight line): a linear operation, applied to the values and to each parameter's column.
fn remove_line(x: &[f64], v: &mut [f64], g: &mut [Vec<f64>]) {
    let k = x.len() as f64;
    if k < 2.0 {
        return;
    }
    let xm = x.iter().sum::<f64>() / k;
    let sxx: f64 = x.iter().map(|xi| (xi - xm).powi(2)).sum();
    if sxx <= 0.0 {
        return;
    }
    let detrend = |y: &mut [f64]| {
        let mean = y.iter().sum::<f64>() / k;
        let slope = x
            .iter()
            .zip(y.iter())
            .map(|(xi, yi)| (xi - xm) * yi)
            .sum::<f64>()
            / sxx;
        for (yi, xi) in y.iter_mut().zip(x) {
            *yi -= mean + slope * (xi - xm);
        }
    };
    detrend(v);
    let n = g.first().map_or(0, Vec::len);
    let mut col = vec![0.0; g.len()];
    for j in 0..n {
        for (c, gi) in col.iter_mut().zip(g.iter()) {
            *c = gi[j];
        }
        detrend(&mut col);
        for (c, gi) in col.iter().zip(g.iter_mut()) {
            gi[j] = *c;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A straightness of 2 + 3x + (x² − mean) about its line: the line is gone, the parabola
    /// left; a parameter's column (x itself) is all line, so its gradient is zero.
    #[test]
    fn the_reference_line_is_removed_from_values_and_gradients() {
        let x: Vec<f64> = (0..5).map(f64::from).collect();
        let mut v: Vec<f64> = x.iter().map(|t| 2.0 + 3.0 * t + t * t).collect();
        let mut g: Vec<Vec<f64>> = x.iter().map(|t| vec![*t, t * t]).collect();
        remove_line(&x, &mut v, &mut g);
        // x² over 0..4 less its line 4x − 2: 2, −1, −2, −1, 2.
        for (a, b) in v.iter().zip([2.0, -1.0, -2.0, -1.0, 2.0]) {
            assert!((a - b).abs() < 1e-12, "{v:?}");
        }
        assert!(g.iter().all(|gi| gi[0].abs() < 1e-12));
        assert!((g[2][1] + 2.0).abs() < 1e-12);
    }
}
