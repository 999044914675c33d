//! The most work a scene may ask for. A scene file is input like any other: a typo or a
//! flipped digit must not make the runner allocate without bound or run for days, so
//! every count and every product of counts that sets the size of the work is checked
//! against a limit here before anything is built, and a scene above one is an error
//! naming the task, the field and the limit. docs/scenes.md lists them ("Limits"); each
//! is one to three orders of magnitude above the largest shipped scene.

/// The most joints of a skeleton.
pub const MAX_JOINTS: usize = 1_000_000;

/// The most points a curve sampling gives (an `Ik` task's targets, a `Curve` task).
pub const MAX_SAMPLES: usize = 1_000_000;

/// The most petals of a curve (`Epicycloid` `petals`, `Rose` `k`).
pub const MAX_PETALS: u32 = 10_000;

/// The most frames of an `Ik`, `TwoBone` or `FullBody` task.
pub const MAX_FRAMES: usize = 1_000_000;

/// The most iterations a solver may be allowed per frame (IK, full body, Newton).
pub const MAX_ITERATIONS: usize = 10_000;

/// The most joint updates an IK or full-body task may ask for: frames x the iteration
/// cap x the joints solved.
pub const MAX_SOLVE_WORK: f64 = 1e10;

/// The most particles on a side of a cloth grid (so a grid of `size` squared particles
/// is checked before its size overflows).
pub const MAX_GRID_SIZE: usize = 1_000;

/// The most particles of a cloth.
pub const MAX_PARTICLES: usize = 1_000_000;

/// The most steps of a cloth.
pub const MAX_STEPS: usize = 10_000_000;

/// The most particle steps of a cloth: particles x steps x the substeps of each step
/// (explicit integrators) or the Newton iteration cap (implicit ones).
pub const MAX_PARTICLE_STEPS: f64 = 1e10;

/// The error for `field = value` above `limit`, in the words every limit uses.
#[must_use]
pub fn above(field: &str, value: impl std::fmt::Display, limit: impl std::fmt::Display) -> String {
    format!("{field} = {value} is above the limit of {limit} (docs/scenes.md, \"Limits\")")
}

/// `Ok` when `value <= limit`, else the error of [`above`].
pub fn at_most<T: PartialOrd + std::fmt::Display>(
    field: &str,
    value: T,
    limit: T,
) -> Result<(), String> {
    if value <= limit {
        Ok(())
    } else {
        Err(above(field, value, limit))
    }
}

/// Checks the size of an IK or full-body task: `frames` at most [`MAX_FRAMES`], the
/// iteration cap at most [`MAX_ITERATIONS`], and frames x cap x `joints` (times
/// `attempts`, the solves a frame may restart) at most [`MAX_SOLVE_WORK`].
pub fn check_solve_work(
    frames: usize,
    max_iterations: usize,
    attempts: usize,
    joints: usize,
) -> Result<(), String> {
    at_most("frames", frames, MAX_FRAMES)?;
    at_most("settings: max_iterations", max_iterations, MAX_ITERATIONS)?;
    let work =
        frames as f64 * max_iterations.max(1) as f64 * attempts.max(1) as f64 * joints as f64;
    if work > MAX_SOLVE_WORK {
        return Err(format!(
            "settings: max_iterations = {max_iterations} over {frames} frames of {joints} \
             joints ({attempts} attempts a frame) asks for {work:.2e} joint updates, above the \
             limit of {MAX_SOLVE_WORK:.0e} (docs/scenes.md, \"Limits\")"
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_value_above_its_limit_names_the_field_and_the_limit() {
        assert_eq!(at_most("steps", 10, 10), Ok(()));
        assert_eq!(
            at_most("steps", 11, 10).unwrap_err(),
            "steps = 11 is above the limit of 10 (docs/scenes.md, \"Limits\")"
        );
    }
}
