//! The output folder of `slam run`, written as one set: a run writes its files into a new
//! folder beside `--out`, and only a complete set replaces the previous one.
//!
//! On Unix, `--out DIR` is a symbolic link to the current set, `.DIR.set-<id>` in the same
//! folder. A run
//! 1. checks that `DIR` can be replaced (absent, a link to a set, an empty folder, or a folder
//!    of a former run's outputs) and creates `.DIR.set-<id>` before the run starts, so that an
//!    unwritable `--out` is an error before any work;
//! 2. writes every output into it;
//! 3. points a new link at it and renames that link onto `DIR` (one atomic rename), then
//!    removes the previous set.
//!
//! So whenever the process is killed, `DIR` holds either the previous complete set or the new
//! complete one: **read `DIR`, never a `.DIR.set-*` folder.** Leftover sets of killed runs are
//! removed by the next run. (When `DIR` is still a plain folder, from before this layout, the
//! first run moves it aside first: only then is there a moment without `DIR`. Elsewhere than
//! on Unix there are no links, and `DIR` is replaced by two renames.)

use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use crate::error::{CliError, Result};

/// The files and folders a run writes at the top of its set (stages add folders holding a
/// `metrics.json`).
const OUTPUT_FILES: [&str; 11] = [
    "trajectory.tum",
    "map_path.tum",
    "map.json",
    "estimates.csv",
    "metrics.json",
    "map.svg",
    "map.png",
    "map.pgm",
    "map.yaml",
    "graph.g2o",
    "run.mcap",
];

/// A set being written (see the module documentation); dropped before
/// [`commit`](OutputSet::commit), it removes its folder.
#[derive(Debug)]
pub struct OutputSet {
    /// `--out`.
    dir: PathBuf,
    /// The folder the new set is written into.
    set: PathBuf,
    /// Whether the set was made the current one.
    committed: bool,
}

impl Drop for OutputSet {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.set);
        }
    }
}

fn output_error(path: &Path, source: std::io::Error) -> CliError {
    CliError::Output {
        path: path.to_path_buf(),
        source,
    }
}

/// The folder holding `dir` and the name of `dir`.
fn parent_and_name(dir: &Path) -> Result<(PathBuf, String)> {
    let name = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .filter(|n| !n.is_empty() && n != "." && n != "..")
        .ok_or_else(|| {
            CliError::Usage(format!(
                "--out {}: name a folder of its own (e.g. {}/slam-out): the outputs replace it \
                 as a whole",
                dir.display(),
                dir.display()
            ))
        })?;
    let parent = match dir.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    Ok((parent, name))
}

/// A name no other run uses: the process id and the time.
fn unique() -> String {
    let nanos = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    format!("{}-{nanos}", std::process::id())
}

impl OutputSet {
    /// Checks that `dir` can be replaced by a new set and creates the folder of the set.
    pub fn prepare(dir: &Path) -> Result<Self> {
        let (parent, name) = parent_and_name(dir)?;
        std::fs::create_dir_all(&parent).map_err(|e| output_error(&parent, e))?;
        check_replaceable(dir)?;
        remove_stale_sets(&parent, &name, dir);
        let set = parent.join(format!(".{name}.set-{}", unique()));
        std::fs::create_dir(&set).map_err(|e| output_error(dir, e))?;
        Ok(OutputSet {
            dir: dir.to_path_buf(),
            set,
            committed: false,
        })
    }

    /// The folder to write the outputs into.
    pub fn path(&self) -> &Path {
        &self.set
    }

    /// Makes the written set the one `--out` holds, and removes the previous one.
    pub fn commit(mut self) -> Result<()> {
        let (parent, name) = parent_and_name(&self.dir)?;
        let previous = previous_set(&self.dir);
        let aside = match std::fs::symlink_metadata(&self.dir) {
            Ok(m) if m.is_dir() => {
                // A plain folder (an earlier layout, or made by hand): moved aside first.
                let aside = parent.join(format!(".{name}.set-old-{}", unique()));
                std::fs::rename(&self.dir, &aside).map_err(|e| output_error(&self.dir, e))?;
                Some(aside)
            }
            _ => None,
        };
        swap_in(&self.set, &self.dir, &parent, &name)?;
        self.committed = true;
        for old in previous.into_iter().chain(aside) {
            let _ = std::fs::remove_dir_all(old);
        }
        Ok(())
    }
}

/// Points `dir` at `set` in one rename (Unix: a link renamed over the old link).
#[cfg(unix)]
fn swap_in(set: &Path, dir: &Path, parent: &Path, name: &str) -> Result<()> {
    let link = parent.join(format!(".{name}.link-{}", unique()));
    let target = set.file_name().map(PathBuf::from).unwrap_or_default();
    std::os::unix::fs::symlink(&target, &link).map_err(|e| output_error(dir, e))?;
    std::fs::rename(&link, dir).map_err(|e| {
        let _ = std::fs::remove_file(&link);
        output_error(dir, e)
    })
}

/// Renames `set` to `dir` (`dir` was moved aside or removed before).
#[cfg(not(unix))]
fn swap_in(set: &Path, dir: &Path, _: &Path, _: &str) -> Result<()> {
    if std::fs::symlink_metadata(dir).is_ok() {
        let _ = std::fs::remove_file(dir);
    }
    std::fs::rename(set, dir).map_err(|e| output_error(dir, e))
}

/// The set folder `dir` links to now, if it is a link to one.
fn previous_set(dir: &Path) -> Option<PathBuf> {
    let target = std::fs::read_link(dir).ok()?;
    let name = target.file_name()?.to_string_lossy().into_owned();
    let (parent, own) = parent_and_name(dir).ok()?;
    name.starts_with(&format!(".{own}.set-"))
        .then(|| parent.join(name))
}

/// An error unless `dir` is absent, a link, an empty folder or a folder of a run's outputs.
fn check_replaceable(dir: &Path) -> Result<()> {
    let metadata = match std::fs::symlink_metadata(dir) {
        Ok(m) => m,
        Err(_) => return Ok(()),
    };
    if metadata.file_type().is_symlink() {
        return Ok(());
    }
    if !metadata.is_dir() {
        return Err(CliError::Usage(format!(
            "--out {} is a file: give a folder for the outputs",
            dir.display()
        )));
    }
    let entries = std::fs::read_dir(dir).map_err(|e| output_error(dir, e))?;
    for entry in entries {
        let entry = entry.map_err(|e| output_error(dir, e))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        let known = OUTPUT_FILES.contains(&name.as_str())
            || name.ends_with(".partial")
            || entry.path().join("metrics.json").is_file();
        if !known {
            return Err(CliError::Usage(format!(
                "--out {} holds `{name}`, which is not an output of slam run: the outputs \
                 replace the folder as a whole, so give a new or empty folder (or a former \
                 output folder)",
                dir.display()
            )));
        }
    }
    Ok(())
}

/// Removes the sets of `name` in `parent` that `dir` does not link to (left by killed runs).
fn remove_stale_sets(parent: &Path, name: &str, dir: &Path) {
    let current = previous_set(dir);
    let Ok(entries) = std::fs::read_dir(parent) else {
        return;
    };
    let prefixes = [format!(".{name}.set-"), format!(".{name}.link-")];
    for entry in entries.flatten() {
        let file = entry.file_name().to_string_lossy().into_owned();
        let path = entry.path();
        if !prefixes.iter().any(|p| file.starts_with(p)) {
            continue;
        }
        if current
            .as_ref()
            .is_some_and(|c| c.file_name() == path.file_name())
        {
            continue;
        }
        let _ = std::fs::remove_dir_all(&path).or_else(|_| std::fs::remove_file(&path));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_set(dir: &Path, text: &str) {
        let set = OutputSet::prepare(dir).unwrap();
        std::fs::write(set.path().join("metrics.json"), text).unwrap();
        set.commit().unwrap();
    }

    #[test]
    fn a_set_replaces_the_previous_one_as_a_whole() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("out");
        write_set(&dir, "1");
        write_set(&dir, "2");
        assert_eq!(
            std::fs::read_to_string(dir.join("metrics.json")).unwrap(),
            "2"
        );
        // A run killed while writing leaves its set; the next one removes it.
        let killed = OutputSet::prepare(&dir).unwrap();
        std::fs::write(killed.path().join("metrics.json"), "partial").unwrap();
        assert_eq!(
            std::fs::read_to_string(dir.join("metrics.json")).unwrap(),
            "2"
        );
        write_set(&dir, "3");
        let names: Vec<String> = std::fs::read_dir(root.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names.len(), 2, "{names:?}"); // out and its one set
        assert_eq!(
            std::fs::read_to_string(dir.join("metrics.json")).unwrap(),
            "3"
        );
    }

    #[test]
    fn a_plain_output_folder_is_replaced_and_a_foreign_one_refused() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("old");
        std::fs::create_dir(&dir).unwrap();
        std::fs::write(dir.join("metrics.json"), "old").unwrap();
        write_set(&dir, "new");
        assert_eq!(
            std::fs::read_to_string(dir.join("metrics.json")).unwrap(),
            "new"
        );
        let foreign = root.path().join("home");
        std::fs::create_dir(&foreign).unwrap();
        std::fs::write(foreign.join("thesis.tex"), "mine").unwrap();
        let e = OutputSet::prepare(&foreign).unwrap_err().to_string();
        assert!(e.contains("thesis.tex"), "{e}");
        assert!(OutputSet::prepare(Path::new(".")).is_err());
    }

    #[cfg(unix)]
    #[test]
    fn an_unwritable_out_is_an_error_before_the_run() {
        use std::os::unix::fs::PermissionsExt;
        let root = tempfile::tempdir().unwrap();
        let file = root.path().join("file");
        std::fs::write(&file, "").unwrap();
        let e = OutputSet::prepare(&file.join("out"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("file"), "{e}");
        let locked = root.path().join("locked");
        std::fs::create_dir(&locked).unwrap();
        std::fs::set_permissions(&locked, std::fs::Permissions::from_mode(0o500)).unwrap();
        let probe = locked.join("probe");
        if std::fs::create_dir(&probe).is_ok() {
            // Root ignores permissions: nothing to test here.
            return;
        }
        let e = OutputSet::prepare(&locked.join("out"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("locked"), "{e}");
    }
}
