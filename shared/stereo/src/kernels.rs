//! The inner loops of the patch evaluation, written once over a 4-lane type: [`wide::f32x4`] in the product
//! (SSE2 on x86_64, NEON on aarch64, plain code elsewhere) and [`Scalar4`], its scalar twin, in the parity
//! tests. Both run the same operations in the same order per lane and sum the lanes as (l0 + l1) + (l2 + l3), so
//! their results are bit-identical.
//!
//! Layout: a patch row holds p values padded with zeros to `pw` = p rounded up to 4; `colmask` is 1 on the p
//! real columns and 0 on the padding, so padded lanes never count.

use std::ops::{Add, Mul, Sub};

/// Four f32 lanes.
pub trait Lanes: Copy + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> {
    fn splat(v: f32) -> Self;
    fn from_array(a: [f32; 4]) -> Self;
    /// 1.0 in lanes that are ≠ 0, else 0.0.
    fn nonzero(self) -> Self;
    fn abs(self) -> Self;
    fn to_array(self) -> [f32; 4];
    fn hsum(self) -> f32 {
        let a = self.to_array();
        (a[0] + a[1]) + (a[2] + a[3])
    }
}

/// Four values at `s[j..j + 4]`.
///
/// # Safety
/// `j + 4 <= s.len()`. Every caller below loops `j = 4c` for `c < pw / 4` over slices it has just cut to a
/// length of at least `pw` (or `pw + 1` when it also reads at `j + 1`), with `pw` a multiple of 4; slicing once
/// per row instead of per load is what keeps bounds checks out of the innermost loop.
#[inline(always)]
unsafe fn load4(s: &[f32], j: usize) -> [f32; 4] {
    debug_assert!(j + 4 <= s.len());
    // SAFETY: guaranteed by the caller (see above); unaligned reads of plain f32s.
    unsafe { std::ptr::read_unaligned(s.as_ptr().add(j).cast::<[f32; 4]>()) }
}

impl Lanes for wide::f32x4 {
    #[inline(always)]
    fn splat(v: f32) -> Self {
        wide::f32x4::splat(v)
    }
    #[inline(always)]
    fn from_array(a: [f32; 4]) -> Self {
        wide::f32x4::from(a)
    }
    #[inline(always)]
    fn nonzero(self) -> Self {
        self.simd_ne(wide::f32x4::ZERO) & wide::f32x4::ONE
    }
    #[inline(always)]
    fn abs(self) -> Self {
        wide::f32x4::abs(self)
    }
    #[inline(always)]
    fn to_array(self) -> [f32; 4] {
        wide::f32x4::to_array(self)
    }
}

/// The scalar twin of `f32x4`, lane by lane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scalar4(pub [f32; 4]);

impl Add for Scalar4 {
    type Output = Self;
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        Self([0, 1, 2, 3].map(|i| self.0[i] + o.0[i]))
    }
}
impl Sub for Scalar4 {
    type Output = Self;
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        Self([0, 1, 2, 3].map(|i| self.0[i] - o.0[i]))
    }
}
impl Mul for Scalar4 {
    type Output = Self;
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        Self([0, 1, 2, 3].map(|i| self.0[i] * o.0[i]))
    }
}

impl Lanes for Scalar4 {
    fn splat(v: f32) -> Self {
        Self([v; 4])
    }
    fn from_array(a: [f32; 4]) -> Self {
        Self(a)
    }
    fn nonzero(self) -> Self {
        Self(self.0.map(|v| if v != 0.0 { 1.0 } else { 0.0 }))
    }
    fn abs(self) -> Self {
        Self(self.0.map(f32::abs))
    }
    fn to_array(self) -> [f32; 4] {
        self.0
    }
}

/// The right image under a shifted patch: row `row0 + b` from column `col`, `pw + 1` samples per row.
#[derive(Debug, Clone, Copy)]
pub struct Window<'a> {
    pub right: &'a [f32],
    /// 1 where a bilinear sample starting at that column is usable (both columns valid).
    pub usable: &'a [f32],
    pub stride: usize,
    pub row0: usize,
    pub col: usize,
    pub p: usize,
    pub pw: usize,
    pub frac: f32,
}

impl Window<'_> {
    #[inline(always)]
    fn base(&self, b: usize) -> usize {
        (self.row0 + b) * self.stride + self.col
    }
}

/// Fully usable patch: (Σ s̃, Σ w·s̃) with s̃ = bilinear sample − `offset`; `weights` p × pw.
#[inline(always)]
pub fn sum_and_dot<L: Lanes>(win: &Window<'_>, weights: &[f32], colmask: &[f32], offset: f32) -> (f32, f32) {
    let (fr, off) = (L::splat(win.frac), L::splat(offset));
    let (mut a, mut d) = (L::splat(0.0), L::splat(0.0));
    let pw = win.pw;
    let colmask = &colmask[..pw];
    for b in 0..win.p {
        let base = win.base(b);
        let r = &win.right[base..base + pw + 1];
        let w = &weights[b * pw..(b + 1) * pw];
        for c in 0..pw / 4 {
            let j = 4 * c;
            // SAFETY: j + 5 <= pw + 1 = r.len(); j + 4 <= pw = w.len() = colmask.len().
            let (r0, r1, m, wv) = unsafe { (load4(r, j), load4(r, j + 1), load4(colmask, j), load4(w, j)) };
            let (r0, r1) = (L::from_array(r0), L::from_array(r1));
            let sv = (r0 + fr * (r1 - r0) - off) * L::from_array(m);
            a = a + sv;
            d = d + L::from_array(wv) * sv;
        }
    }
    (a.hsum(), d.hsum())
}

/// Fully usable patch: (Σ s̃, Σ (s̃ − t)²); `template` p × pw.
#[inline(always)]
pub fn sum_and_sq_diff<L: Lanes>(win: &Window<'_>, template: &[f32], colmask: &[f32], offset: f32) -> (f32, f32) {
    let (fr, off) = (L::splat(win.frac), L::splat(offset));
    let (mut a, mut e) = (L::splat(0.0), L::splat(0.0));
    let pw = win.pw;
    let colmask = &colmask[..pw];
    for b in 0..win.p {
        let base = win.base(b);
        let r = &win.right[base..base + pw + 1];
        let t = &template[b * pw..(b + 1) * pw];
        for c in 0..pw / 4 {
            let j = 4 * c;
            // SAFETY: as in `sum_and_dot`.
            let (r0, r1, m, tv) = unsafe { (load4(r, j), load4(r, j + 1), load4(colmask, j), load4(t, j)) };
            let (r0, r1) = (L::from_array(r0), L::from_array(r1));
            let sv = (r0 + fr * (r1 - r0) - off) * L::from_array(m);
            a = a + sv;
            let diff = sv - L::from_array(tv);
            e = e + diff * diff;
        }
    }
    (a.hsum(), e.hsum())
}

/// Statistics of the exact residual.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Exact {
    pub valid: f32,
    pub sum_gr: f32,
    pub sum_r2: f32,
    pub sum_abs: f32,
}

/// The original's residual, exactly (§4): samples are invalid unless both bilinear columns are usable; the
/// sample mean is over valid samples; a normalised sample or template value of exactly 0 makes the pixel
/// invalid. Two passes; `samples` (p × pw) is scratch.
#[inline(always)]
pub fn exact<L: Lanes>(
    win: &Window<'_>,
    template: &[f32],
    grad: &[f32],
    colmask: &[f32],
    samples: &mut [f32],
) -> Exact {
    let fr = L::splat(win.frac);
    let (mut a, mut n) = (L::splat(0.0), L::splat(0.0));
    let pw = win.pw;
    let colmask = &colmask[..pw];
    for b in 0..win.p {
        let base = win.base(b);
        let r = &win.right[base..base + pw + 1];
        let ok = &win.usable[base..base + pw];
        let out = &mut samples[b * pw..(b + 1) * pw];
        for c in 0..pw / 4 {
            let j = 4 * c;
            // SAFETY: j + 5 <= pw + 1 = r.len(); j + 4 <= pw = ok.len() = colmask.len().
            let (r0, r1, okv, m) = unsafe { (load4(r, j), load4(r, j + 1), load4(ok, j), load4(colmask, j)) };
            let (r0, r1) = (L::from_array(r0), L::from_array(r1));
            let v = L::from_array(okv) * L::from_array(m);
            let sv = (r0 + fr * (r1 - r0)) * v;
            a = a + sv;
            n = n + v;
            out[j..j + 4].copy_from_slice(&sv.to_array());
        }
    }
    let count = n.hsum();
    let mean = L::splat(if count > 0.0 { a.hsum() / count } else { 0.0 });
    let (mut g_r, mut r2, mut abs, mut valid) = (L::splat(0.0), L::splat(0.0), L::splat(0.0), L::splat(0.0));
    let total = win.p * pw;
    let (samples, template, grad) = (&samples[..total], &template[..total], &grad[..total]);
    for c in 0..total / 4 {
        let k = 4 * c;
        // SAFETY: k + 4 <= total = the length of all three slices.
        let (sv, tv, gv) = unsafe { (load4(samples, k), load4(template, k), load4(grad, k)) };
        let s = L::from_array(sv);
        let sn = (s - mean) * s.nonzero();
        let t = L::from_array(tv);
        let m = sn.nonzero() * t.nonzero();
        let r = (sn - t) * m;
        g_r = g_r + L::from_array(gv) * r;
        r2 = r2 + r * r;
        abs = abs + r.abs();
        valid = valid + m;
    }
    Exact { valid: valid.hsum(), sum_gr: g_r.hsum(), sum_r2: r2.hsum(), sum_abs: abs.hsum() }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic pseudo-random stream (no test dependency needed).
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> f32 {
            self.0 = self.0.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            ((self.0 >> 40) as f32) / (1u64 << 24) as f32
        }
    }

    #[test]
    fn simd_and_scalar_twins_are_bit_identical() {
        let mut rng = Rng(42);
        for p in [8usize, 10, 12] {
            let pw = p.div_ceil(4) * 4;
            let stride = 64;
            for trial in 0..200 {
                let right: Vec<f32> =
                    (0..stride * 40).map(|_| if rng.next() < 0.1 { 0.0 } else { 1.0 + 254.0 * rng.next() }).collect();
                let usable: Vec<f32> = (0..stride * 40)
                    .map(|i| if right[i] != 0.0 && right.get(i + 1).is_some_and(|v| *v != 0.0) { 1.0 } else { 0.0 })
                    .collect();
                let colmask: Vec<f32> = (0..pw).map(|j| if j < p { 1.0 } else { 0.0 }).collect();
                let pad = |v: Vec<f32>| -> Vec<f32> {
                    (0..p * pw).map(|k| if k % pw < p { v[(k / pw) * p + k % pw] } else { 0.0 }).collect()
                };
                let template =
                    pad((0..p * p).map(|_| if rng.next() < 0.1 { 0.0 } else { rng.next() * 100.0 - 50.0 }).collect());
                let grad = pad((0..p * p).map(|_| rng.next() * 40.0 - 20.0).collect());
                let win = Window {
                    right: &right,
                    usable: &usable,
                    stride,
                    row0: 1 + trial % 20,
                    col: 1 + trial % 30,
                    p,
                    pw,
                    frac: rng.next(),
                };
                let off = rng.next() * 200.0;
                let (x, y) = (
                    sum_and_dot::<wide::f32x4>(&win, &grad, &colmask, off),
                    sum_and_dot::<Scalar4>(&win, &grad, &colmask, off),
                );
                assert_eq!((x.0.to_bits(), x.1.to_bits()), (y.0.to_bits(), y.1.to_bits()));
                let (x, y) = (
                    sum_and_sq_diff::<wide::f32x4>(&win, &template, &colmask, off),
                    sum_and_sq_diff::<Scalar4>(&win, &template, &colmask, off),
                );
                assert_eq!((x.0.to_bits(), x.1.to_bits()), (y.0.to_bits(), y.1.to_bits()));
                let mut s1 = vec![0.0; p * pw];
                let mut s2 = vec![0.0; p * pw];
                let x = exact::<wide::f32x4>(&win, &template, &grad, &colmask, &mut s1);
                let y = exact::<Scalar4>(&win, &template, &grad, &colmask, &mut s2);
                assert_eq!(
                    [x.valid, x.sum_gr, x.sum_r2, x.sum_abs].map(f32::to_bits),
                    [y.valid, y.sum_gr, y.sum_r2, y.sum_abs].map(f32::to_bits)
                );
            }
        }
    }

    #[test]
    fn exact_matches_a_plain_reading_of_the_rule() {
        // One row, p = 4, frac 0: samples 10, 20, invalid, 30 → mean 20; template (1, 0, 2, −3).
        let right = vec![10.0, 20.0, 0.0, 30.0, 30.0, 0.0, 0.0, 0.0, 0.0];
        let usable = vec![1.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let win = Window { right: &right, usable: &usable, stride: 9, row0: 0, col: 0, p: 1, pw: 4, frac: 0.0 };
        let template = [1.0, 0.0, 2.0, -3.0];
        let grad = [1.0, 1.0, 1.0, 1.0];
        let colmask = [1.0, 1.0, 1.0, 1.0];
        let mut s = [0.0; 4];
        let e = exact::<Scalar4>(&win, &template, &grad, &colmask, &mut s);
        // Normalised samples: −10, 0 (→ invalid), invalid, +10; template 0 at k = 1 is invalid too.
        // Valid: k = 0 (r = −10 − 1 = −11) and k = 3 (r = 10 − (−3) = 13).
        assert_eq!(e.valid, 2.0);
        assert_eq!(e.sum_gr, 2.0);
        assert_eq!(e.sum_r2, 121.0 + 169.0);
        assert_eq!(e.sum_abs, 24.0);
    }
}
