//! Figures for people who would rather look than read.
//!
//! The reinforcement-learning reproduction produces numbers (returns per episode, state traces,
//! learned policies); this crate turns them into PNG files that can be put beside the paper's figures:
//!
//! - [`LineChart`]: learning curves (per-episode mean return with a shaded ±std band, see
//!   [`Series::band`]) with horizontal reference lines such as the LQR optimum ([`RefLine`]), or
//!   several state traces in one panel;
//! - [`Heatmap`]: a policy's state-to-action map over a 2-D state box, drawn with a diverging colour
//!   map and a labelled colour bar;
//! - [`Figure`]: several such [`Panel`]s in a grid (e.g. yaw and sway side by side), written with
//!   [`Figure::save_png`].
//!
//! Drawing never panics on awkward data: non-finite samples are skipped (a line breaks at a NaN),
//! an empty series or heat map draws an empty panel, and degenerate ranges are widened. Writing is
//! atomic: the PNG is written to a temporary file in the target directory and renamed over the
//! target, so a crash never leaves half an image. Failures are a [`PlotError`] naming the file.
//!
//! Text is rendered with DejaVu Sans, embedded in the library (see `fonts/` and its licence), so
//! figures look the same on every machine and no system font libraries are needed. Figures of up to
//! 8 megapixels are drawn at twice their size and averaged down, which smooths lines and text.
//! Legends sit below the axes, so they never cover data.
//!
//! `cargo run -p plot --release --example demo` draws an example of every panel kind to
//! `/tmp/plot-demo.png`.
//!
//! ```no_run
//! use plot::{Figure, LineChart, Panel, RefLine, Series};
//!
//! let mean: Vec<f64> = (0..200).map(|e| -100.0 * (-(e as f64) / 40.0).exp() - 10.0).collect();
//! let std = vec![5.0; mean.len()];
//! let chart = LineChart {
//!     title: "Yaw".into(),
//!     x_label: "Episode".into(),
//!     y_label: "Mean return".into(),
//!     series: vec![Series::from_y("NAC", mean).with_band(std)],
//!     ref_lines: vec![RefLine::new("LQR limit", -10.0)],
//!     y_range: None,
//! };
//! let figure = Figure::new(vec![Panel::Lines(chart)], 1);
//! figure.save_png(std::path::Path::new("yaw.png"))?;
//! # Ok::<(), plot::PlotError>(())
//! ```

#![warn(missing_docs)]

mod axes;
mod error;
mod figure;
mod geometry;
mod heatmap;
mod line;
mod picture;
mod style;

pub use error::PlotError;
pub use figure::{Figure, MAX_PIXELS, Panel};
pub use heatmap::{Heatmap, NO_DATA_COLOR};
pub use line::{LineChart, RefLine, Series};
pub use picture::Picture;
pub use style::{PALETTE, diverging_color};
