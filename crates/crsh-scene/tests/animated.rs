//! Animated scenes: the built-in `cornell-mirrors-animated`, manifests with instances and
//! motions, and the errors of bad ones.

mod support;

use std::path::{Path, PathBuf};

use crsh_scene::{builtin, load, load_animated, manifest::Manifest, Scene};

fn frame(anim: &crsh_scene::AnimatedScene, f: u32) -> Scene {
    let mut s = anim.scene().clone();
    anim.update(&mut s, f, true).unwrap();
    s
}

#[test]
fn cornell_mirrors_animated_moves_its_instances_and_nothing_else() {
    let (anim, report) = load_animated("cornell-mirrors-animated").unwrap();
    assert!(report.warnings.is_empty(), "{:?}", report.warnings);
    assert!(anim.is_animated());
    let names: Vec<&str> = anim.instances().iter().map(|i| i.name.as_str()).collect();
    assert_eq!(names, ["cube", "flag", "column"]);
    assert!(anim.instances()[1].deforms() && anim.instances()[2].deforms());
    assert!(!anim.instances()[0].deforms());
    let base = builtin::build("cornell-mirrors").unwrap();
    let f0 = anim.scene();
    assert_eq!(f0, &load("cornell-mirrors-animated").unwrap());
    assert_eq!(
        f0.triangle_count(),
        base.triangle_count() + anim.moving_triangles()
    );
    assert_eq!(f0.positions[..base.positions.len()], base.positions[..]);
    support::check_invariants(f0);
    let mut previous = f0.clone();
    for f in 1..16 {
        let s = frame(&anim, f);
        support::check_invariants(&s);
        // The walls and the icosphere stay; every instance moves between frames.
        assert_eq!(s.positions[..base.positions.len()], base.positions[..]);
        for inst in anim.instances() {
            let moved = inst
                .vertices
                .clone()
                .filter(|&v| s.positions[v] != previous.positions[v])
                .count();
            assert!(
                moved * 10 >= inst.vertices.len() * 9,
                "frame {f}: {} moved {moved} of {} vertices",
                inst.name,
                inst.vertices.len()
            );
        }
        previous = s;
    }
    // Updating in place from any frame gives the same arrays as from frame 0, and the sphere
    // pass can be skipped and done later.
    let mut s = frame(&anim, 9);
    anim.update(&mut s, 4, false).unwrap();
    anim.update(&mut s, 4, true).unwrap();
    assert_eq!(s, frame(&anim, 4));
}

#[test]
fn static_scenes_load_as_animations_that_never_move() {
    let (anim, _) = load_animated("office-boxes").unwrap();
    assert!(!anim.is_animated());
    assert_eq!(frame(&anim, 7), *anim.scene());
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("crsh-anim-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

const CAMERA: &str = "[camera]\neye = [0.0, 0.0, 5.0]\ntarget = [0.0, 0.0, 0.0]\nvfov_deg = 45.0\n";

#[test]
fn manifests_place_shapes_and_extend_other_manifests() {
    let d = temp_dir("ok");
    write(
        &d,
        "base.toml",
        &format!(
            "{CAMERA}\n[[instances]]\nshape = \"grid\"\nsubdivisions = 4\nscale = 2.0\n\
             material = {{ diffuse = [0.1, 0.2, 0.3] }}\n"
        ),
    );
    let top = write(
        &d,
        "top.toml",
        "extends = \"base.toml\"\n[animation]\nfps = 10.0\n\n[[instances]]\nname = \"spinner\"\n\
         shape = \"icosphere\"\nsubdivisions = 1\ntranslate = [0.0, 1.0, 0.0]\n\n\
         [[instances.motion]]\nkind = \"rotate\"\ndegrees_per_second = 90.0\n\n\
         [[instances.motion]]\nkind = \"scale\"\nfactor_per_second = 2.0\n",
    );
    let (anim, _) = load_animated(top.to_str().unwrap()).unwrap();
    assert_eq!(anim.fps(), 10.0);
    assert_eq!(anim.instances().len(), 2);
    assert_eq!(anim.scene().triangle_count(), 32 + 80);
    assert_eq!(anim.scene().materials[0].diffuse.x, 0.1);
    // The grid is placed (scaled by 2) and stays; the sphere doubles its size in a second.
    let s = anim.scene();
    assert!((s.meshes[0].aabb.size().x - 4.0).abs() < 1e-5);
    let r0 = s.meshes[1].sphere.radius;
    let s10 = frame(&anim, 10);
    assert!((s10.meshes[1].sphere.radius / r0 - 2.0).abs() < 1e-4);
    support::check_invariants(&s10);
}

#[test]
fn bad_manifests_are_errors_naming_the_problem() {
    let d = temp_dir("bad");
    let cases: [(&str, String, &str); 8] = [
        (
            "kind.toml",
            format!(
                "{CAMERA}[[instances]]\nshape = \"box\"\n[[instances.motion]]\nkind = \"wobble\"\n"
            ),
            "wobble",
        ),
        (
            "both.toml",
            format!("{CAMERA}[[instances]]\nshape = \"box\"\nmesh = \"x.obj\"\n"),
            "exactly one of mesh and shape",
        ),
        (
            "nan.toml",
            format!("{CAMERA}[[instances]]\nshape = \"box\"\ntranslate = [nan, 0.0, 0.0]\n"),
            "translate",
        ),
        (
            "subdiv.toml",
            format!("{CAMERA}[[instances]]\nshape = \"grid\"\nsubdivisions = 1000000\n"),
            "subdivisions",
        ),
        (
            "cycle.toml",
            "extends = \"cycle.toml\"\n".to_string(),
            "levels",
        ),
        (
            "missing.toml",
            "extends = \"nowhere.toml\"\n".to_string(),
            "nowhere.toml",
        ),
        (
            "nocamera.toml",
            "extends = \"office-boxes\"\n[camera]\n".to_string(),
            "missing field",
        ),
        (
            "wave.toml",
            format!(
                "{CAMERA}[[instances]]\nshape = \"grid\"\n[[instances.motion]]\nkind = \"wave\"\n\
                 amplitude = 1.0\nwavelength = -1.0\nspeed = 1.0\n"
            ),
            "wavelength",
        ),
    ];
    for (name, text, what) in cases {
        let p = write(&d, name, &text);
        let e = load_animated(p.to_str().unwrap()).unwrap_err().to_string();
        assert!(e.contains(what), "{name}: {e}");
    }
    // An empty manifest names what it needs.
    let e = Manifest::parse("", Path::new("empty.toml"))
        .map(|m| crsh_scene::manifest::build_animated(&m, Path::new("empty.toml")))
        .unwrap()
        .unwrap_err()
        .to_string();
    assert!(e.contains("nothing to load"), "{e}");
}

/// The repository's large animated scene, when `../shared/scenes` is beside the repository.
#[test]
fn sponza_animated_loads_when_the_shared_scenes_are_there() {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/sponza-animated.toml");
    let sponza =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes/sponza/sponza.obj");
    if !sponza.exists() {
        println!(
            "SKIP: {} not found (the shared scenes are not beside the repository)",
            sponza.display()
        );
        return;
    }
    let (anim, _) = load_animated(manifest.to_str().unwrap()).unwrap();
    assert!(anim.scene().triangle_count() > 370_000);
    assert_eq!(anim.moving_triangles(), 69_451 + 47_794);
    let s = frame(&anim, 3);
    support::check_invariants(&s);
}
