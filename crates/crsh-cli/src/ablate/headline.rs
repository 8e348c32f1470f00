//! The headline numbers of an ablation, per scene: the Pareto-front cells (throughput against
//! hit agreement), each pipeline's fastest cell, and the time and test ratios between
//! pipelines (best against best, and over configurations both pipelines ran).

use std::fmt::Write as _;

use super::charts::pareto_front;
use super::results::{CellResult, Results};

fn ratio(a: f64, b: f64) -> f64 {
    if b > 0.0 {
        a / b
    } else {
        0.0
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

/// The headline text: the table against the fastest anchor when the plan has Embree cells
/// ([`super::anchors`]), then one block per scene.
pub fn headline(results: &Results) -> String {
    let mut out = super::anchors::anchor_table(results)
        .map(|t| t + "\n")
        .unwrap_or_default();
    for scene in results.scenes() {
        let cells: Vec<&CellResult> = results.ok_cells(&scene);
        let failed = results
            .cells
            .iter()
            .filter(|c| c.scene == scene && !c.ok())
            .count();
        let _ = writeln!(out, "{scene}: {} cells ran, {failed} failed", cells.len());
        if cells.is_empty() {
            continue;
        }
        let m = |c: &CellResult| c.measures.clone().unwrap_or_default();
        let with_acc: Vec<&CellResult> = cells
            .iter()
            .copied()
            .filter(|c| m(c).accuracy.is_some() && m(c).mrays_per_s.contains_key("overall"))
            .collect();
        if !with_acc.is_empty() {
            let pts: Vec<(f64, f64)> = with_acc
                .iter()
                .map(|c| {
                    let mm = m(c);
                    (
                        mm.mrays_per_s["overall"],
                        mm.accuracy.map_or(0.0, |a| a.hit_agreement),
                    )
                })
                .collect();
            let front: Vec<String> = pareto_front(&pts)
                .into_iter()
                .map(|i| {
                    format!(
                        "{} ({:.3} Mrays/s, agreement {:.6})",
                        with_acc[i].label, pts[i].0, pts[i].1
                    )
                })
                .collect();
            let _ = writeln!(out, "  Pareto front: {}", front.join("; "));
        }
        // Each pipeline's fastest cell.
        let mut pipelines: Vec<String> = Vec::new();
        for c in &cells {
            if !pipelines.contains(&c.pipeline) {
                pipelines.push(c.pipeline.clone());
            }
        }
        let best: Vec<&CellResult> = pipelines
            .iter()
            .filter_map(|p| {
                cells
                    .iter()
                    .copied()
                    .filter(|c| &c.pipeline == p)
                    .min_by(|a, b| {
                        a.total_ms()
                            .unwrap_or(f64::MAX)
                            .total_cmp(&b.total_ms().unwrap_or(f64::MAX))
                    })
            })
            .collect();
        for c in &best {
            let mm = m(c);
            let _ = writeln!(
                out,
                "  fastest {}: {} — {:.1} ms median total, {} tests/ray, {:.3} Mrays/s",
                c.pipeline,
                c.label,
                c.total_ms().unwrap_or(0.0),
                mm.tests.per_ray_text(),
                mm.mrays_per_s.get("overall").copied().unwrap_or(0.0),
            );
        }
        for (i, a) in best.iter().enumerate() {
            for b in &best[i + 1..] {
                let (ma, mb) = (m(a), m(b));
                // Test ratios only where both count their tests (Embree's are unknown).
                let counted = !ma.tests.uncounted && !mb.tests.uncounted;
                let tests = if counted {
                    format!(
                        "{:.3}x",
                        ratio(ma.tests.total as f64, mb.tests.total as f64)
                    )
                } else {
                    "—".to_string()
                };
                let mut line = format!(
                    "  {} / {}: best vs best time {:.3}x, tests {tests}",
                    a.pipeline,
                    b.pipeline,
                    ratio(a.total_ms().unwrap_or(0.0), b.total_ms().unwrap_or(0.0)),
                );
                // Configurations both ran (same swept parameters).
                let pairs: Vec<(f64, f64)> = cells
                    .iter()
                    .filter(|c| c.pipeline == a.pipeline)
                    .filter_map(|ca| {
                        let cb = cells.iter().find(|cb| {
                            cb.pipeline == b.pipeline
                                && cb.params == ca.params
                                && cb.width == ca.width
                                && cb.depth == ca.depth
                        })?;
                        Some((
                            ratio(ca.total_ms()?, cb.total_ms()?),
                            ratio(m(ca).tests.total as f64, m(cb).tests.total as f64),
                        ))
                    })
                    .collect();
                if pairs.len() > 1 {
                    let times: Vec<f64> = pairs.iter().map(|p| p.0).collect();
                    let tests: Vec<f64> = pairs.iter().map(|p| p.1).collect();
                    let range = |v: &[f64]| {
                        let lo = v.iter().copied().fold(f64::MAX, f64::min);
                        let hi = v.iter().copied().fold(f64::MIN, f64::max);
                        format!("{lo:.3}-{hi:.3}x (median {:.3}x)", median(v.to_vec()))
                    };
                    let _ = write!(
                        line,
                        "; over {} shared configurations time {}, tests {}",
                        pairs.len(),
                        range(&times),
                        if counted {
                            range(&tests)
                        } else {
                            "—".to_string()
                        }
                    );
                }
                let _ = writeln!(out, "{line}");
            }
        }
    }
    out
}
