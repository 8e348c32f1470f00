//! `crsh ablate --merge DIR... --out DIR`: the shards of one ablation (`--shard K/N`, each in
//! its own directory, possibly from different machines) into one results document, checked to
//! belong together.
//!
//! Shards belong together when they were written by the same crsh version at the same git
//! revision, from the same plan (as parsed, every default and command-line override applied),
//! with the same expansion (the digest of every cell's resolved pipeline: a binary with other
//! registered variants expands differently), and the same shard count; every shard `1..=N`
//! must be there exactly once, and together they must hold every cell exactly once. Anything
//! else is refused, naming the directories that differ.

use std::path::{Path, PathBuf};

use super::results::{Expansion, Results, ShardRecord};
use crate::error::{CliError, CliResult};

/// Reads `DIR/results.json` (a usage error when it is missing or not a results document).
pub fn read_results(dir: &Path) -> CliResult<Results> {
    let path = dir.join("results.json");
    let text = std::fs::read_to_string(&path)
        .map_err(|e| CliError::usage(format!("{}: {e}", path.display())))?;
    serde_json::from_str(&text).map_err(|e| {
        CliError::usage(format!(
            "{}: not a crsh ablate results.json: {e}",
            path.display()
        ))
    })
}

/// The shards in `dirs` merged into one document (cells in plan order), or why they do not
/// belong together.
pub fn merge(dirs: &[PathBuf]) -> CliResult<Results> {
    if dirs.is_empty() {
        return Err(CliError::usage("--merge: name the shard directories"));
    }
    let mut shards: Vec<(PathBuf, Results)> = Vec::new();
    for d in dirs {
        let r = read_results(d)?;
        if r.shard.is_none() {
            return Err(CliError::usage(format!(
                "--merge {}: not a shard (its results.json was not written by `crsh ablate --shard K/N`)",
                d.display()
            )));
        }
        shards.push((d.clone(), r));
    }
    let (first_dir, first) = &shards[0];
    let plan_json = |r: &Results| serde_json::to_string(&r.plan).unwrap_or_default();
    let first_plan = plan_json(first);
    let first_count = first.shard.map_or(0, |s| s.count);
    for (dir, r) in &shards[1..] {
        let differ = |what: &str, a: &str, b: &str| {
            CliError::usage(format!(
                "--merge: {} and {} are shards of different {what} ({a} vs {b}); merge only the shards of one run",
                first_dir.display(),
                dir.display()
            ))
        };
        if r.version != first.version {
            return Err(differ("crsh versions", &first.version, &r.version));
        }
        if r.machine.git_revision != first.machine.git_revision {
            return Err(differ(
                "revisions",
                &first.machine.git_revision,
                &r.machine.git_revision,
            ));
        }
        if plan_json(r) != first_plan {
            return Err(differ(
                "plans",
                &first.plan_source,
                &format!("{} (the plans or their overrides differ)", r.plan_source),
            ));
        }
        if r.expansion != first.expansion {
            return Err(differ(
                "expansions",
                &describe(&first.expansion),
                &describe(&r.expansion),
            ));
        }
        let count = r.shard.map_or(0, |s| s.count);
        if count != first_count {
            return Err(differ(
                "shard counts",
                &first_count.to_string(),
                &count.to_string(),
            ));
        }
    }
    let mut seen: Vec<Option<&PathBuf>> = vec![None; first_count];
    for (dir, r) in &shards {
        let s = r.shard.expect("checked above");
        if let Some(other) = seen[s.index - 1] {
            return Err(CliError::usage(format!(
                "--merge: shard {s} is given twice ({} and {})",
                other.display(),
                dir.display()
            )));
        }
        seen[s.index - 1] = Some(dir);
        if let Some(c) = r.cells.iter().find(|c| !s.holds(c.index)) {
            return Err(CliError::usage(format!(
                "--merge {}: cell {} does not belong to shard {s}",
                dir.display(),
                c.index
            )));
        }
    }
    let missing: Vec<String> = seen
        .iter()
        .enumerate()
        .filter(|(_, d)| d.is_none())
        .map(|(i, _)| format!("{}/{first_count}", i + 1))
        .collect();
    if !missing.is_empty() {
        return Err(CliError::usage(format!(
            "--merge: missing shard{} {}; run them (or name their directories) before merging",
            if missing.len() == 1 { "" } else { "s" },
            missing.join(", ")
        )));
    }
    let mut cells: Vec<_> = shards.iter().flat_map(|(_, r)| r.cells.clone()).collect();
    cells.sort_by_key(|c| c.index);
    let complete =
        cells.len() == first.expansion.cells && cells.iter().enumerate().all(|(i, c)| c.index == i);
    if !complete {
        return Err(CliError::usage(format!(
            "--merge: the shards hold {} cells, not the {} cells 0..{} of the plan's expansion",
            cells.len(),
            first.expansion.cells,
            first.expansion.cells
        )));
    }
    let mut records: Vec<ShardRecord> = shards
        .iter()
        .map(|(dir, r)| ShardRecord {
            shard: r.shard.expect("checked above"),
            source: dir.display().to_string(),
            machine: r.machine.clone(),
            wall_s: r.wall_s,
            cells: r.cells.len(),
        })
        .collect();
    records.sort_by_key(|r| r.shard.index);
    Ok(Results {
        version: first.version.clone(),
        title: first.title.clone(),
        plan_source: first.plan_source.clone(),
        plan: first.plan.clone(),
        plan_text: first.plan_text.clone(),
        machine: first.machine.clone(),
        wall_s: records.iter().map(|r| r.wall_s).fold(0.0, f64::max),
        expansion: first.expansion.clone(),
        shard: None,
        merged_from: records,
        cells,
    })
}

fn describe(e: &Expansion) -> String {
    format!("{} cells, digest {}", e.cells, e.digest)
}
