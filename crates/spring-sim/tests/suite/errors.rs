//! One error type for settings ([`SettingsError`], naming the settings and the field) and
//! one for steps ([`StepError`]); a linear solver's failure keeps faer's structured error
//! as its `source` ([`SolverError`]) instead of flattening it to a string.

use faer::sparse::FaerError;
use sinew_spring_sim::*;
use std::error::Error;

fn lab() -> SpringSystem {
    SpringSystem::cloth(&ClothGrid::lab()).unwrap()
}

/// Builds `integrator` on the lab cloth and returns the settings error it must refuse
/// with, checking the message and the `source` chain on the way.
fn settings_error(integrator: Integrator) -> SettingsError {
    let err = Simulation::new(lab(), integrator).expect_err("bad settings are refused");
    let ModelError::Settings(settings) = err else {
        panic!("not a settings error: {err:?}");
    };
    let source = err.source().expect("the settings error is the source");
    assert_eq!(source.downcast_ref::<SettingsError>(), Some(&settings));
    assert_eq!(err.to_string(), settings.to_string());
    settings
}

#[test]
fn every_bad_setting_is_named_with_its_settings_and_field() {
    let newton = |settings: NewtonSettings| Integrator::BackwardEuler(settings);
    let auto = |settings: AutoSettings| Integrator::Auto(settings);
    let cases: Vec<(Integrator, &str, &str)> = vec![
        (
            newton(NewtonSettings {
                tolerance: f64::NAN,
                ..NewtonSettings::default()
            }),
            "NewtonSettings",
            "tolerance",
        ),
        (
            newton(NewtonSettings {
                tolerance: -1.0,
                ..NewtonSettings::default()
            }),
            "NewtonSettings",
            "tolerance",
        ),
        (
            newton(NewtonSettings {
                max_iterations: 0,
                ..NewtonSettings::default()
            }),
            "NewtonSettings",
            "max_iterations",
        ),
        (
            newton(NewtonSettings {
                pcg_forcing: 1.5,
                ..NewtonSettings::default()
            }),
            "NewtonSettings",
            "pcg_forcing",
        ),
        (
            newton(NewtonSettings {
                armijo: 0.7,
                ..NewtonSettings::default()
            }),
            "NewtonSettings",
            "armijo",
        ),
        (
            Integrator::Bdf2(NewtonSettings {
                max_split_depth: 21,
                ..NewtonSettings::default()
            }),
            "NewtonSettings",
            "max_split_depth",
        ),
        (
            newton(NewtonSettings {
                friction_lags: 0,
                ..NewtonSettings::default()
            }),
            "NewtonSettings",
            "friction_lags",
        ),
        (
            Integrator::ImplicitMidpoint(NewtonSettings {
                friction_lags: sinew_spring_sim::MAX_FRICTION_LAGS + 1,
                ..NewtonSettings::default()
            }),
            "NewtonSettings",
            "friction_lags",
        ),
        (
            auto(AutoSettings {
                max_substeps: 0,
                ..AutoSettings::default()
            }),
            "AutoSettings",
            "max_substeps",
        ),
        (
            auto(AutoSettings {
                implicit_cost_model: f64::INFINITY,
                ..AutoSettings::default()
            }),
            "AutoSettings",
            "implicit_cost_model",
        ),
        (
            auto(AutoSettings {
                switch_ratio: 0.5,
                ..AutoSettings::default()
            }),
            "AutoSettings",
            "switch_ratio",
        ),
        (
            auto(AutoSettings {
                newton: NewtonSettings {
                    tolerance: 0.0,
                    ..NewtonSettings::default()
                },
                ..AutoSettings::default()
            }),
            "NewtonSettings",
            "tolerance",
        ),
        (
            Integrator::SymplecticEuler { substeps: 0 },
            "SymplecticEuler",
            "substeps",
        ),
        (
            Integrator::VelocityVerlet { substeps: Some(0) },
            "VelocityVerlet",
            "substeps",
        ),
    ];
    for (integrator, settings, field) in cases {
        let e = settings_error(integrator);
        assert_eq!((e.settings, e.field), (settings, field), "{e}");
        let message = e.to_string();
        assert!(
            message.starts_with(&format!("{settings}.{field}: ")),
            "{message}"
        );
        assert!(
            message.len() > settings.len() + field.len() + 3,
            "{message}"
        );
    }
}

/// A step's bad input is a `StepError` whose message names it and whose source is the
/// model's error; the system is left as it was.
#[test]
fn a_step_names_its_bad_input_and_keeps_the_cause() {
    let mut sim = Simulation::new(lab(), Integrator::default()).unwrap();
    let before = sim.system().positions().to_vec();
    let err = sim.step(f64::NAN).unwrap_err();
    assert!(matches!(
        err,
        StepError::Invalid(ModelError::BadTimeStep { .. })
    ));
    assert!(err.to_string().contains("time step"), "{err}");
    let source = err.source().expect("the model error is the source");
    assert!(matches!(
        source.downcast_ref::<ModelError>(),
        Some(ModelError::BadTimeStep { .. })
    ));
    assert_eq!(sim.system().positions(), before.as_slice());
}

/// faer's errors cannot be provoked at a size a test can hold (an index overflow, an
/// allocation failure), so its error values are handed to the same conversions the
/// solvers use: the `source` chain from a step's error reaches faer's error intact.
#[test]
fn a_solver_failure_keeps_faers_error_as_its_source() {
    for (failure, field) in [
        (
            SolverError::SymbolicFactorization(FaerError::OutOfMemory),
            "linear_solver",
        ),
        (
            SolverError::Ordering(FaerError::IndexOverflow),
            "linear_solver",
        ),
    ] {
        let expected = match &failure {
            SolverError::SymbolicFactorization(e) | SolverError::Ordering(e) => *e,
            SolverError::ThreadPool { .. } => unreachable!(),
        };
        // Built with the integrator: a model error.
        let model = ModelError::from(failure.clone());
        assert!(
            model.to_string().starts_with(&format!("{field}: ")),
            "{model}"
        );
        // Met during a step (the direct solver is built at the first step choosing it):
        // a step error of its own kind, not "invalid input".
        let step = StepError::from(model.clone());
        assert_eq!(step, StepError::Solver(failure.clone()));
        for err in [&model as &dyn Error, &step as &dyn Error] {
            let solver = err.source().expect("the solver error is the source");
            assert_eq!(solver.downcast_ref::<SolverError>(), Some(&failure));
            let faer = solver
                .source()
                .expect("faer's error is the solver error's source");
            assert_eq!(faer.downcast_ref::<FaerError>(), Some(&expected));
        }
    }
}

/// A time step whose square is not a normal f64 is refused by every step (the implicit
/// integrators weigh the inertia by 1/h^2 and the forces by h^2); the bounds themselves
/// are accepted, and the message gives them.
#[test]
fn a_time_step_whose_square_is_not_normal_is_refused() {
    use sinew_spring_sim::{MAX_TIME_STEP, MIN_TIME_STEP, check_time_step};
    // The bounds are the tightest: just beyond either, the square is not normal.
    let (min, max) = (
        std::hint::black_box(MIN_TIME_STEP),
        std::hint::black_box(MAX_TIME_STEP),
    );
    assert!(min * min >= f64::MIN_POSITIVE);
    assert!((max * max).is_finite());
    assert!((max * (1.0 + f64::EPSILON)).powi(2).is_infinite());
    assert!((min * (1.0 - f64::EPSILON)).powi(2) < f64::MIN_POSITIVE);
    check_time_step(MIN_TIME_STEP).unwrap();
    check_time_step(MAX_TIME_STEP).unwrap();
    for dt in [f64::MAX, 1e155, 1e-155, 5e-324] {
        let err = check_time_step(dt).unwrap_err();
        assert!(
            err.to_string().contains("its square is not a normal f64"),
            "{dt}: {err}"
        );
        for integrator in [
            Integrator::default(),
            Integrator::SymplecticEuler { substeps: 1 },
        ] {
            let mut sim = Simulation::new(lab(), integrator).unwrap();
            let before = sim.system().positions().to_vec();
            let err = sim.step(dt).unwrap_err();
            assert!(
                matches!(err, StepError::Invalid(ModelError::BadTimeStep { .. })),
                "{dt}: {err:?}"
            );
            assert_eq!(sim.system().positions(), before.as_slice());
        }
    }
}

#[test]
fn a_bad_material_is_named_in_words_that_fit_the_field() {
    let grid = ClothGrid::lab();
    let with = |material: Material| {
        SpringSystem::cloth(&ClothGrid {
            material,
            ..grid.clone()
        })
        .unwrap_err()
        .to_string()
    };
    let gravity = with(Material {
        gravity: DVec3::new(0.0, f64::NAN, 0.0),
        ..grid.material
    });
    assert_eq!(
        gravity,
        "material: gravity is not finite (a component is NaN or infinite)"
    );
    let damping = with(Material {
        damping: -1.0,
        ..grid.material
    });
    assert_eq!(damping, "material: damping is negative or not finite");
}

/// A term with no energy whose gradient is NaN at one particle: what a term whose
/// arithmetic underflowed (a friction threshold of 1e-300) gave.
#[derive(Debug)]
struct NanGradient(usize);

impl sinew_spring_sim::potential::Term for NanGradient {
    fn name(&self) -> &'static str {
        "nan-gradient"
    }
    fn energy(&self, _: &sinew_spring_sim::potential::StepContext<'_>, _: &[DVec3]) -> f64 {
        0.0
    }
    fn energy_change(
        &self,
        _: &sinew_spring_sim::potential::StepContext<'_>,
        _: &[DVec3],
        _: &[DVec3],
        _: f64,
    ) -> f64 {
        0.0
    }
    fn add_gradient(
        &self,
        _: &sinew_spring_sim::potential::StepContext<'_>,
        _: &[DVec3],
        gradient: &mut [DVec3],
    ) {
        gradient[self.0] = DVec3::NAN;
    }
    fn add_hessian(
        &self,
        _: &sinew_spring_sim::potential::StepContext<'_>,
        _: &[DVec3],
        _: sinew_spring_sim::spring::Curvature,
        _: &mut sinew_spring_sim::potential::HessianSink<'_>,
    ) {
    }
}

#[test]
fn a_solve_whose_gradient_is_nan_is_refused_not_reported_converged() {
    // The NaN in one particle's gradient once vanished from the residual (`f64::max`
    // drops it) and, with every other entry NaN too, the step read as converged.
    let mut system = lab();
    let particle = 60;
    let mut be = BackwardEuler::new(&system, NewtonSettings::default()).unwrap();
    be.add_term(Box::new(NanGradient(particle)));
    let (x0, v0) = (system.positions().to_vec(), system.velocities().to_vec());
    let err = be.step(&mut system, 1.0 / 60.0).unwrap_err();
    assert!(
        matches!(err, StepError::NonFinite { particle: p, .. } if p == particle),
        "{err:?}"
    );
    assert_eq!(system.positions(), x0.as_slice());
    assert_eq!(system.velocities(), v0.as_slice());
    assert_eq!(be.time(), 0.0);
}
