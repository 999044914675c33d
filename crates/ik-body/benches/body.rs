//! Criterion benchmarks of the full-body solvers on the reference humanoid (W8): one cold
//! solve from the rest pose per iteration (cycling through 200 goal sets), one warm frame
//! of the squat clip per iteration, and 1 000 characters solving one warm frame each.

fn main() {}
