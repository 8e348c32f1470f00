//! `crsh` traversal on the wgpu backend: top-down traversal of the sphere-cone hierarchy
//! against mesh and triangle bounding spheres with per-level stream compaction (seed 000
//! §3.2.8, eq. 3.16).
//!
//! The twin is [`crsh_cpu::traverse::crsh::Crsh`]: the same parameters (`mesh_culling`,
//! `candidate_budget_mb`), the same algorithm and the same memory bound:
//!
//! 1. `prepare`: every node becomes the CPU's `NodeBound` (margins, reach); a non-finite or
//!    negative node is an error.
//! 2. `mesh_cull` (with `mesh_culling`): every top node against every mesh sphere, once.
//! 3. Per triangle batch (sized and retried under the budget exactly as the CPU does, from
//!    the pair counts): `top_test` flags every (top node, triangle) pair of kept meshes that
//!    passes the node-sphere test, the flags are scanned into positions
//!    ([`crate::kernels::scan`]) and `top_emit` writes the survivors; then per level
//!    `descend_test` / scan / `descend_emit` over (pair, child slot). The output order is by
//!    (node, triangle) at every level, as on the CPU (a pair's place among its node's
//!    children is computed from its node's run, found by binary search), so the final pairs
//!    go to the intersector's candidate query already sorted.
//!
//! Hierarchies with [`RayHierarchy::leaf_offsets`] (seed 004's tile cones) are accepted:
//! `levels[0]` then has `leaf_offsets.len() − 1` nodes (each level above
//! `⌈below / subdivision⌉`), the offsets are checked once per traversal (downloaded: 0 first,
//! the ray count last, non-decreasing), and the pairs name `levels[0]` nodes as always. Any
//! node that keeps the hierarchy's contract is traversed correctly, apex cones included
//! (sphere radius 0 at the apex, half-angles up to π: from `π − ANGLE_MARGIN` on, every
//! direction passes).
//!
//! What differs: the node-sphere test runs in `f32` (the CPU's in `f64`) with the CPU's
//! margins plus an acceptance that bounds the test's own rounding, with `sin` and `cos` from
//! `kernels/trig.wgsl` (WGSL's may be off by 2⁻¹¹), so the device keeps every pair the CPU
//! keeps and a few more (a superset of the CPU's candidates, which the tests check, also on
//! pairs placed at the test's boundary, and never a missed intersection). The cone condition
//! is evaluated as the distance of the sphere's centre from the cone (`node_bound.wgsl`:
//! `D·sin(θ − α) ≤ ρ` in front of the apex, from `a·v` and `|a × v|`), which stays
//! well-conditioned for narrow cones where the CPU's form, a difference of two near-equal
//! lengths, would need a slack as wide as a shadow node's cone in `f32`. Level counts are
//! close to the CPU's, not equal. `peak_candidate_bytes` counts the
//! input and output pair arrays of a level (the device needs no final concatenation); the
//! survivor flags (4 bytes per tested pair) come on top and must fit one storage binding.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{
    Candidate, CandidateBatch, CoreError, Ray, RayHierarchy, RayKind, Registry, Result, StageSpec,
    Stats, Traverser,
};

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{encoder, submit, uniform, Kernel, Slot};
use crate::kernels::scan::ScanKernel;
use crate::scene::GpuScene;

use super::BoundWords;

const SHADER: &str = include_str!("crsh.wgsl");
const PAIR_BYTES: u64 = 8;

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct Params {
    n: u32,
    n_meshes: u32,
    batch: u32,
    t0: u32,
    sub: u32,
    n_children: u32,
    mesh_culling: u32,
    has_reach: u32,
}

struct CrshKernels {
    kernel: Kernel,
}

impl CrshKernels {
    fn new(ctx: &GpuContext) -> GpuResult<CrshKernels> {
        let slots = [
            Slot::Uniform,
            Slot::Read,
            Slot::Read,
            Slot::ReadWrite,
            Slot::Read,
            Slot::Read,
            Slot::Read,
            Slot::Read,
            Slot::ReadWrite,
            Slot::Read,
            Slot::ReadWrite,
            Slot::ReadWrite,
            Slot::ReadWrite,
        ];
        Ok(CrshKernels {
            kernel: Kernel::new(
                ctx,
                "crsh traversal",
                &format!("{SHADER}\n{}", super::NODE_BOUND_WGSL),
                &[
                    "prepare",
                    "mesh_cull",
                    "top_test",
                    "top_emit",
                    "descend_test",
                    "descend_emit",
                ],
                &slots,
            )?,
        })
    }
}

/// The GPU CRSH traverser.
pub struct Crsh {
    scene: Arc<GpuScene>,
    mesh_culling: bool,
    budget_bytes: u64,
    unused: Unused,
}

/// Empty buffers for the slots a dispatch leaves unbound, made once per stage (a dispatch
/// binds each writable slot to its own buffer).
struct Unused {
    nodes: GpuBuffer<crsh_core::SphereCone>,
    reach: GpuBuffer<f32>,
    bounds: [GpuBuffer<BoundWords>; 2],
    words: [GpuBuffer<u32>; 3],
    pairs: [GpuBuffer<Candidate>; 2],
}

/// The buffers one dispatch binds (unused slots get placeholders).
#[derive(Clone, Copy, Default)]
struct Binds<'a> {
    level_nodes: Option<&'a GpuBuffer<crsh_core::SphereCone>>,
    level_reach: Option<&'a GpuBuffer<f32>>,
    bounds: Option<&'a GpuBuffer<BoundWords>>,
    child_bounds: Option<&'a GpuBuffer<BoundWords>>,
    keep: Option<&'a GpuBuffer<u32>>,
    pairs_in: Option<&'a GpuBuffer<Candidate>>,
    flags: Option<&'a GpuBuffer<u32>>,
    pairs_out: Option<&'a GpuBuffer<Candidate>>,
    counters: Option<&'a GpuBuffer<u32>>,
}

enum Outcome {
    Done {
        pairs: GpuBuffer<Candidate>,
        local: Box<Stats>,
        peak: u64,
        worst: u64,
    },
    Aborted {
        needed: u64,
        local: Box<Stats>,
    },
}

/// Registers the wgpu `crsh` under its CPU twin's catalogue entry (same name, parameters,
/// defaults and documentation).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_traverser(crsh_cpu::traverse::crsh::info(), |ctx, spec| {
        Ok(Box::new(Crsh::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl Crsh {
    /// The traverser over `scene` with `spec`'s `mesh_culling` and `candidate_budget_mb`
    /// (validated as on the CPU).
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<Crsh> {
        let cpu = crsh_cpu::traverse::crsh::Crsh::new(&scene.scene, spec)?;
        Crsh::like(scene, &cpu)
    }

    /// The traverser with explicit options, validated as
    /// [`crsh_cpu::traverse::crsh::Crsh::with_options`] does.
    pub fn with_options(scene: &Arc<GpuScene>, mesh_culling: bool, budget_mb: f64) -> Result<Crsh> {
        let cpu =
            crsh_cpu::traverse::crsh::Crsh::with_options(&scene.scene, mesh_culling, budget_mb)?;
        Crsh::like(scene, &cpu)
    }

    /// The twin of the validated CPU traverser `cpu`.
    fn like(scene: &Arc<GpuScene>, cpu: &crsh_cpu::traverse::crsh::Crsh) -> Result<Crsh> {
        let ctx = scene.ctx();
        Ok(Crsh {
            scene: Arc::clone(scene),
            mesh_culling: cpu.mesh_culling(),
            budget_bytes: cpu.budget_bytes(),
            unused: Unused {
                nodes: GpuBuffer::zeroed(ctx, "crsh unused", 0)?,
                reach: GpuBuffer::zeroed(ctx, "crsh unused", 0)?,
                bounds: [
                    GpuBuffer::zeroed(ctx, "crsh unused", 0)?,
                    GpuBuffer::zeroed(ctx, "crsh unused", 0)?,
                ],
                words: [
                    GpuBuffer::zeroed(ctx, "crsh unused", 0)?,
                    GpuBuffer::zeroed(ctx, "crsh unused", 0)?,
                    GpuBuffer::zeroed(ctx, "crsh unused", 0)?,
                ],
                pairs: [
                    GpuBuffer::zeroed(ctx, "crsh unused", 0)?,
                    GpuBuffer::zeroed(ctx, "crsh unused", 0)?,
                ],
            },
        })
    }

    fn batch_triangles(&self, top_nodes: usize) -> usize {
        let per_tri = 2 * PAIR_BYTES * top_nodes.max(1) as u64;
        let n = (self.budget_bytes / per_tri).max(1);
        n.min(self.scene.triangle_count().max(1) as u64) as usize
    }

    fn bind(
        &self,
        k: &Kernel,
        params: &Params,
        b: &Binds<'_>,
    ) -> GpuResult<crate::kernel::KernelBindings> {
        let ctx = self.scene.ctx();
        let u = uniform(ctx, "crsh traversal params", params);
        let z = &self.unused;
        let s = &self.scene;
        Ok(k.bind_group(
            ctx,
            &[
                u.as_entire_binding(),
                b.level_nodes.unwrap_or(&z.nodes).binding(),
                b.level_reach.unwrap_or(&z.reach).binding(),
                b.bounds.unwrap_or(&z.bounds[0]).binding(),
                b.child_bounds.unwrap_or(&z.bounds[1]).binding(),
                s.tri_spheres.binding(),
                s.info.binding(),
                s.meshes.binding(),
                b.keep.unwrap_or(&z.words[0]).binding(),
                b.pairs_in.unwrap_or(&z.pairs[0]).binding(),
                b.flags.unwrap_or(&z.words[1]).binding(),
                b.pairs_out.unwrap_or(&z.pairs[1]).binding(),
                b.counters.unwrap_or(&z.words[2]).binding(),
            ],
        ))
    }

    /// One test / scan / emit round over `items` flags: returns `(survivors, tests, pairs)`.
    fn compact(
        &self,
        k: &Kernel,
        (test, emit): (&str, &str),
        params: &Params,
        binds: Binds<'_>,
        items: usize,
    ) -> Result<(u64, GpuBuffer<Candidate>)> {
        let ctx = self.scene.ctx();
        ctx.check_storage_binding("traversal survivor flags", items as u64 * 4)?;
        let flags = GpuBuffer::<u32>::zeroed(ctx, "crsh traversal flags", items)?;
        let counters = GpuBuffer::<u32>::zeroed(ctx, "crsh traversal counters", 4)?;
        let total = GpuBuffer::<u32>::zeroed(ctx, "crsh traversal total", 4)?;
        let bg = self.bind(
            k,
            params,
            &Binds {
                flags: Some(&flags),
                counters: Some(&counters),
                ..binds
            },
        )?;
        let mut enc = encoder(ctx, test);
        {
            let mut pass = ctx.compute_pass(&mut enc, test);
            k.dispatch(ctx, &mut pass, test, &bg, items as u32)?;
        }
        ctx.kernel(ScanKernel::new)?.encode_in_place(
            ctx,
            &mut enc,
            &flags,
            Some((total.buffer(), 0)),
        )?;
        submit(ctx, test, enc)?;
        let survivors = total.to_vec(ctx)?[0] as usize;
        let c = counters.to_vec(ctx)?;
        let tests = u64::from(c[0]) | (u64::from(c[1]) << 32);
        let out = GpuBuffer::<Candidate>::zeroed(ctx, "crsh candidates", survivors)?;
        if survivors > 0 {
            ctx.check_storage_binding("candidate pairs", out.byte_len())?;
            let bg = self.bind(
                k,
                params,
                &Binds {
                    flags: Some(&flags),
                    counters: Some(&counters),
                    pairs_out: Some(&out),
                    ..binds
                },
            )?;
            let mut enc = encoder(ctx, emit);
            {
                let mut pass = ctx.compute_pass(&mut enc, emit);
                k.dispatch(ctx, &mut pass, emit, &bg, items as u32)?;
            }
            submit(ctx, emit, enc)?;
        }
        Ok((tests, out))
    }

    #[allow(clippy::too_many_arguments)]
    fn run_batch(
        &self,
        k: &Kernel,
        bounds: &[GpuBuffer<BoundWords>],
        keep: Option<&GpuBuffer<u32>>,
        sub: u32,
        kind: RayKind,
        t0: usize,
        t1: usize,
    ) -> Result<Outcome> {
        let top = bounds.last().expect("checked non-empty");
        let top_level = bounds.len() as u32;
        let mut local = Stats::default();
        let mut worst = 0u64;
        let batch = t1 - t0;
        let params = Params {
            n: top.len() as u32,
            n_meshes: self.scene.scene.meshes.len() as u32,
            batch: batch as u32,
            t0: t0 as u32,
            sub,
            mesh_culling: u32::from(self.mesh_culling),
            ..Default::default()
        };
        let (tests, mut level) = self.compact(
            k,
            ("top_test", "top_emit"),
            &params,
            Binds {
                bounds: Some(top),
                keep,
                ..Default::default()
            },
            top.len() * batch,
        )?;
        local.add_bounds(tests);
        local.add_level(kind, top_level, tests, level.len() as u64);
        let mut peak = level.byte_len();
        for li in (1..bounds.len()).rev() {
            let p = level.len() as u64;
            let worst_out = p * u64::from(sub) * PAIR_BYTES;
            let needed = if li == 1 {
                (level.byte_len() + worst_out).max(2 * worst_out)
            } else {
                level.byte_len() + worst_out
            };
            worst = worst.max(needed);
            if needed > self.budget_bytes && batch > 1 {
                return Ok(Outcome::Aborted {
                    needed,
                    local: Box::new(local),
                });
            }
            if level.is_empty() {
                local.add_level(kind, li as u32, 0, 0);
                continue;
            }
            let children = &bounds[li - 1];
            let params = Params {
                n: level.len() as u32,
                sub,
                n_children: children.len() as u32,
                ..Default::default()
            };
            let (tests, next) = self.compact(
                k,
                ("descend_test", "descend_emit"),
                &params,
                Binds {
                    child_bounds: Some(children),
                    pairs_in: Some(&level),
                    ..Default::default()
                },
                level.len() * sub as usize,
            )?;
            local.add_bounds(tests);
            local.add_level(kind, li as u32, tests, next.len() as u64);
            peak = peak.max(level.byte_len() + next.byte_len());
            level = next;
        }
        Ok(Outcome::Done {
            pairs: level,
            local: Box::new(local),
            peak,
            worst,
        })
    }
}

impl Traverser<Wgpu> for Crsh {
    fn name(&self) -> &str {
        "crsh"
    }

    fn traverse(
        &self,
        backend: &Wgpu,
        rays: &GpuBuffer<Ray>,
        kind: RayKind,
        h: &RayHierarchy<Wgpu>,
        sink: &mut dyn FnMut(CandidateBatch<Wgpu>, &mut Stats) -> Result<()>,
        stats: &mut Stats,
    ) -> Result<()> {
        let ctx = backend.context();
        let n_rays = rays.len();
        let n_tris = self.scene.triangle_count();
        if n_rays == 0 {
            return Ok(());
        }
        let sub = h.subdivision;
        super::check_hierarchy(ctx, h, n_rays)?;
        let has_reach = !h.reach.is_empty();
        let k = ctx.kernel(CrshKernels::new)?;
        // Prepare every level's bounds.
        let counters = GpuBuffer::<u32>::zeroed(ctx, "crsh traversal counters", 4)?;
        let mut bounds: Vec<GpuBuffer<BoundWords>> = Vec::with_capacity(h.levels.len());
        let mut enc = encoder(ctx, "crsh traversal prepare");
        for (li, level) in h.levels.iter().enumerate() {
            let out = GpuBuffer::<BoundWords>::zeroed(ctx, "crsh node bounds", level.len())?;
            let params = Params {
                n: level.len() as u32,
                has_reach: u32::from(has_reach),
                ..Default::default()
            };
            let bg = self.bind(
                &k.kernel,
                &params,
                &Binds {
                    level_nodes: Some(level),
                    level_reach: h.reach.get(li),
                    bounds: Some(&out),
                    counters: Some(&counters),
                    ..Default::default()
                },
            )?;
            {
                let mut pass = ctx.compute_pass(&mut enc, "crsh traversal prepare");
                k.kernel
                    .dispatch(ctx, &mut pass, "prepare", &bg, level.len() as u32)?;
            }
            bounds.push(out);
        }
        submit(ctx, "crsh traversal prepare", enc)?;
        if counters.to_vec(ctx)?[3] != 0 {
            return Err(CoreError::InvalidInput(
                "hierarchy has a node with a non-finite or negative sphere or cone, or a zero \
                 cone axis"
                    .into(),
            ));
        }
        if n_tris == 0 {
            return Ok(());
        }
        let top = bounds.last().expect("checked non-empty");
        let meshes = self.scene.scene.meshes.len();
        let keep = if self.mesh_culling {
            let keep = GpuBuffer::<u32>::zeroed(ctx, "crsh mesh culling", top.len() * meshes)?;
            let counters = GpuBuffer::<u32>::zeroed(ctx, "crsh traversal counters", 4)?;
            let params = Params {
                n: top.len() as u32,
                n_meshes: meshes as u32,
                ..Default::default()
            };
            let bg = self.bind(
                &k.kernel,
                &params,
                &Binds {
                    bounds: Some(top),
                    keep: Some(&keep),
                    counters: Some(&counters),
                    ..Default::default()
                },
            )?;
            let mut enc = encoder(ctx, "crsh mesh culling");
            {
                let mut pass = ctx.compute_pass(&mut enc, "crsh mesh culling");
                k.kernel.dispatch(
                    ctx,
                    &mut pass,
                    "mesh_cull",
                    &bg,
                    (top.len() * meshes) as u32,
                )?;
            }
            submit(ctx, "crsh mesh culling", enc)?;
            let kept = u64::from(counters.to_vec(ctx)?[2]);
            let tests = (top.len() * meshes) as u64;
            stats.add_bounds(tests);
            stats.add_mesh_culling(kind, tests, kept);
            Some(keep)
        } else {
            None
        };
        let max_batch = self.batch_triangles(top.len());
        let mut batch = max_batch;
        let mut peak_all = 0u64;
        let mut t0 = 0usize;
        while t0 < n_tris {
            let t1 = (t0 + batch).min(n_tris);
            match self.run_batch(&k.kernel, &bounds, keep.as_ref(), sub, kind, t0, t1)? {
                Outcome::Aborted { needed, local } => {
                    stats.add_bounds(local.tests.bounds);
                    for row in &local.levels {
                        stats.add_level(kind, row.level, row.tests, row.hits);
                    }
                    let scaled = (batch as f64 * self.budget_bytes as f64 / needed as f64) as usize;
                    batch = scaled.min(batch / 2).max(1);
                }
                Outcome::Done {
                    pairs,
                    local,
                    peak,
                    worst,
                } => {
                    stats.add_bounds(local.tests.bounds);
                    for row in &local.levels {
                        stats.add_level(kind, row.level, row.tests, row.hits);
                    }
                    peak_all = peak_all.max(peak);
                    if !pairs.is_empty() {
                        sink(CandidateBatch::new(pairs), stats)?;
                    }
                    if worst <= self.budget_bytes / 2 {
                        batch = (batch * 2).min(max_batch);
                    }
                    t0 = t1;
                }
            }
        }
        stats.peak_candidate_bytes = stats.peak_candidate_bytes.max(peak_all);
        Ok(())
    }
}
