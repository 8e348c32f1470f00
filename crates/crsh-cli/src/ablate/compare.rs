//! `crsh ablate --compare OLD.json NEW.json`: per cell (matched by scene, pipeline, backend,
//! swept parameters, size and depth) the ratios new/old of median total time, total tests and
//! hit agreement, one line each, then the cells found in one file only.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use serde_json::Value;

use crate::error::{CliError, CliResult};

/// Reads a `results.json`; a missing or malformed file is a usage error.
fn read(path: &Path) -> CliResult<Vec<Value>> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| CliError::usage(format!("cannot read {}: {e}", path.display())))?;
    let v: Value = serde_json::from_str(&text)
        .map_err(|e| CliError::usage(format!("{} is not JSON: {e}", path.display())))?;
    v.get("cells")
        .and_then(Value::as_array)
        .cloned()
        .ok_or_else(|| {
            CliError::usage(format!(
                "{} is not a crsh ablate results.json (no `cells` list)",
                path.display()
            ))
        })
}

/// The identity of a cell: `scene | pipeline | backend | k=v ... | WxH d=D`.
pub fn cell_key(c: &Value) -> String {
    let s = |k: &str| c.get(k).and_then(Value::as_str).unwrap_or("?").to_string();
    let n = |k: &str| c.get(k).and_then(Value::as_u64).unwrap_or(0);
    let params: Vec<String> = c
        .get("params")
        .and_then(Value::as_object)
        .map(|o| {
            o.iter()
                .map(|(k, v)| format!("{k}={}", v.as_str().map_or(v.to_string(), str::to_string)))
                .collect()
        })
        .unwrap_or_default();
    let params = if params.is_empty() {
        "-".to_string()
    } else {
        params.join(" ")
    };
    format!(
        "{} | {} | {} | {params} | {}x{} depth {}",
        s("scene"),
        s("pipeline"),
        s("backend"),
        n("width"),
        n("height"),
        n("depth")
    )
}

fn figures(c: &Value) -> Option<(f64, f64, Option<f64>)> {
    if c.get("status").and_then(Value::as_str) != Some("ok") {
        return None;
    }
    let time = c.pointer("/measures/timings_ms/total/median")?.as_f64()?;
    let tests = c.pointer("/measures/tests/total")?.as_f64()?;
    let agreement = c
        .pointer("/measures/accuracy/hit_agreement")
        .and_then(Value::as_f64);
    Some((time, tests, agreement))
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
pub fn compare_text(old: &[Value], new: &[Value]) -> String {
    let index = |cells: &[Value]| -> BTreeMap<String, Value> {
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
                let _ = writeln!(
                    out,
                    "{key}: time {} ({ot:.1} -> {nt:.1} ms) | tests {} ({} -> {}) | agreement {agreement}",
                    ratio(nt, ot),
                    ratio(nx, ox),
                    ox as u64,
                    nx as u64,
                );
            }
            (a, b) => {
                let st =
                    |x: &Option<(f64, f64, Option<f64>)>| if x.is_some() { "ok" } else { "failed" };
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

    fn cell(pipeline: &str, sub: &str, time: f64, tests: u64, agree: f64) -> Value {
        json!({
            "scene": "s", "pipeline": pipeline, "backend": "cpu",
            "params": {"hierarchy.subdivision": sub}, "width": 32, "height": 32, "depth": 3,
            "status": "ok",
            "measures": {
                "timings_ms": {"total": {"median": time, "min": time, "max": time}},
                "tests": {"total": tests},
                "accuracy": {"hit_agreement": agree}
            }
        })
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
