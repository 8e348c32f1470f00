//! The order a pipeline traces each batch of rays in: as generated, or shuffled.
//!
//! Ray generators emit their rays in surface order (pixel order for the first bounce), which
//! hands every tracer the screen-space coherence of the camera for free. Measuring a tracer
//! or a ray hierarchy on the same rays with that coherence destroyed says how much of its
//! speed is its own: `raygen.order = shuffled` applies a seeded permutation to each batch
//! right after generation. The driver traces the permuted batch and puts the hits back in
//! generation order before shading, so the image and every hit are the same under both
//! orders; only the speed differs. Every ray generator takes the parameters ([`order_params`],
//! added by the registry), so any pipeline can be measured under either order.

use crate::config::{ParamInfo, StageSpec, StageVariantInfo};
use crate::error::{CoreError, Result};
use crate::ray::RayKind;
use crate::rng::pcg4d;

/// The order the driver traces each batch of rays in (`raygen.order`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum RayOrder {
    /// As the generator emitted them (surface order, lights one after another).
    #[default]
    Generation,
    /// A seeded pseudo-random permutation of each batch, a pure function of the seed, the
    /// batch's bounce depth and ray kind and its length ([`RayOrder::permutation`]).
    Shuffled {
        /// `raygen.order_seed`.
        seed: u32,
    },
}

impl RayOrder {
    /// The parameter values, in the order of [`order_params`].
    pub const NAMES: [&'static str; 2] = ["generation", "shuffled"];

    /// The order of a resolved `raygen` spec carrying [`order_params`] (a spec without them,
    /// from a variant registered before they existed, traces in generation order).
    pub fn from_spec(spec: &StageSpec) -> Result<RayOrder> {
        if !spec.params.contains_key("order") {
            return Ok(RayOrder::Generation);
        }
        match spec.str("order")? {
            "generation" => Ok(RayOrder::Generation),
            "shuffled" => {
                let seed = spec.i64("order_seed")?;
                let seed = u32::try_from(seed).map_err(|_| CoreError::InvalidParam {
                    key: "raygen.order_seed".into(),
                    reason: format!("{seed} is outside 0..={}", u32::MAX),
                })?;
                Ok(RayOrder::Shuffled { seed })
            }
            other => Err(CoreError::InvalidParam {
                key: "raygen.order".into(),
                reason: format!("`{other}` is not one of {}", RayOrder::NAMES.join(", ")),
            }),
        }
    }

    /// The name of the order (`generation`, `shuffled`).
    pub fn name(self) -> &'static str {
        match self {
            RayOrder::Generation => "generation",
            RayOrder::Shuffled { .. } => "shuffled",
        }
    }

    /// The trace order of a batch of `n` rays of `kind` at bounce depth `generation`: `None`
    /// in generation order, else `perm` with `perm[i]` the generated index of the `i`-th ray
    /// traced. A Fisher-Yates shuffle driven by `pcg4d(seed, generation, kind, i)`, so the
    /// same batch gets the same permutation on every backend and thread count.
    pub fn permutation(self, n: usize, kind: RayKind, generation: u32) -> Option<Vec<u32>> {
        let RayOrder::Shuffled { seed } = self else {
            return None;
        };
        let mut perm: Vec<u32> = (0..n as u32).collect();
        for i in (1..n).rev() {
            let w = pcg4d([seed, generation, kind as u32, i as u32]);
            // Lemire's multiply-shift: a uniform index in 0..=i without a division.
            let j = ((u64::from(w[0]) * (i as u64 + 1)) >> 32) as usize;
            perm.swap(i, j);
        }
        Some(perm)
    }
}

/// `data` in the order `order` (`out[i] = data[order[i]]`), the host half of
/// [`crate::Backend::gather`].
///
/// # Errors
/// [`CoreError::InvalidInput`] when an index is outside `data`.
pub fn gather<T: Copy>(data: &[T], order: &[u32]) -> Result<Vec<T>> {
    check_indices(order, data.len())?;
    Ok(order.iter().map(|&i| data[i as usize]).collect())
}

/// Checks that every index of `order` is inside a batch of `n`, as [`gather`] needs.
///
/// # Errors
/// [`CoreError::InvalidInput`] naming the first index outside.
pub fn check_indices(order: &[u32], n: usize) -> Result<()> {
    match order.iter().find(|&&i| i as usize >= n) {
        Some(i) => Err(CoreError::InvalidInput(format!(
            "ray order index {i} is outside a batch of {n}"
        ))),
        None => Ok(()),
    }
}

/// The inverse of [`gather`] (`out[order[i]] = data[i]`), the host half of
/// [`crate::Backend::scatter`].
///
/// # Errors
/// [`CoreError::InvalidInput`] when `order` is not a permutation of `0..data.len()`.
pub fn scatter<T: Copy>(data: &[T], order: &[u32]) -> Result<Vec<T>> {
    let inverse = inverse(order, data.len())?;
    gather(data, &inverse)
}

/// The inverse permutation of `order` (`inverse[order[i]] = i`), so that gathering by it
/// scatters by `order`.
///
/// # Errors
/// [`CoreError::InvalidInput`] when `order` is not a permutation of `0..n`.
pub fn inverse(order: &[u32], n: usize) -> Result<Vec<u32>> {
    let bad = || {
        CoreError::InvalidInput(format!(
            "a ray order of {} indices is not a permutation of a batch of {n}",
            order.len()
        ))
    };
    if order.len() != n {
        return Err(bad());
    }
    let mut inverse = vec![u32::MAX; n];
    for (i, &o) in order.iter().enumerate() {
        let slot = inverse.get_mut(o as usize).ok_or_else(bad)?;
        if *slot != u32::MAX {
            return Err(bad());
        }
        *slot = i as u32;
    }
    Ok(inverse)
}

/// The order parameters every ray generator takes (`order`, `order_seed`), added to `info`
/// by [`crate::Registry`] when a generator is registered.
pub fn order_params(info: StageVariantInfo) -> StageVariantInfo {
    let info = if info.params.iter().any(|p| p.name == "order") {
        info
    } else {
        info.param(ParamInfo::choice(
            "order",
            "generation",
            &RayOrder::NAMES,
            "the order each batch is traced in: as generated (surface order), or a seeded \
             permutation of the batch (shuffled), which takes away the coherence generation \
             order hands every tracer; hits go back to generation order before shading, so \
             the image is the same",
        ))
    };
    if info.params.iter().any(|p| p.name == "order_seed") {
        info
    } else {
        info.param(ParamInfo::int(
            "order_seed",
            1,
            0,
            u32::MAX as i64,
            "the seed of order = shuffled",
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generation_order_is_no_permutation() {
        assert_eq!(
            RayOrder::Generation.permutation(10, RayKind::Shadow, 1),
            None
        );
    }

    #[test]
    fn shuffles_are_seeded_permutations() {
        let a = RayOrder::Shuffled { seed: 1 };
        let p = a.permutation(1000, RayKind::Shadow, 1).unwrap();
        let mut sorted = p.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..1000).collect::<Vec<u32>>());
        assert_eq!(Some(p.clone()), a.permutation(1000, RayKind::Shadow, 1));
        // Few fixed points: a real shuffle, not the identity.
        let fixed = p
            .iter()
            .enumerate()
            .filter(|(i, &v)| *i as u32 == v)
            .count();
        assert!(fixed < 10, "{fixed} fixed points");
        for other in [
            RayOrder::Shuffled { seed: 2 }.permutation(1000, RayKind::Shadow, 1),
            a.permutation(1000, RayKind::Reflection, 1),
            a.permutation(1000, RayKind::Shadow, 2),
        ] {
            assert_ne!(other.unwrap(), p);
        }
        assert_eq!(a.permutation(0, RayKind::Shadow, 1), Some(vec![]));
        assert_eq!(a.permutation(1, RayKind::Shadow, 1), Some(vec![0]));
    }

    #[test]
    fn gather_and_scatter_are_inverse() {
        let data = [10, 11, 12, 13];
        let order = [2, 0, 3, 1];
        let g = gather(&data, &order).unwrap();
        assert_eq!(g, vec![12, 10, 13, 11]);
        assert_eq!(scatter(&g, &order).unwrap(), data.to_vec());
        assert!(gather(&data, &[4]).is_err());
        assert!(scatter(&data, &[0, 0, 1, 2]).is_err());
        assert!(scatter(&data, &[0, 1, 2]).is_err());
        assert!(scatter(&data, &[0, 1, 2, 9]).is_err());
    }

    #[test]
    fn params_parse_and_are_added_once() {
        let info = order_params(order_params(StageVariantInfo::new(
            crate::StageKind::Raygen,
            "g",
            "doc",
        )));
        assert_eq!(info.params.len(), 2);
        let mut spec = info.defaults();
        assert_eq!(RayOrder::from_spec(&spec).unwrap(), RayOrder::Generation);
        spec.params
            .insert("order".into(), crate::ParamValue::Str("shuffled".into()));
        spec.params
            .insert("order_seed".into(), crate::ParamValue::Int(7));
        assert_eq!(
            RayOrder::from_spec(&spec).unwrap(),
            RayOrder::Shuffled { seed: 7 }
        );
        assert_eq!(
            RayOrder::from_spec(&StageSpec::new("g")).unwrap(),
            RayOrder::Generation
        );
    }
}
