//! Awkward data draws what can be drawn and nothing else, and failures are errors that name the file.

use crate::util::{Image, WHITE, median};
use plot::{Figure, Heatmap, LineChart, NO_DATA_COLOR, PALETTE, Panel, PlotError, RefLine, Series};

fn save(figure: &Figure) -> Image {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("figure.png");
    figure.save_png(&path).unwrap();
    Image::load(&path)
}

fn small(panels: Vec<Panel>) -> Figure {
    Figure {
        panels,
        columns: 2,
        panel_size: (320, 240),
    }
}

/// Whether a pixel is part of a dark grey line: the axes and the box around a plotting area (drawn
/// supersampled, so a thin line comes out in a lighter grey than it was drawn in).
fn line_grey(p: [u8; 3]) -> bool {
    p[0] == p[1] && p[1] == p[2] && p[0] <= 160
}

/// The columns of panel `k` of a row of 320-pixel panels.
fn panel(k: u32) -> (u32, u32) {
    (k * 320, (k + 1) * 320)
}

/// The pixels of `colour` in `columns`, over the whole height.
fn pixels_of(image: &Image, columns: (u32, u32), colour: [u8; 3]) -> Vec<(u32, u32)> {
    image.find(columns, (0, image.height), |p| p == colour)
}

/// The plotting area's box in `columns`: (left, right, top, bottom), the rows and columns where the
/// box's lines run (those with the most dark grey pixels; text and tick marks have far fewer).
fn plot_box(image: &Image, columns: (u32, u32)) -> (u32, u32, u32, u32) {
    let axis = image.find(columns, (0, image.height), line_grey);
    let longest = |coordinate: fn(&(u32, u32)) -> u32| {
        let mut count = std::collections::BTreeMap::new();
        for p in &axis {
            *count.entry(coordinate(p)).or_insert(0u32) += 1;
        }
        let most = count.values().copied().max().expect("axis lines drawn");
        let lines: Vec<u32> = count
            .into_iter()
            .filter(|&(_, n)| n * 10 >= most * 9)
            .map(|(at, _)| at)
            .collect();
        (lines[0], lines[lines.len() - 1])
    };
    let (top, bottom) = longest(|p| p.1);
    let (left, right) = longest(|p| p.0);
    (left, right, top, bottom)
}

/// The pixels of `colour` strictly inside the plotting area's box of `columns` (no text there).
fn inside(image: &Image, columns: (u32, u32), colour: [u8; 3]) -> Vec<(u32, u32)> {
    let (left, right, top, bottom) = plot_box(image, columns);
    image.find((left + 1, right), (top + 1, bottom), |p| p == colour)
}

/// Every pixel of `curve` lies within the plotting area's box (left, right, top, bottom), but for
/// what a line at most 3 pixels wide may reach over its edge: its half-width.
fn assert_inside(curve: &[(u32, u32)], (left, right, top, bottom): (u32, u32, u32, u32)) {
    let outside: Vec<_> = curve
        .iter()
        .filter(|&&(x, y)| x + 2 < left || x > right + 2 || y + 2 < top || y > bottom + 2)
        .collect();
    assert!(
        outside.is_empty(),
        "{} pixels outside {left}..{right} x {top}..{bottom}, e.g. {:?}",
        outside.len(),
        &outside[..outside.len().min(5)]
    );
}

#[test]
fn nans_infinities_and_ragged_series_draw_their_finite_points() {
    let nan = f64::NAN;
    let mut chart = LineChart::new("Gaps", "t [s]", "Theta [rad]");
    chart.series = vec![
        Series::from_y(
            "gaps",
            vec![nan, 1.0, 2.0, nan, 3.0, f64::INFINITY, 4.0, nan],
        )
        .with_band(vec![0.5, nan, 0.5]),
        Series::new("ragged", vec![0.0, 1.0, 2.0, 3.0], vec![1.0, 2.0]),
        Series::from_y("all NaN", vec![nan; 10]).with_band(vec![nan; 10]),
        Series::new("one point", vec![2.5], vec![2.5]),
    ];
    chart.ref_lines = vec![RefLine::new("NaN line", nan), RefLine::new("", 1.0)];
    let image = save(&small(vec![chart.into()]));
    assert_eq!((image.width, image.height), (320, 240));
    // Each series with a finite point is drawn in its colour; the series without one is not drawn.
    // A dot keeps its exact colour in a pixel or two only (the image is drawn supersampled).
    for (k, name, least) in [
        (0, "gaps", 20),
        (1, "ragged", 20),
        (3, "one point (a dot)", 1),
    ] {
        let drawn = inside(&image, panel(0), PALETTE[k]).len();
        assert!(drawn >= least, "{name}: {drawn} pixels in its colour");
    }
    assert_eq!(inside(&image, panel(0), PALETTE[2]), vec![], "all NaN");
}

#[test]
fn a_series_of_values_too_large_for_any_range_still_gets_its_axes() {
    let mut chart = LineChart::new("Huge", "x", "y");
    chart.series = vec![Series::from_y("huge", vec![1e300, -1e300, f64::MAX])];
    let image = save(&small(vec![chart.into()]));
    assert_eq!((image.width, image.height), (320, 240));
    let (left, right, top, bottom) = plot_box(&image, panel(0));
    assert!(
        right - left > 100 && bottom - top > 100,
        "a box of {left}..{right} x {top}..{bottom}"
    );
}

#[test]
fn empty_series_draw_the_axes_and_no_curve() {
    let mut empty = LineChart::new("Empty", "Episode", "Return");
    empty.series = vec![Series::default(), Series::from_y("nothing", Vec::new())];
    let bare = LineChart::default();
    let image = save(&small(vec![empty.into(), bare.into()]));
    assert_eq!((image.width, image.height), (640, 240));
    for k in 0..2 {
        let (left, right, top, bottom) = plot_box(&image, panel(k));
        assert!(
            right - left > 100 && bottom - top > 100,
            "panel {k}: a box of {left}..{right} x {top}..{bottom}"
        );
        for colour in PALETTE {
            assert_eq!(inside(&image, panel(k), colour), vec![], "panel {k}");
        }
    }
}

#[test]
fn a_fixed_range_clips_what_falls_outside_it() {
    let mut chart = LineChart::new("Clipped", "x", "y");
    // No name: the series stays out of the legend, so all its colour is the curve.
    chart.series = vec![Series::from_y("", vec![-100.0, 100.0, 0.5, -100.0])];
    chart.ref_lines = vec![RefLine::new("outside", 7.0)];
    chart.y_range = Some((0.0, 1.0));
    let image = save(&small(vec![chart.into()]));
    let curve = pixels_of(&image, panel(0), PALETTE[0]);
    assert!(curve.len() > 20, "{} pixels of the curve", curve.len());
    assert_inside(&curve, plot_box(&image, panel(0)));
}

/// A series far denser than the pixels (a flight record's thousands of steps across one panel),
/// turning back on itself within a pixel at every sample, stays inside its plotting area: a thick
/// polyline's joins must not shoot out of it.
#[test]
fn a_dense_series_turning_back_at_every_sample_stays_inside_its_box() {
    let n = 6000;
    let chart = |y: Vec<f64>| {
        let mut chart = LineChart::new("Dense", "t [s]", "command");
        chart.series = vec![Series::new("", (0..n).map(|k| k as f64).collect(), y)];
        chart.y_range = Some((-1.0, 1.0));
        chart
    };
    let wobble: Vec<f64> = (0..n)
        .map(|k| {
            let size = ((k * 7919) % 1000) as f64 / 1000.0;
            if k % 2 == 0 { size } else { -size }
        })
        .collect();
    // The box is found on the same axes with a flat line (the dense curve covers its edges).
    let flat = save(&small(vec![chart(vec![0.0; n]).into()]));
    let image = save(&small(vec![chart(wobble).into()]));
    let curve = pixels_of(&image, panel(0), PALETTE[0]);
    assert!(curve.len() > 1000, "{} pixels of the curve", curve.len());
    assert_inside(&curve, plot_box(&flat, panel(0)));
}

#[test]
fn a_reversed_fixed_range_is_put_in_order_and_a_non_finite_one_is_zero_to_one() {
    // A horizontal line at a quarter of the range, with the range given upside down, and one at
    // three quarters of (0, 1), the range that replaces (NaN, 1).
    let line = |y: f64| Series::new("", vec![0.0, 1.0], vec![y, y]);
    let mut reversed = LineChart::new("Reversed", "x", "y");
    reversed.series = vec![line(0.25)];
    reversed.y_range = Some((1.0, 0.0));
    let mut invalid = LineChart::new("Invalid", "x", "y");
    invalid.series = vec![line(0.75)];
    invalid.y_range = Some((f64::NAN, 1.0));
    let image = save(&small(vec![reversed.into(), invalid.into()]));
    for (k, fraction_up) in [(0, 0.25), (1, 0.75)] {
        let (_, _, top, bottom) = plot_box(&image, panel(k));
        let (_, y) = median(&pixels_of(&image, panel(k), PALETTE[0]));
        let expected = bottom as f64 - fraction_up * (bottom - top) as f64;
        assert!(
            (y as f64 - expected).abs() <= 3.0,
            "panel {k}: the line at row {y}, expected {expected:.0} (box rows {top}..{bottom})"
        );
    }
}

#[test]
fn a_single_value_gets_a_range_around_it() {
    let mut flat = LineChart::new("One value", "x", "y");
    flat.series = vec![Series::from_y("", vec![2.0])];
    let image = save(&small(vec![flat.into()]));
    let (left, right, top, bottom) = plot_box(&image, panel(0));
    let (x, y) = median(&pixels_of(&image, panel(0), PALETTE[0]));
    let centre = ((left + right) as f64 / 2.0, (top + bottom) as f64 / 2.0);
    assert!(
        (x as f64 - centre.0).abs() <= 3.0 && (y as f64 - centre.1).abs() <= 3.0,
        "the point at ({x}, {y}), the box's centre at {centre:?}"
    );
}

#[test]
fn heat_maps_draw_missing_and_non_finite_cells_as_no_data_and_empty_maps_no_cells() {
    let nan = f64::NAN;
    let empty = Heatmap {
        title: "Empty".into(),
        value_range: (-1.0, 1.0),
        ..Heatmap::default()
    };
    // 3 x 3 cells: two finite (both below the degenerate value range: its low end's colour), seven
    // missing or not finite.
    let ragged = Heatmap {
        title: "Ragged".into(),
        x_range: (0.0, 0.0),
        y_range: (nan, 1.0),
        values: vec![vec![0.5], Vec::new(), vec![nan, f64::INFINITY, -3.0]],
        value_range: (1.0, 1.0),
        value_label: "Action".into(),
        ..Heatmap::default()
    };
    let empty_rows = Heatmap {
        values: vec![Vec::new(); 3],
        ..Heatmap::default()
    };
    let image = save(&Figure {
        columns: 3,
        ..small(vec![empty.into(), ragged.into(), empty_rows.into()])
    });
    assert_eq!((image.width, image.height), (960, 240));
    let low_end = plot::diverging_color(0.0);
    let count = |k: u32, colour: [u8; 3]| inside(&image, panel(k), colour).len();
    for (k, what) in [(0, "the empty map"), (2, "rows without values")] {
        assert_eq!(count(k, NO_DATA_COLOR), 0, "{what} draws no cell");
        assert_eq!(count(k, low_end), 0, "{what} draws no cell");
    }
    let (no_data, finite) = (count(1, NO_DATA_COLOR), count(1, low_end));
    assert!(finite > 100, "two finite cells: {finite} pixels");
    assert!(
        no_data > 3 * finite,
        "seven no-data cells ({no_data} pixels) against two finite ones ({finite} pixels)"
    );
}

#[test]
fn a_figure_without_panels_is_one_blank_panel() {
    let image = save(&small(Vec::new()));
    assert_eq!((image.width, image.height), (320, 240));
    assert!(image.rgb.iter().all(|&c| c == 255));
}

#[test]
fn a_missing_directory_is_an_error_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("no-such-dir").join("figure.png");
    let err = small(vec![LineChart::default().into()])
        .save_png(&path)
        .unwrap_err();
    assert!(matches!(err, PlotError::Write { .. }), "{err:?}");
    assert_eq!(err.path(), path);
    assert!(
        err.to_string().contains(&path.display().to_string()),
        "{err}"
    );
}

#[test]
fn an_empty_image_size_is_an_error_naming_the_file_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("figure.png");
    let figure = Figure {
        panel_size: (0, 240),
        ..small(vec![LineChart::default().into()])
    };
    let err = figure.save_png(&path).unwrap_err();
    assert!(matches!(err, PlotError::Size { .. }), "{err:?}");
    assert_eq!(err.path(), path);
    assert!(
        err.to_string().contains(&path.display().to_string()),
        "{err}"
    );
    assert!(!path.exists());
}

#[test]
fn tiny_panels_keep_their_size_and_a_crowded_legend_leaves_the_curves_room() {
    let mut crowded = LineChart::new("Many trials", "t [s]", "Theta [rad]");
    crowded.series = (0..60)
        .map(|i| Series::from_y(format!("trial {i}"), vec![i as f64, 0.0]))
        .collect();
    let map = Heatmap {
        values: vec![vec![0.0, 1.0]],
        value_range: (-1.0, 1.0),
        value_label: "Action".into(),
        ..Heatmap::default()
    };
    for size in [(1, 1), (40, 30), (120, 80), (320, 240)] {
        let figure = Figure {
            panel_size: size,
            ..small(vec![crowded.clone().into(), map.clone().into()])
        };
        let image = save(&figure);
        assert_eq!((image.width, image.height), (2 * size.0, size.1));
        if size == (320, 240) {
            // The legend takes at most a third of the panel: the axes keep most of the rest.
            let (_, _, top, bottom) = plot_box(&image, panel(0));
            assert!(
                bottom - top >= 240 / 3,
                "the axes' box: rows {top}..{bottom} of 240"
            );
            let above_the_axis = image
                .find(panel(0), (top, bottom), |p| {
                    p != WHITE && PALETTE.contains(&p)
                })
                .len();
            assert!(above_the_axis > 100, "{above_the_axis} pixels of curves");
        }
    }
}
