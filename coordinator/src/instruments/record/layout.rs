//! Wire structs read and written through their compile-time layouts: as nested JSON for the
//! recording and the panel, and leaf by leaf for the panel's settings editor.

use protocol::layout::TypeInfo;
use serde_json::{json, Value};

/// A `Pod` wire struct as nested JSON, field by field, from its compile-time layout.
pub fn layout_json<T: protocol::Layout + bytemuck::Pod>(value: &T) -> Value {
    typed_json(&T::LAYOUT, bytemuck::bytes_of(value))
}

fn typed_json(ty: &TypeInfo, bytes: &[u8]) -> Value {
    if let Some((elem, len)) = ty.array {
        return Value::Array(
            (0..len)
                .map(|i| typed_json(elem, &bytes[i * elem.size..(i + 1) * elem.size]))
                .collect(),
        );
    }
    if !ty.fields.is_empty() {
        let mut m = serde_json::Map::new();
        for f in ty.fields {
            m.insert(
                f.name.to_string(),
                typed_json(f.ty, &bytes[f.offset..f.offset + f.ty.size]),
            );
        }
        return Value::Object(m);
    }
    primitive_json(ty.name, bytes).unwrap_or(Value::Null)
}

fn primitive_json(name: &str, b: &[u8]) -> Option<Value> {
    Some(match name {
        "u8" => json!(b[0]),
        "i8" => json!(b[0] as i8),
        "u16" => json!(u16::from_le_bytes(b.try_into().ok()?)),
        "i16" => json!(i16::from_le_bytes(b.try_into().ok()?)),
        "u32" => json!(u32::from_le_bytes(b.try_into().ok()?)),
        "i32" => json!(i32::from_le_bytes(b.try_into().ok()?)),
        "u64" => json!(u64::from_le_bytes(b.try_into().ok()?)),
        "i64" => json!(i64::from_le_bytes(b.try_into().ok()?)),
        // Through f64 so the JSON shows the f32 exactly.
        "f32" => json!(f64::from(f32::from_le_bytes(b.try_into().ok()?))),
        _ => return None,
    })
}

/// One leaf of a wire struct's layout: its path (`line_pid.kp`, `spots[3]`), offset and type.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Leaf {
    /// Dotted path with array indices.
    pub path: String,
    /// Byte offset.
    pub offset: usize,
    /// Primitive type name (`f32`, `u16`, …).
    pub ty: &'static str,
    /// Size in bytes.
    pub size: usize,
}

/// Every primitive leaf of a layout, arrays expanded.
pub fn leaves(ty: &'static TypeInfo) -> Vec<Leaf> {
    fn walk(ty: &'static TypeInfo, path: String, base: usize, out: &mut Vec<Leaf>) {
        if let Some((elem, len)) = ty.array {
            for i in 0..len {
                walk(elem, format!("{path}[{i}]"), base + i * elem.size, out);
            }
        } else if ty.fields.is_empty() {
            out.push(Leaf {
                path,
                offset: base,
                ty: ty.name,
                size: ty.size,
            });
        } else {
            for f in ty.fields {
                let p = if path.is_empty() {
                    f.name.to_string()
                } else {
                    format!("{path}.{}", f.name)
                };
                walk(f.ty, p, base + f.offset, out);
            }
        }
    }
    let mut out = Vec::new();
    walk(ty, String::new(), 0, &mut out);
    out
}

/// A leaf's value in `bytes` (the whole struct) as JSON.
pub fn leaf_value(leaf: &Leaf, bytes: &[u8]) -> Value {
    bytes
        .get(leaf.offset..leaf.offset + leaf.size)
        .and_then(|b| primitive_json(leaf.ty, b))
        .unwrap_or(Value::Null)
}

/// The little-endian bytes of `text` as a value of the leaf's type.
///
/// # Errors
/// Text that is not a number of that type, or out of its range.
pub fn leaf_bytes(leaf: &Leaf, text: &str) -> Result<Vec<u8>, String> {
    let text = text.trim();
    let bad = || format!("{}: {text:?} is not a valid {}", leaf.path, leaf.ty);
    if leaf.ty == "f32" {
        let v: f32 = text.parse().map_err(|_| bad())?;
        if !v.is_finite() {
            return Err(bad());
        }
        return Ok(v.to_le_bytes().to_vec());
    }
    let v: i128 = text.parse().map_err(|_| bad())?;
    let (lo, hi): (i128, i128) = match leaf.ty {
        "u8" => (0, u8::MAX.into()),
        "i8" => (i8::MIN.into(), i8::MAX.into()),
        "u16" => (0, u16::MAX.into()),
        "i16" => (i16::MIN.into(), i16::MAX.into()),
        "u32" => (0, u32::MAX.into()),
        "i32" => (i32::MIN.into(), i32::MAX.into()),
        "u64" => (0, u64::MAX.into()),
        "i64" => (i64::MIN.into(), i64::MAX.into()),
        _ => return Err(format!("{}: type {} cannot be edited", leaf.path, leaf.ty)),
    };
    if v < lo || v > hi {
        return Err(format!(
            "{}: {v} is out of range for {}",
            leaf.path, leaf.ty
        ));
    }
    Ok(v.to_le_bytes()[..leaf.size].to_vec())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_leaves_round_trip_through_text() {
        let leaves = leaves(&<protocol::Settings as protocol::Layout>::LAYOUT);
        let kp = leaves
            .iter()
            .find(|l| l.path == "line_pid.kp")
            .expect("line_pid.kp is a leaf");
        assert_eq!(kp.ty, "f32");
        let bytes = leaf_bytes(kp, "1.25").unwrap();
        assert_eq!(bytes, 1.25f32.to_le_bytes());
        assert!(leaf_bytes(kp, "fast").is_err());
        let small = leaves.iter().find(|l| l.ty == "u8").expect("a u8 setting");
        assert!(leaf_bytes(small, "256").is_err());
        assert_eq!(leaf_bytes(small, "255").unwrap(), vec![255]);
    }

    #[test]
    fn state_json_has_every_sub_struct() {
        let mut s = protocol::RobotState::default();
        s.wheels.left_mps = 0.25;
        s.line.darkness[3] = 700;
        let v = layout_json(&s);
        assert_eq!(v["wheels"]["left_mps"], json!(0.25));
        assert_eq!(v["line"]["darkness"][3], json!(700));
        assert!(v["power"]["battery_mv"].is_number());
    }
}
