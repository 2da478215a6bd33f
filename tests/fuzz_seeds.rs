//! Every committed fuzz seed (`fuzz/seeds/TARGET/*`: the starting inputs and every input a
//! fuzzer once found to crash volver) goes through its reader's harness in
//! `volver_core::fuzz`: refused or accepted, never a panic.

use std::path::Path;

#[test]
fn every_fuzz_seed_is_read_without_a_panic() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/seeds");
    let mut total = 0;
    for (target, harness) in volver_core::fuzz::TARGETS {
        let dir = root.join(target);
        let mut files: Vec<_> = std::fs::read_dir(&dir)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        assert!(!files.is_empty(), "{}: no seeds", dir.display());
        for f in files {
            let data = std::fs::read(&f).unwrap();
            let run = std::panic::catch_unwind(|| harness(&data));
            assert!(run.is_ok(), "{} panics", f.display());
            total += 1;
        }
    }
    assert!(total >= 7);
}
