//! Keeps `docs/protocol.md` true: its tables are rendered here from the code's layout reflection
//! and compared with the document's `<!-- generated:NAME -->` … `<!-- end -->` regions. Run with
//! `POCKETFLEET_BLESS=1` to rewrite the regions after a protocol change.

use std::fmt::Write as _;
use std::path::PathBuf;

use protocol::layout::{FieldInfo, Layout, TypeInfo};
use protocol::packets::{
    CalibrationAction, DriveMode, LogLevel, Mark, MoveOutcome, NackReason, ReflectorMode, Side,
    SETTINGS_CHUNK,
};
use protocol::settings::{Range, RULES};
use protocol::state::RobotState;
use protocol::{
    wire_struct, PacketType, Settings, HEADER_LEN, MAX_PACKET, MAX_PAYLOAD, PROTOCOL_VERSION,
    SETTINGS_LAYOUT_HASH,
};

/// Doc comment text fit for a table cell: one line, rustdoc link targets dropped, pipes escaped.
fn cell(doc: &str) -> String {
    let mut out = String::new();
    let mut chars = doc.trim().chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '[' | ']' => {
                if c == ']' && chars.peek() == Some(&'(') {
                    // Skip a rustdoc link target such as `(crate::packets::LogLevel)`.
                    for d in chars.by_ref() {
                        if d == ')' {
                            break;
                        }
                    }
                }
            }
            '|' => out.push_str("\\|"),
            '\n' => out.push(' '),
            _ => out.push(c),
        }
    }
    let mut squeezed = String::new();
    for w in out.split_whitespace() {
        if !squeezed.is_empty() {
            squeezed.push(' ');
        }
        squeezed.push_str(w);
    }
    squeezed
}

fn type_name(ty: &TypeInfo) -> String {
    match ty.array {
        Some((elem, n)) => format!("{}[{n}]", type_name(elem)),
        None => ty.name.to_string(),
    }
}

/// Visits every leaf (primitive or array of primitives) with its dotted path, offset and field.
fn leaves(
    ty: &TypeInfo,
    prefix: &str,
    base: usize,
    visit: &mut dyn FnMut(&str, usize, &FieldInfo),
) {
    for f in ty.fields {
        let path = if prefix.is_empty() {
            f.name.to_string()
        } else {
            format!("{prefix}.{}", f.name)
        };
        if f.ty.fields.is_empty() {
            visit(&path, base + f.offset, f);
        } else {
            leaves(f.ty, &path, base + f.offset, visit);
        }
    }
}

fn number_at(bytes: &[u8], ty: &TypeInfo) -> String {
    let b = &bytes[..ty.size];
    match ty.name {
        "u8" => b[0].to_string(),
        "i8" => (b[0] as i8).to_string(),
        "u16" => u16::from_le_bytes(b.try_into().unwrap()).to_string(),
        "i16" => i16::from_le_bytes(b.try_into().unwrap()).to_string(),
        "u32" => u32::from_le_bytes(b.try_into().unwrap()).to_string(),
        "i32" => i32::from_le_bytes(b.try_into().unwrap()).to_string(),
        "u64" => u64::from_le_bytes(b.try_into().unwrap()).to_string(),
        "f32" => f32::from_le_bytes(b.try_into().unwrap()).to_string(),
        other => panic!("no reader for {other}"),
    }
}

fn value_at(bytes: &[u8], ty: &TypeInfo) -> String {
    match ty.array {
        Some((elem, n)) => {
            let items: Vec<String> = (0..n)
                .map(|k| number_at(&bytes[k * elem.size..], elem))
                .collect();
            if elem.name == "u8" && ty.size > 4 {
                let end = bytes[..ty.size].iter().position(|&b| b == 0).unwrap_or(n);
                return format!("\"{}\"", String::from_utf8_lossy(&bytes[..end]));
            }
            if items.iter().all(|i| *i == items[0]) {
                format!("{} ×{n}", items[0])
            } else {
                items.join(", ")
            }
        }
        None => number_at(bytes, ty),
    }
}

fn number(v: f64) -> String {
    match v {
        v if v == f64::from(u16::MAX) => "65535".into(),
        v if v.abs() >= 1.0e5 && v.fract() == 0.0 => format!("{v:.0}"),
        v => format!("{v}"),
    }
}

fn render_packets() -> String {
    let mut s = String::from(
        "| code | packet | direction | payload bytes | meaning |\n|---|---|---|---|---|\n",
    );
    for &t in PacketType::ALL {
        let (min, max) = t.payload_range();
        let size = if min == max {
            format!("{max}")
        } else {
            format!("{min} to {max}")
        };
        let dir = if (t as u8) < 0x40 {
            "robot → host"
        } else {
            "host → robot"
        };
        let _ = writeln!(
            s,
            "| `{:#04x}` | `{}` | {dir} | {size} | {} |",
            t as u8,
            t.name(),
            cell(t.layout().doc)
        );
    }
    s
}

fn render_packet_fields() -> String {
    let mut s = String::new();
    for &t in PacketType::ALL {
        let ty = t.layout();
        let (min, max) = t.payload_range();
        let _ = writeln!(s, "#### `{:#04x}` {}\n", t as u8, t.name());
        if ty.fields.is_empty() {
            let _ = writeln!(s, "Empty payload.\n");
            continue;
        }
        if min != max {
            let _ = writeln!(
                s,
                "Variable length: the first {min} bytes always travel, then only the used part of \
                 the last field ({min} to {max} bytes).\n"
            );
        } else {
            let _ = writeln!(s, "{max} bytes.\n");
        }
        s.push_str("| offset | field | type | meaning |\n|---|---|---|---|\n");
        leaves(ty, "", 0, &mut |path, offset, f| {
            let _ = writeln!(
                s,
                "| {offset} | `{path}` | `{}` | {} |",
                type_name(f.ty),
                cell(f.doc)
            );
        });
        s.push('\n');
    }
    s.trim_end().to_string() + "\n"
}

fn render_settings() -> String {
    let defaults = Settings::default();
    let bytes = defaults.as_bytes();
    let mut s = String::from(
        "| offset | field | type | default | valid | meaning |\n|---|---|---|---|---|---|\n",
    );
    leaves(&Settings::LAYOUT, "", 0, &mut |path, offset, f| {
        let rule = RULES
            .iter()
            .find(|r| r.path == path)
            .unwrap_or_else(|| panic!("no rule for {path}"));
        let mut valid = match rule.range {
            Range::Number { min, max } => format!("{} to {}", number(min), number(max)),
            Range::Text => "printable ASCII, NUL-padded".into(),
        };
        if let Some(b) = rule.bound_by {
            let op = if b.strict { "<" } else { "≤" };
            let _ = write!(valid, "; {op} `{}`", b.other);
        }
        if f.ty.array.is_some() && rule.range != Range::Text {
            valid.push_str(" (each)");
        }
        if !rule.note.is_empty() {
            let _ = write!(valid, "; {}", rule.note);
        }
        let _ = writeln!(
            s,
            "| {offset} | `{path}` | `{}` | {} | {valid} | {} |",
            type_name(f.ty),
            value_at(&bytes[offset..], f.ty),
            cell(f.doc)
        );
    });
    s
}

fn render_codes() -> String {
    let mut s = String::new();
    macro_rules! table {
        ($t:ty, $title:literal) => {
            let _ = writeln!(s, "{}\n\n| code | name | meaning |\n|---|---|---|", $title);
            for &v in <$t>::ALL {
                let _ = writeln!(s, "| {} | `{}` | {} |", v as u8, v.name(), cell(v.doc()));
            }
            s.push('\n');
        };
    }
    table!(NackReason, "Nack reasons (`Nack.reason`):");
    table!(
        ReflectorMode,
        "Reflector modes (`ReflectorConfig.mode`, `reflector.mode`):"
    );
    table!(LogLevel, "Log levels (`Log.level`, `log.level`):");
    table!(
        CalibrationAction,
        "Calibration actions (`LineCalibration.action`):"
    );
    table!(MoveOutcome, "Move outcomes (`MoveFinished.outcome`):");
    table!(DriveMode, "Drive modes (`State.locomotion.mode`):");
    table!(
        Side,
        "Receiver sides (`Obstacle.side`, `RobotEncountered.side`):"
    );
    table!(Mark, "Colour marks (`State.line.mark`):");
    s.trim_end().to_string() + "\n"
}

fn render_constants() -> String {
    let rows = [
        ("`PROTOCOL_VERSION`", PROTOCOL_VERSION.to_string()),
        ("header bytes", HEADER_LEN.to_string()),
        ("largest payload", MAX_PAYLOAD.to_string()),
        ("largest frame (before SLIP)", MAX_PACKET.to_string()),
        ("settings chunk (update, read)", SETTINGS_CHUNK.to_string()),
        ("settings size", Settings::SIZE.to_string()),
        (
            "settings layout hash",
            format!("`{SETTINGS_LAYOUT_HASH:#018x}`"),
        ),
        ("state size", RobotState::LAYOUT.size.to_string()),
        (
            "state layout hash",
            format!("`{:#018x}`", RobotState::LAYOUT.hash),
        ),
        ("`Nack.field_offset` when no field", "`0xffff`".to_string()),
    ];
    let mut s = String::from("| constant | value |\n|---|---|\n");
    for (k, v) in rows {
        let _ = writeln!(s, "| {k} | {v} |");
    }
    s
}

wire_struct! {
    /// The worked example of the layout hash.
    pub struct Tiny {
        /// A byte.
        pub a: u8,
        /// A 16-bit value.
        pub b: u16,
    }
}

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;

fn fnv(mut h: u64, bytes: &[u8]) -> u64 {
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(FNV_PRIME);
    }
    h
}

/// The hash of `Tiny` computed step by step as the document describes it, checked against the
/// code's own value so the description cannot drift from the algorithm.
fn render_hash_example() -> String {
    let mut s = String::new();
    let mut prim = |name: &str, size: u64| {
        let h1 = fnv(FNV_OFFSET, name.as_bytes());
        let h2 = fnv(h1, &size.to_le_bytes());
        let _ = writeln!(
            s,
            "- `{name}`: FNV-1a of the bytes `\"{name}\"` from the offset basis gives `{h1:#018x}`; \
             continuing with the size {size} as 8 little-endian bytes gives `{h2:#018x}`."
        );
        h2
    };
    let u8_hash = prim("u8", 1);
    let u16_hash = prim("u16", 2);
    assert_eq!(u8_hash, u8::LAYOUT.hash);
    assert_eq!(u16_hash, u16::LAYOUT.hash);
    let size = Tiny::LAYOUT.size as u64;
    let mut h = fnv(FNV_OFFSET, b"Tiny");
    let _ = writeln!(s, "- `Tiny`: start with FNV-1a of `\"Tiny\"`: `{h:#018x}`;");
    h = fnv(h, &size.to_le_bytes());
    let _ = writeln!(s, "  - the size {size} (8 bytes LE): `{h:#018x}`;");
    for (name, offset, field_hash) in [("a", 0u64, u8_hash), ("b", 1u64, u16_hash)] {
        h = fnv(h, name.as_bytes());
        let _ = writeln!(s, "  - field name `\"{name}\"`: `{h:#018x}`;");
        h = fnv(h, &offset.to_le_bytes());
        let _ = writeln!(s, "  - its offset {offset} (8 bytes LE): `{h:#018x}`;");
        h = fnv(h, &field_hash.to_le_bytes());
        let _ = writeln!(
            s,
            "  - its type's hash `{field_hash:#018x}` (8 bytes LE): `{h:#018x}`;"
        );
    }
    assert_eq!(
        h,
        Tiny::LAYOUT.hash,
        "the described steps disagree with the code"
    );
    let _ = writeln!(s, "- so the layout hash of `Tiny` is `{h:#018x}`.");
    s
}

fn doc_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../docs/protocol.md")
}

/// Replaces the body of every generated region; returns the new text and the stale region names.
fn regenerate(text: &str, sections: &[(&str, String)]) -> Result<(String, Vec<String>), String> {
    let mut out = text.to_string();
    let mut stale = Vec::new();
    for (name, body) in sections {
        let open = format!("<!-- generated:{name} -->\n");
        let start = out
            .find(&open)
            .ok_or_else(|| format!("docs/protocol.md lacks the marker `{}`", open.trim()))?
            + open.len();
        let len = out[start..]
            .find("<!-- end -->")
            .ok_or_else(|| format!("region {name} has no `<!-- end -->`"))?;
        let current = &out[start..start + len];
        let wanted = format!("{body}\n");
        if current != wanted {
            let line = current
                .lines()
                .zip(wanted.lines())
                .position(|(a, b)| a != b)
                .unwrap_or(current.lines().count().min(wanted.lines().count()));
            stale.push(format!(
                "{name} (first difference at its line {}: doc has {:?}, code gives {:?})",
                line + 1,
                current.lines().nth(line).unwrap_or(""),
                wanted.lines().nth(line).unwrap_or("")
            ));
            out.replace_range(start..start + len, &wanted);
        }
    }
    Ok((out, stale))
}

#[test]
fn protocol_doc_tables_match_the_code() {
    let sections = [
        ("constants", render_constants()),
        ("packets", render_packets()),
        ("packet-fields", render_packet_fields()),
        ("settings", render_settings()),
        ("codes", render_codes()),
        ("hash-example", render_hash_example()),
    ];
    let path = doc_path();
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    let (fresh, stale) = regenerate(&text, &sections).unwrap_or_else(|e| panic!("{e}"));
    if stale.is_empty() {
        return;
    }
    if std::env::var_os("POCKETFLEET_BLESS").is_some_and(|v| v == "1") {
        std::fs::write(&path, fresh)
            .unwrap_or_else(|e| panic!("cannot write {}: {e}", path.display()));
        return;
    }
    panic!(
        "docs/protocol.md is out of date in: {}.\nRerun with POCKETFLEET_BLESS=1 to regenerate \
         the marked regions, then review the diff.",
        stale.join("; ")
    );
}

#[test]
fn a_stale_region_is_reported_and_rewritten() {
    let doc = "intro\n<!-- generated:x -->\nold\n<!-- end -->\nafter\n";
    let (fresh, stale) = regenerate(doc, &[("x", "new".into())]).unwrap();
    assert_eq!(
        fresh,
        "intro\n<!-- generated:x -->\nnew\n<!-- end -->\nafter\n"
    );
    assert_eq!(stale.len(), 1);
    let (again, none) = regenerate(&fresh, &[("x", "new".into())]).unwrap();
    assert_eq!(again, fresh);
    assert!(none.is_empty());
    assert!(regenerate(doc, &[("missing", String::new())]).is_err());
}
