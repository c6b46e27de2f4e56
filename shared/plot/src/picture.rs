//! Pictures: an 8-bit grey image (a camera frame) with line segments drawn over it, e.g. the cable
//! as perception found it, scaled to fill its panel without changing its proportions.

use crate::style::{Theme, rgb};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// A grey image and segments over it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Picture {
    /// Drawn above the image; may be empty.
    pub title: String,
    /// The image's size in pixels.
    pub width: u32,
    /// See `width`.
    pub height: u32,
    /// `width * height` grey levels, row by row from the top; missing pixels are drawn black.
    pub grey: Vec<u8>,
    /// Segments in the image's pixel coordinates (origin at the top-left corner, y down), with their
    /// colour.
    pub segments: Vec<([f64; 2], [f64; 2], [u8; 3])>,
}

pub(crate) fn draw<DB: DrawingBackend>(
    picture: &Picture,
    area: &DrawingArea<DB, Shift>,
    theme: &Theme,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let (width, height) = area.dim_in_pixel();
    let (width, height) = (width as i32, height as i32);
    let top = if picture.title.is_empty() {
        theme.px(8.0)
    } else {
        let style = theme.title_font().pos(Pos::new(HPos::Center, VPos::Top));
        area.draw_text(&picture.title, &style, (width / 2, theme.px(8.0)))?;
        area.estimate_text_size(&picture.title, &theme.title_font())?
            .1 as i32
            + theme.px(16.0)
    };
    if picture.width == 0 || picture.height == 0 {
        return Ok(());
    }
    let margin = theme.px(8.0);
    let (room_w, room_h) = ((width - 2 * margin).max(1), (height - top - margin).max(1));
    let scale = (room_w as f64 / picture.width as f64).min(room_h as f64 / picture.height as f64);
    let (w, h) = (
        (picture.width as f64 * scale) as i32,
        (picture.height as f64 * scale) as i32,
    );
    let (x0, y0) = ((width - w) / 2, top + (room_h - h) / 2);
    for y in 0..h {
        let row = ((y as f64 / scale) as u32).min(picture.height - 1);
        for x in 0..w {
            let column = ((x as f64 / scale) as u32).min(picture.width - 1);
            let g = picture
                .grey
                .get((row * picture.width + column) as usize)
                .copied()
                .unwrap_or(0);
            area.draw_pixel((x0 + x, y0 + y), &RGBColor(g, g, g))?;
        }
    }
    let to_panel = |p: [f64; 2]| {
        (
            x0 + (p[0] * scale).round() as i32,
            y0 + (p[1] * scale).round() as i32,
        )
    };
    for (a, b, colour) in &picture.segments {
        area.draw(&PathElement::new(
            vec![to_panel(*a), to_panel(*b)],
            rgb(*colour).stroke_width(theme.px(2.5) as u32),
        ))?;
    }
    Ok(())
}
