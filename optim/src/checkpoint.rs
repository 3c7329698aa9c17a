//! Checkpoints that survive a kill at any moment: every file is written to a temporary
//! name in the same directory, flushed to disk, then renamed over the old one (an atomic
//! replace on POSIX file systems), so a reader sees the old or the new file, never a
//! torn one.
//!
//! [`SolverCheckpoint`] plugs into argmin's `Executor::checkpointing`: it saves the
//! solver (Adam's moments, L-BFGS's history), argmin's iteration state and the fit's
//! loss history together, in one file, so they always agree. The format is postcard
//! (binary serde): unlike JSON it keeps every `f64` bit-exact, infinities included, which
//! an exact resume needs.

use argmin::core::checkpointing::{Checkpoint, CheckpointingFrequency};
use argmin::core::Error;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use std::cell::RefCell;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::rc::Rc;

/// Writes `bytes` to `path` atomically (temporary file, fsync, rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty());
    if let Some(d) = dir {
        std::fs::create_dir_all(d)?;
    }
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = path.with_file_name(format!(".{name}.tmp{}", std::process::id()));
    {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
    }
    std::fs::rename(&tmp, path)?;
    if let Some(d) = dir {
        // Persist the rename itself (best effort: not every file system allows it).
        if let Ok(f) = std::fs::File::open(d) {
            let _ = f.sync_all();
        }
    }
    Ok(())
}

/// One recorded iteration of the fit.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LossRecord {
    /// Iteration over the whole fit (all stages).
    pub iteration: u64,
    pub stage: usize,
    /// Total cost (data + regularisation).
    pub cost: f64,
    pub data_loss: f64,
    pub smoothness: f64,
    /// The objective's report (e.g. the intensity scale).
    pub report: Vec<(String, f64)>,
}

/// The loss history, shared between the observer that fills it and the checkpoint that
/// saves it.
pub type History = Rc<RefCell<Vec<LossRecord>>>;

#[derive(Serialize, Deserialize)]
struct Saved<S, I> {
    solver: S,
    state: I,
    history: Vec<LossRecord>,
}

#[derive(Serialize)]
struct SavedRef<'a, S, I> {
    solver: &'a S,
    state: &'a I,
    history: &'a [LossRecord],
}

/// argmin checkpoint to one file, written atomically.
pub struct SolverCheckpoint {
    pub path: PathBuf,
    pub every: u64,
    pub history: History,
}

impl<S, I> Checkpoint<S, I> for SolverCheckpoint
where
    S: Serialize + DeserializeOwned,
    I: Serialize + DeserializeOwned,
{
    fn save(&self, solver: &S, state: &I) -> Result<(), Error> {
        let history = self.history.borrow();
        let saved = SavedRef {
            solver,
            state,
            history: &history,
        };
        let bytes = postcard::to_stdvec(&saved)?;
        write_atomic(&self.path, &bytes).map_err(|e| {
            Error::msg(format!(
                "{}: cannot write checkpoint: {e}",
                self.path.display()
            ))
        })
    }

    fn load(&self) -> Result<Option<(S, I)>, Error> {
        if !self.path.exists() {
            return Ok(None);
        }
        let bytes = std::fs::read(&self.path)
            .map_err(|e| Error::msg(format!("{}: {e}", self.path.display())))?;
        let saved: Saved<S, I> = postcard::from_bytes(&bytes).map_err(|e| {
            Error::msg(format!(
                "{}: not a readable checkpoint: {e}",
                self.path.display()
            ))
        })?;
        *self.history.borrow_mut() = saved.history;
        Ok(Some((saved.solver, saved.state)))
    }

    fn frequency(&self) -> CheckpointingFrequency {
        CheckpointingFrequency::Every(self.every.max(1))
    }
}
