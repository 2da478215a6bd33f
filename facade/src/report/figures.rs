//! The report's figures and tables: per-cell means of the residuals, the error functions' panels
//! with their U bands, the tool point's U over the volume, and the HTML table helper.

use super::*;
use crate::plot::{Cell, FunctionPanel};
use volver_core::units::UM_PER_MM;

/// Per-cell means over the points that share the two plotted axes' positions.
pub(super) fn cells(
    problem: &Problem,
    axes: (usize, usize),
    vectors: &[[f64; 3]],
    dirs: (usize, usize),
) -> (Vec<Cell>, Vec<Cell>) {
    let data = problem.data();
    let m = problem.model().machine();
    let (ka, kb) = axes;
    // Per cell: position, sum of modules, sum of vectors, count.
    type Sums = (f64, f64, f64, [f64; 3], usize);
    let mut groups: BTreeMap<(i64, i64), Sums> = BTreeMap::new();
    for (p, v) in data.points.iter().zip(vectors) {
        let (x, y) = (
            m.axes()[ka].to_file_units(p.commands.0[ka]),
            m.axes()[kb].to_file_units(p.commands.0[kb]),
        );
        let key = ((x * 1e3).round() as i64, (y * 1e3).round() as i64);
        let g = groups.entry(key).or_insert((x, y, 0.0, [0.0; 3], 0));
        g.2 += norm(*v) * UM_PER_MM;
        for (acc, vc) in g.3.iter_mut().zip(v) {
            *acc += vc * UM_PER_MM;
        }
        g.4 += 1;
    }
    let map = groups
        .values()
        .map(|g| Cell {
            x: g.0,
            y: g.1,
            a: g.2 / g.4 as f64,
            b: 0.0,
        })
        .collect();
    let arrows = groups
        .values()
        .map(|g| Cell {
            x: g.0,
            y: g.1,
            a: g.3[dirs.0] / g.4 as f64,
            b: g.3[dirs.1] / g.4 as f64,
        })
        .collect();
    (map, arrows)
}

/// Every plane of two linear axes that `moved` accepts (chain indices `(a, b)`), ordered by
/// the axes' names: X–Y, X–Z, Y–Z as the machine has them.
pub(super) fn planes(
    m: &volver_core::machine::Machine,
    moved: impl Fn(usize) -> bool,
) -> Vec<(usize, usize)> {
    let mut linear: Vec<usize> = (0..m.axes().len())
        .filter(|&k| !m.axes()[k].axis.is_rotary() && moved(k))
        .collect();
    linear.sort_by_key(|&k| m.axes()[k].axis);
    let mut out = Vec::new();
    for (i, &a) in linear.iter().enumerate() {
        for &b in &linear[i + 1..] {
            out.push((a, b));
        }
    }
    out
}

/// The planes of the linear axes the data move (at least two distinct positions of each).
pub(super) fn measured_planes(problem: &Problem) -> Vec<(usize, usize)> {
    let m = problem.model().machine();
    planes(m, |k| {
        let mut v: Vec<i64> = problem
            .data()
            .points
            .iter()
            .map(|p| (p.commands.0[k] * 1e3).round() as i64)
            .collect();
        v.sort_unstable();
        v.dedup();
        v.len() > 1
    })
}

/// The error functions of a fit against their axis positions, with bands of their expanded
/// uncertainty (k = 2: the data's and the held combinations' prior); a function the prior
/// dominates is titled as not determined.
pub(super) fn function_panels(
    model: &Model,
    params: &[f64],
    cov: Option<&Covariance>,
    gauge: Option<&volver_solvers::gauge::Gauge>,
    truth: Option<(&Model, &[f64])>,
) -> Vec<FunctionPanel> {
    let m = model.machine();
    let mut out = Vec::new();
    for t in model.terms() {
        let ErrorId::Component { .. } = t.id else {
            continue;
        };
        let ax = &m.axes()[t.axis];
        let (scale, unit) = micro(t.id);
        let n = 61;
        let (mut x, mut value, mut sigma, mut tv) = (vec![], vec![], vec![], vec![]);
        let mut g = vec![0.0; model.n_params()];
        let mut gb = vec![0.0; t.params.len()];
        // Where the held combinations' prior outweighs the data, the function is not measured.
        let (mut data_sq, mut held_sq, mut worst) = (0.0, 0.0, None);
        for i in 0..n {
            let u = ax.min + (ax.max - ax.min) * i as f64 / (n - 1) as f64;
            let arg = if t.basis.kind().is_periodic() {
                u
            } else {
                ax.normalise(u)
            };
            let v = t.basis.eval(arg, &params[t.params.clone()], &mut gb);
            g.fill(0.0);
            g[t.params.clone()].copy_from_slice(&gb);
            x.push(ax.to_file_units(u));
            value.push(v * scale);
            if let Some(c) = cov {
                let (uh, w) = c.u_held(&g);
                let ud = c.u_data(&g);
                data_sq += ud * ud;
                held_sq += uh * uh;
                worst = worst.or(w);
                sigma.push(ud.hypot(uh) * scale);
            } else {
                sigma.push(0.0);
            }
            if let Some((tm, tp)) = truth {
                tv.push(tm.error_value(t.id, u, tp).map(|v| v * scale));
            }
        }
        let truth_values = if tv.iter().all(Option::is_some) && !tv.is_empty() {
            Some(tv.into_iter().flatten().collect())
        } else {
            None
        };
        let name = match (gauge, worst) {
            (Some(g), Some(c)) if held_sq > data_sq => format!(
                "{} — not determined by the data (held combination {})",
                t.id,
                crate::uncertainty::combination_text(model, g, c)
            ),
            _ => t.id.to_string(),
        };
        out.push(FunctionPanel {
            name,
            xlabel: format!("{} ({})", ax.axis, ax.file_unit()),
            unit: unit.into(),
            x,
            value,
            sigma,
            truth: truth_values,
        });
    }
    out
}

/// Scale from internal units (mm, rad) to µm or µrad, and the unit's name.
pub(super) fn micro(id: ErrorId) -> (f64, &'static str) {
    id.unit().micro()
}

pub(super) fn table(head: &[&str], rows: &[Vec<String>]) -> String {
    let mut s = String::from("<table><tr>");
    for h in head {
        let _ = write!(s, "<th>{}</th>", escape(h));
    }
    s.push_str("</tr>\n");
    for r in rows {
        s.push_str("<tr>");
        for c in r {
            let _ = write!(s, "<td>{}</td>", escape(c));
        }
        s.push_str("</tr>\n");
    }
    s.push_str("</table>\n");
    s
}

/// The section on the uncertainty of the compensated tool point: U (k = 2, the largest of its
/// three coordinates) over the default grid of the volume (5 positions per axis), after the
/// set-up's rigid transform and raw, as colour maps in each plane of the linear axes
/// (the largest U over the other axes' positions), with the worst held combination named.
pub(super) fn tool_point_uncertainty(
    s: &mut String,
    input: &ReportInput,
    model: &Model,
    params: &[f64],
    gauge: Option<&volver_solvers::gauge::Gauge>,
    cov: &Covariance,
) -> Result<()> {
    let m = model.machine();
    let grid = crate::uncertainty::default_grid(m, 5)?;
    let tg = volver_solvers::uncertainty::ToolGrid {
        commands: grid.positions,
        tool: input.tool,
    };
    let aligned = tg.uncertainty(model, params, cov, true);
    let raw = tg.uncertainty(model, params, cov, false);
    let umax = |v: &[volver_solvers::uncertainty::PointUncertainty]| {
        v.iter()
            .map(|p| p.u95_max_mm() * UM_PER_MM)
            .fold(0.0_f64, f64::max)
    };
    let (ua, ur) = (umax(&aligned), umax(&raw));
    let verdict = u_verdict(input, model, gauge, &aligned, ua);
    let _ = writeln!(
        s,
        "<h2>Uncertainty of the compensated tool point</h2><p>Expanded uncertainty U (k = 2, the \
         largest of the three coordinates) of the tool point at ({:.1}, {:.1}, {:.1}) mm from the \
         last tool-side axis, over {} commands of the volume: the data's part (linearised, σ from the \
         residuals) and the held combinations' prior. After the set-up's rigid transform (what a workpiece set-up \
         absorbs anyway) U is at most <b>{ua:.1} µm</b>, {verdict}; raw, in the workpiece frame, \
         at most {ur:.1} µm. <code>volver uncertainty --tool-offset x,y,z</code> lists every point; \
         <code>--monte-carlo N</code> checks the linearisation.</p>",
        input.tool[0],
        input.tool[1],
        input.tool[2],
        tg.commands.len()
    );
    u_maps(s, m, &tg.commands, &aligned, &raw);
    Ok(())
}

/// Whether the tool point's U after the transform, `ua` (µm), passes the compensation's limit,
/// in words, naming the held combination behind the worst point when it dominates.
pub(super) fn u_verdict(
    input: &ReportInput,
    model: &Model,
    gauge: Option<&volver_solvers::gauge::Gauge>,
    aligned: &[PointUncertainty],
    ua: f64,
) -> String {
    let worst = aligned
        .iter()
        .max_by(|a, b| a.u95_max_mm().total_cmp(&b.u95_max_mm()))
        .and_then(|p| {
            let held: f64 = p.u95_held_mm.iter().fold(0.0, |m, v| m.max(*v));
            let data: f64 = p.u95_data_mm.iter().fold(0.0, |m, v| m.max(*v));
            (held > data).then_some(p.worst_held).flatten()
        });
    if ua <= input.max_u_um {
        format!(
            "within the {:.0} µm that <code>compensate</code> and <code>tables</code> accept",
            input.max_u_um
        )
    } else {
        format!(
            "above the {:.0} µm that <code>compensate</code> and <code>tables</code> accept: they \
             refuse this tool offset unless <code>--force</code>{}",
            input.max_u_um,
            match (worst, gauge) {
                (Some(c), Some(g)) => format!(
                    "; most of it is the held combination {} (not determined by the data: a \
                     third reflector off the line through the two, or one at the tool's length, \
                     would determine it)",
                    escape(&crate::uncertainty::combination_text(model, g, c))
                ),
                _ => String::new(),
            }
        )
    }
}

/// Colour maps of the tool point's U in each plane of the linear axes that have a travel (the
/// largest over the other axes' positions), after the transform and raw.
pub(super) fn u_maps(
    s: &mut String,
    m: &volver_core::machine::Machine,
    commands: &[volver_core::machine::Commands],
    aligned: &[PointUncertainty],
    raw: &[PointUncertainty],
) {
    for (ka, kb) in planes(m, |k| m.axes()[k].max > m.axes()[k].min) {
        let cells = |v: &[PointUncertainty]| {
            let mut out: Vec<Cell> = Vec::new();
            for (c, p) in commands.iter().zip(v) {
                let (x, y) = (
                    m.axes()[ka].to_file_units(c.0[ka]),
                    m.axes()[kb].to_file_units(c.0[kb]),
                );
                let u = p.u95_max_mm() * UM_PER_MM;
                match out
                    .iter_mut()
                    .find(|q| (q.x - x).abs() < 1e-9 && (q.y - y).abs() < 1e-9)
                {
                    Some(q) => q.a = q.a.max(u),
                    None => out.push(Cell { x, y, a: u, b: 0.0 }),
                }
            }
            out
        };
        let (la, lb) = (m.axes()[ka].axis, m.axes()[kb].axis);
        s.push_str(&plot::colour_maps(
            &format!(
                "U (k = 2) of the compensated tool point in the {la}–{lb} plane, largest over the other axes (µm)"
            ),
            &format!("{la} (mm)"),
            &format!("{lb} (mm)"),
            &[
                ("after the set-up's rigid transform", cells(aligned)),
                ("raw, workpiece frame", cells(raw)),
            ],
        ));
    }
}
