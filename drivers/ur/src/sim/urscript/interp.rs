//! The interpreter: runs a parsed program statement by statement against a [`Host`] (the
//! simulated controller), which carries out built-in calls and may stop the program.

use std::collections::HashMap;

use super::ast::{Expr, Program, Stmt};
use super::value::Val;

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
