//! Files that survive a crash: a SIGKILL at any moment, a power cut, a full disk.
//!
//! - [`replace`]: a file is replaced whole, never torn. The new bytes go to a temporary file beside
//!   the target, which is synced, renamed over the target, and the directory is synced (the rename
//!   is only durable once the directory entry is). A crash at any point leaves either the old file
//!   or the new one; a failure (a full disk) leaves the old one and removes the temporary file.
//! - [`is_disk_full`]: the errors a full file system gives (no space, a quota), so a process can
//!   say so once and carry on ([`Outage`]) instead of failing at every write.
//!
//! Every process that keeps a file that must never be torn (the behaviours' checkpoints, the
//! monitor's run record, the figures) writes it through [`replace`]. The flight record, which is
//! appended to for hours, keeps itself readable its own way (the recorder's `seal`).

use std::fs::{self, File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// A step of a replacement failed; names the file and the step.
#[derive(Debug, thiserror::Error)]
#[error("cannot {action} {}", path.display())]
pub struct Error {
    pub path: PathBuf,
    pub action: &'static str,
    #[source]
    pub source: io::Error,
}

impl Error {
    /// The file system is full (see [`is_disk_full`]).
    pub fn is_disk_full(&self) -> bool {
        is_disk_full(&self.source)
    }
}

/// Replaces `path` with `bytes` (see the crate's docs): after `Ok`, `path` holds exactly `bytes`,
/// durably; after `Err` or a crash, it holds what it held before, or, once the rename is done, the
/// new bytes.
pub fn replace(path: &Path, bytes: &[u8]) -> Result<(), Error> {
    replace_with(path, |file| file.write_all(bytes))
}

/// [`replace`] with the file's contents written by `write` (a serializer writing into the file, or
/// a test failing half-way).
pub fn replace_with(
    path: &Path,
    write: impl FnOnce(&mut File) -> io::Result<()>,
) -> Result<(), Error> {
    let err = |action: &'static str| {
        move |source| Error {
            path: path.to_owned(),
            action,
            source,
        }
    };
    let name = path.file_name().ok_or_else(|| {
        err("write")(io::Error::new(
            io::ErrorKind::InvalidInput,
            "the path names no file",
        ))
    })?;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let tmp = dir.join(temporary_name(&name.to_string_lossy()));
    let staged = (|| {
        let mut file = OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)
            .map_err(err("create a temporary file for"))?;
        write(&mut file).map_err(err("write"))?;
        file.sync_all().map_err(err("sync"))?;
        drop(file);
        fs::rename(&tmp, path).map_err(err("rename the temporary file over"))
    })();
    if let Err(e) = staged {
        // Best effort: the old file is untouched either way, and a name that stays behind is
        // recognisable as a temporary one (`is_temporary`).
        let _ = fs::remove_file(&tmp);
        return Err(e);
    }
    sync_dir(dir).map_err(err("sync the directory of"))
}

/// `.NAME.tmp-PID-N`: hidden, unique per process and call (two writers never share one), and
/// recognisable by [`is_temporary`].
fn temporary_name(name: &str) -> String {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    format!(
        ".{name}.tmp-{}-{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    )
}

/// Whether `file_name` is a temporary file of [`replace`] (left behind only by a process killed
/// while writing it; never a file a reader should take).
pub fn is_temporary(file_name: &str) -> bool {
    file_name.starts_with('.') && file_name.contains(".tmp-")
}

/// Makes the entries of `dir` (a file created or renamed in it) durable.
pub fn sync_dir(dir: &Path) -> io::Result<()> {
    File::open(dir)?.sync_all()
}

/// The errors of a full file system: no space left, or a quota reached.
pub fn is_disk_full(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::StorageFull | io::ErrorKind::QuotaExceeded
    )
}

/// Whether a repeated write is failing, so that its failure is said once (with what failed) and its
/// recovery once (with how many writes failed), instead of at every attempt.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Outage {
    failed: u64,
}

impl Outage {
    /// A write failed: `true` the first time since the last success (say it now).
    pub fn failed(&mut self) -> bool {
        self.failed += 1;
        self.failed == 1
    }

    /// A write succeeded: the number of failed writes before it, when it ends an outage.
    pub fn succeeded(&mut self) -> Option<u64> {
        let n = std::mem::take(&mut self.failed);
        (n > 0).then_some(n)
    }

    /// Failed writes since the last success.
    pub fn failures(&self) -> u64 {
        self.failed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn a_replacement_holds_the_new_bytes_and_leaves_nothing_beside_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.json");
        replace(&path, b"first").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"first");
        replace(&path, b"second, longer").unwrap();
        replace(&path, b"third").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"third");
        assert_eq!(names(dir.path()), ["run.json"]);
    }

    #[test]
    fn a_write_failing_half_way_leaves_the_old_file_and_no_temporary_one() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sway.ckpt");
        replace(&path, b"the good one").unwrap();
        let e = replace_with(&path, |f| {
            f.write_all(b"the new one, half")?;
            Err(io::Error::from(io::ErrorKind::StorageFull))
        })
        .unwrap_err();
        assert_eq!(e.action, "write");
        assert!(e.is_disk_full());
        assert!(e.to_string().contains("sway.ckpt"), "{e}");
        assert_eq!(fs::read(&path).unwrap(), b"the good one");
        assert_eq!(names(dir.path()), ["sway.ckpt"]);
    }

    #[test]
    fn a_path_without_a_directory_or_a_name_is_refused_or_taken_as_here() {
        assert_eq!(
            replace(Path::new("/"), b"x").unwrap_err().source.kind(),
            io::ErrorKind::InvalidInput
        );
        let dir = tempfile::tempdir().unwrap();
        let e = replace(&dir.path().join("missing/run.json"), b"x").unwrap_err();
        assert_eq!(e.action, "create a temporary file for");
        assert!(e.to_string().contains("missing/run.json"), "{e}");
    }

    #[test]
    fn temporary_names_are_recognised_and_unique() {
        let (a, b) = (temporary_name("yaw.ckpt"), temporary_name("yaw.ckpt"));
        assert_ne!(a, b);
        assert!(is_temporary(&a) && is_temporary(&b));
        assert!(!is_temporary("yaw.ckpt") && !is_temporary("yaw.ckpt.prev"));
    }

    #[test]
    fn an_outage_is_said_once_and_its_end_once() {
        let mut o = Outage::default();
        assert_eq!(o.succeeded(), None);
        assert!(o.failed());
        assert!(!o.failed());
        assert!(!o.failed());
        assert_eq!(o.failures(), 3);
        assert_eq!(o.succeeded(), Some(3));
        assert_eq!(o.succeeded(), None);
        assert!(o.failed());
    }

    #[test]
    fn the_errors_of_a_full_disk_are_told_apart() {
        assert!(is_disk_full(&io::Error::from_raw_os_error(28))); // ENOSPC
        assert!(is_disk_full(&io::Error::from_raw_os_error(122))); // EDQUOT
        assert!(!is_disk_full(&io::Error::from_raw_os_error(5))); // EIO
    }
}
