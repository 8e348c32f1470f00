//! The real scenes of `../shared/scenes` (env `CRSH_SCENES`, else `<workspace>/../shared/scenes`):
//! every manifest loads with the triangle count its README gives. Skipped, with a printed
//! reason, when the directory is absent.

mod support;

use std::path::PathBuf;

use crsh_scene::{load_path, load_with_report, manifest};

fn scenes_dir() -> Option<PathBuf> {
    let dir = std::env::var_os("CRSH_SCENES")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes")
        });
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!(
            "SKIP: scenes directory {} not found (set CRSH_SCENES)",
            dir.display()
        );
        None
    }
}

fn check(rel: &str, triangles: usize) {
    let Some(dir) = scenes_dir() else { return };
    let path = dir.join(rel);
    if !path.is_file() {
        eprintln!("SKIP: {} not found", path.display());
        return;
    }
    let (s, report) = load_with_report(path.to_str().unwrap()).unwrap();
    assert_eq!(s.triangle_count(), triangles, "{rel}");
    assert!(!s.lights.is_empty());
    support::check_invariants(&s);
    eprintln!("{rel}: {} (warnings: {:?})", s.summary(), report.warnings);
}

#[test]
fn cornell_original() {
    check("cornell/cornell-original.toml", 36);
}

#[test]
fn cornell_mirror_has_its_mirror_box() {
    check("cornell/cornell-mirror.toml", 36);
    let Some(dir) = scenes_dir() else { return };
    let s = load_path(&dir.join("cornell/cornell-mirror.toml")).unwrap();
    let tall = s.materials.iter().find(|m| m.name == "tallBox").unwrap();
    assert!((tall.reflectivity - 0.95).abs() < 1e-6, "illum 5 → max(Ks)");
    let light = s.materials.iter().find(|m| m.name == "light").unwrap();
    assert!(light.is_emitter());
}

#[test]
fn cornell_sphere_overrides_apply() {
    check("cornell/cornell-sphere.toml", 2188);
    let Some(dir) = scenes_dir() else { return };
    let s = load_path(&dir.join("cornell/cornell-sphere.toml")).unwrap();
    let m = |n: &str| s.materials.iter().find(|m| m.name == n).unwrap().clone();
    assert_eq!(m("leftSphere").reflectivity, 0.95);
    assert_eq!(m("rightSphere").transparency, 0.95);
    assert_eq!(m("rightSphere").ior, 1.6);
    assert_eq!(m("floor").reflectivity, 0.0);
    assert!(s
        .tri_material
        .iter()
        .any(|&i| s.materials[i as usize].name == "leftSphere"));
}

#[test]
fn large_scenes_load_with_the_readme_counts() {
    for (rel, tris) in [
        ("sponza/sponza.toml", 262_205),
        ("dining-room/dining-room.toml", 269_538),
        ("bunny/bunny.toml", 69_451),
        ("dragon/dragon.toml", 47_794),
    ] {
        let t = std::time::Instant::now();
        check(rel, tris);
        eprintln!("{rel}: loaded and checked in {:?}", t.elapsed());
    }
}

#[test]
fn dining_room_chrome_and_gold_are_mirrors() {
    let Some(dir) = scenes_dir() else { return };
    let s = load_path(&dir.join("dining-room/dining-room.toml")).unwrap();
    for name in ["Chrome", "Gold"] {
        let m = s.materials.iter().find(|m| m.name == name).unwrap();
        assert_eq!(m.reflectivity, 1.0, "{name}");
    }
}

#[test]
fn list_finds_every_shared_manifest() {
    let Some(dir) = scenes_dir() else { return };
    let l = manifest::list(&dir).unwrap();
    let names: Vec<&str> = l.iter().map(|e| e.name.as_str()).collect();
    for n in [
        "bunny",
        "cornell-mirror",
        "cornell-original",
        "cornell-sphere",
        "dining-room",
        "dragon",
        "sponza",
    ] {
        assert!(names.contains(&n), "{n} missing from {names:?}");
    }
    assert!(l.iter().all(|e| e.problem.is_none()));
}
