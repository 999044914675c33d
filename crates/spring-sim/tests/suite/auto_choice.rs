//! `Integrator::Auto` chooses from counts by default, not from a clock: two runs of the
//! same setup give bitwise the same states and the same choices, each step says why and
//! with which costs, and the choice follows the costs it reports.

use sinew_spring_sim::*;

/// The lab cloth (11 x 11, mass 1, the lab's gravity, corners (0, 0) and (0, 10) pinned)
/// at stiffness `k` and damping `damping`; or `size` x `size`, 2 wide.
fn cloth(size: usize, k: f64, damping: f64) -> SpringSystem {
    let mut spec = if size == 11 {
        ClothGrid::lab().with_damping(damping)
    } else {
        ClothGrid::lab_sized(size, 2.0 / (size - 1) as f64).with_damping(damping)
    };
    spec.material.stiffness = k;
    SpringSystem::cloth(&spec).unwrap()
}

fn run(
    system: &SpringSystem,
    settings: AutoSettings,
    h: f64,
    steps: usize,
) -> (SpringSystem, Vec<StepReport>) {
    let mut sim = Simulation::new(system.clone(), Integrator::Auto(settings)).unwrap();
    let reports = (0..steps).map(|_| sim.step(h).unwrap()).collect();
    (sim.into_system(), reports)
}

/// W4 (k = 100, h = 1/60), W5 (k = 1e4 and 1e6, h = 1/30, damping 0.2), and a cloth so
/// stiff (k = 1e8, h = 1/10) that the bound asks for far more substeps than an implicit
/// step costs; and the same with an implicit step modelled as cheap as 2 substeps, so
/// BDF2 runs and its observed counts decide afterwards.
#[test]
fn two_runs_of_auto_are_bitwise_equal_and_say_why() {
    let cases = [
        (cloth(11, 100.0, 0.0), 1.0 / 60.0, 30),
        (cloth(11, 1e4, 0.2), 1.0 / 30.0, 15),
        (cloth(11, 1e6, 0.2), 1.0 / 30.0, 15),
        (cloth(11, 1e8, 0.0), 0.1, 6),
    ];
    let mut seen = Vec::new();
    for (system, h, steps) in &cases {
        for settings in [
            AutoSettings::default(),
            AutoSettings {
                implicit_cost_model: 2.0,
                ..AutoSettings::default()
            },
        ] {
            let (a, reports_a) = run(system, settings, *h, *steps);
            let (b, reports_b) = run(system, settings, *h, *steps);
            assert_eq!(a.positions(), b.positions());
            assert_eq!(a.velocities(), b.velocities());
            for (n, (ra, rb)) in reports_a.iter().zip(&reports_b).enumerate() {
                // Everything but the energies' bits is compared; those follow from the
                // states, equal above.
                assert_eq!(ra.integrator, rb.integrator, "step {n}");
                assert_eq!(ra.auto_reason, rb.auto_reason, "step {n}");
                assert_eq!(ra.auto_costs, rb.auto_costs, "step {n}");
                assert_eq!(ra.substeps, rb.substeps, "step {n}");
                let reason = ra.auto_reason.expect("auto reports its reason");
                let costs = ra.auto_costs.expect("the costs compared are reported");
                assert!(!costs.timed);
                assert!(costs.explicit > 0.0 && costs.implicit > 0.0);
                // The choice follows the reported costs, within the hysteresis.
                match reason {
                    AutoReason::ExplicitCheapest => {
                        assert_eq!(ra.integrator, IntegratorKind::VelocityVerlet);
                        assert!(costs.explicit <= costs.implicit * settings.switch_ratio);
                    }
                    AutoReason::ImplicitCheaper => {
                        assert_eq!(ra.integrator, IntegratorKind::Bdf2);
                        assert!(costs.explicit * settings.switch_ratio >= costs.implicit);
                    }
                    other => panic!("step {n}: unexpected reason {other:?}"),
                }
                // The implicit cost is the prior until BDF2 has run once.
                let bdf2_before = reports_a[..n]
                    .iter()
                    .any(|r| r.integrator == IntegratorKind::Bdf2);
                assert_eq!(costs.implicit_observed, bdf2_before, "step {n}");
                seen.push((ra.integrator, costs.implicit_observed));
            }
        }
    }
    // Both integrators were chosen, and BDF2 also from an observed cost.
    assert!(seen.contains(&(IntegratorKind::VelocityVerlet, false)));
    assert!(seen.contains(&(IntegratorKind::Bdf2, false)));
    assert!(seen.contains(&(IntegratorKind::Bdf2, true)));
}

/// On W4, W5 k = 1e6 (h = 1/30) and W6 (101 x 101, h = 1/60), the workloads where Verlet at
/// the bound was measured cheapest, the count model chooses it on every step.
#[test]
fn the_count_model_keeps_verlet_on_the_workloads() {
    for (system, h, steps) in [
        (cloth(11, 100.0, 0.0), 1.0 / 60.0, 10),
        (cloth(11, 1e6, 0.0), 1.0 / 30.0, 10),
        (cloth(101, 100.0, 0.0), 1.0 / 60.0, 3),
    ] {
        let (_, reports) = run(&system, AutoSettings::default(), h, steps);
        for r in reports {
            assert_eq!(r.integrator, IntegratorKind::VelocityVerlet, "{r:?}");
            assert_eq!(r.substeps, r.stable_substeps);
        }
    }
}

/// Timing-based tuning is there when asked for, and says its costs are seconds.
#[test]
fn tuning_by_timing_is_opt_in_and_reported() {
    let system = cloth(11, 100.0, 0.0);
    let settings = AutoSettings {
        tune_by_timing: true,
        ..AutoSettings::default()
    };
    let (_, reports) = run(&system, settings, 1.0 / 60.0, 10);
    let timed: Vec<_> = reports.iter().filter_map(|r| r.auto_costs).collect();
    assert!(!timed.is_empty());
    assert!(timed.iter().all(|c| c.timed));
    assert!(reports.iter().all(|r| r.auto_reason.is_some()));
}

/// A compressed sheet (every particle moved halfway to the centre) at h = 1/4: the
/// stability bound taken at the step's start asks for a substep count the sheet outgrows
/// within the step as its springs shorten, and Verlet at that count ran away (7e4 to
/// 1e17 in one step). `auto` must notice, keep nothing of that attempt and redo the step
/// by backward Euler. Checked from the states, step by step: every step `auto` kept as
/// Verlet changed the energy by less than half the energy scale at its start; every
/// redone step is a backward Euler step that did not raise the total energy (backward
/// Euler's energy inequality; BDF2, which redid these steps before, raised it up to 631
/// times the starting scale for k = 1e7); every state is finite; and a
/// second run makes the same choices and ends in bitwise the same state. With k = 1e4
/// and 1e5 the first step is the runaway; with k = 1e7 the bound asks for more substeps
/// than an implicit step costs, so the first step is BDF2's (a damped backward Euler
/// start), and Verlet then holds from the state it leaves (when BDF2 started with an
/// undamped midpoint step, Verlet ran away from that state and had to be redone).
#[test]
fn auto_redoes_a_runaway_explicit_step_implicitly() {
    for k in [1e4, 1e5, 1e7] {
        let mut system = cloth(11, k, 0.0);
        crate::common::scale_about_centre(&mut system, 0.5);
        let mut sim =
            Simulation::new(system.clone(), Integrator::Auto(AutoSettings::default())).unwrap();
        let mut redone = 0;
        let mut reasons = Vec::new();
        for step in 0..20 {
            let before = sim.system().energies();
            let report = sim.step(0.25).unwrap();
            let after = sim.system().energies();
            reasons.push(report.auto_reason);
            assert!(
                sim.system().positions().iter().all(|p| p.is_finite()) && after.total().is_finite(),
                "k {k}, step {step}: a non-finite state"
            );
            let scale = before.kinetic.abs() + before.spring.abs() + before.gravity.abs();
            match report.auto_reason {
                Some(AutoReason::ExplicitUnstable) => {
                    redone += 1;
                    assert_eq!(
                        report.integrator,
                        IntegratorKind::BackwardEuler,
                        "k {k}, step {step}"
                    );
                    assert!(
                        after.total() <= before.total() + 1e-9 * scale,
                        "k {k}, step {step}: the backward Euler redo raised the energy from {} to {}",
                        before.total(),
                        after.total()
                    );
                }
                Some(AutoReason::ExplicitCheapest) => {
                    assert!(
                        after.total() - before.total() <= 0.5 * scale,
                        "k {k}, step {step}: a kept Verlet step raised the energy from {} to {}",
                        before.total(),
                        after.total()
                    );
                }
                _ => {}
            }
        }
        if k < 1e6 {
            assert!(redone > 0, "k {k}: the case must exercise the fallback");
        } else {
            assert_eq!(reasons[0], Some(AutoReason::ImplicitCheaper), "k {k}");
            assert_eq!(redone, 0, "k {k}: {reasons:?}");
        }
        let (again, again_reports) = run(&system, AutoSettings::default(), 0.25, 20);
        let again_reasons: Vec<_> = again_reports.iter().map(|r| r.auto_reason).collect();
        assert_eq!(reasons, again_reasons, "k {k}");
        let bits = |s: &SpringSystem| -> Vec<u64> {
            s.positions()
                .iter()
                .chain(s.velocities())
                .flat_map(|v| [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()])
                .collect()
        };
        assert_eq!(
            bits(sim.system()),
            bits(&again),
            "k {k}: a second run ended elsewhere"
        );
    }
}
