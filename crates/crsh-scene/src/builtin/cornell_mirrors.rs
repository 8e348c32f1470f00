//! `cornell-mirrors`: the thesis's CORNELL scene (seed 000's evaluation), a smooth object of a
//! few hundred triangles inside a closed box whose six walls are all mirrors, lit by one point
//! light inside the box. Every primary ray bounces between mirrors, so reflection rays dominate.
//!
//! Layout: the box spans `[-1, 1]³`; each wall is its own mesh (two triangles, normals facing
//! the inside) with reflectivity 0.7 and a distinct diffuse tint so the image stays readable;
//! the object is an icosphere (two subdivisions, 320 triangles, smooth normals) of radius 0.4
//! resting on the floor; the light hangs under the ceiling; the camera stands inside the box
//! near the front wall, looking at the object.

use glam::Vec3;

use super::Geometry;
use crate::model::{Camera, Light, Material, SceneBuilder};

/// Mirror weight of the walls.
pub const WALL_REFLECTIVITY: f32 = 0.7;

/// The scene's builder (camera, light, materials and meshes set; call `build`).
pub fn builder() -> SceneBuilder {
    let mut b = SceneBuilder::new("cornell-mirrors");
    let wall = |name: &str, tint: Vec3| Material {
        name: name.into(),
        diffuse: tint,
        specular: Vec3::splat(0.2),
        shininess: 64.0,
        reflectivity: WALL_REFLECTIVITY,
        transparency: 0.0,
        ior: 1.0,
        emission: Vec3::ZERO,
    };
    let v = Vec3::new;
    // (name, tint, four corners, inward direction)
    let walls: [(&str, Vec3, [Vec3; 4], Vec3); 6] = [
        (
            "floor",
            v(0.55, 0.55, 0.5),
            [
                v(-1., -1., -1.),
                v(1., -1., -1.),
                v(1., -1., 1.),
                v(-1., -1., 1.),
            ],
            Vec3::Y,
        ),
        (
            "ceiling",
            v(0.6, 0.6, 0.6),
            [
                v(-1., 1., -1.),
                v(1., 1., -1.),
                v(1., 1., 1.),
                v(-1., 1., 1.),
            ],
            -Vec3::Y,
        ),
        (
            "left-wall",
            v(0.6, 0.12, 0.1),
            [
                v(-1., -1., -1.),
                v(-1., 1., -1.),
                v(-1., 1., 1.),
                v(-1., -1., 1.),
            ],
            Vec3::X,
        ),
        (
            "right-wall",
            v(0.12, 0.5, 0.12),
            [
                v(1., -1., -1.),
                v(1., 1., -1.),
                v(1., 1., 1.),
                v(1., -1., 1.),
            ],
            -Vec3::X,
        ),
        (
            "back-wall",
            v(0.15, 0.2, 0.55),
            [
                v(-1., -1., -1.),
                v(1., -1., -1.),
                v(1., 1., -1.),
                v(-1., 1., -1.),
            ],
            Vec3::Z,
        ),
        (
            "front-wall",
            v(0.55, 0.5, 0.15),
            [
                v(-1., -1., 1.),
                v(1., -1., 1.),
                v(1., 1., 1.),
                v(-1., 1., 1.),
            ],
            -Vec3::Z,
        ),
    ];
    for (name, tint, [p0, p1, p2, p3], inward) in walls {
        let m = b.material(wall(name, tint));
        let mut g = Geometry::default();
        g.quad_facing(p0, p1, p2, p3, inward);
        b.mesh(name, &g.positions, Some(&g.normals), &g.indices, m);
    }
    let object = b.material(Material {
        name: "object".into(),
        diffuse: v(0.8, 0.45, 0.15),
        specular: Vec3::splat(0.5),
        shininess: 48.0,
        reflectivity: 0.0,
        transparency: 0.0,
        ior: 1.0,
        emission: Vec3::ZERO,
    });
    let sphere = Geometry::icosphere(v(0.0, -0.6, -0.2), 0.4, 2);
    b.mesh(
        "icosphere",
        &sphere.positions,
        Some(&sphere.normals),
        &sphere.indices,
        object,
    );
    b.light(Light {
        position: v(0.0, 0.8, 0.2),
        color: Vec3::ONE,
        intensity: 1.0,
        attenuation: [1.0, 0.0, 0.0],
        radius: 0.0,
    });
    b.camera(Camera {
        eye: v(0.0, 0.1, 0.95),
        target: v(0.0, -0.5, -0.2),
        up: Vec3::Y,
        vfov_deg: 60.0,
        aspect: None,
    });
    b
}
