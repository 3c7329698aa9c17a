//! The `.npy` header read before the data (NumPy's format, versions 1-3): the array it
//! announces must fit the file exactly, so a header that claims terabytes over a few bytes
//! of data, a truncated file, or trailing bytes are refused with both sizes named, before
//! anything is allocated.

use crate::error::{Error, Result};
use std::io::Read;
use std::path::Path;

/// What the header says: the element size in bytes and the shape.
#[derive(Debug, PartialEq)]
pub struct NpyHeader {
    pub item_bytes: u64,
    pub shape: Vec<u64>,
    /// Bytes before the data.
    pub data_offset: u64,
}

/// Reads and checks the header of `path` against the file's size.
pub fn check(path: &Path) -> Result<NpyHeader> {
    let bad = |msg: String| Error::scene(path, msg);
    let mut f = super::text::open_regular(path, "a .npy array")?;
    let file_len = f.metadata().map_err(|e| Error::io(path, e))?.len();
    let mut pre = [0u8; 12];
    let got = read_up_to(&mut f, &mut pre).map_err(|e| Error::io(path, e))?;
    if got < 10 || &pre[..6] != b"\x93NUMPY" {
        return Err(bad("not a .npy file (no \\x93NUMPY magic)".into()));
    }
    let (len, start) = match pre[6] {
        1 => (u16::from_le_bytes([pre[8], pre[9]]) as u64, 10u64),
        2 | 3 if got == 12 => (
            u32::from_le_bytes([pre[8], pre[9], pre[10], pre[11]]) as u64,
            12u64,
        ),
        v => return Err(bad(format!(".npy format version {v} is not 1, 2 or 3"))),
    };
    let data_offset = start + len;
    if data_offset > file_len {
        return Err(bad(format!(
            "truncated .npy: its header needs {data_offset} bytes, the file has {file_len}"
        )));
    }
    let mut text = vec![0u8; len as usize];
    use std::io::{Seek, SeekFrom};
    f.seek(SeekFrom::Start(start))
        .and_then(|_| f.read_exact(&mut text))
        .map_err(|e| Error::io(path, e))?;
    let text = String::from_utf8_lossy(&text);
    let descr = field(&text, "descr")
        .ok_or_else(|| bad(format!("the .npy header has no 'descr': {}", text.trim())))?;
    let item_bytes: u64 = match descr.trim_matches(|c| c == '\'' || c == '"') {
        "<f4" | "|f4" => 4,
        "<f8" | "|f8" => 8,
        other => {
            return Err(bad(format!(
                "dtype '{other}': Umbra reads little-endian float32 or float64 .npy files"
            )))
        }
    };
    let shape_text = field(&text, "shape")
        .ok_or_else(|| bad(format!("the .npy header has no 'shape': {}", text.trim())))?;
    let shape = shape_text
        .trim_matches(|c| c == '(' || c == ')')
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse::<u64>())
        .collect::<std::result::Result<Vec<u64>, _>>()
        .map_err(|_| {
            bad(format!(
                "the .npy shape {shape_text} is not a tuple of integers"
            ))
        })?;
    let need = shape
        .iter()
        .try_fold(item_bytes, |acc, &d| acc.checked_mul(d))
        .and_then(|n| n.checked_add(data_offset));
    match need {
        Some(n) if n == file_len => Ok(NpyHeader {
            item_bytes,
            shape,
            data_offset,
        }),
        Some(n) if n < file_len => Err(bad(format!(
            "the .npy header announces shape {shape:?} ({n} bytes with the header) but the file has {file_len}: {} trailing bytes",
            file_len - n
        ))),
        Some(n) => Err(bad(format!(
            "truncated .npy: shape {shape:?} needs {n} bytes with the header, the file has {file_len}"
        ))),
        None => Err(bad(format!(
            "the .npy header announces shape {shape:?}, more bytes than a file can hold; the file has {file_len}"
        ))),
    }
}

fn read_up_to(f: &mut std::fs::File, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match f.read(&mut buf[n..])? {
            0 => break,
            k => n += k,
        }
    }
    Ok(n)
}

/// The value text of `'key': value` in a Python dict literal (a tuple kept whole).
fn field<'a>(text: &'a str, key: &str) -> Option<&'a str> {
    let at = text
        .find(&format!("'{key}'"))
        .or_else(|| text.find(&format!("\"{key}\"")))?;
    let rest = text[at + key.len() + 2..].trim_start();
    let rest = rest.strip_prefix(':')?.trim_start();
    let end = if rest.starts_with('(') {
        rest.find(')')? + 1
    } else {
        rest.find([',', '}']).unwrap_or(rest.len())
    };
    Some(rest[..end].trim())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn npy(header: &str, data: usize) -> Vec<u8> {
        let mut h = header.to_string();
        while !(10 + h.len() + 1).is_multiple_of(64) {
            h.push(' ');
        }
        h.push('\n');
        let mut v = b"\x93NUMPY\x01\x00".to_vec();
        v.extend((h.len() as u16).to_le_bytes());
        v.extend(h.as_bytes());
        v.extend(vec![0u8; data]);
        v
    }

    fn check_bytes(name: &str, bytes: &[u8]) -> Result<NpyHeader> {
        let p = std::env::temp_dir().join(format!("umbra-npyh-{}-{name}.npy", std::process::id()));
        std::fs::write(&p, bytes).unwrap();
        let r = check(&p);
        std::fs::remove_file(&p).ok();
        r
    }

    #[test]
    fn the_header_must_fit_the_file() {
        let h = "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3, 5), }";
        let ok = check_bytes("ok", &npy(h, 120)).unwrap();
        assert_eq!((ok.item_bytes, ok.shape), (4, vec![2, 3, 5]));
        let e = check_bytes("short", &npy(h, 100)).unwrap_err().to_string();
        assert!(e.contains("truncated") && e.contains("[2, 3, 5]"), "{e}");
        let e = check_bytes("long", &npy(h, 124)).unwrap_err().to_string();
        assert!(e.contains("4 trailing bytes"), "{e}");
        let huge =
            "{'descr': '<f4', 'fortran_order': False, 'shape': (1000000, 1000000, 1000000), }";
        let e = check_bytes("huge", &npy(huge, 64)).unwrap_err().to_string();
        assert!(e.contains("truncated") && e.contains("1000000"), "{e}");
        let e = check_bytes("int", &npy(&h.replace("<f4", "<i8"), 240))
            .unwrap_err()
            .to_string();
        assert!(e.contains("'<i8'"), "{e}");
        let scalar = "{'descr': '<f8', 'fortran_order': False, 'shape': (), }";
        assert_eq!(
            check_bytes("scalar", &npy(scalar, 8)).unwrap().shape,
            Vec::<u64>::new()
        );
    }
}
