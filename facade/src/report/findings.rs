//! The report's sections on what the fit lacks: the diagnosis, the candidate effects and the
//! model revisions, what the data identify, the cross-validation.

use super::figures::table;
use super::{Page, measurement_parts};
use crate::error::Result;
use crate::plot::{self, escape};
use std::fmt::Write;
use volver_core::diagnose;
use volver_core::units::UM_PER_MM;

/// The diagnosis: residual breakdowns, candidates, the model revisions.
pub(super) fn diagnosis(p: &Page, s: &mut String) -> Result<()> {
    let Page { problem, after, .. } = p;
    // Diagnosis.
    let _ = writeln!(s, "<h2>Diagnosis: where the model fails</h2>");
    let breakdowns = diagnose::breakdowns(problem, after);
    let noise_ref = diagnose::repeat_noise(problem).map(|(n, _)| n.emm_um);
    for b in &breakdowns {
        let data: Vec<(String, f64)> = b
            .bins
            .iter()
            .map(|x| (x.label.clone(), x.stats.emm_um))
            .collect();
        s.push_str(&plot::bars(
            &format!(
                "Residual EMM by {} {} (spread {:.2})",
                b.by,
                b.unit,
                b.spread()
            ),
            "EMM (µm)",
            &data,
            noise_ref.map(|n| ("repeat noise", n)),
        ));
    }
    Ok(())
}

/// The candidate effects ranked for the first fit, and the model revisions.
pub(super) fn candidates(p: &Page, s: &mut String) -> Result<()> {
    let Page { input, .. } = p;
    if !input.candidates.is_empty() {
        let _ = writeln!(
            s,
            "<h3>Effects the first model most likely missed (ranked by ΔBIC; below −10 is strong evidence)</h3>"
        );
        if let Some(first) = input.fits.first() {
            let _ = writeln!(
                s,
                "<p><b>Verdict:</b> {}</p>",
                crate::plot::escape(&volver_solvers::candidates::verdict(
                    &input.candidates,
                    first.id.reached.stats.emm_um
                ))
            );
        }
        let rows: Vec<Vec<String>> = input
            .candidates
            .iter()
            .take(8)
            .map(|c| {
                if c.seen() {
                    let why = c
                        .flag
                        .as_ref()
                        .map_or(String::new(), |f| format!("IMPLAUSIBLE ({f}): "));
                    vec![
                        c.id.clone(),
                        format!("{:.1}", c.delta_bic),
                        format!("{:.3}", c.emm_um),
                        format!("{:.2} {}", c.size, c.size_unit),
                        format!("{why}{}", c.description),
                    ]
                } else {
                    vec![
                        c.id.clone(),
                        "—".into(),
                        "—".into(),
                        "—".into(),
                        match &c.failed {
                            Some(why) => format!("could not be scored ({why}): {}", c.description),
                            None => format!("not seen in these data: {}", c.description),
                        },
                    ]
                }
            })
            .collect();
        s.push_str(&table(
            &["candidate", "ΔBIC", "EMM µm", "size", "meaning"],
            &rows,
        ));
    }
    if input.fits.len() > 1 {
        let data: Vec<(String, f64)> = input
            .fits
            .iter()
            .map(|f| (f.label.clone(), f.id.reached.stats.emm_um))
            .collect();
        s.push_str(&plot::bars(
            "EMM per model revision",
            "EMM (µm)",
            &data,
            input.noise_um.map(|n| ("noise error", n)),
        ));
    }
    Ok(())
}

/// What the data identify: weak combinations and correlated pairs.
pub(super) fn identifiability(p: &Page, s: &mut String) -> Result<()> {
    let Page { model, ident, .. } = p;
    // Identifiability.
    let _ = writeln!(s, "<h2>Identifiability</h2>");
    match &ident {
        Some(a) => {
            let _ = writeln!(
                s,
                "<p>{} of {} free directions identified; condition number {:.3e}; residual σ {:.2} µm per coordinate.</p>",
                a.rank,
                a.free,
                a.condition,
                a.sigma_mm * UM_PER_MM
            );
            let rows: Vec<Vec<String>> = a
                .weak
                .iter()
                .map(|w| {
                    vec![
                        format!("{:.1e}", w.relative_curvature),
                        w.parameters
                            .iter()
                            .take(5)
                            .map(|(j, x)| format!("{} {x:+.2}", model.params()[*j].name))
                            .collect::<Vec<_>>()
                            .join(", "),
                    ]
                })
                .collect();
            if !rows.is_empty() {
                s.push_str(&table(
                    &[
                        "relative curvature",
                        "combination the data cannot identify (the model's parameters and signs)",
                    ],
                    &rows,
                ));
            }
            let rows: Vec<Vec<String>> = a
                .correlations
                .iter()
                .take(10)
                .map(|(i, j, c)| {
                    vec![
                        model.params()[*i].name.clone(),
                        model.params()[*j].name.clone(),
                        format!("{c:+.3}"),
                    ]
                })
                .collect();
            if !rows.is_empty() {
                let _ = writeln!(s, "<p>Most correlated parameter pairs:</p>");
                s.push_str(&table(&["parameter", "parameter", "correlation"], &rows));
            }
        }
        None => {
            let _ = writeln!(s, "<p>The analysis failed (non-finite Jacobian).</p>");
        }
    }
    Ok(())
}

/// Cross-validation on a reference test.
pub(super) fn cross_validation(p: &Page, s: &mut String) -> Result<()> {
    let Page { input, model, .. } = p;
    if !input.cross.is_empty() {
        let _ = writeln!(
            s,
            "<h2>Cross-validation</h2><p>The errors identified on each set compensate an independent reference test: only the measurement's parameters ({}) are fitted there, never the machine's geometry. EMM before: the uncompensated machine with the tracker fitted rigidly, the initial EMM an identification of the reference prints. Residual % = EMM after / EMM before.</p>",
            escape(&measurement_parts(model).join(", "))
        );
        let rows: Vec<Vec<String>> = input
            .cross
            .iter()
            .map(|c| {
                vec![
                    c.label.clone(),
                    format!("{:.3}", c.emm_before_um),
                    format!("{:.3} ± {:.3}", c.emm_after_um, c.emm_after_u95_um),
                    format!("{:.2} %", c.residual_percent),
                ]
            })
            .collect();
        s.push_str(&table(
            &["identified on", "EMM before µm", "EMM after µm", "residual"],
            &rows,
        ));
        let data: Vec<(String, f64)> = input
            .cross
            .iter()
            .map(|c| (c.label.clone(), c.residual_percent))
            .collect();
        s.push_str(&plot::bars(
            "Residual on the reference after compensation",
            "residual (%)",
            &data,
            None,
        ));
    }
    Ok(())
}
