//! A 4-wide `f32` vector for the coherent traversals' per-ray and per-frustum intervals (seed
//! 003 §2.3.1 "Using SIMD", listings 2.6 and 4.2's `__m128`).
//!
//! On `x86_64` it wraps SSE2's `__m128` through `std::arch` (SSE2 is part of the `x86_64`
//! baseline, so no runtime detection and no `unsafe` target features are needed, and no
//! dependency is added for the handful of operations the traversals use); on other targets it
//! is a plain `[f32; 4]` with the same semantics, chosen by `cfg`. Both paths give the same
//! bits: [`F4::min`] / [`F4::max`] follow SSE's `minps` / `maxps` (`a < b ? a : b`, so a NaN
//! in either operand yields `b`), comparisons are ordered (false on NaN), and the arithmetic
//! is IEEE single precision lane by lane.
//!
//! [`M4`] is a lane mask (all bits set or clear per lane, as SSE compares produce it);
//! [`M4::bits`] is `movemask`.

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

/// Four `f32` lanes.
#[derive(Clone, Copy, Debug)]
#[repr(transparent)]
pub struct F4(
    #[cfg(target_arch = "x86_64")] __m128,
    #[cfg(not(target_arch = "x86_64"))] [f32; 4],
);

/// A four-lane mask (the result of an [`F4`] comparison).
#[derive(Clone, Copy, Debug)]
#[repr(transparent)]
pub struct M4(
    #[cfg(target_arch = "x86_64")] __m128,
    #[cfg(not(target_arch = "x86_64"))] [bool; 4],
);

#[cfg(target_arch = "x86_64")]
mod imp {
    use super::*;

    // SAFETY (every block below): SSE and SSE2 are enabled on every x86_64 target, and the
    // intrinsics only read and write their register operands (loads and stores go through
    // arrays of the right size).
    impl F4 {
        /// All lanes `x`.
        #[inline(always)]
        pub fn splat(x: f32) -> F4 {
            F4(unsafe { _mm_set1_ps(x) })
        }
        /// Lanes `a[0..4]`.
        #[inline(always)]
        pub fn new(a: [f32; 4]) -> F4 {
            F4(unsafe { _mm_loadu_ps(a.as_ptr()) })
        }
        /// The lanes as an array.
        #[inline(always)]
        pub fn to_array(self) -> [f32; 4] {
            let mut a = [0.0f32; 4];
            unsafe { _mm_storeu_ps(a.as_mut_ptr(), self.0) };
            a
        }
        /// `a < b ? a : b` per lane (`minps`).
        #[inline(always)]
        pub fn min(self, b: F4) -> F4 {
            F4(unsafe { _mm_min_ps(self.0, b.0) })
        }
        /// `a > b ? a : b` per lane (`maxps`).
        #[inline(always)]
        pub fn max(self, b: F4) -> F4 {
            F4(unsafe { _mm_max_ps(self.0, b.0) })
        }
        /// Lane-wise `a < b`.
        #[inline(always)]
        pub fn lt(self, b: F4) -> M4 {
            M4(unsafe { _mm_cmplt_ps(self.0, b.0) })
        }
        /// Lane-wise `a <= b`.
        #[inline(always)]
        pub fn le(self, b: F4) -> M4 {
            M4(unsafe { _mm_cmple_ps(self.0, b.0) })
        }
        /// Lane-wise `a >= b`.
        #[inline(always)]
        pub fn ge(self, b: F4) -> M4 {
            M4(unsafe { _mm_cmpge_ps(self.0, b.0) })
        }
        /// `m ? a : b` per lane.
        #[inline(always)]
        pub fn select(m: M4, a: F4, b: F4) -> F4 {
            F4(unsafe { _mm_or_ps(_mm_and_ps(m.0, a.0), _mm_andnot_ps(m.0, b.0)) })
        }
    }

    impl std::ops::Mul for F4 {
        type Output = F4;
        /// Lane-wise product.
        #[inline(always)]
        fn mul(self, b: F4) -> F4 {
            F4(unsafe { _mm_mul_ps(self.0, b.0) })
        }
    }

    impl M4 {
        /// Lane `l` set exactly when bit `l` of `bits` is.
        #[inline(always)]
        pub fn from_bits(bits: u32) -> M4 {
            let f = |l: u32| if bits >> l & 1 == 1 { -1i32 } else { 0 };
            M4(unsafe { _mm_castsi128_ps(_mm_setr_epi32(f(0), f(1), f(2), f(3))) })
        }
        /// Bit `l` set when lane `l` is (`movemask`).
        #[inline(always)]
        pub fn bits(self) -> u32 {
            unsafe { _mm_movemask_ps(self.0) as u32 }
        }
        /// Lane-wise and.
        #[inline(always)]
        pub fn and(self, b: M4) -> M4 {
            M4(unsafe { _mm_and_ps(self.0, b.0) })
        }
        /// Lane-wise or.
        #[inline(always)]
        pub fn or(self, b: M4) -> M4 {
            M4(unsafe { _mm_or_ps(self.0, b.0) })
        }
    }
}

#[cfg(not(target_arch = "x86_64"))]
mod imp {
    use super::*;

    impl F4 {
        /// All lanes `x`.
        #[inline(always)]
        pub fn splat(x: f32) -> F4 {
            F4([x; 4])
        }
        /// Lanes `a[0..4]`.
        #[inline(always)]
        pub fn new(a: [f32; 4]) -> F4 {
            F4(a)
        }
        /// The lanes as an array.
        #[inline(always)]
        pub fn to_array(self) -> [f32; 4] {
            self.0
        }
        /// `a < b ? a : b` per lane (`minps`).
        #[inline(always)]
        pub fn min(self, b: F4) -> F4 {
            F4(std::array::from_fn(|l| {
                if self.0[l] < b.0[l] {
                    self.0[l]
                } else {
                    b.0[l]
                }
            }))
        }
        /// `a > b ? a : b` per lane (`maxps`).
        #[inline(always)]
        pub fn max(self, b: F4) -> F4 {
            F4(std::array::from_fn(|l| {
                if self.0[l] > b.0[l] {
                    self.0[l]
                } else {
                    b.0[l]
                }
            }))
        }
        /// Lane-wise `a < b`.
        #[inline(always)]
        pub fn lt(self, b: F4) -> M4 {
            M4(std::array::from_fn(|l| self.0[l] < b.0[l]))
        }
        /// Lane-wise `a <= b`.
        #[inline(always)]
        pub fn le(self, b: F4) -> M4 {
            M4(std::array::from_fn(|l| self.0[l] <= b.0[l]))
        }
        /// Lane-wise `a >= b`.
        #[inline(always)]
        pub fn ge(self, b: F4) -> M4 {
            M4(std::array::from_fn(|l| self.0[l] >= b.0[l]))
        }
        /// `m ? a : b` per lane.
        #[inline(always)]
        pub fn select(m: M4, a: F4, b: F4) -> F4 {
            F4(std::array::from_fn(
                |l| if m.0[l] { a.0[l] } else { b.0[l] },
            ))
        }
    }

    impl std::ops::Mul for F4 {
        type Output = F4;
        /// Lane-wise product.
        #[inline(always)]
        fn mul(self, b: F4) -> F4 {
            F4(std::array::from_fn(|l| self.0[l] * b.0[l]))
        }
    }

    impl M4 {
        /// Lane `l` set exactly when bit `l` of `bits` is.
        #[inline(always)]
        pub fn from_bits(bits: u32) -> M4 {
            M4(std::array::from_fn(|l| bits >> l & 1 == 1))
        }
        /// Bit `l` set when lane `l` is (`movemask`).
        #[inline(always)]
        pub fn bits(self) -> u32 {
            (0..4).filter(|&l| self.0[l]).map(|l| 1 << l).sum()
        }
        /// Lane-wise and.
        #[inline(always)]
        pub fn and(self, b: M4) -> M4 {
            M4(std::array::from_fn(|l| self.0[l] && b.0[l]))
        }
        /// Lane-wise or.
        #[inline(always)]
        pub fn or(self, b: M4) -> M4 {
            M4(std::array::from_fn(|l| self.0[l] || b.0[l]))
        }
    }
}

impl F4 {
    /// The smallest lane ([`F4::min`]'s rule, folded from lane 0).
    #[inline(always)]
    pub fn hmin(self) -> f32 {
        let a = self.to_array();
        let m = |x: f32, y: f32| if x < y { x } else { y };
        m(m(a[0], a[1]), m(a[2], a[3]))
    }

    /// The largest lane ([`F4::max`]'s rule).
    #[inline(always)]
    pub fn hmax(self) -> f32 {
        let a = self.to_array();
        let m = |x: f32, y: f32| if x > y { x } else { y };
        m(m(a[0], a[1]), m(a[2], a[3]))
    }

    /// Lane `l` of the vector.
    #[inline(always)]
    pub fn lane(self, l: usize) -> f32 {
        self.to_array()[l]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lanes_follow_the_sse_rules() {
        let a = F4::new([1.0, f32::NAN, -0.0, 5.0]);
        let b = F4::new([2.0, 3.0, 0.0, f32::NAN]);
        // minps/maxps: a NaN in either operand yields the second one.
        let mn = a.min(b).to_array();
        assert_eq!(mn[0], 1.0);
        assert_eq!(mn[1], 3.0);
        assert!(mn[3].is_nan());
        let mx = a.max(b).to_array();
        assert_eq!(mx[0], 2.0);
        assert_eq!(mx[1], 3.0);
        // -0.0 < 0.0 is false, so min(-0, +0) is +0, the second operand.
        assert!(mn[2].is_sign_positive());
        assert_eq!(a.lt(b).bits(), 0b0001);
        assert_eq!(a.le(b).bits(), 0b0101);
        assert_eq!(a.ge(b).bits(), 0b0100);
        assert_eq!(M4::from_bits(0b1010).bits(), 0b1010);
        let s = F4::select(M4::from_bits(0b0110), F4::splat(7.0), F4::splat(-1.0));
        assert_eq!(s.to_array(), [-1.0, 7.0, 7.0, -1.0]);
        assert_eq!(F4::new([3.0, -2.0, 8.0, 1.0]).hmin(), -2.0);
        assert_eq!(F4::new([3.0, -2.0, 8.0, 1.0]).hmax(), 8.0);
        assert_eq!(
            (F4::splat(2.0) * F4::new([1.0, 2.0, 3.0, 4.0])).lane(3),
            8.0
        );
        let m = M4::from_bits(0b0011).and(M4::from_bits(0b0110));
        assert_eq!(m.bits(), 0b0010);
        assert_eq!(m.or(M4::from_bits(0b1000)).bits(), 0b1010);
    }
}
