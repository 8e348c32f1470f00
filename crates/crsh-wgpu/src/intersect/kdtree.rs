//! `kdtree` on the wgpu backend: RTTest's kd-tree (seed 003 §2.2.1, §3.2.1) traversed one ray
//! per invocation, the twin of [`crsh_cpu::kdtree::trace_single`] (listing 2.2 with its
//! errata fixed).
//!
//! - **The tree** is built on the host ([`build_tree_for`]) and uploaded as it is: the 12-byte
//!   [`KdNode`]s, the 32-byte [`KdLeaf`]s (cell and triangle run) and the leaf triangle ids,
//!   with every scene triangle prepared for Möller-Trumbore by the CPU's own code
//!   ([`PreparedTriangle`], the buffer `brute` uses), indexed by scene id.
//! - **The traversal** (`kdtree.wgsl`) is `trace_single`'s operation for operation: the clip
//!   to the root cell with the same [`T_SLACK`] widening, front and back children by the
//!   origin's side of the split plane (listing 4.1's modification 2), crossings behind the
//!   origin as `+∞` (modification 1), both children kept whole for an origin on the plane, the
//!   interval split with the old far distance kept for the back child (listing 2.2's erratum),
//!   the leaf triangles tested with `kernels/mt.wgsl` (brute force's code) and merged with
//!   `Hit::closer_than`, and the same end: any hit at the first hit, closest hit at the first
//!   leaf whose cell, shrunk by [`CELL_MARGIN`], holds the best hit point
//!   ([`KdLeaf::holds_final`]). The constants are generated from the Rust ones. Where the
//!   CPU's arithmetic meets infinities (a zero direction component, a plane never crossed),
//!   the kernel takes the branch f32's NaN-ignoring `max`/`min` take instead of forming NaN,
//!   and products feeding additions are kept from being fused into multiply-adds, so the
//!   intervals, and with them the nodes visited, are the CPU's bit for bit.
//! - **The stack** is a fixed array of [`STACK`] entries; its entries lie at distinct depths,
//!   so a tree no deeper than [`STACK`] cannot overflow it. Deeper trees are refused when they
//!   are uploaded.
//! - **Counts** are [`KdCounts`]'s, recorded as the CPU records them
//!   ([`KdCounts::record`]): a bound test and an inner-node visit per inner node, a leaf visit
//!   per leaf (empty ones included), a ray-triangle test per leaf triangle tested.
//! - **Loop bound**: llvmpipe (Mesa's software rasterizer, the adapter of machines without a
//!   GPU) silently ends every loop of an invocation once its loops have run 65535 iterations
//!   in all. A probe loop at the end of each traversal detects that, and the query fails with
//!   [`CoreError::Backend`] rather than return wrong hits; on such adapters a ray may visit
//!   only some tens of thousands of nodes and triangles.
//!
//! Hits equal wgpu brute force's bit for bit (closest: triangle, `t`, `u`, `v`; any hit: hit
//! or not), and so brute force's on the CPU wherever the device's Möller-Trumbore rounds like
//! the host's; there the hits are also the CPU twin's bit for bit and so are the counts.
//! Closest and any hit, whole-scene queries; only `test = "mt"` has a WGSL twin.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{
    CoreError, Hit, HitMode, Intersector, Query, Ray, Registry, Result, StageSpec,
    StageVariantInfo, Stats,
};
#[cfg(doc)]
use crsh_cpu::kdtree::trace_single;
use crsh_cpu::kdtree::{KdCounts, KdLeaf, KdNode, KdTree, CELL_MARGIN, T_SLACK};
use crsh_cpu::triangle::{MollerTrumbore, PreparedTriangle, TestKind, TriangleSet};
use crsh_scene::Scene;

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{dispatch_chunks, uniform, Kernel, Slot};
use crate::kernels::{compose, f32_const};
use crate::scene::GpuScene;

const SHADER: &str = include_str!("kdtree.wgsl");

/// Entries of the device traversal stack, and so the deepest tree (root alone: depth 0) the
/// device traverses.
pub const STACK: u32 = 64;

/// Uniform block of `kdtree.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n: u32,
    any_hit: u32,
    first: u32,
    n_nodes: u32,
    lo: [f32; 4],
    hi: [f32; 4],
    /// Always 0 (the operand of the kernel's contraction barrier).
    zero: u32,
    pad: [u32; 3],
}

/// The kernel source: the triangle test, the constants generated from the CPU's, the traversal.
fn source() -> String {
    let consts = f32_const("T_SLACK", T_SLACK)
        + &f32_const("CELL_MARGIN", CELL_MARGIN)
        + &format!("const STACK: u32 = {STACK}u;\n");
    compose(&[super::MT_WGSL, &consts, SHADER])
}

struct KdKernels {
    kernel: Kernel,
}

impl KdKernels {
    fn new(ctx: &GpuContext) -> GpuResult<KdKernels> {
        let mut slots = vec![Slot::Uniform];
        slots.extend([Slot::Read; 5]);
        slots.extend([Slot::ReadWrite; 2]);
        Ok(KdKernels {
            kernel: Kernel::new(ctx, "crsh kdtree", &source(), &["traverse"], &slots)?,
        })
    }
}

/// The catalogue entry of the wgpu `kdtree`: the CPU twin's
/// ([`crsh_cpu::intersect::kdtree::info`]: the same tree build parameters) with the triangle
/// test narrowed to Möller-Trumbore ([`crate::registry::mt_only`]) and the traversal to
/// single rays.
pub fn info() -> StageVariantInfo {
    let mut info = crate::registry::mt_only(crsh_cpu::intersect::kdtree::info());
    for p in &mut info.params {
        if p.name == "traversal" {
            p.choices = GPU_TRAVERSALS;
        }
    }
    info
}

/// The `traversal` values the wgpu kd-tree implements: single rays (seed 003's coherent
/// packets, frusta and cones are CPU traversals, `crsh_cpu::kdtree::coherent`).
pub const GPU_TRAVERSALS: &[&str] = &["single"];

/// Registers the wgpu `kdtree` ([`info`], [`KdIntersector::new`]).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_intersector(info(), |ctx, spec| {
        Ok(Box::new(KdIntersector::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

/// The host build of the tree `spec` asks for: the CPU twin's
/// ([`crsh_cpu::intersect::kdtree::build_tree`], SAH or middle splits) over the triangles
/// Möller-Trumbore can hit. A `traversal` other than `single` is refused here.
pub fn build_tree_for(scene: &Scene, spec: &StageSpec) -> Result<KdTree> {
    if let Ok(t) = spec.str("traversal") {
        if !GPU_TRAVERSALS.contains(&t) {
            return Err(CoreError::Unsupported {
                stage: "intersect",
                variant: "kdtree".into(),
                what: format!(
                    "traversal `{t}` on the wgpu backend (it traverses single rays; seed 003's \
                     coherent traversals run on the CPU)"
                ),
            });
        }
    }
    crsh_cpu::intersect::kdtree::build_tree(scene, spec, TestKind::MollerTrumbore)
}

/// The depth of `tree`'s deepest leaf (the root alone or no node: 0), walked rather than
/// trusted; `tree` passed [`KdTree::validate`].
fn walked_depth(tree: &KdTree) -> u32 {
    let mut deepest = 0;
    let mut work = if tree.nodes.is_empty() {
        Vec::new()
    } else {
        vec![(0usize, 0u32)]
    };
    while let Some((n, depth)) = work.pop() {
        let node = tree.nodes[n];
        if node.is_leaf() {
            deepest = deepest.max(depth);
        } else {
            work.push((node.index as usize, depth + 1));
            work.push((node.index as usize + 1, depth + 1));
        }
    }
    deepest
}

/// Whether the device can traverse `tree` over a scene of `n_tris` triangles: it passes
/// [`KdTree::validate`] and names scene triangles only ([`CoreError::InvalidInput`]), and it is
/// no deeper than [`STACK`] ([`CoreError::Unsupported`]).
pub fn check_tree(tree: &KdTree, n_tris: usize) -> Result<()> {
    tree.validate()
        .map_err(|e| CoreError::InvalidInput(format!("kd-tree: {e}")))?;
    if let Some(id) = tree.leaf_tris.iter().find(|&&id| id as usize >= n_tris) {
        return Err(CoreError::InvalidInput(format!(
            "kd-tree: triangle {id} is not in the scene ({n_tris} triangles)"
        )));
    }
    if u32::try_from(tree.nodes.len()).is_err() {
        return Err(CoreError::InvalidInput(format!(
            "kd-tree: {} nodes exceed u32 indices",
            tree.nodes.len()
        )));
    }
    let depth = walked_depth(tree);
    if depth > STACK {
        return Err(CoreError::Unsupported {
            stage: "intersect",
            variant: "kdtree".into(),
            what: format!(
                "a kd-tree of depth {depth} on the wgpu backend (its traversal stack holds \
                 {STACK} entries: build with max_depth <= {STACK})"
            ),
        });
    }
    Ok(())
}

/// A buffer holding `data`, or one zeroed element when it is empty (a binding is never empty).
fn padded<T: Pod>(ctx: &GpuContext, label: &str, data: &[T]) -> Result<GpuBuffer<T>> {
    ctx.check_storage_binding(label, std::mem::size_of_val(data) as u64)?;
    Ok(if data.is_empty() {
        GpuBuffer::zeroed(ctx, label, 1)?
    } else {
        GpuBuffer::from_slice(ctx, label, data)?
    })
}

/// The GPU kd-tree intersector (variant `kdtree`).
pub struct KdIntersector {
    tree: KdTree,
    nodes: GpuBuffer<KdNode>,
    leaves: GpuBuffer<KdLeaf>,
    leaf_tris: GpuBuffer<u32>,
    tris: GpuBuffer<PreparedTriangle>,
}

impl KdIntersector {
    /// Builds the tree on the host ([`build_tree_for`]; `spec.test` must be `mt`) and uploads
    /// it.
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<KdIntersector> {
        super::require_mt(spec, "kdtree")?;
        let tree = build_tree_for(&scene.scene, spec)?;
        KdIntersector::from_tree(scene, tree)
    }

    /// Uploads `tree`, built on the host over `scene`'s triangle ids (the triangles
    /// Möller-Trumbore can hit), once [`check_tree`] accepts it.
    pub fn from_tree(scene: &Arc<GpuScene>, tree: KdTree) -> Result<KdIntersector> {
        check_tree(&tree, scene.scene.triangle_count())?;
        let ctx = scene.ctx();
        let set = TriangleSet::<MollerTrumbore>::new(&scene.scene);
        Ok(KdIntersector {
            nodes: padded(ctx, "crsh kdtree nodes", &tree.nodes)?,
            leaves: padded(ctx, "crsh kdtree leaves", &tree.leaves)?,
            leaf_tris: padded(ctx, "crsh kdtree leaf triangles", &tree.leaf_tris)?,
            tris: padded(ctx, "crsh kdtree triangles", set.triangles())?,
            tree,
        })
    }

    /// The tree on the device (host copy).
    pub fn tree(&self) -> &KdTree {
        &self.tree
    }
}

impl Intersector<Wgpu> for KdIntersector {
    fn name(&self) -> &str {
        "kdtree"
    }

    fn supports_candidates(&self) -> bool {
        false
    }

    fn intersect(
        &self,
        backend: &Wgpu,
        rays: &GpuBuffer<Ray>,
        query: Query<'_, Wgpu>,
        mode: HitMode,
        hits: &mut GpuBuffer<Hit>,
        stats: &mut Stats,
    ) -> Result<()> {
        query.whole_scene_only("kdtree")?;
        #[allow(unreachable_patterns)] // Modes added to HitMode later are refused.
        let any_hit = match mode {
            HitMode::Closest => false,
            HitMode::Any => true,
            other => {
                return Err(CoreError::Unsupported {
                    stage: "intersect",
                    variant: "kdtree".into(),
                    what: format!("hit mode {other:?} on the wgpu backend"),
                })
            }
        };
        crsh_core::ray::check_hits_per_ray("rays", rays.len(), hits.len())?;
        if rays.is_empty() {
            return Ok(());
        }
        let ctx = backend.context();
        let k = ctx.kernel(KdKernels::new)?;
        let counters = GpuBuffer::<u32>::zeroed(ctx, "crsh kdtree counters", 8)?;
        let b = &self.tree.bounds;
        dispatch_chunks::<Ray>(
            ctx,
            &k.kernel,
            "crsh kdtree",
            "traverse",
            rays.len(),
            |range| {
                let params = Params {
                    n: range.len() as u32,
                    any_hit: u32::from(any_hit),
                    first: range.start as u32,
                    n_nodes: self.tree.nodes.len() as u32,
                    lo: b.min.extend(0.0).to_array(),
                    hi: b.max.extend(0.0).to_array(),
                    zero: 0,
                    pad: [0; 3],
                };
                let u = uniform(ctx, "crsh kdtree params", &params);
                k.kernel.bind_group(
                    ctx,
                    &[
                        u.as_entire_binding(),
                        rays.slice_binding(range.clone()),
                        self.nodes.binding(),
                        self.leaves.binding(),
                        self.leaf_tris.binding(),
                        self.tris.binding(),
                        hits.slice_binding(range.clone()),
                        counters.binding(),
                    ],
                )
            },
        )?;
        let c = counters.to_vec(ctx)?;
        super::brute::check_invalid(c[6])?;
        if c[7] & 1 != 0 {
            return Err(CoreError::Backend(format!(
                "kdtree traversal stack ({STACK} entries) overflowed"
            )));
        }
        if c[7] & 2 != 0 {
            return Err(CoreError::Backend(format!(
                "the adapter ({}) cut a kdtree traversal loop short (llvmpipe ends an \
                 invocation's loops after 65535 iterations in all); its hits would be wrong",
                ctx.info().name
            )));
        }
        let wide = |at: usize| u64::from(c[at]) | (u64::from(c[at + 1]) << 32);
        KdCounts {
            inner: wide(0),
            leaves: wide(2),
            tests: wide(4),
        }
        .record(stats);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crsh_core::Aabb;
    use crsh_cpu::kdtree::LEAF;

    /// The generated constants read back as the CPU's, bit for bit.
    #[test]
    fn kernel_constants_are_the_cpu_ones() {
        let src = source();
        for (name, want) in [("T_SLACK", T_SLACK), ("CELL_MARGIN", CELL_MARGIN)] {
            let decl = format!("const {name}: f32 = ");
            let at = src.find(&decl).expect(name) + decl.len();
            let lit = &src[at..at + src[at..].find("f;").expect(name)];
            let got: f32 = lit.parse().expect(lit);
            assert_eq!(got.to_bits(), want.to_bits(), "{name} = {lit}");
        }
        assert!(src.contains(&format!("const STACK: u32 = {STACK}u;")));
        assert!(src.contains("fn mt_hit(") && src.contains("fn traverse("));
    }

    /// A chain of `depth` inner nodes halving x towards 0, empty leaves on the right.
    fn chain(depth: u32) -> KdTree {
        let mut tree = KdTree {
            bounds: Aabb {
                min: crsh_core::glam::Vec3::ZERO,
                max: crsh_core::glam::Vec3::ONE,
            },
            depth,
            ..KdTree::default()
        };
        let mut hi = 1.0f32;
        tree.nodes.push(KdNode {
            split: 0.5,
            axis: 0,
            index: 1,
        });
        for level in 1..=depth {
            let split = hi * 0.5;
            let mut push_leaf = |lo: f32, hi: f32| {
                tree.leaves.push(KdLeaf {
                    min: [lo, 0.0, 0.0],
                    start: 0,
                    max: [hi, 1.0, 1.0],
                    count: 0,
                });
                KdNode {
                    split: 0.0,
                    axis: LEAF,
                    index: tree.leaves.len() as u32 - 1,
                }
            };
            let left = if level == depth {
                push_leaf(0.0, split)
            } else {
                KdNode {
                    split: split * 0.5,
                    axis: 0,
                    index: 0,
                }
            };
            let right = push_leaf(split, hi);
            let at = tree.nodes.len() as u32;
            let left = KdNode {
                index: if left.axis == LEAF {
                    left.index
                } else {
                    at + 2
                },
                ..left
            };
            tree.nodes.extend([left, right]);
            hi = split;
        }
        tree
    }

    #[test]
    fn trees_deeper_than_the_stack_are_refused() {
        check_tree(&KdTree::default(), 0).unwrap();
        let ok = chain(STACK);
        assert_eq!(walked_depth(&ok), STACK);
        check_tree(&ok, 0).unwrap();
        let deep = chain(STACK + 1);
        deep.validate().unwrap();
        match check_tree(&deep, 0) {
            Err(CoreError::Unsupported { what, .. }) => {
                assert!(what.contains(&format!("depth {}", STACK + 1)), "{what}")
            }
            other => panic!("{other:?}"),
        }
        // The depth is walked, not read from the tree.
        let lying = KdTree { depth: 1, ..deep };
        assert!(check_tree(&lying, 0).is_err());
    }

    #[test]
    fn bad_trees_are_refused() {
        let mut t = chain(2);
        t.leaves[0].count = 1;
        t.leaf_tris.push(5);
        check_tree(&t, 6).unwrap();
        let e = check_tree(&t, 5).unwrap_err();
        assert!(
            e.to_string().contains("triangle 5 is not in the scene"),
            "{e}"
        );
        let mut t = chain(2);
        t.nodes[0].split = 2.0;
        assert!(matches!(check_tree(&t, 0), Err(CoreError::InvalidInput(_))));
    }

    fn spec(max_depth: i64, leaf_size: i64) -> StageSpec {
        let mut s = StageSpec::new("kdtree");
        for p in &info().params {
            s.params.insert(p.name.into(), p.default.clone());
        }
        s.params
            .insert("max_depth".into(), crsh_core::ParamValue::Int(max_depth));
        s.params
            .insert("leaf_size".into(), crsh_core::ParamValue::Int(leaf_size));
        s
    }

    /// The host build is the CPU twin's, over the triangles Möller-Trumbore can hit, with its
    /// parameters; depths past the stack are refused.
    #[test]
    fn build_is_the_cpu_twins() {
        let scene = crsh_scene::builtin::build("cornell-mirrors").unwrap();
        for (depth, leaf_size) in [(0, 1), (4, 1), (12, 8)] {
            let s = spec(depth, leaf_size);
            let t = build_tree_for(&scene, &s).unwrap();
            let cpu = crsh_cpu::intersect::kdtree::build_tree(&scene, &s, TestKind::MollerTrumbore)
                .unwrap();
            assert_eq!(t, cpu);
            t.validate().unwrap();
            if depth > 0 {
                assert!(i64::from(t.depth) <= depth);
            }
            assert_eq!(walked_depth(&t), t.depth);
        }
        assert!(build_tree_for(&scene, &spec(i64::from(STACK) + 1, 1)).is_err());
        assert!(build_tree_for(&scene, &spec(4, -1)).is_err());
    }
}
