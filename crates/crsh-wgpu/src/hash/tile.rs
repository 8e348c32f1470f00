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
//! contract. With `order = morton` the tiles are numbered in Z-order and shadow groups are
//! `light·span + tile` ([`TileGrid::span`]; see [`crsh_cpu::hash::tile`]).
//!
//! The twin is [`crsh_cpu::hash::tile::TileHasher`]: this variant registers under its
//! catalogue entry ([`crsh_cpu::hash::tile::info`]), reads its parameters through it and takes
//! the grid ([`TileGrid`]) and the key width from it, so the two cannot drift apart. The keys
//! are integers, so both backends give the same keys bit for bit. A ray the CPU refuses (its
//! pixel outside the frame, or a shadow ray naming a light the scene lacks) is an error there;
//! the kernel cannot fail, so it writes the all-ones key of `key_bits` for such a ray (the
//! generators never make one).
//!
//! The tile grid is also what the `tile_cone` builder groups by
//! ([`crate::hierarchy::tile_cone`]); both use `tile_group.wgsl`.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{CoreError, FrameSize, Hasher, Ray, RayKind, Registry, Result, StageSpec, Stats};
use crsh_cpu::hash::tile::{TileGrid, TileHasher as CpuTile, TileOrder};

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{Kernel, Slot};
use crate::scene::GpuScene;

const SHADER: &str = include_str!("tile.wgsl");

/// `tile_group.wgsl` with the constant it needs (generated from [`RayKind::Shadow`]): the
/// group of a ray, shared by the `tile` hash and the `tile_cone` builder.
pub(crate) fn tile_group_wgsl() -> String {
    format!(
        "const RAY_KIND_SHADOW: u32 = {}u;\n{}",
        RayKind::Shadow as u32,
        include_str!("tile_group.wgsl")
    )
}

/// The grid's tile counts as the kernels' `u32` (`tiles_x`, and [`TileGrid::span`], which is
/// the tile count in rows).
///
/// # Errors
/// [`CoreError::InvalidInput`] when the tile numbers do not fit `u32`.
pub(crate) fn grid_u32(grid: &TileGrid) -> Result<(u32, u32)> {
    let span = u32::try_from(grid.span()).map_err(|_| {
        CoreError::InvalidInput(format!(
            "{} tile numbers of {} pixels over the {} frame exceed u32",
            grid.span(),
            grid.tile_size(),
            grid.frame()
        ))
    })?;
    Ok((grid.tiles_x(), span))
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n: u32,
    width: u32,
    height: u32,
    tile_size: u32,
    tiles_x: u32,
    span: u32,
    lights: u32,
    none_lo: u32,
    none_hi: u32,
    morton: u32,
    pad: [u32; 2],
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
    lights: usize,
    key_bits: u32,
}

/// Registers the wgpu `tile` under the CPU twin's entry ([`crsh_cpu::hash::tile::info`]),
/// [`Tile::new`] with the stage context's frame.
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_hasher(crsh_cpu::hash::tile::info(), |ctx, spec| {
        Ok(Box::new(Tile::new(ctx.scene, ctx.frame, spec)?))
    })?;
    Ok(())
}

impl Tile {
    /// The hasher for `scene` (its light count sizes the keys) rendering `frame`, with a
    /// resolved `spec` (`tile_size`), read by the CPU twin.
    ///
    /// # Errors
    /// [`CoreError::InvalidParam`] for a `tile_size` out of range.
    pub fn new(scene: &Arc<GpuScene>, frame: FrameSize, spec: &StageSpec) -> Result<Tile> {
        let lights = scene.scene.lights.len();
        Tile::with_grid(*CpuTile::new(frame, lights, spec)?.grid(), lights)
    }

    /// The hasher over `grid` with keys sized for `lights` lights (the CPU twin's
    /// [`TileGrid::key_bits`]).
    ///
    /// # Errors
    /// [`CoreError::InvalidInput`] for a frame of more than `u32::MAX` tiles.
    pub fn with_grid(grid: TileGrid, lights: usize) -> Result<Tile> {
        grid_u32(&grid)?;
        Ok(Tile {
            grid,
            lights,
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
        if rays.is_empty() {
            return Ok(GpuBuffer::zeroed(ctx, "crsh ray keys", 0)?);
        }
        let k = ctx.kernel(TileKernels::new)?;
        let none = if self.key_bits >= 64 {
            u64::MAX
        } else {
            (1u64 << self.key_bits) - 1
        };
        let g = self.grid;
        let (tiles_x, span) = grid_u32(&g)?;
        super::per_ray_keys(ctx, &k.kernel, "crsh tile hash", rays, |range| Params {
            n: range.len() as u32,
            width: g.frame().width,
            height: g.frame().height,
            tile_size: g.tile_size(),
            tiles_x,
            span,
            lights: u32::try_from(self.lights).unwrap_or(u32::MAX),
            none_lo: none as u32,
            none_hi: (none >> 32) as u32,
            morton: u32::from(g.order() == TileOrder::Morton),
            pad: [0; 2],
        })
    }
}
