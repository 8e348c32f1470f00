//! End-to-end tests of `crsh tables`: the thesis's tables on the built-in scenes, CSV that
//! accounts for every test, exact hits for every pipeline, and clear errors.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

mod common;
use common::{crsh, text};

fn scratch(test: &str) -> PathBuf {
    common::scratch("tables", test)
}

/// The rows of a CSV file as maps from header to value (no quoting in our CSVs).
fn csv(path: &Path) -> Vec<BTreeMap<String, String>> {
    let t = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = t.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    lines
        .map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            assert_eq!(cells.len(), header.len(), "{}: {l}", path.display());
            header
                .iter()
                .zip(cells)
                .map(|(h, c)| (h.to_string(), c.to_string()))
                .collect()
        })
        .collect()
}

fn num(row: &BTreeMap<String, String>, key: &str) -> u64 {
    row[key]
        .parse()
        .unwrap_or_else(|_| panic!("{key} = {:?} is not a count", row[key]))
}

#[test]
fn thesis_tables_on_the_builtin_scenes() {
    let dir = scratch("builtin");
    let out = crsh(
        &dir,
        &[
            "tables",
            "--scene",
            "cornell-mirrors,office-boxes",
            "--pipelines",
            "crsh,rah,bvh",
            "--subdivision",
            "4,8",
            "--depth",
            "1,2",
            "--width",
            "24",
            "--bounces",
            "2",
            "--reference",
            "brute",
            "--repeat",
            "2",
            "--csv",
            ".",
            "--out",
            "tables.md",
        ],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let md = text(&out.stdout);
    assert_eq!(md, std::fs::read_to_string(dir.join("tables.md")).unwrap());
    for needle in [
        "## Hierarchy traversal results",
        "### CORNELL-MIRRORS — subdivision 8 depth 2",
        "| CORNELL-MIRRORS | MESHES | LEVEL 2 | LEVEL 1 | FINAL |",
        "| # SH INTERSECTIONS |",
        "| # RE HITS |",
        "## Total intersection tests",
        "| brute force |",
        "Total tests crsh / rah:",
        "## Configuration comparison",
        "## Throughput on the same rays",
        "## Rendering time (tables 4.25-4.27), subdivision 4 depth 1",
        "| FINAL TESTS |",
        "| HASHING |",
    ] {
        assert!(md.contains(needle), "missing {needle:?} in\n{md}");
    }

    let totals = csv(&dir.join("totals.csv"));
    let levels = csv(&dir.join("levels.csv"));
    let times = csv(&dir.join("times.csv"));
    // 2 scenes × (2 hierarchy pipelines × 4 configurations + bvh).
    assert_eq!(totals.len(), 2 * (2 * 4 + 1));
    for t in &totals {
        let who = format!(
            "{} {} {}×{}",
            t["scene"], t["pipeline"], t["subdivision"], t["depth"]
        );
        assert_eq!(t["hit_agreement"], "1.000000000", "{who}");
        let total = num(t, "total_tests");
        assert_eq!(total, num(t, "bounds_tests") + num(t, "ray_triangle_tests"));
        assert!(total < num(t, "brute_force_tests"), "{who}");
        // Mrays/s is the traced (secondary) rays over their tracing time.
        let (rays, ms, m) = (
            num(t, "traced_rays") as f64,
            t["trace_ms"].parse::<f64>().unwrap(),
            t["mrays_per_s"].parse::<f64>().unwrap(),
        );
        if ms > 0.001 {
            // `trace_ms` is printed to 0.001 ms, `mrays_per_s` to 1e-4.
            let (lo, hi) = (rays / (ms + 0.0005) * 1e-3, rays / (ms - 0.0005) * 1e-3);
            assert!(
                m >= lo - 1e-4 && m <= hi + 1e-4,
                "{who}: {m} Mrays/s, want {lo}..{hi}"
            );
        }
        if t["pipeline"] == "bvh" {
            assert_eq!(t["subdivision"], "", "{who}");
            continue;
        }
        // Every test of a hierarchy pipeline is in exactly one level row (mesh culling,
        // node levels, final tests), and the final tests are the ray-triangle tests.
        let rows: Vec<_> = levels
            .iter()
            .filter(|l| {
                ["scene", "pipeline", "subdivision", "depth"]
                    .iter()
                    .all(|k| l[*k] == t[*k])
            })
            .collect();
        let sum: u64 = rows.iter().map(|l| num(l, "tests")).sum();
        assert_eq!(sum, total, "{who}: level rows");
        let finals: u64 = rows
            .iter()
            .filter(|l| l["level_name"] == "final")
            .map(|l| num(l, "tests"))
            .sum();
        assert_eq!(finals, num(t, "ray_triangle_tests"), "{who}");
        let depth: u64 = t["depth"].parse().unwrap();
        for l in &rows {
            assert_eq!(num(l, "tests"), num(l, "hits") + num(l, "misses"), "{who}");
            if let Ok(level) = l["level"].parse::<u64>() {
                assert!(level <= depth, "{who}: level {level} above depth {depth}");
            } else {
                assert_eq!(l["level_name"], "meshes", "{who}");
                assert_eq!(t["pipeline"], "crsh", "{who}: rah does not cull meshes");
            }
        }
    }
    // The same rays for every pipeline of a scene.
    for scene in ["cornell-mirrors", "office-boxes"] {
        let rays: Vec<&String> = totals
            .iter()
            .filter(|t| t["scene"] == scene)
            .map(|t| &t["traced_rays"])
            .collect();
        assert!(rays.windows(2).all(|w| w[0] == w[1]), "{scene}: {rays:?}");
    }
    assert!(times
        .iter()
        .any(|r| r["pipeline"] == "crsh" && r["stage"] == "final_tests"));
    assert!(times
        .iter()
        .any(|r| r["pipeline"] == "bvh" && r["stage"] == "intersection"));
}

#[test]
fn bad_tables_arguments_are_clear_errors() {
    let dir = scratch("errors");
    for (args, code, needle) in [
        (
            &["tables", "--scene", "cornell-mirrors", "--subdivision", "1"][..],
            2,
            "subdivision",
        ),
        (
            &[
                "tables",
                "--scene",
                "cornell-mirrors",
                "--pipelines",
                "nope",
            ],
            2,
            "unknown pipeline",
        ),
        (
            &["tables", "--scene", "no-such-scene"],
            1,
            "cannot load scene",
        ),
        (
            &[
                "tables",
                "--scene",
                "cornell-mirrors",
                "--csv",
                "missing-dir",
            ],
            2,
            "--csv",
        ),
        (
            &[
                "tables",
                "--scene",
                "cornell-mirrors",
                "--reference",
                "nope",
            ],
            2,
            "--reference",
        ),
    ] {
        let out = crsh(&dir, args);
        let err = text(&out.stderr);
        assert_eq!(out.status.code(), Some(code), "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
}
