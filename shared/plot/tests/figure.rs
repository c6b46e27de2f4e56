//! A figure is written as a PNG of the grid's size, every panel shows something, and heat maps
//! colour their cells by value.

use crate::util::{Image, WHITE, median};
use plot::{Figure, Heatmap, LineChart, PALETTE, Panel, RefLine, Series};

fn learning_curve(title: &str, limit: f64) -> LineChart {
    let episodes = 120;
    let mean: Vec<f64> = (0..episodes)
        .map(|e| limit - 80.0 * (-(e as f64) / 25.0).exp())
        .collect();
    let std: Vec<f64> = (0..episodes)
        .map(|e| 4.0 + 20.0 * (-(e as f64) / 30.0).exp())
        .collect();
    LineChart {
        series: vec![Series::from_y("NAC", mean).with_band(std)],
        ref_lines: vec![RefLine::new("LQR limit", limit)],
        ..LineChart::new(title, "Episode", "Mean return")
    }
}

/// A 2 × 2 map: minimum at the bottom left, maximum at the top right, zero elsewhere.
fn corner_map() -> Heatmap {
    Heatmap {
        title: "Policy".into(),
        x_label: "x_g".into(),
        y_label: "dx_g/dt".into(),
        x_range: (-0.5, 0.5),
        y_range: (-0.5, 0.5),
        values: vec![vec![-1.0, 0.0], vec![0.0, 1.0]],
        value_range: (-1.0, 1.0),
        value_label: "Action".into(),
    }
}

fn three_panels() -> Figure {
    Figure {
        panels: vec![
            Panel::Lines(learning_curve("Yaw", -10.0)),
            Panel::Lines(learning_curve("Sway", -20.0)),
            Panel::Heat(corner_map()),
        ],
        columns: 3,
        panel_size: (480, 360),
    }
}

#[test]
fn figure_is_a_png_of_the_grid_size() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("figure.png");
    let figure = three_panels();
    figure.save_png(&path).unwrap();

    let image = Image::load(&path);
    assert_eq!((image.width, image.height), (3 * 480, 360));
    assert_eq!(figure.pixel_size(), (3 * 480, 360));
}

#[test]
fn every_panel_is_drawn_on() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("figure.png");
    three_panels().save_png(&path).unwrap();
    let image = Image::load(&path);

    for panel in 0..3 {
        let columns = (panel * 480, (panel + 1) * 480);
        let drawn = image.find(columns, (0, 360), |p| p != WHITE).len();
        assert!(
            drawn > 480 * 360 / 50,
            "panel {panel}: only {drawn} pixels drawn"
        );
    }
    // The curves are drawn in the first palette colour (their interior is not smoothed away).
    for panel in 0..2 {
        let columns = (panel * 480, (panel + 1) * 480);
        let curve = image.find(columns, (0, 360), |p| p == PALETTE[0]).len();
        assert!(
            curve > 50,
            "panel {panel}: {curve} pixels in the series colour"
        );
    }
}

#[test]
fn heat_map_colours_follow_its_values() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("figure.png");
    three_panels().save_png(&path).unwrap();
    let image = Image::load(&path);
    let map = corner_map();
    let panel = (2 * 480, 3 * 480);

    let (max_colour, min_colour, mid_colour) = (map.color(1.0), map.color(-1.0), map.color(0.0));
    assert_eq!(
        max_colour,
        plot::diverging_color(1.0),
        "the maximum takes the red end"
    );
    assert_eq!(
        min_colour,
        plot::diverging_color(0.0),
        "the minimum takes the blue end"
    );

    let max_cell = image.find(panel, (0, 360), |p| p == max_colour);
    let min_cell = image.find(panel, (0, 360), |p| p == min_colour);
    assert!(
        max_cell.len() > 2000,
        "{} pixels of the maximum colour",
        max_cell.len()
    );
    assert!(
        min_cell.len() > 2000,
        "{} pixels of the minimum colour",
        min_cell.len()
    );
    let (max_x, max_y) = median(&max_cell);
    let (min_x, min_y) = median(&min_cell);
    assert!(
        max_x > min_x && max_y < min_y,
        "maximum at ({max_x}, {max_y}) is not above right of the minimum at ({min_x}, {min_y})"
    );
    // The other two cells hold zero: the middle of the colour map.
    assert_eq!(image.pixel(min_x, max_y), mid_colour, "top-left cell");
    assert_eq!(image.pixel(max_x, min_y), mid_colour, "bottom-right cell");
}

#[test]
fn saving_replaces_an_existing_file_and_leaves_no_temporary_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("figure.png");
    std::fs::write(&path, b"not a png").unwrap();
    let figure = Figure {
        panel_size: (320, 240),
        ..Figure::new(vec![learning_curve("Yaw", -10.0).into()], 1)
    };
    figure.save_png(&path).unwrap();

    assert_eq!(
        (Image::load(&path).width, Image::load(&path).height),
        (320, 240)
    );
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names, vec![std::ffi::OsString::from("figure.png")]);
}
