//! The image the downward camera sees, rendered into a caller's buffer.
//!
//! A frame is made in one pass over the rows plus optional passes for blur and noise:
//!
//! 1. **Floor.** The floor-to-image map of a downward camera is affine, so the floor point under each
//!    pixel centre is stepped incrementally along a row (fixed-point texel coordinates) from three
//!    points given by [`model::Camera::image_to_floor`]; the texel is looked up in precomputed tiles
//!    (texture with the clutter already composited, see `texture.rs`).
//! 2. **Cable.** Its signed distance from the centre line ([`model::Cable::offset`]) is affine in the
//!    pixel too; per row only the few columns it covers are visited. Each gets the area coverage of the
//!    cable (a linear ramp one pixel footprint wide: anti-aliased, so edges sit at sub-pixel positions)
//!    and is composited *under* the clutter, which thereby partly hides it.
//! 3. **Light.** A precomputed per-pixel gain (vignetting and a linear gradient, fixed in the image like
//!    the vehicle's lamp).
//! 4. **Motion blur.** The image velocity at the image centre over the exposure (the camera geometry
//!    at the pose advanced by -T/2 and +T/2) gives a smear of (bx, by) pixels; the image is blurred by a
//!    box of |bx| horizontally and of |by| vertically (separable, each pass a few vectorised taps):
//!    exact for motion along an image axis (the dominant surge and sway), a rectangle instead of a
//!    slanted segment otherwise; the rotation's smear away from the centre is neglected.
//! 5. **Noise.** Gaussian sensor noise from a precomputed table, read from a per-frame offset derived
//!    from (seed, frame index): frame k of a seed is always the same image.

use crate::error::VisionError;
use crate::geometry::pixel_centre;
use crate::image::{Frame, check_size};
use crate::rng::{SplitMix64, sub_seed};
use crate::texture::{self, FloorTiles, TILE, TILE_MASK};
use config::{CableParams, CameraParams, RenderParams, Scenario, Validate};
use model::{Cable, Camera, Pose, PoseRate};

/// Distinct noise values; the table holds this many plus one frame so a frame reads a contiguous run.
const NOISE_PERIOD: usize = 1 << 18;
/// Most taps of a blur pass (a box of `max_px` <= 64 pixels).
const MAX_TAPS: usize = 67;

/// Renders the camera's view of the pool floor and the cable.
pub struct Renderer {
    params: RenderParams,
    camera: Camera,
    cable: Cable,
    width: usize,
    height: usize,
    seed: u64,
    metres_per_px: f64,
    tiles: Option<FloorTiles>,
    /// Per pixel, the light's gain times 256.
    gain: Option<Vec<u16>>,
    noise: Option<Vec<i8>>,
    scratch: Vec<u8>,
    padded: Vec<u8>,
    acc: Vec<u16>,
}

impl Renderer {
    /// A renderer of the camera's view of the cable; `seed` fixes the floor, the clutter and the noise.
    pub fn new(
        params: &RenderParams,
        camera: &CameraParams,
        cable: &CableParams,
        seed: u64,
    ) -> Result<Self, VisionError> {
        let config = |what, invalid| VisionError::Config { what, invalid };
        params.validate("render").map_err(|e| config("render", e))?;
        camera.validate("camera").map_err(|e| config("camera", e))?;
        cable.validate("cable").map_err(|e| config("cable", e))?;
        let (width, height) = (camera.width as usize, camera.height as usize);
        check_size(width, height, width * height)?;
        let cam = Camera::new(camera);
        let metres_per_px = cam.metres_per_px();
        let tiles = texture::build(params, metres_per_px, sub_seed(seed, 100));
        let gain = params
            .lighting
            .enabled
            .then(|| light_gain(params, width, height));
        let noise = (params.noise.enabled && params.noise.std_dn > 0.0).then(|| {
            let mut rng = SplitMix64::new(sub_seed(seed, 200));
            let mut table: Vec<i8> = (0..NOISE_PERIOD)
                .map(|_| {
                    (params.noise.std_dn * rng.gaussian())
                        .round()
                        .clamp(-127.0, 127.0) as i8
                })
                .collect();
            // One frame more, repeating the table, so any offset reads a contiguous run.
            let frame: Vec<i8> = (0..width * height)
                .map(|k| table[k % NOISE_PERIOD])
                .collect();
            table.extend_from_slice(&frame);
            table
        });
        Ok(Renderer {
            params: params.clone(),
            camera: cam,
            cable: Cable::new(cable),
            width,
            height,
            seed,
            metres_per_px,
            tiles,
            gain,
            noise,
            scratch: vec![0; width * height],
            padded: vec![0; width.max(height) + MAX_TAPS],
            acc: vec![0; width.max(height)],
        })
    }

    /// The scenario's renderer (its `[render]`, `[camera]` and `[cable]`).
    pub fn from_scenario(scenario: &Scenario, seed: u64) -> Result<Self, VisionError> {
        Renderer::new(&scenario.render, &scenario.camera, &scenario.cable, seed)
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    pub fn cable(&self) -> &Cable {
        &self.cable
    }

    pub fn params(&self) -> &RenderParams {
        &self.params
    }

    /// The smear (pixels, image x and y) of the image centre during the exposure; zero when blur is off.
    pub fn blur_vector(&self, pose: &Pose, rate: &PoseRate) -> [f64; 2] {
        let b = &self.params.blur;
        if !b.enabled || b.exposure_s <= 0.0 {
            return [0.0, 0.0];
        }
        let centre = self.camera.image_to_floor(pose, [0.0, 0.0]);
        let half = 0.5 * b.exposure_s;
        let a = self
            .camera
            .floor_to_image(&pose.advanced(rate, half), centre);
        let z = self
            .camera
            .floor_to_image(&pose.advanced(rate, -half), centre);
        let clip = |v: f64| {
            if v.is_finite() {
                v.clamp(-b.max_px, b.max_px)
            } else {
                0.0
            }
        };
        [clip(a[0] - z[0]), clip(a[1] - z[1])]
    }

    /// Renders frame `frame_index` seen from `pose` moving at `rate` into `out` (row-major,
    /// `width * height` bytes). The same seed, frame index, pose and rate give the same bytes.
    pub fn render(
        &mut self,
        pose: &Pose,
        rate: &PoseRate,
        frame_index: u64,
        out: &mut [u8],
    ) -> Result<(), VisionError> {
        check_size(self.width, self.height, out.len())?;
        #[cfg(target_arch = "x86_64")]
        if crate::wide::avx2() {
            // SAFETY: the CPU has AVX2, checked just above.
            unsafe { self.render_avx2(pose, rate, frame_index, out) };
            return Ok(());
        }
        self.render_baseline(pose, rate, frame_index, out);
        Ok(())
    }

    /// [`Renderer::render`] compiled for AVX2 (see `wide.rs`).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn render_avx2(&mut self, pose: &Pose, rate: &PoseRate, frame_index: u64, out: &mut [u8]) {
        self.render_baseline(pose, rate, frame_index, out);
    }

    /// The frame, into an `out` of the right size; inlined into each build of [`Renderer::render`].
    #[inline(always)]
    fn render_baseline(&mut self, pose: &Pose, rate: &PoseRate, frame_index: u64, out: &mut [u8]) {
        self.draw_scene(pose, out);
        let [bx, by] = self.blur_vector(pose, rate);
        self.blur(bx.abs(), by.abs(), out);
        if let Some(noise) = &self.noise {
            let offset = (sub_seed(self.seed, frame_index) % NOISE_PERIOD as u64) as usize;
            for (o, &n) in out
                .iter_mut()
                .zip(&noise[offset..offset + self.width * self.height])
            {
                *o = (*o as i16 + n as i16).clamp(0, 255) as u8;
            }
        }
    }

    /// [`Renderer::render`] into a new frame.
    pub fn render_frame(&mut self, pose: &Pose, rate: &PoseRate, frame_index: u64) -> Frame {
        let mut frame = Frame::new(self.width, self.height).expect("the camera size was checked");
        self.render(pose, rate, frame_index, frame.data_mut())
            .expect("the frame has the camera's size");
        frame
    }

    /// Floor, cable, clutter and light (steps 1 to 3).
    #[inline(always)]
    fn draw_scene(&self, pose: &Pose, out: &mut [u8]) {
        let (w, h) = (self.width, self.height);
        let q00 = pixel_centre(0.0, 0.0, w as f64, h as f64);
        let p00 = self.camera.image_to_floor(pose, q00);
        let p10 = self.camera.image_to_floor(pose, [q00[0] + 1.0, q00[1]]);
        let p01 = self.camera.image_to_floor(pose, [q00[0], q00[1] + 1.0]);
        let di = [p10[0] - p00[0], p10[1] - p00[1]];
        let dj = [p01[0] - p00[0], p01[1] - p00[1]];

        // The cable's signed distance (pixels) is affine in (i, j).
        let mpp = self.metres_per_px;
        let n = self.cable.normal();
        let d00 = self.cable.offset(p00) / mpp;
        let ddi = (di[0] * n[0] + di[1] * n[1]) / mpp;
        let ddj = (dj[0] * n[0] + dj[1] * n[1]) / mpp;
        let half = 0.5 * self.cable.width_m / mpp;
        let ramp = (ddi.abs() + ddj.abs()).max(1e-9);
        let reach = half + 0.5 * ramp;
        let floor_level = self.params.floor_level;
        let cable_level = self.params.cable_level as f32;

        // Texel coordinates in 16.16 fixed point, wrapping with the tile.
        let inv_texel = 1.0 / mpp;
        let step = |v: f64| ((v * inv_texel * 65536.0).round() as i64) as u32;
        let (du, dv) = (step(di[0]), step(di[1]));
        let start = |v: f64| ((v * inv_texel).rem_euclid(TILE as f64) * 65536.0) as u32;

        for (j, row) in out.chunks_exact_mut(w).enumerate() {
            let jf = j as f64;
            let u = start(p00[0] + jf * dj[0]);
            let v = start(p00[1] + jf * dj[1]);
            let (u0, v0) = (u, v);
            match &self.tiles {
                Some(t) => {
                    let (mut u, mut v) = (u, v);
                    for px in row.iter_mut() {
                        *px = t.scene[texel(u, v)];
                        u = u.wrapping_add(du);
                        v = v.wrapping_add(dv);
                    }
                }
                None => row.fill(floor_level.round() as u8),
            }
            // The cable's columns in this row: |d_row + i ddi| < reach.
            let d_row = d00 + jf * ddj;
            let (lo, hi) = if ddi.abs() < 1e-12 {
                if d_row.abs() < reach {
                    (0, w - 1)
                } else {
                    (1, 0)
                }
            } else {
                let a = (-reach - d_row) / ddi;
                let b = (reach - d_row) / ddi;
                let (a, b) = (a.min(b), a.max(b));
                if b < 0.0 || a > (w - 1) as f64 {
                    (1, 0)
                } else {
                    (
                        a.ceil().max(0.0) as usize,
                        b.floor().min((w - 1) as f64) as usize,
                    )
                }
            };
            // `lo` is at most `hi + 1` (an empty span).
            for (offset, px) in row[lo..=hi].iter_mut().enumerate() {
                let i = lo + offset;
                let d = d_row + i as f64 * ddi;
                let cover = (0.5 + (half - d.abs()) / ramp).clamp(0.0, 1.0) as f32;
                if cover <= 0.0 {
                    continue;
                }
                let value = match &self.tiles {
                    Some(t) => {
                        let k = texel(
                            u0.wrapping_add(du.wrapping_mul(i as u32)),
                            v0.wrapping_add(dv.wrapping_mul(i as u32)),
                        );
                        let base = t.base[k] as f32;
                        let clear = 1.0 - t.alpha[k] as f32 / 255.0;
                        t.scene[k] as f32 + cover * clear * (cable_level - base)
                    }
                    None => floor_level as f32 + cover * (cable_level - floor_level as f32),
                };
                *px = value.round().clamp(0.0, 255.0) as u8;
            }
            if let Some(gain) = &self.gain {
                for (px, &g) in row.iter_mut().zip(&gain[j * w..(j + 1) * w]) {
                    *px = ((*px as u32 * g as u32 + 128) >> 8).min(255) as u8;
                }
            }
        }
    }

    /// Separable box blur of `lx` pixels horizontally and `ly` vertically (step 4), in place.
    #[inline(always)]
    fn blur(&mut self, lx: f64, ly: f64, out: &mut [u8]) {
        let (w, h) = (self.width, self.height);
        let horizontal = box_weights(lx);
        let vertical = box_weights(ly);
        if horizontal.is_none() && vertical.is_none() {
            return;
        }
        // Horizontal: out -> scratch (or a plain copy when there is nothing to do).
        match &horizontal {
            Some((weights, taps)) => {
                let pad = taps / 2;
                for (src, dst) in out.chunks_exact(w).zip(self.scratch.chunks_exact_mut(w)) {
                    let padded = &mut self.padded[..w + 2 * pad];
                    padded[..pad].fill(src[0]);
                    padded[pad..pad + w].copy_from_slice(src);
                    padded[pad + w..].fill(src[w - 1]);
                    let acc = &mut self.acc[..w];
                    acc.fill(128);
                    for (t, &wt) in weights[..*taps].iter().enumerate() {
                        if wt == 0 {
                            continue;
                        }
                        for (a, &p) in acc.iter_mut().zip(&padded[t..t + w]) {
                            *a += wt * p as u16;
                        }
                    }
                    for (d, &a) in dst.iter_mut().zip(acc.iter()) {
                        *d = (a >> 8) as u8;
                    }
                }
            }
            None => self.scratch.copy_from_slice(out),
        }
        // Vertical: scratch -> out.
        match &vertical {
            Some((weights, taps)) => {
                let pad = (taps / 2) as isize;
                for (j, dst) in out.chunks_exact_mut(w).enumerate() {
                    let acc = &mut self.acc[..w];
                    acc.fill(128);
                    for (t, &wt) in weights[..*taps].iter().enumerate() {
                        if wt == 0 {
                            continue;
                        }
                        let r = (j as isize + t as isize - pad).clamp(0, h as isize - 1) as usize;
                        for (a, &p) in acc.iter_mut().zip(&self.scratch[r * w..(r + 1) * w]) {
                            *a += wt * p as u16;
                        }
                    }
                    for (d, &a) in dst.iter_mut().zip(acc.iter()) {
                        *d = (a >> 8) as u8;
                    }
                }
            }
            None => out.copy_from_slice(&self.scratch),
        }
    }
}

/// The texel at fixed-point coordinates (u, v).
#[inline(always)]
fn texel(u: u32, v: u32) -> usize {
    texture::texel_index((u >> 16) & TILE_MASK, (v >> 16) & TILE_MASK)
}

/// The taps (weights summing to 256, centred) of a box of `len` pixels: whole pixels inside the box
/// get 1/len, the two partly covered end pixels their covered fraction; `None` below one pixel.
fn box_weights(len: f64) -> Option<([u16; MAX_TAPS], usize)> {
    if len.is_nan() || len < 1.0 {
        return None;
    }
    let half = 0.5 * len;
    let inner = (half - 0.5).floor() as usize; // taps -inner..=inner are fully covered
    let frac = half - 0.5 - inner as f64;
    let taps = 2 * inner + 3;
    if taps > MAX_TAPS {
        return None;
    }
    let mut weights = [0u16; MAX_TAPS];
    let full = 256.0 / len;
    let end = (256.0 * frac / len).round() as u16;
    for w in &mut weights[1..taps - 1] {
        *w = full.round() as u16;
    }
    weights[0] = end;
    weights[taps - 1] = end;
    let sum: i32 = weights[..taps].iter().map(|&w| w as i32).sum();
    let centre = taps / 2;
    weights[centre] = (weights[centre] as i32 + 256 - sum) as u16;
    Some((weights, taps))
}

/// Per-pixel gain times 256: vignetting (quadratic fall-off to the corners) and a linear gradient.
fn light_gain(params: &RenderParams, width: usize, height: usize) -> Vec<u16> {
    let l = &params.lighting;
    let (hw, hh) = (0.5 * width as f64, 0.5 * height as f64);
    let (s, c) = l.gradient_angle_deg.to_radians().sin_cos();
    let reach = c.abs() * hw + s.abs() * hh;
    let mut gain = Vec::with_capacity(width * height);
    for j in 0..height {
        for i in 0..width {
            let q = pixel_centre(i as f64, j as f64, width as f64, height as f64);
            let r2 = (q[0] * q[0] + q[1] * q[1]) / (hw * hw + hh * hh);
            let vignette = 1.0 - l.vignetting * r2;
            let gradient = 1.0 + l.gradient * (q[0] * c + q[1] * s) / reach;
            gain.push((256.0 * vignette * gradient).round().clamp(0.0, 1023.0) as u16);
        }
    }
    gain
}

#[cfg(test)]
mod tests {
    use super::*;
    use model::Velocity;

    fn scenario() -> Scenario {
        Scenario::default()
    }

    fn renderer(params: RenderParams, seed: u64) -> Renderer {
        let s = scenario();
        Renderer::new(&params, &s.camera, &s.cable, seed).unwrap()
    }

    fn still() -> PoseRate {
        PoseRate::default()
    }

    /// The AVX2 build (`wide.rs`) gives the baseline build's bytes, with every effect on and with
    /// none, across seeds, poses and velocities (blur from none to the longest). On a CPU without
    /// AVX2 both calls run the baseline build and the test compares it with itself.
    #[test]
    fn the_avx2_build_renders_the_baseline_bytes() {
        let s = scenario();
        let camera = Camera::new(&s.camera);
        let cable = Cable::new(&s.cable);
        for params in [RenderParams::clean(), s.render.clone()] {
            for seed in 1..4 {
                let mut r = renderer(params.clone(), seed);
                let mut sampler = crate::sampling::PoseSampler::new(seed);
                let mut wide = vec![0u8; r.width() * r.height()];
                let mut narrow = wide.clone();
                for k in 0..40 {
                    let p = match k % 4 {
                        0 => sampler.without_cable(&camera, &cable, 1.0),
                        _ => sampler.with_cable(&camera, &cable),
                    };
                    let rate = if k % 5 == 0 { still() } else { p.rate };
                    r.render(&p.pose, &rate, k, &mut wide).unwrap();
                    r.render_baseline(&p.pose, &rate, k, &mut narrow);
                    assert!(wide == narrow, "seed {seed}, frame {k}: the builds differ");
                }
            }
        }
    }

    #[test]
    fn the_same_seed_and_frame_give_the_same_image() {
        let pose = Pose {
            x: 0.3,
            y: 0.1,
            psi: 0.4,
        };
        let rate = model::VehicleState {
            pose,
            velocity: Velocity {
                u: 0.3,
                v: 0.1,
                r: 0.1,
            },
        }
        .pose_rate();
        let a = renderer(RenderParams::default(), 5).render_frame(&pose, &rate, 3);
        let b = renderer(RenderParams::default(), 5).render_frame(&pose, &rate, 3);
        assert_eq!(a, b);
        // Another frame index changes the noise only; another seed changes the floor too.
        let c = renderer(RenderParams::default(), 5).render_frame(&pose, &rate, 4);
        let d = renderer(RenderParams::default(), 6).render_frame(&pose, &rate, 3);
        assert_ne!(a, c);
        assert_ne!(a, d);
        let diff = |x: &Frame, y: &Frame| {
            x.data()
                .iter()
                .zip(y.data())
                .map(|(&p, &q)| (p as f64 - q as f64).abs())
                .sum::<f64>()
                / x.data().len() as f64
        };
        assert!(
            diff(&a, &c) < diff(&a, &d),
            "{} {}",
            diff(&a, &c),
            diff(&a, &d)
        );
    }

    /// Clean frames: the cable's pixels are dark exactly where the geometric camera puts the cable.
    #[test]
    fn cable_pixels_are_where_the_geometry_says() {
        let mut r = renderer(RenderParams::clean(), 1);
        let cam = r.camera().clone();
        let cable = *r.cable();
        let p = RenderParams::clean();
        for pose in [
            Pose::default(),
            Pose {
                x: 2.0,
                y: 0.15,
                psi: 0.5,
            },
            Pose {
                x: -1.0,
                y: -0.2,
                psi: -1.0,
            },
        ] {
            let f = r.render_frame(&pose, &still(), 0);
            let half_px = 0.5 * cable.width_m / cam.metres_per_px();
            for j in 0..240 {
                for i in 0..320 {
                    let q = pixel_centre(i as f64, j as f64, 320.0, 240.0);
                    let d = cable.offset(cam.image_to_floor(&pose, q)) / cam.metres_per_px();
                    let v = f.view().get(i, j) as f64;
                    if d.abs() < half_px - 1.0 {
                        assert_eq!(v, p.cable_level, "({i},{j}) d={d}");
                    } else if d.abs() > half_px + 1.0 {
                        assert_eq!(v, p.floor_level, "({i},{j}) d={d}");
                    } else {
                        assert!(v >= p.cable_level && v <= p.floor_level);
                    }
                }
            }
            // The darkness across a row integrates to the cable's width (anti-aliasing is unbiased).
            let row = 120;
            let dark: f64 = (0..320)
                .map(|i| {
                    (p.floor_level - f.view().get(i, row) as f64) / (p.floor_level - p.cable_level)
                })
                .sum();
            let line = cam.view(&pose, &cable).unwrap();
            let expected = 2.0 * half_px / line.theta.cos();
            assert!((dark - expected).abs() < 0.3, "{dark} vs {expected}");
        }
    }

    #[test]
    fn each_effect_switches_on_and_off() {
        let pose = Pose {
            x: 1.0,
            y: 0.05,
            psi: 0.2,
        };
        let moving = model::VehicleState {
            pose,
            velocity: Velocity {
                u: 0.3,
                v: 0.0,
                r: 0.0,
            },
        }
        .pose_rate();
        let clean = renderer(RenderParams::clean(), 2).render_frame(&pose, &moving, 0);
        let differs = |p: RenderParams| renderer(p, 2).render_frame(&pose, &moving, 0) != clean;
        let mut p = RenderParams::clean();
        p.texture.enabled = true;
        assert!(differs(p));
        let mut p = RenderParams::clean();
        p.clutter.enabled = true;
        assert!(differs(p));
        let mut p = RenderParams::clean();
        p.lighting.enabled = true;
        assert!(differs(p));
        let mut p = RenderParams::clean();
        p.noise.enabled = true;
        assert!(differs(p));
        let mut p = RenderParams::clean();
        p.blur.enabled = true;
        assert!(differs(p.clone()));
        // Zero amounts are as good as off.
        let mut p = RenderParams::default();
        p.texture.contrast = 0.0;
        p.texture.grain = 0.0;
        p.clutter.coverage = 0.0;
        p.lighting.vignetting = 0.0;
        p.lighting.gradient = 0.0;
        p.noise.std_dn = 0.0;
        p.blur.exposure_s = 0.0;
        assert!(!differs(p));
    }

    #[test]
    fn motion_blur_smears_along_the_motion() {
        let mut p = RenderParams::clean();
        p.blur.enabled = true;
        p.blur.exposure_s = 0.1;
        let mut r = renderer(p, 0);
        // Swaying to starboard at 0.2 m/s: the floor moves left by 0.02 m = 5.5 px during the exposure.
        let pose = Pose::default();
        let sway = model::VehicleState {
            pose,
            velocity: Velocity {
                u: 0.0,
                v: 0.2,
                r: 0.0,
            },
        }
        .pose_rate();
        let b = r.blur_vector(&pose, &sway);
        let px = 0.02 / r.camera().metres_per_px();
        assert!((b[0] + px).abs() < 1e-6 && b[1].abs() < 1e-9, "{b:?}");
        let blurred = r.render_frame(&pose, &sway, 0);
        let sharp = r.render_frame(&pose, &still(), 0);
        let (floor, cable) = (r.params().floor_level as u8, r.params().cable_level as u8);
        let edge_width = |f: &Frame| {
            (0..320)
                .filter(|&i| f.view().get(i, 100) != floor && f.view().get(i, 100) != cable)
                .count()
        };
        assert!(
            edge_width(&blurred) >= edge_width(&sharp) + 6,
            "{} {}",
            edge_width(&blurred),
            edge_width(&sharp)
        );
        // Surging smears rows, not columns: a vertical cable stays sharp.
        let surge = model::VehicleState {
            pose,
            velocity: Velocity {
                u: 0.3,
                v: 0.0,
                r: 0.0,
            },
        }
        .pose_rate();
        assert_eq!(r.render_frame(&pose, &surge, 0), sharp);
    }

    #[test]
    fn box_weights_sum_to_one() {
        for len in [1.0, 1.5, 2.0, 3.3, 10.0, 24.0, 64.0] {
            let (w, taps) = box_weights(len).unwrap();
            assert_eq!(
                w[..taps].iter().map(|&x| x as u32).sum::<u32>(),
                256,
                "{len}"
            );
            assert_eq!(taps % 2, 1);
        }
        assert!(box_weights(0.5).is_none());
    }

    /// Another camera: a frame larger than the noise table's period, an odd size, a narrow view.
    #[test]
    fn renders_for_other_cameras() {
        for (width, height, hfov_deg) in [(640, 480, 60.0), (97, 33, 20.0)] {
            let camera = config::CameraParams {
                width,
                height,
                hfov_deg,
                ..config::CameraParams::default()
            };
            let mut r = Renderer::new(
                &RenderParams::default(),
                &camera,
                &Scenario::default().cable,
                4,
            )
            .unwrap();
            let f = r.render_frame(&Pose::default(), &still(), 0);
            assert_eq!((f.width(), f.height()), (width as usize, height as usize));
        }
    }

    #[test]
    fn a_wrong_buffer_is_an_error() {
        let mut r = renderer(RenderParams::clean(), 0);
        let mut small = vec![0u8; 100];
        assert!(matches!(
            r.render(&Pose::default(), &still(), 0, &mut small),
            Err(VisionError::LengthMismatch { .. })
        ));
    }
}
