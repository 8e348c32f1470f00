//! `glass-sphere` and `glass-sphere-N`: a clear glass UV sphere that fills the whole view,
//! inside a closed box (a long corridor) of opaque diffuse walls, lit by one point light. Every
//! primary ray hits glass, so after the primary hit the frame is nothing but refraction rays
//! (and the shadow rays of the walls they end on).
//!
//! # Why
//!
//! Seed 004 (Szécsi, "The Hierarchical Ray Engine", §7) measures its ray engine on "refractive
//! objects" where "a refractive surface was visible in every pixel", traced through several
//! generations of refraction (fig. 4 shows 1, 2, 4 and 8 iterations, fig. 7 uses paths of
//! length 5, fig. 5 shows such renders), and sweeps the object's triangle count (fig. 7:
//! 100, 500, 1000 and 5000, [`PAPER_TRIANGLES`]; 5000 is its throughput estimate's case,
//! 100 the count where the hierarchy already runs twice as fast). This scene is that
//! setup: `glass-sphere` is the headline case of 5000 object triangles
//! ([`DEFAULT_TRIANGLES`]), `glass-sphere-N` the same scene with an object of exactly `N`
//! triangles. The paper queries an environment map for rays that leave the object; here the
//! environment is a box of six two-triangle walls, so every ray that leaves the sphere ends on
//! a wall and every path terminates. The number of generations is the pipeline's `--depth`,
//! not part of the scene (`--depth 8` for fig. 4's deepest column), but note that one convex
//! sphere refracts every path exactly twice: a ray entering a sphere at incidence `i` meets the
//! far side at `r = asin(sin i / 1.5) < 41.8°`, the critical angle, so it always leaves (no
//! total internal reflection) and then ends on a wall. At 256² the render counts exactly two
//! refraction rays per pixel for N = 100, 500 and 5000, whatever the depth ≥ 2; deeper
//! generations need a non-convex object or several glass objects.
//!
//! # Names and triangle counts
//!
//! - `glass-sphere`: `N = 5000` (slices `s = 50`, stacks `t = 51`): 5000 + 12 = 5012
//!   triangles, 2 + 50·50 + 24 = 2526 vertices.
//! - `glass-sphere-N`: `N` even, [`MIN_TRIANGLES`] ≤ `N` ≤ [`MAX_TRIANGLES`], and `N / 2` must
//!   split as `s·(t − 1)` with `s ≥ 3` and `t − 1 ≥ 2` (so `N / 2` is neither prime nor 4: 8,
//!   10, 14, 22, ... are refused; the smallest accepted `N` is 12). The scene has exactly
//!   `N + 12` triangles: the sphere's `N` (mesh 0, triangles `0..N`), then two per wall
//!   ([`ENVIRONMENT_TRIANGLES`]). The suffix is a plain decimal number (no sign, no leading
//!   zero); anything else, like an odd or out-of-range `N`, is a [`SceneError`] naming the scene
//!   and the allowed values, never a panic.
//!
//! The paper's counts give ([`UvGrid::for_triangles`]):
//!
//! | N | slices s | stacks t | N + 12 |
//! |---|---|---|---|
//! | 100 | 10 | 6 | 112 |
//! | 500 | 25 | 11 | 512 |
//! | 1000 | 25 | 21 | 1012 |
//! | 5000 | 50 | 51 | 5012 |
//!
//! # The object
//!
//! A UV sphere of radius 1 centred at the origin, poles on the `y` axis, with smooth per-vertex
//! normals (the unit position) and outward (counter-clockwise) winding: `t` stacks of polar
//! angle `π / t` each, `s` slices of azimuth `2π / s` each, `t − 1` rings of `s` vertices
//! between the two poles. The two polar stacks are triangle fans (`s` triangles each), every
//! other stack has two triangles per cell, so `N = 2s + 2s(t − 2) = 2·s·(t − 1)`. Of the
//! divisor pairs `N / 2 = s·(t − 1)` with `s ≥ 3`, `t − 1 ≥ 2`, the one whose ratio
//! `s / (t − 1)` is closest to 2 on a logarithmic scale wins (a cell at the equator is then
//! about as wide, `2π / s`, as it is tall, `π / t`). **Tie rule**: two pairs whose ratios are
//! equally far from 2 by that measure (e.g. `N = 5000`: 50 / 50 is half of 2 and 100 / 25
//! twice 2) go to the one with fewer slices (50 × 51 rather than 100 × 26): cells narrow by
//! `sin θ` away from the equator, so the pair with the wider equatorial cells is the squarer
//! one on average.
//!
//! Each cell's four corners lie on two parallel chords, so the cells are planar trapezoids and
//! the mesh is a convex polyhedron inscribed in the unit sphere; it contains the ball of radius
//! [`UvGrid::inscribed_radius`] (0.9216 for N = 100, 0.9820 for 500, 0.9893 for 1000, 0.9976
//! for 5000).
//!
//! # Material
//!
//! Clear glass ([`glass`]): transparency 1, reflectivity 0, index of refraction [`IOR`] = 1.5,
//! no specular, a tiny grey diffuse ([`GLASS_DIFFUSE`]). Its local weight `1 − reflectivity −
//! transparency` is 0, so the Whitted generator spawns only refraction rays at the sphere (no
//! shadow or reflection rays; total internal reflection keeps the refraction kind) and the
//! Phong shader gives it no local colour: the diffuse colour matters only to the AO and
//! diffuse generators, which treat every material as opaque and diffuse, and it is not black
//! so that their images of this scene are not black either. The walls are opaque diffuse
//! (reflectivity and transparency 0, no specular), each its own mesh and colour (floor grey,
//! ceiling light grey, left red, right green, back blue, front yellow), normals facing the
//! inside of the box [`ROOM_MIN`]..[`ROOM_MAX`] = `[-2, 2] × [-2, 2] × [-12, 4]`; they spawn
//! only shadow rays. The box is a corridor so that the refraction shows: the sphere is a ball
//! lens that turns the view around and spreads it (a ray 16.7° off the axis, a square
//! frame's corner, leaves at 32°), and only rays leaving within about 12° of the axis reach
//! the back wall, so the image is the corridor upside down, the blue back wall in the middle
//! (out to about 10° of the 12° half field of view) and the four long walls around it (a cube
//! such as `[-6, 6]³` would show the back wall in every pixel). The point light sits at [`LIGHT_POSITION`], above, right of and in
//! front of the sphere, off the camera's axis and not behind the sphere.
//!
//! # Camera and coverage
//!
//! The eye is on `+z` at [`EYE_DISTANCE`] = 3 from the centre, looking at the origin, up `+y`,
//! vertical field of view [`VFOV_DEG`] = 24°, framed for square images (`aspect = 1`, so the
//! image height defaults to its width). A ray at angle `α` from the axis passes at distance
//! `3·sin α` from the centre, so it hits the unit sphere iff `α < asin(1/3) = 19.47°`. The
//! widest ray of a square frame goes through a corner: `α = atan(√2·tan 12°) = 16.73°`, a
//! margin of 2.74°; that ray passes 0.864 from the centre, 0.136 inside the silhouette. Every
//! pixel of every square frame therefore sees the sphere, and because the mesh contains the ball
//! of its inscribed radius, the mesh covers the view too whenever that radius exceeds
//! 0.864 + [`COVER_MARGIN`] = 0.884. That holds for all of the paper's counts and for every
//! accepted `N > 84` except the grids of three stacks (`N = 4p`, `p` prime, whose only
//! factorisation is `p × 2`: a spindle whose middle band spans 60°). For those and for the
//! coarse meshes (`N ≤ 84`, e.g. 0.433 for `N = 12`) the field of view narrows to the widest
//! that the inscribed ball still covers ([`camera`], [`covering_vfov_deg`]; 11.2° for
//! `N = 12`), so "glass in every pixel of a square frame" holds for every accepted `N`.
//!
//! Pixels are square and the horizontal extent grows with the image's `width / height` `a`
//! ([`Camera::direction`]): a corner ray has `tan α = tan 12°·√(1 + a²)`. Portrait and square
//! frames (`a ≤ 1`) are fully covered; landscape frames are fully covered by the unit sphere up
//! to `a = 1.329`, by the mesh's inscribed ball up to `a ≈ 1.14` for N = 100, 1.29 for 500,
//! 1.30 for 1000 and 1.32 for 5000. So 4:3 and 16:9 frames show the walls in their corners
//! (the paper used square 256² and 512² frames).

use std::f64::consts::PI;

use glam::Vec3;

use super::Geometry;
use crate::error::SceneError;
use crate::model::{Camera, Light, Material, SceneBuilder};

/// The parameterless name (`N =` [`DEFAULT_TRIANGLES`]).
pub const NAME: &str = "glass-sphere";

/// The prefix of the sized names `glass-sphere-N`.
pub const PREFIX: &str = "glass-sphere-";

/// Object triangles of `glass-sphere`: the paper's headline case.
pub const DEFAULT_TRIANGLES: u32 = 5000;

/// The object triangle counts seed 004 §7 sweeps.
pub const PAPER_TRIANGLES: [u32; 4] = [100, 500, 1000, 5000];

/// Smallest `N` of `glass-sphere-N` in range (the factorisation rule refuses 8 and 10 too; the
/// smallest accepted `N` is 12).
pub const MIN_TRIANGLES: u32 = 8;

/// Largest `N` of `glass-sphere-N`.
pub const MAX_TRIANGLES: u32 = 200_000;

/// Triangles of the environment: six walls of two triangles.
pub const ENVIRONMENT_TRIANGLES: usize = 12;

/// Lower corner of the closed box of walls.
pub const ROOM_MIN: Vec3 = Vec3::new(-2.0, -2.0, -12.0);

/// Upper corner of the closed box of walls.
pub const ROOM_MAX: Vec3 = Vec3::new(2.0, 2.0, 4.0);

/// Distance of the eye (on `+z`) from the sphere's centre.
pub const EYE_DISTANCE: f32 = 3.0;

/// Vertical field of view in degrees (narrowed for meshes too coarse to fill it: [`camera`]).
pub const VFOV_DEG: f32 = 24.0;

/// How far inside the mesh's inscribed ball (in units of the sphere's radius) the widest view
/// ray of a square frame must pass, so rounding never lets it slip past the mesh.
pub const COVER_MARGIN: f64 = 0.02;

/// Index of refraction of the glass.
pub const IOR: f32 = 1.5;

/// Diffuse colour of the glass: unused by Whitted shading (its local weight is 0), seen only
/// by the AO and diffuse generators, which treat the sphere as an opaque dark grey ball.
pub const GLASS_DIFFUSE: Vec3 = Vec3::splat(0.05);

/// Where the point light sits: inside the box, off the camera's axis, in front of the sphere.
pub const LIGHT_POSITION: Vec3 = Vec3::new(1.2, 1.6, 2.0);

/// The slices and stacks of a UV sphere.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct UvGrid {
    /// Number of slices (vertices per ring), at least 3.
    pub slices: u32,
    /// Number of stacks (bands from pole to pole), at least 3; there are `stacks − 1` rings.
    pub stacks: u32,
}

impl UvGrid {
    /// The grid of exactly `triangles` triangles (`2·s·(t − 1)`) whose equatorial cells are
    /// squarest: of the pairs `s·(t − 1) = triangles / 2` with `s ≥ 3`, `t − 1 ≥ 2`, the one
    /// with `s / (t − 1)` closest to 2 on a log scale, the smaller `s` on a tie (module docs).
    /// An error message when `triangles` is not [`MIN_TRIANGLES`]..=[`MAX_TRIANGLES`], odd,
    /// or has no such factorisation.
    pub fn for_triangles(triangles: u32) -> Result<UvGrid, String> {
        if !(MIN_TRIANGLES..=MAX_TRIANGLES).contains(&triangles) {
            return Err(format!(
                "{triangles} triangles is outside {MIN_TRIANGLES}..={MAX_TRIANGLES}"
            ));
        }
        if !triangles.is_multiple_of(2) {
            return Err(format!(
                "{triangles} triangles is odd (a UV sphere has 2·s·(t − 1))"
            ));
        }
        let half = triangles / 2;
        // Distance of s / (t − 1) from 2 on a log scale, as the exact fraction
        // max(s, 2m) / min(s, 2m) (m = t − 1), compared by cross-multiplication.
        let skew = |s: u32, m: u32| {
            let (a, b) = (u64::from(s), 2 * u64::from(m));
            (a.max(b), a.min(b))
        };
        let mut best: Option<(u32, u32)> = None;
        for s in 3..=half / 2 {
            if !half.is_multiple_of(s) {
                continue;
            }
            let m = half / s;
            if m < 2 {
                continue;
            }
            let better = match best {
                None => true,
                Some((bs, bm)) => {
                    let ((p, q), (bp, bq)) = (skew(s, m), skew(bs, bm));
                    // Strictly closer wins; s only grows, so a tie keeps the smaller s.
                    p * bq < bp * q
                }
            };
            if better {
                best = Some((s, m));
            }
        }
        best.map(|(slices, m)| UvGrid {
            slices,
            stacks: m + 1,
        })
        .ok_or_else(|| {
            format!(
                "{triangles} triangles: {half} = {triangles} / 2 has no factorisation s·(t − 1) \
                 with s ≥ 3 slices and t − 1 ≥ 2 (it is prime or 4)"
            )
        })
    }

    /// Number of triangles, `2·s·(t − 1)`.
    pub fn triangles(self) -> u32 {
        2 * self.slices * (self.stacks - 1)
    }

    /// Number of vertices, `2 + s·(t − 1)` (one per pole, the seam not duplicated).
    pub fn vertices(self) -> u32 {
        2 + self.slices * (self.stacks - 1)
    }

    /// Radius of the largest ball about the centre inside the (convex) mesh: the smallest
    /// distance from the centre to a face's plane. A cell between polar angles `θ₀, θ₁` lies
    /// in the plane through the chords at mid-azimuth; in that meridian plane its corners are
    /// `(c·sin θ, cos θ)` with `c = cos(π / s)`, and the distance is the line's.
    pub fn inscribed_radius(self) -> f64 {
        let c = (PI / f64::from(self.slices)).cos();
        let t = f64::from(self.stacks);
        (0..self.stacks)
            .map(|i| {
                let (a, b) = (PI * f64::from(i) / t, PI * f64::from(i + 1) / t);
                let (x0, y0, x1, y1) = (c * a.sin(), a.cos(), c * b.sin(), b.cos());
                (x0 * y1 - x1 * y0).abs() / (x0 - x1).hypot(y0 - y1)
            })
            .fold(f64::INFINITY, f64::min)
    }
}

/// Whether `name` is one of this scene's names, well-formed or not: `glass-sphere`, or
/// `glass-sphere-` followed by a suffix without `.`, `/` or `\` (so that a file such as
/// `glass-sphere-5.toml` stays a file). [`triangles_for_name`] then accepts or refuses it.
pub fn is_name(name: &str) -> bool {
    is_sized_name(name, NAME, PREFIX)
}

/// Whether `name` is `base` or `prefix` followed by a suffix without `.`, `/` or `\` (a sized
/// built-in name, well-formed or not; a file such as `prefix5.toml` stays a file). Shared by
/// `glass-sphere-N` and `glass-shell-N`.
pub(crate) fn is_sized_name(name: &str, base: &str, prefix: &str) -> bool {
    name == base
        || name
            .strip_prefix(prefix)
            .is_some_and(|rest| !rest.contains(['.', '/', '\\']))
}

/// The object triangle count a name asks for: [`DEFAULT_TRIANGLES`] for `glass-sphere`, `N`
/// for `glass-sphere-N`; an error naming the scene and the allowed values for anything else.
pub fn triangles_for_name(name: &str) -> Result<u32, SceneError> {
    sized_triangles(name, NAME, PREFIX, DEFAULT_TRIANGLES, &allowed(), |n| {
        UvGrid::for_triangles(n).map(|_| ())
    })
}

/// The triangle count a sized built-in name asks for: `default` for `base`, `N` for `prefixN`
/// when `check(N)` accepts it; otherwise an error naming the scene, why, and `allowed`. The
/// suffix must be a plain decimal number (no sign, no leading zero). Shared by
/// `glass-sphere-N` and `glass-shell-N`.
pub(crate) fn sized_triangles(
    name: &str,
    base: &str,
    prefix: &str,
    default: u32,
    allowed: &str,
    check: impl Fn(u32) -> Result<(), String>,
) -> Result<u32, SceneError> {
    if name == base {
        return Ok(default);
    }
    let refuse = |why: String| {
        SceneError::invalid(
            format!("built-in scene '{name}'"),
            format!("{why}; {allowed}"),
        )
    };
    let Some(suffix) = name.strip_prefix(prefix) else {
        return Err(refuse(format!("not a {base} name")));
    };
    if suffix.is_empty()
        || !suffix.bytes().all(|b| b.is_ascii_digit())
        || (suffix.len() > 1 && suffix.starts_with('0'))
    {
        return Err(refuse(format!(
            "'{suffix}' is not a triangle count (a decimal number without sign or leading zero)"
        )));
    }
    let n: u32 = suffix
        .parse()
        .map_err(|_| refuse(format!("{suffix} triangles is too large")))?;
    check(n).map_err(refuse)?;
    Ok(n)
}

/// What `glass-sphere-N` accepts, for error messages and listings.
pub fn allowed() -> String {
    format!(
        "glass-sphere-N takes N even, {MIN_TRIANGLES} <= N <= {MAX_TRIANGLES}, with N/2 = \
         s*(t-1) for some s >= 3 and t-1 >= 2 (e.g. glass-sphere-100, glass-sphere-500, \
         glass-sphere-1000; glass-sphere alone is N = {DEFAULT_TRIANGLES})"
    )
}

/// The glass of the sphere: transparency 1, reflectivity 0, ior [`IOR`], diffuse
/// [`GLASS_DIFFUSE`], no specular (its local weight is 0, so only refraction rays leave it in
/// a Whitted frame).
pub fn glass() -> Material {
    Material {
        name: "glass".into(),
        diffuse: GLASS_DIFFUSE,
        specular: Vec3::ZERO,
        shininess: 1.0,
        reflectivity: 0.0,
        transparency: 1.0,
        ior: IOR,
        emission: Vec3::ZERO,
    }
}

/// The largest vertical field of view (degrees) for which every ray of a square frame from
/// the eye at [`EYE_DISTANCE`] passes within `radius` of the centre: the corner ray's angle
/// `atan(√2·tan(vfov / 2))` equals `asin(radius / EYE_DISTANCE)`.
pub fn covering_vfov_deg(radius: f64) -> f32 {
    let alpha = (radius / f64::from(EYE_DISTANCE)).clamp(0.0, 1.0).asin();
    (2.0 * (alpha.tan() / 2f64.sqrt()).atan()).to_degrees() as f32
}

/// The camera for an object of grid `grid`: on `+z` at [`EYE_DISTANCE`], looking at the
/// centre, up `+y`, square framing, vertical field of view [`VFOV_DEG`] or, for a mesh whose
/// inscribed ball cannot fill that view, [`covering_vfov_deg`] of its inscribed radius less
/// [`COVER_MARGIN`].
pub fn camera(grid: UvGrid) -> Camera {
    Camera {
        eye: Vec3::new(0.0, 0.0, EYE_DISTANCE),
        target: Vec3::ZERO,
        up: Vec3::Y,
        vfov_deg: VFOV_DEG.min(covering_vfov_deg(grid.inscribed_radius() - COVER_MARGIN)),
        aspect: Some(1.0),
    }
}

/// The UV sphere of `grid` and `radius` about the origin (module docs): north pole first, then
/// the rings from north to south (`s` vertices each, azimuth 0 on `+z`, increasing towards
/// `+x`), then the south pole. `outward`: normals are the unit positions and the winding is
/// counter-clockwise seen from outside (front faces outside); otherwise both are reversed
/// (normals toward the centre, front faces inside, as a cavity's wall). Radius 1 and outward
/// is `glass-sphere`'s object and `glass-shell`'s outer surface.
pub(crate) fn uv_sphere(grid: UvGrid, radius: f32, outward: bool) -> Geometry {
    let (s, t) = (grid.slices, grid.stacks);
    let mut g = Geometry::default();
    let sign = if outward { 1.0 } else { -1.0 };
    let mut vertex = |unit: Vec3| {
        g.positions.push(unit * radius);
        g.normals.push(unit * sign);
    };
    vertex(Vec3::Y);
    for i in 1..t {
        let theta = PI * f64::from(i) / f64::from(t);
        for j in 0..s {
            let phi = 2.0 * PI * f64::from(j) / f64::from(s);
            let p = glam::DVec3::new(
                theta.sin() * phi.sin(),
                theta.cos(),
                theta.sin() * phi.cos(),
            );
            vertex(p.normalize().as_vec3());
        }
    }
    vertex(-Vec3::Y);
    let south = 1 + s * (t - 1);
    let ring = |i: u32, j: u32| 1 + (i - 1) * s + j % s;
    for j in 0..s {
        g.indices.push([0, ring(1, j), ring(1, j + 1)]);
    }
    for i in 1..t - 1 {
        for j in 0..s {
            let (a, b, c, d) = (
                ring(i, j),
                ring(i + 1, j),
                ring(i + 1, j + 1),
                ring(i, j + 1),
            );
            g.indices.extend([[a, b, c], [a, c, d]]);
        }
    }
    for j in 0..s {
        g.indices.push([south, ring(t - 1, j + 1), ring(t - 1, j)]);
    }
    if !outward {
        for tri in &mut g.indices {
            tri.swap(1, 2);
        }
    }
    g
}

/// The builder of `glass-sphere` or `glass-sphere-N` (any name [`is_name`] accepts); the
/// scene is named `name`. Errors as [`triangles_for_name`].
pub fn builder_named(name: &str) -> Result<SceneBuilder, SceneError> {
    let mut b = builder(triangles_for_name(name)?)?;
    b.rename(name);
    Ok(b)
}

/// The builder of the scene with an object of exactly `triangles` triangles, named
/// `glass-sphere-N` (camera, light, materials and meshes set; call `build`). An error naming
/// the scene and the allowed values when [`UvGrid::for_triangles`] refuses `triangles`.
pub fn builder(triangles: u32) -> Result<SceneBuilder, SceneError> {
    let name = format!("{PREFIX}{triangles}");
    let grid = UvGrid::for_triangles(triangles).map_err(|why| {
        SceneError::invalid(
            format!("built-in scene '{name}'"),
            format!("{why}; {}", allowed()),
        )
    })?;
    let mut b = SceneBuilder::new(name);
    let glass = b.material(glass());
    let sphere = uv_sphere(grid, 1.0, true);
    b.mesh(
        "glass-sphere",
        &sphere.positions,
        Some(&sphere.normals),
        &sphere.indices,
        glass,
    );
    corridor(&mut b);
    b.camera(camera(grid));
    Ok(b)
}

/// Adds the environment shared by `glass-sphere` and `glass-shell` to `b`: the six diffuse
/// walls of the corridor [`ROOM_MIN`]..[`ROOM_MAX`] (one mesh and material each, in the order
/// floor, ceiling, left, right, back, front, facing the inside; [`ENVIRONMENT_TRIANGLES`]) and
/// the point light at [`LIGHT_POSITION`].
pub(crate) fn corridor(b: &mut SceneBuilder) {
    let wall = |name: &str, diffuse: Vec3| Material {
        name: name.into(),
        diffuse,
        specular: Vec3::ZERO,
        shininess: 1.0,
        reflectivity: 0.0,
        transparency: 0.0,
        ior: 1.0,
        emission: Vec3::ZERO,
    };
    let (lo, hi) = (ROOM_MIN, ROOM_MAX);
    let v = Vec3::new;
    // (name, colour, axis, whether the wall is the box's face at `hi` (else `lo`) along that
    // axis); each faces the inside.
    let walls: [(&str, Vec3, usize, bool); 6] = [
        ("floor", v(0.7, 0.7, 0.65), 1, false),
        ("ceiling", v(0.85, 0.85, 0.85), 1, true),
        ("left-wall", v(0.75, 0.15, 0.1), 0, false),
        ("right-wall", v(0.15, 0.6, 0.15), 0, true),
        ("back-wall", v(0.15, 0.25, 0.7), 2, false),
        ("front-wall", v(0.7, 0.6, 0.15), 2, true),
    ];
    for (name, colour, axis, high) in walls {
        let m = b.material(wall(name, colour));
        let level = if high { hi[axis] } else { lo[axis] };
        let (u, w) = ((axis + 1) % 3, (axis + 2) % 3);
        let corner = |cu: f32, cw: f32| {
            let mut p = Vec3::ZERO;
            p[axis] = level;
            p[u] = cu;
            p[w] = cw;
            p
        };
        let mut inward = Vec3::ZERO;
        inward[axis] = if high { -1.0 } else { 1.0 };
        let mut g = Geometry::default();
        g.quad_facing(
            corner(lo[u], lo[w]),
            corner(hi[u], lo[w]),
            corner(hi[u], hi[w]),
            corner(lo[u], hi[w]),
            inward,
        );
        b.mesh(name, &g.positions, Some(&g.normals), &g.indices, m);
    }
    b.light(Light {
        position: LIGHT_POSITION,
        color: Vec3::ONE,
        intensity: 1.0,
        attenuation: [1.0, 0.0, 0.0],
        radius: 0.0,
    });
}
