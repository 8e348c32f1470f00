//! `tile_cone` on the wgpu backend: seed 004's enclosing cones of screen tiles (Szécsi, "The
//! Hierarchical Ray Engine", WSCG 2006, §4 "Construction of an enclosing cone"), one level of
//! apex cones over variable-size nodes.
//!
//! # What it builds
//!
//! The nodes are the maximal runs of consecutive positions `i` of the given order whose rays
//! have the same group: the screen tile of [`Ray::pixel`] for the builder's own `tile_size`,
//! and for shadow rays `light·tiles + tile` (the `tile` hasher's key, [`TileGrid::group`]).
//! After the `tile` hasher and a stable sort with the same tile size every node is one whole
//! (compacted) tile; in generation order the runs are pieces of tiles (correct, less coherent).
//! The [`RayHierarchy`] has the given `order`, one level (`levels = [nodes]`),
//! `leaf_offsets = Some(offsets)` (`offsets[k]` the first position of node `k`, the last entry
//! the ray count), the nominal `subdivision = tile_size²` (no level above uses it) and one
//! reach per node. A node is `SphereCone { sphere: (apex, 0), cone: (axis, half_angle) }`:
//! every point `o + t·d`, `t ≥ 0`, of every ray of the node lies in the cone of that apex, axis
//! and half-angle (the containment that [`RayHierarchy::levels`] asks for), or the half-angle
//! is π and the node passes every test.
//!
//! Per node, in `f32` (one invocation per node, the rays in order), the construction is the
//! CPU twin's [`crsh_cpu::hierarchy::tile_cone::node_cone`] operation for operation: start with
//! the zero-angle cone of the first ray (`a = o₀`, `x = d₀/|d₀|`), then for each further ray
//! (a) extend the cone's solid angle to hold its direction (§4, fig. 2: `q` towards the axis,
//! the far generator `e = x cos φ + q sin φ`, the new axis `(e + r)/|e + r|`,
//! `cos φ = x·r`) and (b) translate the cone along its far generator until the near generator
//! `n = x cos φ − q sin φ` holds the origin (§4, fig. 3: `g = c − n(n·c)`, `t = g²/(e·g)`). A
//! final pass measures the half-angle that is stored against the stored apex and axis, and
//! computes the reach. The errata and choices (the apex sign `a + e·t`, a node flagged full
//! as soon as `x·r ≤ −cos φ` or `|e + r| ≤` [`EXTEND_EPS`] or `cos φ ≤ 0`, the widening to
//! `min_half_angle_deg` before a translation, an origin in the backward cone becoming the
//! apex, the fixed perpendicular below `|w| ≤` [`PERP_EPS`]`·|v|`, the guard
//! `φ·`[`GUARD_SCALE`]` + `[`GUARD_ADD`], π for a full node or `φ ≥ π/2`) are documented
//! there, in the CPU module; the WGSL constants are generated from the CPU's, and the minimum
//! angle's sine and cosine are [`TileConeParams::sin_cos_min`]'s.
//!
//! The reach of a node is the largest distance from the apex to a ray's origin or to its end
//! `o + d·t_max` (infinite for an unbounded ray), rounded up by the guard of the sphere-cone
//! builder's reach (`kernels/reach.wgsl`, shared with [`super::sphere_cone`]).
//!
//! # On the device
//!
//! Three passes and the exclusive scan ([`crate::kernels::scan`]): `run_flags` (one invocation
//! per position: 1 where the group differs from the previous position's), the in-place scan
//! of those flags (run starts become node indices; its total, the node count, is read back to
//! size the level), `run_offsets` (each run start writes its position into the offsets) and
//! `cones` (one invocation per node, the construction above). The groups come from
//! `hash/tile_group.wgsl`, the tile hasher's own function.
//!
//! The twin is [`crsh_cpu::hierarchy::tile_cone`]: this variant registers under its catalogue
//! entry ([`crsh_cpu::hierarchy::tile_cone::info`]), reads its parameters through it
//! ([`TileConeParams`]) and groups by its grid ([`TileGrid`], whose WGSL twin
//! `hash/tile_group.wgsl` the `tile` hasher shares). Same operations in the same order
//! (`normalize` as a division per component, `dot` as `(x·x + y·y) + z·z`), so the offsets
//! are equal and the nodes agree up to WGSL's rounding of `sqrt` and division (lavapipe's are
//! correctly rounded), the contraction of multiply-adds a driver may do, and the angles of
//! `kernels/trig.wgsl`'s `atan2` (a few 1e-8 rad from the CPU's); `tests/tile_cone.rs`
//! compares them. The reach is guarded in `f32` on the device (`+1e-6·max(1, |coordinates|)`,
//! `+1e-5` relative), a little wider than the CPU's bound computed in `f64`.
//!
//! # Errors
//!
//! [`CoreError::InvalidInput`] when the order's length is not the ray count, an order entry is
//! out of range, a ray's pixel is outside the frame, or a ray is not valid (non-finite origin
//! or direction, zero direction, NaN interval): the first bad position is named.

use bytemuck::{Pod, Zeroable};
use crsh_core::{
    CoreError, FrameSize, HierarchyBuilder, Ray, RayHierarchy, Registry, Result, SphereCone,
    StageSpec, Stats,
};
use crsh_cpu::hash::tile::TileGrid;
use crsh_cpu::hierarchy::tile_cone::{
    TileConeBuilder as CpuTileCone, TileConeParams, EXTEND_EPS, GUARD_ADD, GUARD_SCALE, PERP_EPS,
    PERP_SWITCH,
};

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::hash::tile::{grid_u32, tile_group_wgsl};
use crate::kernel::{encoder, submit, uniform, Kernel, Slot};
use crate::kernels::{compose, f32_const, GLAM_WGSL, REACH_WGSL, TRIG_WGSL};

const SHADER: &str = include_str!("tile_cone.wgsl");

/// The WGSL constants of `tile_cone.wgsl`, generated from the CPU twin's
/// (`crsh_cpu::hierarchy::tile_cone`: [`EXTEND_EPS`], [`PERP_EPS`], [`PERP_SWITCH`],
/// [`GUARD_SCALE`], [`GUARD_ADD`]) and `π`, `π/2` as `f32`, so the two cannot drift apart.
fn constants_wgsl() -> String {
    let mut s = String::from("// Generated from crsh_cpu::hierarchy::tile_cone.\n");
    s += &f32_const("PI", std::f32::consts::PI);
    s += &f32_const("FRAC_PI_2", std::f32::consts::FRAC_PI_2);
    s += &f32_const("EXTEND_EPS", EXTEND_EPS);
    s += &f32_const("PERP_EPS", PERP_EPS);
    s += &f32_const("PERP_SWITCH", PERP_SWITCH);
    s += &f32_const("GUARD_SCALE", GUARD_SCALE);
    s += &f32_const("GUARD_ADD", GUARD_ADD);
    s
}

/// Registers the wgpu `tile_cone` under the CPU twin's entry
/// ([`crsh_cpu::hierarchy::tile_cone::info`]), [`TileConeBuilder::new`] with the stage
/// context's frame.
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_hierarchy(crsh_cpu::hierarchy::tile_cone::info(), |ctx, spec| {
        Ok(Box::new(TileConeBuilder::new(ctx.frame, spec)?))
    })?;
    Ok(())
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n: u32,
    nodes: u32,
    width: u32,
    height: u32,
    tile_size: u32,
    tiles_x: u32,
    tiles: u32,
    pad0: u32,
    sin_min: f32,
    cos_min: f32,
    pad1: [f32; 2],
}

struct TileConeKernels {
    kernel: Kernel,
}

impl TileConeKernels {
    fn new(ctx: &GpuContext) -> GpuResult<TileConeKernels> {
        let mut slots = vec![Slot::Uniform, Slot::Read, Slot::Read];
        slots.extend([Slot::ReadWrite; 5]);
        let constants = constants_wgsl();
        let group = tile_group_wgsl();
        Ok(TileConeKernels {
            kernel: Kernel::new(
                ctx,
                "crsh tile-cone",
                &compose(&[GLAM_WGSL, REACH_WGSL, &constants, &group, SHADER, TRIG_WGSL]),
                &["run_flags", "run_offsets", "cones"],
                &slots,
            )?,
        })
    }
}

/// The GPU `tile_cone` hierarchy builder.
#[derive(Clone, Debug)]
pub struct TileConeBuilder {
    grid: TileGrid,
    params: TileConeParams,
}

impl TileConeBuilder {
    /// The builder for `frame` with a resolved `spec` (`tile_size`, `min_half_angle_deg`),
    /// read by the CPU twin ([`crsh_cpu::hierarchy::tile_cone::TileConeBuilder::new`]).
    ///
    /// # Errors
    /// [`CoreError::InvalidParam`] for a parameter out of range.
    pub fn new(frame: FrameSize, spec: &StageSpec) -> Result<TileConeBuilder> {
        TileConeBuilder::with_params(frame, *CpuTileCone::new(frame, spec)?.params())
    }

    /// The builder for `frame` with `params` (checked by [`TileConeParams::new`]).
    ///
    /// # Errors
    /// [`CoreError::InvalidParam`] for a parameter out of range; [`CoreError::InvalidInput`]
    /// for a frame of more than `u32::MAX` tiles.
    pub fn with_params(frame: FrameSize, params: TileConeParams) -> Result<TileConeBuilder> {
        let params = TileConeParams::new(params.tile_size, params.min_half_angle_deg)?;
        let grid = TileGrid::new(frame, params.tile_size)?;
        grid_u32(&grid)?;
        Ok(TileConeBuilder { grid, params })
    }

    /// The tile grid the nodes follow.
    pub fn grid(&self) -> TileGrid {
        self.grid
    }

    /// The parameters.
    pub fn params(&self) -> &TileConeParams {
        &self.params
    }

    fn kernel_params(&self, n: usize, nodes: usize) -> Result<Params> {
        let g = self.grid;
        let (tiles_x, tiles) = grid_u32(&g)?;
        let (sin_min, cos_min) = self.params.sin_cos_min();
        Ok(Params {
            n: n as u32,
            nodes: nodes as u32,
            width: g.frame().width,
            height: g.frame().height,
            tile_size: g.tile_size(),
            tiles_x,
            tiles,
            pad0: 0,
            sin_min,
            cos_min,
            pad1: [0.0; 2],
        })
    }
}

impl HierarchyBuilder<Wgpu> for TileConeBuilder {
    fn name(&self) -> &str {
        "tile_cone"
    }

    fn build(
        &self,
        backend: &Wgpu,
        rays: &GpuBuffer<Ray>,
        order: GpuBuffer<u32>,
        _stats: &mut Stats,
    ) -> Result<RayHierarchy<Wgpu>> {
        let ctx = backend.context();
        let n = rays.len();
        super::check_order_len("tile_cone", order.len(), n)?;
        let subdivision = self.params.tile_size * self.params.tile_size;
        if n == 0 {
            return Ok(RayHierarchy {
                order,
                levels: vec![GpuBuffer::zeroed(ctx, "crsh tile cones", 0)?],
                subdivision,
                leaf_offsets: Some(GpuBuffer::from_slice(ctx, "crsh leaf offsets", &[0u32])?),
                reach: vec![GpuBuffer::zeroed(ctx, "crsh tile-cone reach", 0)?],
            });
        }
        if u32::try_from(n).is_err() {
            return Err(CoreError::InvalidInput(format!(
                "tile_cone: {n} rays exceed u32 positions"
            )));
        }
        ctx.check_storage_binding("hierarchy rays", rays.byte_len())?;
        let k = ctx.kernel(TileConeKernels::new)?;
        let starts = GpuBuffer::<u32>::zeroed(ctx, "crsh tile-cone run starts", n)?;
        let counters = GpuBuffer::<u32>::zeroed(ctx, "crsh tile-cone counters", 4)?;
        let none_offsets = GpuBuffer::<u32>::zeroed(ctx, "crsh unused", 0)?;
        let none_nodes = GpuBuffer::<SphereCone>::zeroed(ctx, "crsh unused", 0)?;
        let none_reach = GpuBuffer::<f32>::zeroed(ctx, "crsh unused", 0)?;
        let bind = |params: &Params,
                    offsets: &GpuBuffer<u32>,
                    nodes: &GpuBuffer<SphereCone>,
                    reach: &GpuBuffer<f32>| {
            let u = uniform(ctx, "crsh tile-cone params", params);
            k.kernel.bind_group(
                ctx,
                &[
                    u.as_entire_binding(),
                    rays.binding(),
                    order.binding(),
                    starts.binding(),
                    offsets.binding(),
                    nodes.binding(),
                    reach.binding(),
                    counters.binding(),
                ],
            )
        };
        // Run starts, their scan into node indices, and the node count.
        let bg = bind(
            &self.kernel_params(n, 0)?,
            &none_offsets,
            &none_nodes,
            &none_reach,
        );
        let mut enc = encoder(ctx, "crsh tile-cone runs");
        {
            let mut pass = ctx.compute_pass(&mut enc, "crsh tile-cone runs");
            k.kernel
                .dispatch(ctx, &mut pass, "run_flags", &bg, n as u32)?;
        }
        ctx.kernel(crate::kernels::scan::ScanKernel::new)?
            .encode_in_place(ctx, &mut enc, &starts, Some((counters.buffer(), 4)))?;
        submit(ctx, "crsh tile-cone runs", enc)?;
        let c = counters.to_vec(ctx)?;
        if c[0] != 0 {
            let at = u32::MAX - c[0];
            let mut what = Vec::new();
            if c[2] & 1 != 0 {
                what.push(format!("an order entry is not below the ray count {n}"));
            }
            if c[2] & 2 != 0 {
                what.push(format!(
                    "a pixel is outside the {} frame",
                    self.grid.frame()
                ));
            }
            if c[2] & 4 != 0 {
                what.push(
                    "a ray is not valid (NaN or infinite origin or direction, zero direction, \
                     or NaN interval)"
                        .into(),
                );
            }
            return Err(CoreError::InvalidInput(format!(
                "tile_cone: bad input at order position {at} or later: {}",
                what.join("; ")
            )));
        }
        let nodes = c[1] as usize;
        // Offsets, then one cone per node.
        let offsets = GpuBuffer::<u32>::zeroed(ctx, "crsh leaf offsets", nodes + 1)?;
        let level = GpuBuffer::<SphereCone>::zeroed(ctx, "crsh tile cones", nodes)?;
        let reach = GpuBuffer::<f32>::zeroed(ctx, "crsh tile-cone reach", nodes)?;
        let bg = bind(&self.kernel_params(n, nodes)?, &offsets, &level, &reach);
        let mut enc = encoder(ctx, "crsh tile-cone nodes");
        {
            let mut pass = ctx.compute_pass(&mut enc, "crsh tile-cone offsets");
            k.kernel
                .dispatch(ctx, &mut pass, "run_offsets", &bg, n as u32)?;
        }
        {
            let mut pass = ctx.compute_pass(&mut enc, "crsh tile-cone cones");
            k.kernel
                .dispatch(ctx, &mut pass, "cones", &bg, nodes as u32)?;
        }
        submit(ctx, "crsh tile-cone nodes", enc)?;
        Ok(RayHierarchy {
            order,
            levels: vec![level],
            subdivision,
            leaf_offsets: Some(offsets),
            reach: vec![reach],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The generated constants read back as the CPU twin's, bit for bit.
    #[test]
    fn tile_cone_constants_are_the_cpu_ones() {
        let src = constants_wgsl();
        for (name, want) in [
            ("PI", std::f32::consts::PI),
            ("FRAC_PI_2", std::f32::consts::FRAC_PI_2),
            ("EXTEND_EPS", EXTEND_EPS),
            ("PERP_EPS", PERP_EPS),
            ("PERP_SWITCH", PERP_SWITCH),
            ("GUARD_SCALE", GUARD_SCALE),
            ("GUARD_ADD", GUARD_ADD),
        ] {
            let decl = format!("const {name}: f32 = ");
            let at = src.find(&decl).expect(name) + decl.len();
            let lit = &src[at..at + src[at..].find("f;").expect(name)];
            let got: f32 = lit.parse().expect(lit);
            assert_eq!(got.to_bits(), want.to_bits(), "{name} = {lit}");
        }
        assert!(SHADER.contains("fn cones("));
    }

    #[test]
    fn parameters_are_checked() {
        let frame = FrameSize::new(100, 37).unwrap();
        let with = |ts, deg| {
            TileConeBuilder::with_params(
                frame,
                TileConeParams {
                    tile_size: ts,
                    min_half_angle_deg: deg,
                },
            )
        };
        assert!(with(16, 0.05).is_ok());
        assert!(with(16, 10.0).is_ok());
        for (ts, deg) in [
            (0, 0.05),
            (4097, 0.05),
            (16, 0.0),
            (16, 10.5),
            (16, f64::NAN),
        ] {
            assert!(
                matches!(with(ts, deg), Err(CoreError::InvalidParam { .. })),
                "{ts} {deg}"
            );
        }
        let mut spec = crsh_cpu::hierarchy::tile_cone::info().defaults();
        let b = TileConeBuilder::new(frame, &spec).unwrap();
        assert_eq!(b.grid().tile_size(), 16);
        assert_eq!(*b.params(), TileConeParams::default());
        spec.params.insert(
            "min_half_angle_deg".into(),
            crsh_core::ParamValue::Float(0.0),
        );
        assert!(matches!(
            TileConeBuilder::new(frame, &spec),
            Err(CoreError::InvalidParam { .. })
        ));
    }
}
