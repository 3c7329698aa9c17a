//! Text inputs (scene TOML and XML, OBJ meshes, fit schedules), read with two guards a
//! plain `read_to_string` lacks (besides [`check_regular`]'s refusal of FIFOs, devices
//! and sockets): a size cap, so a wrong path (`/dev/zero`, a 40 GB
//! capture given as a mesh) fails at once instead of exhausting memory, and a check
//! for NUL bytes, which no text format Umbra reads contains and every binary file
//! does within its first kilobytes.

use crate::error::{Error, Result};
use std::io::Read;
use std::path::Path;

/// Largest text input read (bytes): 1 GiB, about 20 million OBJ vertex lines, which is
/// beyond what the renderer can fit in memory as a BVH on a workstation anyway.
pub const MAX_TEXT_BYTES: u64 = 1 << 30;

/// Checks by its type, before anything opens it, that `path` is a regular file (or a
/// link to one): a FIFO without a writer would block the read forever, a device or a
/// socket holds no file. `what` names the kind of file expected, with its article.
pub fn check_regular(path: &Path, what: &str) -> Result<()> {
    use std::os::unix::fs::FileTypeExt;
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    let t = meta.file_type();
    let kind = if t.is_file() {
        return Ok(());
    } else if t.is_dir() {
        "a folder"
    } else if t.is_fifo() {
        "a FIFO (named pipe)"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_socket() {
        "a socket"
    } else {
        "not a regular file"
    };
    Err(Error::scene(
        path,
        format!("is {kind}, not {what}: Umbra reads regular files only"),
    ))
}

/// Opens `path` for reading after [`check_regular`].
pub fn open_regular(path: &Path, what: &str) -> Result<std::fs::File> {
    check_regular(path, what)?;
    std::fs::File::open(path).map_err(|e| Error::io(path, e))
}

/// Reads `path` as UTF-8 text of at most [`MAX_TEXT_BYTES`]; `what` names the kind of
/// file in the messages, with its article ("an OBJ mesh", "a scene").
pub fn read_text(path: &Path, what: &str) -> Result<String> {
    read_text_capped(path, what, MAX_TEXT_BYTES)
}

/// [`read_text`] with an explicit cap (bytes).
pub fn read_text_capped(path: &Path, what: &str, cap: u64) -> Result<String> {
    let file = open_regular(path, what)?;
    let mut bytes = Vec::new();
    let mut chunk = vec![0u8; 1 << 16];
    let mut reader = file;
    loop {
        let n = match reader.read(&mut chunk) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(Error::io(path, e)),
        };
        if let Some(i) = chunk[..n].iter().position(|&b| b == 0) {
            return Err(Error::scene(
                path,
                format!(
                    "is not {what}: it holds binary data (a NUL byte at offset {})",
                    bytes.len() + i
                ),
            ));
        }
        bytes.extend_from_slice(&chunk[..n]);
        if bytes.len() as u64 > cap {
            return Err(Error::scene(
                path,
                format!(
                    "is larger than {} MiB, the most Umbra reads as {what}",
                    cap >> 20
                ),
            ));
        }
    }
    String::from_utf8(bytes).map_err(|e| {
        Error::scene(
            path,
            format!(
                "is not {what}: not UTF-8 text (invalid byte at offset {})",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_binary_oversized_and_folders() {
        let dir = std::env::temp_dir().join(format!("umbra-text-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let bin = dir.join("mesh.obj");
        std::fs::write(&bin, b"v 0 0 0\n\0\0\0").unwrap();
        let e = read_text(&bin, "an OBJ mesh").unwrap_err().to_string();
        assert!(e.contains("binary data (a NUL byte at offset 8)"), "{e}");
        let big = dir.join("big.obj");
        std::fs::write(&big, "v 0 0 0\n".repeat(200)).unwrap();
        let e = read_text_capped(&big, "an OBJ mesh", 1000)
            .unwrap_err()
            .to_string();
        assert!(e.contains("larger than 0 MiB"), "{e}");
        assert_eq!(
            read_text_capped(&big, "an OBJ mesh", 1600).unwrap().len(),
            1600
        );
        let e = read_text(&dir, "a scene").unwrap_err().to_string();
        assert!(e.contains("is a folder, not a scene"), "{e}");
        let e = read_text(Path::new("/dev/zero"), "a scene")
            .unwrap_err()
            .to_string();
        assert!(e.contains("is a character device, not a scene"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
