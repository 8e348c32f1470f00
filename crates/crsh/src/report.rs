//! What a frame reports: the stats JSON document (`crsh render --stats`), the summary text,
//! Mrays/s, and the accuracy of a frame against a reference image.
//!
//! The JSON layout is documented key by key in the README ("Stats JSON"). Every number comes
//! from the frame's [`Stats`]; this module only derives ratios (tests per ray, Mrays/s) and
//! shapes the document.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use crsh_core::metrics::psnr_rgba8;
use crsh_core::{
    AccuracyCounts, KindStats, LevelStats, PipelineConfig, RayKind, Stats, TestCounts,
};
use crsh_scene::Scene;
use serde::Serialize;

/// The scene, as reported.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SceneInfo {
    /// Scene name (built-in name or the manifest's `name`).
    pub name: String,
    /// What `--scene` said (built-in name or path).
    pub source: String,
    /// Triangles, degenerate ones included.
    pub triangles: u64,
    /// Vertices.
    pub vertices: u64,
    /// Meshes (contiguous triangle ranges).
    pub meshes: u64,
    /// Point lights.
    pub lights: u64,
    /// Materials.
    pub materials: u64,
    /// Zero-area triangles (loaded, never hit).
    pub degenerate_triangles: u64,
}

impl SceneInfo {
    /// The counts of `scene`, loaded from `source`.
    pub fn of(scene: &Scene, source: &str) -> SceneInfo {
        SceneInfo {
            name: scene.name.clone(),
            source: source.to_string(),
            triangles: scene.triangle_count() as u64,
            vertices: scene.positions.len() as u64,
            meshes: scene.meshes.len() as u64,
            lights: scene.lights.len() as u64,
            materials: scene.materials.len() as u64,
            degenerate_triangles: scene.degenerate_triangles as u64,
        }
    }
}

/// Rays per kind, plus totals.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RaysReport {
    /// Camera rays: one per pixel (rasterized or cast).
    pub primary: u64,
    /// Shadow rays (one per shaded point and light).
    pub shadow: u64,
    /// Reflection rays.
    pub reflection: u64,
    /// Refraction rays.
    pub refraction: u64,
    /// Ambient-occlusion rays.
    pub ao: u64,
    /// Diffuse bounce rays (counted per ray, not per path).
    pub diffuse: u64,
    /// Rays the frame driver traced through intersection stages (shadow + reflection +
    /// refraction, plus the camera rays when the primary variant casts them): the rays that
    /// `tests.brute_force` and `tests.per_traced_ray` count.
    pub traced: u64,
    /// All rays, primary included.
    pub total: u64,
}

/// Intersection tests, plus derived ratios. The counted fields are `None` (`null` in JSON,
/// "—" in the summary) when a stage that ran does not count its tests
/// ([`TestCounts::uncounted`]: Embree), never 0. The default is the report of no tests.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TestsReport {
    /// Bounding-volume tests (BVH node boxes, hierarchy nodes vs spheres).
    pub bounds: Option<u64>,
    /// Exact ray-triangle tests.
    pub ray_triangle: Option<u64>,
    /// `bounds + ray_triangle`.
    pub total: Option<u64>,
    /// What brute force would need: Σ over traced rays × scene triangles.
    pub brute_force: u64,
    /// `total / rays.traced` (0 when nothing was traced).
    pub per_traced_ray: Option<f64>,
    /// `total / brute_force` (0 when nothing was traced): the fraction of the brute-force work done.
    pub fraction_of_brute_force: Option<f64>,
    /// Object-hierarchy inner nodes visited (seed 001's "visited internal nodes"; 0 without
    /// an object hierarchy).
    pub inner_nodes: Option<u64>,
    /// Object-hierarchy leaves visited.
    pub leaves: Option<u64>,
    /// `inner_nodes / rays.traced`.
    pub inner_nodes_per_ray: Option<f64>,
    /// `leaves / rays.traced`.
    pub leaves_per_ray: Option<f64>,
}

impl Default for TestsReport {
    fn default() -> Self {
        TestsReport::new(&TestCounts::default(), 0)
    }
}

impl TestsReport {
    /// The counts `t` with their ratios over `traced` rays.
    pub fn new(t: &TestCounts, traced: u64) -> TestsReport {
        let known = |v: u64| (!t.uncounted).then_some(v);
        let known_f = |v: f64| (!t.uncounted).then_some(v);
        TestsReport {
            bounds: known(t.bounds),
            ray_triangle: known(t.ray_triangle),
            total: known(t.total),
            brute_force: t.brute_force,
            per_traced_ray: known_f(ratio(t.total as f64, traced as f64)),
            fraction_of_brute_force: known_f(ratio(t.total as f64, t.brute_force as f64)),
            inner_nodes: known(t.inner_nodes),
            leaves: known(t.leaves),
            inner_nodes_per_ray: known_f(ratio(t.inner_nodes as f64, traced as f64)),
            leaves_per_ray: known_f(ratio(t.leaves as f64, traced as f64)),
        }
    }

    /// Whether the test counts are unknown ([`TestCounts::uncounted`]).
    pub fn uncounted(&self) -> bool {
        self.total.is_none()
    }

    /// The counts again (unknown ones as 0, with [`TestCounts::uncounted`] set), e.g. to sum
    /// frames.
    pub fn counts(&self) -> TestCounts {
        TestCounts {
            bounds: self.bounds.unwrap_or(0),
            ray_triangle: self.ray_triangle.unwrap_or(0),
            total: self.total.unwrap_or(0),
            brute_force: self.brute_force,
            inner_nodes: self.inner_nodes.unwrap_or(0),
            leaves: self.leaves.unwrap_or(0),
            uncounted: self.uncounted(),
        }
    }
}

/// `Some(v)` as a grouped number, `None` as "—" (a count that was not counted).
fn group_opt(v: Option<u64>) -> String {
    v.map_or_else(|| "—".to_string(), group)
}

/// The keys of the per-kind and per-generation entries that count tests: `null` in the JSON
/// of a frame whose tests were not counted.
const TEST_KEYS: [&str; 4] = ["bounds", "ray_triangle", "inner_nodes", "leaves"];

/// Agreement with the reference intersector (`--reference`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct AccuracyReport {
    /// The reference intersector variant (e.g. `brute`).
    pub reference: String,
    /// Fraction of pixels whose primary hit is on the triangle the reference pipeline's
    /// primary stage (the CPU twin of this one) sees there, the background included; `null`
    /// when the primaries were not compared ([`AccuracyReport::with_primaries`]). Secondary
    /// rays start from the primaries, so a frame can agree on every traced ray and still
    /// show other surfaces.
    pub primary_agreement: Option<f64>,
    /// Pixels compared for [`Self::primary_agreement`].
    pub primary_pixels: u64,
    /// Pixels whose primary triangle differs from the reference's.
    pub primary_mismatches: u64,
    /// Fraction of traced rays whose hit/miss and nearest triangle match the reference
    /// (a different triangle at a `t` equal within 1e-6 relative counts as a match).
    pub hit_agreement: f64,
    /// PSNR in dB of the 8-bit image against a full render by the reference pipeline (same
    /// config, intersector replaced); `null` when the images are identical (JSON has no
    /// infinity), see `images_identical`.
    pub psnr_db: Option<f64>,
    /// Whether the 8-bit images are identical.
    pub images_identical: bool,
    /// Pixels whose 8-bit RGB differs from the reference image.
    pub pixels_differing: u64,
    /// Rays compared (every traced ray).
    pub rays_compared: u64,
    /// Rays that agree.
    pub agreeing: u64,
    /// Rays where one intersector hit and the other missed.
    pub hit_miss_mismatches: u64,
    /// Closest-hit rays that hit different triangles at different `t`.
    pub nearest_mismatches: u64,
    /// Mean `|t − t_reference|` over agreeing closest-hit rays that hit.
    pub mean_abs_t_error: f64,
    /// Secondary rays whose hit is the triangle they were spawned from (self-intersections,
    /// a lower bound; [`AccuracyCounts::self_hits`]).
    pub self_hits: u64,
    /// Wall time of the full reference render, ms (not part of `timings_ms`).
    pub reference_render_ms: f64,
}

/// Wall time spent before the frame (not part of `timings_ms`).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SetupTimes {
    /// Loading and validating the scene (OBJ / manifest parsing, normals, bounding spheres), ms.
    pub scene_load_ms: f64,
    /// Building the pipeline's stages for the scene (e.g. the object BVH of `intersect.kind=bvh`), ms.
    pub build_stages_ms: f64,
    /// Bytes of the tables the stages built and report ([`crsh_core::StageBuild::bytes`]:
    /// seed 001's hemisphere set of `raygen.offsets`); 0 when none does.
    #[serde(default)]
    pub stage_table_bytes: u64,
    /// The instruction set the CPU backend's hot loops ran in and, where it has more, what
    /// the CPU offers ([`crsh_cpu::isa::description`], e.g. `x86-64-v1 (CPU: x86-64-v4)`).
    #[serde(default)]
    pub isa: String,
}

impl SetupTimes {
    /// The setup of a run whose scene took `scene_load_ms` to load (the other times 0), with
    /// this build's [`SetupTimes::isa`].
    pub fn new(scene_load_ms: f64) -> SetupTimes {
        SetupTimes {
            scene_load_ms,
            isa: crsh_cpu::isa::description(),
            ..SetupTimes::default()
        }
    }
}

/// The whole `--stats` document.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StatsReport {
    /// crsh version that wrote the file.
    pub version: &'static str,
    /// The scene.
    pub scene: SceneInfo,
    /// Pipeline name (the preset or the pipeline file's `name`).
    pub pipeline: String,
    /// The full resolved pipeline (every stage, every parameter), as `--pipeline FILE.toml` reads it.
    pub config: PipelineConfig,
    /// The variant that ran in each filled slot, as the stage objects name themselves (equal to
    /// `config`'s kinds unless a program swapped a stage in).
    pub stages: BTreeMap<String, String>,
    /// Backend that ran it (`cpu`, `wgpu`).
    pub backend: String,
    /// The wgpu adapter that ran it (absent on the CPU).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub adapter: Option<AdapterReport>,
    /// Worker threads in the rayon pool.
    pub threads: usize,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Bounce limit (`--depth`).
    pub max_depth: u32,
    /// The PNG written.
    pub output: String,
    /// Rays per kind.
    pub rays: RaysReport,
    /// Intersection tests.
    pub tests: TestsReport,
    /// Per ray kind: rays, bounds and ray-triangle tests, tracing wall time (ms).
    pub per_kind: BTreeMap<String, KindStats>,
    /// Per ray-space-hierarchy level counters (empty without a hierarchy stage).
    pub levels: Vec<LevelStats>,
    /// Whole-mesh culling counters per ray kind (empty without mesh culling).
    pub mesh_culling: BTreeMap<String, crsh_core::CullStats>,
    /// Object-hierarchy counters of the `dual` traverser per ray kind and object node depth
    /// ([`crsh_core::Stats::object_levels`]; absent unless it ran with `objects = lbvh`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub object_levels: Vec<LevelStats>,
    /// Seed 003's coherent kd-tree traversal counters per ray kind: packets, nodes and
    /// packet-triangle tests (the paper's `N` and `I` per packet), culled packet-leaf tests
    /// (empty unless a coherent traversal ran).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub packets: BTreeMap<String, crsh_core::PacketStats>,
    /// What stages chose from the frame's data ([`crsh_core::Stats::choices`]; absent unless
    /// such a stage ran, e.g. the `auto_shape` hierarchy).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub choices: BTreeMap<String, String>,
    /// The most bytes the candidate arrays held at once (0 without a hierarchy).
    pub peak_candidate_bytes: u64,
    /// Per generation (bounce depth) and ray kind: rays, tests, tracing time and the
    /// histogram of the hierarchy's node cone half-angles (seed 004 fig. 4).
    pub generations: Vec<crsh_core::GenerationStats>,
    /// Wall time per stage, ms, plus `total` (the frame, excluding `reference`).
    pub timings_ms: BTreeMap<String, f64>,
    /// Device time per stage from GPU timestamp queries, ms (wgpu on adapters that have them).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub device_timings_ms: BTreeMap<String, f64>,
    /// Wall time before the frame: scene load and stage construction, ms.
    pub setup: SetupTimes,
    /// Millions of rays per second: per traced ray kind (rays / that kind's trace time),
    /// `overall` (all traced rays / all trace time) and `frame` (all rays / frame total).
    pub mrays_per_s: BTreeMap<String, f64>,
    /// Agreement with `--reference` (absent without it).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub accuracy: Option<AccuracyReport>,
    /// How the program set up its memory allocator (the `crsh` binary: whether glibc's
    /// `malloc` keeps freed memory, which changes the stage times); absent when the program
    /// did not say.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub allocator: Option<String>,
}

/// The adapter of a wgpu run.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct AdapterReport {
    /// Adapter name (e.g. `llvmpipe (LLVM 19.1.7, 256 bits)` for lavapipe).
    pub name: String,
    /// Graphics API backend (`vulkan`, `metal`, ...).
    pub backend: String,
    /// Device type (`DiscreteGpu`, `Cpu`, ...).
    pub device_type: String,
}

impl AdapterReport {
    /// The report of `info` (the adapter of a render is in [`crate::Render::adapter`]).
    pub fn of(info: &crsh_wgpu::AdapterInfo) -> AdapterReport {
        AdapterReport {
            name: info.name.clone(),
            backend: info.backend.clone(),
            device_type: info.device_type.clone(),
        }
    }
}

/// The inputs of a report besides the stats.
pub struct RunInfo<'a> {
    /// Scene counts.
    pub scene: SceneInfo,
    /// The resolved pipeline.
    pub config: &'a PipelineConfig,
    /// Backend name.
    pub backend: &'a str,
    /// The adapter of a wgpu run.
    pub adapter: Option<AdapterReport>,
    /// Rayon pool size.
    pub threads: usize,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Bounce limit.
    pub max_depth: u32,
    /// PNG path.
    pub output: String,
    /// Setup times.
    pub setup: SetupTimes,
}

fn ratio(a: f64, b: f64) -> f64 {
    if b > 0.0 {
        a / b
    } else {
        0.0
    }
}

/// Mrays/s per traced kind, `overall` and `frame` (see [`StatsReport::mrays_per_s`]).
pub fn mrays_per_s(stats: &Stats) -> BTreeMap<String, f64> {
    let mut out = BTreeMap::new();
    let (mut rays, mut ms) = (0u64, 0.0f64);
    for (kind, k) in &stats.per_kind {
        if k.trace_ms > 0.0 {
            out.insert(kind.clone(), k.rays as f64 / (k.trace_ms * 1e3));
            rays += k.rays;
            ms += k.trace_ms;
        }
    }
    if ms > 0.0 {
        out.insert("overall".into(), rays as f64 / (ms * 1e3));
    }
    let total = stats.time_ms("total");
    if total > 0.0 {
        out.insert("frame".into(), stats.rays.total() as f64 / (total * 1e3));
    }
    out
}

impl StatsReport {
    /// Shapes the report of one frame.
    pub fn new(run: RunInfo<'_>, stats: &Stats, accuracy: Option<AccuracyReport>) -> StatsReport {
        let r = &stats.rays;
        let traced = stats.traced_rays;
        StatsReport {
            version: env!("CARGO_PKG_VERSION"),
            scene: run.scene,
            pipeline: run.config.name.clone(),
            config: run.config.clone(),
            stages: stats.stages.clone(),
            backend: run.backend.to_string(),
            adapter: run.adapter,
            threads: run.threads,
            width: run.width,
            height: run.height,
            max_depth: run.max_depth,
            output: run.output,
            rays: RaysReport {
                primary: r.primary,
                shadow: r.shadow,
                reflection: r.reflection,
                refraction: r.refraction,
                ao: r.ao,
                diffuse: r.diffuse,
                traced,
                total: r.total(),
            },
            tests: TestsReport::new(&stats.tests, traced),
            per_kind: stats.per_kind.clone(),
            levels: stats.levels.clone(),
            mesh_culling: stats.mesh_culling.clone(),
            object_levels: stats.object_levels.clone(),
            packets: stats.packets.clone(),
            choices: stats.choices.clone(),
            peak_candidate_bytes: stats.peak_candidate_bytes,
            generations: stats.generations.clone(),
            timings_ms: stats.timings_ms.clone(),
            device_timings_ms: stats.device_timings_ms.clone(),
            setup: run.setup,
            mrays_per_s: mrays_per_s(stats),
            accuracy,
            allocator: None,
        }
    }

    /// The JSON text of the report (pretty-printed).
    pub fn to_json(&self) -> String {
        // Every field is a plain number, string, map with string keys or list, and every f64
        // is finite (ratios guard against 0, PSNR infinity is `null`).
        let mut v = match serde_json::to_value(self) {
            Ok(v) => v,
            Err(e) => return format!("{{\"error\": \"{e}\"}}"),
        };
        if self.tests.uncounted() {
            // The per-kind and per-generation counts are partial too: absent, not 0.
            let null_tests = |entry: &mut serde_json::Value| {
                for key in TEST_KEYS {
                    if let Some(x) = entry.get_mut(key) {
                        *x = serde_json::Value::Null;
                    }
                }
            };
            if let Some(m) = v["per_kind"].as_object_mut() {
                m.values_mut().for_each(null_tests);
            }
            if let Some(a) = v["generations"].as_array_mut() {
                a.iter_mut().for_each(null_tests);
            }
        }
        serde_json::to_string_pretty(&v).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
    }

    /// The human-readable summary printed on stdout.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        let sc = &self.scene;
        let _ = writeln!(
            s,
            "scene     {} ({}): {}, {} degenerate, {}, {}",
            sc.name,
            sc.source,
            count(sc.triangles, "triangle", "triangles"),
            group(sc.degenerate_triangles),
            count(sc.meshes, "mesh", "meshes"),
            count(sc.lights, "light", "lights"),
        );
        let _ = writeln!(
            s,
            "pipeline  {} on {} ({} threads), {}x{}, depth {}: {}",
            self.pipeline,
            self.backend,
            self.threads,
            self.width,
            self.height,
            self.max_depth,
            if self.stages.is_empty() {
                stage_line(&self.config)
            } else {
                names_line(&self.stages)
            },
        );
        let r = &self.rays;
        let mut kinds = format!(
            "primary {} | shadow {} | reflection {} | refraction {}",
            group(r.primary),
            group(r.shadow),
            group(r.reflection),
            group(r.refraction),
        );
        // Seed 001's kinds only where a generator made them, so Whitted lines stay as they were.
        for (name, n) in [("ao", r.ao), ("diffuse", r.diffuse)] {
            if n > 0 {
                let _ = write!(kinds, " | {name} {}", group(n));
            }
        }
        let offset_ended: u64 = self.per_kind.values().map(|k| k.offset_ended).sum();
        if offset_ended > 0 {
            let _ = write!(kinds, " | ended by offsets {}", group(offset_ended));
        }
        let _ = writeln!(s, "rays      {kinds} | traced {}", group(r.traced));
        let t = &self.tests;
        match (t.per_traced_ray, t.fraction_of_brute_force) {
            (Some(per_ray), Some(fraction)) => {
                let _ = writeln!(
                    s,
                    "tests     bounds {} | ray-triangle {} | total {} | brute force {} | {per_ray:.1} per traced ray ({:.4}% of brute force)",
                    group_opt(t.bounds),
                    group_opt(t.ray_triangle),
                    group_opt(t.total),
                    group(t.brute_force),
                    fraction * 100.0,
                );
            }
            _ => {
                let _ = writeln!(
                    s,
                    "tests     bounds — | ray-triangle — | total — | brute force {} (not counted: a stage that ran does not report its tests)",
                    group(t.brute_force),
                );
            }
        }
        if let (Some(inner), Some(leaves)) = (t.inner_nodes, t.leaves) {
            if inner + leaves > 0 {
                let _ = writeln!(
                    s,
                    "visits    inner nodes {} | leaves {} | per traced ray {:.2} / {:.2}",
                    group(inner),
                    group(leaves),
                    t.inner_nodes_per_ray.unwrap_or(0.0),
                    t.leaves_per_ray.unwrap_or(0.0),
                );
            }
        }
        for (key, choice) in &self.choices {
            let _ = writeln!(s, "choice    {key}: {choice}");
        }
        for kind in RayKind::ALL {
            let rows: Vec<&LevelStats> = self
                .object_levels
                .iter()
                .filter(|l| l.ray_kind == kind.name())
                .collect();
            if rows.is_empty() {
                continue;
            }
            let tests: u64 = rows.iter().map(|l| l.tests).sum();
            let hits: u64 = rows.iter().map(|l| l.hits).sum();
            let deepest = rows.iter().map(|l| l.level).max().unwrap_or(0);
            let _ = writeln!(
                s,
                "objects   {}: {} object-node tests at depths 0-{deepest}, {:.1} % passed",
                kind.name(),
                group(tests),
                100.0 * ratio(hits as f64, tests as f64),
            );
        }
        for (kind, p) in &self.packets {
            let _ = writeln!(
                s,
                "packets   {kind}: {} packets | N {:.2} nodes / packet | I {:.2} tests / packet | \
                 culled {:.1} % | {} groups | {} rays alone",
                group(p.packets),
                p.nodes_per_packet(),
                p.tests_per_packet(),
                p.culled_fraction() * 100.0,
                group(p.groups),
                group(p.single_rays),
            );
        }
        s.push_str(&generation_lines(&self.generations, self.tests.uncounted()));
        let _ = writeln!(
            s,
            "setup ms  scene load {:.1} | build stages {:.1}{} | isa {}",
            self.setup.scene_load_ms,
            self.setup.build_stages_ms,
            if self.setup.stage_table_bytes > 0 {
                format!(" | stage tables {} B", group(self.setup.stage_table_bytes))
            } else {
                String::new()
            },
            self.setup.isa,
        );
        if let Some(a) = &self.adapter {
            let _ = writeln!(s, "adapter   {} ({}, {})", a.name, a.backend, a.device_type);
        }
        let _ = writeln!(s, "time ms   {}", timing_line(&self.timings_ms));
        if !self.device_timings_ms.is_empty() {
            let _ = writeln!(s, "device ms {}", timing_line(&self.device_timings_ms));
        }
        let mut mr: Vec<String> = RayKind::ALL
            .iter()
            .filter_map(|k| {
                self.mrays_per_s
                    .get(k.name())
                    .map(|v| format!("{} {v:.2}", k.name()))
            })
            .collect();
        for key in ["overall", "frame"] {
            if let Some(v) = self.mrays_per_s.get(key) {
                mr.push(format!("{key} {v:.2}"));
            }
        }
        let _ = writeln!(
            s,
            "Mrays/s   {}",
            if mr.is_empty() {
                "(no rays traced)".to_string()
            } else {
                mr.join(" | ")
            }
        );
        if let Some(a) = &self.accuracy {
            let psnr = match a.psnr_db {
                Some(db) => format!(
                    "PSNR {db:.2} dB, {} pixels differ",
                    group(a.pixels_differing)
                ),
                None => "images identical".to_string(),
            };
            let primary = match a.primary_agreement {
                Some(p) => format!(
                    "primary agreement {p:.6} over {} pixels ({} see another triangle); ",
                    group(a.primary_pixels),
                    group(a.primary_mismatches)
                ),
                None => String::new(),
            };
            let _ = writeln!(
                s,
                "accuracy  vs {}: {primary}hit agreement {:.6} over {} rays ({} hit/miss, {} nearest mismatches); {}",
                a.reference,
                a.hit_agreement,
                group(a.rays_compared),
                group(a.hit_miss_mismatches),
                group(a.nearest_mismatches),
                psnr,
            );
        }
        s
    }
}

/// One line per generation of secondary rays, when the frame traced more than one: each
/// kind's rays, tests per ray and, with a ray-space hierarchy, its lowest nodes' cone
/// half-angles (mean and widest; tests per ray "—" when `uncounted`). Empty for a single
/// generation.
fn generation_lines(generations: &[crsh_core::GenerationStats], uncounted: bool) -> String {
    let mut numbers: Vec<u32> = generations
        .iter()
        .filter(|g| g.generation > 0)
        .map(|g| g.generation)
        .collect();
    numbers.dedup();
    if numbers.len() < 2 {
        return String::new();
    }
    let mut s = String::new();
    for n in numbers {
        let parts: Vec<String> = generations
            .iter()
            .filter(|g| g.generation == n && g.rays > 0)
            .map(|g| {
                let tests = if uncounted {
                    "—".to_string()
                } else {
                    format!("{:.1}", (g.bounds + g.ray_triangle) as f64 / g.rays as f64)
                };
                let mut part = format!("{} {} ({tests} tests/ray", g.ray_kind, group(g.rays));
                if g.nodes > 0 {
                    let _ = write!(
                        part,
                        ", {} cones, mean {:.2}° max {:.1}°",
                        group(g.nodes),
                        g.mean_half_angle_deg(),
                        g.max_half_angle_deg
                    );
                }
                part.push(')');
                part
            })
            .collect();
        if !parts.is_empty() {
            let _ = writeln!(s, "gen {n:<5} {}", parts.join(" | "));
        }
    }
    s
}

/// `primary=raster raygen=whitted ... intersect=bvh shade=phong`.
pub fn stage_line(cfg: &PipelineConfig) -> String {
    crsh_core::StageKind::ALL
        .iter()
        .filter_map(|&k| cfg.slot(k).map(|spec| format!("{k}={}", spec.kind)))
        .collect::<Vec<_>>()
        .join(" ")
}

/// `primary=raster raygen=whitted ...` from the stage names a frame recorded
/// ([`Stats::stages`]), in pipeline order.
pub fn names_line(names: &BTreeMap<String, String>) -> String {
    crsh_core::StageKind::ALL
        .iter()
        .filter_map(|k| names.get(k.key()).map(|n| format!("{k}={n}")))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Compares a frame's 8-bit image with the reference pipeline's and shapes the accuracy
/// report: the hit agreement of `counts` (the frame's [`Stats::accuracy`]), PSNR and differing
/// pixels; `reference_render_ms` is the reference render's wall time.
///
/// # Panics
/// If the images differ in size.
pub fn compare_images(
    reference: &str,
    counts: &AccuracyCounts,
    rgba: &[u8],
    ref_rgba: &[u8],
    reference_render_ms: f64,
) -> AccuracyReport {
    let psnr = psnr_rgba8(rgba, ref_rgba);
    let pixels_differing = rgba
        .chunks_exact(4)
        .zip(ref_rgba.chunks_exact(4))
        .filter(|(a, b)| a[..3] != b[..3])
        .count() as u64;
    AccuracyReport {
        reference: reference.to_string(),
        primary_agreement: None,
        primary_pixels: 0,
        primary_mismatches: 0,
        hit_agreement: counts.hit_agreement(),
        psnr_db: psnr.is_finite().then_some(psnr),
        images_identical: pixels_differing == 0,
        pixels_differing,
        rays_compared: counts.rays,
        agreeing: counts.agreeing,
        hit_miss_mismatches: counts.hit_miss_mismatches,
        nearest_mismatches: counts.nearest_mismatches,
        mean_abs_t_error: counts.mean_abs_t_error(),
        self_hits: counts.self_hits,
        reference_render_ms,
    }
}

impl AccuracyReport {
    /// The report with the primary visibility compared: `got` and `want` hold the triangle
    /// each pixel's primary hit is on (the frame's and the reference's,
    /// [`crsh_core::Frame::primary_triangles`]); a pixel one of them lacks counts as a
    /// mismatch.
    pub fn with_primaries(self, got: &[u32], want: &[u32]) -> AccuracyReport {
        let pixels = got.len().max(want.len()) as u64;
        let same = got.iter().zip(want).filter(|(a, b)| a == b).count() as u64;
        AccuracyReport {
            primary_agreement: Some(if pixels == 0 {
                1.0
            } else {
                same as f64 / pixels as f64
            }),
            primary_pixels: pixels,
            primary_mismatches: pixels - same,
            ..self
        }
    }
}

/// Stage timings in pipeline order, then any others, then `reference` and `total`.
fn timing_line(t: &BTreeMap<String, f64>) -> String {
    const ORDER: [&str; 13] = crsh_core::STAGE_TIMINGS;
    let mut keys: Vec<&str> = ORDER
        .iter()
        .copied()
        .filter(|k| t.contains_key(*k))
        .collect();
    keys.extend(
        t.keys()
            .map(String::as_str)
            .filter(|k| !ORDER.contains(k) && *k != "reference" && *k != "total"),
    );
    keys.extend(
        ["reference", "total"]
            .into_iter()
            .filter(|k| t.contains_key(*k)),
    );
    if keys.is_empty() {
        return "(none)".into();
    }
    keys.iter()
        .map(|k| format!("{k} {:.1}", t[*k]))
        .collect::<Vec<_>>()
        .join(" | ")
}

/// `n` grouped, with the singular or plural noun: `1 mesh`, `1,024 meshes`.
pub fn count(n: u64, one: &str, many: &str) -> String {
    format!("{} {}", group(n), if n == 1 { one } else { many })
}

/// `1234567` → `1,234,567`.
pub fn group(n: u64) -> String {
    let digits = n.to_string();
    let mut out = String::with_capacity(digits.len() + digits.len() / 3);
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stats() -> Stats {
        let mut s = Stats::default();
        s.rays.primary = 16;
        s.rays.shadow = 10;
        s.rays.reflection = 4;
        s.add_bounds(30);
        s.add_ray_triangle(12);
        s.tests.brute_force = 14 * 100;
        s.traced_rays = 14;
        s.per_kind.insert(
            "primary".into(),
            KindStats {
                rays: 16,
                ..Default::default()
            },
        );
        s.per_kind.insert(
            "shadow".into(),
            KindStats {
                rays: 10,
                bounds: 20,
                ray_triangle: 8,
                trace_ms: 2.0,
                ..Default::default()
            },
        );
        s.per_kind.insert(
            "reflection".into(),
            KindStats {
                rays: 4,
                bounds: 10,
                ray_triangle: 4,
                trace_ms: 0.5,
                ..Default::default()
            },
        );
        s.generation_mut(1, RayKind::Shadow).rays = 6;
        let g = s.generation_mut(1, RayKind::Reflection);
        g.rays = 4;
        g.bounds = 10;
        g.ray_triangle = 4;
        g.add_half_angles([0.01, 0.03]);
        s.generation_mut(2, RayKind::Shadow).rays = 4;
        s.add_object_level(RayKind::Shadow, 0, 5, 4);
        s.add_object_level(RayKind::Shadow, 3, 15, 6);
        s.timings_ms.insert("total".into(), 10.0);
        s.timings_ms.insert("primary".into(), 1.0);
        s.timings_ms.insert("intersection".into(), 2.5);
        s.accuracy = Some(AccuracyCounts {
            rays: 14,
            agreeing: 14,
            ..Default::default()
        });
        s
    }

    fn report(acc: Option<AccuracyReport>) -> StatsReport {
        let cfg = PipelineConfig::whitted("bvh", "bvh");
        let scene_info = SceneInfo {
            name: "t".into(),
            source: "t".into(),
            triangles: 100,
            vertices: 300,
            meshes: 2,
            lights: 1,
            materials: 1,
            degenerate_triangles: 0,
        };
        StatsReport::new(
            RunInfo {
                scene: scene_info,
                config: &cfg,
                backend: "cpu",
                adapter: None,
                threads: 2,
                width: 4,
                height: 4,
                max_depth: 1,
                output: "x.png".into(),
                setup: SetupTimes {
                    build_stages_ms: 2.5,
                    ..SetupTimes::new(1.5)
                },
            },
            &stats(),
            acc,
        )
    }

    #[test]
    fn accuracy_of_identical_and_different_images() {
        let counts = AccuracyCounts {
            rays: 10,
            agreeing: 9,
            hit_miss_mismatches: 1,
            nearest_mismatches: 0,
            ..Default::default()
        };
        let a = vec![10u8, 20, 30, 255, 40, 50, 60, 255];
        let same = compare_images("brute", &counts, &a, &a, 1.0);
        assert_eq!(same.psnr_db, None);
        assert!(same.images_identical);
        assert_eq!(same.pixels_differing, 0);
        assert!((same.hit_agreement - 0.9).abs() < 1e-12);
        let mut b = a.clone();
        b[4] = 41;
        let diff = compare_images("brute", &counts, &a, &b, 1.0);
        assert!(!diff.images_identical);
        assert_eq!(diff.pixels_differing, 1);
        assert!(diff.psnr_db.unwrap() > 40.0);
        assert_eq!(diff.primary_agreement, None);
        let p = diff.clone().with_primaries(&[1, 2, 3, 4], &[1, 2, 9, 4]);
        assert_eq!(
            (p.primary_agreement, p.primary_pixels, p.primary_mismatches),
            (Some(0.75), 4, 1)
        );
        let short = diff.with_primaries(&[1, 2], &[1, 2, 3]);
        assert_eq!((short.primary_pixels, short.primary_mismatches), (3, 1));
    }

    #[test]
    fn uncounted_tests_are_absent_not_zero() {
        let mut r = report(None);
        let mut counts = r.tests.counts();
        counts.uncounted = true;
        r.tests = TestsReport::new(&counts, r.rays.traced);
        assert!(r.tests.uncounted());
        assert_eq!((r.tests.total, r.tests.per_traced_ray), (None, None));
        assert_eq!(r.tests.brute_force, 1400, "brute force's count is known");
        let v: serde_json::Value = serde_json::from_str(&r.to_json()).unwrap();
        assert!(v["tests"]["bounds"].is_null() && v["tests"]["total"].is_null());
        assert!(v["per_kind"]["shadow"]["bounds"].is_null());
        assert!(v["per_kind"]["shadow"]["ray_triangle"].is_null());
        assert_eq!(v["per_kind"]["shadow"]["rays"], 10);
        assert!(v["generations"][1]["bounds"].is_null());
        let text = r.summary();
        assert!(
            text.contains("tests     bounds — | ray-triangle — | total —"),
            "{text}"
        );
        assert!(!text.contains("visits "), "{text}");
        // A counted report keeps its numbers.
        let v: serde_json::Value = serde_json::from_str(&report(None).to_json()).unwrap();
        assert_eq!(v["per_kind"]["shadow"]["bounds"], 20);
    }

    #[test]
    fn derived_numbers() {
        let r = report(None);
        assert_eq!(r.rays.traced, 14);
        assert_eq!(r.rays.total, 30);
        assert_eq!(r.tests.total, Some(42));
        assert!((r.tests.per_traced_ray.unwrap() - 3.0).abs() < 1e-12);
        assert!((r.tests.fraction_of_brute_force.unwrap() - 0.03).abs() < 1e-12);
        // 10 rays in 2 ms = 5000 rays/s = 0.005 Mrays/s.
        assert!((r.mrays_per_s["shadow"] - 0.005).abs() < 1e-12);
        assert!((r.mrays_per_s["reflection"] - 0.008).abs() < 1e-12);
        assert!((r.mrays_per_s["overall"] - 14.0 / 2500.0).abs() < 1e-12);
        assert!((r.mrays_per_s["frame"] - 30.0 / 10000.0).abs() < 1e-12);
        assert!(
            !r.mrays_per_s.contains_key("primary"),
            "primary has no trace time"
        );
    }

    #[test]
    fn json_has_required_keys_and_null_psnr() {
        let acc = AccuracyReport {
            reference: "brute".into(),
            primary_agreement: Some(1.0),
            primary_pixels: 4,
            primary_mismatches: 0,
            hit_agreement: 1.0,
            psnr_db: None,
            images_identical: true,
            pixels_differing: 0,
            rays_compared: 14,
            agreeing: 14,
            hit_miss_mismatches: 0,
            nearest_mismatches: 0,
            mean_abs_t_error: 0.0,
            self_hits: 0,
            reference_render_ms: 3.0,
        };
        let v: serde_json::Value = serde_json::from_str(&report(Some(acc)).to_json()).unwrap();
        for k in [
            "scene",
            "pipeline",
            "config",
            "backend",
            "width",
            "height",
            "max_depth",
            "rays",
            "tests",
            "per_kind",
            "levels",
            "timings_ms",
            "setup",
            "mrays_per_s",
            "threads",
            "version",
            "accuracy",
        ] {
            assert!(v.get(k).is_some(), "missing {k}");
        }
        assert!(v["accuracy"]["psnr_db"].is_null());
        assert_eq!(v["accuracy"]["images_identical"], true);
        assert_eq!(v["config"]["intersect"]["kind"], "bvh");
        let no_acc: serde_json::Value = serde_json::from_str(&report(None).to_json()).unwrap();
        assert!(no_acc.get("accuracy").is_none());
    }

    #[test]
    fn summary_mentions_everything() {
        let s = report(None).summary();
        for needle in [
            "100 triangles",
            "2 meshes",
            "1 light",
            "shadow 10",
            "bounds 30",
            "ray-triangle 12",
            "total 42",
            "brute force 1,400",
            "3.0 per traced ray",
            "primary 1.0 | intersection 2.5 | total 10.0",
            "scene load 1.5 | build stages 2.5",
            "Mrays/s",
            "gen 1     shadow 6 (0.0 tests/ray) | reflection 4 (3.5 tests/ray, 2 cones, mean 1.15° max 1.7°)",
            "gen 2     shadow 4 (0.0 tests/ray)",
            "objects   shadow: 20 object-node tests at depths 0-3, 50.0 % passed",
        ] {
            assert!(s.contains(needle), "summary lacks `{needle}`:\n{s}");
        }
    }

    #[test]
    fn grouping() {
        assert_eq!(group(0), "0");
        assert_eq!(group(999), "999");
        assert_eq!(group(1000), "1,000");
        assert_eq!(group(1234567), "1,234,567");
        assert_eq!(count(1, "mesh", "meshes"), "1 mesh");
        assert_eq!(count(0, "mesh", "meshes"), "0 meshes");
        assert_eq!(count(1000, "light", "lights"), "1,000 lights");
    }
}
