//! The line search: Armijo backtracking from the Newton step, then doubling of an
//! accepted full step while `g` keeps falling, never beyond the terms' largest safe step.
//!
//! The changes of `g` are computed by the terms from the differences themselves (see
//! [`crate::spring::energy_change`]), so the sufficient-decrease test stays meaningful
//! when the change is far below `g`. A change that is `+inf` or NaN (a state a term does
//! not admit) fails the test like any increase.

use super::NewtonSettings;
use crate::potential::{Potential, StepContext};
use sinew_math::DVec3;

/// The most doublings of an accepted full Newton step in one line search (a step up to
/// 2^10 times the Newton step).
pub(super) const MAX_EXPANSIONS: usize = 10;

/// A rejected step is replaced by the minimizer of the quadratic through the slope and
/// the change it gave when that minimizer is below this fraction of it; otherwise the
/// step is halved.
const JUMP_BELOW: f64 = 1.0 / 1_048_576.0;

/// The next step length after `alpha` was rejected with the change `change` of `g`:
/// half of it, or, when the change is so far above the linear prediction `alpha slope`
/// that the quadratic model `slope t + c t^2` through it has its minimizer below
/// [`JUMP_BELOW`] `alpha`, that minimizer. A Newton step along a direction of (almost)
/// no curvature is huge (a flat sheet under gravity across its plane, whose springs at
/// rest have no stiffness out of the plane, and a step of 1e12 s: a fall of `g h^2`,
/// 3e23 under the lab's gravity), and
/// halving it down to a step the springs allow would take more trials than the search
/// has; the quadratic through the springs' energy there gives the right length at
/// once. A change that is not finite (outside a barrier's domain) is halved.
fn shorter(alpha: f64, slope: f64, change: f64) -> f64 {
    let half = 0.5 * alpha;
    if !change.is_finite() {
        return half;
    }
    // `c alpha^2 = change - slope alpha > 0`, as the change is above `armijo slope alpha`
    // with `slope < 0`.
    let curvature_term = change - slope * alpha;
    let minimizer = -slope * alpha * alpha / (2.0 * curvature_term);
    if minimizer > 0.0 && minimizer < JUMP_BELOW * alpha {
        minimizer
    } else {
        half
    }
}

/// What one line search found.
#[derive(Clone, Copy, Debug)]
pub(super) struct Outcome {
    /// The accepted step length, `None` when no tried step decreased `g` enough.
    pub(super) alpha: Option<f64>,
    /// Step halvings.
    pub(super) backtracks: usize,
    /// No step was accepted and every change of `g` tried was infinite or NaN.
    pub(super) none_finite: bool,
}

/// Searches along `dx` from `x` with slope `grad g . dx = slope < 0`, the changes of `g`
/// summed in fixed chunks (on the current thread pool when `par`; `partials` holds the
/// chunks' sums). An accepted full step is lengthened only when `expand`.
#[allow(clippy::too_many_arguments)]
pub(super) fn search(
    potential: &Potential,
    step: &StepContext<'_>,
    x: &[DVec3],
    dx: &[DVec3],
    slope: f64,
    settings: &NewtonSettings,
    expand: bool,
    par: bool,
    partials: &mut Vec<f64>,
) -> Outcome {
    // A term with a barrier caps the step so no tried state leaves its domain; without
    // lengthening, nothing beyond the full step is tried, and the terms need not look
    // further.
    let reach = if expand { f64::INFINITY } else { 1.0 };
    let cap = potential.max_step(step, x, dx, reach);
    let mut alpha = cap.min(1.0);
    let mut backtracks = 0;
    let mut accepted = None;
    // The change at the doubled full step, computed with the full step's: when the full
    // step is accepted and may be lengthened, the doubling is the next thing tried, and
    // evaluating both in one pass over the springs reads them once instead of twice
    // (the two results are the bits of two separate evaluations). A term other than
    // inertia and gravity (contact) is evaluated at the doubled step only when that step
    // is tried, so a rejected full step costs it nothing more.
    let mut doubled = None;
    let mut none_finite = alpha > 0.0;
    if alpha > 0.0 {
        for _ in 0..=settings.max_backtracks {
            let change = if expand && alpha == 1.0 && 2.0 <= cap {
                let (full, twice) =
                    potential.energy_change_pair_chunked(step, x, dx, [1.0, 2.0], par, partials);
                doubled = Some(twice);
                full
            } else {
                potential.energy_change_chunked(step, x, dx, alpha, par, partials)
            };
            if change <= settings.armijo * alpha * slope {
                accepted = Some(change);
                break;
            }
            none_finite &= !change.is_finite();
            backtracks += 1;
            alpha = shorter(alpha, slope, change);
        }
    }
    let Some(mut best) = accepted else {
        return Outcome {
            alpha: None,
            backtracks,
            none_finite,
        };
    };
    if expand && alpha == 1.0 {
        // The full step was accepted: where compressed springs make g non-convex, the
        // projected Hessian overstates the curvature and its step is too short, so Newton
        // crawls (hundreds of iterations on a sheet compressed to half size,
        // docs/stress.md). Double the step while g keeps falling and Armijo holds. Near a
        // minimum of a quadratic model the doubled step gives no decrease at all, so this
        // costs one evaluation of the change of g there and never changes a step that was
        // already right.
        for _ in 0..MAX_EXPANSIONS {
            if 2.0 * alpha > cap {
                break;
            }
            let trial = match doubled.take() {
                Some(twice) if alpha == 1.0 => potential.second_change(step, x, dx, twice),
                _ => potential.energy_change_chunked(step, x, dx, 2.0 * alpha, par, partials),
            };
            if trial < best && trial <= settings.armijo * 2.0 * alpha * slope {
                alpha *= 2.0;
                best = trial;
            } else {
                break;
            }
        }
    }
    Outcome {
        alpha: Some(alpha),
        backtracks,
        none_finite: false,
    }
}
