//! Compile-time descriptions of wire structs: field names, offsets and sizes, and a layout hash.
//!
//! Every wire struct is declared through [`wire_struct!`](crate::wire_struct), which derives its [`TypeInfo`] from the
//! compiler's own layout (`core::mem::offset_of!`, `size_of`). Nothing here is typed in by hand, so
//! the settings-layout hash in the hello packet changes whenever a field is added, removed,
//! renamed, retyped or moved.

/// Layout of one wire type: a primitive, an array, or a struct with named fields.
#[derive(Debug)]
pub struct TypeInfo {
    /// Type name as written in the source (`"f32"`, `"PidSettings"`, `"array"`).
    pub name: &'static str,
    /// Size in bytes on the wire.
    pub size: usize,
    /// Hash of the whole layout, children included (FNV-1a, 64 bit).
    pub hash: u64,
    /// Named fields of a struct; empty for primitives and arrays.
    pub fields: &'static [FieldInfo],
    /// Element type and count of an array; `None` otherwise.
    pub array: Option<(&'static TypeInfo, usize)>,
    /// The type's doc comment, lines joined; empty for primitives and arrays.
    pub doc: &'static str,
}

/// One named field of a wire struct.
#[derive(Debug)]
pub struct FieldInfo {
    /// Field name.
    pub name: &'static str,
    /// Byte offset inside the enclosing struct.
    pub offset: usize,
    /// Layout of the field's type.
    pub ty: &'static TypeInfo,
    /// The field's doc comment, lines joined.
    pub doc: &'static str,
}

/// A type whose wire layout is known at compile time.
pub trait Layout {
    /// The layout description.
    const LAYOUT: TypeInfo;
}

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;

const fn fnv_bytes(mut h: u64, bytes: &[u8]) -> u64 {
    let mut i = 0;
    while i < bytes.len() {
        h ^= bytes[i] as u64;
        h = h.wrapping_mul(FNV_PRIME);
        i += 1;
    }
    h
}

const fn fnv_u64(h: u64, v: u64) -> u64 {
    fnv_bytes(h, &v.to_le_bytes())
}

/// Hash of a primitive type from its name and size.
pub const fn primitive_hash(name: &str, size: usize) -> u64 {
    fnv_u64(fnv_bytes(FNV_OFFSET, name.as_bytes()), size as u64)
}

/// Hash of an array from its element hash and length.
pub const fn array_hash(elem: u64, len: usize) -> u64 {
    fnv_u64(fnv_u64(fnv_bytes(FNV_OFFSET, b"[]"), elem), len as u64)
}

/// Hash of a struct from its name, size and fields (names, offsets, field type hashes).
pub const fn struct_hash(name: &str, size: usize, fields: &[FieldInfo]) -> u64 {
    let mut h = fnv_u64(fnv_bytes(FNV_OFFSET, name.as_bytes()), size as u64);
    let mut i = 0;
    while i < fields.len() {
        h = fnv_bytes(h, fields[i].name.as_bytes());
        h = fnv_u64(h, fields[i].offset as u64);
        h = fnv_u64(h, fields[i].ty.hash);
        i += 1;
    }
    h
}

macro_rules! primitive_layout {
    ($($t:ty),*) => {$(
        impl Layout for $t {
            const LAYOUT: TypeInfo = TypeInfo {
                name: stringify!($t),
                size: core::mem::size_of::<$t>(),
                hash: primitive_hash(stringify!($t), core::mem::size_of::<$t>()),
                fields: &[],
                array: None,
                doc: "",
            };
        }
    )*};
}
primitive_layout!(u8, i8, u16, i16, u32, i32, u64, i64, f32);

impl<T: Layout, const N: usize> Layout for [T; N] {
    const LAYOUT: TypeInfo = TypeInfo {
        name: "array",
        size: core::mem::size_of::<T>() * N,
        hash: array_hash(T::LAYOUT.hash, N),
        fields: &[],
        array: Some((&T::LAYOUT, N)),
        doc: "",
    };
}

impl TypeInfo {
    /// Looks up a field by dotted path (`"line_pid.kp"`, `"line.white[3]"`), giving (offset, size).
    pub fn field(&self, path: &str) -> Option<(usize, usize)> {
        self.field_type(path).map(|(offset, ty)| (offset, ty.size))
    }

    /// Looks up a field by dotted path, giving its offset and layout.
    pub fn field_type(&self, path: &str) -> Option<(usize, &TypeInfo)> {
        let mut ty = self;
        let mut offset = 0usize;
        for part in path.split('.') {
            let (name, index) = match part.split_once('[') {
                Some((name, rest)) => (name, Some(rest.strip_suffix(']')?.parse::<usize>().ok()?)),
                None => (part, None),
            };
            let f = ty.fields.iter().find(|f| f.name == name)?;
            offset += f.offset;
            ty = f.ty;
            if let Some(i) = index {
                let (elem, len) = ty.array?;
                if i >= len {
                    return None;
                }
                offset += i * elem.size;
                ty = elem;
            }
        }
        Some((offset, ty))
    }

    /// Whether `offset` is where some leaf value (a primitive, possibly inside an array) begins,
    /// or the very end of the type.
    pub fn is_leaf_boundary(&self, offset: usize) -> bool {
        if offset == self.size {
            return true;
        }
        if offset > self.size {
            return false;
        }
        if let Some((elem, _)) = self.array {
            return elem.is_leaf_boundary(offset % elem.size);
        }
        match self
            .fields
            .iter()
            .find(|f| offset >= f.offset && offset < f.offset + f.ty.size)
        {
            Some(f) => f.ty.is_leaf_boundary(offset - f.offset),
            None => offset == 0,
        }
    }

    /// The dotted path of the leaf value that contains `offset` (`"proximity.range_mm[2]"`).
    pub fn path_of(&self, offset: usize) -> Option<FieldPath> {
        let mut path = FieldPath {
            parts: [("", None); MAX_DEPTH],
            depth: 0,
        };
        let mut ty = self;
        let mut rest = offset;
        if rest >= ty.size {
            return None;
        }
        while !ty.fields.is_empty() {
            let f = ty
                .fields
                .iter()
                .find(|f| rest >= f.offset && rest < f.offset + f.ty.size)?;
            rest -= f.offset;
            ty = f.ty;
            let mut index = None;
            if let Some((elem, _)) = ty.array {
                index = Some(rest / elem.size);
                rest %= elem.size;
                ty = elem;
            }
            *path.parts.get_mut(path.depth)? = (f.name, index);
            path.depth += 1;
        }
        Some(path)
    }

    /// Calls `visit` with the dotted path, offset and type of every leaf value, in offset order.
    pub fn for_each_leaf(&self, visit: &mut dyn FnMut(&[&str], usize, &TypeInfo)) {
        let mut path: [&str; 8] = [""; 8];
        self.walk(&mut path, 0, 0, visit);
    }

    fn walk<'a>(
        &'a self,
        path: &mut [&'a str; 8],
        depth: usize,
        base: usize,
        visit: &mut dyn FnMut(&[&str], usize, &TypeInfo),
    ) {
        if self.fields.is_empty() {
            visit(&path[..depth], base, self);
            return;
        }
        for f in self.fields {
            if depth < path.len() {
                path[depth] = f.name;
            }
            f.ty.walk(path, (depth + 1).min(path.len()), base + f.offset, visit);
        }
    }
}

const MAX_DEPTH: usize = 8;

/// A dotted field path such as `line_sensor.white[3]`, printed by its `Display`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FieldPath {
    parts: [(&'static str, Option<usize>); MAX_DEPTH],
    depth: usize,
}

impl core::fmt::Display for FieldPath {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        for (i, (name, index)) in self.parts[..self.depth].iter().enumerate() {
            if i > 0 {
                f.write_str(".")?;
            }
            f.write_str(name)?;
            if let Some(k) = index {
                write!(f, "[{k}]")?;
            }
        }
        Ok(())
    }
}

/// Declares a `#[repr(C, packed)]` plain-old-data wire struct and derives its [`Layout`].
///
/// Packed sub-structs have alignment 1, so references to them are sound; scalar fields are read
/// and written by value only. Doc comments are the only attributes accepted; they are kept in the
/// layout so the protocol document's tables are generated from the same source.
#[macro_export]
macro_rules! wire_struct {
    (
        $(#[doc = $doc:literal])*
        pub struct $name:ident {
            $( $(#[doc = $fdoc:literal])* pub $field:ident : $fty:ty ),* $(,)?
        }
    ) => {
        $(#[doc = $doc])*
        #[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
        #[repr(C, packed)]
        pub struct $name {
            $( $(#[doc = $fdoc])* pub $field: $fty ),*
        }

        impl $crate::layout::Layout for $name {
            const LAYOUT: $crate::layout::TypeInfo = {
                const FIELDS: &[$crate::layout::FieldInfo] = &[
                    $( $crate::layout::FieldInfo {
                        name: stringify!($field),
                        offset: core::mem::offset_of!($name, $field),
                        ty: &<$fty as $crate::layout::Layout>::LAYOUT,
                        doc: concat!($($fdoc),*),
                    } ),*
                ];
                $crate::layout::TypeInfo {
                    name: stringify!($name),
                    size: core::mem::size_of::<$name>(),
                    hash: $crate::layout::struct_hash(
                        stringify!($name),
                        core::mem::size_of::<$name>(),
                        FIELDS,
                    ),
                    fields: FIELDS,
                    array: None,
                    doc: concat!($($doc),*),
                }
            };
        }
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    wire_struct! {
        /// Test inner.
        pub struct Inner {
            /// a
            pub a: u8,
            /// b
            pub b: f32,
        }
    }
    wire_struct! {
        /// Test outer.
        pub struct Outer {
            /// x
            pub x: u16,
            /// inner
            pub inner: Inner,
            /// arr
            pub arr: [u16; 3],
        }
    }
    wire_struct! {
        /// Same as Outer with two fields swapped.
        pub struct Swapped {
            /// inner
            pub inner: Inner,
            /// x
            pub x: u16,
            /// arr
            pub arr: [u16; 3],
        }
    }

    #[test]
    fn offsets_come_from_the_compiler() {
        assert_eq!(Outer::LAYOUT.size, 2 + 5 + 6);
        assert_eq!(Outer::LAYOUT.field("x"), Some((0, 2)));
        assert_eq!(Outer::LAYOUT.field("inner.b"), Some((3, 4)));
        assert_eq!(Outer::LAYOUT.field("arr[2]"), Some((11, 2)));
        assert_eq!(Outer::LAYOUT.field("arr[3]"), None);
        assert_eq!(Outer::LAYOUT.field("nope"), None);
    }

    #[test]
    fn leaf_boundaries_reject_partial_fields() {
        let t = &Outer::LAYOUT;
        for ok in [0, 2, 3, 7, 9, 11, 13] {
            assert!(t.is_leaf_boundary(ok), "{ok}");
        }
        for bad in [1, 4, 5, 6, 8, 10, 12, 14] {
            assert!(!t.is_leaf_boundary(bad), "{bad}");
        }
    }

    #[test]
    fn hash_changes_when_layout_changes() {
        assert_ne!(Outer::LAYOUT.hash, Swapped::LAYOUT.hash);
        assert_ne!(<[u16; 3]>::LAYOUT.hash, <[u16; 4]>::LAYOUT.hash);
        assert_ne!(<[u16; 3]>::LAYOUT.hash, <[i16; 3]>::LAYOUT.hash);
    }

    #[test]
    fn paths_name_the_leaf_under_an_offset() {
        let t = &Outer::LAYOUT;
        assert_eq!(t.path_of(0).unwrap().to_string(), "x");
        assert_eq!(t.path_of(1).unwrap().to_string(), "x");
        assert_eq!(t.path_of(4).unwrap().to_string(), "inner.b");
        assert_eq!(t.path_of(11).unwrap().to_string(), "arr[2]");
        assert_eq!(t.path_of(13), None);
    }

    #[test]
    fn doc_comments_are_kept() {
        assert_eq!(Outer::LAYOUT.doc, " Test outer.");
        assert_eq!(Outer::LAYOUT.fields[2].doc, " arr");
    }

    #[test]
    fn leaves_are_visited_in_order() {
        let mut seen = [0usize; 8];
        let mut n = 0;
        Outer::LAYOUT.for_each_leaf(&mut |_, off, _| {
            seen[n] = off;
            n += 1;
        });
        assert_eq!(&seen[..n], &[0, 2, 3, 7]);
    }
}
