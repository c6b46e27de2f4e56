//! Figures: panels in a grid, drawn into memory and written atomically as PNG.

use crate::error::PlotError;
use crate::heatmap::{self, Heatmap};
use crate::line::{self, LineChart};
use crate::picture::{self, Picture};
use crate::style::{Theme, ensure_font};
use plotters::prelude::*;
use std::path::Path;

/// The largest figure [`Figure::save_png`] draws, in pixels (width × height).
pub const MAX_PIXELS: u64 = 32_000_000;

/// Figures up to this many pixels are drawn at twice their size and scaled down, which smooths
/// lines and text; larger ones are drawn at their size.
const SUPERSAMPLE_MAX_PIXELS: u64 = 8_000_000;

/// One panel of a figure.
#[derive(Clone, Debug, PartialEq)]
pub enum Panel {
    /// Curves over shared axes: learning curves, state traces.
    Lines(LineChart),
    /// A value over a 2-D box: a policy's state-to-action map.
    Heat(Heatmap),
    /// A grey image with segments over it: a camera frame and the cable found in it.
    Picture(Picture),
}

impl From<Picture> for Panel {
    fn from(picture: Picture) -> Self {
        Panel::Picture(picture)
    }
}

impl From<LineChart> for Panel {
    fn from(chart: LineChart) -> Self {
        Panel::Lines(chart)
    }
}

impl From<Heatmap> for Panel {
    fn from(map: Heatmap) -> Self {
        Panel::Heat(map)
    }
}

/// Panels in a grid, filled row by row, each `panel_size` pixels large.
#[derive(Clone, Debug, PartialEq)]
pub struct Figure {
    /// The panels, left to right, then top to bottom.
    pub panels: Vec<Panel>,
    /// Panels per row; 0 counts as 1, and a figure is never wider than its number of panels.
    pub columns: usize,
    /// Width and height of one panel in pixels; text and lines scale with it.
    pub panel_size: (u32, u32),
}

impl Figure {
    /// The size of one panel unless set otherwise: readable on a screen and in a paper at 300 dpi.
    pub const DEFAULT_PANEL_SIZE: (u32, u32) = (640, 440);

    /// A figure of `panels` in rows of `columns`, each [`Figure::DEFAULT_PANEL_SIZE`] large.
    pub fn new(panels: Vec<Panel>, columns: usize) -> Self {
        Figure {
            panels,
            columns,
            panel_size: Self::DEFAULT_PANEL_SIZE,
        }
    }

    /// `(rows, columns)` of the grid. A figure without panels has one empty cell.
    pub fn grid(&self) -> (usize, usize) {
        let n = self.panels.len().max(1);
        let columns = self.columns.clamp(1, n);
        (n.div_ceil(columns), columns)
    }

    /// The size of the image in pixels, `(width, height)`.
    pub fn pixel_size(&self) -> (u64, u64) {
        let (rows, columns) = self.grid();
        (
            u64::from(self.panel_size.0) * columns as u64,
            u64::from(self.panel_size.1) * rows as u64,
        )
    }

    /// Draws the figure and writes it to `path` as an 8-bit RGB PNG.
    ///
    /// The image replaces `path` whole (`durable::replace`: a temporary file beside it, synced and
    /// renamed over it), so `path` holds either its old content or the whole new image, never a part. The directory must exist.
    pub fn save_png(&self, path: &Path) -> Result<(), PlotError> {
        let (width, height) = self.pixel_size();
        if width == 0 || height == 0 || width.saturating_mul(height) > MAX_PIXELS {
            return Err(PlotError::Size {
                path: path.to_path_buf(),
                width,
                height,
            });
        }
        // Both fit in u32: each is at most MAX_PIXELS.
        let (width, height) = (width as u32, height as u32);
        let rgb = self
            .render(width, height)
            .map_err(|message| PlotError::Draw {
                path: path.to_path_buf(),
                message,
            })?;
        let png = encode_png(&rgb, width, height).map_err(|e| PlotError::Encode {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        durable::replace(path, &png).map_err(|e| PlotError::Write {
            path: path.to_path_buf(),
            source: e.source,
        })
    }

    /// Draws the figure into an RGB buffer of `width` × `height` pixels.
    fn render(&self, width: u32, height: u32) -> Result<Vec<u8>, String> {
        ensure_font()?;
        let supersample = if u64::from(width) * u64::from(height) <= SUPERSAMPLE_MAX_PIXELS {
            2
        } else {
            1
        };
        let (w, h) = (width * supersample, height * supersample);
        let mut buffer = vec![255u8; w as usize * h as usize * 3];
        {
            let root = BitMapBackend::with_buffer(&mut buffer, (w, h)).into_drawing_area();
            root.fill(&WHITE).map_err(|e| e.to_string())?;
            let theme = Theme::new(self.panel_size, supersample);
            let (_, columns) = self.grid();
            let (pw, ph) = (
                self.panel_size.0 * supersample,
                self.panel_size.1 * supersample,
            );
            for (i, panel) in self.panels.iter().enumerate() {
                let (row, column) = ((i / columns) as u32, (i % columns) as u32);
                let area = root.clone().shrink((column * pw, row * ph), (pw, ph));
                match panel {
                    Panel::Lines(chart) => line::draw(chart, &area, &theme),
                    Panel::Heat(map) => heatmap::draw(map, &area, &theme),
                    Panel::Picture(p) => picture::draw(p, &area, &theme),
                }
                .map_err(|e| format!("panel {}: {e}", i + 1))?;
            }
            root.present().map_err(|e| e.to_string())?;
        }
        Ok(downsample(&buffer, w, h, supersample))
    }
}

/// Averages `factor` × `factor` blocks of an RGB image of `width` × `height` pixels.
fn downsample(rgb: &[u8], width: u32, height: u32, factor: u32) -> Vec<u8> {
    if factor == 1 {
        return rgb.to_vec();
    }
    let (w, h, f) = (width as usize, height as usize, factor as usize);
    let (ow, oh) = (w / f, h / f);
    let mut out = vec![0u8; ow * oh * 3];
    let n = (f * f) as u32;
    for y in 0..oh {
        for x in 0..ow {
            let mut sum = [0u32; 3];
            for dy in 0..f {
                let start = ((y * f + dy) * w + x * f) * 3;
                for px in rgb[start..start + 3 * f].chunks_exact(3) {
                    for c in 0..3 {
                        sum[c] += u32::from(px[c]);
                    }
                }
            }
            let o = (y * ow + x) * 3;
            for c in 0..3 {
                out[o + c] = ((sum[c] + n / 2) / n) as u8;
            }
        }
    }
    out
}

fn encode_png(rgb: &[u8], width: u32, height: u32) -> Result<Vec<u8>, png::EncodingError> {
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header()?;
    writer.write_image_data(rgb)?;
    writer.finish()?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn downsample_averages_blocks() {
        // 2x2 image: black, white / white, black -> one mid-grey pixel.
        let rgb = [0, 0, 0, 255, 255, 255, 255, 255, 255, 0, 0, 0];
        assert_eq!(downsample(&rgb, 2, 2, 2), vec![128, 128, 128]);
    }

    #[test]
    fn grid_is_never_wider_than_the_panels() {
        let mut figure = Figure::new(Vec::new(), 3);
        assert_eq!(figure.grid(), (1, 1));
        figure.panels = vec![Panel::Lines(LineChart::default()); 4];
        assert_eq!(figure.grid(), (2, 3));
        figure.columns = 0;
        assert_eq!(figure.grid(), (4, 1));
    }
}
