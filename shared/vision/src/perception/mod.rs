//! Finding the cable in a frame, the way the paper's vision system does: the cable's two long,
//! near-parallel edges.
//!
//! **Search (first frame, or after a loss).** The frame is halved (2x2 means: less noise, a quarter of
//! the pixels); edge points come from Sobel gradients with a noise-adaptive threshold and non-maximum
//! suppression; a Hough transform over *signed* normals, each point voting only near its gradient's
//! direction, shows each edge as a peak with its polarity; pairs of antiparallel peaks whose offsets
//! add up to the cable's width (known from the camera and the cable) are the hypotheses. The best are
//! checked at full resolution: edge points (sub-pixel) in a band around the hypothesis, a least-squares
//! fit of two parallel lines, and a verdict on width and on how much of both edges is actually seen.
//!
//! **Tracking.** While the cable is found, the next frame is searched only in a band around the line
//! predicted by the rate filter (full resolution, a Hough over the band's points, the same fit). When
//! that fails, the whole frame is searched again in the same call; when that fails too, the prediction
//! is reported for up to `coast_frames` frames with a decaying confidence, then the cable is lost.
//!
//! **Output.** rho, Theta, x_g, y_g in `model::camera`'s conventions; dx_g/dt and dTheta/dt from
//! alpha-beta filters (not raw differences), clipped to the observation box; a confidence in [0, 1].
//! Nothing is allocated per frame.

mod edges;
mod filter;
mod fit;
mod hough;

use crate::error::VisionError;
use crate::geometry::{line_from_normal, line_from_polar};
use crate::image::ImageView;
use config::{
    CableParams, CablePolarity, CameraParams, ObservationLimits, PerceptionParams, Scenario,
    Validate,
};
use edges::{EdgePoint, Gradients, LevelMap, Span};
use filter::AlphaBeta;
use fit::{coverage, fit_pair};
use hough::{Hough, Hypothesis};
use model::{CableLine, CableObservation, Camera, wrap_half_pi};

/// Hypotheses checked per search.
const MAX_HYPOTHESES: usize = 4;
/// Hough peaks considered for pairing.
const MAX_PEAKS: usize = 24;
/// Distance gates of the fit's iterations (pixels); the first is the band's half-width.
const FIT_RADII: [f64; 3] = [4.0, 2.0, 1.25];
/// Band half-width beyond the cable's edges when a search hypothesis is checked at full resolution.
const CHECK_MARGIN_PX: f64 = 6.0;
/// Shorter time steps (s) than this are taken as unknown: no rate is derived over them.
const MIN_DT_S: f64 = 1e-3;
/// After a longer gap between frames (s) the track is dropped and the frame searched whole.
const MAX_GAP_S: f64 = 5.0;

/// One frame's detection, before filtering.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Detection {
    /// The centre line between the two edges.
    pub line: CableLine,
    /// The distance between the two edges (pixels).
    pub width_px: f64,
    /// The cable is darker than the floor.
    pub dark: bool,
    /// Edge points on each edge.
    pub points: [usize; 2],
    /// Fraction of each edge's visible length covered by edge points.
    pub support: [f64; 2],
    /// Fraction of the visible line's 16 segments in which both edges were seen.
    pub coverage: f64,
    /// RMS distance of the edge points from the fitted edges (pixels).
    pub rms_px: f64,
    pub confidence: f64,
    /// Found by a search of the whole frame (not in the tracking band).
    pub full_search: bool,
}

/// What the tracker knows between frames.
#[derive(Clone, Copy, Debug)]
struct Track {
    /// Theta, unwrapped (continuous across +-pi/2), and rho in the same sign.
    theta: AlphaBeta,
    rho: AlphaBeta,
    x_g: AlphaBeta,
    half: f64,
    confidence: f64,
    misses: u32,
}

/// The cable tracker: feed it frames, get [`CableObservation`]s.
pub struct Perception {
    params: PerceptionParams,
    limits: ObservationLimits,
    width: usize,
    height: usize,
    cable_width_px: f64,
    cos_gradient: f64,
    coarse: Vec<u8>,
    coarse_gradients: Gradients,
    fine_gradients: Gradients,
    edges: Vec<EdgePoint>,
    spans: Vec<Span>,
    hough: Hough,
    hypotheses: Vec<Hypothesis>,
    track: Option<Track>,
    last: Option<Detection>,
}

impl Perception {
    /// A tracker for frames of `camera`'s size, looking for a cable `cable.width_m` wide; rates are
    /// clipped to `limits`.
    pub fn new(
        params: &PerceptionParams,
        camera: &CameraParams,
        cable: &CableParams,
        limits: &ObservationLimits,
    ) -> Result<Self, VisionError> {
        let config = |what, invalid| VisionError::Config { what, invalid };
        params
            .validate("perception")
            .map_err(|e| config("perception", e))?;
        camera.validate("camera").map_err(|e| config("camera", e))?;
        cable.validate("cable").map_err(|e| config("cable", e))?;
        limits
            .validate("observation")
            .map_err(|e| config("observation", e))?;
        let (width, height) = (camera.width as usize, camera.height as usize);
        crate::image::check_size(width, height, width * height)?;
        let cam = Camera::new(camera);
        let (cw, ch) = (width / 2, height / 2);
        let rho_max = 0.5 * (width as f64).hypot(height as f64) + 2.0;
        Ok(Perception {
            params: params.clone(),
            limits: limits.clone(),
            width,
            height,
            cable_width_px: cable.width_m / cam.metres_per_px(),
            cos_gradient: params.gradient_tolerance_deg.to_radians().cos(),
            coarse: vec![0; cw * ch],
            coarse_gradients: Gradients::new(cw, ch, true),
            fine_gradients: Gradients::new(width, height, true),
            edges: Vec::with_capacity(params.max_edge_points as usize),
            spans: vec![Span::EMPTY; height],
            hough: Hough::new(
                params.hough_angle_step_deg,
                params.hough_rho_step_px,
                rho_max,
            ),
            hypotheses: Vec::with_capacity(MAX_HYPOTHESES + 1),
            track: None,
            last: None,
        })
    }

    /// The scenario's tracker (its `[perception]`, `[camera]`, `[cable]` and `[observation]`).
    pub fn from_scenario(scenario: &Scenario) -> Result<Self, VisionError> {
        Perception::new(
            &scenario.perception,
            &scenario.camera,
            &scenario.cable,
            &scenario.observation,
        )
    }

    /// The cable's expected width in the image (pixels).
    pub fn cable_width_px(&self) -> f64 {
        self.cable_width_px
    }

    /// Forgets the track: the next frame is searched whole and the rates start from zero.
    pub fn reset(&mut self) {
        self.track = None;
        self.last = None;
    }

    /// The last frame's detection (`None` when the cable was not found in it, even while coasting).
    pub fn last_detection(&self) -> Option<&Detection> {
        self.last.as_ref()
    }

    /// Processes one frame taken `dt_s` seconds after the previous one. An image of another size than
    /// the camera's is an error; anything else in it (noise, no cable, garbage) gives an observation.
    pub fn process(
        &mut self,
        image: ImageView<'_>,
        dt_s: f64,
    ) -> Result<CableObservation, VisionError> {
        if image.width() != self.width || image.height() != self.height {
            return Err(VisionError::SizeMismatch {
                what: "perception",
                width: self.width,
                height: self.height,
                got_width: image.width(),
                got_height: image.height(),
            });
        }
        let dt = self.step(dt_s);
        let img = image.data();
        let mut detection = None;
        if self.params.tracking.enabled
            && let Some(track) = self.track
        {
            let theta = track.theta.predict(dt);
            let prediction = Hypothesis {
                normal: [theta.cos(), theta.sin()],
                centre: track.rho.predict(dt),
                half: track.half,
                score: 0,
            };
            detection = self.search_band(img, &prediction);
        }
        if detection.is_none() {
            detection = self.search_full(img);
        }
        self.last = detection;
        Ok(self.update_track(detection, dt))
    }

    /// A frame that cannot be looked at, taken `dt_s` seconds after the previous one (its image is
    /// damaged: video data lost on the way): the track coasts on its prediction as for a frame
    /// where the cable was not found, and is lost after `coast_frames` of them.
    pub fn coast(&mut self, dt_s: f64) -> CableObservation {
        let dt = self.step(dt_s);
        self.last = None;
        self.update_track(None, dt)
    }

    /// The time step to use: an unknown or absurd step gives no rate update; after a long gap the
    /// track is stale and dropped.
    fn step(&mut self, dt_s: f64) -> f64 {
        let dt = if dt_s.is_finite() && dt_s >= MIN_DT_S {
            dt_s
        } else {
            0.0
        };
        if dt > MAX_GAP_S {
            self.track = None;
        }
        dt
    }

    /// Searches the whole frame: coarse Hough, then each hypothesis checked at full resolution.
    fn search_full(&mut self, img: &[u8]) -> Option<Detection> {
        let (w, cw, ch) = (self.width, self.width / 2, self.height / 2);
        for cj in 0..ch {
            let (r0, r1) = (&img[2 * cj * w..], &img[(2 * cj + 1) * w..]);
            for (ci, c) in self.coarse[cj * cw..(cj + 1) * cw].iter_mut().enumerate() {
                let sum = r0[2 * ci] as u16
                    + r0[2 * ci + 1] as u16
                    + r1[2 * ci] as u16
                    + r1[2 * ci + 1] as u16;
                *c = ((sum + 2) >> 2) as u8;
            }
        }
        let p = &self.params;
        let map = LevelMap {
            scale: 2.0,
            half_width: 0.5 * self.width as f32,
            half_height: 0.5 * self.height as f32,
        };
        self.edges.clear();
        self.coarse_gradients.extract(
            &self.coarse,
            None,
            p.edge_threshold,
            p.edge_threshold_median_factor,
            map,
            p.max_edge_points as usize,
            &mut self.edges,
        );
        let min_votes = (0.35 * p.min_edge_length_px / 2.0).max(6.0) as u32;
        let hypotheses = self.hypotheses_from_edges(min_votes);
        for h in hypotheses.iter().flatten() {
            self.fill_band(h, CHECK_MARGIN_PX);
            self.extract_fine(img);
            if let Some(d) = self.check(h, true) {
                return Some(d);
            }
        }
        None
    }

    /// Searches the band around the predicted line at full resolution.
    fn search_band(&mut self, img: &[u8], prediction: &Hypothesis) -> Option<Detection> {
        self.fill_band(prediction, self.params.tracking.band_margin_px);
        self.extract_fine(img);
        let min_votes = (0.35 * self.params.min_edge_length_px).max(6.0) as u32;
        let hypotheses = self.hypotheses_from_edges(min_votes);
        for h in hypotheses
            .iter()
            .flatten()
            .chain(std::iter::once(prediction))
        {
            if let Some(d) = self.check(h, false) {
                return Some(d);
            }
        }
        None
    }

    /// Hough over the current edge points, paired into at most [`MAX_HYPOTHESES`] hypotheses.
    fn hypotheses_from_edges(&mut self, min_votes: u32) -> [Option<Hypothesis>; MAX_HYPOTHESES] {
        let p = &self.params;
        self.hough.vote(&self.edges, p.hough_vote_spread as usize);
        self.hough.peaks(min_votes, MAX_PEAKS);
        self.hough.pairs(
            self.cable_width_px,
            p.width_tolerance,
            p.parallel_tolerance_deg.to_radians(),
            p.polarity,
            MAX_HYPOTHESES,
            &mut self.hypotheses,
        );
        let mut out = [None; MAX_HYPOTHESES];
        for (o, h) in out.iter_mut().zip(&self.hypotheses) {
            *o = Some(*h);
        }
        out
    }

    /// Full-resolution edge points within the current band.
    fn extract_fine(&mut self, img: &[u8]) {
        let p = &self.params;
        let map = LevelMap {
            scale: 1.0,
            half_width: 0.5 * self.width as f32,
            half_height: 0.5 * self.height as f32,
        };
        self.edges.clear();
        self.fine_gradients.extract(
            img,
            Some(&self.spans),
            p.edge_threshold,
            p.edge_threshold_median_factor,
            map,
            p.max_edge_points as usize,
            &mut self.edges,
        );
    }

    /// Sets each row's span to the pixels within `margin` of the hypothesis' edges.
    fn fill_band(&mut self, h: &Hypothesis, margin: f64) {
        let reach = h.half.abs() + margin;
        let (w, hh) = (self.width as f64, self.height as f64);
        let [nx, ny] = h.normal;
        for (j, span) in self.spans.iter_mut().enumerate() {
            let y = j as f64 + 0.5 - 0.5 * hh;
            let rest = h.centre - ny * y;
            let (lo, hi) = if nx.abs() < 1e-9 {
                if rest.abs() <= reach {
                    (0.0, w - 1.0)
                } else {
                    (1.0, 0.0)
                }
            } else {
                // Column i has x = i + 0.5 - w/2.
                let a = (rest - reach) / nx + 0.5 * w - 0.5;
                let b = (rest + reach) / nx + 0.5 * w - 0.5;
                (a.min(b).floor(), a.max(b).ceil())
            };
            *span = if hi < 0.0 || lo > w - 1.0 || lo > hi {
                Span::EMPTY
            } else {
                Span {
                    lo: lo.max(0.0) as u16,
                    hi: hi.min(w - 1.0) as u16,
                }
            };
        }
    }

    /// Fits the pair from hypothesis `h` to the current edge points and judges it.
    fn check(&self, h: &Hypothesis, full_search: bool) -> Option<Detection> {
        let p = &self.params;
        let fit = fit_pair(&self.edges, h, self.cos_gradient, &FIT_RADII, 8)?;
        let dark = fit.half > 0.0;
        match p.polarity {
            CablePolarity::Dark if !dark => return None,
            CablePolarity::Bright if dark => return None,
            _ => {}
        }
        let width_px = 2.0 * fit.half.abs();
        let width_error = (width_px / self.cable_width_px - 1.0).abs();
        if width_error > p.width_tolerance {
            return None;
        }
        let line = line_from_normal(
            fit.normal,
            fit.centre,
            self.width as f64,
            self.height as f64,
        )?;
        // Edge points per pixel of edge length: one per row or per column, whichever is more.
        let density = fit.normal[0].abs().max(fit.normal[1].abs());
        let expected = line.visible_px() * density;
        let min_points = p.min_edge_length_px * density;
        if (fit.counts[0] as f64) < min_points || (fit.counts[1] as f64) < min_points {
            return None;
        }
        let support = fit.counts.map(|c| (c as f64 / expected.max(1.0)).min(1.0));
        let last_radius = FIT_RADII[FIT_RADII.len() - 1];
        let coverage = coverage(
            &self.edges,
            &fit,
            self.cos_gradient,
            last_radius,
            line.ends[0],
            line.ends[1],
        );
        let confidence =
            (0.5 * (support[0] + support[1]) * (1.0 - 0.5 * width_error / p.width_tolerance))
                .clamp(0.0, 1.0);
        (confidence >= p.min_confidence && coverage >= p.min_coverage).then_some(Detection {
            line,
            width_px,
            dark,
            points: fit.counts,
            support,
            coverage,
            rms_px: fit.rms,
            confidence,
            full_search,
        })
    }

    /// Updates the filters with this frame's detection and builds the observation.
    fn update_track(&mut self, detection: Option<Detection>, dt: f64) -> CableObservation {
        let t = &self.params.tracking;
        let (alpha, beta) = (t.filter_alpha, t.filter_beta);
        match (detection, self.track.as_mut()) {
            (Some(d), Some(track)) => {
                // Unwrap the measured Theta next to the prediction (a line is the same turned by pi).
                let predicted = track.theta.predict(dt);
                let turns = ((predicted - d.line.theta) / std::f64::consts::PI).round();
                if !turns.is_finite() || turns.abs() > 1e6 {
                    // The filter has run away (garbage in): start the track again.
                    self.track = None;
                    return self.update_track(Some(d), 0.0);
                }
                let theta = d.line.theta + turns * std::f64::consts::PI;
                let rho = if turns.rem_euclid(2.0) == 1.0 {
                    -d.line.rho
                } else {
                    d.line.rho
                };
                track.theta.update(theta, dt, alpha, beta);
                track.rho.update(rho, dt, alpha, beta);
                track.x_g.update(d.line.x_g, dt, alpha, beta);
                track.half = 0.5 * d.width_px * if d.dark { 1.0 } else { -1.0 };
                track.confidence = d.confidence;
                track.misses = 0;
            }
            (Some(d), None) => {
                self.track = Some(Track {
                    theta: AlphaBeta::new(d.line.theta),
                    rho: AlphaBeta::new(d.line.rho),
                    x_g: AlphaBeta::new(d.line.x_g),
                    half: 0.5 * d.width_px * if d.dark { 1.0 } else { -1.0 },
                    confidence: d.confidence,
                    misses: 0,
                });
            }
            (None, Some(track)) => {
                track.misses += 1;
                if track.misses > t.coast_frames {
                    self.track = None;
                    return CableObservation::default();
                }
                track.theta.coast(dt);
                track.rho.coast(dt);
                track.x_g.coast(dt);
                // Theta wrapped into (-pi/2, pi/2], rho with it.
                let theta = wrap_half_pi(track.theta.value());
                let flipped = (theta - track.theta.value()).abs() > 1.0;
                let rho = if flipped {
                    -track.rho.value()
                } else {
                    track.rho.value()
                };
                let confidence = track.confidence * 0.5f64.powi(track.misses as i32);
                let Some(line) = line_from_polar(rho, theta, self.width as f64, self.height as f64)
                else {
                    self.track = None;
                    return CableObservation::default();
                };
                return self.observation(&line, confidence);
            }
            (None, None) => return CableObservation::default(),
        }
        let d = detection.expect("handled above");
        self.observation(&d.line, d.confidence)
    }

    fn observation(&self, line: &CableLine, confidence: f64) -> CableObservation {
        let (x_rate, theta_rate) = match &self.track {
            Some(t) => (t.x_g.rate(), t.theta.rate()),
            None => (0.0, 0.0),
        };
        let l = &self.limits;
        CableObservation {
            found: true,
            rho: line.rho,
            theta: line.theta,
            x_g: line.x_g,
            y_g: line.y_g,
            x_g_rate: x_rate.clamp(-l.x_g_rate_max, l.x_g_rate_max),
            theta_rate: theta_rate.clamp(-l.theta_rate_max, l.theta_rate_max),
            confidence,
        }
    }
}

#[cfg(test)]
mod tests;
