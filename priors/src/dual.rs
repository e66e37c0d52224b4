//! Second-order forward-mode dual numbers: a value with its exact gradient and Hessian with
//! respect to `N` inputs. Every operation applies the chain rule to second order, so a
//! priorlet expression evaluated on these numbers gives its exact derivatives (no finite
//! differences).

use std::ops::{Add, Div, Mul, Neg, Sub};

/// What an expression can be evaluated on: plain `f64` (values only) or [`Dual`] (values with
/// exact gradients and Hessians).
pub trait Scalar:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// A constant (zero derivatives).
    fn constant(value: f64) -> Self;
    /// The value.
    fn value(&self) -> f64;
    /// A function of one argument given its value and first two derivatives at `self`.
    fn chain(self, f: f64, df: f64, d2f: f64) -> Self;
    /// A function of two arguments given its value, gradient and Hessian at `(self, other)`.
    fn chain2(self, other: Self, f: f64, df: [f64; 2], d2f: [[f64; 2]; 2]) -> Self;

    /// Sine.
    fn sin(self) -> Self {
        unary(self, Unary::Sin)
    }
    /// Cosine.
    fn cos(self) -> Self {
        unary(self, Unary::Cos)
    }
    /// Tangent.
    fn tan(self) -> Self {
        unary(self, Unary::Tan)
    }
    /// Arc tangent.
    fn atan(self) -> Self {
        unary(self, Unary::Atan)
    }
    /// Square root.
    fn sqrt(self) -> Self {
        unary(self, Unary::Sqrt)
    }
    /// Exponential.
    fn exp(self) -> Self {
        unary(self, Unary::Exp)
    }
    /// Natural logarithm.
    fn ln(self) -> Self {
        unary(self, Unary::Ln)
    }
    /// Absolute value (derivative sign(x), second derivative 0).
    fn abs(self) -> Self {
        unary(self, Unary::Abs)
    }
    /// `self` to a constant power.
    fn powf(self, c: f64) -> Self {
        unary(self, Unary::PowC(c))
    }
    /// `atan2(self, x)`: the angle of the vector `(x, self)`.
    fn atan2(self, x: Self) -> Self {
        let (f, df, d2f) = atan2_at(self.value(), x.value());
        self.chain2(x, f, df, d2f)
    }
}

/// `function` of `x`, through [`Scalar::chain`].
fn unary<S: Scalar>(x: S, function: Unary) -> S {
    let (f, df, d2f) = function.at(x.value());
    x.chain(f, df, d2f)
}

/// The functions of one argument of the language.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Unary {
    /// Sine.
    Sin,
    /// Cosine.
    Cos,
    /// Tangent.
    Tan,
    /// Arc tangent.
    Atan,
    /// Square root.
    Sqrt,
    /// Exponential.
    Exp,
    /// Natural logarithm.
    Ln,
    /// Absolute value (derivative sign(x), second derivative 0).
    Abs,
    /// To a constant power.
    PowC(f64),
}

impl Unary {
    /// The value and the first two derivatives at `v`.
    pub(crate) fn at(self, v: f64) -> (f64, f64, f64) {
        match self {
            Unary::Sin => (v.sin(), v.cos(), -v.sin()),
            Unary::Cos => (v.cos(), -v.sin(), -v.cos()),
            Unary::Tan => {
                let t = v.tan();
                let d = 1.0 + t * t;
                (t, d, 2.0 * t * d)
            }
            Unary::Atan => {
                let d = 1.0 / (1.0 + v * v);
                (v.atan(), d, -2.0 * v * d * d)
            }
            Unary::Sqrt => {
                let s = v.sqrt();
                (s, 0.5 / s, -0.25 / (s * v))
            }
            Unary::Exp => {
                let e = v.exp();
                (e, e, e)
            }
            Unary::Ln => (v.ln(), 1.0 / v, -1.0 / (v * v)),
            Unary::Abs => (v.abs(), if v < 0.0 { -1.0 } else { 1.0 }, 0.0),
            Unary::PowC(2.0) => (v * v, 2.0 * v, 2.0),
            Unary::PowC(c) => (
                v.powf(c),
                c * v.powf(c - 1.0),
                c * (c - 1.0) * v.powf(c - 2.0),
            ),
        }
    }
}

/// `atan2(a, b)` with its gradient and Hessian with respect to `(a, b)`.
pub(crate) fn atan2_at(a: f64, b: f64) -> Derivatives2 {
    let r2 = a * a + b * b;
    let r4 = r2 * r2;
    (
        a.atan2(b),
        [b / r2, -a / r2],
        [
            [-2.0 * a * b / r4, (a * a - b * b) / r4],
            [(a * a - b * b) / r4, 2.0 * a * b / r4],
        ],
    )
}

impl Scalar for f64 {
    fn constant(value: f64) -> Self {
        value
    }
    fn value(&self) -> f64 {
        *self
    }
    fn chain(self, f: f64, _: f64, _: f64) -> Self {
        f
    }
    fn chain2(self, _: Self, f: f64, _: [f64; 2], _: [[f64; 2]; 2]) -> Self {
        f
    }
}

/// A value with its gradient and Hessian with respect to `N` inputs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dual<const N: usize> {
    /// The value.
    pub v: f64,
    /// The gradient.
    pub g: [f64; N],
    /// The Hessian (symmetric).
    pub h: [[f64; N]; N],
}

impl<const N: usize> Dual<N> {
    /// Input number `index` at `value` (gradient: the unit vector `index`).
    pub fn variable(value: f64, index: usize) -> Self {
        let mut g = [0.0; N];
        if let Some(slot) = g.get_mut(index) {
            *slot = 1.0;
        }
        Dual {
            v: value,
            g,
            h: [[0.0; N]; N],
        }
    }
}

impl<const N: usize> Scalar for Dual<N> {
    fn constant(value: f64) -> Self {
        Dual {
            v: value,
            g: [0.0; N],
            h: [[0.0; N]; N],
        }
    }
    fn value(&self) -> f64 {
        self.v
    }
    fn chain(self, f: f64, df: f64, d2f: f64) -> Self {
        let mut out = Dual::constant(f);
        for i in 0..N {
            out.g[i] = df * self.g[i];
            for j in 0..N {
                out.h[i][j] = df * self.h[i][j] + d2f * self.g[i] * self.g[j];
            }
        }
        out
    }
    fn chain2(self, other: Self, f: f64, df: [f64; 2], d2f: [[f64; 2]; 2]) -> Self {
        let mut out = Dual::constant(f);
        let (a, b) = (&self, &other);
        for i in 0..N {
            out.g[i] = df[0] * a.g[i] + df[1] * b.g[i];
            for j in 0..N {
                out.h[i][j] = df[0] * a.h[i][j]
                    + df[1] * b.h[i][j]
                    + d2f[0][0] * a.g[i] * a.g[j]
                    + d2f[1][1] * b.g[i] * b.g[j]
                    + d2f[0][1] * (a.g[i] * b.g[j] + b.g[i] * a.g[j]);
            }
        }
        out
    }
}

impl<const N: usize> Add for Dual<N> {
    type Output = Self;
    fn add(mut self, rhs: Self) -> Self {
        self.v += rhs.v;
        for i in 0..N {
            self.g[i] += rhs.g[i];
            for j in 0..N {
                self.h[i][j] += rhs.h[i][j];
            }
        }
        self
    }
}

impl<const N: usize> Sub for Dual<N> {
    type Output = Self;
    fn sub(self, rhs: Self) -> Self {
        self + (-rhs)
    }
}

impl<const N: usize> Neg for Dual<N> {
    type Output = Self;
    fn neg(mut self) -> Self {
        self.v = -self.v;
        for i in 0..N {
            self.g[i] = -self.g[i];
            for j in 0..N {
                self.h[i][j] = -self.h[i][j];
            }
        }
        self
    }
}

impl<const N: usize> Mul for Dual<N> {
    type Output = Self;
    fn mul(self, rhs: Self) -> Self {
        let (a, b) = (&self, &rhs);
        let mut out = Dual::constant(a.v * b.v);
        for i in 0..N {
            out.g[i] = a.v * b.g[i] + b.v * a.g[i];
            for j in 0..N {
                out.h[i][j] = a.v * b.h[i][j] + b.v * a.h[i][j] + a.g[i] * b.g[j] + b.g[i] * a.g[j];
            }
        }
        out
    }
}

impl<const N: usize> Div for Dual<N> {
    type Output = Self;
    fn div(self, rhs: Self) -> Self {
        let v = rhs.v;
        self * rhs.chain(1.0 / v, -1.0 / (v * v), 2.0 / (v * v * v))
    }
}

/// A [`Dual`] that knows which inputs it depends on (`mask`, bit `i` for input `i`) and
/// computes only those entries of its gradient and Hessian; the others stay zero.
///
/// Each entry it computes uses the same formula, with the same operands in the same order,
/// as [`Dual`]: values, gradients and Hessians are bit for bit those of [`Dual`], except that
/// a zero may differ in sign (a term outside an operand's mask is `+0` here where [`Dual`]
/// may have `-0`), and that an entry outside the mask is zero where [`Dual`] has NaN after an
/// infinite value on the way. Derivatives only ever meet values, sums and products, so the
/// sign of a zero never changes a non-zero result. The `set_*` operations write the result into `self`, touching only the
/// value, the mask and the entries of `index`, the inputs of the result (the bits of the
/// union of the operands' masks): the entries outside it must be zero already (a slot that
/// always receives results of one mask stays clean).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Sparse<const N: usize> {
    /// The value.
    pub v: f64,
    /// The inputs it depends on.
    pub mask: u8,
    /// The gradient (zero outside the mask).
    pub g: [f64; N],
    /// The Hessian (zero outside the mask, in rows and columns).
    pub h: [[f64; N]; N],
}

/// Value, gradient and Hessian of a function of two arguments.
pub(crate) type Derivatives2 = (f64, [f64; 2], [[f64; 2]; 2]);

/// The indices of the bits of `mask` below `N`, and how many there are.
#[inline]
pub(crate) fn bits<const N: usize>(mask: u8) -> ([usize; N], usize) {
    let mut out = [0; N];
    let mut count = 0;
    for i in 0..N.min(8) {
        if mask & (1 << i) != 0 {
            out[count] = i;
            count += 1;
        }
    }
    (out, count)
}

/// Calls `g(i)` and then `h(i, j)` for the entries of a result whose inputs are `index`:
/// those entries only when there are few, every entry of the `N x N` block otherwise (fixed
/// loops that the compiler unrolls and vectorizes; the entries outside `index` then get
/// zero operands, so they stay zero).
#[inline(always)]
fn entries<const N: usize>(
    index: &[usize],
    mut g: impl FnMut(usize),
    mut h: impl FnMut(usize, usize),
) {
    if 4 * index.len() * index.len() >= N * N {
        for i in 0..N {
            g(i);
            for j in 0..N {
                h(i, j);
            }
        }
    } else {
        for &i in index {
            g(i);
            for &j in index {
                h(i, j);
            }
        }
    }
}

impl<const N: usize> Sparse<N> {
    /// A constant (zero derivatives).
    pub fn constant(value: f64) -> Self {
        Sparse {
            v: value,
            mask: 0,
            g: [0.0; N],
            h: [[0.0; N]; N],
        }
    }

    /// Sets `self` to input number `index` at `value` (gradient: the unit vector `index`).
    #[inline]
    pub fn set_variable(&mut self, value: f64, index: usize) {
        self.v = value;
        if index < N.min(8) {
            self.g[index] = 1.0;
            self.mask = 1 << index;
        }
    }

    /// `self = f(a)` given `f`'s value and first two derivatives at `a` (as
    /// [`Scalar::chain`] on [`Dual`]).
    #[inline]
    pub fn set_chain(&mut self, a: &Self, (f, df, d2f): (f64, f64, f64), index: &[usize]) {
        self.v = f;
        self.mask = a.mask;
        entries::<N>(
            index,
            |i| self.g[i] = df * a.g[i],
            |i, j| self.h[i][j] = df * a.h[i][j] + d2f * a.g[i] * a.g[j],
        );
    }

    /// `self = f(a, b)` given `f`'s value, gradient and Hessian (as [`Scalar::chain2`] on
    /// [`Dual`]).
    #[inline]
    pub fn set_chain2(&mut self, a: &Self, b: &Self, d: Derivatives2, index: &[usize]) {
        let (f, df, d2f) = d;
        self.v = f;
        self.mask = a.mask | b.mask;
        entries::<N>(
            index,
            |i| self.g[i] = df[0] * a.g[i] + df[1] * b.g[i],
            |i, j| {
                self.h[i][j] = df[0] * a.h[i][j]
                    + df[1] * b.h[i][j]
                    + d2f[0][0] * a.g[i] * a.g[j]
                    + d2f[1][1] * b.g[i] * b.g[j]
                    + d2f[0][1] * (a.g[i] * b.g[j] + b.g[i] * a.g[j])
            },
        );
    }

    /// `self = a + b`.
    #[inline]
    pub fn set_add(&mut self, a: &Self, b: &Self, index: &[usize]) {
        self.v = a.v + b.v;
        self.mask = a.mask | b.mask;
        entries::<N>(
            index,
            |i| self.g[i] = a.g[i] + b.g[i],
            |i, j| self.h[i][j] = a.h[i][j] + b.h[i][j],
        );
    }

    /// `self = self + b` ([`Dual`]'s `+`, which adds `b` to a copy of `self`).
    #[inline]
    pub fn add_assign(&mut self, b: &Self, index: &[usize]) {
        self.v += b.v;
        self.mask |= b.mask;
        entries::<N>(
            index,
            |i| self.g[i] += b.g[i],
            |i, j| self.h[i][j] += b.h[i][j],
        );
    }

    /// `self = a - b`, as [`Dual`] computes it: `a + (-b)`, which IEEE 754 rounds exactly as
    /// `a - b`.
    #[inline]
    pub fn set_sub(&mut self, a: &Self, b: &Self, index: &[usize]) {
        self.v = a.v - b.v;
        self.mask = a.mask | b.mask;
        entries::<N>(
            index,
            |i| self.g[i] = a.g[i] - b.g[i],
            |i, j| self.h[i][j] = a.h[i][j] - b.h[i][j],
        );
    }

    /// `self = -a`.
    #[inline]
    pub fn set_neg(&mut self, a: &Self, index: &[usize]) {
        self.v = -a.v;
        self.mask = a.mask;
        entries::<N>(
            index,
            |i| self.g[i] = -a.g[i],
            |i, j| self.h[i][j] = -a.h[i][j],
        );
    }

    /// `self = a * b`.
    #[inline]
    pub fn set_mul(&mut self, a: &Self, b: &Self, index: &[usize]) {
        self.v = a.v * b.v;
        self.mask = a.mask | b.mask;
        entries::<N>(
            index,
            |i| self.g[i] = a.v * b.g[i] + b.v * a.g[i],
            |i, j| {
                self.h[i][j] = a.v * b.h[i][j] + b.v * a.h[i][j] + a.g[i] * b.g[j] + b.g[i] * a.g[j]
            },
        );
    }

    /// `self = c * a` for a constant `c`: [`Sparse::set_mul`] of a constant and `a` (whose
    /// terms with the constant's zero derivatives add only zeros).
    #[inline]
    pub fn set_scaled(&mut self, c: f64, a: &Self, index: &[usize]) {
        self.v = c * a.v;
        self.mask = a.mask;
        entries::<N>(
            index,
            |i| self.g[i] = c * a.g[i],
            |i, j| self.h[i][j] = c * a.h[i][j],
        );
    }

    /// `self = a / b`, as [`Dual`] computes it: `a` times the reciprocal of `b`.
    #[inline]
    pub fn set_div(&mut self, a: &Self, b: &Self, index: &[usize]) {
        let mut reciprocal = Sparse::constant(0.0);
        let v = b.v;
        let (b_index, count) = bits::<N>(b.mask);
        let derivatives = (1.0 / v, -1.0 / (v * v), 2.0 / (v * v * v));
        reciprocal.set_chain(b, derivatives, &b_index[..count]);
        self.set_mul(a, &reciprocal, index);
    }
}
