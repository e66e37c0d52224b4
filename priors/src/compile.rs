//! The checker: resolves inheritance, checks names, indices and shapes, and compiles every
//! priorlet to a tape of scalar operations (vectors and matrices are expanded at compile
//! time, common subexpressions shared, constants folded).

use std::collections::{HashMap, HashSet};

use crate::dual::Scalar;
use crate::error::{PriorError, Result};
use crate::lexer::Pos;
use crate::parser::{BinOp, Expr, ExprKind, Item, PriorFile, RelOp, Topology, parse};

/// The largest supported order (number of consecutive readings a priorlet sees).
pub const MAX_ORDER: usize = 4;

/// One scalar operation of a tape; arguments are indices of earlier operations.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Op {
    /// A constant.
    Const(f64),
    /// `rho_{k+1}`.
    Rho(usize),
    /// `alpha_{k+1}`.
    Alpha(usize),
    /// `phi_{k+1}` (a bearing: known, not optimized).
    Phi(usize),
    /// Sum.
    Add(usize, usize),
    /// Difference.
    Sub(usize, usize),
    /// Product.
    Mul(usize, usize),
    /// Quotient.
    Div(usize, usize),
    /// Negation.
    Neg(usize),
    /// Power with a constant exponent.
    PowC(usize, f64),
    /// Sine.
    Sin(usize),
    /// Cosine.
    Cos(usize),
    /// Tangent.
    Tan(usize),
    /// Arc tangent.
    Atan(usize),
    /// `atan2(y, x)`.
    Atan2(usize, usize),
    /// Square root.
    Sqrt(usize),
    /// Exponential.
    Exp(usize),
    /// Natural logarithm.
    Ln(usize),
    /// Absolute value.
    Abs(usize),
}

impl Op {
    fn key(&self) -> (u8, u64, usize, usize) {
        match *self {
            Op::Const(c) => (0, c.to_bits(), 0, 0),
            Op::Rho(k) => (1, 0, k, 0),
            Op::Alpha(k) => (2, 0, k, 0),
            Op::Phi(k) => (3, 0, k, 0),
            Op::Add(a, b) => (4, 0, a.min(b), a.max(b)),
            Op::Sub(a, b) => (5, 0, a, b),
            Op::Mul(a, b) => (6, 0, a.min(b), a.max(b)),
            Op::Div(a, b) => (7, 0, a, b),
            Op::Neg(a) => (8, 0, a, 0),
            Op::PowC(a, c) => (9, c.to_bits(), a, 0),
            Op::Sin(a) => (10, 0, a, 0),
            Op::Cos(a) => (11, 0, a, 0),
            Op::Tan(a) => (12, 0, a, 0),
            Op::Atan(a) => (13, 0, a, 0),
            Op::Atan2(a, b) => (14, 0, a, b),
            Op::Sqrt(a) => (15, 0, a, 0),
            Op::Exp(a) => (16, 0, a, 0),
            Op::Ln(a) => (17, 0, a, 0),
            Op::Abs(a) => (18, 0, a, 0),
        }
    }

    /// The value of this operation on the window `x` with bearings `phi`, given the values
    /// `nodes` of the earlier operations (a variable or bearing missing from the window is
    /// NaN).
    pub(crate) fn apply<S: Scalar>(&self, x: &[S], phi: &[f64], nodes: &[S]) -> S {
        let nan = || S::constant(f64::NAN);
        let get = |k: usize| nodes[k];
        match *self {
            Op::Const(c) => S::constant(c),
            Op::Rho(k) => x.get(2 * k).copied().unwrap_or_else(nan),
            Op::Alpha(k) => x.get(2 * k + 1).copied().unwrap_or_else(nan),
            Op::Phi(k) => S::constant(phi.get(k).copied().unwrap_or(f64::NAN)),
            Op::Add(a, b) => get(a) + get(b),
            Op::Sub(a, b) => get(a) - get(b),
            Op::Mul(a, b) => get(a) * get(b),
            Op::Div(a, b) => get(a) / get(b),
            Op::Neg(a) => -get(a),
            Op::PowC(a, c) => get(a).powf(c),
            Op::Sin(a) => get(a).sin(),
            Op::Cos(a) => get(a).cos(),
            Op::Tan(a) => get(a).tan(),
            Op::Atan(a) => get(a).atan(),
            Op::Atan2(a, b) => get(a).atan2(get(b)),
            Op::Sqrt(a) => get(a).sqrt(),
            Op::Exp(a) => get(a).exp(),
            Op::Ln(a) => get(a).ln(),
            Op::Abs(a) => get(a).abs(),
        }
    }

    /// The earlier operations this one reads.
    pub(crate) fn arguments(&self) -> [Option<usize>; 2] {
        match *self {
            Op::Const(_) | Op::Rho(_) | Op::Alpha(_) | Op::Phi(_) => [None, None],
            Op::Add(a, b) | Op::Sub(a, b) | Op::Mul(a, b) | Op::Div(a, b) | Op::Atan2(a, b) => {
                [Some(a), Some(b)]
            }
            Op::Neg(a)
            | Op::PowC(a, _)
            | Op::Sin(a)
            | Op::Cos(a)
            | Op::Tan(a)
            | Op::Atan(a)
            | Op::Sqrt(a)
            | Op::Exp(a)
            | Op::Ln(a)
            | Op::Abs(a) => [Some(a), None],
        }
    }
}

/// Which relation an atom of a constraint states about its tape value `v`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AtomKind {
    /// `v == 0`.
    Equal,
    /// `v <= 0`.
    AtMost,
}

/// One relation of a constraint.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Atom {
    /// The relation.
    pub kind: AtomKind,
    /// The tape node holding `left - right` (or `right - left` for `>=`).
    pub node: usize,
}

impl Atom {
    /// How far `value` is from satisfying the relation (0 when satisfied).
    pub fn violation(&self, value: f64) -> f64 {
        match self.kind {
            AtomKind::Equal => value.abs(),
            AtomKind::AtMost => value.max(0.0),
        }
    }
}

/// A constraint: a disjunction of relations (one relation for a plain equality or inequality).
#[derive(Clone, Debug, PartialEq)]
pub struct Constraint {
    /// The alternatives; the constraint holds when one of them holds.
    pub branches: Vec<Atom>,
    /// Where it is written.
    pub pos: Pos,
}

/// A compiled priorlet: a tape and the constraints and energies read from it.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Priorlet {
    /// Scalar operations, each depending only on earlier ones.
    pub tape: Vec<Op>,
    /// Equalities, inequalities and disjunctions.
    pub constraints: Vec<Constraint>,
    /// Tape nodes of the energies (`model_likelihood`), added to the negative log-posterior.
    pub energies: Vec<usize>,
}

impl Priorlet {
    /// Whether the priorlet states nothing.
    pub fn is_empty(&self) -> bool {
        self.constraints.is_empty() && self.energies.is_empty()
    }

    /// Evaluates the tape on the window `x = (rho_1, alpha_1, rho_2, alpha_2, ...)` with
    /// bearings `phi`, writing every node's value into `out`.
    pub fn eval<S: Scalar>(&self, x: &[S], phi: &[f64], out: &mut Vec<S>) {
        out.clear();
        for op in &self.tape {
            let value = op.apply(x, phi, out);
            out.push(value);
        }
    }
}

/// A checked, compiled prior.
#[derive(Clone, Debug, PartialEq)]
pub struct Prior {
    /// Its name.
    pub name: String,
    /// How many consecutive readings each priorlet sees.
    pub order: usize,
    /// Largest curvature of the environment, 1/m, if given (bounds the normals).
    pub max_curvature: Option<f64>,
    /// The `same_region`, `different_region` and `different_surface` priorlets.
    pub priorlets: [Priorlet; 3],
}

impl Prior {
    /// The priorlet for a topology case.
    pub fn priorlet(&self, topology: Topology) -> &Priorlet {
        &self.priorlets[topology.index()]
    }
}

/// A set of prior files that may specialize each other; looked up by their `name:`.
#[derive(Clone, Debug, Default)]
pub struct Library {
    files: Vec<PriorFile>,
}

/// The prior files shipped with the crate: `(file name, text)`.
pub const SHIPPED: [(&str, &str); 7] = [
    ("polygonal.prior", include_str!("../priors/polygonal.prior")),
    (
        "rectangular.prior",
        include_str!("../priors/rectangular.prior"),
    ),
    (
        "rectangular_relaxed.prior",
        include_str!("../priors/rectangular_relaxed.prior"),
    ),
    (
        "rectangular_energy.prior",
        include_str!("../priors/rectangular_energy.prior"),
    ),
    ("circular.prior", include_str!("../priors/circular.prior")),
    (
        "circular_radius.prior",
        include_str!("../priors/circular_radius.prior"),
    ),
    ("splines.prior", include_str!("../priors/splines.prior")),
];

/// Parses and checks a single self-contained prior (no `specializes:`), e.g. for tests.
pub fn parse_prior(text: &str, origin: &str) -> Result<Prior> {
    let mut library = Library::default();
    let name = library.add(text, origin)?;
    library.compile(&name)
}

impl Library {
    /// The shipped priors (see [`SHIPPED`]).
    pub fn shipped() -> Result<Library> {
        let mut library = Library::default();
        for (origin, text) in SHIPPED {
            library.add(text, origin)?;
        }
        Ok(library)
    }

    /// Parses a prior file and adds it; returns its name. A name already present is an error.
    pub fn add(&mut self, text: &str, origin: &str) -> Result<String> {
        let file = parse(text, origin)?;
        let Some((name, pos)) = file.name.clone() else {
            return Err(check_error(
                origin,
                Pos { line: 1, column: 1 },
                "missing 'name:'",
            ));
        };
        if self.find(&name).is_some() {
            return Err(check_error(
                origin,
                pos,
                format!("a prior named {name:?} is already loaded"),
            ));
        }
        self.files.push(file);
        Ok(name)
    }

    /// Reads, parses and adds a prior file; returns its name.
    pub fn add_file(&mut self, path: &std::path::Path) -> Result<String> {
        let text = std::fs::read_to_string(path).map_err(|source| PriorError::Io {
            path: path.display().to_string(),
            source,
        })?;
        self.add(&text, &path.display().to_string())
    }

    /// The names of the loaded priors, in loading order.
    pub fn names(&self) -> Vec<String> {
        self.files
            .iter()
            .filter_map(|f| f.name.as_ref().map(|(n, _)| n.clone()))
            .collect()
    }

    fn find(&self, name: &str) -> Option<&PriorFile> {
        self.files
            .iter()
            .find(|f| f.name.as_ref().is_some_and(|(n, _)| n == name))
    }

    /// Resolves inheritance and checks and compiles the prior `name`.
    ///
    /// Inheritance (`specializes:`): the nearest `order:` and `max_curvature:` win (a child
    /// may not lower the order); definitions are taken ancestor first, so a child's
    /// redefinition overrides the parent's (also inside the parent's priorlet lines); each
    /// priorlet is the parent's lines followed by the child's (the source's circular prior
    /// with a prior on the radius adds an energy to the circular prior's constraints).
    pub fn compile(&self, name: &str) -> Result<Prior> {
        let mut chain: Vec<&PriorFile> = Vec::new();
        let mut seen = HashSet::new();
        let mut current = self
            .find(name)
            .ok_or_else(|| PriorError::UnknownPrior(name.to_string()))?;
        loop {
            let current_name = current.name.as_ref().map_or("", |(n, _)| n.as_str());
            if !seen.insert(current_name.to_string()) {
                let mut names: Vec<&str> = chain
                    .iter()
                    .map(|f| f.name.as_ref().map_or("", |(n, _)| n.as_str()))
                    .collect();
                names.push(current_name);
                return Err(PriorError::InheritanceCycle(names.join(" -> ")));
            }
            chain.push(current);
            match &current.specializes {
                None => break,
                Some((parent, pos)) => {
                    current = self.find(parent).ok_or_else(|| {
                        check_error(
                            &current.origin,
                            *pos,
                            format!("specializes unknown prior {parent:?}"),
                        )
                    })?;
                }
            }
        }
        let leaf = chain[0];
        // Order and curvature: the nearest declaration wins; a child may not lower the order.
        let mut order = None;
        let mut max_curvature = None;
        for file in &chain {
            if let Some((o, pos)) = file.order {
                match order {
                    None => order = Some((o, pos, file)),
                    Some((child, child_pos, child_file)) if child < o => {
                        return Err(check_error(
                            &child_file.origin,
                            child_pos,
                            format!(
                                "order {child} is lower than order {o} of the prior it \
                                 specializes"
                            ),
                        ));
                    }
                    Some(_) => {}
                }
            }
            if max_curvature.is_none() {
                max_curvature = file.max_curvature;
            }
        }
        let Some((order, order_pos, order_file)) = order else {
            let pos = leaf.name.as_ref().map_or(Pos::default(), |(_, p)| *p);
            return Err(check_error(
                &leaf.origin,
                pos,
                "no 'order:' given (here or in a prior it specializes)",
            ));
        };
        if !(2..=MAX_ORDER).contains(&order) {
            return Err(check_error(
                &order_file.origin,
                order_pos,
                format!("order must be between 2 and {MAX_ORDER}, not {order}"),
            ));
        }
        if let Some((k, pos)) = max_curvature
            && (k.is_nan() || k < 0.0)
        {
            let file = chain
                .iter()
                .find(|f| f.max_curvature.is_some())
                .map_or(leaf.origin.as_str(), |f| f.origin.as_str());
            return Err(check_error(
                file,
                pos,
                format!("max_curvature must be non-negative, not {k}"),
            ));
        }
        let mut priorlets: [Priorlet; 3] = Default::default();
        for topology in Topology::ALL {
            let mut compiler = Compiler {
                order,
                tape: Vec::new(),
                index: HashMap::new(),
                env: HashMap::new(),
                origin: String::new(),
            };
            for file in chain.iter().rev() {
                compiler.origin = file.origin.clone();
                for item in &file.globals {
                    compiler.item(item, &mut priorlets[topology.index()])?;
                }
            }
            for file in chain.iter().rev() {
                compiler.origin = file.origin.clone();
                for item in &file.priorlets[topology.index()] {
                    compiler.item(item, &mut priorlets[topology.index()])?;
                }
            }
            priorlets[topology.index()].tape = compiler.tape;
        }
        Ok(Prior {
            name: name.to_string(),
            order,
            max_curvature: max_curvature.map(|(k, _)| k),
            priorlets,
        })
    }
}

fn check_error(origin: &str, pos: Pos, message: impl Into<String>) -> PriorError {
    PriorError::Check {
        origin: origin.to_string(),
        line: pos.line,
        column: pos.column,
        message: message.into(),
    }
}

/// A compiled value: a matrix of tape nodes (row-major); a scalar is 1 x 1.
#[derive(Clone, Debug)]
struct Value {
    rows: usize,
    cols: usize,
    data: Vec<usize>,
}

impl Value {
    fn scalar(node: usize) -> Value {
        Value {
            rows: 1,
            cols: 1,
            data: vec![node],
        }
    }
    fn is_scalar(&self) -> bool {
        self.rows == 1 && self.cols == 1
    }
    fn shape(&self) -> String {
        format!("{}x{}", self.rows, self.cols)
    }
}

struct Compiler {
    order: usize,
    tape: Vec<Op>,
    index: HashMap<(u8, u64, usize, usize), usize>,
    env: HashMap<String, Value>,
    origin: String,
}

const FUNCTIONS: &str = "sin, cos, tan, atan, atan2, sqrt, exp, log, abs, norm, dot, deg2rad, \
                         rad2deg, transpose";

impl Compiler {
    fn error<T>(&self, pos: Pos, message: impl Into<String>) -> Result<T> {
        Err(check_error(&self.origin, pos, message))
    }

    fn push(&mut self, op: Op) -> usize {
        // Constant folding.
        let constant = |k: usize| match self.tape[k] {
            Op::Const(c) => Some(c),
            _ => None,
        };
        let folded = match op {
            Op::Add(a, b) => constant(a).zip(constant(b)).map(|(a, b)| a + b),
            Op::Sub(a, b) => constant(a).zip(constant(b)).map(|(a, b)| a - b),
            Op::Mul(a, b) => constant(a).zip(constant(b)).map(|(a, b)| a * b),
            Op::Div(a, b) => constant(a).zip(constant(b)).map(|(a, b)| a / b),
            Op::Neg(a) => constant(a).map(|a| -a),
            Op::PowC(a, c) => constant(a).map(|a| a.powf(c)),
            Op::Sin(a) => constant(a).map(f64::sin),
            Op::Cos(a) => constant(a).map(f64::cos),
            Op::Tan(a) => constant(a).map(f64::tan),
            Op::Atan(a) => constant(a).map(f64::atan),
            Op::Atan2(a, b) => constant(a).zip(constant(b)).map(|(a, b)| a.atan2(b)),
            Op::Sqrt(a) => constant(a).map(f64::sqrt),
            Op::Exp(a) => constant(a).map(f64::exp),
            Op::Ln(a) => constant(a).map(f64::ln),
            Op::Abs(a) => constant(a).map(f64::abs),
            _ => None,
        };
        let op = folded.map_or(op, Op::Const);
        let key = op.key();
        if let Some(&k) = self.index.get(&key) {
            return k;
        }
        self.tape.push(op);
        let k = self.tape.len() - 1;
        self.index.insert(key, k);
        k
    }

    fn item(&mut self, item: &Item, priorlet: &mut Priorlet) -> Result<()> {
        match item {
            Item::Define { name, pos, expr } => {
                if predefined(name).is_some() || name == "pi" {
                    return self.error(*pos, format!("cannot redefine the predefined {name:?}"));
                }
                let value = self.value(expr)?;
                self.env.insert(name.clone(), value);
            }
            Item::Energy(expr) => {
                let value = self.value(expr)?;
                if !value.is_scalar() {
                    return self.error(
                        expr.pos,
                        format!("model_likelihood needs a scalar, not a {}", value.shape()),
                    );
                }
                priorlet.energies.push(value.data[0]);
            }
            Item::Constraint(expr) => {
                let mut branches = Vec::new();
                self.branches(expr, &mut branches)?;
                priorlet.constraints.push(Constraint {
                    branches,
                    pos: expr.pos,
                });
            }
        }
        Ok(())
    }

    fn branches(&mut self, expr: &Expr, out: &mut Vec<Atom>) -> Result<()> {
        match &expr.kind {
            ExprKind::Or(a, b) => {
                self.branches(a, out)?;
                self.branches(b, out)
            }
            ExprKind::Rel(op, a, b) => {
                let left = self.scalar(a, "a side of a relation")?;
                let right = self.scalar(b, "a side of a relation")?;
                let (kind, node) = match op {
                    RelOp::Eq => (AtomKind::Equal, self.push(Op::Sub(left, right))),
                    RelOp::Le => (AtomKind::AtMost, self.push(Op::Sub(left, right))),
                    RelOp::Ge => (AtomKind::AtMost, self.push(Op::Sub(right, left))),
                };
                out.push(Atom { kind, node });
                Ok(())
            }
            _ => self.error(
                expr.pos,
                "a constraint must be a relation (==, <=, >=) or a disjunction of relations \
                 (||)",
            ),
        }
    }

    fn scalar(&mut self, expr: &Expr, what: &str) -> Result<usize> {
        let value = self.value(expr)?;
        if !value.is_scalar() {
            return self.error(
                expr.pos,
                format!("{what} must be a scalar, not a {}", value.shape()),
            );
        }
        Ok(value.data[0])
    }

    fn map(&mut self, value: Value, f: impl Fn(usize) -> Op) -> Value {
        let data = value.data.iter().map(|&k| self.push(f(k))).collect();
        Value { data, ..value }
    }

    fn value(&mut self, expr: &Expr) -> Result<Value> {
        match &expr.kind {
            ExprKind::Num(c) => Ok(Value::scalar(self.push(Op::Const(*c)))),
            ExprKind::Var(name) => self.variable(name, expr.pos),
            ExprKind::Neg(inner) => {
                let v = self.value(inner)?;
                Ok(self.map(v, Op::Neg))
            }
            ExprKind::Transpose(inner) => {
                let v = self.value(inner)?;
                Ok(transpose(&v))
            }
            ExprKind::Matrix(rows) => self.matrix(rows, expr.pos),
            ExprKind::Binary(op, a, b) => {
                let left = self.value(a)?;
                let right = self.value(b)?;
                self.binary(*op, left, right, expr.pos, b)
            }
            ExprKind::Call(name, args) => self.call(name, args, expr.pos),
            ExprKind::Rel(..) | ExprKind::Or(..) => self.error(
                expr.pos,
                "a relation cannot be used as a value (relations belong at the top of a \
                 constraint)",
            ),
        }
    }

    fn variable(&mut self, name: &str, pos: Pos) -> Result<Value> {
        if name == "pi" {
            return Ok(Value::scalar(self.push(Op::Const(std::f64::consts::PI))));
        }
        if let Some((kind, k)) = predefined(name) {
            if k == 0 || k > self.order {
                return self.error(
                    pos,
                    format!(
                        "{name} is out of range for a prior of order {} (indices run from 1 \
                         to {})",
                        self.order, self.order
                    ),
                );
            }
            let op = match kind {
                "rho" => Op::Rho(k - 1),
                "alpha" => Op::Alpha(k - 1),
                _ => Op::Phi(k - 1),
            };
            return Ok(Value::scalar(self.push(op)));
        }
        match self.env.get(name) {
            Some(v) => Ok(v.clone()),
            None => self.error(pos, format!("unknown variable {name:?}")),
        }
    }

    fn matrix(&mut self, rows: &[Vec<Expr>], pos: Pos) -> Result<Value> {
        // Horizontal then vertical concatenation, MATLAB style.
        let mut blocks: Vec<Value> = Vec::new();
        for row in rows {
            let mut parts = Vec::new();
            for e in row {
                parts.push(self.value(e)?);
            }
            let height = parts.first().map_or(0, |p| p.rows);
            if parts.iter().any(|p| p.rows != height) {
                return self.error(pos, "matrix row parts have different heights");
            }
            let width: usize = parts.iter().map(|p| p.cols).sum();
            let mut data = Vec::with_capacity(height * width);
            for r in 0..height {
                for p in &parts {
                    data.extend_from_slice(&p.data[r * p.cols..(r + 1) * p.cols]);
                }
            }
            blocks.push(Value {
                rows: height,
                cols: width,
                data,
            });
        }
        let width = blocks.first().map_or(0, |b| b.cols);
        if width == 0 || blocks.iter().any(|b| b.cols != width) {
            return self.error(pos, "matrix rows have different lengths");
        }
        let rows = blocks.iter().map(|b| b.rows).sum();
        let data = blocks.into_iter().flat_map(|b| b.data).collect();
        Ok(Value {
            rows,
            cols: width,
            data,
        })
    }

    fn binary(
        &mut self,
        op: BinOp,
        left: Value,
        right: Value,
        pos: Pos,
        right_expr: &Expr,
    ) -> Result<Value> {
        match op {
            BinOp::Add | BinOp::Sub => {
                let make = |a, b| {
                    if op == BinOp::Add {
                        Op::Add(a, b)
                    } else {
                        Op::Sub(a, b)
                    }
                };
                if left.is_scalar() && !right.is_scalar() {
                    let s = left.data[0];
                    return Ok(self.map(right, |b| make(s, b)));
                }
                if right.is_scalar() && !left.is_scalar() {
                    let s = right.data[0];
                    return Ok(self.map(left, |a| make(a, s)));
                }
                if left.rows != right.rows || left.cols != right.cols {
                    return self.error(
                        pos,
                        format!(
                            "cannot add or subtract a {} and a {}",
                            left.shape(),
                            right.shape()
                        ),
                    );
                }
                let data = left
                    .data
                    .iter()
                    .zip(&right.data)
                    .map(|(&a, &b)| self.push(make(a, b)))
                    .collect();
                Ok(Value { data, ..left })
            }
            BinOp::Mul => {
                if left.is_scalar() {
                    let s = left.data[0];
                    return Ok(self.map(right, |b| Op::Mul(s, b)));
                }
                if right.is_scalar() {
                    let s = right.data[0];
                    return Ok(self.map(left, |a| Op::Mul(a, s)));
                }
                if left.cols != right.rows {
                    return self.error(
                        pos,
                        format!(
                            "cannot multiply a {} by a {} (inner sizes differ)",
                            left.shape(),
                            right.shape()
                        ),
                    );
                }
                let mut data = Vec::with_capacity(left.rows * right.cols);
                for r in 0..left.rows {
                    for c in 0..right.cols {
                        let mut acc: Option<usize> = None;
                        for k in 0..left.cols {
                            let term = self.push(Op::Mul(
                                left.data[r * left.cols + k],
                                right.data[k * right.cols + c],
                            ));
                            acc = Some(match acc {
                                None => term,
                                Some(a) => self.push(Op::Add(a, term)),
                            });
                        }
                        data.push(acc.unwrap_or_else(|| self.push(Op::Const(0.0))));
                    }
                }
                Ok(Value {
                    rows: left.rows,
                    cols: right.cols,
                    data,
                })
            }
            BinOp::Div => {
                if !right.is_scalar() {
                    return self.error(
                        right_expr.pos,
                        format!("can only divide by a scalar, not a {}", right.shape()),
                    );
                }
                let s = right.data[0];
                Ok(self.map(left, |a| Op::Div(a, s)))
            }
            BinOp::Pow => {
                if !left.is_scalar() || !right.is_scalar() {
                    return self.error(
                        pos,
                        format!(
                            "'^' needs scalars, not a {} and a {}",
                            left.shape(),
                            right.shape()
                        ),
                    );
                }
                let (a, b) = (left.data[0], right.data[0]);
                let node = match self.tape[b] {
                    Op::Const(c) => self.push(Op::PowC(a, c)),
                    _ => {
                        let ln = self.push(Op::Ln(a));
                        let product = self.push(Op::Mul(b, ln));
                        self.push(Op::Exp(product))
                    }
                };
                Ok(Value::scalar(node))
            }
        }
    }

    fn call(&mut self, name: &str, args: &[Expr], pos: Pos) -> Result<Value> {
        let arity = match name {
            "atan2" | "dot" => 2,
            "sin" | "cos" | "tan" | "atan" | "sqrt" | "exp" | "log" | "abs" | "norm"
            | "deg2rad" | "rad2deg" | "transpose" => 1,
            _ => {
                return self.error(
                    pos,
                    format!("unknown function {name:?} (known: {FUNCTIONS})"),
                );
            }
        };
        if args.len() != arity {
            return self.error(
                pos,
                format!("{name} takes {arity} argument(s), given {}", args.len()),
            );
        }
        let mut values = Vec::new();
        for a in args {
            values.push(self.value(a)?);
        }
        let first = values[0].clone();
        let elementwise = |op: fn(usize) -> Op| op;
        let unary = match name {
            "sin" => Some(elementwise(Op::Sin)),
            "cos" => Some(elementwise(Op::Cos)),
            "tan" => Some(elementwise(Op::Tan)),
            "atan" => Some(elementwise(Op::Atan)),
            "sqrt" => Some(elementwise(Op::Sqrt)),
            "exp" => Some(elementwise(Op::Exp)),
            "log" => Some(elementwise(Op::Ln)),
            "abs" => Some(elementwise(Op::Abs)),
            _ => None,
        };
        if let Some(op) = unary {
            return Ok(self.map(first, op));
        }
        match name {
            "deg2rad" | "rad2deg" => {
                let factor = if name == "deg2rad" {
                    std::f64::consts::PI / 180.0
                } else {
                    180.0 / std::f64::consts::PI
                };
                let f = self.push(Op::Const(factor));
                Ok(self.map(first, |a| Op::Mul(a, f)))
            }
            "transpose" => Ok(transpose(&first)),
            "norm" | "dot" => {
                let second = if name == "dot" {
                    values[1].clone()
                } else {
                    first.clone()
                };
                let vector = |v: &Value| v.rows == 1 || v.cols == 1;
                if !vector(&first) || !vector(&second) || first.data.len() != second.data.len() {
                    return self.error(
                        pos,
                        format!(
                            "{name} needs vectors of one length, not a {} and a {}",
                            first.shape(),
                            second.shape()
                        ),
                    );
                }
                let mut acc: Option<usize> = None;
                for (&a, &b) in first.data.iter().zip(&second.data) {
                    let term = self.push(Op::Mul(a, b));
                    acc = Some(match acc {
                        None => term,
                        Some(s) => self.push(Op::Add(s, term)),
                    });
                }
                let sum = acc.unwrap_or_else(|| self.push(Op::Const(0.0)));
                let node = if name == "norm" {
                    self.push(Op::Sqrt(sum))
                } else {
                    sum
                };
                Ok(Value::scalar(node))
            }
            "atan2" => {
                let (y, x) = (first, values[1].clone());
                if !y.is_scalar() || !x.is_scalar() {
                    return self.error(pos, "atan2 needs two scalars");
                }
                Ok(Value::scalar(self.push(Op::Atan2(y.data[0], x.data[0]))))
            }
            _ => self.error(pos, format!("unknown function {name:?}")),
        }
    }
}

fn transpose(v: &Value) -> Value {
    let mut data = Vec::with_capacity(v.data.len());
    for c in 0..v.cols {
        for r in 0..v.rows {
            data.push(v.data[r * v.cols + c]);
        }
    }
    Value {
        rows: v.cols,
        cols: v.rows,
        data,
    }
}

/// `rho_3` -> `("rho", 3)`; also `alpha_k`, `phi_k`. Any other name: `None`.
fn predefined(name: &str) -> Option<(&'static str, usize)> {
    for kind in ["rho", "alpha", "phi"] {
        if let Some(rest) = name.strip_prefix(kind).and_then(|r| r.strip_prefix('_'))
            && !rest.is_empty()
            && rest.bytes().all(|b| b.is_ascii_digit())
        {
            return Some((kind, rest.parse().unwrap_or(usize::MAX)));
        }
    }
    None
}
