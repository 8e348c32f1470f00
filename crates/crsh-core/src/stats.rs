//! Counters and timings that every stage feeds.

use std::collections::BTreeMap;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::ray::RayKind;

/// The stage timing keys of [`Stats::timings_ms`] in pipeline order (seed 000 table 4.25's
/// rows, plus primary visibility, whole-scene intersection, shading, and `reordering`: putting
/// a batch into its sorter's order for a whole-scene tracer and its hits back).
pub const STAGE_TIMINGS: [&str; 13] = [
    "primary",
    "ray_creation",
    "trimming",
    "hashing",
    "compression",
    "sorting",
    "decompression",
    "reordering",
    "hierarchy_creation",
    "traversal",
    "final_tests",
    "intersection",
    "shading",
];

/// Rays traced per kind.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct RayCounts {
    /// Camera rays (pixels, for raster primaries too).
    pub primary: u64,
    /// Shadow rays.
    pub shadow: u64,
    /// Reflection rays.
    pub reflection: u64,
    /// Refraction rays.
    pub refraction: u64,
    /// Ambient-occlusion rays.
    #[serde(default)]
    pub ao: u64,
    /// Diffuse bounce rays.
    #[serde(default)]
    pub diffuse: u64,
}

impl RayCounts {
    /// Adds `n` rays of `kind`.
    pub fn add(&mut self, kind: RayKind, n: u64) {
        *self.get_mut(kind) += n;
    }

    /// Count for `kind`.
    pub fn get(&self, kind: RayKind) -> u64 {
        match kind {
            RayKind::Primary => self.primary,
            RayKind::Shadow => self.shadow,
            RayKind::Reflection => self.reflection,
            RayKind::Refraction => self.refraction,
            RayKind::Ao => self.ao,
            RayKind::Diffuse => self.diffuse,
        }
    }

    fn get_mut(&mut self, kind: RayKind) -> &mut u64 {
        match kind {
            RayKind::Primary => &mut self.primary,
            RayKind::Shadow => &mut self.shadow,
            RayKind::Reflection => &mut self.reflection,
            RayKind::Refraction => &mut self.refraction,
            RayKind::Ao => &mut self.ao,
            RayKind::Diffuse => &mut self.diffuse,
        }
    }

    /// Sum over kinds.
    pub fn total(&self) -> u64 {
        self.primary + self.shadow + self.reflection + self.refraction + self.ao + self.diffuse
    }
}

/// Intersection-test counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TestCounts {
    /// Bounding-volume tests (BVH node boxes, hierarchy node vs sphere, ...).
    pub bounds: u64,
    /// Exact ray-triangle tests.
    pub ray_triangle: u64,
    /// `bounds + ray_triangle`.
    pub total: u64,
    /// What brute force would need: Σ over traced rays × scene triangles.
    pub brute_force: u64,
    /// Inner nodes an object hierarchy (BVH) visited: nodes whose children were tested. Not
    /// part of `total` (their child tests are in `bounds`). Seed 001's "visited internal
    /// nodes"; 0 for intersectors without a hierarchy.
    #[serde(default)]
    pub inner_nodes: u64,
    /// Leaves an object hierarchy visited: leaf nodes whose primitives were tested (seed 001's
    /// "visited leaves"). Not part of `total`.
    #[serde(default)]
    pub leaves: u64,
    /// Some stage that ran does not count its tests (a tracer whose internals are opaque to
    /// crsh: Embree): the counts above are then partial, and reports show them as absent
    /// (`null`, "—"), never as 0. Set with [`Stats::mark_tests_uncounted`].
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub uncounted: bool,
}

impl TestCounts {
    /// Adds the counts `o` (of another frame or batch) to these; unknown if either is.
    pub fn add(&mut self, o: &TestCounts) {
        self.bounds += o.bounds;
        self.ray_triangle += o.ray_triangle;
        self.total += o.total;
        self.brute_force += o.brute_force;
        self.inner_nodes += o.inner_nodes;
        self.leaves += o.leaves;
        self.uncounted |= o.uncounted;
    }
}

/// Per hierarchy level counters (tables 4.1-4.24 of seed 000).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct LevelStats {
    /// Ray kind of the batch.
    pub ray_kind: String,
    /// Level number as in the thesis: the highest level first, 1 the lowest node level;
    /// 0 stands for the final ray-triangle tests.
    pub level: u32,
    /// Node-triangle (or ray-triangle) tests.
    pub tests: u64,
    /// Tests that found an overlap (hit).
    pub hits: u64,
    /// Tests that did not.
    pub misses: u64,
}

/// Whole-mesh culling counters of one ray kind: the hierarchy's top nodes against the per-mesh
/// bounding spheres (seed 000 §3.2.8), before the top level's triangle tests.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct CullStats {
    /// Node-mesh tests.
    pub tests: u64,
    /// (node, mesh) pairs kept.
    pub hits: u64,
    /// Pairs culled.
    pub misses: u64,
}

/// Per-kind work: rays, tests and time in the tracing stages.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct KindStats {
    /// Rays traced.
    pub rays: u64,
    /// Bounding-volume tests.
    pub bounds: u64,
    /// Ray-triangle tests.
    pub ray_triangle: u64,
    /// Wall time of the tracing stages (hash to final tests) for this kind, ms.
    pub trace_ms: f64,
    /// Object-hierarchy inner nodes visited ([`TestCounts::inner_nodes`]).
    #[serde(default)]
    pub inner_nodes: u64,
    /// Object-hierarchy leaves visited ([`TestCounts::leaves`]).
    #[serde(default)]
    pub leaves: u64,
    /// Rays of this kind whose origin offset (seed 001) passed their end, so they were traced
    /// with an empty interval and ended without traversal (seed 001 fig. 4's fraction).
    #[serde(default)]
    pub offset_ended: u64,
}

/// Coherent kd-tree traversal counters of one ray kind (seed 003 tables 4.1-4.5): the work of
/// the traversal units (single rays, 2×2 packets, frusta, groups of four frusta, cones) over
/// the rays they carry.
///
/// `N = nodes / packets` is the paper's "traversed nodes per packet", `I = packet_tests /
/// packets` its "intersection tests per packet", and `culled_tests / (culled_tests +
/// packet_tests)` table 4.2's "culled intersections".
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PacketStats {
    /// 2×2 ray packets traced (a ray traced on its own counts as one packet).
    pub packets: u64,
    /// Kd-tree nodes (inner and leaf) entered by the traversal units: a ray, a packet, a
    /// frustum or cone, or a group of four frusta (each node once per unit, however many of
    /// its rays are active there).
    pub nodes: u64,
    /// Packet-triangle tests: one per packet and triangle tested, however many of its rays
    /// take part.
    pub packet_tests: u64,
    /// Packet-triangle tests that packet/leaf culling avoided (packets whose rays all miss a
    /// visited leaf's cell).
    pub culled_tests: u64,
    /// Ray groups (shared origin and screen tile) traced coherently.
    pub groups: u64,
    /// Rays traced on their own (no other ray of the batch shares their origin and tile,
    /// or the traversal is `single`).
    pub single_rays: u64,
}

impl PacketStats {
    /// Adds `o` to these counters.
    pub fn add(&mut self, o: &PacketStats) {
        self.packets += o.packets;
        self.nodes += o.nodes;
        self.packet_tests += o.packet_tests;
        self.culled_tests += o.culled_tests;
        self.groups += o.groups;
        self.single_rays += o.single_rays;
    }

    /// The paper's `N`: nodes traversed per packet (0 without packets).
    pub fn nodes_per_packet(&self) -> f64 {
        ratio(self.nodes, self.packets)
    }

    /// The paper's `I`: packet-triangle tests per packet (0 without packets).
    pub fn tests_per_packet(&self) -> f64 {
        ratio(self.packet_tests, self.packets)
    }

    /// Table 4.2's culled intersections: the fraction of packet-leaf tests that culling
    /// avoided, `culled / (culled + done)` (0 when nothing was tested or culled).
    pub fn culled_fraction(&self) -> f64 {
        ratio(self.culled_tests, self.culled_tests + self.packet_tests)
    }
}

fn ratio(a: u64, b: u64) -> f64 {
    if b == 0 {
        0.0
    } else {
        a as f64 / b as f64
    }
}

/// Upper bin edges, in degrees, of [`GenerationStats::half_angle_histogram`]: bin `i < 10`
/// counts the node cones whose half-angle is below `HALF_ANGLE_BIN_EDGES_DEG[i]` and not below
/// the previous edge; the last bin (index 10) counts those of 90° and more, which bound no
/// convex region (a tile cone that wide culls nothing, seed 004 §4).
pub const HALF_ANGLE_BIN_EDGES_DEG: [f32; 10] =
    [0.1, 0.25, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 45.0, 90.0];

/// The work of one ray kind in one generation: the rays of bounce depth `generation`
/// ([`crate::Ray::depth`]; 1 for the rays spawned at the primary hits, 0 for camera rays),
/// their tests and the cones of the ray-space hierarchy built over them. Seed 004 follows
/// refraction through up to 8 generations and shows how the tile cones widen (fig. 4) while
/// terminated paths drop out (§5): the refraction and reflection rays of a generation are the
/// paths still alive.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GenerationStats {
    /// Bounce depth of the rays.
    pub generation: u32,
    /// Ray kind ([`RayKind::name`]).
    pub ray_kind: String,
    /// Rays traced.
    pub rays: u64,
    /// Bounding-volume tests.
    pub bounds: u64,
    /// Ray-triangle tests.
    pub ray_triangle: u64,
    /// Wall time of the tracing stages, ms.
    pub trace_ms: f64,
    /// Lowest-level hierarchy nodes built over these rays (0 without a ray-space hierarchy).
    pub nodes: u64,
    /// Those nodes' cone half-angles, binned by [`HALF_ANGLE_BIN_EDGES_DEG`] (11 bins; empty
    /// without a hierarchy).
    pub half_angle_histogram: Vec<u64>,
    /// Σ of those half-angles in degrees (their mean is this over `nodes`).
    pub half_angle_sum_deg: f64,
    /// The widest of those half-angles, degrees.
    pub max_half_angle_deg: f64,
}

impl GenerationStats {
    /// Adds the cone half-angles (radians) of the lowest-level nodes of one hierarchy.
    pub fn add_half_angles(&mut self, half_angles: impl IntoIterator<Item = f32>) {
        if self.half_angle_histogram.len() != HALF_ANGLE_BIN_EDGES_DEG.len() + 1 {
            self.half_angle_histogram = vec![0; HALF_ANGLE_BIN_EDGES_DEG.len() + 1];
        }
        for a in half_angles {
            let deg = a.to_degrees();
            // NaN lands in the last bin, as a cone that culls nothing.
            let bin = HALF_ANGLE_BIN_EDGES_DEG
                .iter()
                .position(|&edge| deg < edge)
                .unwrap_or(HALF_ANGLE_BIN_EDGES_DEG.len());
            self.half_angle_histogram[bin] += 1;
            self.nodes += 1;
            let deg = if deg.is_nan() { 180.0 } else { deg as f64 };
            self.half_angle_sum_deg += deg;
            self.max_half_angle_deg = self.max_half_angle_deg.max(deg);
        }
    }

    /// Mean node half-angle in degrees (0 without nodes).
    pub fn mean_half_angle_deg(&self) -> f64 {
        if self.nodes == 0 {
            0.0
        } else {
            self.half_angle_sum_deg / self.nodes as f64
        }
    }
}

/// Agreement of the traced rays with a reference intersector tracing the very same rays.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AccuracyCounts {
    /// Rays compared.
    pub rays: u64,
    /// Rays whose hit/miss agrees and, for closest-hit rays, whose nearest triangle matches
    /// (a different triangle at a `t` equal within 1e-6 relative counts as a match).
    pub agreeing: u64,
    /// Rays whose hit/miss differs.
    pub hit_miss_mismatches: u64,
    /// Closest-hit rays that hit different triangles at different `t`, and edge-width rays
    /// (seed 003 §5) that both hit with a different occlusion.
    pub nearest_mismatches: u64,
    /// Agreeing closest-hit rays where both hit: the rays [`AccuracyCounts::t_abs_error_sum`]
    /// sums over.
    #[serde(default)]
    pub t_compared: u64,
    /// Σ `|t − t_reference|` over the `t_compared` rays (the distance error of agreeing hits).
    #[serde(default)]
    pub t_abs_error_sum: f64,
    /// Secondary rays (of the pipeline under test) whose hit is the triangle they were spawned
    /// from: self-intersections ([`crate::pipeline::count_self_hits`]; a lower bound).
    #[serde(default)]
    pub self_hits: u64,
}

impl AccuracyCounts {
    /// `agreeing / rays` (1.0 when nothing was compared).
    pub fn hit_agreement(&self) -> f64 {
        if self.rays == 0 {
            1.0
        } else {
            self.agreeing as f64 / self.rays as f64
        }
    }

    /// `self_hits / rays` (0 when nothing was compared).
    pub fn self_hit_rate(&self) -> f64 {
        if self.rays == 0 {
            0.0
        } else {
            self.self_hits as f64 / self.rays as f64
        }
    }

    /// Mean `|t − t_reference|` over agreeing closest-hit rays that hit (0 when there are
    /// none).
    pub fn mean_abs_t_error(&self) -> f64 {
        if self.t_compared == 0 {
            0.0
        } else {
            self.t_abs_error_sum / self.t_compared as f64
        }
    }
}

/// Everything a frame measured. Stages add to it; the driver times them.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Stats {
    /// The variant that ran in each filled slot (`slot key → name`, e.g. `"hash" →
    /// "thesis"`), as the stage objects name themselves ([`crate::Stages::names`]): a stage
    /// swapped into a built pipeline is reported under its own name.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub stages: BTreeMap<String, String>,
    /// Rays per kind.
    pub rays: RayCounts,
    /// Test totals.
    pub tests: TestCounts,
    /// Rays that went through intersection stages: every secondary ray, plus the camera rays
    /// when the primary variant casts them ([`crate::PrimaryVisibility::casts_rays`]). The
    /// rays `tests.brute_force` counts.
    pub traced_rays: u64,
    /// Per kind breakdown, keyed by [`RayKind::name`].
    pub per_kind: BTreeMap<String, KindStats>,
    /// Per hierarchy level counters (empty when no hierarchy is used).
    pub levels: Vec<LevelStats>,
    /// Whole-mesh culling counters per ray kind (empty unless the traverser culls meshes).
    /// With [`Stats::levels`] they account for every bounding test of a hierarchy traversal.
    #[serde(default)]
    pub mesh_culling: BTreeMap<String, CullStats>,
    /// Object-hierarchy counters of a dual traversal (ray hierarchy and object hierarchy
    /// descended together, seed 000 §5.1): per ray kind and object node depth (`level` is the
    /// depth below the object root, 0 the root), the ray-node tests against object nodes of
    /// that depth and how many passed. The same tests, counted by the ray node's level, are in
    /// [`Stats::levels`]; each table sums to the traversal's bounds tests. Empty unless a dual
    /// traversal ran.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub object_levels: Vec<LevelStats>,
    /// Wall time per stage in milliseconds, plus `total`. The stage keys do not overlap (a
    /// stage's own sub-stages are subtracted from it), in pipeline order: `primary`,
    /// `ray_creation`, `trimming`, `hashing`, `compression`, `sorting`, `decompression`,
    /// `hierarchy_creation`, `traversal`, `final_tests` (candidate tests after a ray-space
    /// hierarchy) or `intersection` (whole-scene queries: brute force, object BVH), `shading`;
    /// the thesis's table 4.25 rows. `reference` is the untimed reference tracing, not part
    /// of `total`.
    pub timings_ms: BTreeMap<String, f64>,
    /// Device-side time per stage key in milliseconds, from GPU timestamp queries around the
    /// backend's compute and render passes (the wgpu backend on adapters with timestamp
    /// queries; empty on the CPU). Unlike `timings_ms` it excludes host work (encoding,
    /// submission, readbacks of counters), so the two differ most where a stage launches many
    /// small dispatches.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub device_timings_ms: BTreeMap<String, f64>,
    /// Agreement with a reference, when one was given.
    pub accuracy: Option<AccuracyCounts>,
    /// The most bytes the traversal's candidate arrays held at once (0 without a
    /// ray-space hierarchy): the memory the traversal budget bounds.
    #[serde(default)]
    pub peak_candidate_bytes: u64,
    /// Per generation and ray kind, in the order the batches ran: rays, tests, time and the
    /// hierarchy's cone widths ([`GenerationStats`]).
    #[serde(default)]
    pub generations: Vec<GenerationStats>,
    /// Coherent kd-tree traversal counters per ray kind ([`RayKind::name`]; seed 003's `N`,
    /// `I` and culling, [`PacketStats`]); empty unless a coherent traversal ran. Added to
    /// with [`Stats::add_packets`].
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub packets: BTreeMap<String, PacketStats>,
    /// What stages chose from the data of this frame, by `slot.ray_kind` key (e.g.
    /// `"hierarchy.shadow"` → the ray-hierarchy shape an automatic builder picked for shadow
    /// rays, with the estimates it compared); empty unless such a stage ran. Added to with
    /// [`Stats::add_choice`].
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub choices: BTreeMap<String, String>,
}

impl Stats {
    /// Adds `n` bounding-volume tests.
    pub fn add_bounds(&mut self, n: u64) {
        self.tests.bounds += n;
        self.tests.total += n;
    }

    /// Adds `n` ray-triangle tests.
    pub fn add_ray_triangle(&mut self, n: u64) {
        self.tests.ray_triangle += n;
        self.tests.total += n;
    }

    /// Marks the test counts as unknown ([`TestCounts::uncounted`]): a stage traced rays
    /// without counting its bounding and ray-triangle tests.
    pub fn mark_tests_uncounted(&mut self) {
        self.tests.uncounted = true;
    }

    /// Adds `inner` visited inner nodes and `leaves` visited leaves of an object hierarchy
    /// (counted beside, not in, [`TestCounts::total`]).
    pub fn add_visits(&mut self, inner: u64, leaves: u64) {
        self.tests.inner_nodes += inner;
        self.tests.leaves += leaves;
    }

    /// Adds `n` rays of `kind` that an origin offset ended before traversal
    /// ([`KindStats::offset_ended`]).
    pub fn add_offset_ended(&mut self, kind: RayKind, n: u64) {
        if n > 0 {
            self.per_kind
                .entry(kind.name().to_string())
                .or_default()
                .offset_ended += n;
        }
    }

    /// Adds coherent-traversal counters of `kind` rays ([`Stats::packets`]).
    pub fn add_packets(&mut self, kind: RayKind, counts: &PacketStats) {
        self.packets
            .entry(kind.name().to_string())
            .or_default()
            .add(counts);
    }

    /// Adds `d` to the stage timer `key`.
    pub fn add_time(&mut self, key: &str, d: Duration) {
        *self.timings_ms.entry(key.to_string()).or_insert(0.0) += d.as_secs_f64() * 1e3;
    }

    /// Adds level counters, merging with an existing entry of the same kind and level.
    pub fn add_level(&mut self, kind: RayKind, level: u32, tests: u64, hits: u64) {
        add_row(&mut self.levels, kind, level, tests, hits);
    }

    /// Records what stage slot `slot` chose for rays of `kind` ([`Stats::choices`], key
    /// `slot.kind`); a later choice for the same key replaces it.
    pub fn add_choice(&mut self, slot: &str, kind: RayKind, choice: String) {
        self.choices
            .insert(format!("{slot}.{}", kind.name()), choice);
    }

    /// Adds object-hierarchy counters at object node depth `depth` ([`Stats::object_levels`]),
    /// merging with an existing entry of the same kind and depth.
    pub fn add_object_level(&mut self, kind: RayKind, depth: u32, tests: u64, hits: u64) {
        add_row(&mut self.object_levels, kind, depth, tests, hits);
    }

    /// Adds whole-mesh culling counters: `tests` node-mesh tests of which `kept` passed.
    pub fn add_mesh_culling(&mut self, kind: RayKind, tests: u64, kept: u64) {
        let c = self
            .mesh_culling
            .entry(kind.name().to_string())
            .or_default();
        c.tests += tests;
        c.hits += kept.min(tests);
        c.misses += tests - kept.min(tests);
    }

    /// The entry of `kind` rays in `generation`, created empty when missing.
    pub fn generation_mut(&mut self, generation: u32, kind: RayKind) -> &mut GenerationStats {
        let name = kind.name();
        let i = match self
            .generations
            .iter()
            .position(|g| g.generation == generation && g.ray_kind == name)
        {
            Some(i) => i,
            None => {
                self.generations.push(GenerationStats {
                    generation,
                    ray_kind: name.to_string(),
                    ..GenerationStats::default()
                });
                self.generations.len() - 1
            }
        };
        &mut self.generations[i]
    }

    /// Wall time of stage `key` in ms (0 if it never ran).
    pub fn time_ms(&self, key: &str) -> f64 {
        self.timings_ms.get(key).copied().unwrap_or(0.0)
    }
}

/// Adds `tests` and `hits` to the row of `kind` and `level` of `rows` (a new row if none).
fn add_row(rows: &mut Vec<LevelStats>, kind: RayKind, level: u32, tests: u64, hits: u64) {
    let name = kind.name();
    let misses = tests - hits.min(tests);
    if let Some(l) = rows
        .iter_mut()
        .find(|l| l.ray_kind == name && l.level == level)
    {
        l.tests += tests;
        l.hits += hits;
        l.misses += misses;
    } else {
        rows.push(LevelStats {
            ray_kind: name.to_string(),
            level,
            tests,
            hits,
            misses,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counters_add_up() {
        let mut s = Stats::default();
        s.add_bounds(3);
        s.add_ray_triangle(4);
        assert_eq!(s.tests.total, 7);
        s.add_level(RayKind::Shadow, 2, 10, 4);
        s.add_level(RayKind::Shadow, 2, 5, 1);
        assert_eq!(s.levels.len(), 1);
        assert_eq!(s.levels[0].misses, 10);
        s.rays.add(RayKind::Reflection, 5);
        assert_eq!(s.rays.total(), 5);
        // Object rows stay apart from the ray levels, and out of JSON while empty.
        assert!(!serde_json::to_string(&s).unwrap().contains("object_levels"));
        s.add_object_level(RayKind::Shadow, 2, 7, 3);
        s.add_object_level(RayKind::Shadow, 2, 1, 1);
        assert_eq!(s.levels.len(), 1);
        assert_eq!(s.object_levels.len(), 1);
        assert_eq!(
            (s.object_levels[0].tests, s.object_levels[0].misses),
            (8, 4)
        );
        let back: Stats = serde_json::from_str(&serde_json::to_string(&s).unwrap()).unwrap();
        assert_eq!(back, s);
    }

    #[test]
    fn packet_counters_add_per_kind_and_stay_out_of_old_json() {
        let mut s = Stats::default();
        let json = serde_json::to_string(&s).unwrap();
        assert!(!json.contains("packets"), "{json}");
        let back: Stats = serde_json::from_str(&json).unwrap();
        assert_eq!(back, s);
        let p = PacketStats {
            packets: 4,
            nodes: 10,
            packet_tests: 6,
            culled_tests: 2,
            groups: 1,
            single_rays: 0,
        };
        s.add_packets(RayKind::Primary, &p);
        s.add_packets(RayKind::Primary, &p);
        s.add_packets(RayKind::Shadow, &p);
        let q = &s.packets["primary"];
        assert_eq!(q.packets, 8);
        assert_eq!(q.nodes_per_packet(), 2.5);
        assert_eq!(q.tests_per_packet(), 1.5);
        assert_eq!(q.culled_fraction(), 0.25);
        assert_eq!(s.packets.len(), 2);
        let back: Stats = serde_json::from_str(&serde_json::to_string(&s).unwrap()).unwrap();
        assert_eq!(back, s);
        assert_eq!(PacketStats::default().nodes_per_packet(), 0.0);
    }

    #[test]
    fn half_angle_histogram_bins_by_degrees() {
        let mut s = Stats::default();
        let deg = |d: f32| d.to_radians();
        s.generation_mut(2, RayKind::Refraction).add_half_angles([
            deg(0.05),
            deg(0.1),
            deg(3.0),
            deg(89.9),
            deg(90.0),
            std::f32::consts::PI,
            f32::NAN,
        ]);
        s.generation_mut(1, RayKind::Refraction).rays += 4;
        let g = s.generation_mut(2, RayKind::Refraction);
        assert_eq!(g.nodes, 7);
        assert_eq!(
            g.half_angle_histogram,
            vec![1, 1, 0, 0, 0, 1, 0, 0, 0, 1, 3]
        );
        assert!((g.max_half_angle_deg - 180.0).abs() < 1e-3);
        assert_eq!(s.generations.len(), 2);
        assert_eq!(s.generations[1].generation, 1);
    }
}
