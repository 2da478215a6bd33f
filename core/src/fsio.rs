//! Atomic file output: the content goes to a temporary file beside the target, is flushed to
//! disk, then renamed over the target, so a failure (a full disk, a killed process) never
//! leaves a half-written results, measurement or model file: the reader sees the old file or
//! the new one. A symbolic link is written through (the file it points to is replaced, the link
//! stays), an existing file keeps its permissions, and a target that is not a regular file (a
//! device, a pipe) is written directly. [`Outputs`] refuses an output path that names one of the
//! command's inputs (the same path or a link to it) or another of its outputs.

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

/// `true` when `a` and `b` name the same file: the same path once links are resolved, or (where
/// both exist, on Unix) the same device and inode, so a hard link to a file is that file. For a
/// path that does not exist yet, its longest existing ancestor is resolved and the rest
/// compared component by component.
pub fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if let (Ok(x), Ok(y)) = (std::fs::metadata(a), std::fs::metadata(b)) {
            return x.dev() == y.dev() && x.ino() == y.ino();
        }
    }
    resolved(a) == resolved(b)
}

/// `path` with every symbolic link resolved, also where the path (or the target of a dangling
/// link) does not exist yet: the longest existing ancestor canonicalised, the rest appended
/// without `.` components.
fn resolved(path: &Path) -> PathBuf {
    let mut path = path.to_path_buf();
    // A dangling link names the file a write through it would create (at most 40 links, as
    // the kernel follows).
    for _ in 0..40 {
        match std::fs::read_link(&path) {
            Ok(target) => path = path.parent().unwrap_or(Path::new("")).join(target),
            Err(_) => break,
        }
    }
    let mut rest = Vec::new();
    let mut base = path.as_path();
    loop {
        let probe = if base.as_os_str().is_empty() {
            Path::new(".")
        } else {
            base
        };
        if let Ok(c) = std::fs::canonicalize(probe) {
            let mut out = c;
            for part in rest.iter().rev() {
                out.push(part);
            }
            return out;
        }
        match (base.parent(), base.file_name()) {
            (Some(parent), Some(name)) => {
                rest.push(name.to_os_string());
                base = parent;
            }
            _ => return path.components().collect(),
        }
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
    Outputs::new(inputs.iter().copied()).claim(out).map(|_| ())
}

/// The files one run of a command reads, and those it has claimed to write: the one check every
/// command makes, before anything is written, for every file it writes (derived names such as
/// `PLAN.machine.toml` and the files of an output folder included). An output is refused when
/// it is an input (the same path, or a symbolic or hard link to it) or another output of the
/// same run; the error names both paths.
///
/// ```
/// use std::path::Path;
/// use volver_core::fsio::Outputs;
/// let mut outputs = Outputs::new([Path::new("machine.toml")]);
/// assert!(outputs.claim(Path::new("plan.csv")).is_ok());
/// let twice = outputs.claim(Path::new("./plan.csv")).unwrap_err().to_string();
/// assert!(twice.contains("another output of this command"), "{twice}");
/// assert!(outputs.claim(Path::new("machine.toml")).is_err());
/// ```
#[derive(Debug, Default)]
pub struct Outputs {
    inputs: Vec<PathBuf>,
    claimed: Vec<PathBuf>,
}

impl Outputs {
    /// The check for a run that reads `inputs`.
    pub fn new<P: AsRef<Path>>(inputs: impl IntoIterator<Item = P>) -> Outputs {
        Outputs {
            inputs: inputs
                .into_iter()
                .map(|p| p.as_ref().to_path_buf())
                .collect(),
            claimed: Vec::new(),
        }
    }

    /// Adds an input read by the run (a file named inside another input, such as a plan's
    /// machine file).
    pub fn input(&mut self, path: &Path) {
        self.inputs.push(path.to_path_buf());
    }

    /// Claims `out` for writing: an error when it is an input of the run or an output already
    /// claimed (a device such as `/dev/null` may take several outputs). Returns the path, for the caller's convenience.
    pub fn claim(&mut self, out: &Path) -> std::io::Result<PathBuf> {
        if let Some(i) = self.inputs.iter().find(|i| same_file(out, i)) {
            return Err(std::io::Error::other(format!(
                "{} is an input of this command{}: writing the output there would destroy it; \
                 choose another output path",
                i.display(),
                link_note(out, i)
            )));
        }
        // A device (`/dev/null`, a terminal) takes any number of outputs.
        let device = std::fs::metadata(out).is_ok_and(|m| !m.is_file() && !m.is_dir());
        if let Some(o) = self.claimed.iter().find(|o| !device && same_file(out, o)) {
            return Err(std::io::Error::other(format!(
                "{} is another output of this command{}: one would overwrite the other; choose \
                 distinct output paths",
                o.display(),
                link_note(out, o)
            )));
        }
        self.claimed.push(out.to_path_buf());
        Ok(out.to_path_buf())
    }

    /// Claims the files `names` inside the folder `dir`; returns their paths.
    pub fn claim_in(&mut self, dir: &Path, names: &[&str]) -> std::io::Result<Vec<PathBuf>> {
        names.iter().map(|n| self.claim(&dir.join(n))).collect()
    }
}

/// ` (as OUT)` when the two paths are spelled differently (a link, `./`, another folder name).
fn link_note(out: &Path, other: &Path) -> String {
    if out == other {
        String::new()
    } else {
        format!(" (as {})", out.display())
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

    /// A hard link, a symbolic link (also a dangling one) and a folder not yet made name the
    /// same file as their target; two outputs of one run may not be one file.
    #[cfg(unix)]
    #[test]
    fn links_and_repeated_outputs_are_refused() {
        let d = dir("outputs");
        let input = d.join("machine.toml");
        std::fs::write(&input, "x").unwrap();
        std::fs::hard_link(&input, d.join("hard.toml")).unwrap();
        std::os::unix::fs::symlink(&input, d.join("soft.toml")).unwrap();
        std::os::unix::fs::symlink(d.join("new/plan.csv"), d.join("dangling.csv")).unwrap();
        let mut o = Outputs::new([&input]);
        for alias in ["hard.toml", "soft.toml", "./machine.toml"] {
            let e = o.claim(&d.join(alias)).unwrap_err().to_string();
            assert!(e.contains("is an input"), "{alias}: {e}");
        }
        o.claim(&d.join("new/plan.csv")).unwrap();
        for alias in ["new/./plan.csv", "dangling.csv"] {
            let e = o.claim(&d.join(alias)).unwrap_err().to_string();
            assert!(e.contains("another output"), "{alias}: {e}");
        }
        o.claim(&d.join("new/plan.nc")).unwrap();
        o.claim(Path::new("/dev/null")).unwrap();
        o.claim(Path::new("/dev/null")).unwrap();
        std::fs::remove_dir_all(&d).unwrap();
    }
}
