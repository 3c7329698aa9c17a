//! What a MATLAB v5 `.mat` file holds, variable by variable, for error messages.
//!
//! The `matfile` crate reads numeric arrays and skips what it cannot read, so a
//! variable that is a cell, a struct or text, or that a cut-off download ends inside,
//! looked simply absent ("no variable 'rect_data'"). [`variables`] walks the file's
//! top-level data elements itself (MAT-File Format, The MathWorks, 2019: a 128-byte
//! header, then `(type, bytes)` tagged elements padded to 8 bytes, `miCOMPRESSED` ones
//! holding a zlib stream of one `miMATRIX`), reading each variable's name and class, and
//! where the file ends early.

use std::io::Read;

/// One top-level variable.
#[derive(Clone, Debug, PartialEq)]
pub struct Variable {
    pub name: String,
    /// MATLAB's class: "double", "cell", "char", …
    pub class: &'static str,
    /// Whether the file holds all the bytes its tag announces.
    pub whole: bool,
}

const MI_MATRIX: u32 = 14;
const MI_COMPRESSED: u32 = 15;

/// The variables of a MAT v5 file's bytes (an empty list for another format).
pub fn variables(bytes: &[u8]) -> Vec<Variable> {
    let Some(big) = endian(bytes) else {
        return Vec::new();
    };
    let u32_at = |b: &[u8], at: usize| -> Option<u32> {
        let w: [u8; 4] = b.get(at..at + 4)?.try_into().ok()?;
        Some(if big {
            u32::from_be_bytes(w)
        } else {
            u32::from_le_bytes(w)
        })
    };
    let mut out = Vec::new();
    let mut at = 128usize;
    while let (Some(kind), Some(len)) = (u32_at(bytes, at), u32_at(bytes, at + 4)) {
        let start = at + 8;
        let end = start.saturating_add(len as usize);
        let whole = end <= bytes.len();
        let body = &bytes[start.min(bytes.len())..end.min(bytes.len())];
        let head = match kind {
            MI_COMPRESSED => {
                let mut d = Vec::new();
                if let Ok(z) = libflate::zlib::Decoder::new(body) {
                    let _ = z.take(512).read_to_end(&mut d);
                }
                d
            }
            MI_MATRIX => {
                let mut d = kind_and_len(kind, len, big);
                d.extend_from_slice(&body[..body.len().min(512)]);
                d
            }
            _ => Vec::new(),
        };
        if let Some((name, class)) = matrix_header(&head, big, &u32_at) {
            out.push(Variable { name, class, whole });
        } else if !whole {
            out.push(Variable {
                name: String::new(),
                class: "unknown",
                whole,
            });
        }
        if !whole {
            break;
        }
        at = end.next_multiple_of(8);
    }
    out
}

fn endian(bytes: &[u8]) -> Option<bool> {
    match bytes.get(126..128)? {
        b"IM" => Some(false),
        b"MI" => Some(true),
        _ => None,
    }
}

fn kind_and_len(kind: u32, len: u32, big: bool) -> Vec<u8> {
    let enc = |v: u32| {
        if big {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        }
    };
    [enc(kind), enc(len)].concat()
}

/// `(name, class)` of an `miMATRIX` element's start: its array flags, dimensions and name.
fn matrix_header(
    m: &[u8],
    big: bool,
    u32_at: &dyn Fn(&[u8], usize) -> Option<u32>,
) -> Option<(String, &'static str)> {
    if u32_at(m, 0)? != MI_MATRIX {
        return None;
    }
    // Sub-elements from byte 8: flags (8 bytes of data), dimensions, name.
    let mut at = 8;
    let mut sub = || -> Option<&[u8]> {
        let tag = u32_at(m, at)?;
        let (len, data_at, next) = if tag >> 16 != 0 {
            // A small element: type and length share the tag's four bytes.
            let len = (tag >> 16) as usize;
            (len, at + 4, at + 8)
        } else {
            let len = u32_at(m, at + 4)? as usize;
            (len, at + 8, at + 8 + len.next_multiple_of(8))
        };
        let data = m.get(data_at..data_at + len)?;
        at = next;
        Some(data)
    };
    let flags = sub()?;
    let class_code = if big { flags.get(3)? } else { flags.first()? };
    let _dims = sub()?;
    let name = String::from_utf8_lossy(sub()?).into_owned();
    Some((name, class_name(*class_code)))
}

fn class_name(code: u8) -> &'static str {
    match code {
        1 => "cell",
        2 => "struct",
        3 => "object",
        4 => "char",
        5 => "sparse",
        6 => "double",
        7 => "single",
        8 => "int8",
        9 => "uint8",
        10 => "int16",
        11 => "uint16",
        12 => "int32",
        13 => "uint32",
        14 => "int64",
        15 => "uint64",
        _ => "unknown",
    }
}

/// Why variable `name` could not be read, from the file's own layout: the file ends
/// inside it, or it is not a numeric array; `None` if it is simply not there.
pub fn why_unreadable(bytes: &[u8], name: &str) -> Option<String> {
    let vars = variables(bytes);
    if let Some(v) = vars.iter().find(|v| v.name == name) {
        return Some(if !v.whole {
            format!(
                "the file ends inside variable '{name}' (truncated: {} bytes in all)",
                bytes.len()
            )
        } else {
            format!(
                "variable '{name}' is a {} array, not a numeric one",
                v.class
            )
        });
    }
    vars.last().filter(|v| !v.whole).map(|_| {
        format!(
            "the file ends inside a variable before '{name}' was found (truncated: {} bytes in all)",
            bytes.len()
        )
    })
}
