//! The pool floor as precomputed tiles in floor coordinates: its texture (fractal value noise and a
//! grain) and the clutter lying on it (sand and algae patches). Built once per renderer and seed;
//! rendering a frame only looks texels up. The tiles wrap seamlessly, so the floor is endless.

use crate::rng::{SplitMix64, sub_seed};
use config::RenderParams;

pub(crate) const TILE_BITS: u32 = 10;
/// Texels per tile side.
pub(crate) const TILE: usize = 1 << TILE_BITS;
pub(crate) const TILE_MASK: u32 = TILE as u32 - 1;
pub(crate) const TEXELS: usize = TILE * TILE;

/// The index of texel (`x` along the pool's x, `y` along its y), both below [`TILE`]. Texels
/// consecutive along y are consecutive in memory: an image row runs across the vehicle, so while the
/// vehicle heads along the pool (and the cable) a row reads nearly consecutive bytes.
#[inline(always)]
pub(crate) fn texel_index(x: u32, y: u32) -> usize {
    ((x << TILE_BITS) | y) as usize
}

/// The floor's tiles, indexed by [`texel_index`].
pub(crate) struct FloorTiles {
    /// What the camera sees where there is no cable: the floor with the clutter on it.
    pub scene: Box<[u8; TEXELS]>,
    /// The bare floor, and the clutter's opacity (0-255): to put the cable between the two.
    pub base: Box<[u8; TEXELS]>,
    pub alpha: Box<[u8; TEXELS]>,
}

fn boxed_tile() -> Box<[u8; TEXELS]> {
    vec![0u8; TEXELS]
        .into_boxed_slice()
        .try_into()
        .expect("TEXELS bytes")
}

/// Builds the tiles for texels of `texel_m` metres, or `None` when both texture and clutter are off
/// (the floor is then uniform and rendering skips the look-ups).
pub(crate) fn build(params: &RenderParams, texel_m: f64, seed: u64) -> Option<FloorTiles> {
    let rows = build_row_major(params, texel_m, seed)?;
    let mut tiles = FloorTiles {
        scene: boxed_tile(),
        base: boxed_tile(),
        alpha: boxed_tile(),
    };
    for y in 0..TILE {
        for x in 0..TILE {
            let (from, to) = (y * TILE + x, texel_index(x as u32, y as u32));
            tiles.scene[to] = rows.scene[from];
            tiles.base[to] = rows.base[from];
            tiles.alpha[to] = rows.alpha[from];
        }
    }
    Some(tiles)
}

/// [`build`] with the tiles row by row.
fn build_row_major(params: &RenderParams, texel_m: f64, seed: u64) -> Option<FloorTiles> {
    let texture =
        params.texture.enabled && (params.texture.contrast > 0.0 || params.texture.grain > 0.0);
    let clutter =
        params.clutter.enabled && params.clutter.coverage > 0.0 && params.clutter.opacity > 0.0;
    if !texture && !clutter {
        return None;
    }
    let mut base = vec![params.floor_level as f32; TEXELS];
    if texture {
        let t = &params.texture;
        let blotches = fbm(sub_seed(seed, 1), spacing(t.scale_m, texel_m), 5);
        let mut grain = SplitMix64::new(sub_seed(seed, 2));
        for (b, n) in base.iter_mut().zip(&blotches) {
            *b += t.contrast as f32 * n + t.grain as f32 * grain.gaussian() as f32;
        }
    }
    let mut tiles = FloorTiles {
        scene: boxed_tile(),
        base: boxed_tile(),
        alpha: boxed_tile(),
    };
    for (dst, b) in tiles.base.iter_mut().zip(&base) {
        *dst = b.round().clamp(0.0, 255.0) as u8;
    }
    if !clutter {
        tiles.scene.copy_from_slice(&tiles.base[..]);
        return Some(tiles);
    }
    let c = &params.clutter;
    let s = spacing(c.scale_m, texel_m);
    let patches = fbm(sub_seed(seed, 3), s, 3);
    // The threshold above which a fraction `coverage` of the floor lies.
    let mut sample: Vec<f32> = patches.iter().step_by(7).copied().collect();
    let k = ((1.0 - c.coverage) * (sample.len() - 1) as f64) as usize;
    let (_, &mut threshold, _) = sample.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    let kind = fbm(sub_seed(seed, 4), (4 * s).min(TILE / 4), 2);
    let mut grain = SplitMix64::new(sub_seed(seed, 5));
    let soft = 0.3f32;
    for t in 0..TEXELS {
        let a = c.opacity as f32 * smoothstep(threshold - soft, threshold + soft, patches[t]);
        // Grainy patches: sand and algae are not a uniform sheet.
        let a = a * (0.7 + 0.3 * grain.next_f64() as f32);
        let sand = smoothstep(-0.3, 0.3, kind[t]);
        let level = c.algae_level as f32
            + (c.sand_level - c.algae_level) as f32 * sand
            + 8.0 * grain.gaussian() as f32;
        let mixed = base[t] * (1.0 - a) + level * a;
        tiles.scene[t] = mixed.round().clamp(0.0, 255.0) as u8;
        tiles.alpha[t] = (a * 255.0).round().clamp(0.0, 255.0) as u8;
    }
    Some(tiles)
}

/// The lattice spacing (texels, a power of two dividing the tile) nearest to `scale_m`.
fn spacing(scale_m: f64, texel_m: f64) -> usize {
    let texels = (scale_m / texel_m).max(1.0);
    let p = texels.log2().round().clamp(2.0, (TILE_BITS - 2) as f64);
    1 << p as u32
}

fn smoothstep(lo: f32, hi: f32, x: f32) -> f32 {
    let t = ((x - lo) / (hi - lo)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Fractal value noise over the tile: `octaves` octaves from lattice spacing `spacing` down, each
/// half the size and half the amplitude, normalised to zero mean and unit standard deviation.
fn fbm(seed: u64, spacing: usize, octaves: u32) -> Vec<f32> {
    let mut rng = SplitMix64::new(seed);
    let mut out = vec![0f32; TEXELS];
    let mut s = spacing;
    let mut amp = 1.0f32;
    for _ in 0..octaves {
        if s < 2 {
            break;
        }
        value_noise(&mut rng, s, amp, &mut out);
        s /= 2;
        amp *= 0.5;
    }
    let n = TEXELS as f64;
    let mean = out.iter().map(|&v| v as f64).sum::<f64>() / n;
    let var = out.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / n;
    let inv = if var > 0.0 { 1.0 / var.sqrt() } else { 0.0 };
    for v in &mut out {
        *v = ((*v as f64 - mean) * inv) as f32;
    }
    out
}

/// Adds `amp` times one octave of value noise with lattice spacing `s` (wrapping over the tile).
fn value_noise(rng: &mut SplitMix64, s: usize, amp: f32, out: &mut [f32]) {
    let cells = TILE / s;
    let lattice: Vec<f32> = (0..cells * cells)
        .map(|_| rng.uniform(-1.0, 1.0) as f32)
        .collect();
    // Per column: lattice cell and smoothed fraction.
    let cols: Vec<(usize, usize, f32)> = (0..TILE)
        .map(|x| {
            let c = x / s;
            let f = (x % s) as f32 / s as f32;
            (c, (c + 1) % cells, f * f * (3.0 - 2.0 * f))
        })
        .collect();
    for y in 0..TILE {
        let (r0, r1, fy) = cols[y];
        let row0 = &lattice[r0 * cells..(r0 + 1) * cells];
        let row1 = &lattice[r1 * cells..(r1 + 1) * cells];
        let dst = &mut out[y * TILE..(y + 1) * TILE];
        for (d, &(c0, c1, fx)) in dst.iter_mut().zip(&cols) {
            let top = row0[c0] + (row0[c1] - row0[c0]) * fx;
            let bottom = row1[c0] + (row1[c1] - row1[c0]) * fx;
            *d += amp * (top + (bottom - top) * fy);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clutter_covers_about_the_asked_fraction() {
        let params = RenderParams::default();
        let tiles = build(&params, 0.0036, 9).unwrap();
        let covered = tiles
            .alpha
            .iter()
            .filter(|&&a| a as f64 > 0.5 * 255.0 * 0.85 * 0.85)
            .count();
        let fraction = covered as f64 / TEXELS as f64;
        assert!(
            (fraction - params.clutter.coverage).abs() < 0.06,
            "{fraction}"
        );
        assert!(build(&RenderParams::clean(), 0.0036, 9).is_none());
    }
}
