//! Cone proxy traversal (seed 003 §4.1.6-4.1.9, eq. 4.1-4.8, listings 4.3-4.5): a group of
//! rays sharing an origin is enclosed in a cone (apex `s` = the origin, unit axis `v`,
//! half-angle `α`), and the cone traverses the tree with one interval, like a frustum
//! ([`super::frustum::trace_proxy`]) but with two precomputed multipliers per axis instead of
//! the extremes of the rays' inverse directions.
//!
//! # Derivation (eq. 4.8, with its conditions)
//!
//! Measure positions along the cone by `h = (p − s)·v`; the cone's cross-section at `h ≥ 0` is
//! a disc of radius `h·tanα` perpendicular to `v`. On axis `k`, that disc's points span
//! `s_k + h·v_k ± h·tanα·√(1 − v_k²)` (the largest `k` component of a unit vector orthogonal
//! to `v` is `√(1 − v_k²)`: this needs `|v| = 1`; eq. 4.7 reduces to eq. 4.8 only for a unit
//! `v`, so the axis is normalised here, erratum). With `β_k = tanα·√(1 − v_k²)`,
//! `c₊ = v_k + β_k`, `c₋ = v_k − β_k` and `dist = split − s_k`:
//!
//! - `dist > 0` (origin below the plane): the disc reaches the back side (`≥ split`) iff
//!   `h·c₊ ≥ dist`, i.e. from `h = dist / c₊` on when `c₊ > 0`, never when `c₊ ≤ 0` (the whole
//!   cone points away from the plane: `+∞`); it still touches the front side iff
//!   `h·c₋ ≤ dist`, i.e. up to `dist / c₋` when `c₋ > 0`, for ever (`+∞`) when `c₋ ≤ 0` (the
//!   cone contains directions parallel to or pointing away from the plane).
//! - `dist < 0` mirrors it: back from `dist / c₋` if `c₋ < 0` (else never), front up to
//!   `dist / c₊` if `c₊ < 0` (else for ever).
//!
//! These are listing 4.5's `t1 = min`, `t2 = max` of `dist·precompute[0|1]` with negative
//! values taken as `+∞` (listing 4.4: `precompute = 1/(v_k ± β_k)`); [`Proxy::m`] stores the
//! same reciprocals already sorted by the sign of `dist`. Listing 4.5 picks front and back
//! from an undefined `dist`: it is `split_minus_o` (erratum), as in every traversal here
//! ([`super::front_back`]).
//!
//! The group's rays enter in the units of `h`: a point at `t` on ray `i` has `h = t·(d_i·v)`,
//! positive for rays inside a cone narrower than 90°. The root interval is the span of the
//! rays' root intervals in `h`. Everything about the cone is computed in `f64` and rounded
//! outwards (α raised, `c₊` raised and `c₋` lowered by [`C_EPS`], the root span widened), so
//! the cone contains every ray and its crossings enclose theirs; the traversal widens each
//! crossing by [`super::T_SLACK`] as the others do.
//!
//! A group whose rays are not within [`MIN_COS`] of one axis (a cone wider than about 84°,
//! where `h` loses meaning) is traversed with its pyramid instead
//! ([`super::frustum::trace_group`]).
//!
//! [`Proxy::m`]: super::frustum::Proxy::m

use crsh_core::glam::{DVec3, Vec3};

use super::frustum::{self, live_dirs, trace_proxy, Proxy, NEVER_NEG, NEVER_POS};
use super::group::GroupState;
use super::{Entry, Interval};
use crate::triangle::TriangleTest;

/// Smallest cosine between the cone axis and a ray for which a cone is built.
pub const MIN_COS: f64 = 0.1;

/// Outward rounding of the `c±` denominators.
pub const C_EPS: f64 = 1e-12;

/// Relative outward rounding of the cone's angle and root span.
const REL_EPS: f64 = 1e-9;

/// A cone: unit axis and `tan` of its half-angle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cone {
    /// Unit axis.
    pub axis: DVec3,
    /// `tan α`.
    pub tan_alpha: f64,
}

impl Cone {
    /// The cone around the mean of the normalised directions `dirs` that contains all of them;
    /// `None` without directions, or when one is more than `acos(MIN_COS)` off the axis.
    pub fn enclosing(dirs: &[Vec3]) -> Option<Cone> {
        let units: Vec<DVec3> = dirs
            .iter()
            .map(|d| d.as_dvec3().normalize_or_zero())
            .collect();
        let axis = units.iter().copied().sum::<DVec3>().normalize_or_zero();
        if axis == DVec3::ZERO || units.contains(&DVec3::ZERO) {
            return None;
        }
        let cos = units.iter().map(|u| u.dot(axis)).fold(1.0f64, f64::min);
        if cos.is_nan() || cos < MIN_COS {
            return None;
        }
        let cos = cos.min(1.0);
        let tan = (1.0 - cos * cos).max(0.0).sqrt() / cos;
        Some(Cone {
            axis,
            tan_alpha: tan * (1.0 + REL_EPS) + REL_EPS,
        })
    }

    /// Listing 4.4's per-axis precomputation (eq. 4.8), as [`Proxy`] multipliers (module doc).
    /// `axis` may have any length: it is normalised first (eq. 4.7 erratum).
    pub fn proxy(axis: DVec3, tan_alpha: f64) -> Proxy {
        let v = axis.normalize();
        let mut m = [[[0.0f32; 2]; 2]; 3];
        for (k, mk) in m.iter_mut().enumerate() {
            let (i, j) = ((k + 1) % 3, (k + 2) % 3);
            // √(1 − v_k²) without cancellation for v_k ≈ ±1.
            let beta = tan_alpha * (v[i] * v[i] + v[j] * v[j]).sqrt();
            let cp = v[k] + beta + C_EPS;
            let cm = v[k] - beta - C_EPS;
            let r = |c: f64| (1.0 / c) as f32;
            mk[0] = [
                if cp > 0.0 { r(cp) } else { NEVER_POS },
                if cm > 0.0 { r(cm) } else { NEVER_POS },
            ];
            mk[1] = [
                if cm < 0.0 { r(cm) } else { NEVER_NEG },
                if cp < 0.0 { r(cp) } else { NEVER_NEG },
            ];
        }
        Proxy { m }
    }

    /// The span, in `h`, of the root intervals of the unfinished rays of `st` in the quadrants
    /// of `quadrants`, rounded outwards.
    pub fn root_span<T: TriangleTest>(
        &self,
        st: &GroupState<'_, T>,
        quadrants: u32,
    ) -> Option<Interval> {
        let mut span: Option<(f64, f64)> = None;
        for pk in st
            .packets
            .iter()
            .filter(|p| quadrants >> p.quadrant & 1 == 1)
        {
            for i in pk.start as usize..(pk.start + pk.len) as usize {
                if let (false, Some((n, f))) = (st.done[i], st.root[i]) {
                    let g = st.rays[i].dir.as_dvec3().dot(self.axis);
                    let (a, b) = (n as f64 * g, f as f64 * g);
                    span = Some(span.map_or((a, b), |(x, y)| (x.min(a), y.max(b))));
                }
            }
        }
        span.map(|(a, b)| {
            (
                (a * (1.0 - 1e-6)).max(0.0) as f32,
                (b * (1.0 + 1e-6)) as f32,
            )
        })
    }
}

/// Cone proxy traversal of one group (listing 4.5 fixed), or its pyramid when the rays are
/// too spread for a cone.
pub fn trace_group<T: TriangleTest>(
    st: &mut GroupState<'_, T>,
    cull: bool,
    stack: &mut Vec<Entry>,
) {
    let dirs = live_dirs(st, 0xF);
    let Some(cone) = Cone::enclosing(&dirs) else {
        return frustum::trace_group(st, cull, stack);
    };
    let Some(root) = cone.root_span(st, 0xF) else {
        return;
    };
    trace_proxy(
        st,
        &Cone::proxy(cone.axis, cone.tan_alpha),
        root,
        cull,
        stack,
    );
}
