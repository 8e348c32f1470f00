//! End-to-end tests of `crsh ablate`: the quick plan on the built-in scenes (every output
//! file, CSV, JSON, charts, report), failed cells recorded with their reason, the grid of
//! the command-line form, `--compare`, clear errors for bad plans, a plan run as shards and
//! merged, `--redraw` and stale charts, frames of an animated scene (per-frame rows, totals,
//! the frames chart, `frames.csv`), and the report in headless Chromium when it is
//! installed.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

mod common;
use common::{assert_ok, text};

/// A fresh scratch directory for one test.
fn scratch(test: &str) -> PathBuf {
    common::scratch("ablate", test)
}

/// Runs `crsh args...` in `dir`, without `CRSH_SCENES` (the plans must not need it).
fn crsh(dir: &Path, args: &[&str]) -> Output {
    common::crsh_with(dir, args, &["CRSH_SCENES"])
}

fn read_json(path: &Path) -> Value {
    let t = std::fs::read_to_string(path).expect("results.json written");
    serde_json::from_str(&t).expect("results.json is JSON")
}

fn cells(v: &Value) -> &Vec<Value> {
    v["cells"].as_array().expect("cells list")
}

/// Parses CSV with quoted fields (RFC 4180) into rows of fields.
fn parse_csv(t: &str) -> Vec<Vec<String>> {
    let mut rows = Vec::new();
    let mut row = Vec::new();
    let mut field = String::new();
    let mut quoted = false;
    let mut chars = t.chars().peekable();
    while let Some(c) = chars.next() {
        match (quoted, c) {
            (true, '"') if chars.peek() == Some(&'"') => {
                chars.next();
                field.push('"');
            }
            (true, '"') => quoted = false,
            (true, c) => field.push(c),
            (false, '"') => quoted = true,
            (false, ',') => row.push(std::mem::take(&mut field)),
            (false, '\n') => {
                row.push(std::mem::take(&mut field));
                rows.push(std::mem::take(&mut row));
            }
            (false, c) => field.push(c),
        }
    }
    rows
}

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// `plans/quick.toml` at 32 pixels wide, written into `dir`.
fn small_quick_plan(dir: &Path) -> PathBuf {
    let plan = std::fs::read_to_string(repo_root().join("plans/quick.toml")).expect("quick plan");
    assert!(plan.contains("width = 64"), "quick.toml changed: {plan}");
    let small = plan.replace("width = 64", "width = 32");
    let p = dir.join("quick32.toml");
    std::fs::write(&p, small).unwrap();
    p
}

fn is_png(path: &Path) -> bool {
    image::open(path).is_ok_and(|i| i.width() > 100 && i.height() > 100)
}

fn is_svg(path: &Path) -> bool {
    std::fs::read_to_string(path).is_ok_and(|s| {
        let s = s.trim();
        s.contains("<svg") && s.ends_with("</svg>") && s.contains("<text")
    })
}

#[test]
fn quick_plan_end_to_end() {
    let dir = scratch("quick");
    let plan = small_quick_plan(&dir);
    let o = crsh(
        &dir,
        &["ablate", "--plan", plan.to_str().unwrap(), "--out", "out"],
    );
    assert_ok(&o);
    let out = dir.join("out");
    let stdout = text(&o.stdout);
    // One line per cell, then the headline.
    assert!(
        stdout.contains("[1/10] cornell-mirrors | crsh subdivision=8 | cpu:"),
        "{stdout}"
    );
    assert!(stdout.contains("Pareto front:"), "{stdout}");
    assert!(stdout.contains("crsh / rah: best vs best time"), "{stdout}");

    // JSON: every cell ran, with counters equal across repeats and exact accuracy.
    let v = read_json(&out.join("results.json"));
    let cs = cells(&v);
    // 2 scenes × (crsh × 2 + rah × 2 + bvh).
    assert_eq!(cs.len(), 10);
    for c in cs {
        assert_eq!(c["status"], "ok", "{c:#}");
        let m = &c["measures"];
        assert_eq!(m["counters_equal_across_repeats"], true);
        assert_eq!(c["width"], 32);
        let t = &m["timings_ms"]["total"];
        let (lo, med, hi) = (
            t["min"].as_f64().unwrap(),
            t["median"].as_f64().unwrap(),
            t["max"].as_f64().unwrap(),
        );
        assert!(lo > 0.0 && lo <= med && med <= hi, "{t}");
        assert_eq!(m["accuracy"]["reference"], "brute");
        assert_eq!(
            m["accuracy"]["hit_agreement"], 1.0,
            "exact pipelines: {c:#}"
        );
        assert!(m["tests"]["total"].as_u64().unwrap() > 0);
        assert!(m["mrays_per_s"]["overall"].as_f64().unwrap() > 0.0);
        assert!(c["config"]["intersect"]["kind"].is_string());
        if c["pipeline"] != "bvh" {
            assert!(!m["levels"].as_array().unwrap().is_empty());
            assert!(
                m["timings_ms"]["hierarchy_creation"]["median"]
                    .as_f64()
                    .unwrap()
                    > 0.0
            );
        }
    }
    assert_eq!(v["plan"]["repeat"], 3);
    assert!(v["machine"]["cpu_model"].is_string());
    assert!(v["machine"]["git_revision"].is_string());
    // The binary's memory policy (`crsh_cli::allocator`), which changes the stage times.
    let allocator = v["machine"]["allocator"].as_str().unwrap();
    if cfg!(all(target_os = "linux", target_env = "gnu")) {
        assert!(allocator.starts_with("glibc malloc"), "{allocator}");
    } else {
        assert!(!allocator.is_empty());
    }

    // CSV: the header and one row per cell, matching the JSON.
    let csv = parse_csv(&std::fs::read_to_string(out.join("results.csv")).unwrap());
    let header = &csv[0];
    for col in [
        "scene",
        "pipeline",
        "backend",
        "hierarchy.subdivision",
        "status",
        "reason",
        "rays_shadow",
        "rays_traced",
        "tests_bounds",
        "tests_ray_triangle",
        "tests_total",
        "tests_brute_force",
        "tests_per_ray",
        "tests_fraction",
        "level_shadow_0_tests",
        "level_shadow_1_tests",
        "time_total_median_ms",
        "time_total_min_ms",
        "time_total_max_ms",
        "time_traversal_median_ms",
        "mrays_shadow",
        "mrays_overall",
        "hit_agreement",
        "psnr_db",
        "mean_abs_t_error",
        "peak_candidate_bytes",
        "config",
    ] {
        assert!(
            header.iter().any(|h| h == col),
            "CSV lacks {col}: {header:?}"
        );
    }
    assert_eq!(csv.len(), 11, "header + 10 rows");
    let col = |name: &str| header.iter().position(|h| h == name).unwrap();
    for (row, c) in csv[1..].iter().zip(cs) {
        assert_eq!(row.len(), header.len());
        assert_eq!(row[col("pipeline")], c["pipeline"].as_str().unwrap());
        assert_eq!(
            row[col("tests_total")],
            c["measures"]["tests"]["total"].to_string()
        );
        let cfg: Value = serde_json::from_str(&row[col("config")]).expect("config is JSON");
        assert_eq!(cfg, c["config"]);
    }

    // Charts: three per scene, valid PNG and SVG.
    let report = std::fs::read_to_string(out.join("report.html")).unwrap();
    for scene in ["cornell-mirrors", "office-boxes"] {
        for kind in ["pareto", "tests", "stages"] {
            let stem = format!("{scene}-{kind}");
            assert!(
                is_png(&out.join(format!("charts/{stem}.png"))),
                "{stem}.png"
            );
            assert!(
                is_svg(&out.join(format!("charts/{stem}.svg"))),
                "{stem}.svg"
            );
            assert!(
                report.contains(&format!("id=\"chart-{stem}\"")),
                "report lacks {stem}"
            );
        }
        assert!(report.contains(&format!("id=\"table-{scene}\"")));
    }
    // Self-contained: inlined SVG, no scripts, no remote resources.
    assert_eq!(report.matches("<svg").count(), 6);
    // (the SVG namespace URI is an identifier, not a fetch)
    for remote in [
        "<script",
        "src=\"http",
        "href=\"http",
        "url(http",
        "@import",
    ] {
        assert!(
            !report.contains(remote),
            "report fetches or runs something: {remote}"
        );
    }
    assert!(report.contains("id=\"machine-table\"") && report.contains("id=\"plan-text\""));
    assert!(report.contains("<th class=\"l\">allocator</th>"));
}

/// A reduced `plans/accuracy.toml`: the offset policies against one robust reference image,
/// with the three Pareto charts.
#[test]
fn accuracy_axes_draw_three_pareto_charts_with_self_hits() {
    let dir = scratch("accuracy");
    let shipped =
        std::fs::read_to_string(repo_root().join("plans/accuracy.toml")).expect("accuracy plan");
    let plan = crsh_plan_check(&shipped);
    std::fs::write(dir.join("acc.toml"), plan).unwrap();
    let o = crsh(
        &dir,
        &["ablate", "--plan", "acc.toml", "--out", "out", "-q"],
    );
    assert_ok(&o);
    let out = dir.join("out");
    let v = read_json(&out.join("results.json"));
    assert_eq!(v["plan"]["reference_params"]["raygen.offset"], "wachter");
    let cs = cells(&v);
    assert_eq!(cs.len(), 4, "bvh × (mt, watertight) × (normal, wachter)");
    for c in cs {
        assert_eq!(c["status"], "ok", "{c:#}");
        let a = &c["measures"]["accuracy"];
        assert_eq!(a["reference"], "brute64");
        assert!(a["self_hits"].is_u64(), "{a:#}");
        let rate = a["self_hit_rate"].as_f64().expect("self_hit_rate");
        assert!((0.0..=1.0).contains(&rate));
        assert_eq!(
            c["config"]["raygen"]["offset"],
            c["params"]["raygen.offset"]
        );
    }
    // The reference image is rendered with `raygen.offset = wachter` for every cell: the
    // wachter cell (same configuration, exact hits) matches it exactly, the normal cell,
    // whose origins move by another offset, does not (were reference_params ignored, its
    // reference would be its own configuration and identical too).
    let by = |policy: &str, test: &str| {
        cs.iter()
            .find(|c| {
                c["params"]["raygen.offset"] == policy && c["params"]["intersect.test"] == test
            })
            .unwrap()["measures"]["accuracy"]
            .clone()
    };
    for test in ["mt", "watertight"] {
        let (wachter, normal) = (by("wachter", test), by("normal", test));
        assert!(wachter["psnr_db"].is_null(), "{test}: {wachter:#}");
        assert_eq!(wachter["images_identical"], true, "{test}");
        assert_eq!(normal["images_identical"], false, "{test}: {normal:#}");
        assert!(normal["psnr_db"].as_f64().is_some_and(|db| db.is_finite()));
    }
    let csv = parse_csv(&std::fs::read_to_string(out.join("results.csv")).unwrap());
    for col in ["self_hits", "self_hit_rate", "psnr_db"] {
        assert!(csv[0].iter().any(|h| h == col), "CSV lacks {col}");
    }
    let report = std::fs::read_to_string(out.join("report.html")).unwrap();
    for kind in [
        "pareto",
        "pareto-psnr",
        "pareto-self-hits",
        "tests",
        "stages",
    ] {
        let stem = format!("cornell-mirrors-{kind}");
        assert!(
            is_png(&out.join(format!("charts/{stem}.png"))),
            "{stem}.png"
        );
        assert!(
            is_svg(&out.join(format!("charts/{stem}.svg"))),
            "{stem}.svg"
        );
        assert!(
            report.contains(&format!("id=\"chart-{stem}\"")),
            "report lacks {stem}"
        );
    }
    assert!(report.contains("self hits (rate)"));
    let psnr = std::fs::read_to_string(out.join("charts/cornell-mirrors-pareto-psnr.svg")).unwrap();
    assert!(
        psnr.contains("identical images drawn at 100 dB"),
        "ceiling not named"
    );
}

/// The shipped accuracy plan, checked and cut down: one scene, one run, bvh only, two
/// policies (64 pixels and two bounces, as shipped: at 32 pixels and one bounce the `normal`
/// image happens to match the `wachter` reference exactly).
fn crsh_plan_check(shipped: &str) -> String {
    for needle in [
        "reference = \"brute64\"",
        "reference_params = { \"raygen.offset\" = \"wachter\" }",
        "accuracy_axes = [\"hit_agreement\", \"psnr_db\", \"self_hit_rate\"]",
        "\"raygen.offset\" = [\"normal\", \"scaled\", \"fixed\", \"wachter\"]",
        "\"intersect.test\" = [\"mt\", \"watertight\", \"projected\"]",
        "scenes = [\"cornell-mirrors\", \"office-boxes\"]",
        "width = 64",
        "depth = 2",
    ] {
        assert!(shipped.contains(needle), "accuracy.toml changed: {needle}");
    }
    let head = &shipped[..shipped.find("[[pipelines]]").expect("pipelines")];
    head.replace(
        "scenes = [\"cornell-mirrors\", \"office-boxes\"]",
        "scenes = [\"cornell-mirrors\"]",
    )
    .replace("repeat = 2", "repeat = 1\nwarmup = 0")
    .replace(
        "\"raygen.offset\" = [\"normal\", \"scaled\", \"fixed\", \"wachter\"]",
        "\"raygen.offset\" = [\"normal\", \"wachter\"]",
    )
    .replace(
        "\"intersect.test\" = [\"mt\", \"watertight\", \"projected\"]",
        "\"intersect.test\" = [\"mt\", \"watertight\"]",
    ) + "[[pipelines]]\npipeline = \"bvh\"\n"
}

#[test]
fn failed_cells_are_recorded_and_the_run_goes_on() {
    let dir = scratch("failed");
    let o = crsh(
        &dir,
        &[
            "ablate",
            "--scenes",
            "cornell-mirrors,no/such/scene.toml",
            "--pipelines",
            "bvh,crsh",
            "--backends",
            "cpu,wgpu",
            "--width",
            "16",
            "--repeat",
            "1",
            "--out",
            "out",
        ],
    );
    assert_ok(&o);
    let v = read_json(&dir.join("out/results.json"));
    let cs = cells(&v);
    assert_eq!(cs.len(), 8);
    let status: Vec<(&str, &str, &str, &str)> = cs
        .iter()
        .map(|c| {
            (
                c["scene_source"].as_str().unwrap(),
                c["pipeline"].as_str().unwrap(),
                c["backend"].as_str().unwrap(),
                c["status"].as_str().unwrap(),
            )
        })
        .collect();
    // wgpu cells run where an adapter exists (lavapipe in CI), else fail saying so.
    let gpu = crsh_wgpu::testing::shared_context("failed_cells_are_recorded_and_the_run_goes_on")
        .is_some();
    let on_gpu = if gpu { "ok" } else { "failed" };
    assert_eq!(
        status,
        [
            ("cornell-mirrors", "bvh", "cpu", "ok"),
            ("cornell-mirrors", "bvh", "wgpu", on_gpu),
            ("cornell-mirrors", "crsh", "cpu", "ok"),
            ("cornell-mirrors", "crsh", "wgpu", on_gpu),
            ("no/such/scene.toml", "bvh", "cpu", "failed"),
            ("no/such/scene.toml", "bvh", "wgpu", "failed"),
            ("no/such/scene.toml", "crsh", "cpu", "failed"),
            ("no/such/scene.toml", "crsh", "wgpu", "failed"),
        ]
    );
    if gpu {
        let m = &cs[1]["measures"];
        assert_eq!(m["accuracy"]["hit_agreement"].as_f64(), Some(1.0), "{m}");
        assert_eq!(m["rays"], cs[0]["measures"]["rays"]);
        assert_eq!(m["tests"], cs[0]["measures"]["tests"]);
        let m = &cs[3]["measures"];
        assert_eq!(m["accuracy"]["hit_agreement"].as_f64(), Some(1.0), "{m}");
        assert_eq!(m["rays"], cs[2]["measures"]["rays"]);
    } else {
        assert!(cs[1]["reason"].as_str().unwrap().contains("wgpu"));
        assert!(cs[3]["reason"].as_str().unwrap().contains("wgpu"));
    }
    assert!(cs[4]["reason"]
        .as_str()
        .unwrap()
        .starts_with("scene not found: no/such/scene.toml"));
    let csv = parse_csv(&std::fs::read_to_string(dir.join("out/results.csv")).unwrap());
    let reason = csv[0].iter().position(|h| h == "reason").unwrap();
    assert!(csv[5][reason].starts_with("scene not found"));
    let report = std::fs::read_to_string(dir.join("out/report.html")).unwrap();
    assert!(report.contains("class=\"failed\""));
    assert!(report.contains("scene not found: no/such/scene.toml"));
    assert!(text(&o.stdout).contains("FAILED: scene not found"));

    // Every cell failing is a failed run (exit 1), with the files still written.
    let o = crsh(
        &dir,
        &[
            "ablate",
            "--scenes",
            "missing.obj",
            "--pipelines",
            "bvh",
            "--out",
            "none",
        ],
    );
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    assert!(text(&o.stderr).starts_with("error: every cell failed"));
    assert!(dir.join("none/results.json").is_file());
}

#[test]
fn command_line_grid_expands_every_combination() {
    let dir = scratch("grid");
    let o = crsh(
        &dir,
        &[
            "ablate",
            "--scenes",
            "cornell-mirrors",
            "--pipelines",
            "crsh,rah,bvh",
            "--set",
            "hierarchy.subdivision=8,16",
            "--set",
            "hierarchy.depth=2,3",
            "--width",
            "16",
            "--repeat",
            "1",
            "--reference",
            "none",
            "--quiet",
            "--out",
            "out",
        ],
    );
    assert_ok(&o);
    assert!(
        !text(&o.stdout).contains("[1/"),
        "--quiet hides per-cell lines"
    );
    let v = read_json(&dir.join("out/results.json"));
    let cs = cells(&v);
    // crsh and rah: 2 × 2 each; bvh has no hierarchy and runs once.
    assert_eq!(cs.len(), 9);
    let mut combos: Vec<String> = cs
        .iter()
        .filter(|c| c["pipeline"] != "bvh")
        .map(|c| {
            let h = &c["config"]["hierarchy"];
            assert_eq!(
                h["subdivision"].to_string(),
                c["params"]["hierarchy.subdivision"].as_str().unwrap()
            );
            format!(
                "{} s{} d{}",
                c["pipeline"].as_str().unwrap(),
                h["subdivision"],
                h["depth"]
            )
        })
        .collect();
    combos.sort();
    assert_eq!(
        combos,
        [
            "crsh s16 d2",
            "crsh s16 d3",
            "crsh s8 d2",
            "crsh s8 d3",
            "rah s16 d2",
            "rah s16 d3",
            "rah s8 d2",
            "rah s8 d3"
        ]
    );
    let bvh = cs.iter().find(|c| c["pipeline"] == "bvh").unwrap();
    assert_eq!(bvh["params"], serde_json::json!({}));
    assert!(bvh["measures"].get("accuracy").is_none(), "reference none");
    // Without accuracy there is no Pareto chart, the other two are drawn.
    assert!(!dir.join("out/charts/cornell-mirrors-pareto.png").exists());
    assert!(is_png(&dir.join("out/charts/cornell-mirrors-tests.png")));
}

#[test]
fn counters_do_not_depend_on_threads() {
    let dir = scratch("threads");
    let run = |threads: &str, out: &str| {
        let o = crsh(
            &dir,
            &[
                "ablate",
                "--pipelines",
                "crsh,rah",
                "--width",
                "16",
                "--repeat",
                "2",
                "--threads",
                threads,
                "--quiet",
                "--out",
                out,
            ],
        );
        assert_ok(&o);
        read_json(&dir.join(out).join("results.json"))
    };
    let (a, b) = (run("1", "t1"), run("2", "t2"));
    for (x, y) in cells(&a).iter().zip(cells(&b)) {
        for key in ["rays", "tests", "levels", "peak_candidate_bytes"] {
            assert_eq!(x["measures"][key], y["measures"][key], "{key}");
        }
    }
    assert_eq!(a["machine"]["threads"], 1);
    assert_eq!(b["machine"]["threads"], 2);
}

#[test]
fn compare_prints_one_line_per_cell() {
    let dir = scratch("compare");
    let run = |subdivisions: &str, out: &str| {
        let o = crsh(
            &dir,
            &[
                "ablate",
                "--pipelines",
                "crsh",
                "--set",
                subdivisions,
                "--width",
                "16",
                "--repeat",
                "1",
                "--quiet",
                "--out",
                out,
            ],
        );
        assert_ok(&o);
    };
    run("hierarchy.subdivision=8,16", "old");
    run("hierarchy.subdivision=8,4", "new");
    let o = crsh(
        &dir,
        &[
            "ablate",
            "--compare",
            "old/results.json",
            "new/results.json",
        ],
    );
    assert_ok(&o);
    let t = text(&o.stdout);
    let line = t
        .lines()
        .find(|l| l.contains("hierarchy.subdivision=8 |"))
        .unwrap_or_else(|| panic!("no matched line:\n{t}"));
    assert!(
        line.starts_with(
            "cornell-mirrors | crsh | cpu | hierarchy.subdivision=8 | 16x16 depth 3: time "
        ),
        "{line}"
    );
    // Counters are deterministic: the same configuration does the same tests.
    assert!(line.contains("| tests 1.000x"), "{line}");
    assert!(line.contains("| agreement 1.000x"), "{line}");
    assert!(
        t.contains("only in old: cornell-mirrors | crsh | cpu | hierarchy.subdivision=16"),
        "{t}"
    );
    assert!(
        t.contains("only in new: cornell-mirrors | crsh | cpu | hierarchy.subdivision=4"),
        "{t}"
    );
    assert!(
        t.contains("1 cells matched, 1 only in old, 1 only in new"),
        "{t}"
    );

    // Not a results file: usage error.
    std::fs::write(dir.join("x.json"), "{\"a\": 1}").unwrap();
    let o = crsh(&dir, &["ablate", "--compare", "x.json", "new/results.json"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o.stderr).contains("not a crsh ablate results.json"));
}

#[test]
fn bad_plans_exit_2_with_one_clear_line() {
    let dir = scratch("bad");
    let write = |name: &str, body: &str| {
        std::fs::write(dir.join(name), body).unwrap();
        name.to_string()
    };
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec!["--plan".into(), write("syntax.toml", "scenes = [\"a\"\n"), "--out".into(), "o".into()],
            "plan syntax.toml",
        ),
        (
            vec![
                "--plan".into(),
                write("unknown.toml", "scenes = [\"cornell-mirrors\"]\nbogus = 1\n[[pipelines]]\npipeline = \"bvh\"\n"),
                "--out".into(),
                "o".into(),
            ],
            "unknown field `bogus`",
        ),
        (
            vec![
                "--plan".into(),
                write("nopipe.toml", "scenes = [\"cornell-mirrors\"]\n[[pipelines]]\npipeline = \"warp-drive\"\n"),
                "--out".into(),
                "o".into(),
            ],
            "unknown pipeline `warp-drive`",
        ),
        (
            vec![
                "--plan".into(),
                write("param.toml", "scenes = [\"cornell-mirrors\"]\n[[pipelines]]\npipeline = \"crsh\"\n[pipelines.grid]\n\"hierarchy.bogus\" = [1, 2]\n"),
                "--out".into(),
                "o".into(),
            ],
            "hierarchy.bogus",
        ),
        (
            vec!["--plan".into(), "does-not-exist.toml".into(), "--out".into(), "o".into()],
            "cannot read plan does-not-exist.toml",
        ),
        (vec!["--pipelines".into(), "bvh".into()], "--out DIR is required"),
        (
            vec!["--set".into(), "hierarchy.depth".into(), "--out".into(), "o".into()],
            "expected KEY=VALUE",
        ),
        (
            vec!["--width".into(), "12,abc".into(), "--out".into(), "o".into()],
            "not a whole number",
        ),
        (
            vec!["--backends".into(), "metal".into(), "--out".into(), "o".into()],
            "unknown backend `metal`",
        ),
        (
            vec![
                "--plan".into(),
                write("axis.toml", "scenes = [\"cornell-mirrors\"]\naccuracy_axes = [\"beauty\"]\n[[pipelines]]\npipeline = \"bvh\"\n"),
                "--out".into(),
                "o".into(),
            ],
            "unknown accuracy axis `beauty`",
        ),
        (
            vec![
                "--plan".into(),
                write("refparams.toml", "scenes = [\"cornell-mirrors\"]\nreference_params = { \"raygen.bogus\" = 1 }\n[[pipelines]]\npipeline = \"bvh\"\n"),
                "--out".into(),
                "o".into(),
            ],
            "raygen.bogus",
        ),
        (
            vec![
                "--plan".into(),
                write("frames0.toml", "scenes = [\"cornell-mirrors-animated\"]\nframes = 0\n[[pipelines]]\npipeline = \"bvh\"\n"),
                "--out".into(),
                "o".into(),
            ],
            "frames = 0 is outside 1..=100000",
        ),
        (
            vec!["--frames".into(), "100001".into(), "--out".into(), "o".into()],
            "frames = 100001 is outside 1..=100000",
        ),
        (
            vec![
                "--plan".into(),
                write("basekey.toml", "scenes = [\"cornell-mirrors\"]\nbaseline = { \"raygen.offsets\" = \"none\" }\n[[pipelines]]\npipeline = \"bvh\"\n"),
                "--out".into(),
                "o".into(),
            ],
            "baseline key `raygen.offsets` is not a grid key of the plan (grid keys: none)",
        ),
        (
            vec![
                "--plan".into(),
                write("baseval.toml", "scenes = [\"cornell-mirrors\"]\nbaseline = { \"intersect.test\" = \"projected\" }\n[grid]\n\"intersect.test\" = [\"mt\", \"watertight\"]\n[[pipelines]]\npipeline = \"bvh\"\n"),
                "--dry-run".into(),
            ],
            "baseline `intersect.test` = projected is not among the values pipeline `bvh` sweeps (mt, watertight)",
        ),
        (
            vec![
                "--plan".into(),
                write("every.toml", "scenes = [\"cornell-mirrors-animated\"]\nreference_every = 2\n[[pipelines]]\npipeline = \"bvh\"\n"),
                "--out".into(),
                "o".into(),
            ],
            "set `frames` too",
        ),
    ];
    for (args, needle) in cases {
        let mut full = vec!["ablate".to_string()];
        full.extend(args);
        let refs: Vec<&str> = full.iter().map(String::as_str).collect();
        let o = crsh(&dir, &refs);
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{full:?}: {err}");
        assert!(err.starts_with("error: "), "{full:?}: {err}");
        assert_eq!(
            err.trim_end().lines().count(),
            1,
            "{full:?}: one line: {err}"
        );
        assert!(err.contains(needle), "{full:?}: `{needle}` not in {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    assert!(!dir.join("o").exists(), "nothing is written for a bad plan");
}

#[test]
fn frames_plan_has_per_frame_rows_totals_and_a_chart() {
    let dir = scratch("frames");
    let plan = dir.join("frames.toml");
    std::fs::write(
        &plan,
        r#"
scenes = ["cornell-mirrors-animated"]
width = 24
depth = 1
repeat = 1
warmup = 0
frames = 3
reference = "brute"

[[pipelines]]
pipeline = "bvh"

[[pipelines]]
pipeline = "bvh"
label = "bvh-refit"
[pipelines.grid]
"intersect.update" = "refit"

[[pipelines]]
pipeline = "crsh"
"#,
    )
    .unwrap();
    let o = crsh(
        &dir,
        &["ablate", "--plan", plan.to_str().unwrap(), "--out", "out"],
    );
    assert_ok(&o);
    let stdout = text(&o.stdout);
    assert!(stdout.contains("3 frames,"), "{stdout}");
    assert!(stdout.contains("frames.csv, report.html"), "{stdout}");
    let out = dir.join("out");
    let v = read_json(&out.join("results.json"));
    assert_eq!(v["plan"]["frames"], 3);
    let cs = cells(&v);
    assert_eq!(cs.len(), 3);
    let mut structures = Vec::new();
    for c in cs {
        assert_eq!(c["status"], "ok", "{c:#}");
        let m = &c["measures"];
        assert_eq!(m["counters_equal_across_repeats"], true);
        assert_eq!(m["accuracy"]["hit_agreement"], 1.0, "{c:#}");
        let rows = m["frames"]["rows"].as_array().expect("per-frame rows");
        assert_eq!(rows.len(), 3);
        let mut frame_sum = 0.0;
        let mut rays = 0;
        for (i, r) in rows.iter().enumerate() {
            assert_eq!(r["frame"], i as u64);
            assert_eq!(r["hit_agreement"], 1.0, "{r}");
            assert!(r["moved_triangles"].as_u64().unwrap() > 0);
            let update = r["update_ms"].as_f64().unwrap();
            let render = r["render_ms"].as_f64().unwrap();
            assert!(update > 0.0 && render > 0.0, "{r}");
            assert!((r["frame_ms"].as_f64().unwrap() - (update + render)).abs() < 1e-6);
            assert!(r["structure_ms"].as_f64().unwrap() <= update);
            assert!(r["trace_ms"].as_f64().unwrap() <= render);
            assert!(r["tests_per_ray"].as_f64().unwrap() > 0.0);
            frame_sum += r["frame_ms"].as_f64().unwrap();
            rays += r["traced_rays"].as_u64().unwrap();
        }
        let t = &m["frames"]["totals"];
        assert_eq!(
            (t["frames"].as_u64(), t["frames_checked"].as_u64()),
            (Some(3), Some(3))
        );
        assert_eq!(t["min_hit_agreement"], 1.0);
        assert!(
            (t["frame_ms"].as_f64().unwrap() - frame_sum).abs() < 1e-6,
            "{t}"
        );
        assert!((t["mean_frame_ms"].as_f64().unwrap() - frame_sum / 3.0).abs() < 1e-6);
        for k in [
            "update_ms",
            "structure_ms",
            "trace_ms",
            "mean_update_ms",
            "mean_structure_ms",
        ] {
            assert!(t[k].as_f64().unwrap() > 0.0, "{k}: {t}");
        }
        // The cell's counters are the sequence's: every frame's rays summed.
        assert_eq!(t["traced_rays"].as_u64(), Some(rays));
        assert_eq!(m["rays"]["traced"].as_u64(), Some(rays));
        assert!(m["timings_ms"]["update"]["median"].as_f64().unwrap() > 0.0);
        structures.push((
            c["label"].as_str().unwrap().to_string(),
            rows[0]["structure"].as_str().unwrap().to_string(),
            rows[2]["structure"].as_str().unwrap().to_string(),
        ));
    }
    // Frame 0 builds; afterwards the BVH rebuilds or refits and crsh updates its spheres.
    assert_eq!(
        structures,
        [
            (
                "bvh".to_string(),
                "bvh rebuild".to_string(),
                "bvh rebuild".to_string()
            ),
            (
                "bvh-refit update=refit".to_string(),
                "bvh rebuild".to_string(),
                "bvh refit".to_string()
            ),
            (
                "crsh".to_string(),
                "spheres + crsh rebuild + brute rebuild".to_string(),
                "spheres + crsh rebuild + brute rebuild".to_string()
            ),
        ]
    );

    // results.csv: the totals' columns, filled for frames cells.
    let csv = parse_csv(&std::fs::read_to_string(out.join("results.csv")).unwrap());
    let header = &csv[0];
    let col = |name: &str| {
        header
            .iter()
            .position(|h| h == name)
            .unwrap_or_else(|| panic!("CSV lacks {name}: {header:?}"))
    };
    for (row, c) in csv[1..].iter().zip(cs) {
        assert_eq!(row.len(), header.len());
        assert_eq!(row[col("frames")], "3");
        let mean: f64 = row[col("frame_mean_ms")].parse().unwrap();
        let want = c["measures"]["frames"]["totals"]["mean_frame_ms"]
            .as_f64()
            .unwrap();
        assert!((mean - want).abs() < 1e-3, "{mean} vs {want}");
        for k in ["update_mean_ms", "structure_mean_ms", "render_mean_ms"] {
            assert!(row[col(k)].parse::<f64>().unwrap() > 0.0, "{k}");
        }
    }
    // frames.csv: one line per cell and frame.
    let frames_csv = std::fs::read_to_string(out.join("frames.csv")).expect("frames.csv");
    let fcsv = parse_csv(&frames_csv);
    assert_eq!(fcsv.len(), 1 + 3 * 3, "{frames_csv}");
    let fcol = |name: &str| fcsv[0].iter().position(|h| h == name).unwrap();
    assert_eq!(fcsv[5][fcol("label")], "bvh-refit update=refit");
    assert_eq!(fcsv[6][fcol("structure")], "bvh refit");
    assert_eq!(fcsv[1][fcol("hit_agreement")], "1.00000000");

    // The frames chart, and the report shows it with the frames table.
    let stem = "cornell-mirrors-animated-frames";
    assert!(is_png(&out.join(format!("charts/{stem}.png"))));
    assert!(is_svg(&out.join(format!("charts/{stem}.svg"))));
    let report = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(
        report.contains(&format!("id=\"chart-{stem}\"")),
        "chart not in report"
    );
    assert!(report.contains(&format!("charts/{stem}.png")));
    assert!(report.contains("id=\"frames-cornell-mirrors-animated\""));
    assert!(report.contains("render (trace and shade)"));

    // --redraw from results.json alone gives the same CSV files (the frames round-trip).
    let o = crsh(&dir, &["ablate", "--redraw", "out", "--out", "again"]);
    assert_ok(&o);
    for f in ["results.csv", "frames.csv"] {
        assert_eq!(
            std::fs::read_to_string(dir.join("again").join(f)).unwrap(),
            std::fs::read_to_string(out.join(f)).unwrap(),
            "{f}"
        );
    }
    assert!(is_png(&dir.join(format!("again/charts/{stem}.png"))));
}

/// Renders `report.html` in headless Chromium and checks every chart and table is in the DOM.
/// The figures of a cell that do not depend on the run: everything but wall times (and the
/// per-kind trace times and Mrays/s derived from them).
fn deterministic(c: &Value) -> Value {
    let mut c = c.clone();
    c["threads"] = Value::Null;
    if let Some(m) = c.get_mut("measures").and_then(|m| m.as_object_mut()) {
        for k in [
            "timings_ms",
            "device_timings_ms",
            "mrays_per_s",
            "build_stages_ms",
        ] {
            m.remove(k);
        }
        if let Some(kinds) = m.get_mut("per_kind").and_then(|k| k.as_object_mut()) {
            for k in kinds.values_mut() {
                k["trace_ms"] = Value::Null;
            }
        }
    }
    c
}

/// A plan run as 3 shards (3 processes, 3 directories) and merged equals the plan run whole,
/// cell for cell: same cells in the same order, equal counters and accuracy, times present.
/// The merge refuses a missing shard, a repeated one, a shard of another plan or revision and
/// a directory that is not a shard.
#[test]
fn sharded_and_merged_equals_the_whole_run() {
    let dir = scratch("shards");
    let plan = small_quick_plan(&dir);
    let plan = plan.to_str().unwrap();
    let run = |extra: &[&str]| {
        let mut args = vec!["ablate", "--plan", plan, "--repeat", "2", "--quiet"];
        args.extend_from_slice(extra);
        let o = crsh(&dir, &args);
        assert_ok(&o);
        o
    };
    run(&["--out", "whole"]);
    for k in 1..=3 {
        let o = run(&["--out", &format!("shard{k}"), "--shard", &format!("{k}/3")]);
        assert!(
            text(&o.stdout).contains(&format!("(shard {k}/3 of 10 cells)")),
            "{}",
            text(&o.stdout)
        );
    }
    let whole = read_json(&dir.join("whole/results.json"));
    let mut digests = Vec::new();
    for k in 1..=3 {
        let v = read_json(&dir.join(format!("shard{k}/results.json")));
        assert_eq!(v["shard"]["index"], k);
        assert_eq!(v["shard"]["count"], 3);
        assert_eq!(v["expansion"]["cells"], 10);
        for c in cells(&v) {
            assert_eq!(
                c["index"].as_u64().unwrap() % 3,
                k - 1,
                "round robin: {c:#}"
            );
        }
        digests.push(v["expansion"]["digest"].clone());
    }
    assert!(digests.iter().all(|d| *d == whole["expansion"]["digest"]));

    let o = crsh(
        &dir,
        &[
            "ablate", "--merge", "shard3", "shard1", "shard2", "--out", "merged",
        ],
    );
    assert_ok(&o);
    assert!(
        text(&o.stdout).contains("(merged from 3 shards)"),
        "{}",
        text(&o.stdout)
    );
    let merged = read_json(&dir.join("merged/results.json"));
    let (w, m) = (cells(&whole), cells(&merged));
    assert_eq!(w.len(), 10);
    assert_eq!(m.len(), w.len());
    for (a, b) in w.iter().zip(m) {
        assert_eq!(deterministic(a), deterministic(b), "cell {}", a["index"]);
        for c in [a, b] {
            assert_eq!(c["status"], "ok");
            let t = &c["measures"]["timings_ms"]["total"];
            assert!(t["median"].as_f64().unwrap() > 0.0, "{c:#}");
            assert!(c["measures"]["mrays_per_s"]["overall"].as_f64().unwrap() > 0.0);
        }
    }
    assert_eq!(merged["plan"], whole["plan"]);
    assert!(merged.get("shard").is_none());
    let shards = merged["merged_from"].as_array().unwrap();
    let order: Vec<u64> = shards
        .iter()
        .map(|s| s["shard"]["index"].as_u64().unwrap())
        .collect();
    assert_eq!(order, [1, 2, 3]);
    // The CSV has the whole run's columns and rows; the report says where the cells ran.
    let csv =
        |d: &str| parse_csv(&std::fs::read_to_string(dir.join(d).join("results.csv")).unwrap());
    let (wc, mc) = (csv("whole"), csv("merged"));
    assert_eq!(wc[0], mc[0]);
    assert_eq!(wc.len(), mc.len());
    let html = std::fs::read_to_string(dir.join("merged/report.html")).unwrap();
    assert!(
        html.contains("id=\"shards-table\""),
        "merged report lists the shards"
    );
    assert!(
        std::fs::read_dir(dir.join("merged/charts"))
            .unwrap()
            .count()
            >= 6
    );

    // Refusals: exit 2, one line naming the problem.
    let refuse = |args: &[&str], needle: &str| {
        let o = crsh(&dir, args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", text(&o.stderr));
        let err = text(&o.stderr);
        assert!(err.contains(needle), "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
    };
    refuse(
        &["ablate", "--merge", "shard1", "shard2", "--out", "m2"],
        "missing shard 3/3",
    );
    refuse(
        &[
            "ablate", "--merge", "shard1", "shard1", "shard2", "shard3", "--out", "m2",
        ],
        "given twice",
    );
    refuse(
        &["ablate", "--merge", "whole", "shard1", "--out", "m2"],
        "not a shard",
    );
    run(&["--out", "other1", "--shard", "1/3", "--reference", "bvh"]);
    refuse(
        &[
            "ablate", "--merge", "other1", "shard2", "shard3", "--out", "m2",
        ],
        "different plans",
    );
    let p3 = dir.join("shard3/results.json");
    let mut v = read_json(&p3);
    v["machine"]["git_revision"] = Value::String("0000000".into());
    std::fs::write(&p3, serde_json::to_string(&v).unwrap()).unwrap();
    refuse(
        &[
            "ablate", "--merge", "shard1", "shard2", "shard3", "--out", "m2",
        ],
        "different revisions",
    );
    refuse(
        &["ablate", "--shard", "4/3", "--plan", plan, "--out", "x"],
        "--shard 4/3",
    );
    assert!(
        !dir.join("m2").exists(),
        "nothing is written by a refused merge"
    );
}

/// The file names in `out/charts`, sorted.
fn chart_names(out: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(out.join("charts"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .collect();
    names.sort();
    names
}

/// `--redraw` rebuilds charts, CSV and report from `results.json` alone, and a rerun into the
/// same directory removes the charts it no longer draws.
#[test]
fn redraw_rebuilds_the_outputs_and_stale_charts_go() {
    let dir = scratch("redraw");
    let plan = small_quick_plan(&dir);
    let run_into_out = |plan: &Path| {
        let args = [
            "ablate",
            "--plan",
            plan.to_str().unwrap(),
            "--out",
            "out",
            "--repeat",
            "1",
            "--quiet",
        ];
        assert_ok(&crsh(&dir, &args));
    };
    run_into_out(&plan);
    let out = dir.join("out");
    let charts = chart_names(&out);
    assert!(
        charts.iter().any(|c| c.starts_with("office-boxes-")),
        "{charts:?}"
    );
    let report = std::fs::read_to_string(out.join("report.html")).unwrap();
    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    // A chart nobody draws, then everything but results.json removed: --redraw restores them
    // and removes the stranger.
    std::fs::write(out.join("charts/old-scene-tests.svg"), "<svg/>").unwrap();
    std::fs::remove_file(out.join("report.html")).unwrap();
    std::fs::remove_file(out.join("results.csv")).unwrap();
    for c in &charts {
        std::fs::remove_file(out.join("charts").join(c)).unwrap();
    }
    let o = crsh(&dir, &["ablate", "--redraw", "out"]);
    assert_ok(&o);
    assert_eq!(
        chart_names(&out),
        charts,
        "the same charts, and no stale one"
    );
    assert_eq!(
        std::fs::read_to_string(out.join("results.csv")).unwrap(),
        csv
    );
    assert_eq!(
        std::fs::read_to_string(out.join("report.html")).unwrap(),
        report,
        "the report is a function of results.json"
    );
    // A rerun on one scene into the same directory drops the other scene's charts.
    let one = std::fs::read_to_string(&plan).unwrap().replace(
        "scenes = [\"cornell-mirrors\", \"office-boxes\"]",
        "scenes = [\"cornell-mirrors\"]",
    );
    let one_plan = dir.join("one.toml");
    std::fs::write(&one_plan, one).unwrap();
    run_into_out(&one_plan);
    let left = chart_names(&out);
    assert!(!left.is_empty());
    assert!(
        left.iter().all(|c| c.starts_with("cornell-mirrors-")),
        "{left:?}"
    );
    // --redraw of a directory without results.json is a usage error.
    let o = crsh(&dir, &["ablate", "--redraw", "nowhere"]);
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn report_renders_in_headless_chromium() {
    let Some(chromium) = ["chromium", "chromium-browser"].into_iter().find(|c| {
        Command::new(c)
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
    }) else {
        println!("SKIP: chromium not installed");
        return;
    };
    let dir = scratch("chromium");
    let o = crsh(
        &dir,
        &[
            "ablate",
            "--scenes",
            "cornell-mirrors,office-boxes",
            "--pipelines",
            "crsh,bvh",
            "--width",
            "16",
            "--repeat",
            "1",
            "--reference",
            "brute",
            "--quiet",
            "--out",
            "out",
        ],
    );
    assert_ok(&o);
    let report = dir.join("out/report.html").canonicalize().unwrap();
    let profile = dir.join("chromium-profile");
    let o = Command::new(chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--no-first-run",
            &format!("--user-data-dir={}", profile.display()),
            "--dump-dom",
            &format!("file://{}", report.display()),
        ])
        .output()
        .expect("run chromium");
    assert!(o.status.success(), "chromium failed: {}", text(&o.stderr));
    let dom = text(&o.stdout);
    for scene in ["cornell-mirrors", "office-boxes"] {
        for kind in ["pareto", "tests", "stages"] {
            let id = format!("id=\"chart-{scene}-{kind}\"");
            assert!(dom.contains(&id), "DOM lacks {id}");
        }
        assert!(
            dom.contains(&format!("id=\"table-{scene}\"")),
            "DOM lacks table {scene}"
        );
    }
    assert_eq!(dom.matches("<svg").count(), 6, "every chart inlined as SVG");
    assert!(dom.contains("id=\"machine-table\"") && dom.contains("id=\"plan-text\""));
}

/// The rows of a CSV file as maps column → field (the header is checked to be unique).
fn csv_records(path: &Path) -> (Vec<String>, Vec<std::collections::HashMap<String, String>>) {
    let rows = parse_csv(&std::fs::read_to_string(path).expect("CSV written"));
    let header = rows[0].clone();
    let unique: std::collections::BTreeSet<&String> = header.iter().collect();
    assert_eq!(unique.len(), header.len(), "repeated columns: {header:?}");
    let records = rows[1..]
        .iter()
        .map(|r| {
            assert_eq!(r.len(), header.len(), "{r:?}");
            header.iter().cloned().zip(r.iter().cloned()).collect()
        })
        .collect();
    (header, records)
}

/// The ray kinds in `crsh_core::RayKind::ALL` order.
const RAY_KINDS: [&str; 6] = [
    "primary",
    "shadow",
    "reflection",
    "refraction",
    "ao",
    "diffuse",
];

/// Asserts that `header` has every column of the space-separated `cols`.
fn assert_columns(header: &[String], cols: &str, file: &str) {
    for col in cols.split_whitespace() {
        assert!(
            header.iter().any(|h| h == col),
            "{file} lacks {col}: {header:?}"
        );
    }
}

/// `plans/origin-offsets.toml` without its `bvh2` pipelines when this build has no `bvh2`
/// intersector (it lands with another branch), and whether it had to drop them.
fn origin_offsets_plan() -> (String, bool) {
    let shipped =
        std::fs::read_to_string(repo_root().join("plans/origin-offsets.toml")).expect("plan");
    let listing = crsh(&repo_root(), &["pipelines"]);
    assert_ok(&listing);
    let has_bvh2 = text(&listing.stdout)
        .lines()
        .any(|l| l.trim_start().starts_with("bvh2 "));
    if has_bvh2 {
        return (shipped, false);
    }
    let mut blocks = shipped.split("[[pipelines]]");
    let head = blocks.next().unwrap().to_string();
    let kept: String = blocks
        .filter(|b| !b.contains("bvh2"))
        .map(|b| format!("[[pipelines]]{b}"))
        .collect();
    (head + &kept, true)
}

/// The shipped origin-offsets plan (seed 001 §4) validates with `--dry-run` (its bvh2 half
/// once the binary BVH is registered), and a tiny variant of it on the built-in scenes writes
/// `baseline.csv`, `baseline.md` and the report table: every row pairs its cell with the cell
/// identical but for `raygen.offsets = none`, its ratios are the cells' figures in
/// results.json divided, the baseline's own rows exactly 100 % and 1, and cells that did not
/// run (hemisphere sets still missing in this build) are listed instead of paired.
#[test]
fn origin_offsets_plan_pairs_every_cell_with_its_no_offsets_twin() {
    let dir = scratch("offsets");
    let shipped_path = repo_root().join("plans/origin-offsets.toml");
    let shipped = std::fs::read_to_string(&shipped_path).unwrap();
    for needle in [
        "baseline = { \"raygen.offsets\" = \"none\" }",
        "\"raygen.offsets\" = [\"none\", \"center\", \"vertex\", \"median\", \"polygon\"]",
        "\"raygen.ao_length\" = [0.01, 0.05, 0.10, 0.25]",
        "\"raygen.shadow_origin\" = \"surface\"",
        "\"intersect.kind\" = \"bvh2\"",
        "label = \"cwbvh-ao\"",
        "label = \"bvh2-diffuse\"",
        "reference = \"bvh\"",
        "width = 512",
        "repeat = 3",
        "\"office-boxes\"",
        "${CRSH_SCENES}/dragon/dragon.toml",
    ] {
        assert!(
            shipped.contains(needle),
            "origin-offsets.toml changed: {needle}"
        );
    }
    let (plan, dropped_bvh2) = origin_offsets_plan();
    let o = crsh(
        &dir,
        &[
            "ablate",
            "--plan",
            shipped_path.to_str().unwrap(),
            "--dry-run",
        ],
    );
    if dropped_bvh2 {
        // Until the binary BVH lands the shipped plan names an unknown variant, clearly.
        assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
        assert!(text(&o.stderr).contains("unknown intersect variant `bvh2`"));
        // The rest of it checks out (its scenes, looked up from elsewhere, may be missing:
        // a dry run reports that and goes on).
        let copy = scratch("offsets-plan").join("origin-offsets.toml");
        std::fs::write(&copy, &plan).unwrap();
        let o = crsh(
            &dir,
            &["ablate", "--plan", copy.to_str().unwrap(), "--dry-run"],
        );
        assert_ok(&o);
        let out = text(&o.stdout);
        for needle in [
            "150 cells, 3 timed runs each (nothing run)",
            "scene office-boxes: 30 cells\n",
            "pipeline cwbvh-ao: 100 cells, depth 0\n",
            "pipeline cwbvh-shadow: 25 cells, depth 0\n",
            "pipeline cwbvh-diffuse: 25 cells, depth 3\n",
            "baseline raygen.offsets = none: 150 cells set against 30 baseline cells",
        ] {
            assert!(out.contains(needle), "{needle}: {out}");
        }
    } else {
        assert_ok(&o);
        let out = text(&o.stdout);
        assert!(out.contains("300 cells, 3 timed runs each"), "{out}");
        assert!(
            out.contains("pipeline bvh2-diffuse: 25 cells, depth 3"),
            "{out}"
        );
    }
    assert!(!dir.join("out").exists() && std::fs::read_dir(&dir).unwrap().count() == 0);

    // The tiny variant: built-in scenes, 32 pixels, one timed run.
    let start = plan.find("scenes = [").unwrap();
    let end = start + plan[start..].find("]\n").unwrap() + 2;
    let tiny = format!(
        "{}scenes = [\"cornell-mirrors\", \"office-boxes\"]\n{}",
        &plan[..start],
        &plan[end..]
    )
    .replace("width = 512", "width = 32")
    .replace("repeat = 3", "repeat = 1\nwarmup = 0");
    std::fs::write(dir.join("tiny.toml"), &tiny).unwrap();
    let o = crsh(
        &dir,
        &["ablate", "--plan", "tiny.toml", "--out", "out", "--quiet"],
    );
    assert_ok(&o);
    assert!(
        text(&o.stdout).contains("baseline.csv, baseline.md, report.html"),
        "{}",
        text(&o.stdout)
    );
    let out = dir.join("out");
    let v = read_json(&out.join("results.json"));
    let cs = cells(&v);
    let intersectors = if dropped_bvh2 { 1 } else { 2 };
    // 2 scenes × (4 AO lengths + diffuse + shadow) × 5 offsets per intersector.
    assert_eq!(cs.len(), 2 * 6 * 5 * intersectors);
    let offsets = |c: &Value| c["params"]["raygen.offsets"].as_str().unwrap().to_string();
    let baseline_of = |c: &Value| -> &Value {
        cs.iter()
            .find(|b| {
                offsets(b) == "none"
                    && ["scene", "pipeline", "backend", "width", "height", "depth"]
                        .iter()
                        .all(|k| b[k] == c[k])
                    && b["params"]
                        .as_object()
                        .unwrap()
                        .iter()
                        .all(|(k, x)| k == "raygen.offsets" || c["params"][k] == *x)
            })
            .expect("every cell's baseline is in the run")
    };
    for c in cs.iter().filter(|c| offsets(c) == "none") {
        assert_eq!(c["status"], "ok", "baseline cells run: {c:#}");
    }

    // results.csv: the per-kind columns equal results.json's per_kind.
    let (header, rows) = csv_records(&out.join("results.csv"));
    // (The loop below reads kind_KIND_{rays,bounds_per_ray,offset_ended_fraction} and rays_ao.)
    assert_columns(
        &header,
        "rays_diffuse tests_inner_nodes_per_ray tests_leaves_per_ray kind_ao_inner_nodes_per_ray \
         kind_ao_leaves_per_ray kind_ao_ray_triangle_per_ray kind_ao_trace_ms \
         time_ray_creation_median_ms",
        "results.csv",
    );
    for (row, c) in rows.iter().zip(cs) {
        let Some(kinds) = c["measures"]["per_kind"].as_object() else {
            continue;
        };
        for (kind, k) in kinds {
            let rays = k["rays"].as_u64().unwrap();
            assert_eq!(row[&format!("kind_{kind}_rays")], rays.to_string());
            let per = |n: &str| k[n].as_u64().unwrap_or(0) as f64 / rays.max(1) as f64;
            assert_eq!(
                row[&format!("kind_{kind}_bounds_per_ray")],
                format!("{:.4}", per("bounds"))
            );
            assert_eq!(
                row[&format!("kind_{kind}_offset_ended_fraction")],
                format!("{:.6}", per("offset_ended"))
            );
        }
        if c["measures"]["rays"]["ao"].as_u64().unwrap_or(0) > 0 {
            assert_eq!(row["rays_ao"], c["measures"]["rays"]["ao"].to_string());
        }
    }

    // baseline.csv: one row per paired cell and traced kind but the camera's, in plan order.
    let (header, rows) = csv_records(&out.join("baseline.csv"));
    // (The checks below read the other columns; a missing one panics there.)
    assert_columns(
        &header,
        "baseline_key inner_nodes_per_ray baseline_inner_nodes_per_ray leaves_per_ray \
         offset_ended_fraction cell_ray_creation_ms hit_agreement",
        "baseline.csv",
    );
    let kinds_of = |c: &Value| -> Vec<String> {
        let mut ks: Vec<String> = c["measures"]["per_kind"]
            .as_object()
            .unwrap()
            .iter()
            .filter(|(k, s)| *k != "primary" && s["rays"].as_u64().unwrap() > 0)
            .map(|(k, _)| k.clone())
            .collect();
        ks.sort_by_key(|k| RAY_KINDS.iter().position(|o| o == k));
        ks
    };
    let mut want: Vec<(String, String, String)> = Vec::new();
    let mut unpaired = Vec::new();
    for c in cs {
        let b = baseline_of(c);
        if c["status"] == "ok" && b["status"] == "ok" {
            for k in kinds_of(c) {
                want.push((c["scene"].to_string(), c["label"].to_string(), k));
            }
        } else {
            unpaired.push(format!(
                "- {} | {}: ",
                c["scene"].as_str().unwrap(),
                c["label"].as_str().unwrap()
            ));
        }
    }
    let got: Vec<(String, String, String)> = rows
        .iter()
        .map(|r| {
            (
                Value::String(r["scene"].clone()).to_string(),
                Value::String(r["label"].clone()).to_string(),
                r["kind"].clone(),
            )
        })
        .collect();
    assert_eq!(got, want);
    assert!(rows.iter().any(|r| r["kind"] == "ao"));
    assert!(rows.iter().any(|r| r["kind"] == "diffuse"));
    assert!(rows.iter().any(|r| r["kind"] == "shadow"));
    let mut own_rows = 0;
    for r in &rows {
        let c = cs
            .iter()
            .find(|c| c["label"] == r["label"].as_str() && c["scene"] == r["scene"].as_str())
            .unwrap();
        let b = baseline_of(c);
        let (k, bk) = (
            &c["measures"]["per_kind"][&r["kind"]],
            &b["measures"]["per_kind"][&r["kind"]],
        );
        assert_eq!(r["baseline_label"], b["label"].as_str().unwrap());
        assert_eq!(r["baseline_value"], "none");
        assert_eq!(r["rays"], k["rays"].to_string());
        assert_eq!(r["baseline_rays"], bk["rays"].to_string());
        let ms = |s: &Value| s["trace_ms"].as_f64().unwrap();
        // Three decimals of the same time (results.json keeps it rounded too, so the last
        // digit may differ by one where the time sits on a rounding boundary).
        let close = |csv: &str, json: f64| {
            let v: f64 = csv.parse().unwrap();
            assert!((v - json).abs() <= 5e-4 + 1e-9, "{csv} against {json}");
        };
        close(&r["trace_ms"], ms(k));
        close(&r["baseline_trace_ms"], ms(bk));
        if ms(bk) > 0.0 {
            let got: f64 = r["trace_ratio"].parse().unwrap();
            assert!((got - ms(k) / ms(bk)).abs() <= 5e-5, "{r:?}");
        }
        let agree = c["measures"]["accuracy"]["hit_agreement"].as_f64().unwrap();
        let same_rays = kinds_of(c) == kinds_of(b)
            && RAY_KINDS.iter().all(|k| {
                c["measures"]["per_kind"][k]["rays"] == b["measures"]["per_kind"][k]["rays"]
            });
        assert_eq!(
            r["identical_hits"],
            (agree == 1.0 && same_rays).to_string(),
            "{r:?}"
        );
        if c == b {
            // The baseline against itself: exactly 100 % and 1.
            own_rows += 1;
            assert_eq!(r["trace_ratio"], "1.0000", "{r:?}");
            assert_eq!(r["trace_plus_creation_ratio"], "1.0000", "{r:?}");
            assert_eq!(
                r["tests_pct"], "100.00",
                "CWBVH counts its box tests: {r:?}"
            );
            let visits = |n: &str| k[n].as_u64().unwrap();
            for (what, col) in [("inner_nodes", "inner_nodes_pct"), ("leaves", "leaves_pct")] {
                let want = if visits(what) > 0 { "100.00" } else { "" };
                assert_eq!(r[col], want, "{what}: {r:?}");
            }
            assert_eq!(r["identical_hits"], "true");
        }
    }
    assert_eq!(
        own_rows,
        rows.iter()
            .filter(|r| r["raygen.offsets"] == "none")
            .count()
    );
    assert!(own_rows >= 2 * 6 * intersectors);

    // baseline.md: seed 001's layout per kind, the `none` column the baseline's visits per
    // ray, one row per scene × setting, the cells that did not pair listed.
    let md = std::fs::read_to_string(out.join("baseline.md")).unwrap();
    for kind in ["shadow", "ao", "diffuse"] {
        let head = format!("## {kind} rays: visited inner nodes / leaves per ray\n");
        let at = md.find(&head).unwrap_or_else(|| panic!("{head}: {md}"));
        let table: Vec<&str> = md[at + head.len()..]
            .trim_start()
            .lines()
            .take_while(|l| l.starts_with('|'))
            .collect();
        assert_eq!(
            table[0],
            "| scene | setting | none: inner / leaves | center | vertex | median | polygon |"
        );
        let base_cells: Vec<&Value> = cs
            .iter()
            .filter(|c| offsets(c) == "none" && kinds_of(c).contains(&kind.to_string()))
            .collect();
        assert_eq!(table.len() - 2, base_cells.len(), "{kind}: {table:?}");
        for (line, b) in table[2..].iter().zip(&base_cells) {
            let s = &b["measures"]["per_kind"][kind];
            let per = |n: &str| s[n].as_f64().unwrap() / s["rays"].as_f64().unwrap();
            let fields: Vec<&str> = line.trim_matches('|').split(" | ").map(str::trim).collect();
            assert_eq!(fields[0], b["scene"].as_str().unwrap());
            assert!(fields[1].starts_with(b["pipeline"].as_str().unwrap()));
            assert_eq!(
                fields[2],
                format!("{:.2} / {:.2}", per("inner_nodes"), per("leaves"))
            );
            assert_eq!(fields.len(), 7, "{line}");
        }
    }
    assert!(
        md.contains("| cornell-mirrors | cwbvh-ao ao_length=0.01 |"),
        "{md}"
    );
    assert!(md.contains("## ao rays: trace time"), "{md}");
    // Tables in the plan's order of settings: AO first (seed 001's table 2).
    let at = |h: &str| md.find(h).unwrap();
    assert!(
        at("## ao rays") < at("## shadow rays") && at("## shadow rays") < at("## diffuse rays")
    );
    for line in &unpaired {
        assert!(md.contains(line.as_str()), "{line} not listed: {md}");
    }

    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    let at = html
        .find("id=\"baseline-table\"")
        .expect("report has the baseline table");
    let table = &html[at..at + html[at..].find("</table>").unwrap()];
    assert_eq!(table.matches("<tr><td").count(), rows.len());
}

/// A baseline on a key whose cells differ in this build (the AO length): each row's ratios
/// are the cell's figures over its baseline's, from the same run.
#[test]
fn baseline_ratios_divide_the_cells_figures() {
    let dir = scratch("baseline-ratios");
    std::fs::write(
        dir.join("p.toml"),
        "scenes = [\"cornell-mirrors\", \"office-boxes\"]\nwidth = 32\ndepth = 0\nrepeat = 1\nwarmup = 0\nbaseline = { \"raygen.ao_length\" = 0.05 }\n[[pipelines]]\npipeline = \"bvh\"\nlabel = \"ao\"\n[pipelines.grid]\n\"raygen.kind\" = \"ao\"\n\"shade.kind\" = \"ao\"\n\"raygen.ao_length\" = [0.01, 0.05, 0.25]\n",
    )
    .unwrap();
    let o = crsh(
        &dir,
        &["ablate", "--plan", "p.toml", "--out", "out", "--quiet"],
    );
    assert_ok(&o);
    let v = read_json(&dir.join("out/results.json"));
    let cs = cells(&v);
    let (_, rows) = csv_records(&dir.join("out/baseline.csv"));
    assert_eq!(rows.len(), 6, "2 scenes × 3 lengths, AO rays only");
    let mut differ = 0;
    for r in &rows {
        let find = |label: &str| {
            cs.iter()
                .find(|c| c["label"] == label && c["scene"] == r["scene"].as_str())
                .unwrap()
        };
        let (c, b) = (find(&r["label"]), find(&r["baseline_label"]));
        assert_eq!(b["params"]["raygen.ao_length"], "0.05");
        assert_eq!(
            c["params"]["raygen.ao_length"],
            r["raygen.ao_length"].as_str()
        );
        let tests = |c: &Value| {
            let k = &c["measures"]["per_kind"]["ao"];
            (k["bounds"].as_f64().unwrap() + k["ray_triangle"].as_f64().unwrap())
                / k["rays"].as_f64().unwrap()
        };
        let pct: f64 = r["tests_pct"].parse().unwrap();
        assert!((pct - 100.0 * tests(c) / tests(b)).abs() <= 0.005, "{r:?}");
        let trace = |c: &Value, ms: f64| {
            c["measures"]["per_kind"]["ao"]["trace_ms"]
                .as_f64()
                .unwrap()
                + ms
        };
        let creation = |c: &Value| {
            c["measures"]["timings_ms"]["ray_creation"]["median"]
                .as_f64()
                .unwrap()
        };
        let got: f64 = r["trace_plus_creation_ratio"].parse().unwrap();
        let want = trace(c, creation(c)) / trace(b, creation(b));
        assert!((got - want).abs() <= 5e-5, "{r:?}: {want}");
        if r["tests_pct"] != "100.00" {
            differ += 1;
        }
    }
    // Longer or shorter rays test other boxes: the pairs are not the cells themselves.
    assert!(differ >= 2, "{rows:?}");
    let md = std::fs::read_to_string(dir.join("out/baseline.md")).unwrap();
    assert!(
        md.contains("| scene | setting | 0.05: inner / leaves | 0.01 | 0.25 |"),
        "{md}"
    );
}

/// The shipped seed 004 plan (`plans/ray-engine.toml`) validates, and a tiny version of it
/// (24 pixels, the 100-triangle sphere and shell, generations 1 and 5) runs every pipeline
/// exactly: hit agreement 1 against brute force on every cell, no tile-cone cell makes more
/// ray-triangle tests than brute force, and 8-pixel tiles (9 per frame) need fewer tests in
/// all. (A 32-pixel tile covers the whole 24-pixel frame: its bound tests come on top.)
#[test]
fn ray_engine_plan_is_exact_on_every_cell() {
    let dir = scratch("ray-engine");
    let shipped_path = repo_root().join("plans/ray-engine.toml");
    let shipped = std::fs::read_to_string(&shipped_path).unwrap();
    for needle in [
        "width = 256",
        "depth = [1, 2, 5, 8]",
        "reference = \"brute\"",
        "\"glass-sphere-5000\"",
        "\"glass-shell-5000\"",
        "label = \"tile_cone-8\"",
        "label = \"tile_cone-32\"",
        "\"hierarchy.min_half_angle_deg\" = [1.0, 0.05]",
    ] {
        assert!(
            shipped.contains(needle),
            "ray-engine.toml changed: {needle}"
        );
    }
    let o = crsh(
        &dir,
        &[
            "ablate",
            "--plan",
            shipped_path.to_str().unwrap(),
            "--dry-run",
        ],
    );
    assert_ok(&o);
    let small = with_scenes(&shipped, &["glass-sphere-100", "glass-shell-100"])
        .replace("width = 256", "width = 24")
        .replace("depth = [1, 2, 5, 8]", "depth = [1, 5]");
    let plan = dir.join("ray-engine-small.toml");
    std::fs::write(&plan, small).unwrap();
    let o = crsh(
        &dir,
        &["ablate", "--plan", plan.to_str().unwrap(), "--out", "out"],
    );
    assert_ok(&o);
    let v = read_json(&dir.join("out/results.json"));
    let cs = cells(&v);
    // 2 scenes × 2 depths × (brute, bvh, rah, crsh, tile 8, tile 16 × 2 angles, tile 32).
    assert_eq!(cs.len(), 32);
    let mut tile_cells = 0;
    for c in cs {
        assert_eq!(c["status"], "ok", "{c:#}");
        let m = &c["measures"];
        assert_eq!(m["accuracy"]["reference"], "brute");
        assert_eq!(m["accuracy"]["hit_agreement"], 1.0, "{c:#}");
        let label = c["pipeline"].as_str().unwrap();
        if label.starts_with("tile_cone") {
            tile_cells += 1;
            let brute = m["tests"]["brute_force"].as_u64().unwrap();
            let ray_triangle = m["tests"]["ray_triangle"].as_u64().unwrap();
            assert!(ray_triangle <= brute, "{ray_triangle} > {brute}: {c:#}");
            if label == "tile_cone-8" {
                let tests = m["tests"]["total"].as_u64().unwrap();
                assert!(tests < brute, "{tests} >= {brute}: {c:#}");
            }
        }
    }
    assert_eq!(tile_cells, 16);
}

/// Soft shadows (seed 003 §5): a plan-wide `light_radius` (the scenes' own lights are points),
/// cells sweeping `raygen.shadow`, and the reference image rendered with 256 light samples
/// through `reference_params`. Hit agreement stays per ray (each cell's own rays in its own
/// query mode, edge-width occlusions bit for bit); PSNR compares each cell's image with the
/// 256-sample one, 4 samples closer than hard shadows.
#[test]
fn soft_shadow_cells_against_a_256_sample_reference() {
    let dir = scratch("soft-shadows");
    let plan = r#"scenes = ["cornell-mirrors"]
width = 24
depth = 1
repeat = 1
warmup = 0
reference = "brute"
light_radius = 0.1
reference_params = { "raygen.shadow" = "samples", "raygen.shadow_samples" = 256 }
accuracy_axes = ["hit_agreement", "psnr_db"]

[[pipelines]]
pipeline = "bvh"
[pipelines.grid]
"raygen.shadow" = ["hard", "samples", "edge_width"]
"raygen.shadow_samples" = 4
"#;
    std::fs::write(dir.join("soft.toml"), plan).unwrap();
    let o = crsh(&dir, &["ablate", "--plan", "soft.toml", "--dry-run"]);
    assert_ok(&o);
    assert!(
        text(&o.stdout).contains("light radius 0.1"),
        "{}",
        text(&o.stdout)
    );
    let o = crsh(
        &dir,
        &["ablate", "--plan", "soft.toml", "--out", "out", "-q"],
    );
    assert_ok(&o);
    let v = read_json(&dir.join("out/results.json"));
    assert_eq!(v["plan"]["light_radius"], 0.1);
    let cs = cells(&v);
    assert_eq!(cs.len(), 3);
    let psnr = |shadow: &str| {
        let c = cs
            .iter()
            .find(|c| c["params"]["raygen.shadow"] == shadow)
            .unwrap();
        assert_eq!(c["status"], "ok", "{c:#}");
        let a = &c["measures"]["accuracy"];
        assert_eq!(a["hit_agreement"], 1.0, "{shadow}: {a:#}");
        a["psnr_db"].as_f64().expect("finite PSNR")
    };
    let (hard, samples, edge) = (psnr("hard"), psnr("samples"), psnr("edge_width"));
    assert!(samples > hard, "4 samples {samples} dB, hard {hard} dB");
    assert!(edge >= hard, "edge width {edge} dB, hard {hard} dB");
    // A negative radius is refused with one clear line.
    std::fs::write(
        dir.join("bad.toml"),
        plan.replace("light_radius = 0.1", "light_radius = -1.0"),
    )
    .unwrap();
    let o = crsh(&dir, &["ablate", "--plan", "bad.toml", "--dry-run"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        text(&o.stderr).contains("light_radius"),
        "{}",
        text(&o.stderr)
    );
}

/// The shipped seed 003 plans (`plans/rttest.toml`, `plans/rttest-shadows.toml`) validate, and
/// a tiny version of the traversal plan (32 pixels, two built-in scenes) runs every cell
/// exactly (hit agreement 1 against the CWBVH) and writes the paper's `N` and `I` per ray kind
/// to results.csv.
#[test]
fn rttest_plan_is_exact_on_every_cell_and_reports_packets() {
    let dir = scratch("rttest");
    for name in ["plans/rttest.toml", "plans/rttest-shadows.toml"] {
        let path = repo_root().join(name);
        let o = crsh(
            &dir,
            &["ablate", "--plan", path.to_str().unwrap(), "--dry-run"],
        );
        assert_ok(&o);
    }
    let shipped = std::fs::read_to_string(repo_root().join("plans/rttest.toml")).unwrap();
    for needle in [
        "width = 512",
        "depth = 0",
        "reference = \"bvh\"",
        "\"primary.accel\" = \"pipeline\"",
    ] {
        assert!(shipped.contains(needle), "rttest.toml changed: {needle}");
    }
    let small = with_scenes(&shipped, &["office-boxes", "cornell-mirrors"])
        .replace("width = 512", "width = 32");
    let plan = dir.join("rttest-small.toml");
    std::fs::write(&plan, small).unwrap();
    let o = crsh(
        &dir,
        &["ablate", "--plan", plan.to_str().unwrap(), "--out", "out"],
    );
    assert_ok(&o);
    let v = read_json(&dir.join("out/results.json"));
    let cs = cells(&v);
    assert_eq!(cs.len(), 2 * 36);
    for c in cs {
        assert_eq!(c["status"], "ok", "{c:#}");
        let m = &c["measures"];
        assert_eq!(m["accuracy"]["hit_agreement"], 1.0, "{c:#}");
        if c["pipeline"] != "cwbvh" {
            assert!(
                m["packets"]["primary"]["packets"].as_u64().unwrap() > 0,
                "{c:#}"
            );
        }
    }
    let csv = std::fs::read_to_string(dir.join("out/results.csv")).unwrap();
    let header = csv.lines().next().unwrap();
    for col in [
        "packets_primary_n",
        "packets_primary_i",
        "packets_shadow_culled_fraction",
    ] {
        assert!(header.contains(col), "{col} missing from {header}");
    }
}

/// The shipped dual-traversal plan (issue 17) validates, and a tiny version of it (32 pixels,
/// two built-in scenes) runs every cell exactly (hit agreement 1 against the CWBVH), with the
/// default `dual` cells needing fewer tests per ray than the thesis's `crsh` traversal.
#[test]
fn dual_plan_is_exact_on_every_cell() {
    let dir = scratch("dual-plan");
    let path = repo_root().join("plans/dual.toml");
    let o = crsh(
        &dir,
        &["ablate", "--plan", path.to_str().unwrap(), "--dry-run"],
    );
    assert_ok(&o);
    assert!(
        text(&o.stdout).contains("69 cells, 3 timed runs each (nothing run)"),
        "{}",
        text(&o.stdout)
    );
    let shipped = std::fs::read_to_string(&path).unwrap();
    let small = with_scenes(&shipped, &["office-boxes", "cornell-mirrors"])
        .replace("width = 512", "width = 32")
        .replace("repeat = 3", "repeat = 1");
    let plan = dir.join("dual-small.toml");
    std::fs::write(&plan, small).unwrap();
    let o = crsh(
        &dir,
        &["ablate", "--plan", plan.to_str().unwrap(), "--out", "out"],
    );
    assert_ok(&o);
    let v = read_json(&dir.join("out/results.json"));
    let cs = cells(&v);
    assert_eq!(cs.len(), 2 * 23);
    // `dual_screen` in both tile orders and `dual_screen_bvh`, exact like every cell (below).
    let labelled = |prefix: &str| {
        cs.iter()
            .filter(|c| c["label"].as_str().is_some_and(|l| l.starts_with(prefix)))
            .count()
    };
    assert_eq!(labelled("preset-dual-screen"), 2 * 4);
    // `dual_screen_bvh` with its wide nodes through the 8-wide BVH and without.
    assert_eq!(labelled("preset-dual-screen-bvh"), 2 * 2);
    for scene in ["office-boxes", "cornell-mirrors"] {
        let per_ray = |label: &str| -> f64 {
            let c = cs
                .iter()
                .find(|c| c["scene"] == scene && c["label"] == label)
                .unwrap_or_else(|| panic!("{scene}: no {label} cell"));
            c["measures"]["tests"]["per_ray"].as_f64().unwrap()
        };
        let crsh_tests = per_ray("crsh");
        let dual_default = cs
            .iter()
            .find(|c| {
                c["scene"] == scene
                    && c["label"].as_str().is_some_and(|l| {
                        l.starts_with("dual ")
                            && l.contains("subdivision=8")
                            && l.contains("depth=2")
                    })
            })
            .unwrap_or_else(|| panic!("{scene}: no default dual cell"));
        let dual_tests = dual_default["measures"]["tests"]["per_ray"]
            .as_f64()
            .unwrap();
        assert!(
            dual_tests < crsh_tests,
            "{scene}: dual {dual_tests} against crsh {crsh_tests}"
        );
    }
    for c in cs {
        assert_eq!(c["status"], "ok", "{c:#}");
        assert_eq!(c["measures"]["accuracy"]["hit_agreement"], 1.0, "{c:#}");
    }
}

/// `shipped` (a plan's text) with its `scenes = [...]` list replaced by `scenes`.
fn with_scenes(shipped: &str, scenes: &[&str]) -> String {
    let start = shipped.find("scenes = [").expect("a scenes list");
    let end = start + shipped[start..].find("]\n").expect("its end") + 2;
    let list: Vec<String> = scenes.iter().map(|s| format!("\"{s}\"")).collect();
    format!(
        "{}scenes = [{}]\n{}",
        &shipped[..start],
        list.join(", "),
        &shipped[end..]
    )
}

/// The shipped dual-traversal plans validate with `--dry-run`: the CPU one and its wgpu twin
/// (every cell on the wgpu backend, the same scenes, `dual` against `crsh` and `bvh`), and the
/// dynamic-scene plan (`dual` rebuilding or refitting its object side).
#[test]
fn dual_plans_validate() {
    let dir = scratch("dual-plans");
    for (plan, cells) in [
        ("plans/dual.toml", 69),
        ("plans/dual-wgpu.toml", 33),
        ("plans/dynamic.toml", 26),
    ] {
        let path = repo_root().join(plan);
        let shipped = std::fs::read_to_string(&path).unwrap();
        assert!(shipped.contains("\"traverse.kind\" = \"dual\""), "{plan}");
        if plan.contains("dynamic") {
            assert!(
                shipped.contains("\"traverse.update\" = [\"rebuild\", \"refit\"]"),
                "{plan}"
            );
        }
        if plan.contains("wgpu") {
            assert!(shipped.contains("backends = [\"wgpu\"]"), "{plan}");
        }
        let o = crsh(
            &dir,
            &["ablate", "--plan", path.to_str().unwrap(), "--dry-run"],
        );
        assert_ok(&o);
        let out = text(&o.stdout);
        assert!(out.contains(&format!("{cells} cells")), "{plan}: {out}");
    }
}

/// The shipped anchors plan validates, and a CI-sized version (24 pixels, two built-in
/// scenes, one run per cell) runs: with the `embree` feature every cell traces, agrees with
/// the CWBVH, and the report opens with the table against the fastest anchor, in which every
/// group's fastest Embree cell is 1 and no Embree cell is above it; without the feature the
/// Embree cells fail naming the feature, the others run, and there is no such table.
#[test]
fn anchors_plan_puts_every_cell_against_the_fastest_embree() {
    let dir = scratch("anchors");
    let path = repo_root().join("plans/anchors.toml");
    let o = crsh(
        &dir,
        &["ablate", "--plan", path.to_str().unwrap(), "--dry-run"],
    );
    assert_ok(&o);
    let shipped = std::fs::read_to_string(&path).unwrap();
    for needle in [
        "width = 256",
        "repeat = 3",
        "warmup = 1",
        "\"raygen.order\" = [\"generation\", \"shuffled\"]",
        "pipeline = \"embree_sorted\"",
        "\"raygen.ao_length\" = 0.05",
        "\"raygen.shadow_samples\" = 16",
    ] {
        assert!(shipped.contains(needle), "anchors.toml changed: {needle}");
    }
    let small = with_scenes(&shipped, &["office-boxes", "cornell-mirrors"])
        .replace("width = 256", "width = 24")
        .replace("repeat = 3", "repeat = 1")
        .replace("warmup = 1", "warmup = 0");
    let plan = dir.join("anchors-small.toml");
    std::fs::write(&plan, small).unwrap();
    let o = crsh(
        &dir,
        &["ablate", "--plan", plan.to_str().unwrap(), "--out", "out"],
    );
    let v = read_json(&dir.join("out/results.json"));
    let cs = cells(&v);
    // 2 scenes × 4 ray settings × 7 pipelines × 2 orders.
    assert_eq!(cs.len(), 112);
    let stdout = String::from_utf8_lossy(&o.stdout).to_string();
    let report = std::fs::read_to_string(dir.join("out/report.html")).unwrap();
    let embree = |c: &Value| c["pipeline"].as_str().unwrap().starts_with("embree");
    if !cfg!(feature = "embree") {
        for c in cs {
            if embree(c) {
                assert_eq!(c["status"], "failed", "{c:#}");
                assert!(c["reason"].as_str().unwrap().contains("embree"), "{c:#}");
            } else {
                assert_eq!(c["status"], "ok", "{c:#}");
            }
        }
        assert!(!stdout.contains("Against the fastest anchor"), "{stdout}");
        return;
    }
    assert_ok(&o);
    for c in cs {
        assert_eq!(c["status"], "ok", "{c:#}");
        let agreement = c["measures"]["accuracy"]["hit_agreement"].as_f64().unwrap();
        assert!(agreement >= 0.9999, "{agreement}: {c:#}");
    }
    assert!(stdout.contains("Against the fastest anchor"), "{stdout}");
    assert!(report.contains("Against the fastest anchor"));
    // Embree's tests are unknown: "—" in the headline, never a count or a ratio from 0.
    for line in stdout.lines() {
        if line.trim_start().starts_with("fastest embree") {
            assert!(line.contains("— tests/ray"), "{line}");
        }
        if line.contains("best vs best") && line.contains("embree") {
            assert!(line.contains(", tests —"), "{line}");
        }
    }
    assert!(
        stdout
            .lines()
            .any(|l| l.trim_start().starts_with("fastest embree")),
        "{stdout}"
    );
    // Rows: | scene | rays | order | kind | cell | Mrays/s | × anchor | agreement |.
    let mut groups: std::collections::BTreeMap<String, Vec<(String, f64)>> = Default::default();
    for line in stdout
        .lines()
        .filter(|l| l.starts_with("| ") && !l.starts_with("| scene"))
    {
        let f: Vec<&str> = line.split('|').map(str::trim).collect();
        if f.len() < 9 {
            continue;
        }
        let key = format!("{} {} {} {}", f[1], f[2], f[3], f[4]);
        groups
            .entry(key)
            .or_default()
            .push((f[5].to_string(), f[7].parse().unwrap()));
    }
    // Every ray setting traces shadow or AO rays on both scenes in both orders.
    assert!(groups.len() >= 2 * 4 * 2, "{groups:?}");
    for (key, rows) in &groups {
        assert_eq!(rows.len(), 7, "{key}: {rows:?}");
        let anchors: Vec<f64> = rows
            .iter()
            .filter(|(cell, _)| cell.starts_with("embree"))
            .map(|r| r.1)
            .collect();
        assert_eq!(anchors.len(), 3, "{key}");
        assert!(anchors.contains(&1.0), "{key}: {rows:?}");
        assert!(anchors.iter().all(|&r| r <= 1.0), "{key}: {rows:?}");
    }
}
