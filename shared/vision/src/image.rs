//! 8-bit grey images: a borrowed, validated view (what the renderer writes into and perception reads,
//! e.g. a shared-memory slice) and an owned [`Frame`] for files (PGM and PNG).

use crate::error::{DecodeError, FrameError, VisionError};
use std::path::Path;

/// Smallest and largest image side accepted anywhere in this crate.
pub const MIN_SIDE: usize = 8;
pub const MAX_SIDE: usize = 8192;

/// Checks an image size and a buffer length against it.
pub(crate) fn check_size(width: usize, height: usize, len: usize) -> Result<(), VisionError> {
    if !(MIN_SIDE..=MAX_SIDE).contains(&width) || !(MIN_SIDE..=MAX_SIDE).contains(&height) {
        return Err(VisionError::BadSize {
            width,
            height,
            min: MIN_SIDE,
            max: MAX_SIDE,
        });
    }
    let expected = width * height;
    if len != expected {
        return Err(VisionError::LengthMismatch {
            width,
            height,
            expected,
            got: len,
        });
    }
    Ok(())
}

/// A borrowed row-major 8-bit grey image whose length matches its size.
#[derive(Clone, Copy, Debug)]
pub struct ImageView<'a> {
    data: &'a [u8],
    width: usize,
    height: usize,
}

impl<'a> ImageView<'a> {
    /// A view of `data` as a `width x height` image; the length must be exactly `width * height`.
    pub fn new(data: &'a [u8], width: usize, height: usize) -> Result<Self, VisionError> {
        check_size(width, height, data.len())?;
        Ok(ImageView {
            data,
            width,
            height,
        })
    }

    pub fn data(&self) -> &'a [u8] {
        self.data
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// The grey level at column `i`, row `j`.
    pub fn get(&self, i: usize, j: usize) -> u8 {
        self.data[j * self.width + i]
    }
}

/// An owned 8-bit grey image.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Frame {
    width: usize,
    height: usize,
    data: Vec<u8>,
}

impl Frame {
    /// A black frame.
    pub fn new(width: usize, height: usize) -> Result<Self, VisionError> {
        check_size(width, height, width.saturating_mul(height))?;
        Ok(Frame {
            width,
            height,
            data: vec![0; width * height],
        })
    }

    pub fn from_vec(width: usize, height: usize, data: Vec<u8>) -> Result<Self, VisionError> {
        check_size(width, height, data.len())?;
        Ok(Frame {
            width,
            height,
            data,
        })
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    pub fn data(&self) -> &[u8] {
        &self.data
    }

    pub fn data_mut(&mut self) -> &mut [u8] {
        &mut self.data
    }

    pub fn view(&self) -> ImageView<'_> {
        ImageView {
            data: &self.data,
            width: self.width,
            height: self.height,
        }
    }

    /// Decodes a PGM (binary P5 or plain P2, any maxval) or PNG (any colour type, converted to grey).
    pub fn decode(bytes: &[u8]) -> Result<Frame, DecodeError> {
        if bytes.starts_with(b"\x89PNG") {
            decode_png(bytes)
        } else if bytes.starts_with(b"P5") || bytes.starts_with(b"P2") {
            decode_pgm(bytes)
        } else {
            Err(DecodeError::UnknownFormat)
        }
    }

    /// Reads a PGM or PNG file (the format is told by its content).
    pub fn read(path: &Path) -> Result<Frame, FrameError> {
        let bytes = std::fs::read(path).map_err(|source| FrameError::Read {
            path: path.to_owned(),
            source,
        })?;
        Frame::decode(&bytes).map_err(|source| FrameError::Decode {
            path: path.to_owned(),
            source,
        })
    }

    /// The frame as a binary PGM (P5).
    pub fn encode_pgm(&self) -> Vec<u8> {
        let mut out = format!("P5\n{} {}\n255\n", self.width, self.height).into_bytes();
        out.extend_from_slice(&self.data);
        out
    }

    /// The frame as an 8-bit grey PNG.
    pub fn encode_png(&self) -> Result<Vec<u8>, String> {
        let mut out = Vec::new();
        let mut encoder = png::Encoder::new(&mut out, self.width as u32, self.height as u32);
        encoder.set_color(png::ColorType::Grayscale);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().map_err(|e| e.to_string())?;
        writer
            .write_image_data(&self.data)
            .map_err(|e| e.to_string())?;
        writer.finish().map_err(|e| e.to_string())?;
        Ok(out)
    }

    /// Writes the frame as PGM or PNG, chosen by the file's extension.
    pub fn write(&self, path: &Path) -> Result<(), FrameError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        let bytes = match ext.as_deref() {
            Some("pgm") => self.encode_pgm(),
            Some("png") => self.encode_png().map_err(|reason| FrameError::Encode {
                path: path.to_owned(),
                reason,
            })?,
            _ => {
                return Err(FrameError::Extension {
                    path: path.to_owned(),
                });
            }
        };
        std::fs::write(path, bytes).map_err(|source| FrameError::Write {
            path: path.to_owned(),
            source,
        })
    }
}

/// Reads PGM header tokens: whitespace-separated, `#` starts a comment to the end of the line.
struct PgmHeader<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl PgmHeader<'_> {
    fn skip_space(&mut self) {
        while self.pos < self.bytes.len() {
            match self.bytes[self.pos] {
                b'#' => {
                    while self.pos < self.bytes.len() && self.bytes[self.pos] != b'\n' {
                        self.pos += 1;
                    }
                }
                b if b.is_ascii_whitespace() => self.pos += 1,
                _ => break,
            }
        }
    }

    fn number(&mut self, what: &str) -> Result<usize, DecodeError> {
        self.skip_space();
        let start = self.pos;
        while self.pos < self.bytes.len() && self.bytes[self.pos].is_ascii_digit() {
            self.pos += 1;
        }
        let digits = &self.bytes[start..self.pos];
        if digits.is_empty() || digits.len() > 9 {
            return Err(DecodeError::PgmHeader(format!(
                "expected the {what} as a decimal number"
            )));
        }
        // Only ASCII digits, at most 9 of them: fits in usize.
        Ok(digits
            .iter()
            .fold(0usize, |n, d| n * 10 + (d - b'0') as usize))
    }
}

fn decode_pgm(bytes: &[u8]) -> Result<Frame, DecodeError> {
    let plain = bytes[1] == b'2';
    let mut h = PgmHeader { bytes, pos: 2 };
    let width = h.number("width")?;
    let height = h.number("height")?;
    let maxval = h.number("maximum value")?;
    if !(1..=65535).contains(&maxval) {
        return Err(DecodeError::PgmHeader(format!(
            "maximum value {maxval} is not within [1, 65535]"
        )));
    }
    check_size(width, height, width * height)?;
    let n = width * height;
    let scale = |v: usize| ((v.min(maxval) * 255 + maxval / 2) / maxval) as u8;
    let mut data = Vec::with_capacity(n);
    if plain {
        for _ in 0..n {
            h.skip_space();
            if h.pos >= bytes.len() {
                return Err(DecodeError::Truncated {
                    expected: n,
                    got: data.len(),
                });
            }
            data.push(scale(h.number("pixel value")?));
        }
    } else {
        // Exactly one whitespace byte separates the header from the raster.
        match bytes.get(h.pos) {
            Some(b) if b.is_ascii_whitespace() => h.pos += 1,
            _ => {
                return Err(DecodeError::PgmHeader(
                    "expected whitespace after the maximum value".into(),
                ));
            }
        }
        let raster = &bytes[h.pos..];
        let bytes_per = if maxval < 256 { 1 } else { 2 };
        let expected = n * bytes_per;
        if raster.len() < expected {
            return Err(DecodeError::Truncated {
                expected,
                got: raster.len(),
            });
        }
        if bytes_per == 1 {
            if maxval == 255 {
                data.extend_from_slice(&raster[..n]);
            } else {
                data.extend(raster[..n].iter().map(|&v| scale(v as usize)));
            }
        } else {
            data.extend(
                raster[..expected]
                    .chunks_exact(2)
                    .map(|c| scale(((c[0] as usize) << 8) | c[1] as usize)),
            );
        }
    }
    Ok(Frame::from_vec(width, height, data)?)
}

fn decode_png(bytes: &[u8]) -> Result<Frame, DecodeError> {
    let png_err = |e: png::DecodingError| DecodeError::Png(e.to_string());
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::normalize_to_color8());
    let header = decoder.read_header_info().map_err(png_err)?;
    let (width, height) = (header.width as usize, header.height as usize);
    check_size(width, height, width * height)?;
    let mut reader = decoder.read_info().map_err(png_err)?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| DecodeError::Png("image too large".into()))?;
    let mut buf = vec![0; size];
    let info = reader.next_frame(&mut buf).map_err(png_err)?;
    let channels = info.color_type.samples();
    let line = info.line_size;
    let mut data = Vec::with_capacity(width * height);
    for row in buf.chunks_exact(line).take(height) {
        for px in row.chunks_exact(channels).take(width) {
            let grey = match channels {
                1 | 2 => px[0],
                // ITU-R BT.601 luma, integer weights summing to 256.
                _ => {
                    ((77 * px[0] as u32 + 150 * px[1] as u32 + 29 * px[2] as u32 + 128) >> 8) as u8
                }
            };
            data.push(grey);
        }
    }
    if data.len() != width * height {
        return Err(DecodeError::Truncated {
            expected: width * height,
            got: data.len(),
        });
    }
    Ok(Frame::from_vec(width, height, data)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp() -> Frame {
        let data = (0..16 * 12).map(|k| (k * 7 % 256) as u8).collect();
        Frame::from_vec(16, 12, data).unwrap()
    }

    #[test]
    fn pgm_and_png_round_trip() {
        let f = ramp();
        assert_eq!(Frame::decode(&f.encode_pgm()).unwrap(), f);
        assert_eq!(Frame::decode(&f.encode_png().unwrap()).unwrap(), f);
    }

    #[test]
    fn pgm_variants() {
        let plain = b"P2\n# a comment\n8 8\n# another\n15\n".iter().copied();
        let mut text: Vec<u8> = plain.collect();
        for k in 0..64 {
            text.extend_from_slice(format!("{} ", k % 16).as_bytes());
        }
        let f = Frame::decode(&text).unwrap();
        assert_eq!(f.data()[15], 255);
        assert_eq!(f.data()[0], 0);
        let mut wide = b"P5 8 8 65535\n".to_vec();
        for k in 0..64u16 {
            wide.extend_from_slice(&(k * 1000).to_be_bytes());
        }
        let f = Frame::decode(&wide).unwrap();
        assert_eq!(f.data()[1], ((1000 * 255 + 32767) / 65535) as u8);
    }

    #[test]
    fn a_short_frame_is_a_clear_error() {
        let mut bytes = ramp().encode_pgm();
        bytes.truncate(bytes.len() - 10);
        match Frame::decode(&bytes) {
            Err(DecodeError::Truncated { expected, got }) => {
                assert_eq!((expected, got), (192, 182))
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn views_check_their_length() {
        let buf = vec![0u8; 100];
        assert!(matches!(
            ImageView::new(&buf, 320, 240),
            Err(VisionError::LengthMismatch {
                expected: 76800,
                got: 100,
                ..
            })
        ));
        assert!(matches!(
            ImageView::new(&buf, 0, 0),
            Err(VisionError::BadSize { .. })
        ));
        assert!(ImageView::new(&buf, 10, 10).is_ok());
    }
}
