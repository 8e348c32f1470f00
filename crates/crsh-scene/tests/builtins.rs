//! The built-in scenes: valid, deterministic, and shaped as documented.

mod support;

use crsh_scene::{builtin, load, Scene};
use glam::Vec3;

fn same(a: &Scene, b: &Scene) {
    assert_eq!(a.positions, b.positions);
    assert_eq!(a.normals, b.normals);
    assert_eq!(a.indices, b.indices);
    assert_eq!(a.tri_material, b.tri_material);
    assert_eq!(a.tri_mesh, b.tri_mesh);
    assert_eq!(a.tri_spheres, b.tri_spheres);
    assert_eq!(a.meshes, b.meshes);
    assert_eq!(a.materials, b.materials);
    assert_eq!(a.lights, b.lights);
    assert_eq!(a.camera, b.camera);
}

#[test]
fn every_builtin_is_valid_and_deterministic() {
    for &name in builtin::NAMES {
        let (a, warnings) = builtin::build_with_warnings(name).unwrap();
        assert!(warnings.is_empty(), "{name}: {warnings:?}");
        assert_eq!(a.name, name);
        support::check_invariants(&a);
        assert_eq!(a.degenerate_triangles, 0);
        same(&a, &builtin::build(name).unwrap());
        same(&a, &load(name).unwrap());
    }
}

#[test]
fn cornell_mirrors_is_a_closed_mirror_box_around_an_object() {
    let s = builtin::build("cornell-mirrors").unwrap();
    assert_eq!(s.meshes.len(), 7, "six walls and the object");
    let inside = |p: Vec3| p.abs().max_element() < 1.0;
    let mut tints = Vec::new();
    for m in &s.meshes[..6] {
        let mat = s.material_of(m.first_tri as usize);
        assert!((0.6..=0.8).contains(&mat.reflectivity), "{}", m.name);
        assert!(!tints.contains(&mat.diffuse), "tints differ");
        tints.push(mat.diffuse);
        // Wall normals face the inside of the box.
        for t in m.first_tri..m.first_tri + m.tri_count {
            let [a, b, c] = s.triangle(t as usize);
            let n = (b - a).cross(c - a);
            assert!(n.dot(-(a + b + c) / 3.0) > 0.0, "{} faces outward", m.name);
            for &v in &s.indices[t as usize] {
                assert!(s.normals[v as usize].dot(n.normalize()) > 0.999);
            }
        }
    }
    // The six walls close the box [-1, 1]³: together they cover every face of the cube.
    let faces: Vec<Vec3> = s.meshes[..6].iter().map(|m| m.aabb.center()).collect();
    for axis in [Vec3::X, Vec3::Y, Vec3::Z, -Vec3::X, -Vec3::Y, -Vec3::Z] {
        assert!(
            faces.iter().any(|c| (*c - axis).length() < 1e-6),
            "no wall at {axis}"
        );
    }
    let obj = &s.meshes[6];
    assert!((200..=1000).contains(&obj.tri_count));
    assert!(s.material_of(obj.first_tri as usize).reflectivity == 0.0);
    assert_eq!(s.lights.len(), 1);
    assert!(inside(s.lights[0].position) && inside(s.camera.eye));
    // The camera looks at the object.
    let to_obj = (obj.sphere.center - s.camera.eye).normalize();
    let fwd = (s.camera.target - s.camera.eye).normalize();
    assert!(to_obj.dot(fwd) > 0.95);
}

#[test]
fn office_boxes_has_many_meshes_two_lights_and_every_ray_kind() {
    let s = builtin::build("office-boxes").unwrap();
    assert!((50..=200).contains(&s.meshes.len()), "{}", s.meshes.len());
    assert!((1000..=10_000).contains(&s.triangle_count()));
    assert_eq!(s.lights.len(), 2);
    let room = crsh_core::Aabb {
        min: crsh_scene::builtin::office_boxes::ROOM_MIN,
        max: crsh_scene::builtin::office_boxes::ROOM_MAX,
    };
    for l in &s.lights {
        assert!(room.contains(l.position));
    }
    assert!(room.contains(s.camera.eye));
    let used: Vec<&crsh_scene::Material> =
        (0..s.triangle_count()).map(|t| s.material_of(t)).collect();
    assert!(used.iter().any(|m| m.transparency > 0.0 && m.ior == 1.5));
    assert!(used
        .iter()
        .any(|m| m.reflectivity > 0.5 && m.transparency == 0.0));
    assert!(used
        .iter()
        .any(|m| m.specular.max_element() > 0.0 && m.reflectivity == 0.0));
    let diffuse_only = used
        .iter()
        .filter(|m| m.reflectivity == 0.0 && m.transparency == 0.0);
    assert!(diffuse_only.count() * 2 > used.len(), "mostly diffuse");
    // Meshes are separate objects: names are unique.
    let mut names: Vec<&str> = s.meshes.iter().map(|m| m.name.as_str()).collect();
    names.sort_unstable();
    names.dedup();
    assert_eq!(names.len(), s.meshes.len());
}
