//! Seed 001's origin offsets on the device: the hemisphere set of the `offsets` parameter,
//! built once on the host when a generator is constructed ([`crsh_cpu::raygen::offsets`]) and
//! uploaded for `kernels/origin_offset.wgsl`, which the generators' kernels call where their
//! CPU twins call [`Offsets::apply`] and [`Offsets::cut_end`].
//!
//! Layout on the device (the bindings `raygen/slots.wgsl` declares):
//! - a uniform [`HemiParams`]: records per slot (0 for `offsets = none`), the scene's triangle
//!   count, whether slots go through the polygon index, and where the normals start;
//! - one `array<vec4<f32>>`: [`HemisphereSet::records`] followed by
//!   [`HemisphereSet::normals`]. Records and normals share a binding so that a ray
//!   generator's kernel needs 8 storage bindings, WebGPU's default
//!   `max_storage_buffers_per_shader_stage`;
//! - one `array<u32>`: [`HemisphereSet::triangle_index`] (polygon; a dummy otherwise).
//!
//! [`HemisphereSet::records`]: crsh_cpu::raygen::origin_offset::HemisphereSet::records
//! [`HemisphereSet::normals`]: crsh_cpu::raygen::origin_offset::HemisphereSet::normals
//! [`HemisphereSet::triangle_index`]: crsh_cpu::raygen::origin_offset::HemisphereSet::triangle_index

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{ParamValue, Result, StageSpec};
use crsh_cpu::raygen::offsets::Offsets;
use crsh_cpu::raygen::origin_offset::SetKind;

use crate::backend::GpuBuffer;
use crate::kernel::uniform;
use crate::scene::GpuScene;

/// Uniform block `HemiParams` of `origin_offset.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct HemiParams {
    /// Records per slot; 0 when no set is in use.
    pub per_slot: u32,
    /// Triangles of the scene the set was built for.
    pub triangles: u32,
    /// 1 for the polygon set (slots through the triangle index).
    pub polygon: u32,
    /// Index of slot 0's normal in the table (the number of records).
    pub normals_at: u32,
}

/// A generator's origin offsets on the device: the host set ([`Offsets`]) and its upload.
pub struct GpuOffsets {
    offsets: Offsets,
    params: HemiParams,
    uniform: wgpu::Buffer,
    table: GpuBuffer<[f32; 4]>,
    index: GpuBuffer<u32>,
}

impl GpuOffsets {
    /// Bytes of the hemisphere tables ([`Offsets::table_bytes`], what the CPU twin reports).
    pub fn table_bytes(&self) -> u64 {
        self.offsets.table_bytes()
    }

    /// The offsets a resolved `spec`'s `offsets` parameter asks for, built over the host scene
    /// of `scene` and uploaded.
    pub fn from_spec(scene: &GpuScene, spec: &StageSpec) -> Result<Arc<GpuOffsets>> {
        let offsets = Offsets::from_spec(&scene.scene, spec)?;
        Ok(Arc::new(GpuOffsets::upload(scene, offsets)?))
    }

    /// `offsets` uploaded to `scene`'s device; the table must fit one storage binding.
    pub fn upload(scene: &GpuScene, offsets: Offsets) -> Result<GpuOffsets> {
        let ctx = scene.ctx();
        let (params, table, index) = match offsets.hemispheres() {
            None => (HemiParams::default(), Vec::new(), Vec::new()),
            Some(set) => {
                let mut table = Vec::with_capacity(set.records().len() + set.normals().len());
                table.extend_from_slice(set.records());
                table.extend_from_slice(set.normals());
                let polygon = set.kind() == SetKind::Polygon;
                let params = HemiParams {
                    per_slot: set.per_slot() as u32,
                    triangles: set.triangle_count() as u32,
                    polygon: u32::from(polygon),
                    normals_at: set.records().len() as u32,
                };
                (params, table, set.triangle_index().to_vec())
            }
        };
        ctx.check_storage_binding("hemisphere records and normals", table.len() as u64 * 16)?;
        ctx.check_storage_binding("hemisphere triangle index", index.len() as u64 * 4)?;
        Ok(GpuOffsets {
            params,
            uniform: uniform(ctx, "crsh hemisphere params", &params),
            table: GpuBuffer::from_slice(ctx, "crsh hemisphere table", &table)?,
            index: GpuBuffer::from_slice(ctx, "crsh hemisphere index", &index)?,
            offsets,
        })
    }

    /// The host set (the CPU twin's offsets).
    pub fn offsets(&self) -> &Offsets {
        &self.offsets
    }

    /// The uniform block uploaded.
    pub fn params(&self) -> HemiParams {
        self.params
    }

    /// The three bindings of `raygen/slots.wgsl` (7, 8, 9): parameters, table, index.
    pub(crate) fn bindings(&self) -> [wgpu::BindingResource<'_>; 3] {
        [
            self.uniform.as_entire_binding(),
            self.table.binding(),
            self.index.binding(),
        ]
    }
}

/// `spec` with `offsets = none`: what the wgpu generators pass to their CPU twins'
/// constructors, which validate every other parameter, so that the hemisphere set is built
/// once (by [`GpuOffsets::from_spec`]) rather than once per twin.
pub(crate) fn without_offsets(spec: &StageSpec) -> StageSpec {
    let mut s = spec.clone();
    s.params
        .insert("offsets".into(), ParamValue::Str("none".into()));
    s
}
