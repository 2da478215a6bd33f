//! `volver study paper`: the paper's studies on synthetic data beside the paper's figures.

use anyhow::{Context, Result};
use std::path::PathBuf;
use volver::study::{self, Figures, Table};

/// Options of `volver study`.
#[derive(clap::Args)]
pub struct StudyArgs {
    /// Which study: paper.
    which: String,
    /// Seed of the true errors and the noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Also draw table 12 (cross-validation: residual % on the reference test 4 after
    /// compensation with each test's errors, ours beside the paper's) as an SVG chart here.
    #[arg(long)]
    svg: Option<PathBuf>,
}

/// Runs `volver study`.
pub fn run(a: StudyArgs) -> Result<()> {
    let StudyArgs { which, seed, svg } = a;
    if which != "paper" {
        anyhow::bail!("unknown study '{which}': the study is `paper`");
    }
    println!(
        "volver study paper — the paper's studies on synthetic data (seed {seed}; each \
         table's true errors scaled to its initial EMM in the paper; the paper's noise \
         read as bounds, {})",
        volver::core::noise::TrackerNoise::PAPER
    );
    let tables = study::paper(seed)?;
    print(&tables);
    print_estimators(seed)?;
    if let Some(path) = svg {
        let t12 = tables
            .iter()
            .find(|t| t.title.starts_with("Table 12"))
            .ok_or_else(|| anyhow::anyhow!("the study has no table 12"))?;
        volver::core::fsio::write_atomic(&path, study::table12_svg(t12))
            .with_context(|| format!("writing {}", path.display()))?;
        println!("\n  table 12 drawn in {}", path.display());
    }
    Ok(())
}

/// Prints the tables.
fn print(tables: &[Table]) {
    let cells = |f: &Figures| {
        format!(
            "{:>8.2} {:>8.2} → {:>9.3} {:>9.3} ({:>7.2} %)",
            f.emm0_um, f.emax0_um, f.emm_um, f.emax_um, f.residual_percent
        )
    };
    for t in tables {
        println!("\n{}", t.title);
        println!(
            "  {:<46}        EMM₀ µm  EMax₀ µm →    EMM µm   EMax µm (residual)",
            ""
        );
        for r in &t.rows {
            println!(
                "  {:<46} paper  {}",
                r.label,
                r.paper.as_ref().map_or("—".to_string(), cells)
            );
            println!(
                "  {:<46} volver {}{}",
                "",
                cells(&r.ours),
                if r.converged {
                    String::new()
                } else {
                    format!(" * {}", r.termination)
                }
            );
        }
        if let Some(((pe, pm), (oe, om))) = t.noise {
            println!(
                "  {:<46} paper  EMM {pe:.1} µm, EMax {pm:.1} µm; volver EMM {oe:.1} µm, EMax {om:.1} µm",
                "noise error of the noisy data"
            );
        }
        println!("  note: {}", t.note);
    }
    if tables.iter().flat_map(|t| &t.rows).any(|r| !r.converged) {
        println!(
            "\n  * not converged: stopped by a limit, or where the shared check found that one \
             more step could still lower Φ (the fraction it gives); the figures are those reached"
        );
    }
}

/// The estimators side by side on test 4 (not in the paper): Φ, ml and whitened Φ on five
/// truths per noise, beside the Cramér–Rao limit.
fn print_estimators(seed: u64) -> Result<()> {
    let model = volver::core::model::Model::default_xcfz();
    let m = model.machine();
    let plan = volver::core::plan::Plan::preset(m, "test4")?;
    let grid = volver::solvers::uncertainty::ToolGrid {
        commands: volver::uncertainty::grid_of(m, None)?.positions,
        tool: volver::shared::reflector_centroid(&model),
    };
    println!(
        "\nThe estimators on test 4 (not in the paper): the paper's Φ, ml (least squares on \
         residuals whitened by the tracker's noise) and whitened Φ, 5 truths per noise (seeds \
         {seed}–{}); the tool point at the reflectors' centroid over {} commands after the \
         set-up's transform, RMS over the truths",
        seed + 4,
        grid.commands.len()
    );
    println!(
        "  {:<20} {:<7} {:>16} {:>13} {:>15} {:>8}",
        "noise", "", "realised µm", "expected µm", "U95 max µm", "time s"
    );
    for noise in ["paper", "normal:30,30,4,0.8"] {
        let tracker = volver::core::noise::TrackerNoise::from_text(noise)?;
        let s = volver::estimators::over_truths(&model, &plan, tracker, &grid, seed..seed + 5)?;
        for r in &s.rows {
            println!(
                "  {noise:<20} {:<7} {:>16.2} {:>13.2} {:>15.2} {:>8.2}",
                r.objective.to_string(),
                r.realised_um.unwrap_or(f64::NAN),
                r.expected_um,
                r.u95_max_um,
                r.time_s
            );
        }
        println!(
            "  {noise:<20} {:<7} {:>16} {:>13.2}   ({})",
            "limit",
            "",
            s.cramer_rao_um,
            s.limit_name()
        );
    }
    Ok(())
}
