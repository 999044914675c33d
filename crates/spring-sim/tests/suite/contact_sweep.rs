//! Kinematic colliders that travel about their own size in a step: a sphere rising
//! through a sheet and a capsule turning through one must push the cloth, not pass
//! through it. Checked here independently of the library: every particle's straight
//! path from one accepted state to the next, and from one piece's end to the next
//! within a step split in pieces (the record of [`Simulation::record_piece_ends`]), is
//! sampled against the collider posed at the same times (distances from the shape's
//! fields), and must not go deeper into it than the allowance the integrators grant
//! (`dhat`); every piece's end state is outside.

use crate::common::independent_distance;
use sinew_math::DVec3;
use sinew_spring_sim::contact::{Collider, ContactSettings};
use sinew_spring_sim::{
    AutoSettings, ClothGrid, Integrator, IntegratorKind, Material, NewtonSettings, Particle,
    Simulation, SpringSystem,
};

const H: f64 = 1.0 / 60.0;
/// Samples per path: at 1 m a step the sphere moves 0.25 mm between samples.
const SAMPLES: usize = 4000;

/// The three implicit schemes, named for messages, with `max_split_depth` as given.
fn schemes(max_split_depth: usize) -> [(&'static str, Integrator); 3] {
    let s = NewtonSettings {
        max_split_depth,
        ..NewtonSettings::default()
    };
    [
        ("backward Euler", Integrator::BackwardEuler(s)),
        ("BDF2", Integrator::Bdf2(s)),
        ("implicit midpoint", Integrator::ImplicitMidpoint(s)),
    ]
}

/// A 9 x 9 sheet at rest in the plane y = 0, spacing 5 cm, centred on the origin, 1 kg
/// a particle, soft springs (1 N/m) and no gravity, so only the collider moves it.
fn sheet() -> SpringSystem {
    let n = 9;
    let mut particles = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let p = DVec3::new(0.05 * i as f64 - 0.2, 0.0, 0.05 * j as f64 - 0.2);
            particles.push(Particle::at_rest(p, 1.0));
        }
    }
    let material = Material {
        stiffness: 1.0,
        damping: 0.0,
        gravity: DVec3::ZERO,
    };
    SpringSystem::new(&particles, &ClothGrid::spring_pattern(n), material).unwrap()
}

/// The deepest any particle's straight path from `from` (at `t0`) to `to` (at `t0 + h`)
/// goes into `collider` posed at the same times (negative inside), and the particle.
fn deepest_on_paths(
    collider: &Collider,
    (t0, h): (f64, f64),
    from: &[DVec3],
    to: &[DVec3],
) -> (f64, usize) {
    let mut deepest = (f64::INFINITY, 0);
    for (i, (&p, &q)) in from.iter().zip(to).enumerate() {
        for k in 0..=SAMPLES {
            let s = k as f64 / SAMPLES as f64;
            let d = independent_distance(collider, t0 + s * h, p.lerp(q, s));
            if d < deepest.0 {
                deepest = (d, i);
            }
        }
    }
    deepest
}

/// What [`run`] measured: the deepest any straight path between two accepted states
/// went into the collider (`chord`), the deepest any piece's path went (`piece`, the
/// promise), the total [`sinew_spring_sim::StepReport::swept_passes`], the largest number
/// of pieces a step took, and the final positions.
struct Sweep {
    chord: f64,
    piece: f64,
    passes: usize,
    pieces: usize,
    end: Vec<DVec3>,
}

/// Runs `steps` steps of the sheet against `collider` with `integrator`, recording every
/// piece's end state. Every step's end state and every piece's is checked strictly
/// outside.
fn run(name: &str, integrator: Integrator, collider: Collider, steps: usize) -> Sweep {
    let mut sim = Simulation::new(sheet(), integrator).unwrap();
    sim.set_contact(vec![collider], ContactSettings::default())
        .unwrap();
    sim.record_piece_ends(true).unwrap();
    let mut out = Sweep {
        chord: f64::INFINITY,
        piece: f64::INFINITY,
        passes: 0,
        pieces: 0,
        end: Vec::new(),
    };
    for step in 0..steps {
        let (t0, before) = (sim.time(), sim.system().positions().to_vec());
        let report = sim.step(H).unwrap();
        let after = sim.system().positions();
        for (i, &x) in after.iter().enumerate() {
            let d = independent_distance(&collider, sim.time(), x);
            assert!(
                d > 0.0,
                "{name}, step {step}: particle {i} inside (d = {d})"
            );
        }
        let (d, i) = deepest_on_paths(&collider, (t0, H), &before, after);
        // The pieces: as many as the report counts, back to back from the step's start
        // to its end.
        let record = sim.piece_ends().expect("recording");
        assert_eq!(record.len(), report.pieces, "{name}, step {step}");
        let (mut t, mut from) = (t0, before.as_slice());
        let mut deepest_piece = (f64::INFINITY, 0);
        for (k, (end, to)) in record.iter().enumerate() {
            assert!(
                end > t,
                "{name}, step {step}: piece {k} ends at {end}, before {t}"
            );
            for (i, &x) in to.iter().enumerate() {
                let d = independent_distance(&collider, end, x);
                assert!(
                    d > 0.0,
                    "{name}, step {step}, piece {k}: particle {i} inside (d = {d})"
                );
            }
            let found = deepest_on_paths(&collider, (t, end - t), from, to);
            if found.0 < deepest_piece.0 {
                deepest_piece = found;
            }
            (t, from) = (end, to);
        }
        assert!(
            (t - sim.time()).abs() <= 1e-12,
            "{name}, step {step}: pieces end at {t}"
        );
        assert_eq!(
            from, after,
            "{name}, step {step}: the last piece is not the step's end"
        );
        println!(
            "{name}, step {step}: {} pieces, deepest path {d:.3e} (particle {i}), deepest piece's path {:.3e} (particle {}), swept passes {}",
            report.pieces, deepest_piece.0, deepest_piece.1, report.swept_passes
        );
        out.chord = out.chord.min(d);
        out.piece = out.piece.min(deepest_piece.0);
        out.passes += report.swept_passes;
        out.pieces = out.pieces.max(report.pieces);
    }
    out.end = sim.system().positions().to_vec();
    out
}

/// A sphere of radius 0.1 starting 1 cm below the sheet's middle and rising at `speed`.
fn rising_sphere(speed: f64) -> Collider {
    Collider::sphere(DVec3::new(0.0, -0.11, 0.0), 0.1)
        .moving(DVec3::new(0.0, speed, 0.0), DVec3::ZERO)
}

/// The middle particle of the 9 x 9 sheet.
const MIDDLE: usize = 40;

#[test]
fn a_sphere_rising_through_a_sheet_within_a_step_lifts_it() {
    // At 24 and 60 m/s the sphere travels 2 and 5 of its diameters a step: the end-pose
    // minimization alone left the sheet flat behind it. Split until no path passes, the
    // sheet rides on it in every scheme.
    let dhat = ContactSettings::default().dhat;
    for speed in [1.5, 3.0, 6.0, 12.0, 24.0, 60.0] {
        for (name, integrator) in schemes(NewtonSettings::default().max_split_depth) {
            let name = format!("{name} at {speed} m/s");
            let steps = 3;
            let sweep = run(&name, integrator, rising_sphere(speed), steps);
            assert_eq!(sweep.passes, 0, "{name}: a step kept a pass");
            assert!(
                sweep.piece > -dhat,
                "{name}: a piece's path went {} into the sphere",
                sweep.piece
            );
            // Across a split step (from its start to its end) the chord is not promised;
            // here it stays within the allowance too.
            assert!(
                sweep.chord > -dhat,
                "{name}: a straight path went {} into the sphere",
                sweep.chord
            );
            if speed > 10.0 {
                assert!(
                    sweep.pieces > 1,
                    "{name}: the pass was found without splitting"
                );
            }
            let end = sweep.end;
            // The middle particle is above the sphere: carried on it (backward Euler, and
            // BDF2, whose start and pieces are backward Euler steps), or thrown ahead of
            // it by the barrier's rebound (the undamped midpoint), never left behind.
            let top = -0.11 + speed * steps as f64 * H + 0.1;
            let y = end[MIDDLE].y;
            println!(
                "{name}: the middle particle {:.4} above the sphere's top",
                y - top
            );
            assert!(
                y > top,
                "{name}: the middle particle at y = {y}, the sphere's top at {top}"
            );
        }
    }
}

#[test]
fn without_splitting_a_pass_is_reported_not_hidden() {
    // With splitting off the step cannot be resolved: the sphere passes through the
    // sheet, and the report says so.
    for (name, integrator) in schemes(0) {
        let sweep = run(name, integrator, rising_sphere(60.0), 1);
        assert!(sweep.chord < -0.05, "{name}: deepest path {}", sweep.chord);
        assert_eq!(sweep.piece, sweep.chord, "{name}: one piece, the step");
        assert_eq!(sweep.passes, 1, "{name}");
        assert!(
            sweep.end[MIDDLE].y.abs() < 1e-9,
            "{name}: the sheet stayed flat"
        );
    }
}

/// A paddle (a capsule 0.3 long, radius 0.03) 1 cm below the sheet, turning at 30 rad/s
/// about the z axis through its middle: its tips move 7.5 cm a step, more than its
/// diameter, and one rises through the sheet's plane within three steps.
fn paddle() -> Collider {
    Collider::capsule(
        DVec3::new(-0.15, -0.04, 0.0),
        DVec3::new(0.15, -0.04, 0.0),
        0.03,
    )
    .moving(DVec3::ZERO, DVec3::new(0.0, 0.0, 30.0))
}

#[test]
fn without_splitting_a_turning_paddle_passes_and_it_is_reported() {
    for (name, integrator) in schemes(0) {
        let sweep = run(name, integrator, paddle(), 4);
        assert!(sweep.chord < -0.01, "{name}: deepest path {}", sweep.chord);
        assert!(sweep.passes >= 1, "{name}");
    }
}

#[test]
fn a_capsule_turning_through_a_sheet_pushes_it() {
    // The turning shape's time of impact is the conservative advancement, not a closed
    // form.
    let dhat = ContactSettings::default().dhat;
    let paddle = paddle();
    for (name, integrator) in schemes(NewtonSettings::default().max_split_depth) {
        let sweep = run(name, integrator, paddle, 4);
        assert_eq!(sweep.passes, 0, "{name}: a step kept a pass");
        assert!(
            sweep.piece > -dhat,
            "{name}: a piece's path went {} into the paddle",
            sweep.piece
        );
        println!(
            "{name}: the deepest chord across a whole step {:.3e}",
            sweep.chord
        );
        assert!(sweep.pieces > 1, "{name}: no step was split");
        // The rising arm (x > 0) has lifted the sheet above its plane.
        let lifted = sweep
            .end
            .iter()
            .map(|p| p.y)
            .fold(f64::NEG_INFINITY, f64::max);
        assert!(lifted > 0.05, "{name}: highest particle at {lifted}");
    }
}

#[test]
fn piece_ends_are_recorded_when_asked_and_only_by_the_implicit_integrators() {
    let mut sim = Simulation::new(
        sheet(),
        Integrator::BackwardEuler(NewtonSettings::default()),
    )
    .unwrap();
    sim.set_contact(vec![rising_sphere(6.0)], ContactSettings::default())
        .unwrap();
    assert!(sim.piece_ends().is_none(), "off by default");
    sim.record_piece_ends(true).unwrap();
    let report = sim.step(H).unwrap();
    let record = sim.piece_ends().unwrap();
    assert!(report.pieces > 1);
    assert_eq!(record.len(), report.pieces);
    // Each step starts the record afresh: a step taken whole (the sheet now rides the
    // sphere, without gravity) records one piece, the step's end.
    let mut whole = None;
    for _ in 0..2 {
        let report = sim.step(H).unwrap();
        let record = sim.piece_ends().unwrap();
        assert_eq!(record.len(), report.pieces);
        if report.pieces == 1 {
            whole = Some(record.get(0).unwrap().0);
            assert_eq!(record.get(0).unwrap().1, sim.system().positions());
            assert!(record.get(1).is_none());
        }
    }
    let end = whole.expect("a step taken whole");
    assert!(end > 0.0 && end <= sim.time());
    sim.record_piece_ends(false).unwrap();
    assert!(sim.piece_ends().is_none());

    let explicit = Simulation::new(sheet(), Integrator::VelocityVerlet { substeps: None });
    let err = explicit.unwrap().record_piece_ends(true).unwrap_err();
    assert!(err.to_string().contains("integrator"), "{err}");
}

#[test]
fn auto_records_the_pieces_of_whichever_integrator_took_the_step() {
    // With contact every step of `auto` is BDF2: its pieces, as for BDF2 itself.
    let mut sim = Simulation::new(sheet(), Integrator::Auto(AutoSettings::default())).unwrap();
    sim.set_contact(vec![rising_sphere(60.0)], ContactSettings::default())
        .unwrap();
    sim.record_piece_ends(true).unwrap();
    let mut bdf2 =
        Simulation::new(sheet(), Integrator::Bdf2(AutoSettings::default().newton)).unwrap();
    bdf2.set_contact(vec![rising_sphere(60.0)], ContactSettings::default())
        .unwrap();
    bdf2.record_piece_ends(true).unwrap();
    for step in 0..2 {
        let report = sim.step(H).unwrap();
        assert_eq!(report.integrator, IntegratorKind::Bdf2);
        bdf2.step(H).unwrap();
        let record = sim.piece_ends().unwrap();
        assert_eq!(record.len(), report.pieces, "step {step}");
        assert_eq!(Some(record), bdf2.piece_ends(), "step {step}");
    }
    assert!(sim.piece_ends().unwrap().len() > 1);
    // Without contact, a Verlet step is one piece: its end state.
    let mut sim = Simulation::new(sheet(), Integrator::Auto(AutoSettings::default())).unwrap();
    sim.record_piece_ends(true).unwrap();
    let report = sim.step(H).unwrap();
    assert_eq!(report.integrator, IntegratorKind::VelocityVerlet);
    let record = sim.piece_ends().unwrap();
    assert_eq!(record.len(), 1);
    let (end, x) = record.get(0).unwrap();
    assert!((end - sim.time()).abs() <= 1e-15);
    assert_eq!(x, sim.system().positions());
}
