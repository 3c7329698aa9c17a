//! One writer per output folder: a fit takes [`FolderLock`] on its folder before it
//! clears stale temporaries or reads a checkpoint, so two fits (two processes, or two
//! threads of one Python process) never write into one folder; the second is refused,
//! naming the holder.
//!
//! The lock is the operating system's advisory lock (`flock`) on `.umbra.lock` in the
//! folder, held while the `FolderLock` lives: a killed holder releases it with its file
//! descriptors, so no stale lock outlives its process. The file itself stays (removing
//! it would race with a new holder) and says who holds it: `pid`, the command, the start
//! time (seconds since the Unix epoch).

use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};

/// Name of the lock file in a locked folder.
pub const LOCK_FILE: &str = ".umbra.lock";

/// A held lock on a folder (released on drop).
#[derive(Debug)]
pub struct FolderLock {
    _file: std::fs::File,
    pub path: PathBuf,
}

impl FolderLock {
    /// Locks `dir` (made if missing) for `what` (e.g. "umbra fit"); an error, naming the
    /// holder, if another writer holds it.
    pub fn acquire(dir: &Path, what: &str) -> Result<FolderLock, String> {
        let io = |p: &Path, e: std::io::Error| format!("{}: {e}", p.display());
        std::fs::create_dir_all(dir).map_err(|e| io(dir, e))?;
        let path = dir.join(LOCK_FILE);
        let mut file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(|e| io(&path, e))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                let mut holder = String::new();
                let _ = file.read_to_string(&mut holder);
                let holder = holder.trim();
                return Err(format!(
                    "{}: the folder is in use by another run ({}); wait for it to end or choose another output folder (lock file {})",
                    dir.display(),
                    if holder.is_empty() { "starting" } else { holder },
                    path.display()
                ));
            }
            Err(std::fs::TryLockError::Error(e)) => return Err(io(&path, e)),
        }
        let since = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs());
        let note = format!(
            "{what}, pid {}, started at {since} s (Unix time)\n",
            std::process::id()
        );
        let written = file
            .set_len(0)
            .and_then(|()| file.rewind())
            .and_then(|()| file.write_all(note.as_bytes()));
        written.map_err(|e| io(&path, e))?;
        Ok(FolderLock { _file: file, path })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_holder_is_refused_until_the_first_lets_go() {
        let d = std::env::temp_dir().join(format!("umbra-lock-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        let first = FolderLock::acquire(&d, "umbra fit").unwrap();
        // A second open file description conflicts, within one process too (threads).
        let e = FolderLock::acquire(&d, "umbra fit").unwrap_err();
        assert!(e.contains("in use by another run (umbra fit, pid"), "{e}");
        assert!(e.contains(LOCK_FILE), "{e}");
        drop(first);
        let again = FolderLock::acquire(&d, "umbra fit");
        assert!(again.is_ok(), "{again:?}");
        drop(again);
        std::fs::remove_dir_all(&d).unwrap();
    }
}
