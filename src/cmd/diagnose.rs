//! `volver diagnose`: where the fit fails and what it most likely misses.

use super::{Inputs, um};
use anyhow::Result;
use volver::diagnosis::Diagnosis;

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
    let (_, model, set) = a.inputs.load()?;
    let mut d = volver::diagnosis::diagnose(&model, &set)?;
    d.candidates.truncate(a.top);
    if a.json {
        let value = serde_json::to_value(&d)?;
        println!("{}", serde_json::to_string_pretty(&value)?);
        return Ok(());
    }
    print_diagnosis(&d);
    Ok(())
}

/// The diagnosis as tables.
fn print_diagnosis(d: &Diagnosis) {
    println!(
        "volver diagnose — {} points, model \"{}\": EMM {} µm, EMax {} µm ({})",
        d.points,
        d.model,
        um(d.emm_um),
        um(d.emax_um),
        d.termination
    );
    match (d.noise_estimate_um, d.repeat_pairs) {
        (Some(s), Some(n)) => println!(
            "  noise estimated from {n} repeated points: EMM {} µm — the fit is {:.2} × that",
            um(s),
            d.emm_um / s
        ),
        _ => println!("  no repeated points: the noise cannot be estimated from these data"),
    }
    println!("\nWhere it fails (EMM per bin, µm; spread = largest / smallest bin):");
    for b in &d.breakdowns {
        let cells: Vec<String> = b
            .bins
            .iter()
            .map(|x| format!("{}:{:.1}", x.label, x.emm_um))
            .collect();
        println!(
            "  {:<10} spread {:>5.2}  {}",
            format!("{} {}", b.by, b.unit).trim(),
            b.spread,
            cells.join("  ")
        );
    }
    let worst: Vec<String> = d
        .outliers
        .iter()
        .map(|o| format!("{} {:.1} µm", o.place, o.error_um))
        .collect();
    println!("  largest residuals: {}", worst.join("; "));
    println!("\nPeriodograms of the residuals in the machine frame (amplitude µm of orders 1–6):");
    for p in &d.periodograms {
        let cells: Vec<String> = p
            .lines
            .iter()
            .map(|l| format!("{:.1}", l.total_um()))
            .collect();
        println!("  {}: {}", p.axis, cells.join("  "));
    }
    print_candidates(d);
}

/// What the data cannot separate, the verdict and the candidates.
fn print_candidates(d: &Diagnosis) {
    if let Some(a) = &d.identifiability {
        println!(
            "\nIdentifiability: {} of {} free directions identified, condition {:.2e}",
            a.rank, a.free, a.condition
        );
        for w in a.weak.iter().take(4) {
            let parts: Vec<String> = w
                .iter()
                .take(4)
                .map(|s| format!("{} {:+.2}", s.name, s.share))
                .collect();
            println!("  cannot separate: {}", parts.join(", "));
        }
    }
    println!("\nVerdict: {}", d.verdict);
    println!("\nWhat is most likely missing (ranked by ΔBIC; below −10 is strong evidence):");
    println!(
        "  {:<3} {:<18} {:>10} {:>12} {:>12}  meaning",
        "#", "candidate", "ΔBIC", "EMM µm", "size"
    );
    for (i, s) in d.candidates.iter().enumerate() {
        let (bic, emm, size) =
            if let (Some(bic), Some(emm), Some(size)) = (s.delta_bic, s.emm_um, s.size) {
                (
                    format!("{bic:.1}"),
                    um(emm),
                    format!("{:>8.2} {:<4}", size, s.size_unit),
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
            if s.seen {
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
}
