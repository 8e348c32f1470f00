//! Output paths, write failures, `ablate --compare` inputs, sizes and `--set` values.

use std::path::Path;

use crate::harness::Case;

const SUITE: &str = "outputs";

/// A lit triangle whose material comes from `tri.mtl`, and a manifest around it.
fn scene(name: &str) -> Case {
    let c = Case::new(SUITE, name);
    c.file(
        "s.obj",
        "mtllib tri.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m\nf 1 2 3\n",
    )
    .file("tri.mtl", "newmtl m\nKd 0.8 0.8 0.8\n")
    .file("scene.toml", manifest("45", ""));
    c
}

/// A manifest of `s.obj` with the camera's `vfov_deg` and extra camera lines.
fn manifest(vfov: &str, camera_extra: &str) -> String {
    format!(
        "mesh = \"s.obj\"\n[camera]\neye = [0.3, 0.3, 3]\ntarget = [0.3, 0.3, 0]\n\
         vfov_deg = {vfov}\n{camera_extra}\n[[lights]]\nposition = [0, 0, 3]\n"
    )
}

/// `crsh render` of `scene` at 16 pixels, no bounces, with `extra` arguments.
fn render<'a>(scene: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut v = vec!["render", "--scene", scene, "--width", "16", "--depth", "0"];
    v.extend_from_slice(extra);
    v
}

// --- Item 2: outputs over inputs or over each other -------------------------------------

#[test]
fn stats_over_the_scene_obj() {
    let c = scene("stats-over-obj");
    c.expect_error(
        &render("s.obj", &["--out", "o.png", "--stats", "s.obj"]),
        2,
        &["--stats s.obj", "`.json`"],
    );
}

#[test]
fn stats_over_the_manifest() {
    let c = scene("stats-over-manifest");
    c.expect_error(
        &render("scene.toml", &["--out", "o.png", "--stats", "scene.toml"]),
        2,
        &["--stats scene.toml", "`.json`"],
    );
}

#[test]
fn stats_over_the_png() {
    let c = scene("stats-over-png");
    c.expect_error(
        &render("scene.toml", &["--out", "x.png", "--stats", "x.png"]),
        2,
        &["--stats x.png", "`.json`"],
    );
    // Without extensions the names pass, and the same file twice is refused.
    c.expect_error(
        &render("scene.toml", &["--out", "x", "--stats", "./x"]),
        2,
        &["--stats ./x", "is also --out x"],
    );
}

#[test]
fn output_over_an_mtl_file_by_another_spelling() {
    let c = Case::new(SUITE, "out-over-mtl");
    c.file(
        "m/s.obj",
        "mtllib mat\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    )
    .file("m/mat", "newmtl m\nKd 1 1 1\n");
    c.expect_error(
        &render("m/s.obj", &["--out", "o.png", "--stats", "m/../m/mat"]),
        2,
        &[
            "--stats m/../m/mat",
            "an input of this run",
            "scene `m/s.obj`",
        ],
    );
}

#[test]
fn output_over_the_pipeline_file() {
    let c = scene("out-over-pipeline");
    c.file("pipe", "name = \"mine\"\n");
    c.expect_error(
        &render("scene.toml", &["--pipeline", "pipe", "--out", "pipe"]),
        2,
        &["--out pipe", "a pipeline file"],
    );
}

#[test]
fn frames_over_an_input() {
    // `--out o` numbers its frames `o-0000.png`, ...: one of them is the scene's MTL file.
    let c = Case::new(SUITE, "frames-over-mtl");
    c.file(
        "s.obj",
        "mtllib o-0001.png\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    )
    .file("o-0001.png", "newmtl m\nKd 1 1 1\n");
    c.expect_error(
        &render("s.obj", &["--frames", "3", "--out", "o"]),
        2,
        &["--out (frame 1) o-0001.png", "an input of this run"],
    );
}

#[test]
fn ablate_out_over_its_plan() {
    let c = scene("ablate-over-plan");
    c.file(
        "out/report.html",
        "scenes = [\"cornell-mirrors\"]\nwidth = 16\n[[pipelines]]\npipeline = \"bvh\"\n",
    );
    c.expect_error(
        &[
            "ablate",
            "--plan",
            "out/report.html",
            "--out",
            "out",
            "--repeat",
            "1",
        ],
        2,
        &["--out out/report.html", "the plan"],
    );
}

#[test]
fn ablate_out_over_a_scene_in_its_charts() {
    let c = Case::new(SUITE, "ablate-over-charts");
    c.file("out/charts/s.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    c.expect_error(
        &[
            "ablate",
            "--scenes",
            "out/charts/s.obj",
            "--pipelines",
            "bvh",
            "--out",
            "out",
        ],
        2,
        &["--out out/charts", "s.obj", "an input of this run"],
    );
}

#[test]
fn ablate_merge_into_a_shard() {
    let c = Case::new(SUITE, "ablate-merge-into-shard");
    c.file("a/results.json", "{}\n")
        .file("b/results.json", "{}\n");
    c.expect_error(
        &["ablate", "--merge", "a", "b", "--out", "a"],
        2,
        &["--out a/results.json", "a shard's results.json"],
    );
}

#[test]
fn tables_and_grid_build_outputs_need_their_extension() {
    let c = scene("tables-grid-build-ext");
    c.expect_error(
        &[
            "tables",
            "--scene",
            "scene.toml",
            "--width",
            "16",
            "--out",
            "scene.toml",
        ],
        2,
        &["--out scene.toml", "`.md`"],
    );
    c.expect_error(
        &["grid-build", "--sizes", "10", "--json", "s.obj"],
        2,
        &["--json s.obj", "`.json`"],
    );
}

// --- Item 3: write errors are reported, and leave no half-written file ------------------

#[test]
fn out_to_dev_full_fails() {
    if !Path::new("/dev/full").exists() {
        println!("SKIP: no /dev/full");
        return;
    }
    let c = scene("dev-full");
    let line = c.expect_error(&render("scene.toml", &["--out", "/dev/full"]), 1, &[]);
    assert_eq!(
        line,
        "error: writing /dev/full: No space left on device (os error 28)"
    );
    c.expect_error(
        &render(
            "scene.toml",
            &["--out", "/dev/null", "--stats", "/dev/full"],
        ),
        1,
        &["writing /dev/full:"],
    );
}

#[test]
fn a_failed_write_keeps_the_previous_output() {
    let c = scene("failed-write-keeps-old");
    c.expect_ok(&render("scene.toml", &["--out", "good.png"]));
    let good = std::fs::read(c.path("good.png")).unwrap();
    // A file size limit (which binds root too) makes the larger image's write fail half-way
    // (EFBIG; the signal is ignored so that the write returns the error).
    let line = c.expect_error_after(
        "trap '' XFSZ; ulimit -f 1",
        &[
            "render",
            "--scene",
            "scene.toml",
            "--width",
            "256",
            "--depth",
            "0",
            "--out",
            "good.png",
        ],
        1,
        &["writing good.png:"],
    );
    assert!(line.contains("too large"), "{line}");
    assert_eq!(std::fs::read(c.path("good.png")).unwrap(), good);
}

#[test]
fn output_onto_a_directory() {
    let c = scene("out-is-a-directory");
    std::fs::create_dir(c.path("d.png")).unwrap();
    c.expect_error(
        &render("scene.toml", &["--out", "d.png"]),
        2,
        &["--out d.png", "is a directory"],
    );
    c.expect_error(
        &render("scene.toml", &["--out", "no/such/o.png"]),
        2,
        &["--out no/such/o.png", "does not exist"],
    );
}

// --- Item 5: `ablate --compare` on files it cannot read ---------------------------------

const GOOD_CELL: &str = r#"{"scene": "s", "pipeline": "bvh", "backend": "cpu", "params": {},
 "width": 16, "height": 16, "depth": 0, "status": "ok",
 "measures": {"timings_ms": {"total": {"median": 1.0}}, "tests": {"total": 10}}}"#;

#[test]
fn compare_refuses_cells_it_cannot_read() {
    let c = Case::new(SUITE, "compare-bad-cells");
    c.file("old.json", format!("{{\"cells\": [{GOOD_CELL}]}}\n"))
        .file("strings.json", "{\"cells\": [\"a\",\n \"b\"]}\n")
        .file(
            "missing.json",
            format!("{{\"cells\": [{GOOD_CELL},\n{{\"pipeline\": \"bvh\"}}]}}\n"),
        )
        .file(
            "width.json",
            "{\"cells\": [{\"scene\": \"s\", \"pipeline\": \"bvh\", \"backend\": \"cpu\",\n \"params\": {}, \"width\": \"x\"}]}\n",
        )
        .file(
            "twice.json",
            format!("{{\"cells\": [{GOOD_CELL}, {GOOD_CELL}]}}\n"),
        )
        .file(
            "nomeasures.json",
            "{\"cells\": [{\"scene\": \"s\", \"pipeline\": \"bvh\", \"backend\": \"cpu\", \"params\": {},\n \"width\": 16, \"height\": 16, \"depth\": 0, \"status\": \"ok\"}]}\n",
        );
    let cmp = |new: &'static str| ["ablate", "--compare", "old.json", new];
    c.expect_error(
        &cmp("strings.json"),
        2,
        &["strings.json:1:", "invalid type: string \"a\""],
    );
    c.expect_error(
        &cmp("missing.json"),
        2,
        &["missing.json:4:", "missing field `scene`"],
    );
    c.expect_error(
        &cmp("width.json"),
        2,
        &["width.json:2:", "invalid type: string \"x\", expected u32"],
    );
    c.expect_error(
        &cmp("twice.json"),
        2,
        &["twice.json: cells[1]", "same cell as cells[0]"],
    );
    c.expect_error(
        &cmp("nomeasures.json"),
        2,
        &["nomeasures.json: cells[0]", "no `measures`"],
    );
    let o = c.expect_ok(&cmp("old.json"));
    assert!(
        crate::common::text(&o.stdout).contains("1 cells matched, 0 only in old, 0 only in new")
    );
}

// --- Item 6: sizes and fields of view that give no image; no `error:` on success --------

#[test]
fn camera_fields_that_give_no_image() {
    let c = scene("camera-no-image");
    c.file("thin.toml", manifest("45", "aspect = 1e-9"))
        .file("wide.toml", manifest("45", "aspect = 1e9"))
        .file("narrow.toml", manifest("1e-30", ""))
        .file("flat.toml", manifest("179.9", ""))
        .file("tall.toml", manifest("45", "aspect = 0.001"));
    for (file, says) in [
        (
            "thin.toml",
            "camera aspect 0.000000001 gives no usable image",
        ),
        (
            "wide.toml",
            "camera aspect 1000000000 gives no usable image",
        ),
        (
            "narrow.toml",
            "camera vfov_deg 0.000000000000000000000000000001 gives no usable image",
        ),
        ("flat.toml", "camera vfov_deg 179.9 gives no usable image"),
    ] {
        let line = c.expect_error(&render(file, &["--out", "o.png"]), 1, &[says]);
        assert!(line.contains(&format!("{file}: camera")), "{line}");
    }
    // A usable aspect that makes this width's height too large: the height is named.
    c.expect_error(
        &[
            "render",
            "--scene",
            "tall.toml",
            "--width",
            "100",
            "--out",
            "o.png",
        ],
        2,
        &[
            "--width 100",
            "gives a height of 100000 pixels, outside 1..=16384",
        ],
    );
}

#[test]
fn bad_sizes_and_set_values() {
    let c = scene("sizes-and-set");
    for (args, mentions) in [
        (vec!["--width", "0"], vec!["'--width <WIDTH>'"]),
        (vec!["--width", "-3"], vec!["'-3'"]),
        (vec!["--height", "100000"], vec!["'--height <HEIGHT>'"]),
        (vec!["--depth", "1000"], vec!["'--depth <DEPTH>'"]),
        (
            vec!["--set", "hash.kind=nosuch"],
            vec!["unknown hash variant `nosuch`"],
        ),
        (
            vec!["--set", "nonsense"],
            vec!["--set nonsense", "key=value"],
        ),
        (
            vec!["--set", "intersect.nosuch=1"],
            vec!["`intersect.nosuch`", "no such parameter"],
        ),
        (
            vec!["--set", "intersect.build_quality=-1"],
            vec!["intersect.build_quality"],
        ),
        (vec!["--light-radius", "nan"], vec!["--light-radius NaN"]),
    ] {
        let mut full = vec!["render", "--scene", "scene.toml", "--out", "o.png"];
        full.extend(args);
        c.expect_error(&full, 2, &mentions);
    }
}

#[test]
fn wgpu_success_prints_no_error_line() {
    let c = scene("wgpu-no-error-line");
    // Without a Wayland session: the case where Mesa's Vulkan device-selection layer printed
    // `error: XDG_RUNTIME_DIR is invalid or not set in the environment.` twice.
    let unset = [
        "XDG_RUNTIME_DIR",
        "WAYLAND_DISPLAY",
        "NODEVICE_SELECT",
        "MESA_VK_DEVICE_SELECT",
        "DRI_PRIME",
    ];
    let o = c.expect_ok_without_env(&["adapters", "--json"], &unset);
    let adapters: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    if adapters.as_array().is_none_or(Vec::is_empty) {
        println!("SKIP: no wgpu adapter in `wgpu_success_prints_no_error_line`");
        return;
    }
    c.expect_ok_without_env(
        &render(
            "scene.toml",
            &["--backend", "wgpu", "--out", "o.png", "--stats", "o.json"],
        ),
        &unset,
    );
    assert!(c.path("o.png").is_file() && c.path("o.json").is_file());
}
