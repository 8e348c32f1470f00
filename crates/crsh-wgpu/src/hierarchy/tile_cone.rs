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
//! Per node, in `f32` (one invocation per node, the rays in order, operation for operation as
//! the shared spec of the CPU and wgpu twins says): start with the zero-angle cone of the
//! first ray (`a = o₀`, `x = d₀/|d₀|`), then for each further ray (a) extend the cone's solid
//! angle to hold its direction (§4, fig. 2: `q` towards the axis, the far generator
//! `e = x cos φ + q sin φ`, the new axis `(e + r)/|e + r|`, `cos φ = x·r`) and (b) translate
//! the cone along its far generator until the near generator `n = x cos φ − q sin φ` holds the
//! origin (§4, fig. 3: `g = c − n(n·c)`, `t = g²/(e·g)`). A final pass measures the half-angle
//! that is stored against the stored apex and axis and computes the reach.
//!
//! # Errata (how the paper's construction is corrected)
//!
//! 1. **Apex sign.** The paper prints `a_new = a − e·t`; with `t = g²/(e·g) < 0` that moves the
//!    apex towards the origin's side and the cone misses it. The apex moves by `+e·t` (the
//!    tests show the literal update failing containment).
//! 2. **Opening beyond 90°.** The construction assumes a convex cone: when extending makes
//!    `cos φ ≤ 0`, or the new direction is opposite the far generator (`|e + r| ≤`
//!    [`FULL_LENGTH`]), or the final measured angle reaches π/2, the node's half-angle is π
//!    (culling is disabled for that node, which stays correct).
//! 3. **Translating a zero-angle cone.** With `φ = 0` the near and far generators coincide with
//!    the axis and `e·g = 0`: a cone whose angle is below `min_half_angle_deg` is first widened
//!    to it (parameter, default 0.05°), then translated. `e·g ≥ 0` (impossible in exact
//!    arithmetic) gives π too.
//! 4. **Undefined `q`.** When the ray is opposite the axis or the origin lies on the axis line,
//!    `(x·v)x − v` vanishes; any unit perpendicular of the axis is used (`|w| ≤`
//!    [`PERP_REL`]` · max(1, |v|)`; the cross product with the x axis, or the y axis when
//!    `|x.x| ≥` [`PERP_SWITCH`]).
//! 5. **Rounding.** The incremental result only chooses the apex and the axis: the stored
//!    half-angle is `max` over the node's rays of the angles from the axis to `d` and to
//!    `o − a` (`atan2(|x × v|, x·v)`, skipped when `o = a`), times `1 +`
//!    [`ANGLE_GUARD_REL`] plus [`ANGLE_GUARD_ABS`], so every ray is inside in exact arithmetic
//!    (the tests check it in `f64`).
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
//! The twin is the CPU `tile_cone` builder (`crsh_cpu::hierarchy::tile_cone`, written from the
//! same spec on another branch): the same operations in the same order, so the nodes agree up
//! to WGSL's rounding of `sqrt` and division (lavapipe's are correctly rounded), the
//! contraction of multiply-adds a driver may do, and the angles of `kernels/trig.wgsl`'s
//! `atan2` (a few 1e-8 rad from the CPU's). The reach is guarded in `f32` on the device
//! (`+1e-6·max(1, |coordinates|)`, `+1e-5` relative), a little wider than a bound computed in
//! `f64`. Until the twin lands, this module carries the catalogue entry ([`info`]) and the
//! construction's constants ([`FULL_LENGTH`] and the others), from which the WGSL constants
//! are generated.
//!
//! # Errors
//!
//! [`CoreError::InvalidInput`] when the order's length is not the ray count, an order entry is
//! out of range, a ray's pixel is outside the frame, or a ray is not valid (non-finite origin
//! or direction, zero direction, NaN interval): the first bad position is named.

use bytemuck::{Pod, Zeroable};
use crsh_core::{
    CoreError, FrameSize, HierarchyBuilder, ParamInfo, Ray, RayHierarchy, Registry, Result,
    SphereCone, StageKind, StageSpec, StageVariantInfo, Stats,
};

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::hash::tile::{tile_group_wgsl, tile_size_param, TileGrid, MAX_TILE_SIZE};
use crate::kernel::{encoder, submit, uniform, Kernel, Slot};
use crate::kernels::{compose, f32_const, GLAM_WGSL, REACH_WGSL, TRIG_WGSL};

const SHADER: &str = include_str!("tile_cone.wgsl");

/// Default `min_half_angle_deg`: the opening a zero-angle cone gets before it is translated
/// (erratum 3), in degrees.
pub const DEFAULT_MIN_HALF_ANGLE_DEG: f64 = 0.05;
/// Largest `min_half_angle_deg` (the smallest is above 0).
pub const MAX_MIN_HALF_ANGLE_DEG: f64 = 10.0;
/// `|e + r|` at or below which the new direction is opposite the far generator: the node can
/// only be bounded by more than a half-space (half-angle π, erratum 2).
pub const FULL_LENGTH: f32 = 1e-6;
/// `perp_towards_axis` falls back to a fixed perpendicular when `|(x·v)x − v|` is at most this
/// times `max(1, |v|)` (erratum 4).
pub const PERP_REL: f32 = 1e-12;
/// `any_perpendicular(x)` crosses `x` with the x axis when `|x.x|` is below this, else with the
/// y axis.
pub const PERP_SWITCH: f32 = 0.9;
/// Relative rounding guard of the measured half-angle (erratum 5).
pub const ANGLE_GUARD_REL: f32 = 1e-5;
/// Absolute rounding guard of the measured half-angle, in radians (erratum 5).
pub const ANGLE_GUARD_ABS: f32 = 4e-6;

/// `sin` and `cos` of `min_half_angle_deg` as the construction uses them: the angle converted
/// to radians in `f64`, rounded to `f32`, and its `f32` sine and cosine (computed once, on the
/// host).
pub fn min_half_angle_sin_cos(min_half_angle_deg: f64) -> (f32, f32) {
    let a = min_half_angle_deg.to_radians() as f32;
    (a.sin(), a.cos())
}

/// The WGSL constants of `tile_cone.wgsl`, generated from the Rust ones above (and `π`, `π/2`
/// as `f32`), so the two cannot drift apart.
fn constants_wgsl() -> String {
    let mut s = String::from("// Generated from crate::hierarchy::tile_cone.\n");
    s += &f32_const("PI", std::f32::consts::PI);
    s += &f32_const("FRAC_PI_2", std::f32::consts::FRAC_PI_2);
    s += &f32_const("FULL_LENGTH", FULL_LENGTH);
    s += &f32_const("PERP_REL", PERP_REL);
    s += &f32_const("PERP_SWITCH", PERP_SWITCH);
    s += &f32_const("ANGLE_GUARD_REL", ANGLE_GUARD_REL);
    s += &f32_const("ANGLE_GUARD_ABS", ANGLE_GUARD_ABS);
    s
}

/// The catalogue entry of the `tile_cone` builder.
///
/// Carried here until the CPU twin's (`crsh_cpu::hierarchy::tile_cone::info`) lands; then the
/// wgpu variant registers under that one, as every other wgpu variant does.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Hierarchy,
        "tile_cone",
        "one enclosing cone per run of rays of one screen tile, built incrementally (seed 004 \
         §4, with the apex sign and the >90° openings corrected)",
    )
    .param(tile_size_param())
    .param(
        ParamInfo::float(
            "min_half_angle_deg",
            DEFAULT_MIN_HALF_ANGLE_DEG,
            "opening (degrees, above 0) a zero-angle cone gets before it is translated",
        )
        .range(0.0, MAX_MIN_HALF_ANGLE_DEG),
    )
}

/// Registers the wgpu `tile_cone` ([`info`], [`TileConeBuilder::new`] with the stage
/// context's frame).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_hierarchy(info(), |ctx, spec| {
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
    min_half_angle_deg: f64,
    sin_min: f32,
    cos_min: f32,
}

impl TileConeBuilder {
    /// The builder for `frame` with a resolved `spec` (`tile_size`, `min_half_angle_deg`).
    ///
    /// # Errors
    /// [`CoreError::InvalidParam`] for a parameter out of range.
    pub fn new(frame: FrameSize, spec: &StageSpec) -> Result<TileConeBuilder> {
        let tile_size = spec.u32_in("tile_size", 1..=MAX_TILE_SIZE)?;
        let deg = spec.f64("min_half_angle_deg")?;
        TileConeBuilder::with_params(frame, tile_size, deg).map_err(|e| match e {
            CoreError::InvalidInput(reason) => CoreError::InvalidParam {
                key: "hierarchy.min_half_angle_deg".into(),
                reason,
            },
            e => e,
        })
    }

    /// The builder for `frame` with tiles of `tile_size` pixels and a minimum opening of
    /// `min_half_angle_deg` degrees (in `(0, 10]`).
    ///
    /// # Errors
    /// [`CoreError::InvalidInput`] for a parameter out of range.
    pub fn with_params(
        frame: FrameSize,
        tile_size: u32,
        min_half_angle_deg: f64,
    ) -> Result<TileConeBuilder> {
        let grid = TileGrid::new(frame, tile_size)?;
        if !(min_half_angle_deg > 0.0 && min_half_angle_deg <= MAX_MIN_HALF_ANGLE_DEG) {
            return Err(CoreError::InvalidInput(format!(
                "min_half_angle_deg {min_half_angle_deg} is outside (0, \
                 {MAX_MIN_HALF_ANGLE_DEG}]"
            )));
        }
        let (sin_min, cos_min) = min_half_angle_sin_cos(min_half_angle_deg);
        Ok(TileConeBuilder {
            grid,
            min_half_angle_deg,
            sin_min,
            cos_min,
        })
    }

    /// The tile grid the nodes follow.
    pub fn grid(&self) -> TileGrid {
        self.grid
    }

    /// The minimum opening of a translated cone, in degrees.
    pub fn min_half_angle_deg(&self) -> f64 {
        self.min_half_angle_deg
    }

    fn params(&self, n: usize, nodes: usize) -> Params {
        let g = self.grid;
        Params {
            n: n as u32,
            nodes: nodes as u32,
            width: g.width,
            height: g.height,
            tile_size: g.tile_size,
            tiles_x: g.tiles_x,
            tiles: g.tiles,
            pad0: 0,
            sin_min: self.sin_min,
            cos_min: self.cos_min,
            pad1: [0.0; 2],
        }
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
        if order.len() != n {
            return Err(CoreError::InvalidInput(format!(
                "tile_cone: {} leaves for a batch of {n} rays (the order must be a permutation)",
                order.len()
            )));
        }
        let subdivision = self.grid.tile_size * self.grid.tile_size;
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
        let bg = bind(&self.params(n, 0), &none_offsets, &none_nodes, &none_reach);
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
                    "a pixel is outside the {}x{} frame",
                    self.grid.width, self.grid.height
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
        let bg = bind(&self.params(n, nodes), &offsets, &level, &reach);
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

    /// The generated constants read back as the Rust ones, bit for bit.
    #[test]
    fn tile_cone_constants_are_the_rust_ones() {
        let src = constants_wgsl();
        for (name, want) in [
            ("PI", std::f32::consts::PI),
            ("FRAC_PI_2", std::f32::consts::FRAC_PI_2),
            ("FULL_LENGTH", FULL_LENGTH),
            ("PERP_REL", PERP_REL),
            ("PERP_SWITCH", PERP_SWITCH),
            ("ANGLE_GUARD_REL", ANGLE_GUARD_REL),
            ("ANGLE_GUARD_ABS", ANGLE_GUARD_ABS),
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
        assert!(TileConeBuilder::with_params(frame, 16, 0.05).is_ok());
        assert!(TileConeBuilder::with_params(frame, 16, 10.0).is_ok());
        for (ts, deg) in [
            (0, 0.05),
            (4097, 0.05),
            (16, 0.0),
            (16, 10.5),
            (16, f64::NAN),
        ] {
            assert!(
                TileConeBuilder::with_params(frame, ts, deg).is_err(),
                "{ts} {deg}"
            );
        }
        let mut spec = info().defaults();
        let b = TileConeBuilder::new(frame, &spec).unwrap();
        assert_eq!(b.grid().tile_size, 16);
        assert_eq!(b.min_half_angle_deg(), 0.05);
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
