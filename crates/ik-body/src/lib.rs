//! Full-body inverse kinematics: several effectors on one skeleton tree (hands, feet,
//! head, any joint, not only leaves), solved together.
//!
//! - [`BodyProblem`]: the job's inputs, the skeleton (with its joint limits), the
//!   [`BodyEffector`]s (an [`EffectorGoal`](sinew_skeleton::ik::EffectorGoal) each, and
//!   whether it is pinned where it stands, like a planted foot), the solve settings and
//!   whether the whole body may translate. [`BodyProblem::validate`] names the offending
//!   effector and field.
//! - [`BodyState`]: what a solve updates (pose, the body's translation, forward kinematics,
//!   per-effector errors); [`BodyReport`]: iterations, stop reason, weighted cost before
//!   and after, worst errors, largest limit violation.
//! - [`TreeFabrikSolver`]: FABRIK with sub-bases (Aristidou and Lasenby 2011), the joint
//!   limits, and a damped least-squares finish over all effectors at once, so feasible
//!   goals are reached to the tolerance.
//! - [`TreeCcdSolver`]: cyclic coordinate descent where each joint takes the closed-form
//!   best rotation for all the effectors below it ([`BestRotation`], Horn 1987).
//! - [`BodySolverOptions`]: the registry, so a caller (or a scene file, with the `serde`
//!   feature) builds either solver from options; [`BodyBatch`]: many characters, one
//!   warm frame each, without allocation once warmed up.
//! - [`workload`]: the reference humanoid of 22 joints with human-like limits and its goal
//!   sets (W8), shared by the tests, the benchmark and the measurement example.
//!
//! Every solver decreases one weighted least-squares cost (see [`problem`]); when the goals
//! conflict, it ends at a local minimum of that cost, reported per effector. The method and
//! the derivations are in `docs/ik-body.md`.
//!
//! Architecture invariant: depends on sinew-skeleton and sinew-math only (serde behind the
//! `serde` feature).
//!
//! # Example
//!
//! One frame of the reference squat: both ankles pinned where they stand, the head and
//! the wrists given goals, the hips free to move. FABRIK reaches every goal to the
//! default tolerance (1e-6) and the planted feet do not slide.
//!
//! ```
//! use sinew_ik_body::{BodyProblem, BodySolver, BodyState, TreeFabrikSolver, workload};
//! use sinew_skeleton::ik::SolveSettings;
//!
//! let skeleton = workload::humanoid()?; // 22 joints with human-like limits
//! let mut state = BodyState::rest(&skeleton);
//! let rest = state.global.clone();
//! let effectors = workload::clip_frame(&rest, 150); // the bottom of the squat
//! let settings = SolveSettings::default();
//! let problem = BodyProblem::new(&skeleton, &effectors, settings).with_root_translation(true);
//!
//! let report = TreeFabrikSolver::new().solve(&problem, &mut state)?;
//! assert!(report.within(&settings), "{report:?}");
//! let ankle = workload::EFFECTORS[2];
//! assert!(state.global.positions[ankle].distance(rest.positions[ankle]) <= 1e-6);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod carry;
pub mod ccd;
mod common;
pub mod fabrik;
mod horn;
pub mod problem;
pub mod workload;

pub use ccd::{TreeCcdOptions, TreeCcdSolver};
use common::SolveScratch;
pub use fabrik::{TreeFabrikOptions, TreeFabrikSolver};
pub use horn::BestRotation;
pub use problem::{
    BodyEffector, BodyProblem, BodyReport, BodyState, EffectorErrors, PIN_WEIGHT,
    forward_kinematics, limit_violation,
};

use sinew_skeleton::ik::IkError;

/// A full-body solver: moves the effectors of a [`BodyProblem`] towards their goals by
/// changing local rotations (and the body's translation when the problem allows it).
///
/// Contract: on `Ok`, `state.pose` is inside every joint limit (the starting pose is
/// projected onto them first), `state.global` is forward kinematics of the pose and
/// translation, `state.effectors` and the report carry the errors of that pose, the
/// weighted cost never ends above the starting one, a pinned effector ends within the
/// tolerance of where it started, no NaN is produced for any valid input, and nothing
/// allocates once the solver's buffers have grown to the problem's size.
pub trait BodySolver {
    /// A short name for reports ("fabrik", "ccd").
    fn name(&self) -> &'static str;

    /// Solves `problem`, starting from `state` (warm start).
    fn solve(
        &mut self,
        problem: &BodyProblem<'_>,
        state: &mut BodyState,
    ) -> Result<BodyReport, IkError>;
}

/// Which body solver, with its options; with the `serde` feature it reads as
/// `Fabrik(...)` or `Ccd(...)`, every option defaulted.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum BodySolverOptions {
    /// Tree FABRIK ([`TreeFabrikSolver`]).
    Fabrik(#[cfg_attr(feature = "serde", serde(default))] TreeFabrikOptions),
    /// Tree CCD ([`TreeCcdSolver`]).
    Ccd(#[cfg_attr(feature = "serde", serde(default))] TreeCcdOptions),
}

impl Default for BodySolverOptions {
    fn default() -> Self {
        Self::Fabrik(TreeFabrikOptions::default())
    }
}

impl BodySolverOptions {
    /// The configurations the reports compare, with their labels.
    pub const NAMED: [(&'static str, BodySolverOptions); 5] = [
        (
            "dls",
            Self::Fabrik(TreeFabrikOptions {
                max_passes: 0,
                switch_ratio: 0.5,
                finish: true,
                restarts: 3,
            }),
        ),
        (
            "fabrik",
            Self::Fabrik(TreeFabrikOptions {
                max_passes: 4,
                switch_ratio: 0.5,
                finish: true,
                restarts: 3,
            }),
        ),
        (
            "fabrik-plain",
            Self::Fabrik(TreeFabrikOptions {
                max_passes: usize::MAX,
                switch_ratio: 1.0,
                finish: false,
                restarts: 0,
            }),
        ),
        (
            "ccd",
            Self::Ccd(TreeCcdOptions {
                finish: false,
                max_sweeps: 10,
            }),
        ),
        (
            "ccd-finish",
            Self::Ccd(TreeCcdOptions {
                finish: true,
                max_sweeps: 10,
            }),
        ),
    ];

    /// The named configuration `name`, or an error listing the names.
    pub fn by_name(name: &str) -> Result<Self, IkError> {
        Self::NAMED
            .iter()
            .find(|(n, _)| *n == name)
            .map(|&(_, options)| options)
            .ok_or_else(|| {
                let names: Vec<&str> = Self::NAMED.iter().map(|(n, _)| *n).collect();
                IkError::InvalidSettings(format!(
                    "unknown body solver {name:?}; the solvers are {}",
                    names.join(", ")
                ))
            })
    }

    /// Checks the options of the chosen solver.
    pub fn validate(&self) -> Result<(), IkError> {
        match self {
            Self::Fabrik(options) => options.validate(),
            Self::Ccd(options) => options.validate(),
        }
    }

    /// The solver, with validated options.
    pub fn build(&self) -> Result<Box<dyn BodySolver + Send>, IkError> {
        Ok(match self {
            Self::Fabrik(options) => Box::new(TreeFabrikSolver::with_options(*options)?),
            Self::Ccd(options) => Box::new(TreeCcdSolver::with_options(*options)?),
        })
    }
}

/// Many characters, each solving one frame: one solver per character, holding what
/// carries from one frame to the next (the last answers, the last factor and columns),
/// and per group of characters solved on one thread one set of scratch buffers (what a
/// solve writes before it reads it), lent to each character's solver for its solve. The
/// scratch buffers stay in cache from one character to the next, and each character
/// brings in only its own carried state: on W8's 1 000 characters that is 27 kB of heap
/// a character instead of 43 kB; and while a character solves, the next one's carried
/// state is asked for ([`sinew_skeleton::prefetch`], a hint that changes no result). See
/// `docs/ik-body.md`. Once every character has been
/// solved once nothing allocates on one thread.
///
/// # Example
///
/// Four characters at four frames of the squat, on two threads; each ends within the
/// tolerance, exactly as a lone solver would.
///
/// ```
/// use sinew_ik_body::{
///     BodyBatch, BodyProblem, BodySolver, BodyState, TreeFabrikOptions, TreeFabrikSolver, workload,
/// };
/// use sinew_skeleton::ik::SolveSettings;
///
/// let skeleton = workload::humanoid()?;
/// let rest = BodyState::rest(&skeleton);
/// let settings = SolveSettings::default();
/// let frames: Vec<_> = (0..4).map(|c| workload::clip_frame(&rest.global, 75 * c)).collect();
/// let problems: Vec<_> = frames
///     .iter()
///     .map(|e| BodyProblem::new(&skeleton, e, settings).with_root_translation(true))
///     .collect();
/// // The first character solved alone, for comparison.
/// let mut alone = rest.clone();
/// let first = TreeFabrikSolver::new().solve(&problems[0], &mut alone)?;
///
/// let mut states = vec![rest.clone(); 4];
/// let mut reports = vec![first; 4]; // every entry is overwritten
/// let mut batch = BodyBatch::new(TreeFabrikOptions::default())?;
/// batch.solve(&problems, &mut states, &mut reports, 2)?;
/// assert!(reports.iter().all(|r| r.within(&settings)), "{reports:?}");
/// assert_eq!(states[0], alone);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug, Default)]
pub struct BodyBatch {
    solvers: Vec<TreeFabrikSolver>,
    /// Per thread, the scratch buffers lent to each of its characters' solvers in turn
    /// (what a solve writes before it reads it), so that they stay in cache while the
    /// characters' own buffers (what carries from one frame to the next) are fetched.
    scratch: Vec<SolveScratch>,
    options: TreeFabrikOptions,
}

impl BodyBatch {
    /// A batch whose solvers use `options`, validated.
    pub fn new(options: TreeFabrikOptions) -> Result<Self, IkError> {
        options.validate()?;
        Ok(Self {
            solvers: Vec::new(),
            scratch: Vec::new(),
            options,
        })
    }

    /// Solves `problems[i]` on `states[i]` for every character, writing `reports[i]`, on
    /// up to `threads` threads: the characters split into contiguous groups, the last
    /// solved on the calling thread and each other one on a scoped thread spawned for
    /// this call (its only allocations); 1 spawns none and allocates nothing once warm.
    /// Each character keeps its own solver, and a solve's results do not depend on the
    /// scratch buffers it is lent, so the answers are the same, to the bit, on any number
    /// of threads and as a lone [`TreeFabrikSolver`] per character would give them. All three slices must have the same length; the first error
    /// (in character order) is returned, the other characters being solved all the same.
    pub fn solve(
        &mut self,
        problems: &[BodyProblem<'_>],
        states: &mut [BodyState],
        reports: &mut [BodyReport],
        threads: usize,
    ) -> Result<(), IkError> {
        if states.len() != problems.len() || reports.len() != problems.len() {
            return Err(IkError::InvalidSettings(format!(
                "batch: {} problems, {} states and {} reports; they must match",
                problems.len(),
                states.len(),
                reports.len()
            )));
        }
        if self.solvers.len() < problems.len() {
            let solver = TreeFabrikSolver::with_options(self.options)?;
            self.solvers.resize(problems.len(), solver);
        }
        let threads = threads.clamp(1, problems.len().max(1));
        let solvers = &mut self.solvers[..problems.len()];
        let per = problems.len().div_ceil(threads);
        // One set of scratch buffers per group of characters (as many as threads, or one
        // fewer when the groups of `per` need fewer).
        let groups = problems.len().div_ceil(per.max(1)).max(1);
        if self.scratch.len() < groups {
            self.scratch.resize_with(groups, SolveScratch::default);
        }
        let scratch = &mut self.scratch[..groups];
        if threads == 1 {
            return solve_group(solvers, &mut scratch[0], problems, states, reports);
        }
        std::thread::scope(|scope| {
            solve_split(scope, solvers, scratch, problems, states, reports, per)
        })
    }
}

/// Solves the characters in groups of `per`: the first group on a new scoped thread, the
/// rest by recursion on this one, so the calling thread solves the last group and the
/// only allocations are the spawns themselves (no list of handles). The first error in
/// character order is returned, every group being solved all the same.
fn solve_split<'scope>(
    scope: &'scope std::thread::Scope<'scope, '_>,
    solvers: &'scope mut [TreeFabrikSolver],
    scratch: &'scope mut [SolveScratch],
    problems: &'scope [BodyProblem<'_>],
    states: &'scope mut [BodyState],
    reports: &'scope mut [BodyReport],
    per: usize,
) -> Result<(), IkError> {
    let Some((own, other_scratch)) = scratch.split_first_mut() else {
        return Err(IkError::InvalidSettings(
            "batch: no scratch buffers for a group of characters".into(),
        ));
    };
    if problems.len() <= per {
        return solve_group(solvers, own, problems, states, reports);
    }
    let (solvers, other_solvers) = solvers.split_at_mut(per);
    let (problems, other_problems) = problems.split_at(per);
    let (states, other_states) = states.split_at_mut(per);
    let (reports, other_reports) = reports.split_at_mut(per);
    let first = scope.spawn(move || solve_group(solvers, own, problems, states, reports));
    let rest = solve_split(
        scope,
        other_solvers,
        other_scratch,
        other_problems,
        other_states,
        other_reports,
        per,
    );
    let first = first.join().unwrap_or_else(|_| {
        Err(IkError::InvalidSettings(
            "batch: a solver thread panicked".into(),
        ))
    });
    first.and(rest)
}

fn solve_group(
    solvers: &mut [TreeFabrikSolver],
    scratch: &mut SolveScratch,
    problems: &[BodyProblem<'_>],
    states: &mut [BodyState],
    reports: &mut [BodyReport],
) -> Result<(), IkError> {
    let mut first = Ok(());
    for i in 0..problems.len() {
        // The next character's state was last touched a batch ago: fetched while this
        // one is solved rather than as its solve first reads it (a hint; no result
        // depends on it).
        if let (Some(next), Some(next_state)) = (solvers.get(i + 1), states.get(i + 1)) {
            next.prefetch(next_state);
        }
        let (solver, problem, state, report) = (
            &mut solvers[i],
            &problems[i],
            &mut states[i],
            &mut reports[i],
        );
        // The group's scratch buffers lent for this solve and taken back after it, so
        // that a character's solver owns only what carries from one frame to the next.
        solver.swap_scratch(scratch);
        let solved = solver.solve(problem, state);
        solver.swap_scratch(scratch);
        match solved {
            Ok(r) => *report = r,
            Err(e) => {
                if first.is_ok() {
                    first = Err(e);
                }
            }
        }
    }
    first
}
