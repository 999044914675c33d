//! Continuous collision detection for self-contact: additive CCD (ACCD, Li et al.,
//! "Codimensional Incremental Potential Contact", 2021) for a point-triangle or edge-edge
//! pair moving linearly over a step, giving the fraction of the step the pair may take
//! while its distance stays above a set fraction of its current gap.
//!
//! Over the step the vertices move as `x_k(t) = x_k + t dx_k`, `t` in `[0, 1]`. Only the
//! relative motion matters, so the mean displacement is subtracted from every `dx_k`;
//! then `l_p = |dx_p| + max_k |dx_tk|` (point-triangle) or
//! `max(|dx_a0|, |dx_a1|) + max(|dx_b0|, |dx_b1|)` (edge-edge) bounds how fast any point
//! of one primitive approaches any point of the other, so the gap `g(t) = d(t) - xi`
//! (`xi` the thickness) falls at most at rate `l_p`: from a time with gap `g`, a further
//! `0.9 g / l_p` keeps the gap above `0.1 g > 0`. ACCD advances by such steps, each
//! measured again at the exact distance, until the gap would fall below `s g_0` (`s` the
//! fraction of the gap kept) or the step is covered. Every time it passes has a positive
//! gap, so no crossing can happen before the returned time. It needs no root finding
//! and no floating-point filters; its cost grows where the pair slides tangentially
//! very close (many small steps), which an iteration cap bounds: at the cap the time
//! reached so far is returned, still safe.

use super::distance::{PairKind, SEPARATION_MARGIN, separation, squared_distance};
use sinew_math::DVec3;

/// Most ACCD iterations per pair; at this many the time reached so far is returned.
pub const MAX_ITERATIONS: usize = 10_000;

/// The largest fraction `t` in `[0, 1]` of the linear step `x -> x + dx` of the pair
/// `x` (of kind `kind`) such that on `[0, t]` the distance stays above `thickness`, with
/// the gap `d - thickness` at `t` at least about `keep` times its value at `t = 0`
/// (`0 < keep < 1`); 1 when the pair never comes that close within the step, 0 when the
/// gap is already zero or negative. See the module documentation.
#[must_use]
pub fn additive_ccd(
    kind: PairKind,
    x: &[DVec3; 4],
    dx: &[DVec3; 4],
    thickness: f64,
    keep: f64,
) -> f64 {
    let gap0 = squared_distance(kind, x).sqrt() - thickness;
    additive_ccd_within(kind, x, dx, thickness, keep, gap0, 1.0)
}

/// `l_p` of the module documentation: a bound on how much the gap of a pair moving by
/// `dx` over the step can fall (the rate at which any point of one primitive approaches
/// any point of the other, the mean displacement taken out).
#[must_use]
pub fn approach_bound(kind: PairKind, dx: &[DVec3; 4]) -> f64 {
    let mean = (dx[0] + dx[1] + dx[2] + dx[3]) / 4.0;
    let p = dx.map(|d| d - mean);
    // The largest length is the root of the largest squared length (the root is
    // monotone and correctly rounded: the same bits), two roots where there were four.
    let s = p.map(DVec3::length_squared);
    match kind {
        PairKind::PointTriangle => s[0].sqrt() + s[1].max(s[2]).max(s[3]).sqrt(),
        PairKind::EdgeEdge => s[0].max(s[1]).sqrt() + s[2].max(s[3]).sqrt(),
    }
}

/// Whether [`additive_ccd`] returns 1 for the pair on its first test (`l_p <= (1 - keep)
/// gap0`, the whole step closes less than the allowed part of the gap), shown with a
/// lower bound of `gap0` instead of the exact distance: the pair's [`separation`] less
/// [`SEPARATION_MARGIN`] of it, less the thickness. A pair the broad phase lists along a
/// long step is usually clear this way, at a few dot products.
#[must_use]
pub fn clear_without_distance(
    kind: PairKind,
    x: &[DVec3; 4],
    dx: &[DVec3; 4],
    thickness: f64,
    keep: f64,
) -> bool {
    clear_with_bound(
        separation(kind, x),
        approach_bound(kind, dx),
        thickness,
        keep,
    )
}

/// [`clear_without_distance`] with the pair's [`separation`] at `x` and its
/// [`approach_bound`] `lp` given (a caller that sweeps the pair when it is not clear
/// computes the bound once for both, and one that sweeps it along two steps from the
/// same state computes the separation once). A NaN separation fails the first test.
#[must_use]
pub fn clear_with_bound(separation: f64, lp: f64, thickness: f64, keep: f64) -> bool {
    let lower = separation * (1.0 - SEPARATION_MARGIN) - thickness;
    lower > 0.0 && lp.is_finite() && lp <= lower * (1.0 - keep)
}

/// [`additive_ccd`] with the pair's gap at `t = 0` given (`gap0` must be
/// `squared_distance(kind, x).sqrt() - thickness`, as [`additive_ccd`] computes it; a
/// caller that already has it saves that distance), and only fractions up to `limit`
/// wanted: the answer is `min(limit, additive_ccd(..))`, bit for bit, for `limit` in
/// `[0, 1]` (`limit` 1 gives the whole sweep's). The sweep stops once it has safely
/// passed `limit` (the whole sweep would go at least that far). A line search needs the smallest fraction over all pairs, so each pair's sweep
/// may stop at the smallest fraction found so far: the minimum over the pairs is
/// unchanged, whatever the order they are swept in (each limit is at least that
/// minimum). A pair sliding a long way past another at a small gap crawls in steps of
/// `0.9 gap / l_p`; once another pair has capped the step at a small fraction, its sweep
/// stops there.
#[must_use]
pub fn additive_ccd_within(
    kind: PairKind,
    x: &[DVec3; 4],
    dx: &[DVec3; 4],
    thickness: f64,
    keep: f64,
    gap0: f64,
    limit: f64,
) -> f64 {
    additive_ccd_with_bound(
        kind,
        x,
        dx,
        approach_bound(kind, dx),
        thickness,
        keep,
        gap0,
        limit,
    )
}

/// [`additive_ccd_within`] with the pair's [`approach_bound`] `lp` given.
#[allow(clippy::too_many_arguments)]
#[must_use]
pub fn additive_ccd_with_bound(
    kind: PairKind,
    x: &[DVec3; 4],
    dx: &[DVec3; 4],
    lp: f64,
    thickness: f64,
    keep: f64,
    gap0: f64,
    limit: f64,
) -> f64 {
    let gap_at = |t: f64| {
        let xt: [DVec3; 4] = std::array::from_fn(|k| x[k] + t * dx[k]);
        squared_distance(kind, &xt).sqrt() - thickness
    };
    if gap0.is_nan() || gap0 <= 0.0 {
        return 0.0;
    }
    if !lp.is_finite() {
        // A non-finite motion is never safe.
        return 0.0;
    }
    if lp <= 0.0 {
        // No relative motion: the distance does not change.
        return limit;
    }
    if lp <= gap0 * (1.0 - keep) {
        // Even approaching at the bound's rate the whole step closes less than allowed.
        return limit;
    }
    let target = keep * gap0;
    let mut t = 0.0;
    let mut step = (1.0 - keep) * gap0 / lp;
    for _ in 0..MAX_ITERATIONS {
        let next = t + step;
        if next >= 1.0 {
            // The last step reaches past the end with a positive gap all the way.
            return limit;
        }
        let gap = gap_at(next);
        // The first step is sized to stop at the target; a later one below it ends the
        // search at the last time known to be above it.
        if t > 0.0 && gap < target {
            return t;
        }
        if gap.is_nan() || gap <= 0.0 {
            // Only round-off in the distance can get here: stay at the last safe time.
            return t;
        }
        if next >= limit {
            // Safe up to `next`, past the limit: the whole sweep would return at least
            // `next`.
            return limit;
        }
        t = next;
        step = 0.9 * gap / lp;
    }
    t
}
