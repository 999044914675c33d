//! Linear solvers for the Newton system `H dx = -grad g`, behind one interface.
//!
//! - [`DirectSolver`]: faer's sparse Cholesky through the low-level API, with the
//!   symbolic factorization (the AMD ordering of the particle graph, simplicial or
//!   supernodal structure) computed once per topology and the factor values and
//!   workspaces allocated once and reused.
//!   A failed factorization is retried on `H + sigma I` with a growing shift; the shifts
//!   are counted for the step report. The supernodal path writes the matrix straight
//!   into the ordering's positions through a slot map built once, factors it on faer's
//!   symbolic structure with two subtrees of the elimination tree side by side and the
//!   separators above them by panels on both threads (`tree_llt`), and solves with the
//!   factor by the same split; the last factor can precondition conjugate gradients on
//!   a later matrix instead of a factorization.
//! - [`PcgSolver`]: conjugate gradients preconditioned by the inverse 3x3 diagonal blocks
//!   (block Jacobi), to a relative residual, on the same assembled matrix.
//!
//! - [`SolverCosts`]: the counts `Auto` chooses between them from (the factor's size and
//!   work under a fill-reducing ordering, the matrix's nonzeros), no timing; the model
//!   and its measured crossover are in docs/spring-sim.md.
//!
//! Which one a step uses is decided by the integrator (see `LinearSolverChoice`).

use crate::pattern::HessianPattern;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::perm::PermRef;
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::linalg::amd;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymbolicCholeskyRaw, SymmetricOrdering,
    factorize_symbolic_cholesky, simplicial,
};
use faer::sparse::utils::{permute_self_adjoint_scratch, permute_self_adjoint_to_unsorted};
use faer::sparse::{FaerError, SparseColMatRef, SymbolicSparseColMat};
use faer::{Conj, MatMut, Par, Side};
use sinew_math::{DMat3, DVec3};
use std::sync::Arc;

mod tree_llt;

/// A linear solver that could not be set up, with faer's (or the thread pool's) own
/// error as its `source`, so a caller can reach the structured cause.
#[derive(Clone, Debug)]
pub enum SolverError {
    /// faer's symbolic Cholesky factorization of the Newton matrix's pattern failed
    /// (an index overflow or an allocation failure).
    SymbolicFactorization(FaerError),
    /// faer's approximate minimum degree ordering of the particle graph failed (the order
    /// of the direct solver's factor and of the automatic solver choice's cost counts).
    Ordering(FaerError),
    /// The thread pool of `threads` threads could not be started.
    ThreadPool {
        /// The threads asked for.
        threads: usize,
        /// The thread pool builder's error.
        cause: Arc<dyn std::error::Error + Send + Sync>,
    },
}

impl SolverError {
    /// A thread pool of `threads` threads failed to start with `cause`.
    #[cfg(feature = "parallel")]
    pub(crate) fn thread_pool(
        threads: usize,
        cause: impl std::error::Error + Send + Sync + 'static,
    ) -> Self {
        Self::ThreadPool {
            threads,
            cause: Arc::new(cause),
        }
    }
}

impl PartialEq for SolverError {
    /// The same failure of the same step: the causes are compared where they can be
    /// (faer's errors), the thread pool's by the thread count alone.
    fn eq(&self, other: &Self) -> bool {
        match (self, other) {
            (Self::SymbolicFactorization(a), Self::SymbolicFactorization(b))
            | (Self::Ordering(a), Self::Ordering(b)) => a == b,
            (Self::ThreadPool { threads: a, .. }, Self::ThreadPool { threads: b, .. }) => a == b,
            _ => false,
        }
    }
}

impl std::fmt::Display for SolverError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::SymbolicFactorization(_) => f.write_str(
                "linear_solver: the symbolic Cholesky factorization of the Newton matrix failed",
            ),
            Self::Ordering(_) => f.write_str(
                "linear_solver: the ordering of the particle graph (the direct solver's and the cost model's) failed",
            ),
            Self::ThreadPool { threads, .. } => {
                write!(f, "threads: a pool of {threads} threads could not be started")
            }
        }
    }
}

impl std::error::Error for SolverError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::SymbolicFactorization(e) | Self::Ordering(e) => Some(e),
            Self::ThreadPool { cause, .. } => Some(cause.as_ref()),
        }
    }
}

/// Which linear solver the Newton iterations use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum LinearSolverChoice {
    /// Sparse Cholesky every Newton iteration.
    Direct,
    /// Block-Jacobi preconditioned conjugate gradients.
    Pcg,
    /// Chosen per step by a cost model from counts (see [`SolverCosts`]): PCG while the
    /// PCG iterations it needs per Newton iteration stay below the model's crossover,
    /// the direct solve above it. No timing enters, so two identical runs make the same
    /// choices and give bitwise the same results.
    #[default]
    Auto,
}

/// The solver a step actually used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum LinearSolverKind {
    /// Sparse Cholesky.
    Direct,
    /// Preconditioned conjugate gradients.
    Pcg,
}

impl LinearSolverKind {
    /// A short name for reports.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Direct => "direct",
            Self::Pcg => "pcg",
        }
    }
}

/// Which factorization structure the direct solver uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum FactorStructure {
    /// Supernodal (measured faster here on every lab-cloth size, see
    /// docs/bench/spring-sim.md).
    #[default]
    Supernodal,
    /// Simplicial.
    Simplicial,
    /// faer's own flop-ratio rule.
    FaerAuto,
}

/// The weight of one multiply-add of the numeric factorization against one of PCG's
/// (the unit of [`SolverCosts`]): the supernodal factorization runs dense kernels on
/// contiguous blocks, far faster per multiply-add than the indirect loads of PCG's sparse
/// product. Fitted with [`FACTOR_ENTRY_WEIGHT`] to the factorization's measured time on
/// cloths of 11 x 11 to 101 x 101 particles (docs/spring-sim.md), within 10%.
pub const FACTOR_WEIGHT: f64 = 0.045;

/// The weight of one entry of the factor in the numeric factorization (its assembly,
/// scatter and memory traffic, which dominate on small grids), in the same unit.
pub const FACTOR_ENTRY_WEIGHT: f64 = 19.0;

/// The weight of one multiply-add of the two triangular solves (memory-bound like PCG's
/// product, so 1).
pub const SOLVE_WEIGHT: f64 = 1.0;

/// The free particles' graph (the Newton matrix's 3x3 blocks as single entries, lower
/// triangle) and its approximate minimum degree ordering (faer's AMD): the fill-reducing
/// order of both the cost model's analysis and the direct solver's factorization.
///
/// The scalar matrix's AMD finds each particle's three unknowns indistinguishable and
/// orders them together anyway; the particle graph has a ninth of the entries, and the
/// whole symbolic set-up on it took about a third less time on 50 x 50 and 61 x 61 lab
/// sheets, a set-up a contact run pays again each time contact widens the pattern
/// (docs/spring-sim.md).
struct ParticleOrdering {
    graph: SymbolicSparseColMat<usize>,
    /// `perm[new] = old`, as faer's orderings.
    perm: Vec<usize>,
    perm_inv: Vec<usize>,
}

impl ParticleOrdering {
    /// The ordering of `pattern`'s free particles (at least one).
    fn of(pattern: &HessianPattern) -> Result<Self, SolverError> {
        let particles = pattern.free_particles.len();
        // Column p holds p, then every neighbour below it, read from the first scalar
        // column of p's block column (its diagonal block's three entries, then three rows
        // per neighbour).
        let col_ptr = pattern.symbolic.col_ptr();
        let row_idx = pattern.symbolic.row_idx();
        let mut block_col_ptr = Vec::with_capacity(particles + 1);
        let mut block_rows = Vec::with_capacity(pattern.nnz() / 9 + particles);
        block_col_ptr.push(0usize);
        for p in 0..particles {
            block_rows.push(p);
            let (start, end) = (col_ptr[3 * p] + 3, col_ptr[3 * p + 1]);
            block_rows.extend(row_idx[start..end].iter().step_by(3).map(|r| r / 3));
            block_col_ptr.push(block_rows.len());
        }
        let graph = SymbolicSparseColMat::new_checked(
            particles,
            particles,
            block_col_ptr,
            None,
            block_rows,
        );
        let mut perm = vec![0usize; particles];
        let mut perm_inv = vec![0usize; particles];
        let mut work = MemBuffer::new(amd::order_scratch::<usize>(
            particles,
            graph.row_idx().len(),
        ));
        amd::order(
            &mut perm,
            &mut perm_inv,
            graph.as_ref(),
            amd::Control::default(),
            MemStack::new(&mut work),
        )
        .map_err(SolverError::Ordering)?;
        Ok(Self {
            graph,
            perm,
            perm_inv,
        })
    }

    /// The ordering of the unknowns, forward and inverse: each particle's three in the
    /// particle's place, in their own order.
    fn unknowns(&self) -> (Vec<usize>, Vec<usize>) {
        let spread = |order: &[usize]| -> Vec<usize> {
            order
                .iter()
                .flat_map(|&p| [3 * p, 3 * p + 1, 3 * p + 2])
                .collect()
        };
        (spread(&self.perm), spread(&self.perm_inv))
    }
}

/// The counts the automatic linear-solver choice is made from, for one Newton matrix
/// pattern.
///
/// The direct solver's work comes from a symbolic analysis of the particle graph (the
/// pattern's 3x3 blocks): faer's approximate minimum degree ordering of the free
/// particles, then the elimination tree's column counts under that ordering, expanded
/// to the three unknowns per particle. The analysis of the particle graph is nine
/// times smaller than that of the scalar matrix and never allocates the factor. PCG's
/// work per iteration comes from the matrix's nonzeros and its dimension. Both are in
/// multiply-adds, weighted by three constants fitted to measured factorization times
/// (docs/spring-sim.md); the crossover
/// ([`SolverCosts::crossover_iterations`]) is the number of PCG iterations per Newton
/// iteration at which the two cost the same.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolverCosts {
    /// Unknowns (three per free particle).
    pub dim: usize,
    /// Stored entries of the matrix's lower triangle.
    pub matrix_nonzeros: usize,
    /// Entries of the Cholesky factor below its diagonal.
    pub factor_nonzeros: f64,
    /// Multiply-adds of the numeric factorization, `sum_j d_j (d_j + 1) / 2` over the
    /// factor's columns with `d_j` entries below the diagonal.
    pub factor_multiply_adds: f64,
}

impl SolverCosts {
    /// Analyses `pattern` (see the type's documentation). `O(springs)` memory; the time
    /// of an ordering of the particle graph (milliseconds on 101 x 101).
    pub fn analyze(pattern: &HessianPattern) -> Result<Self, SolverError> {
        let particles = pattern.free_particles.len();
        let dim = pattern.dim();
        let matrix_nonzeros = pattern.nnz();
        if particles == 0 {
            return Ok(Self {
                dim,
                matrix_nonzeros,
                factor_nonzeros: 0.0,
                factor_multiply_adds: 0.0,
            });
        }
        let ParticleOrdering {
            graph, perm_inv, ..
        } = ParticleOrdering::of(pattern)?;
        // The permuted graph's upper triangle (what the column counts read).
        let mut columns: Vec<Vec<usize>> = vec![Vec::new(); particles];
        for p in 0..particles {
            for &q in &graph.row_idx()[graph.col_ptr()[p]..graph.col_ptr()[p + 1]] {
                let (a, b) = (perm_inv[p], perm_inv[q]);
                columns[a.max(b)].push(a.min(b));
            }
        }
        let mut upper_ptr = Vec::with_capacity(particles + 1);
        let mut upper_rows = Vec::with_capacity(graph.row_idx().len());
        upper_ptr.push(0usize);
        for mut column in columns {
            column.sort_unstable();
            upper_rows.extend(column);
            upper_ptr.push(upper_rows.len());
        }
        let upper =
            SymbolicSparseColMat::new_checked(particles, particles, upper_ptr, None, upper_rows);
        let mut etree = vec![0isize; particles];
        let mut counts = vec![0usize; particles];
        let mut work = MemBuffer::new(simplicial::prefactorize_symbolic_cholesky_scratch::<usize>(
            particles,
            upper.row_idx().len(),
        ));
        simplicial::prefactorize_symbolic_cholesky(
            &mut etree,
            &mut counts,
            upper.as_ref(),
            MemStack::new(&mut work),
        );
        // A block column of the factor with `c` blocks (its diagonal one included) is
        // three scalar columns with `3 (c - 1) + 2`, `+ 1` and `+ 0` entries below the
        // diagonal.
        let mut factor_nonzeros = 0.0;
        let mut factor_multiply_adds = 0.0;
        for &c in &counts {
            for r in 0..3 {
                let d = (3 * (c - 1) + 2 - r) as f64;
                factor_nonzeros += d;
                factor_multiply_adds += 0.5 * d * (d + 1.0);
            }
        }
        Ok(Self {
            dim,
            matrix_nonzeros,
            factor_nonzeros,
            factor_multiply_adds,
        })
    }

    /// Counts no larger than [`SolverCosts::analyze`]'s, from the pattern's sizes alone
    /// (no ordering, O(1)), so their crossover is no larger than the analysed one: a
    /// PCG count at or below it is below the analysed crossover too, and the choice it
    /// makes is the analysis' without the analysis (docs/spring-sim.md, "The solver
    /// choice without its analysis").
    ///
    /// Under any ordering the factor has every entry the matrix stores below its
    /// diagonal, so `nnz(L) >= nnz(A) - n`; and `F = sum_j d_j (d_j + 1) / 2` over the
    /// `n` columns, a convex and increasing function of the `d_j` whose sum is `nnz(L)`,
    /// is at least `n f(nnz(L) / n)` (Jensen).
    #[must_use]
    pub fn lower_bound(pattern: &HessianPattern) -> Self {
        let dim = pattern.dim();
        let matrix_nonzeros = pattern.nnz();
        let below = matrix_nonzeros.saturating_sub(dim) as f64;
        let factor_multiply_adds = if dim > 0 {
            let mean = below / dim as f64;
            dim as f64 * 0.5 * mean * (mean + 1.0)
        } else {
            0.0
        };
        Self {
            dim,
            matrix_nonzeros,
            factor_nonzeros: below,
            factor_multiply_adds,
        }
    }

    /// Model cost of one PCG iteration, in multiply-adds: the symmetric product reads
    /// every stored off-diagonal entry twice (`2 nnz`), and the preconditioner (9 per
    /// particle row, 3 per unknown), three dot products and three updates add 9 per
    /// unknown.
    #[must_use]
    pub fn cg_iteration_cost(&self) -> f64 {
        2.0 * self.matrix_nonzeros as f64 + 9.0 * self.dim as f64
    }

    /// Model cost of one direct solve (numeric factorization and the two triangular
    /// solves), in the units of [`SolverCosts::cg_iteration_cost`].
    #[must_use]
    pub fn direct_cost(&self) -> f64 {
        FACTOR_WEIGHT * self.factor_multiply_adds
            + FACTOR_ENTRY_WEIGHT * self.factor_nonzeros
            + SOLVE_WEIGHT * 2.0 * (self.factor_nonzeros + self.dim as f64)
    }

    /// The PCG iterations per Newton iteration at which PCG costs as much as the direct
    /// solve: `direct_cost / cg_iteration_cost` (infinite for an empty system).
    #[must_use]
    pub fn crossover_iterations(&self) -> f64 {
        let cg = self.cg_iteration_cost();
        if cg > 0.0 {
            self.direct_cost() / cg
        } else {
            f64::INFINITY
        }
    }
}

/// What one direct solve did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DirectOutcome {
    /// How many shifted retries were needed (0: the matrix factored as is).
    pub shifts: usize,
    /// Whether every factorization failed (the right-hand side is then untouched).
    pub failed: bool,
}

/// How a solve preconditioned by the kept factor ended (see
/// [`DirectSolver::solve_with_kept_factor`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KeptFactorStatus {
    /// The relative residual was reached: the right-hand side holds the solution.
    Converged,
    /// A search direction `p` with `p^T A p <= 0` was met: a certificate that the matrix
    /// is not positive definite.
    NonPositiveCurvature,
    /// The iteration budget ran out first.
    OverBudget,
    /// No factor is kept (none yet, or forgotten).
    NoFactor,
}

/// What one solve preconditioned by the kept factor did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KeptFactorOutcome {
    /// Conjugate-gradient iterations (each one product with the matrix and one pair of
    /// triangular solves with the kept factor).
    pub iterations: usize,
    /// Final `|r| / |b|` (Euclidean).
    pub relative_residual: f64,
    /// How it ended.
    pub status: KeptFactorStatus,
}

/// Sparse Cholesky with a symbolic factorization built once and reused buffers.
///
/// The last successful numeric factor is kept: a later, nearby matrix can be solved by
/// conjugate gradients preconditioned with it ([`DirectSolver::solve_with_kept_factor`])
/// instead of a new factorization. Once [`DirectSolver::set_keep_factor`] asks for it, a
/// failed factorization never overwrites the kept factor (it is computed into a second
/// buffer, swapped in on success); without it the factor has one buffer, no larger than
/// the solver needs for its own solves.
pub struct DirectSolver {
    symbolic: SymbolicCholesky<usize>,
    factor_values: Vec<f64>,
    /// Where a factorization is computed before it replaces `factor_values`, when the
    /// factor is kept (empty otherwise).
    trial_values: Vec<f64>,
    /// Whether a failed factorization must leave the kept factor as it was.
    keep: bool,
    /// Whether `factor_values` holds the factor of a positive definite matrix.
    has_factor: bool,
    shifted_values: Vec<f64>,
    /// faer's numeric factorization's scratch (empty when `permuted` factors instead).
    factor_work: MemBuffer,
    solve_work: MemBuffer,
    /// The conjugate-gradient vectors of the preconditioned solve: iterate, residual,
    /// preconditioned residual, direction, product.
    cg: [Vec<f64>; 5],
    /// The supernodal path's matrix in the fill-reducing order, written straight from
    /// the pattern's values (see [`PermutedMatrix`]); `None` for the other structures.
    permuted: Option<PermutedMatrix>,
}

/// The lower triangle of `P A P^T` for the symbolic factorization's ordering `P`, built
/// once: its structure, and for each of its entries the slot of `A`'s lower triangle it
/// is read from. faer's own path recomputes this structure at every numeric
/// factorization (counting, prefix sums, scattering); here each factorization only
/// gathers the values through the slot map, into the same positions, and factors them
/// with [`tree_llt`]'s plan.
struct PermutedMatrix {
    symbolic: SymbolicSparseColMat<usize>,
    /// `values[k] = a[slots[k]]`.
    slots: Vec<usize>,
    values: Vec<f64>,
    /// The numeric factorization's plan (see [`tree_llt`]).
    plan: tree_llt::TreePlan,
    /// The factorization's and the solve's scratch, one per thread (built with the plan).
    works: [tree_llt::Work; 2],
    /// The solve's right-hand side in the factorization's order.
    solve_x: Vec<f64>,
}

impl PermutedMatrix {
    /// The permuted structure of `pattern` under `symbolic`'s ordering, when the
    /// factorization is supernodal and has an ordering.
    fn new(pattern: &HessianPattern, symbolic: &SymbolicCholesky<usize>) -> Option<Self> {
        let SymbolicCholeskyRaw::Supernodal(supernodal) = symbolic.raw() else {
            return None;
        };
        let plan = tree_llt::TreePlan::new(supernodal);
        let perm = symbolic.perm()?;
        let n = pattern.dim();
        let nnz = pattern.nnz();
        // Slot numbers as values: exact in f64 far beyond any pattern here (2^53).
        let tags: Vec<f64> = (0..nnz).map(|k| k as f64).collect();
        let mut values = vec![0.0; nnz];
        let mut col_ptr = vec![0usize; n + 1];
        let mut row_idx = vec![0usize; nnz];
        let mut work = MemBuffer::new(permute_self_adjoint_scratch::<usize>(n));
        permute_self_adjoint_to_unsorted(
            &mut values,
            &mut col_ptr,
            &mut row_idx,
            pattern.matrix(&tags),
            perm,
            Side::Lower,
            Side::Lower,
            MemStack::new(&mut work),
        );
        let slots = values.iter().map(|&v| v as usize).collect();
        // The structure exactly as faer's path produces it before factoring (the
        // unsorted constructor checks the bounds without asking for sorted rows).
        let symbolic = SymbolicSparseColMat::new_unsorted_checked(n, n, col_ptr, None, row_idx);
        let works = std::array::from_fn(|thread| tree_llt::Work::new(n, &plan, thread));
        Some(Self {
            symbolic,
            slots,
            values,
            plan,
            works,
            solve_x: Vec::new(),
        })
    }
}

impl std::fmt::Debug for DirectSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // faer's work buffers have no Debug; show the sizes that matter.
        f.debug_struct("DirectSolver")
            .field("supernodal", &self.is_supernodal())
            .field("factor_len", &self.factor_values.len())
            .field("has_factor", &self.has_factor)
            .finish_non_exhaustive()
    }
}

impl DirectSolver {
    /// The symbolic factorization of `pattern`'s matrix with the given structure.
    pub fn new(pattern: &HessianPattern, structure: FactorStructure) -> Result<Self, SolverError> {
        let threshold = match structure {
            FactorStructure::Supernodal => SupernodalThreshold::FORCE_SUPERNODAL,
            FactorStructure::Simplicial => SupernodalThreshold::FORCE_SIMPLICIAL,
            FactorStructure::FaerAuto => SupernodalThreshold::AUTO,
        };
        let params = CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: threshold,
            ..Default::default()
        };
        let n = pattern.dim();
        // The particles' ordering spread to their unknowns (`ParticleOrdering`); an empty
        // system has nothing to order.
        let order = match n {
            0 => None,
            _ => Some(ParticleOrdering::of(pattern)?.unknowns()),
        };
        let ordering = match &order {
            Some((forward, inverse)) => {
                SymmetricOrdering::Custom(PermRef::new_checked(forward, inverse, n))
            }
            None => SymmetricOrdering::Identity,
        };
        let symbolic =
            factorize_symbolic_cholesky(pattern.symbolic.as_ref(), Side::Lower, ordering, params)
                .map_err(SolverError::SymbolicFactorization)?;
        let factor_values = vec![0.0; symbolic.len_val()];
        let permuted = PermutedMatrix::new(pattern, &symbolic);
        // faer's numeric factorization runs only where `tree_llt` does not: its scratch
        // is needed only then.
        let factor_work = MemBuffer::new(match permuted {
            Some(_) => faer::dyn_stack::StackReq::EMPTY,
            None => symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
        });
        let solve_work = MemBuffer::new(symbolic.solve_in_place_scratch::<f64>(1, Par::Seq));
        Ok(Self {
            symbolic,
            trial_values: Vec::new(),
            keep: false,
            factor_values,
            has_factor: false,
            shifted_values: vec![0.0; pattern.nnz()],
            factor_work,
            solve_work,
            cg: std::array::from_fn(|_| vec![0.0; n]),
            permuted,
        })
    }

    /// Whether the factorization is supernodal.
    #[must_use]
    pub fn is_supernodal(&self) -> bool {
        matches!(self.symbolic.raw(), SymbolicCholeskyRaw::Supernodal(_))
    }

    /// Number of stored factor entries.
    #[must_use]
    pub fn factor_len(&self) -> usize {
        self.factor_values.len()
    }

    /// Whether a factor is kept for [`DirectSolver::solve_with_kept_factor`].
    #[must_use]
    pub fn has_factor(&self) -> bool {
        self.has_factor
    }

    /// Whether a failed factorization leaves the last good factor in place for
    /// [`DirectSolver::solve_with_kept_factor`] (off by default): on, factorizations are
    /// computed into a second factor-sized buffer and swapped in when they succeed, so
    /// the solver holds two factors' worth of memory.
    pub fn set_keep_factor(&mut self, keep: bool) {
        self.keep = keep;
        if !keep {
            self.trial_values = Vec::new();
        }
    }

    /// Drops the kept factor: the next solve preconditioned by it reports
    /// [`KeptFactorStatus::NoFactor`].
    pub fn forget_factor(&mut self) {
        self.has_factor = false;
    }

    /// Factors the matrix (lower triangle `values` on `pattern`) into the trial buffer
    /// and, on success, makes it the kept factor. Returns whether it succeeded.
    fn factor(&mut self, pattern: &HessianPattern, values: &[f64]) -> bool {
        let stack = MemStack::new(&mut self.factor_work);
        // Without `keep` the factor is computed in place: a failure then leaves no factor.
        let target = if self.keep {
            self.trial_values.resize(self.factor_values.len(), 0.0);
            &mut self.trial_values
        } else {
            self.has_factor = false;
            &mut self.factor_values
        };
        let factored = match (&mut self.permuted, self.symbolic.raw()) {
            (Some(permuted), SymbolicCholeskyRaw::Supernodal(supernodal)) => {
                for (v, &k) in permuted.values.iter_mut().zip(&permuted.slots) {
                    *v = values[k];
                }
                tree_llt::factorize(
                    supernodal,
                    &permuted.plan,
                    SparseColMatRef::new(permuted.symbolic.as_ref(), &permuted.values),
                    target,
                    &mut permuted.works,
                    crate::pool::shared(),
                )
            }
            _ => self
                .symbolic
                .factorize_numeric_llt(
                    target,
                    pattern.matrix(values),
                    Side::Lower,
                    LltRegularization::default(),
                    Par::Seq,
                    stack,
                    Default::default(),
                )
                .is_ok(),
        };
        if factored {
            if self.keep {
                std::mem::swap(&mut self.factor_values, &mut self.trial_values);
            }
            self.has_factor = true;
        }
        factored
    }

    /// `rhs = F^-1 rhs` with the kept factor `F` (which must exist): by [`tree_llt`]'s
    /// solve when its plan splits the tree (the two groups side by side on a pool, in
    /// turn on one thread: the same bits either way, as for the factor), else by
    /// faer's.
    fn apply_factor(
        symbolic: &SymbolicCholesky<usize>,
        permuted: &mut Option<PermutedMatrix>,
        factor_values: &[f64],
        solve_work: &mut MemBuffer,
        rhs: &mut [f64],
    ) {
        if let (Some(permuted), SymbolicCholeskyRaw::Supernodal(supernodal), Some(perm)) =
            (permuted.as_mut(), symbolic.raw(), symbolic.perm())
            && permuted.plan.splits()
        {
            // `perm[new] = old`: the solve runs in the factorization's order.
            let (order, _) = perm.arrays();
            let x = &mut permuted.solve_x;
            x.clear();
            x.extend(order.iter().map(|&old| rhs[old]));
            tree_llt::solve(
                supernodal,
                &permuted.plan,
                factor_values,
                x,
                &mut permuted.works,
                crate::pool::shared(),
            );
            for (&old, &v) in order.iter().zip(x.iter()) {
                rhs[old] = v;
            }
            return;
        }
        let llt = LltRef::new(symbolic, factor_values);
        let n = rhs.len();
        llt.solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(rhs, n, 1),
            Par::Seq,
            MemStack::new(solve_work),
        );
    }

    /// Factors the matrix (lower triangle `values` on `pattern`) and only that, for
    /// benchmarks of the numeric factorization. Returns whether it succeeded.
    pub fn factor_only(&mut self, pattern: &HessianPattern, values: &[f64]) -> bool {
        self.factor(pattern, values)
    }

    /// Solves `A x = rhs` in place if `A` factors as it is; returns false (and leaves
    /// `rhs` untouched, and the kept factor as it was) when it is not numerically
    /// positive definite.
    pub fn solve_unshifted(
        &mut self,
        pattern: &HessianPattern,
        values: &[f64],
        rhs: &mut [f64],
    ) -> bool {
        if !self.factor(pattern, values) {
            return false;
        }
        Self::apply_factor(
            &self.symbolic,
            &mut self.permuted,
            &self.factor_values,
            &mut self.solve_work,
            rhs,
        );
        true
    }

    /// Solves `A x = rhs` in place. On a failed factorization, retries with
    /// `A + sigma I`, sigma starting at `1e-10` times the largest diagonal entry and
    /// growing 1000-fold, at most four times. The factor that succeeded (of the shifted
    /// matrix, after a retry) is kept.
    pub fn solve(
        &mut self,
        pattern: &HessianPattern,
        values: &[f64],
        rhs: &mut [f64],
    ) -> DirectOutcome {
        let mut outcome = DirectOutcome::default();
        let max_diag = pattern
            .diag_slots
            .iter()
            .flat_map(|s| [s[0], s[3], s[5]])
            .map(|k| values[k].abs())
            .fold(0.0, f64::max);
        let mut sigma = 1e-10 * max_diag.max(f64::MIN_POSITIVE);
        loop {
            let factored = if outcome.shifts == 0 {
                self.factor(pattern, values)
            } else {
                let mut shifted = std::mem::take(&mut self.shifted_values);
                shifted.copy_from_slice(values);
                for s in &pattern.diag_slots {
                    for k in [s[0], s[3], s[5]] {
                        shifted[k] += sigma;
                    }
                }
                sigma *= 1e3;
                let factored = self.factor(pattern, &shifted);
                self.shifted_values = shifted;
                factored
            };
            if factored {
                Self::apply_factor(
                    &self.symbolic,
                    &mut self.permuted,
                    &self.factor_values,
                    &mut self.solve_work,
                    rhs,
                );
                return outcome;
            }
            if outcome.shifts < 4 {
                outcome.shifts += 1;
            } else {
                outcome.failed = true;
                return outcome;
            }
        }
    }

    /// Solves `A x = rhs` in place by conjugate gradients from zero, preconditioned by
    /// the kept factor (of an earlier, nearby matrix), to `|rhs - A x| <= rtol |rhs|`
    /// within `max_iterations` iterations. Only on [`KeptFactorStatus::Converged`] is
    /// `rhs` overwritten by the solution; otherwise it is left as it was.
    ///
    /// The preconditioned operator `F^-1/2 A F^-1/2` has the inertia of `A` (a
    /// congruence), so with `F` close to `A` its eigenvalues cluster near 1 and a few
    /// iterations suffice; a direction of non-positive curvature proves `A` is not
    /// positive definite. Every decision is a comparison of computed values, so the same
    /// inputs give the same iterations and bits.
    pub fn solve_with_kept_factor(
        &mut self,
        pattern: &HessianPattern,
        values: &[f64],
        rhs: &mut [f64],
        rtol: f64,
        max_iterations: usize,
    ) -> KeptFactorOutcome {
        let mut outcome = KeptFactorOutcome {
            iterations: 0,
            relative_residual: 1.0,
            status: KeptFactorStatus::NoFactor,
        };
        if !self.has_factor {
            return outcome;
        }
        let b_norm = dot(rhs, rhs).sqrt();
        if b_norm == 0.0 {
            outcome.relative_residual = 0.0;
            outcome.status = KeptFactorStatus::Converged;
            return outcome;
        }
        let [x, r, z, p, ap] = &mut self.cg;
        x.fill(0.0);
        r.copy_from_slice(rhs);
        z.copy_from_slice(rhs);
        Self::apply_factor(
            &self.symbolic,
            &mut self.permuted,
            &self.factor_values,
            &mut self.solve_work,
            z,
        );
        p.copy_from_slice(z);
        let mut rz = dot(r, z);
        outcome.status = KeptFactorStatus::OverBudget;
        while outcome.iterations < max_iterations {
            pattern.sym_matvec(values, p, ap);
            let pap = dot(p, ap);
            // NaN counts as non-positive curvature too.
            if pap.is_nan() || pap <= 0.0 {
                outcome.status = KeptFactorStatus::NonPositiveCurvature;
                break;
            }
            let alpha = rz / pap;
            for (((x, r), p), ap) in x.iter_mut().zip(r.iter_mut()).zip(&*p).zip(&*ap) {
                *x += alpha * p;
                *r -= alpha * ap;
            }
            outcome.iterations += 1;
            outcome.relative_residual = dot(r, r).sqrt() / b_norm;
            if outcome.relative_residual <= rtol {
                outcome.status = KeptFactorStatus::Converged;
                break;
            }
            if outcome.iterations >= max_iterations {
                break;
            }
            z.copy_from_slice(r);
            Self::apply_factor(
                &self.symbolic,
                &mut self.permuted,
                &self.factor_values,
                &mut self.solve_work,
                z,
            );
            let rz_new = dot(r, z);
            let beta = rz_new / rz;
            rz = rz_new;
            for (p, z) in p.iter_mut().zip(&*z) {
                *p = z + beta * *p;
            }
        }
        if outcome.status == KeptFactorStatus::Converged {
            rhs.copy_from_slice(x);
        }
        outcome
    }
}

/// What one PCG solve did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PcgOutcome {
    /// CG iterations.
    pub iterations: usize,
    /// Final `|r| / |b|` (Euclidean).
    pub relative_residual: f64,
    /// Whether a search direction of non-positive curvature was met (the matrix is not
    /// positive definite); the iterate before it is returned.
    pub negative_curvature: bool,
}

/// Unknowns per chunk of PCG's vector work on systems above [`PARALLEL_MIN`] (a
/// multiple of 3, so a chunk holds whole particles). The chunks are fixed by the
/// dimension alone, never by the thread count: each dot product is the sum, in chunk
/// order, of the chunks' sums (each summed in order), and every other operation is per
/// entry, so one thread, many, or the `parallel` feature off give bitwise the same
/// result. Small enough that two threads share W6's 30 603 unknowns evenly (20 chunks,
/// where 5 chunks of 6 144 left one thread a fifth of the work idle), large enough that a
/// chunk's dot product (1 536 multiply-adds) is far above the cost of handing it out.
pub const CHUNK: usize = 3 * 512;

/// Systems of at most this many unknowns (the 11 x 11 lab cloths: 357) are one chunk:
/// the column-ordered product, one sequential sum per dot product, the calling thread.
pub const PARALLEL_MIN: usize = 3 * 2048;

/// Block-Jacobi preconditioned conjugate gradients with owned buffers.
///
/// Systems above [`PARALLEL_MIN`] unknowns use a row-ordered product (each particle's
/// rows summed by that particle, so chunks of rows can be computed by different threads
/// with a fixed order of additions), and with the `parallel` feature their vector work
/// runs on a thread pool of [`PcgSolver::set_threads`] threads; smaller systems use the
/// column-ordered product on the stored lower triangle, on the calling thread.
#[derive(Debug, Default)]
pub struct PcgSolver {
    inverse_blocks: Vec<DMat3>,
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    ap: Vec<f64>,
    /// Unknowns per chunk: [`CHUNK`], or the whole system up to [`PARALLEL_MIN`].
    chunk: usize,
    /// Per-chunk partial sums of a dot product.
    partials: Vec<f64>,
    /// Per-chunk partial sums of two dot products computed in one pass.
    partials2: Vec<[f64; 2]>,
    /// Per-chunk partial sums of the three sums of a cold start's set-up.
    partials3: Vec<[f64; 3]>,
    /// The row-ordered product's index, for systems above [`PARALLEL_MIN`].
    rows: Option<RowProduct>,
    /// Whether a system of one chunk has a pool too, and whether it is in use (see
    /// [`PcgSolver::use_small_pool`]).
    small_too: bool,
    small_active: bool,
    /// The threads (none: the calling thread only).
    #[cfg(feature = "parallel")]
    pool: Option<std::sync::Arc<rayon::ThreadPool>>,
}

/// For the row-ordered product `y = A x`: per free particle `p`, the blocks above its
/// diagonal block, which the lower triangle stores in the columns of a particle `q < p`
/// (as the block `(p, q)`).
#[derive(Debug, Default)]
struct RowProduct {
    /// Particle `p`'s entries are `upper[upper_ptr[p]..upper_ptr[p + 1]]`.
    upper_ptr: Vec<usize>,
    /// `(q, [s0, s1, s2])`: the block `(p, q)` is the `k`-th neighbour block of column
    /// particle `q`, and its column `3 q + c` starts at `values[sc]`. The starts are found
    /// once here, so the product reads no `col_ptr` entry of `q` per block.
    upper: Vec<(usize, [usize; 3])>,
    /// Particle `p`'s neighbours below it are `lower[lower_ptr[p]..lower_ptr[p + 1]]`,
    /// in the order of its columns' blocks: one index per 3x3 block instead of the
    /// pattern's one per entry, so the product reads a ninth of the indices.
    lower_ptr: Vec<usize>,
    /// Each neighbour `q` below the diagonal (its unknowns are `3 q..3 q + 3`).
    lower: Vec<usize>,
}

impl RowProduct {
    fn new(pattern: &HessianPattern) -> Self {
        let particles = pattern.free_particles.len();
        let col_ptr = pattern.symbolic.col_ptr();
        let row_idx = pattern.symbolic.row_idx();
        let mut lists: Vec<Vec<(usize, [usize; 3])>> = vec![Vec::new(); particles];
        let mut lower_ptr = Vec::with_capacity(particles + 1);
        lower_ptr.push(0);
        let mut lower = Vec::with_capacity(row_idx.len() / 9);
        for q in 0..particles {
            let start = col_ptr[3 * q] + 3;
            for (k, &row) in row_idx[start..col_ptr[3 * q + 1]]
                .iter()
                .step_by(3)
                .enumerate()
            {
                let start_of = |c: usize| col_ptr[3 * q + c] + (3 - c) + 3 * k;
                lists[row / 3].push((q, [start_of(0), start_of(1), start_of(2)]));
                lower.push(row / 3);
            }
            lower_ptr.push(lower.len());
        }
        let mut upper_ptr = Vec::with_capacity(particles + 1);
        upper_ptr.push(0);
        let mut upper = Vec::new();
        for list in lists {
            upper.extend(list);
            upper_ptr.push(upper.len());
        }
        Self {
            upper_ptr,
            upper,
            lower_ptr,
            lower,
        }
    }

    /// Writes the rows of particles `first..first + y.len() / 3` of `A x` into `y`.
    fn apply_rows(
        &self,
        pattern: &HessianPattern,
        values: &[f64],
        x: &[f64],
        first: usize,
        y: &mut [f64],
    ) {
        let col_ptr = pattern.symbolic.col_ptr();
        // `x` by particle: a neighbour's three entries are one bounds check on its
        // index, where a range of three needed an overflow check and two bounds checks.
        let (xs, _) = x.as_chunks::<3>();
        for (offset, yp) in y.chunks_exact_mut(3).enumerate() {
            let p = first + offset;
            let below = &self.lower[self.lower_ptr[p]..self.lower_ptr[p + 1]];
            // Row 3p + c's sum is one chain of additions in a fixed order: its diagonal
            // block's three entries, then the blocks below the diagonal in column 3p + c
            // (the transposes of the blocks right of the diagonal in p's rows), three
            // entries per neighbour in the stored order, then the blocks left of the
            // diagonal. The three rows' chains are advanced side by side, a neighbour at
            // a time: each chain's order is unchanged (so are the bits), but the three
            // are independent, so the processor overlaps them instead of waiting on one
            // addition after another, and each neighbour's `x` is read once, not thrice.
            let (s0, s1, s2) = (col_ptr[3 * p], col_ptr[3 * p + 1], col_ptr[3 * p + 2]);
            let end = col_ptr[3 * p + 3];
            let xp = xs[p];
            let (d00, d10, d20) = (values[s0], values[s0 + 1], values[s0 + 2]);
            let (d11, d21, d22) = (values[s1], values[s1 + 1], values[s2]);
            let mut acc = [0.0f64; 3];
            acc[0] += d00 * xp[0];
            acc[1] += d10 * xp[0];
            acc[0] += d10 * xp[1];
            acc[2] += d20 * xp[0];
            acc[0] += d20 * xp[2];
            acc[1] += d11 * xp[1];
            acc[2] += d21 * xp[1];
            acc[1] += d21 * xp[2];
            acc[2] += d22 * xp[2];
            // Column 3p + c's neighbour blocks start `3 - c` entries past its start.
            let blocks0 = &values[s0 + 3..s1];
            let blocks1 = &values[s1 + 2..s2];
            let blocks2 = &values[s2 + 1..end];
            for (((v0, v1), v2), &q) in blocks0
                .chunks_exact(3)
                .zip(blocks1.chunks_exact(3))
                .zip(blocks2.chunks_exact(3))
                .zip(below)
            {
                let xr = xs[q];
                acc[0] += v0[0] * xr[0];
                acc[1] += v1[0] * xr[0];
                acc[2] += v2[0] * xr[0];
                acc[0] += v0[1] * xr[1];
                acc[1] += v1[1] * xr[1];
                acc[2] += v2[1] * xr[1];
                acc[0] += v0[2] * xr[2];
                acc[1] += v1[2] * xr[2];
                acc[2] += v2[2] * xr[2];
            }
            // The blocks left of the diagonal: stored as the block (p, q) in q's columns.
            for (q, starts) in &self.upper[self.upper_ptr[p]..self.upper_ptr[p + 1]] {
                for (xq, &start) in xs[*q].iter().zip(starts) {
                    for (a, v) in acc.iter_mut().zip(&values[start..start + 3]) {
                        *a += v * xq;
                    }
                }
            }
            yp.copy_from_slice(&acc);
        }
    }
}

impl PcgSolver {
    /// Buffers for `pattern`'s dimension, on the calling thread.
    #[must_use]
    pub fn new(pattern: &HessianPattern) -> Self {
        let n = pattern.dim();
        Self {
            inverse_blocks: vec![DMat3::IDENTITY; n / 3],
            r: vec![0.0; n],
            z: vec![0.0; n],
            p: vec![0.0; n],
            ap: vec![0.0; n],
            chunk: if n > PARALLEL_MIN { CHUNK } else { n.max(3) },
            partials: Vec::new(),
            partials2: Vec::new(),
            partials3: Vec::new(),
            rows: (n > PARALLEL_MIN).then(|| RowProduct::new(pattern)),
            small_too: false,
            small_active: false,
            #[cfg(feature = "parallel")]
            pool: None,
        }
    }

    /// Whether the solver takes a thread pool: its system is above [`PARALLEL_MIN`]
    /// unknowns (its vector work is cut in chunks), or it was asked to take one
    /// whatever its size ([`Self::use_small_pool`]).
    #[cfg(feature = "parallel")]
    fn spreads(&self) -> bool {
        self.rows.is_some() || self.small_too
    }

    /// Whether a system of one chunk runs the integrator's passes on a pool of
    /// `threads` threads (see [`Self::set_threads`]): `on` for a step whose terms have
    /// work that grows with something other than the particles (self-contact's pairs),
    /// off otherwise, where the hand-offs would cost more than they share. The pool is
    /// built the first time it is asked for and kept; PCG's own solves stay on the
    /// calling thread. Nothing for a system above [`PARALLEL_MIN`] unknowns, whose pool
    /// is always in use. An error if the pool cannot be built, and the solver is then as
    /// it was.
    pub(crate) fn use_small_pool(&mut self, threads: usize, on: bool) -> Result<(), SolverError> {
        if self.rows.is_some() {
            return Ok(());
        }
        if on && !self.small_too {
            self.small_too = true;
            if let Err(error) = self.set_threads(threads) {
                self.small_too = false;
                return Err(error);
            }
        }
        self.small_active = on;
        Ok(())
    }

    /// Spreads the work of systems above [`PARALLEL_MIN`] unknowns over `threads`
    /// threads (0: one per core). The result does not depend on it (see [`CHUNK`]). Without the
    /// `parallel` feature everything runs on the calling thread. An error if the thread
    /// pool cannot be built. A smaller system gets none unless
    /// [`Self::use_small_pool`] asked for one.
    pub fn set_threads(&mut self, threads: usize) -> Result<(), SolverError> {
        #[cfg(feature = "parallel")]
        {
            let count = if threads == 0 {
                std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
            } else {
                threads
            };
            self.pool = if count > 1 && self.spreads() {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(count)
                    .build()
                    .map_err(|e| SolverError::thread_pool(count, e))?;
                Some(std::sync::Arc::new(pool))
            } else {
                None
            };
        }
        #[cfg(not(feature = "parallel"))]
        let _ = threads;
        Ok(())
    }

    /// Runs on `previous`'s threads, sharing its thread pool instead of starting one
    /// (a pattern widened during a run, possibly a few times a step, gets a new solver
    /// each time), when the two split their work alike (both above [`PARALLEL_MIN`]
    /// unknowns or both not, as for one system's patterns, which differ only in their
    /// coupled pairs); a small system's pool asked for by
    /// [`PcgSolver::use_small_pool`] is shared too, in use or not as there. False, and
    /// nothing changes, when they do not: then [`PcgSolver::set_threads`] is the way.
    pub fn share_threads(&mut self, previous: &PcgSolver) -> bool {
        if self.rows.is_some() != previous.rows.is_some() {
            return false;
        }
        self.small_too = previous.small_too;
        self.small_active = previous.small_active;
        #[cfg(feature = "parallel")]
        {
            self.pool = previous.pool.clone();
        }
        true
    }

    /// Whether the system is above [`PARALLEL_MIN`] unknowns, so its work is cut in
    /// chunks (and spread over the thread pool, when there is one).
    #[cfg(feature = "parallel")]
    #[must_use]
    pub(crate) fn is_chunked(&self) -> bool {
        self.rows.is_some()
    }

    /// The thread pool, when the work is spread over more than one thread (for a system
    /// of one chunk, the integrator's passes only, and only while in use, see
    /// [`Self::use_small_pool`]).
    #[cfg(feature = "parallel")]
    pub(crate) fn pool(&self) -> Option<&std::sync::Arc<rayon::ThreadPool>> {
        self.pool
            .as_ref()
            .filter(|_| self.rows.is_some() || self.small_active)
    }

    /// The threads of the solver's pool in use (1: the calling thread only). PCG's
    /// vector work runs on them above [`PARALLEL_MIN`] unknowns; below, only the
    /// integrator's passes that take [`Self::pool`], while it is in use.
    #[must_use]
    pub fn threads(&self) -> usize {
        #[cfg(feature = "parallel")]
        if let Some(pool) = self.pool() {
            return pool.current_num_threads();
        }
        1
    }

    /// Solves `A x = b` to `|b - A x| <= rtol |b|` or `max_iterations`, starting from the
    /// `x` given (a warm start; zeros for none).
    pub fn solve(
        &mut self,
        pattern: &HessianPattern,
        values: &[f64],
        b: &[f64],
        x: &mut [f64],
        rtol: f64,
        max_iterations: usize,
    ) -> PcgOutcome {
        #[cfg(feature = "parallel")]
        if let Some(pool) = self.pool.clone().filter(|_| self.rows.is_some()) {
            return pool
                .install(|| self.solve_on(true, pattern, values, b, x, rtol, max_iterations));
        }
        self.solve_on(false, pattern, values, b, x, rtol, max_iterations)
    }

    /// PCG's iterations with the vector work fused into three passes over the chunks
    /// per iteration (the product with its dot product; the updates of `x` and `r` with
    /// the preconditioner and both dot products of `r`; the update of `p`), each a
    /// single parallel region when `par`: every region costs a hand-off to the pool and
    /// a wait for its slowest chunk, which on W6 weighed as much as the work itself
    /// when there were seven per iteration. The arithmetic is entry for entry the
    /// unfused loop's, and each dot product is still the in-order sum of the chunks'
    /// in-order sums.
    #[allow(clippy::too_many_arguments)]
    fn solve_on(
        &mut self,
        par: bool,
        pattern: &HessianPattern,
        values: &[f64],
        b: &[f64],
        x: &mut [f64],
        rtol: f64,
        max_iterations: usize,
    ) -> PcgOutcome {
        let size = self.chunk;
        // The usual cold start (every Newton direction starts from zero): `A 0 = 0`, so
        // the residual is `b` itself and the product, a fifth to a third of the products
        // of a solve that ends in a few iterations, is skipped. `b - 0` is `b` bit for
        // bit, so the iterates are the same as with it. Then nothing of the set-up needs
        // another chunk's data, and its two passes are one region: each chunk inverts
        // its diagonal blocks, sums its share of `|b|^2`, sets `r = b`, `z = P^-1 r`,
        // `p = z` and sums its shares of `r . r` and `r . z`, the same operations on the
        // same chunks as the two passes of a warm start.
        let cold = x.iter().all(|v| *v == 0.0);
        let (b_norm, rr, rz) = if cold {
            let [bb, rr, rz] = self.cold_setup(par, pattern, values, b);
            (bb.sqrt(), rr, rz)
        } else {
            self.warm_setup(par, pattern, values, b, x)
        };
        if b_norm == 0.0 {
            x.fill(0.0);
            return PcgOutcome::default();
        }
        let mut rz = rz;
        let mut r_norm = rr.sqrt();
        let mut iterations = 0;
        let mut negative_curvature = false;
        while r_norm > rtol * b_norm && iterations < max_iterations {
            let pap = self.product_dot(par, pattern, values);
            // NaN counts as non-positive curvature too.
            if pap.is_nan() || pap <= 0.0 {
                negative_curvature = true;
                break;
            }
            let alpha = rz / pap;
            let (p, ap, inverse) = (&self.p, &self.ap, &self.inverse_blocks);
            chunks3(
                par,
                size,
                [&mut *x, &mut self.r, &mut self.z],
                &mut self.partials2,
                |first, [x, r, z]| {
                    let range = first..first + x.len();
                    for (((x, r), p), ap) in x
                        .iter_mut()
                        .zip(r.iter_mut())
                        .zip(&p[range.clone()])
                        .zip(&ap[range])
                    {
                        *x += alpha * p;
                        *r -= alpha * ap;
                    }
                    precondition(inverse, first, r, z);
                    dot2(r, z)
                },
            );
            iterations += 1;
            let [rr, rz_new] = ordered_sum2(&self.partials2);
            r_norm = rr.sqrt();
            if r_norm <= rtol * b_norm || iterations >= max_iterations {
                // The loop ends here: the next direction would never be used.
                break;
            }
            let beta = rz_new / rz;
            rz = rz_new;
            let z = &self.z;
            chunks_mut(par, &mut self.p, size, |first, p| {
                let z = &z[first..first + p.len()];
                for (p, z) in p.iter_mut().zip(z) {
                    *p = z + beta * *p;
                }
            });
        }
        PcgOutcome {
            iterations,
            relative_residual: r_norm / b_norm,
            negative_curvature,
        }
    }

    /// The set-up of a warm start (`x` not zero) in two passes: the block inverses with
    /// `|b|^2`, then (unless `b` is zero) `r = b - A x`, `z = P^-1 r`, `p = z` with
    /// `r . r` and `r . z`. Returns `(|b|, r . r, r . z)`, `|b| = 0` alone when `b` is
    /// zero.
    fn warm_setup(
        &mut self,
        par: bool,
        pattern: &HessianPattern,
        values: &[f64],
        b: &[f64],
        x: &[f64],
    ) -> (f64, f64, f64) {
        let size = self.chunk;
        // The block inverses, with |b|^2 (chunks of `size / 3` blocks are the chunks of
        // `size` unknowns).
        chunks1(
            par,
            size / 3,
            &mut self.inverse_blocks,
            &mut self.partials,
            |first, blocks| {
                invert_diagonal_blocks(pattern, values, first, blocks);
                let piece = &b[3 * first..3 * (first + blocks.len())];
                dot(piece, piece)
            },
        );
        let b_norm = ordered_sum(&self.partials).sqrt();
        if b_norm == 0.0 {
            return (0.0, 0.0, 0.0);
        }
        self.product(par, pattern, values, x);
        let (inverse, ap) = (&self.inverse_blocks, &self.ap);
        chunks3(
            par,
            size,
            [&mut self.r, &mut self.z, &mut self.p],
            &mut self.partials2,
            |first, [r, z, p]| {
                let b = &b[first..first + r.len()];
                for ((r, b), ap) in r.iter_mut().zip(b).zip(&ap[first..first + b.len()]) {
                    *r = b - ap;
                }
                precondition(inverse, first, r, z);
                p.copy_from_slice(z);
                dot2(r, z)
            },
        );
        let [rr, rz] = ordered_sum2(&self.partials2);
        (b_norm, rr, rz)
    }

    /// The set-up of a cold start (`x` zero) in one pass over the chunks (see
    /// [`Self::solve_on`]): returns `[|b|^2, r . r, r . z]`, each the in-order sum of
    /// the chunks' in-order sums, as the two passes of [`Self::warm_setup`] give them.
    fn cold_setup(
        &mut self,
        par: bool,
        pattern: &HessianPattern,
        values: &[f64],
        b: &[f64],
    ) -> [f64; 3] {
        let size = self.chunk;
        let chunk = |k: usize, inverse: &mut [DMat3], [r, z, p]: [&mut [f64]; 3]| {
            let first = k * size;
            invert_diagonal_blocks(pattern, values, first / 3, inverse);
            let b = &b[first..first + r.len()];
            let bb = dot(b, b);
            r.copy_from_slice(b);
            precondition(inverse, 0, r, z);
            p.copy_from_slice(z);
            let [rr, rz] = dot2(r, z);
            [bb, rr, rz]
        };
        let partials = &mut self.partials3;
        #[cfg(feature = "parallel")]
        if par {
            use rayon::prelude::*;
            self.inverse_blocks
                .par_chunks_mut(size / 3)
                .zip(self.r.par_chunks_mut(size))
                .zip(self.z.par_chunks_mut(size))
                .zip(self.p.par_chunks_mut(size))
                .enumerate()
                .map(|(k, (((inv, r), z), p))| chunk(k, inv, [r, z, p]))
                .collect_into_vec(partials);
            return ordered_sum3(partials);
        }
        let _ = par;
        partials.clear();
        partials.extend(
            self.inverse_blocks
                .chunks_mut(size / 3)
                .zip(self.r.chunks_mut(size))
                .zip(self.z.chunks_mut(size))
                .zip(self.p.chunks_mut(size))
                .enumerate()
                .map(|(k, (((inv, r), z), p))| chunk(k, inv, [r, z, p])),
        );
        ordered_sum3(partials)
    }

    /// `ap = A x`.
    fn product(&mut self, par: bool, pattern: &HessianPattern, values: &[f64], x: &[f64]) {
        match &self.rows {
            Some(rows) => chunks_mut(par, &mut self.ap, self.chunk, |first, y| {
                rows.apply_rows(pattern, values, x, first / 3, y);
            }),
            None => pattern.sym_matvec(values, x, &mut self.ap),
        }
    }

    /// `ap = A p`, returning `p . ap` (each chunk's rows and their share of the dot
    /// product in one pass).
    fn product_dot(&mut self, par: bool, pattern: &HessianPattern, values: &[f64]) -> f64 {
        let p = &self.p;
        match &self.rows {
            Some(rows) => chunks1(
                par,
                self.chunk,
                &mut self.ap,
                &mut self.partials,
                |first, y| {
                    rows.apply_rows(pattern, values, p, first / 3, y);
                    dot(&p[first..first + y.len()], y)
                },
            ),
            None => {
                pattern.sym_matvec(values, p, &mut self.ap);
                self.partials.clear();
                self.partials.push(dot(p, &self.ap));
            }
        }
        ordered_sum(&self.partials)
    }
}

/// The inverses of the diagonal blocks `first..first + inverse.len()` of the matrix
/// `values` on `pattern` into `inverse` (the identity for a block that is not positive
/// definite).
fn invert_diagonal_blocks(
    pattern: &HessianPattern,
    values: &[f64],
    first: usize,
    inverse: &mut [DMat3],
) {
    for (i, inv) in inverse.iter_mut().enumerate() {
        let block = pattern.diag_block(values, first + i);
        // The diagonal blocks of an SPD matrix are SPD; the guard keeps a NaN out if a
        // caller passes something else.
        let d = block.determinant();
        *inv = if d.is_finite() && d > 0.0 {
            block.inverse()
        } else {
            DMat3::IDENTITY
        };
    }
}

/// `z = P^-1 r` on the chunk of unknowns starting at `first`, block by block.
fn precondition(inverse: &[DMat3], first: usize, r: &[f64], z: &mut [f64]) {
    let inverse = &inverse[first / 3..first / 3 + r.len() / 3];
    for ((z, r), inv) in z.chunks_exact_mut(3).zip(r.chunks_exact(3)).zip(inverse) {
        let v = inv.mul_vec3(DVec3::new(r[0], r[1], r[2]));
        z[0] = v.x;
        z[1] = v.y;
        z[2] = v.z;
    }
}

/// The sum of per-chunk partial sums, in chunk order.
fn ordered_sum(partials: &[f64]) -> f64 {
    partials.iter().sum()
}

/// [`ordered_sum`] of three sums' partial sums at once.
fn ordered_sum3(partials: &[[f64; 3]]) -> [f64; 3] {
    [
        partials.iter().map(|p| p[0]).sum(),
        partials.iter().map(|p| p[1]).sum(),
        partials.iter().map(|p| p[2]).sum(),
    ]
}

/// [`ordered_sum`] of two dot products' partial sums at once.
fn ordered_sum2(partials: &[[f64; 2]]) -> [f64; 2] {
    [
        partials.iter().map(|p| p[0]).sum(),
        partials.iter().map(|p| p[1]).sum(),
    ]
}

/// Calls `f(first, chunk)` on `data` cut in chunks of `size` (`first`: the index of the
/// chunk's first element), on the current thread pool when `par`, and collects the
/// results in chunk order into `out`.
fn chunks1<T: Send, S: Send>(
    par: bool,
    size: usize,
    data: &mut [T],
    out: &mut Vec<S>,
    f: impl Fn(usize, &mut [T]) -> S + Sync + Send,
) {
    #[cfg(feature = "parallel")]
    if par {
        use rayon::prelude::*;
        data.par_chunks_mut(size)
            .enumerate()
            .map(|(c, chunk)| f(c * size, chunk))
            .collect_into_vec(out);
        return;
    }
    let _ = par;
    out.clear();
    out.extend(
        data.chunks_mut(size)
            .enumerate()
            .map(|(c, chunk)| f(c * size, chunk)),
    );
}

/// [`chunks1`] over three slices of the same length at once.
fn chunks3<S: Send>(
    par: bool,
    size: usize,
    [a, b, c]: [&mut [f64]; 3],
    out: &mut Vec<S>,
    f: impl Fn(usize, [&mut [f64]; 3]) -> S + Sync + Send,
) {
    #[cfg(feature = "parallel")]
    if par {
        use rayon::prelude::*;
        a.par_chunks_mut(size)
            .zip(b.par_chunks_mut(size))
            .zip(c.par_chunks_mut(size))
            .enumerate()
            .map(|(k, ((a, b), c))| f(k * size, [a, b, c]))
            .collect_into_vec(out);
        return;
    }
    let _ = par;
    out.clear();
    out.extend(
        a.chunks_mut(size)
            .zip(b.chunks_mut(size))
            .zip(c.chunks_mut(size))
            .enumerate()
            .map(|(k, ((a, b), c))| f(k * size, [a, b, c])),
    );
}

/// Calls `f(first, chunk)` on `data` cut in chunks of `size` (`first`: the index of the
/// chunk's first element), on the current thread pool when `par`.
fn chunks_mut<T: Send>(
    par: bool,
    data: &mut [T],
    size: usize,
    f: impl Fn(usize, &mut [T]) + Sync + Send,
) {
    #[cfg(feature = "parallel")]
    if par {
        use rayon::prelude::*;
        data.par_chunks_mut(size)
            .enumerate()
            .for_each(|(c, chunk)| f(c * size, chunk));
        return;
    }
    let _ = par;
    for (c, chunk) in data.chunks_mut(size).enumerate() {
        f(c * size, chunk);
    }
}

/// `[r . r, r . z]` in one pass: each the in-order sum [`dot`] makes (from the same
/// starting value), as two independent chains of additions the processor overlaps.
fn dot2(r: &[f64], z: &[f64]) -> [f64; 2] {
    let start: f64 = std::iter::empty::<f64>().sum();
    r.iter()
        .zip(z)
        .fold([start, start], |[rr, rz], (r, z)| [rr + r * r, rz + r * z])
}

/// Euclidean dot product.
#[must_use]
pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{ClothGrid, SpringSystem};
    use crate::newton::newton_matrix_triplets;

    /// The Newton matrix of a stretched `n x n` lab-pattern cloth (spacing `spacing`)
    /// at step 1/60: its pattern, values and dense lower-triangle triplets.
    fn stretched(n: usize, spacing: f64) -> (HessianPattern, Vec<f64>, Vec<(usize, usize, f64)>) {
        stretched_by(n, spacing, 1.2)
    }

    /// [`stretched`] with the positions scaled by `factor` instead of 1.2.
    fn stretched_by(
        n: usize,
        spacing: f64,
        factor: f64,
    ) -> (HessianPattern, Vec<f64>, Vec<(usize, usize, f64)>) {
        let mut system =
            SpringSystem::cloth(&ClothGrid::lab_sized(n, spacing).with_damping(0.2)).unwrap();
        let x: Vec<sinew_math::DVec3> = system
            .positions()
            .iter()
            .enumerate()
            .map(|(i, p)| *p * factor + sinew_math::DVec3::new(0.0, 0.01 * (i as f64).sin(), 0.0))
            .collect();
        let v = vec![sinew_math::DVec3::ZERO; x.len()];
        system.set_state(&x, &v).unwrap();
        let pattern = HessianPattern::new(&system);
        let triplets = newton_matrix_triplets(&system, 1.0 / 60.0);
        let values: Vec<f64> = triplets.iter().map(|t| t.2).collect();
        assert_eq!(pattern.symbolic.col_ptr()[pattern.dim()], triplets.len());
        (pattern, values, triplets)
    }

    /// `|b - A x| / |b|` from the dense triplets.
    fn relative_residual(triplets: &[(usize, usize, f64)], b: &[f64], x: &[f64]) -> f64 {
        let mut r = b.to_vec();
        for &(i, j, value) in triplets {
            r[i] -= value * x[j];
            if i != j {
                r[j] -= value * x[i];
            }
        }
        (dot(&r, &r) / dot(b, b)).sqrt()
    }

    /// PCG's fused passes give bitwise the same iterates on one thread and on two or
    /// three (chunks of [`CHUNK`] unknowns, the last one short), from a cold and from a
    /// warm start, and the answer meets the asked residual by an independent check.
    #[test]
    fn pcg_is_bitwise_the_same_on_one_two_and_three_threads() {
        // 46 x 46: 6 342 unknowns, just above `PARALLEL_MIN`, chunks of 1 536 and a last
        // one of 198; 61 x 61: 11 157 unknowns, 8 chunks.
        for (n, spacing) in [(46, 0.04), (61, 0.03)] {
            let (pattern, values, triplets) = stretched(n, spacing);
            let dim = pattern.dim();
            assert!(dim > PARALLEL_MIN && dim % CHUNK != 0, "{dim}");
            let b: Vec<f64> = (0..dim)
                .map(|i| ((i * 7919) % 1000) as f64 / 500.0 - 1.0)
                .collect();
            let warm: Vec<f64> = (0..dim).map(|i| 1e-3 * ((i * 31) % 17) as f64).collect();
            for start in [vec![0.0; dim], warm] {
                let mut answers = Vec::new();
                for threads in [1, 2, 3] {
                    let mut solver = PcgSolver::new(&pattern);
                    solver.set_threads(threads).unwrap();
                    // Without the `parallel` feature every solver runs on the calling
                    // thread, and the comparison still checks its answers agree.
                    let expected = if cfg!(feature = "parallel") {
                        threads
                    } else {
                        1
                    };
                    assert_eq!(solver.threads(), expected);
                    let mut x = start.clone();
                    let outcome = solver.solve(&pattern, &values, &b, &mut x, 1e-10, 500);
                    assert!(!outcome.negative_curvature);
                    assert!(outcome.relative_residual <= 1e-10, "{outcome:?}");
                    let check = relative_residual(&triplets, &b, &x);
                    assert!(check <= 2e-10, "{n}: independent residual {check}");
                    answers.push((outcome.iterations, x));
                }
                assert!(answers[0].0 > 5, "{n}: {} iterations", answers[0].0);
                for (threads, answer) in [2, 3].iter().zip(&answers[1..]) {
                    assert_eq!(answer.0, answers[0].0, "{n}, {threads} threads: iterations");
                    assert!(
                        answer
                            .1
                            .iter()
                            .zip(&answers[0].1)
                            .all(|(a, b)| a.to_bits() == b.to_bits()),
                        "{n}, {threads} threads: the solution differs"
                    );
                }
            }
        }
    }

    /// A solver for a widened pattern shares its predecessor's thread pool (the same
    /// pool, not a new one of the same size) and then solves bitwise as one with a pool
    /// of its own; a solver that splits its work differently (below [`PARALLEL_MIN`])
    /// is refused and keeps none.
    #[cfg(feature = "parallel")]
    #[test]
    fn a_widened_patterns_solver_shares_the_thread_pool() {
        let (pattern, values, _) = stretched(46, 0.04);
        let mut first = PcgSolver::new(&pattern);
        first.set_threads(2).unwrap();
        let mut shared = PcgSolver::new(&pattern);
        assert!(shared.share_threads(&first));
        assert_eq!(shared.threads(), 2);
        assert!(std::sync::Arc::ptr_eq(
            first.pool().unwrap(),
            shared.pool().unwrap()
        ));
        let b = rhs(pattern.dim());
        let mut answers = Vec::new();
        for solver in [&mut first, &mut shared] {
            let mut x = vec![0.0; pattern.dim()];
            let outcome = solver.solve(&pattern, &values, &b, &mut x, 1e-10, 500);
            assert!(outcome.relative_residual <= 1e-10 && outcome.iterations > 5);
            answers.push(x);
        }
        assert!(
            answers[0]
                .iter()
                .zip(&answers[1])
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
        let (small, _, _) = stretched(11, 0.1);
        let mut other = PcgSolver::new(&small);
        assert!(!other.share_threads(&first));
        assert!(other.pool().is_none());
        assert_eq!(other.threads(), 1);
    }

    /// The row-ordered product of a system above one chunk equals the column-ordered one
    /// (on the stored lower triangle) and a product with the dense triplets, to round-off.
    #[test]
    fn the_row_ordered_product_matches_the_column_ordered_one() {
        // 61 x 61, stretched and bent so every block is full: 11 157 unknowns.
        let (pattern, values, triplets) = stretched(61, 0.03);
        let n = pattern.dim();
        assert!(n > PARALLEL_MIN);
        let input: Vec<f64> = (0..n)
            .map(|i| ((i * 7919) % 1000) as f64 / 500.0 - 1.0)
            .collect();
        let mut column = vec![0.0; n];
        pattern.sym_matvec(&values, &input, &mut column);
        let mut solver = PcgSolver::new(&pattern);
        solver.product(false, &pattern, &values, &input);
        let mut dense = vec![0.0; n];
        for &(r, c, value) in &triplets {
            dense[r] += value * input[c];
            if r != c {
                dense[c] += value * input[r];
            }
        }
        let scale = column.iter().fold(0.0f64, |m, y| m.max(y.abs()));
        for i in 0..n {
            assert!((solver.ap[i] - column[i]).abs() <= 1e-13 * scale, "row {i}");
            assert!((solver.ap[i] - dense[i]).abs() <= 1e-13 * scale, "row {i}");
        }
    }

    /// The product by a particle's three columns at once is the entry-by-entry product
    /// of the stored lower triangle (each column's diagonal entry, then its entries below
    /// in storage order, each adding to its row and to the column's sum) bit for bit.
    #[test]
    fn the_blocked_product_is_the_entry_by_entry_one_bit_for_bit() {
        for (size, stretch) in [(5, 0.1), (61, 0.03)] {
            let (pattern, values, _) = stretched(size, stretch);
            let n = pattern.dim();
            let input: Vec<f64> = (0..n)
                .map(|i| ((i * 7919) % 1000) as f64 / 500.0 - 1.0)
                .collect();
            let (col_ptr, row_idx) = (pattern.symbolic.col_ptr(), pattern.symbolic.row_idx());
            let mut entry_by_entry = vec![0.0; n];
            for j in 0..n {
                let mut acc = values[col_ptr[j]] * input[j];
                for k in col_ptr[j] + 1..col_ptr[j + 1] {
                    let i = row_idx[k];
                    entry_by_entry[i] += values[k] * input[j];
                    acc += values[k] * input[i];
                }
                entry_by_entry[j] += acc;
            }
            let mut blocked = vec![f64::NAN; n];
            pattern.sym_matvec(&values, &input, &mut blocked);
            let bits = |v: &[f64]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&blocked), bits(&entry_by_entry), "{size}");
            assert!(blocked.iter().any(|v| *v != 0.0));
        }
    }

    /// A right-hand side with every entry non-zero.
    fn rhs(dim: usize) -> Vec<f64> {
        (0..dim)
            .map(|i| ((i * 7919) % 1000) as f64 / 500.0 - 1.0)
            .collect()
    }

    /// Conjugate gradients preconditioned by the factor of one Newton matrix solve a
    /// nearby one (the sheet stretched a little further) to the asked residual, checked
    /// independently and against a fresh factorization of that matrix, bitwise the same
    /// twice; the factor survives a failed factorization; no factor, an exhausted budget
    /// and an indefinite matrix leave the right-hand side untouched.
    #[test]
    fn the_kept_factor_solves_a_nearby_matrix_to_the_direct_answer() {
        let (pattern, old, _) = stretched_by(21, 0.05, 1.2);
        let (_, new, triplets) = stretched_by(21, 0.05, 1.25);
        let dim = pattern.dim();
        let b = rhs(dim);
        let mut solver = DirectSolver::new(&pattern, FactorStructure::Supernodal).unwrap();
        solver.set_keep_factor(true);
        let mut x = b.clone();
        let none = solver.solve_with_kept_factor(&pattern, &new, &mut x, 1e-12, 100);
        assert_eq!(none.status, KeptFactorStatus::NoFactor);
        assert_eq!(x, b);
        let mut scratch = b.clone();
        assert_eq!(
            solver.solve(&pattern, &old, &mut scratch),
            DirectOutcome::default()
        );
        assert!(solver.has_factor());
        let mut answers = Vec::new();
        for _ in 0..2 {
            let mut x = b.clone();
            let outcome = solver.solve_with_kept_factor(&pattern, &new, &mut x, 1e-12, 100);
            assert_eq!(outcome.status, KeptFactorStatus::Converged, "{outcome:?}");
            assert!(outcome.relative_residual <= 1e-12);
            // A different matrix: more than one iteration, yet far fewer than block
            // Jacobi needs.
            assert!(
                (2..30).contains(&outcome.iterations),
                "{} iterations",
                outcome.iterations
            );
            let check = relative_residual(&triplets, &b, &x);
            assert!(check <= 2e-12, "independent residual {check}");
            answers.push((outcome.iterations, x));
        }
        assert_eq!(answers[0].0, answers[1].0);
        assert!(
            answers[0]
                .1
                .iter()
                .zip(&answers[1].1)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
        let mut fresh = DirectSolver::new(&pattern, FactorStructure::Supernodal).unwrap();
        let mut direct = b.clone();
        assert!(fresh.solve_unshifted(&pattern, &new, &mut direct));
        let scale = direct.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (kept, exact) in answers[0].1.iter().zip(&direct) {
            assert!(
                (kept - exact).abs() <= 1e-9 * scale,
                "{kept} against {exact}"
            );
        }
        // A matrix that is not positive definite: the factorization fails and leaves the
        // kept factor as it was; the preconditioned solve proves it indefinite.
        let negated: Vec<f64> = new.iter().map(|v| -v).collect();
        let mut x = b.clone();
        assert!(!solver.solve_unshifted(&pattern, &negated, &mut x));
        assert_eq!(x, b);
        assert!(solver.has_factor());
        let outcome = solver.solve_with_kept_factor(&pattern, &negated, &mut x, 1e-12, 100);
        assert_eq!(outcome.status, KeptFactorStatus::NonPositiveCurvature);
        assert_eq!(x, b);
        let mut again = b.clone();
        let outcome = solver.solve_with_kept_factor(&pattern, &new, &mut again, 1e-12, 100);
        assert_eq!(outcome.iterations, answers[0].0);
        assert!(
            again
                .iter()
                .zip(&answers[0].1)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
        // One iteration is not enough for this matrix.
        let outcome = solver.solve_with_kept_factor(&pattern, &new, &mut x, 1e-12, 1);
        assert_eq!(outcome.status, KeptFactorStatus::OverBudget);
        assert_eq!(outcome.iterations, 1);
        assert_eq!(x, b);
        solver.forget_factor();
        let outcome = solver.solve_with_kept_factor(&pattern, &new, &mut x, 1e-12, 100);
        assert_eq!(outcome.status, KeptFactorStatus::NoFactor);
    }

    /// The supernodal factorization of the matrix written straight into the ordering's
    /// positions through the slot map (and factored by `tree_llt`) is faer's own path's
    /// (which permutes the matrix at every factorization) to round-off, and so are the
    /// solutions: a wrong slot would put a value in another entry and change both far
    /// beyond it.
    #[test]
    fn the_slot_map_factor_is_faers_own_to_round_off() {
        for (n, spacing) in [(11, 0.1), (31, 0.04)] {
            let (pattern, values, _) = stretched(n, spacing);
            let mut solver = DirectSolver::new(&pattern, FactorStructure::Supernodal).unwrap();
            assert!(solver.permuted.is_some());
            let b = rhs(pattern.dim());
            let mut mapped = b.clone();
            assert!(solver.solve_unshifted(&pattern, &values, &mut mapped));
            let factor = solver.factor_values.clone();
            // faer's own path, with the scratch it needs (the solver sized none for it).
            solver.permuted = None;
            solver.factor_work = MemBuffer::new(
                solver
                    .symbolic
                    .factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
            );
            let mut faers = b.clone();
            assert!(solver.solve_unshifted(&pattern, &values, &mut faers));
            let largest = |v: &[f64]| v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            let apart = |a: &[f64], b: &[f64]| {
                a.iter()
                    .zip(b)
                    .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
            };
            let scale = largest(&solver.factor_values);
            let off = apart(&factor, &solver.factor_values);
            assert!(off <= 1e-13 * scale, "{n}: the factors differ by {off:e}");
            let off = apart(&mapped, &faers);
            assert!(
                off <= 1e-12 * largest(&faers),
                "{n}: the solutions differ by {off:e}"
            );
        }
    }

    /// A stretched sheet's pattern, Newton matrix values and triplets.
    type Stretched = (HessianPattern, Vec<f64>, Vec<(usize, usize, f64)>);

    /// With a plan that splits the tree, the direct solve (factorization and triangular
    /// solves, `tree_llt`) gives the same bits on one thread and on a pool of two, its
    /// residual against the matrix is round-off, and the scratch the solves share with
    /// the factorization leaves nothing behind: one solver solving two matrices in turn
    /// (the second sheet stretched further) gives each the bits a fresh solver gives.
    #[test]
    fn the_split_direct_solve_is_the_same_on_one_and_two_threads() {
        for (n, spacing) in [(31, 0.04), (46, 0.03)] {
            let first = stretched(n, spacing);
            let second = stretched_by(n, spacing, 1.3);
            let b = rhs(first.0.dim());
            let solve = |systems: &[&Stretched]| {
                let mut solver = DirectSolver::new(&first.0, FactorStructure::Supernodal).unwrap();
                assert!(solver.permuted.as_ref().unwrap().plan.splits());
                let mut answers = Vec::new();
                for (pattern, values, _) in systems {
                    let mut x = b.clone();
                    assert!(solver.solve_unshifted(pattern, values, &mut x));
                    answers.push(x);
                }
                answers
            };
            let on_pool = |systems: &[&Stretched]| {
                #[cfg(feature = "parallel")]
                return rayon::ThreadPoolBuilder::new()
                    .num_threads(2)
                    .build()
                    .unwrap()
                    .install(|| solve(systems));
                #[cfg(not(feature = "parallel"))]
                solve(systems)
            };
            let in_turn = solve(&[&first, &second]);
            let runs = [
                in_turn.clone(),
                on_pool(&[&first, &second]),
                [solve(&[&first]), solve(&[&second])].concat(),
            ];
            for run in &runs[1..] {
                assert!(
                    run.iter()
                        .flatten()
                        .zip(in_turn.iter().flatten())
                        .all(|(a, b)| a.to_bits() == b.to_bits()),
                    "{n}: the runs differ"
                );
            }
            for (x, (_, _, triplets)) in in_turn.iter().zip([&first, &second]) {
                let residual = relative_residual(triplets, &b, x);
                assert!(residual < 1e-12, "{n}: {residual:e}");
            }
        }
    }

    /// The direct solver orders the unknowns by the particle graph's ordering, each
    /// particle's three together in their own order, so its factor is the one the cost
    /// model analyses: a simplicial factor holds exactly the analysis' entries below the
    /// diagonal plus the diagonal, and the supernodal solver takes the same order.
    #[test]
    fn the_factor_follows_the_particle_ordering_the_costs_analyse() {
        for n in [3, 11, 31] {
            let system = SpringSystem::cloth(&ClothGrid::lab_sized(n, 0.05)).unwrap();
            let far: Vec<[usize; 2]> = (0..n).map(|i| [i, n * n - 1 - i]).collect();
            for pattern in [
                HessianPattern::new(&system),
                HessianPattern::with_pairs(&system, &far),
            ] {
                let costs = SolverCosts::analyze(&pattern).unwrap();
                let solver = DirectSolver::new(&pattern, FactorStructure::Simplicial).unwrap();
                assert_eq!(
                    solver.factor_len() as f64,
                    costs.factor_nonzeros + costs.dim as f64,
                    "{n}"
                );
                let (forward, _) = solver.symbolic.perm().unwrap().arrays();
                let particles = ParticleOrdering::of(&pattern).unwrap();
                for (k, &old) in forward.iter().enumerate() {
                    assert_eq!(old, 3 * particles.perm[k / 3] + k % 3, "{n}: unknown {k}");
                }
                let supernodal = DirectSolver::new(&pattern, FactorStructure::Supernodal).unwrap();
                assert_eq!(supernodal.symbolic.perm().unwrap().arrays().0, forward);
            }
        }
    }

    /// The bound of [`SolverCosts::lower_bound`] is below the analysis' counts and
    /// crossover on lab-pattern cloths of several sizes (with and without extra coupled
    /// pairs, which add fill), on a chain (no fill: the factor's count is the matrix's)
    /// and on an empty system, and high enough that the soft cloths' 2 to 3 PCG
    /// iterations per Newton iteration stay below it.
    #[test]
    fn the_costs_bound_is_below_the_analysis() {
        let chain = {
            let particles: Vec<crate::model::Particle> = (0..6)
                .map(|i| crate::model::Particle {
                    fixed: i == 0,
                    ..crate::model::Particle::at_rest(
                        sinew_math::DVec3::new(0.0, -(i as f64), 0.0),
                        1.0,
                    )
                })
                .collect();
            let springs: Vec<crate::model::SpringSpec> = (0..5)
                .map(|i| crate::model::SpringSpec::between(i, i + 1))
                .collect();
            SpringSystem::new(&particles, &springs, crate::model::Material::default()).unwrap()
        };
        let grid = |n: usize| SpringSystem::cloth(&ClothGrid::lab_sized(n, 0.05)).unwrap();
        let mut patterns = vec![HessianPattern::new(&chain)];
        for n in [3, 11, 31, 51] {
            let system = grid(n);
            patterns.push(HessianPattern::new(&system));
            // Far pairs across the sheet: fill the ordering cannot avoid.
            let far: Vec<[usize; 2]> = (0..n).map(|i| [i, n * n - 1 - i]).collect();
            patterns.push(HessianPattern::with_pairs(&system, &far));
        }
        for pattern in &patterns {
            let bound = SolverCosts::lower_bound(pattern);
            let exact = SolverCosts::analyze(pattern).unwrap();
            assert_eq!(
                (bound.dim, bound.matrix_nonzeros),
                (exact.dim, exact.matrix_nonzeros)
            );
            assert!(
                bound.factor_nonzeros <= exact.factor_nonzeros,
                "{bound:?} {exact:?}"
            );
            assert!(
                bound.factor_multiply_adds <= exact.factor_multiply_adds,
                "{bound:?} {exact:?}"
            );
            assert!(
                bound.crossover_iterations() <= exact.crossover_iterations(),
                "{bound:?} {exact:?}"
            );
            if pattern.dim() > 100 {
                assert!(bound.crossover_iterations() > 5.0, "{bound:?}");
            }
        }
        // The chain has no fill: the bound's count of factor entries is exact.
        let (bound, exact) = (
            SolverCosts::lower_bound(&patterns[0]),
            SolverCosts::analyze(&patterns[0]).unwrap(),
        );
        assert_eq!(bound.factor_nonzeros, exact.factor_nonzeros);
        let empty = SpringSystem::new(
            &[crate::model::Particle {
                fixed: true,
                ..crate::model::Particle::at_rest(sinew_math::DVec3::ZERO, 1.0)
            }],
            &[],
            crate::model::Material::default(),
        )
        .unwrap();
        let bound = SolverCosts::lower_bound(&HessianPattern::new(&empty));
        assert_eq!(bound.factor_multiply_adds, 0.0);
        assert_eq!(bound.crossover_iterations(), f64::INFINITY);
    }
}
