//! `recording`: arbitrary bytes through the recording reader that `coordinator replay` uses.
//!
//! Properties: no panic and no unbounded allocation (libFuzzer's memory limit catches one); a
//! recording read back holds one link list per robot its metadata names.

/// Checks one input; panics when a property fails.
pub fn check(data: &[u8]) {
    let Ok(rec) = coordinator::instruments::replay::read(data) else {
        return;
    };
    assert_eq!(rec.links.len(), rec.info.robots, "one link list per robot");
    let _ = rec.wanted();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_recordings_are_refused() {
        assert!(coordinator::instruments::replay::read(b"").is_err());
        assert!(coordinator::instruments::replay::read(b"\x89MCAP0\r\n").is_err());
        check(b"not mcap");
    }
}
