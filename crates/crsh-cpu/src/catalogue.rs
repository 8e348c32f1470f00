//! The CPU backend's stage catalogue, pipeline presets and stage factory.
//!
//! [`catalogue`] lists every CPU stage variant with its parameters (what `crsh pipelines`
//! prints and what [`PipelineConfig::resolve`] checks configs against); [`preset`] gives the
//! named pipelines of `--pipeline`; [`build_stages`] turns a config and a scene into runnable
//! [`Stages`]; [`build_intersector`] makes the `--reference` intersector; [`render`] does all of
//! it and renders a frame; [`with_threads`] runs it on a pool of a chosen size.

use std::sync::Arc;

use crsh_core::{
    render_frame, CoreError, Frame, FrameOptions, Intersector, ParamInfo, ParamValue,
    PipelineConfig, Progress, Result, StageKind, StageSpec, StageVariantInfo, Stages,
};
use crsh_scene::Scene;

use crate::backend::Cpu;
use crate::hash::morton_octa::{self, MortonOcta};
use crate::hash::thesis::{self, ThesisHasher};
use crate::hierarchy::sphere_cone::{self, SphereConeBuilder};
use crate::intersect::brute::BruteForce;
use crate::intersect::brute64::BruteForce64;
use crate::intersect::bvh::CwBvh;
use crate::primary::raster::Raster;
use crate::primary::raycast::RayCast;
use crate::raygen::whitted::Whitted;
use crate::shade::phong::Phong;
use crate::sort::compress::{self, CompressSorter};
use crate::sort::radix::{self, RadixSorter};
use crate::traverse::crsh::{self, Crsh};

/// Names of the pipelines [`preset`] knows (the CLI's `--pipeline`).
pub const PRESETS: &[&str] = &["brute", "bvh", "crsh", "rah"];

/// Every stage variant the CPU backend offers, with parameters, defaults and choices.
pub fn catalogue() -> Vec<StageVariantInfo> {
    vec![
        StageVariantInfo {
            stage: StageKind::Primary,
            name: "raster",
            doc: "z-buffer rasterizer writing the G-buffer (position, normals, material, \
                  triangle id), seed 000 §3.1",
            params: vec![],
        },
        StageVariantInfo {
            stage: StageKind::Primary,
            name: "raycast",
            doc: "the same G-buffer by casting one camera ray per pixel centre",
            params: vec![ParamInfo {
                name: "accel",
                default: ParamValue::Str("bvh".into()),
                choices: &["bvh", "brute"],
                doc: "what traces the camera rays: the obvhs CWBVH or every triangle",
            }],
        },
        StageVariantInfo {
            stage: StageKind::Raygen,
            name: "whitted",
            doc: "shadow, reflection and refraction rays with total internal reflection, \
                  seed 000 §3.2.3 eq. 3.1-3.7",
            params: vec![
                ParamInfo {
                    name: "shadow_origin",
                    default: ParamValue::Str("light".into()),
                    choices: &["light", "surface"],
                    doc: "shadow rays start at the light (thesis, eq. 3.1-3.2) or at the surface",
                },
                ParamInfo {
                    name: "cull_backfacing",
                    default: ParamValue::Bool(true),
                    choices: &[],
                    doc: "no shadow ray to a light behind the geometric normal (it lights nothing)",
                },
                ParamInfo {
                    name: "min_throughput",
                    default: ParamValue::Float(1e-3),
                    choices: &[],
                    doc: "rays whose largest throughput component is below this are not spawned",
                },
                ParamInfo {
                    name: "epsilon",
                    default: ParamValue::Float(1e-5),
                    choices: &[],
                    doc: "the offset distance of the `normal` and `scaled` policies, as a \
                          fraction of the scene's bounding-box diagonal",
                },
                ParamInfo {
                    name: "offset",
                    default: ParamValue::Str("normal".into()),
                    choices: &["normal", "scaled", "fixed", "wachter"],
                    doc: "self-intersection policy: origin moved along the geometric normal and \
                          t_min (normal), t_min only (scaled: epsilon, fixed: fixed_epsilon), or \
                          Wächter & Binder's ULP offset with t_min = 0 (wachter)",
                },
                ParamInfo {
                    name: "fixed_epsilon",
                    default: ParamValue::Float(1e-4),
                    choices: &[],
                    doc: "t_min of the `fixed` policy, an absolute distance in scene units",
                },
            ],
        },
        StageVariantInfo {
            stage: StageKind::Intersect,
            name: "brute",
            doc: "every ray against every triangle: the exact reference, N×M tests (§3.2.9)",
            params: vec![ParamInfo {
                name: "test",
                default: ParamValue::Str("mt".into()),
                choices: crate::triangle::TEST_NAMES,
                doc: "ray-triangle test: `mt` Möller-Trumbore (f32), `watertight` Woop, Benthin \
                      and Wald 2013 (no ray slips through shared edges), `projected` RTTest's \
                      projected barycentrics (seed 003 §4.2)",
            }],
        },
        crate::intersect::brute64::info(),
        StageVariantInfo {
            stage: StageKind::Intersect,
            name: "bvh",
            doc: "obvhs compressed-wide BVH (CWBVH), closest and any hit, node and triangle \
                  tests counted",
            params: vec![
                ParamInfo {
                    name: "build_quality",
                    default: ParamValue::Str("medium".into()),
                    choices: &["fast", "medium", "slow"],
                    doc: "obvhs build preset: faster builds or better trees",
                },
                ParamInfo {
                    name: "test",
                    default: ParamValue::Str("mt".into()),
                    choices: crate::triangle::TEST_NAMES,
                    doc:
                        "ray-triangle test: `mt` Möller-Trumbore (f32), `watertight` Woop, Benthin \
                      and Wald 2013 (no ray slips through shared edges), `projected` RTTest's \
                      projected barycentrics (seed 003 §4.2)",
                },
            ],
        },
        StageVariantInfo {
            stage: StageKind::Shade,
            name: "phong",
            doc: "Phong with attenuation and shadows, barycentric normals, reflection and \
                  refraction weighted by the material, seed 000 eq. 3.17-3.19",
            params: vec![
                ParamInfo {
                    name: "ambient",
                    default: ParamValue::Float(0.05),
                    choices: &[],
                    doc: "ambient fill as a fraction of the diffuse colour (0: the thesis exactly)",
                },
                ParamInfo {
                    name: "background",
                    default: ParamValue::Float(0.0),
                    choices: &[],
                    doc: "grey level that rays missing the scene see",
                },
            ],
        },
        thesis::info(),
        morton_octa::info(),
        compress::info(),
        radix::info(),
        sphere_cone::info(),
        crsh::info(),
    ]
}

/// The named pipeline `name` (one of [`PRESETS`]), unresolved. All use raster primaries,
/// Whitted ray generation and Phong shading; they differ in how rays are traced:
/// - `brute`: every ray against every triangle;
/// - `bvh`: the obvhs CWBVH;
/// - `crsh`: seed 000's Coherent Ray-Space Hierarchy: thesis hashes, compress-sort-decompress,
///   sphere-cone hierarchy (subdivision 8, depth 2), traversal with whole-mesh culling, and the
///   final tests on the surviving candidates;
/// - `rah`: Roger et al.'s ray-space hierarchy (seed 000 §2.4): the same hierarchy over rays in
///   generation order (no hashing or sorting) and no mesh culling.
pub fn preset(name: &str) -> Option<PipelineConfig> {
    let hierarchy_pipeline = |name: &str, sorted: bool| {
        let mut cfg = PipelineConfig::whitted(name, "brute");
        if sorted {
            cfg.hash = Some(StageSpec::new("thesis"));
            cfg.sort = Some(StageSpec::new("compress"));
        }
        cfg.hierarchy = Some(StageSpec::new("sphere_cone"));
        let mut traverse = StageSpec::new("crsh");
        traverse
            .params
            .insert("mesh_culling".into(), ParamValue::Bool(sorted));
        cfg.traverse = Some(traverse);
        cfg
    };
    match name {
        "brute" => Some(PipelineConfig::whitted("brute", "brute")),
        "bvh" => Some(PipelineConfig::whitted("bvh", "bvh")),
        "crsh" => Some(hierarchy_pipeline("crsh", true)),
        "rah" => Some(hierarchy_pipeline("rah", false)),
        _ => None,
    }
}

fn no_cpu_variant(slot: StageKind, spec: &StageSpec) -> CoreError {
    CoreError::UnknownVariant {
        stage: slot.key().into(),
        name: spec.kind.clone(),
        known: catalogue()
            .iter()
            .filter(|v| v.stage == slot)
            .map(|v| v.name)
            .collect::<Vec<_>>()
            .join(", "),
    }
}

/// Builds the stages of `cfg` for `scene`. A clone of `cfg` is resolved against [`catalogue`]
/// first (unknown variants or parameters are errors; defaults are filled in).
pub fn build_stages(cfg: &PipelineConfig, scene: &Arc<Scene>) -> Result<Stages<Cpu>> {
    let mut cfg = cfg.clone();
    cfg.resolve(&catalogue())?;
    let primary: Box<dyn crsh_core::PrimaryVisibility<Cpu>> = match cfg.primary.kind.as_str() {
        "raster" => Box::new(Raster::new(scene, &cfg.primary)?),
        "raycast" => Box::new(RayCast::new(scene, &cfg.primary)?),
        _ => return Err(no_cpu_variant(StageKind::Primary, &cfg.primary)),
    };
    let raygen: Box<dyn crsh_core::RayGen<Cpu>> = match cfg.raygen.kind.as_str() {
        "whitted" => Box::new(Whitted::new(scene, &cfg.raygen)?),
        _ => return Err(no_cpu_variant(StageKind::Raygen, &cfg.raygen)),
    };
    let shader: Box<dyn crsh_core::Shader<Cpu>> = match cfg.shade.kind.as_str() {
        "phong" => Box::new(Phong::new(scene, &cfg.shade)?),
        _ => return Err(no_cpu_variant(StageKind::Shade, &cfg.shade)),
    };
    let hasher = cfg
        .hash
        .as_ref()
        .map(|spec| -> Result<Box<dyn crsh_core::Hasher<Cpu>>> {
            Ok(match spec.kind.as_str() {
                "thesis" => Box::new(ThesisHasher::new(scene, spec)?),
                "morton" => Box::new(MortonOcta::new(scene, spec)?),
                _ => return Err(no_cpu_variant(StageKind::Hash, spec)),
            })
        })
        .transpose()?;
    let sorter = cfg
        .sort
        .as_ref()
        .map(|spec| -> Result<Box<dyn crsh_core::Sorter<Cpu>>> {
            Ok(match spec.kind.as_str() {
                "compress" => Box::new(CompressSorter::new(scene, spec)?),
                "radix" => Box::new(RadixSorter::new(scene, spec)?),
                _ => return Err(no_cpu_variant(StageKind::Sort, spec)),
            })
        })
        .transpose()?;
    let hierarchy = cfg
        .hierarchy
        .as_ref()
        .map(
            |spec| -> Result<Box<dyn crsh_core::HierarchyBuilder<Cpu>>> {
                Ok(match spec.kind.as_str() {
                    "sphere_cone" => Box::new(SphereConeBuilder::new(scene, spec)?),
                    _ => return Err(no_cpu_variant(StageKind::Hierarchy, spec)),
                })
            },
        )
        .transpose()?;
    let traverser = cfg
        .traverse
        .as_ref()
        .map(|spec| -> Result<Box<dyn crsh_core::Traverser<Cpu>>> {
            Ok(match spec.kind.as_str() {
                "crsh" => Box::new(Crsh::new(scene, spec)?),
                _ => return Err(no_cpu_variant(StageKind::Traverse, spec)),
            })
        })
        .transpose()?;
    let intersector = make_intersector(&cfg.intersect, scene)?;
    if hierarchy.is_some() && !intersector.supports_candidates() {
        return Err(CoreError::Unsupported {
            stage: "intersect",
            variant: cfg.intersect.kind.clone(),
            what: "the final tests of a ray-space hierarchy (it answers whole-scene queries \
                   only: use it as --reference, or in a pipeline without a hierarchy)"
                .into(),
        });
    }
    Ok(Stages {
        primary,
        raygen,
        hasher,
        sorter,
        hierarchy,
        traverser,
        intersector,
        shader,
    })
}

fn make_intersector(spec: &StageSpec, scene: &Arc<Scene>) -> Result<Box<dyn Intersector<Cpu>>> {
    Ok(match spec.kind.as_str() {
        "brute" => Box::new(BruteForce::new(scene, spec)?),
        "brute64" => Box::new(BruteForce64::new(scene, spec)?),
        "bvh" => Box::new(CwBvh::new(scene, spec)?),
        _ => return Err(no_cpu_variant(StageKind::Intersect, spec)),
    })
}

/// Builds the intersector `spec` (resolved against [`catalogue`] first), e.g. the reference of
/// `--reference brute|bvh`.
pub fn build_intersector(
    spec: &StageSpec,
    scene: &Arc<Scene>,
) -> Result<Box<dyn Intersector<Cpu>>> {
    let mut cfg = PipelineConfig::whitted("reference", &spec.kind);
    cfg.intersect = spec.clone();
    cfg.resolve(&catalogue())?;
    make_intersector(&cfg.intersect, scene)
}

/// Renders one frame of `scene` with pipeline `cfg` on the CPU: builds the stages (and the
/// `reference` intersector, if given, whose agreement lands in [`crsh_core::Stats::accuracy`])
/// and runs [`render_frame`]. `opts.triangles` is taken from the scene, whatever the caller
/// put there. `progress` receives a report before every batch.
pub fn render(
    scene: &Arc<Scene>,
    cfg: &PipelineConfig,
    opts: &FrameOptions,
    reference: Option<&StageSpec>,
    progress: &mut dyn FnMut(Progress),
) -> Result<Frame<Cpu>> {
    let stages = build_stages(cfg, scene)?;
    let reference = reference.map(|r| build_intersector(r, scene)).transpose()?;
    let opts = FrameOptions {
        triangles: scene.triangle_count() as u64,
        ..opts.clone()
    };
    render_frame(&Cpu, &stages, &opts, reference.as_deref(), progress)
}

/// Runs `f` on a dedicated rayon pool of `threads` worker threads (0: rayon's default, one per
/// core), so that every CPU stage `f` runs uses that many threads: the CLI's `--threads`, and
/// the determinism tests (the output does not depend on the count).
pub fn with_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> Result<T> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| CoreError::Backend(format!("cannot start {threads} worker threads: {e}")))?;
    Ok(pool.install(f))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_resolve_against_the_catalogue() {
        for name in PRESETS {
            let mut cfg = preset(name).expect("listed preset exists");
            cfg.resolve(&catalogue()).unwrap();
            let expect = if ["brute", "bvh"].contains(name) {
                *name
            } else {
                "brute"
            };
            assert_eq!(cfg.intersect.kind, expect);
            assert_eq!(cfg.hierarchy.is_some(), ["crsh", "rah"].contains(name));
            assert_eq!(cfg.hash.is_some(), *name == "crsh");
            if let Some(t) = &cfg.traverse {
                assert_eq!(t.bool("mesh_culling").unwrap(), *name == "crsh");
            }
            assert_eq!(cfg.raygen.str("shadow_origin").unwrap(), "light");
            assert_eq!(cfg.shade.f64("ambient").unwrap(), 0.05);
        }
        assert!(preset("kdtree").is_none());
    }

    #[test]
    fn thread_pools_have_the_size_asked_for() {
        assert_eq!(with_threads(3, rayon::current_num_threads).unwrap(), 3);
        assert_eq!(with_threads(1, rayon::current_num_threads).unwrap(), 1);
    }

    #[test]
    fn catalogue_is_well_formed() {
        let cat = catalogue();
        for (i, v) in cat.iter().enumerate() {
            assert!(!v.doc.is_empty(), "{} has no doc", v.name);
            assert!(
                cat[..i]
                    .iter()
                    .all(|w| (w.stage, w.name) != (v.stage, v.name)),
                "{} listed twice",
                v.name
            );
            for p in &v.params {
                assert!(!p.doc.is_empty());
                if let ParamValue::Str(s) = &p.default {
                    assert!(p.choices.is_empty() || p.choices.contains(&s.as_str()));
                }
            }
        }
        for slot in [
            StageKind::Primary,
            StageKind::Raygen,
            StageKind::Intersect,
            StageKind::Shade,
        ] {
            assert!(cat.iter().any(|v| v.stage == slot), "no variant for {slot}");
        }
    }
}
