//! The self-contact term on two small sheets 1.5 mm apart: its gradient against central
//! differences of its energy, its energy change against the direct difference, its
//! Hessian positive semidefinite, `max_step` stopping a step that would pass one sheet
//! through the other at the kept fraction of the gap, and the energy `+inf` within the
//! thickness.

use crate::common::{Sample, Xorshift as Rng};
use crate::sheets;
use sinew_math::DVec3;
use sinew_spring_sim::contact::self_contact::{
    SelfContactSettings, SelfContactTerm, additive_ccd, candidates,
};
use sinew_spring_sim::potential::{AtEndOfStep, HessianSink, StepContext, StepTiming, Term};
use sinew_spring_sim::spring::Curvature;
use sinew_spring_sim::{ClothGrid, HessianPattern, SpringSystem, StepError, TriangleMesh};

fn two_sheets() -> (SpringSystem, Vec<[usize; 3]>) {
    two_sheets_fixing(vec![0])
}

/// [`two_sheets`] with the particles `fixed` pinned.
fn two_sheets_fixing(fixed: Vec<usize>) -> (SpringSystem, Vec<[usize; 3]>) {
    let n = 3;
    let grid = ClothGrid {
        size: n,
        ..ClothGrid::lab()
    };
    let mut x = Vec::new();
    let mut t = grid.triangles();
    for (offset, h) in [(DVec3::ZERO, 0.0), (DVec3::new(0.013, 0.0, 0.021), 0.0015)] {
        let base = x.len();
        for i in 0..n {
            for j in 0..n {
                x.push(offset + DVec3::new(0.05 * i as f64, h, 0.05 * j as f64));
            }
        }
        if base > 0 {
            t.extend(
                grid.triangles()
                    .into_iter()
                    .map(|tri| tri.map(|v| v + base)),
            );
        }
    }
    // The term sees the masses (areal density 0.2) and gravity alone, not the springs.
    let mesh = TriangleMesh::new(x, t.clone()).unwrap();
    (sheets::cloth(fixed).build(&mesh).unwrap().system, t)
}

/// [`two_sheets`] with `dhat` 2 mm and a thickness of 0.5 mm (the sheets' 1.5 mm apart
/// leave a 1 mm gap).
fn two_sheets_thick() -> (SpringSystem, Vec<[usize; 3]>, SelfContactSettings) {
    let (system, triangles) = two_sheets();
    let settings = SelfContactSettings {
        dhat: 2e-3,
        thickness: 5e-4,
        ..SelfContactSettings::default()
    };
    (system, triangles, settings)
}

/// The reuse tests' setting: the two sheets with `dhat` 2 mm and thickness 0.5 mm, and a
/// direction that drifts the top sheet down and sideways by random amounts (at most
/// 0.1 mm per unit step, so the whole segment up to 8 steps stays clear of the bottom
/// sheet).
fn drifting_sheets(
    seed: u64,
) -> (
    SpringSystem,
    Vec<[usize; 3]>,
    SelfContactSettings,
    Vec<DVec3>,
) {
    let (system, triangles, settings) = two_sheets_thick();
    let mut rng = Rng(seed);
    let dx = (0..system.positions().len())
        .map(|i| {
            if i >= 9 {
                DVec3::new(
                    2e-5 * rng.signed(),
                    -8e-5 + 2e-5 * rng.signed(),
                    2e-5 * rng.signed(),
                )
            } else {
                DVec3::ZERO
            }
        })
        .collect();
    (system, triangles, settings, dx)
}

/// A term for `system` that has begun `step`. A fresh one has no list kept, so it hashes
/// the mesh for every query: the reference answer for a term that reuses its list.
fn begun(
    system: &SpringSystem,
    triangles: &[[usize; 3]],
    settings: SelfContactSettings,
    step: &StepContext,
) -> SelfContactTerm {
    let mut t = SelfContactTerm::new(system, triangles, settings).unwrap();
    t.begin_step(step);
    t
}

/// Checks `term`'s gradient at `at` bitwise equal to that of `fresh`, a term that has
/// kept nothing from earlier queries, given its active set at `at`.
fn assert_gradient_as_fresh(
    term: &SelfContactTerm,
    mut fresh: SelfContactTerm,
    step: &StepContext,
    at: &[DVec3],
) {
    let mut g = vec![DVec3::ZERO; at.len()];
    let mut g_fresh = g.clone();
    term.add_gradient(step, at, &mut g);
    fresh.update_active_set(step, at);
    fresh.add_gradient(step, at, &mut g_fresh);
    assert_eq!(g, g_fresh);
}

/// Checks the gradient `g` at `x` against central differences (step 1e-9) of `energy`
/// at every coordinate of every particle but the first (pinned in these sheets), to 1e-5
/// of the gradient's largest entry; returns that entry.
fn assert_central_differences(g: &[DVec3], x: &[DVec3], energy: impl Fn(&[DVec3]) -> f64) -> f64 {
    let h = 1e-9;
    let scale = g.iter().map(|v| v.abs().max_element()).fold(0.0, f64::max);
    for i in 1..x.len() {
        for c in 0..3 {
            let (mut xp, mut xm) = (x.to_vec(), x.to_vec());
            xp[i][c] += h;
            xm[i][c] -= h;
            let fd = (energy(&xp) - energy(&xm)) / (2.0 * h);
            assert!(
                (fd - g[i][c]).abs() <= 1e-5 * scale,
                "particle {i} coordinate {c}: {} vs {fd}",
                g[i][c]
            );
        }
    }
    scale
}

#[test]
fn the_term_is_one_consistent_function() {
    let (system, triangles) = two_sheets();
    let settings = SelfContactSettings {
        dhat: 2e-3,
        ..SelfContactSettings::default()
    };
    let mut term = SelfContactTerm::new(&system, &triangles, settings).unwrap();
    let x0 = system.positions().to_vec();
    let step = StepContext::new(&system, 1.0 / 60.0, &x0, &x0);
    term.begin_step(&step);
    assert!(term.kappa() > 0.0);
    let mut rng = Rng(7);
    // A state with the sheets a little crumpled, every gap between 0.5 and 2.5 mm.
    let x: Vec<DVec3> = x0
        .iter()
        .map(|p| *p + 2e-4 * DVec3::new(rng.signed(), rng.signed(), rng.signed()))
        .collect();
    let e = term.energy(&step, &x);
    assert!(e > 0.0 && e.is_finite(), "{e}");
    // The gradient against central differences (every free coordinate).
    let mut g = vec![DVec3::ZERO; x.len()];
    term.add_gradient(&step, &x, &mut g);
    let scale = assert_central_differences(&g, &x, |at| term.energy(&step, at));
    // The same gradient through the active set collected at x.
    term.update_active_set(&step, &x);
    let mut g2 = vec![DVec3::ZERO; x.len()];
    term.add_gradient(&step, &x, &mut g2);
    for (a, b) in g.iter().zip(&g2) {
        assert!((*a - *b).length() <= 1e-12 * scale);
    }
    // The change along a direction against the direct difference.
    let dx: Vec<DVec3> = (0..x.len())
        .map(|_| 5e-4 * DVec3::new(rng.signed(), rng.signed(), rng.signed()))
        .collect();
    for alpha in [1e-3, 0.1, 0.5] {
        let moved: Vec<DVec3> = x.iter().zip(&dx).map(|(p, d)| *p + alpha * *d).collect();
        let direct = term.energy(&step, &moved) - term.energy(&step, &x);
        let change = term.energy_change(&step, &x, &dx, alpha);
        assert!(
            (change - direct).abs() <= 1e-9 * e,
            "{alpha}: {change} vs {direct}"
        );
    }
    // The Hessian is positive semidefinite: z^T H z >= 0 for random z.
    let fixed = system.fixed().to_vec();
    for _ in 0..20 {
        let z: Vec<DVec3> = (0..x.len())
            .map(|_| DVec3::new(rng.signed(), rng.signed(), rng.signed()))
            .collect();
        let mut out = vec![DVec3::ZERO; x.len()];
        let mut sink = HessianSink::product(&fixed, &z, &mut out);
        term.add_hessian(&step, &x, Curvature::Clamped, &mut sink);
        let q: f64 = z.iter().zip(&out).map(|(a, b)| a.dot(*b)).sum();
        let norm: f64 = out.iter().map(|v| v.length()).sum();
        assert!(q >= -1e-12 * norm, "{q}");
        assert!(norm > 0.0);
    }
}

#[test]
fn max_step_stops_a_step_through_the_other_sheet() {
    let (system, triangles, settings) = two_sheets_thick();
    let mut term = SelfContactTerm::new(&system, &triangles, settings).unwrap();
    let x = system.positions().to_vec();
    let step = StepContext::new(&system, 1.0 / 60.0, &x, &x);
    term.begin_step(&step);
    // The top sheet moves 3 mm down: through the bottom sheet (1.5 mm below it).
    let dx: Vec<DVec3> = (0..x.len())
        .map(|i| {
            if i >= 9 {
                DVec3::new(0.0, -3e-3, 0.0)
            } else {
                DVec3::ZERO
            }
        })
        .collect();
    let alpha = term.max_step(&step, &x, &dx, f64::INFINITY);
    // The gap is 1 mm (1.5 mm minus the thickness), closing at 3 mm per unit step: it
    // would vanish at 1/3, and a tenth of it is kept, so alpha = 0.9 / 3.
    assert!((alpha - 0.3).abs() < 1e-9, "{alpha}");
    let moved: Vec<DVec3> = x.iter().zip(&dx).map(|(p, d)| *p + alpha * *d).collect();
    assert!(term.min_gap(&moved, system.fixed()) > 0.0);
    assert!(term.energy(&step, &moved).is_finite());
    // The full step's end: through the sheet and out, but the energy's change to within
    // the thickness is infinite, so no line search accepts it.
    let within: Vec<DVec3> = x.iter().zip(&dx).map(|(p, d)| *p + 0.45 * *d).collect();
    assert_eq!(term.energy(&step, &within), f64::INFINITY);
    assert_eq!(term.energy_change(&step, &x, &dx, 0.45), f64::INFINITY);
    // A step moving the sheets apart is not capped below the full step.
    let apart: Vec<DVec3> = (0..x.len())
        .map(|i| {
            if i >= 9 {
                DVec3::new(0.0, 1e-3, 0.0)
            } else {
                DVec3::ZERO
            }
        })
        .collect();
    assert!(term.max_step(&step, &x, &apart, f64::INFINITY) >= 1.0);
}

#[test]
fn max_step_looks_beyond_the_full_step_only_when_asked_to() {
    let (system, triangles, settings) = two_sheets_thick();
    let x = system.positions().to_vec();
    let step = StepContext::new(&system, 1.0 / 60.0, &x, &x);
    let begun = || {
        let mut term = SelfContactTerm::new(&system, &triangles, settings).unwrap();
        term.begin_step(&step);
        term
    };
    let down = |by: f64| -> Vec<DVec3> {
        (0..x.len())
            .map(|i| {
                if i >= 9 {
                    DVec3::new(0.0, -by, 0.0)
                } else {
                    DVec3::ZERO
                }
            })
            .collect()
    };
    // Through the other sheet: capped below the full step, the same bits at any reach.
    let through = down(3e-3);
    let capped = begun().max_step(&step, &x, &through, f64::INFINITY);
    assert!(capped < 1.0, "{capped}");
    assert_eq!(
        capped.to_bits(),
        begun().max_step(&step, &x, &through, 1.0).to_bits()
    );
    // 0.2 mm down: the full step is clear (the 1 mm gap closes to 0.8 mm) and eight of
    // it are not (1.6 mm). Asked for the largest, the term looks along the longer path:
    // a tenth of the gap kept, 8 (0.9 / 1.6) = 4.5 steps. Asked about the step alone, it
    // answers the step.
    let near = down(2e-4);
    let longest = begun().max_step(&step, &x, &near, f64::INFINITY);
    assert!((longest - 4.5).abs() < 1e-9, "{longest}");
    let term = begun();
    let moved: Vec<DVec3> = x
        .iter()
        .zip(&near)
        .map(|(p, d)| *p + longest * *d)
        .collect();
    assert!(term.min_gap(&moved, system.fixed()) > 0.0);
    assert_eq!(begun().max_step(&step, &x, &near, 1.0), 1.0);
    assert_eq!(begun().max_step(&step, &x, &near, 0.5), 1.0);
    // A reach between the two: the longer path is looked along.
    assert_eq!(
        begun().max_step(&step, &x, &near, 2.0).to_bits(),
        longest.to_bits()
    );
}

/// The smallest safe fraction of `x -> x + dx` over every pair the broad phase lists,
/// each swept by `additive_ccd` (1 when none caps it): what `max_step` answers for the
/// step itself.
fn swept_over_every_pair(term: &SelfContactTerm, x: &[DVec3], dx: &[DVec3], fixed: &[bool]) -> f64 {
    let s = term.settings();
    let prims = term.primitives();
    let pairs = candidates(prims, x, Some(dx), s.dhat + s.thickness, fixed);
    assert!(!pairs.is_empty());
    pairs
        .iter()
        .map(|&c| {
            let (kind, v) = c.kind_and_particles(prims);
            additive_ccd(
                kind,
                &v.map(|i| x[i]),
                &v.map(|i| dx[i]),
                s.thickness,
                1.0 - s.toi_fraction,
            )
        })
        .fold(1.0, f64::min)
}

#[test]
fn a_move_of_pinned_particles_alone_is_capped_as_every_pair_caps_it() {
    // The top sheet's first row (particles 9, 10, 11) is pinned and moved alone; the
    // term sweeps only the pairs touching it, and must answer what sweeping every
    // listed pair answers.
    let (system, triangles) = two_sheets_fixing(vec![0, 9, 10, 11]);
    let settings = two_sheets_thick().2;
    let x = system.positions().to_vec();
    let fixed = system.fixed();
    let step = StepContext::new(&system, 1.0 / 60.0, &x, &x);
    let pins_down = |by: DVec3| -> Vec<DVec3> {
        (0..x.len())
            .map(|i| {
                if (9..12).contains(&i) {
                    by
                } else {
                    DVec3::ZERO
                }
            })
            .collect()
    };
    // Down through the bottom sheet (its 1 mm gap closes at 3 mm per unit step) and
    // sideways: capped below a third, the bits of every pair's sweep, at any reach.
    let through = pins_down(DVec3::new(0.002, -3e-3, 0.001));
    let term = begun(&system, &triangles, settings, &step);
    let stats = term.stats();
    let before = stats.broad_phases();
    let capped = term.max_step(&step, &x, &through, f64::INFINITY);
    assert!(capped > 0.0 && capped < 1.0 / 3.0, "{capped}");
    let every = swept_over_every_pair(&term, &x, &through, fixed);
    assert_eq!(capped.to_bits(), every.to_bits());
    assert_eq!(
        term.max_step(&step, &x, &through, 1.0).to_bits(),
        every.to_bits()
    );
    // Each sweep of the move is a broad phase of its own (the first capped the step,
    // so it did not look along the longer one).
    assert_eq!(stats.broad_phases(), before + 2);
    // A short move: the full step is clear, and along eight of it the term answers
    // every pair's sweep of the longer step, times eight.
    let near = pins_down(DVec3::new(0.0, -2e-4, 0.0));
    let longest = term.max_step(&step, &x, &near, f64::INFINITY);
    let long: Vec<DVec3> = near.iter().map(|d| 8.0 * *d).collect();
    let every_long = 8.0 * swept_over_every_pair(&term, &x, &long, fixed);
    assert!(longest > 1.0 && longest < 8.0, "{longest}");
    assert_eq!(longest.to_bits(), every_long.to_bits());
    assert_eq!(term.max_step(&step, &x, &near, 1.0), 1.0);
}

#[test]
fn one_broad_phase_serves_the_whole_line_search_segment_with_unchanged_answers() {
    let (system, triangles, settings, dx) = drifting_sheets(31);
    let x = system.positions().to_vec();
    let step = StepContext::new(&system, 1.0 / 60.0, &x, &x);
    let mut term = begun(&system, &triangles, settings, &step);
    let fresh = || begun(&system, &triangles, settings, &step);
    let stats = term.stats();
    let before = stats.broad_phases();
    let cap = term.max_step(&step, &x, &dx, f64::INFINITY);
    assert_eq!(cap, fresh().max_step(&step, &x, &dx, f64::INFINITY));
    assert!(cap >= 1.0, "{cap}");
    // The cap hashed the mesh once for the whole segment.
    assert_eq!(stats.broad_phases(), before + 1);
    let mut nonzero = 0;
    for alpha in [0.125, 0.5, 1.0, 2.0, 4.0, 8.0_f64.min(cap)] {
        let end: Vec<DVec3> = x.iter().zip(&dx).map(|(p, d)| *p + alpha * *d).collect();
        let change = term.energy_change(&step, &x, &dx, alpha);
        assert_eq!(
            change.to_bits(),
            fresh().energy_change(&step, &x, &dx, alpha).to_bits()
        );
        let energy = term.energy(&step, &end);
        assert_eq!(energy.to_bits(), fresh().energy(&step, &end).to_bits());
        nonzero += usize::from(change != 0.0);
        term.update_active_set(&step, &end);
        assert_gradient_as_fresh(&term, fresh(), &step, &end);
    }
    // Every query above lay inside the segment: no further hashing.
    assert_eq!(stats.broad_phases(), before + 1);
    // The pairs act (the changes are not all zero).
    assert!(nonzero > 0);
    // A state outside the segment is hashed again.
    let far: Vec<DVec3> = x.iter().zip(&dx).map(|(p, d)| *p + 20.0 * *d).collect();
    let _ = term.energy(&step, &far);
    assert_eq!(stats.broad_phases(), before + 2);
}

#[test]
fn the_next_iterations_segment_inside_the_kept_region_is_not_hashed_and_answers_unchanged() {
    let (system, triangles, settings, dx) = drifting_sheets(57);
    let x = system.positions().to_vec();
    let step = StepContext::new(&system, 1.0 / 60.0, &x, &x);
    let mut term = begun(&system, &triangles, settings, &step);
    let fresh = || begun(&system, &triangles, settings, &step);
    let stats = term.stats();
    let before = stats.broad_phases();
    let _ = term.max_step(&step, &x, &dx, f64::INFINITY);
    assert_eq!(stats.broad_phases(), before + 1);
    // Newton's next iterates: on the segment, each with a shorter direction along it, as
    // when Newton converges. Their segments lie inside the first one's region.
    let mut at = x.clone();
    let mut nonzero = 0;
    for (alpha, shrink) in [(1.0, 0.5), (1.0, 0.5), (0.5, 0.25)] {
        at = at.iter().zip(&dx).map(|(p, d)| *p + alpha * *d).collect();
        let next: Vec<DVec3> = dx.iter().map(|d| shrink * *d).collect();
        term.update_active_set(&step, &at);
        let cap = term.max_step(&step, &at, &next, f64::INFINITY);
        assert_eq!(
            cap.to_bits(),
            fresh().max_step(&step, &at, &next, f64::INFINITY).to_bits()
        );
        for trial in [0.25, 1.0, 2.0] {
            let change = term.energy_change(&step, &at, &next, trial);
            let reference = fresh().energy_change(&step, &at, &next, trial);
            assert_eq!(change.to_bits(), reference.to_bits());
            nonzero += usize::from(change != 0.0);
        }
        assert_gradient_as_fresh(&term, fresh(), &step, &at);
    }
    // No iteration after the first hashed the mesh, and the pairs act.
    assert_eq!(stats.broad_phases(), before + 1);
    assert!(nonzero > 0);
}

#[test]
fn a_step_starting_at_the_last_active_set_takes_its_values_and_answers_as_a_fresh_term() {
    // A step starts where the last one ended, the state its last active set was
    // collected at: the start check and the first guess's segment (cap, then energy
    // change) take that set's gaps and separations. Every answer must be the bits of a
    // term that kept nothing, at states with pairs within `dhat` and, last, with a pair
    // pushed within the thickness (the check must refuse it, naming the same pair).
    let (system, triangles, settings, dx) = drifting_sheets(91);
    // The state each step starts from (the step's context keeps the first one).
    let mut start = system.clone();
    let x0 = system.positions().to_vec();
    let v = vec![DVec3::ZERO; x0.len()];
    let step = StepContext::new(&system, 1.0 / 60.0, &x0, &x0);
    let mut term = begun(&system, &triangles, settings, &step);
    let fresh = || begun(&system, &triangles, settings, &step);
    let stats = term.stats();
    let mut active = 0;
    for alpha in [0.0, 3.0, 6.0] {
        let at: Vec<DVec3> = x0.iter().zip(&dx).map(|(p, d)| *p + alpha * *d).collect();
        term.update_active_set(&step, &at);
        active = active.max(stats.active_pairs());
        start.set_state(&at, &v).unwrap();
        assert!(term.check_start(&start, 0.0).is_ok());
        let path: Vec<DVec3> = dx.iter().map(|d| 0.5 * *d).collect();
        let cap = term.max_step(&step, &at, &path, 1.0);
        let change = term.energy_change(&step, &at, &path, 1.0);
        let reference = fresh();
        assert_eq!(
            cap.to_bits(),
            reference.max_step(&step, &at, &path, 1.0).to_bits()
        );
        assert_eq!(
            change.to_bits(),
            fresh().energy_change(&step, &at, &path, 1.0).to_bits()
        );
    }
    assert!(active > 0, "no pair within dhat: the case tests nothing");
    // The top sheet's first vertex (9) moved onto the bottom sheet's plane, inside
    // its triangles: within the thickness.
    let mut touching = x0.clone();
    touching[9].y = 1e-4;
    term.update_active_set(&step, &touching);
    start.set_state(&touching, &v).unwrap();
    let kept = term.check_start(&start, 0.0).unwrap_err();
    let reference = fresh().check_start(&start, 0.0).unwrap_err();
    assert!(matches!(kept, StepError::SelfContactStart { .. }), "{kept}");
    assert_eq!(kept.to_string(), reference.to_string());
}

#[test]
fn an_active_set_at_a_trials_state_takes_its_values_and_answers_as_a_fresh_term() {
    // The line search's trials keep their pairs' values at the states they tried; an
    // active set collected at the state of one of the two latest (the accepted step, or
    // the full step before a refused doubled one) takes them. Its gradient, Hessians in
    // both forms, energy, smallest gap and start check must be the bits of a term that
    // collected the set afresh.
    let (system, triangles, settings, dx) = drifting_sheets(57);
    let x0 = system.positions().to_vec();
    let v = vec![DVec3::ZERO; x0.len()];
    let mut start = system.clone();
    let step = StepContext::new(&system, 1.0 / 60.0, &x0, &x0);
    let mut term = begun(&system, &triangles, settings, &step);
    let stats = term.stats();
    let mut rng = Rng(5);
    let mut active = 0;
    for (alpha, accepted) in [(3.0, 2.0), (5.0, 1.0), (6.0, 2.0)] {
        let at: Vec<DVec3> = x0.iter().zip(&dx).map(|(p, d)| *p + alpha * *d).collect();
        term.update_active_set(&step, &at);
        let path: Vec<DVec3> = dx.iter().map(|d| 0.5 * *d).collect();
        assert!(term.max_step(&step, &at, &path, 1.0) > 0.0);
        // The full step, then the doubled one; either may be the one accepted.
        let _ = term.energy_change(&step, &at, &path, 1.0);
        let _ = term.energy_change(&step, &at, &path, 2.0);
        let next: Vec<DVec3> = at
            .iter()
            .zip(&path)
            .map(|(p, d)| *p + accepted * *d)
            .collect();
        term.update_active_set(&step, &next);
        active = active.max(stats.active_pairs());
        let mut reference = begun(&system, &triangles, settings, &step);
        reference.update_active_set(&step, &next);
        assert_eq!(stats.active_pairs(), reference.stats().active_pairs());
        assert_eq!(
            stats.min_gap().to_bits(),
            reference.stats().min_gap().to_bits()
        );
        let (mut g, mut g_reference) = (vec![DVec3::ZERO; x0.len()], vec![DVec3::ZERO; x0.len()]);
        term.add_gradient(&step, &next, &mut g);
        reference.add_gradient(&step, &next, &mut g_reference);
        assert_eq!(g, g_reference);
        assert_eq!(
            term.energy(&step, &next).to_bits(),
            reference.energy(&step, &next).to_bits()
        );
        let z: Vec<DVec3> = (0..x0.len())
            .map(|_| DVec3::new(rng.signed(), rng.signed(), rng.signed()))
            .collect();
        for curvature in [Curvature::Clamped, Curvature::ExactContact(1.0)] {
            assert_eq!(
                hessian_product(&term, &step, &next, curvature, &z),
                hessian_product(&reference, &step, &next, curvature, &z)
            );
        }
        // The next line search from that state starts from the values the active set
        // took (separations, gaps and the trial's energies).
        let further: Vec<DVec3> = path.iter().map(|d| 0.5 * *d).collect();
        assert_eq!(
            term.max_step(&step, &next, &further, 1.0).to_bits(),
            reference.max_step(&step, &next, &further, 1.0).to_bits()
        );
        assert_eq!(
            term.energy_change(&step, &next, &further, 1.0).to_bits(),
            reference
                .energy_change(&step, &next, &further, 1.0)
                .to_bits()
        );
        start.set_state(&next, &v).unwrap();
        assert!(term.check_start(&start, 0.0).is_ok());
        assert!(reference.check_start(&start, 0.0).is_ok());
    }
    assert!(active > 0, "no pair within dhat: the case tests nothing");
}

#[test]
fn a_query_that_repeats_the_last_takes_its_answer_and_no_other_does() {
    // The cap's sweep of a step and the line search's trial of the full step ask the same
    // swept boxes, and the second takes the first's answer. The top sheet starts 5.5 mm
    // above the bottom one and the step lowers it 0.5 mm, so the cap's segment (8 steps)
    // reaches pairs within dhat that the step itself does not: a trial 7.5 steps long,
    // a step from 7 steps lower, and the full step again after them must each answer as
    // a fresh term, which a trial given the last query's answer would not.
    let (system, triangles, settings) = two_sheets_thick();
    let x0 = system.positions().to_vec();
    let lift = |i: usize, by: f64| {
        if i >= 9 {
            DVec3::new(0.0, by, 0.0)
        } else {
            DVec3::ZERO
        }
    };
    let at: Vec<DVec3> = x0
        .iter()
        .enumerate()
        .map(|(i, p)| *p + lift(i, 4e-3))
        .collect();
    let path: Vec<DVec3> = (0..x0.len()).map(|i| lift(i, -5e-4)).collect();
    let long: Vec<DVec3> = path.iter().map(|d| 7.5 * *d).collect();
    let lower: Vec<DVec3> = at.iter().zip(&path).map(|(p, d)| *p + 7.0 * *d).collect();
    let step = StepContext::new(&system, 1.0 / 60.0, &at, &at);
    let mut term = begun(&system, &triangles, settings, &step);
    term.update_active_set(&step, &at);
    assert_eq!(term.max_step(&step, &at, &path, 1.0), 1.0);
    let trials = [
        (&at, &path),
        (&at, &long),
        (&at, &path),
        (&lower, &path),
        (&at, &path),
    ];
    let mut changes = Vec::new();
    for (x, d) in trials {
        let fresh = begun(&system, &triangles, settings, &step);
        let change = term.energy_change(&step, x, d, 1.0);
        assert_eq!(
            change.to_bits(),
            fresh.energy_change(&step, x, d, 1.0).to_bits()
        );
        changes.push(change);
    }
    assert_eq!(changes[0], 0.0, "the step itself comes within dhat");
    assert!(
        changes[1] > 0.0 && changes[3] > 0.0,
        "{changes:?}: the case tests nothing"
    );
}

#[test]
fn the_places_kept_from_the_last_active_set_give_a_fresh_terms_matrix() {
    // The term keeps the places its active pairs' blocks have in the Newton matrix and
    // looks up only the pairs new to the next active set. Active sets that gain and lose
    // pairs (the top sheet slid partly off the other and back), on a pattern with every particle pair, then
    // on one without some (the same active set: every place is another), must give the
    // values a fresh term gives.
    let (system, triangles) = two_sheets();
    let n = system.len();
    let all: Vec<[usize; 2]> = (0..n)
        .flat_map(|i| (i + 1..n).map(move |j| [i, j]))
        .collect();
    let some: Vec<[usize; 2]> = all
        .iter()
        .copied()
        .filter(|[i, j]| (i + j) % 3 != 0)
        .collect();
    let full = HessianPattern::with_pairs(&system, &all);
    let partial = HessianPattern::with_pairs(&system, &some);
    let x0 = system.positions().to_vec();
    let step = StepContext::new(&system, 1.0 / 60.0, &x0, &x0);
    let settings = SelfContactSettings {
        dhat: 2e-3,
        ..SelfContactSettings::default()
    };
    let mut term = begun(&system, &triangles, settings, &step);
    let values = |term: &SelfContactTerm, x: &[DVec3], pattern: &HessianPattern| {
        let mut v = vec![0.0; pattern.nnz()];
        let mut sink = HessianSink::values(pattern, &mut v);
        term.add_hessian(&step, x, Curvature::Clamped, &mut sink);
        v
    };
    let mut counts = Vec::new();
    for (slide, pattern) in [
        (0.0, &full),
        (0.07, &full),
        (0.035, &full),
        (0.07, &full),
        (0.07, &partial),
        (0.0, &partial),
        (0.0, &full),
    ] {
        let x: Vec<DVec3> = x0
            .iter()
            .enumerate()
            .map(|(i, p)| {
                *p + if i >= 9 {
                    DVec3::new(slide, 0.0, 0.0)
                } else {
                    DVec3::ZERO
                }
            })
            .collect();
        term.update_active_set(&step, &x);
        counts.push(term.stats().active_pairs());
        let mut fresh = begun(&system, &triangles, settings, &step);
        fresh.update_active_set(&step, &x);
        let v = values(&term, &x, pattern);
        assert!(v.iter().any(|&e| e != 0.0));
        assert_eq!(v, values(&fresh, &x, pattern), "slide {slide}");
    }
    assert!(
        counts[0] != counts[1] && counts[1] != counts[2],
        "{counts:?}: the active sets are alike"
    );
}

/// `H z` of `term` at `x` in the form `curvature` asks for.
fn hessian_product(
    term: &SelfContactTerm,
    step: &StepContext,
    x: &[DVec3],
    curvature: Curvature,
    z: &[DVec3],
) -> Vec<DVec3> {
    let fixed = step.system.fixed().to_vec();
    let mut out = vec![DVec3::ZERO; x.len()];
    let mut sink = HessianSink::product(&fixed, z, &mut out);
    term.add_hessian(step, x, curvature, &mut sink);
    out
}

/// `H z` of `term`'s exact form at `x`, checked against central differences of its
/// gradient along `z` (a step of 1e-9) at every particle from `from` on, to `tolerance`
/// of the product's largest entry (which must not be zero).
fn exact_form_against_differences(
    term: &SelfContactTerm,
    step: &StepContext,
    x: &[DVec3],
    z: &[DVec3],
    from: usize,
    tolerance: f64,
) -> Vec<DVec3> {
    let hz = hessian_product(term, step, x, Curvature::ExactContact(1.0), z);
    let eps = 1e-9;
    let gradient_at = |s: f64| {
        let moved: Vec<DVec3> = x.iter().zip(z).map(|(p, d)| *p + s * *d).collect();
        let mut g = vec![DVec3::ZERO; x.len()];
        term.add_gradient(step, &moved, &mut g);
        g
    };
    let (gp, gm) = (gradient_at(eps), gradient_at(-eps));
    let scale = hz.iter().map(|v| v.abs().max_element()).fold(0.0, f64::max);
    assert!(scale > 0.0, "no pair within dhat");
    for i in from..x.len() {
        let fd = (gp[i] - gm[i]) / (2.0 * eps);
        assert!(
            (fd - hz[i]).abs().max_element() <= tolerance * scale,
            "particle {i}: {} vs {fd}",
            hz[i]
        );
    }
    hz
}

#[test]
fn the_exact_hessian_matches_differences_of_the_gradient_and_the_projection_follows_it() {
    let (system, triangles) = two_sheets();
    let exact_settings = SelfContactSettings {
        dhat: 2e-3,
        exact_hessian: true,
        ..SelfContactSettings::default()
    };
    let projected_settings = SelfContactSettings {
        exact_hessian: false,
        ..exact_settings
    };
    let x0 = system.positions().to_vec();
    let step = StepContext::new(&system, 1.0 / 60.0, &x0, &x0);
    let mut term = begun(&system, &triangles, exact_settings, &step);
    let mut projected = begun(&system, &triangles, projected_settings, &step);
    let stats = term.stats();
    let mut rng = Rng(23);
    let x: Vec<DVec3> = x0
        .iter()
        .map(|p| *p + 2e-4 * DVec3::new(rng.signed(), rng.signed(), rng.signed()))
        .collect();
    let free = |v: &mut Vec<DVec3>| v[0] = DVec3::ZERO;
    let mut differs = false;
    // Twice: at a state the active set was not collected at (computed afresh), then at
    // the active set's state (the kept slots, in whichever form they were filled).
    for collected in [false, true] {
        if collected {
            term.update_active_set(&step, &x);
            projected.update_active_set(&step, &x);
        }
        for _ in 0..6 {
            let mut z: Vec<DVec3> = (0..x.len())
                .map(|_| DVec3::new(rng.signed(), rng.signed(), rng.signed()))
                .collect();
            free(&mut z);
            let hz = exact_form_against_differences(&term, &step, &x, &z, 1, 1e-5);
            // The projection, asked for after the exact form, is the projected term's,
            // to the bit; the exact form asked again is the same as before.
            let clamped = hessian_product(&term, &step, &x, Curvature::Clamped, &z);
            let reference = hessian_product(&projected, &step, &x, Curvature::Clamped, &z);
            assert_eq!(clamped, reference);
            differs |= clamped != hz;
            let again = hessian_product(&term, &step, &x, Curvature::ExactContact(1.0), &z);
            assert_eq!(again, hz);
            // Without the setting the term gives its projection whatever is asked.
            let refused = hessian_product(&projected, &step, &x, Curvature::ExactContact(1.0), &z);
            assert_eq!(refused, reference);
        }
    }
    assert!(differs, "the exact and projected Hessians never differed");
    assert!(stats.exact_hessians() > 0);
    // At the collected state the projection was asked for after the exact form: one
    // fallback counted for that iterate, however many times it was asked.
    assert_eq!(stats.projected_after_exact(), 1);
    assert_eq!(projected.stats().exact_hessians(), 0);
    assert_eq!(projected.stats().projected_after_exact(), 0);
}

/// Two triangles whose edges `0-1` and `3-4` are 1.5 mm apart and all but parallel (at
/// 1e-3 rad: the edge pair is mollified), the second triangle standing up from its edge,
/// so that few other pairs come within `dhat`.
fn near_parallel_edges() -> (SpringSystem, Vec<[usize; 3]>) {
    let angle: f64 = 1e-3;
    let x = vec![
        DVec3::new(0.0, 0.0, 0.0),
        DVec3::new(0.05, 0.0, 0.0),
        DVec3::new(0.0, 0.0, 0.05),
        DVec3::new(0.01, 1.5e-3, 0.0),
        DVec3::new(0.01 + 0.03 * angle.cos(), 1.5e-3, 0.03 * angle.sin()),
        DVec3::new(0.025, 0.03, 0.0),
    ];
    let t = vec![[0, 1, 2], [3, 4, 5]];
    let mesh = TriangleMesh::new(x, t.clone()).unwrap();
    let mut cloth = sheets::cloth(Vec::new());
    cloth.material.gravity = DVec3::ZERO;
    (cloth.build(&mesh).unwrap().system, t)
}

/// The exact form is the Hessian of the term's energy for mollified edge pairs too: on
/// near-parallel edges the exact form's product matches central differences of the
/// gradient to 1e-7 of its size (with the mollified pair projected it misses by about
/// 2e-4), and differs from the projected form's.
#[test]
fn the_exact_form_is_the_hessian_of_mollified_edge_pairs_too() {
    let (system, triangles) = near_parallel_edges();
    let settings = SelfContactSettings {
        dhat: 2e-3,
        ..SelfContactSettings::default()
    };
    let x0 = system.positions().to_vec();
    let step = StepContext::new(&system, 1.0 / 60.0, &x0, &x0);
    let mut term = begun(&system, &triangles, settings, &step);
    let mut rng = Rng(31);
    let mut differs = false;
    for _ in 0..8 {
        let x: Vec<DVec3> = x0
            .iter()
            .map(|p| *p + 1e-5 * DVec3::new(rng.signed(), rng.signed(), rng.signed()))
            .collect();
        term.update_active_set(&step, &x);
        let z: Vec<DVec3> = (0..x.len())
            .map(|_| DVec3::new(rng.signed(), rng.signed(), rng.signed()))
            .collect();
        let hz = exact_form_against_differences(&term, &step, &x, &z, 0, 1e-7);
        let projected = hessian_product(&term, &step, &x, Curvature::Clamped, &z);
        differs |= projected != hz;
    }
    assert!(differs, "the exact and projected forms never differed");
}

#[test]
fn at_the_midpoint_the_term_is_evaluated_at_the_end_state() {
    // The implicit midpoint's unknowns are the step's midpoint z; its end state is
    // w = 2 z - x_n. Wrapped, the term's energy at z is the plain term's at w (a backward
    // Euler step of the real length from x_n), its gradient twice the plain one at w and
    // the central differences of its own energy in z, its Hessian four times the plain
    // one (as values on a pattern, as row sums and as a product), and its cap along dz
    // the plain cap along 2 dz.
    let (system, triangles) = two_sheets();
    let settings = SelfContactSettings {
        dhat: 2e-3,
        mu: 0.3,
        ..SelfContactSettings::default()
    };
    let x0 = system.positions().to_vec();
    let (h_e, length) = (1.0 / 120.0, 1.0 / 60.0);
    let timing = StepTiming {
        start: 0.0,
        length,
        midpoint: true,
    };
    let step = StepContext::new(&system, h_e, &x0, &x0).with_timing(timing);
    let ends = StepContext::new(&system, length, &x0, &x0);
    let mut wrapped =
        AtEndOfStep::new(SelfContactTerm::new(&system, &triangles, settings).unwrap());
    wrapped.begin_step(&step);
    let mut plain = begun(&system, &triangles, settings, &ends);
    let mut rng = Rng(11);
    // A midpoint whose end state is crumpled (every gap between 0.5 and 2.5 mm), that
    // end state computed as the scheme computes it.
    let z: Vec<DVec3> = x0
        .iter()
        .map(|p| *p + 1e-4 * DVec3::new(rng.signed(), rng.signed(), rng.signed()))
        .collect();
    let w: Vec<DVec3> = z.iter().zip(&x0).map(|(z, x)| 2.0 * *z - *x).collect();
    // Friction lagged where the midpoint's iterate says (the wrapped term maps it).
    assert!(wrapped.relag_friction(&step, &z));
    assert!(plain.relag_friction(&ends, &w));
    wrapped.update_active_set(&step, &z);
    plain.update_active_set(&ends, &w);
    let e = wrapped.energy(&step, &z);
    assert!(e > 0.0 && e.is_finite(), "{e}");
    assert_eq!(e, plain.energy(&ends, &w));
    let mut g = vec![DVec3::ZERO; z.len()];
    wrapped.add_gradient(&step, &z, &mut g);
    let mut g_end = vec![DVec3::ZERO; z.len()];
    plain.add_gradient(&ends, &w, &mut g_end);
    for i in 1..z.len() {
        assert_eq!(g[i], 2.0 * g_end[i], "particle {i}");
    }
    assert_central_differences(&g, &z, |at| wrapped.energy(&step, at));
    // The Hessian, three ways.
    let pattern = HessianPattern::with_pairs(
        &system,
        &(0..z.len())
            .flat_map(|i| (i + 1..z.len()).map(move |j| [i, j]))
            .collect::<Vec<_>>(),
    );
    let fixed = system.fixed().to_vec();
    let v: Vec<DVec3> = (0..z.len())
        .map(|_| DVec3::new(rng.signed(), rng.signed(), rng.signed()))
        .collect();
    let hessian = |term: &dyn Term, s: &StepContext, at: &[DVec3]| {
        let mut values = vec![0.0; pattern.nnz()];
        term.add_hessian(
            s,
            at,
            Curvature::Clamped,
            &mut HessianSink::values(&pattern, &mut values),
        );
        let mut rows = vec![DVec3::ZERO; at.len()];
        term.add_hessian(
            s,
            at,
            Curvature::Clamped,
            &mut HessianSink::row_sums(&fixed, &mut rows),
        );
        let mut product = vec![DVec3::ZERO; at.len()];
        term.add_hessian(
            s,
            at,
            Curvature::Clamped,
            &mut HessianSink::product(&fixed, &v, &mut product),
        );
        (values, rows, product)
    };
    let (values, rows, product) = hessian(&wrapped, &step, &z);
    let (values_end, rows_end, product_end) = hessian(&plain, &ends, &w);
    assert!(values_end.iter().any(|&x| x != 0.0));
    for (a, b) in values.iter().zip(&values_end) {
        assert_eq!(*a, 4.0 * b);
    }
    for (a, b) in rows
        .iter()
        .zip(&rows_end)
        .chain(product.iter().zip(&product_end))
    {
        assert_eq!(*a, 4.0 * *b);
    }
    // The cap: the end state moves along 2 dz by the same fraction. The top sheet pushed
    // down through the lower one stops short of it.
    let dz: Vec<DVec3> = (0..z.len())
        .map(|i| {
            if i >= 9 {
                DVec3::new(0.0, -2e-3, 0.0)
            } else {
                DVec3::ZERO
            }
        })
        .collect();
    let dw: Vec<DVec3> = dz.iter().map(|d| 2.0 * *d).collect();
    let cap = wrapped.max_step(&step, &z, &dz, 1.0);
    assert!(cap > 0.0 && cap < 1.0, "{cap}");
    assert_eq!(cap, plain.max_step(&ends, &w, &dw, 1.0));
}
