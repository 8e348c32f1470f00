//! "Against the fastest anchor": every cell's throughput per ray kind as a ratio of the
//! fastest Embree cell that traced the same rays.
//!
//! Two cells trace the same rays when they share the scene, the image size, the bounce depth,
//! the ray generator with every parameter but `order`/`order_seed`, the shader and the ray
//! order. Among such cells the anchors are those whose intersector is `embree` (any mode,
//! sorted or not); the fastest of them on a ray kind is 1.0 for that kind. Cells with no anchor
//! beside them (a plan without Embree, or a build without the feature, whose Embree cells
//! fail) are left out; without any anchor the table is absent.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use crsh_core::PipelineConfig;

use super::results::{CellResult, Results};

/// The intersector variant that makes a cell an anchor.
pub const ANCHOR_INTERSECTOR: &str = "embree";

/// What makes two cells' rays the same (see the module doc), and a short name for it.
fn workload(c: &CellResult) -> (String, String) {
    let cfg: &PipelineConfig = &c.config;
    let mut raygen = cfg.raygen.clone();
    raygen.params.remove("order");
    raygen.params.remove("order_seed");
    let key = format!(
        "{}|{}x{}|{}|{:?}|{}",
        c.scene, c.width, c.height, c.depth, raygen, cfg.shade.kind
    );
    let name = match raygen.kind.as_str() {
        "whitted" => match raygen.str("shadow").unwrap_or("hard") {
            "samples" => format!(
                "whitted {} samples",
                raygen.i64("shadow_samples").unwrap_or(0)
            ),
            other => format!("whitted {other}"),
        },
        "ao" => format!(
            "ao {:.0}% diagonal",
            raygen.f64("ao_length").unwrap_or(0.0) * 100.0
        ),
        other => match raygen.i64("samples") {
            Ok(n) if n > 1 => format!("{other} ×{n}"),
            _ => other.to_string(),
        },
    };
    (key, format!("{name}, depth {}", c.depth))
}

/// The cell's ray order (`generation` when its generator has no `order`).
fn order(c: &CellResult) -> String {
    c.config
        .raygen
        .str("order")
        .unwrap_or("generation")
        .to_string()
}

/// One row of the table.
#[derive(Clone, Debug, PartialEq)]
pub struct AnchorRow {
    /// Scene name.
    pub scene: String,
    /// The rays (generator and depth).
    pub rays: String,
    /// `generation` or `shuffled`.
    pub order: String,
    /// The traced ray kind (`shadow`, `reflection`, ...).
    pub kind: String,
    /// The cell's label.
    pub cell: String,
    /// The cell's Mrays/s on that kind.
    pub mrays_per_s: f64,
    /// `mrays_per_s` over the fastest anchor's on the same rays and kind.
    pub ratio: f64,
    /// The label of that anchor.
    pub anchor: String,
    /// The cell's hit agreement with the plan's reference, if measured.
    pub hit_agreement: Option<f64>,
}

/// The throughput per ray kind of an ok cell.
fn mrays(c: &CellResult) -> &BTreeMap<String, f64> {
    &c.measures
        .as_ref()
        .expect("ok cells have measures")
        .mrays_per_s
}

/// The rows, grouped by scene, rays, order and kind, fastest first.
pub fn anchor_rows(results: &Results) -> Vec<AnchorRow> {
    // Each ok cell with its workload key, the workload's name and its order, computed once.
    let ok: Vec<(&CellResult, String, String, String)> = results
        .cells
        .iter()
        .filter(|c| c.ok())
        .map(|c| {
            let (key, name) = workload(c);
            (c, key, name, order(c))
        })
        .collect();
    // Fastest anchor per (workload, order, kind).
    let mut best: BTreeMap<(String, String, String), (f64, String)> = BTreeMap::new();
    for (c, key, _, order) in &ok {
        if c.config.intersect.kind != ANCHOR_INTERSECTOR {
            continue;
        }
        for (kind, &m) in mrays(c) {
            if kind == "overall" || m.is_nan() || m <= 0.0 {
                continue;
            }
            let slot = best
                .entry((key.clone(), order.clone(), kind.clone()))
                .or_insert((0.0, String::new()));
            if m > slot.0 {
                *slot = (m, c.label.clone());
            }
        }
    }
    let mut rows = Vec::new();
    for (c, key, name, order) in &ok {
        for (kind, &m) in mrays(c) {
            if kind == "overall" {
                continue;
            }
            let Some((anchor, anchor_label)) =
                best.get(&(key.clone(), order.clone(), kind.clone()))
            else {
                continue;
            };
            rows.push(AnchorRow {
                scene: c.scene.clone(),
                rays: name.clone(),
                order: order.clone(),
                kind: kind.clone(),
                cell: c.label.clone(),
                mrays_per_s: m,
                ratio: m / anchor,
                anchor: anchor_label.clone(),
                hit_agreement: c
                    .measures
                    .as_ref()
                    .and_then(|m| m.accuracy.as_ref())
                    .map(|a| a.hit_agreement),
            });
        }
    }
    rows.sort_by(|a, b| {
        (&a.scene, &a.rays, &a.order, &a.kind)
            .cmp(&(&b.scene, &b.rays, &b.order, &b.kind))
            .then(b.ratio.total_cmp(&a.ratio))
    });
    rows
}

/// The table as text (a Markdown pipe table), or `None` when no cell has an anchor.
pub fn anchor_table(results: &Results) -> Option<String> {
    let rows = anchor_rows(results);
    if rows.is_empty() {
        return None;
    }
    let mut out = String::from(
        "Against the fastest anchor (Mrays/s per ray kind, ratio to the fastest Embree cell on \
         the same scene, rays and order):\n\
         | scene | rays | order | kind | cell | Mrays/s | × anchor | hit agreement |\n\
         |---|---|---|---|---|---:|---:|---:|\n",
    );
    for r in rows {
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {} | {:.2} | {:.2} | {} |",
            r.scene,
            r.rays,
            r.order,
            r.kind,
            r.cell,
            r.mrays_per_s,
            r.ratio,
            r.hit_agreement
                .map_or("—".to_string(), |a| format!("{a:.6}"))
        );
    }
    Some(out)
}
