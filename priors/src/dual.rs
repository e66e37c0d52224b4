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
        let v = self.value();
        self.chain(v.sin(), v.cos(), -v.sin())
    }
    /// Cosine.
    fn cos(self) -> Self {
        let v = self.value();
        self.chain(v.cos(), -v.sin(), -v.cos())
    }
    /// Tangent.
    fn tan(self) -> Self {
        let v = self.value();
        let t = v.tan();
        let d = 1.0 + t * t;
        self.chain(t, d, 2.0 * t * d)
    }
    /// Arc tangent.
    fn atan(self) -> Self {
        let v = self.value();
        let d = 1.0 / (1.0 + v * v);
        self.chain(v.atan(), d, -2.0 * v * d * d)
    }
    /// Square root.
    fn sqrt(self) -> Self {
        let v = self.value();
        let s = v.sqrt();
        self.chain(s, 0.5 / s, -0.25 / (s * v))
    }
    /// Exponential.
    fn exp(self) -> Self {
        let e = self.value().exp();
        self.chain(e, e, e)
    }
    /// Natural logarithm.
    fn ln(self) -> Self {
        let v = self.value();
        self.chain(v.ln(), 1.0 / v, -1.0 / (v * v))
    }
    /// Absolute value (derivative sign(x), second derivative 0).
    fn abs(self) -> Self {
        let v = self.value();
        self.chain(v.abs(), if v < 0.0 { -1.0 } else { 1.0 }, 0.0)
    }
    /// `self` to a constant power.
    fn powf(self, c: f64) -> Self {
        let v = self.value();
        if c == 2.0 {
            return self.chain(v * v, 2.0 * v, 2.0);
        }
        self.chain(
            v.powf(c),
            c * v.powf(c - 1.0),
            c * (c - 1.0) * v.powf(c - 2.0),
        )
    }
    /// `atan2(self, x)`: the angle of the vector `(x, self)`.
    fn atan2(self, x: Self) -> Self {
        let (a, b) = (self.value(), x.value());
        let r2 = a * a + b * b;
        let r4 = r2 * r2;
        self.chain2(
            x,
            a.atan2(b),
            [b / r2, -a / r2],
            [
                [-2.0 * a * b / r4, (a * a - b * b) / r4],
                [(a * a - b * b) / r4, 2.0 * a * b / r4],
            ],
        )
    }
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
