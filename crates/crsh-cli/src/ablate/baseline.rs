//! The plan's `baseline = { KEY = VALUE }`: every cell whose parameters include `KEY` is set
//! against its baseline cell, the cell of the same run identical but for `KEY = VALUE` (same
//! scene, size, depth, pipeline, backend and other parameters; the baseline cell pairs with
//! itself), per ray kind traced (camera rays left out: seed 001's offsets move extension rays):
//!
//! - `baseline.csv`: one row per cell and kind, the cell's and its baseline's figures side by
//!   side (rays, inner nodes, leaves and tests per ray, rays ended by offsets, trace and ray
//!   creation times), the ratios (inner nodes, leaves and tests per ray in % of the baseline's;
//!   trace time and trace + ray creation over the baseline's) and `identical_hits`;
//! - `baseline.md`: seed 001 tables 2-4's layout, one table per ray kind: rows scene ×
//!   setting, the baseline value's column absolute (inner nodes / leaves per ray), every other
//!   value's in % of it, then the same layout for trace times;
//! - a table in `report.html` ([`html_section`]).
//!
//! Ray creation is one timer for all kinds of a cell (the driver times every batch's
//! generation under `ray_creation`), so the trace + ray creation ratio adds the CELL's ray
//! creation to the kind's trace time; for a cell that traces one kind of extension ray (AO, or
//! shadow rays at depth 0) that is the kind's own.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::fmt::Write as _;

use serde_json::json;

use super::html::escape;
use super::results::{
    cell_id_fields, cell_id_header, kind_order, push_row, CellResult, KindPerRay, Measures, Results,
};

/// One ray kind's figures in one cell.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct KindFigures {
    /// Rays of the kind.
    pub rays: u64,
    /// Its work per ray.
    pub per_ray: KindPerRay,
    /// Median trace time of the kind, ms.
    pub trace_ms: f64,
    /// The cell's median ray-creation time (every kind), ms.
    pub cell_ray_creation_ms: f64,
}

impl KindFigures {
    fn of(m: &Measures, kind: &str) -> KindFigures {
        let k = m.per_kind.get(kind).cloned().unwrap_or_default();
        KindFigures {
            rays: k.rays,
            per_ray: KindPerRay::of(&k),
            trace_ms: k.trace_ms,
            cell_ray_creation_ms: m.ray_creation_ms(),
        }
    }
}

/// A cell set against its baseline cell for one ray kind.
#[derive(Clone, Debug)]
pub struct BaselineRow<'a> {
    /// The cell.
    pub cell: &'a CellResult,
    /// Its baseline cell (the cell itself for the baseline value).
    pub base: &'a CellResult,
    /// The ray kind.
    pub kind: String,
    /// The cell's figures for the kind.
    pub figures: KindFigures,
    /// The baseline cell's.
    pub baseline: KindFigures,
    /// Whether the cell's hits are the baseline's: hit agreement with the reference exactly 1
    /// and every kind's ray count equal to the baseline cell's (`None` without a reference).
    pub identical_hits: Option<bool>,
}

/// `100 × a / b`, or `None` when `b` is 0.
fn percent(a: f64, b: f64) -> Option<f64> {
    (b > 0.0).then(|| 100.0 * a / b)
}

/// `a / b`, or `None` when `b` is 0.
fn ratio(a: f64, b: f64) -> Option<f64> {
    (b > 0.0).then(|| a / b)
}

impl BaselineRow<'_> {
    /// Inner nodes per ray in % of the baseline's (`None` when the baseline visited none).
    pub fn inner_nodes_pct(&self) -> Option<f64> {
        percent(
            self.figures.per_ray.inner_nodes,
            self.baseline.per_ray.inner_nodes,
        )
    }

    /// Leaves per ray in % of the baseline's.
    pub fn leaves_pct(&self) -> Option<f64> {
        percent(self.figures.per_ray.leaves, self.baseline.per_ray.leaves)
    }

    /// Bounds and ray-triangle tests per ray in % of the baseline's.
    pub fn tests_pct(&self) -> Option<f64> {
        percent(self.figures.per_ray.tests, self.baseline.per_ray.tests)
    }

    /// The kind's trace time over the baseline's.
    pub fn trace_ratio(&self) -> Option<f64> {
        ratio(self.figures.trace_ms, self.baseline.trace_ms)
    }

    /// The kind's trace time plus the cell's ray creation, over the baseline's.
    pub fn trace_plus_creation_ratio(&self) -> Option<f64> {
        ratio(
            self.figures.trace_ms + self.figures.cell_ray_creation_ms,
            self.baseline.trace_ms + self.baseline.cell_ray_creation_ms,
        )
    }
}

/// The cells of a run paired with their baselines.
#[derive(Clone, Debug)]
pub struct Pairing<'a> {
    /// The baseline key.
    pub key: String,
    /// Its baseline value (as the cells' parameters spell it).
    pub value: String,
    /// The values of the key in the run, the baseline's first, then in plan order.
    pub values: Vec<String>,
    /// One row per paired cell and ray kind, in plan order.
    pub rows: Vec<BaselineRow<'a>>,
    /// Cells with the key that have no row, and why (failed, or their baseline cell failed or
    /// is not in these results, as in a shard).
    pub unpaired: Vec<(&'a CellResult, String)>,
}

/// What makes two cells the same but for their parameters' values: scene, pipeline, backend,
/// size, depth and the parameters given.
fn identity(c: &CellResult, params: &BTreeMap<String, String>) -> String {
    json!([
        c.scene_source,
        c.scene,
        c.pipeline,
        c.backend,
        c.width,
        c.height,
        c.depth,
        params
    ])
    .to_string()
}

/// The kinds a pair traced, camera rays left out, in [`crsh_core::RayKind::ALL`] order.
fn kinds_of(a: &Measures, b: &Measures) -> Vec<String> {
    let kinds: BTreeSet<(usize, &String)> = a
        .per_kind
        .iter()
        .chain(&b.per_kind)
        .filter(|(k, s)| *k != "primary" && s.rays > 0)
        .map(|(k, _)| (kind_order(k), k))
        .collect();
    kinds.into_iter().map(|(_, k)| k.clone()).collect()
}

/// Whether `a`'s hits are `b`'s (see [`BaselineRow::identical_hits`]).
fn identical_hits(a: &Measures, b: &Measures) -> Option<bool> {
    let agreement = a.accuracy.as_ref()?.hit_agreement;
    let kinds: BTreeSet<&String> = a.per_kind.keys().chain(b.per_kind.keys()).collect();
    let rays = |m: &Measures, k: &str| m.per_kind.get(k).map_or(0, |s| s.rays);
    Some(agreement == 1.0 && kinds.iter().all(|k| rays(a, k) == rays(b, k)))
}

/// Pairs the cells of `results` with their baselines (`None` when the plan has no baseline).
pub fn pair(results: &Results) -> Option<Pairing<'_>> {
    let (key, value) = results.plan.baseline.iter().next()?;
    let value = value.to_string();
    let by_identity: HashMap<String, &CellResult> = results
        .cells
        .iter()
        .map(|c| (identity(c, &c.params), c))
        .collect();
    let mut values = vec![value.clone()];
    let mut rows = Vec::new();
    let mut unpaired = Vec::new();
    for c in &results.cells {
        let Some(v) = c.params.get(key) else { continue };
        if !values.contains(v) {
            values.push(v.clone());
        }
        let mut params = c.params.clone();
        params.insert(key.clone(), value.clone());
        let base = by_identity.get(&identity(c, &params)).copied();
        let (m, bm, base) = match (c.measures.as_ref(), base) {
            (None, _) => {
                unpaired.push((c, format!("the cell failed: {}", c.reason)));
                continue;
            }
            (_, None) => {
                unpaired.push((c, "its baseline cell is not in these results".to_string()));
                continue;
            }
            (Some(m), Some(b)) => match b.measures.as_ref() {
                Some(bm) if b.ok() && c.ok() => (m, bm, b),
                _ => {
                    unpaired.push((c, format!("its baseline cell `{}` failed", b.label)));
                    continue;
                }
            },
        };
        let same = identical_hits(m, bm);
        for kind in kinds_of(m, bm) {
            rows.push(BaselineRow {
                cell: c,
                base,
                figures: KindFigures::of(m, &kind),
                baseline: KindFigures::of(bm, &kind),
                kind,
                identical_hits: same,
            });
        }
    }
    Some(Pairing {
        key: key.clone(),
        value,
        values,
        rows,
        unpaired,
    })
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map(|x| format!("{x:.digits$}")).unwrap_or_default()
}

/// The header of `baseline.csv`: the cell as `results.csv` names it (its swept keys
/// `params`), its label, then the figures.
pub fn csv_header(params: &[String]) -> Vec<String> {
    let mut h = cell_id_header(params);
    h.extend(
        [
            "label",
            "baseline_key",
            "baseline_value",
            "baseline_label",
            "kind",
            "rays",
            "baseline_rays",
            "inner_nodes_per_ray",
            "baseline_inner_nodes_per_ray",
            "inner_nodes_pct",
            "leaves_per_ray",
            "baseline_leaves_per_ray",
            "leaves_pct",
            "tests_per_ray",
            "baseline_tests_per_ray",
            "tests_pct",
            "offset_ended_fraction",
            "baseline_offset_ended_fraction",
            "trace_ms",
            "baseline_trace_ms",
            "trace_ratio",
            "cell_ray_creation_ms",
            "baseline_cell_ray_creation_ms",
            "trace_plus_creation_ratio",
            "hit_agreement",
            "identical_hits",
        ]
        .iter()
        .map(|s| s.to_string()),
    );
    h
}

/// `baseline.csv`: one row per [`BaselineRow`] (see the module documentation); ratios whose
/// baseline figure is 0 are empty.
pub fn to_csv(p: &Pairing<'_>, results: &Results) -> String {
    let params = results.param_keys();
    let mut out = String::new();
    push_row(&mut out, &csv_header(&params));
    for r in &p.rows {
        let c = r.cell;
        let (f, b) = (&r.figures, &r.baseline);
        let mut row = cell_id_fields(c, &params);
        row.extend([
            c.label.clone(),
            p.key.clone(),
            p.value.clone(),
            r.base.label.clone(),
            r.kind.clone(),
            f.rays.to_string(),
            b.rays.to_string(),
            format!("{:.4}", f.per_ray.inner_nodes),
            format!("{:.4}", b.per_ray.inner_nodes),
            opt(r.inner_nodes_pct(), 2),
            format!("{:.4}", f.per_ray.leaves),
            format!("{:.4}", b.per_ray.leaves),
            opt(r.leaves_pct(), 2),
            format!("{:.4}", f.per_ray.tests),
            format!("{:.4}", b.per_ray.tests),
            opt(r.tests_pct(), 2),
            format!("{:.6}", f.per_ray.offset_ended_fraction),
            format!("{:.6}", b.per_ray.offset_ended_fraction),
            format!("{:.3}", f.trace_ms),
            format!("{:.3}", b.trace_ms),
            opt(r.trace_ratio(), 4),
            format!("{:.3}", f.cell_ray_creation_ms),
            format!("{:.3}", b.cell_ray_creation_ms),
            opt(r.trace_plus_creation_ratio(), 4),
            c.measures
                .as_ref()
                .and_then(|m| m.accuracy.as_ref())
                .map(|a| format!("{:.8}", a.hit_agreement))
                .unwrap_or_default(),
            r.identical_hits.map(|b| b.to_string()).unwrap_or_default(),
        ]);
        push_row(&mut out, &row);
    }
    out
}

/// What names a row of `baseline.md`, per pipeline: the parameters (but the baseline key)
/// that take several values among that pipeline's cells, and whether their size, depth or
/// backend vary.
struct Settings {
    by_pipeline: HashMap<String, (BTreeSet<String>, bool, bool, bool)>,
}

impl Settings {
    fn of(results: &Results, key: &str) -> Settings {
        let mut seen: HashMap<&str, Vec<&CellResult>> = HashMap::new();
        for c in &results.cells {
            seen.entry(&c.pipeline).or_default().push(c);
        }
        let by_pipeline = seen
            .into_iter()
            .map(|(pipeline, cells)| {
                let varies = |f: &dyn Fn(&CellResult) -> String| {
                    cells.iter().map(|c| f(c)).collect::<BTreeSet<_>>().len() > 1
                };
                let keys: BTreeSet<String> = cells
                    .iter()
                    .flat_map(|c| c.params.keys())
                    .filter(|k| {
                        *k != key && varies(&|c| c.params.get(*k).cloned().unwrap_or_default())
                    })
                    .cloned()
                    .collect();
                let size = varies(&|c| format!("{}x{}", c.width, c.height));
                let depth = varies(&|c| c.depth.to_string());
                let backend = varies(&|c| c.backend.clone());
                (pipeline.to_string(), (keys, size, depth, backend))
            })
            .collect();
        Settings { by_pipeline }
    }

    /// The setting of `c`: its pipeline, then what varies (`ao_length=0.05`, `512x512`,
    /// `depth 3`, `[wgpu]`).
    fn name(&self, c: &CellResult) -> String {
        let mut s = c.pipeline.clone();
        let Some((keys, size, depth, backend)) = self.by_pipeline.get(&c.pipeline) else {
            return s;
        };
        for k in keys {
            if let Some(v) = c.params.get(k) {
                let _ = write!(s, " {}={v}", k.rsplit('.').next().unwrap_or(k));
            }
        }
        if *size {
            let _ = write!(s, " {}x{}", c.width, c.height);
        }
        if *depth {
            let _ = write!(s, " depth {}", c.depth);
        }
        if *backend {
            let _ = write!(s, " [{}]", c.backend);
        }
        s
    }
}

/// Rows of one kind's table: (scene, setting) and the row of each value of the key, in plan
/// order.
type KindTable<'p, 'a> = Vec<((String, String), BTreeMap<String, &'p BaselineRow<'a>>)>;

fn kind_table<'p, 'a>(p: &'p Pairing<'a>, kind: &str, settings: &Settings) -> KindTable<'p, 'a> {
    // Grouped by the cell's identity without the baseline key.
    let mut groups: Vec<BTreeMap<String, &'p BaselineRow<'a>>> = Vec::new();
    let mut index: HashMap<String, usize> = HashMap::new();
    for r in p.rows.iter().filter(|r| r.kind == kind) {
        let mut rest = r.cell.params.clone();
        rest.remove(&p.key);
        let i = *index.entry(identity(r.cell, &rest)).or_insert_with(|| {
            groups.push(BTreeMap::new());
            groups.len() - 1
        });
        let value = r.cell.params.get(&p.key).cloned().unwrap_or_default();
        groups[i].insert(value, r);
    }
    groups
        .into_iter()
        .map(|by_value| {
            let c = by_value.values().next().expect("one row per group").cell;
            ((c.scene.clone(), settings.name(c)), by_value)
        })
        .collect()
}

/// The kinds with rows, in order of first appearance (the plan's order of its settings).
fn row_kinds(p: &Pairing<'_>) -> Vec<String> {
    let mut kinds: Vec<String> = Vec::new();
    for r in &p.rows {
        if !kinds.contains(&r.kind) {
            kinds.push(r.kind.clone());
        }
    }
    kinds
}

/// One markdown table: per (scene, setting) row, the baseline value's cell from `absolute`,
/// every other value's from `relative` ("—" where a value has no cell).
fn md_table(
    out: &mut String,
    p: &Pairing<'_>,
    table: &KindTable<'_, '_>,
    baseline_head: &str,
    absolute: &dyn Fn(&BaselineRow<'_>) -> String,
    relative: &dyn Fn(&BaselineRow<'_>) -> String,
) {
    let mut head = vec![
        "scene".to_string(),
        "setting".to_string(),
        format!("{}: {baseline_head}", p.value),
    ];
    head.extend(p.values.iter().skip(1).cloned());
    let _ = writeln!(out, "| {} |", head.join(" | "));
    let align: Vec<&str> = head
        .iter()
        .enumerate()
        .map(|(i, _)| if i < 2 { "---" } else { "---:" })
        .collect();
    let _ = writeln!(out, "|{}|", align.join("|"));
    for ((scene, setting), by_value) in table {
        let mut fields = vec![scene.replace('|', "\\|"), setting.replace('|', "\\|")];
        for (i, v) in p.values.iter().enumerate() {
            fields.push(match by_value.get(v) {
                None => "—".to_string(),
                Some(r) if i == 0 => absolute(r),
                Some(r) => {
                    let mark = if r.identical_hits == Some(false) {
                        " †"
                    } else {
                        ""
                    };
                    format!("{}{mark}", relative(r))
                }
            });
        }
        let _ = writeln!(out, "| {} |", fields.join(" | "));
    }
    out.push('\n');
}

/// `baseline.md`: per ray kind, seed 001 tables 2-4's traversal table, then the trace times in
/// the same layout (see the module documentation).
pub fn to_markdown(p: &Pairing<'_>, results: &Results) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "# {}\n\nBaseline: `{}` = {}.\n",
        results.title, p.key, p.value
    );
    let _ = writeln!(
        out,
        "Seed 001 tables 2-4's layout, per ray kind: one row per scene and setting; the `{}` column holds the baseline's visited inner nodes / leaves per ray, every other column the cell's in % of its baseline's (the cell identical but for `{}`). Then the trace times: the baseline's median trace ms of the kind (+ the cell's ray creation, one timer for every kind), the others as ratios trace / baseline (trace + ray creation in parentheses). \u{2014}: no such cell, or the baseline's figure is 0 (an intersector that does not count visits). \u{2020}: hits not identical to the baseline's (hit agreement below 1, or other ray counts). Camera rays are left out. Data: baseline.csv.\n",
        p.value, p.key
    );
    let fmt_pct = |v: Option<f64>| v.map_or("\u{2014}".to_string(), |x| format!("{x:.0}%"));
    let fmt_ratio = |v: Option<f64>| v.map_or("\u{2014}".to_string(), |x| format!("{x:.2}\u{d7}"));
    let settings = Settings::of(results, &p.key);
    for kind in row_kinds(p) {
        let table = kind_table(p, &kind, &settings);
        let _ = writeln!(
            out,
            "## {kind} rays: visited inner nodes / leaves per ray\n"
        );
        md_table(
            &mut out,
            p,
            &table,
            "inner / leaves",
            &|r| {
                format!(
                    "{:.2} / {:.2}",
                    r.baseline.per_ray.inner_nodes, r.baseline.per_ray.leaves
                )
            },
            &|r| {
                format!(
                    "{} / {}",
                    fmt_pct(r.inner_nodes_pct()),
                    fmt_pct(r.leaves_pct())
                )
            },
        );
        let _ = writeln!(out, "## {kind} rays: trace time\n");
        md_table(
            &mut out,
            p,
            &table,
            "trace ms (+ ray creation)",
            &|r| {
                format!(
                    "{:.2} (+ {:.2})",
                    r.baseline.trace_ms, r.baseline.cell_ray_creation_ms
                )
            },
            &|r| {
                format!(
                    "{} ({})",
                    fmt_ratio(r.trace_ratio()),
                    fmt_ratio(r.trace_plus_creation_ratio())
                )
            },
        );
    }
    if p.rows.is_empty() {
        let _ = writeln!(out, "No cell could be set against its baseline.\n");
    }
    if !p.unpaired.is_empty() {
        let _ = writeln!(out, "Cells without a baseline row:\n");
        for (c, why) in &p.unpaired {
            let _ = writeln!(out, "- {} | {}: {why}", c.scene, c.label);
        }
    }
    out
}

/// The report's baseline section: a table of every [`BaselineRow`].
pub fn html_section(h: &mut String, p: &Pairing<'_>) {
    let _ = writeln!(
        h,
        "<h2 id=\"baseline\">Against the baseline <code>{} = {}</code></h2>\n<p class=\"note\">Each cell against the cell identical but for <code>{}</code>, per ray kind (camera rays left out), from the same run. Inner nodes, leaves and tests per ray in % of the baseline's (— when the baseline's is 0); trace time over the baseline's, and trace + ray creation over the baseline's (ray creation is one timer for every kind of a cell, so this adds the cell's). Identical hits: hit agreement with the reference exactly 1 and every kind's ray count equal to the baseline's. Data: <a href=\"baseline.csv\">baseline.csv</a>; seed 001's table layout: <a href=\"baseline.md\">baseline.md</a>.</p>",
        escape(&p.key),
        escape(&p.value),
        escape(&p.key),
    );
    let _ = writeln!(
        h,
        "<table id=\"baseline-table\">\n<tr><th class=\"l\">scene</th><th class=\"l\">cell</th><th class=\"l\">kind</th><th>rays</th><th>baseline inner / leaves per ray</th><th>inner %</th><th>leaves %</th><th>tests %</th><th>ended by offsets</th><th>baseline trace ms</th><th>trace ratio</th><th>trace + creation ratio</th><th>identical hits</th></tr>"
    );
    let pct = |v: Option<f64>| v.map_or("—".to_string(), |x| format!("{x:.1}%"));
    let rat = |v: Option<f64>| v.map_or("—".to_string(), |x| format!("{x:.3}"));
    for r in &p.rows {
        let _ = writeln!(
            h,
            "<tr><td class=\"l\">{}</td><td class=\"l\">{}</td><td class=\"l\">{}</td><td>{}</td><td>{:.2} / {:.2}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.2}%</td><td>{:.3}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            escape(&r.cell.scene),
            escape(&r.cell.label),
            escape(&r.kind),
            r.figures.rays,
            r.baseline.per_ray.inner_nodes,
            r.baseline.per_ray.leaves,
            pct(r.inner_nodes_pct()),
            pct(r.leaves_pct()),
            pct(r.tests_pct()),
            r.figures.per_ray.offset_ended_fraction * 100.0,
            r.baseline.trace_ms,
            rat(r.trace_ratio()),
            rat(r.trace_plus_creation_ratio()),
            match r.identical_hits {
                Some(true) => "yes",
                Some(false) => "NO",
                None => "—",
            },
        );
    }
    let _ = writeln!(h, "</table>");
    if !p.unpaired.is_empty() {
        let _ = writeln!(
            h,
            "<p class=\"note\" id=\"baseline-unpaired\">{} cells have no baseline row (failed, or their baseline cell failed or is in another shard).</p>",
            p.unpaired.len()
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ablate::plan::parse_plan;
    use crate::ablate::results::{CellAccuracy, Expansion, Machine, TimeSummary};
    use crsh_core::KindStats;

    /// A cell of scene `s`, pipeline `ao`, with `offsets` and `len` as its swept values, whose
    /// `ao` kind traced `rays` rays visiting `inner` and `leaves` nodes in `trace` ms (ray
    /// creation `creation` ms), with hit agreement `agree`; `None` figures: a failed cell.
    fn cell(
        index: usize,
        offsets: &str,
        len: &str,
        figures: Option<(u64, u64, u64, f64, f64, f64)>,
    ) -> CellResult {
        let params = BTreeMap::from([
            ("raygen.offsets".to_string(), offsets.to_string()),
            ("raygen.ao_length".to_string(), len.to_string()),
        ]);
        let measures = figures.map(|(rays, inner, leaves, trace, creation, agree)| {
            let mut m = Measures::default();
            for (kind, n) in [("primary", 64), ("ao", rays)] {
                m.per_kind.insert(
                    kind.to_string(),
                    KindStats {
                        rays: n,
                        inner_nodes: inner,
                        leaves,
                        bounds: 2 * inner,
                        ray_triangle: 3 * leaves,
                        offset_ended: rays / 4,
                        trace_ms: trace,
                    },
                );
            }
            let t = |v: f64| TimeSummary {
                median: v,
                min: v,
                max: v,
            };
            m.timings_ms.insert("ray_creation".into(), t(creation));
            m.accuracy = Some(CellAccuracy {
                hit_agreement: agree,
                ..Default::default()
            });
            m
        });
        CellResult {
            index,
            label: format!("ao offsets={offsets} len={len}"),
            scene: "s".into(),
            scene_source: "s".into(),
            pipeline: "ao".into(),
            backend: "cpu".into(),
            params,
            width: 8,
            height: 8,
            depth: 0,
            status: if measures.is_some() { "ok" } else { "failed" }.into(),
            reason: String::new(),
            repeat: 1,
            threads: 1,
            config: crsh::Registries::builtin().preset("bvh").unwrap(),
            measures,
        }
    }

    fn results(cells: Vec<CellResult>) -> Results {
        let plan = parse_plan(
            "scenes = [\"s\"]\nbaseline = { \"raygen.offsets\" = \"none\" }\n[[pipelines]]\npipeline = \"bvh\"\n",
        )
        .unwrap();
        Results {
            version: "0".into(),
            title: "t".into(),
            plan_source: "test".into(),
            plan,
            plan_text: String::new(),
            machine: Machine {
                cpu_model: "cpu".into(),
                cores: 1,
                threads: 1,
                os: "os".into(),
                crsh_version: "0".into(),
                git_revision: "r".into(),
                wgpu_adapters: Vec::new(),
                started_utc: "2026-01-01T00:00:00Z".into(),
                allocator: String::new(),
                isa: String::new(),
            },
            wall_s: 0.0,
            expansion: Expansion::default(),
            shard: None,
            merged_from: Vec::new(),
            cells,
        }
    }

    #[test]
    fn cells_pair_with_the_cell_identical_but_for_the_key() {
        let r = results(vec![
            // len 0.1: none (10 inner, 4 leaves per ray), center (half the inner nodes, a
            // quarter of the leaves, 0.8 of the time), vertex (other ray counts).
            cell(0, "none", "0.1", Some((100, 1000, 400, 10.0, 2.0, 1.0))),
            cell(1, "center", "0.1", Some((100, 500, 100, 8.0, 3.0, 1.0))),
            cell(2, "vertex", "0.1", Some((50, 500, 200, 5.0, 1.0, 1.0))),
            // len 0.5: the baseline failed; vertex missed hits.
            cell(3, "none", "0.5", None),
            cell(4, "center", "0.5", Some((100, 1, 1, 1.0, 1.0, 1.0))),
            cell(5, "vertex", "0.25", Some((100, 1, 1, 1.0, 1.0, 0.5))),
        ]);
        let p = pair(&r).unwrap();
        assert_eq!(
            (p.key.as_str(), p.value.as_str()),
            ("raygen.offsets", "none")
        );
        assert_eq!(p.values, ["none", "center", "vertex"]);
        // Camera rays are left out: one `ao` row per paired cell.
        let rows: Vec<(usize, usize, &str)> = p
            .rows
            .iter()
            .map(|r| (r.cell.index, r.base.index, r.kind.as_str()))
            .collect();
        assert_eq!(rows, [(0, 0, "ao"), (1, 0, "ao"), (2, 0, "ao")]);
        let unpaired: Vec<(usize, &str)> = p
            .unpaired
            .iter()
            .map(|(c, why)| (c.index, why.as_str()))
            .collect();
        assert_eq!(
            unpaired,
            [
                (3, "the cell failed: "),
                (4, "its baseline cell `ao offsets=none len=0.5` failed"),
                (5, "its baseline cell is not in these results"),
            ]
        );

        let (own, center, vertex) = (&p.rows[0], &p.rows[1], &p.rows[2]);
        // The baseline against itself: exactly 100 % and 1.
        assert_eq!(own.inner_nodes_pct(), Some(100.0));
        assert_eq!(own.leaves_pct(), Some(100.0));
        assert_eq!(own.tests_pct(), Some(100.0));
        assert_eq!(own.trace_ratio(), Some(1.0));
        assert_eq!(own.trace_plus_creation_ratio(), Some(1.0));
        assert_eq!(own.identical_hits, Some(true));
        assert_eq!(center.inner_nodes_pct(), Some(50.0));
        assert_eq!(center.leaves_pct(), Some(25.0));
        // tests: (2·500 + 3·100) / (2·1000 + 3·400) = 1300 / 3200.
        assert_eq!(center.tests_pct(), Some(100.0 * 13.0 / 32.0));
        assert_eq!(center.trace_ratio(), Some(0.8));
        assert_eq!(center.trace_plus_creation_ratio(), Some(11.0 / 12.0));
        assert_eq!(center.figures.per_ray.offset_ended_fraction, 0.25);
        assert_eq!(center.identical_hits, Some(true));
        // Per ray: 500 / 50 = 10 inner nodes, as many as the baseline's; other ray counts.
        assert_eq!(vertex.inner_nodes_pct(), Some(100.0));
        assert_eq!(vertex.leaves_pct(), Some(100.0));
        assert_eq!(vertex.identical_hits, Some(false));

        let csv = to_csv(&p, &r);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 4);
        let header: Vec<&str> = lines[0].split(',').collect();
        let col = |row: usize, name: &str| {
            let i = header.iter().position(|h| *h == name).unwrap();
            lines[row].split(',').nth(i).unwrap().to_string()
        };
        assert_eq!(col(1, "inner_nodes_pct"), "100.00");
        assert_eq!(col(1, "trace_ratio"), "1.0000");
        assert_eq!(col(2, "leaves_pct"), "25.00");
        assert_eq!(col(2, "trace_plus_creation_ratio"), "0.9167");
        assert_eq!(col(2, "cell_ray_creation_ms"), "3.000");
        assert_eq!(col(3, "identical_hits"), "false");
        assert_eq!(col(3, "baseline_rays"), "100");

        let md = to_markdown(&p, &r);
        assert!(
            md.contains("| scene | setting | none: inner / leaves | center | vertex |"),
            "{md}"
        );
        // The setting names what varies besides the key: ao_length.
        assert!(
            md.contains("| s | ao ao_length=0.1 | 10.00 / 4.00 | 50% / 25% | 100% / 100% † |"),
            "{md}"
        );
        assert!(
            md.contains(
                "| s | ao ao_length=0.1 | 10.00 (+ 2.00) | 0.80× (0.92×) | 0.50× (0.50×) † |"
            ),
            "{md}"
        );
        assert!(
            md.contains("- s | ao offsets=none len=0.5: the cell failed"),
            "{md}"
        );
        let mut html = String::new();
        html_section(&mut html, &p);
        assert_eq!(html.matches("<tr><td").count(), 3);
        assert!(html.contains("id=\"baseline-unpaired\">3 cells"), "{html}");
    }

    #[test]
    fn a_zero_baseline_gives_no_ratio_and_no_plan_no_pairing() {
        let r = results(vec![
            cell(0, "none", "0.1", Some((100, 0, 0, 0.0, 0.0, 1.0))),
            cell(1, "center", "0.1", Some((100, 0, 0, 1.0, 1.0, 1.0))),
        ]);
        let p = pair(&r).unwrap();
        let center = &p.rows[1];
        assert_eq!(center.inner_nodes_pct(), None);
        assert_eq!(center.trace_ratio(), None);
        assert!(to_markdown(&p, &r).contains("| 0.00 / 0.00 | — / — |"));
        let mut plain = r.clone();
        plain.plan.baseline.clear();
        assert!(pair(&plain).is_none());
    }
}
