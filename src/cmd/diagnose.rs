//! `volver diagnose`: where the fit fails and what it most likely misses.

use super::{Inputs, um};
use anyhow::{Context, Result};
use std::path::Path;
use volver::core::measure::MeasurementSet;
use volver::core::model::Model;
use volver::diagnosis::Diagnosis;

/// Options of `volver diagnose`.
#[derive(clap::Args)]
pub struct DiagnoseArgs {
    #[command(flatten)]
    inputs: Inputs,
    /// How many candidates to list.
    #[arg(long, default_value_t = 10)]
    top: usize,
    /// The tracker's noise specification the fit is judged against: paper, none,
    /// normal:AZ_URAD,EL_URAD,RANGE_UM,RANGE_UM_PER_M (σ), uniform:… (bounds) or
    /// mpe:A_UM,B_UM_PER_M (±(a + b·L), k = 2). Default: the machine file's `[tracker] noise`.
    /// A station whose `[[station]]` table states its own noise is judged by its own.
    #[arg(long)]
    noise: Option<String>,
    /// Run the loop to the end: add the best significant candidate, refit, diagnose again,
    /// until the fit is at the noise or nothing significant is left.
    #[arg(long)]
    iterate: bool,
    /// With --iterate: at most this many candidates are added.
    #[arg(long, default_value_t = 5, requires = "iterate")]
    max_added: usize,
    /// With --iterate: append every round's fit to this history file (default:
    /// volver-history.jsonl beside the data).
    #[arg(long, requires = "iterate")]
    history: Option<std::path::PathBuf>,
    /// With --iterate: do not append the rounds to any history file.
    #[arg(long, conflicts_with = "history")]
    no_history: bool,
    /// With --iterate: write the final error model (every addition of the loop) as TOML, for
    /// `volver identify --model`.
    #[arg(long, requires = "iterate")]
    write_model: Option<std::path::PathBuf>,
    /// With --iterate: write the final model's fit as a results file (JSON), as `volver identify
    /// --out` writes it; a fit `identify` would refuse (implausible sizes, a limit reached) is
    /// not written and the command fails with the reason.
    #[arg(long, requires = "iterate")]
    out: Option<std::path::PathBuf>,
    /// Print one JSON object instead of the tables.
    #[arg(long)]
    json: bool,
}

/// Runs `volver diagnose`.
pub fn run(a: DiagnoseArgs) -> Result<()> {
    let (_, model, set) = a.inputs.load()?;
    let noise = match &a.noise {
        Some(text) => Some(volver::core::noise::TrackerNoise::from_text(text)?),
        None => model.machine().default_noise(),
    };
    if a.iterate {
        return iterate(&a, &model, &set, noise.as_ref());
    }
    let mut d = volver::diagnosis::diagnose_with(&model, &set, noise.as_ref())?;
    d.candidates.truncate(a.top);
    if a.json {
        let value = serde_json::to_value(&d)?;
        println!("{}", serde_json::to_string_pretty(&value)?);
        return Ok(());
    }
    print_diagnosis(&d);
    Ok(())
}

/// `volver diagnose --iterate`: the loop of diagnoses and additions, its history and its final
/// model.
fn iterate(
    a: &DiagnoseArgs,
    model: &Model,
    set: &MeasurementSet,
    noise: Option<&volver::core::noise::TrackerNoise>,
) -> Result<()> {
    let history = (!a.no_history).then(|| {
        a.history
            .clone()
            .unwrap_or_else(|| volver::history::default_path(&a.inputs.data))
    });
    let mut outputs = volver::core::fsio::Outputs::new(a.inputs.paths(&[]));
    for path in [&history, &a.write_model, &a.out].into_iter().flatten() {
        outputs.claim(path)?;
    }
    let data_name = a.inputs.data.display().to_string();
    let mut records = Vec::new();
    let (mut rounds, last_model) =
        volver::diagnosis::iterate(model, set, noise, a.max_added, |r| {
            records.push(
                r.diagnosis
                    .history_record(&data_name, &r.added, r.parameters),
            );
            if !a.json {
                print_round(records.len(), r);
            }
        })?;
    if let Some(path) = &history {
        for record in &records {
            volver::history::append(path, record)?;
        }
    }
    write_final(a, &last_model, set)?;
    if let Some(last) = rounds.last_mut() {
        last.diagnosis.candidates.truncate(a.top);
    }
    let last = rounds
        .last()
        .ok_or_else(|| anyhow::anyhow!("the diagnosis loop ran no round"))?;
    if a.json {
        let value = serde_json::json!({
            "rounds": rounds.iter().map(|r| serde_json::json!({
                "added": r.added,
                "parameters": r.parameters,
                "emm_um": r.diagnosis.emm_um,
                "noise_ratio": r.diagnosis.noise.as_ref().map(|n| n.ratio),
                "verdict": r.diagnosis.verdict,
            })).collect::<Vec<_>>(),
            "final": serde_json::to_value(&last.diagnosis)?,
        });
        println!("{}", serde_json::to_string_pretty(&value)?);
        return Ok(());
    }
    print_final(a, last, history.as_deref(), records.len());
    Ok(())
}

/// The final model's diagnosis of the loop and the files written.
fn print_final(
    a: &DiagnoseArgs,
    last: &volver::diagnosis::Round,
    history: Option<&Path>,
    rounds: usize,
) {
    println!(
        "\nThe final model{}:\n",
        if last.added.is_empty() {
            String::new()
        } else {
            format!(" (with {})", last.added.join(", "))
        }
    );
    print_diagnosis(&last.diagnosis);
    if let Some(path) = history {
        println!(
            "\n{rounds} rounds appended to {} (`volver history` shows them)",
            path.display()
        );
    }
    if let Some(path) = &a.write_model {
        println!(
            "the final model is written to {} (`volver identify --model` reads it)",
            path.display()
        );
    }
    if let Some(path) = &a.out {
        println!("its fit is written to {}", path.display());
    }
}

/// One round of `diagnose --iterate`, in a line or two.
/// The final model of the loop as TOML (`--write-model`) and its fit as a results file
/// (`--out`, as `volver identify --out` writes it: the same fit, with its uncertainty).
fn write_final(
    a: &DiagnoseArgs,
    model: &volver::core::model::Model,
    set: &volver::core::measure::MeasurementSet,
) -> Result<()> {
    if let Some(path) = &a.write_model {
        let text = toml::to_string(model.spec()).context("writing the error model")?;
        volver::core::fsio::write_atomic(path, text)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(path) = &a.out {
        // The noise of the uncertainty it records: the one rule `identify` follows.
        let mut settings = volver::identification::Settings::default();
        settings.noise = volver::inputs::noise_rule(a.noise.as_deref(), model.machine())?.0;
        let outcome =
            volver::identification::identify(model, set, &settings, &mut volver::solvers::Silent)?;
        if let Some(why) = &outcome.refusal {
            anyhow::bail!(
                "the final model's fit is not written to {}: {why}",
                path.display()
            );
        }
        outcome
            .results
            .save(path)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

fn print_round(k: usize, r: &volver::diagnosis::Round) {
    let d = &r.diagnosis;
    let noise = d.noise.as_ref().map_or(String::new(), |n| {
        format!(
            " = {:.3} × the noise's {} µm",
            n.ratio,
            um(n.expected_fit_um)
        )
    });
    println!(
        "round {k}: {}{} — EMM {} µm{noise}",
        d.model,
        if r.added.is_empty() {
            String::new()
        } else {
            format!(" + {}", r.added.join(" + "))
        },
        um(d.emm_um)
    );
    match (&r.next, d.finding()) {
        (Some(_), Some(c)) => println!(
            "  → add {} (ΔBIC {:.0}): {}",
            c.id,
            c.delta_bic.unwrap_or(0.0),
            c.description
        ),
        _ if r.limited => println!(
            "  → stop: --max-added reached; the loop would add {} next",
            d.finding().map_or("nothing", |c| c.id.as_str())
        ),
        _ => println!("  → stop: {}", d.verdict),
    }
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
    print_noise(d);
    println!("\nWhere it fails (EMM per bin, µm; spread = largest / smallest bin):");
    for b in &d.breakdowns {
        let cells: Vec<String> = b
            .bins
            .iter()
            .map(|x| {
                let above = d.noise.as_ref().is_some_and(|n| {
                    n.above.iter().any(|a| {
                        a.by == b.by && a.bin.split(' ').next() == x.label.split(' ').next()
                    })
                });
                format!(
                    "{}:{:.1}{}",
                    x.label,
                    x.emm_um,
                    if above { "*" } else { "" }
                )
            })
            .collect();
        println!(
            "  {:<10} spread {:>5.2}  {}",
            format!("{} {}", b.by, b.unit).trim(),
            b.spread,
            cells.join("  ")
        );
    }
    if d.noise.as_ref().is_some_and(|n| !n.above.is_empty()) {
        println!("  (* the misfit there exceeds the tracker's noise)");
    }
    print_directions(d);
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

/// The residuals split by each axis' direction of approach (axes reached from both sides).
fn print_directions(d: &Diagnosis) {
    if d.directions.is_empty() {
        return;
    }
    println!(
        "  by direction of approach (the positioning error each side's points show beyond the \
         model; forward − reverse at the same position is the reversal they show):"
    );
    for x in &d.directions {
        println!("    {}{}", x.text(), if x.significant { " *" } else { "" });
    }
    if d.directions.iter().any(|x| x.significant) {
        println!(
            "    (* more than {} standard errors: the residuals depend on the direction of \
             approach — a reversal the model lacks)",
            volver::diagnosis::DIRECTION_Z
        );
    }
}

/// The fit against the noise: the tracker's specification, repeated points, or neither.
fn print_noise(d: &Diagnosis) {
    let repeats = d.noise_estimate_um.zip(d.repeat_pairs);
    match (&d.noise, repeats) {
        (Some(n), _) => {
            let label = if n.stations.is_empty() {
                format!("tracker noise {}", n.model)
            } else if n.stations.iter().all(|s| s.own) {
                "the stations' noise (each its own)".to_string()
            } else {
                format!("the stations' noise (by default {})", n.model)
            };
            println!(
                "  {label}: its noise error here is {} µm, a complete model's fit leaves {} ± {} \
                 µm (k = 2); this fit is {:.3} × that — {}",
                um(n.noise_error_um),
                um(n.expected_fit_um),
                um(n.u95_um),
                n.ratio,
                if n.at_noise {
                    "at the noise"
                } else if n.below {
                    "far below it: the specification overstates these data's noise"
                } else {
                    "above the noise"
                }
            );
            if !n.stations.is_empty() {
                println!("  by station, the σ per coordinate its residuals show and its noise's:");
            }
            for st in &n.stations {
                let standing = match st.standing {
                    volver::diagnosis::Standing::AtNoise => "at its noise",
                    volver::diagnosis::Standing::Above => "ABOVE its noise",
                    volver::diagnosis::Standing::Below => "BELOW its noise",
                };
                println!("    {} — {standing}", st.text());
            }
            if let Some(r) = &n.repeats {
                println!(
                    "  {} repeated points give {} µm, the specification {} ± {} µm there: {}",
                    r.pairs,
                    um(r.estimate_um),
                    um(r.specified_um),
                    um(r.u95_um),
                    if r.agree {
                        "they agree"
                    } else {
                        "they DISAGREE — the specification does not describe this tracker \
                         here, or the machine moved between repeats"
                    }
                );
            }
            if !n.above.is_empty() {
                let worst: Vec<String> = n
                    .above
                    .iter()
                    .take(6)
                    .map(|a| format!("{} {} ({:.2} ×)", a.by, a.bin, a.ratio))
                    .collect();
                println!(
                    "  the misfit exceeds the noise most at: {}",
                    worst.join(", ")
                );
            }
        }
        (None, Some((s, n))) => println!(
            "  noise estimated from {n} repeated points: EMM {} µm — the fit is {:.2} × that",
            um(s),
            d.emm_um / s
        ),
        (None, None) => println!(
            "  no repeated points and no tracker noise given (--noise or the machine file's \
             [tracker] noise): the noise cannot be judged"
        ),
    }
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
            match (&s.flag, s.seen) {
                _ if s.failed.is_some() => format!(
                    "COULD NOT BE SCORED ({}): ",
                    s.failed.as_deref().unwrap_or("")
                ),
                (Some(why), _) => format!("IMPLAUSIBLE ({why}): "),
                (None, true) => String::new(),
                (None, false) => "not seen in these data: ".into(),
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
