//! The program's memory policy: glibc's `malloc` told to keep what the process frees.
//!
//! A frame allocates and frees buffers of megabytes per stage and per batch (rays, keys, sort
//! records, hits). glibc serves a block above its mmap threshold (128 KiB at first, raised to
//! at most 32 MiB as blocks are freed) with a fresh mapping and unmaps it on `free`, and it
//! returns the top of the heap to the kernel past the trim threshold. Every such buffer then
//! costs one page fault per 4 KiB written, on each batch again: on this project's 2-core
//! machine a 1024² frame of cornell-mirror took about 80,000 faults against its 270 MB peak
//! (66,000 pages). With freed memory kept it took about 66,000, its sorting stage about half
//! the time (6-10 against 12-14 ms) and the whole process 0.40-0.44 against 0.46-0.51 s of
//! wall time, in alternating runs (README, "Fixed stages and memory").
//!
//! [`keep_freed_memory`] sets, with `mallopt`:
//! - `M_MMAP_MAX = 0`: every block comes from a heap, none from its own mapping;
//! - `M_TRIM_THRESHOLD` to its largest value: freed memory stays with the process;
//! - `M_TOP_PAD = 64 MiB`: the heap grows in large steps.
//!
//! Freed blocks are reused, so the peak resident memory grows only by what the heaps cannot
//! reuse across threads (Sponza 1024², `dual_inline`: 377 to 425 MB), but the process no longer
//! gives memory back before it exits. [`main_with`](crate::main_with) calls
//! it first thing, unless the environment sets glibc's malloc tunables itself
//! ([`USER_TUNABLES`]); elsewhere than on glibc it does nothing.

use std::sync::OnceLock;

/// Environment variables by which a user tunes glibc's `malloc`: with any of them set,
/// [`keep_freed_memory`] leaves the allocator as the user set it.
pub const USER_TUNABLES: [&str; 6] = [
    "GLIBC_TUNABLES",
    "MALLOC_ARENA_MAX",
    "MALLOC_MMAP_MAX_",
    "MALLOC_MMAP_THRESHOLD_",
    "MALLOC_TOP_PAD_",
    "MALLOC_TRIM_THRESHOLD_",
];

/// `M_TOP_PAD`: bytes added to every extension of the heap.
pub const TOP_PAD: i32 = 64 << 20;

/// What [`keep_freed_memory`] did.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum MallocPolicy {
    /// glibc keeps freed memory (every `mallopt` call succeeded).
    KeptFreed,
    /// The environment tunes glibc's `malloc` (the first variable of [`USER_TUNABLES`] set);
    /// left as it is.
    UserTunables(&'static str),
    /// glibc refused a setting (`mallopt` returned 0; its parameter number); the ones before
    /// it hold.
    Refused(i32),
    /// The C library is not glibc: nothing set.
    NotGlibc,
}

impl MallocPolicy {
    /// One line for reports (the stats JSON's `allocator`).
    pub fn describe(&self) -> String {
        match self {
            MallocPolicy::KeptFreed => format!(
                "glibc malloc keeps freed memory (mmap_max 0, trim_threshold {}, top_pad {})",
                i32::MAX,
                TOP_PAD
            ),
            MallocPolicy::UserTunables(var) => {
                format!("glibc malloc as the environment tunes it ({var} is set)")
            }
            MallocPolicy::Refused(p) => format!("glibc malloc refused mallopt parameter {p}"),
            MallocPolicy::NotGlibc => "the platform's allocator, untuned".into(),
        }
    }
}

static POLICY: OnceLock<MallocPolicy> = OnceLock::new();

/// Tells glibc's `malloc` to keep freed memory for reuse (see the module doc), once per
/// process; later calls return the first call's outcome. Call it before other threads start
/// allocating.
pub fn keep_freed_memory() -> &'static MallocPolicy {
    POLICY.get_or_init(|| {
        let set = |k: &str| std::env::var_os(k).is_some_and(|v| !v.is_empty());
        match USER_TUNABLES.iter().find(|k| set(k)) {
            Some(var) => MallocPolicy::UserTunables(var),
            None => glibc::keep_freed(),
        }
    })
}

/// The policy [`keep_freed_memory`] applied, `None` before it is called (a program that runs
/// [`crate::run`] without [`crate::main_with`]).
pub fn policy() -> Option<&'static MallocPolicy> {
    POLICY.get()
}

/// The [`policy`]'s [`MallocPolicy::describe`] line, as the reports record it.
pub fn description() -> Option<String> {
    policy().map(MallocPolicy::describe)
}

#[cfg(all(target_os = "linux", target_env = "gnu"))]
mod glibc {
    use std::ffi::c_int;

    use super::{MallocPolicy, TOP_PAD};

    extern "C" {
        /// glibc's `int mallopt(int param, int value)` (`malloc.h`): 1 on success, 0 on error.
        fn mallopt(param: c_int, value: c_int) -> c_int;
    }

    /// `malloc.h`'s parameter numbers.
    const M_TRIM_THRESHOLD: c_int = -1;
    const M_TOP_PAD: c_int = -2;
    const M_MMAP_MAX: c_int = -4;

    pub(super) fn keep_freed() -> MallocPolicy {
        for (param, value) in [
            (M_MMAP_MAX, 0),
            (M_TRIM_THRESHOLD, c_int::MAX),
            (M_TOP_PAD, TOP_PAD),
        ] {
            // SAFETY: `mallopt` takes two integers and changes only glibc's allocator
            // parameters, under the allocator's own lock.
            if unsafe { mallopt(param, value) } == 0 {
                return MallocPolicy::Refused(param);
            }
        }
        MallocPolicy::KeptFreed
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
mod glibc {
    use super::MallocPolicy;

    pub(super) fn keep_freed() -> MallocPolicy {
        MallocPolicy::NotGlibc
    }
}
