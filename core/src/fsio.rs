//! Atomic file output: the content goes to a temporary file beside the target, is flushed to
//! disk, then renamed over the target, so a failure (a full disk, a killed process) never
//! leaves a half-written results, measurement or model file: the reader sees the old file or
//! the new one. A symbolic link is written through (the file it points to is replaced, the link
//! stays), an existing file keeps its permissions, and a target that is not a regular file (a
//! device, a pipe) is written directly. [`check_not_an_input`] refuses an output path that names
//! one of the command's inputs.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// Temporary files being written now (removed by [`remove_temporaries`] on an interrupt).
static TEMPORARIES: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

fn register(tmp: &Path, on: bool) {
    let mut list = TEMPORARIES.lock().unwrap_or_else(|e| e.into_inner());
    if on {
        list.push(tmp.to_path_buf());
    } else {
        list.retain(|p| p != tmp);
    }
}

/// Removes the temporary files of writes under way: for a program's interrupt handler (the
/// `volver` CLI calls it on Ctrl-C and SIGTERM), so that an interrupted write leaves neither a
/// half-written target nor a hidden temporary file.
pub fn remove_temporaries() {
    let list = TEMPORARIES.lock().unwrap_or_else(|e| e.into_inner());
    for p in list.iter() {
        let _ = std::fs::remove_file(p);
    }
}

/// Removes temporary files beside `target` left by processes that no longer run (killed
/// before they could clean up) and at least an hour old. Only where `/proc` tells which
/// processes run (Linux).
fn remove_stale(target: &Path) {
    let (Some(dir), Some(name)) = (target.parent(), target.file_name()) else {
        return;
    };
    if !Path::new("/proc/self").exists() {
        return;
    }
    let prefix = format!(".{}.", name.to_string_lossy());
    let dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let file = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = file
            .strip_prefix(&prefix)
            .and_then(|r| r.strip_suffix(".tmp"))
            .and_then(|p| p.parse::<u32>().ok())
        else {
            continue;
        };
        // Also an hour old: a process in another PID namespace (a container writing to the same
        // folder) is not in our /proc, and its write under way must not lose its file.
        let old = e
            .metadata()
            .and_then(|m| m.modified())
            .ok()
            .and_then(|t| t.elapsed().ok())
            .is_some_and(|age| age.as_secs() >= 3600);
        if pid != std::process::id() && old && !Path::new(&format!("/proc/{pid}")).exists() {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

/// Writes `contents` to `path` atomically (temporary file in the same directory, `fsync`,
/// rename). On error the temporary file is removed and `path` is untouched.
///
/// ```
/// let dir = std::env::temp_dir().join(format!("volver-fsio-doc-{}", std::process::id()));
/// std::fs::create_dir_all(&dir).unwrap();
/// let f = dir.join("out.txt");
/// volver_core::fsio::write_atomic(&f, b"one").unwrap();
/// volver_core::fsio::write_atomic(&f, b"two").unwrap();
/// assert_eq!(std::fs::read_to_string(&f).unwrap(), "two");
/// assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1); // no temporary file left
/// std::fs::remove_dir_all(&dir).unwrap();
/// ```
pub fn write_atomic(path: &Path, contents: impl AsRef<[u8]>) -> std::io::Result<()> {
    // Through a symbolic link to the file it names (every link of a chain resolved).
    let target = match std::fs::symlink_metadata(path) {
        Ok(m) if m.file_type().is_symlink() => std::fs::canonicalize(path)?,
        _ => path.to_path_buf(),
    };
    let existing = std::fs::metadata(&target).ok();
    if let Some(m) = &existing
        && !m.is_file()
    {
        if m.is_dir() {
            return Err(std::io::Error::other(format!(
                "{} is a directory",
                target.display()
            )));
        }
        // A device or a pipe: no rename over it, write to it.
        let mut f = std::fs::OpenOptions::new().write(true).open(&target)?;
        return f.write_all(contents.as_ref());
    }
    remove_stale(&target);
    let tmp = temporary_beside(&target);
    register(&tmp, true);
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(contents.as_ref())?;
        f.sync_all()?;
        drop(f);
        if let Some(m) = &existing {
            std::fs::set_permissions(&tmp, m.permissions())?;
        }
        std::fs::rename(&tmp, &target)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    register(&tmp, false);
    result
}

/// `true` when `a` and `b` name the same file (links resolved), or the same path when either
/// does not exist yet.
pub fn same_file(a: &Path, b: &Path) -> bool {
    match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(x), Ok(y)) => x == y,
        _ => a == b,
    }
}

/// Refuses an output path that names one of `inputs` (writing it would destroy the input
/// before, or while, it is read): an error naming both.
///
/// ```
/// use std::path::Path;
/// let e = volver_core::fsio::check_not_an_input(Path::new("m.csv"), &[Path::new("m.csv")]);
/// assert!(e.unwrap_err().to_string().contains("m.csv is an input"));
/// assert!(volver_core::fsio::check_not_an_input(Path::new("o.csv"), &[Path::new("m.csv")]).is_ok());
/// ```
pub fn check_not_an_input(out: &Path, inputs: &[&Path]) -> std::io::Result<()> {
    match inputs.iter().find(|i| same_file(out, i)) {
        Some(i) => Err(std::io::Error::other(format!(
            "{} is an input of this command: writing the output there would destroy it; \
             choose another output path",
            i.display()
        ))),
        None => Ok(()),
    }
}

/// `.<name>.<pid>.tmp` in the target's directory (a rename within one file system is atomic).
fn temporary_beside(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "output".into());
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("volver-fsio-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    /// A link is written through and stays a link; the file keeps its mode.
    #[cfg(unix)]
    #[test]
    fn links_are_written_through_and_modes_kept() {
        use std::os::unix::fs::{PermissionsExt, symlink};
        let d = dir("link");
        let real = d.join("real.json");
        std::fs::write(&real, "old").unwrap();
        std::fs::set_permissions(&real, std::fs::Permissions::from_mode(0o640)).unwrap();
        let link = d.join("link.json");
        symlink(&real, &link).unwrap();
        write_atomic(&link, "new").unwrap();
        assert!(
            std::fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink()
        );
        assert_eq!(std::fs::read_to_string(&real).unwrap(), "new");
        let mode = std::fs::metadata(&real).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o640);
        // A device is written to, not replaced.
        write_atomic(Path::new("/dev/null"), "x").unwrap();
        assert!(!std::fs::metadata("/dev/null").unwrap().is_file());
        std::fs::remove_dir_all(&d).unwrap();
    }

    /// A temporary file of a process that no longer runs, an hour old, is removed by the next
    /// write; one of a running process, or a recent one, is left alone.
    #[cfg(target_os = "linux")]
    #[test]
    fn stale_temporaries_are_removed() {
        let d = dir("stale");
        let target = d.join("m.csv");
        // PIDs above the kernel's limit (4 194 304) never run.
        let stale = d.join(".m.csv.4999999.tmp");
        std::fs::write(&stale, "half").unwrap();
        std::fs::write(d.join(".m.csv.1.tmp"), "init's").unwrap();
        let young = d.join(".m.csv.4999998.tmp");
        std::fs::write(&young, "another namespace's, under way").unwrap();
        let two_hours_ago = std::time::SystemTime::now() - std::time::Duration::from_secs(7200);
        for f in [&stale, &d.join(".m.csv.1.tmp")] {
            std::fs::File::options()
                .write(true)
                .open(f)
                .unwrap()
                .set_modified(two_hours_ago)
                .unwrap();
        }
        write_atomic(&target, "whole").unwrap();
        assert!(!stale.exists());
        assert!(d.join(".m.csv.1.tmp").exists(), "pid 1 runs");
        assert!(young.exists(), "less than an hour old");
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "whole");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn an_input_is_not_an_output() {
        let d = dir("input");
        let f = d.join("m.csv");
        std::fs::write(&f, "x").unwrap();
        let other = d.join(".").join("m.csv");
        assert!(check_not_an_input(&other, &[&f]).is_err());
        assert!(check_not_an_input(&d.join("o.csv"), &[&f]).is_ok());
        std::fs::remove_dir_all(&d).unwrap();
    }
}
