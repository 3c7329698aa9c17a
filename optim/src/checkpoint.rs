//! Checkpoints that survive a kill at any moment: every file is written to a temporary
//! name in the same directory, flushed to disk, then renamed over the old one (an atomic
//! replace on POSIX file systems), so a reader sees the old or the new file, never a
//! torn one.
//!
//! [`SolverCheckpoint`] plugs into argmin's `Executor::checkpointing`: it saves the
//! solver (Adam's moments, L-BFGS's history), argmin's iteration state and the fit's
//! loss history together, in one file, so they always agree. The body is postcard
//! (binary serde): unlike JSON it keeps every `f64` bit-exact, infinities included, which
//! an exact resume needs.
//!
//! Every checkpoint file is an envelope ([`encode`], [`decode`]):
//!
//! | bytes | content |
//! |---|---|
//! | 8 | magic number `UMBRAFCK` |
//! | 4 | format version ([`FORMAT_VERSION`]), little-endian |
//! | 1 | kind: 1 `stage.bin`, 2 `solver-<s>.bin` |
//! | 8 | length `n` of the body, little-endian |
//! | n | postcard of ([`Identity`], the body) |
//! | 8 | FNV-1a 64 of every byte before, little-endian |
//!
//! so a truncated, corrupted, foreign or older file is refused with a message naming
//! it, never decoded into a mesh of nothing. The [`Identity`] lists, one hash per
//! component (scene, measurement, schedule, model, options, initial mesh), what the
//! checkpoint's contents depend on; a resume whose identity differs is refused naming
//! the components that differ. Hashes are 64-bit FNV-1a ([`Fnv64`]) over canonical
//! bytes: stable across runs and machines (std's `Hash` is randomised per process).

use crate::step::State;
use argmin::core::checkpointing::{Checkpoint, CheckpointingFrequency};
use argmin::core::{Error, State as _};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::rc::Rc;

/// The first bytes of every checkpoint file.
pub const MAGIC: [u8; 8] = *b"UMBRAFCK";

/// The envelope's format version: 2 (version 1, before the envelope, was bare postcard).
/// Raise it whenever a body's layout or an identity component's meaning changes.
pub const FORMAT_VERSION: u32 = 2;

/// What a checkpoint file holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Kind {
    /// `stage.bin`: the stage to run next and its starting mesh.
    Stage = 1,
    /// `solver-<s>.bin`: a stage's solver and iteration state.
    Solver = 2,
}

impl Kind {
    fn name(self) -> &'static str {
        match self {
            Kind::Stage => "a stage checkpoint (stage.bin)",
            Kind::Solver => "a solver checkpoint (solver-<s>.bin)",
        }
    }
}

/// 64-bit FNV-1a (Fowler, Noll, Vo): offset basis `0xcbf29ce484222325`, prime
/// `0x100000001b3`, one byte at a time. Not cryptographic; stable everywhere.
#[derive(Clone, Copy, Debug)]
pub struct Fnv64(u64);

impl Default for Fnv64 {
    fn default() -> Self {
        Fnv64(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv64 {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn write(&mut self, bytes: &[u8]) -> &mut Self {
        for &b in bytes {
            self.0 ^= b as u64;
            self.0 = self.0.wrapping_mul(0x100_0000_01b3);
        }
        self
    }

    /// A length-prefixed field (so `("ab", "c")` and `("a", "bc")` differ).
    pub fn field(&mut self, bytes: &[u8]) -> &mut Self {
        self.write(&(bytes.len() as u64).to_le_bytes()).write(bytes)
    }

    pub fn f64s(&mut self, values: &[f64]) -> &mut Self {
        self.write(&(values.len() as u64).to_le_bytes());
        for v in values {
            self.write(&v.to_bits().to_le_bytes());
        }
        self
    }

    pub fn f32s(&mut self, values: &[f32]) -> &mut Self {
        self.write(&(values.len() as u64).to_le_bytes());
        for v in values {
            self.write(&v.to_bits().to_le_bytes());
        }
        self
    }

    pub fn finish(&self) -> u64 {
        self.0
    }
}

/// FNV-1a 64 of `bytes`.
pub fn fnv1a(bytes: &[u8]) -> u64 {
    Fnv64::new().write(bytes).finish()
}

/// FNV-1a 64 of a value's postcard bytes (canonical for a given type).
pub fn hash_postcard<T: Serialize>(value: &T) -> u64 {
    postcard::to_stdvec(value).map_or(0, |b| fnv1a(&b))
}

/// FNV-1a 64 of a mesh's bits (positions, faces, values).
pub fn hash_mesh(mesh: &crate::Mesh) -> u64 {
    let mut h = Fnv64::new();
    h.f64s(&mesh.vertices.iter().flatten().copied().collect::<Vec<_>>());
    let faces: Vec<u8> = mesh
        .faces
        .iter()
        .flatten()
        .flat_map(|i| i.to_le_bytes())
        .collect();
    h.field(&faces);
    h.f64s(&mesh.vertex_values);
    h.finish()
}

/// One thing a checkpoint depends on.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Component {
    /// What it is, as the refusal names it: "scene", "measurement", "schedule", ….
    pub name: String,
    pub hash: u64,
    /// A short human-readable value (e.g. `tri3, 16 spp`), shown when it differs; may be
    /// empty.
    pub summary: String,
}

/// What a fit's checkpoints depend on, one hash per component.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Identity {
    pub components: Vec<Component>,
}

impl Identity {
    /// Adds (or replaces) component `name`.
    pub fn with(mut self, name: &str, hash: u64, summary: impl Into<String>) -> Identity {
        self.components.retain(|c| c.name != name);
        self.components.push(Component {
            name: name.into(),
            hash,
            summary: summary.into(),
        });
        self
    }

    pub fn get(&self, name: &str) -> Option<&Component> {
        self.components.iter().find(|c| c.name == name)
    }

    /// How `saved` (a checkpoint's) differs from this run's identity, one clause per
    /// component, or `None` when they agree.
    pub fn differences(&self, saved: &Identity) -> Option<String> {
        let short = |h: u64| format!("{h:016x}");
        let mut out = Vec::new();
        for now in &self.components {
            match saved.get(&now.name) {
                None => out.push(format!("without a {} component", now.name)),
                Some(old) if old.hash != now.hash => {
                    let values = if old.summary != now.summary
                        && !old.summary.is_empty()
                        && !now.summary.is_empty()
                    {
                        format!("{} vs {} now; ", old.summary, now.summary)
                    } else {
                        String::new()
                    };
                    out.push(format!(
                        "for another {} ({values}hash {} vs {})",
                        now.name,
                        short(old.hash),
                        short(now.hash)
                    ))
                }
                Some(_) => {}
            }
        }
        for old in &saved.components {
            if self.get(&old.name).is_none() {
                out.push(format!("with a {} component this run lacks", old.name));
            }
        }
        (!out.is_empty()).then(|| out.join(", and "))
    }
}

/// The refusal of a checkpoint written for something else.
pub fn mismatch_error(path: &Path, differences: &str) -> String {
    let dir = path
        .parent()
        .map_or(String::new(), |d| d.display().to_string());
    format!(
        "{} was written {differences}; delete {dir} or choose another output directory to start afresh, or resume with the options it was written with",
        path.display()
    )
}

/// The envelope around `body` (module doc).
pub fn encode<T: Serialize>(kind: Kind, identity: &Identity, body: &T) -> Result<Vec<u8>, String> {
    let payload = postcard::to_stdvec(&(identity, body)).map_err(|e| e.to_string())?;
    let mut bytes = Vec::with_capacity(payload.len() + 29);
    bytes.extend_from_slice(&MAGIC);
    bytes.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    bytes.push(kind as u8);
    bytes.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&payload);
    let sum = fnv1a(&bytes);
    bytes.extend_from_slice(&sum.to_le_bytes());
    Ok(bytes)
}

/// The identity and body of a checkpoint file's bytes, or why they are not one (the
/// message names `path`).
pub fn decode<T: DeserializeOwned>(
    path: &Path,
    bytes: &[u8],
    kind: Kind,
) -> Result<(Identity, T), String> {
    check_envelope(path, bytes, kind)?;
    let end = bytes.len() - 8;
    let (value, rest) = postcard::take_from_bytes::<(Identity, T)>(&bytes[HEAD..end])
        .map_err(|e| format!("{}: unreadable checkpoint ({e})", path.display()))?;
    if !rest.is_empty() {
        return Err(format!(
            "{}: unreadable checkpoint ({} bytes left over)",
            path.display(),
            rest.len()
        ));
    }
    Ok(value)
}

/// The envelope's header length: magic, version, kind, body length.
const HEAD: usize = 8 + 4 + 1 + 8;

/// Magic number, version, kind, length and checksum of a checkpoint file's bytes.
fn check_envelope(path: &Path, bytes: &[u8], kind: Kind) -> Result<(), String> {
    let p = path.display();
    if bytes.len() < 8 || bytes[..8] != MAGIC {
        return Err(format!(
            "{p}: not an Umbra fit checkpoint (no magic number {:?}; written by an older version or not a checkpoint); delete it",
            std::str::from_utf8(&MAGIC).unwrap_or_default()
        ));
    }
    if bytes.len() < HEAD + 8 {
        return Err(format!(
            "{p}: truncated checkpoint ({} bytes, shorter than its header)",
            bytes.len()
        ));
    }
    let version = u32::from_le_bytes(bytes[8..12].try_into().unwrap_or_default());
    if version != FORMAT_VERSION {
        return Err(format!(
            "{p}: checkpoint format version {version}, this build reads version {FORMAT_VERSION}; delete it or resume with the version that wrote it"
        ));
    }
    if bytes[12] != kind as u8 {
        return Err(format!("{p}: not {} (kind {})", kind.name(), bytes[12]));
    }
    let len = u64::from_le_bytes(bytes[13..21].try_into().unwrap_or_default());
    let want = (HEAD as u64).saturating_add(len).saturating_add(8);
    if bytes.len() as u64 != want {
        return Err(format!(
            "{p}: truncated or corrupt checkpoint ({} bytes, its header says {want})",
            bytes.len()
        ));
    }
    let end = bytes.len() - 8;
    let sum = u64::from_le_bytes(bytes[end..].try_into().unwrap_or_default());
    if fnv1a(&bytes[..end]) != sum {
        return Err(format!(
            "{p}: corrupt checkpoint (its checksum does not match its contents)"
        ));
    }
    Ok(())
}

/// The identity alone of a checkpoint file (the envelope checked in full; the body,
/// whose type the caller may not know, not decoded).
pub fn read_identity(path: &Path, kind: Kind) -> Result<Identity, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    check_envelope(path, &bytes, kind)?;
    postcard::take_from_bytes::<Identity>(&bytes[HEAD..bytes.len() - 8])
        .map(|(identity, _)| identity)
        .map_err(|e| format!("{}: unreadable checkpoint ({e})", path.display()))
}

/// Reads and decodes a checkpoint file (I/O errors name the file).
pub fn read<T: DeserializeOwned>(path: &Path, kind: Kind) -> Result<(Identity, T), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    decode(path, &bytes, kind)
}

/// Something loaded from a checkpoint that must hold finite numbers only.
pub trait CheckFinite {
    /// The first non-finite value, described, or `None`.
    fn non_finite(&self) -> Option<String>;
}

/// The first non-finite entry of `values`, as `what[i] = v`.
pub fn first_non_finite(what: &str, values: &[f64]) -> Option<String> {
    values
        .iter()
        .position(|v| !v.is_finite())
        .map(|i| format!("{what}[{i}] = {}", values[i]))
}

impl CheckFinite for State {
    fn non_finite(&self) -> Option<String> {
        let vectors = [
            ("parameters", self.get_param()),
            ("best parameters", self.get_best_param()),
            ("gradient", self.get_gradient()),
        ];
        vectors
            .iter()
            .find_map(|(what, v)| v.and_then(|v| first_non_finite(what, v)))
            .or_else(|| {
                (!self.get_cost().is_finite()).then(|| format!("cost = {}", self.get_cost()))
            })
    }
}

impl CheckFinite for LossRecord {
    fn non_finite(&self) -> Option<String> {
        first_non_finite(
            &format!("loss history (iteration {}): cost", self.iteration),
            &[self.cost, self.data_loss, self.smoothness],
        )
    }
}

pub use crate::atomic::{
    remove_stale_temporaries, remove_stale_temporaries_of, write_atomic, write_file_atomic,
};

/// One recorded iteration of the fit.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LossRecord {
    /// Iteration over the whole fit (all stages).
    pub iteration: u64,
    pub stage: usize,
    /// Total cost (data + regularisation).
    pub cost: f64,
    pub data_loss: f64,
    /// The regularisation: the Laplacian smoothness term plus the albedo's total
    /// variation ([`crate::problem::Breakdown`] has them apart).
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

/// argmin checkpoint to one file, written atomically, stamped with the fit's
/// [`Identity`]; loading refuses another identity, a damaged file and non-finite values.
pub struct SolverCheckpoint {
    pub path: PathBuf,
    pub every: u64,
    pub history: History,
    pub identity: Identity,
}

impl<S> Checkpoint<S, State> for SolverCheckpoint
where
    S: Serialize + DeserializeOwned + CheckFinite,
{
    fn save(&self, solver: &S, state: &State) -> Result<(), Error> {
        let history = self.history.borrow();
        let saved = SavedRef {
            solver,
            state,
            history: &history,
        };
        let bytes = encode(Kind::Solver, &self.identity, &saved).map_err(Error::msg)?;
        write_atomic(&self.path, &bytes).map_err(|e| {
            Error::msg(format!(
                "{}: cannot write checkpoint: {e}",
                self.path.display()
            ))
        })
    }

    fn load(&self) -> Result<Option<(S, State)>, Error> {
        if !self.path.exists() {
            return Ok(None);
        }
        let (identity, saved): (Identity, Saved<S, State>) =
            read(&self.path, Kind::Solver).map_err(Error::msg)?;
        if let Some(d) = self.identity.differences(&identity) {
            return Err(Error::msg(mismatch_error(&self.path, &d)));
        }
        let bad = saved
            .solver
            .non_finite()
            .or_else(|| saved.state.non_finite())
            .or_else(|| saved.history.iter().find_map(|r| r.non_finite()));
        if let Some(what) = bad {
            return Err(Error::msg(format!(
                "{}: corrupt checkpoint: {what} is not finite; delete it",
                self.path.display()
            )));
        }
        *self.history.borrow_mut() = saved.history;
        Ok(Some((saved.solver, saved.state)))
    }

    fn frequency(&self) -> CheckpointingFrequency {
        CheckpointingFrequency::Every(self.every.max(1))
    }
}
