//! OBJ, MTL and manifest text (issue 18): each row is one bad input, rendered through
//! `crsh render`, which must exit 1 with a single `error:` line naming the file and line
//! (where there is one) and what is wrong, and leave every file as it was.

use crate::harness::Case;

/// A lit triangle with a material from `m.mtl`.
const OBJ: &str = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl red\nf 1 2 3\n";

/// The material `OBJ` uses.
const MTL: &str = "newmtl red\nKd 0.8 0.1 0.1\n";

/// A manifest for `s.obj`; `{camera}` and `{light}` are replaced by the rows' text.
const MANIFEST: &str = "mesh = \"s.obj\"\n\n[camera]\n{camera}\n\n[[lights]]\n{light}\n";
const CAMERA: &str = "eye = [0.3, 0.3, 3.0]\ntarget = [0.3, 0.3, 0.0]\nvfov_deg = 40.0";
const LIGHT: &str = "position = [0.0, 2.0, 2.0]";

/// `crsh render` of `scene` in a case holding `files`, tiny and fast.
fn render_fails(name: &str, files: &[(&str, &[u8])], scene: &str, mentions: &[&str]) -> String {
    let c = Case::new("scene-files", name);
    for (file, text) in files {
        c.file(file, text);
    }
    let args = [
        "render", "--scene", scene, "--width", "16", "--depth", "0", "--out", "o.png",
    ];
    c.expect_error(&args, 1, mentions)
}

/// A bare OBJ (with the good MTL) that must fail.
fn obj_fails(name: &str, obj: &str, mentions: &[&str]) -> String {
    render_fails(
        name,
        &[("s.obj", obj.as_bytes()), ("m.mtl", MTL.as_bytes())],
        "s.obj",
        mentions,
    )
}

/// The good OBJ with an MTL that must fail.
fn mtl_fails(name: &str, mtl: &str, mentions: &[&str]) -> String {
    render_fails(
        name,
        &[("s.obj", OBJ.as_bytes()), ("m.mtl", mtl.as_bytes())],
        "s.obj",
        mentions,
    )
}

/// The good OBJ and MTL under a manifest with this camera and light that must fail.
fn manifest_fails(name: &str, camera: &str, light: &str, mentions: &[&str]) -> String {
    let manifest = MANIFEST
        .replace("{camera}", camera)
        .replace("{light}", light);
    render_fails(
        name,
        &[
            ("s.obj", OBJ.as_bytes()),
            ("m.mtl", MTL.as_bytes()),
            ("s.toml", manifest.as_bytes()),
        ],
        "s.toml",
        mentions,
    )
}

#[test]
fn the_good_files_render() {
    let c = Case::new("scene-files", "good");
    let manifest = MANIFEST
        .replace("{camera}", CAMERA)
        .replace("{light}", LIGHT);
    c.file("s.obj", OBJ)
        .file("m.mtl", MTL)
        .file("s.toml", manifest);
    for (scene, out) in [("s.obj", "obj.png"), ("s.toml", "toml.png")] {
        c.expect_ok(&[
            "render", "--scene", scene, "--width", "16", "--depth", "0", "--out", out,
        ]);
    }
}

/// Issue 18 defect 1: these panicked inside `tobj` (exit 101).
#[test]
fn short_mtl_colours_name_the_line() {
    for (name, line, key, found) in [
        ("kd2", "Kd 0.5 0.5", "Kd", 2),
        ("kd1", "Kd 0.5", "Kd", 1),
        ("kd0", "Kd", "Kd", 0),
        ("ks2", "Ks 1 1", "Ks", 2),
        ("ka1", "Ka 1", "Ka", 1),
        ("ke2", "Ke 1 1", "Ke", 2),
    ] {
        let e = mtl_fails(
            name,
            &format!("newmtl red\nNs 10\n{line}\n"),
            &["m.mtl:3: ", &format!("{key}: needs three numbers")],
        );
        assert!(e.contains(&format!("found {found}")), "{e}");
    }
}

/// Issue 18 defect 4 (MTL): values outside their meaning were accepted, or a garbled line
/// silently replaced the whole file by the default material.
#[test]
fn mtl_values_outside_their_meaning_name_the_line() {
    for (name, line, mention) in [
        (
            "d-neg",
            "d -1",
            "d: -1 is outside its meaning (must be in [0, 1])",
        ),
        ("d-nan", "d nan", "d: NaN is not a finite number"),
        ("tf-nan", "Tf nan", "Tf: NaN is not a finite number"),
        ("tr-nan", "Tr nan", "Tr: NaN is not a finite number"),
        (
            "kd4",
            "Kd 1 1 1 1",
            "Kd: needs three numbers (r g b), found 4",
        ),
        (
            "kd-big",
            "Kd 1 2 1",
            "Kd: 2 is outside its meaning (must be in [0, 1])",
        ),
        ("ni-nan", "Ni nan", "Ni: NaN is not a finite number"),
        ("ni-zero", "Ni 0", "Ni: 0 must be > 0"),
        ("ni-neg", "Ni -1.5", "Ni: -1.5 must be > 0"),
        ("kd-abc", "Kd a b c", "Kd: 'a' is not a number"),
        (
            "illum-x",
            "illum x",
            "illum: 'x' is not an illumination model",
        ),
        ("map-empty", "map_Kd", "map_Kd: a file name is required"),
    ] {
        mtl_fails(
            name,
            &format!("newmtl red\n{line}\n"),
            &["m.mtl:2: ", mention],
        );
    }
    // Before any newmtl, tobj dropped the value.
    mtl_fails(
        "before-newmtl",
        "Kd 0.5 0.5 0.5\nnewmtl red\n",
        &["m.mtl:1: Kd: comes before the first newmtl"],
    );
    // A binary MTL.
    let mut binary = b"newmtl red\n".to_vec();
    binary.extend((0..=255u8).rev());
    render_fails(
        "mtl-binary",
        &[("s.obj", OBJ.as_bytes()), ("m.mtl", &binary)],
        "s.obj",
        &["m.mtl:2: line is not valid UTF-8"],
    );
}

/// Keys crsh does not use (textures, `Pe`, ...) keep working, emission may exceed 1, and a
/// missing MTL only warns.
#[test]
fn unknown_mtl_keys_and_a_missing_mtl_still_load() {
    let c = Case::new("scene-files", "mtl-extras");
    c.file("s.obj", OBJ).file(
        "m.mtl",
        "# comment\r\nnewmtl red\r\n  Ka 0.6 0.1 0.1 # red\r\nKd 0.8 0.1 0.1\r\nKe 17 12 4\r\n\
         Pe 10\r\nmap_Kd red.png\r\nbump -bm 0.5 b.png\r\nrefl -type sphere r.png\r\n\
         Tf 0.9 0.9 0.9\r\nillum 7\r\n",
    );
    let args = [
        "render", "--scene", "s.obj", "--width", "16", "--depth", "0", "--out", "o.png",
    ];
    c.expect_ok(&args);
    std::fs::remove_file(c.path("m.mtl")).unwrap();
    std::fs::remove_file(c.path("o.png")).unwrap();
    let o = c.expect_ok(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("m.mtl") && err.contains("not found"), "{err}");
}

/// Issue 18 defect 4 (OBJ): faces of one or two vertices among valid ones vanished, bad
/// texture and normal indices were accepted, a file of only such faces said "no meshes".
#[test]
fn dropped_faces_and_bad_attribute_indices_name_the_line() {
    const HEAD: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1 2 3\n";
    for (name, line, mention) in [
        ("face2", "f 1 2", "face has 2 vertices (3 or more needed)"),
        ("face1", "f 3", "face has 1 vertices (3 or more needed)"),
        (
            "vt-range",
            "f 1/9 2/9 3/9",
            "texture coordinate index 9 is out of range (0 in the file)",
        ),
        (
            "vn-zero",
            "f 1//0 2//0 3//0",
            "normal index 0 is invalid (OBJ indices start at 1)",
        ),
        (
            "vn-range",
            "f 1//2 2//1 3//1",
            "normal index 2 is out of range (1 in the file)",
        ),
        (
            "slashes",
            "f 1/// 2 3",
            "face corner '1///' has more than three '/'-separated indices",
        ),
        (
            "vn-text",
            "f 1//a 2 3",
            "normal index 'a' is not an integer",
        ),
    ] {
        obj_fails(
            name,
            &format!("{HEAD}{line}\nf 3 2 1\n"),
            &["s.obj:6: ", mention],
        );
    }
    obj_fails(
        "only-short-faces",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\nf 2 3\n",
        &["s.obj:4: face has 2 vertices"],
    );
    obj_fails(
        "mixed-colours",
        "v 0 0 0 1 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
        &["s.obj:2: vertex 2 lacks a colour"],
    );
}

/// Issue 18 defect 6: a finite huge coordinate was reported as "non-finite bounds".
#[test]
fn huge_coordinates_are_named_as_such() {
    let e = obj_fails(
        "huge",
        "v 0 0 0\nv 1e19 0 0\nv 0 1 0\nf 1 2 3\n",
        &[
            "s.obj:2: ",
            "vertex 2 has a coordinate beyond the supported magnitude 1e15",
        ],
    );
    assert!(!e.contains("non-finite"), "{e}");
}

/// Errors that already named the file and line: kept so they stay that way.
#[test]
fn bad_obj_files_that_already_failed_cleanly() {
    for (name, obj, mentions) in [
        (
            "index-range",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n",
            &[
                "s.obj:4: ",
                "vertex index 9 is out of range (3 in the file)",
            ][..],
        ),
        (
            "index-neg",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n",
            &["s.obj:4: ", "relative vertex index -4"],
        ),
        (
            "index-zero",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n",
            &["s.obj:4: ", "vertex index 0 is invalid"],
        ),
        (
            "nan",
            "v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n",
            &["s.obj:2: ", "non-finite coordinate"],
        ),
        (
            "inf",
            "v 0 0 0\nv 1 0 0\nv 0 1 -inf\nf 1 2 3\n",
            &["s.obj:3: ", "non-finite coordinate"],
        ),
        (
            "not-a-number",
            "v 0 0 0\nv 1 0 0\nv 0 one 0\nf 1 2 3\n",
            &["s.obj:3: ", "'one' is not a number"],
        ),
        ("empty", "", &["s.obj", "empty scene"]),
        ("comments-only", "# nothing\n\n", &["s.obj", "empty scene"]),
    ] {
        obj_fails(name, obj, mentions);
    }
    let mut binary = b"v 0 0 0\n".to_vec();
    binary.extend((0..=255u8).cycle().take(1000));
    render_fails(
        "binary",
        &[("s.obj", &binary)],
        "s.obj",
        &["s.obj:", "not valid UTF-8"],
    );
    render_fails("missing", &[], "absent.obj", &["absent.obj"]);
}

/// Issue 18 defect 4 (manifest): arrays with extra elements were truncated.
#[test]
fn manifest_arrays_of_another_length_name_the_line() {
    for (name, camera, light, line) in [
        (
            "eye-extra",
            "eye = [0, 2, 3, \"x\"]\ntarget = [0.3, 0.3, 0.0]\nvfov_deg = 40.0",
            LIGHT,
            "s.toml:4: ",
        ),
        (
            "target-short",
            "eye = [0.3, 0.3, 3.0]\ntarget = [0.3, 0.3]\nvfov_deg = 40.0",
            LIGHT,
            "s.toml:5: ",
        ),
        (
            "up-long",
            &format!("{CAMERA}\nup = [0, 1, 0, 0]"),
            LIGHT,
            "s.toml:7: ",
        ),
        (
            "light-position",
            CAMERA,
            "position = [0, 2, 2, 1]",
            "s.toml:9: ",
        ),
        (
            "light-colour",
            CAMERA,
            "position = [0, 2, 2]\ncolor = [1, 1]",
            "s.toml:10: ",
        ),
    ] {
        manifest_fails(
            name,
            camera,
            light,
            &[line, "invalid length", "expected an array of 3 numbers"],
        );
    }
}

/// Bad cameras and lights in manifests, which already failed naming the manifest.
#[test]
fn bad_cameras_and_lights_in_manifests() {
    for (name, camera, light, mentions) in [
        (
            "eye-is-target",
            "eye = [0, 0, 1]\ntarget = [0, 0, 1]\nvfov_deg = 40.0",
            LIGHT,
            &["s.toml", "coincide"][..],
        ),
        (
            "up-parallel",
            "eye = [0, 0, 1]\ntarget = [0, 0, 0]\nup = [0, 0, 1]\nvfov_deg = 40.0",
            LIGHT,
            &["s.toml", "camera up"],
        ),
        (
            "vfov-zero",
            "eye = [0, 0, 1]\ntarget = [0, 0, 0]\nvfov_deg = 0.0",
            LIGHT,
            &["s.toml", "vfov_deg"],
        ),
        (
            "eye-nan",
            "eye = [0, nan, 1]\ntarget = [0, 0, 0]\nvfov_deg = 40.0",
            LIGHT,
            &["s.toml", "finite"],
        ),
        (
            "eye-text",
            "eye = [0, \"a\", 1]\ntarget = [0, 0, 0]\nvfov_deg = 40.0",
            LIGHT,
            &["s.toml:4: ", "invalid type"],
        ),
        (
            "no-vfov",
            "eye = [0, 0, 1]\ntarget = [0, 0, 0]",
            LIGHT,
            &["s.toml:3: ", "missing field `vfov_deg`"],
        ),
        (
            "light-radius",
            CAMERA,
            "position = [0, 2, 2]\nradius = -1",
            &["s.toml", "radius -1"],
        ),
        (
            "light-unknown-key",
            CAMERA,
            "position = [0, 2, 2]\nbrightness = 2",
            &["s.toml:10: ", "brightness"],
        ),
    ] {
        manifest_fails(name, camera, light, mentions);
    }
}

/// Found by the loaders' fuzz test (`crates/crsh-scene/tests/fuzz_inputs.rs`): a subnormal
/// `fps` or instance scale loaded into a scene with infinite times or zero normals, and an
/// unreadable mtllib named only the path.
#[test]
fn fuzz_findings_name_the_file() {
    let head = format!("{CAMERA}\n\n[[lights]]\n{LIGHT}\n\n[[instances]]\nmesh = \"s.obj\"\n");
    for (name, tail, mentions) in [
        (
            "fps",
            "[animation]\nfps = 1e-45\n",
            &["s.toml: [animation]: fps 1e-45 is outside 0.001..=1000000"][..],
        ),
        (
            "scale",
            "scale = 1e-45\n",
            &["s.toml: instance #0", "must lie in 1e-12..=1e12"],
        ),
    ] {
        let manifest = format!("[camera]\n{head}{tail}");
        render_fails(
            name,
            &[
                ("s.obj", OBJ.as_bytes()),
                ("m.mtl", MTL.as_bytes()),
                ("s.toml", manifest.as_bytes()),
            ],
            "s.toml",
            mentions,
        );
    }
    let c = Case::new("scene-files", "mtllib-dir");
    c.file("s.obj", OBJ.replace("m.mtl", "sub"))
        .file("sub/keep.txt", "a directory, not an MTL file");
    c.expect_error(
        &[
            "render", "--scene", "s.obj", "--width", "16", "--depth", "0", "--out", "o.png",
        ],
        1,
        &["s.obj: mtllib sub: ", "directory"],
    );
}
