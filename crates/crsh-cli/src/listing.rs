//! `crsh scenes`, `crsh pipelines` and `crsh adapters`.

use std::fmt::Write as _;
use std::path::Path;

use crsh::report::{count, stage_line};
use crsh::{BackendKind, Registries};
use crsh_core::{PipelineConfig, StageKind, StageVariantInfo};
use serde::Serialize;

use crate::args::{AdaptersArgs, PipelinesArgs, ScenesArgs};
use crate::error::{CliError, CliResult};
use crate::output;

/// A built-in scene and its counts.
#[derive(Debug, Serialize)]
struct BuiltinEntry {
    name: String,
    triangles: u64,
    meshes: u64,
    lights: u64,
    materials: u64,
}

/// A manifest found under the scenes directory.
#[derive(Debug, Serialize)]
struct ManifestRow {
    name: String,
    path: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    problem: Option<String>,
}

/// A parameterized built-in name (`glass-sphere-N`, `glass-shell-N`) and what it means.
#[derive(Debug, Serialize)]
struct PatternEntry {
    name: String,
    doc: String,
}

#[derive(Debug, Serialize)]
struct ScenesListing {
    builtins: Vec<BuiltinEntry>,
    patterns: Vec<PatternEntry>,
    scenes_dir: String,
    manifests: Vec<ManifestRow>,
    #[serde(skip_serializing_if = "Option::is_none")]
    note: Option<String>,
}

/// Runs `crsh scenes`.
pub fn scenes(args: &ScenesArgs) -> CliResult<()> {
    let mut builtins = Vec::new();
    for name in crsh_scene::builtin::NAMES {
        let scene = crsh_scene::builtin::build(name)
            .map_err(|e| CliError::runtime(format!("built-in scene `{name}`: {e}")))?;
        builtins.push(BuiltinEntry {
            name: name.to_string(),
            triangles: scene.triangle_count() as u64,
            meshes: scene.meshes.len() as u64,
            lights: scene.lights.len() as u64,
            materials: scene.materials.len() as u64,
        });
    }
    let dir = &args.scenes_dir;
    let (manifests, note) = manifests(dir)?;
    let patterns = crsh_scene::builtin::PATTERNS
        .iter()
        .map(|(name, doc)| PatternEntry {
            name: name.to_string(),
            doc: doc.to_string(),
        })
        .collect();
    let listing = ScenesListing {
        builtins,
        patterns,
        scenes_dir: dir.display().to_string(),
        manifests,
        note,
    };
    if args.json {
        output::print_stdout(&(to_json(&listing)? + "\n"))?;
    } else {
        output::print_stdout(&scenes_text(&listing))?;
    }
    Ok(())
}

/// The manifests under `dir`, or a note saying why there are none.
fn manifests(dir: &Path) -> CliResult<(Vec<ManifestRow>, Option<String>)> {
    if !dir.is_dir() {
        return Ok((
            Vec::new(),
            Some(format!(
                "scenes directory {} not found; pass --scenes-dir DIR or set CRSH_SCENES",
                dir.display()
            )),
        ));
    }
    let entries = crsh_scene::manifest::list(dir)
        .map_err(|e| CliError::runtime(format!("listing {}: {e}", dir.display())))?;
    let rows: Vec<ManifestRow> = entries
        .into_iter()
        .map(|m| ManifestRow {
            name: m.name,
            path: m.path.display().to_string(),
            problem: m.problem,
        })
        .collect();
    let note = rows
        .is_empty()
        .then(|| format!("no scene manifests (*.toml) under {}", dir.display()));
    Ok((rows, note))
}

fn scenes_text(l: &ScenesListing) -> String {
    let mut s = String::from("Built-in scenes (--scene NAME):\n");
    let w = (l.builtins.iter().map(|b| b.name.len()))
        .chain(l.patterns.iter().map(|p| p.name.len()))
        .max()
        .unwrap_or(0);
    for b in &l.builtins {
        let _ = writeln!(
            s,
            "  {:w$}  {:>17}  {:>12}  {}",
            b.name,
            count(b.triangles, "triangle", "triangles"),
            count(b.meshes, "mesh", "meshes"),
            count(b.lights, "light", "lights"),
        );
    }
    for p in &l.patterns {
        let _ = writeln!(s, "  {:w$}  {}", p.name, p.doc);
    }
    let _ = writeln!(s, "\nScene manifests in {} (--scene PATH):", l.scenes_dir);
    let w = l.manifests.iter().map(|m| m.name.len()).max().unwrap_or(0);
    for m in &l.manifests {
        let _ = writeln!(s, "  {:w$}  {}", m.name, m.path);
        if let Some(problem) = &m.problem {
            let _ = writeln!(s, "  {:w$}  (unusable: {problem})", "");
        }
    }
    if let Some(note) = &l.note {
        let _ = writeln!(s, "  note: {note}");
    }
    s
}

#[derive(Debug, Serialize)]
struct PresetEntry {
    name: String,
    doc: String,
    config: PipelineConfig,
}

/// A variant with the backends that implement it.
#[derive(Debug, Serialize)]
struct VariantEntry {
    #[serde(flatten)]
    info: StageVariantInfo,
    backends: Vec<BackendKind>,
}

#[derive(Debug, Serialize)]
struct PipelinesListing {
    presets: Vec<PresetEntry>,
    variants: Vec<VariantEntry>,
}

/// Runs `crsh pipelines`: the presets and every variant of the registries, CPU first, then
/// the variants only the wgpu backend has.
pub fn pipelines(args: &PipelinesArgs, registries: &Registries) -> CliResult<()> {
    let mut presets = Vec::new();
    for name in registries.preset_names() {
        let backend = if registries.cpu.preset(&name).is_some() {
            BackendKind::Cpu
        } else {
            BackendKind::Wgpu
        };
        let config = crate::render::pipeline_config(registries, &name, &[], backend)?;
        let doc = registries
            .cpu
            .presets()
            .iter()
            .chain(registries.wgpu.presets())
            .find(|p| p.name == name)
            .map(|p| p.doc.clone())
            .unwrap_or_default();
        presets.push(PresetEntry { name, doc, config });
    }
    let mut variants: Vec<VariantEntry> = Vec::new();
    for info in registries
        .cpu
        .variants()
        .iter()
        .chain(registries.wgpu.variants())
    {
        if variants
            .iter()
            .any(|v| v.info.stage == info.stage && v.info.name == info.name)
        {
            continue;
        }
        variants.push(VariantEntry {
            info: info.clone(),
            backends: registries.backends_of(info.stage, info.name),
        });
    }
    let listing = PipelinesListing { presets, variants };
    if args.json {
        output::print_stdout(&(to_json(&listing)? + "\n"))?;
    } else {
        output::print_stdout(&pipelines_text(&listing))?;
    }
    Ok(())
}

fn pipelines_text(l: &PipelinesListing) -> String {
    let mut s = String::from("Presets (--pipeline NAME):\n");
    let w = l.presets.iter().map(|p| p.name.len()).max().unwrap_or(0);
    for p in &l.presets {
        let _ = writeln!(s, "  {:w$}  {}", p.name, stage_line(&p.config));
        if !p.doc.is_empty() {
            let _ = writeln!(s, "  {:w$}  ({})", "", p.doc);
        }
    }
    s.push_str(
        "\nStage variants (--set STAGE.kind=VARIANT, --set STAGE.PARAM=VALUE, --set STAGE=off for optional stages; [backends]):\n",
    );
    for stage in StageKind::ALL {
        let variants: Vec<&VariantEntry> = l
            .variants
            .iter()
            .filter(|v| v.info.stage == stage)
            .collect();
        let _ = writeln!(
            s,
            "{stage}{}",
            if stage.optional() { " (optional)" } else { "" }
        );
        if variants.is_empty() {
            s.push_str("  (no variant registered)\n");
        }
        let w = variants
            .iter()
            .map(|v| v.info.name.len())
            .max()
            .unwrap_or(0);
        for v in variants {
            let backends: Vec<&str> = v.backends.iter().map(|b| b.name()).collect();
            let _ = writeln!(
                s,
                "  {:w$}  [{}] {}{}{}",
                v.info.name,
                backends.join(", "),
                v.info.doc,
                if v.info.scene_only {
                    " (whole-scene queries only)"
                } else {
                    ""
                },
                v.info
                    .unavailable
                    .map(|why| format!(" [{why}]"))
                    .unwrap_or_default()
            );
            for p in &v.info.params {
                let choices = if p.choices.is_empty() {
                    String::new()
                } else {
                    format!(" [{}]", p.choices.join("|"))
                };
                let range = if p.min.is_some() || p.max.is_some() {
                    format!(" ({})", p.range_text())
                } else {
                    String::new()
                };
                let _ = writeln!(
                    s,
                    "      {stage}.{} = {}{choices}{range}  {}",
                    p.name, p.default, p.doc
                );
            }
        }
    }
    s
}

/// One line describing a wgpu adapter: `name: backend, device type, driver[, software]`
/// (the PCI ids are in `--json`).
pub fn adapter_line(a: &crsh_wgpu::AdapterInfo) -> String {
    let mut parts = vec![a.backend.clone(), a.device_type.clone()];
    let driver = format!("{} {}", a.driver, a.driver_info);
    if !driver.trim().is_empty() {
        parts.push(format!("driver {}", driver.trim()));
    }
    if a.is_software() {
        parts.push("software renderer".into());
    }
    format!("{}: {}", a.name, parts.join(", "))
}

/// Runs `crsh adapters`.
pub fn adapters(args: &AdaptersArgs) -> CliResult<()> {
    let adapters = crsh_wgpu::enumerate_adapters();
    let text = if args.json {
        to_json(&adapters)? + "\n"
    } else if adapters.is_empty() {
        "no wgpu adapter found (on Linux without a GPU, install mesa-vulkan-drivers for lavapipe)\n"
            .to_string()
    } else {
        let mut s = String::from("wgpu adapters:\n");
        for a in &adapters {
            let _ = writeln!(s, "  {}", adapter_line(a));
        }
        s
    };
    output::print_stdout(&text)
}

fn to_json<T: Serialize>(v: &T) -> CliResult<String> {
    serde_json::to_string_pretty(v).map_err(|e| CliError::runtime(format!("JSON output: {e}")))
}
