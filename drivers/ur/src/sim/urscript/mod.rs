//! The URScript subset the simulator runs: `def`/`sec` programs with assignments, `if`/`elif`/
//! `else`, `while`, `break`/`continue`/`halt`, arithmetic, comparisons, lists and poses, and
//! the built-ins in [`BUILTINS`]. Anything else is a compile error reported to the client.

mod ast;
mod interp;
mod lexer;
mod parser;
#[cfg(test)]
mod tests;
mod value;

pub(crate) use ast::{CompileError, Program};
pub(crate) use interp::{num, run, Host, RuntimeError};
pub(crate) use parser::parse_program;
pub(crate) use value::Val;

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
