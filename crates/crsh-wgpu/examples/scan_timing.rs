//! Times the device exclusive scan against its CPU twin and checks that they agree.
//!
//! `cargo run -p crsh-wgpu --release --example scan_timing -- [elements] [repetitions]`
//! (defaults: 2^22 elements, 5 repetitions). Prints the adapter, the median wall time of the
//! in-place device scan (submit + wait + 4-byte total readback, no upload/download), and of
//! the CPU twin.

use std::time::{Duration, Instant};

use crsh_wgpu::{exclusive_scan_cpu, exclusive_scan_in_place, GpuBuffer, GpuContext};

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let n: usize = args
        .next()
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(1 << 22);
    let reps: usize = args
        .next()
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(5)
        .max(1);

    let ctx = GpuContext::new()?;
    println!("adapter: {}", serde_json::to_string(ctx.info())?);
    println!(
        "max storage binding: {} MiB, timestamps: {}",
        ctx.max_storage_binding_bytes() >> 20,
        ctx.has_timestamp_query()
    );

    let mut state = 0x1234_5678_u64;
    let input: Vec<u32> = (0..n)
        .map(|_| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 32) as u32
        })
        .collect();
    let (want, want_total) = exclusive_scan_cpu(&input);

    // Warm-up: compiles the kernel.
    let warm = GpuBuffer::from_slice(&ctx, "warm-up", &input[..input.len().min(1024)])?;
    exclusive_scan_in_place(&ctx, &warm)?;

    let mut gpu_times = Vec::with_capacity(reps);
    let mut cpu_times = Vec::with_capacity(reps);
    for _ in 0..reps {
        let buf = GpuBuffer::from_slice(&ctx, "timed", &input)?;
        ctx.wait()?;
        let t = Instant::now();
        let total = exclusive_scan_in_place(&ctx, &buf)?;
        gpu_times.push(t.elapsed());
        if total != want_total || buf.to_vec(&ctx)? != want {
            return Err("device scan disagrees with its CPU twin".into());
        }
        let t = Instant::now();
        let (out, total) = exclusive_scan_cpu(&input);
        cpu_times.push(t.elapsed());
        assert_eq!((out.len(), total), (n, want_total));
    }
    let g = median(gpu_times);
    let c = median(cpu_times);
    let rate = |d: Duration| n as f64 / d.as_secs_f64() / 1e6;
    println!(
        "n = {n}: device {:.3} ms ({:.0} M elem/s), cpu twin {:.3} ms ({:.0} M elem/s), results equal",
        g.as_secs_f64() * 1e3,
        rate(g),
        c.as_secs_f64() * 1e3,
        rate(c)
    );
    Ok(())
}
