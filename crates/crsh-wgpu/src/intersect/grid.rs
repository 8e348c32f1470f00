//! `grid` on the wgpu backend: the uniform grid of seed 002 (Ivson, Duarte and Celes 2009),
//! built on the device by the five passes of §3.1/§3.2 and traversed with the 3D-DDA of
//! Amanatides and Woo 1987 (§4), the twin of [`crsh_cpu::intersect::grid`].
//!
//! - Resolution (eq. 1), margin and cell planes are the CPU twin's
//!   ([`GridGeometry::new`]), computed on the host; which triangles are binned (not
//!   degenerate for Möller-Trumbore) too ([`hittable`]).
//! - Pass 1 (`count` in `grid_build.wgsl`): per triangle, its widened box's cells, from the
//!   scene's vertices on the device. Pass 2: the project's GPU scan
//!   ([`crate::kernels::scan::exclusive_scan`]), total appended. Pass 3 (`write_pairs`, or
//!   `write_pairs_listed` on explicit overlap lists such as fig. 5): one invocation per output
//!   slot, binary search in the scan. Pass 4: the project's GPU
//!   [`crate::sort::radix::stable_radix_order`] on u64 keys (the cell id), then a gather.
//!   Pass 5 (`ranges`): one invocation per cell, binary searches. Every pass's output equals
//!   the CPU twin's ([`BuildPasses`]), which the tests check.
//! - Traversal (`grid.wgsl`): one ray per invocation, the CPU's DDA operation for operation
//!   (distances `(plane − o)·(1/d)`, entry cell by binary search, the same slack), with
//!   Möller-Trumbore (`kernels/mt.wgsl`); closest and any hit; cells visited are counted as
//!   bounds tests and triangle tests as ray-triangle tests, as on the CPU. Hits equal brute
//!   force's; counts equal the CPU twin's wherever WGSL's division rounds like the host's
//!   (lavapipe does). Whole-scene queries only; only `test = "mt"` has a WGSL twin.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{
    CoreError, Hit, HitMode, Intersector, Query, Ray, Registry, Result, StageSpec, Stats,
};
use crsh_cpu::intersect::grid::{hittable, BuildPasses, GridGeometry, ListedCells};
use crsh_cpu::triangle::{MollerTrumbore, PreparedTriangle, TestKind, TriangleSet};

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{dispatch_chunks, encoder, submit, uniform, Kernel, Slot};
use crate::scene::GpuScene;

const BUILD_SHADER: &str = include_str!("grid_build.wgsl");
const SHADER: &str = include_str!("grid.wgsl");

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct BuildParams {
    n: u32,
    total: u32,
    n_cells: u32,
    margin: f32,
    dims: [u32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n: u32,
    any_hit: u32,
    first: u32,
    n_tris: u32,
    dims: [u32; 4],
    lo: [f32; 4],
    hi: [f32; 4],
    margin: f32,
    pad: [f32; 3],
}

struct GridKernels {
    build: Kernel,
    traverse: Kernel,
}

impl GridKernels {
    fn new(ctx: &GpuContext) -> GpuResult<GridKernels> {
        let mut slots = vec![Slot::Uniform];
        slots.extend([Slot::Read; 5]);
        slots.extend([Slot::ReadWrite; 3]);
        let build = Kernel::new(
            ctx,
            "crsh grid build",
            BUILD_SHADER,
            &[
                "count",
                "write_pairs",
                "write_pairs_listed",
                "gather",
                "ranges",
            ],
            &slots,
        )?;
        let source = format!("{}\n{SHADER}", super::MT_WGSL);
        let mut slots = vec![Slot::Uniform];
        slots.extend([Slot::Read; 5]);
        slots.extend([Slot::ReadWrite; 2]);
        let traverse = Kernel::new(ctx, "crsh grid", &source, &["traverse"], &slots)?;
        Ok(GridKernels { build, traverse })
    }
}

/// The grid on the device: cell planes, `(start, count)` per cell, triangle lists.
pub struct DeviceGrid {
    /// Box, resolution, planes (host copy).
    pub geometry: GridGeometry,
    planes: GpuBuffer<f32>,
    ranges: GpuBuffer<[u32; 2]>,
    cell_tris: GpuBuffer<u32>,
    pairs: u32,
}

/// What a build needs besides the kernels: where pass 1's boxes or pass 3's cells come from.
enum Source<'a> {
    /// The scene's triangles (pass 1 on the device).
    Scene(&'a GpuScene, &'a [bool]),
    /// Explicit per-primitive cell lists (passes 2-5 only).
    Listed(&'a ListedCells),
}

fn one<T: Pod>(ctx: &GpuContext, label: &str, data: &[T]) -> GpuResult<GpuBuffer<T>> {
    if data.is_empty() {
        GpuBuffer::zeroed(ctx, label, 1)
    } else {
        GpuBuffer::from_slice(ctx, label, data)
    }
}

/// Runs the five passes; returns the grid and, when `readback`, every pass's output.
fn build(
    ctx: &GpuContext,
    geometry: &GridGeometry,
    source: Source<'_>,
    readback: bool,
) -> Result<(DeviceGrid, Option<BuildPasses>)> {
    let k = ctx.kernel(GridKernels::new)?;
    let n_cells = geometry.cell_count();
    let flat_planes: Vec<f32> = geometry.planes.iter().flatten().copied().collect();
    let planes = one(ctx, "crsh grid planes", &flat_planes)?;
    let d = geometry.dims;
    let n = match &source {
        Source::Scene(s, _) => s.scene.triangle_count(),
        Source::Listed(l) => l.0.len(),
    };
    let params = |total: u32| BuildParams {
        n: n as u32,
        total,
        n_cells: n_cells as u32,
        margin: geometry.margin,
        dims: [d[0], d[1], d[2], 0],
    };
    let dummy = GpuBuffer::<u32>::zeroed(ctx, "crsh grid dummy", 1)?;
    let dummy_w = GpuBuffer::<u32>::zeroed(ctx, "crsh grid dummy out", 1)?;
    let dummy_w2 = GpuBuffer::<u32>::zeroed(ctx, "crsh grid dummy out 2", 1)?;
    let dummy_f = GpuBuffer::<f32>::zeroed(ctx, "crsh grid dummy f32", 1)?;
    let dispatch = |entry: &str,
                    u: &wgpu::Buffer,
                    res: [wgpu::BindingResource<'_>; 8],
                    count: u32|
     -> Result<()> {
        let mut all = vec![u.as_entire_binding()];
        all.extend(res);
        let bg = k.build.bind_group(ctx, &all);
        let mut enc = encoder(ctx, "crsh grid build");
        {
            let mut pass = ctx.compute_pass(&mut enc, entry);
            k.build.dispatch(ctx, &mut pass, entry, &bg, count)?;
        }
        submit(ctx, "crsh grid build", enc)?;
        Ok(())
    };
    // Pass 1.
    ctx.check_storage_binding("grid cell boxes", 24 * n.max(1) as u64)?;
    let mut counts = GpuBuffer::<u32>::zeroed(ctx, "crsh grid counts", n.max(1))?;
    let boxes = GpuBuffer::<u32>::zeroed(ctx, "crsh grid boxes", 6 * n.max(1))?;
    let listed_flat: Vec<u32>;
    let listed_buf;
    match &source {
        Source::Scene(scene, keep) => {
            let flags: Vec<u32> = keep.iter().map(|&h| u32::from(h)).collect();
            let flags = one(ctx, "crsh grid hittable", &flags)?;
            let u = uniform(ctx, "crsh grid params", &params(0));
            dispatch(
                "count",
                &u,
                [
                    scene.triangles.binding(),
                    flags.binding(),
                    planes.binding(),
                    dummy.binding(),
                    dummy.binding(),
                    counts.binding(),
                    boxes.binding(),
                    dummy_w.binding(),
                ],
                n as u32,
            )?;
            listed_buf = None;
        }
        Source::Listed(l) => {
            let c: Vec<u32> = l.0.iter().map(|v| v.len() as u32).collect();
            counts = one(ctx, "crsh grid counts", &c)?;
            listed_flat = l.0.iter().flatten().copied().collect();
            listed_buf = Some(one(ctx, "crsh grid listed cells", &listed_flat)?);
        }
    }
    let counts_host = if readback {
        Some(counts.to_vec(ctx)?[..n].to_vec())
    } else {
        None
    };
    // Pass 2: the GPU scan, total appended.
    let (scan_part, total) = if n == 0 {
        (GpuBuffer::<u32>::zeroed(ctx, "crsh grid scan", 1)?, 0)
    } else {
        crate::kernels::scan::exclusive_scan(ctx, &counts)?
    };
    let scan_vec_dev = {
        let mut v = scan_part.to_vec(ctx)?;
        v.truncate(n);
        v
    };
    // The total must fit u32 (the CPU's check, on the summed counts).
    let sum: u64 = match &counts_host {
        Some(c) => c.iter().map(|&x| x as u64).sum(),
        None => counts.to_vec(ctx)?[..n].iter().map(|&x| x as u64).sum(),
    };
    if sum > u32::MAX as u64 {
        return Err(CoreError::InvalidInput(format!(
            "the grid would hold {sum} (cell, primitive) pairs, more than 32-bit indices address"
        )));
    }
    let mut scan_vec = scan_vec_dev;
    scan_vec.push(total);
    let scan = GpuBuffer::from_slice(ctx, "crsh grid scan", &scan_vec)?;
    // Pass 3.
    ctx.check_storage_binding("grid pair keys", 8 * total.max(1) as u64)?;
    let keys = GpuBuffer::<u64>::zeroed(ctx, "crsh grid keys", total.max(1) as usize)?;
    let prims = GpuBuffer::<u32>::zeroed(ctx, "crsh grid pair prims", total.max(1) as usize)?;
    let u = uniform(ctx, "crsh grid params", &params(total));
    let (entry, cells_in) = match &listed_buf {
        Some(b) => ("write_pairs_listed", b.binding()),
        None => ("write_pairs", boxes.binding()),
    };
    dispatch(
        entry,
        &u,
        [
            dummy_f.binding(),
            dummy.binding(),
            planes.binding(),
            scan.binding(),
            cells_in,
            keys.binding(),
            prims.binding(),
            dummy_w.binding(),
        ],
        total,
    )?;
    // Pass 4: the GPU radix order on u64 keys, then a gather.
    let (pair_cells, pair_prims) = if readback {
        let kv = keys.to_vec(ctx)?;
        let pv = prims.to_vec(ctx)?;
        (
            kv[..total as usize].iter().map(|&k| k as u32).collect(),
            pv[..total as usize].to_vec(),
        )
    } else {
        (Vec::new(), Vec::new())
    };
    let sorted_cells =
        GpuBuffer::<u32>::zeroed(ctx, "crsh grid sorted cells", total.max(1) as usize)?;
    let cell_tris = GpuBuffer::<u32>::zeroed(ctx, "crsh grid cell tris", total.max(1) as usize)?;
    if total > 0 {
        let order = crate::sort::radix::stable_radix_order(ctx, &keys, geometry.key_bits())?;
        dispatch(
            "gather",
            &u,
            [
                dummy_f.binding(),
                dummy.binding(),
                planes.binding(),
                order.binding(),
                prims.binding(),
                keys.binding(),
                sorted_cells.binding(),
                cell_tris.binding(),
            ],
            total,
        )?;
    }
    // Pass 5.
    ctx.check_storage_binding("grid cell ranges", 8 * n_cells as u64)?;
    let ranges = GpuBuffer::<[u32; 2]>::zeroed(ctx, "crsh grid ranges", n_cells.max(1))?;
    dispatch(
        "ranges",
        &u,
        [
            dummy_f.binding(),
            dummy.binding(),
            planes.binding(),
            dummy.binding(),
            sorted_cells.binding(),
            ranges.binding(),
            dummy_w.binding(),
            dummy_w2.binding(),
        ],
        n_cells as u32,
    )?;
    let passes = if readback {
        let t = total as usize;
        Some(BuildPasses {
            counts: counts_host.unwrap_or_default(),
            scan: scan_vec,
            pair_cells,
            pair_prims,
            sorted_cells: sorted_cells.to_vec(ctx)?[..t].to_vec(),
            sorted_prims: cell_tris.to_vec(ctx)?[..t].to_vec(),
            ranges: ranges.to_vec(ctx)?[..n_cells].to_vec(),
        })
    } else {
        None
    };
    Ok((
        DeviceGrid {
            geometry: geometry.clone(),
            planes,
            ranges,
            cell_tris,
            pairs: total,
        },
        passes,
    ))
}

/// Passes 2-5 on the device for explicit per-primitive cell lists (seed 002 fig. 5), in a
/// grid of `geometry`'s cells; returns every pass's output.
pub fn device_passes_listed(
    ctx: &GpuContext,
    geometry: &GridGeometry,
    cells: &ListedCells,
) -> Result<BuildPasses> {
    build(ctx, geometry, Source::Listed(cells), true)?
        .1
        .ok_or_else(|| CoreError::Backend("grid passes not read back".into()))
}

/// The five passes on the device for `scene` at density `k` (Möller-Trumbore's binning);
/// returns the grid and every pass's output.
pub fn device_passes(scene: &Arc<GpuScene>, k: f64) -> Result<(DeviceGrid, BuildPasses)> {
    let keep = hittable(&scene.scene, TestKind::MollerTrumbore);
    let binned = keep.iter().filter(|&&h| h).count();
    let geometry = GridGeometry::new(&scene.scene.bounds, binned, k);
    let (g, p) = build(scene.ctx(), &geometry, Source::Scene(scene, &keep), true)?;
    Ok((
        g,
        p.ok_or_else(|| CoreError::Backend("grid passes not read back".into()))?,
    ))
}

/// The GPU uniform-grid intersector (variant `grid`, parameters `grid_density`, `test` = `mt`).
pub struct UniformGrid {
    scene: Arc<GpuScene>,
    grid: DeviceGrid,
    tris: GpuBuffer<PreparedTriangle>,
}

/// Registers the wgpu `grid` under its CPU twin's catalogue entry (`test` offers `mt` only).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_intersector(
        crate::registry::mt_only(crsh_cpu::intersect::grid::info()),
        |ctx, spec| Ok(Box::new(UniformGrid::new(ctx.scene, spec)?)),
    )?;
    Ok(())
}

impl UniformGrid {
    /// Builds the grid of `scene` on the device with `spec.grid_density` (`spec.test` must be
    /// `mt`).
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<UniformGrid> {
        super::require_mt(spec, "grid")?;
        let k = spec.f64("grid_density")?;
        use crsh_cpu::intersect::grid::{MAX_DENSITY, MIN_DENSITY};
        if !(MIN_DENSITY..=MAX_DENSITY).contains(&k) {
            return Err(CoreError::InvalidParam {
                key: "grid.grid_density".into(),
                reason: format!("{k} is outside {MIN_DENSITY}..={MAX_DENSITY}"),
            });
        }
        UniformGrid::build(scene, k)
    }

    /// Builds the grid of `scene` on the device at density `k`.
    pub fn build(scene: &Arc<GpuScene>, k: f64) -> Result<UniformGrid> {
        let keep = hittable(&scene.scene, TestKind::MollerTrumbore);
        let binned = keep.iter().filter(|&&h| h).count();
        let geometry = GridGeometry::new(&scene.scene.bounds, binned, k);
        let ctx = scene.ctx();
        let (grid, _) = build(ctx, &geometry, Source::Scene(scene, &keep), false)?;
        let set = TriangleSet::<MollerTrumbore>::new(&scene.scene);
        Ok(UniformGrid {
            scene: Arc::clone(scene),
            grid,
            tris: one(ctx, "crsh grid triangles", set.triangles())?,
        })
    }

    /// The grid on the device.
    pub fn grid(&self) -> &DeviceGrid {
        &self.grid
    }
}

impl Intersector<Wgpu> for UniformGrid {
    fn name(&self) -> &str {
        "grid"
    }

    fn supports_candidates(&self) -> bool {
        false
    }

    fn intersect(
        &self,
        backend: &Wgpu,
        rays: &GpuBuffer<Ray>,
        query: Query<'_, Wgpu>,
        mode: HitMode,
        hits: &mut GpuBuffer<Hit>,
        stats: &mut Stats,
    ) -> Result<()> {
        if mode.is_edge_width() {
            return Err(mode.unsupported("grid (wgpu)"));
        }
        query.whole_scene_only("grid")?;
        crsh_core::ray::check_hits_per_ray("rays", rays.len(), hits.len())?;
        if rays.is_empty() {
            return Ok(());
        }
        let ctx = backend.context();
        let k = ctx.kernel(GridKernels::new)?;
        let counters = GpuBuffer::<u32>::zeroed(ctx, "crsh grid counters", 5)?;
        let g = &self.grid.geometry;
        dispatch_chunks::<Ray>(
            ctx,
            &k.traverse,
            "crsh grid",
            "traverse",
            rays.len(),
            |range| {
                let params = Params {
                    n: range.len() as u32,
                    any_hit: u32::from(mode == HitMode::Any),
                    first: range.start as u32,
                    n_tris: self.grid.pairs,
                    dims: [g.dims[0], g.dims[1], g.dims[2], 0],
                    lo: g.bounds.min.extend(0.0).to_array(),
                    hi: g.bounds.max.extend(0.0).to_array(),
                    margin: g.margin,
                    pad: [0.0; 3],
                };
                let u = uniform(ctx, "crsh grid params", &params);
                k.traverse.bind_group(
                    ctx,
                    &[
                        u.as_entire_binding(),
                        rays.slice_binding(range.clone()),
                        self.grid.planes.binding(),
                        self.grid.ranges.binding(),
                        self.grid.cell_tris.binding(),
                        self.tris.binding(),
                        hits.slice_binding(range.clone()),
                        counters.binding(),
                    ],
                )
            },
        )?;
        let c = counters.to_vec(ctx)?;
        super::brute::check_invalid(c[4])?;
        stats.add_bounds(u64::from(c[0]) | (u64::from(c[1]) << 32));
        stats.add_ray_triangle(u64::from(c[2]) | (u64::from(c[3]) << 32));
        let _ = &self.scene;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{hits_agree, rounding_explains};
    use crsh_core::glam::Vec3;
    use crsh_core::{Aabb, Backend, RayKind};
    use crsh_cpu::intersect::grid::{GridData, UniformGrid as CpuGrid};
    use crsh_cpu::Cpu;

    /// A small deterministic generator (xorshift64*).
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
        }
        fn f(&mut self) -> f32 {
            (self.next() >> 40) as f32 / (1u64 << 24) as f32
        }
        fn v(&mut self, lo: f32, hi: f32) -> Vec3 {
            Vec3::new(
                lo + (hi - lo) * self.f(),
                lo + (hi - lo) * self.f(),
                lo + (hi - lo) * self.f(),
            )
        }
    }

    fn rays(scene: &crsh_scene::Scene, seed: u64, n: usize) -> Vec<Ray> {
        let mut rng = Rng(seed);
        let c = scene.bounds.center();
        let r = scene.bounds.diagonal();
        (0..n)
            .map(|i| {
                let tri = scene.triangle(rng.next() as usize % scene.triangle_count());
                let on = (tri[0] + tri[1] + tri[2]) / 3.0;
                let o = if i % 2 == 0 {
                    on
                } else {
                    c + rng.v(-0.6, 0.6) * r
                };
                let dir = if i % 2 == 0 {
                    rng.v(-1.0, 1.0).normalize_or(Vec3::Y)
                } else {
                    (on - o).normalize_or(Vec3::X)
                };
                Ray {
                    origin: o,
                    t_min: if i % 2 == 0 { r * 1e-5 } else { 0.0 },
                    dir,
                    t_max: if i % 3 == 0 { r * 0.3 } else { f32::INFINITY },
                    throughput: Vec3::ONE,
                    kind: RayKind::Reflection as u32,
                    pixel: i as u32,
                    light: u32::MAX,
                    depth: 1,
                    source: i as u32,
                }
            })
            .collect()
    }

    /// Seed 002 fig. 5 on the device: passes 2-5 fed the explicit overlap lists.
    #[test]
    fn fig5_on_the_device() {
        let Some(b) = crate::testing::shared_backend("grid fig5_on_the_device") else {
            return;
        };
        // The 3×3 grid of fig. 5 (one cell deep).
        let geometry = GridGeometry {
            dims: [3, 3, 1],
            bounds: Aabb {
                min: Vec3::ZERO,
                max: Vec3::new(3.0, 3.0, 1.0),
            },
            cell_size: Vec3::ONE,
            margin: 0.0,
            planes: [
                vec![0.0, 1.0, 2.0, 3.0],
                vec![0.0, 1.0, 2.0, 3.0],
                vec![0.0, 1.0],
            ],
        };
        assert_eq!(geometry.cell_count(), 9);
        let cells = ListedCells(vec![vec![3, 4, 6], vec![0, 3], vec![3, 4, 5, 7], vec![1]]);
        let got = device_passes_listed(b.context(), &geometry, &cells).unwrap();
        assert_eq!(got.counts, [3, 2, 4, 1]);
        assert_eq!(got.scan, [0, 3, 5, 9, 10]);
        assert_eq!(got.pair_cells, [3, 4, 6, 0, 3, 3, 4, 5, 7, 1]);
        assert_eq!(got.pair_prims, [0, 0, 0, 1, 1, 2, 2, 2, 2, 3]);
        assert_eq!(got.sorted_cells, [0, 1, 3, 3, 3, 4, 4, 5, 6, 7]);
        assert_eq!(got.sorted_prims, [1, 3, 0, 1, 2, 0, 2, 2, 0, 2]);
        assert_eq!(
            got.ranges,
            [
                [0, 1],
                [1, 1],
                [0, 0],
                [2, 3],
                [5, 2],
                [7, 1],
                [8, 1],
                [9, 1],
                [0, 0]
            ]
        );
    }

    /// Every pass on random triangles equals the CPU twin's.
    #[test]
    fn passes_match_the_cpu_on_random_triangles() {
        let Some(b) = crate::testing::shared_backend("grid passes_match_the_cpu") else {
            return;
        };
        let mut rng = Rng(7);
        let mut builder = crsh_scene::SceneBuilder::new("random");
        let m = builder.material(crsh_scene::Material::default());
        builder.camera(crsh_scene::Camera {
            eye: Vec3::new(0.0, 0.0, 10.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            vfov_deg: 45.0,
            aspect: None,
        });
        let mut positions = Vec::new();
        let mut indices = Vec::new();
        for i in 0..5000u32 {
            let a = rng.v(-4.0, 4.0);
            let s = if i % 50 == 0 { 3.0 } else { 0.3 };
            positions.extend([a, a + rng.v(-s, s), a + rng.v(-s, s)]);
            indices.push([3 * i, 3 * i + 1, 3 * i + 2]);
        }
        indices.push([0, 0, 1]);
        builder.mesh("all", &positions, None, &indices, m);
        let scene = Arc::new(builder.build("random").unwrap());
        let g = GpuScene::new(&b, &scene).unwrap();
        for k in [0.5, 5.0] {
            let (_, want) = GridData::build_passes(&scene, k, TestKind::MollerTrumbore).unwrap();
            let (_, got) = device_passes(&g, k).unwrap();
            assert_eq!(got.counts, want.counts, "k {k} pass 1");
            assert_eq!(got.scan, want.scan, "k {k} pass 2");
            assert_eq!(got.pair_cells, want.pair_cells, "k {k} pass 3");
            assert_eq!(got.pair_prims, want.pair_prims, "k {k} pass 3");
            assert_eq!(got.sorted_cells, want.sorted_cells, "k {k} pass 4");
            assert_eq!(got.sorted_prims, want.sorted_prims, "k {k} pass 4");
            assert_eq!(got.ranges, want.ranges, "k {k} pass 5");
        }
    }

    /// Hits equal the CPU `grid`'s and brute force's on the built-in scenes up to rounding
    /// ([`hits_agree`], [`rounding_explains`]), and the counters the CPU grid's.
    #[test]
    fn hits_and_counters_match_the_cpu() {
        let Some(b) = crate::testing::shared_backend("grid hits_and_counters_match_the_cpu") else {
            return;
        };
        for name in crsh_scene::builtin::NAMES {
            let scene = Arc::new(crsh_scene::builtin::build(name).unwrap());
            let g = GpuScene::new(&b, &scene).unwrap();
            let rays = rays(&scene, 11, 3000);
            let gpu = UniformGrid::build(&g, 5.0).unwrap();
            let cpu = CpuGrid::build(&scene, 5.0, TestKind::MollerTrumbore).unwrap();
            let brute = crate::testing::cpu_intersector(&StageSpec::new("brute"), &scene);
            for mode in [HitMode::Closest, HitMode::Any] {
                let mut want = vec![Hit::MISS; rays.len()];
                let mut cpu_stats = Stats::default();
                cpu.intersect(&Cpu, &rays, Query::Scene, mode, &mut want, &mut cpu_stats)
                    .unwrap();
                let mut reference = vec![Hit::MISS; rays.len()];
                brute
                    .intersect(
                        &Cpu,
                        &rays,
                        Query::Scene,
                        mode,
                        &mut reference,
                        &mut Stats::default(),
                    )
                    .unwrap();
                let buf = b.upload(&rays).unwrap();
                let mut hits = b.upload(&vec![Hit::MISS; rays.len()]).unwrap();
                let mut stats = Stats::default();
                gpu.intersect(&b, &buf, Query::Scene, mode, &mut hits, &mut stats)
                    .unwrap();
                let got = b.download(&hits).unwrap();
                // The same hits up to the rounding WGSL allows, and a different one only where
                // rounding decides (an edge, a tie, a grazing ray); the counters where every
                // hit agrees.
                let mut differ = 0;
                for (i, ((g, w), r)) in got.iter().zip(&want).zip(&reference).enumerate() {
                    for (other, what) in [(w, "cpu grid"), (r, "brute")] {
                        if !hits_agree(mode, g, other) {
                            differ += 1;
                            assert!(
                                rounding_explains(&scene, &rays[i], g, other),
                                "{name} {mode:?} ray {i}: gpu {g:?} vs {what} {other:?}"
                            );
                        }
                    }
                }
                // Of the 2 × 3000 comparisons, lavapipe: none differ; an NVIDIA H200
                // (2026-12-04), which fuses `a·b + c`: 16 on office-boxes, every one explained.
                assert!(
                    differ * 50 <= rays.len(),
                    "{name} {mode:?}: {differ} differ"
                );
                assert!(want.iter().filter(|h| h.is_hit()).count() > rays.len() / 4);
                if differ == 0 {
                    assert_eq!(stats.tests, cpu_stats.tests, "{name} {mode:?}: counters");
                }
            }
        }
    }
}
