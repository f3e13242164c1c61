//! The parsed form of a program (expressions, statements, [`Program`]) and the
//! [`CompileError`] the lexer and parser report.

use super::value::Val;

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

pub(super) fn err<T>(line: usize, message: impl Into<String>) -> Result<T, CompileError> {
    Err(CompileError {
        line,
        message: message.into(),
    })
}
