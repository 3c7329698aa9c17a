//! One error type for the library. Every user-facing error names its file and, where
//! known, the field or line: "scene.toml: film.bin_width_opl: must be > 0, got -1".

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Something wrong with a whole file (unknown format, unreadable, empty).
    #[error("{}: {}", file.display(), cut_long(msg))]
    Scene { file: PathBuf, msg: String },
    /// A bad value in a named field of a scene.
    #[error("{}: {}: {}", file.display(), cut_long(field), cut_long(msg))]
    Field {
        file: PathBuf,
        field: String,
        msg: String,
    },
    /// A parse error at a line of a text file (XML, OBJ, TOML).
    #[error("{}:{line}: {}", file.display(), cut_long(msg))]
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
    #[error("{}", cut_long(.0))]
    Invalid(String),
    /// The user interrupted a render.
    #[error("interrupted")]
    Cancelled,
}

pub type Result<T> = std::result::Result<T, Error>;

/// Longest run of non-blank characters a message shows whole (a value echoed back).
const MAX_RUN: usize = 120;
/// Longest message shown whole.
const MAX_MESSAGE: usize = 2000;

/// `msg` with every run of more than [`MAX_RUN`] non-blank characters cut to its start
/// and its length ("aaaa… (1048576 characters)"), and the whole cut in its middle past
/// [`MAX_MESSAGE`]: an error echoing a 1 MB value stays readable.
pub fn cut_long(msg: &str) -> std::borrow::Cow<'_, str> {
    let long_run = msg.split_whitespace().any(|w| w.len() > MAX_RUN);
    if !long_run && msg.len() <= MAX_MESSAGE {
        return std::borrow::Cow::Borrowed(msg);
    }
    let mut out = String::new();
    let mut rest = msg;
    while let Some(start) = rest.find(|c: char| !c.is_whitespace()) {
        out.push_str(&rest[..start]);
        rest = &rest[start..];
        let end = rest.find(char::is_whitespace).unwrap_or(rest.len());
        let run = &rest[..end];
        if run.len() > MAX_RUN {
            let keep: String = run.chars().take(40).collect();
            out.push_str(&format!("{keep}… ({} characters)", run.chars().count()));
        } else {
            out.push_str(run);
        }
        rest = &rest[end..];
    }
    out.push_str(rest);
    if out.len() > MAX_MESSAGE {
        let head: String = out.chars().take(MAX_MESSAGE / 2).collect();
        let tail: String = {
            let n = out.chars().count();
            out.chars().skip(n - MAX_MESSAGE / 4).collect()
        };
        out = format!(
            "{head} … ({} characters cut) … {tail}",
            out.chars().count() - MAX_MESSAGE * 3 / 4
        );
    }
    std::borrow::Cow::Owned(out)
}

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_values_are_cut_in_messages() {
        let v = "x".repeat(1 << 20);
        let e = Error::field(
            Path::new("s.toml"),
            "capture_type",
            format!("'{v}' is not one of single, confocal, exhaustive"),
        );
        let m = e.to_string();
        assert!(m.len() < 300, "{}", m.len());
        assert!(
            m.contains("(1048578 characters) is not one of single"),
            "{m}"
        );
        let short = Error::Invalid("spp: must be at least 1".into()).to_string();
        assert_eq!(short, "spp: must be at least 1");
        let many = Error::Invalid("ab ".repeat(100_000)).to_string();
        assert!(
            many.len() < MAX_MESSAGE + 200 && many.contains("characters cut"),
            "{}",
            many.len()
        );
    }
}
