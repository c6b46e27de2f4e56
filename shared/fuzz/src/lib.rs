//! What the fuzz targets share: shared-memory payloads made of any bytes, and a file for the parsers
//! that read one.

use std::io::Write;

/// A payload another process could have written: any bits in every field.
///
/// # Safety
/// Implemented only for the contract's `#[repr(C)]` payloads, whose fields are all integers and
/// floats (any bit pattern is a value; see `shared/messages`).
pub unsafe trait Pod: Copy {}

unsafe impl Pod for messages::Stamp {}
unsafe impl Pod for messages::CameraFrameHeader {}
unsafe impl Pod for messages::DofCommand {}
unsafe impl Pod for messages::ThrusterSetpoints {}

/// Takes the next `size_of::<T>()` bytes of `data` as a `T` (missing bytes are zero), or `None`
/// when `data` is empty.
pub fn take<T: Pod>(data: &mut &[u8]) -> Option<T> {
    if data.is_empty() {
        return None;
    }
    let n = size_of::<T>().min(data.len());
    let mut buf = vec![0u8; size_of::<T>()];
    buf[..n].copy_from_slice(&data[..n]);
    *data = &data[n..];
    // SAFETY: `buf` holds size_of::<T>() bytes, and every bit pattern is a `T` (see `Pod`).
    Some(unsafe { std::ptr::read_unaligned(buf.as_ptr().cast::<T>()) })
}

/// Takes the next `n` bytes as a little-endian integer (missing bytes are zero).
pub fn take_u64(data: &mut &[u8], n: usize) -> u64 {
    let n = n.min(8).min(data.len());
    let mut b = [0u8; 8];
    b[..n].copy_from_slice(&data[..n]);
    *data = &data[n..];
    u64::from_le_bytes(b)
}

/// A file holding `bytes` in a private temporary directory (kept while the value lives), for the
/// parsers that open a path.
pub struct TempFile {
    _dir: tempfile::TempDir,
    pub path: std::path::PathBuf,
}

impl TempFile {
    pub fn new(name: &str, bytes: &[u8]) -> TempFile {
        // /dev/shm when there is one: a file per execution must not wear a disk.
        let dir = tempfile::Builder::new()
            .prefix("cabletrack-fuzz-")
            .tempdir_in(shm_or_tmp())
            .expect("a temporary directory");
        let path = dir.path().join(name);
        std::fs::File::create(&path)
            .and_then(|mut f| f.write_all(bytes))
            .expect("the input written");
        TempFile { _dir: dir, path }
    }
}

fn shm_or_tmp() -> std::path::PathBuf {
    let shm = std::path::Path::new("/dev/shm");
    if shm.is_dir() {
        shm.to_owned()
    } else {
        std::env::temp_dir()
    }
}
