//! Self-contact stress cases: a free sheet thrown down onto a sheet pinned along its
//! border, both one triangle mesh with self-contact (the IPC barrier between its own
//! vertices, triangles and edges, the line search capped by continuous collision
//! detection), at every stiffness x time step x drop speed, without and with friction
//! between the sheets, by backward Euler and by BDF2. After every accepted step the
//! mesh is checked for triangles passing through each other by the exact check of
//! [`sinew_exact`], which shares no code with the solver; any intersection,
//! a non-finite value or a refused step fails the case.

use crate::stress::cloth::{FarSteps, residual_floor};
use serde::Serialize;
use sinew_exact::intersecting_pairs;
use sinew_math::DVec3;
use sinew_spring_sim::contact::self_contact::SelfContactSettings;
use sinew_spring_sim::{
    Bending, ClothGrid, Integrator, Material, MeshCloth, NewtonSettings, StepStop, TriangleMesh,
};
use std::time::Instant;

/// Spacing of the pinned (bottom) sheet, m; the free sheet's is 0.8 of it.
pub const SELF_SPACING: f64 = 0.05;
/// Height of the free sheet above the pinned one at the start, m.
pub const SELF_DROP_HEIGHT: f64 = 0.02;
/// The barrier's reach and the cloth's thickness, m.
pub const SELF_DHAT: f64 = 2e-3;
/// The cloth's thickness, m.
pub const SELF_THICKNESS: f64 = 1e-3;

/// The implicit scheme a self-contact case is stepped by.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SelfContactScheme {
    /// Backward Euler.
    BackwardEuler,
    /// BDF2 (its first step, and the pieces of a split step, backward Euler steps).
    Bdf2,
}

impl SelfContactScheme {
    /// Every scheme, in table order.
    pub const ALL: [Self; 2] = [Self::BackwardEuler, Self::Bdf2];

    /// The scheme with `settings`.
    fn integrator(self, settings: NewtonSettings) -> Integrator {
        match self {
            Self::BackwardEuler => Integrator::BackwardEuler(settings),
            Self::Bdf2 => Integrator::Bdf2(settings),
        }
    }
}

/// One self-contact case.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SelfContactCase {
    /// The implicit scheme.
    pub scheme: SelfContactScheme,
    /// Particles per side of each sheet.
    pub grid: usize,
    /// Stiffness of every spring, N/m.
    pub stiffness: f64,
    /// Time step, s.
    pub dt: f64,
    /// Initial downward speed of the free sheet, m/s.
    pub speed: f64,
    /// Friction coefficient between the sheets (`SelfContactSettings::mu`).
    pub mu: f64,
    /// Steps taken.
    pub steps: usize,
}

impl SelfContactCase {
    /// A label for messages: `2x6x6 k=1e4 dt=1/60 v=5 mu=0.5`, with ` bdf2` after it
    /// for BDF2.
    #[must_use]
    pub fn label(&self) -> String {
        format!(
            "2x{0}x{0} k={1:.0e} dt={2} v={3} mu={4}{5}",
            self.grid,
            self.stiffness,
            super::cloth::dt_label(self.dt),
            self.speed,
            self.mu,
            match self.scheme {
                SelfContactScheme::BackwardEuler => "",
                SelfContactScheme::Bdf2 => " bdf2",
            }
        )
    }
}

/// The cases: scheme x stiffness x time step x drop speed x friction, backward Euler's
/// first. Quick: 5 x 5 sheets, stiffness 1e2 and 1e4, dt 1/60 and 1/4, speed 0 and 5 m/s,
/// `mu` 0 and 0.5, 8 steps (16 cases a scheme, 32 in all). Full: 8 x 8 sheets, stiffness
/// 1e1, 1e3, 1e5, dt 1/240, 1/60, 1/4, speed 0, 2, 10 m/s, `mu` 0 and 0.5, 30 steps (54
/// cases a scheme, 108 in all).
#[must_use]
pub fn self_contact_cases(quick: bool) -> Vec<SelfContactCase> {
    let (grid, stiffnesses, dts, speeds, steps): (usize, &[f64], &[f64], &[f64], usize) = if quick {
        (5, &[1e2, 1e4], &[1.0 / 60.0, 0.25], &[0.0, 5.0], 8)
    } else {
        (
            8,
            &[1e1, 1e3, 1e5],
            &[1.0 / 240.0, 1.0 / 60.0, 0.25],
            &[0.0, 2.0, 10.0],
            30,
        )
    };
    let mut cases = Vec::new();
    for scheme in SelfContactScheme::ALL {
        for &stiffness in stiffnesses {
            for &dt in dts {
                for &speed in speeds {
                    for mu in [0.0, 0.5] {
                        cases.push(SelfContactCase {
                            scheme,
                            grid,
                            stiffness,
                            dt,
                            speed,
                            mu,
                            steps,
                        });
                    }
                }
            }
        }
    }
    cases
}

/// What one self-contact case did.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SelfContactOutcome {
    /// The case.
    pub case: SelfContactCase,
    /// Steps completed.
    pub steps_run: usize,
    /// Pairs of triangles (sharing no vertex) found meeting, summed over the accepted
    /// states (every piece's end state of a split step too), by the exact check; any is
    /// a failure.
    pub intersections: usize,
    /// The smallest gap the term saw at a Newton iterate's start (`+inf` if none came
    /// within `dhat`).
    pub min_gap: f64,
    /// The most pairs within `dhat` at an iterate's start.
    pub active_pairs_max: usize,
    /// Steps that stopped with a non-finite value or left one in the state.
    pub nan_steps: usize,
    /// Steps whose residual stayed above the tolerance.
    pub unconverged_steps: usize,
    /// The steps' final residuals against the round-off floor.
    pub far: FarSteps,
    /// Largest Newton iteration count of a step.
    pub iterations_max: usize,
    /// Wall-clock seconds.
    pub seconds: f64,
    /// Broken invariants, as sentences.
    pub failures: Vec<String>,
}

/// An `n x n` grid `origin + s (i u + j w)` and its triangles, indices offset.
fn sheet(
    n: usize,
    origin: DVec3,
    u: DVec3,
    w: DVec3,
    s: f64,
    offset: usize,
) -> (Vec<DVec3>, Vec<[usize; 3]>) {
    ClothGrid {
        size: n,
        spacing: s,
        origin,
        ..ClothGrid::lab()
    }
    .sheet(u, w, offset)
}

/// Runs one case.
#[must_use]
pub fn run_self_contact_case(case: &SelfContactCase) -> SelfContactOutcome {
    let started = Instant::now();
    let mut out = SelfContactOutcome {
        case: *case,
        steps_run: 0,
        intersections: 0,
        min_gap: f64::INFINITY,
        active_pairs_max: 0,
        nan_steps: 0,
        unconverged_steps: 0,
        far: FarSteps::default(),
        iterations_max: 0,
        seconds: 0.0,
        failures: Vec::new(),
    };
    let n = case.grid;
    let (mut x, mut t) = sheet(n, DVec3::ZERO, DVec3::X, DVec3::Z, SELF_SPACING, 0);
    // The free sheet is smaller, turned 0.1 rad about the vertical and centred above.
    let (c, s) = (0.1f64.cos(), 0.1f64.sin());
    let inset = 0.1 * SELF_SPACING * (n - 1) as f64;
    let (xt, tt) = sheet(
        n,
        DVec3::new(inset, SELF_DROP_HEIGHT, inset),
        DVec3::new(c, 0.0, s),
        DVec3::new(-s, 0.0, c),
        0.8 * SELF_SPACING,
        x.len(),
    );
    x.extend(xt);
    t.extend(tt);
    let fixed: Vec<usize> = (0..n * n)
        .filter(|k| k / n == 0 || k / n == n - 1 || k % n == 0 || k % n == n - 1)
        .collect();
    let triangles = t.clone();
    let built = TriangleMesh::new(x, t)
        .map_err(|e| e.to_string())
        .and_then(|mesh| {
            MeshCloth {
                areal_density: 0.2,
                material: Material {
                    stiffness: case.stiffness,
                    damping: 0.1,
                    gravity: DVec3::new(0.0, -9.81, 0.0),
                },
                bending: Bending::None,
                fixed,
            }
            .build(&mesh)
            .map_err(|e| e.to_string())
        });
    let model = match built {
        Ok(m) => m,
        Err(e) => {
            out.failures.push(format!("could not build the case: {e}"));
            return out;
        }
    };
    let settings = NewtonSettings {
        max_iterations: 100,
        ..NewtonSettings::default()
    };
    let mut integrator = match model.implicit_stepper(case.scheme.integrator(settings)) {
        Ok(i) => i,
        Err(e) => {
            out.failures
                .push(format!("could not build the integrator: {e}"));
            return out;
        }
    };
    let contact = SelfContactSettings {
        dhat: SELF_DHAT,
        thickness: SELF_THICKNESS,
        mu: case.mu,
        ..SelfContactSettings::default()
    };
    let stats = match model.enable_self_contact(integrator.newton_mut(), contact) {
        Ok(s) => s,
        Err(e) => {
            out.failures
                .push(format!("could not enable self-contact: {e}"));
            return out;
        }
    };
    let mut system = model.system.clone();
    let start = system.positions().to_vec();
    let velocities: Vec<DVec3> = (0..system.len())
        .map(|i| {
            if i >= n * n {
                DVec3::new(0.0, -case.speed, 0.0)
            } else {
                DVec3::ZERO
            }
        })
        .collect();
    if let Err(e) = system.set_state(&start, &velocities) {
        out.failures.push(format!("could not set the state: {e}"));
        return out;
    }
    // The guarantee holds at the end of every piece of a split step, which the step
    // does not return: the integrator records them for the exact check.
    integrator.newton_mut().record_piece_ends(true);
    for step in 0..case.steps {
        let report = match integrator.take_step(&mut system, case.dt) {
            Ok(r) => r,
            Err(e) => {
                out.failures.push(format!("step {step} refused: {e}"));
                break;
            }
        };
        out.steps_run += 1;
        out.iterations_max = out.iterations_max.max(report.iterations);
        out.min_gap = out.min_gap.min(stats.min_gap());
        out.active_pairs_max = out.active_pairs_max.max(stats.active_pairs());
        if report.stop == StepStop::NonFinite
            || !report.residual.is_finite()
            || system.positions().iter().any(|p| !p.is_finite())
            || system.velocities().iter().any(|v| !v.is_finite())
        {
            out.nan_steps += 1;
            out.failures
                .push(format!("step {step}: a non-finite value"));
            break;
        }
        if report.residual > report.tolerance {
            out.unconverged_steps += 1;
        }
        out.far
            .note(step, &report, residual_floor(&system, case.dt, &report));
        // Every piece's end state: the step's own is the last.
        let pieces = integrator.newton().piece_ends().expect("recording");
        if pieces.len() != report.pieces {
            out.failures.push(format!(
                "step {step}: {} pieces recorded, {} reported",
                pieces.len(),
                report.pieces
            ));
        }
        for (k, (_, x)) in pieces.iter().enumerate() {
            let meeting = intersecting_pairs(x, &triangles);
            if let Some(&(a, b)) = meeting.first() {
                out.intersections += meeting.len();
                out.failures.push(format!(
                    "step {step}, piece {k} of {}: {} pair(s) of triangles pass through each other (first: {a} and {b})",
                    pieces.len(),
                    meeting.len()
                ));
            }
        }
    }
    out.seconds = started.elapsed().as_secs_f64();
    out
}

/// The self-contact cases as a table (console and markdown share it).
#[must_use]
pub fn self_contact_table(outcomes: &[SelfContactOutcome]) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| case | steps | intersections | min gap (m) | active pairs max | NaN steps | unconverged steps | far | residual / max(tol, floor) max | Newton max | seconds |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|");
    for o in outcomes {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.2e} | {} | {} | {} | {} | {:.2e} | {} | {:.2} |",
            o.case.label(),
            o.steps_run,
            o.intersections,
            o.min_gap,
            o.active_pairs_max,
            o.nan_steps,
            o.unconverged_steps,
            o.far.count,
            o.far.ratio_max,
            o.iterations_max,
            o.seconds
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_quick_case_runs_without_intersections_and_comes_into_contact() {
        for scheme in SelfContactScheme::ALL {
            let case = SelfContactCase {
                scheme,
                grid: 4,
                stiffness: 1e3,
                dt: 1.0 / 60.0,
                speed: 2.0,
                mu: 0.5,
                steps: 4,
            };
            quick_case(&case);
        }
    }

    fn quick_case(case: &SelfContactCase) {
        let out = run_self_contact_case(case);
        assert!(out.failures.is_empty(), "{:?}", out.failures);
        assert_eq!(out.steps_run, 4);
        assert_eq!(out.intersections, 0);
        assert!(out.far.ratio_max.is_finite(), "{:?}", out.far);
        assert_eq!(
            out.far.ratio_max > crate::stress::cloth::FAR_FACTOR,
            out.far.count > 0,
            "{:?}",
            out.far
        );
        assert_eq!(out.far.first.is_some(), out.far.count > 0, "{:?}", out.far);
        assert!(out.far.count <= out.unconverged_steps, "{out:?}");
        // At 2 m/s the free sheet covers its 2 cm in a hundredth of a second: it must
        // reach the barrier's range within the four steps, or the case tests nothing.
        assert!(out.min_gap < SELF_DHAT, "min gap {}", out.min_gap);
    }
}
