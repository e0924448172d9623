//! `coordinator recover`: a recording whose writer never finished (killed, or cut off mid-record
//! by a full disk or a copy) rewritten as a complete MCAP file, with the summary and indexes a
//! clean finish writes.
//!
//! The input is walked record by record. Everything up to the last whole record that makes sense
//! is kept: a chunk is kept whole or not at all, and reading stops at the first record that is
//! cut short, unreadable, or names a schema or channel never defined. Chunk boundaries are kept,
//! so a file that was already complete comes out with the same records in the same chunks.

use std::collections::HashMap;
use std::fmt;
use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _, Result};
use mcap::records::{self, op, Record};

/// How the input ended.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Ending {
    /// With its summary: the recording had been finished.
    Complete,
    /// With a data end and footer but no summary: a recording killed after its last write.
    Unfinished,
    /// In the middle of the data: everything from `offset` on (`dropped` bytes) was left out.
    Cut {
        /// Byte offset of the first record left out.
        offset: u64,
        /// Bytes left out.
        dropped: u64,
        /// What was wrong there.
        why: String,
    },
}

/// What a recovery kept.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Recovered {
    /// Messages written to the output.
    pub messages: u64,
    /// Chunks of the input they came from.
    pub chunks: u64,
    /// Metadata records kept.
    pub metadata: u64,
    /// Attachments kept.
    pub attachments: u64,
    /// Chunks left out on the way, whole records whose bytes are damaged (failing their CRC,
    /// or unreadable inside): the byte offset of each, and what was wrong.
    pub skipped: Vec<(u64, String)>,
    /// How the input ended.
    pub ending: Ending,
}

impl fmt::Display for Recovered {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "kept {} messages from {} chunks, {} metadata records and {} attachments; ",
            self.messages, self.chunks, self.metadata, self.attachments
        )?;
        for (offset, why) in &self.skipped {
            write!(f, "left out damaged data at byte {offset} ({why}); ")?;
        }
        match &self.ending {
            Ending::Complete => write!(f, "the input was already complete"),
            Ending::Unfinished => write!(
                f,
                "the input had no summary (its recorder did not finish) but no tail was cut"
            ),
            Ending::Cut {
                offset,
                dropped,
                why,
            } => write!(
                f,
                "the tail was cut: {dropped} bytes from byte {offset} on were left out ({why})"
            ),
        }
    }
}

/// Where `coordinator recover FILE` writes by default: `run.mcap` gives `run.recovered.mcap`.
pub fn default_output(input: &Path) -> PathBuf {
    let stem = match input.extension() {
        Some(ext) if ext.eq_ignore_ascii_case("mcap") => input.with_extension(""),
        _ => input.to_path_buf(),
    };
    let mut name = stem.file_name().unwrap_or_default().to_os_string();
    name.push(".recovered.mcap");
    stem.with_file_name(name)
}

/// Recovers `input` into `output`. The output is written beside its final place and renamed
/// there only once complete, so `output` may be `input` itself.
///
/// # Errors
/// An input that cannot be read, is empty, is not MCAP or lacks its header record; an output
/// that cannot be written.
pub fn recover_file(input: &Path, output: &Path) -> Result<Recovered> {
    let buf = std::fs::read(input).with_context(|| format!("reading {}", input.display()))?;
    let name = output
        .file_name()
        .with_context(|| format!("{} does not name a file", output.display()))?;
    let mut partial = name.to_os_string();
    partial.push(".partial");
    let partial = output.with_file_name(partial);
    let result = File::create(&partial)
        .with_context(|| format!("creating {}", partial.display()))
        .and_then(|file| {
            let mut out = BufWriter::new(file);
            let kept = recover(&buf, &mut out)
                .with_context(|| format!("recovering {}", input.display()))?;
            out.flush()
                .with_context(|| format!("writing {}", partial.display()))?;
            Ok(kept)
        })
        .and_then(|kept| {
            std::fs::rename(&partial, output).with_context(|| {
                format!("renaming {} to {}", partial.display(), output.display())
            })?;
            Ok(kept)
        });
    if result.is_err() {
        // Nothing half-written is left behind; the input is untouched.
        let _ = std::fs::remove_file(&partial);
    }
    result
}

/// Schemas and channels defined so far, to check what a record refers to before writing it.
#[derive(Clone, Default)]
struct Known {
    schemas: HashMap<u16, (String, String, Vec<u8>)>,
    channels: HashMap<u16, records::Channel>,
}

impl Known {
    /// Registers a schema or channel and checks a message's channel; the reason otherwise.
    fn admit(&mut self, record: &Record<'_>) -> Result<(), String> {
        match record {
            Record::Schema { header, data } => {
                if header.id == 0 {
                    return Err("a schema with id 0".into());
                }
                let content = (header.name.clone(), header.encoding.clone(), data.to_vec());
                match self.schemas.get(&header.id) {
                    Some(known) if *known != content => {
                        Err(format!("schema {} defined twice, differently", header.id))
                    }
                    _ => {
                        self.schemas.insert(header.id, content);
                        Ok(())
                    }
                }
            }
            Record::Channel(c) => {
                if c.schema_id != 0 && !self.schemas.contains_key(&c.schema_id) {
                    return Err(format!(
                        "channel {} ({}) names schema {}, never defined",
                        c.id, c.topic, c.schema_id
                    ));
                }
                match self.channels.get(&c.id) {
                    Some(known) if known != c => {
                        Err(format!("channel {} defined twice, differently", c.id))
                    }
                    _ => {
                        self.channels.insert(c.id, c.clone());
                        Ok(())
                    }
                }
            }
            Record::Message { header, .. } if !self.channels.contains_key(&header.channel_id) => {
                Err(format!(
                    "a message on channel {}, never defined",
                    header.channel_id
                ))
            }
            _ => Ok(()),
        }
    }
}

/// Writes an admitted schema, channel or message.
fn emit<W: Write + Seek>(writer: &mut mcap::Writer<W>, record: &Record<'_>) -> Result<()> {
    match record {
        Record::Schema { header, data } => {
            writer.add_schema_with_id(header.id, &header.name, &header.encoding, data)?;
        }
        Record::Channel(c) => {
            writer.add_channel_with_id(
                c.id,
                c.schema_id,
                &c.topic,
                &c.message_encoding,
                &c.metadata,
            )?;
        }
        Record::Message { header, data } => writer.write_to_known_channel(header, data)?,
        _ => {}
    }
    Ok(())
}

/// The records inside an uncompressed chunk, each framed by [`frame`] within the chunk's bytes.
///
/// The mcap crate's chunk reader trusts inner record lengths (0.26 panics on an overflow when a
/// record claims more bytes than its chunk holds), so chunks are taken apart here. Our recorder
/// writes uncompressed chunks; the crate is built without its decompressors.
fn chunk_records<'a>(
    header: &records::ChunkHeader,
    data: &'a [u8],
) -> Result<Vec<Record<'a>>, String> {
    if !header.compression.is_empty() {
        return Err(format!(
            "a chunk compressed with {:?}, which this build does not read",
            header.compression
        ));
    }
    if data.len() as u64 != header.uncompressed_size {
        return Err(format!(
            "a chunk of {} bytes that says it holds {}",
            data.len(),
            header.uncompressed_size
        ));
    }
    // 0 means the writer computed none; any other value must match, or a flipped bit inside a
    // message would replay as if it had been recorded.
    let crc = crc32fast::hash(data);
    if header.uncompressed_crc != 0 && crc != header.uncompressed_crc {
        return Err(format!(
            "its data fails its CRC (0x{crc:08x}, recorded 0x{:08x})",
            header.uncompressed_crc
        ));
    }
    let mut out = Vec::new();
    let mut pos = 0;
    while pos < data.len() {
        let (op, body) = frame(data, pos)?;
        let record = mcap::parse_record(op, body)
            .map_err(|e| format!("an unreadable {} record: {e}", op_name(op)))?;
        out.push(record);
        pos += 9 + body.len();
    }
    Ok(out)
}

/// The next record's opcode and body at `pos`, or why there is none.
fn frame(buf: &[u8], pos: usize) -> Result<(u8, &[u8]), String> {
    let rest = &buf[pos..];
    let Some(len) = rest.get(1..9) else {
        return Err(format!(
            "a record header cut short ({} of 9 bytes)",
            rest.len()
        ));
    };
    let len = u64::from_le_bytes(len.try_into().unwrap_or_default());
    match usize::try_from(len)
        .ok()
        .and_then(|l| rest.get(9..).and_then(|body| body.get(..l)))
    {
        Some(body) => Ok((rest[0], body)),
        // What the mcap crate writes before it knows a streamed chunk's length.
        None if len == u64::MAX => Err(format!(
            "a {} record whose length was never filled in",
            op_name(rest[0])
        )),
        None => Err(format!(
            "a {} record of {len} bytes with {} bytes left in the file",
            op_name(rest[0]),
            rest.len() - 9
        )),
    }
}

fn op_name(op: u8) -> String {
    match op {
        op::HEADER => "header".into(),
        op::FOOTER => "footer".into(),
        op::SCHEMA => "schema".into(),
        op::CHANNEL => "channel".into(),
        op::MESSAGE => "message".into(),
        op::CHUNK => "chunk".into(),
        op::MESSAGE_INDEX => "message index".into(),
        op::CHUNK_INDEX => "chunk index".into(),
        op::ATTACHMENT => "attachment".into(),
        op::ATTACHMENT_INDEX => "attachment index".into(),
        op::STATISTICS => "statistics".into(),
        op::METADATA => "metadata".into(),
        op::METADATA_INDEX => "metadata index".into(),
        op::SUMMARY_OFFSET => "summary offset".into(),
        op::DATA_END => "data end".into(),
        other => format!("0x{other:02x}"),
    }
}

/// Whether `buf` ends with a footer that points to a summary.
fn has_summary(buf: &[u8]) -> bool {
    let Some(start) = buf.len().checked_sub(8 + 29) else {
        return false;
    };
    if &buf[buf.len() - 8..] != mcap::MAGIC {
        return false;
    }
    match frame(buf, start).map(|(op, body)| mcap::parse_record(op, body)) {
        Ok(Ok(Record::Footer(footer))) => footer.summary_start != 0,
        _ => false,
    }
}

/// Recovers the MCAP file in `buf` into `out`.
///
/// # Errors
/// An empty input, one without the MCAP magic or header record, or a write error.
pub fn recover<W: Write + Seek>(buf: &[u8], out: W) -> Result<Recovered> {
    let (header, mut pos) = read_header(buf)?;
    let mut writer = mcap::WriteOptions::new()
        .profile(header.profile)
        .library(header.library)
        .create(out)?;
    let mut known = Known::default();
    let mut kept = Recovered {
        messages: 0,
        chunks: 0,
        metadata: 0,
        attachments: 0,
        skipped: Vec::new(),
        ending: Ending::Unfinished,
    };
    let cut = |pos: usize, why: String| Ending::Cut {
        offset: pos as u64,
        dropped: (buf.len() - pos) as u64,
        why,
    };
    let mut resync_from = pos;
    loop {
        if pos == buf.len() {
            kept.ending = cut(pos, "the file ends without a data end record".into());
            break;
        }
        let parsed = frame(buf, pos).and_then(|(opcode, body)| {
            mcap::parse_record(opcode, body)
                .map(|r| (r, body.len()))
                .map_err(|e| format!("an unreadable {} record: {e}", op_name(opcode)))
        });
        let (record, len) = match parsed {
            Ok(r) => r,
            Err(why) => {
                // A damaged length or header: the records after it may still be whole. Reading
                // goes on at the next whole chunk that passes its CRC, if there is one, looked
                // for from inside the record before: a length that grew still let that record
                // read whole, and sent the reader past the chunks it swallowed.
                match next_chunk(buf, resync_from) {
                    Some(next) => {
                        kept.skipped.push((pos as u64, why));
                        pos = next;
                        continue;
                    }
                    None => {
                        kept.ending = cut(pos, why);
                        break;
                    }
                }
            }
        };
        match take(&mut writer, &mut known, &mut kept, record)? {
            Taken::Next => {}
            // A damaged chunk's length may be what is damaged: if no whole record starts where
            // it says, the resynchronisation above looks from inside it.
            Taken::Skip(why) => kept.skipped.push((pos as u64, why)),
            Taken::Cut(why) => {
                kept.ending = cut(pos, why);
                break;
            }
            Taken::End => {
                kept.ending = if has_summary(buf) {
                    Ending::Complete
                } else {
                    Ending::Unfinished
                };
                break;
            }
        }
        resync_from = pos + 9;
        pos += 9 + len;
    }
    writer.finish()?;
    Ok(kept)
}

/// The offset of the first whole chunk at or after `from` whose data passes its CRC.
fn next_chunk(buf: &[u8], from: usize) -> Option<usize> {
    (from..buf.len().saturating_sub(9))
        .filter(|&p| buf[p] == op::CHUNK)
        .find(|&p| {
            let Ok((op, body)) = frame(buf, p) else {
                return false;
            };
            match mcap::parse_record(op, body) {
                Ok(Record::Chunk { header, data }) => {
                    header.uncompressed_crc != 0
                        && data.len() as u64 == header.uncompressed_size
                        && crc32fast::hash(&data) == header.uncompressed_crc
                }
                _ => false,
            }
        })
}

/// The file's header record and where the records after it start.
fn read_header(buf: &[u8]) -> Result<(records::Header, usize)> {
    if buf.is_empty() {
        bail!("the file is empty");
    }
    if !buf.starts_with(mcap::MAGIC) {
        bail!("not an MCAP file: it does not start with the MCAP magic bytes");
    }
    let pos = mcap::MAGIC.len();
    let header = match frame(buf, pos).map(|(op, body)| (op, mcap::parse_record(op, body))) {
        Ok((_, Ok(Record::Header(h)))) => h,
        Ok((op, _)) => bail!(
            "the MCAP magic is followed by a {} record, not a readable header",
            op_name(op)
        ),
        Err(why) => bail!("the file ends inside its MCAP header: {why}"),
    };
    Ok((
        header,
        pos + 9 + frame(buf, pos).map_or(0, |(_, body)| body.len()),
    ))
}

/// What one record did to the recovery.
enum Taken {
    /// Kept or passed over: on to the next record.
    Next,
    /// A chunk left out for damage inside it, for this reason: on to the next record.
    Skip(String),
    /// Refused: the file is cut before it, for this reason.
    Cut(String),
    /// The data end or the footer: the data is all there.
    End,
}

/// Writes one record the input holds, or says why the file must be cut before it.
fn take<W: Write + Seek>(
    writer: &mut mcap::Writer<W>,
    known: &mut Known,
    kept: &mut Recovered,
    record: Record<'_>,
) -> Result<Taken> {
    match record {
        Record::Chunk { header, data } => {
            let inner = match admit_chunk(known, &header, &data, kept.chunks) {
                Ok(inner) => inner,
                Err(why) => return Ok(Taken::Skip(why)),
            };
            for r in &inner {
                emit(writer, r)?;
                if matches!(r, Record::Message { .. }) {
                    kept.messages += 1;
                }
            }
            // Close the output's chunk where the input's closed.
            writer.flush()?;
            kept.chunks += 1;
        }
        r @ (Record::Schema { .. } | Record::Channel(_) | Record::Message { .. }) => {
            if let Err(why) = known.admit(&r) {
                return Ok(Taken::Cut(why));
            }
            emit(writer, &r)?;
            if matches!(r, Record::Message { .. }) {
                kept.messages += 1;
            }
        }
        Record::Metadata(m) => {
            writer.write_metadata(&m)?;
            kept.metadata += 1;
        }
        Record::Attachment { header, data, .. } => {
            writer.attach(&mcap::Attachment {
                log_time: header.log_time,
                create_time: header.create_time,
                name: header.name,
                media_type: header.media_type,
                data,
            })?;
            kept.attachments += 1;
        }
        Record::DataEnd(_) | Record::Footer(_) => return Ok(Taken::End),
        // Indexes and statistics are written afresh; a second header adds nothing.
        _ => {}
    }
    Ok(Taken::Next)
}

/// A chunk's records, all of them or none: every record is checked against what is `known`
/// before any is written, and `known` learns the chunk's schemas and channels only when all
/// pass. `done` chunks came before it.
fn admit_chunk<'a>(
    known: &mut Known,
    header: &records::ChunkHeader,
    data: &'a [u8],
    done: u64,
) -> Result<Vec<Record<'a>>, String> {
    let mut trial = known.clone();
    let inner = chunk_records(header, data)
        .and_then(|records| {
            records
                .into_iter()
                .map(|r| match r {
                    Record::Schema { .. } | Record::Channel(_) | Record::Message { .. } => {
                        trial.admit(&r)?;
                        Ok(r)
                    }
                    other => Err(format!(
                        "a {} record inside a chunk",
                        op_name(other.opcode())
                    )),
                })
                .collect::<Result<Vec<_>, String>>()
        })
        .map_err(|why| format!("chunk {}: {why}", done + 1))?;
    *known = trial;
    Ok(inner)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;
    use std::io::Cursor;

    /// A small complete recording: metadata, two schemas' channels, messages over three chunks.
    fn sample() -> Vec<u8> {
        let mut w = mcap::WriteOptions::new()
            .library("test")
            .chunk_size(None)
            .create(Cursor::new(Vec::new()))
            .unwrap();
        w.write_metadata(&records::Metadata {
            name: "run".into(),
            metadata: BTreeMap::from([("k".to_string(), "v".to_string())]),
        })
        .unwrap();
        let s = w.add_schema("S", "jsonschema", b"{}").unwrap();
        let a = w.add_channel(s, "/a", "json", &BTreeMap::new()).unwrap();
        let b = w.add_channel(s, "/b", "json", &BTreeMap::new()).unwrap();
        for i in 0..30u32 {
            let header = records::MessageHeader {
                channel_id: if i % 3 == 0 { b } else { a },
                sequence: i,
                log_time: 1000 + u64::from(i),
                publish_time: 1000 + u64::from(i),
            };
            w.write_to_known_channel(&header, format!("{{\"i\":{i}}}").as_bytes())
                .unwrap();
            if i % 10 == 9 {
                w.flush().unwrap();
            }
        }
        w.finish().unwrap();
        w.into_inner().into_inner()
    }

    fn messages(buf: &[u8]) -> Vec<(String, u32, u64, Vec<u8>)> {
        mcap::MessageStream::new(buf)
            .unwrap()
            .map(|m| {
                let m = m.unwrap();
                (
                    m.channel.topic.clone(),
                    m.sequence,
                    m.log_time,
                    m.data.to_vec(),
                )
            })
            .collect()
    }

    #[test]
    fn a_complete_file_recovers_to_the_same_messages_chunks_and_metadata() {
        let input = sample();
        let mut out = Cursor::new(Vec::new());
        let kept = recover(&input, &mut out).unwrap();
        assert_eq!(kept.ending, Ending::Complete);
        assert_eq!((kept.messages, kept.chunks, kept.metadata), (30, 3, 1));
        let out = out.into_inner();
        assert_eq!(messages(&out), messages(&input));
        let before = mcap::Summary::read(&input).unwrap().unwrap();
        let after = mcap::Summary::read(&out).unwrap().unwrap();
        assert_eq!(after.chunk_indexes.len(), before.chunk_indexes.len());
        assert_eq!(after.stats, before.stats);
    }

    #[test]
    fn every_cut_of_a_file_recovers_its_whole_chunks_or_is_a_clear_error() {
        let input = sample();
        // The data end record is whole from here on.
        let data_end = mcap::read::footer(&input).unwrap().summary_start as usize;
        let mut kept_before = 0;
        for len in 0..input.len() {
            let cut = &input[..len];
            let mut out = Cursor::new(Vec::new());
            match recover(cut, &mut out) {
                Ok(kept) => {
                    let out = out.into_inner();
                    let read = messages(&out);
                    assert_eq!(read.len() as u64, kept.messages, "cut at {len}");
                    assert_eq!(kept.messages % 10, 0, "a chunk kept in part, cut at {len}");
                    assert!(kept.messages >= kept_before, "cut at {len}");
                    kept_before = kept.messages;
                    assert!(mcap::Summary::read(&out).unwrap().is_some());
                    if len < data_end {
                        assert!(matches!(kept.ending, Ending::Cut { .. }), "cut at {len}");
                    } else {
                        assert_eq!(kept.ending, Ending::Unfinished, "cut at {len}");
                    }
                }
                Err(e) => {
                    assert!(len < 40, "cut at {len}: {e:#}");
                    assert!(!format!("{e:#}").is_empty());
                }
            }
        }
        assert_eq!(kept_before, 30);
    }

    #[test]
    fn empty_and_foreign_files_are_clear_errors() {
        let e = recover(b"", Cursor::new(Vec::new())).unwrap_err();
        assert!(e.to_string().contains("empty"), "{e}");
        let e = recover(b"PK\x03\x04 a zip file", Cursor::new(Vec::new())).unwrap_err();
        assert!(e.to_string().contains("not an MCAP file"), "{e}");
        let e = recover(b"\x89MCAP0\r\n\x01", Cursor::new(Vec::new())).unwrap_err();
        assert!(e.to_string().contains("header"), "{e}");
    }

    #[test]
    fn absurd_record_lengths_end_what_is_kept() {
        let mut input = sample();
        let data_end = mcap::read::footer(&input).unwrap().summary_start as usize - 13;
        for len in [u64::MAX, u64::MAX - 3, 1 << 62] {
            input.truncate(data_end);
            input.push(op::MESSAGE);
            input.extend_from_slice(&len.to_le_bytes());
            input.extend_from_slice(b"rest");
            let kept = recover(&input, Cursor::new(Vec::new())).unwrap();
            assert_eq!(kept.messages, 30);
            match kept.ending {
                Ending::Cut { offset, .. } => assert_eq!(offset, data_end as u64),
                other => panic!("{other:?}"),
            }
        }
    }

    #[test]
    fn a_message_on_an_unknown_channel_ends_what_is_kept() {
        let mut w = mcap::WriteOptions::new()
            .use_chunks(false)
            .create(Cursor::new(Vec::new()))
            .unwrap();
        let s = w.add_schema("S", "jsonschema", b"{}").unwrap();
        let c = w.add_channel(s, "/a", "json", &BTreeMap::new()).unwrap();
        let header = records::MessageHeader {
            channel_id: c,
            sequence: 1,
            log_time: 5,
            publish_time: 5,
        };
        w.write_to_known_channel(&header, b"{}").unwrap();
        w.finish().unwrap();
        let mut input = w.into_inner().into_inner();
        // Point the one message at channel 7.
        let at = input
            .windows(2)
            .position(|p| p == [op::MESSAGE, 2 + 4 + 8 + 8 + 2])
            .unwrap();
        input[at + 9] = 7;
        let kept = recover(&input, Cursor::new(Vec::new())).unwrap();
        assert_eq!(kept.messages, 0);
        match kept.ending {
            Ending::Cut { why, .. } => assert!(why.contains("channel 7"), "{why}"),
            other => panic!("{other:?}"),
        }
    }

    /// Each chunk's offset and length in `buf`, walking its top-level records.
    fn chunks(buf: &[u8]) -> Vec<(usize, usize)> {
        let mut pos = mcap::MAGIC.len();
        let mut out = Vec::new();
        while let Ok((op, body)) = frame(buf, pos) {
            if op == op::CHUNK {
                out.push((pos, body.len()));
            }
            if op == op::DATA_END {
                break;
            }
            pos += 9 + body.len();
        }
        out
    }

    /// One flipped bit inside a chunk's messages fails its CRC: that chunk is left out and
    /// named, every other one kept (19 such flips once replayed as exact). The first chunk
    /// defines the channels, and chunks after it cannot be read without it: a flip there
    /// keeps none. A first chunk whose length field grew still reads whole, and the chunks it
    /// seemed to swallow are found again (0 of 18 chunks were kept).
    #[test]
    fn a_damaged_chunk_is_left_out_and_named_and_every_intact_one_kept() {
        let input = sample();
        let found = chunks(&input);
        assert_eq!(found.len(), 3);
        for (k, &(at, len)) in found.iter().enumerate() {
            let mut flipped = input.clone();
            flipped[at + 9 + len - 20] ^= 0x04;
            let kept = recover(&flipped, Cursor::new(Vec::new())).unwrap();
            let skipped: Vec<u64> = kept.skipped.iter().map(|s| s.0).collect();
            let (chunks, lost) = if k == 0 {
                (0, found.iter().map(|c| c.0 as u64).collect())
            } else {
                (2, vec![at as u64])
            };
            assert_eq!(
                (kept.chunks, kept.messages),
                (chunks, chunks * 10),
                "chunk {k}"
            );
            assert_eq!(skipped, lost, "chunk {k}");
            assert!(kept.skipped[0].1.contains("CRC"), "{:?}", kept.skipped);
            assert_eq!(kept.ending, Ending::Complete);
        }
        let (at, len) = found[0];
        let mut grown = input.clone();
        grown[at + 1..at + 9].copy_from_slice(&(len as u64 + 500).to_le_bytes());
        let mut out = Cursor::new(Vec::new());
        let kept = recover(&grown, &mut out).unwrap();
        assert_eq!((kept.chunks, kept.messages), (3, 30), "{kept}");
        assert_eq!(messages(&out.into_inner()), messages(&input));
        assert!(!kept.skipped.is_empty());
    }

    #[test]
    fn default_output_sits_beside_the_input() {
        assert_eq!(
            default_output(Path::new("/tmp/run.mcap")),
            Path::new("/tmp/run.recovered.mcap")
        );
        assert_eq!(
            default_output(Path::new("run")),
            Path::new("run.recovered.mcap")
        );
    }
}
