//! Scene files: the TOML contract of `DESIGN.md`, parsed strictly.
//!
//! Unknown keys are rejected with the key's name and line; every value out of
//! range is rejected with its key, line and allowed range. Relative paths are
//! resolved against the scene file's folder.

mod render;
mod run;
mod spec;

pub use render::render_run;
pub use run::{resume_run, run_scene, Run, RunOptions, CHECKPOINT_FILE};
pub use spec::*;

use std::path::{Path, PathBuf};

use thiserror::Error;

use crate::param::ParamError;

/// A scene that cannot be read or run.
#[derive(Debug, Error)]
pub enum SceneError {
    /// The scene file could not be read.
    #[error("{}: {source}", .path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The TOML is malformed, has an unknown key or a value of the wrong type.
    #[error("{}:{line}: {message}", .path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// The line (1-based).
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// A value is out of its allowed range.
    #[error("{}:{line}: {key} = {value}: {allowed}", .path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// The line (1-based).
        line: usize,
        /// The scene key (dotted path).
        key: String,
        /// The rejected value.
        value: String,
        /// What is allowed.
        allowed: String,
    },
    /// A checkpoint could not be written or read.
    #[error(transparent)]
    Checkpoint(Box<crate::checkpoint::CheckpointError>),
    /// A run guard fired (or a step's solve failed): the run stopped at
    /// its last good state, whose frame and checkpoint are in `dir`.
    #[error("{}: run stopped: {diagnosis}; the last good state (step {last_good_step}) is in {} as its frame and {}", .path.display(), .dir.display(), run::CHECKPOINT_FILE)]
    Stopped {
        /// The scene file.
        path: PathBuf,
        /// What fired: step, quantity and bound, elements and nodes.
        diagnosis: String,
        /// The last step whose state passed the guards.
        last_good_step: usize,
        /// The output folder.
        dir: PathBuf,
    },
    /// The engine failed while building or running the scene.
    #[error("{}: {source}", .path.display())]
    Engine {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: Box<crate::Error>,
    },
}

/// A parsed scene with the file it came from.
#[derive(Clone, Debug)]
pub struct LoadedScene {
    /// The scene file.
    pub path: PathBuf,
    /// The scene's text (for locating keys in error messages).
    pub text: String,
    /// The parsed scene.
    pub scene: Scene,
}

impl LoadedScene {
    /// Reads, parses and range-checks a scene file.
    pub fn load(path: &Path) -> Result<Self, SceneError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| SceneError::Read { path: path.to_path_buf(), source })?;
        Self::parse(path, text)
    }

    /// Parses and range-checks scene text; `path` names it in errors and
    /// anchors relative paths.
    pub fn parse(path: &Path, text: String) -> Result<Self, SceneError> {
        let scene: Scene = toml::from_str(&text).map_err(|e| {
            let line = e.span().map_or(1, |s| line_of_offset(&text, s.start));
            SceneError::Parse { path: path.to_path_buf(), line, message: e.message().trim().to_string() }
        })?;
        let loaded = LoadedScene { path: path.to_path_buf(), text, scene };
        loaded.scene.check(&loaded)?;
        Ok(loaded)
    }

    /// Resolves a path written in the scene against the scene's folder.
    pub fn resolve(&self, p: &str) -> PathBuf {
        let p = Path::new(p);
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            self.path.parent().unwrap_or(Path::new(".")).join(p)
        }
    }

    /// Line of `key` (a dotted path such as `material.young` or
    /// `fixed.1.box`) in the scene text: the line where its last component
    /// is assigned inside the right table, or the table header, or 1.
    pub fn line_of(&self, key: &str) -> usize {
        locate_key(&self.text, key)
    }

    pub(crate) fn invalid(&self, key: &str, value: impl std::fmt::Display, allowed: &str) -> SceneError {
        SceneError::Invalid {
            path: self.path.clone(),
            line: self.line_of(key),
            key: key.to_string(),
            value: value.to_string(),
            allowed: allowed.to_string(),
        }
    }

    /// The engine's [`ParamError`] as an error at scene key `key`.
    pub(crate) fn param(&self, key: &str, e: ParamError) -> SceneError {
        self.invalid(key, e.value, &e.allowed)
    }
}

fn line_of_offset(text: &str, offset: usize) -> usize {
    text.as_bytes()[..offset.min(text.len())].iter().filter(|&&b| b == b'\n').count() + 1
}

/// Finds the line of a dotted key: `section[.index].name`.
fn locate_key(text: &str, key: &str) -> usize {
    let parts: Vec<&str> = key.split('.').collect();
    let (section, index, name) = match parts.as_slice() {
        [s] => (*s, None, None),
        [s, i, n, ..] if i.parse::<usize>().is_ok() => (*s, i.parse::<usize>().ok(), Some(*n)),
        [s, i] if i.parse::<usize>().is_ok() => (*s, i.parse::<usize>().ok(), None),
        [s, n, ..] => (*s, None, Some(*n)),
        [] => return 1,
    };
    let mut in_section = false;
    let mut seen = 0usize;
    let mut header_line = 1;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.starts_with('[') {
            let name_in = line.trim_matches(|c| c == '[' || c == ']').trim();
            in_section = false;
            if name_in == section {
                match index {
                    Some(want) => {
                        if seen == want {
                            in_section = true;
                            header_line = i + 1;
                        }
                        seen += 1;
                    }
                    None => {
                        in_section = true;
                        header_line = i + 1;
                    }
                }
            }
            continue;
        }
        if in_section {
            if let Some(n) = name {
                let lhs = line.split('=').next().unwrap_or("").trim();
                if lhs == n {
                    return i + 1;
                }
            }
        }
    }
    header_line
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn locate_keys() {
        let text = "[mesh]\nfile = \"a.mesh\"\n\n[material]\nyoung = -1\npoisson = 0.3\n[[fixed]]\nbox = {}\n[[fixed]]\n\nbox = {}\n";
        assert_eq!(locate_key(text, "material.young"), 5);
        assert_eq!(locate_key(text, "material.poisson"), 6);
        assert_eq!(locate_key(text, "fixed.1.box"), 11);
        assert_eq!(locate_key(text, "fixed.0"), 7);
        assert_eq!(locate_key(text, "material.density"), 4);
    }
}
