use std::path::{Path, PathBuf};

/// Why a figure could not be written; every variant names the file it was meant for.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The figure's size in pixels is zero or larger than [`crate::MAX_PIXELS`].
    #[error("cannot draw figure {}: {width}x{height} pixels is not a usable image size", path.display())]
    Size {
        /// The file the figure was meant for.
        path: PathBuf,
        /// Width of the whole figure in pixels.
        width: u64,
        /// Height of the whole figure in pixels.
        height: u64,
    },
    /// The drawing library failed (e.g. the embedded font could not be loaded).
    #[error("cannot draw figure {}: {message}", path.display())]
    Draw {
        /// The file the figure was meant for.
        path: PathBuf,
        /// What the drawing library reported, with the panel (counted from 1).
        message: String,
    },
    /// The drawn pixels could not be encoded as PNG.
    #[error("cannot encode figure {} as PNG: {message}", path.display())]
    Encode {
        /// The file the figure was meant for.
        path: PathBuf,
        /// What the PNG encoder reported.
        message: String,
    },
    /// The file could not be written (missing directory, permissions, full disk, ...).
    #[error("cannot write figure {}: {source}", path.display())]
    Write {
        /// The file the figure was meant for.
        path: PathBuf,
        /// The failed file-system operation.
        #[source]
        source: std::io::Error,
    },
}

impl PlotError {
    /// The file the figure was meant for.
    pub fn path(&self) -> &Path {
        match self {
            PlotError::Size { path, .. }
            | PlotError::Draw { path, .. }
            | PlotError::Encode { path, .. }
            | PlotError::Write { path, .. } => path,
        }
    }
}
