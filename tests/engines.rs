//! The engine table (`volver_solvers::ENGINES`) against what a user reads and gets: the README's
//! engine table names every engine with its Cargo feature and no other, each engine of the build
//! answers to its name, and an engine the build lacks is refused with the feature that brings it.
//! The engines' settings reach the CLI through one file, checked before anything is fitted.

mod common;

use volver::solvers::{ENGINES, engine, engine_names};

/// The rows of the README's table under "### Engines": (engine names, feature cell).
fn readme_rows() -> Vec<(Vec<String>, String)> {
    let readme = include_str!("../README.md");
    let section = readme
        .split("### Engines")
        .nth(1)
        .expect("the README has an Engines section");
    section
        .lines()
        .skip_while(|l| !l.starts_with("| engine"))
        .skip(2)
        .take_while(|l| l.starts_with('|'))
        .map(|l| {
            let cells: Vec<&str> = l.split('|').map(str::trim).collect();
            let names = cells[1]
                .split(',')
                .map(|n| n.trim().trim_matches('`').to_string())
                .collect();
            (names, cells[2].to_string())
        })
        .collect()
}

#[test]
fn the_readme_table_lists_every_engine_with_its_feature() {
    let rows = readme_rows();
    assert!(!rows.is_empty(), "no engine table found in the README");
    for e in ENGINES {
        let (_, feature) = rows
            .iter()
            .find(|(names, _)| names.iter().any(|n| n == e.name))
            .unwrap_or_else(|| panic!("the README's engine table lacks `{}`", e.name));
        match e.feature {
            None => assert!(feature.contains("always"), "{}: {feature}", e.name),
            Some(f) => assert!(feature.contains(&format!("`{f}`")), "{}: {feature}", e.name),
        }
        assert!(!e.description.is_empty());
    }
    for (names, _) in &rows {
        for n in names {
            assert!(
                ENGINES.iter().any(|e| e.name == n),
                "the README names an engine volver does not know: {n}"
            );
        }
    }
}

#[test]
fn every_engine_answers_to_its_name_or_names_its_feature() {
    let names = engine_names();
    for e in ENGINES {
        match e.make {
            Some(_) => {
                assert!(names.contains(&e.name));
                assert_eq!(engine(e.name).unwrap().name(), e.name);
            }
            None => {
                let err = engine(e.name).err().unwrap();
                let f = e.feature.expect("an engine built always has a constructor");
                assert!(
                    matches!(&err, volver::solvers::Error::UnknownEngine { feature, .. } if *feature == Some(f)),
                    "{err}"
                );
                let msg = err.to_string();
                assert!(
                    msg.contains(&format!("needs the Cargo feature `{f}`")),
                    "{msg}"
                );
            }
        }
    }
    let msg = engine("simplex").err().unwrap().to_string();
    assert!(
        msg.starts_with("unknown solver 'simplex': this build has lm"),
        "{msg}"
    );
}

/// The README's Engines section tells a library user which crate to depend on: its Rust code
/// (compiled and run as doctests of the facade) must name no crate of volver's that its
/// `[dependencies]` lines leave out (issue 48: the code used `volver::` under a dependency on
/// `volver-solvers` alone).
#[test]
fn the_readme_engines_code_uses_only_the_crates_it_tells_you_to_depend_on() {
    let readme = include_str!("../README.md");
    let section = readme
        .split("### Engines")
        .nth(1)
        .and_then(|s| s.split("\n### ").next())
        .expect("the README has an Engines section");
    let blocks = |lang: &str| -> Vec<String> {
        section
            .split(&format!("```{lang}\n"))
            .skip(1)
            .map(|b| b.split("```").next().unwrap_or_default().to_string())
            .collect()
    };
    let deps: Vec<String> = blocks("toml")
        .iter()
        .flat_map(|b| b.lines().map(str::to_string).collect::<Vec<_>>())
        .filter_map(|l| l.split_once('=').map(|(k, _)| k.trim().replace('-', "_")))
        .collect();
    assert!(deps.contains(&"volver_solvers".to_string()), "{deps:?}");
    let rust = blocks("rust");
    assert!(rust.len() >= 2, "the machine fit and the user's residual");
    // The workspace's crates and the ones they build on, by their names in Rust.
    let crates = [
        "volver",
        "volver_core",
        "volver_solvers",
        "volver_cli",
        "num_dual",
    ];
    for code in &rust {
        for (at, _) in code.match_indices("::") {
            let before = &code[..at];
            let root_start = before
                .rfind(|c: char| !(c.is_alphanumeric() || c == '_'))
                .map_or(0, |k| k + 1);
            let root = &before[root_start..];
            let path_start = before[..root_start].ends_with("::");
            if !path_start && crates.contains(&root) {
                assert!(
                    deps.iter().any(|d| d == root),
                    "the README's Engines code uses `{root}::` but its dependencies are {deps:?}"
                );
            }
        }
    }
}

/// `--engine-settings FILE.toml`: a setting out of range and an unknown field are refused
/// naming them, `--geodesic-acceleration` is refused with an engine that does not read it, and
/// valid settings are taken.
#[test]
fn engine_settings_reach_identify_through_one_checked_file() {
    let dir = common::scratch_dir("engine-settings", "identify");
    let d = |name: &str| dir.join(name).to_str().unwrap().to_string();
    common::ok(&[
        "simulate",
        "--plan",
        "test3",
        "--seed",
        "3",
        "--out",
        &d("sim"),
    ]);
    let data = d("sim/measurements.csv");
    let run = |settings: &str, extra: &[&str]| {
        std::fs::write(dir.join("engines.toml"), settings).unwrap();
        let mut args = vec![
            "identify",
            "--data",
            &data,
            "--no-history",
            "--engine-settings",
        ];
        let file = d("engines.toml");
        args.push(&file);
        args.extend_from_slice(extra);
        let out = common::volver(&args);
        let err = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(!err.contains("panicked"), "{err}");
        (out.status.success(), err)
    };
    let (ok, err) = run("[ceres]\nthreads = 0\n", &[]);
    assert!(!ok && err.contains("ceres.threads = 0"), "{err}");
    let (ok, err) = run("[lm]\nthread = 2\n", &[]);
    assert!(
        !ok && err.contains("engines.toml") && err.contains("thread"),
        "{err}"
    );
    let (ok, err) = run("", &["--solver", "clarabel", "--geodesic-acceleration"]);
    assert!(!ok && err.contains("--geodesic-acceleration"), "{err}");
    let (ok, err) = run("[lm]\nthreads = 2\n", &["--json"]);
    assert!(ok, "{err}");
}
