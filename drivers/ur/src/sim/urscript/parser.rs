//! The parser: expressions by precedence, statements, and `if`/`while` blocks up to their `end`,
//! nesting bounded by [`MAX_BLOCK_DEPTH`] and [`MAX_EXPR_DEPTH`]; `sec` programs are checked too.

use super::ast::{err, CompileError, Expr, Program, Stmt};
use super::lexer::{lex, Tok};
use super::value::Val;
use super::{BUILTINS, MAX_BLOCK_DEPTH, MAX_EXPR_DEPTH};

struct ExprParser<'a> {
    t: &'a [Tok],
    i: usize,
    line: usize,
    depth: usize,
}

impl ExprParser<'_> {
    fn peek(&self) -> Option<&Tok> {
        self.t.get(self.i)
    }
    fn eat_op(&mut self, op: &str) -> bool {
        if matches!(self.peek(), Some(Tok::Op(o)) if *o == op) {
            self.i += 1;
            true
        } else {
            false
        }
    }
    fn eat_kw(&mut self, kw: &str) -> bool {
        if matches!(self.peek(), Some(Tok::Ident(o)) if o == kw) {
            self.i += 1;
            true
        } else {
            false
        }
    }
    fn expect_op(&mut self, op: &str) -> Result<(), CompileError> {
        if self.eat_op(op) {
            Ok(())
        } else {
            err(self.line, format!("expected `{op}`"))
        }
    }
    /// Runs `f` one nesting level deeper; every recursive path of the grammar goes through
    /// here (sub-expressions, unary minus/plus chains, `not` chains), so the depth is bounded.
    fn nested(
        &mut self,
        f: impl FnOnce(&mut Self) -> Result<Expr, CompileError>,
    ) -> Result<Expr, CompileError> {
        self.depth += 1;
        if self.depth > MAX_EXPR_DEPTH {
            return err(
                self.line,
                format!("expression nested too deeply (more than {MAX_EXPR_DEPTH} levels)"),
            );
        }
        let r = f(self);
        self.depth -= 1;
        r
    }
    fn expr(&mut self) -> Result<Expr, CompileError> {
        self.nested(Self::or)
    }
    fn or(&mut self) -> Result<Expr, CompileError> {
        let mut l = self.and()?;
        while self.eat_kw("or") {
            l = Expr::Binary("or", Box::new(l), Box::new(self.and()?));
        }
        Ok(l)
    }
    fn and(&mut self) -> Result<Expr, CompileError> {
        let mut l = self.not()?;
        while self.eat_kw("and") {
            l = Expr::Binary("and", Box::new(l), Box::new(self.not()?));
        }
        Ok(l)
    }
    fn not(&mut self) -> Result<Expr, CompileError> {
        if self.eat_kw("not") {
            return Ok(Expr::Unary("not", Box::new(self.nested(Self::not)?)));
        }
        self.cmp()
    }
    fn cmp(&mut self) -> Result<Expr, CompileError> {
        let l = self.sum()?;
        for op in ["==", "!=", "<=", ">=", "<", ">"] {
            if self.eat_op(op) {
                return Ok(Expr::Binary(op, Box::new(l), Box::new(self.sum()?)));
            }
        }
        Ok(l)
    }
    fn sum(&mut self) -> Result<Expr, CompileError> {
        let mut l = self.product()?;
        loop {
            let op = if self.eat_op("+") {
                "+"
            } else if self.eat_op("-") {
                "-"
            } else {
                return Ok(l);
            };
            l = Expr::Binary(op, Box::new(l), Box::new(self.product()?));
        }
    }
    fn product(&mut self) -> Result<Expr, CompileError> {
        let mut l = self.unary()?;
        loop {
            let op = if self.eat_op("*") {
                "*"
            } else if self.eat_op("/") {
                "/"
            } else if self.eat_op("%") {
                "%"
            } else {
                return Ok(l);
            };
            l = Expr::Binary(op, Box::new(l), Box::new(self.unary()?));
        }
    }
    fn unary(&mut self) -> Result<Expr, CompileError> {
        if self.eat_op("-") {
            return Ok(Expr::Unary("-", Box::new(self.nested(Self::unary)?)));
        }
        if self.eat_op("+") {
            return self.nested(Self::unary);
        }
        let mut e = self.atom()?;
        while self.eat_op("[") {
            let idx = self.expr()?;
            self.expect_op("]")?;
            e = Expr::Index(Box::new(e), Box::new(idx));
        }
        Ok(e)
    }
    fn list(&mut self) -> Result<Vec<Expr>, CompileError> {
        let mut v = Vec::new();
        if self.eat_op("]") {
            return Ok(v);
        }
        loop {
            v.push(self.expr()?);
            if self.eat_op("]") {
                return Ok(v);
            }
            self.expect_op(",")?;
        }
    }
    fn atom(&mut self) -> Result<Expr, CompileError> {
        let Some(t) = self.peek().cloned() else {
            return err(self.line, "expression expected");
        };
        self.i += 1;
        match t {
            Tok::Num(n) => Ok(Expr::Lit(Val::Num(n))),
            Tok::Str(s) => Ok(Expr::Lit(Val::Str(s))),
            Tok::Op("(") => {
                let e = self.expr()?;
                self.expect_op(")")?;
                Ok(e)
            }
            Tok::Op("[") => Ok(Expr::List(self.list()?)),
            Tok::Ident(id) => match id.as_str() {
                "True" => Ok(Expr::Lit(Val::Bool(true))),
                "False" => Ok(Expr::Lit(Val::Bool(false))),
                "p" if self.eat_op("[") => Ok(Expr::Pose(self.list()?)),
                _ if self.eat_op("(") => {
                    let (mut args, mut named) = (Vec::new(), Vec::new());
                    if !self.eat_op(")") {
                        loop {
                            if let (Some(Tok::Ident(n)), Some(Tok::Op("="))) =
                                (self.t.get(self.i), self.t.get(self.i + 1))
                            {
                                let n = n.clone();
                                self.i += 2;
                                named.push((n, self.expr()?));
                            } else {
                                args.push(self.expr()?);
                            }
                            if self.eat_op(")") {
                                break;
                            }
                            self.expect_op(",")?;
                        }
                    }
                    if !BUILTINS.iter().any(|(b, _)| *b == id) {
                        return err(
                            self.line,
                            format!("name '{id}' is not defined (not supported by the simulator)"),
                        );
                    }
                    Ok(Expr::Call {
                        name: id,
                        args,
                        named,
                    })
                }
                _ => Ok(Expr::Var(id)),
            },
            Tok::Op(o) => err(self.line, format!("unexpected `{o}`")),
        }
    }
}

fn parse_expr(line: usize, toks: &[Tok]) -> Result<Expr, CompileError> {
    let mut p = ExprParser {
        t: toks,
        i: 0,
        line,
        depth: 0,
    };
    let e = p.expr()?;
    if p.i != toks.len() {
        return err(line, "unexpected text after the expression");
    }
    Ok(e)
}

/// Parse a whole program text (`def name():` … `end`, or a single statement line).
pub(crate) fn parse_program(text: &str) -> Result<Program, CompileError> {
    let lines: Vec<(usize, &str)> = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
        .collect();
    let Some(&(first_no, first)) = lines.first() else {
        return err(1, "empty program");
    };
    let header = first
        .strip_prefix("def ")
        .map(|r| (r, false))
        .or_else(|| first.strip_prefix("sec ").map(|r| (r, true)));
    let (name, secondary, body_lines) = match header {
        Some((rest, secondary)) => {
            let name = rest.trim().strip_suffix("():").map(str::trim).filter(|n| {
                n.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') && !n.is_empty()
            });
            let Some(name) = name else {
                return err(first_no, "expected `def name():`");
            };
            match lines.last() {
                Some((_, "end")) if lines.len() >= 2 => {}
                _ => return err(first_no, format!("program `{name}` has no closing `end`")),
            }
            (name.to_string(), secondary, &lines[1..lines.len() - 1])
        }
        None => ("unnamed".to_string(), false, &lines[..]),
    };
    let mut i = 0;
    let body = parse_block(body_lines, &mut i, &[], 0)?;
    if i != body_lines.len() {
        return err(body_lines[i].0, format!("unexpected `{}`", body_lines[i].1));
    }
    let prog = Program {
        name,
        secondary,
        body,
    };
    if prog.secondary {
        check_secondary(&prog.body)?;
    }
    Ok(prog)
}

fn check_secondary(body: &[Stmt]) -> Result<(), CompileError> {
    fn walk(e: &Expr, line: usize) -> Result<(), CompileError> {
        match e {
            Expr::Call { name, args, named } => {
                if BUILTINS.iter().any(|(b, t)| b == name && *t) {
                    return err(line, format!("`{name}` takes physical time and is not allowed in a secondary (sec) program"));
                }
                args.iter().try_for_each(|a| walk(a, line))?;
                named.iter().try_for_each(|(_, a)| walk(a, line))
            }
            Expr::List(v) | Expr::Pose(v) => v.iter().try_for_each(|a| walk(a, line)),
            Expr::Index(a, b) | Expr::Binary(_, a, b) => walk(a, line).and_then(|_| walk(b, line)),
            Expr::Unary(_, a) => walk(a, line),
            Expr::Lit(_) | Expr::Var(_) => Ok(()),
        }
    }
    for s in body {
        match s {
            Stmt::Assign { line, value, .. } => walk(value, *line)?,
            Stmt::Expr { line, expr } => walk(expr, *line)?,
            Stmt::If {
                line,
                arms,
                otherwise,
            } => {
                for (c, b) in arms {
                    walk(c, *line)?;
                    check_secondary(b)?;
                }
                check_secondary(otherwise)?;
            }
            Stmt::While { line, .. } => {
                return err(*line, "loops are not allowed in a secondary (sec) program")
            }
            _ => {}
        }
    }
    Ok(())
}

fn parse_block(
    lines: &[(usize, &str)],
    i: &mut usize,
    stops: &[&str],
    depth: usize,
) -> Result<Vec<Stmt>, CompileError> {
    if depth > MAX_BLOCK_DEPTH {
        let line = lines.get(i.saturating_sub(1)).map_or(1, |l| l.0);
        return err(
            line,
            format!("blocks nested too deeply (more than {MAX_BLOCK_DEPTH} levels)"),
        );
    }
    let mut out = Vec::new();
    while *i < lines.len() {
        let (no, l) = lines[*i];
        let word = l
            .split(|c: char| !c.is_ascii_alphanumeric() && c != '_')
            .next()
            .unwrap_or("");
        if stops.contains(&word) {
            return Ok(out);
        }
        *i += 1;
        let toks = lex(no, l)?;
        let cond_of = |toks: &[Tok]| -> Result<Expr, CompileError> {
            match toks.last() {
                Some(Tok::Op(":")) => parse_expr(no, &toks[1..toks.len() - 1]),
                _ => err(no, "expected `:` at the end of the line"),
            }
        };
        match word {
            "if" => {
                let mut arms = vec![(
                    cond_of(&toks)?,
                    parse_block(lines, i, &["elif", "else", "end"], depth + 1)?,
                )];
                let mut otherwise = Vec::new();
                loop {
                    let Some(&(no2, l2)) = lines.get(*i) else {
                        return err(no, "`if` without `end`");
                    };
                    *i += 1;
                    let t2 = lex(no2, l2)?;
                    if l2 == "end" {
                        break;
                    } else if l2.starts_with("elif") {
                        let c = match t2.last() {
                            Some(Tok::Op(":")) => parse_expr(no2, &t2[1..t2.len() - 1])?,
                            _ => return err(no2, "expected `:`"),
                        };
                        arms.push((
                            c,
                            parse_block(lines, i, &["elif", "else", "end"], depth + 1)?,
                        ));
                    } else {
                        otherwise = parse_block(lines, i, &["end"], depth + 1)?;
                        if lines.get(*i).map(|l| l.1) != Some("end") {
                            return err(no, "`if` without `end`");
                        }
                        *i += 1;
                        break;
                    }
                }
                out.push(Stmt::If {
                    line: no,
                    arms,
                    otherwise,
                });
            }
            "while" => {
                let cond = cond_of(&toks)?;
                let body = parse_block(lines, i, &["end"], depth + 1)?;
                if lines.get(*i).map(|l| l.1) != Some("end") {
                    return err(no, "`while` without `end`");
                }
                *i += 1;
                out.push(Stmt::While {
                    line: no,
                    cond,
                    body,
                });
            }
            "break" => out.push(Stmt::Break),
            "continue" => out.push(Stmt::Continue),
            "halt" => out.push(Stmt::Halt),
            "end" | "elif" | "else" => return err(no, format!("unexpected `{word}`")),
            "def" | "sec" | "thread" | "run" | "join" | "kill" | "return" | "for" => {
                return err(no, format!("`{word}` is not supported by the simulator"));
            }
            _ => {
                let toks: &[Tok] = if matches!(toks.first(), Some(Tok::Ident(k)) if k == "local" || k == "global")
                {
                    &toks[1..]
                } else {
                    &toks
                };
                if let (Some(Tok::Ident(name)), Some(Tok::Op("="))) = (toks.first(), toks.get(1)) {
                    out.push(Stmt::Assign {
                        line: no,
                        name: name.clone(),
                        value: parse_expr(no, &toks[2..])?,
                    });
                } else {
                    out.push(Stmt::Expr {
                        line: no,
                        expr: parse_expr(no, toks)?,
                    });
                }
            }
        }
    }
    Ok(out)
}
