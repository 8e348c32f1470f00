//! Ray hashers (seed 000 §3.2.3, figs 3.8-3.9): one sort key per ray.
//!
//! - [`thesis`]: the variant `thesis`, the thesis's per-kind hashes: [`thesis_shadow`] (light
//!   index, then the spherical direction) for shadow rays and [`thesis_bounce`] (quantized
//!   origin, then the spherical direction) for reflection and refraction rays.
//! - [`morton_octa`]: the variant `morton` (ours): a 5-D Morton code of the quantized origin
//!   and the octahedral direction.
//! - [`tile`]: the variant `tile`, seed 004's screen tiles: the tile of the ray's pixel (per
//!   light for shadow rays), so that each tile's rays become one node of the tile cones.
//! - The quantizers and bit interleaving the hashers share live in [`crsh_core::quantize`], so
//!   the wgpu backend and third-party hashers use the same ones.

pub mod morton_octa;
pub mod thesis;
pub mod thesis_bounce;
pub mod thesis_shadow;
pub mod tile;

/// Scenes for the hasher and sorter tests.
#[cfg(test)]
pub(crate) mod test_util {
    use std::sync::Arc;

    use crsh_scene::{Camera, Light, Material, Scene, SceneBuilder};
    use glam::Vec3;

    /// A box `[-2, 2]³` (two quads: floor and back wall span it) lit by `lights` lights.
    pub(crate) fn scene_with_lights(lights: usize) -> Arc<Scene> {
        let mut b = SceneBuilder::new("hash-test");
        b.material(Material::default());
        for i in 0..lights {
            b.light(Light {
                position: Vec3::new(-1.5 + i as f32, 1.5, 0.5),
                color: Vec3::ONE,
                intensity: 1.0,
                attenuation: [1.0, 0.0, 0.0],
                radius: 0.0,
            });
        }
        b.camera(Camera {
            eye: Vec3::new(0.0, 0.0, 5.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            vfov_deg: 45.0,
            aspect: None,
        });
        let floor = [
            Vec3::new(-2.0, -2.0, -2.0),
            Vec3::new(2.0, -2.0, -2.0),
            Vec3::new(2.0, -2.0, 2.0),
            Vec3::new(-2.0, -2.0, 2.0),
        ];
        let wall = [
            Vec3::new(-2.0, -2.0, -2.0),
            Vec3::new(2.0, -2.0, -2.0),
            Vec3::new(2.0, 2.0, -2.0),
            Vec3::new(-2.0, 2.0, -2.0),
        ];
        b.mesh("floor", &floor, None, &[[0, 2, 1], [0, 3, 2]], 0);
        b.mesh("wall", &wall, None, &[[0, 1, 2], [0, 2, 3]], 0);
        Arc::new(b.build("hash test scene").expect("valid test scene"))
    }
}
