//! What an ablation measured: one [`CellResult`] per cell, the machine it ran on, and the
//! writers of `results.json`, `results.csv` and (for plans with `frames`) `frames.csv`.
//!
//! A frames cell's [`Measures`] cover its whole sequence of frames: counters and times are
//! summed over the frames (its `total` is every frame's update and render, the updates also
//! under `update`), and [`Measures::frames`] holds one [`FrameMeasure`] per frame and their
//! [`FramesTotals`].

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;

use crsh_core::{KindStats, LevelStats, PipelineConfig, RayKind, STAGE_TIMINGS};
use serde::{Deserialize, Serialize};

use super::plan::Plan;

/// The `results.csv` columns of each ray kind's [`crsh_core::PacketStats`], after
/// `packets_KIND_`: packets traced, the paper's `N` (nodes per packet) and `I` (packet-triangle
/// tests per packet), the fraction of packet-leaf tests culled (table 4.2), coherent groups,
/// rays traced alone.
pub const PACKET_COLUMNS: [&str; 6] = [
    "packets",
    "n",
    "i",
    "culled_fraction",
    "groups",
    "single_rays",
];

/// Median, minimum and maximum of a set of timed runs, ms.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TimeSummary {
    /// Median (the mean of the two middle values for an even count).
    pub median: f64,
    /// Fastest run.
    pub min: f64,
    /// Slowest run.
    pub max: f64,
}

impl TimeSummary {
    /// The summary of `values` (all zero when empty).
    pub fn of(values: &[f64]) -> TimeSummary {
        if values.is_empty() {
            return TimeSummary::default();
        }
        let mut v = values.to_vec();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        let median = if n % 2 == 1 {
            v[n / 2]
        } else {
            (v[n / 2 - 1] + v[n / 2]) / 2.0
        };
        TimeSummary {
            median,
            min: v[0],
            max: v[n - 1],
        }
    }
}

/// Rays per kind of one frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CellRays {
    /// Camera rays.
    pub primary: u64,
    /// Shadow rays.
    pub shadow: u64,
    /// Reflection rays.
    pub reflection: u64,
    /// Refraction rays.
    pub refraction: u64,
    /// Ambient-occlusion rays (seed 001).
    #[serde(default)]
    pub ao: u64,
    /// Diffuse bounce rays (seed 001).
    #[serde(default)]
    pub diffuse: u64,
    /// Rays that went through the intersection stages.
    pub traced: u64,
}

/// Intersection tests of one frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CellTests {
    /// Bounding-volume tests.
    pub bounds: u64,
    /// Ray-triangle tests.
    pub ray_triangle: u64,
    /// `bounds + ray_triangle`.
    pub total: u64,
    /// What brute force would need.
    pub brute_force: u64,
    /// `total / rays.traced`.
    pub per_ray: f64,
    /// `total / brute_force`.
    pub fraction: f64,
    /// Object-hierarchy inner nodes visited (seed 001's "visited internal nodes"; not part of
    /// `total`, 0 for intersectors that do not count them).
    #[serde(default)]
    pub inner_nodes: u64,
    /// Object-hierarchy leaves visited (not part of `total`).
    #[serde(default)]
    pub leaves: u64,
    /// `inner_nodes / rays.traced`.
    #[serde(default)]
    pub inner_nodes_per_ray: f64,
    /// `leaves / rays.traced`.
    #[serde(default)]
    pub leaves_per_ray: f64,
    /// A stage of the cell does not count its tests (Embree): every count above is unknown,
    /// and tables and CSV leave it blank ("—"), never 0.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub uncounted: bool,
}

impl CellTests {
    /// Tests per ray with one decimal, or "—" when they are [`CellTests::uncounted`].
    pub fn per_ray_text(&self) -> String {
        if self.uncounted {
            "—".to_string()
        } else {
            format!("{:.1}", self.per_ray)
        }
    }
}

/// One ray kind's work per ray, from its [`KindStats`]: what seed 001's tables set against the
/// baseline. Every figure is 0 when the kind traced no ray.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct KindPerRay {
    /// Object-hierarchy inner nodes visited per ray.
    pub inner_nodes: f64,
    /// Object-hierarchy leaves visited per ray.
    pub leaves: f64,
    /// Bounding-volume tests per ray.
    pub bounds: f64,
    /// Ray-triangle tests per ray.
    pub ray_triangle: f64,
    /// Bounding-volume and ray-triangle tests per ray.
    pub tests: f64,
    /// `offset_ended / rays`: the fraction of rays whose origin offset passed their end
    /// (seed 001 fig. 4).
    pub offset_ended_fraction: f64,
}

impl KindPerRay {
    /// The per-ray figures of `k`.
    pub fn of(k: &KindStats) -> KindPerRay {
        let per = |n: u64| {
            if k.rays > 0 {
                n as f64 / k.rays as f64
            } else {
                0.0
            }
        };
        KindPerRay {
            inner_nodes: per(k.inner_nodes),
            leaves: per(k.leaves),
            bounds: per(k.bounds),
            ray_triangle: per(k.ray_triangle),
            tests: per(k.bounds + k.ray_triangle),
            offset_ended_fraction: per(k.offset_ended),
        }
    }
}

/// Agreement with the plan's reference.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CellAccuracy {
    /// The reference intersector.
    pub reference: String,
    /// Fraction of pixels whose primary hit is on the reference pipeline's triangle (`null`
    /// in results written before it was measured).
    #[serde(default)]
    pub primary_agreement: Option<f64>,
    /// Fraction of traced rays whose hit agrees with the reference.
    pub hit_agreement: f64,
    /// PSNR (dB) of the image against the reference pipeline's image; `null` when identical.
    pub psnr_db: Option<f64>,
    /// Whether the 8-bit images are identical.
    pub images_identical: bool,
    /// Pixels whose 8-bit RGB differs.
    pub pixels_differing: u64,
    /// Rays compared.
    pub rays_compared: u64,
    /// Rays where one hit and the other missed.
    pub hit_miss_mismatches: u64,
    /// Closest-hit rays that hit different triangles at different `t`.
    pub nearest_mismatches: u64,
    /// Mean `|t − t_reference|` over agreeing closest-hit rays that hit (scene units).
    pub mean_abs_t_error: f64,
    /// Secondary rays of the cell whose hit is the triangle they were spawned from
    /// (self-intersections, `AccuracyCounts::self_hits`; a lower bound).
    pub self_hits: u64,
    /// `self_hits / rays_compared` (0 when nothing was compared).
    pub self_hit_rate: f64,
}

/// The measurements of a cell that ran.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Measures {
    /// Triangles in the scene.
    pub triangles: u64,
    /// Rays per kind.
    pub rays: CellRays,
    /// Intersection tests.
    pub tests: CellTests,
    /// Per ray kind: rays, tests, object-hierarchy visits, rays ended by origin offsets, and
    /// the median tracing time (ms).
    pub per_kind: BTreeMap<String, KindStats>,
    /// Per ray kind: [`KindPerRay`] of `per_kind` (derived; rebuilt from `per_kind` by
    /// [`Measures::kind_per_ray`] when an older results.json lacks it).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub per_kind_per_ray: BTreeMap<String, KindPerRay>,
    /// Per hierarchy level counters (thesis numbering; empty without a hierarchy).
    pub levels: Vec<LevelStats>,
    /// Whole-mesh culling counters per ray kind (empty without mesh culling).
    pub mesh_culling: BTreeMap<String, crsh_core::CullStats>,
    /// Seed 003's coherent kd-tree traversal counters per ray kind (`N`, `I`, culling; empty
    /// unless a coherent traversal ran).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub packets: BTreeMap<String, crsh_core::PacketStats>,
    /// The most bytes the candidate arrays held at once.
    pub peak_candidate_bytes: u64,
    /// Whether every counter was identical in every timed run (they are deterministic).
    pub counters_equal_across_repeats: bool,
    /// Per stage key and `total`: median, min and max over the timed runs, ms.
    pub timings_ms: BTreeMap<String, TimeSummary>,
    /// Per stage key: device time from GPU timestamp queries (wgpu cells on adapters that
    /// have them), median, min and max over the timed runs, ms. Empty on the CPU.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub device_timings_ms: BTreeMap<String, TimeSummary>,
    /// Mrays/s per traced kind, `overall` and `frame`, from the median times.
    pub mrays_per_s: BTreeMap<String, f64>,
    /// Building the stages (e.g. an object BVH), ms, once per cell.
    pub build_stages_ms: f64,
    /// Agreement with the reference (absent with `reference = "none"`). For a frames cell:
    /// over the checked frames (the lowest hit agreement and PSNR, the counts summed).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub accuracy: Option<CellAccuracy>,
    /// The frames of a frames cell (plans with `frames`): one row per frame and their totals.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames: Option<CellFrames>,
}

/// One frame of a frames cell: its update and rebuild, its render, its counters. Times are
/// medians over the timed sequences, ms.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FrameMeasure {
    /// Frame number.
    pub frame: u32,
    /// Scene time, seconds.
    pub time_s: f32,
    /// What the acceleration structures' update was (`bvh rebuild`, `bvh refit`,
    /// `spheres + crsh rebuild + brute rebuild`, `spheres + dual refit + brute rebuild`, ...).
    pub structure: String,
    /// Triangles moved this frame.
    pub moved_triangles: u64,
    /// Moving the geometry.
    pub scene_ms: f64,
    /// The bounding spheres (ray-space hierarchies only).
    pub spheres_ms: f64,
    /// Uploading the scene (wgpu only).
    pub upload_ms: f64,
    /// The acceleration structure: the intersector's build or refit, plus the spheres.
    pub structure_ms: f64,
    /// The whole update: scene, spheres, upload and every stage's build.
    pub update_ms: f64,
    /// Tracing (hash to final tests, every ray kind).
    pub trace_ms: f64,
    /// The render (primary visibility to shading).
    pub render_ms: f64,
    /// `update_ms + render_ms` (of the same sequence, then the median).
    pub frame_ms: f64,
    /// Rays traced.
    pub traced_rays: u64,
    /// Bounds and ray-triangle tests.
    pub tests: u64,
    /// `tests / traced_rays`.
    pub tests_per_ray: f64,
    /// Agreement with the reference, on the checked frames.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hit_agreement: Option<f64>,
}

/// Sums and means over the rows of a frames cell (sums of the per-frame medians), ms.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FramesTotals {
    /// Frames.
    pub frames: u32,
    /// Σ frame time (update and render).
    pub frame_ms: f64,
    /// Mean frame time.
    pub mean_frame_ms: f64,
    /// Σ update (scene, spheres, upload, stage builds).
    pub update_ms: f64,
    /// Mean update.
    pub mean_update_ms: f64,
    /// Σ acceleration-structure update (build or refit, spheres).
    pub structure_ms: f64,
    /// Mean acceleration-structure update.
    pub mean_structure_ms: f64,
    /// Σ trace.
    pub trace_ms: f64,
    /// Σ render.
    pub render_ms: f64,
    /// Mean render.
    pub mean_render_ms: f64,
    /// Σ rays traced.
    pub traced_rays: u64,
    /// Σ tests.
    pub tests: u64,
    /// Frames checked against the reference.
    pub frames_checked: u32,
    /// Lowest hit agreement over the checked frames.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_hit_agreement: Option<f64>,
}

impl FramesTotals {
    /// The totals of `rows`.
    pub fn of(rows: &[FrameMeasure]) -> FramesTotals {
        let n = rows.len() as u32;
        let sum = |f: &dyn Fn(&FrameMeasure) -> f64| rows.iter().map(f).sum::<f64>();
        let mean = |total: f64| if n > 0 { total / n as f64 } else { 0.0 };
        let (frame_ms, update_ms, structure_ms, render_ms) = (
            sum(&|r| r.frame_ms),
            sum(&|r| r.update_ms),
            sum(&|r| r.structure_ms),
            sum(&|r| r.render_ms),
        );
        let checked: Vec<f64> = rows.iter().filter_map(|r| r.hit_agreement).collect();
        FramesTotals {
            frames: n,
            frame_ms,
            mean_frame_ms: mean(frame_ms),
            update_ms,
            mean_update_ms: mean(update_ms),
            structure_ms,
            mean_structure_ms: mean(structure_ms),
            trace_ms: sum(&|r| r.trace_ms),
            render_ms,
            mean_render_ms: mean(render_ms),
            traced_rays: rows.iter().map(|r| r.traced_rays).sum(),
            tests: rows.iter().map(|r| r.tests).sum(),
            frames_checked: checked.len() as u32,
            min_hit_agreement: checked.into_iter().reduce(f64::min),
        }
    }
}

/// The frames of a frames cell.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CellFrames {
    /// One row per frame, in order.
    pub rows: Vec<FrameMeasure>,
    /// Their sums and means.
    pub totals: FramesTotals,
}

/// One cell's outcome.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CellResult {
    /// Position in the plan's expansion.
    pub index: usize,
    /// Short name (`crsh subdivision=8 depth=2`).
    pub label: String,
    /// Scene name (the manifest's `name`; the plan's spelling when it did not load).
    pub scene: String,
    /// The scene as the plan wrote it.
    pub scene_source: String,
    /// Pipeline label.
    pub pipeline: String,
    /// Backend.
    pub backend: String,
    /// The swept parameters (`--set` key → value).
    pub params: BTreeMap<String, String>,
    /// Image width.
    pub width: u32,
    /// Image height (0 when the scene did not load and the plan gave none).
    pub height: u32,
    /// Bounce depth.
    pub depth: u32,
    /// `ok` or `failed`.
    pub status: String,
    /// Why it failed (empty when ok).
    pub reason: String,
    /// Timed runs.
    pub repeat: u32,
    /// Worker threads.
    pub threads: usize,
    /// The full resolved pipeline.
    pub config: PipelineConfig,
    /// The measurements (absent when the cell failed).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub measures: Option<Measures>,
}

impl Measures {
    /// [`KindPerRay`] of the ray kind `kind` (`None` when the cell did not trace it).
    pub fn kind_per_ray(&self, kind: &str) -> Option<KindPerRay> {
        self.per_kind.get(kind).map(KindPerRay::of)
    }

    /// The median ray-creation time, ms: one timer for every ray kind of the cell (the
    /// driver times each batch's generation under one key), so a kind's own share is not
    /// measured.
    pub fn ray_creation_ms(&self) -> f64 {
        self.timings_ms
            .get("ray_creation")
            .map_or(0.0, |t| t.median)
    }
}

impl CellResult {
    /// Whether the cell ran.
    pub fn ok(&self) -> bool {
        self.status == "ok" && self.measures.is_some()
    }

    /// Median total frame time, ms.
    pub fn total_ms(&self) -> Option<f64> {
        self.measures
            .as_ref()
            .and_then(|m| m.timings_ms.get("total"))
            .map(|t| t.median)
    }
}

/// Facts about the machine and build that ran the ablation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Machine {
    /// CPU model (`/proc/cpuinfo`'s `model name`), or `unknown`.
    pub cpu_model: String,
    /// Logical cores available to the process.
    pub cores: usize,
    /// Worker threads used by the CPU backend.
    pub threads: usize,
    /// Operating system and architecture.
    pub os: String,
    /// crsh version.
    pub crsh_version: String,
    /// `git rev-parse HEAD` in the current directory, or `unknown`.
    pub git_revision: String,
    /// wgpu adapters (name, backend, type), listed when the plan has wgpu cells.
    pub wgpu_adapters: Vec<String>,
    /// When the run started (UTC, ISO 8601).
    pub started_utc: String,
    /// The memory allocator's policy ([`crate::allocator`]; empty in results written before
    /// it was recorded).
    #[serde(default)]
    pub allocator: String,
    /// The instruction set the CPU backend's hot loops ran in ([`crsh::SetupTimes::isa`];
    /// empty in results written before it was recorded).
    #[serde(default)]
    pub isa: String,
}

impl Machine {
    /// Gathers the facts; `with_adapters` enumerates the wgpu adapters.
    pub fn gather(threads: usize, with_adapters: bool) -> Machine {
        let cpu_model = std::fs::read_to_string("/proc/cpuinfo")
            .ok()
            .and_then(|t| {
                t.lines()
                    .find(|l| l.starts_with("model name"))
                    .and_then(|l| l.split_once(':'))
                    .map(|(_, v)| v.trim().to_string())
            })
            .unwrap_or_else(|| "unknown".to_string());
        let git_revision = std::process::Command::new("git")
            .args(["rev-parse", "HEAD"])
            .stderr(std::process::Stdio::null())
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
            .filter(|s| !s.is_empty())
            .unwrap_or_else(|| "unknown".to_string());
        let wgpu_adapters = if with_adapters {
            crsh_wgpu::enumerate_adapters()
                .iter()
                .map(crate::listing::adapter_line)
                .collect()
        } else {
            Vec::new()
        };
        Machine {
            cpu_model,
            cores: std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1),
            threads,
            os: format!("{} {}", std::env::consts::OS, std::env::consts::ARCH),
            crsh_version: env!("CARGO_PKG_VERSION").to_string(),
            git_revision,
            wgpu_adapters,
            started_utc: utc_now(),
            allocator: crate::allocator::description()
                .unwrap_or_else(|| "not set by the program".into()),
            isa: crsh_cpu::isa::description(),
        }
    }
}

/// The current time as `YYYY-MM-DDTHH:MM:SSZ`.
pub fn utc_now() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    utc_from_unix(secs)
}

/// Formats Unix seconds as `YYYY-MM-DDTHH:MM:SSZ` (proleptic Gregorian calendar).
pub fn utc_from_unix(secs: u64) -> String {
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    // Howard Hinnant's civil_from_days.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        rem / 60 % 60,
        rem % 60
    )
}

/// Which share of an ablation's cells a run holds (`crsh ablate --shard K/N`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShardInfo {
    /// The shard, `1..=count`.
    pub index: usize,
    /// How many shards the cells are dealt to.
    pub count: usize,
}

impl ShardInfo {
    /// Parses `K/N` (`1 <= K <= N`).
    pub fn parse(s: &str) -> Result<ShardInfo, String> {
        let (k, n) = s
            .split_once('/')
            .ok_or_else(|| format!("--shard {s}: expected K/N, e.g. 2/8"))?;
        let parse = |v: &str| {
            v.trim()
                .parse::<usize>()
                .map_err(|_| format!("--shard {s}: `{v}` is not a whole number"))
        };
        let (index, count) = (parse(k)?, parse(n)?);
        if count == 0 || index == 0 || index > count {
            return Err(format!("--shard {s}: K must be in 1..=N and N at least 1"));
        }
        Ok(ShardInfo { index, count })
    }

    /// Whether the cell at `index` (0-based, in the plan's expansion) belongs to this shard:
    /// cells are dealt round robin, cell `i` to shard `i mod N + 1`, so every shard gets a
    /// share of every scene and pipeline and the shards take similar times.
    pub fn holds(&self, index: usize) -> bool {
        index % self.count == self.index - 1
    }
}

impl std::fmt::Display for ShardInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// What the plan expanded to, for checking that shards belong together.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Expansion {
    /// Cells in the whole expansion (every shard's).
    pub cells: usize,
    /// FNV-1a (64-bit, hex) of every cell's scene, label, backend, size, depth and resolved
    /// pipeline and reference, in order: equal exactly when two runs expanded the same cells.
    pub digest: String,
}

/// A shard merged into a results document: where it ran and how long it took.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShardRecord {
    /// Which shard.
    pub shard: ShardInfo,
    /// The directory it was read from.
    pub source: String,
    /// The machine that ran it.
    pub machine: Machine,
    /// Its wall time, seconds.
    pub wall_s: f64,
    /// Its cells.
    pub cells: usize,
}

/// The whole `results.json` document.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Results {
    /// crsh version that wrote it.
    pub version: String,
    /// The report's title.
    pub title: String,
    /// Where the plan came from (a path, or `command line`).
    pub plan_source: String,
    /// The plan, as parsed (defaults filled in).
    pub plan: Plan,
    /// The plan's text as given (shown in the report).
    #[serde(default)]
    pub plan_text: String,
    /// The machine and build (of the first shard, for merged results).
    pub machine: Machine,
    /// Wall time of the whole ablation, seconds (merged results: the longest shard's, the
    /// elapsed time when the shards run side by side).
    pub wall_s: f64,
    /// What the plan expanded to.
    #[serde(default)]
    pub expansion: Expansion,
    /// The shard this run holds (`--shard K/N`); absent for a whole run or merged results.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shard: Option<ShardInfo>,
    /// The shards merged into this document (`--merge`), in shard order.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub merged_from: Vec<ShardRecord>,
    /// One entry per cell, in plan order.
    pub cells: Vec<CellResult>,
}

impl Results {
    /// Pretty JSON (every f64 is finite: PSNR infinity is `null`).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
    }

    /// The scene names in plan order, each once.
    pub fn scenes(&self) -> Vec<String> {
        let mut seen = BTreeSet::new();
        self.cells
            .iter()
            .filter(|c| seen.insert(c.scene.clone()))
            .map(|c| c.scene.clone())
            .collect()
    }

    /// The cells of `scene` that ran, in plan order.
    pub fn ok_cells(&self, scene: &str) -> Vec<&CellResult> {
        self.cells
            .iter()
            .filter(|c| c.scene == scene && c.ok())
            .collect()
    }

    /// The swept parameter keys over all cells, sorted.
    pub fn param_keys(&self) -> Vec<String> {
        let keys: BTreeSet<&String> = self.cells.iter().flat_map(|c| c.params.keys()).collect();
        keys.into_iter().cloned().collect()
    }

    /// `results.csv`: one row per cell, flat columns (see the README).
    pub fn to_csv(&self) -> String {
        let params = self.param_keys();
        let level_keys: BTreeSet<(usize, String, u32)> = self
            .cells
            .iter()
            .filter_map(|c| c.measures.as_ref())
            .flat_map(|m| m.levels.iter())
            .map(|l| (kind_order(&l.ray_kind), l.ray_kind.clone(), l.level))
            .collect();
        // Levels: per kind, highest level first (the thesis's table order).
        let mut levels: Vec<(usize, String, u32)> = level_keys.into_iter().collect();
        levels.sort_by(|a, b| a.0.cmp(&b.0).then(b.2.cmp(&a.2)));
        let mesh_kinds = self.kinds_in(&|m| m.mesh_culling.keys().collect());
        let packet_kinds = self.kinds_in(&|m| m.packets.keys().collect());
        let traced_kinds = self.kinds_in(&|m| m.per_kind.keys().collect());
        let mut stages: Vec<String> = STAGE_TIMINGS
            .iter()
            .filter(|k| self.any_timing(k))
            .map(|k| k.to_string())
            .collect();
        let extra: BTreeSet<String> = self
            .cells
            .iter()
            .filter_map(|c| c.measures.as_ref())
            .flat_map(|m| m.timings_ms.keys())
            .filter(|k| !STAGE_TIMINGS.contains(&k.as_str()) && *k != "total")
            .cloned()
            .collect();
        stages.extend(extra);
        let kinds: Vec<&str> = RayKind::ALL
            .iter()
            .map(|k| k.name())
            .filter(|k| {
                self.cells
                    .iter()
                    .filter_map(|c| c.measures.as_ref())
                    .any(|m| m.mrays_per_s.contains_key(*k))
            })
            .collect();

        let mut header = cell_id_header(&params);
        header.extend(
            [
                "status",
                "reason",
                "repeat",
                "threads",
                "triangles",
                "rays_primary",
                "rays_shadow",
                "rays_reflection",
                "rays_refraction",
                "rays_ao",
                "rays_diffuse",
                "rays_traced",
                "tests_bounds",
                "tests_ray_triangle",
                "tests_total",
                "tests_brute_force",
                "tests_per_ray",
                "tests_fraction",
                "tests_inner_nodes",
                "tests_leaves",
                "tests_inner_nodes_per_ray",
                "tests_leaves_per_ray",
            ]
            .iter()
            .map(|s| s.to_string()),
        );
        for kind in &mesh_kinds {
            for what in ["tests", "hits"] {
                header.push(format!("mesh_culling_{kind}_{what}"));
            }
        }
        for kind in &packet_kinds {
            for what in PACKET_COLUMNS {
                header.push(format!("packets_{kind}_{what}"));
            }
        }
        for (_, kind, level) in &levels {
            for what in ["tests", "hits"] {
                header.push(format!("level_{kind}_{level}_{what}"));
            }
        }
        for stage in std::iter::once("total".to_string()).chain(stages.iter().cloned()) {
            for s in ["median", "min", "max"] {
                header.push(format!("time_{stage}_{s}_ms"));
            }
        }
        for k in kinds.iter().copied().chain(["overall", "frame"]) {
            header.push(format!("mrays_{k}"));
        }
        for kind in &traced_kinds {
            for what in KIND_COLUMNS {
                header.push(format!("kind_{kind}_{what}"));
            }
        }
        header.extend(
            [
                "reference",
                "hit_agreement",
                "psnr_db",
                "mean_abs_t_error",
                "self_hits",
                "self_hit_rate",
                "pixels_differing",
                "peak_candidate_bytes",
                "counters_equal_across_repeats",
                "build_stages_ms",
                "frames",
                "frame_mean_ms",
                "update_mean_ms",
                "structure_mean_ms",
                "render_mean_ms",
                "config",
            ]
            .iter()
            .map(|s| s.to_string()),
        );

        let mut out = String::new();
        push_row(&mut out, &header);
        for c in &self.cells {
            let m = c.measures.as_ref();
            let mut row = cell_id_fields(c, &params);
            row.extend([
                c.status.clone(),
                c.reason.clone(),
                c.repeat.to_string(),
                c.threads.to_string(),
            ]);
            let num = |f: &dyn Fn(&Measures) -> String| m.map(f).unwrap_or_default();
            row.push(num(&|m| m.triangles.to_string()));
            row.push(num(&|m| m.rays.primary.to_string()));
            row.push(num(&|m| m.rays.shadow.to_string()));
            row.push(num(&|m| m.rays.reflection.to_string()));
            row.push(num(&|m| m.rays.refraction.to_string()));
            row.push(num(&|m| m.rays.ao.to_string()));
            row.push(num(&|m| m.rays.diffuse.to_string()));
            row.push(num(&|m| m.rays.traced.to_string()));
            // Uncounted tests (Embree) are blank cells, not 0.
            let counted = |f: &dyn Fn(&Measures) -> String| {
                m.filter(|m| !m.tests.uncounted).map(f).unwrap_or_default()
            };
            row.push(counted(&|m| m.tests.bounds.to_string()));
            row.push(counted(&|m| m.tests.ray_triangle.to_string()));
            row.push(counted(&|m| m.tests.total.to_string()));
            row.push(num(&|m| m.tests.brute_force.to_string()));
            row.push(counted(&|m| format!("{:.4}", m.tests.per_ray)));
            row.push(counted(&|m| format!("{:.6e}", m.tests.fraction)));
            row.push(counted(&|m| m.tests.inner_nodes.to_string()));
            row.push(counted(&|m| m.tests.leaves.to_string()));
            row.push(counted(&|m| format!("{:.4}", m.tests.inner_nodes_per_ray)));
            row.push(counted(&|m| format!("{:.4}", m.tests.leaves_per_ray)));
            for kind in &mesh_kinds {
                let c = m.and_then(|m| m.mesh_culling.get(kind));
                row.push(c.map(|c| c.tests.to_string()).unwrap_or_default());
                row.push(c.map(|c| c.hits.to_string()).unwrap_or_default());
            }
            for kind in &packet_kinds {
                match m.and_then(|m| m.packets.get(kind)) {
                    Some(p) => row.extend([
                        p.packets.to_string(),
                        format!("{:.4}", p.nodes_per_packet()),
                        format!("{:.4}", p.tests_per_packet()),
                        format!("{:.4}", p.culled_fraction()),
                        p.groups.to_string(),
                        p.single_rays.to_string(),
                    ]),
                    None => row.extend(PACKET_COLUMNS.iter().map(|_| String::new())),
                }
            }
            for (_, kind, level) in &levels {
                let l = m.and_then(|m| {
                    m.levels
                        .iter()
                        .find(|l| &l.ray_kind == kind && l.level == *level)
                });
                row.push(l.map(|l| l.tests.to_string()).unwrap_or_default());
                row.push(l.map(|l| l.hits.to_string()).unwrap_or_default());
            }
            for stage in std::iter::once("total".to_string()).chain(stages.iter().cloned()) {
                let t = m.and_then(|m| m.timings_ms.get(&stage));
                for pick in [
                    |t: &TimeSummary| t.median,
                    |t: &TimeSummary| t.min,
                    |t: &TimeSummary| t.max,
                ] {
                    row.push(t.map(|t| format!("{:.3}", pick(t))).unwrap_or_default());
                }
            }
            for k in kinds.iter().copied().chain(["overall", "frame"]) {
                row.push(
                    m.and_then(|m| m.mrays_per_s.get(k))
                        .map(|v| format!("{v:.4}"))
                        .unwrap_or_default(),
                );
            }
            for kind in &traced_kinds {
                match m.and_then(|m| Some((m.per_kind.get(kind)?, m.kind_per_ray(kind)?))) {
                    Some((k, p)) => row.extend(kind_fields(k, &p)),
                    None => row.extend(KIND_COLUMNS.iter().map(|_| String::new())),
                }
            }
            let acc = m.and_then(|m| m.accuracy.as_ref());
            row.push(acc.map(|a| a.reference.clone()).unwrap_or_default());
            row.push(
                acc.map(|a| format!("{:.8}", a.hit_agreement))
                    .unwrap_or_default(),
            );
            row.push(
                acc.map(|a| match a.psnr_db {
                    Some(db) => format!("{db:.3}"),
                    None => "inf".to_string(),
                })
                .unwrap_or_default(),
            );
            row.push(
                acc.map(|a| format!("{:.6e}", a.mean_abs_t_error))
                    .unwrap_or_default(),
            );
            row.push(acc.map(|a| a.self_hits.to_string()).unwrap_or_default());
            row.push(
                acc.map(|a| format!("{:.8}", a.self_hit_rate))
                    .unwrap_or_default(),
            );
            row.push(
                acc.map(|a| a.pixels_differing.to_string())
                    .unwrap_or_default(),
            );
            row.push(num(&|m| m.peak_candidate_bytes.to_string()));
            row.push(num(&|m| m.counters_equal_across_repeats.to_string()));
            row.push(num(&|m| format!("{:.3}", m.build_stages_ms)));
            let totals = m.and_then(|m| m.frames.as_ref()).map(|f| &f.totals);
            row.push(totals.map(|t| t.frames.to_string()).unwrap_or_default());
            for pick in [
                |t: &FramesTotals| t.mean_frame_ms,
                |t: &FramesTotals| t.mean_update_ms,
                |t: &FramesTotals| t.mean_structure_ms,
                |t: &FramesTotals| t.mean_render_ms,
            ] {
                row.push(
                    totals
                        .map(|t| format!("{:.3}", pick(t)))
                        .unwrap_or_default(),
                );
            }
            row.push(serde_json::to_string(&c.config).unwrap_or_default());
            push_row(&mut out, &row);
        }
        out
    }

    /// Whether a cell ran frames (the plan has `frames`).
    pub fn has_frames(&self) -> bool {
        self.cells
            .iter()
            .any(|c| c.measures.as_ref().is_some_and(|m| m.frames.is_some()))
    }

    /// `frames.csv`: one row per frames cell and frame (`None` when no cell ran frames):
    /// the cell's identity, then the frame's [`FrameMeasure`].
    pub fn frames_csv(&self) -> Option<String> {
        if !self.has_frames() {
            return None;
        }
        let params = self.param_keys();
        let mut header: Vec<String> = ["scene", "pipeline", "label", "backend"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        header.extend(params.iter().cloned());
        header.extend(
            [
                "width",
                "height",
                "depth",
                "frame",
                "time_s",
                "structure",
                "moved_triangles",
                "scene_ms",
                "spheres_ms",
                "upload_ms",
                "structure_ms",
                "update_ms",
                "trace_ms",
                "render_ms",
                "frame_ms",
                "rays_traced",
                "tests_total",
                "tests_per_ray",
                "hit_agreement",
            ]
            .iter()
            .map(|s| s.to_string()),
        );
        let mut out = String::new();
        push_row(&mut out, &header);
        for c in &self.cells {
            let Some(frames) = c.measures.as_ref().and_then(|m| m.frames.as_ref()) else {
                continue;
            };
            for r in &frames.rows {
                let lead = vec![
                    c.scene.clone(),
                    c.pipeline.clone(),
                    c.label.clone(),
                    c.backend.clone(),
                ];
                let mut row = params_and_size(lead, c, &params);
                row.extend([
                    r.frame.to_string(),
                    format!("{:.4}", r.time_s),
                    r.structure.clone(),
                    r.moved_triangles.to_string(),
                ]);
                for ms in [
                    r.scene_ms,
                    r.spheres_ms,
                    r.upload_ms,
                    r.structure_ms,
                    r.update_ms,
                    r.trace_ms,
                    r.render_ms,
                    r.frame_ms,
                ] {
                    row.push(format!("{ms:.3}"));
                }
                row.extend([
                    r.traced_rays.to_string(),
                    r.tests.to_string(),
                    format!("{:.4}", r.tests_per_ray),
                    r.hit_agreement
                        .map(|a| format!("{a:.8}"))
                        .unwrap_or_default(),
                ]);
                push_row(&mut out, &row);
            }
        }
        Some(out)
    }

    /// The ray kinds `keys` names in any cell's measures, in [`RayKind::ALL`] order.
    fn kinds_in(&self, keys: &dyn Fn(&Measures) -> Vec<&String>) -> Vec<String> {
        let kinds: BTreeSet<(usize, &String)> = self
            .cells
            .iter()
            .filter_map(|c| c.measures.as_ref())
            .flat_map(keys)
            .map(|k| (kind_order(k), k))
            .collect();
        kinds.into_iter().map(|(_, k)| k.clone()).collect()
    }

    fn any_timing(&self, key: &str) -> bool {
        self.cells
            .iter()
            .filter_map(|c| c.measures.as_ref())
            .any(|m| m.timings_ms.contains_key(key))
    }
}

/// The per-kind columns of `results.csv`, `kind_KIND_WHAT` (see [`kind_fields`]).
pub const KIND_COLUMNS: [&str; 7] = [
    "rays",
    "inner_nodes_per_ray",
    "leaves_per_ray",
    "bounds_per_ray",
    "ray_triangle_per_ray",
    "trace_ms",
    "offset_ended_fraction",
];

/// The [`KIND_COLUMNS`] fields of one kind.
fn kind_fields(k: &KindStats, p: &KindPerRay) -> Vec<String> {
    vec![
        k.rays.to_string(),
        format!("{:.4}", p.inner_nodes),
        format!("{:.4}", p.leaves),
        format!("{:.4}", p.bounds),
        format!("{:.4}", p.ray_triangle),
        format!("{:.3}", k.trace_ms),
        format!("{:.6}", p.offset_ended_fraction),
    ]
}

/// Position of `kind` in [`RayKind::ALL`] (unknown names last), for column order.
pub fn kind_order(kind: &str) -> usize {
    RayKind::ALL
        .iter()
        .position(|k| k.name() == kind)
        .unwrap_or(RayKind::ALL.len())
}

/// One CSV field, quoted when it holds a comma, quote or line break (RFC 4180).
pub fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// The columns that name a cell in `results.csv` and `baseline.csv`: `scene, scene_source,
/// pipeline, backend`, the swept keys `params`, `width, height, depth`.
pub fn cell_id_header(params: &[String]) -> Vec<String> {
    let mut h: Vec<String> = ["scene", "scene_source", "pipeline", "backend"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    h.extend(params.iter().cloned());
    h.extend(["width", "height", "depth"].iter().map(|s| s.to_string()));
    h
}

/// The [`cell_id_header`] fields of `c` (empty for a key it does not sweep).
pub fn cell_id_fields(c: &CellResult, params: &[String]) -> Vec<String> {
    let lead = vec![
        c.scene.clone(),
        c.scene_source.clone(),
        c.pipeline.clone(),
        c.backend.clone(),
    ];
    params_and_size(lead, c, params)
}

/// `lead`, then `c`'s values of the swept keys `params` (empty for a key it does not sweep),
/// its width, height and depth.
fn params_and_size(mut row: Vec<String>, c: &CellResult, params: &[String]) -> Vec<String> {
    row.extend(
        params
            .iter()
            .map(|k| c.params.get(k).cloned().unwrap_or_default()),
    );
    row.extend([
        c.width.to_string(),
        c.height.to_string(),
        c.depth.to_string(),
    ]);
    row
}

/// Appends one CSV line of `fields` (each quoted as [`csv_field`] does).
pub fn push_row(out: &mut String, fields: &[String]) {
    let line: Vec<String> = fields.iter().map(|f| csv_field(f)).collect();
    let _ = writeln!(out, "{}", line.join(","));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_min_max() {
        let t = TimeSummary::of(&[3.0, 1.0, 2.0]);
        assert_eq!((t.median, t.min, t.max), (2.0, 1.0, 3.0));
        let t = TimeSummary::of(&[4.0, 1.0, 2.0, 3.0]);
        assert_eq!((t.median, t.min, t.max), (2.5, 1.0, 4.0));
        assert_eq!(TimeSummary::of(&[]), TimeSummary::default());
    }

    #[test]
    fn csv_quoting() {
        assert_eq!(csv_field("plain"), "plain");
        assert_eq!(csv_field("a,b"), "\"a,b\"");
        assert_eq!(csv_field("say \"hi\""), "\"say \"\"hi\"\"\"");
    }

    #[test]
    fn shards_deal_cells_round_robin() {
        assert_eq!(
            ShardInfo::parse("2/3").unwrap(),
            ShardInfo { index: 2, count: 3 }
        );
        for bad in ["0/3", "4/3", "1/0", "x/3", "3", "1/2/3"] {
            assert!(ShardInfo::parse(bad).is_err(), "{bad}");
        }
        let shards: Vec<ShardInfo> = (1..=3).map(|k| ShardInfo { index: k, count: 3 }).collect();
        for i in 0..20 {
            assert_eq!(shards.iter().filter(|s| s.holds(i)).count(), 1, "cell {i}");
        }
        assert!(shards[0].holds(0) && shards[1].holds(1) && shards[2].holds(5));
    }

    #[test]
    fn frame_totals_sum_the_rows() {
        let row = |frame: u32, update: f64, render: f64, agreement: Option<f64>| FrameMeasure {
            frame,
            structure_ms: update / 2.0,
            update_ms: update,
            render_ms: render,
            frame_ms: update + render,
            traced_rays: 10,
            tests: 30,
            hit_agreement: agreement,
            ..Default::default()
        };
        let t = FramesTotals::of(&[
            row(0, 4.0, 6.0, Some(1.0)),
            row(1, 2.0, 4.0, None),
            row(2, 0.0, 2.0, Some(0.5)),
        ]);
        assert_eq!((t.frames, t.frames_checked), (3, 2));
        assert_eq!((t.frame_ms, t.mean_frame_ms), (18.0, 6.0));
        assert_eq!((t.update_ms, t.mean_update_ms), (6.0, 2.0));
        assert_eq!((t.structure_ms, t.mean_structure_ms), (3.0, 1.0));
        assert_eq!((t.render_ms, t.mean_render_ms), (12.0, 4.0));
        assert_eq!((t.traced_rays, t.tests), (30, 90));
        assert_eq!(t.min_hit_agreement, Some(0.5));
        assert_eq!(FramesTotals::of(&[]), FramesTotals::default());
    }

    /// `results.json` is the record `--redraw`, `--merge` and `compare` rebuild everything
    /// from, so every f64 it holds must read back bit for bit (serde_json's default parser
    /// misrounds about one value in ten; the workspace enables `float_roundtrip`).
    #[test]
    fn results_json_floats_read_back_exactly() {
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut values = vec![985.690_694_632_869_5, 212.918_907_267_134_6, 0.1, 1e-300];
        for _ in 0..20_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            values.push((x >> 11) as f64 / (1u64 << 53) as f64 * 1000.0);
        }
        let text = serde_json::to_string(&values).unwrap();
        let back: Vec<f64> = serde_json::from_str(&text).unwrap();
        for (v, b) in values.iter().zip(&back) {
            assert_eq!(v.to_bits(), b.to_bits(), "{v:?} read back as {b:?}");
        }
    }

    #[test]
    fn utc_dates() {
        assert_eq!(utc_from_unix(0), "1970-01-01T00:00:00Z");
        assert_eq!(utc_from_unix(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(utc_from_unix(1_700_000_000), "2023-11-14T22:13:20Z");
    }
}
