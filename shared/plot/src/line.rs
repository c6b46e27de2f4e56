//! Line charts: learning curves with ±std bands and reference lines, or state traces.

use crate::axes::{AxesFrame, draw_frame};
use crate::geometry::{Point, Rect, clip_polygon, clip_polyline, runs};
use crate::style::{
    AXIS, GRID, PALETTE, REF_COLORS, TEXT, TICK_SIZE, Theme, TickFormat, key_points, rgb,
    usable_range,
};
use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// One curve: `y` over `x`, optionally with a shaded band `y ± band`.
///
/// Samples are paired by index; extra samples in the longer of `x`, `y` (and `band`) are ignored.
/// A sample with a non-finite `x` or `y` is skipped and breaks the line there; a non-finite band
/// value leaves a gap in the band only.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Series {
    /// The name shown in the legend; an empty name keeps the series out of the legend.
    pub name: String,
    /// Abscissae, e.g. episode numbers or times in seconds.
    pub x: Vec<f64>,
    /// Ordinates, e.g. the mean return over runs.
    pub y: Vec<f64>,
    /// Half-width of the shaded band around `y`, e.g. the standard deviation over runs.
    pub band: Option<Vec<f64>>,
}

impl Series {
    /// A series of the points `(x[i], y[i])` without a band.
    pub fn new(name: impl Into<String>, x: Vec<f64>, y: Vec<f64>) -> Self {
        Series {
            name: name.into(),
            x,
            y,
            band: None,
        }
    }

    /// A series over the sample index: `x = 0, 1, 2, ...` (e.g. one value per episode).
    pub fn from_y(name: impl Into<String>, y: Vec<f64>) -> Self {
        let x = (0..y.len()).map(|i| i as f64).collect();
        Series::new(name, x, y)
    }

    /// The same series with a shaded band `y ± band` (half-widths; their sign is ignored).
    pub fn with_band(mut self, band: Vec<f64>) -> Self {
        self.band = Some(band);
        self
    }

    fn len(&self) -> usize {
        self.x.len().min(self.y.len())
    }

    /// The runs of finite points of the line.
    fn line_runs(&self) -> Vec<Vec<Point>> {
        let points: Vec<Point> = self.x.iter().copied().zip(self.y.iter().copied()).collect();
        runs(&points, |p| p.0.is_finite() && p.1.is_finite())
    }

    /// The runs of finite `(x, y, half-width)` of the band.
    fn band_runs(&self) -> Vec<Vec<(f64, f64, f64)>> {
        let Some(band) = &self.band else {
            return Vec::new();
        };
        let samples: Vec<(f64, f64, f64)> = (0..self.len().min(band.len()))
            .map(|i| (self.x[i], self.y[i], band[i].abs()))
            .collect();
        runs(&samples, |s| {
            s.0.is_finite() && s.1.is_finite() && s.2.is_finite()
        })
    }
}

/// A horizontal reference line across the whole chart, e.g. the return of the LQR optimum.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RefLine {
    /// The name shown in the legend; an empty name keeps the line out of the legend.
    pub name: String,
    /// Where the line is drawn; a non-finite value draws nothing.
    pub y: f64,
}

impl RefLine {
    /// A reference line at `y`.
    pub fn new(name: impl Into<String>, y: f64) -> Self {
        RefLine {
            name: name.into(),
            y,
        }
    }
}

/// A panel of curves sharing one pair of axes, with a legend below the axes.
///
/// Series get the colours of [`PALETTE`](crate::PALETTE) in order; bands are drawn translucent in
/// the colour of their series, reference lines dashed in black and dark greys.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LineChart {
    /// Drawn above the axes; may be empty.
    pub title: String,
    /// Description of the horizontal axis, e.g. "Episode".
    pub x_label: String,
    /// Description of the vertical axis, e.g. "Mean return".
    pub y_label: String,
    /// The curves, drawn in order (later ones on top).
    pub series: Vec<Series>,
    /// Horizontal reference lines.
    pub ref_lines: Vec<RefLine>,
    /// A fixed vertical range `(min, max)`; `None` fits the data, bands and reference lines.
    /// Whatever falls outside a fixed range is clipped.
    pub y_range: Option<(f64, f64)>,
}

impl LineChart {
    /// An empty chart with a title and axis descriptions; push series and reference lines into it.
    pub fn new(
        title: impl Into<String>,
        x_label: impl Into<String>,
        y_label: impl Into<String>,
    ) -> Self {
        LineChart {
            title: title.into(),
            x_label: x_label.into(),
            y_label: y_label.into(),
            ..LineChart::default()
        }
    }

    /// The horizontal range: that of all finite samples, `(0, 1)` if there are none.
    fn x_extent(&self) -> (f64, f64) {
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for s in &self.series {
            for run in s.line_runs() {
                for (x, _) in run {
                    lo = lo.min(x);
                    hi = hi.max(x);
                }
            }
        }
        usable_range((lo, hi), (0.0, 1.0))
    }

    /// The vertical range: the fixed one, or that of all finite samples, band edges and reference
    /// lines with a margin of 5 % on each side.
    fn y_extent(&self) -> (f64, f64) {
        if let Some(range) = self.y_range {
            return usable_range(range, (0.0, 1.0));
        }
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        let mut include = |v: f64| {
            if v.is_finite() {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        };
        for s in &self.series {
            for run in s.line_runs() {
                run.iter().for_each(|p| include(p.1));
            }
            for run in s.band_runs() {
                run.iter().for_each(|&(_, y, b)| {
                    include(y - b);
                    include(y + b);
                });
            }
        }
        self.ref_lines.iter().for_each(|r| include(r.y));
        let (lo, hi) = usable_range((lo, hi), (0.0, 1.0));
        let pad = (hi - lo) * 0.05;
        usable_range((lo - pad, hi + pad), (lo, hi))
    }
}

/// What a legend entry shows beside its name.
enum Swatch {
    Line { color: RGBColor, band: bool },
    Dashed { color: RGBColor },
}

struct LegendEntry<'a> {
    name: &'a str,
    swatch: Swatch,
}

fn series_color(i: usize) -> RGBColor {
    rgb(PALETTE[i % PALETTE.len()])
}

fn ref_color(i: usize) -> RGBColor {
    rgb(REF_COLORS[i % REF_COLORS.len()])
}

const BAND_ALPHA: f64 = 0.22;

/// Draws `chart` into `area`, which it fills.
pub(crate) fn draw<DB: DrawingBackend>(
    chart: &LineChart,
    area: &DrawingArea<DB, Shift>,
    theme: &Theme,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let (width, height) = area.dim_in_pixel();
    let (width, height) = (width as i32, height as i32);
    let x_range = chart.x_extent();
    let y_range = chart.y_extent();

    // The legend lists what is drawn: named series with a finite sample, named reference lines
    // inside the vertical range.
    let ref_visible = |r: &RefLine| r.y.is_finite() && r.y >= y_range.0 && r.y <= y_range.1;
    let mut legend: Vec<LegendEntry> = Vec::new();
    for (i, s) in chart.series.iter().enumerate() {
        if !s.name.is_empty() && !s.line_runs().is_empty() {
            let band = !s.band_runs().is_empty();
            let color = series_color(i);
            legend.push(LegendEntry {
                name: &s.name,
                swatch: Swatch::Line { color, band },
            });
        }
    }
    for (i, r) in chart.ref_lines.iter().enumerate() {
        if !r.name.is_empty() && ref_visible(r) {
            legend.push(LegendEntry {
                name: &r.name,
                swatch: Swatch::Dashed {
                    color: ref_color(i),
                },
            });
        }
    }
    let mut legend_rows = layout_legend(area, &legend, theme, width - 2 * theme.px(10.0))?;
    // The legend takes at most a third of the panel; entries beyond that are left out.
    legend_rows.truncate(((height / 3 - theme.px(8.0)) / legend_row_height(theme)).max(1) as usize);
    let legend_height = if legend_rows.is_empty() {
        0
    } else {
        legend_rows.len() as i32 * legend_row_height(theme) + theme.px(8.0)
    };
    let (chart_area, legend_area) = area.split_vertically(height - legend_height);

    let frame = AxesFrame::layout(
        &chart_area,
        theme,
        &chart.title,
        &chart.x_label,
        &chart.y_label,
        y_range,
        theme.px(22.0),
    )?;
    let y_ticks = key_points(y_range, frame.y_ticks);
    let y_format = TickFormat::for_ticks(&y_ticks);
    let x_ticks = key_points(x_range, frame.x_ticks);
    let x_format = TickFormat::for_ticks(&x_ticks);
    let x_fmt = |v: &f64| x_format.format(*v);
    let y_fmt = |v: &f64| y_format.format(*v);

    let mut ctx = frame
        .builder(&chart_area)
        .build_cartesian_2d(x_range.0..x_range.1, y_range.0..y_range.1)?;
    let mut mesh = ctx.configure_mesh();
    mesh.x_labels(frame.x_ticks)
        .y_labels(frame.y_ticks)
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .y_label_offset(AxesFrame::y_label_offset(theme))
        .label_style(theme.tick_font())
        .axis_desc_style(theme.label_font())
        .bold_line_style(GRID.stroke_width(theme.px(1.0) as u32))
        .light_line_style(TRANSPARENT)
        .axis_style(AXIS.stroke_width(theme.px(1.0) as u32))
        .set_all_tick_mark_size(theme.tick_len());
    if !chart.x_label.is_empty() {
        mesh.x_desc(chart.x_label.as_str());
    }
    if !chart.y_label.is_empty() {
        mesh.y_desc(chart.y_label.as_str());
    }
    mesh.draw()?;

    let clip = Rect {
        x: x_range,
        y: y_range,
    };
    let lw = theme.line_width();
    for (i, s) in chart.series.iter().enumerate() {
        let fill = series_color(i).mix(BAND_ALPHA).filled();
        for run in s.band_runs() {
            let mut outline: Vec<Point> = run.iter().map(|&(x, y, b)| (x, y + b)).collect();
            outline.extend(run.iter().rev().map(|&(x, y, b)| (x, y - b)));
            let polygon = clip_polygon(&outline, &clip);
            if polygon.len() >= 3 {
                ctx.draw_series(std::iter::once(Polygon::new(polygon, fill)))?;
            }
        }
    }
    for (i, r) in chart.ref_lines.iter().enumerate() {
        if ref_visible(r) {
            let style = ref_color(i).stroke_width(lw);
            let points = vec![(x_range.0, r.y), (x_range.1, r.y)];
            ctx.draw_series(std::iter::once(DashedPathElement::new(
                points,
                theme.px(7.0),
                theme.px(4.0),
                style,
            )))?;
        }
    }
    for (i, s) in chart.series.iter().enumerate() {
        let color = series_color(i);
        for run in s.line_runs() {
            for part in clip_polyline(&run, &clip) {
                if part.len() == 1 {
                    let dot = Circle::new(part[0], theme.px(2.0), color.filled());
                    ctx.draw_series(std::iter::once(dot))?;
                } else {
                    // Segment by segment: plotters joins the segments of a thick polyline with
                    // miters, which shoot far out of the chart where a dense series turns back
                    // on itself within a pixel or two. A segment whose ends fall on the same
                    // pixel draws nothing and is left out.
                    let style = color.stroke_width(lw);
                    let pixels: Vec<_> = part.iter().map(|p| ctx.backend_coord(p)).collect();
                    let segments = part
                        .windows(2)
                        .zip(pixels.windows(2))
                        .filter(|(_, px)| px[0] != px[1])
                        .map(|(ends, _)| PathElement::new(ends.to_vec(), style));
                    ctx.draw_series(segments)?;
                }
            }
        }
    }
    draw_frame(&ctx.plotting_area().strip_coord_spec(), theme)?;
    frame.draw_title(
        area,
        &ctx.plotting_area().get_pixel_range().0,
        theme,
        &chart.title,
    )?;

    draw_legend(&legend_area, &legend, &legend_rows, theme)
}

/// One row of the legend: the entries' indices and widths in pixels.
type LegendRow = Vec<(usize, i32)>;

fn legend_row_height(theme: &Theme) -> i32 {
    theme.px(20.0)
}

fn swatch_width(theme: &Theme) -> i32 {
    theme.px(26.0)
}

/// Splits the legend entries into rows no wider than `max_width`; each row lists the entries'
/// indices and widths.
fn layout_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    entries: &[LegendEntry],
    theme: &Theme,
    max_width: i32,
) -> Result<Vec<LegendRow>, DrawingAreaErrorKind<DB::ErrorType>> {
    let font = theme.legend_font();
    let spacing = theme.px(18.0);
    let mut rows: Vec<LegendRow> = Vec::new();
    let mut row_width = 0;
    for (i, entry) in entries.iter().enumerate() {
        let (text_w, _) = area.estimate_text_size(entry.name, &font)?;
        let w = swatch_width(theme) + theme.px(6.0) + text_w as i32;
        match rows.last_mut() {
            Some(row) if row_width + spacing + w <= max_width => {
                row.push((i, w));
                row_width += spacing + w;
            }
            _ => {
                rows.push(vec![(i, w)]);
                row_width = w;
            }
        }
    }
    Ok(rows)
}

fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    entries: &[LegendEntry],
    rows: &[LegendRow],
    theme: &Theme,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let (width, _) = area.dim_in_pixel();
    let spacing = theme.px(18.0);
    let row_h = legend_row_height(theme);
    let sw = swatch_width(theme);
    let font = theme
        .legend_font()
        .color(&TEXT)
        .pos(Pos::new(HPos::Left, VPos::Center));
    for (r, row) in rows.iter().enumerate() {
        let row_width: i32 =
            row.iter().map(|(_, w)| w).sum::<i32>() + spacing * (row.len() as i32 - 1);
        let mut x = (width as i32 - row_width) / 2;
        let y = theme.px(2.0) + r as i32 * row_h + row_h / 2;
        for &(i, w) in row {
            let entry = &entries[i];
            match entry.swatch {
                Swatch::Line { color, band } => {
                    if band {
                        let half = theme.px(6.0);
                        area.draw(&Rectangle::new(
                            [(x, y - half), (x + sw, y + half)],
                            color.mix(BAND_ALPHA).filled(),
                        ))?;
                    }
                    area.draw(&PathElement::new(
                        vec![(x, y), (x + sw, y)],
                        color.stroke_width(theme.line_width()),
                    ))?;
                }
                Swatch::Dashed { color } => {
                    area.draw(&DashedPathElement::new(
                        vec![(x, y), (x + sw, y)],
                        theme.px(7.0),
                        theme.px(4.0),
                        color.stroke_width(theme.line_width()),
                    ))?;
                }
            }
            let text_y = y + theme.centre_correction(TICK_SIZE);
            area.draw_text(entry.name, &font, (x + sw + theme.px(6.0), text_y))?;
            x += w + spacing;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extents_cover_bands_and_reference_lines() {
        let mut chart = LineChart::new("", "", "");
        chart
            .series
            .push(Series::from_y("a", vec![0.0, 1.0, f64::NAN, 2.0]).with_band(vec![1.0; 4]));
        chart.ref_lines.push(RefLine::new("limit", 5.0));
        assert_eq!(chart.x_extent(), (0.0, 3.0));
        let (lo, hi) = chart.y_extent();
        assert!(lo < -1.0 && hi > 5.0, "{lo} {hi}");
        chart.y_range = Some((0.0, 2.0));
        assert_eq!(chart.y_extent(), (0.0, 2.0));
    }

    #[test]
    fn empty_chart_has_unit_extents() {
        let chart = LineChart::new("", "", "");
        assert_eq!(chart.x_extent(), (0.0, 1.0));
        let (lo, hi) = chart.y_extent();
        assert!(lo < 0.0 && hi > 1.0);
    }
}
