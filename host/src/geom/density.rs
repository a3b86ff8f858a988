//! Densities for weighted CVTs: a value `ρ > 0` per mesh vertex, linear
//! inside each tet (paper Eq. 3), given by an expression in `x`, `y`, `z`
//! (world coordinates) such as `1+10*x` or `exp(-8*((x-0.5)^2+y^2))`.

use crate::error::{Error, Result};
use crate::geom::mesh::TetMesh;

/// A parsed density expression.
#[derive(Clone, Debug)]
pub struct Expr(Node);

#[derive(Clone, Debug)]
enum Node {
    Num(f64),
    Var(usize),
    Neg(Box<Node>),
    Bin(char, Box<Node>, Box<Node>),
    Call(fn(f64) -> f64, Box<Node>),
}

impl Expr {
    /// Parses `text`: numbers, `x y z`, `+ - * / ^`, parentheses and the
    /// functions `exp sqrt abs sin cos`.
    pub fn parse(text: &str) -> Result<Self> {
        let mut p = Parser { text, pos: 0 };
        let node = p.sum()?;
        p.skip_space();
        if p.pos < text.len() {
            return Err(p.error("an operator or the end"));
        }
        Ok(Self(node))
    }

    /// The value at `p`.
    pub fn eval(&self, p: [f64; 3]) -> f64 {
        fn go(n: &Node, p: [f64; 3]) -> f64 {
            match n {
                Node::Num(v) => *v,
                Node::Var(i) => p[*i],
                Node::Neg(a) => -go(a, p),
                Node::Call(f, a) => f(go(a, p)),
                Node::Bin(op, a, b) => {
                    let (a, b) = (go(a, p), go(b, p));
                    match op {
                        '+' => a + b,
                        '-' => a - b,
                        '*' => a * b,
                        '/' => a / b,
                        _ => a.powf(b),
                    }
                }
            }
        }
        go(&self.0, p)
    }

    /// The density at every vertex of `mesh`; every value must be finite
    /// and positive.
    pub fn at_vertices(&self, mesh: &TetMesh, text: &str) -> Result<Vec<f64>> {
        mesh.vertices
            .iter()
            .enumerate()
            .map(|(i, v)| {
                let rho = self.eval(v.map(f64::from));
                if rho.is_finite() && rho > 0.0 && (rho as f32) > 0.0 {
                    Ok(rho)
                } else {
                    Err(Error::InvalidInput(format!(
                        "density \"{text}\" is {rho} at vertex {i} {v:?}; it must be finite and positive"
                    )))
                }
            })
            .collect()
    }
}

struct Parser<'a> {
    text: &'a str,
    pos: usize,
}

impl Parser<'_> {
    fn error(&self, expected: &str) -> Error {
        let found = self.text[self.pos..].chars().next().map_or("the end".to_string(), |c| format!("'{c}'"));
        Error::InvalidInput(format!(
            "density \"{}\": expected {expected} at character {}, found {found}",
            self.text,
            self.pos + 1
        ))
    }

    fn skip_space(&mut self) {
        while self.text[self.pos..].starts_with(char::is_whitespace) {
            self.pos += self.text[self.pos..].chars().next().map_or(1, char::len_utf8);
        }
    }

    fn eat(&mut self, c: char) -> bool {
        self.skip_space();
        if self.text[self.pos..].starts_with(c) {
            self.pos += c.len_utf8();
            true
        } else {
            false
        }
    }

    fn sum(&mut self) -> Result<Node> {
        let mut a = self.product()?;
        loop {
            if self.eat('+') {
                a = Node::Bin('+', Box::new(a), Box::new(self.product()?));
            } else if self.eat('-') {
                a = Node::Bin('-', Box::new(a), Box::new(self.product()?));
            } else {
                return Ok(a);
            }
        }
    }

    fn product(&mut self) -> Result<Node> {
        let mut a = self.unary()?;
        loop {
            if self.eat('*') {
                a = Node::Bin('*', Box::new(a), Box::new(self.unary()?));
            } else if self.eat('/') {
                a = Node::Bin('/', Box::new(a), Box::new(self.unary()?));
            } else {
                return Ok(a);
            }
        }
    }

    /// A sign binds looser than `^`: `-x^2 = -(x^2)`, `2^-1 = 0.5`.
    fn unary(&mut self) -> Result<Node> {
        if self.eat('-') {
            return Ok(Node::Neg(Box::new(self.unary()?)));
        }
        if self.eat('+') {
            return self.unary();
        }
        self.power()
    }

    fn power(&mut self) -> Result<Node> {
        let base = self.atom()?;
        if self.eat('^') {
            // Right-associative: 2^3^2 = 2^(3^2).
            return Ok(Node::Bin('^', Box::new(base), Box::new(self.unary()?)));
        }
        Ok(base)
    }

    fn atom(&mut self) -> Result<Node> {
        if self.eat('(') {
            let inner = self.sum()?;
            if !self.eat(')') {
                return Err(self.error("')'"));
            }
            return Ok(inner);
        }
        self.skip_space();
        let rest = &self.text[self.pos..];
        let number_len = rest
            .char_indices()
            .take_while(|&(i, c)| {
                c.is_ascii_digit()
                    || c == '.'
                    || ((c == 'e' || c == 'E') && i > 0)
                    || ((c == '-' || c == '+') && i > 0 && matches!(rest.as_bytes()[i - 1], b'e' | b'E'))
            })
            .count();
        if number_len > 0 {
            let token = &rest[..number_len];
            let value = token.parse::<f64>().map_err(|_| self.error("a number"))?;
            self.pos += number_len;
            return Ok(Node::Num(value));
        }
        let word_len = rest.chars().take_while(|c| c.is_ascii_alphabetic()).count();
        let word = &rest[..word_len];
        let function: Option<fn(f64) -> f64> = match word {
            "exp" => Some(f64::exp),
            "sqrt" => Some(f64::sqrt),
            "abs" => Some(f64::abs),
            "sin" => Some(f64::sin),
            "cos" => Some(f64::cos),
            _ => None,
        };
        match (word, function) {
            ("x", _) | ("y", _) | ("z", _) => {
                self.pos += 1;
                Ok(Node::Var((word.as_bytes()[0] - b'x') as usize))
            }
            (_, Some(f)) => {
                self.pos += word_len;
                if !self.eat('(') {
                    return Err(self.error("'(' after the function name"));
                }
                let arg = self.sum()?;
                if !self.eat(')') {
                    return Err(self.error("')'"));
                }
                Ok(Node::Call(f, Box::new(arg)))
            }
            _ => Err(self.error("a number, x, y, z, a function (exp sqrt abs sin cos) or '('")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn expressions_evaluate() {
        let at = |t: &str, p: [f64; 3]| Expr::parse(t).unwrap().eval(p);
        assert_eq!(at("1+10*x", [0.5, 0.0, 0.0]), 6.0);
        assert_eq!(at("2^3^2", [0.0; 3]), 512.0);
        assert_eq!(at("-x^2", [3.0, 0.0, 0.0]), -9.0);
        assert_eq!(at("2^-1", [0.0; 3]), 0.5);
        assert_eq!(at(" (x + y) * z / 2 ", [1.0, 2.0, 4.0]), 6.0);
        assert_eq!(at("1.5e1 - 2E-1", [0.0; 3]), 14.8);
        assert!((at("exp(-8*((x-0.5)^2+y^2))", [0.5, 0.0, 0.0]) - 1.0).abs() < 1e-15);
        assert_eq!(at("abs(sqrt(4)-3)", [0.0; 3]), 1.0);
    }

    #[test]
    fn bad_expressions_say_where() {
        for (text, needle) in [
            ("1+", "expected a number, x, y, z"),
            ("(x", "expected ')'"),
            ("x y", "expected an operator or the end at character 3"),
            ("w", "found 'w'"),
            ("exp x", "'(' after the function name"),
            ("1..2", "expected a number"),
        ] {
            let e = Expr::parse(text).unwrap_err().to_string();
            assert!(e.contains(needle), "{text}: {e}");
        }
    }

    #[test]
    fn non_positive_densities_are_refused() {
        let mesh = TetMesh::cube(1);
        let e = Expr::parse("x - 0.5").unwrap().at_vertices(&mesh, "x - 0.5").unwrap_err().to_string();
        assert!(e.contains("must be finite and positive"), "{e}");
        assert_eq!(Expr::parse("1+x").unwrap().at_vertices(&mesh, "1+x").unwrap().len(), mesh.vertices.len());
    }
}
