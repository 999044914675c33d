//! Friction between the cloth's own primitives: a small sheet lying on a larger pinned
//! one, with gravity tilted by `theta` from the sheets' normal (the same as an incline of
//! angle `theta`). With `mu > tan theta` the top sheet stays put (it creeps no faster than
//! `eps_v`); with `mu < tan theta` it slides with Coulomb's acceleration
//! `g (sin theta - mu cos theta)`; without friction it slides at `g sin theta`. Every
//! accepted state is checked by brute force to keep every pair's gap positive.

use crate::common::{Scheme, assert_coulomb_landing};
use crate::sheets::{self, grid};
use sinew_math::DVec3;
use sinew_spring_sim::contact::ContactError;
use sinew_spring_sim::contact::self_contact::distance::{PairKind, squared_distance};
use sinew_spring_sim::contact::self_contact::{SelfContactSettings, SelfContactStats};
use sinew_spring_sim::{NewtonSettings, TriangleMesh};
use std::sync::Arc;

const H: f64 = 1.0 / 60.0;
const G: f64 = 9.81;

/// The smallest gap over every vertex-triangle and edge-edge pair of the two sheets
/// (`top` the first vertex of the top sheet), by brute force.
fn min_gap_between(x: &[DVec3], triangles: &[[usize; 3]], top: usize, thickness: f64) -> f64 {
    let mesh = TriangleMesh::new(x.to_vec(), triangles.to_vec()).unwrap();
    let edges = mesh.edges();
    let mut min = f64::INFINITY;
    for (v, _) in x.iter().enumerate() {
        for t in triangles.iter().filter(|t| (t[0] >= top) != (v >= top)) {
            let pair = [x[v], x[t[0]], x[t[1]], x[t[2]]];
            min = min.min(squared_distance(PairKind::PointTriangle, &pair));
        }
    }
    for a in &edges {
        for b in edges.iter().filter(|b| (b[0] >= top) != (a[0] >= top)) {
            let pair = [x[a[0]], x[a[1]], x[b[0]], x[b[1]]];
            min = min.min(squared_distance(PairKind::EdgeEdge, &pair));
        }
    }
    min.sqrt() - thickness
}

/// The height above the lower sheet the top sheet is released at: a gap of 0.5 mm once
/// the thickness (1 mm) is taken off, inside its resting gap of about 1.68 mm.
const RELEASED_AT: f64 = 1.5e-3;

/// The height at which the top sheet rests on the lower one (the gap where the barrier
/// carries the normal part of its weight, measured after backward Euler settled it).
const RESTING_AT: f64 = 2.68e-3;

/// A 4 x 4 sheet (spacing 5 cm) lying `height` above a pinned `n x n` sheet (the same
/// spacing), turned by `turn` about their normal (at 0 its edges are parallel to the
/// lower sheet's and its vertices over the lower triangles' insides), `dhat` 2 mm and
/// thickness 1 mm, gravity `G` tilted by `theta` towards +x, friction `mu` between the
/// sheets, lagged once a step; `steps` steps of `h` in `scheme`, every one converged
/// and every accepted state's gaps positive. The top sheet's mean velocity along x after
/// each step (for the midpoint its step-mean velocity, the one its friction sees: its
/// end-of-step velocity rings about it, the scheme adding no damping), and the term's
/// statistics.
#[allow(clippy::too_many_arguments)]
fn slide_in(
    height: f64,
    scheme: Scheme,
    n: usize,
    turn: f64,
    theta: f64,
    mu: f64,
    steps: usize,
    h: f64,
) -> (Vec<f64>, Arc<SelfContactStats>) {
    let s = 0.05;
    let (mut x, mut t) = grid(n, DVec3::ZERO, DVec3::X, DVec3::Z, s, 0);
    let top = x.len();
    let (xt, tt) = grid(
        4,
        DVec3::new(0.063, height, 0.271),
        DVec3::new(turn.cos(), 0.0, turn.sin()),
        DVec3::new(-turn.sin(), 0.0, turn.cos()),
        s,
        top,
    );
    x.extend(xt);
    t.extend(tt);
    let mesh = TriangleMesh::new(x, t.clone()).unwrap();
    let mut cloth = sheets::cloth((0..top).collect());
    cloth.material.gravity = G * DVec3::new(theta.sin(), -theta.cos(), 0.0);
    let model = cloth.build(&mesh).unwrap();
    let mut integrator = scheme.build(&model, NewtonSettings::default());
    let settings = SelfContactSettings {
        dhat: 2e-3,
        thickness: 1e-3,
        mu,
        ..SelfContactSettings::default()
    };
    let stats = model
        .enable_self_contact(integrator.newton_mut(), settings)
        .unwrap();
    let mut system = model.system.clone();
    let mut speeds = Vec::new();
    for step in 0..steps {
        let before = system.positions()[top..].to_vec();
        let report = integrator.take_step(&mut system, h).unwrap();
        assert_eq!(report.friction_relags, 0);
        assert!(
            report.residual <= report.tolerance,
            "step {step}: {report:?}"
        );
        let x = system.positions();
        let gap = min_gap_between(x, &t, top, settings.thickness);
        assert!(gap > 0.0, "step {step}: smallest gap {gap}");
        if scheme == Scheme::Midpoint {
            let moved = x[top..].iter().zip(&before).map(|(x, x0)| x.x - x0.x);
            speeds.push(moved.sum::<f64>() / (before.len() as f64 * h));
        } else {
            let v = &system.velocities()[top..];
            speeds.push(v.iter().map(|v| v.x).sum::<f64>() / v.len() as f64);
        }
    }
    (speeds, stats)
}

/// [`slide_in`] in backward Euler on a 14 x 14 sheet, the top sheet's edges parallel to
/// the lower sheet's.
fn slide(theta: f64, mu: f64, steps: usize, h: f64) -> (Vec<f64>, Arc<SelfContactStats>) {
    slide_in(
        RELEASED_AT,
        Scheme::BackwardEuler,
        14,
        0.0,
        theta,
        mu,
        steps,
        h,
    )
}

/// A 2 x 2 sheet (spacing 5 cm) 1 cm above a pinned 2 x 2 sheet of spacing 1 m, over
/// the inside of one of its triangles, moving at (1, -1, 0) m/s: it reaches the lower
/// sheet within one step of 1/60 s, with friction `mu` 0.3 between the sheets and `lags`
/// lags a step. The step's report and the top sheet's velocity after it (its momentum
/// over its mass; its gaps positive; the only pairs within reach are its vertices over
/// that triangle).
fn land(lags: usize) -> (sinew_spring_sim::StepReport, DVec3) {
    let (mut x, mut t) = grid(2, DVec3::ZERO, DVec3::X, DVec3::Z, 1.0, 0);
    let top = x.len();
    let (xt, tt) = grid(2, DVec3::new(0.6, 0.01, 0.1), DVec3::X, DVec3::Z, 0.05, top);
    x.extend(xt);
    t.extend(tt);
    let mesh = TriangleMesh::new(x, t.clone()).unwrap();
    let model = sheets::cloth((0..top).collect()).build(&mesh).unwrap();
    let newton = NewtonSettings {
        friction_lags: lags,
        ..NewtonSettings::default()
    };
    let mut integrator = model.backward_euler(newton).unwrap();
    let settings = SelfContactSettings {
        dhat: 2e-3,
        thickness: 1e-3,
        mu: 0.3,
        ..SelfContactSettings::default()
    };
    model
        .enable_self_contact(&mut integrator, settings)
        .unwrap();
    let mut system = model.system.clone();
    let positions = system.positions().to_vec();
    let mut velocities = system.velocities().to_vec();
    velocities[top..].fill(DVec3::new(1.0, -1.0, 0.0));
    system.set_state(&positions, &velocities).unwrap();
    let report = integrator.step(&mut system, H).unwrap();
    assert!(report.residual <= report.tolerance, "{report:?}");
    let gap = min_gap_between(system.positions(), &t, top, settings.thickness);
    assert!(gap > 0.0 && gap < settings.dhat, "landed at a gap of {gap}");
    // Mass-weighted: the lumped masses differ, the barrier's force at a gap does not,
    // so the sheet bends a little as it lands; its springs' forces cancel in the sum.
    let (v, m) = (&system.velocities()[top..], &system.masses()[top..]);
    let momentum = v.iter().zip(m).map(|(v, m)| *v * *m).sum::<DVec3>();
    (report, momentum / m.iter().sum::<f64>())
}

#[test]
fn friction_lagged_again_acts_in_the_step_a_sheet_lands_on_a_sheet() {
    let (once, v_once) = land(1);
    let (again, v) = land(4);
    assert_coulomb_landing(0.3, H, (&once, v_once), (&again, v), 1e-7);
}

/// The mean acceleration over steps `a..b` (of `h`) of a run's speeds.
fn acceleration(speeds: &[f64], a: usize, b: usize, h: f64) -> f64 {
    (speeds[b] - speeds[a]) / ((b - a) as f64 * h)
}

#[test]
fn friction_holds_a_sheet_on_a_sheet_when_mu_exceeds_tan_theta() {
    let theta = 30f64.to_radians();
    let (speeds, stats) = slide(theta, 0.8, 30, H);
    assert!(stats.friction_pairs() > 0);
    let eps_v = SelfContactSettings::default().eps_v;
    for (step, s) in speeds.iter().enumerate().skip(5) {
        assert!(s.abs() < eps_v, "step {step}: creeping at {s}");
    }
}

#[test]
fn a_sheet_slides_on_a_sheet_with_coulomb_acceleration_when_mu_is_below_tan_theta() {
    let theta = 30f64.to_radians();
    let mu = 0.2;
    // Friction's deceleration `mu g cos theta` is the difference of the accelerations
    // with and without friction; without it the sheet slides at `g sin theta`. The first
    // third of the run is skipped while the sheet settles on the barrier.
    let run = |h: f64, steps: usize| {
        let (free, none) = slide(theta, 0.0, steps + 1, h);
        let (held, some) = slide(theta, mu, steps + 1, h);
        assert_eq!(none.friction_pairs(), 0);
        assert!(some.friction_pairs() > 0);
        let a = steps / 3;
        (
            acceleration(&free, a, steps, h),
            acceleration(&free, a, steps, h) - acceleration(&held, a, steps, h),
        )
    };
    let (sliding, friction) = (G * theta.sin(), mu * G * theta.cos());
    // At h = 1/240 the sheet moves a quarter of a millimetre or less a step, an eighth of
    // dhat: the pairs lagged at a step's start carry its load to its end.
    let (free, decel) = run(1.0 / 240.0, 96);
    println!("h 1/240: free {free} (g sin {sliding}), friction {decel} (mu g cos {friction})");
    assert!(
        (free - sliding).abs() <= 2e-3 * sliding,
        "{free} vs {sliding}"
    );
    assert!(
        (decel - friction).abs() <= 2e-3 * friction,
        "{decel} vs {friction}"
    );
    // At h = 1/60 the difference is 3.5% short of `mu g cos theta` (1.6398): the sheet
    // slides 1.4% faster than Coulomb's `g (sin - mu cos)`. Not from friction: the
    // normal forces it lags are those of the turned sheets below (2.4972 against 2.4979
    // summed over the run), and the barrier's own push along the slope at the steps' end
    // states, which backward Euler applies over each whole step, is 2.7% of the friction
    // force over the measured steps, nearly all of it in the two steps that end with every
    // vertex of a row beside a lower edge at once (docs/contact.md, "Aligned meshes").
    let (free, decel) = run(H, 24);
    println!("h 1/60: free {free} (g sin {sliding}), friction {decel} (mu g cos {friction})");
    assert!(
        (free - sliding).abs() <= 5e-3 * sliding,
        "{free} vs {sliding}"
    );
    assert!(
        decel <= friction && decel >= 0.95 * friction,
        "{decel} vs {friction}"
    );
    // Turned 0.3 rad against the lower sheet, so that no edge of one is parallel to an
    // edge of the other, the sheet slides at Coulomb's acceleration at h = 1/60 as well
    // (measured 3.2039 against 3.2059); so it does turned 0.01 rad (3.2015), where the
    // nearly parallel edge pairs are still inside the mollifier's range (`m` 0.16 to 0.19)
    // but the rows' vertices pass the lower edges 1.5 mm apart instead of at once.
    let coulomb = sliding - friction;
    for turn in [0.3, 0.01] {
        let (held, _) = slide_in(
            RELEASED_AT,
            Scheme::BackwardEuler,
            14,
            turn,
            theta,
            mu,
            25,
            H,
        );
        let measured = acceleration(&held, 8, 24, H);
        println!("h 1/60, turned {turn} rad: {measured} (g (sin - mu cos) {coulomb})");
        assert!(
            (measured - coulomb).abs() <= 3e-3 * coulomb,
            "turned {turn}: {measured} vs {coulomb}"
        );
    }
}

#[test]
fn bad_friction_settings_are_errors_naming_them() {
    let (x, t) = grid(3, DVec3::ZERO, DVec3::X, DVec3::Z, 0.1, 0);
    let mesh = TriangleMesh::new(x, t).unwrap();
    let model = sheets::cloth(vec![]).build(&mesh).unwrap();
    for (mu, eps_v, name) in [
        (-0.1, 1e-3, "mu"),
        (f64::NAN, 1e-3, "mu"),
        (101.0, 1e-3, "mu"),
        (0.3, 0.0, "eps_v"),
        (0.3, f64::INFINITY, "eps_v"),
    ] {
        let mut be = model.backward_euler(NewtonSettings::default()).unwrap();
        let settings = SelfContactSettings {
            mu,
            eps_v,
            ..SelfContactSettings::default()
        };
        let err = model.enable_self_contact(&mut be, settings).unwrap_err();
        assert!(
            matches!(err, ContactError::BadSetting { name: n, .. } if n == name),
            "mu {mu}, eps_v {eps_v}: {err}"
        );
    }
}

/// Self-contact friction in BDF2 and the implicit midpoint, as in backward Euler above:
/// the sheet turned 0.3 rad against the lower one slides at Coulomb's `g (sin - mu cos)`
/// with `mu` 0.2 at `h` = 1/60, and with `mu` 0.8 creeps below `eps_v` once settled
/// (below). The acceleration is taken over steps 12 to 44 on a 24 x 24 lower sheet (the 14 x 14
/// one is left after about 30 steps): over shorter windows it moves by some 0.3% either
/// way in every scheme as the rows pass the lower edges (backward Euler 3.1974 to 3.2063
/// over windows of 12 to 16 steps). Measured over 12 to 44: backward Euler 3.2007, BDF2
/// 3.2106, midpoint 3.2068, against 3.2059.
#[test]
fn bdf2_and_the_midpoint_hold_or_slide_a_sheet_on_a_sheet_as_coulomb_says() {
    let theta = 30f64.to_radians();
    let coulomb = G * (theta.sin() - 0.2 * theta.cos());
    let eps_v = SelfContactSettings::default().eps_v;
    for scheme in [Scheme::Bdf2, Scheme::Midpoint] {
        let (held, stats) = slide_in(RELEASED_AT, scheme, 24, 0.3, theta, 0.2, 45, H);
        assert!(stats.friction_pairs() > 0, "{scheme:?}");
        let measured = acceleration(&held, 12, 44, H);
        println!("{scheme:?}: {measured} (g (sin - mu cos) {coulomb})");
        assert!(
            (measured - coulomb).abs() <= 3e-3 * coulomb,
            "{scheme:?}: {measured} vs {coulomb}"
        );
        // Released at a gap of 0.5 mm, inside its resting gap (1.68 mm, where the barrier
        // carries the weight's normal part), the sheet is thrown off the barrier by the
        // barrier's stored energy, which these schemes damp less than backward Euler, and
        // slips in its first steps (measured: up to 0.039 m/s for BDF2 in its fourth
        // step, 0.073 m/s for the midpoint in its fourth, against 1.2e-3 for backward
        // Euler). Traced for BDF2: its first step, backward Euler's, leaves the sheet
        // rising at 63 mm/s; its second, the first BDF2 step, ends with the sheet's gaps
        // at 1.68 to 2.34 mm (backward Euler's: 1.66 to 1.85), some vertices beyond
        // `dhat` (2 mm) and the others near it, where the barrier's force, and with it
        // the friction lagged from that state, nearly vanish; the sheet then slides for
        // two steps (37 and 39 mm/s) and is caught as it lands. BDF2 holds from its
        // fifth step on like backward Euler (4.7e-4 m/s, the creep of the smoothed
        // friction), the midpoint from its tenth. When BDF2 started with an undamped
        // midpoint step its slip reached 0.14 m/s and it held from its tenth step.
        let (speeds, _) = slide_in(RELEASED_AT, scheme, 14, 0.3, theta, 0.8, 30, H);
        let settled = if scheme == Scheme::Bdf2 { 4 } else { 9 };
        for (step, s) in speeds.iter().enumerate().skip(settled) {
            assert!(s.abs() < eps_v, "{scheme:?} step {step}: creeping at {s}");
        }
        // Released at its resting gap instead, with no barrier energy to throw it, the
        // sheet holds from its first step in both schemes.
        let (speeds, _) = slide_in(RESTING_AT, scheme, 14, 0.3, theta, 0.8, 30, H);
        for (step, s) in speeds.iter().enumerate() {
            assert!(
                s.abs() < eps_v,
                "{scheme:?} from rest, step {step}: creeping at {s}"
            );
        }
    }
}
