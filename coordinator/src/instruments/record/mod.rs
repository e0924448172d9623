//! MCAP recording: every packet in both directions, the world model's snapshots, the robots'
//! events and Foxglove scene messages, written by one thread so no actor ever waits on the disk.
//!
//! Chunks are built in memory and reach the file only whole: every [`FLUSH_EVERY`] (or every
//! [`CHUNK_BYTES`]) the open chunk is closed and written in one piece, followed by a provisional
//! end (a data end record, a footer without summary and the closing magic) that the next write
//! overwrites. The file on disk is therefore a complete MCAP file at every moment: a process
//! killed mid-run leaves one that any MCAP reader reads up to its last closed chunk, and
//! `coordinator recover` adds the summary and indexes a clean finish would have written.
//!
//! # Layout
//! - `format`: the channels, the run's metadata and packet directions.
//! - `writer`: the [`Recorder`] and its writer thread.
//! - `whole_records`: the file that only ever holds whole records and a valid end.
//! - `tap`: the connector wrapper recording every packet.
//! - `layout`: wire structs as JSON and leaf by leaf, from their layouts.
//! - `foxglove`: Foxglove message parts.

mod format;
mod foxglove;
mod layout;
mod tap;
mod whole_records;
mod writer;

pub use format::{Dir, RunInfo, Topic, METADATA_NAME};
pub use foxglove::{fox_pose, fox_time};
pub use layout::{layout_json, leaf_bytes, leaf_value, leaves, Leaf};
pub use tap::Tap;
pub use writer::{RecordStats, Recorder, CHUNK_BYTES, FLUSH_EVERY};
