//! `report.html`: one self-contained page (no scripts, no network) with the machine facts,
//! the plan, and per scene its charts inlined as SVG and a table of every cell (plans with
//! `frames`: also a table of each cell's frame totals).

use std::fmt::Write as _;

use super::charts::{pareto_front, slug, ChartFile};
use super::results::{CellResult, Results};

/// Escapes text for HTML.
pub fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            _ => out.push(c),
        }
    }
    out
}

const STYLE: &str = "body{font-family:'DejaVu Sans',Helvetica,Arial,sans-serif;margin:2em auto;max-width:1200px;color:#222;padding:0 1em}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;margin:1em 0;font-size:.85em}
th,td{border:1px solid #ccc;padding:.25em .5em;text-align:right;white-space:nowrap}
th{background:#f0f0f0}td.l,th.l{text-align:left}
tr.failed td{background:#fde8e8}tr.front td{font-weight:bold}
figure{margin:1.5em 0}figure svg{max-width:100%;height:auto}
figcaption{font-size:.9em;color:#555}pre{background:#f6f6f6;padding:1em;overflow-x:auto;white-space:pre-wrap}
.note{color:#555;font-size:.9em}";

/// The report page. `charts` holds, per scene, the charts written (possibly none).
pub fn report(results: &Results, charts: &[(String, Vec<ChartFile>)]) -> String {
    let mut h = String::new();
    let title = escape(&results.title);
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{title}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n<h1>{title}</h1>\n"
    );
    let ok = results.cells.iter().filter(|c| c.ok()).count();
    let _ = writeln!(
        h,
        "<p>{} cells: {ok} ran, {} failed; wall time {:.1} s. Data: <a href=\"results.csv\">results.csv</a>, <a href=\"results.json\">results.json</a>. Times are medians of {} timed runs after {} warm-up run(s); accuracy is measured against the <code>{}</code> reference.</p>",
        results.cells.len(),
        results.cells.len() - ok,
        results.wall_s,
        results.plan.repeat,
        results.plan.warmup,
        escape(&results.plan.reference),
    );
    if let Some(n) = results.plan.frames {
        let _ = writeln!(
            h,
            "<p class=\"note\" id=\"frames-note\">Dynamic scenes: every cell renders frames 0..{} of its scene, each frame's update (the moved geometry, the bounding spheres for ray-space hierarchies, the upload, every stage's rebuild or refit) timed with its render; a cell's times and counters are over the whole sequence, each frame's time the median of the timed sequences. {} Per-frame rows: <a href=\"frames.csv\">frames.csv</a>.</p>",
            n.saturating_sub(1),
            match results.plan.reference_every {
                1 => "Every frame is checked against the reference.".to_string(),
                k => format!(
                    "Every {k}th frame (frame 0 included) is checked against the reference."
                ),
            },
        );
    }
    if let Some(shard) = &results.shard {
        let _ = writeln!(
            h,
            "<p class=\"note\" id=\"shard\">This is shard {shard} of an ablation of {} cells: it holds the cells whose index <i>i</i> (in the plan's expansion) has <i>i</i> mod {} = {}. Merge the shards' directories with <code>crsh ablate --merge DIR... --out DIR</code>.</p>",
            results.expansion.cells,
            shard.count,
            shard.index - 1,
        );
    }
    if !results.merged_from.is_empty() {
        let _ = writeln!(
            h,
            "<h2 id=\"shards\">Shards</h2>\n<p class=\"note\">Merged from {} shards; the wall time above is the longest shard's. Cells that ran on different machines are not comparable in time.</p>\n<table id=\"shards-table\"><tr><th>shard</th><th class=\"l\">from</th><th class=\"l\">CPU</th><th>cores</th><th>threads</th><th class=\"l\">started (UTC)</th><th>cells</th><th>wall s</th></tr>",
            results.merged_from.len()
        );
        for r in &results.merged_from {
            let _ = writeln!(
                h,
                "<tr><td>{}</td><td class=\"l\">{}</td><td class=\"l\">{}</td><td>{}</td><td>{}</td><td class=\"l\">{}</td><td>{}</td><td>{:.1}</td></tr>",
                r.shard,
                escape(&r.source),
                escape(&r.machine.cpu_model),
                r.machine.cores,
                r.machine.threads,
                escape(&r.machine.started_utc),
                r.cells,
                r.wall_s
            );
        }
        let _ = writeln!(h, "</table>");
    }

    let _ = writeln!(
        h,
        "<h2 id=\"headline\">Headline</h2>\n<pre id=\"headline-text\">{}</pre>",
        escape(&super::headline::headline(results))
    );

    // Machine facts.
    let m = &results.machine;
    let _ = writeln!(h, "<h2 id=\"machine\">Machine</h2>");
    let _ = writeln!(h, "<table id=\"machine-table\">");
    let mut fact = |k: &str, v: &str| {
        let _ = writeln!(
            h,
            "<tr><th class=\"l\">{}</th><td class=\"l\">{}</td></tr>",
            escape(k),
            escape(v)
        );
    };
    fact("CPU", &m.cpu_model);
    fact("cores", &m.cores.to_string());
    fact("worker threads", &m.threads.to_string());
    fact("OS", &m.os);
    fact("crsh version", &m.crsh_version);
    fact("git revision", &m.git_revision);
    fact("started (UTC)", &m.started_utc);
    if !m.allocator.is_empty() {
        fact("allocator", &m.allocator);
    }
    if !m.isa.is_empty() {
        fact("instruction set", &m.isa);
    }
    let has_wgpu = results.cells.iter().any(|c| c.backend == "wgpu");
    if has_wgpu {
        fact(
            "wgpu adapters",
            &if m.wgpu_adapters.is_empty() {
                "none found".to_string()
            } else {
                m.wgpu_adapters.join("; ")
            },
        );
    }
    let _ = writeln!(h, "</table>");

    for (scene, files) in charts {
        let sid = slug(scene);
        let _ = writeln!(h, "<h2 id=\"scene-{sid}\">{}</h2>", escape(scene));
        let cells: Vec<&CellResult> = results.cells.iter().filter(|c| &c.scene == scene).collect();
        if let Some(c) = cells.iter().find(|c| c.measures.is_some()) {
            let m = c.measures.as_ref().map(|m| m.triangles).unwrap_or(0);
            let _ = writeln!(
                h,
                "<p class=\"note\">{} ({m} triangles), {}x{}, depth {}.</p>",
                escape(&c.scene_source),
                c.width,
                c.height,
                c.depth
            );
        }
        if files.is_empty() {
            let _ = writeln!(
                h,
                "<p class=\"note\">No cell of this scene ran, so there are no charts.</p>"
            );
        }
        for f in files {
            let _ = writeln!(
                h,
                "<figure class=\"chart chart-{}\" id=\"chart-{}\">\n{}\n<figcaption>{} (<a href=\"charts/{}.png\">PNG</a>, <a href=\"charts/{}.svg\">SVG</a>)</figcaption>\n</figure>",
                f.kind,
                escape(&f.stem),
                strip_xml_header(&f.svg),
                escape(&f.title),
                escape(&f.stem),
                escape(&f.stem),
            );
        }
        frames_table(&mut h, &sid, &cells);
        cell_table(&mut h, &sid, &cells);
    }

    if let Some(p) = super::baseline::pair(results) {
        super::baseline::html_section(&mut h, &p);
    }

    let _ = writeln!(h, "<h2 id=\"plan\">Plan</h2>");
    let _ = writeln!(
        h,
        "<p class=\"note\">From {}.</p>\n<pre id=\"plan-text\">{}</pre>",
        escape(&results.plan_source),
        escape(&results.plan_text)
    );
    let _ = writeln!(h, "</body>\n</html>");
    h
}

fn strip_xml_header(svg: &str) -> &str {
    match svg.find("<svg") {
        Some(i) => &svg[i..],
        None => svg,
    }
}

/// The frames cells' totals: mean frame, update, structure and render times, the structure
/// updates seen, the lowest hit agreement of the checked frames.
fn frames_table(h: &mut String, sid: &str, cells: &[&CellResult]) {
    let framed: Vec<(&CellResult, &super::results::CellFrames)> = cells
        .iter()
        .filter_map(|c| Some((*c, c.measures.as_ref()?.frames.as_ref()?)))
        .collect();
    if framed.is_empty() {
        return;
    }
    let _ = writeln!(
        h,
        "<table class=\"frames\" id=\"frames-{sid}\">\n<tr><th class=\"l\">cell</th><th class=\"l\">backend</th><th>frames</th><th>mean frame ms</th><th>mean update ms</th><th>mean structure ms</th><th>mean render ms</th><th>Σ frame ms</th><th>Σ trace ms</th><th class=\"l\">structure updates</th><th>min hit agreement (checked frames)</th></tr>"
    );
    for (c, f) in framed {
        let t = &f.totals;
        let mut kinds: Vec<&str> = Vec::new();
        for r in &f.rows {
            if !kinds.contains(&r.structure.as_str()) {
                kinds.push(&r.structure);
            }
        }
        let _ = writeln!(
            h,
            "<tr><td class=\"l\">{}</td><td class=\"l\">{}</td><td>{}</td><td>{:.2}</td><td>{:.2}</td><td>{:.2}</td><td>{:.2}</td><td>{:.1}</td><td>{:.1}</td><td class=\"l\">{}</td><td>{}</td></tr>",
            escape(&c.label),
            escape(&c.backend),
            t.frames,
            t.mean_frame_ms,
            t.mean_update_ms,
            t.mean_structure_ms,
            t.mean_render_ms,
            t.frame_ms,
            t.trace_ms,
            escape(&kinds.join(", then ")),
            t.min_hit_agreement.map_or("—".into(), |a| format!(
                "{a:.6} ({} frames)",
                t.frames_checked
            )),
        );
    }
    let _ = writeln!(h, "</table>");
}

fn cell_table(h: &mut String, sid: &str, cells: &[&CellResult]) {
    // The cells on the throughput / agreement Pareto front.
    let measured: Vec<(usize, (f64, f64))> = cells
        .iter()
        .enumerate()
        .filter_map(|(i, c)| {
            let m = c.measures.as_ref()?;
            Some((
                i,
                (
                    *m.mrays_per_s.get("overall")?,
                    m.accuracy.as_ref()?.hit_agreement,
                ),
            ))
        })
        .collect();
    let pts: Vec<(f64, f64)> = measured.iter().map(|p| p.1).collect();
    let front: Vec<usize> = pareto_front(&pts)
        .into_iter()
        .map(|k| measured[k].0)
        .collect();
    let _ = writeln!(h, "<table class=\"cells\" id=\"table-{sid}\">");
    let _ = writeln!(
        h,
        "<tr><th class=\"l\">cell</th><th class=\"l\">backend</th><th>status</th><th>total ms (median)</th><th>min</th><th>max</th><th>Mrays/s</th><th>rays traced</th><th>tests / ray</th><th>% of brute force</th><th>hit agreement</th><th>PSNR dB</th><th>mean |t| error</th><th>self hits (rate)</th><th>peak candidates MiB</th><th>counters equal</th><th>Pareto front (agreement)</th></tr>"
    );
    for (i, c) in cells.iter().enumerate() {
        let on_front = front.contains(&i);
        match &c.measures {
            Some(m) if c.ok() => {
                let t = m.timings_ms.get("total").copied().unwrap_or_default();
                let acc = m.accuracy.as_ref();
                let _ = writeln!(
                    h,
                    "<tr{}><td class=\"l\">{}</td><td class=\"l\">{}</td><td>ok</td><td>{:.1}</td><td>{:.1}</td><td>{:.1}</td><td>{:.3}</td><td>{}</td><td>{:.1}</td><td>{:.4}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.2}</td><td>{}</td><td>{}</td></tr>",
                    if on_front { " class=\"front\"" } else { "" },
                    escape(&c.label),
                    escape(&c.backend),
                    t.median,
                    t.min,
                    t.max,
                    m.mrays_per_s.get("overall").copied().unwrap_or(0.0),
                    m.rays.traced,
                    m.tests.per_ray,
                    m.tests.fraction * 100.0,
                    acc.map_or("—".into(), |a| format!("{:.6}", a.hit_agreement)),
                    acc.map_or("—".into(), |a| match a.psnr_db {
                        Some(db) => format!("{db:.2}"),
                        None => "∞ (identical)".into(),
                    }),
                    acc.map_or("—".into(), |a| format!("{:.3e}", a.mean_abs_t_error)),
                    acc.map_or("—".into(), |a| format!(
                        "{} ({:.3}%)",
                        a.self_hits,
                        a.self_hit_rate * 100.0
                    )),
                    m.peak_candidate_bytes as f64 / (1024.0 * 1024.0),
                    if m.counters_equal_across_repeats { "yes" } else { "NO" },
                    if on_front { "yes" } else { "" },
                );
            }
            _ => {
                let _ = writeln!(
                    h,
                    "<tr class=\"failed\"><td class=\"l\">{}</td><td class=\"l\">{}</td><td>failed</td><td class=\"l\" colspan=\"14\">{}</td></tr>",
                    escape(&c.label),
                    escape(&c.backend),
                    escape(&c.reason),
                );
            }
        }
    }
    let _ = writeln!(h, "</table>");
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_markup() {
        assert_eq!(
            escape("<a href=\"x\">&'"),
            "&lt;a href=&quot;x&quot;&gt;&amp;&#39;"
        );
        assert_eq!(
            strip_xml_header("<?xml version=\"1.0\"?>\n<svg a>"),
            "<svg a>"
        );
    }
}
