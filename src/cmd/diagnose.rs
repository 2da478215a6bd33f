//! `volver diagnose`: where the fit fails and what it most likely misses.

use super::{Inputs, um};
use anyhow::Result;
use volver::core::problem::Problem;
use volver::solvers::Options;

/// Options of `volver diagnose`.
#[derive(clap::Args)]
pub struct DiagnoseArgs {
    #[command(flatten)]
    inputs: Inputs,
    /// How many candidates to list.
    #[arg(long, default_value_t = 10)]
    top: usize,
    /// Print one JSON object instead of the tables.
    #[arg(long)]
    json: bool,
}

/// Runs `volver diagnose`.
pub fn run(a: DiagnoseArgs) -> Result<()> {
    let DiagnoseArgs { inputs, top, json } = a;
    use volver::core::diagnose;
    use volver::solvers::candidates::rank;
    use volver::solvers::identifiability::analyse;
    let (m, model, set) = inputs.load()?;
    let problem = Problem::new(&model, &set)?;
    let id = volver::solvers::strategy::fit(problem.clone());
    if id.termination.failed() {
        anyhow::bail!("the fit failed: {}", id.termination);
    }
    let r = problem.residuals(&id.params);
    let rm = diagnose::to_machine_frame(&problem, &id.params, &r);
    let breakdowns = diagnose::breakdowns(&problem, &r);
    let periodograms: Vec<(String, Vec<diagnose::Line>)> = m
        .axes()
        .iter()
        .enumerate()
        .map(|(k, ax)| {
            (
                ax.axis.to_string(),
                diagnose::axis_periodogram(&problem, &rm, k, 6),
            )
        })
        .collect();
    let repeat = diagnose::repeat_noise(&problem);
    let outliers = diagnose::largest(&r, 5);
    let describe = |i: usize| {
        let p = &set.points[i];
        let pos: Vec<String> = m
            .axes()
            .iter()
            .enumerate()
            .map(|(k, ax)| {
                let v = (ax.to_file_units(p.commands.0[k]) * 1e6).round() / 1e6;
                format!("{}={v}", ax.axis)
            })
            .collect();
        format!(
            "line {} ({} {})",
            p.line,
            pos.join(" "),
            m.reflectors()[p.reflector].id
        )
    };
    let options = Options::default();
    let ident = analyse(
        &volver::solvers::Task::new(problem.clone()),
        &id.params,
        options.rank_tolerance,
        0.99,
    );
    let ranked = rank(&problem, &id.params, options.rank_tolerance);
    let name = |j: usize| model.params()[j].name.clone();
    if json {
        let obj = serde_json::json!({
            "emm_um": id.final_.stats.emm_um,
            "emax_um": id.final_.stats.emax_um,
            "termination": id.termination.to_string(),
            "noise_estimate_um": repeat.map(|(s, _)| s.emm_um),
            "repeat_pairs": repeat.map(|(_, n)| n),
            "breakdowns": breakdowns.iter().map(|b| serde_json::json!({
                "by": b.by, "unit": b.unit, "spread": b.spread(),
                "bins": b.bins.iter().map(|x| serde_json::json!({
                    "label": x.label, "count": x.count, "emm_um": x.stats.emm_um,
                    "emax_um": x.stats.emax_um, "mean_um": x.mean_um,
                })).collect::<Vec<_>>(),
            })).collect::<Vec<_>>(),
            "periodograms": periodograms.iter().map(|(a, lines)| serde_json::json!({
                "axis": a,
                "lines": lines.iter().map(|l| serde_json::json!({
                    "order": l.frequency, "amplitude_um": l.amplitude_um,
                })).collect::<Vec<_>>(),
            })).collect::<Vec<_>>(),
            "outliers": outliers.iter().map(|(i, e)| serde_json::json!({
                "line": set.points[*i].line, "error_um": e, "where": describe(*i),
            })).collect::<Vec<_>>(),
            "identifiability": ident.as_ref().map(|a| serde_json::json!({
                "free": a.free, "rank": a.rank, "condition": a.condition,
                "weak": a.weak.iter().map(|w| w.parameters.iter().map(|(j, x)| serde_json::json!({"name": name(*j), "share": x})).collect::<Vec<_>>()).collect::<Vec<_>>(),
            })),
            "verdict": volver::solvers::candidates::verdict(&ranked, id.final_.stats.emm_um),
            "candidates": ranked.iter().take(top).map(|s| serde_json::json!({
                "id": s.id, "description": s.description, "seen": s.seen(),
                "delta_bic": s.seen().then_some(s.delta_bic),
                "emm_um": s.seen().then_some(s.emm_um),
                "size": s.seen().then_some(s.size), "size_unit": s.size_unit,
                "added": s.added, "equivalent": s.equivalent,
            })).collect::<Vec<_>>(),
        });
        println!("{}", serde_json::to_string_pretty(&obj)?);
        return Ok(());
    }
    println!(
        "volver diagnose — {} points, model \"{}\": EMM {} µm, EMax {} µm ({})",
        set.points.len(),
        model.spec().name,
        um(id.final_.stats.emm_um),
        um(id.final_.stats.emax_um),
        id.termination
    );
    match repeat {
        Some((s, n)) => println!(
            "  noise estimated from {n} repeated points: EMM {} µm — the fit is {:.2} × that",
            um(s.emm_um),
            id.final_.stats.emm_um / s.emm_um
        ),
        None => println!("  no repeated points: the noise cannot be estimated from these data"),
    }
    println!("\nWhere it fails (EMM per bin, µm; spread = largest / smallest bin):");
    for b in &breakdowns {
        let cells: Vec<String> = b
            .bins
            .iter()
            .map(|x| format!("{}:{:.1}", x.label, x.stats.emm_um))
            .collect();
        println!(
            "  {:<10} spread {:>5.2}  {}",
            format!("{} {}", b.by, b.unit).trim(),
            b.spread(),
            cells.join("  ")
        );
    }
    let worst: Vec<String> = outliers
        .iter()
        .map(|(i, e)| format!("{} {:.1} µm", describe(*i), e))
        .collect();
    println!("  largest residuals: {}", worst.join("; "));
    println!("\nPeriodograms of the residuals in the machine frame (amplitude µm of orders 1–6):");
    for (a, lines) in &periodograms {
        let cells: Vec<String> = lines
            .iter()
            .map(|l| format!("{:.1}", l.total_um()))
            .collect();
        println!("  {a}: {}", cells.join("  "));
    }
    if let Some(a) = &ident {
        println!(
            "\nIdentifiability: {} of {} free directions identified, condition {:.2e}",
            a.rank, a.free, a.condition
        );
        for w in a.weak.iter().take(4) {
            let parts: Vec<String> = w
                .parameters
                .iter()
                .take(4)
                .map(|(j, x)| format!("{} {x:+.2}", name(*j)))
                .collect();
            println!("  cannot separate: {}", parts.join(", "));
        }
    }
    println!(
        "\nVerdict: {}",
        volver::solvers::candidates::verdict(&ranked, id.final_.stats.emm_um)
    );
    println!("\nWhat is most likely missing (ranked by ΔBIC; below −10 is strong evidence):");
    println!(
        "  {:<3} {:<18} {:>10} {:>12} {:>12}  meaning",
        "#", "candidate", "ΔBIC", "EMM µm", "size"
    );
    for (i, s) in ranked.iter().take(top).enumerate() {
        let (bic, emm, size) = if s.seen() {
            (
                format!("{:.1}", s.delta_bic),
                um(s.emm_um),
                format!("{:>8.2} {:<4}", s.size, s.size_unit),
            )
        } else {
            ("—".into(), "—".into(), format!("{:>8} {:<4}", "—", ""))
        };
        println!(
            "  {:<3} {:<18} {:>10} {:>12} {size}  {}{}{}",
            i + 1,
            s.id,
            bic,
            emm,
            if s.seen() {
                ""
            } else {
                "not seen in these data: "
            },
            s.description,
            if s.equivalent.is_empty() {
                String::new()
            } else {
                format!(" (indistinguishable here from {})", s.equivalent.join(", "))
            }
        );
    }
    Ok(())
}
