//! The library user's examples (`examples/`), built by `cargo test` and run here as a user runs
//! them: `render_scene` renders from code, `custom_hasher` registers a hasher that `--set
//! hash.kind=screen_tile` selects, `custom_intersector` registers an intersector and runs an
//! ablation plan comparing it with the built-in ones.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

/// The example binary `name`, which `cargo test` builds next to this test's directory
/// (`target/<profile>/examples/`).
fn example(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("test binary path");
    let profile = exe
        .parent()
        .and_then(Path::parent)
        .expect("target/<profile>/deps/<test>");
    let path = profile
        .join("examples")
        .join(format!("{name}{}", std::env::consts::EXE_SUFFIX));
    assert!(
        path.is_file(),
        "{} is missing: `cargo test` builds the examples (run the workspace tests, or `cargo build --examples` with the same profile)",
        path.display()
    );
    path
}

fn scratch(test: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("crsh-examples-{}-{test}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn run(name: &str, dir: &Path, args: &[&str]) -> Output {
    Command::new(example(name))
        .args(args)
        .current_dir(dir)
        .env_remove("RAYON_NUM_THREADS")
        .output()
        .expect("run the example")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn assert_ok(o: &Output) {
    assert!(
        o.status.success(),
        "exit {:?}\nstdout:\n{}\nstderr:\n{}",
        o.status.code(),
        text(&o.stdout),
        text(&o.stderr)
    );
}

fn json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("written")).expect("JSON")
}

#[test]
fn render_scene_renders_a_scene_from_code() {
    let dir = scratch("render");
    // A shared manifest when the scenes are there (the example's default), else a built-in.
    let scene = crsh_tests::shared_scene("cornell/cornell-sphere.toml")
        .map_or("office-boxes".to_string(), |p| p.display().to_string());
    let o = run("render_scene", &dir, &[&scene, "crsh", ".", "48"]);
    assert_ok(&o);
    let out = text(&o.stdout);
    assert!(
        out.contains("accuracy  vs bvh: primary agreement 1.000000"),
        "{out}"
    );
    assert!(out.contains("; hit agreement 1.000000"), "{out}");
    let stats = json(&dir.join("render_scene.json"));
    assert_eq!(stats["width"], 48);
    assert_eq!(stats["stages"]["hash"], "thesis");
    assert_eq!(stats["accuracy"]["images_identical"], true);
    assert!(stats["tests"]["brute_force"].as_u64().unwrap() > 0);
    assert!(image_ok(&dir.join("render_scene.png"), 48));
}

fn image_ok(path: &Path, width: u32) -> bool {
    let b = std::fs::read(path).unwrap_or_default();
    // PNG signature, then the IHDR width (big-endian) at byte 16.
    b.starts_with(&[0x89, b'P', b'N', b'G']) && b.len() > 24 && b[16..20] == width.to_be_bytes()
}

#[test]
fn custom_hasher_is_selected_by_set_and_named_in_the_stats() {
    let dir = scratch("hasher");
    // The documented command: no arguments.
    let o = run("custom_hasher", &dir, &[]);
    assert_ok(&o);
    let stats = json(&dir.join("custom_hasher.json"));
    assert_eq!(stats["stages"]["hash"], "screen_tile", "{stats:#}");
    assert_eq!(stats["config"]["hash"]["kind"], "screen_tile");
    assert_eq!(stats["config"]["hash"]["tile"], 8, "defaults filled in");
    assert_eq!(stats["accuracy"]["hit_agreement"], 1.0);
    assert_eq!(stats["accuracy"]["images_identical"], true);
    assert!(text(&o.stdout).contains("hash=screen_tile"));
    assert!(image_ok(&dir.join("custom_hasher.png"), 256));

    // The whole command line knows it: the listing, parameters with ranges, plans.
    let o = run("custom_hasher", &dir, &["pipelines", "--json"]);
    assert_ok(&o);
    let listing: Value = serde_json::from_slice(&o.stdout).unwrap();
    let v = listing["variants"]
        .as_array()
        .unwrap()
        .iter()
        .find(|v| v["name"] == "screen_tile")
        .expect("listed");
    assert_eq!(v["stage"], "hash");
    assert_eq!(v["backends"], serde_json::json!(["cpu"]));
    assert_eq!(v["params"][0]["max"], 1024.0);
    let o = run(
        "custom_hasher",
        &dir,
        &[
            "render",
            "--pipeline",
            "crsh",
            "--set",
            "hash.kind=screen_tile",
            "--set",
            "hash.tile=0",
            "--width",
            "16",
            "--out",
            "x.png",
        ],
    );
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("hash.tile"), "{}", text(&o.stderr));
    // No wgpu twin: refused before any device work, naming the backend that runs it.
    let o = run(
        "custom_hasher",
        &dir,
        &[
            "render",
            "--backend",
            "wgpu",
            "--pipeline",
            "crsh",
            "--set",
            "hash.kind=screen_tile",
            "--width",
            "16",
            "--out",
            "x.png",
        ],
    );
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
    let err = text(&o.stderr);
    assert!(
        err.contains("does not support the wgpu backend") && err.contains("--backend cpu"),
        "{err}"
    );
    let o = run(
        "custom_hasher",
        &dir,
        &[
            "ablate",
            "--pipelines",
            "crsh",
            "--set",
            "hash.kind=thesis,screen_tile",
            "--width",
            "24",
            "--depth",
            "1",
            "--repeat",
            "1",
            "--reference",
            "brute",
            "--quiet",
            "--out",
            "ab",
        ],
    );
    assert_ok(&o);
    let results = json(&dir.join("ab/results.json"));
    let kinds: Vec<&str> = results["cells"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["config"]["hash"]["kind"].as_str().unwrap())
        .collect();
    assert_eq!(kinds, ["thesis", "screen_tile"]);
    // Without the registration (the stock `crsh`), the name is unknown.
    let stock = crsh_cli::run(
        &crsh::Registries::builtin(),
        [
            "crsh",
            "render",
            "--pipeline",
            "crsh",
            "--set",
            "hash.kind=screen_tile",
        ],
    );
    let e = stock.unwrap_err();
    assert_eq!(e.exit_code(), crsh_cli::EXIT_USAGE);
    assert!(
        e.to_string().contains("unknown hash variant `screen_tile`"),
        "{e}"
    );
}

#[test]
fn custom_intersector_is_compared_in_an_ablation_plan() {
    let dir = scratch("intersector");
    let plan = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/examples/custom_intersector.toml"
    );
    let o = run(
        "custom_intersector",
        &dir,
        &[
            "ablate", "--plan", plan, "--out", "out", "--repeat", "1", "--quiet",
        ],
    );
    assert_ok(&o);
    let results = json(&dir.join("out/results.json"));
    let cells = results["cells"].as_array().unwrap();
    // 2 scenes × (brute + bvh + mesh_spheres × cull on / off).
    assert_eq!(cells.len(), 8);
    let mut ours = 0;
    for c in cells {
        assert_eq!(c["status"], "ok", "{c:#}");
        let m = &c["measures"];
        assert_eq!(m["accuracy"]["hit_agreement"], 1.0, "{c:#}");
        assert_eq!(m["accuracy"]["images_identical"], true, "{c:#}");
        if c["pipeline"] == "mesh_spheres" {
            ours += 1;
            assert_eq!(c["config"]["intersect"]["kind"], "mesh_spheres");
        }
    }
    assert_eq!(ours, 4);
    // Culling by mesh spheres does fewer ray-triangle tests than brute force on every scene.
    for scene in ["cornell-mirrors", "office-boxes"] {
        let tests = |pipeline: &str, cull: &str| {
            cells
                .iter()
                .find(|c| {
                    c["scene"] == scene
                        && c["pipeline"] == pipeline
                        && c["params"]
                            .get("intersect.cull")
                            .and_then(Value::as_str)
                            .unwrap_or("-")
                            == cull
                })
                .map(|c| c["measures"]["tests"]["ray_triangle"].as_u64().unwrap())
                .expect("cell present")
        };
        assert!(
            tests("mesh_spheres", "true") < tests("brute", "-"),
            "{scene}"
        );
        assert!(
            tests("mesh_spheres", "true") < tests("mesh_spheres", "false"),
            "{scene}"
        );
    }
    assert!(dir.join("out/report.html").is_file());
    // The stock registries refuse the plan: the variant is the example's.
    let stock = crsh_cli::run(
        &crsh::Registries::builtin(),
        [
            "crsh",
            "ablate",
            "--plan",
            plan,
            "--out",
            dir.join("stock").to_str().unwrap(),
        ],
    );
    assert_eq!(stock.unwrap_err().exit_code(), crsh_cli::EXIT_USAGE);
    // A hierarchy cannot use it: refused when the pipeline is built, naming the slots.
    let o = run(
        "custom_intersector",
        &dir,
        &[
            "render",
            "--pipeline",
            "crsh",
            "--set",
            "intersect.kind=mesh_spheres",
            "--width",
            "16",
            "--out",
            "x.png",
        ],
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(
        text(&o.stderr).contains("hierarchy, intersect"),
        "{}",
        text(&o.stderr)
    );
}
