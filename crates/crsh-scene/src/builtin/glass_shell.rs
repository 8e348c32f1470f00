//! `glass-shell` and `glass-shell-N`: a hollow clear-glass sphere, the outer surface that of
//! [`glass_sphere`] (radius 1, normals outward) around a concentric
//! cavity of radius [`INNER_RADIUS`] = 0.6 (normals toward the centre), in the same corridor,
//! under the same camera and light. Every primary ray still hits glass, and unlike the solid
//! sphere the shell keeps paths inside the object for more than two refractions and makes
//! some of them totally internally reflect.
//!
//! # Why
//!
//! Seed 004 (Szécsi, "The Hierarchical Ray Engine", §5, §7) traces refractive objects "up to 8
//! generations of refraction", and its per-generation costs exclude the paths that have
//! terminated. `glass-sphere` cannot exercise that: a solid convex sphere refracts every path
//! exactly twice and never totally reflects. The shell adds a glass→air surface inside the
//! object, so paths go on to generations 3 and 4, and rays that meet the cavity beyond the
//! critical angle `asin(1 / 1.5) = 41.8°` are totally internally reflected (the Whitted
//! generator keeps their kind Refraction).
//!
//! # Generations reached, and why not more than 4
//!
//! Generation `k` is a path's `k`-th refraction ray (Whitted depth `k`; the primary ray is
//! depth 0); a path is alive at generation `k` when its first `k − 1` refraction rays all hit
//! glass. Traced exactly (analytic spheres, f64, pixel centres of the 256² frame, test
//! `the_alive_fractions_per_generation_are_as_documented`), with [`INNER_RADIUS`] 0.6:
//!
//! | generation | 1 | 2 | 3 | 4 | 5 | 6 | 7 | 8 |
//! |---|---|---|---|---|---|---|---|---|
//! | paths alive | 100 % | 100 % | 100 % | 72.5 % | 0 | 0 | 0 | 0 |
//!
//! and 27.5 % of the paths are totally internally reflected once (at the cavity, as their
//! generation-2 ray). Every path ends on a wall after 2, 3 or 4 refraction rays, and no
//! concentric shell of any inner radius does better: refraction and reflection at a sphere
//! conserve `n·b`, the index times the distance `b` of the ray's line from the centre
//! (Bouguer's formula for spherically symmetric media), so a camera ray passing `b` from the
//! centre (at most 0.864 in a square frame) has its whole path fixed by `b`:
//!
//! - `b < r` (72.5 % for `r` = 0.6): enters the glass, enters the cavity, leaves it, leaves the
//!   glass: 4 refraction rays;
//! - `r ≤ b < 1.5·r` (27.5 %): enters (its line then passes `b / 1.5` from the centre),
//!   meets the cavity at sine `b / (1.5·r) ≥ 1 / 1.5`, beyond the critical angle, is totally
//!   reflected, leaves: 3;
//! - `b ≥ 1.5·r` (none for `r` = 0.6): misses the cavity: 2.
//!
//! A ray in the glass meets the outer surface at sine `b / 1.5 ≤ 0.576 < 1 / 1.5`, so it always
//! leaves there. The inner radius therefore only trades generation 4 (`b < r`) against total
//! internal reflection (`r ≤ b < 1.5·r`): at 256², 0.5 gives 95.7 % / 49.7 % alive at
//! generations 3 / 4 and 46 % reflected, 0.6 gives 100 % / 72.5 % and 27.5 %, 0.75 gives
//! 100 % / 95.7 % and only 4.3 %. 0.6 keeps most paths to generation 4 and still reflects a
//! quarter of them. (Moving the cavity off-centre, by up to 0.4, still ends every path by
//! generation 4 in the same measurement; nested shells do reach 8: glass 1–0.8, air 0.8–0.6,
//! glass 0.6–0.45, air inside keeps 40 % of the paths alive at generation 8. Those are other
//! scenes.)
//!
//! The faceted mesh agrees: `glass-shell-1000` traced the same way at 48² keeps 71.4 % to
//! generation 4 and reflects 28.5 % (test `the_mesh_reflects_totally_and_keeps_paths_to_generation_4`),
//! and `crsh render --scene glass-shell --width 128 --depth 8` (BVH on the CPU) counts
//! 16,384 refraction rays in each of generations 1-3, 11,812 (72.1 %) in generation 4 and
//! none after.
//!
//! The image still shows the corridor: the final rays end on the back wall for 8 % of the
//! pixels and on the four long walls for 23 % each (the solid sphere: 60 % back wall).
//!
//! # Names and triangle counts
//!
//! - `glass-shell`: `N = 5000`, 2500 per sphere (slices `s = 50`, stacks `t = 26`): 5012
//!   triangles, 2·(2 + 50·25) + 24 = 2528 vertices.
//! - `glass-shell-N`: `N` a multiple of 4, [`MIN_TRIANGLES`] ≤ `N` ≤ [`MAX_TRIANGLES`], whose
//!   half `N / 2` the rule of [`UvGrid::for_triangles`] accepts, i.e. `N / 4 = s·(t − 1)` with
//!   `s ≥ 3` and `t − 1 ≥ 2` (the smallest accepted `N` is 24; 16, 20, 28, 44, ... are
//!   refused). Both spheres use that one grid of `N / 2` triangles. The scene has exactly
//!   `N + 12` triangles: the outer sphere (mesh 0, triangles `0..N/2`), the inner one (mesh 1,
//!   `N/2..N`), then the corridor's two per wall. Bad names are [`SceneError`]s naming the scene
//!   and the allowed values, as for `glass-sphere-N`.
//!
//! | N | slices s | stacks t | N + 12 |
//! |---|---|---|---|
//! | 100 | 5 | 6 | 112 |
//! | 500 | 25 | 6 | 512 |
//! | 1000 | 25 | 11 | 1012 |
//! | 5000 | 50 | 26 | 5012 |
//!
//! # The object
//!
//! Two UV spheres of the same grid about the origin ([`glass_sphere`]'s
//! construction): the outer of radius 1 with smooth normals and winding outward, so a ray
//! arriving from the air sees its front face (air→glass, `ri = 1 / 1.5`) and one from the glass
//! its back face; the inner of radius [`inner_radius`] with normals and winding toward the
//! centre, so its front side, the side of the lower index, is the cavity: a ray in the glass
//! sees its back face (glass→air, `ri = 1.5`, or total internal reflection), a ray crossing the
//! cavity its front face (air→glass). The Whitted generator decides entering / leaving by
//! exactly that: `Surface::FRONT_FACE` is set when the ray meets the counter-clockwise side.
//! The inner radius is 0.6 unless the outer mesh is so coarse that its inscribed ball is
//! smaller than `0.6 / 0.8`; it is then 0.8 × that ball's radius (e.g. 0.35 for `N = 24`), so
//! the cavity's mesh always lies strictly inside the outer mesh. The paper's four counts all
//! use 0.6.
//!
//! Material, corridor, light and camera are `glass-sphere`'s ([`glass_sphere::glass`],
//! [`glass_sphere::camera`] of the outer grid): the outer surface is the same, so every pixel
//! of a square frame sees glass, with the field of view narrowed for coarse outer meshes
//! exactly as for `glass-sphere` (here for `N = 100` too, whose 5 × 6 grid's inscribed radius
//! is 0.79).

use super::glass_sphere::{self, UvGrid};
use crate::error::SceneError;
use crate::model::SceneBuilder;

/// The parameterless name (`N =` [`DEFAULT_TRIANGLES`]).
pub const NAME: &str = "glass-shell";

/// The prefix of the sized names `glass-shell-N`.
pub const PREFIX: &str = "glass-shell-";

/// Object triangles of `glass-shell` (both spheres): seed 004's headline count.
pub const DEFAULT_TRIANGLES: u32 = 5000;

/// The object triangle counts seed 004 §7 sweeps.
pub const PAPER_TRIANGLES: [u32; 4] = glass_sphere::PAPER_TRIANGLES;

/// Smallest `N` in range (the grid rule refuses 16 and 20 too; the smallest accepted is 24).
pub const MIN_TRIANGLES: u32 = 16;

/// Largest `N` of `glass-shell-N`.
pub const MAX_TRIANGLES: u32 = 200_000;

/// Radius of the cavity (the outer radius is 1): module docs for the measurement behind it.
pub const INNER_RADIUS: f32 = 0.6;

/// The cavity is at most this fraction of the outer mesh's inscribed radius ([`inner_radius`]).
pub const INNER_FRACTION: f64 = 0.8;

/// The grid of each of the two spheres of an object of `triangles` triangles (`triangles / 2`
/// each), or why `triangles` is refused.
pub fn grid_for_triangles(triangles: u32) -> Result<UvGrid, String> {
    if !(MIN_TRIANGLES..=MAX_TRIANGLES).contains(&triangles) {
        return Err(format!(
            "{triangles} triangles is outside {MIN_TRIANGLES}..={MAX_TRIANGLES}"
        ));
    }
    if !triangles.is_multiple_of(4) {
        return Err(format!(
            "{triangles} triangles is not a multiple of 4 (two UV spheres of 2·s·(t − 1))"
        ));
    }
    let quarter = triangles / 4;
    UvGrid::for_triangles(triangles / 2).map_err(|_| {
        format!(
            "{triangles} triangles: {quarter} = {triangles} / 4 has no factorisation s·(t − 1) \
             with s ≥ 3 slices and t − 1 ≥ 2 (it is prime or 4)"
        )
    })
}

/// The cavity's radius for spheres of `grid`: [`INNER_RADIUS`], or [`INNER_FRACTION`] of the
/// outer mesh's inscribed radius when that is smaller (coarse meshes only).
pub fn inner_radius(grid: UvGrid) -> f32 {
    INNER_RADIUS.min((INNER_FRACTION * grid.inscribed_radius()) as f32)
}

/// Whether `name` is one of this scene's names, well-formed or not: `glass-shell`, or
/// `glass-shell-` followed by a suffix without `.`, `/` or `\`. [`triangles_for_name`] then
/// accepts or refuses it.
pub fn is_name(name: &str) -> bool {
    glass_sphere::is_sized_name(name, NAME, PREFIX)
}

/// The object triangle count a name asks for: [`DEFAULT_TRIANGLES`] for `glass-shell`, `N`
/// for `glass-shell-N`; an error naming the scene and the allowed values for anything else.
pub fn triangles_for_name(name: &str) -> Result<u32, SceneError> {
    glass_sphere::sized_triangles(name, NAME, PREFIX, DEFAULT_TRIANGLES, &allowed(), |n| {
        grid_for_triangles(n).map(|_| ())
    })
}

/// What `glass-shell-N` accepts, for error messages and listings.
pub fn allowed() -> String {
    format!(
        "glass-shell-N takes N a multiple of 4, {MIN_TRIANGLES} <= N <= {MAX_TRIANGLES}, with \
         N/4 = s*(t-1) for some s >= 3 and t-1 >= 2 (e.g. glass-shell-100, glass-shell-500, \
         glass-shell-1000; glass-shell alone is N = {DEFAULT_TRIANGLES})"
    )
}

/// The builder of `glass-shell` or `glass-shell-N` (any name [`is_name`] accepts); the scene
/// is named `name`. Errors as [`triangles_for_name`].
pub fn builder_named(name: &str) -> Result<SceneBuilder, SceneError> {
    let mut b = builder(triangles_for_name(name)?)?;
    b.rename(name);
    Ok(b)
}

/// The builder of the scene with an object of exactly `triangles` triangles, named
/// `glass-shell-N`. An error naming the scene and the allowed values when
/// [`grid_for_triangles`] refuses `triangles`.
pub fn builder(triangles: u32) -> Result<SceneBuilder, SceneError> {
    let name = format!("{PREFIX}{triangles}");
    let grid = grid_for_triangles(triangles).map_err(|why| {
        SceneError::invalid(
            format!("built-in scene '{name}'"),
            format!("{why}; {}", allowed()),
        )
    })?;
    let mut b = SceneBuilder::new(name);
    let glass = b.material(glass_sphere::glass());
    for (mesh, radius, outward) in [
        ("glass-shell-outer", 1.0, true),
        ("glass-shell-inner", inner_radius(grid), false),
    ] {
        let g = glass_sphere::uv_sphere(grid, radius, outward);
        b.mesh(mesh, &g.positions, Some(&g.normals), &g.indices, glass);
    }
    glass_sphere::corridor(&mut b);
    b.camera(glass_sphere::camera(grid));
    Ok(b)
}
