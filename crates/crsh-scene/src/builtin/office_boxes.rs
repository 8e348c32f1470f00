//! `office-boxes`: a deterministic procedural office for shadow-ray work (the role of the
//! thesis's OFFICE scene): a closed room with six desks (top and four legs each), a chair at
//! every desk, shelving units along the back wall, and boxes of random size and colour on the
//! desks and shelves — about 140 separate meshes and three thousand triangles — lit by two
//! point lights under the ceiling. Mostly diffuse, a glossy specular term on the desks,
//! metal and some boxes; one glass sphere (transparency 0.9, ior 1.5) on a desk and one mirror
//! on a side wall, so that every ray kind occurs.
//!
//! Randomness comes from a fixed-seed SplitMix64 (`crate::rng`), so every call builds the
//! same arrays.

use glam::Vec3;

use super::Geometry;
use crate::model::{Camera, Light, Material, SceneBuilder};
use crate::rng::SplitMix64;

/// Seed of the layout generator.
pub const SEED: u64 = 0x0FF1_CE00_B0CE_5001;

/// Room extent: x in `[-5, 5]`, y in `[0, 3]`, z in `[-4, 4]`.
pub const ROOM_MIN: Vec3 = Vec3::new(-5.0, 0.0, -4.0);
/// Upper corner of the room.
pub const ROOM_MAX: Vec3 = Vec3::new(5.0, 3.0, 4.0);

fn plain(name: &str, diffuse: Vec3) -> Material {
    Material {
        name: name.into(),
        diffuse,
        ..Material::default()
    }
}

fn glossy(name: &str, diffuse: Vec3, specular: f32, shininess: f32) -> Material {
    Material {
        name: name.into(),
        diffuse,
        specular: Vec3::splat(specular),
        shininess,
        ..Material::default()
    }
}

/// The scene's builder (camera, lights, materials and meshes set; call `build`).
pub fn builder() -> SceneBuilder {
    let mut b = SceneBuilder::new("office-boxes");
    let mut rng = SplitMix64::new(SEED);
    let v = Vec3::new;

    let floor_m = b.material(plain("floor", v(0.45, 0.38, 0.3)));
    let wall_m = b.material(plain("wall", v(0.75, 0.74, 0.7)));
    let ceiling_m = b.material(plain("ceiling", v(0.85, 0.85, 0.85)));
    let wood_m = b.material(glossy("desk-wood", v(0.55, 0.36, 0.2), 0.3, 40.0));
    let metal_m = b.material(glossy("metal", v(0.3, 0.3, 0.32), 0.6, 80.0));
    let shelf_m = b.material(plain("shelf", v(0.6, 0.55, 0.45)));
    let chair_m = b.material(plain("chair-fabric", v(0.15, 0.2, 0.35)));
    let glass_m = b.material(Material {
        name: "glass".into(),
        diffuse: Vec3::splat(0.05),
        specular: Vec3::splat(0.8),
        shininess: 200.0,
        reflectivity: 0.1,
        transparency: 0.9,
        ior: 1.5,
        emission: Vec3::ZERO,
    });
    let mirror_m = b.material(Material {
        name: "mirror".into(),
        diffuse: Vec3::splat(0.05),
        specular: Vec3::splat(0.9),
        shininess: 500.0,
        reflectivity: 0.9,
        transparency: 0.0,
        ior: 1.0,
        emission: Vec3::ZERO,
    });
    let palette = [
        v(0.7, 0.2, 0.15),
        v(0.2, 0.5, 0.25),
        v(0.2, 0.3, 0.65),
        v(0.8, 0.7, 0.2),
        v(0.6, 0.6, 0.58),
        v(0.5, 0.3, 0.55),
    ];
    let box_m: Vec<u32> = palette
        .iter()
        .enumerate()
        .map(|(i, &c)| {
            if i % 2 == 0 {
                b.material(plain(&format!("box-{i}"), c))
            } else {
                b.material(glossy(&format!("box-{i}"), c, 0.25, 30.0))
            }
        })
        .collect();

    let add_box = |b: &mut SceneBuilder, name: String, min: Vec3, max: Vec3, m: u32| {
        let g = Geometry::cuboid(min, max);
        b.mesh(name, &g.positions, Some(&g.normals), &g.indices, m);
    };

    // The room: six inward-facing quads, one mesh each.
    let (lo, hi) = (ROOM_MIN, ROOM_MAX);
    let room = [
        (
            "floor",
            floor_m,
            [
                v(lo.x, lo.y, lo.z),
                v(hi.x, lo.y, lo.z),
                v(hi.x, lo.y, hi.z),
                v(lo.x, lo.y, hi.z),
            ],
            Vec3::Y,
        ),
        (
            "ceiling",
            ceiling_m,
            [
                v(lo.x, hi.y, lo.z),
                v(hi.x, hi.y, lo.z),
                v(hi.x, hi.y, hi.z),
                v(lo.x, hi.y, hi.z),
            ],
            -Vec3::Y,
        ),
        (
            "wall-west",
            wall_m,
            [
                v(lo.x, lo.y, lo.z),
                v(lo.x, hi.y, lo.z),
                v(lo.x, hi.y, hi.z),
                v(lo.x, lo.y, hi.z),
            ],
            Vec3::X,
        ),
        (
            "wall-east",
            wall_m,
            [
                v(hi.x, lo.y, lo.z),
                v(hi.x, hi.y, lo.z),
                v(hi.x, hi.y, hi.z),
                v(hi.x, lo.y, hi.z),
            ],
            -Vec3::X,
        ),
        (
            "wall-north",
            wall_m,
            [
                v(lo.x, lo.y, lo.z),
                v(hi.x, lo.y, lo.z),
                v(hi.x, hi.y, lo.z),
                v(lo.x, hi.y, lo.z),
            ],
            Vec3::Z,
        ),
        (
            "wall-south",
            wall_m,
            [
                v(lo.x, lo.y, hi.z),
                v(hi.x, lo.y, hi.z),
                v(hi.x, hi.y, hi.z),
                v(lo.x, hi.y, hi.z),
            ],
            -Vec3::Z,
        ),
    ];
    for (name, m, [p0, p1, p2, p3], inward) in room {
        let mut g = Geometry::default();
        g.quad_facing(p0, p1, p2, p3, inward);
        b.mesh(name, &g.positions, Some(&g.normals), &g.indices, m);
    }

    // Six desks in a 3 × 2 grid, each with a chair and one to three boxes on top.
    let mut glass_placed = false;
    for row in 0..2 {
        for col in 0..3 {
            let k = row * 3 + col;
            let c = v(-3.0 + 3.0 * col as f32, 0.0, -0.8 + 2.6 * row as f32);
            let (hw, hd, top) = (0.7, 0.35, 0.75);
            add_box(
                &mut b,
                format!("desk-{k}-top"),
                c + v(-hw, top - 0.05, -hd),
                c + v(hw, top, hd),
                wood_m,
            );
            for (l, (sx, sz)) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
                .iter()
                .enumerate()
            {
                let p = c + v(sx * (hw - 0.06), 0.0, sz * (hd - 0.06));
                add_box(
                    &mut b,
                    format!("desk-{k}-leg-{l}"),
                    p - v(0.03, 0.0, 0.03),
                    p + v(0.03, top - 0.05, 0.03),
                    metal_m,
                );
            }
            // Chair on the +z side of the desk.
            let ch = c + v(rng.range_f32(-0.3, 0.3), 0.0, hd + 0.45);
            add_box(
                &mut b,
                format!("chair-{k}-seat"),
                ch + v(-0.22, 0.42, -0.22),
                ch + v(0.22, 0.47, 0.22),
                chair_m,
            );
            add_box(
                &mut b,
                format!("chair-{k}-back"),
                ch + v(-0.22, 0.47, 0.18),
                ch + v(0.22, 0.95, 0.22),
                chair_m,
            );
            for (l, (sx, sz)) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
                .iter()
                .enumerate()
            {
                let p = ch + v(sx * 0.19, 0.0, sz * 0.19);
                add_box(
                    &mut b,
                    format!("chair-{k}-leg-{l}"),
                    p - v(0.02, 0.0, 0.02),
                    p + v(0.02, 0.42, 0.02),
                    metal_m,
                );
            }
            // Boxes on the desk top, side by side along x.
            let n = 1 + rng.below(3);
            let mut x = -hw + 0.05;
            for i in 0..n {
                let w = rng.range_f32(0.15, 0.35);
                let h = rng.range_f32(0.08, 0.4);
                let d = rng.range_f32(0.15, 0.3);
                let z = rng.range_f32(-hd + 0.02, hd - 0.02 - d);
                let m = box_m[rng.below(box_m.len())];
                add_box(
                    &mut b,
                    format!("desk-{k}-box-{i}"),
                    c + v(x, top, z),
                    c + v(x + w, top + h, z + d),
                    m,
                );
                x += w + 0.05;
            }
            if !glass_placed && k == 1 {
                let g = Geometry::icosphere(c + v(0.45, top + 0.2, 0.0), 0.2, 3);
                b.mesh(
                    "glass-sphere",
                    &g.positions,
                    Some(&g.normals),
                    &g.indices,
                    glass_m,
                );
                glass_placed = true;
            }
        }
    }

    // Four shelving units against the north wall: two side panels, four boards, boxes.
    for s in 0..4 {
        let x0 = -4.6 + 2.35 * s as f32;
        let (w, depth, height) = (1.6, 0.4, 2.0);
        let z0 = lo.z + 0.02;
        add_box(
            &mut b,
            format!("shelf-{s}-side-0"),
            v(x0, 0.0, z0),
            v(x0 + 0.04, height, z0 + depth),
            shelf_m,
        );
        add_box(
            &mut b,
            format!("shelf-{s}-side-1"),
            v(x0 + w - 0.04, 0.0, z0),
            v(x0 + w, height, z0 + depth),
            shelf_m,
        );
        for level in 0..4 {
            let y = 0.1 + 0.6 * level as f32;
            add_box(
                &mut b,
                format!("shelf-{s}-board-{level}"),
                v(x0 + 0.04, y, z0),
                v(x0 + w - 0.04, y + 0.03, z0 + depth),
                shelf_m,
            );
            if level == 3 {
                continue; // the top board carries nothing
            }
            let n = 1 + rng.below(3);
            let mut x = x0 + 0.08;
            for i in 0..n {
                let bw = rng.range_f32(0.2, 0.4);
                let bh = rng.range_f32(0.15, 0.5);
                let bd = rng.range_f32(0.2, depth - 0.05);
                let m = box_m[rng.below(box_m.len())];
                add_box(
                    &mut b,
                    format!("shelf-{s}-box-{level}-{i}"),
                    v(x, y + 0.03, z0 + 0.02),
                    v(x + bw, y + 0.03 + bh, z0 + 0.02 + bd),
                    m,
                );
                x += bw + 0.05;
            }
        }
    }

    // A mirror on the east wall, a thin panel 1 cm off the wall.
    add_box(
        &mut b,
        "mirror".into(),
        v(hi.x - 0.03, 0.6, -1.2),
        v(hi.x - 0.01, 2.2, 1.2),
        mirror_m,
    );

    b.light(Light {
        position: v(-2.0, 2.8, 0.0),
        color: v(1.0, 0.97, 0.9),
        intensity: 1.0,
        attenuation: [1.0, 0.0, 0.0],
        radius: 0.0,
    });
    b.light(Light {
        position: v(2.5, 2.8, 1.5),
        color: v(0.9, 0.95, 1.0),
        intensity: 0.8,
        attenuation: [1.0, 0.0, 0.0],
        radius: 0.0,
    });
    b.camera(Camera {
        eye: v(-4.3, 2.2, 3.6),
        target: v(0.5, 0.7, -1.5),
        up: Vec3::Y,
        vfov_deg: 60.0,
        aspect: None,
    });
    b
}
