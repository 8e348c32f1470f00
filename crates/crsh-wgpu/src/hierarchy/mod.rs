//! Ray-space hierarchy construction on the device, and the shape checks of hierarchies with
//! [`crsh_core::RayHierarchy::leaf_offsets`] that the consumers share.
//!
//! [`sphere_cone`]: seed 000's bottom-up sphere-cone levels (fixed groups of `subdivision`
//! leaves). [`tile_cone`]: seed 004's enclosing cones of screen tiles (one level of apex cones,
//! variable leaves per node through the leaf offsets).

use crsh_core::{CoreError, Result};

pub mod sphere_cone;
pub mod tile_cone;

/// Checks a hierarchy's leaf offsets (downloaded) against a lowest level of `nodes` nodes over
/// `leaves` rays: `nodes + 1` entries, the first 0, the last `leaves`, non-decreasing.
///
/// The semantics of `crsh_core::check_leaf_offsets`, which the CPU side is adding on its
/// branch; this copy goes once that lands.
///
/// # Errors
/// [`CoreError::InvalidInput`] naming the first violation.
pub(crate) fn check_leaf_offsets(offsets: &[u32], nodes: usize, leaves: usize) -> Result<()> {
    let bad = |what: String| {
        Err(CoreError::InvalidInput(format!(
            "hierarchy leaf offsets {what}"
        )))
    };
    if offsets.len() != nodes.saturating_add(1) {
        return bad(format!(
            "have {} entries for {nodes} lowest nodes (expected {})",
            offsets.len(),
            nodes.saturating_add(1)
        ));
    }
    if offsets[0] != 0 {
        return bad(format!("start at {}, not 0", offsets[0]));
    }
    let last = offsets[nodes] as usize;
    if last != leaves {
        return bad(format!("end at {last}, not at the ray count {leaves}"));
    }
    if let Some(i) = offsets.windows(2).position(|w| w[1] < w[0]) {
        return bad(format!(
            "decrease at node {i} ({} then {})",
            offsets[i],
            offsets[i + 1]
        ));
    }
    Ok(())
}

/// Checks the shape of a hierarchy with leaf offsets of `offsets_len` entries over `n_rays`
/// rays: the order has one entry per ray, `levels[0]` has `offsets_len − 1` nodes, each level
/// above `⌈below / subdivision⌉` (`subdivision ≥ 1` when there is such a level), and the reach
/// bounds, when present, match the levels. The offsets-aware counterpart of
/// [`crsh_cpu::traverse::crsh::check_shape`] (which checks fixed groups).
///
/// # Errors
/// [`CoreError::InvalidInput`] naming the mismatch.
pub(crate) fn check_offsets_shape(
    n_rays: usize,
    subdivision: u32,
    order_len: usize,
    offsets_len: usize,
    level_lens: &[usize],
    reach_lens: &[usize],
) -> Result<()> {
    let Some(&level0) = level_lens.first() else {
        return Err(CoreError::InvalidInput("hierarchy has no levels".into()));
    };
    if order_len != n_rays {
        return Err(CoreError::InvalidInput(format!(
            "hierarchy order has {order_len} entries for {n_rays} rays"
        )));
    }
    if offsets_len != level0 + 1 {
        return Err(CoreError::InvalidInput(format!(
            "hierarchy leaf offsets have {offsets_len} entries for {level0} lowest nodes \
             (expected {})",
            level0 + 1
        )));
    }
    let sub = subdivision as usize;
    if level_lens.len() > 1 && sub == 0 {
        return Err(CoreError::InvalidInput("hierarchy subdivision is 0".into()));
    }
    let mut below = level0;
    for (i, &len) in level_lens.iter().enumerate().skip(1) {
        let want = below.div_ceil(sub);
        if len != want {
            return Err(CoreError::InvalidInput(format!(
                "hierarchy level {i} has {len} nodes, expected {want} (⌈{below} / {sub}⌉)"
            )));
        }
        below = want;
    }
    if !reach_lens.is_empty() && reach_lens != level_lens {
        return Err(CoreError::InvalidInput(
            "hierarchy reach bounds do not match its levels".into(),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn leaf_offsets_are_checked() {
        assert!(check_leaf_offsets(&[0, 3, 3, 7, 10], 4, 10).is_ok());
        assert!(check_leaf_offsets(&[0], 0, 0).is_ok());
        for (offsets, nodes, leaves) in [
            (&[0u32, 3, 10][..], 3, 10),
            (&[1, 3, 10], 2, 10),
            (&[0, 3, 9], 2, 10),
            (&[0, 3, 11], 2, 10),
            (&[0, 5, 4, 10], 3, 10),
            (&[], 0, 0),
        ] {
            let r = check_leaf_offsets(offsets, nodes, leaves);
            assert!(matches!(r, Err(CoreError::InvalidInput(_))), "{offsets:?}");
        }
    }

    #[test]
    fn offsets_shapes_are_checked() {
        assert!(check_offsets_shape(10, 0, 10, 5, &[4], &[4]).is_ok());
        assert!(check_offsets_shape(10, 2, 10, 5, &[4, 2, 1], &[]).is_ok());
        assert!(check_offsets_shape(10, 0, 10, 5, &[4, 2], &[]).is_err());
        assert!(check_offsets_shape(10, 2, 10, 4, &[4], &[]).is_err());
        assert!(check_offsets_shape(10, 2, 9, 5, &[4], &[]).is_err());
        assert!(check_offsets_shape(10, 2, 10, 5, &[4, 3], &[]).is_err());
        assert!(check_offsets_shape(10, 2, 10, 5, &[4], &[3]).is_err());
        assert!(check_offsets_shape(10, 2, 10, 5, &[], &[]).is_err());
    }
}
