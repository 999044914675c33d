//! The integrators beyond backward Euler: the stability bound against the empirical stability limit,
//! refusal below the bound, the order of convergence of backward Euler, BDF2 and
//! implicit midpoint on the linear oscillator, midpoint's energy conservation, and
//! `auto`'s choices.

use sinew_math::DVec3;
use sinew_spring_sim::*;

fn cloth(stiffness: f64, damping: f64) -> SpringSystem {
    let mut grid = ClothGrid::lab().with_damping(damping);
    grid.material.stiffness = stiffness;
    SpringSystem::cloth(&grid).unwrap()
}

/// Whether `substeps` substeps of symplectic Euler or Verlet blow up (a non-finite value,
/// or a particle beyond radius 100) within `seconds` at step `h`.
fn explodes(system: &SpringSystem, verlet: bool, substeps: usize, h: f64, seconds: f64) -> bool {
    let mut s = system.clone();
    let steps = (seconds / h).round() as usize;
    let mut se = SymplecticEuler::new(&s, substeps).unwrap();
    let mut vv = VelocityVerlet::new(&s, substeps).unwrap();
    for _ in 0..steps {
        let r = if verlet {
            vv.step(&mut s, h)
        } else {
            se.step(&mut s, h)
        };
        if r.is_err() || s.positions().iter().any(|x| x.length() > 100.0) {
            return true;
        }
    }
    false
}

/// The smallest substep count that does not blow up, by bisection (blowing up is
/// monotone in the count: fewer substeps, larger `dt omega`).
fn empirical_threshold(system: &SpringSystem, verlet: bool, h: f64, upper: usize) -> usize {
    assert!(
        !explodes(system, verlet, upper, h, 2.0),
        "upper bound explodes"
    );
    let (mut lo, mut hi) = (0, upper);
    while hi - lo > 1 {
        let mid = (lo + hi) / 2;
        if explodes(system, verlet, mid, h, 2.0) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    hi
}

#[test]
fn stability_bound_predicts_the_empirical_limit_within_one_substep() {
    for (name, system, h) in [
        ("W4", cloth(100.0, 0.0), 1.0 / 60.0),
        ("W4 at h = 0.5", cloth(100.0, 0.0), 0.5),
        ("W5 k = 1e6", cloth(1e6, 0.0), 1.0 / 30.0),
    ] {
        let bound = StabilityBound::of(&system);
        let predicted = bound.critical_substeps(h);
        let chosen = bound.substeps(h);
        assert!(chosen >= predicted);
        for verlet in [false, true] {
            let found = empirical_threshold(&system, verlet, h, 4 * chosen + 4);
            assert!(
                found.abs_diff(predicted) <= 1,
                "{name}, verlet {verlet}: predicted {predicted}, empirical {found}"
            );
            // The count used (with its safety factor) is stable.
            assert!(!explodes(&system, verlet, chosen, h, 2.0), "{name}");
        }
    }
}

/// The Lanczos estimate is the largest eigenvalue of `M^-1 K` (dense check), and the
/// Gershgorin bound is above it.
#[test]
fn lanczos_estimate_matches_the_dense_eigenvalue() {
    let mut systems = vec![cloth(100.0, 0.0), cloth(1e6, 0.0)];
    // A stretched, bent state with unequal masses, so transverse stiffness and the mass
    // scaling matter.
    let mut s = cloth(100.0, 0.0);
    let x: Vec<DVec3> = s
        .positions()
        .iter()
        .enumerate()
        .map(|(i, p)| {
            *p * 1.1 + DVec3::new(0.0, 0.05 * ((i as f64) * 0.7).sin(), 0.01 * (i % 3) as f64)
        })
        .collect();
    s.set_state(&x, &vec![DVec3::ZERO; x.len()]).unwrap();
    systems.push(s);
    let rope = SpringSystem::new(
        &[
            Particle {
                fixed: true,
                ..Particle::at_rest(DVec3::ZERO, 1.0)
            },
            Particle::at_rest(DVec3::new(1.2, 0.0, 0.0), 0.5),
            Particle::at_rest(DVec3::new(2.0, 0.5, 0.0), 2.0),
            Particle::at_rest(DVec3::new(3.0, 0.5, 0.3), 0.1),
        ],
        &[
            SpringSpec {
                particles: [0, 1],
                rest_length: Some(1.0),
                stiffness: Some(50.0),
            },
            SpringSpec {
                particles: [1, 2],
                rest_length: Some(0.8),
                stiffness: Some(300.0),
            },
            SpringSpec {
                particles: [2, 3],
                rest_length: Some(1.5),
                stiffness: Some(20.0),
            },
        ],
        Material::lab(),
    )
    .unwrap();
    systems.push(rope);
    for system in &systems {
        // The Newton matrix at a huge step is K (+ M/h^2 and C/h, negligible there).
        let h = 1e12;
        let free: Vec<usize> = (0..system.len()).filter(|&i| !system.fixed()[i]).collect();
        let dim = 3 * free.len();
        let mut k = faer::Mat::<f64>::zeros(dim, dim);
        for (r, c, v) in newton_matrix_triplets(system, h) {
            let scale = (system.masses()[free[r / 3]] * system.masses()[free[c / 3]]).sqrt();
            k[(r, c)] = v / scale;
            k[(c, r)] = v / scale;
        }
        let eigenvalues = k.self_adjoint_eigenvalues(faer::Side::Lower).unwrap();
        let exact = *eigenvalues.last().unwrap();
        let bound = StabilityBound::of(system);
        assert!(
            (bound.estimate - exact).abs() <= 1e-9 * exact,
            "Lanczos {} vs dense {exact}",
            bound.estimate
        );
        assert!(bound.gershgorin >= exact * (1.0 - 1e-12));
        // The state-independent bound the monitor tries first is above it too.
        let (uniform, _) = uniform_bound(system);
        assert!(uniform >= exact * (1.0 - 1e-12), "{uniform} < {exact}");
    }
}

/// One free particle of mass 1 at the origin held by two springs of stiffness `k` and
/// rest length 1 to fixed anchors at `(l, 0, 0)` and `(0, l, 0)`. With `s = 1 - 1/l`,
/// `M^-1 K` is `diag(k (1 + s), k (1 + s), 2 k s)` for `l >= 1` (each spring adds `k`
/// along itself and `k s` across), so `lambda_max = k (1 + s)` exactly.
fn cross(k: f64, l: f64) -> SpringSystem {
    let anchor = |p| Particle {
        fixed: true,
        ..Particle::at_rest(p, 1.0)
    };
    let spring = |b| SpringSpec {
        particles: [0, b],
        rest_length: Some(1.0),
        stiffness: Some(k),
    };
    SpringSystem::new(
        &[
            Particle::at_rest(DVec3::ZERO, 1.0),
            anchor(DVec3::new(l, 0.0, 0.0)),
            anchor(DVec3::new(0.0, l, 0.0)),
        ],
        &[spring(1), spring(2)],
        Material {
            damping: 0.0,
            ..Material::default()
        },
    )
    .unwrap()
}

/// The monitor's cheap test (the Gershgorin bound against the one of its last Lanczos
/// estimate) asks for a new estimate when the springs stretch, and the substep count then
/// follows the closed-form bound; a small change keeps the scaled estimate, never below
/// the true value.
#[test]
fn the_monitor_refreshes_its_estimate_when_the_springs_stretch() {
    let (k, h) = (100.0, 1.0);
    let mut monitor = StabilityMonitor::new();
    // At rest: lambda_max = k. The uniform bound 2k gives ceil(h sqrt(200) / 2) = 8
    // substeps, so the monitor has to look at the state.
    let b = monitor.update(&cross(k, 1.0), h);
    assert_eq!(monitor.lanczos_refreshes(), 1);
    assert!((b.estimate - k).abs() <= 1e-9 * k, "{b:?}");
    // Stretched by 5%: lambda = k (1 + s) with s = 1 - 1/1.05; Gershgorin moves by less
    // than the refresh threshold, so no new estimate: the old one scaled by Gershgorin's
    // growth, which is above the true value here.
    let l = 1.05;
    let exact = k * (2.0 - 1.0 / l);
    let b = monitor.update(&cross(k, l), h);
    assert_eq!(monitor.lanczos_refreshes(), 1);
    assert!(b.estimate >= exact * (1.0 - 1e-12), "{b:?} vs {exact}");
    // Stretched to twice the rest length: lambda = 1.5 k, Gershgorin grows by half, a
    // new estimate is computed and equals the closed form.
    let exact = 1.5 * k;
    let b = monitor.update(&cross(k, 2.0), h);
    assert_eq!(monitor.lanczos_refreshes(), 2);
    assert!((b.estimate - exact).abs() <= 1e-9 * exact, "{b:?}");
    let limit = (h * exact.sqrt() / 2.0).ceil() as usize;
    assert_eq!(b.critical_substeps(h), limit);
    assert!(b.substeps(h) >= limit);
}

/// When the uniform bound allows one substep the monitor computes nothing more; when the
/// damping coefficient is raised (the one material change a system allows) the next call
/// sees it at once and leaves the one-substep case, with the same count as a bound
/// computed afresh. Stretching a sheet whose uniform bound asks for several substeps
/// makes the monitor refresh its estimate.
#[test]
fn the_monitor_follows_damping_and_stretch_of_the_lab_cloth() {
    let h = 1.0 / 60.0;
    let mut system = cloth(100.0, 0.2);
    let mut monitor = StabilityMonitor::new();
    let b = monitor.update(&system, h);
    assert_eq!(b.substeps(h), 1);
    assert_eq!(
        monitor.lanczos_refreshes(),
        0,
        "one substep needs no estimate"
    );
    assert!(b.estimate >= StabilityBound::of(&system).estimate);
    system.set_damping(50.0).unwrap();
    let b = monitor.update(&system, h);
    let fresh = StabilityBound::of(&system);
    assert!(b.substeps(h) > 1);
    assert_eq!(b.substeps(h), fresh.substeps(h));
    assert_eq!(monitor.lanczos_refreshes(), 1);
    // At h = 1/2 the uniform bound asks for 13 substeps: the state matters.
    let h = 0.5;
    let mut system = cloth(100.0, 0.0);
    let mut monitor = StabilityMonitor::new();
    let b0 = monitor.update(&system, h);
    assert_eq!(monitor.lanczos_refreshes(), 1);
    // Stretched by half: Gershgorin grows by 16.7% and the true lambda_max by 20.5%
    // (966.76 to 1165.18), so Gershgorin's growth alone would underestimate it by 3.2%.
    let stretched: Vec<DVec3> = system.positions().iter().map(|p| *p * 1.5).collect();
    system
        .set_state(&stretched, &vec![DVec3::ZERO; stretched.len()])
        .unwrap();
    let b = monitor.update(&system, h);
    assert_eq!(monitor.lanczos_refreshes(), 2, "stretch must refresh");
    let fresh = StabilityBound::of(&system);
    assert_eq!(b, fresh);
    assert!(b.substeps(h) > b0.substeps(h));
}

#[test]
fn explicit_runs_below_the_bound_are_refused() {
    let system = cloth(1e6, 0.0);
    let h = 1.0 / 30.0;
    let bound = StabilityBound::of(&system);
    let (needed, recommended) = (bound.critical_substeps(h), bound.substeps(h));
    for integrator in [
        Integrator::VelocityVerlet {
            substeps: Some(needed - 1),
        },
        Integrator::SymplecticEulerBounded {
            substeps: Some(needed - 1),
        },
    ] {
        let mut sim = Simulation::new(system.clone(), integrator).unwrap();
        let e = sim.step(h).unwrap_err();
        assert!(
            matches!(e, StepError::BelowStabilityBound { needed: n, recommended: r, .. }
                if n == needed && r == recommended),
            "{e:?}"
        );
        assert!(
            e.to_string()
                .contains(&format!("at least {needed} substeps")),
            "{e}"
        );
        assert_eq!(sim.system(), &system);
        assert!(run(&mut sim, h, 5).is_err());
    }
    for integrator in [
        Integrator::VelocityVerlet {
            substeps: Some(recommended),
        },
        Integrator::VelocityVerlet { substeps: None },
        Integrator::SymplecticEulerBounded { substeps: None },
    ] {
        let mut sim = Simulation::new(system.clone(), integrator).unwrap();
        let m = run(&mut sim, h, 30).unwrap();
        assert!(!m.diverged && m.steps == 30, "{m:?}");
        // After 30 steps the bound may have grown with the state; the count used is never
        // below the stability limit of the current state.
        let limit = StabilityBound::of(sim.system()).critical_substeps(h);
        let r = sim.step(h).unwrap();
        assert!(r.stable_substeps >= limit);
        assert!(r.substeps >= limit);
    }
    let e = Simulation::new(system, Integrator::VelocityVerlet { substeps: Some(0) }).unwrap_err();
    assert!(e.to_string().contains("substeps"));
}

/// One particle hanging on one spring from a fixed one, moving along the spring's axis:
/// a linear oscillator `s'' = -(k/m)(s - L)` while the spring stays stretched.
fn oscillator() -> (SpringSystem, impl Fn(f64) -> f64) {
    let (k, m, rest, s0) = (4.0, 1.0, 1.0, 1.5);
    let system = SpringSystem::new(
        &[
            Particle {
                fixed: true,
                ..Particle::at_rest(DVec3::ZERO, 1.0)
            },
            Particle::at_rest(DVec3::new(0.0, -s0, 0.0), m),
        ],
        &[SpringSpec {
            particles: [0, 1],
            rest_length: Some(rest),
            stiffness: Some(k),
        }],
        Material {
            damping: 0.0,
            gravity: DVec3::ZERO,
            stiffness: k,
        },
    )
    .unwrap();
    let omega = (k / m).sqrt();
    (system, move |t: f64| rest + (s0 - rest) * (omega * t).cos())
}

fn tight() -> NewtonSettings {
    NewtonSettings {
        tolerance: 1e-13,
        linear_solver: LinearSolverChoice::Direct,
        ..Default::default()
    }
}

/// Error at t = 1 against the exact solution, for steps 1/10, 1/20, 1/40, 1/80.
fn errors(integrator: Integrator) -> Vec<f64> {
    let (system, exact) = oscillator();
    [10, 20, 40, 80]
        .iter()
        .map(|&steps| {
            let mut sim = Simulation::new(system.clone(), integrator).unwrap();
            for _ in 0..steps {
                sim.step(1.0 / steps as f64).unwrap();
            }
            let s = -sim.system().positions()[1].y;
            (s - exact(1.0)).abs()
        })
        .collect()
}

#[test]
fn orders_of_convergence_on_the_linear_oscillator() {
    for (integrator, order) in [
        (Integrator::BackwardEuler(tight()), 1.0),
        (Integrator::Bdf2(tight()), 2.0),
        (Integrator::ImplicitMidpoint(tight()), 2.0),
        (Integrator::VelocityVerlet { substeps: Some(1) }, 2.0),
    ] {
        let e = errors(integrator);
        for w in e.windows(2) {
            let observed = (w[0] / w[1]).log2();
            assert!(
                (observed - order).abs() <= 0.15,
                "{integrator:?}: errors {e:?}, observed order {observed}"
            );
        }
    }
}

/// Implicit midpoint conserves the energy of linear (zero-rest-length) springs with
/// gravity to round-off; backward Euler on the same run loses a visible part of it.
#[test]
fn midpoint_conserves_the_energy_of_linear_springs() {
    let particles = [
        Particle {
            fixed: true,
            ..Particle::at_rest(DVec3::ZERO, 1.0)
        },
        Particle {
            velocity: DVec3::new(0.3, 0.0, -0.2),
            ..Particle::at_rest(DVec3::new(0.5, -0.4, 0.1), 1.0)
        },
        Particle {
            velocity: DVec3::new(0.0, 0.5, 0.1),
            ..Particle::at_rest(DVec3::new(1.0, -0.9, -0.3), 2.0)
        },
        Particle {
            velocity: DVec3::new(-0.4, 0.2, 0.0),
            ..Particle::at_rest(DVec3::new(0.2, -1.3, 0.4), 0.5)
        },
    ];
    let springs: Vec<SpringSpec> = [(0, 1, 30.0), (1, 2, 50.0), (2, 3, 20.0), (1, 3, 40.0)]
        .iter()
        .map(|&(a, b, k)| SpringSpec {
            particles: [a, b],
            rest_length: Some(0.0),
            stiffness: Some(k),
        })
        .collect();
    let material = Material {
        damping: 0.0,
        ..Material::lab()
    };
    let system = SpringSystem::new(&particles, &springs, material).unwrap();
    let e0 = system.energies().total();
    let drift = |integrator: Integrator| {
        let mut sim = Simulation::new(system.clone(), integrator).unwrap();
        let mut worst = 0.0f64;
        for _ in 0..300 {
            sim.step(0.05).unwrap();
            worst = worst.max((sim.system().energies().total() - e0).abs());
        }
        worst / e0.abs()
    };
    let midpoint = drift(Integrator::ImplicitMidpoint(tight()));
    assert!(midpoint <= 1e-12, "midpoint energy drift {midpoint}");
    let backward = drift(Integrator::BackwardEuler(tight()));
    assert!(backward >= 1e-3, "backward Euler energy drift {backward}");
}

/// BDF2 and midpoint stay finite and bounded on W5 k = 1e6 at h = 1/30 and 1/10 for 1 s.
#[test]
fn second_order_implicit_integrators_are_stable_at_large_steps() {
    let system = cloth(1e6, 0.0);
    for h in [1.0 / 30.0, 0.1] {
        for integrator in [
            Integrator::Bdf2(NewtonSettings::default()),
            Integrator::ImplicitMidpoint(NewtonSettings::default()),
        ] {
            let mut sim = Simulation::new(system.clone(), integrator).unwrap();
            let m = run(&mut sim, h, (1.0 / h).round() as usize).unwrap();
            assert!(!m.diverged, "{integrator:?} at h = {h}: {m:?}");
            assert!(
                sim.system()
                    .positions()
                    .iter()
                    .all(|x| x.is_finite() && x.length() < 100.0)
            );
        }
    }
}

/// `auto` never takes an explicit step with fewer substeps than the stability limit of
/// the state it starts from, never blows up, and reports why it chose what it chose.
#[test]
fn auto_never_picks_an_integrator_above_its_stability_bound() {
    let cases = [
        (cloth(100.0, 0.0), 1.0 / 60.0, 30),
        (cloth(100.0, 0.2), 0.5, 4),
        (cloth(1e4, 0.2), 1.0 / 30.0, 15),
        (cloth(1e6, 0.0), 1.0 / 30.0, 15),
        (cloth(1e6, 0.0), 0.1, 5),
    ];
    let mut seen = Vec::new();
    for (system, h, steps) in cases {
        for settings in [
            AutoSettings::default(),
            // An implicit step modelled as cheap as 2 substeps: BDF2 wherever the bound
            // asks for more.
            AutoSettings {
                implicit_cost_model: 2.0,
                ..Default::default()
            },
            AutoSettings {
                max_substeps: 10,
                ..Default::default()
            },
        ] {
            let mut sim = Simulation::new(system.clone(), Integrator::Auto(settings)).unwrap();
            for _ in 0..steps {
                let limit = StabilityBound::of(sim.system()).critical_substeps(h);
                let r = sim.step(h).unwrap();
                let reason = r.auto_reason.unwrap();
                seen.push((r.integrator, reason));
                match r.integrator {
                    IntegratorKind::VelocityVerlet => {
                        assert_eq!(reason, AutoReason::ExplicitCheapest);
                        assert!(r.substeps >= limit, "{} < {limit}", r.substeps);
                        assert!(r.substeps <= settings.max_substeps);
                        assert_eq!(r.substeps, r.stable_substeps);
                    }
                    IntegratorKind::Bdf2 => assert!(matches!(
                        reason,
                        AutoReason::ImplicitCheaper | AutoReason::SubstepCap
                    )),
                    other => panic!("auto chose {other:?}"),
                }
                assert!(r.energy_after.total().is_finite());
            }
        }
    }
    for wanted in [
        (IntegratorKind::VelocityVerlet, AutoReason::ExplicitCheapest),
        (IntegratorKind::Bdf2, AutoReason::ImplicitCheaper),
        (IntegratorKind::Bdf2, AutoReason::SubstepCap),
    ] {
        assert!(seen.contains(&wanted), "{wanted:?} never chosen");
    }
    let mut settle = Simulation::new(
        cloth(100.0, 0.2),
        Integrator::Auto(AutoSettings {
            settle: true,
            ..Default::default()
        }),
    )
    .unwrap();
    let r = settle.step(1.0 / 60.0).unwrap();
    assert_eq!(r.integrator, IntegratorKind::BackwardEuler);
    assert_eq!(r.auto_reason, Some(AutoReason::Settle));
}

/// Auto on W4 and W5 k = 1e6 at the default settings chooses Verlet at the bound's
/// count (the cheapest stable choice there).
#[test]
fn auto_chooses_verlet_on_the_workloads() {
    for (system, h) in [
        (cloth(100.0, 0.0), 1.0 / 60.0),
        (cloth(1e6, 0.0), 1.0 / 30.0),
    ] {
        let needed = StabilityBound::of(&system).substeps(h);
        let mut sim = Simulation::new(system, Integrator::Auto(AutoSettings::default())).unwrap();
        let r = sim.step(h).unwrap();
        assert_eq!(r.integrator, IntegratorKind::VelocityVerlet);
        assert_eq!(r.substeps, needed);
    }
}

/// The explicit force loop of a large system (W6 with damping 0.2, 10 201 particles) on
/// threads gathers each particle's spring forces in spring order, so 1, 2 and all threads
/// give bitwise the same steps, for velocity Verlet and symplectic Euler alike, and for
/// `auto`, whose explicit steps take its Newton settings' thread count.
#[test]
fn explicit_steps_of_w6_are_bitwise_the_same_on_one_and_two_threads() {
    let system = SpringSystem::cloth(&ClothGrid::lab_sized(101, 0.02).with_damping(0.2)).unwrap();
    let h = 1.0 / 60.0;
    let verlet = |threads: usize| {
        let mut vv = VelocityVerlet::new(&system, 3).unwrap();
        vv.set_threads(&system, threads).unwrap();
        let mut s = system.clone();
        for _ in 0..3 {
            vv.step(&mut s, h).unwrap();
        }
        s
    };
    let euler = |threads: usize| {
        let mut se = SymplecticEuler::new(&system, 3).unwrap();
        se.set_threads(&system, threads).unwrap();
        let mut s = system.clone();
        for _ in 0..3 {
            se.step(&mut s, h).unwrap();
        }
        s
    };
    // `auto` steps W6 by velocity Verlet on its Newton settings' thread count.
    let auto = |threads: usize| {
        let settings = AutoSettings {
            newton: NewtonSettings {
                threads,
                ..Default::default()
            },
            ..Default::default()
        };
        let mut sim = Simulation::new(system.clone(), Integrator::Auto(settings)).unwrap();
        for _ in 0..3 {
            let r = sim.step(h).unwrap();
            assert_eq!(r.integrator, IntegratorKind::VelocityVerlet);
        }
        sim.system().clone()
    };
    for run in [&verlet as &dyn Fn(usize) -> SpringSystem, &euler, &auto] {
        let one = run(1);
        assert_ne!(one.positions(), system.positions(), "the sheet moved");
        for threads in [2, 0] {
            let other = run(threads);
            assert_eq!(one.positions(), other.positions(), "{threads} threads");
            assert_eq!(one.velocities(), other.velocities(), "{threads} threads");
        }
    }
}
