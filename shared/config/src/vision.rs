//! `[render]` and `[perception]` in `scenario.toml`: how the camera image is made and how the cable is
//! found in it (the `vision` library).

use crate::{Invalid, Validate, in_range, join, positive};
use serde::{Deserialize, Serialize};

/// How the downward camera's image is rendered. Every effect has an `enabled` switch; the geometry
/// (camera, cable) comes from the scenario's `[camera]` and `[cable]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderParams {
    /// Mean grey level of the bare pool floor (0-255).
    pub floor_level: f64,
    /// Grey level of the cable (below `floor_level`: a dark cable on a light floor).
    pub cable_level: f64,
    pub texture: TextureParams,
    pub clutter: ClutterParams,
    pub lighting: LightingParams,
    pub noise: NoiseParams,
    pub blur: BlurParams,
}

/// The floor's texture: smooth blotches (fractal value noise) and a fine grain.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TextureParams {
    pub enabled: bool,
    /// Standard deviation of the blotches (grey levels).
    pub contrast: f64,
    /// Size of the largest blotches on the floor (m).
    pub scale_m: f64,
    /// Standard deviation of the per-texel grain (grey levels).
    pub grain: f64,
}

/// Sand (light) and algae (dark) patches lying on the floor and partly covering the cable.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ClutterParams {
    pub enabled: bool,
    /// Fraction of the floor covered by patches.
    pub coverage: f64,
    /// Typical size of a patch (m).
    pub scale_m: f64,
    /// Opacity of a patch's core (1 hides the cable completely).
    pub opacity: f64,
    /// Grey level of sand patches.
    pub sand_level: f64,
    /// Grey level of algae patches.
    pub algae_level: f64,
}

/// Uneven light of the vehicle's lamp: darker corners and a linear gradient, fixed in the image.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LightingParams {
    pub enabled: bool,
    /// Fraction of the light lost in the image corners.
    pub vignetting: f64,
    /// Relative brightness change from the centre to the image border along the gradient.
    pub gradient: f64,
    /// Direction towards which the image gets brighter (degrees, 0 = right, 90 = down).
    pub gradient_angle_deg: f64,
}

/// Gaussian sensor noise.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NoiseParams {
    pub enabled: bool,
    /// Standard deviation (grey levels).
    pub std_dn: f64,
}

/// Motion blur: the image smeared by the vehicle's motion during the exposure.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BlurParams {
    pub enabled: bool,
    pub exposure_s: f64,
    /// Longest smear (pixels); faster motion is clipped to it.
    pub max_px: f64,
}

impl RenderParams {
    /// Every effect off: a uniform floor and the anti-aliased cable.
    pub fn clean() -> Self {
        let mut p = RenderParams::default();
        p.texture.enabled = false;
        p.clutter.enabled = false;
        p.lighting.enabled = false;
        p.noise.enabled = false;
        p.blur.enabled = false;
        p
    }
}

impl Default for RenderParams {
    fn default() -> Self {
        RenderParams {
            floor_level: 140.0,
            cable_level: 65.0,
            texture: TextureParams::default(),
            clutter: ClutterParams::default(),
            lighting: LightingParams::default(),
            noise: NoiseParams::default(),
            blur: BlurParams::default(),
        }
    }
}

impl Default for TextureParams {
    fn default() -> Self {
        TextureParams {
            enabled: true,
            contrast: 20.0,
            scale_m: 0.25,
            grain: 7.0,
        }
    }
}

impl Default for ClutterParams {
    fn default() -> Self {
        ClutterParams {
            enabled: true,
            coverage: 0.18,
            scale_m: 0.12,
            opacity: 0.85,
            sand_level: 185.0,
            algae_level: 70.0,
        }
    }
}

impl Default for LightingParams {
    fn default() -> Self {
        LightingParams {
            enabled: true,
            vignetting: 0.45,
            gradient: 0.3,
            gradient_angle_deg: 30.0,
        }
    }
}

impl Default for NoiseParams {
    fn default() -> Self {
        NoiseParams {
            enabled: true,
            std_dn: 8.0,
        }
    }
}

impl Default for BlurParams {
    fn default() -> Self {
        BlurParams {
            enabled: true,
            exposure_s: 0.05,
            max_px: 24.0,
        }
    }
}

impl Validate for RenderParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        in_range(key, "floor_level", self.floor_level, 0.0, 255.0)?;
        in_range(key, "cable_level", self.cable_level, 0.0, 255.0)?;
        let t = &self.texture;
        let k = join(key, "texture");
        in_range(&k, "contrast", t.contrast, 0.0, 128.0)?;
        in_range(&k, "scale_m", t.scale_m, 0.005, 10.0)?;
        in_range(&k, "grain", t.grain, 0.0, 64.0)?;
        let c = &self.clutter;
        let k = join(key, "clutter");
        in_range(&k, "coverage", c.coverage, 0.0, 0.9)?;
        in_range(&k, "scale_m", c.scale_m, 0.005, 10.0)?;
        in_range(&k, "opacity", c.opacity, 0.0, 1.0)?;
        in_range(&k, "sand_level", c.sand_level, 0.0, 255.0)?;
        in_range(&k, "algae_level", c.algae_level, 0.0, 255.0)?;
        let l = &self.lighting;
        let k = join(key, "lighting");
        in_range(&k, "vignetting", l.vignetting, 0.0, 0.95)?;
        in_range(&k, "gradient", l.gradient, 0.0, 0.95)?;
        in_range(
            &k,
            "gradient_angle_deg",
            l.gradient_angle_deg,
            -360.0,
            360.0,
        )?;
        in_range(&join(key, "noise"), "std_dn", self.noise.std_dn, 0.0, 64.0)?;
        let b = &self.blur;
        let k = join(key, "blur");
        in_range(&k, "exposure_s", b.exposure_s, 0.0, 1.0)?;
        in_range(&k, "max_px", b.max_px, 1.0, 64.0)
    }
}

/// Which cables perception accepts: darker or brighter than the floor around them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CablePolarity {
    Dark,
    Bright,
    Any,
}

/// How perception finds the cable: two long, near-parallel edges of opposite gradient a cable width
/// apart (edge detection, a gradient-directed Hough transform, a least-squares fit of the pair), then
/// tracked from frame to frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PerceptionParams {
    /// Smallest gradient an edge point may have: the Sobel magnitude |gx| + |gy| (a step of c grey
    /// levels gives 4c).
    pub edge_threshold: f64,
    /// The edge threshold is at least this many times the median gradient of the searched pixels
    /// (the level of noise and texture: it adapts to them).
    pub edge_threshold_median_factor: f64,
    /// Edge points kept per frame at most (a bound on the work for pathological images).
    pub max_edge_points: u32,
    /// Hough accumulator resolution.
    pub hough_angle_step_deg: f64,
    pub hough_rho_step_px: f64,
    /// Each edge point votes for this many angle bins on each side of its gradient direction.
    pub hough_vote_spread: u32,
    /// A cable edge must be at least this long in the image (pixels of supporting edge points).
    pub min_edge_length_px: f64,
    /// The measured cable width may differ from the expected one by this fraction.
    pub width_tolerance: f64,
    /// The cable's two edges may differ in direction by this much.
    pub parallel_tolerance_deg: f64,
    /// Largest angle between an edge point's gradient and the fitted edge's normal.
    pub gradient_tolerance_deg: f64,
    pub polarity: CablePolarity,
    /// A detection with a smaller confidence (the mean fraction of the two edges' visible length seen)
    /// is reported as lost.
    pub min_confidence: f64,
    /// Both edges must be seen in at least this fraction of the visible line's 16 segments (a cable
    /// crosses the image; a blob with two short parallel sides does not).
    pub min_coverage: f64,
    pub tracking: TrackingParams,
}

/// Frame-to-frame tracking and the rate filter.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackingParams {
    /// Search only a band around the predicted line while the cable is tracked.
    pub enabled: bool,
    /// Half-width of the search band beyond the cable's edges (pixels).
    pub band_margin_px: f64,
    /// After this many frames without a detection the cable is reported lost (before that, the
    /// prediction is reported with a decaying confidence).
    pub coast_frames: u32,
    /// Gains of the alpha-beta filter behind the rates (position and rate correction per frame).
    pub filter_alpha: f64,
    pub filter_beta: f64,
}

impl Default for PerceptionParams {
    fn default() -> Self {
        PerceptionParams {
            edge_threshold: 60.0,
            edge_threshold_median_factor: 1.5,
            max_edge_points: 12_000,
            hough_angle_step_deg: 2.0,
            hough_rho_step_px: 2.0,
            hough_vote_spread: 2,
            min_edge_length_px: 40.0,
            width_tolerance: 0.4,
            parallel_tolerance_deg: 5.0,
            gradient_tolerance_deg: 25.0,
            polarity: CablePolarity::Any,
            min_confidence: 0.3,
            min_coverage: 0.5,
            tracking: TrackingParams::default(),
        }
    }
}

impl Default for TrackingParams {
    fn default() -> Self {
        TrackingParams {
            enabled: true,
            band_margin_px: 14.0,
            coast_frames: 2,
            filter_alpha: 0.6,
            filter_beta: 0.25,
        }
    }
}

impl Validate for PerceptionParams {
    fn validate(&self, key: &str) -> Result<(), Invalid> {
        in_range(key, "edge_threshold", self.edge_threshold, 1.0, 4000.0)?;
        in_range(
            key,
            "edge_threshold_median_factor",
            self.edge_threshold_median_factor,
            0.0,
            100.0,
        )?;
        in_range(
            key,
            "max_edge_points",
            self.max_edge_points as f64,
            100.0,
            1.0e6,
        )?;
        in_range(
            key,
            "hough_angle_step_deg",
            self.hough_angle_step_deg,
            0.25,
            10.0,
        )?;
        in_range(key, "hough_rho_step_px", self.hough_rho_step_px, 0.5, 10.0)?;
        in_range(
            key,
            "hough_vote_spread",
            self.hough_vote_spread as f64,
            0.0,
            8.0,
        )?;
        positive(key, "min_edge_length_px", self.min_edge_length_px)?;
        in_range(key, "width_tolerance", self.width_tolerance, 0.01, 0.9)?;
        in_range(
            key,
            "parallel_tolerance_deg",
            self.parallel_tolerance_deg,
            0.1,
            30.0,
        )?;
        in_range(
            key,
            "gradient_tolerance_deg",
            self.gradient_tolerance_deg,
            1.0,
            60.0,
        )?;
        in_range(key, "min_confidence", self.min_confidence, 0.0, 1.0)?;
        in_range(key, "min_coverage", self.min_coverage, 0.0, 1.0)?;
        let t = &self.tracking;
        let k = join(key, "tracking");
        in_range(&k, "band_margin_px", t.band_margin_px, 1.0, 1000.0)?;
        in_range(&k, "coast_frames", t.coast_frames as f64, 0.0, 100.0)?;
        in_range(&k, "filter_alpha", t.filter_alpha, 0.0, 1.0)?;
        in_range(&k, "filter_beta", t.filter_beta, 0.0, 2.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Wrapper {
        render: RenderParams,
        perception: PerceptionParams,
    }

    impl Validate for Wrapper {
        fn validate(&self, key: &str) -> Result<(), Invalid> {
            self.render.validate(&join(key, "render"))?;
            self.perception.validate(&join(key, "perception"))
        }
    }

    #[test]
    fn defaults_are_valid_and_clean_switches_everything_off() {
        RenderParams::default().validate("render").unwrap();
        PerceptionParams::default().validate("perception").unwrap();
        let c = RenderParams::clean();
        assert!(!c.texture.enabled && !c.clutter.enabled && !c.lighting.enabled);
        assert!(!c.noise.enabled && !c.blur.enabled);
    }

    #[test]
    fn errors_name_the_key() {
        let text = "[render.noise]\nstd_dn = -1\n[perception]\n";
        let err = crate::parse::<Wrapper>(text, Path::new("s.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("render.noise.std_dn") && err.contains("s.toml"),
            "{err}"
        );
        let text = "[render]\n[perception]\npolarity = \"purple\"\n";
        assert!(crate::parse::<Wrapper>(text, Path::new("s.toml")).is_err());
        let text = "[render.blur]\nenabled = false\nshutter = 1\n[perception]\n";
        let err = crate::parse::<Wrapper>(text, Path::new("s.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("shutter"), "{err}");
    }
}
