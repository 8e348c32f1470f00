//! The scene on the device: flat arrays uploaded once and shared by every stage of a pipeline
//! (and by the reference intersector), mirroring [`crsh_scene::Scene`] with the records of
//! `kernels/common.wgsl`.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_scene::Scene;

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;

/// A triangle's vertices (`Triangle` in WGSL, 48 bytes); `w` is 0.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GpuTriangle {
    /// First vertex.
    pub v0: [f32; 4],
    /// Second vertex.
    pub v1: [f32; 4],
    /// Third vertex.
    pub v2: [f32; 4],
}

/// A triangle's mesh, material and degeneracy (`TriangleInfo` in WGSL, 16 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct GpuTriangleInfo {
    /// Mesh id.
    pub mesh: u32,
    /// Material id.
    pub material: u32,
    /// 1 when [`Scene::is_degenerate`] holds (the triangle is never hit).
    pub degenerate: u32,
    /// Padding.
    pub pad: u32,
}

/// A mesh's bounding sphere and box (`Mesh` in WGSL, 48 bytes). `aabb_min[3]` and
/// `aabb_max[3]` hold the bit patterns of `first_tri` and `tri_count`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GpuMesh {
    /// Centre and radius.
    pub sphere: [f32; 4],
    /// Box minimum; `w` is `first_tri` as bits.
    pub aabb_min: [f32; 4],
    /// Box maximum; `w` is `tri_count` as bits.
    pub aabb_max: [f32; 4],
}

/// A material (`Material` in WGSL, 64 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GpuMaterial {
    /// Diffuse colour.
    pub diffuse: [f32; 3],
    /// Phong exponent.
    pub shininess: f32,
    /// Specular colour.
    pub specular: [f32; 3],
    /// Mirror weight.
    pub reflectivity: f32,
    /// Emitted radiance.
    pub emission: [f32; 3],
    /// Refraction weight.
    pub transparency: f32,
    /// Index of refraction.
    pub ior: f32,
    /// Padding.
    pub pad: [f32; 3],
}

/// A point light (`Light` in WGSL, 48 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GpuLight {
    /// Position.
    pub position: [f32; 3],
    /// Scalar intensity.
    pub intensity: f32,
    /// Colour.
    pub color: [f32; 3],
    /// Padding.
    pub pad0: f32,
    /// Constant, linear and quadratic attenuation (eq. 3.19c).
    pub attenuation: [f32; 3],
    /// Padding.
    pub pad1: f32,
}

/// A scene's arrays in device memory, built once per scene and shared (`Arc`) by the stages.
///
/// Triangle `i` of every per-triangle buffer is triangle `i` of the scene, so triangle ids mean
/// the same on both backends.
#[derive(Debug)]
pub struct GpuScene {
    /// The host scene (cameras, lights and counts for host-side parameters).
    pub scene: Arc<Scene>,
    /// The backend the buffers live on.
    pub backend: Wgpu,
    /// Vertices per triangle.
    pub triangles: GpuBuffer<GpuTriangle>,
    /// Vertex normals per triangle, one [`GpuTriangle`] of normals (`v0` = normal of the first
    /// vertex...).
    pub normals: GpuBuffer<GpuTriangle>,
    /// Mesh, material and degeneracy per triangle.
    pub info: GpuBuffer<GpuTriangleInfo>,
    /// Bounding sphere per triangle (`xyz` centre, `w` radius).
    pub tri_spheres: GpuBuffer<[f32; 4]>,
    /// Meshes.
    pub meshes: GpuBuffer<GpuMesh>,
    /// Materials.
    pub materials: GpuBuffer<GpuMaterial>,
    /// Point lights.
    pub lights: GpuBuffer<GpuLight>,
}

fn v4(v: glam::Vec3) -> [f32; 4] {
    [v.x, v.y, v.z, 0.0]
}

impl crsh_core::StageScene for GpuScene {
    fn triangle_count(&self) -> usize {
        self.scene.triangle_count()
    }
}

impl GpuScene {
    /// Uploads `scene` to `backend`'s device.
    pub fn new(backend: &Wgpu, scene: &Arc<Scene>) -> GpuResult<Arc<GpuScene>> {
        let ctx: &GpuContext = backend.context();
        let n = scene.triangle_count();
        let mut triangles = Vec::with_capacity(n);
        let mut normals = Vec::with_capacity(n);
        let mut info = Vec::with_capacity(n);
        for t in 0..n {
            let [a, b, c] = scene.triangle(t);
            triangles.push(GpuTriangle {
                v0: v4(a),
                v1: v4(b),
                v2: v4(c),
            });
            let [i0, i1, i2] = scene.indices[t];
            normals.push(GpuTriangle {
                v0: v4(scene.normals[i0 as usize]),
                v1: v4(scene.normals[i1 as usize]),
                v2: v4(scene.normals[i2 as usize]),
            });
            info.push(GpuTriangleInfo {
                mesh: scene.tri_mesh[t],
                material: scene.tri_material[t],
                degenerate: u32::from(scene.is_degenerate(t)),
                pad: 0,
            });
        }
        let tri_spheres: Vec<[f32; 4]> = scene
            .tri_spheres
            .iter()
            .map(|s| [s.center.x, s.center.y, s.center.z, s.radius])
            .collect();
        let meshes: Vec<GpuMesh> = scene
            .meshes
            .iter()
            .map(|m| GpuMesh {
                sphere: [
                    m.sphere.center.x,
                    m.sphere.center.y,
                    m.sphere.center.z,
                    m.sphere.radius,
                ],
                aabb_min: [
                    m.aabb.min.x,
                    m.aabb.min.y,
                    m.aabb.min.z,
                    f32::from_bits(m.first_tri),
                ],
                aabb_max: [
                    m.aabb.max.x,
                    m.aabb.max.y,
                    m.aabb.max.z,
                    f32::from_bits(m.tri_count),
                ],
            })
            .collect();
        let materials: Vec<GpuMaterial> = scene
            .materials
            .iter()
            .map(|m| GpuMaterial {
                diffuse: m.diffuse.to_array(),
                shininess: m.shininess,
                specular: m.specular.to_array(),
                reflectivity: m.reflectivity,
                emission: m.emission.to_array(),
                transparency: m.transparency,
                ior: m.ior,
                pad: [0.0; 3],
            })
            .collect();
        let lights: Vec<GpuLight> = scene
            .lights
            .iter()
            .map(|l| GpuLight {
                position: l.position.to_array(),
                intensity: l.intensity,
                color: l.color.to_array(),
                pad0: 0.0,
                attenuation: l.attenuation,
                pad1: 0.0,
            })
            .collect();
        Ok(Arc::new(GpuScene {
            scene: Arc::clone(scene),
            backend: backend.clone(),
            triangles: GpuBuffer::from_slice(ctx, "crsh triangles", &triangles)?,
            normals: GpuBuffer::from_slice(ctx, "crsh vertex normals", &normals)?,
            info: GpuBuffer::from_slice(ctx, "crsh triangle info", &info)?,
            tri_spheres: GpuBuffer::from_slice(ctx, "crsh triangle spheres", &tri_spheres)?,
            meshes: GpuBuffer::from_slice(ctx, "crsh meshes", &meshes)?,
            materials: GpuBuffer::from_slice(ctx, "crsh materials", &materials)?,
            lights: GpuBuffer::from_slice(ctx, "crsh lights", &lights)?,
        }))
    }

    /// The device context.
    pub fn ctx(&self) -> &GpuContext {
        self.backend.context()
    }

    /// Triangles in the scene.
    pub fn triangle_count(&self) -> usize {
        self.scene.triangle_count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::mem::size_of;

    #[test]
    fn records_have_the_wgsl_sizes() {
        assert_eq!(size_of::<GpuTriangle>(), 48);
        assert_eq!(size_of::<GpuTriangleInfo>(), 16);
        assert_eq!(size_of::<GpuMesh>(), 48);
        assert_eq!(size_of::<GpuMaterial>(), 64);
        assert_eq!(size_of::<GpuLight>(), 48);
        assert_eq!(size_of::<crsh_core::Ray>(), 64);
        assert_eq!(size_of::<crsh_core::Hit>(), 16);
        assert_eq!(size_of::<crsh_core::Surface>(), 80);
        assert_eq!(size_of::<crsh_core::SphereCone>(), 32);
        assert_eq!(size_of::<crsh_core::Candidate>(), 8);
    }
}
