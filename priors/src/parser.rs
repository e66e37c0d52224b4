//! The syntax tree of a prior file and its parser.
//!
//! Grammar (statements end at a newline or `;`; newlines inside brackets are ignored):
//!
//! ```text
//! file       := { header | section | definition | statement }
//! header     := ("name" | "specializes") ":" text-to-end-of-line
//!             | "order" ":" integer | "max_curvature" ":" number
//! section    := "priorlet" ("same_region" | "different_region" | "different_surface") ":"
//! definition := identifier "=" expr
//! statement  := "model_likelihood" expr | expr          (inside a priorlet)
//! expr       := rel { "||" rel }
//! rel        := sum [ ("==" | "<=" | ">=") sum ]
//! sum        := product { ("+" | "-") product }
//! product    := unary { ("*" | "/") unary }
//! unary      := ("-" | "+") unary | power
//! power      := postfix { "^" ["-"] postfix }
//! postfix    := primary { "'" }
//! primary    := number | identifier [ "(" expr { "," expr } ")" ] | "(" expr ")"
//!             | "[" expr { ("," | ";") expr } "]"
//! ```

use crate::error::{PriorError, Result};
use crate::lexer::{Pos, Tok, Token, lex};

/// Arithmetic operators.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BinOp {
    /// `+`
    Add,
    /// `-`
    Sub,
    /// `*` (matrix product, or scaling by a scalar)
    Mul,
    /// `/` (by a scalar)
    Div,
    /// `^` (of scalars)
    Pow,
}

/// Relations.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RelOp {
    /// `==`
    Eq,
    /// `<=`
    Le,
    /// `>=`
    Ge,
}

/// An expression node and where it starts.
#[derive(Clone, Debug, PartialEq)]
pub struct Expr {
    /// What the node is.
    pub kind: ExprKind,
    /// Its position in the file.
    pub pos: Pos,
}

/// Expression node kinds.
#[derive(Clone, Debug, PartialEq)]
pub enum ExprKind {
    /// A number.
    Num(f64),
    /// A variable or constant name.
    Var(String),
    /// A function call.
    Call(String, Vec<Expr>),
    /// Unary minus.
    Neg(Box<Expr>),
    /// An arithmetic operation.
    Binary(BinOp, Box<Expr>, Box<Expr>),
    /// Transpose `'`.
    Transpose(Box<Expr>),
    /// A matrix literal, row by row.
    Matrix(Vec<Vec<Expr>>),
    /// A relation (constraint).
    Rel(RelOp, Box<Expr>, Box<Expr>),
    /// A disjunction of relations.
    Or(Box<Expr>, Box<Expr>),
}

/// The three priorlets of a prior, one per topology case of two consecutive readings.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Topology {
    /// Same surface, same region.
    SameRegion,
    /// Same surface, different regions.
    DifferentRegion,
    /// Different surfaces.
    DifferentSurface,
}

impl Topology {
    /// All three, strictest first.
    pub const ALL: [Topology; 3] = [
        Topology::SameRegion,
        Topology::DifferentRegion,
        Topology::DifferentSurface,
    ];

    /// Index 0, 1, 2 (strictest first).
    pub fn index(self) -> usize {
        self as usize
    }

    /// The keyword of the priorlet in the language.
    pub fn keyword(self) -> &'static str {
        match self {
            Topology::SameRegion => "same_region",
            Topology::DifferentRegion => "different_region",
            Topology::DifferentSurface => "different_surface",
        }
    }
}

/// A line of a priorlet (or a global definition).
#[derive(Clone, Debug, PartialEq)]
pub enum Item {
    /// `name = expr`.
    Define {
        /// The new variable.
        name: String,
        /// Where it is defined.
        pos: Pos,
        /// Its value.
        expr: Expr,
    },
    /// An equality, inequality or disjunction.
    Constraint(Expr),
    /// `model_likelihood expr`: an energy (negative log-likelihood) added to the objective.
    Energy(Expr),
}

/// A parsed prior file, before inheritance is resolved.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct PriorFile {
    /// Where the text came from (file name), for messages.
    pub origin: String,
    /// `name:`.
    pub name: Option<(String, Pos)>,
    /// `order:`.
    pub order: Option<(usize, Pos)>,
    /// `specializes:`.
    pub specializes: Option<(String, Pos)>,
    /// `max_curvature:` (1/m).
    pub max_curvature: Option<(f64, Pos)>,
    /// Definitions outside any priorlet, in file order.
    pub globals: Vec<Item>,
    /// Items of the `same_region`, `different_region`, `different_surface` priorlets.
    pub priorlets: [Vec<Item>; 3],
}

const MAX_DEPTH: usize = 128;

struct Parser<'a> {
    text: &'a str,
    origin: &'a str,
    tokens: Vec<Token>,
    at: usize,
    depth: usize,
}

/// Parses a prior file; errors name `origin:line:column`.
pub fn parse(text: &str, origin: &str) -> Result<PriorFile> {
    let tokens = lex(text, origin)?;
    let mut parser = Parser {
        text,
        origin,
        tokens,
        at: 0,
        depth: 0,
    };
    parser.file()
}

impl Parser<'_> {
    fn peek(&self) -> &Token {
        // The token list always ends with Eof and `at` never passes it.
        &self.tokens[self.at.min(self.tokens.len() - 1)]
    }

    fn peek2(&self) -> &Tok {
        &self.tokens[(self.at + 1).min(self.tokens.len() - 1)].tok
    }

    fn bump(&mut self) -> Token {
        let token = self.peek().clone();
        if self.at < self.tokens.len() - 1 {
            self.at += 1;
        }
        token
    }

    fn error<T>(&self, pos: Pos, message: impl Into<String>) -> Result<T> {
        Err(PriorError::Syntax {
            origin: self.origin.to_string(),
            line: pos.line,
            column: pos.column,
            message: message.into(),
        })
    }

    fn describe(tok: &Tok) -> String {
        match tok {
            Tok::Ident(name) => format!("'{name}'"),
            Tok::Num(value) => format!("number {value}"),
            Tok::Sym(sym) => format!("'{sym}'"),
            Tok::Newline => "end of line".into(),
            Tok::Eof => "end of file".into(),
        }
    }

    fn expect(&mut self, sym: &'static str) -> Result<Token> {
        let token = self.peek().clone();
        if token.tok == Tok::Sym(sym) {
            Ok(self.bump())
        } else {
            self.error(
                token.pos,
                format!("expected '{sym}', found {}", Self::describe(&token.tok)),
            )
        }
    }

    fn end_of_statement(&mut self) -> Result<()> {
        let token = self.peek().clone();
        match token.tok {
            Tok::Newline | Tok::Sym(";") => {
                self.bump();
                Ok(())
            }
            Tok::Eof => Ok(()),
            other => self.error(
                token.pos,
                format!(
                    "expected the end of the statement, found {}",
                    Self::describe(&other)
                ),
            ),
        }
    }

    fn rest_of_line(&mut self, after: Pos) -> Result<String> {
        let first = self.peek().clone();
        let mut last_end = first.start;
        while !matches!(self.peek().tok, Tok::Newline | Tok::Eof) {
            last_end = self.bump().end;
        }
        let text = self.text[first.start..last_end].trim().to_string();
        if text.is_empty() {
            return self.error(after, "expected a name after ':'");
        }
        Ok(text)
    }

    fn file(&mut self) -> Result<PriorFile> {
        let mut file = PriorFile {
            origin: self.origin.to_string(),
            ..PriorFile::default()
        };
        let mut section: Option<Topology> = None;
        loop {
            let token = self.peek().clone();
            match &token.tok {
                Tok::Eof => break,
                Tok::Newline | Tok::Sym(";") => {
                    self.bump();
                }
                Tok::Ident(word) if *self.peek2() == Tok::Sym(":") => {
                    let word = word.clone();
                    self.bump();
                    let colon = self.bump();
                    match word.as_str() {
                        "name" | "specializes" => {
                            if section.is_some() {
                                return self.error(
                                    token.pos,
                                    format!("'{word}:' must come before the priorlets"),
                                );
                            }
                            let value = self.rest_of_line(colon.pos)?;
                            let slot = if word == "name" {
                                &mut file.name
                            } else {
                                &mut file.specializes
                            };
                            if slot.is_some() {
                                return self.error(token.pos, format!("'{word}:' given twice"));
                            }
                            *slot = Some((value, token.pos));
                        }
                        "order" | "max_curvature" => {
                            if section.is_some() {
                                return self.error(
                                    token.pos,
                                    format!("'{word}:' must come before the priorlets"),
                                );
                            }
                            let number = self.bump();
                            let Tok::Num(value) = number.tok else {
                                return self.error(
                                    number.pos,
                                    format!(
                                        "expected a number after '{word}:', found {}",
                                        Self::describe(&number.tok)
                                    ),
                                );
                            };
                            if word == "order" {
                                if value.fract() != 0.0 || value < 1.0 {
                                    return self.error(
                                        number.pos,
                                        format!("order must be a positive integer, not {value}"),
                                    );
                                }
                                if file.order.is_some() {
                                    return self.error(token.pos, "'order:' given twice");
                                }
                                file.order = Some((value.min(1e6) as usize, number.pos));
                            } else {
                                if file.max_curvature.is_some() {
                                    return self.error(token.pos, "'max_curvature:' given twice");
                                }
                                file.max_curvature = Some((value, number.pos));
                            }
                            self.end_of_statement()?;
                        }
                        _ => {
                            return self.error(
                                token.pos,
                                format!(
                                    "unknown header '{word}:' (expected name, order, specializes, \
                                     max_curvature)"
                                ),
                            );
                        }
                    }
                }
                Tok::Ident(word) if word == "priorlet" => {
                    self.bump();
                    let kind = self.bump();
                    let topology = match &kind.tok {
                        Tok::Ident(k) => Topology::ALL.into_iter().find(|t| t.keyword() == k),
                        _ => None,
                    };
                    let Some(topology) = topology else {
                        return self.error(
                            kind.pos,
                            format!(
                                "expected same_region, different_region or different_surface, \
                                 found {}",
                                Self::describe(&kind.tok)
                            ),
                        );
                    };
                    self.expect(":")?;
                    if !file.priorlets[topology.index()].is_empty() {
                        return self.error(
                            kind.pos,
                            format!("priorlet {} given twice", topology.keyword()),
                        );
                    }
                    section = Some(topology);
                    self.end_of_statement()?;
                }
                Tok::Ident(word) if word == "model_likelihood" => {
                    self.bump();
                    let Some(topology) = section else {
                        return self.error(
                            token.pos,
                            "model_likelihood outside a priorlet (start one with 'priorlet \
                             same_region:')",
                        );
                    };
                    let expr = self.expr()?;
                    file.priorlets[topology.index()].push(Item::Energy(expr));
                    self.end_of_statement()?;
                }
                Tok::Ident(word) if *self.peek2() == Tok::Sym("=") => {
                    let name = word.clone();
                    self.bump();
                    self.bump();
                    let expr = self.expr()?;
                    let item = Item::Define {
                        name,
                        pos: token.pos,
                        expr,
                    };
                    match section {
                        Some(topology) => file.priorlets[topology.index()].push(item),
                        None => file.globals.push(item),
                    }
                    self.end_of_statement()?;
                }
                _ => {
                    let expr = self.expr()?;
                    let Some(topology) = section else {
                        return self.error(
                            token.pos,
                            "a constraint outside a priorlet (start one with 'priorlet \
                             same_region:')",
                        );
                    };
                    file.priorlets[topology.index()].push(Item::Constraint(expr));
                    self.end_of_statement()?;
                }
            }
        }
        Ok(file)
    }

    fn enter(&mut self, pos: Pos) -> Result<()> {
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return self.error(pos, format!("expression nested deeper than {MAX_DEPTH}"));
        }
        Ok(())
    }

    fn expr(&mut self) -> Result<Expr> {
        let pos = self.peek().pos;
        self.enter(pos)?;
        let mut left = self.rel()?;
        while self.peek().tok == Tok::Sym("||") {
            self.bump();
            let right = self.rel()?;
            left = Expr {
                pos: left.pos,
                kind: ExprKind::Or(Box::new(left), Box::new(right)),
            };
        }
        self.depth -= 1;
        Ok(left)
    }

    fn rel(&mut self) -> Result<Expr> {
        let left = self.sum()?;
        let op = match self.peek().tok {
            Tok::Sym("==") => RelOp::Eq,
            Tok::Sym("<=") => RelOp::Le,
            Tok::Sym(">=") => RelOp::Ge,
            _ => return Ok(left),
        };
        self.bump();
        let right = self.sum()?;
        Ok(Expr {
            pos: left.pos,
            kind: ExprKind::Rel(op, Box::new(left), Box::new(right)),
        })
    }

    fn sum(&mut self) -> Result<Expr> {
        let mut left = self.product()?;
        loop {
            let op = match self.peek().tok {
                Tok::Sym("+") => BinOp::Add,
                Tok::Sym("-") => BinOp::Sub,
                _ => return Ok(left),
            };
            self.bump();
            let right = self.product()?;
            left = Expr {
                pos: left.pos,
                kind: ExprKind::Binary(op, Box::new(left), Box::new(right)),
            };
        }
    }

    fn product(&mut self) -> Result<Expr> {
        let mut left = self.unary()?;
        loop {
            let op = match self.peek().tok {
                Tok::Sym("*") => BinOp::Mul,
                Tok::Sym("/") => BinOp::Div,
                _ => return Ok(left),
            };
            self.bump();
            let right = self.unary()?;
            left = Expr {
                pos: left.pos,
                kind: ExprKind::Binary(op, Box::new(left), Box::new(right)),
            };
        }
    }

    fn unary(&mut self) -> Result<Expr> {
        let token = self.peek().clone();
        match token.tok {
            Tok::Sym("-") => {
                self.bump();
                self.enter(token.pos)?;
                let inner = self.unary()?;
                self.depth -= 1;
                Ok(Expr {
                    pos: token.pos,
                    kind: ExprKind::Neg(Box::new(inner)),
                })
            }
            Tok::Sym("+") => {
                self.bump();
                self.enter(token.pos)?;
                let inner = self.unary();
                self.depth -= 1;
                inner
            }
            _ => self.power(),
        }
    }

    fn power(&mut self) -> Result<Expr> {
        let mut left = self.postfix()?;
        while self.peek().tok == Tok::Sym("^") {
            self.bump();
            let token = self.peek().clone();
            let right = if token.tok == Tok::Sym("-") {
                self.bump();
                let inner = self.postfix()?;
                Expr {
                    pos: token.pos,
                    kind: ExprKind::Neg(Box::new(inner)),
                }
            } else {
                self.postfix()?
            };
            left = Expr {
                pos: left.pos,
                kind: ExprKind::Binary(BinOp::Pow, Box::new(left), Box::new(right)),
            };
        }
        Ok(left)
    }

    fn postfix(&mut self) -> Result<Expr> {
        let mut inner = self.primary()?;
        while self.peek().tok == Tok::Sym("'") {
            let token = self.bump();
            inner = Expr {
                pos: token.pos,
                kind: ExprKind::Transpose(Box::new(inner)),
            };
        }
        Ok(inner)
    }

    fn primary(&mut self) -> Result<Expr> {
        let token = self.bump();
        match token.tok {
            Tok::Num(value) => Ok(Expr {
                pos: token.pos,
                kind: ExprKind::Num(value),
            }),
            Tok::Ident(name) => {
                if self.peek().tok == Tok::Sym("(") {
                    self.bump();
                    let mut args = Vec::new();
                    if self.peek().tok != Tok::Sym(")") {
                        loop {
                            args.push(self.expr()?);
                            if self.peek().tok == Tok::Sym(",") {
                                self.bump();
                            } else {
                                break;
                            }
                        }
                    }
                    self.expect(")")?;
                    Ok(Expr {
                        pos: token.pos,
                        kind: ExprKind::Call(name, args),
                    })
                } else {
                    Ok(Expr {
                        pos: token.pos,
                        kind: ExprKind::Var(name),
                    })
                }
            }
            Tok::Sym("(") => {
                let inner = self.expr()?;
                self.expect(")")?;
                Ok(inner)
            }
            Tok::Sym("[") => {
                let mut rows = vec![Vec::new()];
                if self.peek().tok == Tok::Sym("]") {
                    return self.error(token.pos, "empty matrix");
                }
                loop {
                    let element = self.expr()?;
                    if let Some(row) = rows.last_mut() {
                        row.push(element);
                    }
                    let next = self.bump();
                    match next.tok {
                        Tok::Sym(",") => {}
                        Tok::Sym(";") => rows.push(Vec::new()),
                        Tok::Sym("]") => break,
                        other => {
                            return self.error(
                                next.pos,
                                format!(
                                    "expected ',', ';' or ']' in a matrix, found {}",
                                    Self::describe(&other)
                                ),
                            );
                        }
                    }
                }
                Ok(Expr {
                    pos: token.pos,
                    kind: ExprKind::Matrix(rows),
                })
            }
            other => self.error(
                token.pos,
                format!("expected an expression, found {}", Self::describe(&other)),
            ),
        }
    }
}
