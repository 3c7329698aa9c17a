//! Relative file names as Mitsuba 3's file resolver finds them. Measured with Mitsuba
//! 3.9.1 (`mi.load_file`): the resolver starts with the current working directory;
//! loading a file prepends the file's folder; each `<path value=".."/>` in the scene
//! prepends its folder (a relative one found through the resolver), so it is searched
//! first. A relative name is the first `folder/name` that exists. y-tal relies on the
//! working directory: it writes mesh names relative to where `tal render` runs
//! (`../meshes/Z.obj`) and puts the XML one folder deeper.

use std::path::{Path, PathBuf};

/// The folders searched for a relative file name, in order, each with what it is.
#[derive(Clone, Debug)]
pub(crate) struct Resolver {
    dirs: Vec<(PathBuf, String)>,
}

impl Resolver {
    /// The XML's folder, then `cwd` (if known).
    pub fn new(xml_dir: &Path, cwd: Option<&Path>) -> Self {
        // Absolute, so that messages say where (an XML named without a folder has "").
        let dir = if xml_dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            xml_dir
        };
        let xml_dir = std::path::absolute(dir).unwrap_or_else(|_| dir.to_path_buf());
        let mut dirs = vec![(xml_dir, "the XML file's folder".to_string())];
        if let Some(c) = cwd {
            dirs.push((c.to_path_buf(), "the current working directory".to_string()));
        }
        Resolver { dirs }
    }

    /// Mitsuba's `<path value="..">`: `dir` is searched before everything else.
    /// `Err` lists the places searched for a relative `dir` that exists nowhere.
    pub fn prepend(&mut self, dir: &str, line: usize) -> std::result::Result<(), String> {
        let p = Path::new(dir);
        let found = if p.is_absolute() {
            p.is_dir().then(|| p.to_path_buf())
        } else {
            self.dirs
                .iter()
                .map(|(d, _)| d.join(p))
                .find(|c| c.is_dir())
        };
        let Some(found) = found else {
            return Err(format!(
                "<path value=\"{dir}\">: no such folder (looked for {})",
                self.searched(dir)
            ));
        };
        self.dirs
            .insert(0, (found, format!("the <path> at line {line}")));
        Ok(())
    }

    /// The file `name` names; `Err` lists every place searched.
    pub fn resolve(&self, name: &str) -> std::result::Result<PathBuf, String> {
        let p = Path::new(name);
        if p.is_absolute() {
            return if p.is_file() {
                Ok(p.to_path_buf())
            } else {
                Err(format!("'{name}' does not exist"))
            };
        }
        self.dirs
            .iter()
            .map(|(d, _)| d.join(p))
            .find(|c| c.is_file())
            .ok_or_else(|| {
                format!(
                    "'{name}' not found: looked for {} (Mitsuba's search order)",
                    self.searched(name)
                )
            })
    }

    fn searched(&self, name: &str) -> String {
        self.dirs
            .iter()
            .map(|(d, what)| format!("'{}' ({what})", d.join(name).display()))
            .collect::<Vec<_>>()
            .join(", then ")
    }
}
