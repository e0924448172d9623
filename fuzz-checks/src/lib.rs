//! The properties our fuzz targets check, one module per target, each with a `check(data)` that
//! panics when a property fails.
//!
//! The cargo-fuzz package in `fuzz/` (outside the workspace, it needs libFuzzer) calls these on
//! generated inputs; this crate's `corpus` test calls them on every committed corpus and regression
//! file, so `cargo test` replays what fuzzing found without needing cargo-fuzz.

pub mod firmware_link;
pub mod frame;
pub mod recording;
pub mod slip;
pub mod world_file;

/// A target's checks: panics when a property fails.
pub type Check = fn(&[u8]);

/// The fuzz targets, by the name of their corpus folder.
pub const TARGETS: &[(&str, Check)] = &[
    ("frame", frame::check),
    ("slip", slip::check),
    ("firmware_link", firmware_link::check),
    ("world_file", world_file::check),
    ("recording", recording::check),
];

/// Splits an input into a chunking plan and the data it chunks.
///
/// The first byte says how many plan bytes follow (`1 + byte % 8`); the data is cut into pieces
/// whose sizes are those plan bytes in turn, cycled (`1 + plan_byte % max_chunk` each), so the
/// fuzzer explores chunk boundaries as freely as the bytes themselves.
#[derive(Clone, Debug)]
pub struct Chunked<'a> {
    plan: &'a [u8],
    data: &'a [u8],
}

impl<'a> Chunked<'a> {
    /// Reads the plan from the head of `input`; `None` if the input is shorter than its plan.
    pub fn new(input: &'a [u8]) -> Option<Self> {
        let (&n, rest) = input.split_first()?;
        let n = 1 + usize::from(n % 8);
        (rest.len() >= n).then(|| Self {
            plan: &rest[..n],
            data: &rest[n..],
        })
    }

    /// The bytes after the plan.
    pub fn data(&self) -> &'a [u8] {
        self.data
    }

    /// The plan bytes, in the order they are used.
    pub fn plan(&self) -> &'a [u8] {
        self.plan
    }

    /// The data cut into pieces of at most `max_chunk` bytes, each with the plan byte that sized it.
    pub fn pieces(&self, max_chunk: usize) -> Vec<(u8, &'a [u8])> {
        let mut out = Vec::new();
        let mut rest = self.data;
        let mut plan = self.plan.iter().cycle();
        while !rest.is_empty() {
            let &p = plan.next().unwrap_or(&0);
            let n = (1 + usize::from(p) % max_chunk.max(1)).min(rest.len());
            let (piece, tail) = rest.split_at(n);
            out.push((p, piece));
            rest = tail;
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pieces_cover_the_data_in_order() {
        let input = [1u8, 2, 0, 10, 11, 12, 13, 14, 15];
        let c = Chunked::new(&input).unwrap();
        assert_eq!(c.plan(), &[2, 0]);
        let pieces = c.pieces(8);
        let sizes: Vec<usize> = pieces.iter().map(|(_, p)| p.len()).collect();
        assert_eq!(sizes, vec![3, 1, 2]);
        let joined: Vec<u8> = pieces.iter().flat_map(|(_, p)| p.iter().copied()).collect();
        assert_eq!(joined, c.data());
    }

    #[test]
    fn an_input_shorter_than_its_plan_is_skipped() {
        assert!(Chunked::new(&[]).is_none());
        assert!(Chunked::new(&[3, 1, 2]).is_none());
    }
}
