//! The file under the MCAP writer, which reaches the disk only in whole records followed by a
//! provisional end, so a killed process leaves a readable file.

use std::fs::File;
use std::io::{self, Cursor, Seek, SeekFrom, Write};

/// The bytes that end a recording between two writes: a data end record (no CRC), a footer
/// that says there is no summary, and the closing magic. Readers take the file as complete.
const PROVISIONAL_END: [u8; 50] = {
    let mut end = [0u8; 50];
    end[0] = mcap::records::op::DATA_END;
    end[1] = 4; // record length, u64 little-endian; the CRC after it stays 0
    end[13] = mcap::records::op::FOOTER;
    end[14] = 20; // summary start, summary offset start (both 0: none), summary CRC
    let mut i = 0;
    while i < mcap::MAGIC.len() {
        end[42 + i] = mcap::MAGIC[i];
        i += 1;
    }
    end
};

/// The file under the MCAP writer: everything written stays in memory until the writer flushes
/// (it does so only between records: after closing a chunk, and at its finish), then goes to the
/// file in one write followed by [`PROVISIONAL_END`], which the next flush overwrites. A process
/// killed at any moment leaves whole records and a valid end.
pub(super) struct WholeRecords {
    file: File,
    /// Bytes of the recording already in the file (the provisional end follows them).
    written: u64,
    pending: Cursor<Vec<u8>>,
}

impl WholeRecords {
    /// Starts an empty recording in `file`.
    pub(super) fn new(file: File) -> Self {
        Self {
            file,
            written: 0,
            pending: Cursor::new(Vec::new()),
        }
    }

    fn commit(&mut self, provisional: bool) -> io::Result<()> {
        let len = self.pending.get_ref().len();
        if self.pending.position() != len as u64 {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "the MCAP writer flushed while rewriting an earlier record",
            ));
        }
        let mut bytes = std::mem::take(self.pending.get_mut());
        if provisional {
            bytes.extend_from_slice(&PROVISIONAL_END);
        }
        self.file.seek(SeekFrom::Start(self.written))?;
        self.file.write_all(&bytes)?;
        self.written += len as u64;
        bytes.clear();
        self.pending = Cursor::new(bytes);
        Ok(())
    }

    /// Writes what is left without a provisional end and cuts the file there; returns its length.
    pub(super) fn finish(mut self) -> io::Result<u64> {
        self.commit(false)?;
        self.file.set_len(self.written)?;
        self.file.flush()?;
        Ok(self.written)
    }
}

impl Write for WholeRecords {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.pending.write(buf)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.commit(true)
    }
}

impl Seek for WholeRecords {
    fn seek(&mut self, pos: SeekFrom) -> io::Result<u64> {
        let here = self.written + self.pending.position();
        let end = self.written + self.pending.get_ref().len() as u64;
        let target = match pos {
            SeekFrom::Start(p) => Some(p),
            SeekFrom::End(d) => end.checked_add_signed(d),
            SeekFrom::Current(d) => here.checked_add_signed(d),
        };
        match target {
            Some(t) if t >= self.written => {
                self.pending.set_position(t - self.written);
                Ok(t)
            }
            _ => Err(io::Error::new(
                io::ErrorKind::Unsupported,
                "the MCAP writer sought back into bytes already in the file",
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;

    #[test]
    fn the_file_on_disk_is_a_complete_mcap_between_any_two_writes() {
        let dir = std::env::temp_dir().join(format!("pocketfleet-whole-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("whole.mcap");
        let mut w = mcap::WriteOptions::new()
            .chunk_size(None)
            .create(WholeRecords::new(File::create(&path).unwrap()))
            .unwrap();
        let s = w.add_schema("S", "jsonschema", b"{}").unwrap();
        let c = w.add_channel(s, "/a", "json", &BTreeMap::new()).unwrap();
        let on_disk = || {
            let bytes = std::fs::read(&path).unwrap();
            let n = mcap::MessageStream::new(&bytes)
                .expect("a complete file")
                .collect::<Result<Vec<_>, _>>()
                .expect("every message reads")
                .len();
            (n, mcap::Summary::read(&bytes).unwrap().is_some())
        };
        w.flush().unwrap();
        assert_eq!(on_disk(), (0, false));
        for i in 0..20u32 {
            let header = mcap::records::MessageHeader {
                channel_id: c,
                sequence: i,
                log_time: u64::from(i),
                publish_time: u64::from(i),
            };
            w.write_to_known_channel(&header, b"{}").unwrap();
            // Until the chunk closes, nothing of it is in the file.
            assert_eq!(on_disk().0, (i / 5 * 5) as usize);
            if i % 5 == 4 {
                w.flush().unwrap();
                assert_eq!(on_disk(), (i as usize + 1, false));
            }
        }
        w.finish().unwrap();
        let len = w.into_inner().finish().unwrap();
        assert_eq!(len, std::fs::metadata(&path).unwrap().len());
        assert_eq!(on_disk(), (20, true));
    }
}
