//! Tokens of the prior language.

use crate::error::{PriorError, Result};

/// A position in a prior file: 1-based line and column (in characters).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Pos {
    /// 1-based line.
    pub line: usize,
    /// 1-based column, in characters.
    pub column: usize,
}

/// A token kind.
#[derive(Clone, Debug, PartialEq)]
pub enum Tok {
    /// An identifier; Greek letters are spelled out (`ρ_1` becomes `rho_1`, `π` becomes `pi`).
    Ident(String),
    /// A number literal.
    Num(f64),
    /// An operator or punctuation, as written (`==`, `<=`, `||`, `'`, ...).
    Sym(&'static str),
    /// The end of a line outside brackets.
    Newline,
    /// The end of the text.
    Eof,
}

/// A token with its position and byte span in the source.
#[derive(Clone, Debug, PartialEq)]
pub struct Token {
    /// What the token is.
    pub tok: Tok,
    /// Where it starts.
    pub pos: Pos,
    /// Byte offset of its first character.
    pub start: usize,
    /// Byte offset just past its last character.
    pub end: usize,
}

fn greek(c: char) -> Option<&'static str> {
    match c {
        'ρ' => Some("rho"),
        'α' => Some("alpha"),
        'φ' | 'ϕ' => Some("phi"),
        'π' => Some("pi"),
        _ => None,
    }
}

fn ident_start(c: char) -> bool {
    c.is_ascii_alphabetic() || c == '_' || greek(c).is_some()
}

fn ident_continue(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_' || greek(c).is_some()
}

/// Splits `text` into tokens. Newlines inside `()` and `[]` are dropped, so an expression
/// may span lines there; `#` starts a comment that runs to the end of the line.
pub fn lex(text: &str, origin: &str) -> Result<Vec<Token>> {
    let chars: Vec<(usize, char)> = text.char_indices().collect();
    let mut tokens = Vec::new();
    let mut depth: usize = 0;
    let mut line = 1;
    let mut column = 1;
    let mut i = 0;
    let error = |pos: Pos, message: String| PriorError::Syntax {
        origin: origin.to_string(),
        line: pos.line,
        column: pos.column,
        message,
    };
    while i < chars.len() {
        let (start, c) = chars[i];
        let pos = Pos { line, column };
        let byte_at = |k: usize| chars.get(k).map_or(text.len(), |&(b, _)| b);
        let peek = chars.get(i + 1).map(|&(_, c)| c);
        let push = |tok: Tok, len: usize, tokens: &mut Vec<Token>| {
            tokens.push(Token {
                tok,
                pos,
                start,
                end: byte_at(i + len),
            });
        };
        if c == '\n' {
            if depth == 0 {
                push(Tok::Newline, 1, &mut tokens);
            }
            i += 1;
            line += 1;
            column = 1;
            continue;
        }
        if c.is_whitespace() {
            i += 1;
            column += 1;
            continue;
        }
        if c == '#' {
            while i < chars.len() && chars[i].1 != '\n' {
                i += 1;
                column += 1;
            }
            continue;
        }
        if ident_start(c) {
            let mut name = String::new();
            let mut k = i;
            while k < chars.len() && ident_continue(chars[k].1) {
                match greek(chars[k].1) {
                    Some(spelled) => name.push_str(spelled),
                    None => name.push(chars[k].1),
                }
                k += 1;
            }
            let len = k - i;
            push(Tok::Ident(name), len, &mut tokens);
            i = k;
            column += len;
            continue;
        }
        if c.is_ascii_digit() || (c == '.' && peek.is_some_and(|p| p.is_ascii_digit())) {
            let mut k = i;
            let digits = |k: &mut usize| {
                while *k < chars.len() && chars[*k].1.is_ascii_digit() {
                    *k += 1;
                }
            };
            digits(&mut k);
            if k < chars.len() && chars[k].1 == '.' {
                k += 1;
                digits(&mut k);
            }
            if k < chars.len() && (chars[k].1 == 'e' || chars[k].1 == 'E') {
                let mut m = k + 1;
                if m < chars.len() && (chars[m].1 == '+' || chars[m].1 == '-') {
                    m += 1;
                }
                if m < chars.len() && chars[m].1.is_ascii_digit() {
                    k = m;
                    digits(&mut k);
                }
            }
            let literal = &text[start..byte_at(k)];
            let value: f64 = literal
                .parse()
                .map_err(|_| error(pos, format!("bad number {literal:?}")))?;
            if !value.is_finite() {
                return Err(error(pos, format!("number {literal:?} is not finite")));
            }
            let len = k - i;
            push(Tok::Num(value), len, &mut tokens);
            i = k;
            column += len;
            continue;
        }
        let two: Option<&'static str> = match (c, peek) {
            ('=', Some('=')) => Some("=="),
            ('<', Some('=')) => Some("<="),
            ('>', Some('=')) => Some(">="),
            ('|', Some('|')) => Some("||"),
            _ => None,
        };
        if let Some(sym) = two {
            push(Tok::Sym(sym), 2, &mut tokens);
            i += 2;
            column += 2;
            continue;
        }
        let one: &'static str = match c {
            '+' => "+",
            '-' => "-",
            '*' => "*",
            '/' => "/",
            '^' => "^",
            '\'' => "'",
            '(' => "(",
            ')' => ")",
            '[' => "[",
            ']' => "]",
            ',' => ",",
            ';' => ";",
            ':' => ":",
            '=' => "=",
            '<' | '>' => {
                return Err(error(
                    pos,
                    format!("strict inequality '{c}' is not supported: use '{c}='"),
                ));
            }
            _ => return Err(error(pos, format!("unexpected character {c:?}"))),
        };
        match one {
            "(" | "[" => depth += 1,
            ")" | "]" => depth = depth.saturating_sub(1),
            _ => {}
        }
        push(Tok::Sym(one), 1, &mut tokens);
        i += 1;
        column += 1;
    }
    tokens.push(Token {
        tok: Tok::Eof,
        pos: Pos { line, column },
        start: text.len(),
        end: text.len(),
    });
    Ok(tokens)
}
