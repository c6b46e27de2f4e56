//! Heat maps: a value over a 2-D box (e.g. a policy's action over two state variables), with a
//! diverging colour map and a labelled colour bar.

use crate::axes::{AxesFrame, draw_frame};
use crate::style::{
    AXIS, LABEL_SIZE, TICK_SIZE, Theme, TickFormat, diverging_color, key_points, rgb, usable_range,
};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::FontTransform;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// The colour of cells without a finite value (light grey).
pub const NO_DATA_COLOR: [u8; 3] = [0xc8, 0xc8, 0xc8];

/// A grid of values over the box `x_range` × `y_range`, drawn as coloured cells.
///
/// `values[j][i]` is the cell in row `j` (rows run over y, the first row at `y_min`) and column `i`
/// (columns run over x, the first at `x_min`); all cells have the same size. Rows may differ in
/// length: the grid has as many columns as the longest row and missing cells count as no data.
/// Values are coloured with [`diverging_color`] over `value_range` (the middle of the range is
/// white, values outside it take the end colours); non-finite values are drawn in
/// [`NO_DATA_COLOR`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Heatmap {
    /// Drawn above the map; may be empty.
    pub title: String,
    /// Description of the horizontal axis, e.g. "x_g".
    pub x_label: String,
    /// Description of the vertical axis, e.g. "dx_g/dt".
    pub y_label: String,
    /// The horizontal extent `(min, max)` of the grid.
    pub x_range: (f64, f64),
    /// The vertical extent `(min, max)` of the grid.
    pub y_range: (f64, f64),
    /// The cell values, `values[row over y][column over x]`, first row at `y_min`.
    pub values: Vec<Vec<f64>>,
    /// The values mapped to the two ends of the colour map, e.g. the action limits `(-1, 1)`.
    pub value_range: (f64, f64),
    /// Description of the colour bar, e.g. "Action".
    pub value_label: String,
}

impl Heatmap {
    /// Samples `f(x, y)` at the centres of a grid of `columns` × `rows` cells over the box, in the
    /// layout of [`Heatmap::values`].
    pub fn sample(
        x_range: (f64, f64),
        y_range: (f64, f64),
        (columns, rows): (usize, usize),
        f: impl Fn(f64, f64) -> f64,
    ) -> Vec<Vec<f64>> {
        let dx = (x_range.1 - x_range.0) / columns.max(1) as f64;
        let dy = (y_range.1 - y_range.0) / rows.max(1) as f64;
        (0..rows)
            .map(|j| {
                let y = y_range.0 + (j as f64 + 0.5) * dy;
                (0..columns)
                    .map(|i| f(x_range.0 + (i as f64 + 0.5) * dx, y))
                    .collect()
            })
            .collect()
    }

    /// The colour `value` is drawn in.
    pub fn color(&self, value: f64) -> [u8; 3] {
        if !value.is_finite() {
            return NO_DATA_COLOR;
        }
        let (lo, hi) = usable_range(self.value_range, (-1.0, 1.0));
        diverging_color((value - lo) / (hi - lo))
    }

    fn columns(&self) -> usize {
        self.values.iter().map(Vec::len).max().unwrap_or(0)
    }
}

/// Draws `map` into `area`, which it fills: the map on the left, the colour bar on the right.
pub(crate) fn draw<DB: DrawingBackend>(
    map: &Heatmap,
    area: &DrawingArea<DB, Shift>,
    theme: &Theme,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let x_range = usable_range(map.x_range, (0.0, 1.0));
    let y_range = usable_range(map.y_range, (0.0, 1.0));
    let value_range = usable_range(map.value_range, (-1.0, 1.0));

    // The colour bar takes the right margin of the axes.
    let bar = ColourBar::layout(area, theme, value_range, &map.value_label)?;
    let frame = AxesFrame::layout(
        area,
        theme,
        &map.title,
        &map.x_label,
        &map.y_label,
        y_range,
        bar.width,
    )?;
    let x_ticks = key_points(x_range, frame.x_ticks);
    let x_format = TickFormat::for_ticks(&x_ticks);
    let y_ticks = key_points(y_range, frame.y_ticks);
    let y_format = TickFormat::for_ticks(&y_ticks);
    let x_fmt = |v: &f64| x_format.format(*v);
    let y_fmt = |v: &f64| y_format.format(*v);

    let mut ctx = frame
        .builder(area)
        .build_cartesian_2d(x_range.0..x_range.1, y_range.0..y_range.1)?;
    let (rows, columns) = (map.values.len(), map.columns());
    if rows > 0 && columns > 0 {
        let dx = (x_range.1 - x_range.0) / columns as f64;
        let dy = (y_range.1 - y_range.0) / rows as f64;
        let cells = map.values.iter().enumerate().flat_map(|(j, row)| {
            (0..columns).map(move |i| {
                let value = row.get(i).copied().unwrap_or(f64::NAN);
                let (x0, y0) = (x_range.0 + i as f64 * dx, y_range.0 + j as f64 * dy);
                Rectangle::new(
                    [(x0, y0 + dy), (x0 + dx, y0)],
                    rgb(map.color(value)).filled(),
                )
            })
        });
        ctx.draw_series(cells)?;
    }
    // The axes after the cells, so that the axis lines lie on top.
    let mut mesh = ctx.configure_mesh();
    mesh.disable_mesh()
        .x_labels(frame.x_ticks)
        .y_labels(frame.y_ticks)
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .y_label_offset(AxesFrame::y_label_offset(theme))
        .label_style(theme.tick_font())
        .axis_desc_style(theme.label_font())
        .axis_style(AXIS.stroke_width(theme.px(1.0) as u32))
        .set_all_tick_mark_size(theme.tick_len());
    if !map.x_label.is_empty() {
        mesh.x_desc(map.x_label.as_str());
    }
    if !map.y_label.is_empty() {
        mesh.y_desc(map.y_label.as_str());
    }

    mesh.draw()?;
    let plot = ctx.plotting_area();
    draw_frame(&plot.strip_coord_spec(), theme)?;
    let (plot_x, plot_y) = plot.get_pixel_range();
    frame.draw_title(area, &plot_x, theme, &map.title)?;

    let (base_x, base_y) = area.get_base_pixel();
    let left = plot_x.end - base_x + bar.gap;
    bar.draw(
        area,
        theme,
        map,
        left,
        (plot_y.start - base_y, plot_y.end - base_y - 1),
    )
}

/// The colour bar beside a heat map.
struct ColourBar<'a> {
    /// Everything right of the map: gap, bar, ticks, tick labels, description.
    width: i32,
    gap: i32,
    bar: i32,
    /// Width of the widest tick label.
    widest: i32,
    ticks: Vec<f64>,
    format: TickFormat,
    range: (f64, f64),
    label: &'a str,
}

impl<'a> ColourBar<'a> {
    fn layout<DB: DrawingBackend>(
        area: &DrawingArea<DB, Shift>,
        theme: &Theme,
        range: (f64, f64),
        label: &'a str,
    ) -> Result<Self, DrawingAreaErrorKind<DB::ErrorType>> {
        let ticks = key_points(range, 7);
        let format = TickFormat::for_ticks(&ticks);
        let mut widest = 0;
        for v in &ticks {
            widest = widest.max(
                area.estimate_text_size(&format.format(*v), &theme.tick_font())?
                    .0 as i32,
            );
        }
        let label_height = if label.is_empty() {
            0
        } else {
            area.estimate_text_size(label, &theme.label_font())?.1 as i32 + theme.px(8.0)
        };
        let gap = theme.px(18.0);
        let bar = theme.px(16.0);
        let width = gap + bar + 2 * theme.tick_len() + widest + label_height + theme.px(12.0);
        Ok(ColourBar {
            width,
            gap,
            bar,
            widest,
            ticks,
            format,
            range,
            label,
        })
    }

    /// Draws the bar with its left edge at `left`, spanning the pixel rows `top..=bottom` of `area`.
    fn draw<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
        theme: &Theme,
        map: &Heatmap,
        left: i32,
        (top, bottom): (i32, i32),
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        if bottom <= top {
            return Ok(());
        }
        let right = left + self.bar;
        let (lo, hi) = self.range;
        let span = f64::from(bottom - top);
        // One strip per pixel row; plotters skips filled rectangles of zero height.
        for py in top..=bottom {
            let value = lo + (hi - lo) * f64::from(bottom - py) / span;
            let strip = Rectangle::new(
                [(left, py), (right, py + 1)],
                rgb(map.color(value)).filled(),
            );
            area.draw(&strip)?;
        }
        let axis = AXIS.stroke_width(theme.px(1.0) as u32);
        area.draw(&PathElement::new(
            vec![
                (left, top),
                (right, top),
                (right, bottom),
                (left, bottom),
                (left, top),
            ],
            axis,
        ))?;

        let tick = theme.tick_len();
        let font = theme.tick_font().pos(Pos::new(HPos::Left, VPos::Center));
        for &v in &self.ticks {
            let py = bottom - ((v - lo) / (hi - lo) * span).round() as i32;
            area.draw(&PathElement::new(
                vec![(right, py), (right + tick, py)],
                axis,
            ))?;
            let label_y = py + theme.centre_correction(TICK_SIZE);
            area.draw_text(&self.format.format(v), &font, (right + 2 * tick, label_y))?;
        }

        if !self.label.is_empty() {
            // Rotated like a y description: the top of the letters faces the tick labels.
            let style = theme
                .label_font()
                .transform(FontTransform::Rotate270)
                .pos(Pos::new(HPos::Center, VPos::Top));
            let x =
                right + 2 * tick + self.widest + theme.px(8.0) + theme.ink_overshoot(LABEL_SIZE);
            area.draw_text(self.label, &style, (x, (top + bottom) / 2))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_uses_cell_centres_rows_over_y() {
        let values = Heatmap::sample((0.0, 2.0), (0.0, 1.0), (2, 1), |x, y| x + 10.0 * y);
        assert_eq!(values, vec![vec![0.5 + 5.0, 1.5 + 5.0]]);
    }

    #[test]
    fn colours_follow_the_value_range() {
        let map = Heatmap {
            value_range: (-1.0, 1.0),
            ..Heatmap::default()
        };
        assert_eq!(map.color(1.0), diverging_color(1.0));
        assert_eq!(map.color(5.0), diverging_color(1.0));
        assert_eq!(map.color(-1.0), diverging_color(0.0));
        assert_eq!(map.color(0.0), diverging_color(0.5));
        assert_eq!(map.color(f64::NAN), NO_DATA_COLOR);
    }
}
