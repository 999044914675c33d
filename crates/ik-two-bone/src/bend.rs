//! The geometry of one solve, free of skeletons: the root-to-tip distance as a function of
//! the hinge angle, the soften curve, and the choice of the hinge angle inside its range.
//!
//! Derivations: `docs/ik-two-bone.md`, sections 2 to 4.

use sinew_math::DVec3;
use std::f64::consts::TAU;

/// How far (radians) a computed hinge angle may fall outside the hinge range and still
/// count as inside it (it is then clamped onto the bound). Without it, a bend that needs
/// exactly the range's bound could land a rounding error outside and be reported as not
/// reached.
const RANGE_SLACK: f64 = 1e-12;

/// The limb with its root fixed and its upper bone fixed relative to the mid joint's
/// parent frame, as a function of the hinge angle `theta`: the tip, relative to the root,
/// is `upper + R(axis, theta) lower_rest`, where `lower_rest` is the lower bone (mid to
/// tip) as it would lie with the mid joint at its rest rotation. All vectors are in one
/// frame (the solver uses world axes with the root's current rotation).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Limb {
    /// Root to mid joint.
    upper: DVec3,
    /// The part of `lower_rest` along the hinge axis, which the hinge does not move.
    lower_along: DVec3,
    /// The part of `lower_rest` perpendicular to the hinge axis, at `theta = 0`.
    lower_across: DVec3,
    /// `axis x lower_rest`: where `lower_across` goes after a quarter turn.
    lower_turned: DVec3,
    /// `|tip|^2 = squared_mean + a cos(theta) + b sin(theta)`.
    squared_mean: f64,
    a: f64,
    b: f64,
    /// `sqrt(a^2 + b^2)`, how much the squared distance varies with the angle.
    amplitude: f64,
}

/// The hinge angle a solve settled on, with its cosine and sine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Bend {
    /// The hinge angle, in `[min, max]`.
    pub angle: f64,
    /// `cos(angle)`.
    pub cos: f64,
    /// `sin(angle)`.
    pub sin: f64,
    /// Whether the root-to-tip distance at `angle` is the requested one (up to rounding),
    /// as opposed to the nearest the hinge range and the bone lengths allow.
    pub exact: bool,
}

impl Bend {
    fn at(angle: f64, exact: bool) -> Self {
        let (sin, cos) = angle.sin_cos();
        Self {
            angle,
            cos,
            sin,
            exact,
        }
    }
}

impl Limb {
    /// `upper`: root to mid; `lower_rest`: mid to tip with the mid joint at rest; `axis`:
    /// the hinge axis, a unit vector, in the same frame.
    #[inline]
    pub(crate) fn new(upper: DVec3, lower_rest: DVec3, axis: DVec3) -> Self {
        let lower_along = axis * axis.dot(lower_rest);
        let lower_across = lower_rest - lower_along;
        let lower_turned = axis.cross(lower_rest);
        let a = 2.0 * upper.dot(lower_across);
        let b = 2.0 * upper.dot(lower_turned);
        let fast = (a * a + b * b).sqrt();
        // `hypot` is slower but does not overflow for huge limbs.
        let amplitude = if fast.is_finite() { fast } else { a.hypot(b) };
        Self {
            upper,
            lower_along,
            lower_across,
            lower_turned,
            squared_mean: upper.length_squared()
                + lower_rest.length_squared()
                + 2.0 * upper.dot(lower_along),
            a,
            b,
            amplitude,
        }
    }

    /// The tip relative to the root at the hinge angle whose cosine and sine are given.
    #[inline]
    #[must_use]
    pub(crate) fn tip(&self, cos: f64, sin: f64) -> DVec3 {
        self.upper + self.lower_along + self.lower_across * cos + self.lower_turned * sin
    }

    /// The root-to-tip distance at hinge angle `angle`.
    #[inline]
    #[must_use]
    pub(crate) fn distance(&self, angle: f64) -> f64 {
        let (sin, cos) = angle.sin_cos();
        (self.squared_mean + self.a * cos + self.b * sin)
            .max(0.0)
            .sqrt()
    }

    /// The largest root-to-tip distance over all hinge angles (the reach; `l1 + l2` when
    /// the hinge axis is perpendicular to both bones).
    #[inline]
    #[must_use]
    pub(crate) fn max_distance(&self) -> f64 {
        (self.squared_mean + self.amplitude).max(0.0).sqrt()
    }

    /// The hinge angle in `[min, max]` whose root-to-tip distance is `goal`, or when there
    /// is none, the one whose distance is nearest to `goal`.
    ///
    /// With `|tip|^2 = m + R cos(theta - phi)` there are two exact angles
    /// `phi +- acos((goal^2 - m) / R)`; the `+` one (a positive turn about the hinge axis
    /// from the most extended angle `phi`) is preferred when both lie in the range, so the
    /// choice does not flip between calls. Without an exact angle in the range, the
    /// nearest distance is reached at a bound of the range, or at `phi` (most extended) or
    /// `phi + pi` (most folded) when those lie inside it.
    ///
    /// The cosine and sine of the answer come from those of `phi` and of the opening
    /// angle by the angle-sum formulas, not from the angle, so the distance at the answer
    /// is `goal` to rounding whatever the conditioning of the angle itself; one `atan2`
    /// gives the angle for the range test and the report.
    #[must_use]
    pub(crate) fn choose(&self, goal: f64, min: f64, max: f64) -> Bend {
        let amplitude = self.amplitude;
        if amplitude == 0.0 || !amplitude.is_finite() {
            // The hinge does not change the distance (a zero-length bone, or a bone along
            // the axis): the rest angle, clamped into the range, is as good as any.
            let angle = 0.0f64.clamp(min, max);
            let distance = self.distance(angle);
            let exact = (distance - goal).abs() <= 8.0 * f64::EPSILON * distance.max(goal);
            return Bend::at(angle, exact);
        }
        let inverse = 1.0 / amplitude;
        let (cos_phi, sin_phi) = (self.a * inverse, self.b * inverse);
        let squared_goal = goal * goal;
        let cosine = (squared_goal - self.squared_mean) * inverse;
        // The rounding of `cosine`: a goal at exactly the reach (or the fold) can come out
        // a few ulps beyond +-1, and is still reached exactly.
        let within = |cosine: f64| {
            cosine.abs() <= 1.0
                || cosine.is_finite()
                    && cosine.abs()
                        <= 1.0
                            + 8.0
                                * f64::EPSILON
                                * (squared_goal + self.squared_mean.abs())
                                * inverse
        };
        if within(cosine) {
            let c = cosine.clamp(-1.0, 1.0);
            // sin of the opening angle from `1 - c` and `1 + c` each computed from the
            // squared distances directly: `(m + R - goal^2) / R` and
            // `(goal^2 - (m - R)) / R`. Taken as `1 -+ c` after `c` was rounded, a goal at
            // the fold or the full extension (`c = -+1` exactly in exact arithmetic) leaves
            // an ulp in `1 +- c`, and the square root turns it into an angle error of
            // `sqrt(2 eps)`, 1.5e-8 rad: a limb of equal bones folded onto its root would
            // miss it by 4.5e-9 of a 0.3 bone. The differences of the squared distances
            // are exact where they cancel, so the sine keeps its digits there.
            let one_minus = ((self.squared_mean + amplitude - squared_goal) * inverse).max(0.0);
            let one_plus = ((squared_goal - (self.squared_mean - amplitude)) * inverse).max(0.0);
            let s = (one_minus * one_plus).sqrt();
            for s in [s, -s] {
                let cos = cos_phi * c - sin_phi * s;
                let sin = sin_phi * c + cos_phi * s;
                if let Some(bend) = place_in_range(cos, sin, min, max, true) {
                    return bend;
                }
            }
        } else {
            // Out of the distances the bones can make at all: most extended or most
            // folded, if the range allows it.
            let sign = if cosine > 1.0 { 1.0 } else { -1.0 };
            if let Some(bend) = place_in_range(sign * cos_phi, sign * sin_phi, min, max, false) {
                return bend;
            }
        }
        // No exact or extreme angle inside the range: the distance minus the goal keeps
        // one sign over the range, and it has no interior extremum on the goal's side, so
        // the nearest distance is at a bound.
        let miss = |angle: f64| (self.distance(angle) - goal).abs();
        let angle = if miss(max) < miss(min) { max } else { min };
        Bend::at(angle, false)
    }
}

/// The bend at the angle with cosine `cos` and sine `sin`, taken modulo a full turn into
/// `[min, max]`, if it lies there (allowing [`RANGE_SLACK`] outside and clamping it in).
#[inline]
fn place_in_range(cos: f64, sin: f64, min: f64, max: f64, exact: bool) -> Option<Bend> {
    let angle = sin.atan2(cos);
    // The representative at or above min - slack, less than a full turn above it.
    let start = min - RANGE_SLACK;
    let placed = angle + ((start - angle) * (1.0 / TAU)).ceil() * TAU;
    if placed > max + RANGE_SLACK {
        return None;
    }
    Some(if (min..=max).contains(&placed) {
        Bend {
            angle: placed,
            cos,
            sin,
            exact,
        }
    } else {
        Bend::at(placed.clamp(min, max), exact)
    })
}

/// `(cos(angle / 2), sin(angle / 2))` for the angle in `(-pi, pi]` with the given unit
/// cosine and sine, without trigonometric calls: the square root formula for the larger
/// of the two, the double-angle formula `sin = 2 sin(a/2) cos(a/2)` for the other, so
/// neither loses digits.
#[inline]
#[must_use]
pub(crate) fn half_angle(cos: f64, sin: f64) -> (f64, f64) {
    if cos >= 0.0 {
        let c = ((1.0 + cos) * 0.5).sqrt();
        (c, sin / (2.0 * c))
    } else {
        // sin(a/2) has the sign of a, which is the sign of sin(a) on (-pi, pi].
        let s = ((1.0 - cos) * 0.5).sqrt().copysign(sin);
        (sin / (2.0 * s), s)
    }
}

/// The root-to-tip distance the limb aims for when the target is `distance` away, given
/// the reach `reach` and the soften ratio `soften` in `[0, 1]`.
///
/// Below `start = soften * reach` the target distance itself. Beyond it,
/// `start + (reach - start) (1 - exp(-(distance - start) / (reach - start)))`: equal to
/// `distance` with slope 1 at `start` (so the tip moves continuously and without a kink
/// as the target crosses `start`), always below both `distance` and `reach`, and
/// approaching `reach` as the target goes to infinity. `soften = 1` turns it off.
#[inline]
#[must_use]
pub(crate) fn softened(distance: f64, reach: f64, soften: f64) -> f64 {
    let start = soften * reach;
    let span = reach - start;
    if distance <= start || span <= 0.0 {
        return distance;
    }
    start + span * -(-(distance - start) / span).exp_m1()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_2, PI};

    /// Unit bones along x, hinge about z: the textbook planar limb.
    fn planar() -> Limb {
        Limb::new(DVec3::X, DVec3::X, DVec3::Z)
    }

    #[test]
    fn planar_distance_is_the_law_of_cosines() {
        let limb = planar();
        assert!((limb.max_distance() - 2.0).abs() < 1e-15);
        for k in 0..=16 {
            let theta = PI * k as f64 / 16.0;
            // Interior angle pi - theta: d^2 = 1 + 1 - 2 cos(pi - theta).
            let expected = (2.0 + 2.0 * theta.cos()).sqrt();
            assert!((limb.distance(theta) - expected).abs() < 1e-15);
            let (sin, cos) = theta.sin_cos();
            assert!((limb.tip(cos, sin).length() - expected).abs() < 1e-15);
        }
    }

    #[test]
    fn right_angle_and_preference_for_the_positive_turn() {
        let limb = planar();
        let bend = limb.choose(2f64.sqrt(), -PI, PI);
        assert!(bend.exact);
        assert!((bend.angle - FRAC_PI_2).abs() < 1e-15, "{}", bend.angle);
        // Only the negative turn allowed.
        let bend = limb.choose(2f64.sqrt(), -PI, 0.0);
        assert!(bend.exact);
        assert!((bend.angle + FRAC_PI_2).abs() < 1e-15, "{}", bend.angle);
    }

    #[test]
    fn clamps_to_the_nearest_bound() {
        let limb = planar();
        let needed = 160f64.to_radians();
        let goal = limb.distance(needed);
        let max = 150f64.to_radians();
        let bend = limb.choose(goal, 0.0, max);
        assert!(!bend.exact);
        assert_eq!(bend.angle, max);
        // A range entirely on the straight side of the goal, below it in angle.
        let bend = limb.choose(limb.distance(0.5), 1.0, 2.0);
        assert_eq!(bend, Bend::at(1.0, false));
    }

    #[test]
    fn extremes_when_out_of_reach() {
        let limb = Limb::new(DVec3::X, DVec3::X * 0.5, DVec3::Z);
        let far = limb.choose(3.0, -PI, PI);
        assert!(!far.exact);
        assert!(far.angle.abs() < 1e-15);
        let near = limb.choose(0.1, -PI, PI);
        assert!(!near.exact);
        assert!((limb.distance(near.angle) - 0.5).abs() < 1e-15);
    }

    #[test]
    fn range_placement_wraps_and_clamps() {
        let place = |angle: f64, min: f64, max: f64| {
            let (sin, cos) = angle.sin_cos();
            place_in_range(cos, sin, min, max, true).map(|b| b.angle)
        };
        assert!((place(-FRAC_PI_2, 0.0, 5.0).unwrap() - 1.5 * PI).abs() < 1e-15);
        assert_eq!(place(-FRAC_PI_2, 0.0, 4.0), None);
        assert_eq!(place(1.0 + 1e-13, 0.0, 1.0), Some(1.0));
        assert_eq!(place(-1e-13, 0.0, 1.0), Some(0.0));
        assert_eq!(place(0.3, 0.3, 0.3), Some(0.3));
        assert!((place(0.5, 6.0, 7.0).unwrap() - (0.5 + TAU)).abs() < 1e-15);
        assert!((place(0.5, -7.0, -5.0).unwrap() - (0.5 - TAU)).abs() < 1e-15);
        // A clamped placement carries the cosine and sine of the bound.
        let (sin, cos) = (1.0 + 1e-13f64).sin_cos();
        let bend = place_in_range(cos, sin, 0.0, 1.0, true).unwrap();
        assert_eq!((bend.cos, bend.sin), (1f64.cos(), 1f64.sin()));
    }

    #[test]
    fn half_angles_match_the_trigonometric_ones() {
        for k in -64..=64 {
            let angle = PI * k as f64 / 64.0;
            let (sin, cos) = angle.sin_cos();
            let (c, s) = half_angle(cos, sin);
            // The same rotation: (c, s) or (-c, -s) for the angle's half.
            let (s2, c2) = (angle / 2.0).sin_cos();
            let gap = ((c - c2).abs() + (s - s2).abs()).min((c + c2).abs() + (s + s2).abs());
            assert!(gap < 4e-16, "{angle}: {gap:e}");
        }
        // Tiny angles keep their digits.
        let (c, s) = half_angle(1.0, 1e-20);
        assert_eq!((c, s), (1.0, 5e-21));
    }

    #[test]
    fn soften_is_continuous_with_slope_one_and_below_reach() {
        let reach = 2.0;
        let soften = 0.8;
        let start = 1.6;
        assert_eq!(softened(1.5, reach, soften), 1.5);
        assert_eq!(softened(start, reach, soften), start);
        let h = 1e-7;
        let slope = (softened(start + h, reach, soften) - start) / h;
        assert!((slope - 1.0).abs() < 1e-6, "{slope}");
        for d in [1.7, 2.0, 3.0, 100.0, 1e300] {
            let s = softened(d, reach, soften);
            // Strictly below the reach in exact arithmetic; exp underflows far out.
            assert!(s < d && s <= reach && s > start, "{d} -> {s}");
            assert!(d > 10.0 || s < reach, "{d} -> {s}");
        }
        assert_eq!(softened(5.0, reach, 1.0), 5.0);
        // soften = 0 starts at once: 2 (1 - e^-1) at distance 2.
        let expected = 2.0 * (1.0 - (-1.0f64).exp());
        assert!((softened(2.0, reach, 0.0) - expected).abs() < 1e-15);
    }

    #[test]
    fn tilted_axis_reaches_its_own_range_of_distances() {
        // Hinge axis not perpendicular to the lower bone: the distances reachable are
        // [sqrt(m - R), sqrt(m + R)], not [|l1 - l2|, l1 + l2].
        let axis = DVec3::new(0.0, 0.6, 0.8);
        let limb = Limb::new(DVec3::X, DVec3::new(0.5, 0.5, 0.0), axis);
        let far = limb.max_distance();
        assert!(far < 1.0 + 0.5f64.sqrt());
        for goal in [far * 0.9, far * 0.99, far] {
            let bend = limb.choose(goal, -PI, PI);
            assert!(bend.exact);
            assert!((limb.distance(bend.angle) - goal).abs() < 1e-14);
            assert!((limb.tip(bend.cos, bend.sin).length() - goal).abs() < 1e-14);
        }
    }
}
