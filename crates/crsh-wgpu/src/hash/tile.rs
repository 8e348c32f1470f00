//! `tile` on the wgpu backend: seed 004's screen tiles as sort keys (Szécsi, "The Hierarchical
//! Ray Engine", WSCG 2006, §3-§4: "an enclosing cone for rays is built for every tile"), one
//! invocation per ray.
//!
//! The frame (from the stage context, [`crsh_core::StageContext::frame`]) is cut into tiles of
//! `tile_size × tile_size` pixels, `tiles_x = ⌈width / tile_size⌉` per row and
//! `tiles = tiles_x · ⌈height / tile_size⌉` in all. A ray of pixel `y·width + x`
//! ([`Ray::pixel`]) is in tile `(y / tile_size)·tiles_x + x / tile_size`; its key is that tile,
//! and for shadow rays `light·tiles + tile` ([`Ray::light`]) so that a node of the `tile_cone`
//! hierarchy never mixes the rays of two lights (shadow rays are light-major and start at
//! their light in the thesis convention). [`Hasher::key_bits`] is the bit length of
//! `max(1, lights)·tiles − 1` (at least 1), with `lights` the scene's light count. Within a
//! tile the rays keep their generation order: [`crsh_core::Sorter::sort`] is stable by
//! contract.
//!
//! The twin is the CPU `tile` hasher (`crsh_cpu::hash::tile`, written from the same spec on
//! another branch; until it lands, this module carries the catalogue entry, [`info`], and the
//! host-side formula, [`TileGrid::group`]). The keys are integers, so both backends give the
//! same keys bit for bit. A ray whose pixel is outside the frame is an error on the CPU; the
//! kernel cannot fail, so it writes the all-ones key of `key_bits` for such a ray (the
//! generators never make one).
//!
//! The tile grid is also what the `tile_cone` builder groups by
//! ([`crate::hierarchy::tile_cone`]); both use `tile_group.wgsl`.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{
    CoreError, FrameSize, Hasher, ParamInfo, Ray, RayKind, Registry, Result, StageKind, StageSpec,
    StageVariantInfo, Stats,
};

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{chunks, encoder, submit, uniform, Kernel, Slot};
use crate::scene::GpuScene;

const SHADER: &str = include_str!("tile.wgsl");

/// Default tile side in pixels (the `tile_size` parameter of `tile` and `tile_cone`).
pub const DEFAULT_TILE_SIZE: u32 = 16;
/// Largest tile side in pixels.
pub const MAX_TILE_SIZE: u32 = 4096;

/// `tile_group.wgsl` with the constant it needs (generated from [`RayKind::Shadow`]): the
/// group of a ray, shared by the `tile` hash and the `tile_cone` builder.
pub(crate) fn tile_group_wgsl() -> String {
    format!(
        "const RAY_KIND_SHADOW: u32 = {}u;\n{}",
        RayKind::Shadow as u32,
        include_str!("tile_group.wgsl")
    )
}

/// The catalogue entry of the `tile` hasher.
///
/// Carried here until the CPU twin's (`crsh_cpu::hash::tile::info`) lands; then the wgpu
/// variant registers under that one, as every other wgpu variant does.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Hash,
        "tile",
        "screen tile of the ray's pixel (shadow rays: per light), rays of a tile in \
         generation order (seed 004 §4's per-tile cones)",
    )
    .param(tile_size_param())
}

/// The `tile_size` parameter shared by `tile` and `tile_cone`.
pub(crate) fn tile_size_param() -> ParamInfo {
    ParamInfo::int(
        "tile_size",
        i64::from(DEFAULT_TILE_SIZE),
        1,
        i64::from(MAX_TILE_SIZE),
        "tile side in pixels",
    )
}

/// A frame cut into square tiles: the groups of seed 004's tiles, on the host.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileGrid {
    /// Frame width in pixels.
    pub width: u32,
    /// Frame height in pixels.
    pub height: u32,
    /// Tile side in pixels.
    pub tile_size: u32,
    /// Tiles per row: `⌈width / tile_size⌉`.
    pub tiles_x: u32,
    /// Tiles in all: `tiles_x · ⌈height / tile_size⌉`.
    pub tiles: u32,
}

impl TileGrid {
    /// The grid of `frame` with tiles of `tile_size` pixels.
    ///
    /// # Errors
    /// [`CoreError::InvalidInput`] when `tile_size` is outside `1..=`[`MAX_TILE_SIZE`].
    pub fn new(frame: FrameSize, tile_size: u32) -> Result<TileGrid> {
        if !(1..=MAX_TILE_SIZE).contains(&tile_size) {
            return Err(CoreError::InvalidInput(format!(
                "tile size {tile_size} is outside 1..={MAX_TILE_SIZE}"
            )));
        }
        let tiles_x = frame.width.div_ceil(tile_size);
        let tiles_y = frame.height.div_ceil(tile_size);
        Ok(TileGrid {
            width: frame.width,
            height: frame.height,
            tile_size,
            tiles_x,
            tiles: tiles_x * tiles_y,
        })
    }

    /// The group of a ray of `pixel`, `light` and `kind`: its tile, or `light·tiles + tile` for
    /// shadow rays; `None` when the pixel is outside the frame. The host twin of the kernels'
    /// `tile_group`.
    pub fn group(&self, pixel: u32, light: u32, kind: u32) -> Option<u64> {
        let y = pixel / self.width;
        let x = pixel % self.width;
        if y >= self.height {
            return None;
        }
        let tile = u64::from((y / self.tile_size) * self.tiles_x + x / self.tile_size);
        if kind == RayKind::Shadow as u32 {
            Some(u64::from(light) * u64::from(self.tiles) + tile)
        } else {
            Some(tile)
        }
    }

    /// The key width for a scene with `lights` lights: the bit length of
    /// `max(1, lights)·tiles − 1`, at least 1.
    pub fn key_bits(&self, lights: usize) -> u32 {
        let groups = (lights.max(1) as u64).saturating_mul(u64::from(self.tiles));
        let largest = groups.saturating_sub(1);
        (64 - largest.leading_zeros()).max(1)
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n: u32,
    width: u32,
    height: u32,
    tile_size: u32,
    tiles_x: u32,
    tiles: u32,
    none_lo: u32,
    none_hi: u32,
}

struct TileKernels {
    kernel: Kernel,
}

impl TileKernels {
    fn new(ctx: &GpuContext) -> GpuResult<TileKernels> {
        Ok(TileKernels {
            kernel: Kernel::new(
                ctx,
                "crsh tile hash",
                &format!("{}\n{SHADER}", tile_group_wgsl()),
                &["hash"],
                &[Slot::Uniform, Slot::Read, Slot::ReadWrite],
            )?,
        })
    }
}

/// The GPU `tile` hasher.
#[derive(Clone, Debug)]
pub struct Tile {
    grid: TileGrid,
    key_bits: u32,
}

/// Registers the wgpu `tile` ([`info`], [`Tile::new`] with the stage context's frame).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_hasher(info(), |ctx, spec| {
        Ok(Box::new(Tile::new(ctx.scene, ctx.frame, spec)?))
    })?;
    Ok(())
}

impl Tile {
    /// The hasher for `scene` (its light count sizes the keys) rendering `frame`, with a
    /// resolved `spec` (`tile_size`).
    ///
    /// # Errors
    /// [`CoreError::InvalidParam`] for a `tile_size` out of range.
    pub fn new(scene: &Arc<GpuScene>, frame: FrameSize, spec: &StageSpec) -> Result<Tile> {
        let tile_size = spec.u32_in("tile_size", 1..=MAX_TILE_SIZE)?;
        Tile::with_params(frame, tile_size, scene.scene.lights.len())
    }

    /// The hasher for `frame` with tiles of `tile_size` pixels and keys sized for `lights`
    /// lights.
    ///
    /// # Errors
    /// [`CoreError::InvalidInput`] for a `tile_size` out of range.
    pub fn with_params(frame: FrameSize, tile_size: u32, lights: usize) -> Result<Tile> {
        let grid = TileGrid::new(frame, tile_size)?;
        Ok(Tile {
            grid,
            key_bits: grid.key_bits(lights),
        })
    }

    /// The tile grid.
    pub fn grid(&self) -> TileGrid {
        self.grid
    }
}

impl Hasher<Wgpu> for Tile {
    fn name(&self) -> &str {
        "tile"
    }

    fn key_bits(&self) -> u32 {
        self.key_bits
    }

    fn hash(
        &self,
        backend: &Wgpu,
        rays: &GpuBuffer<Ray>,
        _kind: RayKind,
        _stats: &mut Stats,
    ) -> Result<GpuBuffer<u64>> {
        let ctx = backend.context();
        let n = rays.len();
        let keys = GpuBuffer::<u64>::zeroed(ctx, "crsh ray keys", n)?;
        if n == 0 {
            return Ok(keys);
        }
        let k = ctx.kernel(TileKernels::new)?;
        let none = if self.key_bits >= 64 {
            u64::MAX
        } else {
            (1u64 << self.key_bits) - 1
        };
        let g = self.grid;
        let mut groups = Vec::new();
        for range in chunks::<Ray>(ctx, n) {
            let params = Params {
                n: range.len() as u32,
                width: g.width,
                height: g.height,
                tile_size: g.tile_size,
                tiles_x: g.tiles_x,
                tiles: g.tiles,
                none_lo: none as u32,
                none_hi: (none >> 32) as u32,
            };
            let u = uniform(ctx, "crsh tile params", &params);
            let bg = k.kernel.bind_group(
                ctx,
                &[
                    u.as_entire_binding(),
                    rays.slice_binding(range.clone()),
                    keys.slice_binding(range.clone()),
                ],
            );
            groups.push((bg, range.len() as u32));
        }
        let mut enc = encoder(ctx, "crsh tile hash");
        {
            let mut pass = ctx.compute_pass(&mut enc, "crsh tile hash");
            for (bg, n) in &groups {
                k.kernel.dispatch(ctx, &mut pass, "hash", bg, *n)?;
            }
        }
        submit(ctx, "crsh tile hash", enc)?;
        Ok(keys)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_groups_and_key_bits() {
        let g = TileGrid::new(FrameSize::new(100, 37).unwrap(), 16).unwrap();
        assert_eq!((g.tiles_x, g.tiles), (7, 21));
        // Pixel (99, 36): tile (6, 2).
        assert_eq!(
            g.group(36 * 100 + 99, 0, RayKind::Reflection as u32),
            Some(20)
        );
        assert_eq!(g.group(36 * 100 + 99, 2, RayKind::Shadow as u32), Some(62));
        assert_eq!(g.group(37 * 100, 0, RayKind::Reflection as u32), None);
        assert_eq!(g.key_bits(0), 5); // 20 = 0b10100
        assert_eq!(g.key_bits(3), 6); // 62
        let one = TileGrid::new(FrameSize::new(1, 1).unwrap(), 16).unwrap();
        assert_eq!(one.key_bits(1), 1);
        assert!(TileGrid::new(FrameSize::new(1, 1).unwrap(), 0).is_err());
        assert!(TileGrid::new(FrameSize::new(1, 1).unwrap(), MAX_TILE_SIZE + 1).is_err());
    }
}
