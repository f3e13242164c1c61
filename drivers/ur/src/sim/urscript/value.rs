//! Script values ([`Val`]): what variables and expressions hold, their printed form, and the
//! size and depth bounds a program's values must stay within.

use super::{MAX_EXPR_DEPTH, MAX_VALUE_SIZE};

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
    pub(super) fn bounded(self) -> Result<Self, String> {
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
