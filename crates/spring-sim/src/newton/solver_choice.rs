//! The linear solver choice of `Auto`: the first step uses PCG, the second the direct
//! solve; from then on each step uses the one with the smaller measured time per step
//! (the smallest of its last [`TIMING_WINDOW`] step times), and the other is timed again
//! after `reprobe_interval` steps so a change of regime is noticed.

use crate::linear::{LinearSolverChoice, LinearSolverKind};

/// Per-solver timing for the automatic choice (index 0: PCG, 1: direct).
///
/// The estimate is the smallest of the last [`TIMING_WINDOW`] measured step times: on a
/// shared machine noise only ever adds time, so the minimum is the robust figure, and a
/// single preempted step cannot hand the choice to the slower solver.
#[derive(Clone, Copy, Debug)]
struct SolverTiming {
    /// The last step times in seconds (a ring; infinity where not measured).
    recent: [f64; TIMING_WINDOW],
    /// Next ring slot.
    next: usize,
    /// Steps since this solver was last used.
    steps_since_used: usize,
}

/// Step times remembered per solver.
const TIMING_WINDOW: usize = 8;

impl Default for SolverTiming {
    fn default() -> Self {
        Self {
            recent: [f64::INFINITY; TIMING_WINDOW],
            next: 0,
            steps_since_used: 0,
        }
    }
}

impl SolverTiming {
    fn seconds_per_step(&self) -> Option<f64> {
        let m = self.recent.iter().copied().fold(f64::INFINITY, f64::min);
        m.is_finite().then_some(m)
    }

    fn record(&mut self, seconds: f64) {
        self.recent[self.next] = seconds;
        self.next = (self.next + 1) % TIMING_WINDOW;
        self.steps_since_used = 0;
    }
}

/// Records a step's time for the automatic solver choice. A step that converged with no
/// Newton iteration never ran the linear solver, so its time (the gradient alone) says
/// nothing about the solver's cost and is not recorded: recording it made the solver
/// probed on such a step look almost free, and `auto` then kept a solver 10x slower for
/// a dozen steps (W6 at tolerance 1e-6, found by `cargo xtask bench`).
fn record_step_time(
    timing: &mut [SolverTiming; 2],
    kind: LinearSolverKind,
    seconds: f64,
    iterations: usize,
) {
    if iterations == 0 {
        return;
    }
    let index = match kind {
        LinearSolverKind::Pcg => 0,
        LinearSolverKind::Direct => 1,
    };
    for (k, t) in timing.iter_mut().enumerate() {
        if k == index {
            t.record(seconds);
        } else {
            t.steps_since_used += 1;
        }
    }
}

/// The measured costs of both solvers and the choice made from them.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct SolverChooser {
    timing: [SolverTiming; 2],
}

impl SolverChooser {
    /// The solver for the next step under `choice`.
    pub(super) fn choose(
        &self,
        choice: LinearSolverChoice,
        reprobe_interval: usize,
    ) -> LinearSolverKind {
        match choice {
            LinearSolverChoice::Direct => LinearSolverKind::Direct,
            LinearSolverChoice::Pcg => LinearSolverKind::Pcg,
            LinearSolverChoice::Auto => {
                let [pcg, direct] = self.timing;
                match (pcg.seconds_per_step(), direct.seconds_per_step()) {
                    (None, _) => LinearSolverKind::Pcg,
                    (_, None) => LinearSolverKind::Direct,
                    (Some(tp), Some(td)) => {
                        let (best, other, other_timing) = if tp <= td {
                            (LinearSolverKind::Pcg, LinearSolverKind::Direct, direct)
                        } else {
                            (LinearSolverKind::Direct, LinearSolverKind::Pcg, pcg)
                        };
                        if other_timing.steps_since_used >= reprobe_interval {
                            other
                        } else {
                            best
                        }
                    }
                }
            }
        }
    }

    /// Records a step's time with `kind` (see [`record_step_time`]).
    pub(super) fn record(&mut self, kind: LinearSolverKind, seconds: f64, iterations: usize) {
        record_step_time(&mut self.timing, kind, seconds, iterations);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_without_newton_iterations_does_not_time_the_solver() {
        let mut timing = [SolverTiming::default(); 2];
        record_step_time(&mut timing, LinearSolverKind::Pcg, 0.010, 2);
        // The direct probe lands on a step that converged at once: 1 us of gradient work.
        record_step_time(&mut timing, LinearSolverKind::Direct, 1e-6, 0);
        assert_eq!(timing[0].seconds_per_step(), Some(0.010));
        assert_eq!(
            timing[1].seconds_per_step(),
            None,
            "direct is still unmeasured"
        );
        // Its first step with a solve is what counts.
        record_step_time(&mut timing, LinearSolverKind::Direct, 0.190, 1);
        assert_eq!(timing[1].seconds_per_step(), Some(0.190));
        assert_eq!(timing[0].steps_since_used, 1);
        assert_eq!(timing[1].steps_since_used, 0);
    }
}
