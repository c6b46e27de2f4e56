//! Shared helpers for the figure tests: decoding the written PNG and looking at its pixels.

use std::fs::File;
use std::io::BufReader;
use std::path::Path;

/// A decoded 8-bit RGB image.
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

impl Image {
    /// Decodes the PNG at `path`, which must be 8-bit RGB.
    pub fn load(path: &Path) -> Image {
        let file = File::open(path).unwrap_or_else(|e| panic!("open {}: {e}", path.display()));
        let mut reader = png::Decoder::new(BufReader::new(file))
            .read_info()
            .expect("a PNG header");
        let mut rgb = vec![0; reader.output_buffer_size().expect("a sane size")];
        let info = reader.next_frame(&mut rgb).expect("PNG image data");
        assert_eq!(info.color_type, png::ColorType::Rgb);
        assert_eq!(info.bit_depth, png::BitDepth::Eight);
        rgb.truncate(info.buffer_size());
        Image {
            width: info.width,
            height: info.height,
            rgb,
        }
    }

    pub fn pixel(&self, x: u32, y: u32) -> [u8; 3] {
        let i = (y as usize * self.width as usize + x as usize) * 3;
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    /// The pixels of the rectangle `x0..x1` × `y0..y1` that satisfy `keep`.
    pub fn find(
        &self,
        (x0, x1): (u32, u32),
        (y0, y1): (u32, u32),
        keep: impl Fn([u8; 3]) -> bool,
    ) -> Vec<(u32, u32)> {
        let mut found = Vec::new();
        for y in y0..y1 {
            for x in x0..x1 {
                if keep(self.pixel(x, y)) {
                    found.push((x, y));
                }
            }
        }
        found
    }
}

/// The median of the x and of the y coordinates of `points`.
pub fn median(points: &[(u32, u32)]) -> (u32, u32) {
    let mut xs: Vec<u32> = points.iter().map(|p| p.0).collect();
    let mut ys: Vec<u32> = points.iter().map(|p| p.1).collect();
    xs.sort_unstable();
    ys.sort_unstable();
    (xs[xs.len() / 2], ys[ys.len() / 2])
}

pub const WHITE: [u8; 3] = [255, 255, 255];
