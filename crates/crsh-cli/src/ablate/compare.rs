//! `crsh ablate --compare OLD.json NEW.json`: per cell (matched by scene, pipeline, backend,
//! swept parameters, size and depth) the ratios new/old of median total time, total tests and
//! hit agreement, one line each, then the cells found in one file only.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use serde::Deserialize;
use serde_json::Value;

use crate::error::{CliError, CliResult};

/// What `--compare` reads of a results file: its cells.
#[derive(Deserialize)]
struct Document {
    cells: Vec<Cell>,
}

/// What `--compare` reads of a cell; every field must be there with its type (a file that
/// lacks one is refused, not shown as `?`).
#[derive(Clone, Debug, Deserialize)]
pub struct Cell {
    scene: String,
    pipeline: String,
    backend: String,
    params: BTreeMap<String, Value>,
    width: u32,
    height: u32,
    depth: u32,
    status: String,
    #[serde(default)]
    measures: Option<Measures>,
}

#[derive(Clone, Debug, Deserialize)]
struct Measures {
    timings_ms: Timings,
    tests: Tests,
    #[serde(default)]
    accuracy: Option<Accuracy>,
}

#[derive(Clone, Debug, Deserialize)]
struct Timings {
    total: Median,
}

#[derive(Clone, Debug, Deserialize)]
struct Median {
    median: f64,
}

#[derive(Clone, Debug, Deserialize)]
struct Tests {
    total: u64,
    /// The cell's tests are unknown (Embree): no ratio is drawn from them.
    #[serde(default)]
    uncounted: bool,
}

#[derive(Clone, Debug, Deserialize)]
struct Accuracy {
    hit_agreement: f64,
}

/// Reads the cells of a `results.json`; a missing or malformed file, or a cell without the
/// fields a comparison needs (named with its line and column, or its position), is a usage
/// error.
fn read(path: &Path) -> CliResult<Vec<Cell>> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| CliError::usage(format!("cannot read {}: {e}", path.display())))?;
    let doc: Document = serde_json::from_str(&text).map_err(|e| {
        let at = if e.line() > 0 {
            format!("{}:{}:{}", path.display(), e.line(), e.column())
        } else {
            path.display().to_string()
        };
        let why = e.to_string();
        let why = why.split(" at line ").next().unwrap_or(&why).to_string();
        CliError::usage(format!("{at}: not a crsh ablate results.json: {why}"))
    })?;
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    for (i, c) in doc.cells.iter().enumerate() {
        if let Some(first) = seen.insert(cell_key(c), i) {
            return Err(CliError::usage(format!(
                "{}: cells[{i}] ({}) is the same cell as cells[{first}]: cells must differ in scene, pipeline, backend, parameters, size or depth",
                path.display(),
                cell_key(c)
            )));
        }
        let bad = |why: String| {
            CliError::usage(format!(
                "{}: cells[{i}] ({}): {why}",
                path.display(),
                cell_key(c)
            ))
        };
        match c.status.as_str() {
            "ok" if c.measures.is_none() => {
                return Err(bad("status `ok` but no `measures`".into()))
            }
            "ok" | "failed" => {}
            other => {
                return Err(bad(format!(
                    "status `{other}` is neither `ok` nor `failed`"
                )))
            }
        }
        if let Some(m) = &c.measures {
            let time = m.timings_ms.total.median;
            if !(time.is_finite() && time >= 0.0) {
                return Err(bad(format!(
                    "measures.timings_ms.total.median {time} is not a time"
                )));
            }
            if let Some(a) = &m.accuracy {
                if !(0.0..=1.0).contains(&a.hit_agreement) {
                    return Err(bad(format!(
                        "measures.accuracy.hit_agreement {} is outside 0..=1",
                        a.hit_agreement
                    )));
                }
            }
        }
    }
    Ok(doc.cells)
}

/// The identity of a cell: `scene | pipeline | backend | k=v ... | WxH d=D`.
pub fn cell_key(c: &Cell) -> String {
    let params: Vec<String> = c
        .params
        .iter()
        .map(|(k, v)| format!("{k}={}", v.as_str().map_or(v.to_string(), str::to_string)))
        .collect();
    let params = if params.is_empty() {
        "-".to_string()
    } else {
        params.join(" ")
    };
    format!(
        "{} | {} | {} | {params} | {}x{} depth {}",
        c.scene, c.pipeline, c.backend, c.width, c.height, c.depth
    )
}

/// A cell's median total time, its total tests (`None` when uncounted) and hit agreement.
type Figures = (f64, Option<u64>, Option<f64>);

fn figures(c: &Cell) -> Option<Figures> {
    if c.status != "ok" {
        return None;
    }
    let m = c.measures.as_ref()?;
    Some((
        m.timings_ms.total.median,
        (!m.tests.uncounted).then_some(m.tests.total),
        m.accuracy.as_ref().map(|a| a.hit_agreement),
    ))
}

fn ratio(new: f64, old: f64) -> String {
    if old > 0.0 {
        format!("{:.3}x", new / old)
    } else if new == old {
        "1.000x".to_string()
    } else {
        "n/a".to_string()
    }
}

/// The comparison text of two results files.
pub fn compare_text(old: &[Cell], new: &[Cell]) -> String {
    let index = |cells: &[Cell]| -> BTreeMap<String, Cell> {
        cells.iter().map(|c| (cell_key(c), c.clone())).collect()
    };
    let (o, n) = (index(old), index(new));
    let mut out = String::new();
    let _ = writeln!(
        out,
        "cell: time new/old (median total ms) | tests new/old | hit agreement new/old"
    );
    let mut matched = 0;
    for (key, nc) in &n {
        let Some(oc) = o.get(key) else { continue };
        matched += 1;
        match (figures(oc), figures(nc)) {
            (Some((ot, ox, oa)), Some((nt, nx, na))) => {
                let agreement = match (oa, na) {
                    (Some(a), Some(b)) => format!("{} ({a:.6} -> {b:.6})", ratio(b, a)),
                    _ => "n/a (no accuracy)".to_string(),
                };
                let tests = match (ox, nx) {
                    (Some(o), Some(n)) => format!("{} ({o} -> {n})", ratio(n as f64, o as f64)),
                    (o, n) => {
                        let v = |x: Option<u64>| x.map_or("—".to_string(), |x| x.to_string());
                        format!("— ({} -> {})", v(o), v(n))
                    }
                };
                let _ = writeln!(
                    out,
                    "{key}: time {} ({ot:.1} -> {nt:.1} ms) | tests {tests} | agreement {agreement}",
                    ratio(nt, ot),
                );
            }
            (a, b) => {
                let st = |x: &Option<Figures>| if x.is_some() { "ok" } else { "failed" };
                let _ = writeln!(
                    out,
                    "{key}: not comparable (old {}, new {})",
                    st(&a),
                    st(&b)
                );
            }
        }
    }
    let only_old: Vec<&String> = o.keys().filter(|k| !n.contains_key(*k)).collect();
    let only_new: Vec<&String> = n.keys().filter(|k| !o.contains_key(*k)).collect();
    for k in &only_old {
        let _ = writeln!(out, "only in old: {k}");
    }
    for k in &only_new {
        let _ = writeln!(out, "only in new: {k}");
    }
    let _ = writeln!(
        out,
        "{matched} cells matched, {} only in old, {} only in new",
        only_old.len(),
        only_new.len()
    );
    out
}

/// Runs `--compare OLD NEW`.
pub fn run(old: &Path, new: &Path) -> CliResult<()> {
    let (o, n) = (read(old)?, read(new)?);
    crate::output::print_stdout(&compare_text(&o, &n))
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn cell(pipeline: &str, sub: &str, time: f64, tests: u64, agree: f64) -> Cell {
        serde_json::from_value(json!({
            "scene": "s", "pipeline": pipeline, "backend": "cpu",
            "params": {"hierarchy.subdivision": sub}, "width": 32, "height": 32, "depth": 3,
            "status": "ok",
            "measures": {
                "timings_ms": {"total": {"median": time, "min": time, "max": time}},
                "tests": {"total": tests},
                "accuracy": {"hit_agreement": agree}
            }
        }))
        .unwrap()
    }

    #[test]
    fn uncounted_tests_draw_no_ratio() {
        let old = vec![cell("bvh", "8", 100.0, 1000, 1.0)];
        let mut new = cell("bvh", "8", 50.0, 0, 1.0);
        if let Some(m) = new.measures.as_mut() {
            m.tests.uncounted = true;
        }
        let t = compare_text(&old, &[new]);
        assert!(
            t.contains("time 0.500x (100.0 -> 50.0 ms) | tests — (1000 -> —) | agreement"),
            "{t}"
        );
    }

    #[test]
    fn ratios_and_unmatched_cells() {
        let old = vec![
            cell("crsh", "8", 100.0, 1000, 1.0),
            cell("rah", "8", 10.0, 10, 1.0),
        ];
        let new = vec![
            cell("crsh", "8", 50.0, 1500, 0.5),
            cell("crsh", "16", 1.0, 1, 1.0),
        ];
        let t = compare_text(&old, &new);
        assert!(t.contains("s | crsh | cpu | hierarchy.subdivision=8 | 32x32 depth 3: time 0.500x (100.0 -> 50.0 ms) | tests 1.500x (1000 -> 1500) | agreement 0.500x"), "{t}");
        assert!(t.contains("only in old: s | rah |"), "{t}");
        assert!(
            t.contains("only in new: s | crsh | cpu | hierarchy.subdivision=16"),
            "{t}"
        );
        assert!(
            t.contains("1 cells matched, 1 only in old, 1 only in new"),
            "{t}"
        );
    }
}
