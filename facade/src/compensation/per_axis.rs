//! What per-axis tables leave of the identified volumetric error, beside the other ways of
//! compensating it: the leadscrew and the leadscrew + cross-axis projections
//! ([`volver_core::tables::per_axis::fit`]), the error tables of a volumetric compensation
//! (ISG, Etalon) and volver's own compensation, over one evaluation grid and the same tool
//! points ([`PerAxisComparison`]).

use crate::error::{Error, Result};
use volver_core::machine::{Commands, Machine};
use volver_core::model::Model;
use volver_core::tables::ErrorTables;
use volver_core::tables::per_axis::{ErrorSize, Family, Leftover, PerAxisTables, Request, fit};
use volver_core::units::UM_PER_MM;

/// The tool points along the tool's `axis` (unit vector, frame of the last tool-side axis)
/// from `tool` (mm) for `--tool-length MIN:MAX` (mm along the axis): three, at `MIN`, the
/// middle and `MAX` (one when they are equal); `tool` alone without a range.
///
/// ```
/// use volver::compensation::tool_points;
/// let t = tool_points([0.0, 0.0, -50.0], [0.0, 0.0, -1.0], Some("0:100")).unwrap();
/// assert_eq!(t, vec![[0.0, 0.0, -50.0], [0.0, 0.0, -100.0], [0.0, 0.0, -150.0]]);
/// assert!(tool_points([0.0; 3], [0.0, 0.0, -1.0], Some("100:0")).is_err());
/// ```
pub fn tool_points(tool: [f64; 3], axis: [f64; 3], range: Option<&str>) -> Result<Vec<[f64; 3]>> {
    let Some(text) = range else {
        return Ok(vec![tool]);
    };
    let bad = || {
        Error::Request(format!(
            "--tool-length {text}: expected MIN:MAX, two finite lengths in mm along the tool's \
             axis with MIN ≤ MAX (within ±100000 mm)"
        ))
    };
    let (lo, hi) = text.split_once(':').ok_or_else(bad)?;
    let (lo, hi): (f64, f64) = (
        lo.trim().parse().map_err(|_| bad())?,
        hi.trim().parse().map_err(|_| bad())?,
    );
    if !(lo.is_finite() && hi.is_finite() && lo <= hi && lo.abs() <= 1e5 && hi.abs() <= 1e5) {
        return Err(bad());
    }
    let len = axis.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !(len.is_finite() && len > 1e-9) {
        return Err(Error::Request(format!(
            "the tool's axis {axis:?} is not a direction"
        )));
    }
    let lengths: Vec<f64> = if lo == hi {
        vec![lo]
    } else {
        vec![lo, 0.5 * (lo + hi), hi]
    };
    Ok(lengths
        .into_iter()
        .map(|l| std::array::from_fn(|i| tool[i] + l * axis[i] / len))
        .collect())
}

/// What each way of compensating leaves over one evaluation grid
/// ([`volver_core::tables::per_axis::evaluation_grid`]) at the same tool points.
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct PerAxisComparison {
    /// The machine's axes, chain order.
    pub axes: Vec<String>,
    /// The leadscrew tables (LinuxCNC, Siemens `$AA_ENC_COMP`) and what they leave, with the
    /// error before compensation and what volumetric compensation leaves.
    pub leadscrew: (PerAxisTables, Leftover),
    /// The leadscrew and cross-axis tables (Siemens `$AA_ENC_COMP` + `$AN_CEC`).
    pub cross_axis: (PerAxisTables, Leftover),
    /// What the error tables (ISG, Etalon) leave when a control's volumetric compensation
    /// applies them: the tool point from the tables against the model's at each grid command
    /// and tool point (mm), in the order of the leftovers' points.
    pub error_tables: Vec<[f64; 3]>,
    /// Their size.
    pub error_tables_size: ErrorSize,
}

/// Both projections of `model`'s error at `params` for `tools`, every `linear_step` mm and
/// `rotary_step` degrees, and what the error tables `tables` leave, over the evaluation grid.
pub fn compare_per_axis(
    model: &Model,
    params: &[f64],
    tables: &ErrorTables,
    tools: &[[f64; 3]],
    linear_step: f64,
    rotary_step: f64,
) -> Result<PerAxisComparison> {
    let request = |family| Request {
        family,
        tools: tools.to_vec(),
        linear_step,
        rotary_step,
    };
    let leadscrew = fit(model, params, &request(Family::Leadscrew))?;
    let cross_axis = fit(model, params, &request(Family::CrossAxis))?;
    let left = &leadscrew.1;
    let mut error_tables = Vec::with_capacity(left.points.len());
    for p in &left.points {
        let (q, tool) = (&left.grid[p.command], &left.tools[p.tool]);
        let a = tables.tool_point(model, q, tool)?;
        let b = model.tool_point(&q.0, tool, params);
        error_tables.push([a[0] - b[0], a[1] - b[1], a[2] - b[2]]);
    }
    let error_tables_size = size_of(&left.grid, left, &error_tables);
    Ok(PerAxisComparison {
        axes: model
            .machine()
            .axes()
            .iter()
            .map(|a| a.axis.to_string())
            .collect(),
        leadscrew,
        cross_axis,
        error_tables,
        error_tables_size,
    })
}

/// The EMM and EMax of `v` (one vector per point of `left`, mm).
fn size_of(grid: &[Commands], left: &Leftover, v: &[[f64; 3]]) -> ErrorSize {
    ErrorSize::of(
        grid,
        left.points.iter().zip(v).map(|(p, d)| (p.command, *d)),
    )
}

impl PerAxisComparison {
    /// A command as people write it: `X=700, C=90, Z=300` (mm, degrees, 0.001 rounded).
    pub fn place(&self, machine: &Machine, q: &Commands) -> String {
        machine
            .axes()
            .iter()
            .enumerate()
            .map(|(k, a)| {
                let v = (a.to_file_units(q.0[k]) * 1e3).round() / 1e3;
                format!("{}={}", a.axis, if v == 0.0 { 0.0 } else { v })
            })
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// One line per way of compensating, labelled with the control that takes it: EMM and
    /// EMax (µm) and where EMax is; with a reversal, the tables' values arriving forward and
    /// in reverse on lines of their own.
    pub fn lines(&self, machine: &Machine) -> Vec<String> {
        let (lead, cross) = (&self.leadscrew.1, &self.cross_axis.1);
        let line = |label: &str, s: &ErrorSize| {
            format!(
                "{label:<66} EMM {:>9.3} µm  EMax {:>9.3} µm at {}",
                s.emm_mm * UM_PER_MM,
                s.emax_mm * UM_PER_MM,
                self.place(machine, &s.emax_at)
            )
        };
        let mut out = vec![
            line("uncompensated", &lead.before),
            line(
                "leadscrew tables (LinuxCNC COMP_FILE, Siemens $AA_ENC_COMP)",
                &lead.tables,
            ),
            line(
                "leadscrew + cross-axis tables (Siemens $AA_ENC_COMP + $AN_CEC)",
                &cross.tables,
            ),
            line(
                "error tables (ISG-kernel / Etalon volumetric compensation)",
                &self.error_tables_size,
            ),
            line(
                "volumetric compensation (volver compensate: G-code, points)",
                &lead.volumetric,
            ),
        ];
        for (name, l) in [("leadscrew", lead), ("leadscrew + cross-axis", cross)] {
            if let Some((f, r)) = &l.directions {
                out.push(line(
                    &format!("{name} tables, every axis arriving forward"),
                    f,
                ));
                out.push(line(
                    &format!("{name} tables, every axis arriving in reverse"),
                    r,
                ));
            }
        }
        out
    }

    /// The per-point CSV: each grid command (file units: mm, degrees) with each tool point,
    /// then the error's components and module (µm, workpiece frame) before compensation, with
    /// each family of tables, with the error tables and with volumetric compensation.
    pub fn to_csv(&self, machine: &Machine) -> String {
        let mut head: Vec<String> = self
            .axes
            .iter()
            .map(|a| {
                let unit = if machine
                    .axis_named(a)
                    .is_some_and(|(_, m)| m.axis.is_rotary())
                {
                    "deg"
                } else {
                    "mm"
                };
                format!("{a}_{unit}")
            })
            .collect();
        head.extend(["tool_x_mm", "tool_y_mm", "tool_z_mm"].map(String::from));
        for part in [
            "before",
            "leadscrew",
            "cross_axis",
            "error_tables",
            "volumetric",
        ] {
            for c in ["x_um", "y_um", "z_um", "um"] {
                head.push(format!("{part}_{c}"));
            }
        }
        let mut s = head.join(",");
        s.push('\n');
        let (lead, cross) = (&self.leadscrew.1, &self.cross_axis.1);
        for ((a, b), e) in lead
            .points
            .iter()
            .zip(&cross.points)
            .zip(&self.error_tables)
        {
            let q = &lead.grid[a.command];
            let mut row: Vec<String> = machine
                .axes()
                .iter()
                .enumerate()
                .map(|(k, ax)| format!("{}", (ax.to_file_units(q.0[k]) * 1e6).round() / 1e6))
                .collect();
            row.extend(lead.tools[a.tool].iter().map(|v| format!("{v}")));
            for v in [a.before, a.tables, b.tables, *e, a.volumetric] {
                let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                row.extend(
                    v.iter()
                        .chain([n].iter())
                        .map(|x| format!("{:.4}", x * UM_PER_MM)),
                );
            }
            s.push_str(&row.join(","));
            s.push('\n');
        }
        s
    }

    /// The short text summary written beside the CSV: what was compared, over what, and the
    /// lines of [`PerAxisComparison::lines`].
    pub fn summary(&self, machine: &Machine, source: &str) -> String {
        let (lead, cross) = (&self.leadscrew, &self.cross_axis);
        let tools: Vec<String> = lead
            .1
            .tools
            .iter()
            .map(|t| crate::compensation::point_mm(*t))
            .collect();
        let mut s = format!(
            "volver: what per-axis tables leave of the identified error of {source}\n\
             tool points (mm, frame of the last tool-side axis): {}\n\
             evaluated at {} programmed commands (every axis at equal steps over its travel, \
             ends included; a full turn in equal steps) with each tool point; the tables applied \
             as a control applies them (linear interpolation, held beyond the ends), the tool \
             point through the model, errors relative to the nominal machine (µm)\n\
             leadscrew tables: {}; leadscrew + cross-axis tables: {}\n\n",
            tools.join(", "),
            lead.1.grid.len(),
            lead.0.tables.len(),
            cross.0.tables.len(),
        );
        for l in self.lines(machine) {
            s.push_str(&l);
            s.push('\n');
        }
        s
    }
}
