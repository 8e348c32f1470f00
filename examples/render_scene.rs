//! Renders a shared scene from code with the `crsh` library: load a manifest, pick a preset,
//! render with an exact reference, write the PNG and the stats JSON, print the summary.
//!
//! ```sh
//! cargo run --release --example render_scene                       # cornell-sphere, crsh, 256 px
//! cargo run --release --example render_scene -- ../shared/scenes/sponza/sponza.toml bvh out 512
//! ```
//!
//! Arguments, all optional: `SCENE` (a manifest, an OBJ file or a built-in name; default the
//! shared `cornell/cornell-sphere.toml` under `CRSH_SCENES` or `../shared/scenes`, else the
//! built-in `cornell-mirrors`), `PRESET` (default `crsh`), `OUT_DIR` (default `.`), `WIDTH`
//! (default 256). Writes `OUT_DIR/render_scene.png` and `OUT_DIR/render_scene.json`.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use crsh::{Registries, RenderRequest, Renderer};

fn default_scene() -> String {
    let dir = std::env::var_os("CRSH_SCENES")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes"));
    let manifest = dir.join("cornell/cornell-sphere.toml");
    if manifest.is_file() {
        manifest.display().to_string()
    } else {
        eprintln!(
            "note: {} not found (set CRSH_SCENES); rendering the built-in cornell-mirrors",
            manifest.display()
        );
        "cornell-mirrors".to_string()
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let source = args.first().cloned().unwrap_or_else(default_scene);
    let preset = args.get(1).map_or("crsh", String::as_str);
    let out_dir = PathBuf::from(args.get(2).map_or(".", String::as_str));
    let width: u32 = args.get(3).map_or(Ok(256), |w| w.parse())?;

    // The built-in stage variants of both backends; a program would add its own here.
    let registries = Registries::builtin();
    let cfg = registries.preset(preset).ok_or_else(|| {
        format!(
            "no preset `{preset}` ({})",
            registries.preset_names().join(", ")
        )
    })?;

    let t0 = Instant::now();
    let (scene, load) = crsh::crsh_scene::load_with_report(&source)?;
    let scene_load_ms = t0.elapsed().as_secs_f64() * 1e3;
    for w in &load.warnings {
        eprintln!("warning: {w}");
    }
    let scene = Arc::new(scene);

    // The height follows the manifest camera's aspect; `bvh` is an exact and fast reference.
    let renderer = Renderer::new(&registries, Arc::clone(&scene));
    let request = RenderRequest::new()
        .with_width(width)
        .with_max_depth(3)
        .with_reference("bvh");
    let render = renderer.render(&cfg, &request, &mut |_| {})?;

    let png = out_dir.join("render_scene.png");
    let json = out_dir.join("render_scene.json");
    render.write_png(&png)?;
    let report = render.report(&scene, &source, &png.display().to_string(), scene_load_ms);
    std::fs::write(&json, report.to_json() + "\n")?;
    print!("{}", report.summary());
    println!("wrote     {} and {}", png.display(), json.display());
    Ok(())
}
