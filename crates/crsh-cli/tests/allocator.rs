//! The `crsh` binary's memory policy ([`crsh_cli::allocator`]): freed memory stays with the
//! process, so a buffer allocated again after `free` faults no pages in; the user's own
//! malloc tunables win; the stats JSON says which held. Its own test binary: the policy is
//! process-wide.

mod common;

use std::process::Command;

use common::{assert_ok, scratch};
use crsh_cli::allocator::{keep_freed_memory, MallocPolicy};

/// Minor page faults of this process so far (`/proc/self/stat`, field 10).
#[cfg(target_os = "linux")]
fn minor_faults() -> u64 {
    let stat = std::fs::read_to_string("/proc/self/stat").expect("read /proc/self/stat");
    // Fields after the command name, which is in parentheses and may hold spaces.
    let rest = &stat[stat.rfind(')').expect("stat has a command") + 2..];
    rest.split(' ')
        .nth(7)
        .and_then(|f| f.parse().ok())
        .expect("minflt")
}

/// Writes every page of a fresh 48 MiB buffer (above glibc's largest mmap threshold, 32 MiB:
/// by default its own mapping, unmapped on drop) and frees it; returns the faults it took.
#[cfg(target_os = "linux")]
fn faults_of_a_big_buffer() -> u64 {
    const BYTES: usize = 48 << 20;
    let before = minor_faults();
    let mut v: Vec<u8> = Vec::with_capacity(BYTES);
    v.extend((0..BYTES).map(|i| i as u8));
    std::hint::black_box(&v);
    drop(v);
    minor_faults() - before
}

#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[test]
fn freed_memory_is_reused_without_page_faults() {
    let policy = keep_freed_memory();
    if *policy != MallocPolicy::KeptFreed {
        eprintln!("skipped: the policy is `{}`", policy.describe());
        return;
    }
    let pages = (48 << 20) / 4096;
    let first = faults_of_a_big_buffer();
    let again = faults_of_a_big_buffer();
    // The first round may fault its pages in (the heap grows); the second reuses them.
    assert!(
        again < pages / 10,
        "a freed 48 MiB buffer allocated again took {again} faults (first {first}, {pages} pages)"
    );
    assert_eq!(keep_freed_memory(), policy, "the policy is set once");
}

fn stats_allocator(env: &[(&str, &str)], test: &str) -> String {
    let dir = scratch("allocator", test);
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_crsh"));
    cmd.args([
        "render", "--width", "32", "--depth", "1", "--out", "a.png", "--stats", "s.json",
    ])
    .current_dir(&dir);
    for v in crsh_cli::allocator::USER_TUNABLES {
        cmd.env_remove(v);
    }
    cmd.envs(env.iter().copied());
    let o = cmd.output().expect("run crsh");
    assert_ok(&o);
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("s.json")).unwrap()).unwrap();
    s["allocator"]
        .as_str()
        .expect("the stats name the allocator")
        .to_string()
}

#[test]
fn stats_say_whether_freed_memory_is_kept() {
    let kept = stats_allocator(&[], "default");
    let user = stats_allocator(&[("MALLOC_ARENA_MAX", "2")], "user");
    if cfg!(all(target_os = "linux", target_env = "gnu")) {
        assert!(
            kept.starts_with("glibc malloc keeps freed memory"),
            "{kept}"
        );
        assert_eq!(
            user,
            "glibc malloc as the environment tunes it (MALLOC_ARENA_MAX is set)"
        );
    } else {
        assert_eq!(kept, "the platform's allocator, untuned");
    }
}
