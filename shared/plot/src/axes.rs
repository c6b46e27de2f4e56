//! The layout shared by all panel kinds: space for the title, tick labels and axis descriptions
//! around a plotting area, sized from the actual text so that nothing is cut off.

use crate::style::{AXIS, LABEL_SIZE, TICK_SIZE, Theme, TickFormat, key_points};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::ops::Range;

/// Sizes (in buffer pixels) of the margins and label areas of one set of axes.
pub(crate) struct AxesFrame {
    title_height: i32,
    x_label_area: i32,
    y_label_area: i32,
    margin_left: i32,
    margin_right: i32,
    margin_bottom: i32,
    /// Maximum number of ticks on the horizontal axis.
    pub x_ticks: usize,
    /// Maximum number of ticks on the vertical axis.
    pub y_ticks: usize,
}

impl AxesFrame {
    /// Lays out axes filling `area`, whose vertical axis spans `y_range`, leaving `margin_right`
    /// pixels free on the right.
    pub fn layout<DB: DrawingBackend>(
        area: &DrawingArea<DB, Shift>,
        theme: &Theme,
        title: &str,
        x_label: &str,
        y_label: &str,
        y_range: (f64, f64),
        margin_right: i32,
    ) -> Result<Self, DrawingAreaErrorKind<DB::ErrorType>> {
        let (width, height) = area.dim_in_pixel();
        let (width, height) = (width as i32, height as i32);
        let tick = theme.tick_len();

        let title_height = if title.is_empty() {
            theme.px(12.0)
        } else {
            area.estimate_text_size(title, &theme.title_font())?.1 as i32 + theme.px(16.0)
        };
        let tick_text_height = area.estimate_text_size("0123456789", &theme.tick_font())?.1 as i32;
        let desc_height = area.estimate_text_size("Xy", &theme.label_font())?.1 as i32;
        let x_label_area = 2 * tick
            + tick_text_height
            + if x_label.is_empty() {
                0
            } else {
                theme.px(8.0) + desc_height
            }
            + theme.px(4.0);
        let margin_bottom = theme.px(4.0);

        let plot_height = height - title_height - x_label_area - margin_bottom;
        let y_ticks = (plot_height / theme.px(48.0)).clamp(3, 9) as usize;
        let format = TickFormat::for_ticks(&key_points(y_range, y_ticks));
        let mut widest = 0;
        for v in key_points(y_range, y_ticks) {
            widest = widest.max(
                area.estimate_text_size(&format.format(v), &theme.tick_font())?
                    .0 as i32,
            );
        }
        let y_label_area = theme.px(4.0)
            + if y_label.is_empty() {
                0
            } else {
                desc_height + theme.px(8.0)
            }
            + widest
            + 2 * tick;
        // plotters draws the rotated y description from the left edge of the label area, and its
        // ink reaches a little further left than its layout box.
        let margin_left = theme.px(3.0)
            + if y_label.is_empty() {
                0
            } else {
                theme.ink_overshoot(LABEL_SIZE)
            };
        let plot_width = width - margin_left - y_label_area - margin_right;
        let x_ticks = (plot_width / theme.px(85.0)).clamp(2, 10) as usize;

        Ok(AxesFrame {
            title_height,
            x_label_area,
            y_label_area,
            margin_left,
            margin_right,
            margin_bottom,
            x_ticks,
            y_ticks,
        })
    }

    /// Moves centred y tick labels down onto their ticks (see [`Theme::centre_correction`]).
    pub fn y_label_offset(theme: &Theme) -> i32 {
        theme.centre_correction(TICK_SIZE)
    }

    /// A chart builder on `area` with this layout.
    pub fn builder<'a, 'b, DB: DrawingBackend>(
        &self,
        area: &'a DrawingArea<DB, Shift>,
    ) -> ChartBuilder<'a, 'b, DB> {
        let mut builder = ChartBuilder::on(area);
        builder
            .margin_top(self.title_height)
            .margin_left(self.margin_left)
            .margin_right(self.margin_right)
            .margin_bottom(self.margin_bottom)
            .x_label_area_size(self.x_label_area)
            .y_label_area_size(self.y_label_area);
        builder
    }

    /// Draws `title` centred above the plotting area whose absolute pixel columns are `plot_x`.
    pub fn draw_title<DB: DrawingBackend>(
        &self,
        panel: &DrawingArea<DB, Shift>,
        plot_x: &Range<i32>,
        theme: &Theme,
        title: &str,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        if title.is_empty() {
            return Ok(());
        }
        let (base_x, _) = panel.get_base_pixel();
        let centre = (plot_x.start + plot_x.end) / 2 - base_x;
        let style = theme.title_font().pos(Pos::new(HPos::Center, VPos::Top));
        panel.draw_text(title, &style, (centre, theme.px(8.0)))
    }
}

/// Draws a box around a plotting area (the axes draw only its left and bottom sides).
pub(crate) fn draw_frame<DB: DrawingBackend>(
    plot: &DrawingArea<DB, Shift>,
    theme: &Theme,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let (w, h) = plot.dim_in_pixel();
    let (w, h) = (w as i32 - 1, h as i32 - 1);
    let style = AXIS.stroke_width(theme.px(1.0) as u32);
    plot.draw(&PathElement::new(
        vec![(0, h), (0, 0), (w, 0), (w, h), (0, h)],
        style,
    ))
}
