use std::path::PathBuf;

/// A frame buffer or a setup that the renderer or perception cannot use.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VisionError {
    #[error("a {width}x{height} image needs {expected} bytes, the buffer has {got}")]
    LengthMismatch {
        width: usize,
        height: usize,
        expected: usize,
        got: usize,
    },
    #[error(
        "image size {width}x{height} is not supported (each side must be within [{min}, {max}] pixels)"
    )]
    BadSize {
        width: usize,
        height: usize,
        min: usize,
        max: usize,
    },
    #[error("the image is {got_width}x{got_height} but the {what} is set up for {width}x{height}")]
    SizeMismatch {
        what: &'static str,
        width: usize,
        height: usize,
        got_width: usize,
        got_height: usize,
    },
    #[error("invalid {what} parameters: {invalid}")]
    Config {
        what: &'static str,
        #[source]
        invalid: config::Invalid,
    },
}

/// Why an image could not be decoded from bytes (PGM or PNG).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DecodeError {
    #[error("not a PGM (P2/P5) or PNG image")]
    UnknownFormat,
    #[error("bad PGM header: {0}")]
    PgmHeader(String),
    #[error(
        "the pixel data is shorter than the header says: {expected} bytes expected, {got} present"
    )]
    Truncated { expected: usize, got: usize },
    #[error("bad PNG: {0}")]
    Png(String),
    #[error(transparent)]
    Image(#[from] VisionError),
}

/// Why an image file could not be read or written. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    #[error("cannot read {}: {source}", path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot write {}: {source}", path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot decode {}: {source}", path.display())]
    Decode {
        path: PathBuf,
        #[source]
        source: DecodeError,
    },
    #[error("cannot encode {}: {reason}", path.display())]
    Encode { path: PathBuf, reason: String },
    #[error("{}: unknown image file extension (use .pgm or .png)", path.display())]
    Extension { path: PathBuf },
}
