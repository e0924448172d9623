//! Typed access to single settings fields (thesis 6.3, 9.6): a [`Field`] knows its offset and type
//! from the struct layout, so writing one becomes one update packet carrying exactly its bytes.
//!
//! ```
//! use robot_actor::setting;
//! let kp = setting!(line_pid.kp);
//! let (offset, len) = protocol::Settings::field("line_pid.kp").unwrap();
//! assert_eq!((kp.offset(), kp.len()), (offset, len));
//! assert_eq!(kp.get(&protocol::Settings::default()), 40.0);
//! ```

use std::marker::PhantomData;

use protocol::packets::SETTINGS_CHUNK;
use protocol::Settings;

/// One field of [`Settings`] of type `T`.
#[derive(Clone, Copy, Debug)]
pub struct Field<T> {
    offset: usize,
    get: fn(&Settings) -> T,
    _t: PhantomData<T>,
}

impl<T: bytemuck::Pod> Field<T> {
    /// A field at `offset` read by `get`; use [`setting!`](crate::setting) rather than this.
    pub const fn new(offset: usize, get: fn(&Settings) -> T) -> Self {
        Self {
            offset,
            get,
            _t: PhantomData,
        }
    }

    /// Byte offset in the settings structure.
    pub fn offset(&self) -> usize {
        self.offset
    }

    /// Size in bytes.
    pub fn len(&self) -> usize {
        std::mem::size_of::<T>()
    }

    /// Whether the field has no bytes (never, for a real field).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Its value in `settings`.
    pub fn get(&self, settings: &Settings) -> T {
        (self.get)(settings)
    }

    /// The wire bytes of `value`.
    pub fn bytes(&self, value: T) -> Vec<u8> {
        bytemuck::bytes_of(&value).to_vec()
    }
}

/// A typed [`Field`] for a dotted path into [`Settings`], checked by the compiler:
/// `setting!(line_pid.kp)` is a `Field<f32>`.
#[macro_export]
macro_rules! setting {
    ($($path:ident).+) => {
        $crate::settings::Field::new(
            ::core::mem::offset_of!(::protocol::Settings, $($path).+),
            |s: &::protocol::Settings| s.$($path).+,
        )
    };
}

/// Splits the whole settings structure into read-back chunks that never split a value.
pub fn read_chunks() -> Vec<(usize, usize)> {
    use protocol::Layout;
    let mut leaves = Vec::new();
    Settings::LAYOUT.for_each_leaf(&mut |_, offset, ty| leaves.push((offset, ty.size)));
    let mut chunks: Vec<(usize, usize)> = Vec::new();
    for (offset, size) in leaves {
        match chunks.last_mut() {
            Some((start, len)) if *start + *len == offset && *len + size <= SETTINGS_CHUNK => {
                *len += size;
            }
            _ => chunks.push((offset, size)),
        }
    }
    chunks
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunks_cover_everything_on_field_boundaries() {
        let chunks = read_chunks();
        let mut next = 0;
        for &(off, len) in &chunks {
            assert_eq!(off, next);
            assert!(len <= SETTINGS_CHUNK);
            Settings::check_range(off, len).unwrap();
            next = off + len;
        }
        assert_eq!(next, Settings::SIZE);
        assert!(
            chunks.len() <= Settings::SIZE / 16,
            "{} chunks",
            chunks.len()
        );
    }

    #[test]
    fn typed_fields_match_the_layout_table() {
        let f = setting!(proximity.report_period_ms);
        assert_eq!(
            Some((f.offset(), f.len())),
            Settings::field("proximity.report_period_ms")
        );
        let id = setting!(identity.robot_id);
        assert_eq!(id.bytes(7), vec![7, 0]);
    }
}
