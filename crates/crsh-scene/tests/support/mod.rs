//! Checks every valid scene must pass, shared by the integration tests.

use crsh_scene::Scene;

/// Structural invariants: mesh ranges tile the triangles, per-triangle arrays agree, every
/// sphere and box contains what it bounds, normals are unit, materials and ids valid.
pub fn check_invariants(s: &Scene) {
    let n = s.triangle_count();
    assert_eq!(s.tri_mesh.len(), n);
    assert_eq!(s.tri_material.len(), n);
    assert_eq!(s.tri_spheres.len(), n);
    assert_eq!(s.normals.len(), s.positions.len());
    let mut next = 0u32;
    for (k, m) in s.meshes.iter().enumerate() {
        assert_eq!(
            m.first_tri, next,
            "mesh {k} does not follow its predecessor"
        );
        assert!(m.tri_count > 0);
        next += m.tri_count;
        for t in m.first_tri..m.first_tri + m.tri_count {
            assert_eq!(s.tri_mesh[t as usize], k as u32);
            for p in s.triangle(t as usize) {
                assert!(m.sphere.contains(p, 0.0), "mesh {k} sphere misses {p}");
                assert!(m.aabb.contains(p) && s.bounds.contains(p));
            }
        }
    }
    assert_eq!(next as usize, n);
    for t in 0..n {
        let sp = s.tri_spheres[t];
        for p in s.triangle(t) {
            assert!(sp.center.as_dvec3().distance(p.as_dvec3()) <= sp.radius as f64);
        }
        assert!((s.tri_material[t] as usize) < s.materials.len());
    }
    for nrm in &s.normals {
        assert!((nrm.length() - 1.0).abs() < 1e-4, "normal {nrm}");
    }
    for m in &s.materials {
        m.validate().unwrap();
    }
    s.camera.validate().unwrap();
    let degenerate = (0..n).filter(|&t| s.is_degenerate(t)).count();
    assert_eq!(degenerate, s.degenerate_triangles);
}
