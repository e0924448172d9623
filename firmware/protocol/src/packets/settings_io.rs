//! Settings over the link: field writes, read requests and the bytes read back, saving, factory
//! defaults, and the robot's word that they were saved.

use super::SETTINGS_CHUNK;
use crate::wire_struct;

wire_struct! {
    /// Overwrite `len` bytes of the settings at `offset` (thesis fig. 9.3); variable length.
    pub struct SettingsUpdate {
        /// Byte offset into [`Settings`](crate::settings::Settings).
        pub offset: u16,
        /// Number of bytes used in `data`.
        pub len: u8,
        /// New bytes; only the first `len` travel on the wire.
        pub data: [u8; SETTINGS_CHUNK],
    }
}

wire_struct! {
    /// Ask for `len` bytes of the settings at `offset`, answered by [`SettingsData`].
    pub struct SettingsRead {
        /// Byte offset into [`Settings`](crate::settings::Settings).
        pub offset: u16,
        /// Number of bytes, at most [`SETTINGS_CHUNK`].
        pub len: u8,
    }
}

wire_struct! {
    /// Settings bytes read back from the robot; variable length.
    pub struct SettingsData {
        /// Byte offset into [`Settings`](crate::settings::Settings).
        pub offset: u16,
        /// Number of bytes used in `data`.
        pub len: u8,
        /// The bytes; only the first `len` travel on the wire.
        pub data: [u8; SETTINGS_CHUNK],
    }
}

wire_struct! {
    /// Store the current settings in non-volatile memory.
    pub struct SettingsSave {}
}

wire_struct! {
    /// Replace the settings by the factory image (not saved until [`SettingsSave`]).
    pub struct SettingsRestoreDefaults {}
}

wire_struct! {
    /// Settings were written to non-volatile memory.
    pub struct SettingsSaved {
        /// Bytes written.
        pub size: u16,
    }
}

impl SettingsUpdate {
    /// An update of `data` at `offset`; `None` if `data` is longer than a chunk.
    pub fn new(offset: u16, data: &[u8]) -> Option<Self> {
        chunk(data).map(|(len, buf)| Self {
            offset,
            len,
            data: buf,
        })
    }
    /// The used bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.data[..(self.len as usize).min(SETTINGS_CHUNK)]
    }

    /// Checks that `len` matches the data a frame of `payload_len` bytes actually carried; a
    /// shorter frame would otherwise write its zero-filled tail.
    pub fn check_carried(&self, payload_len: usize) -> Result<(), crate::SettingsError> {
        let len = usize::from(self.len);
        if len > SETTINGS_CHUNK || payload_len != 3 + len {
            return Err(crate::SettingsError::LengthMismatch);
        }
        Ok(())
    }
}

impl SettingsData {
    /// A read-back of `data` at `offset`; `None` if `data` is longer than a chunk.
    pub fn new(offset: u16, data: &[u8]) -> Option<Self> {
        chunk(data).map(|(len, buf)| Self {
            offset,
            len,
            data: buf,
        })
    }
    /// The used bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.data[..(self.len as usize).min(SETTINGS_CHUNK)]
    }
}

fn chunk(data: &[u8]) -> Option<(u8, [u8; SETTINGS_CHUNK])> {
    if data.len() > SETTINGS_CHUNK {
        return None;
    }
    let mut buf = [0u8; SETTINGS_CHUNK];
    buf[..data.len()].copy_from_slice(data);
    Some((data.len() as u8, buf))
}
