//! An iceoryx2 namespace of one run's own (a test's, a benchmark run's, a supervisor's with
//! `--own-namespace`): a prefix and a root that no other run on this machine uses, so runs proceed
//! in parallel without meeting, and everything they leave behind is removed with the namespace.

use crate::node::{IoxSettings, shm_files, shm_leftovers};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};

static NEXT: AtomicU32 = AtomicU32::new(0);

/// Where isolated namespaces keep their roots.
const BASE: &str = "/tmp/ctns";

/// A fresh iceoryx2 prefix and root; dropping it removes the root (logs, scratch files, sockets) and
/// the prefix's shared-memory files.
pub struct Namespace {
    pub iox: IoxSettings,
    pub root: PathBuf,
}

impl Namespace {
    /// A fresh namespace; `label` (a few letters) tells runs apart in `/dev/shm`.
    pub fn new(label: &str) -> Namespace {
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        // Short: root + prefix must fit a socket path (see `IoxSettings::config`).
        let prefix = format!(
            "n{}{}x{n}_",
            label.chars().take(4).collect::<String>(),
            std::process::id() % 100_000,
        );
        let root = PathBuf::from(format!("{BASE}/{prefix}/"));
        let _ = std::fs::remove_dir_all(&root);
        Namespace {
            iox: IoxSettings {
                prefix,
                root: root.display().to_string(),
            },
            root,
        }
    }

    pub fn prefix(&self) -> &str {
        &self.iox.prefix
    }

    /// The environment a process needs to join (as `CommonArgs` reads it).
    pub fn env(&self) -> [(&'static str, String); 2] {
        self.iox.env()
    }

    /// A directory of this namespace's own for logs, checkpoints and records (created on call).
    pub fn scratch(&self) -> PathBuf {
        let dir = self.root.join("scratch");
        let _ = std::fs::create_dir_all(&dir);
        dir
    }

    /// Shared-memory files of this namespace still in /dev/shm.
    pub fn shm_files(&self) -> Vec<String> {
        shm_files(&self.iox.prefix)
    }

    /// Files of this namespace that outlive its processes (see [`shm_leftovers`]).
    pub fn leftovers(&self) -> Vec<String> {
        shm_leftovers(&self.iox.prefix)
    }
}

impl Drop for Namespace {
    fn drop(&mut self) {
        for f in self.shm_files() {
            let _ = std::fs::remove_file(Path::new("/dev/shm").join(f));
        }
        let _ = std::fs::remove_dir_all(&self.root);
        // The common parent too, once no other run uses it.
        let _ = std::fs::remove_dir(BASE);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn namespaces_are_distinct_fit_a_socket_path_and_clean_up() {
        let a = Namespace::new("test");
        let b = Namespace::new("test");
        assert_ne!(a.iox.prefix, b.iox.prefix);
        a.iox.config().expect("a valid iceoryx2 configuration");
        let scratch = a.scratch();
        std::fs::write(scratch.join("x"), b"1").unwrap();
        let root = a.root.clone();
        drop(a);
        assert!(!root.exists());
    }
}
