//! End-to-end tests of `crsh stress`: the three output files agree with each other and with
//! the printed table, and bad command lines exit 2.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

mod common;
use common::{assert_ok, crsh, text};

fn scratch(test: &str) -> PathBuf {
    common::scratch("stress", test)
}

/// The rows of `stress.csv` as maps from header to value (the cases chosen have no errors, so
/// no quoted fields).
fn csv(path: &Path) -> Vec<BTreeMap<String, String>> {
    let t = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = t.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    lines
        .map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            assert_eq!(cells.len(), header.len(), "{l}");
            header
                .iter()
                .zip(cells)
                .map(|(h, c)| (h.to_string(), c.to_string()))
                .collect()
        })
        .collect()
}

#[test]
fn writes_consistent_csv_markdown_and_json() {
    let dir = scratch("files");
    let o = crsh(
        &dir,
        &[
            "stress",
            "--cases",
            "plane-5deg",
            "--pipelines",
            "brute,crsh",
            "--out",
            "out",
            "--threads",
            "2",
        ],
    );
    assert_ok(&o);
    let o2 = crsh(
        &dir,
        &[
            "stress",
            "--cases",
            "closed/cube",
            "--pipelines",
            "bvh,rah",
            "--out",
            "out2",
            "--threads",
            "1",
        ],
    );
    assert_ok(&o2);
    for (out, stdout, case, pipelines, offset_is_dash) in [
        (
            "out",
            text(&o.stdout),
            "acne/plane-5deg",
            ["brute", "crsh"],
            false,
        ),
        (
            "out2",
            text(&o2.stdout),
            "closed/cube",
            ["bvh", "rah"],
            true,
        ),
    ] {
        let rows = csv(&dir.join(out).join("stress.csv"));
        let json: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join(out).join("stress.json")).unwrap(),
        )
        .unwrap();
        let md = std::fs::read_to_string(dir.join(out).join("stress.md")).unwrap();
        let jrows = json["rows"].as_array().unwrap();
        // One row per pipeline (one test and offset per pipeline in this build, or more).
        assert!(rows.len() >= 2 && rows.len() == jrows.len(), "{out}");
        assert_eq!(json["cases"].as_array().unwrap().len(), 1);
        for (r, j) in rows.iter().zip(jrows) {
            assert_eq!(r["case"], case);
            assert_eq!(j["case"], case);
            assert_eq!(r["pipeline"], j["variant"]["pipeline"].as_str().unwrap());
            assert!(pipelines.contains(&r["pipeline"].as_str()));
            assert_eq!(r["offset"] == "-", offset_is_dash, "{r:?}");
            let o = &j["outcome"];
            for key in [
                "rays",
                "false_misses",
                "false_hits",
                "wrong_nearest",
                "self_intersections",
                "escapes",
                "bounds_tests",
                "triangle_tests",
            ] {
                assert_eq!(r[key], o[key].to_string(), "{key}");
            }
            let tests: f64 = r["bounds_tests"].parse::<f64>().unwrap()
                + r["triangle_tests"].parse::<f64>().unwrap();
            let per_ray: f64 = r["tests_per_ray"].parse().unwrap();
            assert!(
                tests > 0.0 && (per_ray - tests / r["rays"].parse::<f64>().unwrap()).abs() < 1e-3
            );
            let rays: f64 = r["rays"].parse().unwrap();
            assert!(rays > 0.0);
            let self_int: f64 = r["self_intersections"].parse().unwrap();
            let rate: f64 = r["self_intersection_rate"].parse().unwrap();
            assert!((rate - self_int / rays).abs() < 1e-12);
            assert_eq!(r["panicked"], "false");
            assert_eq!(r["error"], "");
            // The Markdown table has the same row, with the same counts.
            let line = md
                .lines()
                .find(|l| l.starts_with(&format!("| {case} | {} |", r["pipeline"])))
                .expect("row in stress.md");
            assert!(line.contains(&format!("| {} |", r["rays"])), "{line}");
            assert!(line.contains(&format!("| {} |", r["escapes"])), "{line}");
        }
        // The printed table is the Markdown file (plus the `wrote` line).
        assert!(stdout.starts_with(&md), "stdout differs from stress.md");
        assert!(md.contains("## Summary per pipeline × test × offset"));
        // The summary totals one line per configuration.
        assert_eq!(json["summary"].as_array().unwrap().len(), rows.len());
    }
    // Counts do not depend on the thread count: bvh and rah agree with each other (exact),
    // and a rerun with other threads gives the same JSON rows bar the times.
    let o3 = crsh(
        &dir,
        &[
            "stress",
            "--cases",
            "closed/cube",
            "--pipelines",
            "bvh,rah",
            "--out",
            "out3",
            "--threads",
            "2",
        ],
    );
    assert_ok(&o3);
    let strip = |p: &str| {
        let v: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join(p).join("stress.json")).unwrap(),
        )
        .unwrap();
        v["rows"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| {
                let mut r = r.clone();
                r["outcome"]["time_ms"] = serde_json::Value::Null;
                r
            })
            .collect::<Vec<_>>()
    };
    assert_eq!(strip("out2"), strip("out3"));
}

/// Seed 002's known worst case for a uniform grid: a detailed object in a huge sparse scene.
/// The counts are deterministic, so the grid's penalty against the BVH is a fact to check.
#[test]
fn teapot_in_a_stadium_shows_tests_per_ray_per_pipeline() {
    let dir = scratch("stadium");
    let o = crsh(
        &dir,
        &[
            "stress",
            "--cases",
            "stadium/teapot",
            "--pipelines",
            "grid,bvh,crsh",
            "--tests",
            "mt",
            "--offsets",
            "normal",
            "--out",
            "out",
        ],
    );
    assert_ok(&o);
    let rows = csv(&dir.join("out/stress.csv"));
    assert_eq!(rows.len(), 3);
    let per_ray = |p: &str| -> f64 {
        let r = rows.iter().find(|r| r["pipeline"] == p).expect(p);
        assert_eq!(r["error"], "", "{p}");
        r["tests_per_ray"].parse().unwrap()
    };
    let (grid, bvh, crsh) = (per_ray("grid"), per_ray("bvh"), per_ray("crsh"));
    assert!(grid > 0.0 && bvh > 0.0 && crsh > 0.0);
    // The whole teapot falls into a few cells, each tested triangle by triangle.
    assert!(grid > 10.0 * bvh, "grid {grid} bvh {bvh}");
    let md = text(&o.stdout);
    assert!(md.contains("| tests/ray |"), "{md}");
    assert!(md.contains("| stadium/teapot | grid |"), "{md}");
}

#[test]
fn bad_command_lines_exit_2() {
    let dir = scratch("bad");
    for (args, needle) in [
        (
            &["stress", "--pipelines", "octree"][..],
            "unknown pipeline `octree`",
        ),
        (&["stress", "--cases", "no-such-case"], "no case matches"),
        (&["stress", "--tests", "bogus"], "--tests"),
        (&["stress", "--offsets", "bogus"], "--offsets"),
        (&["stress", "--threads", "0"], ""),
        (&["stress", "--frobnicate"], ""),
    ] {
        let o = crsh(&dir, args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", text(&o.stderr));
        let err = text(&o.stderr);
        assert!(err.starts_with("error:"), "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: {err}");
    }
    // --out naming an existing file is a usage error too.
    std::fs::write(dir.join("file"), "x").unwrap();
    let o = crsh(&dir, &["stress", "--cases", "invalid/one", "--out", "file"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
}

#[test]
fn invalid_cases_report_errors_or_misses_never_a_panic() {
    let dir = scratch("invalid");
    let o = crsh(&dir, &["stress", "--cases", "invalid/", "--out", "out"]);
    assert_ok(&o);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("out/stress.json")).unwrap())
            .unwrap();
    for r in json["rows"].as_array().unwrap() {
        let o = &r["outcome"];
        assert_eq!(o["panicked"], false, "{r}");
        assert_eq!(o["false_hits"], 0, "{r}");
        if r["case"].as_str().unwrap().ends_with("empty-scene") {
            assert!(o["error"].as_str().unwrap().contains("empty scene"), "{r}");
        }
    }
}
