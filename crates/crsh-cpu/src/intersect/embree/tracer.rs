//! The Embree scene and its queries (the `embree` feature): see the parent module.

use std::sync::Arc;
use std::time::{Duration, Instant};

use crsh_core::{CoreError, Hit, HitMode, Intersector, Query, Ray, Result, Stats};
use crsh_scene::Scene;
use embree3::{
    BufferUsage, BuildQuality, Device, Format, GeometryKind, IntersectContext, RayHit16, RayHit4,
    RayHit8, SceneFlags, ValidMask, ValidMaskN, INVALID_ID,
};
use rayon::prelude::*;

use super::{Mode, Quality, TASK};
use crate::backend::Cpu;
use crate::intersect::brute::check_batch;
use crate::intersect::nothing_to_trace;

/// The `embree` intersector: one committed Embree scene over the scene's triangles.
pub struct Embree {
    // Field order: the scene is released before its device.
    scene: embree3::Scene<'static>,
    _device: Device,
    mode: Mode,
    coherent: bool,
    quality: Quality,
    build_time: Duration,
}

impl std::fmt::Debug for Embree {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Embree")
            .field("mode", &self.mode)
            .field("coherent", &self.coherent)
            .field("quality", &self.quality)
            .field("build_time", &self.build_time)
            .finish()
    }
}

/// An Embree error as crsh's.
fn backend_error(what: &str, e: impl std::fmt::Debug) -> CoreError {
    CoreError::Backend(format!("Embree: {what}: {e:?}"))
}

impl Embree {
    /// Builds the Embree scene of `scene` with build quality `quality`; its queries run in
    /// `mode` with the coherent flag `coherent`.
    pub fn new(scene: &Arc<Scene>, mode: Mode, coherent: bool, quality: Quality) -> Result<Embree> {
        // Embree's build threads: as many as rayon's pool, so `--threads` bounds both.
        let device = Device::with_config(embree3::Config {
            threads: rayon::current_num_threads() as u32,
            ..Default::default()
        })
        .map_err(|e| backend_error("rtcNewDevice", e))?;
        let mut rtc = device
            .create_scene()
            .map_err(|e| backend_error("rtcNewScene", e))?;
        let t0 = Instant::now();
        let build = match quality {
            Quality::Low => BuildQuality::LOW,
            Quality::Medium => BuildQuality::MEDIUM,
            Quality::High => BuildQuality::HIGH,
        };
        rtc.set_flags(SceneFlags::NONE);
        rtc.set_build_quality(build);
        if scene.triangle_count() > 0 {
            let mut geom = device
                .create_geometry(GeometryKind::TRIANGLE)
                .map_err(|e| backend_error("rtcNewGeometry", e))?;
            geom.set_new_buffer::<[f32; 3]>(
                BufferUsage::VERTEX,
                0,
                Format::FLOAT3,
                12,
                scene.positions.len(),
            )
            .map_err(|e| backend_error("vertex buffer", e))?
            .iter_mut()
            .zip(&scene.positions)
            .for_each(|(d, p)| *d = p.to_array());
            geom.set_new_buffer::<[u32; 3]>(
                BufferUsage::INDEX,
                0,
                Format::UINT3,
                12,
                scene.indices.len(),
            )
            .map_err(|e| backend_error("index buffer", e))?
            .copy_from_slice(&scene.indices);
            geom.set_build_quality(build);
            let geom = geom.commit();
            rtc.attach_geometry(&geom);
        }
        rtc.commit();
        let build_time = t0.elapsed();
        Ok(Embree {
            scene: rtc,
            _device: device,
            mode,
            coherent,
            quality,
            build_time,
        })
    }

    /// The query mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Whether the intersect context's coherent flag is set.
    pub fn coherent(&self) -> bool {
        self.coherent
    }

    /// The build quality.
    pub fn quality(&self) -> Quality {
        self.quality
    }

    /// Time `rtcCommitScene` (and the buffer setup) took.
    pub fn build_time(&self) -> Duration {
        self.build_time
    }

    fn context(&self) -> IntersectContext {
        if self.coherent {
            IntersectContext::coherent()
        } else {
            IntersectContext::incoherent()
        }
    }

    /// Traces `rays` (a task's worth) into `hits`, merging as [`Intersector::intersect`] says.
    fn trace_task(&self, rays: &[Ray], mode: HitMode, hits: &mut [Hit]) {
        let mut ctx = self.context();
        match self.mode {
            Mode::Single => {
                for (ray, hit) in rays.iter().zip(hits.iter_mut()) {
                    if !nothing_to_trace(ray, mode, hit) {
                        self.single(&mut ctx, ray, mode, hit);
                    }
                }
            }
            Mode::Packet4 => self.packets4(&mut ctx, rays, mode, hits),
            Mode::Packet8 => self.packets8(&mut ctx, rays, mode, hits),
            Mode::Packet16 => self.packets16(&mut ctx, rays, mode, hits),
        }
    }

    fn single(&self, ctx: &mut IntersectContext, ray: &Ray, mode: HitMode, hit: &mut Hit) {
        let r = embree3::Ray::segment(
            ray.origin.to_array(),
            ray.dir.to_array(),
            ray.t_min,
            ray.t_max,
        );
        if mode == HitMode::Any {
            let mut r = r;
            if self.scene.occluded(ctx, &mut r) {
                *hit = Hit::occluded(ray.t_max);
            }
        } else {
            let mut rh = embree3::RayHit::from(r);
            self.scene.intersect(ctx, &mut rh);
            if rh.hit.geomID != INVALID_ID {
                merge(
                    hit,
                    Hit {
                        t: rh.ray.tfar,
                        tri: rh.hit.primID,
                        u: rh.hit.u,
                        v: rh.hit.v,
                    },
                );
            }
        }
    }
}

/// Keeps the closer of `best` and `h` ([`Hit::closer_than`]).
#[inline]
fn merge(best: &mut Hit, h: Hit) {
    if h.closer_than(best) {
        *best = h;
    }
}

/// `packetsN`: the rays in consecutive packets of `N` through `rtcIntersectN` /
/// `rtcOccludedN`, lanes past the end or needing no query invalid.
macro_rules! packets {
    ($fn:ident, $n:literal, $ray:ty, $rayhit:ident, $hit:ty, $isect:ident, $occl:ident) => {
        impl Embree {
            fn $fn(
                &self,
                ctx: &mut IntersectContext,
                rays: &[Ray],
                mode: HitMode,
                hits: &mut [Hit],
            ) {
                for (rs, hs) in rays.chunks($n).zip(hits.chunks_mut($n)) {
                    let mut valid = ValidMaskN::<$n>::new([ValidMask::Invalid; $n]);
                    let mut packet = <$ray>::empty();
                    let mut any = false;
                    for (i, (ray, hit)) in rs.iter().zip(hs.iter()).enumerate() {
                        if nothing_to_trace(ray, mode, hit) {
                            continue;
                        }
                        any = true;
                        valid.lanes_mut()[i] = ValidMask::Valid;
                        packet.org_x[i] = ray.origin.x;
                        packet.org_y[i] = ray.origin.y;
                        packet.org_z[i] = ray.origin.z;
                        packet.dir_x[i] = ray.dir.x;
                        packet.dir_y[i] = ray.dir.y;
                        packet.dir_z[i] = ray.dir.z;
                        packet.tnear[i] = ray.t_min;
                        packet.tfar[i] = ray.t_max;
                    }
                    if !any {
                        continue;
                    }
                    if mode == HitMode::Any {
                        self.scene.$occl(ctx, &mut packet, &valid);
                        for (i, (ray, hit)) in rs.iter().zip(hs.iter_mut()).enumerate() {
                            if valid.lanes_mut()[i] == ValidMask::Valid
                                && packet.tfar[i] == f32::NEG_INFINITY
                            {
                                *hit = Hit::occluded(ray.t_max);
                            }
                        }
                    } else {
                        let mut rh = $rayhit {
                            ray: packet,
                            hit: <$hit>::new(),
                        };
                        self.scene.$isect(ctx, &mut rh, &valid);
                        for (i, hit) in hs.iter_mut().enumerate() {
                            if valid.lanes_mut()[i] == ValidMask::Valid
                                && rh.hit.geomID[i] != INVALID_ID
                            {
                                merge(
                                    hit,
                                    Hit {
                                        t: rh.ray.tfar[i],
                                        tri: rh.hit.primID[i],
                                        u: rh.hit.u[i],
                                        v: rh.hit.v[i],
                                    },
                                );
                            }
                        }
                    }
                }
            }
        }
    };
}

packets!(
    packets4,
    4,
    embree3::Ray4,
    RayHit4,
    embree3::Hit4,
    intersect4,
    occluded4
);
packets!(
    packets8,
    8,
    embree3::Ray8,
    RayHit8,
    embree3::Hit8,
    intersect8,
    occluded8
);
packets!(
    packets16,
    16,
    embree3::Ray16,
    RayHit16,
    embree3::Hit16,
    intersect16,
    occluded16
);

impl Intersector<Cpu> for Embree {
    fn name(&self) -> &str {
        "embree"
    }

    fn supports_candidates(&self) -> bool {
        false
    }

    fn intersect(
        &self,
        _backend: &Cpu,
        rays: &Vec<Ray>,
        query: Query<'_, Cpu>,
        mode: HitMode,
        hits: &mut Vec<Hit>,
        stats: &mut Stats,
    ) -> Result<()> {
        query.whole_scene_only("embree")?;
        if mode.is_edge_width() {
            return Err(mode.unsupported("embree"));
        }
        check_batch(rays, hits)?;
        rays.par_chunks(TASK)
            .zip(hits.par_chunks_mut(TASK))
            .for_each(|(rs, hs)| self.trace_task(rs, mode, hs));
        stats.mark_tests_uncounted();
        Ok(())
    }
}
