//! Placing planar curves in 3D: a center and two orthonormal axes.
//!
//! The flower family is defined in a plane with coordinates `(u, v)`; a [`Plane`] maps
//! `(u, v)` to `center + u * u_axis + v * v_axis`. The axes are orthonormal, so lengths
//! and speeds are the same in 3D as in the plane. The lab draws its flower in the plane
//! `y = 0` with `u -> x`, `v -> z`: [`Plane::lab`].

use crate::error::{CurveError, finite};
use sinew_math::{DVec2, DVec3};

/// The orientation of a plane by its two axes, as named in scene files.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum PlaneAxes {
    /// `u -> x`, `v -> y` (the plane `z = const`).
    XY,
    /// `u -> x`, `v -> z` (the plane `y = const`): the lab's flower plane.
    #[default]
    XZ,
    /// `u -> y`, `v -> z` (the plane `x = const`).
    YZ,
    /// Any two axes; they are made exactly orthonormal by [`Plane::new`] (they must be
    /// unit length and perpendicular to within 1e-6 already).
    Axes {
        /// Direction of the `u` coordinate.
        u: DVec3,
        /// Direction of the `v` coordinate.
        v: DVec3,
    },
}

impl PlaneAxes {
    /// The two axes `(u, v)` (not yet checked for custom axes).
    #[must_use]
    pub fn axes(self) -> (DVec3, DVec3) {
        match self {
            Self::XY => (DVec3::X, DVec3::Y),
            Self::XZ => (DVec3::X, DVec3::Z),
            Self::YZ => (DVec3::Y, DVec3::Z),
            Self::Axes { u, v } => (u, v),
        }
    }
}

/// A plane in 3D: a center and two orthonormal axes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    center: DVec3,
    u_axis: DVec3,
    v_axis: DVec3,
}

impl Plane {
    /// How far from unit length and from perpendicular the given axes may be.
    pub const AXIS_TOLERANCE: f64 = 1e-6;

    /// The lab's plane: center at the origin, `u -> x`, `v -> z`, so `y = 0`.
    #[must_use]
    pub fn lab() -> Self {
        Self {
            center: DVec3::ZERO,
            u_axis: DVec3::X,
            v_axis: DVec3::Z,
        }
    }

    /// A plane through `center` with axes `axes`.
    ///
    /// The axes must be finite, of unit length and perpendicular to within
    /// [`Plane::AXIS_TOLERANCE`]; they are then made orthonormal to rounding
    /// (Gram-Schmidt), so the placement preserves lengths exactly. Errors name
    /// `center`, `plane.u` or `plane.v`.
    pub fn new(center: DVec3, axes: PlaneAxes) -> Result<Self, CurveError> {
        for (name, c) in [
            ("center.x", center.x),
            ("center.y", center.y),
            ("center.z", center.z),
        ] {
            finite(name, c)?;
        }
        let (u, v) = axes.axes();
        if !u.is_finite() {
            return Err(CurveError::invalid(
                "plane.u",
                format!("must be finite, got {u}"),
            ));
        }
        if !v.is_finite() {
            return Err(CurveError::invalid(
                "plane.v",
                format!("must be finite, got {v}"),
            ));
        }
        if (u.length() - 1.0).abs() > Self::AXIS_TOLERANCE {
            return Err(CurveError::invalid(
                "plane.u",
                format!("must be a unit vector, got length {}", u.length()),
            ));
        }
        if (v.length() - 1.0).abs() > Self::AXIS_TOLERANCE {
            return Err(CurveError::invalid(
                "plane.v",
                format!("must be a unit vector, got length {}", v.length()),
            ));
        }
        if u.dot(v).abs() > Self::AXIS_TOLERANCE {
            return Err(CurveError::invalid(
                "plane.v",
                format!("must be perpendicular to plane.u, got u . v = {}", u.dot(v)),
            ));
        }
        let u_axis = u.normalize();
        let v_axis = (v - v.dot(u_axis) * u_axis).normalize();
        Ok(Self {
            center,
            u_axis,
            v_axis,
        })
    }

    /// The center (the image of `(u, v) = (0, 0)`).
    #[must_use]
    pub fn center(&self) -> DVec3 {
        self.center
    }

    /// The unit axes `(u_axis, v_axis)`.
    #[must_use]
    pub fn axes(&self) -> (DVec3, DVec3) {
        (self.u_axis, self.v_axis)
    }

    /// The 3D point of plane coordinates `p = (u, v)`.
    #[must_use]
    pub fn point(&self, p: DVec2) -> DVec3 {
        self.center + p.x * self.u_axis + p.y * self.v_axis
    }

    /// The 3D vector of a plane vector `d` (no translation): for derivatives.
    #[must_use]
    pub fn vector(&self, d: DVec2) -> DVec3 {
        d.x * self.u_axis + d.y * self.v_axis
    }
}

impl Default for Plane {
    fn default() -> Self {
        Self::lab()
    }
}
