//! The scene schema and its loading: a scene is a description plus a list of tagged
//! tasks, so new task kinds are new variants of [`Task`] and nothing else changes.
//!
//! Loading reports a malformed file as `file:line:col: what was expected` (with the
//! nearest known name for a misspelt field or task kind), and a well-formed file with a
//! bad value as `file: task "name": item: what is wrong`. Every task is checked before
//! any runs.

use crate::tasks::{self, TaskSpec};
use serde::Deserialize;
use std::fmt;
use std::path::{Path, PathBuf};

/// A scene file as written.
#[derive(Debug, Deserialize)]
#[serde(rename = "Scene", deny_unknown_fields)]
pub struct SceneFile {
    /// One line saying what the scene shows (for `--list` and the summary).
    pub description: String,
    /// The tasks, run in order.
    pub tasks: Vec<Task>,
}

/// One task of a scene; the variant is the task kind.
#[derive(Debug, Deserialize)]
pub enum Task {
    /// Forward kinematics of a skeleton in a given pose.
    Fk(tasks::fk::FkTask),
    /// Inverse kinematics: a chain tracking targets with CCD or FABRIK.
    Ik(tasks::ik::IkTask),
    /// Analytic two-bone IK: a limb's tip following a path, with a pole and a hinge.
    TwoBone(tasks::two_bone::TwoBoneTask),
    /// Points on a curve, uniform in parameter or evenly spaced by arc length.
    Curve(tasks::curve::CurveTask),
    /// A mass-spring system stepped by an integrator.
    Cloth(tasks::cloth::ClothTask),
    /// Full-body IK: several effectors on a skeleton tree solved together over a clip.
    FullBody(tasks::full_body::FullBodyTask),
    /// Triangle-mesh cloth (grid sheets or an OBJ mesh) with self-contact.
    MeshCloth(tasks::mesh_cloth::MeshClothTask),
}

impl Task {
    /// The task's name (unique in its scene).
    #[must_use]
    pub fn name(&self) -> &str {
        match self {
            Task::Fk(t) => &t.name,
            Task::Ik(t) => &t.name,
            Task::TwoBone(t) => &t.name,
            Task::Curve(t) => &t.name,
            Task::Cloth(t) => &t.name,
            Task::FullBody(t) => &t.name,
            Task::MeshCloth(t) => &t.name,
        }
    }

    /// The task kind, as the scene file spells it (`Fk`, ...).
    #[must_use]
    pub fn kind(&self) -> &'static str {
        match self {
            Task::Fk(_) => "Fk",
            Task::Ik(_) => "Ik",
            Task::TwoBone(_) => "TwoBone",
            Task::Curve(_) => "Curve",
            Task::Cloth(_) => "Cloth",
            Task::FullBody(_) => "FullBody",
            Task::MeshCloth(_) => "MeshCloth",
        }
    }

    /// The task's behaviour, whatever its kind.
    pub fn spec(&self) -> &dyn TaskSpec {
        match self {
            Task::Fk(t) => t,
            Task::Ik(t) => t,
            Task::TwoBone(t) => t,
            Task::Curve(t) => t,
            Task::Cloth(t) => t,
            Task::FullBody(t) => t,
            Task::MeshCloth(t) => t,
        }
    }
}

/// A scene read and checked: every task's values are valid and the task names are
/// unique. [`Scene::run`] runs it.
#[derive(Debug)]
pub struct Scene {
    /// The file it came from.
    pub path: PathBuf,
    /// The scene's name: the file stem.
    pub name: String,
    /// One line saying what the scene shows.
    pub description: String,
    /// The tasks, run in order.
    pub tasks: Vec<Task>,
}

/// Why a scene could not be loaded.
#[derive(Debug)]
pub enum SceneError {
    /// The file could not be read.
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's message.
        message: String,
    },
    /// The file is not a valid scene (syntax or schema); with its position.
    Parse {
        /// The file.
        path: PathBuf,
        /// The line of the offending text, from 1.
        line: usize,
        /// The column of the offending text, from 1.
        col: usize,
        /// What was expected (with the nearest known name for a misspelt one).
        message: String,
    },
    /// A value is out of range or inconsistent.
    Invalid {
        /// The file.
        path: PathBuf,
        /// The task's name.
        task: String,
        /// The offending item and what is allowed.
        message: String,
    },
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Io { path, message } => write!(f, "{}: {message}", path.display()),
            Self::Parse {
                path,
                line,
                col,
                message,
            } => write!(f, "{}:{line}:{col}: {message}", path.display()),
            Self::Invalid {
                path,
                task,
                message,
            } => write!(f, "{}: task \"{task}\": {message}", path.display()),
        }
    }
}

impl std::error::Error for SceneError {}

/// The scene's name: the file stem.
pub fn scene_name(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene".to_string())
}

impl Scene {
    /// Reads, parses and checks a scene file.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Scene, SceneError> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|e| SceneError::Io {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        Scene::from_bytes(path, &bytes)
    }

    /// Parses and checks the bytes of a scene file: text that is not UTF-8 is an error
    /// at the line and column of its first bad byte, as a syntax error is.
    pub fn from_bytes(path: impl AsRef<Path>, bytes: &[u8]) -> Result<Scene, SceneError> {
        let path = path.as_ref();
        match std::str::from_utf8(bytes) {
            Ok(text) => Scene::from_text(path, text),
            Err(e) => {
                let good = &bytes[..e.valid_up_to()];
                let line = 1 + good.iter().filter(|&&b| b == b'\n').count();
                let line_start = good.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
                // Columns count characters, as the parser's do.
                let col = 1 + String::from_utf8_lossy(&good[line_start..]).chars().count();
                Err(SceneError::Parse {
                    path: path.to_path_buf(),
                    line,
                    col,
                    message: "the file is not UTF-8 text (a byte that no character begins with)"
                        .into(),
                })
            }
        }
    }

    /// Parses and checks scene text; `path` names it in errors and gives the scene's
    /// name (its file stem).
    pub fn from_text(path: impl AsRef<Path>, text: &str) -> Result<Scene, SceneError> {
        let path = path.as_ref();
        let mut file = parse(path, text)?;
        // Files a task reads are named relative to the scene file.
        let dir = path.parent().unwrap_or(Path::new(""));
        for task in &mut file.tasks {
            match task {
                Task::FullBody(t) => t.base_dir = dir.to_path_buf(),
                Task::MeshCloth(t) => t.base_dir = dir.to_path_buf(),
                Task::Cloth(t) => t.base_dir = dir.to_path_buf(),
                _ => {}
            }
        }
        for task in &file.tasks {
            task.spec()
                .validate()
                .map_err(|message| SceneError::Invalid {
                    path: path.to_path_buf(),
                    task: task.name().to_string(),
                    message,
                })?;
        }
        let mut seen = std::collections::HashSet::new();
        for task in &file.tasks {
            let name = task.name();
            if !seen.insert(name) {
                return Err(SceneError::Invalid {
                    path: path.to_path_buf(),
                    task: name.to_string(),
                    message:
                        "another task has the same name (names must be unique: they name outputs)"
                            .into(),
                });
            }
        }
        Ok(Scene {
            path: path.to_path_buf(),
            name: scene_name(path),
            description: file.description,
            tasks: file.tasks,
        })
    }
}

/// Parses scene text; errors carry the position and, for misspelt names, a suggestion.
pub fn parse(path: &Path, text: &str) -> Result<SceneFile, SceneError> {
    let options = ron::Options::default().with_default_extension(
        ron::extensions::Extensions::IMPLICIT_SOME
            | ron::extensions::Extensions::UNWRAP_VARIANT_NEWTYPES,
    );
    options
        .from_str::<SceneFile>(text)
        .map_err(|e| SceneError::Parse {
            path: path.to_path_buf(),
            line: e.span.start.line,
            col: e.span.start.col,
            message: describe_ron_error(&e.code),
        })
}

fn describe_ron_error(code: &ron::Error) -> String {
    let suggestion = match code {
        ron::Error::NoSuchStructField {
            expected, found, ..
        }
        | ron::Error::NoSuchEnumVariant {
            expected, found, ..
        } => nearest(found, expected),
        _ => None,
    };
    match suggestion {
        Some(s) => format!("{code} (did you mean `{s}`?)"),
        None => code.to_string(),
    }
}

/// The known name closest to `found` by edit distance, if it is close enough to be a typo.
fn nearest<'a>(found: &str, known: &[&'a str]) -> Option<&'a str> {
    known
        .iter()
        .map(|k| (edit_distance(&found.to_lowercase(), &k.to_lowercase()), *k))
        .filter(|&(d, k)| d <= 2.max(k.len() / 3))
        .min_by_key(|&(d, _)| d)
        .map(|(_, k)| k)
}

fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut diagonal = row[0];
        row[0] = i + 1;
        for (j, &cb) in b.iter().enumerate() {
            let substitute = diagonal + usize::from(ca != cb);
            diagonal = row[j + 1];
            row[j + 1] = substitute.min(row[j] + 1).min(diagonal + 1);
        }
    }
    row[b.len()]
}

/// Every `*.ron` file directly in `dir`, sorted, with its description (the first line of
/// a failed parse is reported in place of a description).
pub fn list_scenes(dir: &Path) -> Result<Vec<(PathBuf, String)>, String> {
    let entries = std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && p.extension().is_some_and(|x| x == "ron"))
        .collect();
    files.sort();
    Ok(files
        .into_iter()
        .map(|p| {
            let description = match std::fs::read_to_string(&p) {
                Ok(text) => match parse(&p, &text) {
                    Ok(scene) => scene.description,
                    Err(e) => format!("(invalid: {e})"),
                },
                Err(e) => format!("(unreadable: {e})"),
            };
            (p, description)
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn suggests_the_nearest_name() {
        assert_eq!(
            nearest("skeletn", &["name", "skeleton", "pose"]),
            Some("skeleton")
        );
        assert_eq!(nearest("Fkk", &["Fk", "Ik"]), Some("Fk"));
        assert_eq!(nearest("zzzzzz", &["name", "skeleton"]), None);
        assert_eq!(edit_distance("kitten", "sitting"), 3);
    }

    #[test]
    fn syntax_errors_have_line_and_column() {
        let err = parse(
            Path::new("x.ron"),
            "Scene(\n  description: \"d\",\n  tasks: [ Fk( ],\n)",
        )
        .unwrap_err();
        let text = err.to_string();
        assert!(text.starts_with("x.ron:3:"), "{text}");
    }

    #[test]
    fn bytes_that_are_not_utf8_are_located() {
        let err = Scene::from_bytes("x.ron", b"Scene(\n  descr\xC3\xA9: \xFF)").unwrap_err();
        assert_eq!(
            err.to_string(),
            "x.ron:2:11: the file is not UTF-8 text (a byte that no character begins with)"
        );
    }

    #[test]
    fn unknown_fields_suggest_the_nearest() {
        let err = parse(Path::new("x.ron"), "Scene(descripton: \"d\", tasks: [])").unwrap_err();
        let text = err.to_string();
        assert!(text.contains("did you mean `description`"), "{text}");
    }
}
