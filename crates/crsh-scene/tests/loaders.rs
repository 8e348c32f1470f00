//! Loader behaviour on small fixture files written at test time: every error names its file
//! and line (or mesh), MTL mapping, overrides, normals, degenerate triangles, bare OBJ framing.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use crsh_scene::{load, load_path, load_with_report, manifest, SceneError};
use glam::Vec3;

/// A fresh directory under the system temp dir, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> TempDir {
        static N: AtomicUsize = AtomicUsize::new(0);
        let p = std::env::temp_dir().join(format!(
            "crsh-scene-{}-{}-{tag}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&p).unwrap();
        TempDir(p)
    }

    fn write(&self, name: &str, text: &str) -> PathBuf {
        let p = self.0.join(name);
        if let Some(parent) = p.parent() {
            std::fs::create_dir_all(parent).unwrap();
        }
        std::fs::write(&p, text).unwrap();
        p
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

const QUAD_OBJ: &str = "mtllib m.mtl
o quad
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
usemtl red
f 1 2 3 4
o tri
v 0 0 1
v 1 0 1
v 0 1 1
usemtl glass
f 5 6 7
";

const MTL: &str = "newmtl red
Kd 0.8 0.1 0.1
Ks 0.2 0.2 0.2
Ns 32
illum 2

newmtl glass
Ks 0.1 0.1 0.1
Ni 1.5
Tf 0.9 0.9 0.9

newmtl chrome
Kd 0 0 0
Ks 0.9 0.8 0.7
illum 3

newmtl veil
Kd 0.5 0.5 0.5
d 0.25

newmtl lamp
Ke 5 4 3

newmtl lens
illum 7
Ni 1.33
";

const MANIFEST: &str = "name = \"fixture\"
mesh = \"q.obj\"

[camera]
eye = [0.5, 0.5, 4.0]
target = [0.5, 0.5, 0.0]
up = [0.0, 1.0, 0.0]
vfov_deg = 40.0

[[lights]]
position = [0.0, 3.0, 3.0]
color = [1.0, 1.0, 1.0]
intensity = 1.0
attenuation = [1.0, 0.0, 0.0]
";

fn err_text(r: Result<impl std::fmt::Debug, SceneError>) -> String {
    r.expect_err("expected an error").to_string()
}

#[test]
fn manifest_loads_with_meshes_materials_and_normals() {
    let d = TempDir::new("ok");
    d.write("q.obj", QUAD_OBJ);
    d.write("m.mtl", MTL);
    let m = d.write("s.toml", MANIFEST);
    let (s, report) = load_with_report(m.to_str().unwrap()).unwrap();
    assert!(report.warnings.is_empty(), "{:?}", report.warnings);
    assert_eq!(s.name, "fixture");
    assert_eq!(s.triangle_count(), 3);
    assert_eq!(s.meshes.len(), 2);
    assert_eq!((s.meshes[0].first_tri, s.meshes[0].tri_count), (0, 2));
    assert_eq!((s.meshes[1].first_tri, s.meshes[1].tri_count), (2, 1));
    assert_eq!(s.tri_mesh, vec![0, 0, 1]);
    assert_eq!(s.material_of(0).name, "red");
    assert_eq!(s.material_of(2).name, "glass");
    assert_eq!(s.lights.len(), 1);
    assert_eq!(s.camera.vfov_deg, 40.0);
    // No vn in the file: normals computed, +z for the counter-clockwise quad.
    for n in &s.normals {
        assert!((n.length() - 1.0).abs() < 1e-6 && n.z > 0.999, "{n}");
    }
    // Minimal mesh sphere of the unit square: centre (0.5, 0.5, 0), radius √2 / 2.
    let sp = s.meshes[0].sphere;
    assert!(sp.center.distance(Vec3::new(0.5, 0.5, 0.0)) < 1e-6);
    assert!((sp.radius - 0.5f32.sqrt()).abs() < 1e-6);
    assert_eq!(s.meshes[0].aabb.max, Vec3::new(1.0, 1.0, 0.0));
    assert_eq!(s.bounds.max, Vec3::new(1.0, 1.0, 1.0));
    // Per-triangle minimal spheres: right triangles → hypotenuse midpoint.
    assert!(s.tri_spheres[2].center.distance(Vec3::new(0.5, 0.5, 1.0)) < 1e-6);
    assert_eq!(s.degenerate_triangles, 0);
}

#[test]
fn mtl_mapping_follows_the_readme() {
    let d = TempDir::new("mtl");
    let obj = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\n\
               usemtl red\nf 1 2 3\nusemtl glass\nf 1 2 3\nusemtl chrome\nf 1 2 3\n\
               usemtl veil\nf 1 2 3\nusemtl lamp\nf 1 2 3\nusemtl lens\nf 1 2 3\n";
    let p = d.write("m.obj", obj);
    d.write("m.mtl", MTL);
    let s = load_path(&p).unwrap();
    let mat = |name: &str| s.materials.iter().find(|m| m.name == name).unwrap().clone();
    let red = mat("red");
    assert_eq!(red.diffuse, Vec3::new(0.8, 0.1, 0.1));
    assert_eq!(red.specular, Vec3::splat(0.2));
    assert_eq!(red.shininess, 32.0);
    assert_eq!((red.reflectivity, red.transparency), (0.0, 0.0));
    let glass = mat("glass");
    assert!(
        (glass.transparency - 0.9).abs() < 1e-6,
        "Tf below 1 → max(Tf)"
    );
    assert_eq!(glass.ior, 1.5);
    assert_eq!(glass.diffuse, Vec3::ZERO, "no Kd but Ks/Tf given → black");
    let chrome = mat("chrome");
    assert!(
        (chrome.reflectivity - 0.9).abs() < 1e-6,
        "illum 3 → max(Ks)"
    );
    let veil = mat("veil");
    assert!((veil.transparency - 0.75).abs() < 1e-6, "d → 1 - d");
    let lamp = mat("lamp");
    assert_eq!(lamp.emission, Vec3::new(5.0, 4.0, 3.0));
    assert!(lamp.is_emitter() && lamp.reflectivity == 0.0);
    let lens = mat("lens");
    assert_eq!(
        (lens.transparency, lens.ior),
        (1.0, 1.33),
        "illum 7 → transparent"
    );
    // Each usemtl change starts a mesh: six meshes of one triangle.
    assert_eq!(s.meshes.len(), 6);
}

#[test]
fn material_overrides_apply_and_unknown_names_are_errors() {
    let d = TempDir::new("ovr");
    d.write("q.obj", QUAD_OBJ);
    d.write("m.mtl", MTL);
    let m = d.write(
        "s.toml",
        &format!("{MANIFEST}\n[materials.red]\nreflectivity = 0.5\ndiffuse = [0.1, 0.2, 0.3]\n"),
    );
    let s = load_path(&m).unwrap();
    let red = s.material_of(0);
    assert_eq!(red.reflectivity, 0.5);
    assert_eq!(red.diffuse, Vec3::new(0.1, 0.2, 0.3));
    assert_eq!(
        red.specular,
        Vec3::splat(0.2),
        "untouched fields keep the MTL value"
    );

    let m = d.write(
        "bad.toml",
        &format!("{MANIFEST}\n[materials.blue]\nreflectivity = 0.5\n"),
    );
    let e = err_text(load_path(&m));
    assert!(
        e.contains("bad.toml") && e.contains("'blue'") && e.contains("red"),
        "{e}"
    );

    let m = d.write(
        "range.toml",
        &format!("{MANIFEST}\n[materials.red]\ntransparency = 1.5\n"),
    );
    let e = err_text(load_path(&m));
    assert!(
        e.contains("range.toml") && e.contains("red") && e.contains("transparency"),
        "{e}"
    );
}

#[test]
fn unknown_manifest_keys_are_rejected_with_the_line() {
    let d = TempDir::new("key");
    d.write("q.obj", QUAD_OBJ);
    d.write("m.mtl", MTL);
    let text = MANIFEST.replace("vfov_deg = 40.0", "vfov_deg = 40.0\nfocal = 3.0");
    let m = d.write("s.toml", &text);
    let e = err_text(load_path(&m));
    assert!(e.contains("s.toml:9") && e.contains("focal"), "{e}");
    let m = d.write("t.toml", &format!("colour = 1\n{MANIFEST}"));
    let e = err_text(load_path(&m));
    assert!(e.contains("t.toml:1") && e.contains("colour"), "{e}");
    // A missing required key is an error too.
    let m = d.write("u.toml", "mesh = \"q.obj\"\n");
    let e = err_text(load_path(&m));
    assert!(e.contains("u.toml") && e.contains("camera"), "{e}");
}

#[test]
fn light_radius_defaults_to_zero_and_is_validated() {
    let d = TempDir::new("radius");
    d.write("q.obj", QUAD_OBJ);
    d.write("m.mtl", MTL);
    let m = d.write("s.toml", MANIFEST);
    assert_eq!(load_path(&m).unwrap().lights[0].radius, 0.0);
    let text = MANIFEST.replace("intensity = 1.0", "intensity = 1.0\nradius = 0.25");
    let m = d.write("r.toml", &text);
    assert_eq!(load_path(&m).unwrap().lights[0].radius, 0.25);
    for bad in ["-0.5", "nan", "inf"] {
        let text = MANIFEST.replace(
            "intensity = 1.0",
            &format!("intensity = 1.0\nradius = {bad}"),
        );
        let m = d.write("bad.toml", &text);
        let e = err_text(load_path(&m));
        assert!(e.contains("bad.toml") && e.contains("radius"), "{bad}: {e}");
    }
}

#[test]
fn missing_files_are_named() {
    let d = TempDir::new("missing");
    let e = err_text(load_path(&d.0.join("nope.obj")));
    assert!(e.contains("nope.obj"), "{e}");
    let e = err_text(load_path(&d.0.join("nope.toml")));
    assert!(e.contains("nope.toml"), "{e}");
    let m = d.write("s.toml", MANIFEST);
    let e = err_text(load_path(&m));
    assert!(e.contains("q.obj"), "manifest naming a missing mesh: {e}");
    let e = err_text(load("no-such-scene"));
    assert!(
        e.contains("cornell-mirrors") && e.contains(".toml") && e.contains(".obj"),
        "{e}"
    );
    let p = d.write("x.ply", "ply\n");
    let e = err_text(load(p.to_str().unwrap()));
    assert!(e.contains("x.ply") && e.contains(".obj"), "{e}");
}

#[test]
fn a_missing_mtl_warns_and_a_bad_one_is_an_error() {
    let d = TempDir::new("nomtl");
    let p = d.write("q.obj", QUAD_OBJ);
    let (s, report) = load_with_report(p.to_str().unwrap()).unwrap();
    assert_eq!(s.triangle_count(), 3);
    assert_eq!(s.materials.len(), 1);
    assert_eq!(s.materials[0].name, "default");
    assert!(
        report
            .warnings
            .iter()
            .any(|w| w.contains("m.mtl") && w.contains("not found")),
        "{:?}",
        report.warnings
    );
    // A garbled line used to replace the whole file by the default material.
    d.write("m.mtl", "newmtl red\nKd 0.5 zz 0.5\n");
    let e = err_text(load_with_report(p.to_str().unwrap()));
    assert!(e.contains("m.mtl:2: Kd: 'zz' is not a number"), "{e}");
    // A short colour line used to panic inside tobj.
    d.write("m.mtl", "newmtl red\nNs 10\nKd 0.5 0.5\n");
    let e = err_text(load_with_report(p.to_str().unwrap()));
    assert!(
        e.contains("m.mtl:3: Kd: needs three numbers (r g b), found 2"),
        "{e}"
    );
    // Through a manifest too.
    d.write("m.mtl", "newmtl red\nd -1\n");
    d.write("q2.obj", QUAD_OBJ);
    let m = d.write("s.toml", &MANIFEST.replace("q.obj", "q2.obj"));
    let e = err_text(load_with_report(m.to_str().unwrap()));
    assert!(e.contains("m.mtl:2: d: -1 is outside its meaning"), "{e}");
}

fn obj_error(tag: &str, text: &str) -> String {
    let d = TempDir::new(tag);
    let p = d.write("bad.obj", text);
    err_text(load_path(&p))
}

#[test]
fn malformed_obj_names_the_line() {
    let e = obj_error("malformed", "v 0 0 0\nv 1 0 0\nv 0 one 0\nf 1 2 3\n");
    assert!(e.contains("bad.obj:3") && e.contains("'one'"), "{e}");
    let e = obj_error("shortv", "v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n");
    assert!(e.contains("bad.obj:2"), "{e}");
    let e = obj_error("face", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n");
    assert!(e.contains("bad.obj:4") && e.contains("'x'"), "{e}");
}

#[test]
fn out_of_range_indices_name_the_line() {
    let e = obj_error(
        "range",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\n# comment\nf 1 2 3\nf 1 2 9\n",
    );
    assert!(e.contains("bad.obj:6") && e.contains("9"), "{e}");
    let e = obj_error("neg", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n");
    assert!(e.contains("bad.obj:4") && e.contains("-4"), "{e}");
    let e = obj_error("zero", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n");
    assert!(e.contains("bad.obj:4") && e.contains("index 0"), "{e}");
}

#[test]
fn non_finite_coordinates_name_the_line() {
    for (tag, bad) in [("nan", "nan"), ("inf", "inf"), ("ninf", "-inf")] {
        let e = obj_error(tag, &format!("v 0 0 0\nv 1 0 0\nv 0 {bad} 0\nf 1 2 3\n"));
        assert!(
            e.contains("bad.obj:3") && e.contains("non-finite"),
            "{tag}: {e}"
        );
    }
    // Overflow to infinity while parsing counts as well.
    let e = obj_error("huge", "v 0 0 0\nv 1e39 0 0\nv 0 1 0\nf 1 2 3\n");
    assert!(e.contains("bad.obj:2") && e.contains("non-finite"), "{e}");
}

#[test]
fn dropped_faces_and_bad_attribute_indices_name_the_line() {
    const TRI: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    for (tag, bad, want) in [
        ("f2", "f 1 2", "face has 2 vertices (3 or more needed)"),
        ("f1", "f 3", "face has 1 vertices (3 or more needed)"),
        ("f0", "f", "face has 0 vertices (3 or more needed)"),
        (
            "vt",
            "f 1/9 2/9 3/9",
            "texture coordinate index 9 is out of range (0 in the file)",
        ),
        ("vn0", "f 1//0 2//0 3//0", "normal index 0 is invalid"),
        ("vnx", "f 1//x 2 3", "normal index 'x' is not an integer"),
        (
            "slashes",
            "f 1/// 2 3",
            "face corner '1///' has more than three",
        ),
        ("l1", "l 1", "line element has 1 vertices"),
        ("p9", "p 9", "vertex index 9 is out of range"),
        ("mtllib", "mtllib", "mtllib without a file name"),
    ] {
        // The bad face sits among valid ones.
        let e = obj_error(tag, &format!("{TRI}f 1 2 3\n{bad}\nf 3 2 1\n"));
        assert!(e.contains("bad.obj:5: ") && e.contains(want), "{tag}: {e}");
    }
    // A file whose only faces are degenerate names the first of them, not "no meshes".
    let e = obj_error("onlyshort", &format!("{TRI}f 1 2\nf 2 3\n"));
    assert!(e.contains("bad.obj:4: face has 2 vertices"), "{e}");
}

#[test]
fn huge_coordinates_are_not_called_non_finite() {
    let e = obj_error("e19", "v 0 0 0\nv 1e19 0 0\nv 0 1 0\nf 1 2 3\n");
    assert!(
        e.contains("bad.obj:2: vertex 2 has a coordinate beyond the supported magnitude 1e15"),
        "{e}"
    );
    // The weight divides: 1 / 1e-30 is huge too.
    let e = obj_error("w", "v 0 0 0\nv 1 0 0 1e-30\nv 0 1 0\nf 1 2 3\n");
    assert!(
        e.contains("bad.obj:2: ") && e.contains("supported magnitude"),
        "{e}"
    );
    // Right at the limit loads.
    let d = TempDir::new("e15");
    let p = d.write("ok.obj", "v 0 0 0\nv 1e15 0 0\nv 0 -1e15 0\nf 1 2 3\n");
    assert_eq!(load_path(&p).unwrap().triangle_count(), 1);
}

#[test]
fn lines_and_points_are_ignored_with_a_warning() {
    let d = TempDir::new("lp");
    let p = d.write(
        "lp.obj",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2 3\np 1\nf 1 2 3\n",
    );
    let (s, report) = load_with_report(p.to_str().unwrap()).unwrap();
    assert_eq!(s.triangle_count(), 1);
    assert!(
        report.warnings.iter().any(
            |w| w.contains("lp.obj") && w.contains("2 line (l) and point (p) elements ignored")
        ),
        "{:?}",
        report.warnings
    );
}

/// Found by `fuzz_inputs`: each loaded, then broke an invariant of the scene.
#[test]
fn fuzz_findings_stay_fixed() {
    let d = TempDir::new("fuzzfound");
    // A subnormal coordinate, degenerate once the instance halves it: the count follows.
    d.write(
        "t.obj",
        "v 0 0 1\nv 1e-45 0 1\nv 0 1 1\nf 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 4 5 6\n",
    );
    let head = "[camera]\neye = [0, 0, 5]\ntarget = [0, 0, 0]\nvfov_deg = 40\n\
                [[lights]]\nposition = [0, 2, 2]\n[[instances]]\nmesh = \"t.obj\"\n";
    let m = d.write("a.toml", &format!("{head}scale = 0.5\n"));
    let s = load_path(&m).unwrap();
    let counted = (0..s.triangle_count())
        .filter(|&t| s.is_degenerate(t))
        .count();
    assert_eq!((counted, s.degenerate_triangles), (1, 1));
    // A scale that collapses the normals' transform.
    let m = d.write("b.toml", &format!("{head}scale = 1e-45\n"));
    let e = err_text(load_path(&m));
    assert!(
        e.contains("b.toml: instance #0") && e.contains("must lie in 1e-12..=1e12"),
        "{e}"
    );
    // A subnormal fps put frame 1 at infinity.
    let m = d.write("c.toml", &format!("{head}[animation]\nfps = 1e-45\n"));
    let e = err_text(load_path(&m));
    assert!(
        e.contains("c.toml: [animation]: fps 1e-45 is outside 0.001..=1000000"),
        "{e}"
    );
    // A huge supplied normal was normalized to zero.
    let p = d.write(
        "n.obj",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn -1e30 0 1\nvn 0 0 1e-40\nf 1//1 2//2 3//2\n",
    );
    let s = load_path(&p).unwrap();
    assert!(
        (s.normals[0] - Vec3::new(-1.0, 0.0, 1e-30)).length() < 1e-6,
        "{}",
        s.normals[0]
    );
    assert_eq!(s.normals[1], Vec3::Z);
    // An mtllib naming a directory.
    std::fs::create_dir_all(d.0.join("sub")).unwrap();
    let p = d.write("m.obj", "mtllib sub\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let e = err_text(load_path(&p));
    assert!(e.contains("m.obj: mtllib ") && e.contains("sub: "), "{e}");
}

#[test]
fn empty_scenes_are_errors() {
    let e = obj_error("empty", "# nothing here\n");
    assert!(e.contains("bad.obj") && e.contains("empty"), "{e}");
    let e = obj_error("pointsonly", "v 0 0 0\nv 1 0 0\nl 1 2\n");
    assert!(e.contains("bad.obj") && e.contains("empty"), "{e}");
}

#[test]
fn absurd_sizes_are_rejected_before_loading() {
    // One polygon line claiming 70 M corners: counted, not parsed.
    let d = TempDir::new("absurd");
    let mut text = String::from("v 0 0 0\nv 1 0 0\nv 0 1 0\nf");
    text.reserve(70_000_000 * 2);
    for _ in 0..70_000_000 / 4 {
        text.push_str(" 1 2 3 1");
    }
    text.push('\n');
    let p = d.write("big.obj", &text);
    drop(text);
    let e = err_text(load_path(&p));
    assert!(
        e.contains("big.obj") && e.contains("exceed the limit"),
        "{e}"
    );
}

#[test]
fn crlf_lines_and_a_byte_order_mark_are_accepted() {
    let d = TempDir::new("crlf");
    let p = d.write(
        "c.obj",
        "\u{feff}v 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nf 1 2 3\r\n",
    );
    let s = load_path(&p).unwrap();
    assert_eq!(s.triangle_count(), 1);
    assert_eq!(s.positions.len(), 3);
}

#[test]
fn degenerate_triangles_load_and_are_counted() {
    let d = TempDir::new("degen");
    let p = d.write(
        "d.obj",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\nf 1 1 3\n",
    );
    let (s, report) = load_with_report(p.to_str().unwrap()).unwrap();
    assert_eq!(s.triangle_count(), 3);
    assert_eq!(s.degenerate_triangles, 2);
    assert!(!s.is_degenerate(0) && s.is_degenerate(1) && s.is_degenerate(2));
    assert!(s.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-6));
    // The collinear vertex 4 touches only the degenerate triangle: its normal is invented.
    assert!(
        report.warnings.iter().any(|w| w.contains("zero-area")),
        "{:?}",
        report.warnings
    );
}

#[test]
fn supplied_normals_are_kept_and_bad_ones_replaced() {
    let d = TempDir::new("normals");
    let p = d.write(
        "n.obj",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 2\nvn nan 0 1\nvn 0 0 0\nf 1//1 2//2 3//3\n",
    );
    let s = load_path(&p).unwrap();
    for n in &s.normals {
        assert!((*n - Vec3::Z).length() < 1e-6, "{n}");
    }
    // Area weighting: a vertex shared by a large +z triangle and a small +x one leans to +z.
    let p = d.write(
        "w.obj",
        "v 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 -1\nv 0 1 0\nf 1 2 3\nf 1 4 5\n",
    );
    let s = load_path(&p).unwrap();
    let n0 = s.normals[0];
    let expect = (Vec3::Z * 100.0 + Vec3::X * 1.0).normalize();
    assert!((n0 - expect).length() < 1e-5, "{n0} vs {expect}");
}

#[test]
fn bare_obj_is_framed_with_a_light_above_the_camera() {
    let d = TempDir::new("bare");
    let p = d.write(
        "b.obj",
        "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3 4\n",
    );
    let s = load_path(&p).unwrap();
    assert_eq!(s.name, "b");
    let c = &s.camera;
    assert_eq!(c.target, Vec3::ZERO);
    assert_eq!(c.vfov_deg, 45.0);
    let r = 2f32.sqrt();
    let d_expect = r / (22.5f32).to_radians().sin();
    assert!(
        (c.eye - Vec3::new(0.0, 0.0, d_expect)).length() < 1e-4,
        "{}",
        c.eye
    );
    assert_eq!(s.lights.len(), 1);
    assert!(s.lights[0].position.y > c.eye.y);
    assert_eq!(s.lights[0].color, Vec3::ONE);
}

#[test]
fn list_finds_manifests_one_level_deep_sorted() {
    let d = TempDir::new("list");
    d.write("b/two.toml", &MANIFEST.replace("fixture", "second"));
    d.write("a/one.toml", MANIFEST);
    d.write("top.toml", "mesh = 3\n");
    d.write("a/deeper/three.toml", MANIFEST);
    d.write("a/readme.md", "not a manifest");
    let l = manifest::list(&d.0).unwrap();
    let names: Vec<&str> = l.iter().map(|e| e.name.as_str()).collect();
    assert_eq!(names, ["fixture", "second", "top"]);
    assert!(l[0].path.ends_with(Path::new("a/one.toml")));
    assert!(l[0].problem.is_none() && l[2].problem.is_some());
    let e = err_text(manifest::list(&d.0.join("absent")));
    assert!(e.contains("absent"), "{e}");
}
