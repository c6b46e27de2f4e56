//! Awkward data draws without panicking, and failures are errors that name the file.

use crate::util::Image;
use plot::{Figure, Heatmap, LineChart, Panel, PlotError, RefLine, Series};

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

#[test]
fn nans_infinities_and_ragged_series_draw() {
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
        Series::from_y("one point", vec![2.5]),
        Series::from_y("huge", vec![1e300, -1e300, f64::MAX]),
    ];
    chart.ref_lines = vec![RefLine::new("NaN line", nan), RefLine::new("", 1.0)];
    let image = save(&small(vec![chart.into()]));
    assert_eq!((image.width, image.height), (320, 240));
}

#[test]
fn empty_series_draw_an_empty_panel() {
    let mut empty = LineChart::new("Empty", "Episode", "Return");
    empty.series = vec![Series::default(), Series::from_y("nothing", Vec::new())];
    let bare = LineChart::default();
    let image = save(&small(vec![empty.into(), bare.into()]));
    assert_eq!((image.width, image.height), (640, 240));
}

#[test]
fn fixed_ranges_clip_and_degenerate_ranges_are_widened() {
    let mut clipped = LineChart::new("Clipped", "x", "y");
    clipped.series =
        vec![Series::from_y("wild", vec![-100.0, 100.0, 0.5, -100.0]).with_band(vec![50.0; 4])];
    clipped.ref_lines = vec![RefLine::new("outside", 7.0)];
    clipped.y_range = Some((1.0, 0.0));
    let mut flat = LineChart::new("Flat", "x", "y");
    flat.series = vec![Series::new("constant", vec![3.0, 3.0], vec![2.0, 2.0])];
    flat.y_range = Some((nan(), 1.0));
    save(&small(vec![clipped.into(), flat.into()]));
}

fn nan() -> f64 {
    f64::NAN
}

#[test]
fn awkward_heat_maps_draw() {
    let empty = Heatmap {
        title: "Empty".into(),
        value_range: (-1.0, 1.0),
        ..Heatmap::default()
    };
    let ragged = Heatmap {
        title: "Ragged".into(),
        x_range: (0.0, 0.0),
        y_range: (nan(), 1.0),
        values: vec![vec![0.5], Vec::new(), vec![nan(), f64::INFINITY, -3.0]],
        value_range: (1.0, 1.0),
        value_label: "Action".into(),
        ..Heatmap::default()
    };
    let empty_rows = Heatmap {
        values: vec![Vec::new(); 3],
        ..Heatmap::default()
    };
    save(&Figure {
        columns: 3,
        ..small(vec![empty.into(), ragged.into(), empty_rows.into()])
    });
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
fn an_empty_image_size_is_an_error_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("figure.png");
    let figure = Figure {
        panel_size: (0, 240),
        ..small(vec![LineChart::default().into()])
    };
    let err = figure.save_png(&path).unwrap_err();
    assert!(matches!(err, PlotError::Size { .. }), "{err:?}");
    assert_eq!(err.path(), path);
    assert!(!path.exists());
}

#[test]
fn tiny_panels_and_crowded_legends_draw() {
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
    }
}
