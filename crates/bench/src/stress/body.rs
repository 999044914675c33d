//! The full-body degenerate set: every configuration of `BodySolverOptions::NAMED` on
//! conflicting goals (the hands further apart than the arms reach), goals on the root
//! (with and without the body translating), two effectors on the same chain (feasible
//! and conflicting), zero-length bones, and a tree of 1 000 joints. Each solve is checked
//! against what any correct body solver keeps: no NaN, no joint limit violated, the
//! returned global pose and the reported worst error equal to forward kinematics of the
//! returned pose (computed here), and the weighted cost never above the start.

use serde::Serialize;
use sinew_ik_body::{
    BodyEffector, BodyProblem, BodySolverOptions, BodyState, forward_kinematics, limit_violation,
    workload,
};
use sinew_math::{DQuat, DVec3};
use sinew_skeleton::ik::SolveSettings;
use sinew_skeleton::{GlobalPose, JointDef, Skeleton};

/// One full-body case.
#[derive(Clone, Debug)]
pub struct BodyCase {
    /// What the case is.
    pub name: String,
    /// The skeleton, with its limits.
    pub skeleton: Skeleton,
    /// The effectors.
    pub effectors: Vec<BodyEffector>,
    /// Whether the body translates.
    pub root_translates: bool,
    /// Cap and tolerances.
    pub settings: SolveSettings,
}

/// What one solver did on one case.
#[derive(Clone, Debug, Serialize)]
pub struct BodyOutcome {
    /// The case's name.
    pub case: String,
    /// The configuration's label in `BodySolverOptions::NAMED`.
    pub solver: &'static str,
    /// The solver's error, if it returned one (a valid case must solve).
    pub error: Option<String>,
    /// The reported worst effector error.
    pub max_error: f64,
    /// The weighted cost at the start and at the end.
    pub cost: (f64, f64),
    /// The largest limit violation of the returned pose, measured here (radians).
    pub limit_violation: f64,
    /// The largest distance between the returned global pose and forward kinematics.
    pub fk_gap: f64,
    /// The difference between the reported worst error and forward kinematics'.
    pub report_gap: f64,
    /// The invariants that failed, in words (empty: the case passed).
    pub violations: Vec<String>,
}

impl BodyOutcome {
    /// Whether every invariant held.
    #[must_use]
    pub fn passed(&self) -> bool {
        self.violations.is_empty()
    }
}

fn chain(offsets: &[DVec3]) -> Skeleton {
    let mut joints = vec![JointDef::root(DVec3::ZERO)];
    joints.extend(
        offsets
            .iter()
            .enumerate()
            .map(|(i, &o)| JointDef::child(i, o)),
    );
    Skeleton::new(joints).expect("a chain with finite offsets")
}

fn humanoid() -> Skeleton {
    workload::humanoid().expect("the reference humanoid is valid")
}

fn settings() -> SolveSettings {
    SolveSettings::default()
}

/// The cases, built in code.
#[must_use]
pub fn cases() -> Vec<BodyCase> {
    let body = humanoid();
    let rest = BodyState::rest(&body);
    let at = |j: usize, d: DVec3| BodyEffector::at(j, rest.global.positions[j] + d);
    let [lw, rw, la, ra, head] = workload::EFFECTORS;
    let mut out = vec![
        BodyCase {
            name: "conflicting: hands 4 m apart".into(),
            skeleton: body.clone(),
            effectors: vec![
                at(lw, DVec3::X * 1.3),
                at(rw, -DVec3::X * 1.3),
                BodyEffector::pinned(la, rest.global.positions[la]),
                BodyEffector::pinned(ra, rest.global.positions[ra]),
            ],
            root_translates: true,
            settings: settings(),
        },
        BodyCase {
            name: "conflicting: head up, feet pinned".into(),
            skeleton: body.clone(),
            effectors: vec![
                at(head, DVec3::Y * 0.5),
                BodyEffector::pinned(la, rest.global.positions[la]),
                BodyEffector::pinned(ra, rest.global.positions[ra]),
            ],
            root_translates: true,
            settings: settings(),
        },
        BodyCase {
            name: "goal on the root, body translates".into(),
            skeleton: body.clone(),
            effectors: vec![at(0, DVec3::new(0.1, -0.2, 0.05)), at(head, DVec3::ZERO)],
            root_translates: true,
            settings: settings(),
        },
        BodyCase {
            name: "goal on the root, root fixed".into(),
            skeleton: body.clone(),
            effectors: vec![at(0, DVec3::new(0.1, -0.2, 0.05)), at(lw, DVec3::Y * 0.2)],
            root_translates: false,
            settings: settings(),
        },
        BodyCase {
            name: "same chain: elbow and wrist, feasible".into(),
            skeleton: body.clone(),
            effectors: {
                // Forward kinematics of a bent left arm: reachable by construction.
                let mut state = BodyState::rest(&body);
                state.pose.rotations[8] = body.limit(8).sample([0.5, 0.0, 0.0]);
                let _ = forward_kinematics(&body, &state.pose, DVec3::ZERO, &mut state.global);
                vec![
                    BodyEffector::at(8, state.global.positions[8]),
                    BodyEffector::at(lw, state.global.positions[lw]),
                ]
            },
            root_translates: false,
            settings: settings(),
        },
        BodyCase {
            name: "same chain: elbow and wrist, conflicting".into(),
            skeleton: body.clone(),
            effectors: vec![at(8, DVec3::Y * 0.3), at(lw, -DVec3::Y * 0.3)],
            root_translates: false,
            settings: settings(),
        },
    ];
    let zero = chain(&[DVec3::X, DVec3::ZERO, DVec3::X, DVec3::ZERO, DVec3::ZERO]);
    out.push(BodyCase {
        name: "zero-length bones, tip and a zero bone's joint".into(),
        effectors: vec![
            BodyEffector::at(5, DVec3::new(0.5, 1.2, 0.3)),
            BodyEffector::at(2, DVec3::new(0.7, 0.5, 0.0)),
        ],
        skeleton: zero,
        root_translates: false,
        settings: settings(),
    });
    let all_zero = chain(&[DVec3::ZERO; 4]);
    out.push(BodyCase {
        name: "zero-length bones only".into(),
        effectors: vec![BodyEffector::at(4, DVec3::new(1.0, 0.0, 0.0))],
        skeleton: all_zero,
        root_translates: true,
        settings: settings(),
    });
    out.push(big_tree());
    out
}

/// A tree of 1 000 joints: a root with four limbs of 250 joints (bones of 0.01 along
/// four directions), an effector at each limb's tip, its goal made by forward
/// kinematics of a gently bent pose (so reachable).
fn big_tree() -> BodyCase {
    let directions = [DVec3::X, -DVec3::X, DVec3::Y, DVec3::Z];
    let mut joints = vec![JointDef::root(DVec3::ZERO)];
    let mut tips = Vec::new();
    for dir in directions {
        let mut parent = 0;
        for _ in 0..250 {
            joints.push(JointDef::child(parent, dir * 0.01));
            parent = joints.len() - 1;
        }
        tips.push(parent);
    }
    joints.truncate(1000);
    let tips: Vec<usize> = tips.into_iter().map(|t| t.min(999)).collect();
    let skeleton = Skeleton::new(joints).expect("a valid tree");
    let mut state = BodyState::rest(&skeleton);
    for (j, r) in state.pose.rotations.iter_mut().enumerate().skip(1) {
        let t = j as f64;
        *r = DQuat::from_axis_angle(DVec3::new(t.sin(), t.cos(), 0.5).normalize(), 0.004);
    }
    let _ = forward_kinematics(&skeleton, &state.pose, DVec3::ZERO, &mut state.global);
    BodyCase {
        name: "tree of 1000 joints, four tips".into(),
        effectors: tips
            .iter()
            .map(|&t| BodyEffector::at(t, state.global.positions[t]))
            .collect(),
        skeleton,
        root_translates: false,
        settings: SolveSettings {
            max_iterations: 20,
            ..SolveSettings::default()
        },
    }
}

/// Solves `case` from the rest pose with the configuration `solver` and checks the
/// invariants.
#[must_use]
pub fn run_case(case: &BodyCase, solver: &'static str) -> BodyOutcome {
    let mut outcome = BodyOutcome {
        case: case.name.clone(),
        solver,
        error: None,
        max_error: f64::NAN,
        cost: (f64::NAN, f64::NAN),
        limit_violation: f64::NAN,
        fk_gap: f64::NAN,
        report_gap: f64::NAN,
        violations: Vec::new(),
    };
    let built = BodySolverOptions::by_name(solver).and_then(|o| o.build());
    let mut solver = match built {
        Ok(s) => s,
        Err(e) => {
            outcome.violations.push(format!("solver: {e}"));
            return outcome;
        }
    };
    let problem = BodyProblem::new(&case.skeleton, &case.effectors, case.settings)
        .with_root_translation(case.root_translates);
    let mut state = BodyState::rest(&case.skeleton);
    let report = match solver.solve(&problem, &mut state) {
        Ok(r) => r,
        Err(e) => {
            outcome.error = Some(e.to_string());
            outcome.violations.push(format!("a valid case failed: {e}"));
            return outcome;
        }
    };
    outcome.max_error = report.max_error;
    outcome.cost = (report.initial_cost, report.cost);
    let finite = state.pose.rotations.iter().all(|q| q.is_finite())
        && state.global.positions.iter().all(|p| p.is_finite())
        && state.root_translation.is_finite()
        && [report.cost, report.initial_cost, report.max_error]
            .iter()
            .all(|x| x.is_finite());
    if !finite {
        outcome
            .violations
            .push("NaN or infinity in the result".into());
        return outcome;
    }
    outcome.limit_violation = limit_violation(&case.skeleton, &state.pose);
    if outcome.limit_violation > 1e-12 {
        outcome.violations.push(format!(
            "a joint leaves its limit by {:.3e} rad",
            outcome.limit_violation
        ));
    }
    let mut check = GlobalPose::new();
    if let Err(e) = forward_kinematics(
        &case.skeleton,
        &state.pose,
        state.root_translation,
        &mut check,
    ) {
        outcome.violations.push(format!("forward kinematics: {e}"));
        return outcome;
    }
    let scale = (0..case.skeleton.len())
        .map(|j| case.skeleton.offset(j).length())
        .sum::<f64>()
        .max(1.0)
        + state.root_translation.length();
    outcome.fk_gap = sinew_scene::tasks::max_distance(&check.positions, &state.global.positions);
    let worst = case
        .effectors
        .iter()
        .map(|e| e.goal.position.distance(check.positions[e.goal.joint]))
        .fold(0.0, f64::max);
    outcome.report_gap = (worst - report.max_error).abs();
    if outcome.fk_gap > 1e-12 * scale {
        outcome.violations.push(format!(
            "the global pose differs from forward kinematics by {:.3e}",
            outcome.fk_gap
        ));
    }
    if outcome.report_gap > 1e-12 * scale {
        outcome.violations.push(format!(
            "the reported worst error differs from forward kinematics' by {:.3e}",
            outcome.report_gap
        ));
    }
    if report.cost > report.initial_cost {
        outcome.violations.push(format!(
            "the weighted cost rose from {:.6e} to {:.6e}",
            report.initial_cost, report.cost
        ));
    }
    outcome
}

/// Every case with every configuration of `BodySolverOptions::NAMED`, in order.
#[must_use]
pub fn run_all(cases: &[BodyCase]) -> Vec<BodyOutcome> {
    cases
        .iter()
        .flat_map(|case| {
            BodySolverOptions::NAMED
                .iter()
                .map(move |&(name, _)| run_case(case, name))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_solver_keeps_the_invariants_on_every_case() {
        let outcomes = run_all(&cases());
        assert_eq!(
            outcomes.len(),
            cases().len() * BodySolverOptions::NAMED.len()
        );
        let failed: Vec<String> = outcomes
            .iter()
            .filter(|o| !o.passed())
            .map(|o| format!("{} / {}: {:?}", o.case, o.solver, o.violations))
            .collect();
        assert!(failed.is_empty(), "{failed:#?}");
    }

    #[test]
    fn the_big_tree_has_a_thousand_joints_and_reachable_goals() {
        let case = big_tree();
        assert_eq!(case.skeleton.len(), 1000);
        assert_eq!(case.effectors.len(), 4);
        // Joint 999 is the last limb's tip (the limbs are 250 joints after the root, the
        // last cut to 249).
        assert!(case.effectors.iter().any(|e| e.goal.joint == 999));
    }
}
