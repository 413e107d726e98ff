//! A small arithmetic expression language for measurement models in budget files.
//!
//! Written here rather than using `evalexpr` because a Monte Carlo run evaluates the model a
//! million times: expressions are compiled once to a tree over variable *indices* and evaluated
//! on a slice of `f64`, with IEEE float semantics throughout (evalexpr distinguishes integer and
//! float literals, so `1/2` would be 0 there).
//!
//! Grammar: `+ - * / ^` (power is right-associative and binds tighter than unary minus, so
//! `-x^2 = -(x^2)`), parentheses, numbers like `1.5e-3`, the constant `pi`, and the functions
//! `sin cos tan asin acos atan atan2 sinh cosh tanh sqrt exp ln log10 abs pow min max`.
//!
//! Limits: at most [`MAX_CHARS`] characters and a tree at most [`MAX_DEPTH`] levels deep
//! (nesting and the operands of one `+ - * /` chain both count); past them the expression is
//! refused with the column, instead of overflowing the stack in evaluation.

/// The deepest an expression's tree may be: nested parentheses, function calls, powers, signs
/// and the operands of one chain of `+ - * /` all count. Evaluating (and dropping) a tree
/// recurses once per level, so a 30 000-deep nesting or a 300 000-term sum overflowed the
/// stack; a budget this deep is better written as intermediate quantities.
pub const MAX_DEPTH: usize = 256;

/// The longest expression accepted, characters.
pub const MAX_CHARS: usize = 100_000;

/// Why an expression could not be compiled.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("at column {column}: {message}")]
pub struct ExprError {
    /// 1-based character column in the expression.
    pub column: usize,
    pub message: String,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Func {
    Sin,
    Cos,
    Tan,
    Asin,
    Acos,
    Atan,
    Atan2,
    Sinh,
    Cosh,
    Tanh,
    Sqrt,
    Exp,
    Ln,
    Log10,
    Abs,
    Pow,
    Min,
    Max,
}

impl Func {
    fn lookup(name: &str) -> Option<(Func, usize)> {
        Some(match name {
            "sin" => (Func::Sin, 1),
            "cos" => (Func::Cos, 1),
            "tan" => (Func::Tan, 1),
            "asin" => (Func::Asin, 1),
            "acos" => (Func::Acos, 1),
            "atan" => (Func::Atan, 1),
            "atan2" => (Func::Atan2, 2),
            "sinh" => (Func::Sinh, 1),
            "cosh" => (Func::Cosh, 1),
            "tanh" => (Func::Tanh, 1),
            "sqrt" => (Func::Sqrt, 1),
            "exp" => (Func::Exp, 1),
            "ln" => (Func::Ln, 1),
            "log10" => (Func::Log10, 1),
            "abs" => (Func::Abs, 1),
            "pow" => (Func::Pow, 2),
            "min" => (Func::Min, 2),
            "max" => (Func::Max, 2),
            _ => return None,
        })
    }
}

/// A compiled expression.
#[derive(Debug, Clone, PartialEq)]
pub enum Expr {
    Num(f64),
    Var(usize),
    Neg(Box<Expr>),
    Add(Box<Expr>, Box<Expr>),
    Sub(Box<Expr>, Box<Expr>),
    Mul(Box<Expr>, Box<Expr>),
    Div(Box<Expr>, Box<Expr>),
    Pow(Box<Expr>, Box<Expr>),
    Call1(FuncId, Box<Expr>),
    Call2(FuncId, Box<Expr>, Box<Expr>),
}

/// Opaque function identifier inside [`Expr`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FuncId(Func);

impl Expr {
    /// Compiles `src`; `resolve` maps a variable name to its index in the value slice.
    pub fn compile(src: &str, resolve: &dyn Fn(&str) -> Option<usize>) -> Result<Expr, ExprError> {
        if src.chars().count() > MAX_CHARS {
            return Err(ExprError {
                column: MAX_CHARS + 1,
                message: format!(
                    "the expression is longer than {MAX_CHARS} characters; split it into \
                     intermediate quantities"
                ),
            });
        }
        let chars: Vec<char> = src.chars().collect();
        let mut p = Parser {
            s: &chars,
            i: 0,
            nesting: 0,
            resolve,
        };
        let (e, _) = p.expr()?;
        p.skip_ws();
        if p.i < chars.len() {
            return Err(p.err(format!("unexpected `{}`", chars[p.i])));
        }
        Ok(e)
    }

    /// Evaluates with variable values `v`.
    pub fn eval(&self, v: &[f64]) -> f64 {
        match self {
            Expr::Num(x) => *x,
            Expr::Var(i) => v[*i],
            Expr::Neg(a) => -a.eval(v),
            Expr::Add(a, b) => a.eval(v) + b.eval(v),
            Expr::Sub(a, b) => a.eval(v) - b.eval(v),
            Expr::Mul(a, b) => a.eval(v) * b.eval(v),
            Expr::Div(a, b) => a.eval(v) / b.eval(v),
            Expr::Pow(a, b) => pow(a.eval(v), b.eval(v)),
            Expr::Call1(FuncId(f), a) => {
                let x = a.eval(v);
                match f {
                    Func::Sin => x.sin(),
                    Func::Cos => x.cos(),
                    Func::Tan => x.tan(),
                    Func::Asin => x.asin(),
                    Func::Acos => x.acos(),
                    Func::Atan => x.atan(),
                    Func::Sinh => x.sinh(),
                    Func::Cosh => x.cosh(),
                    Func::Tanh => x.tanh(),
                    Func::Sqrt => x.sqrt(),
                    Func::Exp => x.exp(),
                    Func::Ln => x.ln(),
                    Func::Log10 => x.log10(),
                    Func::Abs => x.abs(),
                    Func::Atan2 | Func::Pow | Func::Min | Func::Max => f64::NAN,
                }
            }
            Expr::Call2(FuncId(f), a, b) => {
                let (x, y) = (a.eval(v), b.eval(v));
                match f {
                    Func::Atan2 => x.atan2(y),
                    Func::Pow => pow(x, y),
                    Func::Min => x.min(y),
                    Func::Max => x.max(y),
                    _ => f64::NAN,
                }
            }
        }
    }
}

fn pow(x: f64, y: f64) -> f64 {
    // Small integer powers are exact products (x^2 of a negative x must not go through ln).
    if y == 2.0 {
        x * x
    } else if y.fract() == 0.0 && y.abs() <= 16.0 {
        x.powi(y as i32)
    } else {
        x.powf(y)
    }
}

/// A parsed subtree and its depth (levels, a leaf is 1).
type Parsed = Result<(Expr, usize), ExprError>;

struct Parser<'a> {
    s: &'a [char],
    i: usize,
    /// How deep the parser has recursed (parentheses, calls, signs, exponents).
    nesting: usize,
    resolve: &'a dyn Fn(&str) -> Option<usize>,
}

impl Parser<'_> {
    fn err(&self, message: String) -> ExprError {
        ExprError {
            column: self.i + 1,
            message,
        }
    }

    fn skip_ws(&mut self) {
        while self.i < self.s.len() && self.s[self.i].is_whitespace() {
            self.i += 1;
        }
    }

    fn peek(&mut self) -> Option<char> {
        self.skip_ws();
        self.s.get(self.i).copied()
    }

    /// A node over subtrees of depth `d`: refused past [`MAX_DEPTH`].
    fn deeper(&self, e: Expr, d: usize) -> Parsed {
        if d >= MAX_DEPTH {
            return Err(self.too_deep());
        }
        Ok((e, d + 1))
    }

    fn too_deep(&self) -> ExprError {
        self.err(format!(
            "the expression is nested or chained deeper than {MAX_DEPTH} levels; split it into \
             intermediate quantities"
        ))
    }

    /// Runs `f` one recursion level deeper, refused past [`MAX_DEPTH`].
    fn nested(&mut self, f: impl FnOnce(&mut Self) -> Parsed) -> Parsed {
        if self.nesting >= MAX_DEPTH {
            return Err(self.too_deep());
        }
        self.nesting += 1;
        let r = f(self);
        self.nesting -= 1;
        r
    }

    fn expr(&mut self) -> Parsed {
        let (mut lhs, mut d) = self.term()?;
        while let Some(c) = self.peek() {
            let op: fn(Box<Expr>, Box<Expr>) -> Expr = match c {
                '+' => Expr::Add,
                '-' => Expr::Sub,
                _ => break,
            };
            self.i += 1;
            let (rhs, dr) = self.term()?;
            (lhs, d) = self.deeper(op(Box::new(lhs), Box::new(rhs)), d.max(dr))?;
        }
        Ok((lhs, d))
    }

    fn term(&mut self) -> Parsed {
        let (mut lhs, mut d) = self.unary()?;
        while let Some(c) = self.peek() {
            let op: fn(Box<Expr>, Box<Expr>) -> Expr = match c {
                '*' => Expr::Mul,
                '/' => Expr::Div,
                _ => break,
            };
            self.i += 1;
            let (rhs, dr) = self.unary()?;
            (lhs, d) = self.deeper(op(Box::new(lhs), Box::new(rhs)), d.max(dr))?;
        }
        Ok((lhs, d))
    }

    fn unary(&mut self) -> Parsed {
        match self.peek() {
            Some('-') => {
                self.i += 1;
                let (a, d) = self.nested(Self::unary)?;
                self.deeper(Expr::Neg(Box::new(a)), d)
            }
            Some('+') => {
                self.i += 1;
                self.nested(Self::unary)
            }
            _ => self.power(),
        }
    }

    fn power(&mut self) -> Parsed {
        let (base, db) = self.atom()?;
        if self.peek() == Some('^') {
            self.i += 1;
            let (exp, de) = self.nested(Self::unary)?;
            return self.deeper(Expr::Pow(Box::new(base), Box::new(exp)), db.max(de));
        }
        Ok((base, db))
    }

    fn atom(&mut self) -> Parsed {
        match self.peek() {
            None => Err(self.err("expression ends where a value was expected".into())),
            Some('(') => {
                self.i += 1;
                let e = self.nested(Self::expr)?;
                if self.peek() != Some(')') {
                    return Err(self.err("missing `)`".into()));
                }
                self.i += 1;
                Ok(e)
            }
            Some(c) if c.is_ascii_digit() || c == '.' => Ok((self.number()?, 1)),
            Some(c) if c.is_alphabetic() || c == '_' => self.name(),
            Some(c) => Err(self.err(format!("unexpected `{c}` where a value was expected"))),
        }
    }

    fn number(&mut self) -> Result<Expr, ExprError> {
        let start = self.i;
        let s = self.s;
        while self.i < s.len() && (s[self.i].is_ascii_digit() || s[self.i] == '.') {
            self.i += 1;
        }
        if self.i < s.len() && (s[self.i] == 'e' || s[self.i] == 'E') {
            let save = self.i;
            self.i += 1;
            if self.i < s.len() && (s[self.i] == '+' || s[self.i] == '-') {
                self.i += 1;
            }
            if self.i < s.len() && s[self.i].is_ascii_digit() {
                while self.i < s.len() && s[self.i].is_ascii_digit() {
                    self.i += 1;
                }
            } else {
                self.i = save;
            }
        }
        let text: String = s[start..self.i].iter().collect();
        text.parse::<f64>().map(Expr::Num).map_err(|_| ExprError {
            column: start + 1,
            message: format!("`{text}` is not a number"),
        })
    }

    fn name(&mut self) -> Parsed {
        let start = self.i;
        let s = self.s;
        while self.i < s.len() && (s[self.i].is_alphanumeric() || s[self.i] == '_') {
            self.i += 1;
        }
        let name: String = s[start..self.i].iter().collect();
        if self.peek() == Some('(') {
            let Some((f, arity)) = Func::lookup(&name) else {
                return Err(ExprError {
                    column: start + 1,
                    message: format!("unknown function `{name}`"),
                });
            };
            self.i += 1;
            let mut args = vec![self.nested(Self::expr)?];
            while self.peek() == Some(',') {
                self.i += 1;
                args.push(self.nested(Self::expr)?);
            }
            if self.peek() != Some(')') {
                return Err(self.err(format!("missing `)` after the arguments of `{name}`")));
            }
            self.i += 1;
            if args.len() != arity {
                return Err(ExprError {
                    column: start + 1,
                    message: format!("`{name}` takes {arity} argument(s), got {}", args.len()),
                });
            }
            let d = args.iter().map(|a| a.1).max().unwrap_or(0);
            let mut it = args.into_iter().map(|a| Box::new(a.0));
            let call = match (it.next(), it.next()) {
                (Some(a), None) => Expr::Call1(FuncId(f), a),
                (Some(a), Some(b)) => Expr::Call2(FuncId(f), a, b),
                _ => unreachable!("arity checked above"),
            };
            return self.deeper(call, d);
        }
        if let Some(i) = (self.resolve)(&name) {
            return Ok((Expr::Var(i), 1));
        }
        if name == "pi" {
            return Ok((Expr::Num(std::f64::consts::PI), 1));
        }
        Err(ExprError {
            column: start + 1,
            message: format!("unknown name `{name}` (not an input or an intermediate quantity)"),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ev(src: &str, vars: &[(&str, f64)]) -> f64 {
        let names: Vec<&str> = vars.iter().map(|v| v.0).collect();
        let vals: Vec<f64> = vars.iter().map(|v| v.1).collect();
        let e = Expr::compile(src, &|n| names.iter().position(|m| *m == n)).unwrap();
        e.eval(&vals)
    }

    #[test]
    fn precedence_and_associativity() {
        assert_eq!(ev("1 + 2 * 3", &[]), 7.0);
        assert_eq!(ev("(1 + 2) * 3", &[]), 9.0);
        assert_eq!(ev("2 ^ 3 ^ 2", &[]), 512.0);
        assert_eq!(ev("-2 ^ 2", &[]), -4.0);
        assert_eq!(ev("2 ^ -1", &[]), 0.5);
        assert_eq!(ev("1 / 2", &[]), 0.5);
        assert_eq!(ev("10 - 4 - 3", &[]), 3.0);
        assert_eq!(ev("1.5e-3 * 2E3", &[]), 3.0);
        assert_eq!(ev("x * y - x", &[("x", 3.0), ("y", 4.0)]), 9.0);
        assert!((ev("atan2(1, 1) * 4 - pi", &[])).abs() < 1e-15);
        assert_eq!(ev("max(min(3, x), 1)", &[("x", 2.0)]), 2.0);
        assert_eq!(ev("(-3)^2", &[]), 9.0);
    }

    #[test]
    fn errors_name_the_column() {
        let r = |s: &str| Expr::compile(s, &|_| None).unwrap_err();
        assert_eq!(r("1 + ").column, 5);
        assert!(r("foo + 1").message.contains("unknown name `foo`"));
        assert!(r("sin(1, 2)").message.contains("takes 1"));
        assert!(r("(1 + 2").message.contains("missing `)`"));
        assert!(r("1 $ 2").message.contains("unexpected `$`"));
        assert!(r("blah(2)").message.contains("unknown function"));
    }

    /// 30 000 nested parentheses, a 300 000-term sum, a long chain of signs or powers: a
    /// clear error at the column where the limit is passed, not a stack overflow.
    #[test]
    fn deep_or_long_expressions_are_refused_not_overflowed() {
        let r = |s: &str| Expr::compile(s, &|_| None).unwrap_err();
        let nested = format!("{}1{}", "(".repeat(30_000), ")".repeat(30_000));
        assert!(
            r(&nested).message.contains("deeper than 256"),
            "{}",
            r(&nested)
        );
        let sum = vec!["1"; 300_000].join("+");
        assert!(r(&sum).message.contains("longer than"), "{}", r(&sum));
        let sum = vec!["1"; 40_000].join("+");
        let e = r(&sum);
        assert!(
            e.message.contains("deeper than 256") && e.column < 1_000,
            "{e}"
        );
        assert!(r(&"-".repeat(50_000)).message.contains("deeper"));
        let pw = vec!["2"; 50_000].join("^");
        assert!(r(&pw).message.contains("deeper"));
        let calls = format!("{}1{}", "sin(".repeat(10_000), ")".repeat(10_000));
        assert!(r(&calls).message.contains("deeper"));
        // At the limit it compiles and evaluates.
        assert_eq!(ev(&vec!["1"; 255].join("+"), &[]), 255.0);
        let ok = format!("{}1{}", "(".repeat(200), ")".repeat(200));
        assert_eq!(ev(&ok, &[]), 1.0);
    }
}
