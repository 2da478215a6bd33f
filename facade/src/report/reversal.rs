//! The report's reversal panel: each axis' reversal value B (ISO 230-2) with its U, where the
//! model has one, and how its points were approached.

use super::Page;
use super::figures::table;
use crate::error::Result;
use crate::plot::escape;
use std::fmt::Write;
use volver_solvers::uncertainty::K;

/// The reversal section: one row per axis with a reversal (at its travel's start, middle and
/// end when B varies along it), value ± U (k = 2), the truth when known, and the count of
/// points approached forward, in reverse and from no known side.
pub(super) fn section(p: &Page, s: &mut String) -> Result<()> {
    let Page {
        model,
        params,
        cov,
        truth,
        problem,
        ..
    } = p;
    let axes = model.reversal_axes();
    if axes.is_empty() {
        return Ok(());
    }
    let _ = writeln!(
        s,
        "<h2>Reversal (direction of approach)</h2><p>Each axis' reversal value B (ISO 230-2): \
         the deviation of the tool relative to the workpiece along the axis' command \
         approaching in its positive direction minus the one approaching in its negative \
         (negative: lost motion; positive: overshoot); the model moves the tool by ±B/2 along \
         the axis by the direction of each point's last move. U (k = 2) as for the error functions. A reversal \
         can be identified only where the axis was approached from both sides.</p>"
    );
    let mut rows = Vec::new();
    for (k, range) in axes {
        let ax = &model.machine().axes()[k];
        // B's unit: the reversal parameters' (mm or rad), printed in µm or µrad.
        let (scale, unit) = model.params()[range.start].unit.micro();
        let counts = approach_counts(problem.data(), k);
        let positions: Vec<f64> = if range.len() > 1 {
            vec![ax.min, 0.5 * (ax.min + ax.max), ax.max]
        } else {
            vec![0.5 * (ax.min + ax.max)]
        };
        for u in positions {
            let mut g = vec![0.0; params.len()];
            let b = model.reversal_at(k, u, params, Some(&mut g)).unwrap_or(0.0);
            let uu = cov.as_ref().map_or(0.0, |c| K * c.u(&g));
            let at = if range.len() > 1 {
                format!(" at {} {}", ax.to_file_units(u), ax.file_unit())
            } else {
                String::new()
            };
            let mut row = vec![
                escape(&format!("{}{at}", ax.axis)),
                format!("{:.3} ± {:.3} {unit}", b * scale, uu * scale),
                counts.clone(),
            ];
            if let Some(t) = truth {
                let tb = model.reversal_at(k, u, &t.params, None).unwrap_or(0.0);
                row.push(format!("{:.3} {unit}", tb * scale));
            }
            rows.push(row);
        }
    }
    let head: &[&str] = if truth.is_some() {
        &[
            "axis",
            "B ± U (k = 2)",
            "points forward / reverse / unknown",
            "truth (in this model)",
        ]
    } else {
        &[
            "axis",
            "B ± U (k = 2)",
            "points forward / reverse / unknown",
        ]
    };
    s.push_str(&table(head, &rows));
    Ok(())
}

/// How many points arrived on chain axis `k` moving forward, in reverse, from no known side.
fn approach_counts(data: &volver_core::measure::MeasurementSet, k: usize) -> String {
    let mut n = [0usize; 3];
    for m in &data.points {
        n[match m.approach.0[k] {
            1 => 0,
            -1 => 1,
            _ => 2,
        }] += 1;
    }
    format!("{} / {} / {}", n[0], n[1], n[2])
}
