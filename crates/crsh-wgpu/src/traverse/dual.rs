//! `dual` traversal on the wgpu backend: the ray hierarchy and an object hierarchy over the
//! triangles descended together, breadth first with stream compaction (seed 000 §3.2.8 with
//! §5.1's "deeper object hierarchy").
//!
//! The twin is [`crsh_cpu::traverse::dual::Dual`]: the same parameters (`objects`,
//! `grid_density`, `box_test`, `single_rays`, `update`, `candidate_budget_mb`), the same object
//! hierarchy (built on the host by the CPU's own code when the stage is constructed, once per
//! frame, and uploaded: [`Lbvh::flat`]; with `update = refit` the host traverser is kept and
//! the next frame uploads its refit), the same pair test, the same rule for which side of a
//! pair to split, single rays with lane masks, and the same counters. `objects = meshes` is
//! the wgpu [`crate::traverse::crsh::Crsh`] with mesh culling, as on the CPU. `wide_cone`
//! needs inline final tests, so here only its default (off) is accepted, as on the CPU with
//! batched final tests.
//!
//! # The device algorithm
//!
//! 1. `prepare`: every ray node becomes the CPU's `NodeBound` (`node_bound.wgsl`, all levels
//!    in one array of node records); a non-finite or negative node is an error.
//!    `lowest_boxes` and `upper_boxes`: every node's segment box, in the same record (the
//!    union of its rays' segment boxes, [`crsh_cpu::traverse::dual::segment_box`], then of its
//!    children's).
//! 2. The pairs (top node, object root) of every top-level ray node are the first
//!    frontier. Each round, `test_pairs` tests every pair of the frontier with the CPU task's
//!    rules (box overlap, then `may_hit` against the object node's sphere; a single-ray pair
//!    tests each live ray's segment against the object node's box) and decides what follows:
//!    nothing, a candidate, the pair as single rays, the ray node's children or the object
//!    node's two children. The children and candidate counts, in one array, are scanned in one
//!    pass ([`crate::kernels::scan`]), and `emit_pairs` writes the next frontier and the round's
//!    candidates and counts each test in its ray level's and object depth's rows. The
//!    traversal ends when no frontier is left.
//! 3. A batch of candidates (at the end, or earlier when they fill a quarter of the budget) is
//!    sorted by `(node, triangle)` ([`crate::sort::radix::stable_radix_order`] on
//!    `node << tri_bits | triangle`), and repeats (a triangle reached through several grid
//!    cells) merged into one candidate for the union of their lane masks (`merge_heads`,
//!    scan, `merge_emit`), so the intersector gets strictly increasing pairs as from the CPU.
//!
//! Each pass binds at most 8 storage buffers (WebGPU's default
//! `max_storage_buffers_per_shader_stage`): the level starts travel in the parameters, a
//! node's bound and box share a record, and a round's two count arrays one buffer.
//!
//! # What differs from the CPU
//!
//! - The node test runs in `f32` with the rounding acceptance of the wgpu `crsh` (its module
//!   doc; the cone condition as a distance from the cone, well-conditioned for narrow cones), the segment boxes by the CPU's `f32` formula (with WGSL's less exact reciprocal in the
//!   clip, so they can differ in their last bits) and the single-ray slabs in `f32` widened
//!   to contain the CPU's `f64` clip (`dual.wgsl` states the bounds). Every test keeps what the CPU's keeps, so no
//!   hit is lost, and a few more pairs pass. The choice of the side to split is a size
//!   comparison evaluated in `f32`: where it comes out differently from the CPU's the pairs
//!   take another path down both trees. The candidates then differ slightly, and so do the
//!   counts; the hits do not (the tests compare them with the CPU's and brute force's).
//! - Memory: the CPU runs depth-first tasks in rounds. Here the frontier grows and shrinks
//!   breadth first. A round that would hold more than the budget (frontier in and out,
//!   candidates held, the round's per-pair arrays), or whose next frontier would not fit one
//!   storage binding, is not emitted: its frontier is split in halves, the second set aside,
//!   and the first tested again (a frontier of one pair proceeds whatever its size). Halves
//!   set aside are taken up last in, first out, so the traversal goes depth first over them;
//!   a split round's test pass runs again on each half, but only the emit pass counts, once
//!   per pair. `peak_candidate_bytes` counts the pairs alive at once: frontiers, halves set
//!   aside and candidates held; the halves set aside come on top of the budget. Measured
//!   with the default 64 MiB on lavapipe: no split on Sponza and the dining room at 512 px;
//!   two splits, one half set aside at a time and a peak of 55 MB on Sponza at 1024 px.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{
    Aabb, CandidateBatch, CoreError, Ray, RayHierarchy, RayKind, Registry, Result, StageContext,
    StageSpec, Stats, Traverser,
};
#[cfg(doc)]
use crsh_cpu::traverse::dual::Lbvh;

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{encoder, submit, uniform, Kernel, Slot};
use crate::kernels::scan::ScanKernel;
use crate::scene::GpuScene;
use crate::sort::radix::stable_radix_order;

use super::BoundWords;

const SHADER: &str = include_str!("dual.wgsl");
/// Bytes of a pair record (frontier pairs and raw candidates).
const PAIR_BYTES: u64 = std::mem::size_of::<GpuPair>() as u64;
/// Bytes per frontier pair of a round's per-pair arrays (outcome, children, candidates).
const ROUND_BYTES: u64 = 16;

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct Params {
    n: u32,
    first: u32,
    has_reach: u32,
    sub: u32,
    n_rays: u32,
    _pad: u32,
    n_levels: u32,
    has_offsets: u32,
    n_depths: u32,
    box_test: u32,
    single_rays: u32,
    root: u32,
    scene_lo: [f32; 3],
    tri_bits: u32,
    scene_hi: [f32; 3],
    child_first: u32,
    /// Each level's first index in the node records, then their total.
    level_first: [[u32; 4]; 16],
}

/// Ray levels the traversal takes: `Params::level_first` holds `MAX_LEVELS + 1` starts. A
/// hierarchy over at most 2³² rays with a subdivision of at least 2 has at most 33 levels.
const MAX_LEVELS: usize = 63;

/// `NodeRec` in WGSL (80 bytes): a ray node's prepared bound ([`BoundWords`]) and its box of
/// ray segments ([`BoxWords`]).
type NodeRecWords = [u32; NODE_REC_WORDS];

const NODE_REC_WORDS: usize =
    (std::mem::size_of::<BoundWords>() + std::mem::size_of::<BoxWords>()) / 4;

/// `ObjNode` in WGSL (48 bytes): [`crsh_cpu::traverse::dual::FlatNode`].
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct GpuObjNode {
    sphere: [f32; 4],
    lo: [f32; 3],
    a: u32,
    hi: [f32; 3],
    b: u32,
}

/// `Pair` in WGSL (16 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct GpuPair {
    node: u32,
    obj: u32,
    mask: u32,
    info: u32,
}

/// `RBox` in WGSL (32 bytes).
type BoxWords = [u32; 8];

struct DualKernels {
    kernel: Kernel,
}

impl DualKernels {
    fn new(ctx: &GpuContext) -> GpuResult<DualKernels> {
        use Slot::{Read, ReadWrite, Uniform};
        let slots = [
            Uniform, Read, Read, ReadWrite, Read, Read, Read, Read, Read, ReadWrite, ReadWrite,
            ReadWrite, ReadWrite, ReadWrite, ReadWrite, ReadWrite, Read, ReadWrite,
        ];
        Ok(DualKernels {
            kernel: Kernel::new(
                ctx,
                "dual traversal",
                &format!(
                    "{SHADER}\n{}\n{}",
                    crate::intersect::MT_WGSL,
                    super::NODE_BOUND_WGSL
                ),
                &[
                    "prepare",
                    "lowest_boxes",
                    "upper_boxes",
                    "seed",
                    "test_pairs",
                    "emit_pairs",
                    "cand_keys",
                    "merge_heads",
                    "merge_emit",
                ],
                &slots,
            )?,
        })
    }
}

/// The buffers one dispatch binds (unused slots get placeholders).
#[derive(Clone, Copy, Default)]
struct Binds<'a> {
    level_nodes: Option<&'a GpuBuffer<crsh_core::SphereCone>>,
    level_reach: Option<&'a GpuBuffer<f32>>,
    nodes: Option<&'a GpuBuffer<NodeRecWords>>,
    rays: Option<&'a GpuBuffer<Ray>>,
    order: Option<&'a GpuBuffer<u32>>,
    offsets: Option<&'a GpuBuffer<u32>>,
    pairs_in: Option<&'a GpuBuffer<GpuPair>>,
    outcome: Option<&'a GpuBuffer<[u32; 2]>>,
    counts: Option<&'a GpuBuffer<u32>>,
    pairs_out: Option<&'a GpuBuffer<GpuPair>>,
    raw: Option<&'a GpuBuffer<GpuPair>>,
    cands: Option<&'a GpuBuffer<crsh_core::Candidate>>,
    lanes: Option<&'a GpuBuffer<u32>>,
    keys: Option<&'a GpuBuffer<u64>>,
    sorted: Option<&'a GpuBuffer<u32>>,
    counters: Option<&'a GpuBuffer<u32>>,
}

/// The GPU `dual` traverser.
pub struct Dual {
    objects: Objects,
}

enum Objects {
    /// An object hierarchy (`lbvh`, `bvh` or `grid`) on the device.
    Tree(Box<Tree>),
    /// `meshes`: the wgpu `crsh` with mesh culling.
    Meshes(Box<crate::traverse::crsh::Crsh>),
}

/// Empty buffers for the slots a dispatch leaves unbound, made once per stage (a dispatch
/// binds each writable slot to its own buffer).
struct Unused {
    nodes: GpuBuffer<crsh_core::SphereCone>,
    reach: GpuBuffer<f32>,
    records: GpuBuffer<NodeRecWords>,
    rays: GpuBuffer<Ray>,
    outcome: GpuBuffer<[u32; 2]>,
    cands: GpuBuffer<crsh_core::Candidate>,
    keys: GpuBuffer<u64>,
    words: Vec<GpuBuffer<u32>>,
    pairs: Vec<GpuBuffer<GpuPair>>,
}

impl Unused {
    fn new(ctx: &GpuContext) -> GpuResult<Unused> {
        Ok(Unused {
            nodes: GpuBuffer::zeroed(ctx, "dual unused", 0)?,
            reach: GpuBuffer::zeroed(ctx, "dual unused", 0)?,
            records: GpuBuffer::zeroed(ctx, "dual unused", 0)?,
            rays: GpuBuffer::zeroed(ctx, "dual unused", 0)?,
            outcome: GpuBuffer::zeroed(ctx, "dual unused", 0)?,
            cands: GpuBuffer::zeroed(ctx, "dual unused", 0)?,
            keys: GpuBuffer::zeroed(ctx, "dual unused", 0)?,
            words: (0..6)
                .map(|_| GpuBuffer::zeroed(ctx, "dual unused", 0))
                .collect::<GpuResult<_>>()?,
            pairs: (0..3)
                .map(|_| GpuBuffer::zeroed(ctx, "dual unused", 0))
                .collect::<GpuResult<_>>()?,
        })
    }
}

struct Tree {
    scene: Arc<GpuScene>,
    unused: Unused,
    source: &'static str,
    objs: GpuBuffer<GpuObjNode>,
    /// The root's index (`None` without triangles).
    root: Option<u32>,
    /// The box of every triangle (margins included).
    bounds: Aabb,
    max_depth: usize,
    budget_bytes: u64,
    box_test: bool,
    single_rays: bool,
    /// With `update = refit`: the host traverser, whose refit the next frame uploads.
    host: Option<Box<crsh_cpu::traverse::dual::Dual>>,
}

/// Registers the wgpu `dual` under its CPU twin's catalogue entry (same name, parameters,
/// defaults and documentation), with `final_tests` narrowed to `batched`.
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    let mut info = crsh_cpu::traverse::dual::info();
    for p in &mut info.params {
        if p.name == "final_tests" {
            // Inline final tests have no device twin: the device traverses breadth first.
            p.choices = &["batched"];
        }
    }
    registry.add_traverser(info, |ctx, spec| Ok(Box::new(Dual::new(ctx.scene, spec)?)))?;
    Ok(())
}

/// Bits to hold every value below `n` (at least 1).
fn bits_for(n: usize) -> u32 {
    (usize::BITS - n.saturating_sub(1).leading_zeros()).max(1)
}

impl Dual {
    /// The traverser over `scene` with `spec`'s parameters (validated as on the CPU); with
    /// `objects = lbvh`, `bvh` or `grid` the object hierarchy is built now, on the host by the
    /// CPU twin's code, and uploaded.
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<Dual> {
        if spec.str("final_tests")? == "inline" {
            return Err(CoreError::Unsupported {
                stage: "traverse",
                variant: "dual".into(),
                what: "`final_tests = inline` on wgpu (the device traverses breadth first and \
                       tests the candidates in batches; inline final tests are CPU only)"
                    .into(),
            });
        }
        let cpu = crsh_cpu::traverse::dual::Dual::new(&scene.scene, spec)?;
        if cpu.lbvh().is_none() {
            let crsh = crate::traverse::crsh::Crsh::with_options(
                scene,
                true,
                spec.f64("candidate_budget_mb")?,
            )?;
            return Ok(Dual {
                objects: Objects::Meshes(Box::new(crsh)),
            });
        }
        Dual::upload(scene, cpu)
    }

    /// The wgpu traverser of the host traverser `cpu` (`objects = lbvh`, `bvh` or `grid`,
    /// built over `scene`'s triangles): its object hierarchy uploaded, and `cpu` itself kept
    /// when it refits (`update = refit`).
    fn upload(scene: &Arc<GpuScene>, cpu: crsh_cpu::traverse::dual::Dual) -> Result<Dual> {
        let Some(tree) = cpu.lbvh() else {
            return Err(CoreError::InvalidInput(
                "dual: `objects = meshes` has no object hierarchy to upload".into(),
            ));
        };
        let (bounds, max_depth) = (tree.bounds(), tree.max_depth());
        let (flat, root) = tree.flat();
        let nodes: Vec<GpuObjNode> = flat
            .iter()
            .map(|n| {
                let (a, b) = match n.children {
                    Some([l, r]) => (l, r),
                    None => (n.triangle, u32::MAX),
                };
                GpuObjNode {
                    sphere: n.sphere.center.extend(n.sphere.radius).to_array(),
                    lo: n.bx.min.to_array(),
                    a,
                    hi: n.bx.max.to_array(),
                    b,
                }
            })
            .collect();
        let ctx = scene.ctx();
        ctx.check_storage_binding(
            "object hierarchy",
            std::mem::size_of_val(nodes.as_slice()) as u64,
        )?;
        Ok(Dual {
            objects: Objects::Tree(Box::new(Tree {
                scene: Arc::clone(scene),
                unused: Unused::new(ctx)?,
                source: cpu.objects(),
                objs: GpuBuffer::from_slice(ctx, "dual object hierarchy", &nodes)?,
                root,
                bounds,
                max_depth,
                budget_bytes: cpu.budget_bytes(),
                box_test: cpu.box_test(),
                single_rays: cpu.single_rays(),
                host: cpu.refits().then(|| Box::new(cpu)),
            })),
        })
    }

    /// The object side (one of [`crsh_cpu::traverse::dual::OBJECTS`]).
    pub fn objects(&self) -> &'static str {
        match &self.objects {
            Objects::Tree(t) => t.source,
            Objects::Meshes(_) => "meshes",
        }
    }
}

/// One traversal's fixed state.
struct Run<'a> {
    tree: &'a Tree,
    k: &'a Kernel,
    base: Params,
    rays: &'a GpuBuffer<Ray>,
    order: &'a GpuBuffer<u32>,
    offsets: Option<&'a GpuBuffer<u32>>,
    nodes: GpuBuffer<NodeRecWords>,
    kind: RayKind,
    key_bits: u32,
}

impl Tree {
    fn bind(
        &self,
        k: &Kernel,
        params: &Params,
        b: &Binds<'_>,
    ) -> GpuResult<crate::kernel::KernelBindings> {
        let ctx = self.scene.ctx();
        let u = uniform(ctx, "dual traversal params", params);
        let z = &self.unused;
        let (u32s, p32s) = (&z.words, &z.pairs);
        Ok(k.bind_group(
            ctx,
            &[
                u.as_entire_binding(),
                b.level_nodes.unwrap_or(&z.nodes).binding(),
                b.level_reach.unwrap_or(&z.reach).binding(),
                b.nodes.unwrap_or(&z.records).binding(),
                b.rays.unwrap_or(&z.rays).binding(),
                b.order.unwrap_or(&u32s[0]).binding(),
                b.offsets.unwrap_or(&u32s[1]).binding(),
                self.objs.binding(),
                b.pairs_in.unwrap_or(&p32s[0]).binding(),
                b.outcome.unwrap_or(&z.outcome).binding(),
                b.counts.unwrap_or(&u32s[2]).binding(),
                b.pairs_out.unwrap_or(&p32s[1]).binding(),
                b.raw.unwrap_or(&p32s[2]).binding(),
                b.cands.unwrap_or(&z.cands).binding(),
                b.lanes.unwrap_or(&u32s[3]).binding(),
                b.keys.unwrap_or(&z.keys).binding(),
                b.sorted.unwrap_or(&u32s[4]).binding(),
                b.counters.unwrap_or(&u32s[5]).binding(),
            ],
        ))
    }

    /// Records one dispatch of `entry` over `n` items.
    fn dispatch(
        &self,
        enc: &mut wgpu::CommandEncoder,
        k: &Kernel,
        entry: &str,
        params: &Params,
        binds: &Binds<'_>,
    ) -> Result<()> {
        let ctx = self.scene.ctx();
        let bg = self.bind(k, params, binds)?;
        let mut pass = ctx.compute_pass(enc, entry);
        k.dispatch(ctx, &mut pass, entry, &bg, params.n)?;
        Ok(())
    }
}

impl Run<'_> {
    fn ctx(&self) -> &GpuContext {
        self.tree.scene.ctx()
    }

    fn binds(&self) -> Binds<'_> {
        Binds {
            nodes: Some(&self.nodes),
            rays: Some(self.rays),
            order: Some(self.order),
            offsets: self.offsets,
            ..Binds::default()
        }
    }

    /// Reads row counters into `stats` (bounds, ray-level rows, object-depth rows).
    fn record(&self, counters: &GpuBuffer<u32>, stats: &mut Stats) -> Result<()> {
        let c = counters.to_vec(self.ctx())?;
        let word = |i: usize| u64::from(c[i]) | (u64::from(c[i + 1]) << 32);
        let levels = self.base.n_levels as usize;
        let rows: Vec<(u64, u64)> = (0..levels + self.base.n_depths as usize)
            .map(|r| (word(4 + 4 * r), word(6 + 4 * r)))
            .collect();
        stats.add_bounds(rows[..levels].iter().map(|r| r.0).sum());
        for (li, r) in rows[..levels].iter().enumerate() {
            stats.add_level(self.kind, li as u32 + 1, r.0, r.1);
        }
        for (depth, r) in rows[levels..].iter().enumerate() {
            stats.add_object_level(self.kind, depth as u32, r.0, r.1);
        }
        Ok(())
    }

    /// Sorts and merges raw candidates and hands them on as one batch.
    fn flush(
        &self,
        held: &mut Vec<GpuBuffer<GpuPair>>,
        sink: &mut dyn FnMut(CandidateBatch<Wgpu>, &mut Stats) -> Result<()>,
        stats: &mut Stats,
    ) -> Result<()> {
        if held.is_empty() {
            return Ok(());
        }
        let ctx = self.ctx();
        let raw = GpuBuffer::concat(ctx, "dual raw candidates", std::mem::take(held))?;
        let n = raw.len();
        ctx.check_storage_binding("dual raw candidates", raw.byte_len())?;
        let keys = GpuBuffer::<u64>::zeroed(ctx, "dual candidate keys", n)?;
        let params = Params {
            n: n as u32,
            ..self.base
        };
        let mut enc = encoder(ctx, "dual candidate keys");
        self.tree.dispatch(
            &mut enc,
            self.k,
            "cand_keys",
            &params,
            &Binds {
                raw: Some(&raw),
                keys: Some(&keys),
                ..Binds::default()
            },
        )?;
        submit(ctx, "dual candidate keys", enc)?;
        let sorted = stable_radix_order(ctx, &keys, self.key_bits)?;
        let heads = GpuBuffer::<u32>::zeroed(ctx, "dual candidate heads", n)?;
        let total = GpuBuffer::<u32>::zeroed(ctx, "dual candidate total", 1)?;
        let binds = Binds {
            raw: Some(&raw),
            keys: Some(&keys),
            sorted: Some(&sorted),
            counts: Some(&heads),
            ..Binds::default()
        };
        let mut enc = encoder(ctx, "dual merge heads");
        self.tree
            .dispatch(&mut enc, self.k, "merge_heads", &params, &binds)?;
        ctx.kernel(ScanKernel::new)?.encode_in_place(
            ctx,
            &mut enc,
            &heads,
            Some((total.buffer(), 0)),
        )?;
        submit(ctx, "dual merge heads", enc)?;
        let unique = total.to_vec(ctx)?[0] as usize;
        let cands = GpuBuffer::<crsh_core::Candidate>::zeroed(ctx, "dual candidates", unique)?;
        let lanes = GpuBuffer::<u32>::zeroed(ctx, "dual candidate lanes", unique)?;
        let mut enc = encoder(ctx, "dual merge");
        self.tree.dispatch(
            &mut enc,
            self.k,
            "merge_emit",
            &params,
            &Binds {
                cands: Some(&cands),
                lanes: Some(&lanes),
                ..binds
            },
        )?;
        submit(ctx, "dual merge", enc)?;
        let batch = if self.tree.single_rays {
            CandidateBatch::with_lanes(cands, lanes)
        } else {
            CandidateBatch::new(cands)
        };
        sink(batch, stats)
    }

    /// The two halves of `frontier`, copied into new buffers.
    fn halves(
        &self,
        frontier: GpuBuffer<GpuPair>,
    ) -> Result<(GpuBuffer<GpuPair>, GpuBuffer<GpuPair>)> {
        let ctx = self.ctx();
        let n = frontier.len();
        let a = GpuBuffer::<GpuPair>::zeroed(ctx, "dual frontier", n / 2)?;
        let b = GpuBuffer::<GpuPair>::zeroed(ctx, "dual frontier", n - n / 2)?;
        let mut enc = encoder(ctx, "dual split frontier");
        enc.copy_buffer_to_buffer(frontier.buffer(), 0, a.buffer(), 0, a.byte_len());
        enc.copy_buffer_to_buffer(frontier.buffer(), a.byte_len(), b.buffer(), 0, b.byte_len());
        submit(ctx, "dual split frontier", enc)?;
        Ok((a, b))
    }

    /// Traverses from every top node; returns the most bytes of pairs alive at once.
    fn traverse_all(
        &self,
        n_top: usize,
        sink: &mut dyn FnMut(CandidateBatch<Wgpu>, &mut Stats) -> Result<()>,
        stats: &mut Stats,
    ) -> Result<u64> {
        let ctx = self.ctx();
        let budget = self.tree.budget_bytes;
        let rows = (self.base.n_levels + self.base.n_depths) as usize;
        let mut counters = GpuBuffer::<u32>::zeroed(ctx, "dual counters", 4 + 4 * rows)?;
        let seed = GpuBuffer::<GpuPair>::zeroed(ctx, "dual frontier", n_top)?;
        let mut enc = encoder(ctx, "dual seed");
        self.tree.dispatch(
            &mut enc,
            self.k,
            "seed",
            &Params {
                n: n_top as u32,
                first: 0,
                ..self.base
            },
            &Binds {
                pairs_out: Some(&seed),
                ..Binds::default()
            },
        )?;
        submit(ctx, "dual seed", enc)?;
        // Frontiers waiting for their turn (halves split off), last in first out.
        let mut pending: Vec<GpuBuffer<GpuPair>> = vec![seed];
        let mut pending_len = n_top as u64;
        let mut held: Vec<GpuBuffer<GpuPair>> = Vec::new();
        let mut held_len = 0u64;
        let mut peak = 0u64;
        let scan = ctx.kernel(ScanKernel::new)?;
        let binding = ctx.max_storage_binding_bytes();
        // Candidates go on at a quarter of the budget, and before their sort keys and merged
        // arrays could outgrow one binding.
        let flush_at = (budget / 4).min(binding / 2);
        while let Some(mut frontier) = pending.pop() {
            pending_len -= frontier.len() as u64;
            while !frontier.is_empty() {
                let n = frontier.len();
                ctx.check_storage_binding("dual frontier", frontier.byte_len())?;
                let outcome = GpuBuffer::<[u32; 2]>::zeroed(ctx, "dual outcome", n)?;
                // Children counts, then candidate counts: one scan gives both positions.
                let counts = GpuBuffer::<u32>::zeroed(ctx, "dual round counts", 2 * n)?;
                let totals = GpuBuffer::<u32>::zeroed(ctx, "dual totals", 2)?;
                let params = Params {
                    n: n as u32,
                    ..self.base
                };
                let binds = Binds {
                    pairs_in: Some(&frontier),
                    outcome: Some(&outcome),
                    counts: Some(&counts),
                    counters: Some(&counters),
                    ..self.binds()
                };
                let mut enc = encoder(ctx, "dual test pairs");
                self.tree
                    .dispatch(&mut enc, self.k, "test_pairs", &params, &binds)?;
                scan.encode_in_place(ctx, &mut enc, &counts, Some((totals.buffer(), 4)))?;
                // After the scan, counts[n] is the sum of the children counts.
                enc.copy_buffer_to_buffer(counts.buffer(), 4 * n as u64, totals.buffer(), 0, 4);
                submit(ctx, "dual test pairs", enc)?;
                let t = totals.to_vec(ctx)?;
                let (children, found) = (t[0] as u64, t[1].wrapping_sub(t[0]) as u64);
                let needed = (n as u64 + children) * PAIR_BYTES
                    + n as u64 * ROUND_BYTES
                    + (held_len + found) * PAIR_BYTES;
                // Past the budget, or a frontier past one storage binding (a budget above
                // the adapter's binding size): test the halves one after the other (nothing
                // was counted yet: the emit pass counts).
                if (needed > budget || children * PAIR_BYTES > binding) && n > 1 {
                    let (a, b) = self.halves(frontier)?;
                    pending_len += b.len() as u64;
                    pending.push(b);
                    frontier = a;
                    continue;
                }
                peak =
                    peak.max((n as u64 + children + held_len + found + pending_len) * PAIR_BYTES);
                let next = GpuBuffer::<GpuPair>::zeroed(ctx, "dual frontier", children as usize)?;
                let raw = GpuBuffer::<GpuPair>::zeroed(ctx, "dual raw candidates", found as usize)?;
                let mut enc = encoder(ctx, "dual emit pairs");
                self.tree.dispatch(
                    &mut enc,
                    self.k,
                    "emit_pairs",
                    &params,
                    &Binds {
                        pairs_out: Some(&next),
                        raw: Some(&raw),
                        ..binds
                    },
                )?;
                submit(ctx, "dual emit pairs", enc)?;
                if found > 0 {
                    held.push(raw);
                    held_len += found;
                }
                frontier = next;
                if held_len * PAIR_BYTES >= flush_at {
                    // Counted before the sink runs, as on the CPU.
                    self.record(&counters, stats)?;
                    counters = GpuBuffer::<u32>::zeroed(ctx, "dual counters", 4 + 4 * rows)?;
                    self.flush(&mut held, sink, stats)?;
                    held_len = 0;
                }
            }
        }
        self.record(&counters, stats)?;
        self.flush(&mut held, sink, stats)?;
        Ok(peak)
    }
}

impl Traverser<Wgpu> for Dual {
    fn name(&self) -> &str {
        "dual"
    }

    /// The host traverser's refit ([`crsh_cpu::traverse::dual::Dual::refitted`]), uploaded.
    fn refit(&self, ctx: &StageContext<'_, Wgpu>) -> Option<Result<Box<dyn Traverser<Wgpu>>>> {
        let Objects::Tree(tree) = &self.objects else {
            return None;
        };
        let cpu = tree.host.as_ref()?.refitted(&ctx.scene.scene)?;
        Some(Dual::upload(ctx.scene, cpu).map(|d| Box::new(d) as Box<dyn Traverser<Wgpu>>))
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
        let tree = match &self.objects {
            Objects::Meshes(crsh) => return crsh.traverse(backend, rays, kind, h, sink, stats),
            Objects::Tree(t) => t,
        };
        let ctx = backend.context();
        let n_rays = rays.len();
        if n_rays == 0 {
            return Ok(());
        }
        let sub = h.subdivision;
        let level_lens = super::check_hierarchy(ctx, h, n_rays)?;
        if level_lens.len() > MAX_LEVELS {
            return Err(CoreError::InvalidInput(format!(
                "{} hierarchy levels: the dual traversal takes at most {MAX_LEVELS}",
                level_lens.len()
            )));
        }
        let k = ctx.kernel(DualKernels::new)?;
        let mut firsts = vec![0u32];
        for len in &level_lens {
            firsts.push(firsts.last().copied().unwrap_or(0) + *len as u32);
        }
        let total_nodes = *firsts.last().unwrap_or(&0) as usize;
        let nodes = GpuBuffer::<NodeRecWords>::zeroed(ctx, "dual node records", total_nodes)?;
        ctx.check_storage_binding("dual node records", nodes.byte_len())?;
        let mut level_first = [[0u32; 4]; 16];
        for (i, f) in firsts.iter().enumerate() {
            level_first[i / 4][i % 4] = *f;
        }
        let n_tris = tree.scene.triangle_count();
        let b = tree.bounds;
        let base = Params {
            sub,
            n_rays: n_rays as u32,
            n_levels: level_lens.len() as u32,
            has_offsets: u32::from(h.leaf_offsets.is_some()),
            n_depths: tree.max_depth as u32 + 1,
            box_test: u32::from(tree.box_test),
            single_rays: u32::from(tree.single_rays),
            root: tree.root.unwrap_or(0),
            scene_lo: b.min.to_array(),
            tri_bits: bits_for(n_tris),
            scene_hi: b.max.to_array(),
            level_first,
            ..Params::default()
        };
        let run = Run {
            tree,
            k: &k.kernel,
            base,
            rays,
            order: &h.order,
            offsets: h.leaf_offsets.as_ref(),
            nodes,
            kind,
            key_bits: bits_for(level_lens[0]) + base.tri_bits,
        };
        // Bounds and boxes of every level.
        let reports = GpuBuffer::<u32>::zeroed(ctx, "dual reports", 4)?;
        let mut enc = encoder(ctx, "dual prepare");
        for (li, level) in h.levels.iter().enumerate() {
            let params = Params {
                n: level.len() as u32,
                first: firsts[li],
                has_reach: u32::from(!h.reach.is_empty()),
                ..base
            };
            let binds = Binds {
                level_nodes: Some(level),
                level_reach: h.reach.get(li),
                counters: Some(&reports),
                ..run.binds()
            };
            tree.dispatch(&mut enc, run.k, "prepare", &params, &binds)?;
        }
        let lowest = Params {
            n: level_lens[0] as u32,
            ..base
        };
        tree.dispatch(&mut enc, run.k, "lowest_boxes", &lowest, &run.binds())?;
        for li in 1..level_lens.len() {
            let params = Params {
                n: level_lens[li] as u32,
                first: firsts[li],
                child_first: firsts[li - 1],
                ..base
            };
            tree.dispatch(&mut enc, run.k, "upper_boxes", &params, &run.binds())?;
        }
        submit(ctx, "dual prepare", enc)?;
        if reports.to_vec(ctx)?[0] != 0 {
            return Err(CoreError::InvalidInput(
                "hierarchy has a node with a non-finite or negative sphere or cone, or a zero \
                 cone axis"
                    .into(),
            ));
        }
        if tree.root.is_none() {
            return Ok(());
        }
        let n_top = *level_lens.last().expect("checked non-empty");
        let peak_all = run.traverse_all(n_top, sink, stats)?;
        stats.peak_candidate_bytes = stats.peak_candidate_bytes.max(peak_all);
        Ok(())
    }
}
