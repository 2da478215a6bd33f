//! Every engine of this build on one problem, compared on Φ and on the residuals (not on raw
//! parameters: what the data cannot identify may differ while the fit is the same). The
//! engines are chosen by Cargo feature: `lm` always, `clarabel` and `lm+clarabel` with
//! `clarabel` (default), `ceres` with `ceres`, the NLopt ones with `nlopt`.
//!
//! ```text
//! cargo run -p volver-solvers --example engines --all-features
//! ```

use volver_core::machine::Machine;
use volver_core::model::{ErrorModelSpec, Model};
use volver_core::noise::TrackerNoise;
use volver_core::plan::Plan;
use volver_core::problem::Problem;
use volver_core::simulate::{Magnitudes, Simulation, Truth};
use volver_solvers::strategy::{Strategy, identify};
use volver_solvers::{ENGINES, Options, Silent, engine};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // Test 3 of the paper on the XCFZ grinder, noise-free: every engine should reach Φ ≈ 0.
    let machine = Machine::default_xcfz();
    let truth = Truth::random(
        &machine,
        &ErrorModelSpec::complete(&machine),
        &Magnitudes::default(),
        1,
    )?;
    let mut sim = Simulation::new(Plan::preset(&machine, "test3")?, truth, 1);
    sim.noise = TrackerNoise::NONE;
    let data = sim.run()?.measurements;
    let model = Model::default_xcfz();
    let problem = Problem::new(&model, &data)?;
    println!(
        "{:<12} {:>14} {:>12}  termination",
        "engine", "Φ µm", "EMax µm"
    );
    for info in ENGINES {
        // An engine whose feature this build lacks says which one it needs.
        let solver = match engine(info.name) {
            Ok(s) => s,
            Err(e) => {
                println!("{:<12} {e}", info.name);
                continue;
            }
        };
        let id = identify(
            solver.as_ref(),
            problem.clone(),
            &model.initial_params(),
            &Strategy::default(),
            &Options::default(),
            &mut Silent,
        );
        println!(
            "{:<12} {:>14.6} {:>12.6}  {}",
            info.name,
            id.reached.phi_mm * 1e3,
            id.reached.stats.emax_um,
            id.termination
        );
    }
    Ok(())
}
