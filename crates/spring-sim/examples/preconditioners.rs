//! Stronger preconditioners for the Newton matrix's conjugate gradients, measured against
//! the block Jacobi one the solver uses (docs/spring-sim.md, "A stronger preconditioner,
//! measured").
//!
//! Workloads: W5 (k = 1e4 and 1e6), W6, and a 61 x 61 lab-pattern sheet as stiff against
//! its masses as the contact workload C3's (`k h^2 / m` = 1 250), without contact.
//! For each the Newton matrix `A = M/h^2 + K` (the assembled, PSD-projected
//! Hessian of backward Euler's incremental potential, `newton_matrix_triplets`) is taken
//! at rest and after a second of backward Euler (the sheet swinging, its springs
//! stretched), and `A x = b` is solved from zero for a fixed pseudo-random `x` by one
//! plain PCG loop with each preconditioner in turn:
//!
//! - `jacobi3`: the inverse of each particle's 3 x 3 diagonal block (what the solver runs);
//! - `liu`: Liu et al. 2013's prefactored `M/h^2 + k L`, the springs' stiffness-weighted
//!   graph Laplacian `L`, one sparse Cholesky factor of the particles' matrix (faer)
//!   applied to the three coordinates;
//! - `ic0`: the incomplete Cholesky factor of `A` on its own pattern (no fill), with the
//!   diagonal shifted by `1e-3 max|diag|` steps until it exists;
//! - `direct`: faer's sparse Cholesky factor of `A` itself (one iteration: the direct
//!   solve's cost, its symbolic analysis included in the set-up).
//!
//! Printed per case and preconditioner: its set-up time (factoring), the iterations to a
//! relative residual of 1e-2 (the solver's forcing term), 1e-6 and 1e-10, and the median
//! time of a solve to 1e-2 and to 1e-10 (one thread). The product, the vector work and
//! the loop are the same code for all three, so the ratios are the preconditioners' own.
//!
//! `cargo run --release -p sinew-spring-sim --example preconditioners [-- repeats]`

use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::{SparseColMat, Triplet};
use faer::{MatMut, Side};
use sinew_spring_sim::{
    BackwardEuler, ClothGrid, NewtonSettings, SpringSystem, newton_matrix_triplets,
};
use std::time::Instant;

/// The full symmetric matrix in compressed rows (both triangles stored).
struct Csr {
    n: usize,
    start: Vec<usize>,
    col: Vec<usize>,
    val: Vec<f64>,
}

impl Csr {
    fn from_lower(n: usize, lower: &[(usize, usize, f64)]) -> Self {
        let mut rows: Vec<Vec<(usize, f64)>> = vec![Vec::new(); n];
        for &(r, c, v) in lower {
            rows[r].push((c, v));
            if r != c {
                rows[c].push((r, v));
            }
        }
        let mut start = vec![0];
        let (mut col, mut val) = (Vec::new(), Vec::new());
        for row in &mut rows {
            row.sort_by_key(|e| e.0);
            for &(c, v) in row.iter() {
                col.push(c);
                val.push(v);
            }
            start.push(col.len());
        }
        Self { n, start, col, val }
    }

    fn apply(&self, x: &[f64], y: &mut [f64]) {
        for (i, out) in y.iter_mut().enumerate().take(self.n) {
            let mut s = 0.0;
            for k in self.start[i]..self.start[i + 1] {
                s += self.val[k] * x[self.col[k]];
            }
            *out = s;
        }
    }

    fn diagonal(&self, i: usize) -> f64 {
        (self.start[i]..self.start[i + 1])
            .find(|&k| self.col[k] == i)
            .map_or(0.0, |k| self.val[k])
    }
}

trait Preconditioner {
    fn apply(&mut self, r: &[f64], z: &mut [f64]);
}

/// The inverse of each 3 x 3 diagonal block.
struct Jacobi3 {
    inverse: Vec<[[f64; 3]; 3]>,
}

impl Jacobi3 {
    fn new(a: &Csr) -> Self {
        let blocks = a.n / 3;
        let mut inverse = Vec::with_capacity(blocks);
        for p in 0..blocks {
            let mut b = [[0.0; 3]; 3];
            for (r, row) in b.iter_mut().enumerate() {
                let i = 3 * p + r;
                for k in a.start[i]..a.start[i + 1] {
                    let c = a.col[k];
                    if c / 3 == p {
                        row[c % 3] = a.val[k];
                    }
                }
            }
            inverse.push(invert3(b));
        }
        Self { inverse }
    }
}

fn invert3(m: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let c = |r: usize, s: usize| {
        m[(r + 1) % 3][(s + 1) % 3] * m[(r + 2) % 3][(s + 2) % 3]
            - m[(r + 1) % 3][(s + 2) % 3] * m[(r + 2) % 3][(s + 1) % 3]
    };
    let det = m[0][0] * c(0, 0) + m[0][1] * c(0, 1) + m[0][2] * c(0, 2);
    let mut out = [[0.0; 3]; 3];
    for (r, row) in out.iter_mut().enumerate() {
        for (s, v) in row.iter_mut().enumerate() {
            *v = c(s, r) / det;
        }
    }
    out
}

impl Preconditioner for Jacobi3 {
    fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        for (p, inv) in self.inverse.iter().enumerate() {
            for (k, row) in inv.iter().enumerate() {
                z[3 * p + k] = row[0] * r[3 * p] + row[1] * r[3 * p + 1] + row[2] * r[3 * p + 2];
            }
        }
    }
}

/// faer's sparse Cholesky factor of the `n x n` matrix whose lower triangle `triplets`
/// holds (both matrices factored here are positive definite by construction).
fn cholesky(n: usize, triplets: &[Triplet<usize, usize, f64>]) -> Llt<usize, f64> {
    let matrix = SparseColMat::<usize, f64>::try_new_from_triplets(n, n, triplets)
        .expect("a valid lower triangle");
    let symbolic =
        SymbolicLlt::try_new(matrix.symbolic(), Side::Lower).expect("its symbolic factor");
    Llt::try_new_with_symbolic(symbolic, matrix.as_ref(), Side::Lower)
        .expect("a positive definite matrix")
}

/// `M/h^2 + k L` over the free particles, factored once, applied per coordinate.
struct Liu {
    llt: Llt<usize, f64>,
    rhs: Vec<f64>,
}

impl Liu {
    fn new(system: &SpringSystem, h: f64) -> Self {
        let fixed = system.fixed();
        let mut free = vec![usize::MAX; fixed.len()];
        let mut n = 0;
        for (i, f) in fixed.iter().enumerate() {
            if !f {
                free[i] = n;
                n += 1;
            }
        }
        let mut triplets: Vec<Triplet<usize, usize, f64>> = Vec::new();
        for (i, &m) in system.masses().iter().enumerate() {
            if free[i] != usize::MAX {
                triplets.push(Triplet::new(free[i], free[i], m / (h * h)));
            }
        }
        for s in system.springs() {
            let (a, b) = (free[s.a], free[s.b]);
            for &p in [a, b].iter().filter(|&&p| p != usize::MAX) {
                triplets.push(Triplet::new(p, p, s.stiffness));
            }
            if a != usize::MAX && b != usize::MAX {
                let (lo, hi) = (a.min(b), a.max(b));
                triplets.push(Triplet::new(hi, lo, -s.stiffness));
            }
        }
        Self {
            llt: cholesky(n, &triplets),
            rhs: vec![0.0; 3 * n],
        }
    }
}

impl Preconditioner for Liu {
    fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        let n = r.len() / 3;
        // Coordinates as three columns.
        for c in 0..3 {
            for p in 0..n {
                self.rhs[c * n + p] = r[3 * p + c];
            }
        }
        self.llt
            .solve_in_place(MatMut::from_column_major_slice_mut(&mut self.rhs, n, 3));
        for c in 0..3 {
            for p in 0..n {
                z[3 * p + c] = self.rhs[c * n + p];
            }
        }
    }
}

/// The exact inverse: faer's sparse Cholesky of `A` itself (its symbolic analysis
/// included in the set-up), so PCG takes one iteration: the direct solve's cost.
struct Direct {
    llt: Llt<usize, f64>,
}

impl Direct {
    fn new(lower: &[(usize, usize, f64)], n: usize) -> Self {
        let triplets: Vec<Triplet<usize, usize, f64>> = lower
            .iter()
            .map(|&(r, c, v)| Triplet::new(r, c, v))
            .collect();
        Self {
            llt: cholesky(n, &triplets),
        }
    }
}

impl Preconditioner for Direct {
    fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        z.copy_from_slice(r);
        let n = z.len();
        self.llt
            .solve_in_place(MatMut::from_column_major_slice_mut(z, n, 1));
    }
}

/// Incomplete Cholesky with no fill: `L` on the lower triangle of `A`'s pattern.
struct Ic0 {
    n: usize,
    /// Row `i`'s entries left of the diagonal (ascending columns), then the diagonal.
    start: Vec<usize>,
    col: Vec<usize>,
    val: Vec<f64>,
    work: Vec<f64>,
    shifts: usize,
}

impl Ic0 {
    fn new(a: &Csr) -> Self {
        let n = a.n;
        let largest = (0..n).map(|i| a.diagonal(i)).fold(0.0, f64::max);
        let mut shift = 0.0;
        let mut shifts = 0;
        loop {
            if let Some(mut f) = Self::factor(a, shift) {
                f.shifts = shifts;
                return f;
            }
            shifts += 1;
            shift = if shift == 0.0 {
                1e-3 * largest
            } else {
                2.0 * shift
            };
        }
    }

    fn factor(a: &Csr, shift: f64) -> Option<Self> {
        let n = a.n;
        let mut start = vec![0];
        let (mut col, mut val) = (Vec::new(), Vec::new());
        for i in 0..n {
            for k in a.start[i]..a.start[i + 1] {
                if a.col[k] <= i {
                    col.push(a.col[k]);
                    val.push(a.val[k] + if a.col[k] == i { shift } else { 0.0 });
                }
            }
            start.push(col.len());
        }
        // Row by row: L[i][k] = (A[i][k] - sum_j<k L[i][j] L[k][j]) / L[k][k] over the
        // pattern, then the diagonal.
        for i in 0..n {
            let (s, e) = (start[i], start[i + 1]);
            for q in s..e {
                let k = col[q];
                // Sparse dot of rows i and k over columns < k.
                let (mut u, mut w) = (s, start[k]);
                let mut dot = 0.0;
                while u < q && w < start[k + 1] - 1 {
                    match col[u].cmp(&col[w]) {
                        std::cmp::Ordering::Less => u += 1,
                        std::cmp::Ordering::Greater => w += 1,
                        std::cmp::Ordering::Equal => {
                            dot += val[u] * val[w];
                            u += 1;
                            w += 1;
                        }
                    }
                }
                if k < i {
                    val[q] = (val[q] - dot) / val[start[k + 1] - 1];
                } else {
                    let d = val[q] - dot;
                    // Not positive (or NaN): no factor without a shift.
                    if d.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
                        return None;
                    }
                    val[q] = d.sqrt();
                }
            }
        }
        Some(Self {
            n,
            start,
            col,
            val,
            work: vec![0.0; n],
            shifts: 0,
        })
    }
}

impl Preconditioner for Ic0 {
    fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        let y = &mut self.work;
        for i in 0..self.n {
            let (s, e) = (self.start[i], self.start[i + 1]);
            let mut t = r[i];
            for q in s..e - 1 {
                t -= self.val[q] * y[self.col[q]];
            }
            y[i] = t / self.val[e - 1];
        }
        z.copy_from_slice(y);
        for i in (0..self.n).rev() {
            let (s, e) = (self.start[i], self.start[i + 1]);
            z[i] /= self.val[e - 1];
            let zi = z[i];
            for q in s..e - 1 {
                z[self.col[q]] -= self.val[q] * zi;
            }
        }
    }
}

/// PCG from zero until the residual is below `tol |b|` (or 20 000 iterations): the
/// iterations at which 1e-2, 1e-6 and 1e-10 were reached (`None`: not reached).
fn pcg(a: &Csr, b: &[f64], pre: &mut dyn Preconditioner, tol: f64) -> [Option<usize>; 3] {
    let n = a.n;
    let (mut x, mut r, mut z, mut p, mut q) = (
        vec![0.0; n],
        b.to_vec(),
        vec![0.0; n],
        vec![0.0; n],
        vec![0.0; n],
    );
    let dot = |u: &[f64], v: &[f64]| u.iter().zip(v).map(|(a, b)| a * b).sum::<f64>();
    let norm_b = dot(b, b).sqrt();
    let marks = [1e-2, 1e-6, 1e-10];
    let mut reached = [None; 3];
    pre.apply(&r, &mut z);
    p.copy_from_slice(&z);
    let mut rz = dot(&r, &z);
    for it in 1..=20_000 {
        a.apply(&p, &mut q);
        let alpha = rz / dot(&p, &q);
        for i in 0..n {
            x[i] += alpha * p[i];
            r[i] -= alpha * q[i];
        }
        let rel = dot(&r, &r).sqrt() / norm_b;
        for (m, slot) in marks.iter().zip(reached.iter_mut()) {
            if slot.is_none() && rel <= *m {
                *slot = Some(it);
            }
        }
        if rel <= tol {
            break;
        }
        pre.apply(&r, &mut z);
        let rz_new = dot(&r, &z);
        let beta = rz_new / rz;
        rz = rz_new;
        for i in 0..n {
            p[i] = z[i] + beta * p[i];
        }
    }
    reached
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn lab(n: usize, stiffness: f64) -> SpringSystem {
    let mut g = if n == 11 {
        ClothGrid::lab()
    } else {
        ClothGrid::lab_sized(n, 2.0 / (n - 1) as f64)
    };
    g.material.stiffness = stiffness;
    SpringSystem::cloth(&g).expect("the lab cloth")
}

fn main() {
    let repeats: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(5);
    let cases: [(&str, usize, f64, f64); 4] = [
        ("W5 k = 1e4", 11, 1e4, 1.0 / 30.0),
        ("W5 k = 1e6", 11, 1e6, 1.0 / 30.0),
        ("W6", 101, 100.0, 1.0 / 60.0),
        // C3's sheet without its contact: 61 x 61 with `k h^2 / m` = 1 250 as there.
        ("61 x 61, k h^2/m = 1250", 61, 1250.0 * 3600.0, 1.0 / 60.0),
    ];
    println!(
        "| case | state | unknowns | preconditioner | set-up (ms) | iterations to 1e-2 / 1e-6 / 1e-10 | solve to 1e-2 (ms) | solve to 1e-10 (ms) |"
    );
    println!("|---|---|---:|---|---:|---|---:|---:|");
    for (name, n, k, h) in cases {
        let mut system = lab(n, k);
        for state in ["rest", "after 1 s"] {
            if state != "rest" {
                let mut be =
                    BackwardEuler::new(&system, NewtonSettings::default()).expect("backward Euler");
                let steps = (1.0 / h).round() as usize;
                for _ in 0..steps {
                    be.step(&mut system, h).expect("a step");
                }
            }
            let lower = newton_matrix_triplets(&system, h);
            let unknowns = lower.iter().map(|t| t.0.max(t.1)).max().unwrap_or(0) + 1;
            let a = Csr::from_lower(unknowns, &lower);
            // A fixed pseudo-random solution (xorshift), the right-hand side its product.
            let mut s = 0x2545_f491_4f6c_dd1d_u64;
            let truth: Vec<f64> = (0..unknowns)
                .map(|_| {
                    s ^= s << 13;
                    s ^= s >> 7;
                    s ^= s << 17;
                    (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
                })
                .collect();
            let mut b = vec![0.0; unknowns];
            a.apply(&truth, &mut b);
            for which in ["jacobi3", "liu", "ic0", "direct"] {
                let t0 = Instant::now();
                let (mut pre, label): (Box<dyn Preconditioner>, String) = match which {
                    "jacobi3" => (Box::new(Jacobi3::new(&a)), which.to_string()),
                    "liu" => (Box::new(Liu::new(&system, h)), which.to_string()),
                    "direct" => (Box::new(Direct::new(&lower, unknowns)), which.to_string()),
                    _ => {
                        let f = Ic0::new(&a);
                        let label = format!("ic0 ({} shifts)", f.shifts);
                        (Box::new(f), label)
                    }
                };
                let setup = t0.elapsed().as_secs_f64() * 1e3;
                let reached = pcg(&a, &b, pre.as_mut(), 1e-10);
                let time = |tol: f64, pre: &mut dyn Preconditioner| {
                    median(
                        (0..repeats)
                            .map(|_| {
                                let t = Instant::now();
                                pcg(&a, &b, pre, tol);
                                t.elapsed().as_secs_f64() * 1e3
                            })
                            .collect(),
                    )
                };
                let loose = time(1e-2, pre.as_mut());
                let tight = time(1e-10, pre.as_mut());
                let its = reached.map(|r| r.map_or("-".to_string(), |i| i.to_string()));
                println!(
                    "| {name} | {state} | {unknowns} | {label} | {setup:.2} | {} / {} / {} | {loose:.3} | {tight:.3} |",
                    its[0], its[1], its[2]
                );
            }
        }
    }
}
