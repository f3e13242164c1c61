//! Registration of a scan against the posed robot model, the hand-eye solve, the pass/fail
//! gate and the benchmark protocol.
