//! sinew-ik: one registry of the inverse-kinematics solvers, so every tool (the scene
//! runner, the benchmarks, the stress grid, the property suite) builds a solver the same
//! way instead of keeping its own table of names.
//!
//! [`SolverOptions`] names a solver and its options; with the `serde` feature it reads
//! and writes as the scene files spell it, `Ccd(...)` or `Fabrik(...)`, every option
//! defaulted (`Ccd()`, `Ccd(extrapolation: false)`, `Fabrik(mode: plain)`).
//! [`SolverOptions::build`] validates the options and returns a boxed [`IkSolver`].
//! [`SolverOptions::NAMED`] lists the configurations the reports compare, under the
//! labels they use.
//!
//! [`workloads`] holds reference skeletons with joint limits (the human arm) and poses drawn
//! inside the limits, shared by the tests, the benchmarks and the scene runner.
//!
//! ```
//! use sinew_ik::{DVec3, SolverOptions};
//! use sinew_skeleton::ik::{Chain, EffectorGoal, IkProblem, IkState, SolveSettings};
//! use sinew_skeleton::{GlobalPose, Skeleton};
//!
//! let arm = Skeleton::chain(DVec3::ZERO, &[DVec3::new(0.25, 0.0, 0.0); 4]).unwrap();
//! let chain = Chain::whole(&arm).unwrap();
//! let goals = [EffectorGoal::at(chain.effector(), DVec3::new(0.2, 0.6, -0.3))];
//! let problem = IkProblem::new(&arm, &chain, &goals, SolveSettings::default());
//! // Every named configuration solves the same problem through the same trait.
//! for (label, options) in SolverOptions::NAMED {
//!     let mut solver = options.build().unwrap();
//!     let (mut pose, mut global) = (arm.rest_pose(), GlobalPose::new());
//!     let report = solver.solve(&problem, &mut IkState::new(&mut pose, &mut global)).unwrap();
//!     assert!(report.error < 1e-6, "{label}: {report:?}");
//!     assert_eq!(options.label(), label);
//! }
//! assert!(SolverOptions::by_name("newton").unwrap_err().to_string().contains("ccd"));
//! ```
//!
//! Architecture invariant: this crate only depends on the solver crates and the
//! skeleton; each solver crate stays usable alone, without this one.

pub mod workloads;

pub use sinew_ik_ccd::{CcdOptions, CcdSolver};
pub use sinew_ik_fabrik::{FabrikMode, FabrikOptions, FabrikSolver};
/// The math types targets and poses are given in, re-exported so a user of this crate
/// does not also have to depend on sinew-math.
pub use sinew_math::{DQuat, DVec3};
use sinew_skeleton::ik::{IkError, IkSolver};

/// Which solver, with its options.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum SolverOptions {
    /// Cyclic coordinate descent ([`CcdSolver`]).
    Ccd(#[cfg_attr(feature = "serde", serde(default))] CcdOptions),
    /// FABRIK, plain or with the damped least-squares finish ([`FabrikSolver`]).
    Fabrik(#[cfg_attr(feature = "serde", serde(default))] FabrikOptions),
}

impl Default for SolverOptions {
    fn default() -> Self {
        Self::Fabrik(FabrikOptions::default())
    }
}

impl SolverOptions {
    /// The configurations the benchmarks, the stress grid and the property suite
    /// compare, with their labels (the same as [`SolverOptions::label`]).
    pub const NAMED: [(&'static str, SolverOptions); 4] = [
        (
            "ccd",
            Self::Ccd(CcdOptions {
                extrapolation: true,
                relaxation: 1.0,
                finish: true,
            }),
        ),
        (
            "ccd-plain",
            Self::Ccd(CcdOptions {
                extrapolation: false,
                relaxation: 1.0,
                finish: false,
            }),
        ),
        (
            "fabrik",
            Self::Fabrik(FabrikOptions {
                mode: FabrikMode::Hybrid,
                switch_ratio: 0.0,
            }),
        ),
        (
            "fabrik-plain",
            Self::Fabrik(FabrikOptions {
                mode: FabrikMode::Plain,
                switch_ratio: 0.0,
            }),
        ),
    ];

    /// The named configuration `name` (one of [`SolverOptions::NAMED`]), or an error
    /// listing the names.
    pub fn by_name(name: &str) -> Result<Self, IkError> {
        Self::NAMED
            .iter()
            .find(|(n, _)| *n == name)
            .map(|&(_, options)| options)
            .ok_or_else(|| {
                let names: Vec<&str> = Self::NAMED.iter().map(|(n, _)| *n).collect();
                IkError::InvalidSettings(format!(
                    "unknown solver {name:?}; the solvers are {}",
                    names.join(", ")
                ))
            })
    }

    /// Checks the options of the chosen solver.
    pub fn validate(&self) -> Result<(), IkError> {
        match self {
            Self::Ccd(options) => options.validate(),
            Self::Fabrik(options) => options.validate(),
        }
    }

    /// The solver, with validated options.
    pub fn build(&self) -> Result<Box<dyn IkSolver>, IkError> {
        Ok(match self {
            Self::Ccd(options) => Box::new(CcdSolver::with_options(*options)?),
            Self::Fabrik(options) => Box::new(FabrikSolver::with_options(*options)?),
        })
    }

    /// A short label for tables: `ccd` (extrapolated sweeps and the least-squares
    /// finish), `ccd-plain` (the lab's plain sweeps, no finish), `ccd-no-finish`
    /// (extrapolated sweeps alone), `ccd-plain-finish` (plain sweeps, then the finish),
    /// `ccd-relaxed` (over-relaxed, whatever else), `fabrik` (the hybrid) or
    /// `fabrik-plain`. Distinct options that behave differently get distinct labels.
    #[must_use]
    pub fn label(&self) -> &'static str {
        match self {
            Self::Ccd(o) if o.relaxation != 1.0 => "ccd-relaxed",
            Self::Ccd(o) => match (o.extrapolation, o.finish) {
                (true, true) => "ccd",
                (false, false) => "ccd-plain",
                (true, false) => "ccd-no-finish",
                (false, true) => "ccd-plain-finish",
            },
            Self::Fabrik(o) => match o.mode {
                FabrikMode::Hybrid => "fabrik",
                FabrikMode::Plain => "fabrik-plain",
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn named_configurations_build_and_carry_their_labels() {
        for (name, options) in SolverOptions::NAMED {
            assert_eq!(options.label(), name);
            assert_eq!(SolverOptions::by_name(name), Ok(options));
            let solver = options.build().unwrap();
            assert_eq!(solver.name(), &name[..name.find('-').unwrap_or(name.len())]);
        }
        assert_eq!(
            SolverOptions::NAMED[0].1,
            SolverOptions::Ccd(CcdOptions::default())
        );
        assert_eq!(
            SolverOptions::NAMED[1].1,
            SolverOptions::Ccd(CcdOptions::plain())
        );
        assert_eq!(
            SolverOptions::NAMED[2].1,
            SolverOptions::Fabrik(FabrikOptions::default())
        );
        assert_eq!(
            SolverOptions::NAMED[3].1,
            SolverOptions::Fabrik(FabrikOptions::plain())
        );
        // Every CCD combination gets its own label, so a table never shows two different
        // solvers under one name.
        let ccd = |extrapolation, finish| {
            SolverOptions::Ccd(CcdOptions {
                extrapolation,
                finish,
                ..CcdOptions::default()
            })
            .label()
        };
        assert_eq!(
            [
                ccd(true, true),
                ccd(false, false),
                ccd(true, false),
                ccd(false, true)
            ],
            ["ccd", "ccd-plain", "ccd-no-finish", "ccd-plain-finish"]
        );
        let err = SolverOptions::by_name("newton").unwrap_err().to_string();
        assert!(
            err.contains("newton") && err.contains("fabrik-plain"),
            "{err}"
        );
    }

    #[test]
    fn bad_options_are_refused_by_build() {
        let relaxed = SolverOptions::Ccd(CcdOptions {
            relaxation: 2.5,
            ..CcdOptions::default()
        });
        let err = relaxed.build().err().expect("refused").to_string();
        assert!(err.contains("relaxation"), "{err}");
        let fabrik = SolverOptions::Fabrik(FabrikOptions {
            switch_ratio: -0.5,
            ..FabrikOptions::default()
        });
        assert!(fabrik.validate().is_err());
        let ok = SolverOptions::Ccd(CcdOptions {
            relaxation: 1.5,
            extrapolation: false,
            finish: true,
        });
        assert_eq!(ok.label(), "ccd-relaxed");
        assert!(ok.build().is_ok());
    }
}
