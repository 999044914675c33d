//! The linear solver choice of `Auto`, from counts only, so it is deterministic.
//!
//! The first step with a Newton iteration uses PCG and records how many PCG iterations
//! each Newton iteration needed. From then on a step uses PCG while that figure (from the
//! last PCG step) is at most the cost model's crossover
//! ([`SolverCosts::crossover_iterations`], from the factor's size under a fill-reducing
//! ordering and the matrix's nonzeros), and the direct solve when it is above. While on
//! the direct solve, PCG is used again once every `reprobe_interval` steps to observe its
//! iteration count afresh, so a system that softens goes back to PCG. Nothing here reads
//! a clock: two identical runs make the same choices.
//!
//! Within a step, a solve that started on PCG moves to the direct solve for the rest of
//! its Newton iterations once PCG has needed more iterations per Newton iteration than
//! the crossover over the step's first [`PCG_PROBE_NEWTON_ITERATIONS`] Newton iterations
//! or more: a stiff sheet far from rest needs hundreds of Newton iterations, each of
//! which would otherwise run PCG to its cap.

use crate::linear::{LinearSolverChoice, LinearSolverKind, SolverCosts};

/// Newton iterations a step runs on PCG before its PCG count may send the rest of the
/// step to the direct solve (the first iteration's count alone is a poor guide: its
/// right-hand side is the largest of the step).
pub(super) const PCG_PROBE_NEWTON_ITERATIONS: usize = 3;

/// The observations and counts the automatic choice is made from.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct SolverChooser {
    /// PCG iterations per Newton iteration on the last PCG step that had a Newton
    /// iteration (`None` before one).
    pcg_iterations_per_newton: Option<f64>,
    /// Steps since PCG last ran a Newton iteration.
    steps_since_pcg: usize,
}

impl SolverChooser {
    /// Whether the choice for the next step under `choice` needs the cost counts (the
    /// caller analyses the pattern once, the first time this is true).
    pub(super) fn needs_costs(&self, choice: LinearSolverChoice) -> bool {
        choice == LinearSolverChoice::Auto && self.pcg_iterations_per_newton.is_some()
    }

    /// PCG iterations per Newton iteration on the last PCG step that had a Newton
    /// iteration, once there was one.
    pub(super) fn observed(&self) -> Option<f64> {
        self.pcg_iterations_per_newton
    }

    /// The solver for the next step under `choice`; `costs` must be given when
    /// [`SolverChooser::needs_costs`] says so.
    pub(super) fn choose(
        &self,
        choice: LinearSolverChoice,
        reprobe_interval: usize,
        costs: Option<&SolverCosts>,
    ) -> LinearSolverKind {
        match choice {
            LinearSolverChoice::Direct => LinearSolverKind::Direct,
            LinearSolverChoice::Pcg => LinearSolverKind::Pcg,
            LinearSolverChoice::Auto => {
                let (Some(observed), Some(costs)) = (self.pcg_iterations_per_newton, costs) else {
                    return LinearSolverKind::Pcg;
                };
                if observed <= costs.crossover_iterations()
                    || self.steps_since_pcg >= reprobe_interval
                {
                    LinearSolverKind::Pcg
                } else {
                    LinearSolverKind::Direct
                }
            }
        }
    }

    /// Whether a step under `choice` that has run `newton_iterations` Newton iterations
    /// on PCG, needing `linear_iterations` PCG iterations in all, should finish on the
    /// direct solve: only under `Auto`, after at least [`PCG_PROBE_NEWTON_ITERATIONS`],
    /// and when the count per Newton iteration is above the crossover of `costs`. When
    /// it says yes the count is recorded as the last PCG observation, so the next steps
    /// start on the direct solve.
    pub(super) fn switch_mid_step(
        &mut self,
        choice: LinearSolverChoice,
        newton_iterations: usize,
        linear_iterations: usize,
        costs: &SolverCosts,
    ) -> bool {
        if choice != LinearSolverChoice::Auto || newton_iterations < PCG_PROBE_NEWTON_ITERATIONS {
            return false;
        }
        let observed = linear_iterations as f64 / newton_iterations as f64;
        if observed <= costs.crossover_iterations() {
            return false;
        }
        self.pcg_iterations_per_newton = Some(observed);
        self.steps_since_pcg = 0;
        true
    }

    /// Records a step taken with `kind`: `newton_iterations` Newton iterations needing
    /// `linear_iterations` PCG iterations in all. A step without a Newton iteration
    /// (converged at its first guess) ran no solver and says nothing about its cost.
    pub(super) fn record(
        &mut self,
        kind: LinearSolverKind,
        newton_iterations: usize,
        linear_iterations: usize,
    ) {
        if kind == LinearSolverKind::Pcg && newton_iterations > 0 {
            self.pcg_iterations_per_newton =
                Some(linear_iterations as f64 / newton_iterations as f64);
            self.steps_since_pcg = 0;
        } else {
            self.steps_since_pcg = self.steps_since_pcg.saturating_add(1);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Counts with a crossover of exactly 10 PCG iterations per Newton iteration.
    fn costs() -> SolverCosts {
        let mut c = SolverCosts {
            dim: 3,
            matrix_nonzeros: 6,
            factor_nonzeros: 0.0,
            factor_multiply_adds: 0.0,
        };
        let cg = c.cg_iteration_cost();
        c.factor_multiply_adds =
            (10.0 * cg - 2.0 * 3.0 * crate::linear::SOLVE_WEIGHT) / crate::linear::FACTOR_WEIGHT;
        assert!((c.crossover_iterations() - 10.0).abs() < 1e-9);
        c
    }

    #[test]
    fn pcg_until_observed_then_the_cheaper_by_the_model() {
        let c = costs();
        let auto = LinearSolverChoice::Auto;
        let mut chooser = SolverChooser::default();
        assert!(!chooser.needs_costs(auto));
        assert_eq!(chooser.choose(auto, 64, None), LinearSolverKind::Pcg);
        // Converged at the guess: nothing observed.
        chooser.record(LinearSolverKind::Pcg, 0, 0);
        assert!(!chooser.needs_costs(auto));
        // 9 PCG iterations per Newton iteration: below the crossover, PCG stays.
        chooser.record(LinearSolverKind::Pcg, 2, 18);
        assert!(chooser.needs_costs(auto));
        assert_eq!(chooser.choose(auto, 64, Some(&c)), LinearSolverKind::Pcg);
        // 30 per Newton iteration: the direct solve.
        chooser.record(LinearSolverKind::Pcg, 2, 60);
        assert_eq!(chooser.choose(auto, 64, Some(&c)), LinearSolverKind::Direct);
        // On the direct solve, PCG is observed again after the reprobe interval.
        for _ in 0..3 {
            chooser.record(LinearSolverKind::Direct, 2, 0);
        }
        assert_eq!(chooser.choose(auto, 4, Some(&c)), LinearSolverKind::Direct);
        chooser.record(LinearSolverKind::Direct, 2, 0);
        assert_eq!(chooser.choose(auto, 4, Some(&c)), LinearSolverKind::Pcg);
        // The system softened: back to PCG for good.
        chooser.record(LinearSolverKind::Pcg, 1, 4);
        assert_eq!(chooser.choose(auto, 4, Some(&c)), LinearSolverKind::Pcg);
        // Mid-step: not before the probe iterations, not at or below the crossover, and
        // never for a fixed choice.
        let mut fresh = SolverChooser::default();
        let probe = PCG_PROBE_NEWTON_ITERATIONS;
        assert!(!fresh.switch_mid_step(auto, probe - 1, 1000 * probe, &c));
        assert!(!fresh.switch_mid_step(auto, probe, 10 * probe, &c));
        assert!(!fresh.switch_mid_step(LinearSolverChoice::Pcg, probe, 1000 * probe, &c));
        assert!(!fresh.needs_costs(auto));
        assert!(fresh.switch_mid_step(auto, probe, 10 * probe + 1, &c));
        // The switch counts as an observation: the next step starts on the direct
        // solve, even after the switched step is recorded as a direct one.
        fresh.record(LinearSolverKind::Direct, 50, 0);
        assert_eq!(fresh.choose(auto, 64, Some(&c)), LinearSolverKind::Direct);
        // The fixed choices ignore everything.
        assert_eq!(
            chooser.choose(LinearSolverChoice::Direct, 4, None),
            LinearSolverKind::Direct
        );
        assert_eq!(
            chooser.choose(LinearSolverChoice::Pcg, 4, Some(&c)),
            LinearSolverKind::Pcg
        );
    }

    /// Widening the pattern (a coupled term, or pairs a term met during a run) makes the
    /// choice's counts those of the new pattern: analysed again, they equal a fresh
    /// integrator's on the widened pattern, and exceed the narrower pattern's.
    #[test]
    fn widening_the_pattern_renews_the_solver_costs() {
        use crate::model::{ClothGrid, SpringSystem};
        use crate::newton::{BackwardEuler, NewtonSettings};
        let system = SpringSystem::cloth(&ClothGrid::lab()).unwrap();
        let mut be = BackwardEuler::new(&system, NewtonSettings::default()).unwrap();
        let narrow = be.solver_costs().unwrap();
        // Opposite corners' neighbours and two far interior particles: pairs no spring
        // joins, far apart in the sheet, so the factor fills in between them.
        let pairs = [[1, 119], [12, 108], [23, 97]];
        be.add_coupled_pairs(&system, &pairs).unwrap();
        let wide = be.solver_costs().unwrap();
        let mut fresh = BackwardEuler::new(&system, NewtonSettings::default()).unwrap();
        fresh.add_coupled_pairs(&system, &pairs).unwrap();
        assert_eq!(wide, fresh.solver_costs().unwrap());
        assert!(wide.matrix_nonzeros > narrow.matrix_nonzeros);
        assert!(wide.factor_nonzeros > narrow.factor_nonzeros);
        assert!(wide.factor_multiply_adds > narrow.factor_multiply_adds);
    }

    /// The soft lab cloth (2 PCG iterations per Newton iteration, below the bound's
    /// crossover) runs `Auto` without the analysis, and its choices are those made with
    /// the analysis; the stiff one (about 35, above the bound) analyses and moves to the
    /// direct solve.
    #[test]
    fn the_soft_cloth_chooses_without_the_analysis() {
        use crate::model::{ClothGrid, SpringSystem};
        use crate::newton::{BackwardEuler, NewtonSettings};
        let run = |stiffness: f64, h: f64, analysed_first: bool| {
            let mut grid = ClothGrid::lab();
            grid.material.stiffness = stiffness;
            let system = SpringSystem::cloth(&grid).unwrap();
            let mut be = BackwardEuler::new(&system, NewtonSettings::default()).unwrap();
            if analysed_first {
                be.solver_costs().unwrap();
            }
            let mut s = system.clone();
            let kinds: Vec<_> = (0..20)
                .map(|_| be.step(&mut s, h).unwrap().linear_solver)
                .collect();
            (kinds, be.costs.is_some(), s)
        };
        let (soft, analysed, end) = run(100.0, 1.0 / 60.0, false);
        assert!(!analysed);
        assert!(soft.iter().all(|k| *k == Some(LinearSolverKind::Pcg)));
        let (with, _, end_with) = run(100.0, 1.0 / 60.0, true);
        assert_eq!(soft, with);
        assert_eq!(end.positions(), end_with.positions());
        let (stiff, analysed, _) = run(1e6, 1.0 / 30.0, false);
        assert!(analysed);
        assert!(stiff.contains(&Some(LinearSolverKind::Direct)));
    }
}
