//! Fonts, colours, sizes and number formatting shared by the panel kinds.

use plotters::coord::ranged1d::{KeyPointHint, Ranged};
use plotters::coord::types::RangedCoordf64;
use plotters::style::{FontFamily, FontStyle, RGBColor, TextStyle};
use std::sync::OnceLock;

/// DejaVu Sans 2.37 (Bitstream Vera licence, see `fonts/LICENSE-DejaVu.txt`).
static DEJAVU_SANS: &[u8] = include_bytes!("../fonts/DejaVuSans.ttf");

/// The family name the embedded font is registered under; unusual so that no other user of plotters
/// in the same process replaces it.
const FONT_FAMILY: &str = "cabletrack-plot-dejavu-sans";

/// Registers the embedded font with plotters (once per process).
pub(crate) fn ensure_font() -> Result<(), String> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(FONT_FAMILY, FontStyle::Normal, DEJAVU_SANS).is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err("the embedded DejaVu Sans font could not be parsed".to_string())
    }
}

/// The colours of successive series in a line chart (matplotlib's "tab10"); series beyond the tenth
/// reuse them from the start.
pub const PALETTE: [[u8; 3]; 10] = [
    [0x1f, 0x77, 0xb4],
    [0xff, 0x7f, 0x0e],
    [0x2c, 0xa0, 0x2c],
    [0xd6, 0x27, 0x28],
    [0x94, 0x67, 0xbd],
    [0x8c, 0x56, 0x4b],
    [0xe3, 0x77, 0xc2],
    [0x7f, 0x7f, 0x7f],
    [0xbc, 0xbd, 0x22],
    [0x17, 0xbe, 0xcf],
];

/// Colours of reference lines (dashed): black first, then dark greys and muted colours.
pub(crate) const REF_COLORS: [[u8; 3]; 4] = [
    [0x00, 0x00, 0x00],
    [0x55, 0x55, 0x55],
    [0x8b, 0x00, 0x00],
    [0x00, 0x00, 0x8b],
];

/// ColorBrewer "RdBu" with 11 classes, from low (dark blue) through white to high (dark red).
const DIVERGING: [[u8; 3]; 11] = [
    [0x05, 0x30, 0x61],
    [0x21, 0x66, 0xac],
    [0x43, 0x93, 0xc3],
    [0x92, 0xc5, 0xde],
    [0xd1, 0xe5, 0xf0],
    [0xf7, 0xf7, 0xf7],
    [0xfd, 0xdb, 0xc7],
    [0xf4, 0xa5, 0x82],
    [0xd6, 0x60, 0x4d],
    [0xb2, 0x18, 0x2b],
    [0x67, 0x00, 0x1f],
];

/// The diverging colour map used by heat maps: `t = 0` is dark blue, `0.5` near-white, `1` dark red
/// (ColorBrewer RdBu, interpolated linearly). `t` is clamped to `[0, 1]`; NaN gives the middle.
pub fn diverging_color(t: f64) -> [u8; 3] {
    let t = if t.is_nan() { 0.5 } else { t.clamp(0.0, 1.0) };
    let pos = t * (DIVERGING.len() - 1) as f64;
    let i = (pos.floor() as usize).min(DIVERGING.len() - 2);
    let f = pos - i as f64;
    let (a, b) = (DIVERGING[i], DIVERGING[i + 1]);
    let mix = |k: usize| (f64::from(a[k]) + (f64::from(b[k]) - f64::from(a[k])) * f).round() as u8;
    [mix(0), mix(1), mix(2)]
}

pub(crate) fn rgb(c: [u8; 3]) -> RGBColor {
    RGBColor(c[0], c[1], c[2])
}

pub(crate) const TEXT: RGBColor = RGBColor(0x22, 0x22, 0x22);
pub(crate) const AXIS: RGBColor = RGBColor(0x33, 0x33, 0x33);
pub(crate) const GRID: RGBColor = RGBColor(0xe3, 0xe3, 0xe3);

/// Nominal font sizes (pixels of a 640 × 420 panel).
pub(crate) const TITLE_SIZE: f64 = 17.0;
pub(crate) const LABEL_SIZE: f64 = 14.5;
pub(crate) const TICK_SIZE: f64 = 12.5;

/// Sizes in pixels of the (supersampled) drawing buffer for one panel.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Theme {
    /// Pixels per nominal pixel: grows with the panel size and the supersampling factor.
    pub scale: f64,
}

impl Theme {
    /// A theme for a panel of `size` final pixels drawn `supersample` times larger.
    pub fn new(size: (u32, u32), supersample: u32) -> Self {
        let fit = (f64::from(size.0) / 640.0).min(f64::from(size.1) / 420.0);
        Theme {
            scale: fit.clamp(0.5, 4.0) * f64::from(supersample),
        }
    }

    /// `nominal` pixels at this theme's scale, at least 1.
    pub fn px(&self, nominal: f64) -> i32 {
        ((nominal * self.scale).round() as i32).max(1)
    }

    fn font(&self, nominal: f64) -> TextStyle<'static> {
        TextStyle::from((FontFamily::Name(FONT_FAMILY), nominal * self.scale)).color(&TEXT)
    }

    pub fn title_font(&self) -> TextStyle<'static> {
        self.font(TITLE_SIZE)
    }

    pub fn label_font(&self) -> TextStyle<'static> {
        self.font(LABEL_SIZE)
    }

    pub fn tick_font(&self) -> TextStyle<'static> {
        self.font(TICK_SIZE)
    }

    pub fn legend_font(&self) -> TextStyle<'static> {
        self.font(TICK_SIZE)
    }

    /// How far plotters' `VPos::Center` places text of `nominal` size above its anchor, to be added
    /// to the anchor. plotters' ab_glyph backend puts the baseline half a font size below the top of
    /// the text's layout box, so centred digits sit about a fifth of the size too high.
    pub fn centre_correction(&self, nominal: f64) -> i32 {
        (0.22 * nominal * self.scale).round() as i32
    }

    /// How far the ink of text of `nominal` size anchored at its top (`VPos::Top`) reaches above
    /// the anchor (rotated text: to the left of it).
    pub fn ink_overshoot(&self, nominal: f64) -> i32 {
        (0.2 * nominal * self.scale).ceil() as i32
    }

    /// Width of data lines.
    pub fn line_width(&self) -> u32 {
        self.px(1.8) as u32
    }

    /// Length of axis tick marks.
    pub fn tick_len(&self) -> i32 {
        self.px(4.0)
    }
}

/// A finite, non-empty interval: `range` if it is usable, widened if it has zero width, `fallback`
/// if either end is not finite.
pub(crate) fn usable_range(range: (f64, f64), fallback: (f64, f64)) -> (f64, f64) {
    let (a, b) = range;
    if !a.is_finite() || !b.is_finite() {
        return fallback;
    }
    let (lo, hi) = (a.min(b), a.max(b));
    if hi - lo > f64::EPSILON * lo.abs().max(hi.abs()).max(1e-300) && (hi - lo).is_finite() {
        (lo, hi)
    } else if (hi - lo).is_finite() {
        let pad = if lo == 0.0 { 0.5 } else { lo.abs() * 0.05 };
        (lo - pad, hi + pad)
    } else {
        fallback
    }
}

/// The tick positions plotters chooses for `range` with at most `max` ticks.
pub(crate) fn key_points(range: (f64, f64), max: usize) -> Vec<f64> {
    let coord = RangedCoordf64::from(range.0..range.1);
    coord.key_points(max.max(1).max_num_points())
}

/// Formats tick values: the fewest decimals (up to 6) that show every tick exactly, scientific
/// notation for very large or very small magnitudes, and a typographic minus sign.
#[derive(Clone, Copy, Debug)]
pub(crate) struct TickFormat {
    decimals: usize,
    scientific: bool,
    /// Values closer to zero than this are rounding noise of the tick computation and shown as 0.
    zero: f64,
}

impl TickFormat {
    pub fn for_ticks(ticks: &[f64]) -> Self {
        let step = ticks
            .windows(2)
            .map(|w| (w[1] - w[0]).abs())
            .filter(|d| *d > 0.0)
            .fold(f64::INFINITY, f64::min);
        let zero = if step.is_finite() { step * 1e-6 } else { 0.0 };
        let ticks: Vec<f64> = ticks
            .iter()
            .map(|&v| if v.abs() < zero { 0.0 } else { v })
            .collect();
        let largest = ticks.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        let scientific = largest >= 1e6 || (largest > 0.0 && largest < 1e-3);
        let mut format = TickFormat {
            decimals: 6,
            scientific,
            zero,
        };
        let tolerance = |v: f64| {
            if step.is_finite() {
                step * 1e-6
            } else {
                v.abs() * 1e-9
            }
        };
        if let Some(decimals) = (0..6).find(|&d| {
            let candidate = TickFormat {
                decimals: d,
                ..format
            };
            ticks.iter().all(|&v| {
                let shown: f64 = candidate.ascii(v).parse().unwrap_or(f64::NAN);
                (shown - v).abs() <= tolerance(v)
            })
        }) {
            format.decimals = decimals;
        }
        format
    }

    /// The value as Rust prints it, with an ASCII minus.
    fn ascii(&self, v: f64) -> String {
        // `+ 0.0` turns -0.0 into 0.0.
        let v = if v.abs() < self.zero { 0.0 } else { v + 0.0 };
        if self.scientific {
            if v == 0.0 {
                "0".to_string()
            } else {
                format!("{:.*e}", self.decimals, v)
            }
        } else {
            format!("{:.*}", self.decimals, v)
        }
    }

    pub fn format(&self, v: f64) -> String {
        let text = self.ascii(v);
        // A value that rounds to zero is shown without a sign.
        let text = match text.strip_prefix('-') {
            Some(unsigned) if unsigned.chars().all(|c| c == '0' || c == '.') => {
                unsigned.to_string()
            }
            _ => text,
        };
        text.replace('-', "\u{2212}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn diverging_ends_and_middle() {
        assert_eq!(diverging_color(0.0), DIVERGING[0]);
        assert_eq!(diverging_color(1.0), DIVERGING[10]);
        assert_eq!(diverging_color(0.5), DIVERGING[5]);
        assert_eq!(diverging_color(2.0), DIVERGING[10]);
        assert_eq!(diverging_color(f64::NAN), DIVERGING[5]);
    }

    #[test]
    fn tick_labels_use_just_enough_decimals() {
        let f = TickFormat::for_ticks(&[-0.4, -0.2, 0.0, 0.2, 0.4]);
        assert_eq!(f.format(-0.4), "\u{2212}0.4");
        assert_eq!(f.format(0.0), "0.0");
        let f = TickFormat::for_ticks(&[-1000.0, -500.0, 0.0]);
        assert_eq!(f.format(-500.0), "\u{2212}500");
        assert_eq!(f.format(-0.0), "0");
        let f = TickFormat::for_ticks(&[0.0, 1e8, 2e8, 3e8]);
        assert_eq!(f.format(2e8), "2e8");
        let f = TickFormat::for_ticks(&[-1e-5, -5e-6, -1.7e-21, 5e-6, 1e-5]);
        assert_eq!(f.format(-5e-6), "\u{2212}5e\u{2212}6");
        assert_eq!(f.format(-1.7e-21), "0");
        let f = TickFormat::for_ticks(&[0.0, 2.5e6, 5e6]);
        assert_eq!(f.format(2.5e6), "2.5e6");
    }

    #[test]
    fn ranges_are_made_usable() {
        assert_eq!(usable_range((1.0, 0.0), (0.0, 1.0)), (0.0, 1.0));
        assert_eq!(usable_range((0.0, 0.0), (0.0, 1.0)), (-0.5, 0.5));
        assert_eq!(usable_range((f64::NAN, 1.0), (0.0, 1.0)), (0.0, 1.0));
        assert_eq!(usable_range((f64::MIN, f64::MAX), (0.0, 1.0)), (0.0, 1.0));
        let (lo, hi) = usable_range((10.0, 10.0), (0.0, 1.0));
        assert!(lo < 10.0 && hi > 10.0);
    }
}
