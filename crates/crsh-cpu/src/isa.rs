//! The instruction set the CPU backend's hot loops run in, for the stats (`setup.isa`).
//!
//! The loops (node tests, triangle tests, hashing, sorting) are plain Rust plus SSE2
//! intrinsics, so they run in whatever the build targets: x86-64's baseline (SSE2) by
//! default, more under `RUSTFLAGS="-C target-cpu=native"`. There is no runtime dispatch yet,
//! and it matters: on an AVX-512 Xeon a native build traces Sponza's shadow rays 20-31 %
//! faster through `bvh` and obvhs alike (`docs/results/anchors.md`), so the stats say which
//! level ran. Levels are the x86-64 psABI's microarchitecture levels (`x86-64-v1` … `v4`).

/// The level the build targets (what the hot loops run in): e.g. `x86-64-v1`, or
/// `aarch64` off x86-64.
pub fn built() -> &'static str {
    #[cfg(target_arch = "x86_64")]
    {
        if cfg!(all(
            target_feature = "avx512f",
            target_feature = "avx512bw",
            target_feature = "avx512cd",
            target_feature = "avx512dq",
            target_feature = "avx512vl"
        )) {
            "x86-64-v4"
        } else if cfg!(all(
            target_feature = "avx2",
            target_feature = "fma",
            target_feature = "bmi2"
        )) {
            "x86-64-v3"
        } else if cfg!(all(target_feature = "sse4.2", target_feature = "popcnt")) {
            "x86-64-v2"
        } else {
            "x86-64-v1"
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        std::env::consts::ARCH
    }
}

/// The highest level this CPU runs (detected at run time): what a native build would target.
pub fn cpu() -> &'static str {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::is_x86_feature_detected as has;
        if has!("avx512f")
            && has!("avx512bw")
            && has!("avx512cd")
            && has!("avx512dq")
            && has!("avx512vl")
        {
            "x86-64-v4"
        } else if has!("avx2") && has!("fma") && has!("bmi2") {
            "x86-64-v3"
        } else if has!("sse4.2") && has!("popcnt") {
            "x86-64-v2"
        } else {
            "x86-64-v1"
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        std::env::consts::ARCH
    }
}

/// `setup.isa` of the stats: the level that ran and, where the CPU offers more, that too
/// (e.g. `x86-64-v1 (CPU: x86-64-v4)`).
pub fn description() -> String {
    let (b, c) = (built(), cpu());
    if b == c {
        b.to_string()
    } else {
        format!("{b} (CPU: {c})")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_build_never_targets_more_than_the_cpu_runs() {
        // A binary built for more than this CPU has would not have got this far.
        let level = |s: &str| {
            s.strip_prefix("x86-64-v")
                .and_then(|v| v.parse::<u32>().ok())
        };
        if let (Some(b), Some(c)) = (level(built()), level(cpu())) {
            assert!(b <= c, "{} / {}", built(), cpu());
        }
        let d = description();
        assert!(d.starts_with(built()), "{d}");
        assert_eq!(d.contains("CPU:"), built() != cpu(), "{d}");
    }
}
