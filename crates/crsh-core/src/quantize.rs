//! Quantizers shared by the ray hashers of every backend and by third-party hashers: uniform
//! cells over an interval, spherical and octahedral direction cells, and MSB-first bit
//! interleaving (seed 000 §3.2.3 quantizes origins and directions before hashing; figs 3.8-3.9
//! lay the fields out).
//!
//! # Bit-identical on every backend
//!
//! Every cell here is defined by `f32` arithmetic that any IEEE-754 machine evaluates to the same
//! bits, so the wgpu hashers (`crsh-wgpu`'s `hash/quantize.wgsl`) compute exactly the CPU's keys:
//!
//! - only `+`, `−`, `×`, comparisons, `floor`, `min`/`max` and bit operations, which WGSL
//!   evaluates exactly or correctly rounded (division, `sqrt`, `acos` and `atan2` are not
//!   correctly rounded in WGSL and are never used);
//! - a product is either exact (the operands are split into 12-bit halves by masking their
//!   bits) or feeds only a comparison or a `floor`, never a sum, so a device that fuses `a·b + c`
//!   into one FMA gets the same bits as one that does not;
//! - inputs are screened by their bits first: NaN, infinities and subnormals (which a GPU may
//!   flush to zero) are mapped to fixed values before any arithmetic, and directions are scaled
//!   by a power of two (an exponent change, exact) so that no intermediate underflows;
//! - angles are never computed: the cell boundaries (`tan²θ_k`, `tan` of the azimuth within an
//!   octant) are tabulated once on the host in `f64` and rounded to `f32`
//!   ([`theta_threshold`], [`phi_threshold`]), and a direction's cell is the last boundary it
//!   passes, found by comparisons against the table.
//!
//! What this relies on from a device: IEEE-754 binary32 with round-to-nearest `+`, `−`, `×` (WGSL
//! requires them correctly rounded) and no reassociation of sums (an assumption about the
//! targets' default, non-fast-math compilation, checked on lavapipe by the wgpu tests); contraction into FMAs and
//! flushing subnormals to zero are allowed and cannot change a cell.
//!
//! The cells are the thesis's fixed quantization (equal cells of the interval, equal angles in
//! `θ` and `φ`, the equal-area octahedral square); only directions or coordinates within a few
//! `f32` rounding errors of a boundary can fall on the other side of it than an exact real
//! computation would put them, the same on every backend.

use std::sync::OnceLock;

use glam::{Vec2, Vec3};

/// `2^bits` as an `f32` (exact for `bits <= 127`).
fn pow2(bits: u32) -> f32 {
    f32::from_bits((127 + bits) << 23)
}

/// Uniform cells of an interval, evaluated identically on every backend: `2^bits` cells of
/// `[lo, hi]`, the cell of `x` being `floor((clamp(x, lo, hi) − lo) · scale)` in `f32`
/// (clamped to `0 ..= 2^bits − 1`), with `scale = 2^bits / (hi − lo)` rounded to `f32` once on
/// the host. A subtraction then a product, both correctly rounded and neither fusable into an
/// FMA, then an exact `floor`: the WGSL twin computes the same cell from the same
/// `(lo, hi, scale)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UniformCells {
    /// Low end of the interval (0 for a degenerate one).
    pub lo: f32,
    /// High end of the interval (0 for a degenerate one).
    pub hi: f32,
    /// `2^bits / (hi − lo)` rounded to `f32`; 0 when every value is in cell 0.
    pub scale: f32,
    /// Bits of the cell index (at most 32).
    pub bits: u32,
}

impl UniformCells {
    /// `2^bits` cells of `[lo, hi]`. `bits == 0`, NaN bounds and an empty or degenerate
    /// interval (`hi <= lo`, e.g. a flat scene's thin axis) put everything in cell 0. `bits`
    /// must be at most 32.
    pub fn new(lo: f32, hi: f32, bits: u32) -> UniformCells {
        debug_assert!(bits <= 32);
        let span = hi as f64 - lo as f64;
        let scale = ((1u64 << bits) as f64 / span) as f32;
        if bits == 0 || !(span > 0.0 && span.is_finite()) || !scale.is_finite() {
            return UniformCells {
                lo: 0.0,
                hi: 0.0,
                scale: 0.0,
                bits,
            };
        }
        UniformCells {
            lo,
            hi,
            scale,
            bits,
        }
    }

    /// The cell of `x`: NaN gives 0, values outside the interval (infinities included) land in
    /// the first or last cell, subnormals count as 0. Monotone non-decreasing in `x`.
    pub fn cell(&self, x: f32) -> u64 {
        let b = x.to_bits();
        let x = match b & 0x7f80_0000 {
            0 => 0.0,
            0x7f80_0000 if b & 0x007f_ffff != 0 => return 0,
            0x7f80_0000 if b >> 31 == 1 => self.lo,
            0x7f80_0000 => self.hi,
            _ => x.max(self.lo).min(self.hi),
        };
        let f = ((x - self.lo) * self.scale).floor();
        if f >= pow2(self.bits) {
            (1u64 << self.bits) - 1
        } else {
            f as u64
        }
    }
}

/// Cell index of `x` among `2^bits` equal cells of `[lo, hi]`: [`UniformCells::new`]`(lo, hi,
/// bits).cell(x)`, i.e. `floor((x − lo) · scale)` in `f32` with `scale = 2^bits / (hi − lo)`,
/// clamped to `0 ..= 2^bits − 1`.
///
/// Values outside the interval land in the first or last cell; NaN, `bits == 0` and an empty
/// or degenerate interval (`hi <= lo`) give 0. `bits` must be at most 32. Monotone
/// non-decreasing in `x`.
pub fn quantize(x: f32, lo: f32, hi: f32, bits: u32) -> u64 {
    UniformCells::new(lo, hi, bits).cell(x)
}

/// Direction `d` scaled by a power of two so that its largest component lies in `[1, 2)`, by
/// exponent arithmetic on the bits (exact): components more than 2³² times smaller than the
/// largest, and subnormal ones, become 0. `None` for a zero, subnormal-only or non-finite
/// direction. What the direction cells are computed from, on every backend.
pub fn scaled_direction(d: Vec3) -> Option<[f32; 3]> {
    let b = d.to_array().map(f32::to_bits);
    let e = b.map(|b| (b >> 23) & 0xff);
    let top = e[0].max(e[1]).max(e[2]);
    if top == 0 || top == 0xff {
        return None;
    }
    Some(std::array::from_fn(|i| {
        if e[i] == 0 || e[i] + 32 < top {
            0.0
        } else {
            f32::from_bits((b[i] & 0x807f_ffff) | ((e[i] + 127 - top) << 23))
        }
    }))
}

/// `a · b` as the sum of the exact products of the operands' 12-bit halves (`ah·bh + ((ah·bl +
/// al·bh) + al·bl)`, halves by masking the bits): within a few ULPs of the product and the same
/// bits whether or not a device fuses a product into the sum that follows it (each product is
/// exact, so the fused and unfused sums round alike). Exact as long as no partial product is
/// subnormal (operands above about 1e-19 in magnitude, or 0). NaN when either operand is
/// infinite.
pub fn product(a: f32, b: f32) -> f32 {
    let half = |x: f32| f32::from_bits(x.to_bits() & 0xffff_f000);
    let (ah, bh) = (half(a), half(b));
    let (al, bl) = (a - ah, b - bh);
    ah * bh + ((ah * bl + al * bh) + al * bl)
}

/// `x²` by [`product`]. `x` comes from [`scaled_direction`] (no underflow).
pub fn square(x: f32) -> f32 {
    product(x, x)
}

/// The largest bits for which the direction boundaries are tabulated (and the widest
/// direction field a device hash takes: the tables travel to it).
pub const MAX_TABLE_BITS: u32 = 20;

/// The `θ` boundary `k` (`1 <= k < 2^bits`; `θ_k = kπ / 2^bits`) as the hash compares it:
/// `tan²θ_k` below the equator, `tan²(π − θ_k)` above it, rounded to `f32` (`+∞` at the
/// equator itself, which is tested by the sign of `z` alone; 0 for `k = 0`).
pub fn theta_threshold(bits: u32, k: u64) -> f32 {
    let n = 1u64 << bits;
    let m = k.min(n - k);
    if k == 0 {
        0.0
    } else if 2 * k == n {
        f32::INFINITY
    } else {
        let t = (std::f64::consts::PI * m as f64 / n as f64).tan();
        (t * t) as f32
    }
}

/// The octant (0-7, in order of increasing azimuth from `−π`) of azimuth boundary `k` of
/// `2^bits`.
fn phi_octant(bits: u32, k: u64) -> u64 {
    (k << 3) >> bits
}

/// The `φ` boundary `k` (`0 <= k < 2^bits`; `φ_k = −π + 2kπ / 2^bits`) as the hash compares it:
/// with `α` the angle from the start of its octant (0 to π/4), `tan α` in an even octant and
/// `tan(π/4 − α)` in an odd one, rounded to `f32`.
pub fn phi_threshold(bits: u32, k: u64) -> f32 {
    let o = phi_octant(bits, k);
    let num = (k << 3) - (o << bits);
    let n = 1u64 << bits;
    let q = std::f64::consts::FRAC_PI_4;
    if o.is_multiple_of(2) {
        (q * num as f64 / n as f64).tan() as f32
    } else {
        (q * (n - num) as f64 / n as f64).tan() as f32
    }
}

/// The boundary table of `threshold` for `bits` (`2^bits` entries), built once per process.
fn table(
    cache: &'static [OnceLock<Box<[f32]>>; MAX_TABLE_BITS as usize + 1],
    threshold: fn(u32, u64) -> f32,
    bits: u32,
) -> &'static [f32] {
    cache[bits as usize].get_or_init(|| (0..1u64 << bits).map(|k| threshold(bits, k)).collect())
}

/// [`theta_threshold`] for every `k < 2^bits` (`bits <= MAX_TABLE_BITS`), built once.
pub fn theta_table(bits: u32) -> &'static [f32] {
    static CACHE: [OnceLock<Box<[f32]>>; MAX_TABLE_BITS as usize + 1] =
        [const { OnceLock::new() }; MAX_TABLE_BITS as usize + 1];
    table(&CACHE, theta_threshold, bits)
}

/// [`phi_threshold`] for every `k < 2^bits` (`bits <= MAX_TABLE_BITS`), built once.
pub fn phi_table(bits: u32) -> &'static [f32] {
    static CACHE: [OnceLock<Box<[f32]>>; MAX_TABLE_BITS as usize + 1] =
        [const { OnceLock::new() }; MAX_TABLE_BITS as usize + 1];
    table(&CACHE, phi_threshold, bits)
}

/// The largest `k` in `0 ..= max` with `test(k)`, for a `test` that holds at 0 and is
/// monotone (true up to some `k`, false after).
fn last_true(max: u64, test: impl Fn(u64) -> bool) -> u64 {
    let (mut lo, mut hi) = (0u64, max);
    while lo < hi {
        let mid = lo + (hi - lo).div_ceil(2);
        if test(mid) {
            lo = mid;
        } else {
            hi = mid - 1;
        }
    }
    lo
}

/// [`last_true`] started from a guess: a few steps from `guess` when the answer is near it (the
/// guess from an `f64` angle is almost always right), else the full binary search. Same result
/// as [`last_true`] for any guess.
fn last_true_near(max: u64, guess: f64, test: impl Fn(u64) -> bool) -> u64 {
    let mut k = if guess.is_finite() && guess > 0.0 {
        (guess as u64).min(max)
    } else {
        0
    };
    for _ in 0..4 {
        if !test(k) {
            if k == 0 {
                break;
            }
            k -= 1;
        } else if k == max || !test(k + 1) {
            return k;
        } else {
            k += 1;
        }
    }
    last_true(max, test)
}

/// Defines `$name`, `atan2(y, x)` in `$t` by a degree-11 odd minimax polynomial on `[0, 1]`
/// after octant reduction (0 for `x = y = 0`), once for each precision the guesses use.
macro_rules! atan2_polynomial {
    ($(#[$doc:meta])* $name:ident, $t:ident) => {
        $(#[$doc])*
        #[inline]
        fn $name(y: $t, x: $t) -> $t {
            let (ax, ay) = (x.abs(), y.abs());
            let (lo, hi) = (ax.min(ay), ax.max(ay));
            if hi == 0.0 {
                return 0.0;
            }
            let a = lo / hi;
            let a2 = a * a;
            let p: $t = -0.011_721_2;
            let p = p * a2 + 0.052_653_32;
            let p = p * a2 - 0.116_432_87;
            let p = p * a2 + 0.193_543_46;
            let p = p * a2 - 0.332_623_47;
            let p = p * a2 + 0.999_977_26;
            let mut r = a * p;
            if ay > ax {
                r = std::$t::consts::FRAC_PI_2 - r;
            }
            if x < 0.0 {
                r = std::$t::consts::PI - r;
            }
            if y < 0.0 {
                -r
            } else {
                r
            }
        }
    };
}

atan2_polynomial!(
    /// `atan2(y, x)` to within 2·10⁻⁶ rad, for the starting guesses of [`theta_cell`] and
    /// [`phi_cell`] in fields wider than the tables (narrower ones use [`atan2_guess_f32`]):
    /// they only need the cell to within a few, and [`last_true_near`] finds the exact one
    /// from any guess, so the cells never depend on this accuracy. 0 for `x = y = 0`.
    atan2_guess,
    f64
);

atan2_polynomial!(
    /// [`atan2_guess`] in `f32` (the same polynomial; within 3·10⁻⁶ rad): the starting guess
    /// for fields of at most [`MAX_TABLE_BITS`] bits, whose cells are at least 3·10⁻⁶ rad wide
    /// (θ) or twice that (φ), so the guess is at most a cell or two off and cheaper to form
    /// than the `f64` one (single-precision square root and division). 0 for `x = y = 0`.
    atan2_guess_f32,
    f32
);

/// [`atan2_guess_f32`] of `n ≤ CELL_PASS` pairs `(y[i], x[i])` into `out`, written without
/// branches (each `if` picks between two values already computed) so that the loop runs on
/// vector lanes: the same operations in the same order as one call per pair, hence the same
/// values.
#[inline]
fn atan2_guesses_f32(
    y: &[f32; CELL_PASS],
    x: &[f32; CELL_PASS],
    n: usize,
    out: &mut [f32; CELL_PASS],
) {
    use std::f32::consts::{FRAC_PI_2, PI};
    for i in 0..n.min(CELL_PASS) {
        let (ax, ay) = (x[i].abs(), y[i].abs());
        let (lo, hi) = (ax.min(ay), ax.max(ay));
        let a = lo / hi;
        let a2 = a * a;
        let p: f32 = -0.011_721_2;
        let p = p * a2 + 0.052_653_32;
        let p = p * a2 - 0.116_432_87;
        let p = p * a2 + 0.193_543_46;
        let p = p * a2 - 0.332_623_47;
        let p = p * a2 + 0.999_977_26;
        let r = a * p;
        let r = if ay > ax { FRAC_PI_2 - r } else { r };
        let r = if x[i] < 0.0 { PI - r } else { r };
        let r = if y[i] < 0.0 { -r } else { r };
        out[i] = if hi == 0.0 { 0.0 } else { r };
    }
}

/// The boundary table of a field of `bits` (from `table`, [`theta_table`] or [`phi_table`]),
/// `None` for a field wider than the tables or of no bits (whose cell is 0 without a search).
fn table_for(bits: u32, table: fn(u32) -> &'static [f32]) -> Option<&'static [f32]> {
    (bits > 0 && bits <= MAX_TABLE_BITS).then(|| table(bits))
}

/// The boundary `k` of `bits`, from the table when there is one.
fn threshold_of(bits: u32, k: u64, tab: Option<&[f32]>, f: fn(u32, u64) -> f32) -> f32 {
    match tab {
        Some(t) => t[k as usize],
        None => f(bits, k),
    }
}

/// The `θ` cell (`bits` wide) of the scaled direction `(x, y, z)`: the last boundary `k` with
/// `θ ≥ θ_k`, tested as `z ≤ 0 or ρ² ≥ tan²θ_k · z²` below the equator, `z ≤ 0` at it and
/// `z < 0 and ρ² ≤ tan²(π − θ_k) · z²` above it (`ρ² = x² + y²`, squares by [`square`]).
pub fn theta_cell(x: f32, y: f32, z: f32, bits: u32) -> u64 {
    let tab = table_for(bits, theta_table);
    let t = ThetaInput::of(x, y, z);
    t.cell(bits, tab, t.guess(bits, tab.is_some()))
}

/// What a `θ` cell is computed from: `ρ² = x² + y²` and `z²` by [`square`], and `z`.
#[derive(Clone, Copy, Debug, Default)]
struct ThetaInput {
    rho2: f32,
    z2: f32,
    z: f32,
}

impl ThetaInput {
    #[inline]
    fn of(x: f32, y: f32, z: f32) -> ThetaInput {
        ThetaInput {
            rho2: square(x) + square(y),
            z2: square(z),
            z,
        }
    }

    /// The starting guess of the cell (`f32` arithmetic when the field has a table, see
    /// [`atan2_guess_f32`]).
    #[inline]
    fn guess(&self, bits: u32, tabulated: bool) -> f64 {
        if bits == 0 {
            0.0
        } else if tabulated {
            (atan2_guess_f32(self.rho2.sqrt(), self.z) * (pow2(bits) * std::f32::consts::FRAC_1_PI))
                as f64
        } else {
            atan2_guess((self.rho2 as f64).sqrt(), self.z as f64) / std::f64::consts::PI
                * (1u64 << bits) as f64
        }
    }

    /// The exact cell, searched from `guess` ([`last_true_near`]: the same for any guess).
    #[inline]
    fn cell(&self, bits: u32, tab: Option<&[f32]>, guess: f64) -> u64 {
        if bits == 0 {
            return 0;
        }
        let ThetaInput { rho2, z2, z } = *self;
        let half = 1u64 << (bits - 1);
        last_true_near((1u64 << bits) - 1, guess, |k| {
            let t = threshold_of(bits, k, tab, theta_threshold);
            if k < half {
                z <= 0.0 || rho2 >= t * z2
            } else if k == half {
                z <= 0.0
            } else {
                z < 0.0 && rho2 <= t * z2
            }
        })
    }
}

/// The octant (0-7 from `φ = −π`, as [`phi_threshold`] numbers them) of `(x, y)`, not both 0.
/// `y = ±0` with `x < 0` counts as `φ = π` (octant 7): the sign of a zero is not kept by every
/// device.
fn octant(x: f32, y: f32) -> u64 {
    let (ax, ay) = (x.abs(), y.abs());
    if y >= 0.0 {
        if x > 0.0 {
            if ay < ax {
                4
            } else {
                5
            }
        } else if ay > ax {
            6
        } else {
            7
        }
    } else if x < 0.0 {
        if ay < ax {
            0
        } else {
            1
        }
    } else if ay > ax {
        2
    } else {
        3
    }
}

/// The `φ` cell (`bits` wide) of the scaled direction `(x, y, ·)`: the last boundary `k` with
/// `φ ≥ φ_k`, by octant, then within the octant by comparing the minor component `|n|` with
/// `t_k · |m|` (the major one). `x = y = 0` (a pole) counts as `φ = 0`.
pub fn phi_cell(x: f32, y: f32, bits: u32) -> u64 {
    let tab = table_for(bits, phi_table);
    let p = PhiInput::of(x, y);
    p.cell(bits, tab, p.guess(bits, tab.is_some()))
}

/// What a `φ` cell is computed from: `(x, y)`, a pole replaced by `(1, 0)`.
#[derive(Clone, Copy, Debug, Default)]
struct PhiInput {
    x: f32,
    y: f32,
}

impl PhiInput {
    #[inline]
    fn of(x: f32, y: f32) -> PhiInput {
        if x == 0.0 && y == 0.0 {
            PhiInput { x: 1.0, y: 0.0 }
        } else {
            PhiInput { x, y }
        }
    }

    /// The starting guess of the cell (as [`ThetaInput::guess`]).
    #[inline]
    fn guess(&self, bits: u32, tabulated: bool) -> f64 {
        let PhiInput { x, y } = *self;
        if bits == 0 {
            0.0
        } else if tabulated {
            let h = pow2(bits - 1);
            (atan2_guess_f32(y, x) * (h * std::f32::consts::FRAC_1_PI) + h) as f64
        } else {
            (atan2_guess(y as f64, x as f64) / std::f64::consts::PI + 1.0)
                * 0.5
                * (1u64 << bits) as f64
        }
    }

    /// The exact cell, searched from `guess` ([`last_true_near`]: the same for any guess).
    #[inline]
    fn cell(&self, bits: u32, tab: Option<&[f32]>, guess: f64) -> u64 {
        if bits == 0 {
            return 0;
        }
        let PhiInput { x, y } = *self;
        let o = octant(x, y);
        let (n, m) = if matches!(o, 0 | 3 | 4 | 7) {
            (y.abs(), x.abs())
        } else {
            (x.abs(), y.abs())
        };
        last_true_near((1u64 << bits) - 1, guess, |k| {
            let ok = phi_octant(bits, k);
            if ok != o {
                return o > ok;
            }
            let t = threshold_of(bits, k, tab, phi_threshold);
            if o.is_multiple_of(2) {
                n >= t * m
            } else {
                n <= t * m
            }
        })
    }
}

/// [`spherical_cells`] prepared for many directions: the boundary tables looked up once, and
/// the cells of a slice of directions found in two passes ([`SphericalCells::cells_of`]):
/// every direction's starting guess first, then every direction's exact cell from its
/// guess. One direction's guess (square root, division, polynomial) and the table lookup that
/// depends on it form one long chain; done one direction at a time the processor waits on each
/// chain in turn, while the passes let neighbouring directions' chains overlap. Same cells as
/// [`spherical_cells`] (the search from a guess finds the same cell from any guess).
#[derive(Clone, Copy)]
pub struct SphericalCells {
    theta_bits: u32,
    phi_bits: u32,
    theta_tab: Option<&'static [f32]>,
    phi_tab: Option<&'static [f32]>,
}

impl std::fmt::Debug for SphericalCells {
    /// The widths, not the tables' entries.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SphericalCells")
            .field("theta_bits", &self.theta_bits)
            .field("phi_bits", &self.phi_bits)
            .field(
                "tabulated",
                &(self.theta_tab.is_some(), self.phi_tab.is_some()),
            )
            .finish()
    }
}

/// Directions per pass of [`SphericalCells::cells_of`].
const CELL_PASS: usize = 32;

impl SphericalCells {
    /// The cells of `theta_bits` and `phi_bits` (each at most 32).
    pub fn new(theta_bits: u32, phi_bits: u32) -> SphericalCells {
        SphericalCells {
            theta_bits,
            phi_bits,
            theta_tab: table_for(theta_bits, theta_table),
            phi_tab: table_for(phi_bits, phi_table),
        }
    }

    /// Bits of the `θ` field.
    pub fn theta_bits(&self) -> u32 {
        self.theta_bits
    }

    /// Bits of the `φ` field.
    pub fn phi_bits(&self) -> u32 {
        self.phi_bits
    }

    /// The inputs of direction `d`'s cells (a zero or non-finite direction: `θ` input
    /// `z = 1`, the cell 0, and `φ` of `(1, 0)`, the cells of `(0, 0)`).
    #[inline]
    fn inputs(d: Vec3) -> (ThetaInput, PhiInput) {
        match scaled_direction(d) {
            Some([x, y, z]) => (ThetaInput::of(x, y, z), PhiInput::of(x, y)),
            None => (ThetaInput::of(0.0, 0.0, 1.0), PhiInput::of(1.0, 0.0)),
        }
    }

    /// The starting guesses of the cells of `inputs`.
    #[inline]
    fn guesses(&self, (t, p): &(ThetaInput, PhiInput)) -> (f64, f64) {
        (
            t.guess(self.theta_bits, self.theta_tab.is_some()),
            p.guess(self.phi_bits, self.phi_tab.is_some()),
        )
    }

    /// The exact cells of `inputs`, searched from `guesses`.
    #[inline]
    fn search(&self, (t, p): &(ThetaInput, PhiInput), (gt, gp): (f64, f64)) -> (u64, u64) {
        (
            t.cell(self.theta_bits, self.theta_tab, gt),
            p.cell(self.phi_bits, self.phi_tab, gp),
        )
    }

    /// The `(θ, φ)` cells of one direction (what [`spherical_cells`] returns).
    pub fn cells(&self, d: Vec3) -> (u64, u64) {
        let i = Self::inputs(d);
        self.search(&i, self.guesses(&i))
    }

    /// The cells of every direction of `dirs` into `out` (`out[i]` the cells of `dirs[i]`,
    /// as [`SphericalCells::cells`] gives them), in passes of a few dozen directions (see
    /// the type's doc).
    ///
    /// # Panics
    /// When `out` is shorter than `dirs`.
    pub fn cells_of(&self, dirs: &[Vec3], out: &mut [(u64, u64)]) {
        assert!(
            out.len() >= dirs.len(),
            "cells_of: output shorter than input"
        );
        let mut inputs = [(ThetaInput::default(), PhiInput::default()); CELL_PASS];
        let mut guesses = [(0.0f64, 0.0f64); CELL_PASS];
        // Both fields tabulated (at most `MAX_TABLE_BITS` bits, the usual case): the guesses
        // of a pass on vector lanes ([`atan2_guesses_f32`]), the values `guesses` gives.
        let lanes = self.theta_bits > 0
            && self.phi_bits > 0
            && self.theta_tab.is_some()
            && self.phi_tab.is_some();
        let theta_scale = pow2(self.theta_bits) * std::f32::consts::FRAC_1_PI;
        let phi_half = pow2(self.phi_bits.max(1) - 1);
        let phi_scale = phi_half * std::f32::consts::FRAC_1_PI;
        let (mut ty, mut tx, mut py, mut px) = (
            [0.0f32; CELL_PASS],
            [0.0; CELL_PASS],
            [0.0; CELL_PASS],
            [0.0; CELL_PASS],
        );
        let (mut ta, mut pa) = ([0.0f32; CELL_PASS], [0.0f32; CELL_PASS]);
        for (dirs, out) in dirs.chunks(CELL_PASS).zip(out.chunks_mut(CELL_PASS)) {
            let n = dirs.len();
            if lanes {
                for (k, (d, i)) in dirs.iter().zip(&mut inputs).enumerate() {
                    *i = Self::inputs(*d);
                    (ty[k], tx[k]) = (i.0.rho2.sqrt(), i.0.z);
                    (py[k], px[k]) = (i.1.y, i.1.x);
                }
                atan2_guesses_f32(&ty, &tx, n, &mut ta);
                atan2_guesses_f32(&py, &px, n, &mut pa);
                for k in 0..n {
                    guesses[k] = (
                        (ta[k] * theta_scale) as f64,
                        (pa[k] * phi_scale + phi_half) as f64,
                    );
                }
            } else {
                for ((d, i), g) in dirs.iter().zip(&mut inputs).zip(&mut guesses) {
                    *i = Self::inputs(*d);
                    *g = self.guesses(i);
                }
            }
            for ((o, i), g) in out.iter_mut().zip(&inputs[..n]).zip(&guesses[..n]) {
                *o = self.search(i, *g);
            }
        }
    }
}

/// Spherical coordinates `(θ, φ)` of direction `d` (need not be unit length): the polar angle
/// `θ = acos(d̂.z) ∈ [0, π]` from +z and the azimuth `φ = atan2(d.y, d.x) ∈ [−π, π]` (the
/// conversion the thesis applies before hashing, §3.2.3). A zero or non-finite direction
/// gives `(0, 0)`. The reference of [`spherical_cells`], which never computes these angles.
pub fn spherical(d: Vec3) -> (f32, f32) {
    let n = d.normalize_or_zero();
    if n == Vec3::ZERO {
        return (0.0, 0.0);
    }
    (n.z.clamp(-1.0, 1.0).acos(), n.y.atan2(n.x))
}

/// Quantized spherical direction: `θ` in `theta_bits` equal cells of `[0, π]` and `φ` in
/// `phi_bits` equal cells of `[−π, π]` ([`theta_cell`], [`phi_cell`]: exact comparisons
/// against tabulated boundaries, the same bits on every backend). A zero or non-finite
/// direction gets the cells of `(θ, φ) = (0, 0)`; `φ = ±π` (`d.y = ±0`, `d.x < 0`) is the last
/// `φ` cell.
pub fn spherical_cells(d: Vec3, theta_bits: u32, phi_bits: u32) -> (u64, u64) {
    SphericalCells::new(theta_bits, phi_bits).cells(d)
}

/// Octahedral encoding of direction `d` into `[−1, 1]²` (Cigolle et al. 2014, "A survey of
/// efficient representations for independent unit vectors"): project onto the octahedron
/// `|x| + |y| + |z| = 1` and fold the lower hemisphere over the diagonals. Cells of a uniform
/// grid on the square have nearly equal solid angle, unlike spherical coordinates, whose
/// cells shrink to slivers at the poles, and neighbouring directions stay neighbours except
/// across the fold. A zero or non-finite direction gives `(0, 0)`. The reference of
/// [`octahedral_cells`], which never divides.
pub fn octahedral(d: Vec3) -> Vec2 {
    let l1 = d.x.abs() + d.y.abs() + d.z.abs();
    if !(l1 > 0.0 && l1.is_finite()) {
        return Vec2::ZERO;
    }
    let p = d / l1;
    if p.z >= 0.0 {
        Vec2::new(p.x, p.y)
    } else {
        let sign = |v: f32| if v >= 0.0 { 1.0 } else { -1.0 };
        Vec2::new((1.0 - p.y.abs()) * sign(p.x), (1.0 - p.x.abs()) * sign(p.y))
    }
}

/// The cell (`bits` wide) of an octahedral coordinate `num / l1` among `2^bits` equal cells of
/// `[−1, 1]`: the last `k` with `num ≥ b_k · l1`, `b_k = −1 + k · 2^(1 − bits)` (exact in `f32`
/// up to 24 bits).
fn octa_cell(num: f32, l1: f32, bits: u32) -> u64 {
    if bits == 0 {
        return 0;
    }
    let guess = ((num / l1) as f64 + 1.0) * 0.5 * (1u64 << bits) as f64;
    last_true_near((1u64 << bits) - 1, guess, |k| {
        let b = (-1.0 + k as f64 * 2f64.powi(1 - bits as i32)) as f32;
        num >= b * l1
    })
}

/// Quantized octahedral direction: the cells of [`octahedral`]`(d)` among `u_bits` and `v_bits`
/// equal cells of `[−1, 1]`, without the division: with `l1 = (|x| + |y|) + |z|` and the
/// numerators `(x, y)` (upper hemisphere, `z ≥ 0`) or `(±(|x| + |z|), ±(|y| + |z|))` (folded,
/// sign of `x`, `y`), the cell is the last boundary `b_k` with `num ≥ b_k · l1`. Sums of
/// non-negative terms and products that only feed comparisons: the same bits on every
/// backend. A zero or non-finite direction gets the cells of `(0, 0)`.
pub fn octahedral_cells(d: Vec3, u_bits: u32, v_bits: u32) -> (u64, u64) {
    let [x, y, z] = scaled_direction(d).unwrap_or([0.0, 0.0, 1.0]);
    let (ax, ay, az) = (x.abs(), y.abs(), z.abs());
    let l1 = (ax + ay) + az;
    let (nu, nv) = if z >= 0.0 {
        (x, y)
    } else {
        let sign = |v: f32| if v >= 0.0 { 1.0 } else { -1.0 };
        ((ax + az) * sign(x), (ay + az) * sign(y))
    };
    (octa_cell(nu, l1, u_bits), octa_cell(nv, l1, v_bits))
}

/// How a hash lays out the fields of a group (the three origin cells, or `θ` and `φ`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FieldOrder {
    /// One field after the other (`x | y | z`, `θ | φ`): a sort orders by the first field and
    /// only breaks its ties with the next, so a run of consecutive keys can cover a thin
    /// slice of the first field and the whole range of the last.
    #[default]
    Concatenated,
    /// Bits interleaved MSB-first ([`interleave`]): a Morton (Z-order) curve over the
    /// fields, so consecutive keys stay close in every field at once.
    Interleaved,
}

impl FieldOrder {
    /// Parses the `hash.layout` parameter value (`concat`, `interleave`).
    pub fn parse(s: &str) -> Option<FieldOrder> {
        match s {
            "concat" => Some(FieldOrder::Concatenated),
            "interleave" => Some(FieldOrder::Interleaved),
            _ => None,
        }
    }

    /// Combines `fields` (each `(value, width)`, first field most significant) in this order.
    pub fn combine(self, fields: &[(u64, u32)]) -> u64 {
        match self {
            FieldOrder::Concatenated => fields.iter().fold(0u64, |acc, &(v, w)| {
                let v = if w >= 64 { v } else { v & ((1u64 << w) - 1) };
                acc.checked_shl(w).unwrap_or(0) | v
            }),
            FieldOrder::Interleaved => interleave(fields),
        }
    }
}

/// Interleaves bit fields MSB-first, round robin: the output's top bit is the top bit of
/// `fields[0]`, then the top bit of `fields[1]`, …, then the second bit of `fields[0]`, and
/// so on; a field whose bits run out drops out of the rotation. Each field is `(value,
/// width)`; bits of `value` above `width` are ignored. The result has `Σ width` significant
/// low bits (at most 64; wider totals lose their top bits).
pub fn interleave(fields: &[(u64, u32)]) -> u64 {
    // Fast paths (bit spreading) for the shapes the hashers use; same result as the loop.
    let mask = |v: u64, w: u32| if w >= 64 { v } else { v & ((1u64 << w) - 1) };
    match *fields {
        [(a, wa), (b, wb)] if wb <= 32 && (wa == wb || wa == wb + 1) => {
            // Equal widths: `a` takes the odd positions; one bit more: the even ones.
            let (sa, sb) = if wa == wb { (1, 0) } else { (0, 1) };
            return (spread2(mask(a, wa)) << sa) | (spread2(mask(b, wb)) << sb);
        }
        [(x, w), (y, wy), (z, wz)] if w == wy && w == wz && w <= 21 => {
            return (spread3(mask(x, w)) << 2) | (spread3(mask(y, w)) << 1) | spread3(mask(z, w));
        }
        _ => {}
    }
    interleave_bits(fields)
}

/// Bit `i` of `v` moves to bit `2i`; bits of `v` from 32 up are dropped. [`interleave`]'s
/// two-field fast path, and the `tile` hash's Z-order of screen tiles.
pub fn spread2(v: u64) -> u64 {
    let mut x = v & 0xFFFF_FFFF;
    x = (x | (x << 16)) & 0x0000_FFFF_0000_FFFF;
    x = (x | (x << 8)) & 0x00FF_00FF_00FF_00FF;
    x = (x | (x << 4)) & 0x0F0F_0F0F_0F0F_0F0F;
    x = (x | (x << 2)) & 0x3333_3333_3333_3333;
    (x | (x << 1)) & 0x5555_5555_5555_5555
}

/// Bit `i` of `v` (below 2²¹) moves to bit `3i`.
fn spread3(v: u64) -> u64 {
    let mut x = v & 0x1F_FFFF;
    x = (x | (x << 32)) & 0x001F_0000_0000_FFFF;
    x = (x | (x << 16)) & 0x001F_0000_FF00_00FF;
    x = (x | (x << 8)) & 0x100F_00F0_0F00_F00F;
    x = (x | (x << 4)) & 0x10C3_0C30_C30C_30C3;
    (x | (x << 2)) & 0x1249_2492_4924_9249
}

/// The general interleaving, one bit at a time.
fn interleave_bits(fields: &[(u64, u32)]) -> u64 {
    let max_width = fields.iter().map(|f| f.1).max().unwrap_or(0);
    let mut out = 0u64;
    for level in 0..max_width {
        for &(value, width) in fields {
            if level < width {
                let bit = (value >> (width - 1 - level)) & 1;
                out = (out << 1) | bit;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The cells' starting guess is `atan2` to within 2·10⁻⁶ rad in every octant, at any
    /// magnitude, on the axes and at the origin.
    #[test]
    fn batched_guesses_are_the_single_guesses_and_give_the_same_cells() {
        let mut r = rng(91);
        let mut dirs: Vec<Vec3> = (0..1000).map(|_| Vec3::new(r(), r(), r())).collect();
        // Poles, axes, diagonals (ties of |x| and |y|), signed zeros, a zero direction.
        for v in [
            Vec3::Z,
            -Vec3::Z,
            Vec3::X,
            -Vec3::X,
            Vec3::Y,
            -Vec3::Y,
            Vec3::new(1.0, 1.0, 0.3),
            Vec3::new(-1.0, 1.0, -0.3),
            Vec3::new(-1.0, -0.0, 0.5),
            Vec3::new(0.0, -0.0, -1.0),
            Vec3::new(-0.0, 0.0, 1.0),
            Vec3::ZERO,
        ] {
            dirs.push(v);
        }
        for (y, x) in dirs.chunks(CELL_PASS).flat_map(|c| {
            c.iter()
                .map(|d| (d.y, d.x))
                .chain(c.iter().map(|d| (d.x.hypot(d.y), d.z)))
        }) {
            let (mut ys, mut xs, mut out) = ([0.0; CELL_PASS], [0.0; CELL_PASS], [9.0; CELL_PASS]);
            (ys[3], xs[3]) = (y, x);
            atan2_guesses_f32(&ys, &xs, 4, &mut out);
            assert_eq!(
                out[3].to_bits(),
                atan2_guess_f32(y, x).to_bits(),
                "({y}, {x})"
            );
            assert_eq!(out[0], 0.0);
            assert_eq!(out[4], 9.0, "only the first n are written");
        }
        // The batched pass (tabulated widths) and the one-direction path agree on every cell.
        for (tb, pb) in [
            (16, 15),
            (15, 15),
            (1, 1),
            (20, 20),
            (0, 7),
            (7, 0),
            (24, 24),
        ] {
            let c = SphericalCells::new(tb, pb);
            let mut out = vec![(0, 0); dirs.len()];
            c.cells_of(&dirs, &mut out);
            for (d, got) in dirs.iter().zip(&out) {
                assert_eq!(*got, spherical_cells(*d, tb, pb), "{d} at ({tb}, {pb})");
            }
        }
    }

    #[test]
    fn atan2_guess_is_close_to_atan2() {
        let mut worst = 0.0f64;
        for i in 0..=100_000 {
            let t = -std::f64::consts::PI + 2.0 * std::f64::consts::PI * i as f64 / 100_000.0;
            for r in [1e-30, 1e-3, 1.0, 7.5e3, 1e30] {
                let (y, x) = (r * t.sin(), r * t.cos());
                worst = worst.max((atan2_guess(y, x) - y.atan2(x)).abs());
            }
        }
        assert!(worst < 2e-6, "worst error {worst}");
        for (y, x) in [(0.0, 1.0), (1.0, 0.0), (0.0, -1.0), (-1.0, 0.0), (1.0, 1.0)] {
            assert!((atan2_guess(y, x) - f64::atan2(y, x)).abs() < 2e-6);
        }
        assert_eq!(atan2_guess(0.0, 0.0), 0.0);
        // The `f32` twin, on `f32` inputs of the magnitudes a scaled direction has.
        let mut worst = 0.0f64;
        for i in 0..=100_000 {
            let t = -std::f64::consts::PI + 2.0 * std::f64::consts::PI * i as f64 / 100_000.0;
            for r in [1e-9f64, 1.0, 1.99] {
                let (y, x) = ((r * t.sin()) as f32, (r * t.cos()) as f32);
                let exact = (y as f64).atan2(x as f64);
                worst = worst.max((atan2_guess_f32(y, x) as f64 - exact).abs());
            }
        }
        assert!(worst < 3e-6, "worst f32 error {worst}");
        assert_eq!(atan2_guess_f32(0.0, 0.0), 0.0);
    }

    #[test]
    fn quantize_cells_clamp_and_degenerate_inputs() {
        assert_eq!(quantize(0.0, 0.0, 1.0, 2), 0);
        assert_eq!(quantize(0.24, 0.0, 1.0, 2), 0);
        assert_eq!(quantize(0.26, 0.0, 1.0, 2), 1);
        assert_eq!(quantize(0.99, 0.0, 1.0, 2), 3);
        assert_eq!(quantize(1.0, 0.0, 1.0, 2), 3);
        assert_eq!(quantize(5.0, 0.0, 1.0, 2), 3);
        assert_eq!(quantize(-5.0, 0.0, 1.0, 2), 0);
        assert_eq!(quantize(f32::NAN, 0.0, 1.0, 8), 0);
        assert_eq!(quantize(0.5, 1.0, 1.0, 8), 0);
        assert_eq!(quantize(0.5, 0.0, 1.0, 0), 0);
        assert_eq!(quantize(1.0, 0.0, 1.0, 32), u32::MAX as u64);
        let mut last = 0;
        for i in 0..=1000 {
            let q = quantize(i as f32 / 1000.0, 0.0, 1.0, 7);
            assert!(q >= last);
            last = q;
        }
        assert_eq!(last, 127);
    }

    /// A tiny xorshift for the tests.
    fn rng(mut seed: u64) -> impl FnMut() -> f32 {
        move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
        }
    }

    /// The reference cell of `v` among `2^bits` cells of `[lo, hi]` in `f64`, and how far
    /// (in cells) `v` is from the nearest boundary.
    fn reference(v: f64, lo: f64, hi: f64, bits: u32) -> (u64, f64) {
        let n = (1u64 << bits) as f64;
        let f = ((v - lo) / (hi - lo) * n).clamp(0.0, n - 0.5);
        (f.floor() as u64, (f - f.round()).abs())
    }

    #[test]
    fn uniform_cells_use_the_f32_scale() {
        let q = UniformCells::new(-1.0, 3.0, 10);
        assert_eq!(q.scale, 256.0);
        assert_eq!(q.cell(-1.0), 0);
        assert_eq!(q.cell(f32::NEG_INFINITY), 0);
        assert_eq!(q.cell(f32::INFINITY), 1023);
        assert_eq!(q.cell(-1.0 + 1.0 / 256.0), 1);
        assert_eq!(q.cell(1e-40), q.cell(0.0));
        assert_eq!(UniformCells::new(2.0, 2.0, 8).scale, 0.0);
        let mut r = rng(7);
        let q = UniformCells::new(-0.37, 5.91, 17);
        for _ in 0..10_000 {
            let x = r() * 4.0 + 2.0;
            let want = ((x - q.lo) * q.scale).floor().clamp(0.0, 131071.0) as u64;
            assert_eq!(q.cell(x), want);
            let (f, near) = reference(x as f64, -0.37, 5.91, 17);
            assert!(q.cell(x) == f || near < 1e-2, "{x}");
        }
    }

    #[test]
    fn squares_are_sums_of_exact_products() {
        let mut r = rng(11);
        for _ in 0..10_000 {
            let [x, ..] = scaled_direction(Vec3::new(r(), r() * 1e-6, 1.0)).unwrap();
            for x in [x, x * 1e-9, 1.999_999_9] {
                let h = f32::from_bits(x.to_bits() & 0xffff_f000);
                let l = x - h;
                assert_eq!(h as f64 + l as f64, x as f64);
                for (a, b) in [(h, h), (h, l), (l, l)] {
                    assert_eq!((a * b) as f64, a as f64 * b as f64);
                }
                let sq = square(x) as f64;
                let exact = x as f64 * x as f64;
                assert!((sq - exact).abs() <= exact * 2e-7, "{x}");
            }
        }
    }

    /// What a device that contracts products into FMAs computes for [`product`]: the same bits.
    #[test]
    fn products_are_the_same_fused_or_not() {
        let mut r = rng(13);
        let half = |x: f32| f32::from_bits(x.to_bits() & 0xffff_f000);
        for _ in 0..100_000 {
            let (a, b) = (r() * 3e3, r() * 1e-3);
            let (ah, bh) = (half(a), half(b));
            let (al, bl) = (a - ah, b - bh);
            let p = product(a, b);
            let fused = [
                ah.mul_add(bh, (ah * bl + al * bh) + al * bl),
                ah.mul_add(bh, al.mul_add(bl, ah.mul_add(bl, al * bh))),
                ah.mul_add(bh, al.mul_add(bl, al.mul_add(bh, ah * bl))),
                ah * bh + al.mul_add(bl, ah * bl + al * bh),
            ];
            for f in fused {
                assert_eq!(f.to_bits(), p.to_bits(), "{a} {b}");
            }
        }
    }

    /// The guided search finds what the plain binary search finds, from any guess.
    #[test]
    fn guided_search_equals_binary_search() {
        let mut r = rng(17);
        for max in [0u64, 1, 2, 7, 100, 65_535, u32::MAX as u64] {
            for _ in 0..2000 {
                let cut = ((r() + 1.0) * 0.5 * max as f32) as u64;
                let test = |k: u64| k <= cut;
                for guess in [
                    cut as f64,
                    cut as f64 + 1.0,
                    cut as f64 - 3.0,
                    0.0,
                    -5.0,
                    1e30,
                    f64::NAN,
                ] {
                    assert_eq!(last_true_near(max, guess, test), cut.min(max));
                }
                assert_eq!(last_true(max, test), cut.min(max));
            }
        }
    }

    #[test]
    fn scaled_directions_are_exact_power_of_two_scalings() {
        let d = Vec3::new(3.0, -0.75, 1e-12);
        let [x, y, z] = scaled_direction(d).unwrap();
        assert_eq!((x, y, z), (1.5, -0.375, 0.0));
        let s = scaled_direction(Vec3::new(1e-30, 2e-30, -3e-30)).unwrap();
        assert_eq!(s[2] / s[0], -3.0);
        assert!(s.iter().all(|v| v.abs() < 2.0) && s[2].abs() >= 1.0);
        assert_eq!(scaled_direction(Vec3::ZERO), None);
        assert_eq!(scaled_direction(Vec3::new(1.0, f32::NAN, 0.0)), None);
        assert_eq!(scaled_direction(Vec3::new(1.0, f32::INFINITY, 0.0)), None);
        assert_eq!(scaled_direction(Vec3::new(1e-40, 0.0, 0.0)), None);
    }

    #[test]
    fn spherical_cells_are_the_angle_cells() {
        let mut r = rng(3);
        let pi = std::f64::consts::PI;
        for (tb, pb) in [(1, 1), (2, 3), (7, 7), (8, 8), (16, 16), (21, 24), (32, 32)] {
            let mut near = 0;
            for i in 0..4000 {
                let d = Vec3::new(r(), r(), r()) * if i % 3 == 0 { 1e-20 } else { 7.0 };
                let (t, p) = spherical_cells(d, tb, pb);
                let dd = d.as_dvec3().normalize();
                let (wt, nt) = reference(dd.z.clamp(-1.0, 1.0).acos(), 0.0, pi, tb);
                let (wp, np) = reference(dd.y.atan2(dd.x), -pi, pi, pb);
                // Within ~1e-6 rad of a boundary either side is fine.
                let slack = |bits: u32| 2e-6 * (1u64 << bits) as f64;
                if nt < slack(tb) || np < slack(pb) {
                    near += 1;
                    assert!(t.abs_diff(wt) <= 1 + (slack(tb) as u64), "{d} {tb}");
                    continue;
                }
                assert_eq!((t, p), (wt, wp), "{d} bits {tb}/{pb}");
            }
            if tb.max(pb) <= 8 {
                assert!(near < 4000 / 100, "{tb}/{pb}: {near}");
            }
        }
    }

    #[test]
    fn spherical_cells_at_poles_seams_and_degenerate_directions() {
        for (tb, pb) in [(1, 1), (2, 2), (3, 5), (16, 16)] {
            let (t_last, p_last) = ((1u64 << tb) - 1, (1u64 << pb) - 1);
            let p0 = (1u64 << pb) >> 1;
            assert_eq!(spherical_cells(Vec3::Z, tb, pb), (0, p0));
            assert_eq!(spherical_cells(-Vec3::Z * 5.0, tb, pb), (t_last, p0));
            assert_eq!(spherical_cells(Vec3::X, tb, pb), (1 << (tb - 1), p0));
            assert_eq!(spherical_cells(-Vec3::X, tb, pb).1, p_last);
            assert_eq!(
                spherical_cells(Vec3::new(-1.0, -0.0, 0.3), tb, pb).1,
                p_last
            );
            assert_eq!(spherical_cells(-Vec3::Y, tb, pb).1, (1 << pb) >> 2);
            assert_eq!(spherical_cells(Vec3::Y, tb, pb).1, (3 * (1 << pb)) >> 2);
            assert_eq!(spherical_cells(Vec3::ZERO, tb, pb), (0, p0));
            assert_eq!(spherical_cells(Vec3::NAN, tb, pb), (0, p0));
        }
        assert_eq!(spherical_cells(Vec3::X, 0, 0), (0, 0));
        // The tables are the threshold functions, cached.
        for bits in [1, 5, 12] {
            let t = theta_table(bits);
            let p = phi_table(bits);
            for k in 0..1u64 << bits {
                assert_eq!(t[k as usize].to_bits(), theta_threshold(bits, k).to_bits());
                assert_eq!(p[k as usize].to_bits(), phi_threshold(bits, k).to_bits());
            }
        }
    }

    /// The prepared, two-pass cells are [`spherical_cells`]' for every width (tabulated or
    /// not, 0 included), on random directions of every magnitude, axes, poles, seams and
    /// degenerate directions, in slices of any length.
    #[test]
    fn prepared_cells_are_spherical_cells() {
        let mut r = rng(23);
        let mut dirs: Vec<Vec3> = (0..3000)
            .map(|i| {
                let scale = [7.0, 1e-20, 3e25, 1.0][i % 4];
                Vec3::new(r(), r(), r()) * scale
            })
            .collect();
        for v in [0.0f32, -0.0, 1.0, -1.0, 1e-40, f32::NAN, f32::INFINITY] {
            for w in [0.0f32, 1.0, -1.0, -0.0] {
                dirs.extend([
                    Vec3::new(v, w, 1.0),
                    Vec3::new(w, v, -1.0),
                    Vec3::new(v, w, v),
                ]);
            }
        }
        for (tb, pb) in [
            (0, 0),
            (1, 1),
            (7, 7),
            (16, 15),
            (20, 20),
            (21, 24),
            (32, 32),
        ] {
            let cells = SphericalCells::new(tb, pb);
            assert_eq!((cells.theta_bits(), cells.phi_bits()), (tb, pb));
            let want: Vec<(u64, u64)> = dirs.iter().map(|&d| spherical_cells(d, tb, pb)).collect();
            for len in [0, 1, 31, 32, 33, dirs.len()] {
                let mut got = vec![(u64::MAX, u64::MAX); len];
                cells.cells_of(&dirs[..len], &mut got);
                assert_eq!(got, want[..len], "bits {tb}/{pb}, {len} directions");
            }
            for (d, w) in dirs.iter().zip(&want) {
                assert_eq!(cells.cells(*d), *w, "{d} bits {tb}/{pb}");
            }
        }
        assert!(format!("{:?}", SphericalCells::new(16, 16)).len() < 200);
    }

    #[test]
    fn octahedral_cells_are_the_square_cells() {
        let mut r = rng(5);
        for (ub, vb) in [(1, 1), (2, 1), (10, 10), (20, 20), (24, 24), (32, 32)] {
            for _ in 0..4000 {
                let d = Vec3::new(r(), r(), r());
                let (u, v) = octahedral_cells(d, ub, vb);
                let e = octahedral(d.as_dvec3().normalize().as_vec3());
                let (wu, nu) = reference(e.x as f64, -1.0, 1.0, ub);
                let (wv, nv) = reference(e.y as f64, -1.0, 1.0, vb);
                let slack = |bits: u32| 1e-6 * (1u64 << bits) as f64;
                if nu < slack(ub) || nv < slack(vb) {
                    continue;
                }
                assert_eq!((u, v), (wu, wv), "{d} bits {ub}/{vb}");
            }
        }
        let mid = |b: u32| (1u64 << b) >> 1;
        assert_eq!(octahedral_cells(Vec3::Z, 4, 3), (mid(4), mid(3)));
        assert_eq!(octahedral_cells(Vec3::ZERO, 4, 3), (mid(4), mid(3)));
        assert_eq!(octahedral_cells(Vec3::X, 4, 3), (15, mid(3)));
        assert_eq!(octahedral_cells(-Vec3::X, 4, 3), (0, mid(3)));
        assert_eq!(octahedral_cells(-Vec3::Z, 4, 3), (15, 7));
        assert_eq!(octahedral_cells(Vec3::X, 0, 0), (0, 0));
    }

    #[test]
    fn spherical_known_directions() {
        let (t, p) = spherical(Vec3::Z);
        assert!(t.abs() < 1e-6 && p.abs() < 1e-6);
        let (t, _) = spherical(-Vec3::Z * 3.0);
        assert!((t - std::f32::consts::PI).abs() < 1e-6);
        let (t, p) = spherical(Vec3::Y);
        assert!((t - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
        assert!((p - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
        assert_eq!(spherical(Vec3::ZERO), (0.0, 0.0));
        assert_eq!(spherical(Vec3::NAN), (0.0, 0.0));
    }

    #[test]
    fn octahedral_corners_and_range() {
        assert_eq!(octahedral(Vec3::Z), Vec2::ZERO);
        assert_eq!(octahedral(Vec3::X), Vec2::new(1.0, 0.0));
        assert_eq!(octahedral(-Vec3::Y), Vec2::new(0.0, -1.0));
        let down = octahedral(-Vec3::Z);
        assert_eq!(down.abs(), Vec2::ONE);
        for i in 0..200 {
            let a = i as f32 * 0.7;
            let d = Vec3::new(a.sin() * (a * 1.3).cos(), a.cos(), (a * 2.1).sin());
            let e = octahedral(d);
            assert!(e.x.abs() <= 1.0 + 1e-6 && e.y.abs() <= 1.0 + 1e-6);
        }
    }

    #[test]
    fn spread2_moves_bit_i_to_bit_2i() {
        assert_eq!(spread2(0b1011), 0b100_0101);
        assert_eq!(spread2(0xffff), 0x5555_5555);
        assert_eq!(spread2(0xffff_ffff), 0x5555_5555_5555_5555);
        assert_eq!(spread2(0x1_0000_0001), 1);
    }

    #[test]
    fn interleave_round_robin_msb_first() {
        // Two 2-bit fields a = 0b10, b = 0b01 → a1 b1 a0 b0 = 1 0 0 1.
        assert_eq!(interleave(&[(0b10, 2), (0b01, 2)]), 0b1001);
        // Unequal widths: a = 0b111 (3), b = 0b0 (1) → a2 b0 a1 a0 = 1 0 1 1.
        assert_eq!(interleave(&[(0b111, 3), (0, 1)]), 0b1011);
        // Bits above the width are ignored.
        assert_eq!(interleave(&[(0xFF, 1)]), 1);
        assert_eq!(interleave(&[]), 0);
        // The fast paths give what the bit loop gives.
        let mut seed = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for _ in 0..2000 {
            let (a, b, c) = (next(), next(), next());
            for w in [0u32, 1, 2, 7, 15, 16, 21, 31, 32] {
                let two = [(a, w + 1), (b, w)];
                assert_eq!(interleave(&two), interleave_bits(&two), "{two:?}");
                let eq = [(a, w), (b, w)];
                assert_eq!(interleave(&eq), interleave_bits(&eq), "{eq:?}");
                if w <= 21 {
                    let three = [(a, w), (b, w), (c, w)];
                    assert_eq!(interleave(&three), interleave_bits(&three), "{three:?}");
                }
            }
        }
        assert_eq!(
            interleave(&[(u32::MAX as u64, 32), (u32::MAX as u64, 32)]),
            u64::MAX
        );
    }
}
