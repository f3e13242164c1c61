//! Unit tests of the URScript subset: control flow and calls, compile errors, the nesting and
//! value-size bounds (issues 14 and 23), and the `urscript` fuzz target.

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
    let prog = parse_program("def p():\n  s = \"ab\"\n  while True:\n    s = s + s\n  end\nend\n")
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
