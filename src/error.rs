//! One error type for the library. Every user-facing error names its file and, where
//! known, the field or line: "scene.toml: film.bin_width_opl: must be > 0, got -1".

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Something wrong with a whole file (unknown format, unreadable, empty).
    #[error("{}: {msg}", file.display())]
    Scene { file: PathBuf, msg: String },
    /// A bad value in a named field of a scene.
    #[error("{}: {field}: {msg}", file.display())]
    Field {
        file: PathBuf,
        field: String,
        msg: String,
    },
    /// A parse error at a line of a text file (XML, OBJ, TOML).
    #[error("{}:{line}: {msg}", file.display())]
    Line {
        file: PathBuf,
        line: usize,
        msg: String,
    },
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A request the renderer cannot honour (model not available, bad option value).
    #[error("{0}")]
    Invalid(String),
    /// The user interrupted a render.
    #[error("interrupted")]
    Cancelled,
}

pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    pub fn scene(file: &Path, msg: impl Into<String>) -> Self {
        Error::Scene {
            file: file.to_path_buf(),
            msg: msg.into(),
        }
    }
    pub fn field(file: &Path, field: &str, msg: impl Into<String>) -> Self {
        Error::Field {
            file: file.to_path_buf(),
            field: field.to_string(),
            msg: msg.into(),
        }
    }
    pub fn line(file: &Path, line: usize, msg: impl Into<String>) -> Self {
        Error::Line {
            file: file.to_path_buf(),
            line,
            msg: msg.into(),
        }
    }
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Error::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}
