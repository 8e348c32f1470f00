//! End-to-end tests of `crsh grid-build` (seed 002 §5.1, table 1): the table's rows and
//! columns, the JSON file against the printed table, the paper's figures, and bad command lines
//! exiting 2. No timing is asserted, only structure.

mod common;
use common::{assert_ok, crsh, text};

/// The cells of the Markdown rows of the first table whose header starts with `header`.
fn table_rows(out: &str, header: &str) -> Vec<Vec<String>> {
    let mut lines = out.lines().skip_while(|l| !l.starts_with(header));
    assert!(lines.next().is_some(), "no table `{header}` in:\n{out}");
    lines
        .skip(1) // the alignment row
        .take_while(|l| l.starts_with('|'))
        .map(|l| {
            l.trim_matches('|')
                .split('|')
                .map(|c| c.trim().to_string())
                .collect()
        })
        .collect()
}

#[test]
fn prints_table_1_with_the_paper_and_the_per_pass_split() {
    let dir = common::scratch("grid-build", "table");
    let o = crsh(
        &dir,
        &[
            "grid-build",
            "--sizes",
            "5000,1234",
            "--repeats",
            "2",
            "--warmup",
            "0",
            "--threads",
            "2",
            "--json",
            "g.json",
        ],
    );
    assert_ok(&o);
    let out = text(&o.stdout);
    let rows = table_rows(&out, "| #tri | cells | pairs |");
    assert_eq!(rows.len(), 2, "{out}");
    // A wgpu column when the machine has an adapter (lavapipe in CI), none otherwise.
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("g.json")).unwrap()).unwrap();
    let gpu = !json["rows"][0]["wgpu_ms"].is_null();
    let width = if gpu { 8 } else { 7 };
    assert_eq!(rows[0].len(), width, "{out}");
    assert_eq!(rows[0][0], "5000");
    // The paper's figures for 5K (table 1), none for a size it lacks: the last two columns.
    assert_eq!(
        (rows[0][width - 2].as_str(), rows[0][width - 1].as_str()),
        ("0.8", "1.7")
    );
    assert_eq!(
        (rows[1][width - 2].as_str(), rows[1][width - 1].as_str()),
        ("-", "-")
    );
    let split = table_rows(&out, "| #tri | threads | setup |");
    assert_eq!(split.len(), 4, "serial and parallel per size: {out}");
    assert_eq!(
        split.iter().map(|r| r[1].as_str()).collect::<Vec<_>>(),
        ["1", "2", "1", "2"]
    );
    // The JSON has the same grids; serial and parallel builds give the same grid.
    let jrows = json["rows"].as_array().unwrap();
    assert_eq!(jrows.len(), 2);
    for (r, j) in rows.iter().zip(jrows) {
        assert_eq!(r[0], j["triangles"].to_string());
        assert_eq!(r[1], j["cells"].to_string());
        assert_eq!(r[2], j["pairs"].to_string());
        for pool in ["serial", "parallel"] {
            assert_eq!(j[pool]["cells"], j["cells"], "{pool}");
            assert_eq!(j[pool]["pairs"], j["pairs"], "{pool}");
            assert_eq!(j[pool]["repeats"], 2);
            let passes = j[pool]["median"].as_object().unwrap();
            assert_eq!(passes.len(), 6, "{pool}: {passes:?}");
        }
        assert_eq!(j["serial"]["threads"], 1);
        assert_eq!(j["parallel"]["threads"], 2);
        // eq. 1: about k·P cells (the default k = 5); every triangle in at least one cell.
        let (n, cells, pairs) = (
            j["triangles"].as_u64().unwrap(),
            j["cells"].as_u64().unwrap(),
            j["pairs"].as_u64().unwrap(),
        );
        assert!(cells >= 2 * n && cells <= 10 * n, "{cells} cells for {n}");
        assert!(pairs >= n, "{pairs} pairs for {n}");
        // The wgpu rebuild time where there is an adapter, else nothing.
        assert_eq!(j["wgpu_ms"].is_null(), !gpu);
        assert!(j["wgpu_ms"].is_null() || j["wgpu_ms"].as_f64().unwrap() > 0.0);
    }
    assert_eq!(jrows[0]["paper_cpu_ms"], 0.8);
    assert!(jrows[1]["paper_gpu_ms"].is_null());
}

#[test]
fn bad_command_lines_exit_2() {
    let dir = common::scratch("grid-build", "bad");
    for (args, needle) in [
        (&["grid-build", "--sizes", "0"][..], "outside 1..=2000000"),
        (&["grid-build", "--sizes", "5000,2000001"], "2000001"),
        (&["grid-build", "--sizes", "lots"], "--sizes"),
        (&["grid-build", "--repeats", "0"], "--repeats"),
        (&["grid-build", "--repeats", "101"], "--repeats"),
        (&["grid-build", "--threads", "0"], "--threads"),
        (
            &[
                "grid-build",
                "--sizes",
                "100",
                "--json",
                "no/such/dir/x.json",
            ],
            "does not exist",
        ),
    ] {
        let o = crsh(&dir, args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", text(&o.stderr));
        let err = text(&o.stderr);
        assert!(err.starts_with("error:"), "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: {err}");
    }
}
