//! `tile`: the screen tile of a ray's pixel as its key (seed 004 §3 and §7: Szécsi's
//! hierarchical ray engine splits the render target into tiles of assumedly coherent rays,
//! 16×16 in his results, and bounds each tile's rays by one cone).
//!
//! # Key
//!
//! With the frame `width × height` of the stage context and the parameter `tile_size` (`ts`),
//! `tiles_x = ⌈width / ts⌉`, `tiles_y = ⌈height / ts⌉` and `tiles = tiles_x · tiles_y`; the
//! last column and row of tiles are partial when `ts` does not divide the frame. A ray of
//! pixel `p = y·width + x` ([`Ray::pixel`]) lies in tile `(y / ts)·tiles_x + x / ts`. Its key is
//! its *group* ([`TileGrid::group`]): the tile, except for shadow rays, whose group is
//! `light·tiles + tile` ([`Ray::light`]), so that a node never mixes rays of two lights (in
//! the thesis's convention the shadow rays of one light share its position as their origin;
//! the generator makes them light-major). The tile cone builder
//! ([`crate::hierarchy::tile_cone`]) groups by the same function.
//!
//! [`Hasher::key_bits`] is the bit length of `max(1, lights)·tiles − 1` (at least 1), with
//! `lights` the scene's light count, so a sorter sorts only the bits a key can have.
//!
//! # Order of the tiles (`order`)
//!
//! `rows` (the default, seed 004) numbers the tiles row by row, as above. `morton` numbers
//! them in Z-order instead ([`TileOrder::Morton`]): the tile at tile coordinates
//! `(tx, ty) = (x / ts, y / ts)` is `interleave(tx, ty)`, `tx` in the even bits and `ty` in the
//! odd ones, and a shadow ray's group is `light·span + tile` with `span = 4^b`, `b` the bit
//! length of `max(tiles_x, tiles_y) − 1` (the numbers a tile can take; `span` replaces
//! `tiles` in the key width as well). Sorted rows of tiles put a ray-space hierarchy's nodes
//! above the tiles over strips one tile high, as wide as the frame; Z-order puts every aligned
//! run of `4^k` tiles over a square of `2^k × 2^k` tiles. With `tile_size = 4` and 16 rays per
//! lowest node, a lowest node holds one 4×4 tile and the node above it 16×16 pixels. The
//! Z-order is not part of seed 004; issue 17 measured it (README, "Screen-ordered keys").
//!
//! # Order within a tile
//!
//! All rays of a group get the same key, and [`crsh_core::Sorter::sort`] is stable by
//! contract, so within a tile the rays keep their generation order (for Whitted rays: the
//! order of the surfaces that spawned them, i.e. row-major pixel order; shadow rays light by
//! light). The hierarchy over the sorted rays then holds each tile's rays consecutively: one
//! node per (compacted) tile.
//!
//! # Errors
//!
//! A ray whose pixel lies outside the frame, or a shadow ray whose light index is not below
//! the scene's light count (its key would not fit `key_bits`), is
//! [`CoreError::InvalidInput`] naming the first such ray (the generators never make one).
//! The wgpu twin writes the all-ones key of `key_bits` for such a ray instead.
//!
//! Keys depend only on the ray and the frame, so they do not depend on the thread count.

use crsh_core::quantize::spread2;
use crsh_core::{
    CoreError, FrameSize, Hasher, ParamInfo, Ray, RayKind, Registry, Result, StageKind, StageSpec,
    StageVariantInfo, Stats,
};
use rayon::prelude::*;

use crate::backend::Cpu;

/// Default tile side in pixels (seed 004 §7: 16×16 tiles).
pub const DEFAULT_TILE_SIZE: u32 = 16;
/// Accepted tile sides in pixels.
pub const TILE_SIZE_RANGE: std::ops::RangeInclusive<u32> = 1..=4096;

/// The catalogue entry of the `tile` hasher.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Hash,
        "tile",
        "the screen tile of the ray's pixel (shadow rays: light-major, light·tiles + tile), \
         so that the stable sort gathers each tile's rays in generation order (seed 004 §3, §7)",
    )
    .param(tile_size_param())
    .param(ParamInfo::choice(
        "order",
        TileOrder::Rows.name(),
        &TileOrder::NAMES,
        "how tiles are numbered: row by row (rows, seed 004) or in Z-order (morton: every \
         aligned run of 4^k tiles is a square, so the hierarchy's nodes above the tiles are \
         squares of the screen too)",
    ))
}

/// The `tile_size` parameter, shared with the tile cone builder (same meaning and range).
pub fn tile_size_param() -> ParamInfo {
    ParamInfo::int(
        "tile_size",
        DEFAULT_TILE_SIZE as i64,
        *TILE_SIZE_RANGE.start() as i64,
        *TILE_SIZE_RANGE.end() as i64,
        "tile side in pixels (partial tiles at the right and bottom edges)",
    )
}

/// Registers `tile` ([`info`], [`TileHasher::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_hasher(info(), |ctx, spec| {
        Ok(Box::new(TileHasher::new(
            ctx.frame,
            ctx.scene.lights.len(),
            spec,
        )?))
    })?;
    Ok(())
}

/// Checks a tile side against [`TILE_SIZE_RANGE`], naming the parameter `key` in the error
/// ([`CoreError::InvalidParam`]).
pub fn check_tile_size(key: &str, tile_size: u32) -> Result<()> {
    if TILE_SIZE_RANGE.contains(&tile_size) {
        return Ok(());
    }
    Err(CoreError::InvalidParam {
        key: key.into(),
        reason: format!(
            "{tile_size} is outside {}..={}",
            TILE_SIZE_RANGE.start(),
            TILE_SIZE_RANGE.end()
        ),
    })
}

/// How the tiles of a frame are numbered (the `order` parameter; see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum TileOrder {
    /// Row by row, `(y / ts)·tiles_x + x / ts` (seed 004).
    #[default]
    Rows,
    /// Z-order: the tile coordinates' bits interleaved, `x / ts` in the even bits.
    Morton,
}

impl TileOrder {
    /// The parameter's values, in the order of [`TileOrder::parse`].
    pub const NAMES: [&'static str; 2] = ["rows", "morton"];

    /// The order named `name` (`rows` or `morton`).
    pub fn parse(name: &str) -> Option<TileOrder> {
        match name {
            "rows" => Some(TileOrder::Rows),
            "morton" => Some(TileOrder::Morton),
            _ => None,
        }
    }

    /// The parameter value naming this order.
    pub fn name(self) -> &'static str {
        match self {
            TileOrder::Rows => "rows",
            TileOrder::Morton => "morton",
        }
    }
}

/// Division of a `u32` by a fixed divisor `d ≥ 1` with one multiplication (Lemire, Kaser and
/// Kurz, "Faster remainder by direct computation", 2019, theorem 1: with `c = ⌈2⁶⁴ / d⌉`,
/// `⌊n·c / 2⁶⁴⌋ = ⌊n / d⌋` for every 32-bit `n`, since 64 ≥ 32 + log₂ d). A hardware division
/// per pixel coordinate took most of the tile hash's time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct DivU32 {
    d: u32,
    /// `⌈2⁶⁴ / d⌉`; unused for `d = 1`, where it does not fit.
    c: u64,
}

impl DivU32 {
    fn new(d: u32) -> DivU32 {
        debug_assert!(d > 0);
        DivU32 {
            d,
            c: if d > 1 { u64::MAX / d as u64 + 1 } else { 0 },
        }
    }

    /// `⌊n / d⌋`.
    #[inline]
    fn div(self, n: u32) -> u32 {
        if self.d == 1 {
            n
        } else {
            ((self.c as u128 * n as u128) >> 64) as u32
        }
    }
}

/// The tiles of a frame, and the group of a ray (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileGrid {
    frame: FrameSize,
    tile_size: u32,
    tiles_x: u32,
    tiles_y: u32,
    order: TileOrder,
    /// The numbers a tile can take: `tiles` in rows, `4^b` in Z-order.
    span: u64,
    /// Division by the frame's width and by the tile side.
    by_width: DivU32,
    by_tile: DivU32,
}

impl TileGrid {
    /// The tiles of side `tile_size` over `frame`.
    ///
    /// # Errors
    /// [`CoreError::InvalidParam`] for a `tile_size` outside [`TILE_SIZE_RANGE`].
    pub fn new(frame: FrameSize, tile_size: u32) -> Result<TileGrid> {
        check_tile_size("tile_size", tile_size)?;
        let (tiles_x, tiles_y) = (
            frame.width.div_ceil(tile_size),
            frame.height.div_ceil(tile_size),
        );
        Ok(TileGrid {
            frame,
            tile_size,
            tiles_x,
            tiles_y,
            order: TileOrder::Rows,
            span: tiles_x as u64 * tiles_y as u64,
            by_width: DivU32::new(frame.width),
            by_tile: DivU32::new(tile_size),
        })
    }

    /// The same tiles numbered in `order`.
    pub fn with_order(self, order: TileOrder) -> TileGrid {
        let span = match order {
            TileOrder::Rows => self.tiles(),
            TileOrder::Morton => {
                // Frames are at most MAX_IMAGE_SIDE (2^14) pixels a side, so b <= 14.
                let b = 32 - (self.tiles_x.max(self.tiles_y) - 1).leading_zeros();
                1u64 << (2 * b)
            }
        };
        TileGrid {
            order,
            span,
            ..self
        }
    }

    /// How the tiles are numbered.
    pub fn order(&self) -> TileOrder {
        self.order
    }

    /// The numbers a tile can take (tile numbers are below it): [`TileGrid::tiles`] in rows,
    /// `4^b` in Z-order with `b` the bit length of `max(tiles_x, tiles_y) − 1`. A shadow
    /// ray's group is `light·span + tile`.
    pub fn span(&self) -> u64 {
        self.span
    }

    /// The frame.
    pub fn frame(&self) -> FrameSize {
        self.frame
    }

    /// The tile side in pixels.
    pub fn tile_size(&self) -> u32 {
        self.tile_size
    }

    /// Tiles per row, `⌈width / tile_size⌉`.
    pub fn tiles_x(&self) -> u32 {
        self.tiles_x
    }

    /// Tiles per column, `⌈height / tile_size⌉`.
    pub fn tiles_y(&self) -> u32 {
        self.tiles_y
    }

    /// Tiles in the frame.
    pub fn tiles(&self) -> u64 {
        self.tiles_x as u64 * self.tiles_y as u64
    }

    /// The number of pixel `pixel`'s (`y·width + x`) tile: `(y / ts)·tiles_x + x / ts` in rows,
    /// `interleave(x / ts, y / ts)` in Z-order; `None` when the pixel lies outside the frame.
    #[inline]
    pub fn tile(&self, pixel: u32) -> Option<u64> {
        let y = self.by_width.div(pixel);
        if y >= self.frame.height {
            return None;
        }
        let x = pixel - y * self.frame.width;
        let (tx, ty) = (self.by_tile.div(x), self.by_tile.div(y));
        Some(match self.order {
            TileOrder::Rows => ty as u64 * self.tiles_x as u64 + tx as u64,
            TileOrder::Morton => spread2(tx as u64) | spread2(ty as u64) << 1,
        })
    }

    /// The group of `ray`: its pixel's tile, plus `light·span` for a shadow ray; `None` when
    /// the pixel lies outside the frame. The key of the `tile` hasher and the node boundary of
    /// the tile cone builder (one definition for both).
    #[inline]
    pub fn group(&self, ray: &Ray) -> Option<u64> {
        let tile = self.tile(ray.pixel)?;
        Some(if ray.kind == RayKind::Shadow as u32 {
            ray.light as u64 * self.span + tile
        } else {
            tile
        })
    }

    /// The bits a group needs with `lights` lights: the bit length of
    /// `max(1, lights)·span − 1`, at least 1.
    pub fn key_bits(&self, lights: usize) -> u32 {
        let top = (lights.max(1) as u64).saturating_mul(self.span) - 1;
        (64 - top.leading_zeros()).max(1)
    }
}

/// The `tile` hasher (see the module docs).
#[derive(Clone, Debug)]
pub struct TileHasher {
    grid: TileGrid,
    lights: usize,
}

impl TileHasher {
    /// The hasher for `frame` and a scene of `lights` lights, with the `tile_size` of a
    /// resolved `spec`.
    ///
    /// # Errors
    /// [`CoreError::InvalidParam`] for a `tile_size` out of range or an `order` other than
    /// `rows` and `morton`.
    pub fn new(frame: FrameSize, lights: usize, spec: &StageSpec) -> Result<TileHasher> {
        let tile_size = spec.u32_in("tile_size", TILE_SIZE_RANGE)?;
        let name = spec.str("order")?;
        let order = TileOrder::parse(name).ok_or_else(|| CoreError::InvalidParam {
            key: "hash.order".into(),
            reason: format!("`{name}` is not a tile order (rows, morton)"),
        })?;
        Ok(TileHasher::with_grid(
            TileGrid::new(frame, tile_size)?.with_order(order),
            lights,
        ))
    }

    /// The hasher over `grid` for a scene of `lights` lights.
    pub fn with_grid(grid: TileGrid, lights: usize) -> TileHasher {
        TileHasher { grid, lights }
    }

    /// The tiles.
    pub fn grid(&self) -> &TileGrid {
        &self.grid
    }

    /// The key of `ray`, or why it has none.
    fn key(&self, ray: &Ray) -> Option<u64> {
        if ray.kind == RayKind::Shadow as u32 && ray.light as usize >= self.lights {
            return None;
        }
        self.grid.group(ray)
    }
}

impl Hasher<Cpu> for TileHasher {
    fn name(&self) -> &str {
        "tile"
    }

    fn key_bits(&self) -> u32 {
        self.grid.key_bits(self.lights)
    }

    fn hash(
        &self,
        _backend: &Cpu,
        rays: &Vec<Ray>,
        _kind: RayKind,
        _stats: &mut Stats,
    ) -> Result<Vec<u64>> {
        // One pass: a group is below 2^60 (a light below 2^32 times a span of at most 2^28),
        // so the all-ones word marks the rays without a key.
        let keys: Vec<u64> = rays
            .par_iter()
            .map(|r| self.key(r).unwrap_or(u64::MAX))
            .collect();
        if let Some(i) = crate::position_first(&keys, |&k| k == u64::MAX) {
            let r = &rays[i];
            let f = self.grid.frame;
            return Err(CoreError::InvalidInput(format!(
                "tile hash: ray {i} (pixel {}, kind {}, light {}) lies outside the {f} frame \
                 or names a light the scene's {} lights lack",
                r.pixel, r.kind, r.light, self.lights
            )));
        }
        Ok(keys)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::with_threads;
    use crsh_core::glam::Vec3;
    use crsh_core::ParamValue;

    fn ray(kind: RayKind, pixel: u32, light: u32) -> Ray {
        Ray {
            origin: Vec3::ZERO,
            t_min: 0.0,
            dir: Vec3::Z,
            t_max: f32::INFINITY,
            throughput: Vec3::ONE,
            kind: kind as u32,
            pixel,
            light,
            depth: 1,
            source: pixel,
        }
    }

    fn frame(w: u32, h: u32) -> FrameSize {
        FrameSize::new(w, h).unwrap()
    }

    fn hash(h: &TileHasher, rays: &Vec<Ray>) -> Result<Vec<u64>> {
        h.hash(&Cpu, rays, RayKind::Reflection, &mut Stats::default())
    }

    #[test]
    fn keys_of_a_frame_with_partial_tiles() {
        // 100×37 in tiles of 16: 7 × 3 tiles, the last column 4 wide, the last row 5 high.
        let grid = TileGrid::new(frame(100, 37), 16).unwrap();
        assert_eq!((grid.tiles_x(), grid.tiles_y(), grid.tiles()), (7, 3, 21));
        let h = TileHasher::with_grid(grid, 1);
        let at = |x: u32, y: u32| y * 100 + x;
        let cases = [
            (at(0, 0), 0),
            (at(15, 15), 0),
            (at(16, 0), 1),
            (at(0, 16), 7),
            (at(95, 0), 5),
            (at(96, 0), 6),
            (at(99, 15), 6),
            (at(31, 17), 8),
            (at(0, 32), 14),
            (at(99, 36), 20),
        ];
        let rays: Vec<Ray> = cases
            .iter()
            .map(|&(p, _)| ray(RayKind::Reflection, p, u32::MAX))
            .collect();
        let keys = hash(&h, &rays).unwrap();
        let want: Vec<u64> = cases.iter().map(|c| c.1).collect();
        assert_eq!(keys, want);
        // Every pixel: the tiles hold 16×16, 4×16 (last column), 16×5 (last row), 4×5 pixels.
        let all: Vec<Ray> = (0..100 * 37)
            .map(|p| ray(RayKind::Refraction, p, u32::MAX))
            .collect();
        let mut count = [0usize; 21];
        for k in hash(&h, &all).unwrap() {
            count[k as usize] += 1;
        }
        for (t, &c) in count.iter().enumerate() {
            let w = if t % 7 == 6 { 4 } else { 16 };
            let hgt = if t / 7 == 2 { 5 } else { 16 };
            assert_eq!(c, w * hgt, "tile {t}");
        }
    }

    #[test]
    fn shadow_rays_of_two_lights_never_share_a_key() {
        let grid = TileGrid::new(frame(100, 37), 16).unwrap();
        let h = TileHasher::with_grid(grid, 2);
        let rays: Vec<Ray> = (0..2)
            .flat_map(|l| (0..100 * 37).map(move |p| ray(RayKind::Shadow, p, l)))
            .collect();
        let keys = hash(&h, &rays).unwrap();
        let (a, b) = keys.split_at(100 * 37);
        let max_a = a.iter().max().unwrap();
        let min_b = b.iter().min().unwrap();
        assert!(
            max_a < min_b,
            "light 0 keys {max_a} >= light 1 keys {min_b}"
        );
        assert_eq!((*max_a, *min_b), (20, 21));
        let bits = Hasher::<Cpu>::key_bits(&h);
        assert!(keys.iter().all(|&k| k < 1 << bits));
        // Other kinds ignore the light field (ao/diffuse keep a sample index there).
        let ao = vec![ray(RayKind::Ao, 0, 7), ray(RayKind::Diffuse, 99, 3)];
        assert_eq!(hash(&h, &ao).unwrap(), [0, 6]);
    }

    #[test]
    fn z_order_keys_of_a_frame_with_partial_tiles() {
        // 100×37 in tiles of 16: 7 × 3 tiles, coordinates below 8, so span 4^3 = 64.
        let grid = TileGrid::new(frame(100, 37), 16)
            .unwrap()
            .with_order(TileOrder::Morton);
        assert_eq!((grid.tiles(), grid.span()), (21, 64));
        let h = TileHasher::with_grid(grid, 2);
        let at = |x: u32, y: u32| y * 100 + x;
        let cases = [
            (at(0, 0), 0),
            (at(15, 15), 0),
            (at(16, 0), 1),
            (at(0, 16), 2),
            (at(31, 31), 3),
            (at(32, 0), 4),
            (at(48, 16), 7),
            (at(0, 32), 8),
            (at(64, 0), 16),
            (at(99, 36), 28), // tile (6, 2): 0b110 and 0b010 interleaved, 0b011100
        ];
        let rays: Vec<Ray> = cases
            .iter()
            .map(|&(p, _)| ray(RayKind::Reflection, p, u32::MAX))
            .collect();
        let want: Vec<u64> = cases.iter().map(|c| c.1).collect();
        assert_eq!(hash(&h, &rays).unwrap(), want);
        // Shadow rays: light·span + tile, so light 1 starts at 64.
        let shadow = vec![
            ray(RayKind::Shadow, at(0, 0), 1),
            ray(RayKind::Shadow, at(99, 36), 1),
        ];
        assert_eq!(hash(&h, &shadow).unwrap(), [64, 92]);
        assert_eq!(
            Hasher::<Cpu>::key_bits(&h),
            7,
            "2 lights · 64: keys 0..=127"
        );
        // Every tile gets its own number, the same 21 tiles as in rows.
        let all: Vec<Ray> = (0..100 * 37)
            .map(|p| ray(RayKind::Refraction, p, u32::MAX))
            .collect();
        let rows = TileHasher::with_grid(TileGrid::new(frame(100, 37), 16).unwrap(), 2);
        let mut pairs: Vec<(u64, u64)> = hash(&h, &all)
            .unwrap()
            .into_iter()
            .zip(hash(&rows, &all).unwrap())
            .collect();
        pairs.sort_unstable();
        pairs.dedup();
        assert_eq!(pairs.len(), 21);
        assert!(pairs
            .windows(2)
            .all(|w| w[0].0 < w[1].0 && w[0].1 != w[1].1));
    }

    #[test]
    fn z_order_runs_of_four_to_the_k_tiles_are_squares() {
        // 64×48 pixels in tiles of 2: 32 × 24 tiles. Sorted by key, every aligned run of
        // 4^k tile numbers lies in one 2^k × 2^k square of tiles.
        let grid = TileGrid::new(frame(64, 48), 2)
            .unwrap()
            .with_order(TileOrder::Morton);
        assert_eq!(grid.span(), 1024);
        for k in 0..=5u32 {
            let side = 2u32 << k; // pixels per square side
            for p in 0..64 * 48u32 {
                let key = grid.tile(p).unwrap();
                let (x, y) = (p % 64, p / 64);
                let run = key >> (2 * k);
                // The square's corner, from the run's number.
                let corner = |bits: u64, shift: u32| {
                    (0..16).fold(0u32, |a, i| {
                        a | (((bits >> (2 * i + shift)) & 1) as u32) << i
                    })
                };
                let (cx, cy) = (corner(run, 0) * side, corner(run, 1) * side);
                assert!(
                    (cx..cx + side).contains(&x) && (cy..cy + side).contains(&y),
                    "k {k}: pixel ({x}, {y}) key {key} outside the square at ({cx}, {cy})"
                );
            }
        }
    }

    #[test]
    fn division_by_multiplication_is_exact() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state as u32
        };
        let edges = [
            0,
            1,
            2,
            3,
            1023,
            1024,
            1025,
            16383,
            16384,
            u32::MAX - 1,
            u32::MAX,
        ];
        let mut divisors = vec![
            1, 2, 3, 4, 5, 7, 16, 100, 1000, 1024, 1920, 4096, 16383, 16384,
        ];
        divisors.extend([65535, 1 << 31, u32::MAX - 1, u32::MAX]);
        divisors.extend((0..200).map(|_| next().max(1)));
        for d in divisors {
            let f = DivU32::new(d);
            for n in edges.into_iter().chain((0..2000).map(|_| next())) {
                assert_eq!(f.div(n), n / d, "{n} / {d}");
            }
            // Around every multiple of small divisors, where a floor changes.
            if d <= 16384 {
                for k in [1u32, 2, 3, 1000, u32::MAX / d] {
                    let m = k * d;
                    for n in [m - 1, m, m.saturating_add(1)] {
                        assert_eq!(f.div(n), n / d, "{n} / {d}");
                    }
                }
            }
        }
    }

    #[test]
    fn key_bits_cover_the_groups() {
        let grid = TileGrid::new(frame(100, 37), 16).unwrap();
        // 21 tiles: keys 0..=20 (5 bits); 2 lights: 0..=41 (6 bits); no light counts as one.
        assert_eq!(grid.key_bits(0), 5);
        assert_eq!(grid.key_bits(1), 5);
        assert_eq!(grid.key_bits(2), 6);
        assert_eq!(grid.key_bits(3), 6);
        assert_eq!(grid.key_bits(4), 7);
        // One tile, one light: key 0, still 1 bit.
        assert_eq!(TileGrid::new(frame(1, 1), 16).unwrap().key_bits(1), 1);
        assert_eq!(TileGrid::new(frame(100, 37), 4096).unwrap().key_bits(1), 1);
        // 32×32 in tiles of 16: 4 tiles, keys 0..=3, 2 bits.
        assert_eq!(TileGrid::new(frame(32, 32), 16).unwrap().key_bits(1), 2);
        // The largest frame in one-pixel tiles with many lights still fits.
        let huge = TileGrid::new(frame(16384, 16384), 1).unwrap();
        assert_eq!(huge.key_bits(1), 28);
        assert_eq!(huge.key_bits(1000), 38);
        // Z-order: span 4^b for tile coordinates of b bits, whatever the other side.
        let z = |w, h, ts| {
            TileGrid::new(frame(w, h), ts)
                .unwrap()
                .with_order(TileOrder::Morton)
        };
        assert_eq!(z(16384, 16384, 1).key_bits(1), 28);
        assert_eq!(z(16384, 1, 1).span(), 1 << 28);
        assert_eq!(z(16384, 16384, 1).key_bits(1000), 38);
        assert_eq!(z(1024, 768, 4).span(), 1 << 16);
        assert_eq!(z(1024, 768, 4).key_bits(3), 18);
        assert_eq!((z(1, 1, 1).span(), z(1, 1, 1).key_bits(1)), (1, 1));
        assert_eq!((z(2, 1, 1).span(), z(2, 1, 1).key_bits(1)), (4, 2));
        assert_eq!(z(100, 37, 4096).key_bits(5), 3);
    }

    #[test]
    fn bad_rays_and_params_are_errors() {
        let grid = TileGrid::new(frame(10, 10), 4).unwrap();
        let h = TileHasher::with_grid(grid, 1);
        for bad in [
            ray(RayKind::Reflection, 100, u32::MAX),
            ray(RayKind::Reflection, u32::MAX, u32::MAX),
            ray(RayKind::Shadow, 5, 1),
            ray(RayKind::Shadow, 5, u32::MAX),
        ] {
            let rays = vec![ray(RayKind::Reflection, 0, 0), bad];
            let r = hash(&h, &rays);
            assert!(matches!(r, Err(CoreError::InvalidInput(_))), "{r:?}");
        }
        assert!(TileGrid::new(frame(10, 10), 0).is_err());
        assert!(TileGrid::new(frame(10, 10), 4097).is_err());
        let mut spec = StageSpec::new("tile");
        spec.params.insert("tile_size".into(), ParamValue::Int(8));
        assert!(matches!(
            TileHasher::new(frame(100, 37), 2, &spec),
            Err(CoreError::InvalidParam { .. })
        ));
        spec.params
            .insert("order".into(), ParamValue::Str("rows".into()));
        let h = TileHasher::new(frame(100, 37), 2, &spec).unwrap();
        assert_eq!(h.grid().tile_size(), 8);
        assert_eq!(
            Hasher::<Cpu>::key_bits(&h),
            8,
            "13 × 5 tiles × 2 lights: keys 0..=129"
        );
        spec.params
            .insert("order".into(), ParamValue::Str("morton".into()));
        let h = TileHasher::new(frame(100, 37), 2, &spec).unwrap();
        assert_eq!(h.grid().order(), TileOrder::Morton);
        assert_eq!(
            Hasher::<Cpu>::key_bits(&h),
            9,
            "13 × 5 tiles in Z-order: span 16², × 2 lights: keys 0..=511"
        );
        spec.params
            .insert("order".into(), ParamValue::Str("hilbert".into()));
        assert!(matches!(
            TileHasher::new(frame(100, 37), 2, &spec),
            Err(CoreError::InvalidParam { .. })
        ));
        spec.params
            .insert("order".into(), ParamValue::Str("rows".into()));
        spec.params.insert("tile_size".into(), ParamValue::Int(0));
        assert!(matches!(
            TileHasher::new(frame(100, 37), 2, &spec),
            Err(CoreError::InvalidParam { .. })
        ));
    }

    #[test]
    fn registry_builds_it_from_the_frame_and_the_stable_sort_keeps_generation_order() {
        use crate::hash::test_util::scene_with_lights;
        use crsh_core::StageContext;
        let scene = scene_with_lights(2);
        let registry = Registry::<Cpu>::builtin();
        let ctx = StageContext::new(&Cpu, &scene, frame(40, 20));
        let mut cfg = registry.preset("crsh").unwrap();
        cfg.set("hash.kind=tile").unwrap();
        cfg.set("hash.tile_size=8").unwrap();
        cfg.set("sort.kind=radix").unwrap();
        let pipeline = registry.build(&ctx, &cfg).unwrap();
        let h = pipeline.stages.hasher.as_ref().unwrap();
        let sorter = pipeline.stages.sorter.as_ref().unwrap();
        assert_eq!(h.name(), "tile");
        // 5 × 3 tiles, 2 lights: 30 groups, 5 bits.
        assert_eq!(h.key_bits(), 5);
        let rays: Vec<Ray> = (0..2)
            .flat_map(|l| (0..800).map(move |p| ray(RayKind::Shadow, p, l)))
            .collect();
        let keys = h
            .hash(&Cpu, &rays, RayKind::Shadow, &mut Stats::default())
            .unwrap();
        let order = sorter
            .sort(&Cpu, &keys, h.key_bits(), &mut Stats::default())
            .unwrap();
        // Runs of one group each, in increasing group order, generation order inside.
        for w in order.windows(2) {
            let (a, b) = (w[0] as usize, w[1] as usize);
            assert!(keys[a] < keys[b] || (keys[a] == keys[b] && a < b));
        }
        let one = with_threads(1, || {
            h.hash(&Cpu, &rays, RayKind::Shadow, &mut Stats::default())
        })
        .unwrap()
        .unwrap();
        assert_eq!(one, keys);
    }
}
