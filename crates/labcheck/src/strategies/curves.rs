//! Flower curves with random petals, size and placement; random polylines; polylines
//! whose vertices are equally spaced (the fixed points of even resampling).
//!
//! Ranges: epicycloids with 1 to 20 petals, roses with `k` from 1 to 12 (so 1 to 24
//! petals), sizes log-uniform in `[1e-3, 1e2]`, placed in the XY, XZ or YZ plane or a
//! random tilted one, centred anywhere in `[-10, 10]^3`; arc-length tolerances relative to
//! the curve's length, log-uniform in `[1e-12, 1e-3]`; polylines of 2 to 64 points in
//! `[-10, 10]^3`, one point in eight repeating its predecessor (a zero-length segment).

use super::{direction, log_uniform, point};
use proptest::prelude::*;
use sinew_curves::{Ends, Epicycloid, Plane, PlaneAxes, Polyline, Rose};
use sinew_math::DVec3;
use std::f64::consts::TAU;
use std::ops::RangeInclusive;

/// A placement: a coordinate plane or a random tilted one, centred in `[-10, 10]^3`.
pub fn plane() -> impl Strategy<Value = Plane> + Clone {
    let axes = prop_oneof![
        Just(PlaneAxes::XY),
        Just(PlaneAxes::XZ),
        Just(PlaneAxes::YZ),
        (direction(), direction()).prop_map(|(u, w)| {
            // Gram-Schmidt, falling back to any perpendicular when w is along u.
            let v = sinew_math::try_unit(w - u * u.dot(w))
                .unwrap_or_else(|| u.any_orthonormal_vector());
            PlaneAxes::Axes { u, v }
        }),
    ];
    (prop_oneof![Just(DVec3::ZERO), point(10.0)], axes)
        .prop_map(|(center, axes)| Plane::new(center, axes).expect("orthonormal axes"))
}

/// An epicycloid: 1 to 20 petals, rolling radius log-uniform in `[1e-3, 1e2]`.
pub fn epicycloid() -> impl Strategy<Value = Epicycloid> + Clone {
    (1u32..=20, log_uniform(-3.0, 2.0), plane())
        .prop_map(|(petals, r, plane)| Epicycloid::with_petals(petals, r, plane).expect("valid"))
}

/// A rose `r = a cos(k theta)`: `k` from 1 to 12, `a` log-uniform in `[1e-3, 1e2]`.
pub fn rose() -> impl Strategy<Value = Rose> + Clone {
    (1u32..=12, log_uniform(-3.0, 2.0), plane())
        .prop_map(|(k, a, plane)| Rose::from_frequency(k, a, plane).expect("valid"))
}

/// An arc-length tolerance relative to the curve's length: log-uniform in
/// `[1e-12, 1e-3]`.
pub fn relative_tolerance() -> impl Strategy<Value = f64> + Clone {
    log_uniform(-12.0, -3.0)
}

/// The points of a random polyline: `points` points in `[-10, 10]^3`, one in eight a
/// repeat of the previous point.
pub fn polyline_points(points: RangeInclusive<usize>) -> impl Strategy<Value = Vec<DVec3>> {
    prop::collection::vec((point(10.0), prop::bool::weighted(0.125)), points).prop_map(|raw| {
        let mut out: Vec<DVec3> = Vec::with_capacity(raw.len());
        for (p, repeat) in raw {
            match out.last() {
                Some(&last) if repeat => out.push(last),
                _ => out.push(p),
            }
        }
        out
    })
}

/// A random polyline of 2 to 64 points, open or closed.
pub fn polyline() -> impl Strategy<Value = Polyline> {
    (polyline_points(2..=64), any::<bool>()).prop_map(|(points, closed)| {
        Polyline::new(points, if closed { Ends::Closed } else { Ends::Open })
            .expect("finite points")
    })
}

/// An open polyline whose segments all have the same length `step` (log-uniform in
/// `[1e-3, 10]`), in random directions: 2 to 64 points from a random start.
pub fn equal_step_polyline() -> impl Strategy<Value = Vec<DVec3>> {
    (
        point(10.0),
        log_uniform(-3.0, 1.0),
        prop::collection::vec(direction(), 1..=63),
    )
        .prop_map(|(start, step, dirs)| {
            let mut points = vec![start];
            for d in dirs {
                let last = *points.last().expect("non-empty");
                points.push(last + d * step);
            }
            points
        })
}

/// The vertices of a regular polygon (3 to 64 vertices, circumradius log-uniform in
/// `[1e-3, 1e2]`, random phase and placement): a closed polyline with equal sides.
pub fn regular_polygon() -> impl Strategy<Value = Vec<DVec3>> {
    (3usize..=64, log_uniform(-3.0, 2.0), 0.0f64..TAU, plane()).prop_map(
        |(n, radius, phase, plane)| {
            (0..n)
                .map(|i| {
                    let angle = phase + TAU * i as f64 / n as f64;
                    plane.point(sinew_math::DVec2::new(
                        radius * angle.cos(),
                        radius * angle.sin(),
                    ))
                })
                .collect()
        },
    )
}
