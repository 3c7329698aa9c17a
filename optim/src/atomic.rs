//! Output files that lose nothing: every file Umbra writes goes through
//! [`write_file_atomic`].
//!
//! - A regular file (or none yet) is replaced atomically: the writer fills the temporary
//!   `.<name>.tmp<pid>-<n>` in the same folder, which is fsynced and renamed over the
//!   output. A reader sees the old file or the new one, never a torn one; a failed write
//!   removes its temporary. `<n>` counts the process's temporaries, so threads of one
//!   process (two Python fits) never share one; a long name is cut so the temporary's
//!   name stays within the file system's 255 bytes.
//! - A link to a file writes the file it points to (the link stays a link).
//! - A character device (`/dev/null`) or a FIFO with a reader is written in place: the
//!   writer fills a temporary in the system's temporary folder, whose bytes are then
//!   copied in (the writers seek, a pipe cannot). A FIFO without a reader, a block device
//!   or a socket is refused: the file system object is never replaced by a file.
//! - Temporaries a killed process left behind (`kill -9`, a power cut) are removed by
//!   the next write of the same output once their process is gone; a run interrupted by
//!   Ctrl-C or a termination signal removes its own ([`remove_live_temporaries`]).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

/// Writes `bytes` to `path` ([`write_file_atomic`]).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_file_atomic(path, |tmp| {
        let mut f = std::fs::File::create(tmp)?;
        f.write_all(bytes)
    })
}

/// Writes `path` through `write`, which fills the file it is given (see the module
/// docs); the output's folder is made if missing.
pub fn write_file_atomic(
    path: &Path,
    write: impl FnOnce(&Path) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let path = &follow_link(path);
    match Special::of(path) {
        Some(kind) => write_in_place(path, kind, write),
        None => replace(path, write),
    }
}

/// Checks, before any work, that `path` can be written: refuses a block device or a
/// socket, as [`write_file_atomic`] would. A FIFO is not opened here (opening and closing
/// it would hand its reader an empty stream): one without a reader is refused at the
/// write.
pub fn check_target(path: &Path) -> std::io::Result<()> {
    match Special::of(&follow_link(path)) {
        Some(kind @ (Special::BlockDevice | Special::Socket)) => open_special(path, kind).map(drop),
        _ => Ok(()),
    }
}

/// Whether `path` (through links) is a device, a FIFO or a socket: an output written in
/// place, beside which no sibling files (previews) belong.
pub fn is_special(path: &Path) -> bool {
    Special::of(&follow_link(path)).is_some()
}

/// A file system object that is not a regular file nor a folder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Special {
    CharDevice,
    Fifo,
    BlockDevice,
    Socket,
}

impl Special {
    fn of(path: &Path) -> Option<Special> {
        use std::os::unix::fs::FileTypeExt;
        let t = std::fs::metadata(path).ok()?.file_type();
        if t.is_char_device() {
            Some(Special::CharDevice)
        } else if t.is_fifo() {
            Some(Special::Fifo)
        } else if t.is_block_device() {
            Some(Special::BlockDevice)
        } else if t.is_socket() {
            Some(Special::Socket)
        } else {
            None
        }
    }
}

/// The file a symbolic link (chain) points to, if it exists; else `path` itself.
fn follow_link(path: &Path) -> PathBuf {
    let is_link = std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink());
    match is_link {
        true => std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf()),
        false => path.to_path_buf(),
    }
}

fn replace(path: &Path, write: impl FnOnce(&Path) -> std::io::Result<()>) -> std::io::Result<()> {
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty());
    if let Some(d) = dir {
        std::fs::create_dir_all(d)?;
    }
    remove_dead_temporaries(path);
    let tmp = Live::new(temp_path(path));
    let written = write(&tmp.0)
        .and_then(|()| std::fs::File::open(&tmp.0)?.sync_all())
        .and_then(|()| std::fs::rename(&tmp.0, path));
    drop(tmp);
    written?;
    if let Some(d) = dir {
        // Persist the rename itself (best effort: not every file system allows it).
        if let Ok(f) = std::fs::File::open(d) {
            let _ = f.sync_all();
        }
    }
    Ok(())
}

fn write_in_place(
    path: &Path,
    kind: Special,
    write: impl FnOnce(&Path) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let mut out = open_special(path, kind)?;
    let name = path.file_name().unwrap_or_default();
    let tmp = Live::new(temp_path(&std::env::temp_dir().join(name)));
    write(&tmp.0)?;
    let mut bytes = std::fs::File::open(&tmp.0)?;
    std::io::copy(&mut bytes, &mut out)?;
    out.flush()
}

/// Opens a special file for writing, without creating or truncating anything.
fn open_special(path: &Path, kind: Special) -> std::io::Result<std::fs::File> {
    use std::os::unix::fs::OpenOptionsExt;
    let refuse = |what: &str| {
        Err(std::io::Error::other(format!(
            "is {what}: refusing to write an output over it (give a file name)"
        )))
    };
    match kind {
        Special::BlockDevice => refuse("a block device"),
        Special::Socket => refuse("a socket"),
        Special::CharDevice => std::fs::OpenOptions::new().write(true).open(path),
        Special::Fifo => {
            // Non-blocking, so a FIFO nobody reads is an error, not a hang; blocking again
            // once open, so the copy waits for the reader instead of failing.
            let f = std::fs::OpenOptions::new()
                .write(true)
                .custom_flags(libc::O_NONBLOCK)
                .open(path);
            match f {
                Err(e) if e.raw_os_error() == Some(libc::ENXIO) => {
                    refuse("a FIFO (named pipe) that no process is reading")
                }
                Err(e) => Err(e),
                Ok(f) => {
                    use std::os::fd::AsRawFd;
                    let fd = f.as_raw_fd();
                    // SAFETY: `fd` is open for the life of `f`; F_GETFL/F_SETFL take ints.
                    let ok = unsafe {
                        let flags = libc::fcntl(fd, libc::F_GETFL);
                        flags >= 0 && libc::fcntl(fd, libc::F_SETFL, flags & !libc::O_NONBLOCK) == 0
                    };
                    match ok {
                        true => Ok(f),
                        false => Err(std::io::Error::last_os_error()),
                    }
                }
            }
        }
    }
}

/// Longest part of an output's name kept in its temporary's name (bytes): with the dot,
/// `.tmp`, a PID and a counter, within the 255 bytes of a file name.
const MAX_TEMP_STEM: usize = 200;

/// The next temporary name for `path`: `.<name>.tmp<pid>-<n>` in its folder.
fn temp_path(path: &Path) -> PathBuf {
    use std::os::unix::ffi::{OsStrExt, OsStringExt};
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let name = path.file_name().unwrap_or_default().as_bytes();
    let stem = &name[..name.len().min(MAX_TEMP_STEM)];
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    let mut tmp = b".".to_vec();
    tmp.extend_from_slice(stem);
    tmp.extend_from_slice(format!(".tmp{}-{n}", std::process::id()).as_bytes());
    path.with_file_name(std::ffi::OsString::from_vec(tmp))
}

/// The temporaries being written now, which [`remove_live_temporaries`] removes.
static LIVE: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// A temporary file registered while it exists; removed (if still there) on drop.
struct Live(PathBuf);

impl Live {
    fn new(p: PathBuf) -> Live {
        LIVE.lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(p.clone());
        Live(p)
    }
}

impl Drop for Live {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
        LIVE.lock()
            .unwrap_or_else(|e| e.into_inner())
            .retain(|p| p != &self.0);
    }
}

/// Removes the temporaries this process is writing: for a signal handler about to exit
/// (the writes are abandoned; the outputs keep their previous contents).
pub fn remove_live_temporaries() {
    let live = LIVE.lock().unwrap_or_else(|e| e.into_inner());
    for p in live.iter() {
        let _ = std::fs::remove_file(p);
    }
}

/// The PID and counter of a temporary's name: `(base, pid)` of `.<base>.tmp<pid>[-<n>]`.
fn parse_temporary(name: &str) -> Option<(&str, u32)> {
    let (base, tail) = name.strip_prefix('.')?.rsplit_once(".tmp")?;
    let (pid, n) = tail.split_once('-').unwrap_or((tail, "0"));
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    (digits(pid) && digits(n)).then_some(())?;
    Some((base, pid.parse().ok()?))
}

/// Whether process `pid` is gone (Linux's `/proc`; elsewhere it is taken as alive).
fn process_gone(pid: u32) -> bool {
    Path::new("/proc/self").exists() && !Path::new("/proc").join(pid.to_string()).exists()
}

/// Removes `path`'s temporaries whose writer process is gone.
fn remove_dead_temporaries(path: &Path) {
    use std::os::unix::ffi::OsStrExt;
    let name = path.file_name().unwrap_or_default().as_bytes();
    let stem = String::from_utf8_lossy(&name[..name.len().min(MAX_TEMP_STEM)]).into_owned();
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty());
    let Ok(entries) = std::fs::read_dir(dir.unwrap_or(Path::new("."))) else {
        return;
    };
    for e in entries.flatten() {
        let n = e.file_name().to_string_lossy().into_owned();
        if let Some((base, pid)) = parse_temporary(&n) {
            if base == stem && process_gone(pid) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}

/// Removes the temporaries [`write_atomic`] leaves when killed between writing and
/// renaming (`.<name>.tmp<pid>[-<n>]` for the checkpoint files `stage.bin` and
/// `solver-<s>.bin`) from `dir`; returns the names removed. For a folder its caller has
/// locked ([`crate::lock::FolderLock`]): no other live process writes there.
pub fn remove_stale_temporaries(dir: &Path) -> Vec<String> {
    remove_stale_temporaries_of(dir, |base| {
        base == "stage.bin"
            || base
                .strip_prefix("solver-")
                .and_then(|s| s.strip_suffix(".bin"))
                .is_some_and(|s| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit()))
    })
}

/// [`remove_stale_temporaries`] for the files whose names `ours` accepts; this process's
/// own live temporaries are kept.
pub fn remove_stale_temporaries_of(dir: &Path, ours: impl Fn(&str) -> bool) -> Vec<String> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let live: Vec<std::ffi::OsString> = (LIVE.lock().unwrap_or_else(|e| e.into_inner()).iter())
        .filter_map(|p| p.file_name().map(ToOwned::to_owned))
        .collect();
    let mut removed = Vec::new();
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some((base, _)) = parse_temporary(&name) else {
            continue;
        };
        if ours(base) && !live.contains(&e.file_name()) && std::fs::remove_file(e.path()).is_ok() {
            removed.push(name);
        }
    }
    removed.sort();
    removed
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("umbra-atomic-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn temporaries_are_named_within_255_bytes_and_parsed_back() {
        let long = "x".repeat(250) + ".npy";
        let t = temp_path(&Path::new("/tmp").join(&long));
        let name = t.file_name().unwrap().to_str().unwrap();
        assert!(name.len() <= 255, "{}", name.len());
        let (base, pid) = parse_temporary(name).unwrap();
        assert_eq!((base.len(), pid), (MAX_TEMP_STEM, std::process::id()));
        assert_eq!(parse_temporary(".a.npy.tmp12"), Some(("a.npy", 12)));
        assert_eq!(parse_temporary(".a.npy.tmp12-3"), Some(("a.npy", 12)));
        assert_eq!(parse_temporary(".a.npy.tmpx"), None);
        assert_eq!(parse_temporary("a.npy.tmp1"), None);
        // Two temporaries of one output in one process differ.
        assert_ne!(temp_path(Path::new("a")), temp_path(Path::new("a")));
    }

    #[test]
    fn a_long_name_is_written() {
        let d = dir("long");
        let p = d.join("y".repeat(250));
        write_atomic(&p, b"ok").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"ok");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn dead_processes_temporaries_go_live_ones_stay() {
        let d = dir("dead");
        let out = d.join("t.npy");
        // PID 4194304 is above Linux's pid_max limit: never alive.
        let dead = d.join(".t.npy.tmp4194304");
        let alive = d.join(format!(".t.npy.tmp{}-999", std::process::id()));
        let other = d.join(".u.npy.tmp4194304");
        for p in [&dead, &alive, &other] {
            std::fs::write(p, b"half").unwrap();
        }
        write_atomic(&out, b"whole").unwrap();
        assert!(!dead.exists());
        assert!(alive.exists() && other.exists());
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn links_and_devices_are_written_through_not_replaced() {
        let d = dir("special");
        let target = d.join("real.npy");
        std::fs::write(&target, b"old").unwrap();
        let link = d.join("link.npy");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        write_atomic(&link, b"new").unwrap();
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        assert_eq!(std::fs::read(&target).unwrap(), b"new");
        // /dev/null stays a character device.
        write_atomic(Path::new("/dev/null"), b"gone").unwrap();
        use std::os::unix::fs::FileTypeExt;
        let t = std::fs::metadata("/dev/null").unwrap().file_type();
        assert!(t.is_char_device());
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_fifo_without_a_reader_is_refused_with_one_it_is_written() {
        let d = dir("fifo");
        let fifo = d.join("pipe");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: a valid C string and mode.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let e = write_atomic(&fifo, b"x").unwrap_err().to_string();
        assert!(
            e.contains("FIFO (named pipe) that no process is reading"),
            "{e}"
        );
        assert!(
            check_target(&fifo).is_ok(),
            "a FIFO is checked at the write"
        );
        let reader = {
            let fifo = fifo.clone();
            std::thread::spawn(move || std::fs::read(fifo).unwrap())
        };
        // The reader opens the FIFO (blocking until a writer comes); retry until it has.
        let mut tries = 0;
        while let Err(e) = write_atomic(&fifo, b"through the pipe") {
            tries += 1;
            assert!(tries < 500, "{e}");
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        assert_eq!(reader.join().unwrap(), b"through the pipe");
        use std::os::unix::fs::FileTypeExt;
        assert!(std::fs::metadata(&fifo).unwrap().file_type().is_fifo());
        std::fs::remove_dir_all(&d).unwrap();
    }
}
