//! `auto_shape`: the sphere-cone hierarchy ([`super::sphere_cone`]) with its shape
//! (subdivision and depth) chosen per ray kind from a sampled pre-pass (issue 17's
//! auto-configuration; seed 000 §4 measures subdivisions 8 and 16 and depths 2-4 and finds no
//! shape best everywhere).
//!
//! # The pre-pass
//!
//! On the first batch of each ray kind the builder sees, it takes a sample of the batch in
//! sorted order: the first block of [`BLOCK`] consecutive leaves and then one in every
//! `sample` (param, default 64, so 1/64 of a big batch; a batch of one block is taken whole).
//! Blocks of consecutive leaves keep the coherence the sort created, which a sample of
//! scattered rays would destroy. For every shape of parameter `shapes` (default
//! [`DEFAULT_SHAPES`]) it builds the sphere-cone hierarchy over the sample and traverses it
//! with the [`Dual`] traverser (LBVH objects, box test and single rays, built once with the
//! stage) against the scene, and estimates the shape's cost per
//! sampled ray in units of one ray-triangle test as
//!
//! `B · bound tests + Σ over candidates of the candidate's rays`,
//!
//! with every ray of a candidate tested (its lane mask's rays for a single-ray candidate, else
//! all of its node's: an upper bound, since any-hit rays stop earlier) and `B` the
//! `bound_cost` parameter, what one bound test costs against one ray-triangle test. The
//! cheapest shape (the first listed on a tie) is kept for that ray kind for the rest of
//! the stage's life (a frame of a moving scene, every frame of a static one), and the full
//! batch's hierarchy is built with it. The choice, every shape's estimate and its two parts go
//! to [`Stats::choices`] (`hierarchy.<kind>`), so the summary and the stats JSON show what was
//! picked and why.
//!
//! # The weight of a bound test
//!
//! `B = 1` counts tests, the figure the issue measures; but a bound test (a pair of the `dual`
//! traversal: boxes, the cone-sphere test in `f64`, the split) costs more than a ray-triangle
//! test (one lane of an 8-ray packet), so the shape with the fewest tests is not the fastest:
//! at 1024² on this project's 2-core machine, 8/3 needs the fewest tests on Sponza (45.9M
//! against 16/3's 46.3M) and traces 1.43 Mrays/s, 16/3 1.75. The stage times give the ratio:
//! `traversal` ms per bound test over `final_tests` ms per ray-triangle test is 2.6 on
//! Sponza, 2.5 on the dining room and 4.3 on cornell-mirror (whose traversal is dominated by
//! per-ray work), so the default is `B = 3`; it picks 16/3 for Sponza's shadow rays at 1024²
//! (1.65 Mrays/s against 1.49 with `B = 1`). It is a proxy, not a model: the time of one test
//! of either kind itself changes with the shape (16-ray nodes fill two packets and split into
//! single rays in one step), and at 512² both weights pick 8/3 on Sponza where 16/2 is the
//! fastest (README, `plans/dual.toml`). The estimate is deterministic (a function of the rays,
//! the order, the scene and `B`), as the pipeline requires: it weighs counts, it does not time
//! them.
//!
//! # Small batches
//!
//! A batch of fewer than `min_batch` rays (default [`DEFAULT_MIN_BATCH`], 64 blocks) gets the
//! default shape ([`DEFAULT_SUBDIVISION`]/[`DEFAULT_DEPTH`]) without a pre-pass, and no choice
//! is kept for its kind: a later, larger batch of that kind still runs one. Below 64 blocks
//! the first block is more than 1/64 of the batch, and a traversal of it per shape costs as
//! much as a good part of the batch's own (the dining room's 7,716 reflection rays: 1,024
//! sampled at about 470 tests per ray, about 100 ms, more than the shape could save). The
//! stats' choice line says so.
//!
//! Its cost is the sample's traversals, one per shape over 1/64 of the rays (measured on
//! Sponza 1024² shadow rays: 1/16 of the rays and six shapes added 260 ms to the hierarchy
//! stage), once per ray kind, plus the probe's LBVH build at stage construction. It is timed
//! with the hierarchy stage.
//!
//! # The shapes compared
//!
//! Parameter `shapes` lists them as `subdivision/depth` pairs separated by commas, in the
//! order the tie rule uses; the default [`DEFAULT_SHAPES`] is seed 000 §4's subdivisions 8
//! and 16 at depths 2 and 3. Subdivision 4 is left out by default: its sample traversals are
//! the slowest (on Sponza's 19,456 sampled shadow rays 4/2 and 4/3 took 11-17 ms each against
//! 5-10 ms for the others, half of the pre-pass), and on the three scenes of issue 17 it was
//! never the estimate's pick nor the fastest fixed shape (`plans/dual.toml`). Any shape the
//! sphere-cone builder accepts may be listed (`--set hierarchy.shapes=4/2,4/3,8/2,8/3`).
//!
//! # Errors
//!
//! As [`super::sphere_cone`]: [`CoreError::InvalidInput`] for an order that is not a
//! permutation of the rays or a ray that is not usable; [`CoreError::InvalidParam`] for a
//! `sample` outside 1..=1024.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use rayon::prelude::*;

use crsh_core::{
    lowest_node_leaves, CoreError, HierarchyBuilder, ParamInfo, Ray, RayHierarchy, RayKind,
    Registry, Result, StageKind, StageSpec, StageVariantInfo, Stats, ALL_LANES,
};
use crsh_scene::Scene;

use super::sphere_cone::{
    validate_leaves, LeafCone, LeafSphere, SphereConeBuilder, DEFAULT_DEPTH, DEFAULT_SUBDIVISION,
};
use crate::backend::Cpu;
use crate::traverse::dual::Dual;

/// The default of parameter `shapes`: the shapes compared, as `subdivision/depth` pairs.
pub const DEFAULT_SHAPES: &str = "8/2,8/3,16/2,16/3";
/// The most shapes one pre-pass compares.
pub const MAX_SHAPES: usize = 16;
/// Consecutive sorted leaves per sample block.
pub const BLOCK: usize = 1024;

/// The catalogue entry of this variant.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Hierarchy,
        "auto_shape",
        "the sphere-cone hierarchy with subdivision and depth chosen per ray kind by a \
         pre-pass: each shape of `shapes` traversed (dual, LBVH) over a sample of the \
         sorted batch, the fewest estimated tests kept (issue 17's auto-configuration)",
    )
    .param(ParamInfo::choice(
        "shapes",
        DEFAULT_SHAPES,
        &[],
        "the shapes the pre-pass compares, `subdivision/depth` pairs separated by commas \
         (first listed wins a tie; at most 16)",
    ))
    .param(ParamInfo::int(
        "sample",
        64,
        1,
        1024,
        "the first block of 1024 consecutive sorted rays and then one in every `sample` go \
         into the pre-pass",
    ))
    .param(ParamInfo::int(
        "min_batch",
        DEFAULT_MIN_BATCH as i64,
        0,
        MAX_MIN_BATCH as i64,
        "batches of fewer rays get the default shape 8/2 without a pre-pass (and no choice is \
         kept for their ray kind)",
    ))
    .param(
        ParamInfo::float(
            "bound_cost",
            DEFAULT_BOUND_COST,
            "what one bound test costs in the pre-pass's estimate, in ray-triangle tests \
             (1: count tests; 3, the default, is the time ratio measured on 2 CPU cores)",
        )
        .range(0.0, MAX_BOUND_COST),
    )
    .param(ParamInfo::choice(
        "leaf_cone",
        "incremental",
        &["incremental", "extremes"],
        "how lowest cone axes are found, in the pre-pass's hierarchies and the batch's \
         (`sphere_cone`'s parameter of the same name)",
    ))
    .param(ParamInfo::choice(
        "leaf_sphere",
        "welzl",
        &LeafSphere::NAMES,
        "how lowest sphere centres are found, in the pre-pass's hierarchies and the batch's \
         (`sphere_cone`'s parameter of the same name)",
    ))
}

/// The shape of batches without a pre-pass: the sphere-cone builder's defaults.
const DEFAULT_SHAPE: (u32, u32) = (DEFAULT_SUBDIVISION, DEFAULT_DEPTH);

/// The smallest batch that gets a pre-pass by default: 64 blocks (see *Small batches*).
pub const DEFAULT_MIN_BATCH: usize = 64 * BLOCK;

/// The largest `min_batch`.
pub const MAX_MIN_BATCH: u32 = 1 << 30;

/// The default weight of a bound test against a ray-triangle test (see the module doc).
pub const DEFAULT_BOUND_COST: f64 = 3.0;

/// The largest `bound_cost` (the smallest is 0).
pub const MAX_BOUND_COST: f64 = 1000.0;

/// Registers `auto_shape` ([`info`], [`AutoShape::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_hierarchy(info(), |ctx, spec| {
        Ok(Box::new(AutoShape::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

/// Parses a `shapes` list: `subdivision/depth` pairs separated by commas (spaces allowed),
/// each one the sphere-cone builder accepts, at least one and at most [`MAX_SHAPES`], none
/// twice.
///
/// # Errors
/// [`CoreError::InvalidParam`] (key `auto_shape.shapes`) naming the entry that is not a pair
/// of integers, is out of the builder's range or repeats one, or the list's length.
pub fn parse_shapes(list: &str) -> Result<Vec<(u32, u32)>> {
    let shapes = list
        .split(',')
        .map(|entry| {
            let entry = entry.trim();
            entry
                .split_once('/')
                .and_then(|(s, d)| Some((s.trim().parse().ok()?, d.trim().parse().ok()?)))
                .ok_or_else(|| {
                    bad_shapes(format!(
                        "`{entry}` is not subdivision/depth (e.g. `{DEFAULT_SHAPES}`)"
                    ))
                })
        })
        .collect::<Result<Vec<_>>>()?;
    check_shapes(shapes)
}

fn bad_shapes(reason: String) -> CoreError {
    CoreError::InvalidParam {
        key: "auto_shape.shapes".into(),
        reason,
    }
}

/// `shapes` if it is a list [`parse_shapes`] accepts.
fn check_shapes(shapes: Vec<(u32, u32)>) -> Result<Vec<(u32, u32)>> {
    if shapes.is_empty() || shapes.len() > MAX_SHAPES {
        return Err(bad_shapes(format!(
            "{} shapes, want 1..={MAX_SHAPES}",
            shapes.len()
        )));
    }
    for (i, &(sub, depth)) in shapes.iter().enumerate() {
        SphereConeBuilder::with_params(sub, depth)
            .map_err(|e| bad_shapes(format!("`{sub}/{depth}`: {e}")))?;
        if shapes[..i].contains(&(sub, depth)) {
            return Err(bad_shapes(format!("`{sub}/{depth}` is listed twice")));
        }
    }
    Ok(shapes)
}

/// The shape one pre-pass picked, with every shape's estimate.
#[derive(Clone, Debug, PartialEq)]
pub struct ShapeChoice {
    /// The kept (subdivision, depth).
    pub shape: (u32, u32),
    /// The shapes compared (parameter `shapes`), in their order.
    pub shapes: Vec<(u32, u32)>,
    /// Rays in the sample.
    pub sample_rays: usize,
    /// Rays in the batch the sample came from.
    pub batch_rays: usize,
    /// The weight of a bound test the estimates use (`bound_cost`).
    pub bound_cost: f64,
    /// Bound tests per sampled ray of each shape of `shapes`, in that order.
    pub bounds: Vec<f64>,
    /// Ray-triangle tests per sampled ray of each shape (every ray of every candidate).
    pub final_tests: Vec<f64>,
}

impl ShapeChoice {
    /// Estimated cost per sampled ray of each shape of `shapes`, in that order:
    /// `bound_cost · bounds + final tests` (see the module doc).
    pub fn estimates(&self) -> Vec<f64> {
        self.bounds
            .iter()
            .zip(&self.final_tests)
            .map(|(b, f)| self.bound_cost * b + f)
            .collect()
    }

    /// One line for [`Stats::choices`].
    pub fn describe(&self) -> String {
        let est: Vec<String> = self
            .shapes
            .iter()
            .zip(self.estimates())
            .zip(self.bounds.iter().zip(&self.final_tests))
            .map(|(((s, d), e), (b, f))| format!("{s}/{d} {e:.1} ({b:.1} + {f:.1})"))
            .collect();
        format!(
            "subdivision {} depth {} (sample {} of {} rays; estimated cost per ray, {} × bound \
             tests + ray-triangle tests: {})",
            self.shape.0,
            self.shape.1,
            self.sample_rays,
            self.batch_rays,
            self.bound_cost,
            est.join(", ")
        )
    }
}

/// The `auto_shape` builder (see the module doc).
pub struct AutoShape {
    probe: Dual,
    sample: usize,
    shapes: Vec<(u32, u32)>,
    bound_cost: f64,
    min_batch: usize,
    leaf_cone: LeafCone,
    leaf_sphere: LeafSphere,
    chosen: Mutex<BTreeMap<u32, ShapeChoice>>,
}

impl AutoShape {
    /// The builder over `scene` with `spec`'s `sample`, `shapes`, `bound_cost` and
    /// `min_batch`; builds the probe's object hierarchy.
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<AutoShape> {
        Ok(
            AutoShape::with_sample(scene, spec.u32_in("sample", 1..=1024)? as usize)?
                .with_shapes(&parse_shapes(spec.str("shapes")?)?)?
                .with_bound_cost(spec.f64("bound_cost")?)?
                .with_min_batch(spec.u32_in("min_batch", 0..=MAX_MIN_BATCH)? as usize)
                .with_leaf_cone(LeafCone::parse(spec.str("leaf_cone")?).ok_or_else(|| {
                    CoreError::InvalidParam {
                        key: "auto_shape.leaf_cone".into(),
                        reason: "not one of incremental, extremes".into(),
                    }
                })?)
                .with_leaf_sphere(LeafSphere::of("auto_shape", spec)?),
        )
    }

    /// The builder finding lowest sphere centres by `leaf_sphere` in every hierarchy it builds
    /// (parameter `leaf_sphere`; [`AutoShape::with_sample`] starts with Welzl's).
    pub fn with_leaf_sphere(self, leaf_sphere: LeafSphere) -> AutoShape {
        AutoShape {
            leaf_sphere,
            ..self
        }
    }

    /// The builder finding lowest cone axes by `leaf_cone` in every hierarchy it builds
    /// (parameter `leaf_cone`; [`AutoShape::with_sample`] starts with eq. 3.8-3.11).
    pub fn with_leaf_cone(self, leaf_cone: LeafCone) -> AutoShape {
        AutoShape { leaf_cone, ..self }
    }

    /// The sphere-cone builder of shape `(sub, depth)` with this builder's `leaf_cone` and
    /// `leaf_sphere`.
    fn builder(&self, sub: u32, depth: u32) -> Result<SphereConeBuilder> {
        Ok(SphereConeBuilder::with_params(sub, depth)?
            .with_leaf_cone(self.leaf_cone)
            .with_leaf_sphere(self.leaf_sphere))
    }

    /// The builder with one block in `sample` (1..=1024) sampled, and the default `shapes`,
    /// `bound_cost` and `min_batch`.
    pub fn with_sample(scene: &Arc<Scene>, sample: usize) -> Result<AutoShape> {
        if !(1..=1024).contains(&sample) {
            return Err(CoreError::InvalidParam {
                key: "auto_shape.sample".into(),
                reason: format!("{sample} is outside 1..=1024"),
            });
        }
        Ok(AutoShape {
            probe: Dual::with_options(scene, "lbvh", 64.0)?,
            sample,
            shapes: parse_shapes(DEFAULT_SHAPES)?,
            bound_cost: DEFAULT_BOUND_COST,
            min_batch: DEFAULT_MIN_BATCH,
            leaf_cone: LeafCone::Incremental,
            leaf_sphere: LeafSphere::Welzl,
            chosen: Mutex::new(BTreeMap::new()),
        })
    }

    /// The builder comparing `shapes` ((subdivision, depth) pairs, in tie order; as
    /// [`parse_shapes`] checks them).
    pub fn with_shapes(self, shapes: &[(u32, u32)]) -> Result<AutoShape> {
        Ok(AutoShape {
            shapes: check_shapes(shapes.to_vec())?,
            ..self
        })
    }

    /// The shapes the pre-pass compares.
    pub fn shapes(&self) -> &[(u32, u32)] {
        &self.shapes
    }

    /// The builder with a bound test weighing `cost` ray-triangle tests (0 ..=
    /// [`MAX_BOUND_COST`]).
    pub fn with_bound_cost(self, cost: f64) -> Result<AutoShape> {
        if !(0.0..=MAX_BOUND_COST).contains(&cost) {
            return Err(CoreError::InvalidParam {
                key: "auto_shape.bound_cost".into(),
                reason: format!("{cost} is outside 0..={MAX_BOUND_COST}"),
            });
        }
        Ok(AutoShape {
            bound_cost: cost,
            ..self
        })
    }

    /// The builder that runs the pre-pass on batches of `rays` rays or more (0: on every
    /// batch).
    pub fn with_min_batch(self, rays: usize) -> AutoShape {
        AutoShape {
            min_batch: rays,
            ..self
        }
    }

    /// The shape chosen for rays of `kind` so far, if any.
    pub fn choice(&self, kind: RayKind) -> Option<ShapeChoice> {
        self.lock().get(&(kind as u32)).cloned()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, BTreeMap<u32, ShapeChoice>> {
        self.chosen
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Runs the pre-pass over `rays` in `order` for rays of `kind`: the sample, every shape's
    /// estimate, the cheapest shape. Errors as the `sphere_cone` builder on a bad order or
    /// unusable rays.
    pub fn pre_pass(&self, rays: &[Ray], order: &[u32], kind: RayKind) -> Result<ShapeChoice> {
        validate_leaves("auto_shape", rays, order)?;
        let sampled: Vec<u32> = order
            .chunks(BLOCK)
            .step_by(self.sample)
            .flatten()
            .copied()
            .collect();
        let sample_rays: Vec<Ray> = sampled.iter().map(|&i| rays[i as usize]).collect();
        let n = sample_rays.len();
        let per_ray = |x: u64| if n == 0 { 0.0 } else { x as f64 / n as f64 };
        // The shapes in parallel (a deep shape over a small sample has few top nodes, so its
        // own traversal leaves cores idle); each shape's counts are its own, in list order.
        let parts = self
            .shapes
            .par_iter()
            .map(|&(sub, depth)| -> Result<(f64, f64)> {
                // The hierarchy the stage would build for the sample (reach bounds included).
                let h = self.builder(sub, depth)?.build(
                    &Cpu,
                    &sample_rays,
                    (0..n as u32).collect(),
                    &mut Stats::default(),
                )?;
                let mut final_tests = 0u64;
                let mut scratch = Stats::default();
                self.probe.traverse_with_report(
                    &sample_rays,
                    kind,
                    &h,
                    &mut |batch, _| {
                        // A candidate's rays: those its lane mask names, else its node's.
                        let masks = batch.lanes.as_deref();
                        final_tests += batch
                            .pairs
                            .iter()
                            .enumerate()
                            .map(|(i, c)| {
                                let rays = lowest_node_leaves(c.node as usize, sub, None, n).len();
                                match masks.map(|m| m[i]) {
                                    Some(m) if m != ALL_LANES => m.count_ones() as u64,
                                    _ => rays as u64,
                                }
                            })
                            .sum::<u64>();
                        Ok(())
                    },
                    &mut scratch,
                )?;
                Ok((per_ray(scratch.tests.bounds), per_ray(final_tests)))
            })
            .collect::<Result<Vec<_>>>()?;
        let (bounds, finals) = parts.into_iter().unzip();
        let mut choice = ShapeChoice {
            shape: self.shapes[0],
            shapes: self.shapes.clone(),
            sample_rays: n,
            batch_rays: order.len(),
            bound_cost: self.bound_cost,
            bounds,
            final_tests: finals,
        };
        let estimates = choice.estimates();
        let best = (0..self.shapes.len())
            .min_by(|&a, &b| estimates[a].total_cmp(&estimates[b]).then(a.cmp(&b)))
            .expect("at least one shape");
        choice.shape = self.shapes[best];
        Ok(choice)
    }
}

impl HierarchyBuilder<Cpu> for AutoShape {
    fn name(&self) -> &str {
        "auto_shape"
    }

    fn build(
        &self,
        backend: &Cpu,
        rays: &Vec<Ray>,
        order: Vec<u32>,
        stats: &mut Stats,
    ) -> Result<RayHierarchy<Cpu>> {
        // Without a first ray (no rays, or an order the builder refuses) there is nothing to
        // choose for: the default shape's builder answers.
        let kind = order
            .first()
            .and_then(|&i| rays.get(i as usize))
            .map(Ray::ray_kind);
        let (sub, depth) = match kind {
            None => DEFAULT_SHAPE,
            Some(kind) => {
                let (shape, line) = match self.choice(kind) {
                    Some(c) => (c.shape, c.describe()),
                    None if order.len() < self.min_batch => (
                        DEFAULT_SHAPE,
                        format!(
                            "subdivision {DEFAULT_SUBDIVISION} depth {DEFAULT_DEPTH} (the default: \
                             a batch of {} rays is below min_batch {}, no pre-pass)",
                            order.len(),
                            self.min_batch
                        ),
                    ),
                    None => {
                        let c = self.pre_pass(rays, &order, kind)?;
                        self.lock().insert(kind as u32, c.clone());
                        (c.shape, c.describe())
                    }
                };
                stats.add_choice("hierarchy", kind, line);
                shape
            }
        };
        self.builder(sub, depth)?.build(backend, rays, order, stats)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crsh_core::ParamValue;

    /// One frame of built-in `name` with the `crsh` preset, `dual` traversal and `auto_shape`
    /// (two sample blocks), on `threads` threads, checked against brute force.
    fn frame(name: &str, threads: usize) -> crsh_core::Frame<Cpu> {
        let scene = Arc::new(crsh_scene::builtin::build(name).unwrap());
        let sets = [
            "traverse.kind=dual",
            "hierarchy.kind=auto_shape",
            "hierarchy.sample=2",
            "hierarchy.min_batch=0",
        ];
        crate::traverse::dual::tests::frame(&scene, &sets.map(String::from), threads)
    }

    #[test]
    fn frames_are_exact_and_report_the_choice_per_kind() {
        for name in ["cornell-mirrors", "office-boxes"] {
            let f = frame(name, 1);
            assert_eq!(f.stats.stages["hierarchy"], "auto_shape", "{name}");
            let acc = f.stats.accuracy.clone().unwrap();
            assert!(acc.rays > 0);
            assert_eq!(acc.agreeing, acc.rays, "{name}: {acc:?}");
            for kind in f.stats.per_kind.keys() {
                if kind == "primary" {
                    continue;
                }
                let choice = &f.stats.choices[&format!("hierarchy.{kind}")];
                assert!(choice.starts_with("subdivision "), "{choice}");
                assert!(
                    choice.contains(
                        "estimated cost per ray, 3 × bound tests + ray-triangle tests: 8/2 "
                    ),
                    "{choice}"
                );
            }
            let three = frame(name, 3);
            assert_eq!(three.image, f.image, "{name}");
            assert_eq!(three.stats.choices, f.stats.choices, "{name}");
            assert_eq!(three.stats.tests, f.stats.tests, "{name}");
        }
    }

    #[test]
    fn the_pre_pass_keeps_the_cheapest_shape_and_samples_blocks() {
        let scene = Arc::new(crsh_scene::builtin::build("office-boxes").unwrap());
        // Shadow segments from the first light to points on the triangles, in triangle
        // order (coherent runs).
        let light = scene.lights[0].position;
        let rays: Vec<Ray> = (0..5000)
            .map(|i| {
                let [a, b, c] = scene.triangle(i % scene.triangle_count());
                let w = (i / scene.triangle_count()) as f32 * 0.07 % 0.3;
                let p = a * (0.4 + w) + b * (0.3 - w / 2.0) + c * (0.3 - w / 2.0);
                let d = p - light;
                let mut r = crate::intersect::brute::tests::test_ray(
                    light,
                    d.normalize(),
                    1e-4,
                    d.length() * 0.999,
                    i,
                );
                r.kind = RayKind::Shadow as u32;
                r
            })
            .collect();
        let order: Vec<u32> = (0..rays.len() as u32).collect();
        let auto = AutoShape::with_sample(&scene, 2).unwrap();
        let c = auto.pre_pass(&rays, &order, RayKind::Shadow).unwrap();
        // Every other block of 1024 sorted leaves.
        let want: usize = order.chunks(BLOCK).step_by(2).map(<[u32]>::len).sum();
        assert_eq!((c.sample_rays, c.batch_rays), (want, rays.len()));
        assert_eq!(c.shapes, parse_shapes(DEFAULT_SHAPES).unwrap());
        assert_eq!(c.estimates().len(), c.shapes.len());
        let best = c.estimates().iter().copied().fold(f64::INFINITY, f64::min);
        let at = c.shapes.iter().position(|s| *s == c.shape).unwrap();
        assert_eq!(c.estimates()[at], best);
        assert!(
            c.estimates().iter().all(|e| e.is_finite() && *e > 0.0),
            "{c:?}"
        );
        // The estimates are the dual traversal's, and depend on the shape.
        assert!(c.estimates().iter().any(|e| *e != best), "{c:?}");
        // A small batch is sampled whole; the sample size is checked.
        let few = &rays[..BLOCK];
        let small = auto
            .pre_pass(few, &order[..BLOCK], RayKind::Shadow)
            .unwrap();
        assert_eq!(small.sample_rays, BLOCK);
        // A bad order is refused.
        assert!(auto
            .pre_pass(&rays, &order[..BLOCK], RayKind::Shadow)
            .is_err());
        assert!(AutoShape::with_sample(&scene, 0).is_err());
        assert!(AutoShape::with_sample(&scene, 1025).is_err());
        for bad in [-1.0, 1001.0, f64::NAN] {
            let a = AutoShape::with_sample(&scene, 2).unwrap();
            assert!(a.with_bound_cost(bad).is_err(), "{bad}");
        }
        // The weight only re-weighs the same counts: a shape's parts do not depend on it, and
        // with bound tests free the cheapest shape is the one with the fewest final tests.
        let free = AutoShape::with_sample(&scene, 2)
            .unwrap()
            .with_bound_cost(0.0)
            .unwrap()
            .pre_pass(&rays, &order, RayKind::Shadow)
            .unwrap();
        assert_eq!(
            (free.bounds.clone(), free.final_tests.clone()),
            (c.bounds.clone(), c.final_tests.clone())
        );
        assert_eq!(free.estimates(), free.final_tests);
        let fewest = free
            .final_tests
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min);
        let at = free.shapes.iter().position(|s| *s == free.shape).unwrap();
        assert_eq!(free.final_tests[at], fewest);
    }

    #[test]
    fn shape_lists_are_parsed_checked_and_compared_in_their_order() {
        assert_eq!(
            parse_shapes(DEFAULT_SHAPES).unwrap(),
            [(8, 2), (8, 3), (16, 2), (16, 3)]
        );
        assert_eq!(parse_shapes(" 4/2 , 16 / 3").unwrap(), [(4, 2), (16, 3)]);
        for bad in [
            "", "8", "8/", "/2", "8/2,", "a/b", "8/2/1", "8/2,8/2", "0/2", "8/0", "-8/2",
        ] {
            let e = parse_shapes(bad).unwrap_err().to_string();
            assert!(e.contains("shapes"), "{bad}: {e}");
        }
        let many: Vec<String> = (2..=2 + MAX_SHAPES as u32)
            .map(|s| format!("{s}/2"))
            .collect();
        assert!(parse_shapes(&many.join(",")).is_err());
        assert!(parse_shapes(&many[..MAX_SHAPES].join(",")).is_ok());

        // A shape's estimate does not depend on the others listed; the pick is among those
        // listed; the stage's parameter reaches the pre-pass.
        let scene = Arc::new(crsh_scene::builtin::build("office-boxes").unwrap());
        let rays = crate::intersect::brute::tests::random_rays(&scene, 3, 2000);
        let order: Vec<u32> = (0..rays.len() as u32).collect();
        let kind = RayKind::from_u32(rays[0].kind).unwrap();
        let all = AutoShape::with_sample(&scene, 1)
            .unwrap()
            .pre_pass(&rays, &order, kind)
            .unwrap();
        let two = AutoShape::with_sample(&scene, 1)
            .unwrap()
            .with_shapes(&[(16, 3), (4, 2)])
            .unwrap();
        assert!(AutoShape::with_sample(&scene, 1)
            .unwrap()
            .with_shapes(&[])
            .is_err());
        let c = two.pre_pass(&rays, &order, kind).unwrap();
        assert_eq!(c.shapes, [(16, 3), (4, 2)]);
        assert_eq!(c.bounds[0], all.bounds[3]);
        assert_eq!(c.final_tests[0], all.final_tests[3]);
        let e = c.estimates();
        assert_eq!(c.shape, if e[1] < e[0] { (4, 2) } else { (16, 3) });
        assert!(c.describe().contains(": 16/3 "), "{}", c.describe());
        let mut spec = StageSpec::new("auto_shape");
        for (k, v) in [
            ("sample", ParamValue::Int(1)),
            ("shapes", ParamValue::Str("16/3,4/2".into())),
            ("bound_cost", ParamValue::Float(3.0)),
            ("min_batch", ParamValue::Int(0)),
            ("leaf_cone", ParamValue::Str("incremental".into())),
            ("leaf_sphere", ParamValue::Str("welzl".into())),
        ] {
            spec.params.insert(k.into(), v);
        }
        let from_spec = AutoShape::new(&scene, &spec).unwrap();
        assert_eq!(from_spec.shapes(), [(16, 3), (4, 2)]);
        assert_eq!(from_spec.pre_pass(&rays, &order, kind).unwrap(), c);
        let mut bad = spec.clone();
        bad.params
            .insert("leaf_cone".into(), ParamValue::Str("widest".into()));
        assert!(AutoShape::new(&scene, &bad).is_err());
        let mut bad = spec.clone();
        bad.params
            .insert("leaf_sphere".into(), ParamValue::Str("ritter".into()));
        assert!(AutoShape::new(&scene, &bad).is_err());
        spec.params
            .insert("shapes".into(), ParamValue::Str("16/3,99/2".into()));
        assert!(AutoShape::new(&scene, &spec).is_err());
    }

    #[test]
    fn small_batches_get_the_default_shape_and_leave_the_choice_open() {
        let scene = Arc::new(crsh_scene::builtin::build("office-boxes").unwrap());
        let rays = crate::intersect::brute::tests::random_rays(&scene, 9, 3000);
        let order: Vec<u32> = (0..rays.len() as u32).collect();
        let kind = RayKind::from_u32(rays[0].kind).unwrap();
        let auto = AutoShape::with_sample(&scene, 2)
            .unwrap()
            .with_min_batch(3001);
        let mut stats = Stats::default();
        let h = auto.build(&Cpu, &rays, order.clone(), &mut stats).unwrap();
        assert_eq!(
            (h.subdivision, h.levels.len() as u32),
            (DEFAULT_SUBDIVISION, DEFAULT_DEPTH)
        );
        let line = &stats.choices[&format!("hierarchy.{}", kind.name())];
        assert!(line.contains("below min_batch 3001, no pre-pass"), "{line}");
        assert!(auto.choice(kind).is_none());
        // The same hierarchy as the default sphere-cone builder's.
        let plain = SphereConeBuilder::with_params(DEFAULT_SUBDIVISION, DEFAULT_DEPTH)
            .unwrap()
            .build(&Cpu, &rays, order.clone(), &mut Stats::default())
            .unwrap();
        assert_eq!(h.levels, plain.levels);
        // With `leaf_cone = extremes`, the sphere-cone builder's extremes hierarchy.
        let extremes = AutoShape::with_sample(&scene, 2)
            .unwrap()
            .with_min_batch(3001)
            .with_leaf_cone(LeafCone::Extremes)
            .build(&Cpu, &rays, order.clone(), &mut Stats::default())
            .unwrap();
        let want = SphereConeBuilder::with_params(DEFAULT_SUBDIVISION, DEFAULT_DEPTH)
            .unwrap()
            .with_leaf_cone(LeafCone::Extremes)
            .build(&Cpu, &rays, order.clone(), &mut Stats::default())
            .unwrap();
        assert_eq!(extremes.levels, want.levels);
        assert_ne!(extremes.levels, plain.levels);
        // With `leaf_sphere = box`, the sphere-cone builder's box-centred hierarchy.
        let boxed = AutoShape::with_sample(&scene, 2)
            .unwrap()
            .with_min_batch(3001)
            .with_leaf_sphere(LeafSphere::BoxCentre)
            .build(&Cpu, &rays, order.clone(), &mut Stats::default())
            .unwrap();
        let want = SphereConeBuilder::with_params(DEFAULT_SUBDIVISION, DEFAULT_DEPTH)
            .unwrap()
            .with_leaf_sphere(LeafSphere::BoxCentre)
            .build(&Cpu, &rays, order.clone(), &mut Stats::default())
            .unwrap();
        assert_eq!(boxed.levels, want.levels);
        assert_ne!(boxed.levels, plain.levels);
        // At the threshold the pre-pass runs, and its choice is kept.
        let auto = auto.with_min_batch(3000);
        let mut stats = Stats::default();
        auto.build(&Cpu, &rays, order, &mut stats).unwrap();
        let kept = auto.choice(kind).expect("a kept choice");
        let line = &stats.choices[&format!("hierarchy.{}", kind.name())];
        assert_eq!(*line, kept.describe());
    }

    #[test]
    fn estimates_are_the_tests_of_a_closest_hit_traversal() {
        // Incoherent rays (single-ray candidates with lane masks), a batch sampled whole: each
        // shape's estimate is its bounds plus the final tests of every candidate's rays,
        // exactly what a closest-hit traversal with that shape counts.
        use crate::intersect::brute::{tests as brute_tests, BruteForce};
        let scene = Arc::new(crsh_scene::builtin::build("office-boxes").unwrap());
        let rays = brute_tests::random_rays(&scene, 5, 900);
        let order: Vec<u32> = (0..rays.len() as u32).collect();
        let auto = AutoShape::with_sample(&scene, 64).unwrap();
        let kind = RayKind::from_u32(rays[0].kind).unwrap();
        let c = auto.pre_pass(&rays, &order, kind).unwrap();
        assert_eq!(c.sample_rays, rays.len());
        let brute = BruteForce::from_scene(&scene);
        let dual = Dual::with_options(&scene, "lbvh", 64.0).unwrap();
        let mut masked = false;
        assert_eq!(c.shapes, auto.shapes());
        for (i, &(sub, depth)) in c.shapes.iter().enumerate() {
            let h = SphereConeBuilder::with_params(sub, depth)
                .unwrap()
                .build(&Cpu, &rays, order.clone(), &mut Stats::default())
                .unwrap();
            let (_, _, stats, _) = crate::traverse::crsh::tests::trace_with(
                &brute,
                &rays,
                &h,
                crsh_core::HitMode::Closest,
                |kind, sink, stats| {
                    dual.traverse_with_report(
                        &rays,
                        kind,
                        &h,
                        &mut |b, s| {
                            masked |= b
                                .lanes
                                .as_ref()
                                .is_some_and(|l| l.iter().any(|&m| m != ALL_LANES));
                            sink(b, s)
                        },
                        stats,
                    )
                },
            );
            let n = rays.len() as f64;
            assert_eq!(c.bounds[i], stats.tests.bounds as f64 / n, "{sub}/{depth}");
            assert_eq!(
                c.final_tests[i],
                stats.tests.ray_triangle as f64 / n,
                "{sub}/{depth}"
            );
            assert_eq!(
                c.estimates()[i],
                DEFAULT_BOUND_COST * c.bounds[i] + c.final_tests[i],
                "{sub}/{depth}"
            );
        }
        assert!(masked, "no single-ray candidate: not a test of the masks");
    }
}
