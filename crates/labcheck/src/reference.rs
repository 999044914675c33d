//! Independent reference computations: what the properties compare the crates under test
//! against. Each is written from the formulas in `docs/labcheck.md`, not by calling the
//! code under test (the only things taken from the crates are their data: a skeleton's
//! parents and offsets, a system's particles and springs).

pub mod kinematics {
    //! Bone lengths and chain depths.

    use crate::bounds::bone_length_allowance;
    use sinew_math::DVec3;
    use sinew_skeleton::Skeleton;
    use sinew_skeleton::ik::Chain;

    /// A bone whose length is off by more than its allowance.
    #[derive(Clone, Copy, Debug, PartialEq)]
    pub struct BoneViolation {
        /// The bone's child joint.
        pub joint: usize,
        /// Its length in the positions checked.
        pub length: f64,
        /// Its rest length.
        pub rest: f64,
        /// The allowance it exceeded ([`bone_length_allowance`]).
        pub allowance: f64,
    }

    /// The first bone of `skeleton` whose length in `positions` (one per joint) differs
    /// from its rest length by more than [`bone_length_allowance`], if any.
    #[must_use]
    pub fn skeleton_bone_violation(
        skeleton: &Skeleton,
        positions: &[DVec3],
    ) -> Option<BoneViolation> {
        (0..skeleton.len()).find_map(|j| {
            let p = skeleton.parent(j)?;
            check_bone(j, positions[p], positions[j], skeleton.offset(j).length())
        })
    }

    /// The first bone of `chain` whose length in `positions` (one per chain joint, base
    /// first) is off by more than its allowance, if any.
    #[must_use]
    pub fn chain_bone_violation(chain: &Chain, positions: &[DVec3]) -> Option<BoneViolation> {
        chain
            .bone_lengths()
            .iter()
            .enumerate()
            .find_map(|(c, &rest)| check_bone(c + 1, positions[c], positions[c + 1], rest))
    }

    fn check_bone(joint: usize, a: DVec3, b: DVec3, rest: f64) -> Option<BoneViolation> {
        let length = (b - a).length();
        let allowance = bone_length_allowance(rest, a, b);
        ((length - rest).abs() > allowance).then_some(BoneViolation {
            joint,
            length,
            rest,
            allowance,
        })
    }

    /// The number of ancestors of joint `j` (0 for a root).
    #[must_use]
    pub fn depth(skeleton: &Skeleton, j: usize) -> usize {
        let mut depth = 0;
        let mut k = j;
        while let Some(p) = skeleton.parent(k) {
            depth += 1;
            k = p;
        }
        depth
    }

    /// The largest coordinate magnitude among `points`: the scale rounding acts on.
    #[must_use]
    pub fn scale(points: impl IntoIterator<Item = DVec3>) -> f64 {
        points.into_iter().map(DVec3::length).fold(0.0, f64::max)
    }
}

pub mod curves {
    //! Arc lengths from closed forms and an independent spectral quadrature.

    use sinew_math::DVec3;
    use std::f64::consts::{PI, TAU};

    /// The arc length of the epicycloid with `petals` cusps and rolling radius `r` from
    /// `t = 0` to `t` (clamped to `[0, 2 pi]`), in closed form: arch `j` (between the cusps
    /// `2 pi j / k` and `2 pi (j + 1) / k`) has length `A = 8 r (k + 1) / k`, and a
    /// parameter `tau` into it adds `A sin^2(k tau / 4)` (docs/labcheck.md).
    #[must_use]
    pub fn epicycloid_arc_length(petals: u32, r: f64, t: f64) -> f64 {
        let k = f64::from(petals);
        let t = t.clamp(0.0, TAU);
        let arch = 8.0 * r * (k + 1.0) / k;
        let j = (t * k / TAU).floor().clamp(0.0, k - 1.0);
        let tau = t - TAU * j / k;
        let s = (k * tau / 4.0).sin();
        j * arch + arch * s * s
    }

    /// Samples per period of the rose's speed in [`RoseArcLength`]: enough that the
    /// neglected Fourier coefficients are below 1e-30 of the mean for `k <= 12`.
    pub const ROSE_SAMPLES: usize = 1024;

    /// The arc length of the rose `r = a cos(k theta)` by an independent spectral method:
    /// with `u = k theta`, the speed is `(a/k) g(u)` per unit `u`, where
    /// `g(u) = sqrt(1 + (k^2 - 1) sin^2 u)` is even and `pi`-periodic, so
    /// `g(u) = c_0 + sum_n c_n cos(2 n u)` and
    /// `s(theta) = (a/k) (c_0 u + sum_n c_n sin(2 n u) / (2 n))`. The coefficients come from
    /// [`ROSE_SAMPLES`] equally spaced samples over one period (the trapezoid rule, exact
    /// for a trigonometric polynomial of lower degree); they decay like
    /// `exp(-2 n asinh(1 / sqrt(k^2 - 1)))`, below 1e-30 of `c_0` by the last one kept.
    #[derive(Clone, Debug)]
    pub struct RoseArcLength {
        k: f64,
        a: f64,
        coefficients: Vec<f64>,
    }

    impl RoseArcLength {
        /// The reference for frequency `k >= 1` and size `a`.
        #[must_use]
        pub fn new(k: u32, a: f64) -> Self {
            let n = ROSE_SAMPLES;
            let m = f64::from(k) * f64::from(k) - 1.0;
            // cos(2 pi i / n) tabulated, so cos(2 n u_j) = cos(2 pi (n j mod N) / N) is a
            // lookup.
            let cosines: Vec<f64> = (0..n).map(|i| (TAU * i as f64 / n as f64).cos()).collect();
            let samples: Vec<f64> = (0..n)
                .map(|j| {
                    let s = (PI * j as f64 / n as f64).sin();
                    (1.0 + m * s * s).sqrt()
                })
                .collect();
            let mut coefficients = Vec::with_capacity(n / 2);
            coefficients.push(samples.iter().sum::<f64>() / n as f64);
            for harmonic in 1..n / 2 {
                let sum: f64 = samples
                    .iter()
                    .enumerate()
                    .map(|(j, g)| g * cosines[(harmonic * j) % n])
                    .sum();
                coefficients.push(2.0 * sum / n as f64);
            }
            Self {
                k: f64::from(k),
                a,
                coefficients,
            }
        }

        /// The arc length from `theta = 0` to `theta`.
        #[must_use]
        pub fn at(&self, theta: f64) -> f64 {
            let u = self.k * theta;
            let mut g = self.coefficients[0] * u;
            for (n, c) in self.coefficients.iter().enumerate().skip(1) {
                let twice = 2.0 * n as f64;
                g += c * (twice * u).sin() / twice;
            }
            self.a / self.k * g
        }
    }

    /// The arc length of the polyline through `points` (closed: with the segment back to
    /// the first point) at parameter `t` (segment `i` on `[i, i + 1]`), summed directly.
    #[must_use]
    pub fn polyline_arc_length(points: &[DVec3], closed: bool, t: f64) -> f64 {
        let segments = if closed {
            points.len()
        } else {
            points.len() - 1
        };
        let t = t.clamp(0.0, segments as f64);
        let i = (t.floor() as usize).min(segments - 1);
        let mut s = 0.0;
        for c in 0..i {
            s += points[c].distance(points[(c + 1) % points.len()]);
        }
        s + (t - i as f64) * points[i].distance(points[(i + 1) % points.len()])
    }
}

pub mod springs {
    //! Energies and the backward Euler incremental potential of a mass-spring system,
    //! each with the magnitude its round-off acts on.

    use sinew_math::{DVec3, try_unit};
    use sinew_spring_sim::SpringSystem;

    /// A computed sum with what bounds its round-off: `scale` (the sum of the magnitudes
    /// the rounding acts on, see docs/labcheck.md) and the number of terms summed.
    #[derive(Clone, Copy, Debug, Default, PartialEq)]
    pub struct Measured {
        /// The value.
        pub value: f64,
        /// The magnitude its rounding acts on.
        pub scale: f64,
        /// Terms summed.
        pub terms: usize,
    }

    impl Measured {
        fn add(&mut self, value: f64, scale: f64) {
            self.value += value;
            self.scale += scale;
            self.terms += 1;
        }

        /// The round-off allowance of this sum ([`crate::bounds::sum_allowance`]).
        #[must_use]
        pub fn allowance(&self) -> f64 {
            crate::bounds::sum_allowance(self.terms, self.scale)
        }
    }

    /// `k/2 (l - L)^2` with its rounding scale `k/2 (l - L)^2 + k |l - L| (|x_a| + |x_b| +
    /// l + L)`: `l` is computed from absolute positions, so it carries an error of order
    /// `EPS (|x_a| + |x_b|)`, which the square multiplies by `k |l - L|`.
    fn spring_term(x_a: DVec3, x_b: DVec3, rest: f64, k: f64) -> (f64, f64) {
        let l = (x_a - x_b).length();
        let e = 0.5 * k * (l - rest) * (l - rest);
        let scale = e + k * (l - rest).abs() * (x_a.length() + x_b.length() + l + rest);
        (e, scale)
    }

    /// The spring energy `sum_s k_s/2 (|x_a - x_b| - L_s)^2` of positions `x`.
    #[must_use]
    pub fn spring_energy(system: &SpringSystem, x: &[DVec3]) -> Measured {
        let mut sum = Measured::default();
        for s in system.springs() {
            let (e, scale) = spring_term(x[s.a], x[s.b], s.rest_length, s.stiffness);
            sum.add(e, scale);
        }
        sum
    }

    /// The gravity energy `-sum_p m_p g . x_p`, over every particle (fixed ones add a
    /// constant) or over the free ones only.
    #[must_use]
    pub fn gravity_energy(system: &SpringSystem, x: &[DVec3], free_only: bool) -> Measured {
        let g = system.material().gravity;
        let mut sum = Measured::default();
        for (p, (&m, &fixed)) in system.masses().iter().zip(system.fixed()).enumerate() {
            if !(free_only && fixed) {
                sum.add(-m * g.dot(x[p]), m * g.length() * x[p].length());
            }
        }
        sum
    }

    /// The kinetic energy `sum_p m_p |v_p|^2 / 2`.
    #[must_use]
    pub fn kinetic_energy(system: &SpringSystem) -> Measured {
        let mut sum = Measured::default();
        for (&m, v) in system.masses().iter().zip(system.velocities()) {
            let e = 0.5 * m * v.length_squared();
            sum.add(e, e);
        }
        sum
    }

    /// `E_total = kinetic + spring + gravity` of the system's current state.
    #[must_use]
    pub fn total_energy(system: &SpringSystem) -> Measured {
        let x = system.positions();
        let parts = [
            kinetic_energy(system),
            spring_energy(system, x),
            gravity_energy(system, x, false),
        ];
        combine(&parts)
    }

    /// The sum of measured sums.
    #[must_use]
    pub fn combine(parts: &[Measured]) -> Measured {
        parts.iter().fold(Measured::default(), |a, b| Measured {
            value: a.value + b.value,
            scale: a.scale + b.scale,
            terms: a.terms + b.terms,
        })
    }

    /// `1/2 |v_after - v_before|_M^2`, with the rounding of the velocities themselves
    /// counted: `v_after = (x_after - x_before)/h` is rounded relative to the positions, so
    /// each term's scale includes `m |dv| ((|x_before| + |x_after|)/h + |v_before| +
    /// |v_after|)`.
    #[must_use]
    pub fn velocity_change_energy(before: &SpringSystem, after: &SpringSystem, h: f64) -> Measured {
        let mut sum = Measured::default();
        for p in 0..before.len() {
            let m = before.masses()[p];
            let (v0, v1) = (before.velocities()[p], after.velocities()[p]);
            let (x0, x1) = (before.positions()[p], after.positions()[p]);
            let dv = v1 - v0;
            let e = 0.5 * m * dv.length_squared();
            let scale =
                e + m * dv.length() * ((x0.length() + x1.length()) / h + v0.length() + v1.length());
            sum.add(e, scale);
        }
        sum
    }

    /// The backward Euler incremental potential of the step of length `h` from the state
    /// of `start`, evaluated at positions `x`:
    /// `g(x) = sum_free m/(2 h^2) |x - y|^2 + E_spring(x) + E_gravity,free(x) + D(x)`,
    /// `y = x_n + h v_n`, `D(x) = c/(2h) sum_s (u_s . (d_s(x) - d_s(x_n)))^2` with `u_s`
    /// the unit direction of spring `s` at `x_n` (zero for a zero-length spring). Gravity
    /// is counted over free particles only, as in spring-sim's recorded trace (fixed
    /// particles do not move, so this changes `g` by a constant).
    #[must_use]
    pub fn incremental_potential(start: &SpringSystem, x: &[DVec3], h: f64) -> Measured {
        let xn = start.positions();
        let vn = start.velocities();
        let mut sum = Measured::default();
        for (p, (&m, &fixed)) in start.masses().iter().zip(start.fixed()).enumerate() {
            if fixed {
                continue;
            }
            let y = xn[p] + h * vn[p];
            let d = x[p] - y;
            let e = 0.5 * m / (h * h) * d.length_squared();
            sum.add(
                e,
                e + m / (h * h) * d.length() * (x[p].length() + y.length()),
            );
        }
        let spring = spring_energy(start, x);
        let gravity = gravity_energy(start, x, true);
        let c = start.material().damping;
        let mut damping = Measured::default();
        if c > 0.0 {
            for s in start.springs() {
                let dn = xn[s.a] - xn[s.b];
                let u = try_unit(dn).unwrap_or(DVec3::ZERO);
                let e = u.dot((x[s.a] - x[s.b]) - dn);
                let value = 0.5 * c / h * e * e;
                let magnitudes =
                    x[s.a].length() + x[s.b].length() + xn[s.a].length() + xn[s.b].length();
                damping.add(value, value + c / h * e.abs() * magnitudes);
            }
        }
        combine(&[sum, spring, gravity, damping])
    }

    /// Whether every spring is at or beyond its rest length in `x` (the convex regime of
    /// docs/labcheck.md).
    #[must_use]
    pub fn all_stretched(system: &SpringSystem, x: &[DVec3]) -> bool {
        system
            .springs()
            .iter()
            .all(|s| (x[s.a] - x[s.b]).length() >= s.rest_length)
    }

    /// `sum_free m/m_min |x_after - x_before|_1` (`m_min` the smallest free mass): with
    /// the final residual, the largest gradient entry with each particle's scaled by
    /// `m_min/m` (spring-sim's `StepReport::residual`), it bounds the first-order term
    /// `grad g . (x_after - x_before)` of docs/labcheck.md, since each particle's gradient
    /// entries are at most the residual times `m/m_min`. With equal masses it is the plain
    /// `l1` norm of the displacement.
    #[must_use]
    pub fn mass_weighted_displacement_l1(before: &SpringSystem, after: &SpringSystem) -> f64 {
        let free = || {
            before
                .positions()
                .iter()
                .zip(after.positions())
                .zip(before.masses())
                .zip(before.fixed())
                .filter(|(_, fixed)| !**fixed)
                .map(|(pm, _)| pm)
        };
        let m_min = free().map(|(_, m)| *m).fold(f64::INFINITY, f64::min);
        free()
            .map(|((a, b), m)| {
                let d = *b - *a;
                m / m_min * (d.x.abs() + d.y.abs() + d.z.abs())
            })
            .sum()
    }
}
