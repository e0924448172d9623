//! Every committed fuzz input, corpus and regressions alike, still passes its target's checks:
//! what fuzzing found stays fixed under a plain `cargo test`.

use std::path::{Path, PathBuf};

fn fuzz_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz")
}

/// The files of `fuzz/<kind>/<target>/`, sorted; none if the folder does not exist.
fn inputs(kind: &str, target: &str) -> Vec<PathBuf> {
    let dir = fuzz_dir().join(kind).join(target);
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return Vec::new();
    };
    let mut files: Vec<PathBuf> = entries
        .map(|e| e.expect("readable corpus folder").path())
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    files
}

fn replay(target: &str) {
    let check = fuzz_checks::TARGETS
        .iter()
        .find(|(name, _)| *name == target)
        .map(|&(_, f)| f)
        .expect("a known target");
    let corpus = inputs("corpus", target);
    assert!(!corpus.is_empty(), "fuzz/corpus/{target} holds no inputs");
    for path in corpus.iter().chain(&inputs("regressions", target)) {
        let data = std::fs::read(path).expect("readable corpus file");
        let outcome = std::panic::catch_unwind(|| check(&data));
        assert!(outcome.is_ok(), "{} fails its checks", path.display());
    }
}

#[test]
fn frame_corpus() {
    replay("frame");
}

#[test]
fn slip_corpus() {
    replay("slip");
}

#[test]
fn firmware_link_corpus() {
    replay("firmware_link");
}

#[test]
fn world_file_corpus() {
    replay("world_file");
}

#[test]
fn recording_corpus() {
    replay("recording");
}

#[test]
fn every_target_has_a_test_here() {
    let names: Vec<&str> = fuzz_checks::TARGETS.iter().map(|(n, _)| *n).collect();
    assert_eq!(
        names,
        ["frame", "slip", "firmware_link", "world_file", "recording"]
    );
}
