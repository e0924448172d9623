//! `world_file`: arbitrary text through the world-file parser and checker.
//!
//! Properties: no panic; a refusal reads `ORIGIN:LINE: MESSAGE` with a line inside the text and a
//! non-empty message, so a user can always find what is wrong.

use world::file::{parse, WorldError};

/// The origin the check passes to the parser.
const ORIGIN: &str = "fuzz.toml";

/// Checks one input; panics when a property fails. Bytes that are not UTF-8 are replaced, as a
/// world file must be text.
pub fn check(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    let Err(e) = parse(&text, ORIGIN) else {
        return;
    };
    let shown = e.to_string();
    let line = e.line().expect("parsed text has a line");
    let lines = text.lines().count().max(1);
    assert!(
        (1..=lines + 1).contains(&line),
        "line {line} of a {lines}-line text: {shown}"
    );
    let head = format!("{ORIGIN}:{line}: ");
    let message = shown
        .strip_prefix(&head)
        .unwrap_or_else(|| panic!("{shown:?} does not start with {head:?}"));
    assert!(
        !message.trim().is_empty(),
        "empty message for {e:?} (reads {shown:?})"
    );
    assert!(!matches!(e, WorldError::Io { .. }));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_worlds_parse() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../world/worlds");
        let mut n = 0;
        for entry in std::fs::read_dir(dir).unwrap() {
            let text = std::fs::read_to_string(entry.unwrap().path()).unwrap();
            parse(&text, ORIGIN).unwrap();
            check(text.as_bytes());
            n += 1;
        }
        assert!(n > 0);
    }

    #[test]
    fn refusals_pass() {
        check(b"name = ");
        check(b"name = \"x\"\n[arena]\nwidth_m = -1\nheight_m = 1\n");
        check(&[0xFF, 0xFE]);
    }
}
