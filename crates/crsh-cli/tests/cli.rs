//! End-to-end tests of the `crsh` binary: outputs, stats consistency, accuracy against the
//! brute-force reference, and clear errors (never a panic) on bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

mod common;
use common::{assert_ok, crsh};

/// A fresh scratch directory for one test.
fn scratch(test: &str) -> PathBuf {
    common::scratch("cli", test)
}

fn stdout(o: &Output) -> String {
    common::text(&o.stdout)
}

fn stderr(o: &Output) -> String {
    common::text(&o.stderr)
}

fn u(v: &Value, path: &str) -> u64 {
    v.pointer(path)
        .and_then(Value::as_u64)
        .unwrap_or_else(|| panic!("{path} is not an unsigned integer in {v:#}"))
}

fn f(v: &Value, path: &str) -> f64 {
    v.pointer(path)
        .and_then(Value::as_f64)
        .unwrap_or_else(|| panic!("{path} is not a number in {v:#}"))
}

fn read_json(path: &Path) -> Value {
    let text = std::fs::read_to_string(path).expect("stats file written");
    serde_json::from_str(&text).expect("stats file is JSON")
}

/// Renders and returns the parsed stats.
fn render(dir: &Path, extra: &[&str]) -> (Value, Output) {
    let mut args = vec!["render", "--out", "img.png", "--stats", "stats.json"];
    args.extend_from_slice(extra);
    let o = crsh(dir, &args);
    assert_ok(&o);
    (read_json(&dir.join("stats.json")), o)
}

#[test]
fn render_default_scene_writes_png_and_consistent_stats() {
    let dir = scratch("default");
    let (s, o) = render(&dir, &["--width", "40", "--height", "24", "--threads", "2"]);

    let img = image::open(dir.join("img.png"))
        .expect("valid PNG")
        .to_rgba8();
    assert_eq!(img.dimensions(), (40, 24));
    assert!(
        img.pixels().any(|p| p.0[..3] != [0, 0, 0]),
        "the default scene renders something, not a black image"
    );

    for key in [
        "/scene/name",
        "/scene/triangles",
        "/scene/meshes",
        "/scene/lights",
        "/scene/degenerate_triangles",
        "/pipeline",
        "/config/intersect/kind",
        "/config/raygen/kind",
        "/backend",
        "/width",
        "/height",
        "/max_depth",
        "/rays/primary",
        "/rays/shadow",
        "/rays/reflection",
        "/rays/refraction",
        "/tests/bounds",
        "/tests/ray_triangle",
        "/tests/total",
        "/tests/brute_force",
        "/per_kind",
        "/levels",
        "/timings_ms/total",
        "/setup/scene_load_ms",
        "/setup/build_stages_ms",
        "/mrays_per_s/overall",
        "/threads",
        "/version",
    ] {
        assert!(s.pointer(key).is_some(), "stats lack {key}: {s:#}");
    }
    assert!(
        s.get("accuracy").is_none(),
        "no accuracy without --reference"
    );
    assert_eq!(s["scene"]["name"], "cornell-mirrors");
    assert_eq!(s["pipeline"], "bvh");
    assert_eq!(s["config"]["intersect"]["kind"], "bvh");
    assert_eq!(s["backend"], "cpu");
    assert_eq!(
        (u(&s, "/width"), u(&s, "/height"), u(&s, "/max_depth")),
        (40, 24, 3)
    );
    assert_eq!(u(&s, "/threads"), 2);
    assert_eq!(s["version"], env!("CARGO_PKG_VERSION"));
    // The instruction set the hot loops ran in, e.g. `x86-64-v1 (CPU: x86-64-v4)`.
    let isa = s["setup"]["isa"].as_str().expect("setup.isa");
    assert!(
        isa.starts_with("x86-64-v") || isa.starts_with(std::env::consts::ARCH),
        "{isa}"
    );

    let tris = u(&s, "/scene/triangles");
    assert!(tris > 0 && u(&s, "/scene/lights") >= 1);
    assert_eq!(u(&s, "/rays/primary"), 40 * 24);
    let traced = u(&s, "/rays/shadow") + u(&s, "/rays/reflection") + u(&s, "/rays/refraction");
    assert!(u(&s, "/rays/shadow") > 0, "shadow rays are traced");
    assert!(u(&s, "/rays/reflection") > 0, "cornell-mirrors has mirrors");
    assert_eq!(u(&s, "/rays/traced"), traced);
    assert_eq!(
        u(&s, "/tests/total"),
        u(&s, "/tests/bounds") + u(&s, "/tests/ray_triangle")
    );
    assert_eq!(u(&s, "/tests/brute_force"), traced * tris);
    assert!(
        u(&s, "/tests/total") < u(&s, "/tests/brute_force"),
        "a BVH does less work than brute force"
    );

    // Per-kind numbers add up to the totals.
    let per_kind = s["per_kind"].as_object().expect("per_kind is an object");
    let sum = |field: &str| -> u64 { per_kind.values().map(|k| k[field].as_u64().unwrap()).sum() };
    assert_eq!(sum("rays"), u(&s, "/rays/primary") + traced);
    assert_eq!(sum("bounds"), u(&s, "/tests/bounds"));
    assert_eq!(sum("ray_triangle"), u(&s, "/tests/ray_triangle"));
    for (kind, k) in per_kind {
        if kind != "primary" && k["rays"].as_u64().unwrap() > 0 {
            assert!(k["trace_ms"].as_f64().unwrap() >= 0.0);
        }
    }
    assert!(f(&s, "/timings_ms/total") > 0.0);
    assert!(f(&s, "/mrays_per_s/overall") > 0.0);

    let out = stdout(&o);
    for needle in [
        "cornell-mirrors",
        "triangles",
        "meshes",
        "shadow",
        "ray-triangle",
        "brute force",
        "per traced ray",
        "time ms",
        "Mrays/s",
        "img.png",
    ] {
        assert!(out.contains(needle), "summary lacks `{needle}`:\n{out}");
    }
}

#[test]
fn brute_force_pipeline_counts_every_pair() {
    let dir = scratch("brute");
    let (s, _) = render(
        &dir,
        &[
            "--pipeline",
            "brute",
            "--width",
            "16",
            "--height",
            "16",
            "--depth",
            "1",
        ],
    );
    assert_eq!(s["pipeline"], "brute");
    assert_eq!(u(&s, "/tests/bounds"), 0);
    let tris = u(&s, "/scene/triangles");
    // Closest-hit rays test every triangle; any-hit (shadow) rays may stop at the first hit.
    for kind in ["reflection", "refraction"] {
        if let Some(k) = s["per_kind"].get(kind) {
            assert_eq!(
                k["ray_triangle"].as_u64().unwrap(),
                k["rays"].as_u64().unwrap() * tris,
                "{kind}"
            );
        }
    }
    assert!(u(&s, "/per_kind/reflection/rays") > 0);
    assert!(u(&s, "/per_kind/shadow/ray_triangle") <= u(&s, "/rays/shadow") * tris);
    assert!(u(&s, "/tests/ray_triangle") <= u(&s, "/tests/brute_force"));
    assert!(f(&s, "/tests/fraction_of_brute_force") <= 1.0);
}

#[test]
fn bvh_matches_the_brute_force_reference() {
    let dir = scratch("reference");
    let (s, o) = render(
        &dir,
        &[
            "--pipeline",
            "bvh",
            "--reference",
            "brute",
            "--width",
            "32",
            "--height",
            "32",
        ],
    );
    let a = &s["accuracy"];
    assert_eq!(a["reference"], "brute");
    assert_eq!(f(&s, "/accuracy/hit_agreement"), 1.0, "{a:#}");
    assert_eq!(u(&s, "/accuracy/rays_compared"), u(&s, "/rays/traced"));
    assert_eq!(u(&s, "/accuracy/hit_miss_mismatches"), 0);
    assert_eq!(u(&s, "/accuracy/nearest_mismatches"), 0);
    // Identical hits give identical images: PSNR is infinite, written as null.
    assert_eq!(a["images_identical"], true, "{a:#}");
    assert!(a["psnr_db"].is_null(), "{a:#}");
    assert_eq!(u(&s, "/accuracy/pixels_differing"), 0);
    assert!(stdout(&o).contains("hit agreement 1.000000"));
}

/// `--backend wgpu` renders on the adapter (lavapipe in CI) with the CPU's rays, tests and
/// image, reports the adapter and the device timings; without an adapter it is a clear error.
#[test]
fn wgpu_backend_renders_what_the_cpu_renders() {
    let dir = scratch("wgpu");
    let args = [
        "--pipeline",
        "bvh",
        "--scene",
        "office-boxes",
        "--width",
        "32",
        "--height",
        "24",
        "--reference",
        "brute",
    ];
    let mut gpu_args = args.to_vec();
    gpu_args.extend(["--backend", "wgpu"]);
    if crsh_wgpu::testing::shared_context("wgpu_backend_renders_what_the_cpu_renders").is_none() {
        let mut full = vec!["render", "--out", "img.png"];
        full.extend(&gpu_args);
        expect_error(&dir, &full, 1, "--backend wgpu: cannot open a device");
        return;
    }
    let (g, o) = render(&dir, &gpu_args);
    let (c, _) = render(&dir, &args);
    assert_eq!(g["backend"], "wgpu");
    assert!(
        g["adapter"]["name"].as_str().is_some_and(|n| !n.is_empty()),
        "{g:#}"
    );
    assert!(stdout(&o).contains("adapter   "));
    assert!(c.get("adapter").is_none());
    assert_eq!(g["rays"], c["rays"]);
    assert_eq!(g["tests"], c["tests"]);
    assert_eq!(f(&g, "/accuracy/hit_agreement"), 1.0);
    assert_eq!(g["accuracy"]["images_identical"], true, "{g:#}");
    // The primaries are the CPU rasterizer's, on every backend (OpenGL's depth range once
    // put office-boxes' mirror behind the wall).
    assert_eq!(f(&g, "/accuracy/primary_agreement"), 1.0, "{g:#}");
    assert_eq!(f(&g, "/accuracy/primary_pixels"), 768.0);
    assert_eq!(f(&c, "/accuracy/primary_agreement"), 1.0);
    assert!(stdout(&o).contains("primary agreement 1.000000 over 768 pixels"));
    let backend = g["adapter"]["backend"].as_str().unwrap_or("");
    assert!(
        ["vulkan", "gl", "metal", "dx12", "webgpu"].contains(&backend),
        "adapter backend `{backend}`"
    );
    assert!(stdout(&o).contains(&format!("({backend}, ")));
    for key in [
        "primary",
        "ray_creation",
        "intersection",
        "shading",
        "total",
    ] {
        assert!(g["timings_ms"].get(key).is_some(), "{key}");
    }
}

#[test]
fn output_does_not_depend_on_thread_count() {
    let dir = scratch("threads");
    let mut images = Vec::new();
    for threads in ["1", "3"] {
        let out = format!("t{threads}.png");
        let o = crsh(
            &dir,
            &[
                "render",
                "--width",
                "24",
                "--height",
                "20",
                "--threads",
                threads,
                "--out",
                &out,
            ],
        );
        assert_ok(&o);
        images.push(std::fs::read(dir.join(&out)).unwrap());
    }
    assert_eq!(images[0], images[1], "PNG differs between 1 and 3 threads");
}

#[test]
fn pipeline_file_and_set_overrides() {
    let dir = scratch("pipeline-file");
    let (s, _) = render(
        &dir,
        &[
            "--width",
            "16",
            "--height",
            "16",
            "--set",
            "intersect.kind=brute",
        ],
    );
    assert_eq!(s["config"]["intersect"]["kind"], "brute");
    // The resolved config of the stats file, saved as TOML, is a valid --pipeline file.
    let cfg = &s["config"];
    let toml_text = toml::to_string(cfg).expect("config serialises to TOML");
    std::fs::write(dir.join("mine.toml"), toml_text).unwrap();
    let (s2, _) = render(
        &dir,
        &["--width", "16", "--height", "16", "--pipeline", "mine.toml"],
    );
    assert_eq!(&s2["config"], cfg);
    assert_eq!(s2["rays"], s["rays"]);
    assert_eq!(s2["tests"]["total"], s["tests"]["total"]);
}

#[test]
fn renders_a_bare_obj_and_a_shared_manifest() {
    let dir = scratch("files");
    // Two quads facing +z, one behind the other: the front one shadows part of the back one.
    std::fs::write(
        dir.join("quads.obj"),
        "o back\nv -2 -2 0\nv 2 -2 0\nv 2 2 0\nv -2 2 0\nf 1 2 3\nf 1 3 4\n\
         o front\nv -0.5 -0.5 1\nv 0.5 -0.5 1\nv 0.5 0.5 1\nv -0.5 0.5 1\nf 5 6 7\nf 5 7 8\n",
    )
    .unwrap();
    let (s, _) = render(
        &dir,
        &["--scene", "quads.obj", "--width", "16", "--height", "16"],
    );
    assert_eq!(u(&s, "/scene/triangles"), 4);
    assert_eq!(u(&s, "/scene/meshes"), 2);
    assert_eq!(u(&s, "/scene/lights"), 1, "a bare OBJ gets one light");
    assert_eq!(s["scene"]["source"], "quads.obj");
    assert!(u(&s, "/rays/shadow") > 0);

    let shared = std::env::var_os("CRSH_SCENES")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes"))
        .join("cornell/cornell-sphere.toml");
    if !shared.is_file() {
        eprintln!("SKIP: {} not found (set CRSH_SCENES)", shared.display());
        return;
    }
    let (s, _) = render(
        &dir,
        &[
            "--scene",
            shared.to_str().unwrap(),
            "--width",
            "24",
            "--height",
            "24",
            "--reference",
            "brute",
        ],
    );
    assert_eq!(s["scene"]["name"], "cornell-sphere");
    assert!(u(&s, "/rays/refraction") > 0, "the glass sphere refracts");
    assert_eq!(f(&s, "/accuracy/hit_agreement"), 1.0);
}

#[test]
fn manifest_aspect_sets_the_default_height_and_pixels_stay_square() {
    let dir = scratch("aspect");
    std::fs::write(
        dir.join("quad.obj"),
        "o q\nv -2 -1 0\nv 2 -1 0\nv 2 1 0\nv -2 1 0\nf 1 2 3\nf 1 3 4\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("wide.toml"),
        "name = \"wide\"\nmesh = \"quad.obj\"\n[camera]\neye = [0.0, 0.0, 4.0]\n\
         target = [0.0, 0.0, 0.0]\nvfov_deg = 40.0\naspect = 2.0\n\
         [[lights]]\nposition = [0.0, 0.0, 3.0]\n",
    )
    .unwrap();
    let (s, _) = render(&dir, &["--scene", "wide.toml", "--width", "40"]);
    assert_eq!(u(&s, "/width"), 40);
    assert_eq!(u(&s, "/height"), 20, "height follows the framing aspect");
    let (s, _) = render(
        &dir,
        &["--scene", "wide.toml", "--width", "40", "--height", "30"],
    );
    assert_eq!(u(&s, "/height"), 30, "an explicit --height wins");
}

/// Runs a command that must fail with `code` and a one-line `error:` message containing
/// `needle`, without panicking.
fn expect_error(dir: &Path, args: &[&str], code: i32, needle: &str) {
    let o = crsh(dir, args);
    let err = stderr(&o);
    assert_eq!(
        o.status.code(),
        Some(code),
        "{args:?}: wrong exit code\nstderr:\n{err}"
    );
    assert!(!err.contains("panicked"), "{args:?} panicked:\n{err}");
    assert!(
        err.starts_with("error:"),
        "{args:?}: stderr does not start with `error:`:\n{err}"
    );
    assert!(
        err.contains(needle),
        "{args:?}: stderr lacks `{needle}`:\n{err}"
    );
    assert!(
        !dir.join("crsh.png").exists(),
        "{args:?} wrote an image anyway"
    );
}

/// `--pipeline embree`, `embree_packets` and `embree_sorted`: with the `embree` feature they render
/// office-boxes with `bvh`'s hits (agreement ≥ 0.9999), name the variant and its mode, and
/// report their tests as absent (`null`), never 0; without it the command fails with one
/// line naming the feature and the package to install.
#[test]
fn embree_renders_with_the_feature_and_is_named_without() {
    let dir = scratch("embree");
    for (preset, mode) in [
        ("embree", "single"),
        ("embree_packets", "packet16"),
        ("embree_sorted", "packet16"),
    ] {
        let args = [
            "--pipeline",
            preset,
            "--scene",
            "office-boxes",
            "--width",
            "64",
            "--height",
            "48",
            "--reference",
            "bvh",
        ];
        if !cfg!(feature = "embree") {
            let mut all = vec!["render"];
            all.extend_from_slice(&args);
            expect_error(&dir, &all, 1, "--features embree");
            expect_error(&dir, &all, 1, "libembree-dev");
            continue;
        }
        let (s, o) = render(&dir, &args);
        assert_eq!(s["stages"]["intersect"], "embree");
        assert_eq!(s["config"]["intersect"]["mode"], mode);
        assert!(s["tests"]["bounds"].is_null() && s["tests"]["total"].is_null());
        assert!(s["per_kind"]["shadow"]["ray_triangle"].is_null());
        assert!(u(&s, "/per_kind/shadow/rays") > 0);
        let agreement = f(&s, "/accuracy/hit_agreement");
        assert!(agreement >= 0.9999, "{preset}: hit agreement {agreement}");
        // The sorted preset reorders each batch for Embree and times it.
        assert_eq!(
            s["timings_ms"].get("reordering").is_some(),
            preset == "embree_sorted",
            "{preset}"
        );
        assert!(
            stdout(&o).contains("tests     bounds — |"),
            "{}",
            stdout(&o)
        );
    }
}

#[test]
fn bad_input_gives_clear_errors() {
    let dir = scratch("errors");
    std::fs::write(
        dir.join("broken.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n",
    )
    .unwrap();
    std::fs::write(dir.join("bad.toml"), "name = \"x\"\nprimary = 3\n").unwrap();
    let cases: &[(&[&str], i32, &str)] = &[
        (&["render", "--scene", "missing.obj"], 1, "missing.obj"),
        (
            &["render", "--scene", "no-such-builtin"],
            1,
            "no-such-builtin",
        ),
        (&["render", "--scene", "broken.obj"], 1, "broken.obj"),
        (&["render", "--set", "intersect"], 2, "--set intersect"),
        (&["render", "--set", "nonsense"], 2, "expected key=value"),
        (&["render", "--set", "warp.speed=9"], 2, "unknown stage"),
        (&["render", "--set", "intersect.kind=octree"], 2, "octree"),
        (&["render", "--set", "shade.ambiant=0.1"], 2, "ambiant"),
        (
            &["render", "--set", "shade.ambient=nan"],
            2,
            "shade.ambient",
        ),
        (
            &["render", "--set", "raygen.epsilon=-1"],
            2,
            "raygen.epsilon",
        ),
        (
            &["render", "--set", "primary.accel=brute"],
            2,
            "primary.accel",
        ),
        (&["render", "--pipeline", "octree"], 2, "unknown pipeline"),
        (&["render", "--pipeline", "bad.toml"], 1, "bad.toml"),
        (&["render", "--pipeline", "absent.toml"], 1, "absent.toml"),
        (&["render", "--reference", "oracle"], 2, "oracle"),
        (&["render", "--width", "0"], 2, "--width"),
        (&["render", "--width", "100000"], 2, "--width"),
        (&["render", "--height", "-1"], 2, "-1"),
        (&["render", "--depth", "100000"], 2, "--depth"),
        (&["render", "--threads", "0"], 2, "--threads"),
        (&["render", "--out", "picture.jpg"], 2, "PNG"),
        (
            &["render", "--out", "no/such/dir/x.png"],
            2,
            "does not exist",
        ),
        (
            &[
                "render",
                "--backend",
                "wgpu",
                "--set",
                "intersect.kind=brute64",
            ],
            2,
            "wgpu backend",
        ),
        (&["render", "--backend", "vulkan"], 2, "--backend"),
        (&["frobnicate"], 2, "frobnicate"),
    ];
    for (args, code, needle) in cases {
        expect_error(&dir, args, *code, needle);
    }
}

#[test]
fn scenes_lists_builtins_and_notes_a_missing_dir() {
    let dir = scratch("scenes");
    let o = crsh(&dir, &["scenes", "--scenes-dir", "nowhere"]);
    assert_ok(&o);
    let out = stdout(&o);
    for needle in [
        "cornell-mirrors",
        "office-boxes",
        "glass-sphere ",
        "glass-sphere-N",
        "glass-shell ",
        "glass-shell-N",
        "triangles",
        "not found",
    ] {
        assert!(
            out.contains(needle),
            "`crsh scenes` lacks `{needle}`:\n{out}"
        );
    }
    let o = crsh(&dir, &["scenes", "--scenes-dir", "nowhere", "--json"]);
    assert_ok(&o);
    let v: Value = serde_json::from_str(&stdout(&o)).expect("scenes --json is JSON");
    let builtins = v["builtins"].as_array().unwrap();
    assert!(builtins
        .iter()
        .any(|b| b["name"] == "cornell-mirrors" && b["triangles"].as_u64().unwrap() > 0));
    assert!(builtins
        .iter()
        .any(|b| b["name"] == "office-boxes" && b["lights"].as_u64().unwrap() >= 2));
    assert!(builtins
        .iter()
        .any(|b| b["name"] == "glass-sphere" && b["triangles"].as_u64() == Some(5012)));
    assert!(builtins
        .iter()
        .any(|b| b["name"] == "glass-shell" && b["triangles"].as_u64() == Some(5012)));
    for pattern in ["glass-sphere-N", "glass-shell-N"] {
        assert!(v["patterns"]
            .as_array()
            .unwrap()
            .iter()
            .any(|p| p["name"] == pattern));
    }
    assert!(v["manifests"].as_array().unwrap().is_empty());

    // A directory with one manifest, through the environment variable.
    std::fs::create_dir_all(dir.join("lib/room")).unwrap();
    std::fs::write(
        dir.join("lib/room/room.toml"),
        "name = \"my-room\"\nmesh = \"room.obj\"\n\
         [camera]\neye = [0.0, 0.0, 5.0]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\nvfov_deg = 45.0\n",
    )
    .unwrap();
    std::fs::write(dir.join("lib/broken.toml"), "name = [\n").unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_crsh"))
        .args(["scenes"])
        .current_dir(&dir)
        .env("CRSH_SCENES", dir.join("lib"))
        .output()
        .unwrap();
    assert_ok(&o);
    let out = stdout(&o);
    assert!(
        out.contains("my-room") && out.contains("room.toml"),
        "{out}"
    );
}

#[test]
fn scenes_lists_the_shared_scenes() {
    let shared = std::env::var_os("CRSH_SCENES")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes")
        });
    if !shared.is_dir() {
        eprintln!(
            "SKIP: shared scenes directory {} not found (set CRSH_SCENES)",
            shared.display()
        );
        return;
    }
    let dir = scratch("shared-scenes");
    let o = crsh(&dir, &["scenes", "--scenes-dir", shared.to_str().unwrap()]);
    assert_ok(&o);
    let out = stdout(&o);
    assert!(out.contains("sponza.toml"), "{out}");
    assert!(out.contains("cornell-mirror.toml"), "{out}");
}

#[test]
fn pipelines_lists_presets_and_every_variant() {
    let dir = scratch("pipelines");
    let o = crsh(&dir, &["pipelines", "--json"]);
    assert_ok(&o);
    let v: Value = serde_json::from_str(&stdout(&o)).expect("pipelines --json is JSON");
    let presets: Vec<&str> = v["presets"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["name"].as_str().unwrap())
        .collect();
    assert!(
        presets.contains(&"brute") && presets.contains(&"bvh"),
        "{presets:?}"
    );
    let variants = v["variants"].as_array().unwrap();
    for (stage, name) in [
        ("primary", "raster"),
        ("primary", "raycast"),
        ("raygen", "whitted"),
        ("intersect", "brute"),
        ("intersect", "bvh"),
        ("shade", "phong"),
    ] {
        assert!(
            variants
                .iter()
                .any(|x| x["stage"] == stage && x["name"] == name),
            "no {stage} variant {name}"
        );
    }
    // Which backends have each variant, ranges, whole-scene-only intersectors, preset docs.
    let find = |stage: &str, name: &str| {
        variants
            .iter()
            .find(|x| x["stage"] == stage && x["name"] == name)
            .unwrap_or_else(|| panic!("{stage} {name}"))
    };
    assert_eq!(
        find("hash", "thesis")["backends"],
        serde_json::json!(["cpu", "wgpu"])
    );
    assert_eq!(
        find("primary", "raycast")["backends"],
        serde_json::json!(["cpu"])
    );
    assert_eq!(find("intersect", "bvh")["scene_only"], true);
    assert!(find("intersect", "brute").get("scene_only").is_none());
    let sub = &find("hierarchy", "sphere_cone")["params"][0];
    assert_eq!(
        (
            sub["name"].as_str(),
            sub["min"].as_f64(),
            sub["max"].as_f64()
        ),
        (Some("subdivision"), Some(2.0), Some(64.0))
    );
    assert!(v["presets"][0]["doc"]
        .as_str()
        .is_some_and(|d| !d.is_empty()));

    let o = crsh(&dir, &["pipelines"]);
    assert_ok(&o);
    let text = stdout(&o);
    for x in variants {
        let (stage, name) = (x["stage"].as_str().unwrap(), x["name"].as_str().unwrap());
        assert!(text.contains(name), "text listing lacks variant {name}");
        for p in x["params"].as_array().unwrap() {
            let key = format!("{stage}.{}", p["name"].as_str().unwrap());
            assert!(
                text.contains(&key),
                "text listing lacks parameter {key}:\n{text}"
            );
        }
    }
    assert!(text.contains("raycast  [cpu]"), "{text}");
    assert!(
        text.contains("hierarchy.subdivision = 8 (2..=64)"),
        "{text}"
    );
}

/// Stages that do not fit together, and values outside a parameter's range, are usage errors
/// (exit 2) found before the scene is loaded or any stage is built, naming the slots.
#[test]
fn slots_that_do_not_fit_and_out_of_range_values_exit_2() {
    let dir = scratch("slots");
    for (sets, needle) in [
        (
            &["--set", "sort=off"][..],
            "stages `hash, sort` do not fit together",
        ),
        (
            &["--set", "traverse=off"],
            "stages `hierarchy, traverse` do not fit together",
        ),
        (
            &["--set", "intersect.kind=bvh"],
            "stages `hierarchy, intersect` do not fit together",
        ),
        (
            &["--set", "hierarchy.subdivision=100"],
            "100 is outside 2..=64",
        ),
        (&["--set", "shade.ambient=nan"], "NaN"),
    ] {
        let mut args = vec![
            "render",
            "--pipeline",
            "crsh",
            "--scene",
            "no/such/scene.toml",
            "--width",
            "8",
        ];
        args.extend_from_slice(sets);
        let o = crsh(&dir, &args);
        assert_eq!(o.status.code(), Some(2), "{sets:?}: {}", stderr(&o));
        assert!(stderr(&o).contains(needle), "{sets:?}: {}", stderr(&o));
    }
}

#[test]
fn help_on_every_command() {
    let dir = scratch("help");
    for args in [
        &["--help"][..],
        &["render", "--help"],
        &["scenes", "--help"],
        &["pipelines", "--help"],
        &["adapters", "--help"],
    ] {
        let o = crsh(&dir, args);
        assert_ok(&o);
        assert!(stdout(&o).contains("Usage: crsh"), "{args:?}");
    }
    let o = crsh(&dir, &["render", "--help"]);
    for opt in [
        "--scene",
        "--pipeline",
        "--backend",
        "--width",
        "--height",
        "--depth",
        "--out",
        "--stats",
        "--reference",
        "--set",
        "--threads",
    ] {
        assert!(stdout(&o).contains(opt), "render --help lacks {opt}");
    }
}

#[test]
fn adapters_lists_what_wgpu_finds() {
    let dir = scratch("adapters");
    let o = crsh(&dir, &["adapters", "--json"]);
    assert_ok(&o);
    let v: Value = serde_json::from_str(&stdout(&o)).expect("adapters --json is JSON");
    let list = v.as_array().expect("a list of adapters");
    let o = crsh(&dir, &["adapters"]);
    assert_ok(&o);
    let text = stdout(&o);
    if list.is_empty() {
        assert!(text.contains("no wgpu adapter"), "{text}");
    } else {
        for a in list {
            assert!(text.contains(a["name"].as_str().unwrap()), "{text}");
        }
    }
}

#[test]
fn render_frames_writes_numbered_pngs_and_a_row_per_frame() {
    let dir = scratch("frames");
    let (s, o) = render(
        &dir,
        &[
            "--scene",
            "cornell-mirrors-animated",
            "--pipeline",
            "bvh",
            "--set",
            "intersect.update=refit",
            "--frames",
            "3",
            "--width",
            "32",
            "--depth",
            "1",
            "--reference",
            "brute",
            "--reference-every",
            "2",
        ],
    );
    for f in 0..3 {
        let img = image::open(dir.join(format!("img-{f:04}.png")))
            .expect("valid PNG")
            .to_rgba8();
        assert_eq!(img.dimensions(), (32, 32));
    }
    assert!(!dir.join("img.png").exists());
    let frames = s["frames"].as_array().expect("frames rows");
    assert_eq!(frames.len(), 3);
    for (i, row) in frames.iter().enumerate() {
        assert_eq!(u(row, "/frame"), i as u64);
        let structure = row["update"]["structure"].as_str().unwrap();
        assert_eq!(structure, if i == 0 { "bvh rebuild" } else { "bvh refit" });
        let frame_ms = f(row, "/frame_ms");
        assert!((frame_ms - f(row, "/update/total_ms") - f(row, "/render_ms")).abs() < 1e-6);
        let output = row["report"]["output"].as_str().unwrap();
        assert!(output.ends_with(&format!("img-{i:04}.png")), "{output}");
        // Frames 0 and 2 are checked (every 2nd), frame 1 is not.
        assert_eq!(row["report"]["accuracy"].is_null(), i == 1, "frame {i}");
    }
    assert_eq!(u(&s, "/totals/frames"), 3);
    assert_eq!(u(&s, "/totals/frames_checked"), 2);
    assert_eq!(f(&s, "/totals/min_hit_agreement"), 1.0);
    assert!(u(&s, "/moving_triangles") > 0);
    let out = stdout(&o);
    assert!(
        out.contains("bvh refit") && out.contains("3 frames"),
        "{out}"
    );
}

#[test]
fn bad_frame_requests_exit_2() {
    let dir = scratch("frames-bad");
    for args in [
        &["render", "--frames", "0"][..],
        &["render", "--reference-every", "2"][..],
        &["render", "--frames", "2", "--reference-every", "0"][..],
    ] {
        let o = crsh(&dir, args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
    }
}

/// `--light-radius` sets every light's radius for soft shadows: with `shadow = edge_width` the
/// image differs from the point-light one, at radius 0 it is the hard image, and a negative or
/// non-finite radius is a usage error; wgpu-only soft shadows are refused clearly elsewhere.
#[test]
fn light_radius_softens_shadows_and_is_checked() {
    let dir = scratch("light-radius");
    let png = |extra: &[&str]| {
        let mut args = vec!["--width", "32", "--depth", "1"];
        args.extend_from_slice(extra);
        render(&dir, &args);
        std::fs::read(dir.join("img.png")).unwrap()
    };
    let hard = png(&[]);
    let edge = ["--set", "raygen.shadow=edge_width"];
    assert_eq!(png(&[&edge[..], &["--light-radius", "0"]].concat()), hard);
    let (v, _) = render(
        &dir,
        &[
            "--width",
            "32",
            "--depth",
            "1",
            "--light-radius",
            "0.2",
            "--set",
            "raygen.shadow=edge_width",
            "--reference",
            "brute",
        ],
    );
    assert_eq!(f(&v, "/accuracy/hit_agreement"), 1.0, "{v:#}");
    assert_ne!(std::fs::read(dir.join("img.png")).unwrap(), hard);
    std::fs::remove_file(dir.join("img.png")).unwrap();
    for bad in ["-1", "NaN", "inf"] {
        let arg = format!("--light-radius={bad}");
        expect_error(&dir, &["render", &arg], 2, "--light-radius");
    }
}
