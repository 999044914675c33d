//! The hybrid's refinement: damped least-squares (Levenberg-Marquardt) steps on the
//! chain's joint rotations, position-only, so each step solves one 3 x 3 system and costs
//! O(bones).
//!
//! The chain is held as bone vectors `b[c]` (world frame, exact lengths); the solver turns
//! them back into joint rotations once, at the end, like the FABRIK positions. A step
//! gives joint `c` a small world-frame rotation `w[c]` (every bone after it turns too); to first order the effector moves by
//! `sum_c w[c] x r[c]` with `r[c] = b[c] + ... + b[n-1]` (joint to effector). With
//! `A = sum_c (|r[c]|^2 I - r[c] r[c]^T)` (that is `J J^T`) the damped step is
//! `(A + lambda^2 I) y = target - effector`, `w[c] = r[c] x y` (`J^T y`). The derivation
//! is in `docs/ik-fabrik.md`.

use sinew_math::{DQuat, DVec3};
use sinew_skeleton::ik::StopReason;

/// The first damping, relative to `trace(A) / 3`: small, so the first step is nearly
/// Gauss-Newton, which converges quadratically when it is accepted.
const INITIAL_DAMPING: f64 = 1e-6;
/// Damping factor after an accepted step (divide) and a rejected one (multiply).
const DAMPING_DOWN: f64 = 10.0;
const DAMPING_UP: f64 = 10.0;
/// Consecutive rejected steps before the refinement declares a stall: by then the
/// damping has grown by 1e8 and the steps are shorter than anything that still helps.
const MAX_REJECTIONS: usize = 8;

/// Buffers of the refinement, owned by the solver so a solve does not allocate.
#[derive(Clone, Debug, Default)]
pub(crate) struct Refiner {
    /// Joint-to-effector vectors `r[c]`.
    to_effector: Vec<DVec3>,
    /// Bone vectors of the trial step.
    trial_bones: Vec<DVec3>,
}

/// What a refinement run did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Refined {
    /// Effector-to-target distance reached (from the bone vectors).
    pub error: f64,
    /// Why it stopped.
    pub stop: StopReason,
    /// Steps tried (accepted or not); each counts as one iteration.
    pub steps: usize,
}

impl Refiner {
    /// Runs damped least-squares steps on `bones` until the
    /// effector `base + sum bones` is within `tolerance` of `target`, `iterations` reaches
    /// `cap`, or steps stop helping. `error` is the current effector distance. Only steps
    /// that reduce the error are kept, so the error never increases.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn run(
        &mut self,
        bones: &mut Vec<DVec3>,
        base: DVec3,
        target: DVec3,
        mut error: f64,
        tolerance: f64,
        iterations: usize,
        cap: usize,
    ) -> Refined {
        let n = bones.len();
        self.to_effector.resize(n, DVec3::ZERO);
        self.trial_bones.resize(n, DVec3::ZERO);
        let mut steps = 0;
        let mut rejections = 0;
        let mut damping = f64::NAN;
        let mut normal = Normal::default();
        let mut fresh = false;
        loop {
            if error <= tolerance {
                return Refined {
                    error,
                    stop: StopReason::Converged,
                    steps,
                };
            }
            if iterations + steps >= cap {
                return Refined {
                    error,
                    stop: StopReason::IterationCap,
                    steps,
                };
            }
            if rejections >= MAX_REJECTIONS {
                return Refined {
                    error,
                    stop: StopReason::Stalled,
                    steps,
                };
            }
            if !fresh {
                normal = self.linearize(bones);
                if damping.is_nan() {
                    damping = INITIAL_DAMPING * normal.trace / 3.0;
                }
                fresh = true;
            }
            let residual = target - (base + normal.effector_offset);
            steps += 1;
            let Some(y) = normal.solve(damping, residual) else {
                damping = damping.max(f64::MIN_POSITIVE) * DAMPING_UP;
                rejections += 1;
                continue;
            };
            let trial_error = self.trial(bones, base, target, y);
            if trial_error < error {
                std::mem::swap(bones, &mut self.trial_bones);
                error = trial_error;
                damping /= DAMPING_DOWN;
                rejections = 0;
                fresh = false;
            } else {
                // A zero damping cannot grow by multiplication; restart it from the scale.
                damping = (damping * DAMPING_UP).max(INITIAL_DAMPING * normal.trace / 3.0);
                rejections += 1;
            }
        }
    }

    /// Joint-to-effector vectors (suffix sums of the bones) and the normal matrix
    /// `A = J J^T = sum_c (|r|^2 I - r r^T)`, accumulated as `trace * I - M`.
    fn linearize(&mut self, bones: &[DVec3]) -> Normal {
        let mut r = DVec3::ZERO;
        let mut normal = Normal::default();
        for (to_effector, &bone) in self.to_effector.iter_mut().zip(bones).rev() {
            r += bone;
            *to_effector = r;
            normal.xx += r.x * r.x;
            normal.yy += r.y * r.y;
            normal.zz += r.z * r.z;
            normal.xy += r.x * r.y;
            normal.xz += r.x * r.z;
            normal.yz += r.y * r.z;
        }
        normal.trace = normal.xx + normal.yy + normal.zz;
        normal.effector_offset = r;
        normal
    }

    /// Applies the step `w[c] = r[c] x y` into `trial_bones` and
    /// returns the trial effector's distance to the target.
    fn trial(&mut self, bones: &[DVec3], base: DVec3, target: DVec3, y: DVec3) -> f64 {
        let mut cumulative = DQuat::IDENTITY;
        let mut effector = base;
        for ((&r, &bone), trial_bone) in self
            .to_effector
            .iter()
            .zip(bones)
            .zip(self.trial_bones.iter_mut())
        {
            // The rotation by the small vector w, as the unit quaternion (w/2, 1)
            // normalized: it agrees with exp(w) to second order, needs no trigonometry,
            // and being a true rotation it keeps the bone length exact.
            // Normalizing the product once normalizes the step as well.
            let half = r.cross(y) * 0.5;
            let step = DQuat::from_xyzw(half.x, half.y, half.z, 1.0);
            cumulative = (cumulative * step).normalize();
            *trial_bone = cumulative * bone;
            effector += *trial_bone;
        }
        effector.distance(target)
    }
}

/// The symmetric 3 x 3 normal matrix `trace * I - M` with `M = sum r r^T`, plus the
/// effector's offset from the base.
#[derive(Clone, Copy, Debug, Default)]
struct Normal {
    xx: f64,
    yy: f64,
    zz: f64,
    xy: f64,
    xz: f64,
    yz: f64,
    trace: f64,
    effector_offset: DVec3,
}

impl Normal {
    /// Solves `(A + damping I) y = rhs` by the adjugate (A is symmetric positive
    /// semidefinite, so the damped matrix is positive definite for damping > 0). `None`
    /// when the determinant is not a positive finite number.
    fn solve(&self, damping: f64, rhs: DVec3) -> Option<DVec3> {
        let d = self.trace + damping;
        let (a, b, c) = (d - self.xx, d - self.yy, d - self.zz);
        let (ab, ac, bc) = (-self.xy, -self.xz, -self.yz);
        // Cofactors of the symmetric matrix [[a, ab, ac], [ab, b, bc], [ac, bc, c]].
        let c00 = b * c - bc * bc;
        let c01 = ac * bc - ab * c;
        let c02 = ab * bc - ac * b;
        let c11 = a * c - ac * ac;
        let c12 = ab * ac - a * bc;
        let c22 = a * b - ab * ab;
        let det = a * c00 + ab * c01 + ac * c02;
        if !(det.is_finite() && det > 0.0) {
            return None;
        }
        let y = DVec3::new(
            c00 * rhs.x + c01 * rhs.y + c02 * rhs.z,
            c01 * rhs.x + c11 * rhs.y + c12 * rhs.z,
            c02 * rhs.x + c12 * rhs.y + c22 * rhs.z,
        ) / det;
        y.is_finite().then_some(y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bent_chain() -> Vec<DVec3> {
        (0..6)
            .map(|i| {
                let t = 0.7 * i as f64;
                DVec3::new(t.cos(), t.sin(), 0.3 * (2.0 * t).sin()) * 0.2
            })
            .collect()
    }

    #[test]
    fn normal_matrix_times_y_is_the_first_order_effector_move() {
        // Finite-difference check of the Jacobian: a step of size h moves the effector by
        // A y h + O(h^2), so the mismatch divided by h shrinks linearly with h.
        let bones = bent_chain();
        let mut refiner = Refiner::default();
        refiner.to_effector.resize(bones.len(), DVec3::ZERO);
        refiner.trial_bones.resize(bones.len(), DVec3::ZERO);
        let normal = refiner.linearize(&bones);
        let y = DVec3::new(0.3, -1.1, 0.7);
        let predicted = {
            // A y with A = trace I - M.
            let m = DVec3::new(
                normal.xx * y.x + normal.xy * y.y + normal.xz * y.z,
                normal.xy * y.x + normal.yy * y.y + normal.yz * y.z,
                normal.xz * y.x + normal.yz * y.y + normal.zz * y.z,
            );
            normal.trace * y - m
        };
        let base = DVec3::new(0.5, -0.25, 1.0);
        let effector = base + normal.effector_offset;
        let mut previous = f64::INFINITY;
        for h in [1e-2, 1e-3, 1e-4] {
            // The trial returns a distance; read the moved effector off the trial bones.
            refiner.trial(&bones, base, DVec3::ZERO, y * h);
            let moved = base + refiner.trial_bones.iter().sum::<DVec3>();
            let mismatch = ((moved - effector) / h - predicted).length();
            assert!(mismatch < previous / 5.0, "h {h}: {mismatch} vs {previous}");
            previous = mismatch;
        }
        assert!(previous < 1e-3 * predicted.length());
    }

    #[test]
    fn the_damped_solve_inverts_the_matrix() {
        let bones = bent_chain();
        let mut refiner = Refiner::default();
        refiner.to_effector.resize(bones.len(), DVec3::ZERO);
        let normal = refiner.linearize(&bones);
        let rhs = DVec3::new(1.0, 2.0, -3.0);
        let damping = 0.01;
        let y = normal.solve(damping, rhs).unwrap();
        let m = DVec3::new(
            normal.xx * y.x + normal.xy * y.y + normal.xz * y.z,
            normal.xy * y.x + normal.yy * y.y + normal.yz * y.z,
            normal.xz * y.x + normal.yz * y.y + normal.zz * y.z,
        );
        let back = (normal.trace + damping) * y - m;
        assert!((back - rhs).length() < 1e-12 * rhs.length(), "{back}");
        // Zero matrix and zero damping: no solution, not NaN.
        assert_eq!(Normal::default().solve(0.0, rhs), None);
    }

    #[test]
    fn refinement_converges_and_keeps_bone_lengths() {
        let mut bones = bent_chain();
        let lengths: Vec<f64> = bones.iter().map(|b| b.length()).collect();
        let base = DVec3::ZERO;
        let target = DVec3::new(0.1, 0.35, -0.2);
        let error = (base + bones.iter().sum::<DVec3>()).distance(target);
        let mut refiner = Refiner::default();
        let out = refiner.run(&mut bones, base, target, error, 1e-12, 0, 100);
        assert_eq!(out.stop, StopReason::Converged, "{out:?}");
        assert!(out.steps < 20, "{out:?}");
        for (b, l) in bones.iter().zip(&lengths) {
            assert!((b.length() - l).abs() < 1e-14);
        }
        let reached = base + bones.iter().sum::<DVec3>();
        assert!((reached.distance(target) - out.error).abs() < 1e-15);
        assert!(out.error <= 1e-12);
    }
}
