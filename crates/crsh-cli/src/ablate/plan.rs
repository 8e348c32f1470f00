//! The ablation plan: a serde TOML document (or the command line's quick form) naming scenes,
//! image size, bounce depth, pipelines with their parameter grids, backends, the reference
//! and the repetition count, and its expansion into cells.
//!
//! A grid is a table `KEY = VALUE` or `KEY = [VALUE, ...]` of `--set` keys
//! (`hierarchy.subdivision = [8, 16]`); every combination of the listed values is one cell.
//! The plan-wide `[grid]` applies to every pipeline, except its `STAGE.*` keys whose stage
//! slot the pipeline leaves empty (and its own grid does not fill with `STAGE.kind`): `bvh` has
//! no hierarchy, so `hierarchy.depth = [2, 3, 4]` does not multiply its cells, and RAH gets no
//! sorter from `sort.kind = [...]`. A plan-wide key no pipeline takes is an error.
//!
//! `frames = N` makes every cell a dynamic one: frames `0..N` of the scene loaded as an
//! animated scene ([`crsh_scene::load_animated`]; a scene that does not move gives N equal
//! frames), each frame's scene update and structure rebuild or refit timed with its render
//! ([`crsh::render_frames`]). `reference_every = K` checks only every K-th frame (frame 0
//! included) against the reference, for large scenes. Without `frames` a cell is one static
//! frame, as before.
//!
//! A pipeline entry may carry its own `depth` (one or several), replacing the plan's for its
//! cells: ray settings that need different bounce depths (seed 001's AO and shadow rays at
//! depth 0, diffuse paths at depth 3) live in one plan as one entry each.
//!
//! `baseline = { KEY = VALUE }` names one grid key and its baseline value: every cell whose
//! parameters include `KEY` is paired with the cell that is identical except for `KEY = VALUE`
//! (the baseline cell pairs with itself), and `baseline.csv`, `baseline.md` and a table in
//! the report set each cell's figures against its baseline's ([`super::baseline`]).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crsh::{BackendKind, Registries};
use crsh_core::{PipelineConfig, StageKind};
use serde::{Deserialize, Serialize};

use crate::error::{CliError, CliResult};
use crate::render::{pipeline_unresolved, reference_config};

/// Default `repeat`: timed runs per cell.
pub const DEFAULT_REPEAT: u32 = 5;
/// Default image width.
pub const DEFAULT_WIDTH: u32 = 256;
/// Default bounce depth.
pub const DEFAULT_DEPTH: u32 = 3;
/// Default reference intersector.
pub const DEFAULT_REFERENCE: &str = "bvh";
/// Largest `repeat` accepted.
pub const MAX_REPEAT: u32 = 1000;
/// The accuracy axes a plan may chart (`accuracy_axes`): hit agreement with the reference
/// intersector (higher is better), PSNR of the image against the reference pipeline's (higher
/// is better) and the self-hit rate (lower is better). The default is the first.
pub const ACCURACY_AXES: &[&str] = &["hit_agreement", "psnr_db", "self_hit_rate"];
/// Largest number of cells a plan may expand to (guards against a typo'd grid).
pub const MAX_CELLS: usize = 10_000;

/// One value or a list of values (`8` or `[8, 16]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum OneOrMany<T> {
    /// A single value.
    One(T),
    /// A list of values, each a grid point.
    Many(Vec<T>),
}

impl<T: Clone> OneOrMany<T> {
    /// The values as a list.
    pub fn to_vec(&self) -> Vec<T> {
        match self {
            OneOrMany::One(v) => vec![v.clone()],
            OneOrMany::Many(v) => v.clone(),
        }
    }
}

/// A grid value: what follows `KEY=` in a `--set`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum GridValue {
    /// `true` / `false`.
    Bool(bool),
    /// An integer.
    Int(i64),
    /// A real number.
    Float(f64),
    /// A name (`interleave`, `off`, ...).
    Str(String),
}

impl std::fmt::Display for GridValue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            GridValue::Bool(b) => write!(f, "{b}"),
            GridValue::Int(i) => write!(f, "{i}"),
            GridValue::Float(x) => write!(f, "{x}"),
            GridValue::Str(s) => f.write_str(s),
        }
    }
}

/// A parameter grid: `--set` key → the values to sweep.
pub type Grid = BTreeMap<String, OneOrMany<GridValue>>;

/// One pipeline of a plan, with its own grid.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PipelinePlan {
    /// A preset (`crsh`, `rah`, `bvh`, `brute`) or a pipeline TOML file (relative to the plan's
    /// directory).
    pub pipeline: String,
    /// Name in results and charts (default: the pipeline's name).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub label: Option<String>,
    /// Bounce depths of this pipeline's cells, replacing the plan's `depth` (absent: the
    /// plan's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth: Option<OneOrMany<u32>>,
    /// Parameter grid of this pipeline, applied after the plan-wide grid.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub grid: Grid,
}

/// An ablation plan (`crsh ablate --plan PLAN.toml`). See the README's "`crsh ablate`".
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Plan {
    /// Title of the report (default: the plan file's name).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub title: Option<String>,
    /// Scenes: built-in names, manifests or OBJ files. Relative paths are looked up in the
    /// plan's directory, then in the scenes directory; `${CRSH_SCENES}` expands to the
    /// `CRSH_SCENES` environment variable, or `../shared/scenes`.
    pub scenes: Vec<String>,
    /// Image widths (one or several, each a grid point).
    #[serde(default = "default_width")]
    pub width: OneOrMany<u32>,
    /// Image height (default: width / the camera's aspect, else square).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub height: Option<u32>,
    /// Bounce depths (one or several).
    #[serde(default = "default_depth")]
    pub depth: OneOrMany<u32>,
    /// Timed runs per cell (after one warm-up run).
    #[serde(default = "default_repeat")]
    pub repeat: u32,
    /// Untimed warm-up runs per cell before the timed ones.
    #[serde(default = "default_warmup")]
    pub warmup: u32,
    /// The reference intersector variant accuracy is measured against (`brute`, `bvh`, ...),
    /// or `none` to skip the accuracy run.
    #[serde(default = "default_reference")]
    pub reference: String,
    /// `--set` keys → values applied to the reference pipeline after its intersector is
    /// swapped for `reference` (`{ "raygen.offset" = "wachter" }`): the reference image is
    /// then rendered with one fixed configuration while the cells vary it. Keys that reach
    /// the intersector (`intersect.*`) change the hit-agreement reference as well.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub reference_params: BTreeMap<String, GridValue>,
    /// The accuracy measures drawn against throughput, one Pareto chart per scene each (see
    /// [`ACCURACY_AXES`]).
    #[serde(default = "default_accuracy_axes")]
    pub accuracy_axes: Vec<String>,
    /// Backends (`cpu`, `wgpu`); a wgpu cell runs the same configuration on the wgpu backend
    /// and fails with its reason when the machine has no adapter or the GPU lacks a variant.
    #[serde(default = "default_backends")]
    pub backends: Vec<String>,
    /// Worker threads (default: rayon's choice).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub threads: Option<usize>,
    /// Every light's radius (scene units), set after each scene loads, for soft shadows (seed
    /// 003 §5: `raygen.shadow = samples | edge_width`); absent: the scenes' own radii (manifest
    /// `radius`, default 0). The shared scenes' manifests give none, so plans set it here.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub light_radius: Option<f32>,
    /// Frames of an animated scene per cell (`1..=`[`crsh::frames::MAX_FRAMES`]); absent: one
    /// static frame per run (see the module documentation).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames: Option<u32>,
    /// With `frames`: check every `reference_every`-th frame against the reference (frame 0
    /// included; 1: every frame).
    #[serde(
        default = "default_reference_every",
        skip_serializing_if = "is_default_reference_every"
    )]
    pub reference_every: u32,
    /// One grid key and its baseline value (`{ "raygen.offsets" = "none" }`): each cell is
    /// set against the cell identical but for that key (see the module documentation). Empty:
    /// no baseline outputs.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub baseline: BTreeMap<String, GridValue>,
    /// Grid applied to every pipeline (see the module documentation).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub grid: Grid,
    /// The pipelines compared.
    pub pipelines: Vec<PipelinePlan>,
}

fn default_width() -> OneOrMany<u32> {
    OneOrMany::One(DEFAULT_WIDTH)
}
fn default_depth() -> OneOrMany<u32> {
    OneOrMany::One(DEFAULT_DEPTH)
}
fn default_repeat() -> u32 {
    DEFAULT_REPEAT
}
fn default_warmup() -> u32 {
    1
}
fn default_reference() -> String {
    DEFAULT_REFERENCE.to_string()
}
fn default_accuracy_axes() -> Vec<String> {
    vec![ACCURACY_AXES[0].to_string()]
}
fn default_backends() -> Vec<String> {
    vec!["cpu".to_string()]
}
fn default_reference_every() -> u32 {
    1
}
fn is_default_reference_every(v: &u32) -> bool {
    *v == default_reference_every()
}

/// The command line's quick form of a plan.
#[derive(Clone, Debug, Default)]
pub struct QuickPlan {
    /// `--scenes a,b`.
    pub scenes: Vec<String>,
    /// `--pipelines crsh,rah`.
    pub pipelines: Vec<String>,
    /// `--set KEY=V1,V2` (repeatable).
    pub sets: Vec<String>,
    /// `--backends cpu,wgpu`.
    pub backends: Vec<String>,
    /// `--width` (comma list).
    pub width: Vec<u32>,
    /// `--height`.
    pub height: Option<u32>,
    /// `--depth` (comma list).
    pub depth: Vec<u32>,
    /// `--repeat`.
    pub repeat: Option<u32>,
    /// `--reference`.
    pub reference: Option<String>,
    /// `--threads`.
    pub threads: Option<usize>,
    /// `--frames`.
    pub frames: Option<u32>,
}

/// Splits a comma list, trimming and dropping empty items.
pub fn split_list(s: &str) -> Vec<String> {
    s.split(',')
        .map(str::trim)
        .filter(|x| !x.is_empty())
        .map(str::to_string)
        .collect()
}

fn many<T: Clone>(v: Vec<T>) -> OneOrMany<T> {
    if v.len() == 1 {
        OneOrMany::One(v[0].clone())
    } else {
        OneOrMany::Many(v)
    }
}

/// Parses `KEY=V1,V2,...` into a grid entry (values typed as TOML would: booleans, integers,
/// numbers, else names).
pub fn parse_set(s: &str) -> CliResult<(String, OneOrMany<GridValue>)> {
    let (key, values) = s
        .split_once('=')
        .ok_or_else(|| CliError::usage(format!("--set {s}: expected KEY=VALUE[,VALUE...]")))?;
    let key = key.trim();
    if key.is_empty() {
        return Err(CliError::usage(format!("--set {s}: empty key")));
    }
    let vals: Vec<GridValue> = split_list(values).iter().map(|v| grid_value(v)).collect();
    if vals.is_empty() {
        return Err(CliError::usage(format!("--set {s}: no value")));
    }
    Ok((key.to_string(), many(vals)))
}

fn grid_value(s: &str) -> GridValue {
    if let Ok(b) = s.parse::<bool>() {
        GridValue::Bool(b)
    } else if let Ok(i) = s.parse::<i64>() {
        GridValue::Int(i)
    } else if let Ok(f) = s.parse::<f64>() {
        GridValue::Float(f)
    } else {
        GridValue::Str(s.to_string())
    }
}

impl QuickPlan {
    /// The plan this command line describes; `--set` lists become the plan-wide grid.
    pub fn into_plan(self) -> CliResult<Plan> {
        let mut grid = Grid::new();
        for s in &self.sets {
            let (k, v) = parse_set(s)?;
            if grid.insert(k.clone(), v).is_some() {
                return Err(CliError::usage(format!(
                    "--set {k} given twice; list its values once: --set {k}=A,B"
                )));
            }
        }
        let pipelines = if self.pipelines.is_empty() {
            vec!["crsh".to_string(), "rah".to_string(), "bvh".to_string()]
        } else {
            self.pipelines
        };
        Ok(Plan {
            title: None,
            scenes: if self.scenes.is_empty() {
                vec!["cornell-mirrors".to_string()]
            } else {
                self.scenes
            },
            width: if self.width.is_empty() {
                default_width()
            } else {
                many(self.width)
            },
            height: self.height,
            depth: if self.depth.is_empty() {
                default_depth()
            } else {
                many(self.depth)
            },
            repeat: self.repeat.unwrap_or(DEFAULT_REPEAT),
            warmup: 1,
            reference: self.reference.unwrap_or_else(default_reference),
            reference_params: BTreeMap::new(),
            accuracy_axes: default_accuracy_axes(),
            backends: if self.backends.is_empty() {
                default_backends()
            } else {
                self.backends
            },
            threads: self.threads,
            light_radius: None,
            baseline: BTreeMap::new(),
            grid,
            pipelines: pipelines
                .into_iter()
                .map(|p| PipelinePlan {
                    pipeline: p,
                    label: None,
                    depth: None,
                    grid: Grid::new(),
                })
                .collect(),
            frames: self.frames,
            reference_every: default_reference_every(),
        })
    }
}

/// Reads and parses a plan file; errors are usage errors (exit 2).
pub fn read_plan(path: &Path) -> CliResult<Plan> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| CliError::usage(format!("cannot read plan {}: {e}", path.display())))?;
    parse_plan(&text).map_err(|e| CliError::usage(format!("plan {}: {e}", path.display())))
}

/// Parses plan TOML.
pub fn parse_plan(text: &str) -> Result<Plan, String> {
    toml::from_str::<Plan>(text).map_err(|e| e.to_string())
}

/// One cell of the expanded plan: everything needed to run it.
#[derive(Clone, Debug)]
pub struct Cell {
    /// Position in the plan's expansion (0-based).
    pub index: usize,
    /// The scene as the plan wrote it.
    pub scene_spec: String,
    /// The scene resolved: a built-in name or a path that exists; `Err` says why not found.
    pub scene: Result<String, String>,
    /// The pipeline's label.
    pub pipeline: String,
    /// Backend name.
    pub backend: String,
    /// The swept parameters of this cell (`--set` key → value), plan-wide and pipeline grids.
    pub params: BTreeMap<String, String>,
    /// Image width.
    pub width: u32,
    /// Image height, if the plan fixes it.
    pub height: Option<u32>,
    /// Bounce depth.
    pub depth: u32,
    /// The pipeline, resolved against the cell's backend (or, when that backend lacks one of
    /// its stages, against the backend that has them: see `unsupported`).
    pub config: PipelineConfig,
    /// The resolved reference pipeline (`None`: no accuracy run).
    pub reference: Option<PipelineConfig>,
    /// Why the cell's backend cannot run the pipeline (a stage or parameter only another
    /// backend has): the cell is recorded as failed with this reason, as a cell whose scene is
    /// missing is.
    pub unsupported: Option<String>,
}

impl Cell {
    /// A short name: `crsh subdivision=8 depth=2` (full keys where the last parts clash).
    pub fn label(&self) -> String {
        let mut s = self.pipeline.clone();
        for (k, v) in &self.params {
            let short = k.rsplit('.').next().unwrap_or(k);
            let clash = self
                .params
                .keys()
                .filter(|o| o.rsplit('.').next() == Some(short))
                .count()
                > 1;
            s.push(' ');
            s.push_str(if clash { k } else { short });
            s.push('=');
            s.push_str(v);
        }
        if self.backend != "cpu" {
            s.push_str(&format!(" [{}]", self.backend));
        }
        s
    }
}

/// Resolves a scene spec: built-in names stay; `${CRSH_SCENES}` expands; a relative path is
/// tried in `plan_dir` (when given), the current directory and the scenes directory.
pub fn resolve_scene(spec: &str, plan_dir: Option<&Path>) -> Result<String, String> {
    if crsh_scene::builtin::is_name(spec) {
        return Ok(spec.to_string());
    }
    let env_dir = std::env::var_os("CRSH_SCENES").map(PathBuf::from);
    let mut scene_dirs: Vec<PathBuf> = Vec::new();
    match &env_dir {
        Some(d) => scene_dirs.push(d.clone()),
        None => {
            scene_dirs.push(PathBuf::from("../shared/scenes"));
            // A plan in `<repo>/plans/` finds `<repo>/../shared/scenes` too.
            if let Some(d) = plan_dir {
                scene_dirs.push(d.join("../../shared/scenes"));
            }
        }
    }
    let mut candidates: Vec<PathBuf> = Vec::new();
    if let Some(rest) = spec.strip_prefix("${CRSH_SCENES}") {
        let rest = rest.trim_start_matches(['/', '\\']);
        candidates.extend(scene_dirs.iter().map(|d| d.join(rest)));
    } else {
        let p = Path::new(spec);
        if p.is_absolute() {
            candidates.push(p.to_path_buf());
        } else {
            if let Some(d) = plan_dir {
                candidates.push(d.join(p));
            }
            candidates.push(p.to_path_buf());
            candidates.extend(scene_dirs.iter().map(|d| d.join(p)));
        }
    }
    candidates
        .iter()
        .find(|c| c.is_file())
        .map(|c| c.display().to_string())
        .ok_or_else(|| {
            let tried: Vec<String> = candidates.iter().map(|c| c.display().to_string()).collect();
            format!(
                "scene not found: {spec} (tried {}; not a built-in scene: {}, {})",
                tried.join(", "),
                crsh_scene::builtin::NAMES.join(", "),
                crsh_scene::builtin::PATTERNS
                    .iter()
                    .map(|(p, _)| *p)
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        })
}

/// Whether the plan-wide grid key `key` applies to a pipeline `base` whose own grid has the
/// keys `own`: a `STAGE.*` key (`kind` included) applies only when `base` fills the slot `STAGE`
/// or the pipeline's own grid fills it with `STAGE.kind`. So `sort.kind = [...]` sweeps the
/// sorter of the pipelines that sort, and does not give RAH a sorter without a hasher.
fn applies(key: &str, base: &PipelineConfig, own: &[&String]) -> bool {
    let Some((stage, _)) = key.split_once('.') else {
        return true; // `STAGE=off`-style keys and malformed ones: let `set` judge
    };
    let Some(slot) = StageKind::from_key(stage) else {
        return true; // an unknown stage: let `set` report it
    };
    base.slot(slot).is_some() || own.iter().any(|k| *k == &format!("{stage}.kind"))
}

/// Orders `KEY=VALUE` assignments so that variant choices (`STAGE.kind=...`, `STAGE=off`)
/// come first (stably), and parameters land on the variant the assignments pick.
fn variant_choices_first(sets: &mut [String]) {
    sets.sort_by_key(|s| {
        let key = s.split('=').next().unwrap_or("");
        !key.ends_with(".kind") && key.contains('.')
    });
}

/// The reference pipeline `r` with the plan's `reference_params` (`KEY=VALUE` assignments,
/// variant choices first) applied and checked; a bad key or value is a usage error.
fn with_reference_params(
    mut r: PipelineConfig,
    sets: &[String],
    registries: &Registries,
) -> CliResult<PipelineConfig> {
    if sets.is_empty() {
        return Ok(r);
    }
    let mut ordered = sets.to_vec();
    variant_choices_first(&mut ordered);
    for s in &ordered {
        r.set(s)
            .map_err(|e| CliError::usage(format!("reference_params {s}: {e}")))?;
    }
    registries
        .resolve(&r, BackendKind::Cpu)
        .map_err(|e| CliError::usage(format!("reference_params: {e}")))
}

/// Checks `frames` (`1..=MAX_FRAMES`) and `reference_every` (at least 1, and only with
/// `frames`); `reference_params` does not combine with `frames` (a frames cell's reference is
/// the plain `reference` intersector, [`crsh::render_frames`] builds it per frame).
fn check_frames(plan: &Plan) -> CliResult<()> {
    let max = crsh::frames::MAX_FRAMES;
    match plan.frames {
        Some(f) if f == 0 || f > max => Err(CliError::usage(format!(
            "frames = {f} is outside 1..={max}"
        ))),
        None if plan.reference_every != 1 => Err(CliError::usage(format!(
            "reference_every = {} applies only to frames cells: set `frames` too",
            plan.reference_every
        ))),
        _ if plan.reference_every == 0 || plan.reference_every > max => {
            Err(CliError::usage(format!(
                "reference_every = {} is outside 1..={max}",
                plan.reference_every
            )))
        }
        Some(_) if !plan.reference_params.is_empty() => Err(CliError::usage(
            "reference_params does not apply to frames cells (their reference is the plain `reference` intersector); remove one of them",
        )),
        _ => Ok(()),
    }
}

/// Checks the plan's `baseline`: at most one key, swept by the plan-wide grid or a pipeline's
/// own, and its value among the values every pipeline sweeping it lists (`entries`: each
/// pipeline's label and effective grid), so that every cell with the key has its baseline cell
/// in the expansion.
fn check_baseline<'a>(
    baseline: &BTreeMap<String, GridValue>,
    plan_grid: &Grid,
    entries: impl Iterator<Item = (&'a str, &'a [(String, Vec<GridValue>)])> + Clone,
) -> CliResult<()> {
    let mut keys = baseline.iter();
    let Some((key, value)) = keys.next() else {
        return Ok(());
    };
    if keys.next().is_some() {
        let all: Vec<&str> = baseline.keys().map(String::as_str).collect();
        return Err(CliError::usage(format!(
            "baseline names {} keys ({}); give one grid key and its baseline value",
            all.len(),
            all.join(", ")
        )));
    }
    let sweeping: Vec<(&str, &Vec<GridValue>)> = entries
        .clone()
        .filter_map(|(label, grid)| grid.iter().find(|(k, _)| k == key).map(|(_, v)| (label, v)))
        .collect();
    if sweeping.is_empty() {
        let mut grid_keys: Vec<&str> = plan_grid
            .keys()
            .map(String::as_str)
            .chain(entries.flat_map(|(_, g)| g.iter().map(|(k, _)| k.as_str())))
            .collect();
        grid_keys.sort_unstable();
        grid_keys.dedup();
        return Err(CliError::usage(format!(
            "baseline key `{key}` is not a grid key of the plan (grid keys: {})",
            if grid_keys.is_empty() {
                "none".to_string()
            } else {
                grid_keys.join(", ")
            }
        )));
    }
    let want = value.to_string();
    for (label, values) in sweeping {
        if !values.iter().any(|v| v.to_string() == want) {
            let listed: Vec<String> = values.iter().map(ToString::to_string).collect();
            return Err(CliError::usage(format!(
                "baseline `{key}` = {want} is not among the values pipeline `{label}` sweeps ({}); add it to the grid",
                listed.join(", ")
            )));
        }
    }
    Ok(())
}

/// Every combination of the grid's values, keys in order.
fn combinations(grid: &[(String, Vec<GridValue>)]) -> Vec<Vec<(String, String)>> {
    let mut out: Vec<Vec<(String, String)>> = vec![Vec::new()];
    for (k, vals) in grid {
        let mut next = Vec::with_capacity(out.len() * vals.len());
        for prefix in &out {
            for v in vals {
                let mut c = prefix.clone();
                c.push((k.clone(), v.to_string()));
                next.push(c);
            }
        }
        out = next;
    }
    out
}

/// Expands `plan` into cells, in order scene × width × depth × pipeline × grid × backend.
/// Resolves every cell's pipeline against its backend's registry and the reference against the
/// CPU's: an unknown pipeline, variant or parameter or a bad value is a usage error naming the
/// cell; a pipeline that only another backend can run makes a failed cell (its reason says
/// which backend has the stage). Scenes are not loaded here; a missing one makes failed cells.
pub fn expand(
    plan: &Plan,
    plan_dir: Option<&Path>,
    registries: &Registries,
) -> CliResult<Vec<Cell>> {
    if plan.scenes.is_empty() {
        return Err(CliError::usage("the plan names no scenes"));
    }
    if plan.pipelines.is_empty() {
        return Err(CliError::usage("the plan names no pipelines"));
    }
    if plan.backends.is_empty() {
        return Err(CliError::usage("the plan names no backends"));
    }
    if plan.repeat == 0 || plan.repeat > MAX_REPEAT {
        return Err(CliError::usage(format!(
            "repeat = {} is outside 1..={MAX_REPEAT}",
            plan.repeat
        )));
    }
    if plan.warmup > MAX_REPEAT {
        return Err(CliError::usage(format!(
            "warmup = {} is above {MAX_REPEAT}",
            plan.warmup
        )));
    }
    if plan.threads == Some(0) {
        return Err(CliError::usage("threads = 0: give at least 1"));
    }
    crate::render::check_light_radius(plan.light_radius, "light_radius =")?;
    check_frames(plan)?;
    let side = crsh_core::pipeline::MAX_IMAGE_SIDE;
    let widths = plan.width.to_vec();
    let depths = plan.depth.to_vec();
    if widths.is_empty() || depths.is_empty() {
        return Err(CliError::usage("width and depth need at least one value"));
    }
    for w in widths.iter().chain(plan.height.iter()) {
        if *w == 0 || *w > side {
            return Err(CliError::usage(format!(
                "image side {w} is outside 1..={side}"
            )));
        }
    }
    let own_depths: Vec<Option<Vec<u32>>> = plan
        .pipelines
        .iter()
        .map(|p| p.depth.as_ref().map(OneOrMany::to_vec))
        .collect();
    if let Some(p) = plan
        .pipelines
        .iter()
        .zip(&own_depths)
        .find_map(|(p, d)| d.as_ref().is_some_and(Vec::is_empty).then_some(p))
    {
        return Err(CliError::usage(format!(
            "pipeline `{}`: depth needs at least one value",
            p.label.as_deref().unwrap_or(&p.pipeline)
        )));
    }
    for d in depths.iter().chain(own_depths.iter().flatten().flatten()) {
        if *d > crate::args::MAX_DEPTH {
            return Err(CliError::usage(format!(
                "depth {d} is above {}",
                crate::args::MAX_DEPTH
            )));
        }
    }
    let backends: Vec<BackendKind> = plan
        .backends
        .iter()
        .map(|b| b.parse::<BackendKind>().map_err(CliError::usage))
        .collect::<CliResult<_>>()?;
    for (k, v) in plan
        .grid
        .iter()
        .chain(plan.pipelines.iter().flat_map(|p| p.grid.iter()))
    {
        if v.to_vec().is_empty() {
            return Err(CliError::usage(format!("grid key {k} has no values")));
        }
    }
    let reference_name = match plan.reference.trim() {
        "" | "none" | "off" => None,
        r => Some(r.to_string()),
    };
    let mut axes_seen = std::collections::BTreeSet::new();
    for a in &plan.accuracy_axes {
        if !ACCURACY_AXES.contains(&a.as_str()) {
            return Err(CliError::usage(format!(
                "unknown accuracy axis `{a}` (axes: {})",
                ACCURACY_AXES.join(", ")
            )));
        }
        if !axes_seen.insert(a) {
            return Err(CliError::usage(format!("accuracy axis `{a}` listed twice")));
        }
    }
    let reference_sets: Vec<String> = plan
        .reference_params
        .iter()
        .map(|(k, v)| format!("{k}={v}"))
        .collect();

    // Each pipeline's base config and effective grid, checked once.
    struct Entry {
        label: String,
        pipeline: String,
        depths: Vec<u32>,
        grid: Vec<(String, Vec<GridValue>)>,
    }
    let mut entries = Vec::new();
    let mut used: std::collections::BTreeSet<String> = std::collections::BTreeSet::new();
    for (p, own_depth) in plan.pipelines.iter().zip(own_depths) {
        // A pipeline file is relative to the plan's directory; preset names stay as they are.
        let pipeline = match plan_dir {
            Some(d)
                if registries.preset(&p.pipeline).is_none()
                    && !Path::new(&p.pipeline).is_absolute()
                    && (p.pipeline.ends_with(".toml") || d.join(&p.pipeline).is_file()) =>
            {
                d.join(&p.pipeline).display().to_string()
            }
            _ => p.pipeline.clone(),
        };
        let base = pipeline_unresolved(registries, &pipeline, &[])
            .map_err(|e| CliError::usage(format!("pipeline `{}`: {e}", p.pipeline)))?;
        let mut merged: BTreeMap<String, Vec<GridValue>> = BTreeMap::new();
        for (k, v) in plan.grid.iter().chain(p.grid.iter()) {
            merged.insert(k.clone(), v.to_vec());
        }
        let own: Vec<&String> = p.grid.keys().collect();
        let grid: Vec<(String, Vec<GridValue>)> = merged
            .iter()
            .filter(|(k, _)| {
                // plan-wide keys that do not apply are dropped; a pipeline's own keys always apply
                p.grid.contains_key(*k) || applies(k, &base, &own)
            })
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect();
        used.extend(grid.iter().map(|(k, _)| k.clone()));
        entries.push(Entry {
            label: p.label.clone().unwrap_or_else(|| base.name.clone()),
            pipeline,
            depths: own_depth.unwrap_or_else(|| depths.clone()),
            grid,
        });
    }
    if let Some(k) = plan.grid.keys().find(|k| !used.contains(*k)) {
        let stage = k.split('.').next().unwrap_or(k);
        return Err(CliError::usage(format!(
            "grid key `{k}` applies to no pipeline: none of them has a `{stage}` stage (to add one, put `{stage}.kind` in a pipeline's own grid)"
        )));
    }
    let mut labels: Vec<&str> = entries.iter().map(|e| e.label.as_str()).collect();
    labels.sort_unstable();
    if let Some(w) = labels.windows(2).find(|w| w[0] == w[1]) {
        return Err(CliError::usage(format!(
            "two pipelines are labelled `{}`; give each a distinct `label`",
            w[0]
        )));
    }
    check_baseline(
        &plan.baseline,
        &plan.grid,
        entries
            .iter()
            .map(|e| (e.label.as_str(), e.grid.as_slice())),
    )?;
    // Every depth a pipeline uses, in order of first appearance, the plan's first: without
    // per-pipeline depths the order is the plan's depth list, as before.
    let mut all_depths: Vec<u32> = Vec::new();
    for &d in depths
        .iter()
        .chain(entries.iter().flat_map(|e| e.depths.iter()))
    {
        if !all_depths.contains(&d) && entries.iter().any(|e| e.depths.contains(&d)) {
            all_depths.push(d);
        }
    }

    let mut cells = Vec::new();
    for scene_spec in &plan.scenes {
        let scene = resolve_scene(scene_spec, plan_dir);
        for &width in &widths {
            for &depth in &all_depths {
                for e in entries.iter().filter(|e| e.depths.contains(&depth)) {
                    for combo in combinations(&e.grid) {
                        let mut sets: Vec<String> =
                            combo.iter().map(|(k, v)| format!("{k}={v}")).collect();
                        variant_choices_first(&mut sets);
                        let params: BTreeMap<String, String> = combo.into_iter().collect();
                        let describe = || {
                            let p: Vec<String> =
                                params.iter().map(|(k, v)| format!("{k}={v}")).collect();
                            format!("cell {} {}", e.label, p.join(" "))
                        };
                        let mut unresolved = pipeline_unresolved(registries, &e.pipeline, &sets)
                            .map_err(|err| {
                                CliError::usage(format!("{}: {err}", describe().trim_end()))
                            })?;
                        unresolved.name = e.label.clone();
                        for &backend in &backends {
                            if cells.len() >= MAX_CELLS {
                                return Err(CliError::usage(format!(
                                    "the plan expands to more than {MAX_CELLS} cells"
                                )));
                            }
                            let (config, unsupported) = match registries
                                .resolve(&unresolved, backend)
                            {
                                Ok(c) => (c, None),
                                Err(err) => {
                                    // Runnable elsewhere: this cell fails with the reason;
                                    // runnable nowhere: the plan is wrong.
                                    let elsewhere = BackendKind::ALL
                                        .into_iter()
                                        .filter(|b| *b != backend)
                                        .find_map(|b| registries.resolve(&unresolved, b).ok());
                                    match elsewhere {
                                        Some(c) => (c, Some(format!("building pipeline: {err}"))),
                                        None => {
                                            return Err(CliError::usage(format!(
                                                "{}: pipeline `{}`: {err}",
                                                describe().trim_end(),
                                                e.label
                                            )))
                                        }
                                    }
                                }
                            };
                            let reference = reference_name
                                .as_deref()
                                .map(|r| reference_config(registries, &config, r))
                                .transpose()
                                .map_err(|err| CliError::usage(format!("reference: {err}")))?
                                .map(|r| with_reference_params(r, &reference_sets, registries))
                                .transpose()?;
                            cells.push(Cell {
                                index: cells.len(),
                                scene_spec: scene_spec.clone(),
                                scene: scene.clone(),
                                pipeline: e.label.clone(),
                                backend: backend.name().to_string(),
                                params: params.clone(),
                                width,
                                height: plan.height,
                                depth,
                                config,
                                reference,
                                unsupported,
                            });
                        }
                    }
                }
            }
        }
    }
    Ok(cells)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quick(pipelines: &str, sets: &[&str]) -> Plan {
        QuickPlan {
            scenes: vec!["cornell-mirrors".into()],
            pipelines: split_list(pipelines),
            sets: sets.iter().map(|s| s.to_string()).collect(),
            ..Default::default()
        }
        .into_plan()
        .unwrap()
    }

    #[test]
    fn quick_form_expands_like_a_grid_and_skips_empty_slots() {
        let plan = quick(
            "crsh,rah,bvh",
            &["hierarchy.subdivision=8,16", "hierarchy.depth=2,3"],
        );
        let cells = expand(&plan, None, &Registries::builtin()).unwrap();
        // crsh and rah: 2 × 2 each; bvh has no hierarchy: one cell.
        assert_eq!(cells.len(), 9);
        let bvh: Vec<_> = cells.iter().filter(|c| c.pipeline == "bvh").collect();
        assert_eq!(bvh.len(), 1);
        assert!(bvh[0].params.is_empty());
        let crsh: Vec<_> = cells.iter().filter(|c| c.pipeline == "crsh").collect();
        let combos: Vec<(String, String)> = crsh
            .iter()
            .map(|c| {
                (
                    c.params["hierarchy.subdivision"].clone(),
                    c.params["hierarchy.depth"].clone(),
                )
            })
            .collect();
        let mut sorted = combos.clone();
        sorted.sort();
        sorted.dedup();
        let want: Vec<(String, String)> = [("16", "2"), ("16", "3"), ("8", "2"), ("8", "3")]
            .iter()
            .map(|(a, b)| (a.to_string(), b.to_string()))
            .collect();
        assert_eq!(sorted, want, "every combination exactly once: {combos:?}");
        assert_eq!(combos.len(), 4);
        for c in &crsh {
            let h = c.config.hierarchy.as_ref().unwrap();
            assert_eq!(
                h.params["subdivision"].to_string(),
                c.params["hierarchy.subdivision"]
            );
            assert_eq!(h.params["depth"].to_string(), c.params["hierarchy.depth"]);
        }
        assert_eq!(crsh[0].label(), "crsh depth=2 subdivision=8");
    }

    #[test]
    fn plan_and_quick_form_agree() {
        let toml = r#"
            scenes = ["cornell-mirrors"]
            [grid]
            "hierarchy.subdivision" = [8, 16]
            "hierarchy.depth" = [2, 3]
            [[pipelines]]
            pipeline = "crsh"
            [[pipelines]]
            pipeline = "rah"
            [[pipelines]]
            pipeline = "bvh"
        "#;
        let from_file = parse_plan(toml).unwrap();
        let from_cli = quick(
            "crsh,rah,bvh",
            &["hierarchy.subdivision=8,16", "hierarchy.depth=2,3"],
        );
        let cat = Registries::builtin();
        let a = expand(&from_file, None, &cat).unwrap();
        let b = expand(&from_cli, None, &cat).unwrap();
        assert_eq!(a.len(), b.len());
        for (x, y) in a.iter().zip(&b) {
            assert_eq!(x.label(), y.label());
            assert_eq!(x.config, y.config);
        }
    }

    #[test]
    fn bad_plans_are_usage_errors() {
        let cat = Registries::builtin();
        assert!(parse_plan("scenes = 3").is_err());
        assert!(parse_plan("scenes = [\"a\"]\npipelines = []\nbogus = 1").is_err());
        let mut p = quick("crsh", &["hierarchy.nonsense=1"]);
        assert_eq!(expand(&p, None, &cat).unwrap_err().exit_code(), 2);
        p = quick("nosuch", &[]);
        assert_eq!(expand(&p, None, &cat).unwrap_err().exit_code(), 2);
        p = quick("crsh", &[]);
        p.repeat = 0;
        assert_eq!(expand(&p, None, &cat).unwrap_err().exit_code(), 2);
        p = quick("crsh", &[]);
        p.reference = "nosuch".into();
        assert_eq!(expand(&p, None, &cat).unwrap_err().exit_code(), 2);
        assert!(parse_set("x").is_err());
        assert!(parse_set("a=").is_err());
    }

    #[test]
    fn kind_assignments_apply_before_parameters() {
        // `hash.direction_bits` sorts before `hash.kind`: it must still land on `morton`.
        let toml = r#"
            scenes = ["cornell-mirrors"]
            [[pipelines]]
            pipeline = "rah"
            [pipelines.grid]
            "hash.direction_bits" = [6]
            "hash.kind" = ["morton"]
            "sort.kind" = ["radix"]
        "#;
        let plan = parse_plan(toml).unwrap();
        let cells = expand(&plan, None, &Registries::builtin()).unwrap();
        assert_eq!(cells.len(), 1);
        let h = cells[0].config.hash.as_ref().unwrap();
        assert_eq!(h.kind, "morton");
        assert_eq!(h.params["direction_bits"].to_string(), "6");
    }

    #[test]
    fn plan_wide_stage_keys_skip_pipelines_without_the_stage() {
        let toml = r#"
            scenes = ["cornell-mirrors"]
            [grid]
            "sort.kind" = ["compress", "radix"]
            [[pipelines]]
            pipeline = "crsh"
            [[pipelines]]
            pipeline = "rah"
            [[pipelines]]
            pipeline = "rah"
            label = "rah-sorted"
            [pipelines.grid]
            "hash.kind" = "morton"
            "sort.kind" = "radix"
        "#;
        let cells = expand(&parse_plan(toml).unwrap(), None, &Registries::builtin()).unwrap();
        let by = |p: &str| cells.iter().filter(|c| c.pipeline == p).count();
        assert_eq!((by("crsh"), by("rah"), by("rah-sorted")), (2, 1, 1));
        let rah = cells.iter().find(|c| c.pipeline == "rah").unwrap();
        assert!(rah.config.sort.is_none() && rah.params.is_empty());
        let sorted = cells.iter().find(|c| c.pipeline == "rah-sorted").unwrap();
        assert_eq!(sorted.config.sort.as_ref().unwrap().kind, "radix");
        // A plan-wide key no pipeline can take is an error, not a silent no-op.
        let e = expand(
            &quick("rah,bvh", &["hash.kind=thesis,morton"]),
            None,
            &Registries::builtin(),
        )
        .unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert!(e.to_string().contains("applies to no pipeline"), "{e}");
    }

    #[test]
    fn reference_params_reach_only_the_reference_and_axes_are_checked() {
        let toml = r#"
            scenes = ["cornell-mirrors"]
            reference = "brute64"
            reference_params = { "raygen.offset" = "wachter" }
            accuracy_axes = ["hit_agreement", "psnr_db", "self_hit_rate"]
            [grid]
            "raygen.offset" = ["normal", "fixed"]
            [[pipelines]]
            pipeline = "bvh"
        "#;
        let plan = parse_plan(toml).unwrap();
        let cat = Registries::builtin();
        let cells = expand(&plan, None, &cat).unwrap();
        assert_eq!(cells.len(), 2);
        for c in &cells {
            let r = c.reference.as_ref().unwrap();
            assert_eq!(r.intersect.kind, "brute64");
            assert_eq!(r.raygen.params["offset"].to_string(), "wachter");
            assert_eq!(
                c.config.raygen.params["offset"].to_string(),
                c.params["raygen.offset"]
            );
        }
        // The default: no reference params, hit agreement only.
        let plain = parse_plan("scenes = [\"x\"]\n[[pipelines]]\npipeline = \"bvh\"\n").unwrap();
        assert!(plain.reference_params.is_empty());
        assert_eq!(plain.accuracy_axes, vec!["hit_agreement".to_string()]);
        for (bad, needle) in [
            (
                toml.replace("\"raygen.offset\" = \"wachter\"", "\"raygen.bogus\" = 1"),
                "raygen.bogus",
            ),
            (toml.replace("wachter\" }", "sideways\" }"), "sideways"),
            (
                toml.replace("\"psnr_db\",", "\"psnr\","),
                "unknown accuracy axis `psnr`",
            ),
            (
                toml.replace("\"psnr_db\",", "\"hit_agreement\","),
                "listed twice",
            ),
        ] {
            let e = expand(&parse_plan(&bad).unwrap(), None, &cat).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{bad}");
            assert!(e.to_string().contains(needle), "{needle}: {e}");
        }
    }

    #[test]
    fn frames_are_optional_and_checked() {
        let cat = Registries::builtin();
        let base = "scenes = [\"cornell-mirrors-animated\"]\n[[pipelines]]\npipeline = \"bvh\"\n";
        let plain = parse_plan(base).unwrap();
        assert_eq!((plain.frames, plain.reference_every), (None, 1));
        // A static plan serializes as before: no frames keys.
        let text = toml::to_string(&plain).unwrap();
        assert!(
            !text.contains("frames") && !text.contains("reference_every"),
            "{text}"
        );
        let p = parse_plan(&format!("frames = 4\nreference_every = 2\n{base}")).unwrap();
        assert_eq!((p.frames, p.reference_every), (Some(4), 2));
        assert_eq!(expand(&p, None, &cat).unwrap().len(), 1);
        assert_eq!(parse_plan(&toml::to_string(&p).unwrap()).unwrap(), p);
        for (bad, needle) in [
            ("frames = 0\n", "frames = 0 is outside"),
            ("frames = 100001\n", "frames = 100001 is outside"),
            ("frames = 2\nreference_every = 0\n", "reference_every = 0"),
            ("reference_every = 2\n", "set `frames` too"),
            (
                "frames = 2\nreference_params = { \"raygen.offset\" = \"wachter\" }\n",
                "reference_params does not apply",
            ),
        ] {
            let e = expand(&parse_plan(&format!("{bad}{base}")).unwrap(), None, &cat).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{bad}");
            assert!(e.to_string().contains(needle), "{needle}: {e}");
        }
        let q = QuickPlan {
            frames: Some(3),
            ..Default::default()
        }
        .into_plan()
        .unwrap();
        assert_eq!(q.frames, Some(3));
    }

    #[test]
    fn pipelines_may_carry_their_own_depths() {
        let toml = r#"
            scenes = ["cornell-mirrors"]
            depth = [1, 2]
            [[pipelines]]
            pipeline = "bvh"
            [[pipelines]]
            pipeline = "bvh"
            label = "deep"
            depth = [3, 1]
        "#;
        let cells = expand(&parse_plan(toml).unwrap(), None, &Registries::builtin()).unwrap();
        let got: Vec<(&str, u32)> = cells
            .iter()
            .map(|c| (c.pipeline.as_str(), c.depth))
            .collect();
        // Depths in order of first appearance, the plan's first; each pipeline only at its own.
        assert_eq!(got, [("bvh", 1), ("deep", 1), ("bvh", 2), ("deep", 3)]);
        // A plan depth no pipeline uses makes no cells; an empty or too deep list is an error.
        let only = toml.replace("depth = [1, 2]", "depth = 7").replace(
            "pipeline = \"bvh\"\n            [[pipelines]]",
            "pipeline = \"bvh\"\n            depth = 0\n            [[pipelines]]",
        );
        let cells = expand(&parse_plan(&only).unwrap(), None, &Registries::builtin()).unwrap();
        let depths: Vec<u32> = cells.iter().map(|c| c.depth).collect();
        assert_eq!(depths, [0, 3, 1]);
        for (bad, needle) in [
            ("depth = [3, 1]", "depth = []"),
            ("depth = [3, 1]", "depth = 99"),
        ] {
            let e = expand(
                &parse_plan(&toml.replace(bad, needle)).unwrap(),
                None,
                &Registries::builtin(),
            )
            .unwrap_err();
            assert_eq!(e.exit_code(), 2);
            let want = if needle.contains("[]") {
                "pipeline `deep`: depth needs at least one value"
            } else {
                "depth 99 is above"
            };
            assert!(e.to_string().contains(want), "{e}");
        }
    }

    #[test]
    fn the_baseline_names_one_swept_key_and_one_of_its_values() {
        let toml = r#"
            scenes = ["cornell-mirrors"]
            baseline = { "raygen.offsets" = "none" }
            [grid]
            "raygen.offsets" = ["none", "center"]
            [[pipelines]]
            pipeline = "bvh"
            [[pipelines]]
            pipeline = "brute"
            [pipelines.grid]
            "intersect.test" = ["mt", "watertight"]
        "#;
        let cat = Registries::builtin();
        let plan = parse_plan(toml).unwrap();
        assert_eq!(expand(&plan, None, &cat).unwrap().len(), 6);
        assert_eq!(parse_plan(&toml::to_string(&plan).unwrap()).unwrap(), plan);
        // A key of one pipeline's own grid.
        let own = toml.replace(
            "{ \"raygen.offsets\" = \"none\" }",
            "{ \"intersect.test\" = \"watertight\" }",
        );
        assert!(expand(&parse_plan(&own).unwrap(), None, &cat).is_ok());
        for (from, to, needle) in [
            (
                "{ \"raygen.offsets\" = \"none\" }",
                "{ \"raygen.offset\" = \"normal\" }",
                "baseline key `raygen.offset` is not a grid key of the plan (grid keys: intersect.test, raygen.offsets)",
            ),
            (
                "{ \"raygen.offsets\" = \"none\" }",
                "{ \"raygen.offsets\" = \"vertex\" }",
                "baseline `raygen.offsets` = vertex is not among the values pipeline `bvh` sweeps (none, center)",
            ),
            (
                "{ \"raygen.offsets\" = \"none\" }",
                "{ \"raygen.offsets\" = \"none\", \"intersect.test\" = \"mt\" }",
                "baseline names 2 keys (intersect.test, raygen.offsets)",
            ),
        ] {
            let e = expand(&parse_plan(&toml.replace(from, to)).unwrap(), None, &cat).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{to}");
            assert!(e.to_string().contains(needle), "{needle}: {e}");
        }
    }

    #[test]
    fn missing_scene_is_a_reason_not_an_error() {
        let r = resolve_scene("no/such/scene.toml", None);
        assert!(r
            .unwrap_err()
            .starts_with("scene not found: no/such/scene.toml"));
        assert_eq!(resolve_scene("office-boxes", None).unwrap(), "office-boxes");
        // Sized built-ins stay names; a bad size is left for the loader to refuse.
        for name in [
            "glass-sphere",
            "glass-sphere-500",
            "glass-sphere-7",
            "glass-shell",
            "glass-shell-500",
            "glass-shell-502",
        ] {
            assert_eq!(resolve_scene(name, None).unwrap(), name);
        }
    }
}
