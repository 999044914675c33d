//! What a solver carries from one warm frame to the next: the answers of its last two
//! solves, so that the next frame starts from their extrapolation (see
//! [`Common::predict`](crate::common::Common::predict) and `docs/ik-body.md`, "One
//! linearization per warm frame").
//!
//! The carried answers count only while the frames form one sequence: the state handed to
//! a solve is exactly (to the bit) the pose and translation the last solve returned, on
//! the same skeleton (structure, and limits to the bit), with the same effectors (joints,
//! pins, weights, which have rotation goals), settings and translation freedom. Anything
//! else (another character through the same solver, a pose the caller changed, an edited
//! problem) drops them, and the solve is exactly the one a fresh solver would do.

use crate::problem::BodyProblem;
use crate::problem::BodyState;
use sinew_math::{DQuat, DVec3};
use sinew_skeleton::ik::SolveSettings;
use sinew_skeleton::limits::{Hinge, JointLimit, SwingTwist};

/// One effector as far as the carried answers are concerned: joint, pinned, position
/// weight, rotation weight, whether it has a rotation goal. The goal positions and
/// rotations are what moves from frame to frame and are not compared.
type EffectorKey = (usize, bool, f64, f64, bool);

/// The carried answers and what they were solved for. No allocation once the buffers have
/// grown to the skeleton's size.
#[derive(Clone, Debug, Default)]
pub(crate) struct Carried {
    /// Whether `last` holds the answer of the last solve, of the problem below.
    valid: bool,
    fingerprint: u64,
    /// The limits of the last solve's skeleton, and a [`Skeleton::limits_revision`] known
    /// to stand for them: a skeleton of that revision has these limits to the bit, and
    /// only a skeleton of another revision has its limits compared (a batch's characters
    /// sharing one skeleton never read this copy).
    ///
    /// [`Skeleton::limits_revision`]: sinew_skeleton::Skeleton::limits_revision
    limits: Vec<JointLimit>,
    limits_revision: u64,
    effectors: Vec<EffectorKey>,
    settings: Option<SolveSettings>,
    root_translates: bool,
    /// The pose and translation the last solve returned.
    pub last: Vec<DQuat>,
    pub last_translation: DVec3,
    /// The global pose the last solve returned (forward kinematics of `last`).
    last_global_rotations: Vec<DQuat>,
    last_global_positions: Vec<DVec3>,
    /// The answer of the solve before it, when the last solve started from it
    /// (`has_before`): the two make a velocity.
    pub before: Vec<DQuat>,
    pub before_translation: DVec3,
    pub has_before: bool,
    /// Per joint, when the last solve's answer came from its extrapolated start
    /// (`has_correction`): the rotation that took the first-order extrapolation to the
    /// answer (`answer * extrapolation^-1`; the identity for a joint that was not
    /// extrapolated), and the same difference of the translation. For a smooth motion it
    /// is the second difference of the answers, which changes slowly, so the next start
    /// composes it onto its own extrapolation (`docs/ik-body.md`, "A start corrected by
    /// the last frame's correction").
    pub correction: Vec<DQuat>,
    pub correction_translation: DVec3,
    pub has_correction: bool,
}

fn key<'a>(problem: &BodyProblem<'a>) -> impl Iterator<Item = EffectorKey> + 'a {
    problem.effectors.iter().map(|e| {
        (
            e.goal.joint,
            e.pinned,
            e.goal.position_weight,
            e.goal.rotation_weight,
            e.goal.rotation.is_some(),
        )
    })
}

/// Zero exactly when `a` and `b` hold the same bits. Every word is compared, with no
/// early exit, so that a whole pose is compared in a few instructions a joint (the
/// carried checks run on every warm frame).
#[inline(always)]
fn bit_difference<const N: usize>(a: &[f64; N], b: &[f64; N]) -> u64 {
    a.iter()
        .zip(b)
        .fold(0, |d, (x, y)| d | (x.to_bits() ^ y.to_bits()))
}

/// Whether two joint limits are the same, to the bit (a limit that equals another only
/// by value, a `-0` for a `0`, counts as another: the carried answers are then dropped,
/// which is always allowed).
fn same_limit_bits(a: &JointLimit, b: &JointLimit) -> bool {
    match (a, b) {
        (JointLimit::Free, JointLimit::Free) | (JointLimit::Fixed, JointLimit::Fixed) => true,
        (JointLimit::Hinge(a), JointLimit::Hinge(b)) => {
            // Every field, by a pattern that a new field would break.
            let words = |&Hinge { axis, min, max }: &Hinge| [axis.x, axis.y, axis.z, min, max];
            bit_difference(&words(a), &words(b)) == 0
        }
        (JointLimit::SwingTwist(a), JointLimit::SwingTwist(b)) => {
            let words = |&SwingTwist {
                             twist_axis: t,
                             a_axis: a,
                             swing_a,
                             swing_b,
                             twist_min,
                             twist_max,
                         }: &SwingTwist| {
                [
                    t.x, t.y, t.z, a.x, a.y, a.z, swing_a, swing_b, twist_min, twist_max,
                ]
            };
            bit_difference(&words(a), &words(b)) == 0
        }
        _ => false,
    }
}

impl Carried {
    /// Asks the processor to bring the carried answers into its cache (a hint).
    pub(crate) fn prefetch(&self) {
        use sinew_skeleton::prefetch::prefetch;
        prefetch(&self.effectors);
        prefetch(&self.last);
        prefetch(&self.last_global_rotations);
        prefetch(&self.last_global_positions);
        prefetch(&self.before);
        prefetch(&self.correction);
    }

    /// Whether `problem` has the structure of the last solve's, which was validated: the
    /// same skeleton (structure, and limits to the bit), effectors (joints, pins,
    /// weights, which have rotation goals), settings and translation freedom, only the
    /// goals' positions, rotations and poles free to differ. The state is not looked at:
    /// a cold solve of another goal set on the same body has the same problem.
    pub fn same_problem(&self, problem: &BodyProblem<'_>) -> bool {
        let skeleton = problem.skeleton;
        self.valid
            && self.settings == Some(problem.settings)
            && self.root_translates == problem.root_translates
            && self.fingerprint == skeleton.fingerprint()
            && self.limits.len() == skeleton.len()
            && (self.limits_revision == skeleton.limits_revision()
                || (0..skeleton.len()).fold(true, |same, j| {
                    same & same_limit_bits(&self.limits[j], skeleton.limit(j))
                }))
            && self.effectors.len() == problem.effectors.len()
            && self.effectors.iter().copied().eq(key(problem))
    }

    /// Whether a solve from `state` of a problem that has the last solve's structure
    /// ([`Carried::same_problem`]) continues the sequence of the carried answers: the
    /// state is the last answer to the bit (call before anything changes `state`).
    pub fn continues(&self, state: &BodyState) -> bool {
        self.valid
            && state.root_translation == self.last_translation
            && state.pose.rotations == self.last
    }

    /// Whether `state.global` is, to the bit, the global pose the last solve returned, so
    /// that for a state that [`Carried::continues`] it is exactly forward kinematics of
    /// the pose and need not be computed again.
    pub fn global_unchanged(&self, state: &BodyState) -> bool {
        self.valid
            && state.global.rotations.len() == self.last_global_rotations.len()
            && state.global.positions.len() == self.last_global_positions.len()
            && state
                .global
                .rotations
                .iter()
                .zip(&self.last_global_rotations)
                .fold(0, |d, (a, b)| {
                    d | bit_difference(&a.to_array(), &b.to_array())
                })
                == 0
            && state
                .global
                .positions
                .iter()
                .zip(&self.last_global_positions)
                .fold(0, |d, (a, b)| {
                    d | bit_difference(&a.to_array(), &b.to_array())
                })
                == 0
    }

    /// Forgets the carried answers (after an error).
    pub fn invalidate(&mut self) {
        self.valid = false;
        self.has_before = false;
        self.has_correction = false;
    }

    /// Records the answer in `state` of a solve of `problem`; `continued` says whether it
    /// started from the last answer ([`Carried::continues`]), which then becomes the one
    /// before, and `same_problem` whether the problem had the last one's structure
    /// ([`Carried::same_problem`]), which then need not be copied again.
    pub fn record(
        &mut self,
        problem: &BodyProblem<'_>,
        state: &BodyState,
        same_problem: bool,
        continued: bool,
    ) {
        let skeleton = problem.skeleton;
        if continued {
            std::mem::swap(&mut self.before, &mut self.last);
            self.before_translation = self.last_translation;
            self.has_before = true;
        } else {
            self.has_before = false;
            self.has_correction = false;
        }
        // Of the same problem, the limits are these to the bit: the revision stands for
        // them from now on.
        self.limits_revision = skeleton.limits_revision();
        if !same_problem {
            self.fingerprint = skeleton.fingerprint();
            self.limits.clear();
            self.limits
                .extend((0..skeleton.len()).map(|j| *skeleton.limit(j)));
            self.effectors.clear();
            self.effectors.extend(key(problem));
            self.settings = Some(problem.settings);
            self.root_translates = problem.root_translates;
            // The next frames' correction, sized now: the first one may come many frames
            // later, and a warm solve must not allocate then.
            // (A new structure is never continued: no correction is kept.)
            self.correction.clear();
            self.correction.reserve(skeleton.len());
        }
        self.last.clear();
        self.last.extend_from_slice(&state.pose.rotations);
        self.last_translation = state.root_translation;
        self.last_global_rotations.clear();
        self.last_global_rotations
            .extend_from_slice(&state.global.rotations);
        self.last_global_positions.clear();
        self.last_global_positions
            .extend_from_slice(&state.global.positions);
        self.valid = true;
    }

    /// After [`Carried::record`] of an answer solved from the extrapolated start whose
    /// first-order part was `first_order` (per joint, used where `extrapolated`) and
    /// `first_order_translation`: keeps how far the answer ended from it, for the next
    /// start ([`Common::predict`](crate::common::Common::predict)).
    pub fn record_correction(
        &mut self,
        state: &BodyState,
        first_order: &[DQuat],
        extrapolated: &[bool],
        first_order_translation: DVec3,
    ) {
        self.correction.clear();
        self.correction.extend(
            state
                .pose
                .rotations
                .iter()
                .zip(first_order)
                .zip(extrapolated)
                .map(|((&answer, &first), &used)| {
                    if !used {
                        return DQuat::IDENTITY;
                    }
                    let mut c = answer * first.conjugate();
                    if c.w < 0.0 {
                        c = -c;
                    }
                    c.normalize()
                }),
        );
        self.correction_translation = state.root_translation - first_order_translation;
        self.has_correction = self.correction.len() == state.pose.rotations.len();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sinew_math::DVec3;

    /// Every field of a limit counts, to the bit; another kind of limit never matches.
    #[test]
    fn limits_are_the_same_only_to_the_bit() {
        let hinge = JointLimit::hinge(DVec3::Y, -0.5, 2.0).expect("valid");
        let shoulder =
            JointLimit::swing_twist(DVec3::X, DVec3::Z, 1.7, 1.2, -1.4, 1.4).expect("valid");
        for limit in [JointLimit::Free, JointLimit::Fixed, hinge, shoulder] {
            assert!(same_limit_bits(&limit, &limit), "{limit:?}");
        }
        assert!(!same_limit_bits(&JointLimit::Free, &JointLimit::Fixed));
        assert!(!same_limit_bits(&hinge, &shoulder));
        let JointLimit::Hinge(h) = hinge else {
            panic!("a hinge")
        };
        let hinges = [
            Hinge { min: -0.4, ..h },
            Hinge { max: 2.1, ..h },
            Hinge {
                axis: DVec3::new(-0.0, 1.0, 0.0),
                ..h
            },
        ];
        for other in hinges {
            assert!(
                !same_limit_bits(&hinge, &JointLimit::Hinge(other)),
                "{other:?}"
            );
        }
        let JointLimit::SwingTwist(st) = shoulder else {
            panic!("a swing-twist")
        };
        let others = [
            SwingTwist {
                twist_axis: DVec3::new(1.0, 1e-17, 0.0),
                ..st
            },
            SwingTwist {
                a_axis: DVec3::new(0.0, 1e-17, 1.0),
                ..st
            },
            SwingTwist { swing_a: 1.6, ..st },
            SwingTwist { swing_b: 1.1, ..st },
            SwingTwist {
                twist_min: -1.3,
                ..st
            },
            SwingTwist {
                twist_max: 1.3,
                ..st
            },
        ];
        for other in others {
            assert!(
                !same_limit_bits(&shoulder, &JointLimit::SwingTwist(other)),
                "{other:?}"
            );
        }
    }
}
