//! The URScript subset the simulator runs: `def`/`sec` programs with assignments, `if`/`elif`/
//! `else`, `while`, `break`/`continue`/`halt`, arithmetic, comparisons, lists and poses, and
//! the built-ins in [`BUILTINS`]. Anything else is a compile error reported to the client.

use std::collections::HashMap;

/// Most nested blocks (`if`/`while`) a program may have; deeper is a compile error, so no
/// program can exhaust the parser's or the interpreter's stack.
pub(crate) const MAX_BLOCK_DEPTH: usize = 64;
/// Most nested expression levels (parentheses, unary operators, `not`, calls, lists, indices).
pub(crate) const MAX_EXPR_DEPTH: usize = 64;

/// Built-ins the simulator knows, with whether they take physical time (not allowed in `sec`).
pub(crate) const BUILTINS: &[(&str, bool)] = &[
    ("movej", true),
    ("movel", true),
    ("stopj", true),
    ("stopl", true),
    ("sleep", true),
    ("sync", true),
    ("set_tcp", false),
    ("textmsg", false),
    ("write_output_integer_register", false),
    ("write_output_float_register", false),
    ("write_output_boolean_register", false),
    ("read_input_integer_register", false),
    ("read_input_float_register", false),
    ("read_input_boolean_register", false),
    ("read_output_integer_register", false),
    ("read_output_float_register", false),
    ("read_output_boolean_register", false),
    ("get_actual_joint_positions", false),
    ("get_target_joint_positions", false),
    ("get_actual_tcp_pose", false),
    ("get_target_tcp_pose", false),
    ("get_tcp_offset", false),
    ("get_forward_kin", false),
    ("pose_trans", false),
    ("pose_inv", false),
    ("sin", false),
    ("cos", false),
    ("sqrt", false),
    ("norm", false),
    ("floor", false),
    ("to_str", false),
];

/// Most elements (counted through nested lists) and string bytes one value may hold, so a loop
/// such as `x = [x, x]` or `s = s + s` ends in a runtime error, not in exhausted memory.
pub(crate) const MAX_VALUE_SIZE: usize = 1 << 16;

/// A script value.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Val {
    Num(f64),
    Bool(bool),
    Str(String),
    List(Vec<Val>),
    Pose([f64; 6]),
    None,
}

impl Val {
    /// Elements, nested elements and string bytes; stops counting past [`MAX_VALUE_SIZE`].
    fn size(&self) -> usize {
        match self {
            Val::Str(s) => s.len(),
            Val::List(v) => {
                let mut n = v.len();
                for x in v {
                    if n > MAX_VALUE_SIZE {
                        break;
                    }
                    n += x.size();
                }
                n
            }
            _ => 1,
        }
    }

    /// Nesting depth of lists (a scalar is 0).
    fn depth(&self) -> usize {
        match self {
            Val::List(v) => 1 + v.iter().map(Val::depth).max().unwrap_or(0),
            _ => 0,
        }
    }

    /// `Err` when the value is larger or deeper than a program may build.
    fn bounded(self) -> Result<Self, String> {
        if self.size() > MAX_VALUE_SIZE {
            return Err(format!(
                "value too large (more than {MAX_VALUE_SIZE} elements or bytes)"
            ));
        }
        if self.depth() > MAX_EXPR_DEPTH {
            return Err(format!(
                "lists nested too deeply (more than {MAX_EXPR_DEPTH} levels)"
            ));
        }
        Ok(self)
    }
}

impl std::fmt::Display for Val {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let list = |f: &mut std::fmt::Formatter<'_>, v: &[f64]| {
            let s: Vec<String> = v.iter().map(|x| format!("{x}")).collect();
            write!(f, "[{}]", s.join(", "))
        };
        match self {
            Val::Num(n) => write!(f, "{n}"),
            Val::Bool(b) => write!(f, "{}", if *b { "True" } else { "False" }),
            Val::Str(s) => f.write_str(s),
            Val::List(v) => {
                let s: Vec<String> = v.iter().map(|x| x.to_string()).collect();
                write!(f, "[{}]", s.join(", "))
            }
            Val::Pose(p) => {
                f.write_str("p")?;
                list(f, p)
            }
            Val::None => f.write_str("None"),
        }
    }
}

/// Expression AST.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Expr {
    Lit(Val),
    Var(String),
    List(Vec<Expr>),
    Pose(Vec<Expr>),
    Index(Box<Expr>, Box<Expr>),
    Unary(&'static str, Box<Expr>),
    Binary(&'static str, Box<Expr>, Box<Expr>),
    Call {
        name: String,
        args: Vec<Expr>,
        named: Vec<(String, Expr)>,
    },
}

/// Statement AST; `line` is 1-based in the received program.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Stmt {
    Assign {
        line: usize,
        name: String,
        value: Expr,
    },
    Expr {
        line: usize,
        expr: Expr,
    },
    If {
        line: usize,
        arms: Vec<(Expr, Vec<Stmt>)>,
        otherwise: Vec<Stmt>,
    },
    While {
        line: usize,
        cond: Expr,
        body: Vec<Stmt>,
    },
    Break,
    Continue,
    Halt,
}

/// A parsed program.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Program {
    pub(crate) name: String,
    pub(crate) secondary: bool,
    pub(crate) body: Vec<Stmt>,
}

/// A compile error with its line.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct CompileError {
    pub(crate) line: usize,
    pub(crate) message: String,
}

fn err<T>(line: usize, message: impl Into<String>) -> Result<T, CompileError> {
    Err(CompileError {
        line,
        message: message.into(),
    })
}

#[derive(Debug, Clone, PartialEq)]
enum Tok {
    Num(f64),
    Ident(String),
    Str(String),
    Op(&'static str),
}

const OPS: &[&str] = &[
    "==", "!=", "<=", ">=", "+", "-", "*", "/", "%", "<", ">", "=", "(", ")", "[", "]", ",", ":",
];

fn lex(line_no: usize, s: &str) -> Result<Vec<Tok>, CompileError> {
    let b = s.as_bytes();
    let mut i = 0;
    let mut out = Vec::new();
    while i < b.len() {
        let c = b[i];
        if c.is_ascii_whitespace() {
            i += 1;
        } else if c == b'#' {
            break;
        } else if c.is_ascii_digit() || (c == b'.' && b.get(i + 1).is_some_and(u8::is_ascii_digit))
        {
            let start = i;
            while i < b.len() && (b[i].is_ascii_digit() || b[i] == b'.') {
                i += 1;
            }
            if i < b.len() && (b[i] == b'e' || b[i] == b'E') {
                i += 1;
                if i < b.len() && (b[i] == b'+' || b[i] == b'-') {
                    i += 1;
                }
                while i < b.len() && b[i].is_ascii_digit() {
                    i += 1;
                }
            }
            let t = &s[start..i];
            out.push(Tok::Num(
                t.parse()
                    .or_else(|_| err(line_no, format!("bad number `{t}`")))?,
            ));
        } else if c.is_ascii_alphabetic() || c == b'_' {
            let start = i;
            while i < b.len() && (b[i].is_ascii_alphanumeric() || b[i] == b'_') {
                i += 1;
            }
            out.push(Tok::Ident(s[start..i].to_string()));
        } else if c == b'"' || c == b'\'' {
            let start = i + 1;
            i += 1;
            while i < b.len() && b[i] != c {
                i += 1;
            }
            if i >= b.len() {
                return err(line_no, "unterminated string");
            }
            out.push(Tok::Str(s[start..i].to_string()));
            i += 1;
        } else if let Some(op) = OPS.iter().find(|op| s[i..].starts_with(**op)) {
            out.push(Tok::Op(op));
            i += op.len();
        } else {
            let c = (c as char).to_string();
            return err(
                line_no,
                format!("unexpected character `{}`", handeye_hal::limits::Quoted(&c)),
            );
        }
    }
    Ok(out)
}

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

/// What the interpreter asks of the controller.
pub(crate) trait Host {
    /// Call a built-in; errors are runtime exceptions.
    fn call(
        &mut self,
        name: &str,
        args: Vec<Val>,
        named: Vec<(String, Val)>,
    ) -> Result<Val, String>;
    /// Called once per statement; `Err` stops the program (stop request, step budget).
    fn tick(&mut self) -> Result<(), String>;
}

enum Flow {
    Normal,
    Break,
    Continue,
    Halt,
}

/// A runtime error with its line.
#[derive(Debug)]
pub(crate) struct RuntimeError {
    pub(crate) line: usize,
    pub(crate) message: String,
}

/// Run a program to completion.
pub(crate) fn run(prog: &Program, host: &mut dyn Host) -> Result<(), RuntimeError> {
    let mut vars = HashMap::new();
    exec(&prog.body, &mut vars, host).map(|_| ())
}

fn exec(
    body: &[Stmt],
    vars: &mut HashMap<String, Val>,
    host: &mut dyn Host,
) -> Result<Flow, RuntimeError> {
    for s in body {
        let line = match s {
            Stmt::Assign { line, .. }
            | Stmt::Expr { line, .. }
            | Stmt::If { line, .. }
            | Stmt::While { line, .. } => *line,
            _ => 0,
        };
        let rt = |message: String| RuntimeError { line, message };
        host.tick().map_err(rt)?;
        match s {
            Stmt::Assign { name, value, .. } => {
                let v = eval(value, vars, host).map_err(rt)?;
                if vars.len() >= 1024 && !vars.contains_key(name) {
                    return Err(rt("too many variables".into()));
                }
                vars.insert(name.clone(), v);
            }
            Stmt::Expr { expr, .. } => {
                eval(expr, vars, host).map_err(rt)?;
            }
            Stmt::If {
                arms, otherwise, ..
            } => {
                let mut taken = None;
                for (c, b) in arms {
                    if truthy(&eval(c, vars, host).map_err(rt)?).map_err(rt)? {
                        taken = Some(b);
                        break;
                    }
                }
                match exec(taken.unwrap_or(otherwise), vars, host)? {
                    Flow::Normal => {}
                    f => return Ok(f),
                }
            }
            Stmt::While { cond, body, .. } => {
                while truthy(&eval(cond, vars, host).map_err(rt)?).map_err(rt)? {
                    host.tick().map_err(rt)?;
                    match exec(body, vars, host)? {
                        Flow::Break => break,
                        Flow::Halt => return Ok(Flow::Halt),
                        Flow::Normal | Flow::Continue => {}
                    }
                }
            }
            Stmt::Break => return Ok(Flow::Break),
            Stmt::Continue => return Ok(Flow::Continue),
            Stmt::Halt => return Ok(Flow::Halt),
        }
    }
    Ok(Flow::Normal)
}

fn truthy(v: &Val) -> Result<bool, String> {
    match v {
        Val::Bool(b) => Ok(*b),
        Val::Num(n) => Ok(*n != 0.0),
        other => Err(format!("type error: `{other}` is not a boolean")),
    }
}

pub(crate) fn num(v: &Val) -> Result<f64, String> {
    match v {
        Val::Num(n) => Ok(*n),
        Val::Bool(b) => Ok(f64::from(u8::from(*b))),
        other => Err(format!("type error: `{other}` is not a number")),
    }
}

fn eval(e: &Expr, vars: &HashMap<String, Val>, host: &mut dyn Host) -> Result<Val, String> {
    Ok(match e {
        Expr::Lit(v) => v.clone(),
        Expr::Var(n) => vars
            .get(n)
            .cloned()
            .ok_or_else(|| format!("variable `{n}` is not defined"))?,
        Expr::List(items) => Val::List(
            items
                .iter()
                .map(|x| eval(x, vars, host))
                .collect::<Result<_, _>>()?,
        )
        .bounded()?,
        Expr::Pose(items) => {
            if items.len() != 6 {
                return Err(format!("a pose needs 6 values, got {}", items.len()));
            }
            let mut p = [0.0; 6];
            for (o, x) in p.iter_mut().zip(items) {
                *o = num(&eval(x, vars, host)?)?;
            }
            Val::Pose(p)
        }
        Expr::Index(a, i) => {
            let i = num(&eval(i, vars, host)?)?;
            let idx = if i >= 0.0 && i.fract() == 0.0 {
                i as usize
            } else {
                usize::MAX
            };
            match eval(a, vars, host)? {
                Val::List(v) => v.get(idx).cloned().ok_or("index out of range")?,
                Val::Pose(p) => Val::Num(*p.get(idx).ok_or("index out of range")?),
                other => return Err(format!("type error: cannot index `{other}`")),
            }
        }
        Expr::Unary(op, a) => {
            let v = eval(a, vars, host)?;
            match *op {
                "not" => Val::Bool(!truthy(&v)?),
                _ => Val::Num(-num(&v)?),
            }
        }
        Expr::Binary(op, a, b) => {
            let l = eval(a, vars, host)?;
            if *op == "and" && !truthy(&l)? {
                return Ok(Val::Bool(false));
            }
            if *op == "or" && truthy(&l)? {
                return Ok(Val::Bool(true));
            }
            let r = eval(b, vars, host)?;
            match *op {
                "and" | "or" => Val::Bool(truthy(&r)?),
                "==" => Val::Bool(l == r),
                "!=" => Val::Bool(l != r),
                "+" if matches!((&l, &r), (Val::Str(_), _) | (_, Val::Str(_))) => {
                    Val::Str(format!("{l}{r}")).bounded()?
                }
                _ => {
                    let (x, y) = (num(&l)?, num(&r)?);
                    match *op {
                        "+" => Val::Num(x + y),
                        "-" => Val::Num(x - y),
                        "*" => Val::Num(x * y),
                        "/" if y == 0.0 => return Err("division by zero".into()),
                        "/" => Val::Num(x / y),
                        "%" if y == 0.0 => return Err("division by zero".into()),
                        "%" => Val::Num(x % y),
                        "<" => Val::Bool(x < y),
                        ">" => Val::Bool(x > y),
                        "<=" => Val::Bool(x <= y),
                        _ => Val::Bool(x >= y),
                    }
                }
            }
        }
        Expr::Call { name, args, named } => {
            let args = args
                .iter()
                .map(|x| eval(x, vars, host))
                .collect::<Result<Vec<_>, _>>()?;
            let named = named
                .iter()
                .map(|(n, x)| Ok((n.clone(), eval(x, vars, host)?)))
                .collect::<Result<Vec<_>, String>>()?;
            host.call(name, args, named)?
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Rec(Vec<String>, usize);
    impl Host for Rec {
        fn call(
            &mut self,
            name: &str,
            args: Vec<Val>,
            _named: Vec<(String, Val)>,
        ) -> Result<Val, String> {
            self.0.push(format!(
                "{name}({})",
                args.iter()
                    .map(|a| a.to_string())
                    .collect::<Vec<_>>()
                    .join(",")
            ));
            Ok(Val::Num(2.0))
        }
        fn tick(&mut self) -> Result<(), String> {
            self.1 += 1;
            if self.1 > 10_000 {
                return Err("too many steps".into());
            }
            Ok(())
        }
    }

    #[test]
    fn runs_control_flow_and_calls() {
        let text = "def prog():\n  i = 0\n  while i < 3:\n    i = i + 1\n    if i == 2:\n      continue\n    elif i > 2:\n      textmsg(\"i=\", i)\n    else:\n      set_tcp(p[0,0,0.1,0,0,0])\n    end\n  end\n  x = read_input_float_register(24) * -1\n  write_output_float_register(24, x)\nend\n";
        let prog = parse_program(text).expect("parses");
        assert!(!prog.secondary);
        let mut h = Rec(Vec::new(), 0);
        run(&prog, &mut h).expect("runs");
        assert_eq!(
            h.0,
            vec![
                "set_tcp(p[0, 0, 0.1, 0, 0, 0])",
                "textmsg(i=,3)",
                "read_input_float_register(24)",
                "write_output_float_register(24,-2)"
            ]
        );
    }

    #[test]
    fn unknown_functions_and_syntax_errors_are_compile_errors() {
        assert!(parse_program("def a():\n  force_mode(1)\nend\n")
            .expect_err("compile error")
            .message
            .contains("force_mode"));
        assert_eq!(
            parse_program("def a():\n  x = (1\nend\n")
                .expect_err("compile error")
                .line,
            2
        );
        assert!(parse_program("def a():\n  x = 1\n").is_err());
        assert!(parse_program("sec a():\n  sleep(1)\nend\n").is_err());
        assert!(
            parse_program("sec a():\n  set_tcp(p[0,0,0,0,0,0])\nend\n")
                .expect("ok")
                .secondary
        );
        assert!(parse_program("textmsg(\"hi\")\n").is_ok());
        // Non-ASCII text: inside strings it is kept, elsewhere it is refused, never a panic.
        assert!(parse_program("textmsg(\"grüße ✓\")\n").is_ok());
        for text in [
            "x = é\n",
            "x = 1 ✓ 2\n",
            "é = 1\n",
            "def ä():\n  x = 1\nend\n",
        ] {
            assert!(parse_program(text).is_err(), "{text}");
        }
    }

    /// Parses `text` on a thread with a quarter of a tokio worker's stack (the primary server
    /// parses on one): a program must fail to compile long before the stack runs out.
    fn parse_on_small_stack(text: String) -> Result<Program, CompileError> {
        std::thread::Builder::new()
            .stack_size(512 * 1024)
            .spawn(move || parse_program(&text))
            .expect("thread")
            .join()
            .expect("the parser did not overflow its stack")
    }

    #[test]
    fn issue_14_deep_nesting_is_a_compile_error_not_a_crash() {
        let nested_ifs = format!("def p():\n{}end\n", "if 1:\n".repeat(5000));
        let e = parse_on_small_stack(nested_ifs).expect_err("refused");
        assert!(e.message.contains("nested too deeply"), "{e:?}");
        assert_eq!(e.line, MAX_BLOCK_DEPTH + 2, "{e:?}");
        let cases = [
            format!("x = {}1\n", "-".repeat(100_000)),
            format!("x = {}1\n", "+".repeat(100_000)),
            format!("x = {}True\n", "not ".repeat(50_000)),
            format!("x = {}1{}\n", "(".repeat(50_000), ")".repeat(50_000)),
            format!("x = {}1{}\n", "[".repeat(50_000), "]".repeat(50_000)),
            format!("x = {}1{}\n", "sin(".repeat(50_000), ")".repeat(50_000)),
            format!("x = y{}\n", "[y".repeat(50_000) + &"]".repeat(50_000)),
            format!("x = {}1{}\n", "p[".repeat(20_000), "]".repeat(20_000)),
        ];
        for text in cases {
            let head = text[..20].to_string();
            let e = parse_on_small_stack(text).expect_err("refused");
            assert!(e.message.contains("nested too deeply"), "{head}: {e:?}");
        }
        // At the limits everything still compiles.
        let ok_blocks = format!(
            "def p():\n{}x = 1\n{}end\n",
            "while False:\n".repeat(MAX_BLOCK_DEPTH),
            "end\n".repeat(MAX_BLOCK_DEPTH)
        );
        parse_on_small_stack(ok_blocks).expect("64 nested blocks compile");
        let ok_expr = format!("x = {}1\n", "-".repeat(MAX_EXPR_DEPTH - 2));
        parse_on_small_stack(ok_expr).expect("a short minus chain compiles");
    }

    #[test]
    fn issue_14_values_cannot_grow_without_bound() {
        let prog = parse_program(
            "def p():\n  x = [1]\n  s = \"ab\"\n  while True:\n    x = [x, x]\n  end\nend\n",
        )
        .expect("parses");
        let e = run(&prog, &mut Rec(Vec::new(), 0)).expect_err("stops");
        assert!(e.message.contains("too large"), "{e:?}");
        let prog =
            parse_program("def p():\n  s = \"ab\"\n  while True:\n    s = s + s\n  end\nend\n")
                .expect("parses");
        let e = run(&prog, &mut Rec(Vec::new(), 0)).expect_err("stops");
        assert!(e.message.contains("too large"), "{e:?}");
        let prog = parse_program("def p():\n  x = 1\n  while True:\n    x = [x]\n  end\nend\n")
            .expect("parses");
        let e = run(&prog, &mut Rec(Vec::new(), 0)).expect_err("stops");
        assert!(e.message.contains("nested too deeply"), "{e:?}");
    }

    /// Random programs of random nesting (blocks, parentheses, unary chains, `not`, calls,
    /// lists, indices) and length: every one either compiles or is refused with a compile
    /// error, on a small stack; the deep ones are always refused.
    #[test]
    fn fuzzed_nesting_and_long_programs_never_crash() {
        let mut rng = crate::rtde::tests::Lcg(14);
        let (mut ok, mut refused) = (0, 0);
        for _ in 0..300 {
            let depth = rng.below(3 * MAX_EXPR_DEPTH);
            let mut open = String::new();
            let mut close = String::new();
            for _ in 0..depth {
                // (`not` chains are in the test above: `-not x` is not URScript.)
                let (o, c) = match rng.below(6) {
                    0 => ("(", ")"),
                    1 => ("-", ""),
                    2 => ("sin(", ")"),
                    3 => ("sin(", ")"),
                    4 => ("[", "]"),
                    5 => ("[0,", "][0]"),
                    _ => ("+", ""),
                };
                open.push_str(o);
                close.insert_str(0, c);
            }
            let blocks = rng.below(3 * MAX_BLOCK_DEPTH);
            let lines = 1 + rng.below(2000);
            let mut text = String::from("def p():\n");
            for b in 0..blocks {
                text.push_str(if b % 2 == 0 {
                    "if 1:\n"
                } else {
                    "while False:\n"
                });
            }
            for i in 0..lines {
                text.push_str(&format!("x{} = {open}{i}{close}\n", i % 50));
            }
            text.push_str(&"end\n".repeat(blocks));
            text.push_str("end\n");
            let too_deep = blocks > MAX_BLOCK_DEPTH || depth + 1 > MAX_EXPR_DEPTH;
            match parse_on_small_stack(text) {
                Ok(_) => {
                    assert!(
                        !too_deep,
                        "blocks {blocks}, expression depth {depth} compiled"
                    );
                    ok += 1;
                }
                Err(e) => {
                    if too_deep {
                        assert!(e.message.contains("nested too deeply"), "{e:?}");
                    }
                    refused += 1;
                }
            }
        }
        assert!(ok > 10 && refused > 10, "{ok} compiled, {refused} refused");
    }

    /// Issue 23 (found by the `urscript` fuzz target): a NUL byte in a program was echoed raw
    /// in the compile error the primary stream sends to every client.
    #[test]
    fn issue_23_unexpected_control_character_is_escaped() {
        let e = parse_program("\0").expect_err("not URScript");
        assert!(e.message.contains("unexpected character"), "{e:?}");
        assert!(!e.message.chars().any(char::is_control), "{e:?}");
    }

    /// Fuzz target `urscript` (hal::fuzz): mutated programs — control flow, calls, lists,
    /// poses, a `sec` program, strings with non-ASCII text — compile or are refused with a
    /// compile error; what compiles runs (bounded to 10 000 steps) without a panic.
    #[test]
    fn fuzz_urscript() {
        let seeds = [
            "def prog():\n  i = 0\n  while i < 3:\n    i = i + 1\n    if i == 2:\n      textmsg(\"x\", [1,2][0])\n    end\n  end\nend\n",
            "def prog():\n  i = 0\n  while i < 3:\n    i = i + 1\n    if i == 2:\n      continue\n    elif i > 2:\n      textmsg(\"i=\", i)\n    else:\n      set_tcp(p[0,0,0.1,0,0,0])\n    end\n  end\n  x = read_input_float_register(24) * -1\n  write_output_float_register(24, x)\nend\n",
            "sec a():\n  set_tcp(p[0,0,0,0,0,0])\nend\n",
            "def f():\n  global q = [0.1, -0.2, 0.3, 0, 0, 0]\n  x = not (1 < 2 and 3 >= 4) or False\n  textmsg(\"grüße ✓\")\n  sleep(0.01)\nend\n",
        ];
        handeye_hal::fuzz::Target::new(
            "urscript",
            seeds.iter().map(|s| s.as_bytes().to_vec()).collect(),
        )
        .run(|b| {
            let p = parse_program(&String::from_utf8_lossy(b)).map_err(|e| e.message)?;
            let _ = run(&p, &mut Rec(Vec::new(), 0));
            Ok::<(), String>(())
        });
    }
}
