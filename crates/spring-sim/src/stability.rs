//! The stability bound of the explicit integrators: the largest frequency of the system,
//! and from it the number of substeps at which symplectic Euler and velocity Verlet are
//! stable at a given step.
//!
//! For the linearization `M x'' = -K x - C x'` (free particles only, `K` the assembled
//! PSD-projected spring blocks, `C` the axial damping blocks), both integrators are stable
//! on a mode of frequency `omega` and damping rate `gamma` when
//! `dt^2 omega^2 + 2 dt gamma <= 4`, i.e. `dt omega_eff <= 2` with
//! `omega_eff = (gamma + sqrt(gamma^2 + 4 omega^2)) / 2` (`= omega` without damping).
//! `omega_max^2 = lambda_max(M^-1 K)` is bounded above by Gershgorin's row sums (cheap,
//! rigorous, often loose) and estimated by Lanczos on `M^-1/2 K M^-1/2` (accurate, from
//! below). The substep count is `min(ceil(h omega_eff / (2 SAFETY)), ceil(h omega_G / 2))`
//! with the Lanczos `omega_eff` and the Gershgorin `omega_G`: the safety factor covers the
//! estimate's error and the drift of the state between two estimates, and the Gershgorin
//! count, which needs no safety factor, caps it. Derivation: docs/integrators.md.
//!
//! `K` and `C` are not written here: they are the Hessians of the potential's
//! [`Springs`] term (PSD-projected) and [`AxialDamping`] term (evaluated with `h = 1`, so
//! its `c/h u u^T` is `C`), computed from those terms' per-spring kernels in one loop over
//! the springs for Gershgorin's row sums and for Lanczos's products.
//!
//! [`Springs`]: crate::potential::Springs
//! [`AxialDamping`]: crate::potential::AxialDamping

use crate::model::SpringSystem;
use crate::potential::{rate_product, rate_row_sums};
use sinew_math::DVec3;

/// The fraction of the stability limit the chosen substep count stays under:
/// `dt omega_eff <= 2 SAFETY`.
pub const SAFETY: f64 = 0.9;

/// Lanczos iterations for the estimate (fewer when the system has fewer unknowns).
pub const LANCZOS_ITERATIONS: usize = 60;

/// The stability data of a system at one state.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct StabilityBound {
    /// Gershgorin upper bound on `lambda_max(M^-1 K)` (rigorous).
    pub gershgorin: f64,
    /// Lanczos estimate of `lambda_max(M^-1 K)` (converges from below; `<= gershgorin`).
    pub estimate: f64,
    /// Gershgorin upper bound on `lambda_max(M^-1 C)`, the fastest damping rate.
    pub damping_rate: f64,
}

/// `(gamma + sqrt(gamma^2 + 4 omega^2)) / 2` for `omega^2 = lambda`: the frequency whose
/// limit `dt omega_eff <= 2` is the damped condition `dt^2 omega^2 + 2 dt gamma <= 4`.
#[must_use]
fn effective_omega(lambda: f64, gamma: f64) -> f64 {
    0.5 * (gamma + (gamma * gamma + 4.0 * lambda.max(0.0)).sqrt())
}

impl StabilityBound {
    /// Computes the bound of `system` at its current state.
    #[must_use]
    pub fn of(system: &SpringSystem) -> Self {
        let (gershgorin, damping_rate) = gershgorin(system);
        let estimate = if gershgorin > 0.0 {
            lanczos_max(system, LANCZOS_ITERATIONS).min(gershgorin)
        } else {
            0.0
        };
        Self {
            gershgorin,
            estimate,
            damping_rate,
        }
    }

    /// The estimated largest effective frequency `omega_eff` (damping included), rad/s.
    #[must_use]
    pub fn omega_max(&self) -> f64 {
        effective_omega(self.estimate, self.damping_rate)
    }

    /// The rigorous (Gershgorin) upper bound on `omega_eff`.
    #[must_use]
    pub fn omega_upper(&self) -> f64 {
        effective_omega(self.gershgorin, self.damping_rate)
    }

    /// The predicted stability limit at step `h`: the smallest substep count with
    /// `h / n omega_eff <= 2`, from the estimate, without safety factor.
    #[must_use]
    pub fn critical_substeps(&self, h: f64) -> usize {
        substeps_for(h * self.omega_max() / 2.0)
    }

    /// The substep count used at step `h`: `ceil(h omega_eff / (2 SAFETY))`, capped by the
    /// Gershgorin count `ceil(h omega_G / 2)` (stable without safety factor).
    #[must_use]
    pub fn substeps(&self, h: f64) -> usize {
        let safe = substeps_for(h * self.omega_max() / (2.0 * SAFETY));
        let rigorous = substeps_for(h * self.omega_upper() / 2.0);
        safe.min(rigorous)
    }
}

/// `max(1, ceil(ratio))`, saturating for huge or non-finite ratios.
fn substeps_for(ratio: f64) -> usize {
    if !ratio.is_finite() || ratio >= usize::MAX as f64 {
        return usize::MAX;
    }
    (ratio.ceil() as usize).max(1)
}

/// Gershgorin bounds `(lambda_max(M^-1 K), lambda_max(M^-1 C))` over the free unknowns:
/// the largest absolute row sum of each matrix. `O(springs)`.
#[must_use]
pub fn gershgorin(system: &SpringSystem) -> (f64, f64) {
    gershgorin_with(system, &mut RowSums::default())
}

/// The buffers of [`gershgorin`]: the row sums of `K` and `C`.
#[derive(Clone, Debug, Default)]
struct RowSums {
    stiffness: Vec<DVec3>,
    damping: Vec<DVec3>,
}

/// [`gershgorin`] with reusable buffers.
fn gershgorin_with(system: &SpringSystem, sums: &mut RowSums) -> (f64, f64) {
    let n = system.len();
    let fixed = system.fixed();
    // K: the springs' PSD-projected Hessian; C: the damping's, along the current
    // directions. Both from the terms' kernels, in one loop over the springs.
    rate_row_sums(system, &mut sums.stiffness, &mut sums.damping);
    let masses = system.masses();
    let mut lk = 0.0f64;
    let mut lc = 0.0f64;
    for i in 0..n {
        if !fixed[i] {
            lk = lk.max(sums.stiffness[i].max_element() / masses[i]);
            lc = lc.max(sums.damping[i].max_element() / masses[i]);
        }
    }
    (lk, lc)
}

/// Bounds on `lambda_max(M^-1 K)` and on `lambda_max(M^-1 C)` per unit damping
/// coefficient that hold at **every** state of the system, from its topology, masses and
/// stiffnesses alone: `(max_i S_K(i) / m_i, max_i S_C(i) / m_i)` over the free particles,
/// with `S_K(i) = sum_{s at i} k_s (1 + [other end free])` and `S_C(i)` the same sum with
/// `k_s = 1`. `O(springs)`, no square root.
///
/// Why it holds: the PSD-projected block of a spring, `alpha I + beta u u^T` with
/// `alpha = k max(0, 1 - L/l)` and `alpha + beta = k`, has eigenvalues `k` and `alpha` in
/// `[0, k]`, so its spectral norm is at most `k` whatever the spring's length and
/// direction (a zero-rest-length spring's block is `k I`); the damping block `c w w^T` has
/// norm at most `c`. Block Gershgorin on `M^-1 K`: for an eigenvector `v` and the particle
/// `i` where `|v_i|` is largest, `|lambda| |v_i| <= (|K_ii| + sum_j |K_ij|) |v_i| / m_i`,
/// and `|K_ii| <= sum_s k_s`, `|K_ij| <= k_s` (docs/integrators.md).
#[must_use]
pub fn uniform_bound(system: &SpringSystem) -> (f64, f64) {
    let fixed = system.fixed();
    let mut stiffness = vec![0.0f64; system.len()];
    let mut count = vec![0.0f64; system.len()];
    for s in system.springs() {
        let (fa, fb) = (fixed[s.a], fixed[s.b]);
        let both = if fa || fb { 1.0 } else { 2.0 };
        if !fa {
            stiffness[s.a] += both * s.stiffness;
            count[s.a] += both;
        }
        if !fb {
            stiffness[s.b] += both * s.stiffness;
            count[s.b] += both;
        }
    }
    let masses = system.masses();
    let (mut lk, mut lc) = (0.0f64, 0.0f64);
    for i in 0..system.len() {
        if !fixed[i] {
            lk = lk.max(stiffness[i] / masses[i]);
            lc = lc.max(count[i] / masses[i]);
        }
    }
    (lk, lc)
}

/// `y = M^-1/2 K M^-1/2 x` over all particles (fixed ones are zero in and out), with
/// `K` the springs' PSD-projected Hessian applied through the product sink.
fn apply(system: &SpringSystem, inv_sqrt_m: &[f64], x: &[DVec3], z: &mut [DVec3], y: &mut [DVec3]) {
    for ((zi, xi), s) in z.iter_mut().zip(x).zip(inv_sqrt_m) {
        *zi = *s * *xi;
    }
    y.fill(DVec3::ZERO);
    rate_product(system, z, y);
    for (yi, s) in y.iter_mut().zip(inv_sqrt_m) {
        *yi *= *s;
    }
}

/// The largest eigenvalue of `M^-1 K` (free unknowns, PSD-projected spring blocks at the
/// current state) estimated by `iterations` Lanczos steps from a fixed pseudo-random start
/// (no reorthogonalization: lost orthogonality only duplicates converged Ritz values, it
/// does not move the largest one). A lower bound up to round-off.
#[must_use]
pub fn lanczos_max(system: &SpringSystem, iterations: usize) -> f64 {
    let n = system.len();
    let fixed = system.fixed();
    let inv_sqrt_m: Vec<f64> = system
        .masses()
        .iter()
        .zip(fixed)
        .map(|(m, f)| if *f { 0.0 } else { 1.0 / m.sqrt() })
        .collect();
    let dim = 3 * fixed.iter().filter(|f| !**f).count();
    let steps = iterations.min(dim);
    if steps == 0 {
        return 0.0;
    }
    // A fixed pseudo-random start (splitmix64), so the estimate is reproducible.
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let mut q: Vec<DVec3> = (0..n)
        .map(|i| {
            let v = DVec3::new(next(), next(), next());
            if fixed[i] { DVec3::ZERO } else { v }
        })
        .collect();
    let norm = |v: &[DVec3]| v.iter().map(|a| a.length_squared()).sum::<f64>().sqrt();
    let q_norm = norm(&q);
    q.iter_mut().for_each(|a| *a /= q_norm);
    let mut q_prev = vec![DVec3::ZERO; n];
    let mut w = vec![DVec3::ZERO; n];
    let mut z = vec![DVec3::ZERO; n];
    let mut alphas = Vec::with_capacity(steps);
    let mut betas: Vec<f64> = Vec::with_capacity(steps);
    let mut beta_prev = 0.0;
    for _ in 0..steps {
        apply(system, &inv_sqrt_m, &q, &mut z, &mut w);
        for (wi, qp) in w.iter_mut().zip(&q_prev) {
            *wi -= beta_prev * *qp;
        }
        let alpha: f64 = w.iter().zip(&q).map(|(a, b)| a.dot(*b)).sum();
        for (wi, qi) in w.iter_mut().zip(&q) {
            *wi -= alpha * *qi;
        }
        alphas.push(alpha);
        let beta = norm(&w);
        let scale = alphas.iter().fold(0.0f64, |m, a| m.max(a.abs()));
        if beta <= 1e-12 * scale || beta.is_nan() {
            break;
        }
        betas.push(beta);
        for i in 0..n {
            q_prev[i] = q[i];
            q[i] = w[i] / beta;
        }
        beta_prev = beta;
    }
    betas.truncate(alphas.len().saturating_sub(1));
    tridiagonal_max(&alphas, &betas)
}

/// The largest eigenvalue of the symmetric tridiagonal matrix with diagonal `a` and
/// off-diagonal `b`, by bisection on the Sturm count (to a relative 1e-14).
fn tridiagonal_max(a: &[f64], b: &[f64]) -> f64 {
    let m = a.len();
    if m == 0 {
        return 0.0;
    }
    // Gershgorin interval of the tridiagonal matrix.
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for i in 0..m {
        let r = if i > 0 { b[i - 1].abs() } else { 0.0 } + if i + 1 < m { b[i].abs() } else { 0.0 };
        lo = lo.min(a[i] - r);
        hi = hi.max(a[i] + r);
    }
    // Number of eigenvalues below `x` (signs of the LDL^T pivots of T - x I).
    let below = |x: f64| -> usize {
        let mut count = 0;
        let mut d = 1.0;
        for i in 0..m {
            let off = if i > 0 { b[i - 1] * b[i - 1] / d } else { 0.0 };
            d = a[i] - x - off;
            if d == 0.0 {
                d = -f64::EPSILON * (x.abs() + 1.0);
            }
            if d < 0.0 {
                count += 1;
            }
        }
        count
    };
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if hi - lo <= 1e-14 * hi.abs().max(lo.abs()) || mid == lo || mid == hi {
            break;
        }
        if below(mid) == m {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    hi
}

/// Keeps a [`StabilityBound`] up to date along a run, at one `O(springs)` pass per step,
/// or none when the state cannot matter.
///
/// First, once per system, the state-independent bound of [`uniform_bound`]: when it
/// alone allows one substep at `h` (W4 and W6 at 1/60: `h omega / 2 = 0.41`), one
/// substep is stable at every state the system can reach, so nothing else is computed,
/// not even Gershgorin, and the bound returned is that uniform one (its `estimate` equal
/// to its `gershgorin`). The system's masses, springs and fixed set cannot change after
/// it is built, and the damping coefficient, which can, is read every call.
///
/// The Gershgorin bound is recomputed every step. Between two Lanczos estimates (about
/// 60 passes each) the estimate is scaled by the growth of the Gershgorin bound since
/// the last one, `lambda ~ lambda_0 g / g_0` when `g > g_0` (kept when it falls), and a
/// new Lanczos estimate is computed when `g / g_0` leaves `[1 - REFRESH, 1 + REFRESH]`.
/// The scaling is a heuristic, not a bound: on W5 k = 1e6 the Gershgorin bound grows by
/// 10% in the first second (the springs' transverse stiffness `k (1 - L/l)` appears in
/// every row sum) while the true `lambda_max` falls by 0.03%, so it errs on the safe side
/// there; the safety factor covers a further 23% in `lambda`. When Gershgorin alone
/// allows one substep nothing more is computed.
#[derive(Clone, Debug, Default)]
pub struct StabilityMonitor {
    bound: Option<StabilityBound>,
    /// The last Lanczos estimate and the Gershgorin bound of its state.
    estimated: f64,
    estimated_at: f64,
    rows: RowSums,
    /// [`uniform_bound`] of the system, with its particle and spring counts.
    uniform: Option<(usize, usize, f64, f64)>,
    /// Lanczos estimates computed so far.
    refreshes: usize,
}

/// Relative change of the Gershgorin bound since the last Lanczos estimate that
/// triggers a new one. On the lab cloth stretched by half, Gershgorin grows by 16.7%
/// while `lambda_max` grows by 20.5%: scaling the old estimate by Gershgorin's growth
/// would then be 3.2% low (within the safety factor's 23%, but not a margin to spend on
/// a cheaper monitor), so a change of 10% already asks for a new estimate.
pub const REFRESH: f64 = 0.1;

impl StabilityMonitor {
    /// A monitor with no bound yet.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// The bound for `system`'s current state at step `h`.
    pub fn update(&mut self, system: &SpringSystem, h: f64) -> StabilityBound {
        let counts = (system.len(), system.springs().len());
        let (lk, lc) = match self.uniform {
            Some((n, s, lk, lc)) if (n, s) == counts => (lk, lc),
            _ => {
                let (lk, lc) = uniform_bound(system);
                self.uniform = Some((counts.0, counts.1, lk, lc));
                (lk, lc)
            }
        };
        let gamma = lc * system.material().damping;
        if substeps_for(h * effective_omega(lk, gamma) / 2.0) <= 1 {
            return StabilityBound {
                gershgorin: lk,
                estimate: lk,
                damping_rate: gamma,
            };
        }
        let (g, c) = gershgorin_with(system, &mut self.rows);
        if let Some(b) = &mut self.bound {
            b.gershgorin = g;
            b.damping_rate = c;
            let ratio = g / self.estimated_at;
            b.estimate = (self.estimated * ratio.max(1.0)).min(g);
            let one = substeps_for(h * b.omega_upper() / 2.0) <= 1;
            if one || (ratio - 1.0).abs() <= REFRESH {
                return *b;
            }
        }
        let b = StabilityBound::of(system);
        self.refreshes += 1;
        self.estimated = b.estimate;
        self.estimated_at = b.gershgorin;
        self.bound = Some(b);
        b
    }

    /// The last bound computed from the state (Gershgorin and Lanczos), if any: the
    /// uniform bound of the one-substep case is not kept here.
    #[must_use]
    pub fn last(&self) -> Option<StabilityBound> {
        self.bound
    }

    /// How many Lanczos estimates the monitor has computed.
    #[must_use]
    pub fn lanczos_refreshes(&self) -> usize {
        self.refreshes
    }
}
