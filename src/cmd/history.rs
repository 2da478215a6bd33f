//! `volver history`: the fits of a diagnosis session.

use anyhow::{Context, Result};
use std::path::PathBuf;
use volver::history;

/// Options of `volver history`.
#[derive(clap::Args)]
pub struct HistoryArgs {
    /// History file written by `volver identify`.
    #[arg(long, default_value = history::DEFAULT_NAME)]
    file: PathBuf,
    /// Write the chart here (SVG).
    #[arg(long)]
    svg: Option<PathBuf>,
}

/// Runs `volver history`.
pub fn run(a: HistoryArgs) -> Result<()> {
    let HistoryArgs { file, svg } = a;
    if let Some(path) = &svg {
        volver::core::fsio::Outputs::new([&file]).claim(path)?;
    }
    let read = history::read(&file)?;
    let records = read.records;
    if !read.skipped.is_empty() {
        let lines: Vec<String> = read.skipped.iter().map(ToString::to_string).collect();
        eprintln!(
            "  warning: {}: line(s) {} skipped, not whole history records (a fit killed while \
             it wrote its line, or a hand edit)",
            file.display(),
            lines.join(", ")
        );
    }
    println!(
        "volver history — {} fits in {}\n",
        records.len(),
        file.display()
    );
    print!("{}", history::table(&records));
    if let Some(path) = svg {
        volver::core::fsio::write_atomic(&path, history::svg(&records))
            .with_context(|| format!("writing {}", path.display()))?;
        println!("\n  chart written to {}", path.display());
    }
    Ok(())
}
