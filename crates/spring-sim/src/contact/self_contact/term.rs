//! [`SelfContactTerm`]: the self-contact barrier of a triangle-mesh cloth as a term of the
//! minimization over the end-of-step positions ([`crate::potential::Term`]; backward Euler's
//! and BDF2's unknowns), and [`enable_self_contact`], which adds it wrapped in
//! [`AtEndOfStep`] so the implicit midpoint evaluates it at its end state too.
//!
//! The energy is `sum_pairs kappa m_k b(d_k - xi)` over every vertex-triangle and
//! edge-edge pair that shares no vertex, with `d_k` the pair's distance, `xi` the
//! thickness, `b` IPC's log barrier with reach `dhat` ([`crate::contact::barrier`]) and
//! `m_k` IPC's mollifier for edge-edge pairs (1 for vertex-triangle pairs). It is `+inf`
//! where a pair's gap `d_k - xi` is zero or negative. Every evaluation (energy, change,
//! gradient, Hessian) uses exactly the broad phase's pairs for the state it is given, so
//! the energy, its gradient and its Hessian are those of one function; the active set
//! collected at the start of each Newton iteration (the pairs within `dhat`) is reused by
//! the gradient and Hessian at that same state and feeds the statistics.
//!
//! The mesh is hashed at most once per Newton iteration: the line-search cap collects the
//! pairs over the whole segment the line search may try (`x + [0, 8] dx`, boxes grown by
//! `dhat + thickness`, and kept grown by a further slack of up to the segment's length,
//! at most `dhat + thickness`), and every later query inside that region (the cap's own
//! sweeps, each trial's energy change, the next iterate's active set and energy, and the
//! next iterations' segments while they stay inside it) filters the list by the query's
//! boxes, which gives the broad phase's set exactly ([`CandidateCache`]); a query
//! outside it hashes the mesh again. Each listed pair's gap and energy at the segment's
//! start are kept once computed, for the cap's two sweeps and every trial's energy
//! change.
//!
//! The line search is capped by additive CCD over the Newton step, so no state it tries
//! is reached through a crossing; backward Euler also asks the cap whether the straight
//! path from the step's start to its first guess is clear.
//!
//! `kappa` starts at [`minimum_kappa`] on the first step (mean free mass, gravity, the
//! step, `dhat`) and follows [`AdaptiveKappa`]'s rule, applied once per step at the
//! step's start (to the smallest gap there) rather than per iteration: the incremental
//! potential is then one function throughout a step, and Newton with its line search
//! never increases it within the step.
//!
//! With [`SelfContactSettings::mu`] above 0 the term also holds the friction of the pairs
//! within `dhat` at the step's start, lagged there with the step's stiffness
//! ([`super::friction`]): their energy, its change, gradient and (positive
//! semidefinite) Hessian are added to the barrier's, and the potential stays one
//! function within the step.
//!
//! Hessian blocks: each pair's 12x12 Hessian is projected to be positive semidefinite
//! and scattered into its 4x4 particle blocks; asked for [`Curvature::ExactContact`] (or
//! [`Curvature::Exact`]) and with [`SelfContactSettings::exact_hessian`] set, the exact
//! Hessian of every pair is scattered instead (mollified edge pairs included: with
//! theirs projected the Newton matrix is not the potential's Hessian, and a wound sheet,
//! whose layers lie edge along edge, converges only linearly), which is cheaper per pair
//! (no eigen-decomposition) and restores the quadratic convergence the projection
//! loses, but may make the Newton matrix
//! indefinite: backward Euler then falls back to the projected blocks at once. A pair couples particles no spring joins,
//! and the Hessian pattern has slots only for the springs' pairs (and pairs added with
//! [`crate::BackwardEuler::add_coupled_term`]); when some of a pair's blocks have no
//! slots, the pair contributes only the blocks within each of its two primitives (or, if
//! those are missing too, only its diagonal blocks). A principal block-diagonal part of a
//! positive semidefinite matrix is positive semidefinite, so the Newton matrix stays
//! positive definite and the step a descent direction; only the convergence rate pays.
//! The particle pairs left without slots are recorded, and the integrator takes them
//! at the start of the next Newton iteration
//! ([`crate::potential::Term::take_missing_pairs`]) and widens its pattern, so from that
//! iteration on the Newton matrix has the pairs' full blocks.

use super::broad::{Candidate, CandidateCache, Primitives, candidates, candidates_touching};
use super::ccd::{additive_ccd_with_bound, approach_bound, clear_with_bound};
use super::closed::{Mollifier, PAIR_BLOCKS, PairBlocks, RegionForm};
use super::crossing::first_crossing;
use super::distance::{
    Closest, PairKind, SEPARATION_MARGIN, mollifier, mollifier_derivatives, mollifier_gradient,
    separation, squared_distance, squared_distance_derivatives, squared_distance_gradient,
    squared_distance_in,
};
use super::dual::{Dual12, Gradient12, Scalar, values};
use super::friction::FrictionPair;
use super::psd12::project_psd12_pair;
use super::spread;
use crate::contact::ContactError;
use crate::contact::barrier::{
    AdaptiveKappa, KappaSettings, barrier, barrier_first_derivative, barrier_second_derivative,
    minimum_kappa,
};
use crate::model::SpringSystem;
use crate::newton::BackwardEuler;
use crate::pattern::HessianPattern;
use crate::potential::{AtEndOfStep, HessianSink, PairPlace, StepContext, SymBlock, Term};
use crate::report::StepError;
use crate::spring::Curvature;
use sinew_math::{DMat3, DVec3};
use std::collections::BTreeSet;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

/// The self-contact settings.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(default))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct SelfContactSettings {
    /// The barrier's reach `dhat`: it acts where a pair's gap is below it (default 1e-3).
    pub dhat: f64,
    /// The cloth's thickness `xi`: gaps are distances minus it (default 0).
    pub thickness: f64,
    /// The line search may close at most this fraction of any pair's gap (default 0.9,
    /// as for colliders: a tenth is kept).
    pub toi_fraction: f64,
    /// IPC's mollifier threshold ratio: an edge pair is mollified where
    /// `|e_a x e_b|^2 < ratio |e_a|^2 |e_b|^2` at rest (default 1e-3, IPC's).
    pub mollifier_ratio: f64,
    /// Coulomb friction coefficient between the cloth's own primitives, `0 <= mu <=`
    /// [`crate::contact::MAX_MU`] (default 0, frictionless): lagged, smoothed friction
    /// on every pair within `dhat` at a step's start ([`super::friction`]).
    pub mu: f64,
    /// Friction's velocity threshold `eps_v` (scene units per second, default 1e-3):
    /// below this relative tangential speed friction is smoothed (static friction is a
    /// very slow creep), above it it is exactly Coulomb.
    pub eps_v: f64,
    /// The adaptive stiffness rule's constants.
    pub kappa: KappaSettings,
    /// Whether the term gives its pairs' exact Hessians when the Newton matrix asks for
    /// them ([`Curvature::ExactContact`]); when false it always gives their projections
    /// (default true: fewer Newton iterations and less time on the stacked and twisted
    /// sheets, docs/bench/contact.md, "The exact pair Hessian first" and "The exact pair
    /// Hessian from the first iteration").
    pub exact_hessian: bool,
}

impl Default for SelfContactSettings {
    fn default() -> Self {
        Self {
            dhat: 1e-3,
            thickness: 0.0,
            toi_fraction: 0.9,
            mollifier_ratio: 1e-3,
            mu: 0.0,
            eps_v: 1e-3,
            kappa: KappaSettings::default(),
            exact_hessian: true,
        }
    }
}

impl SelfContactSettings {
    /// Checks every setting (`dhat > 0`, `thickness >= 0`, `0 < toi_fraction < 1`,
    /// `mollifier_ratio > 0`, `0 <= mu <= MAX_MU`, `eps_v > 0`, the stiffness rule's
    /// constants, all finite); the error names the setting.
    pub fn validate(&self) -> Result<(), ContactError> {
        let bad = ContactError::bad_setting;
        crate::contact::check_gap_settings(self.dhat, self.thickness)?;
        crate::contact::check_toi_fraction(self.toi_fraction)?;
        crate::contact::check_friction_settings(self.mu, self.eps_v)?;
        if !(self.mollifier_ratio.is_finite() && self.mollifier_ratio > 0.0) {
            return bad(
                "mollifier_ratio",
                self.mollifier_ratio,
                "must be positive and finite",
            );
        }
        self.kappa.validate()
    }
}

/// Numbers the term publishes while an integrator owns it.
#[derive(Debug, Default)]
pub struct SelfContactStats {
    kappa: AtomicU64,
    active_pairs: AtomicU64,
    min_gap: AtomicU64,
    broad_phases: AtomicU64,
    exact_hessians: AtomicU64,
    projected_after_exact: AtomicU64,
    friction_pairs: AtomicU64,
    /// Particle pairs a contact pair coupled that the Hessian pattern had no slots for.
    missing: Mutex<BTreeSet<[usize; 2]>>,
}

impl SelfContactStats {
    /// The barrier stiffness (0 before the first step).
    #[must_use]
    pub fn kappa(&self) -> f64 {
        f64::from_bits(self.kappa.load(Ordering::Relaxed))
    }

    /// The number of pairs within `dhat` at the last Newton iteration's start.
    #[must_use]
    pub fn active_pairs(&self) -> usize {
        self.active_pairs.load(Ordering::Relaxed) as usize
    }

    /// The smallest gap (distance minus thickness) among them (`+inf` when none).
    #[must_use]
    pub fn min_gap(&self) -> f64 {
        f64::from_bits(self.min_gap.load(Ordering::Relaxed))
    }

    /// How many times the term has hashed the mesh (run the broad phase) since it was
    /// made; queries answered from the list kept for the current line-search segment
    /// are not counted.
    #[must_use]
    pub fn broad_phases(&self) -> u64 {
        self.broad_phases.load(Ordering::Relaxed)
    }

    /// How many times the term has written its pairs' exact Hessians into a Newton matrix.
    #[must_use]
    pub fn exact_hessians(&self) -> u64 {
        self.exact_hessians.load(Ordering::Relaxed)
    }

    /// How many Newton iterations asked for the projected Hessians after the exact ones
    /// at the same iterate (the fallback when the matrix with the exact blocks was not
    /// positive definite).
    #[must_use]
    pub fn projected_after_exact(&self) -> u64 {
        self.projected_after_exact.load(Ordering::Relaxed)
    }

    /// The number of pairs whose friction the current (or last) step lagged (0 without
    /// friction).
    #[must_use]
    pub fn friction_pairs(&self) -> usize {
        self.friction_pairs.load(Ordering::Relaxed) as usize
    }

    /// Takes the particle pairs (`[low, high]`, sorted) that contact pairs coupled since
    /// the last call but the Hessian pattern had no slots for (the integrator takes them
    /// at every Newton iteration through the term; this is for a caller that runs the
    /// term alone).
    #[must_use]
    pub fn take_missing_pairs(&self) -> Vec<[usize; 2]> {
        let mut set = self.missing.lock().unwrap_or_else(PoisonError::into_inner);
        std::mem::take(&mut *set).into_iter().collect()
    }

    fn note_missing(&self, pairs: impl Iterator<Item = [usize; 2]>) {
        let mut set = self.missing.lock().unwrap_or_else(PoisonError::into_inner);
        set.extend(pairs.map(|[a, b]| [a.min(b), a.max(b)]));
    }
}

/// The self-contact term (see the module documentation). Its positions are the
/// end-of-step positions: added by hand to an implicit midpoint, whose unknowns are the
/// step's midpoint, it must be wrapped in [`AtEndOfStep`] ([`enable_self_contact`] does).
#[derive(Debug)]
pub struct SelfContactTerm {
    prims: Primitives,
    /// Each edge's mollifier factor `sqrt(ratio) |e|^2` at rest, so a pair's threshold
    /// is the product of its two edges' factors.
    edge_factor: Vec<f64>,
    settings: SelfContactSettings,
    kappa: Option<AdaptiveKappa>,
    /// The pairs within `dhat` at `active_at`.
    active: Vec<Candidate>,
    active_at: Vec<DVec3>,
    /// Per active pair, with a barrier at `active_at`: its particles, energy gradient
    /// and, once Newton asks for the matrix at that iterate, its Hessian (in the form
    /// asked for; recomputed in the other form when that is asked). The gradient comes
    /// first and alone: an iterate whose gradient ends the step (most steps' last, and a
    /// resting cloth's every other one) never pays for the pairs' Hessians.
    cache: Mutex<PairCache>,
    /// The form the first Hessian asked for at the current iterate had (`FORM_NONE`
    /// before one is asked), and whether the projected form was asked after the exact
    /// one there.
    first_asked: AtomicU8,
    fell_back: AtomicBool,
    /// The broad phase's pairs near `active_at` (sorted, as every list of pairs is) and
    /// their values there: the line-search segment that starts at that state takes them
    /// instead of computing them again (see [`NearValue`]).
    near: Vec<Candidate>,
    near_values: Vec<NearValue>,
    /// `near`'s positions in the segment's list (ascending) when they were found there,
    /// and that list's [`Segment::list_id`] (`None`: found by hashing the mesh).
    near_positions: Vec<usize>,
    near_list: Option<u64>,
    /// The stiffness `near_values`' energies were computed with (those not NaN).
    near_kappa: f64,
    /// What [`Term::check_start`] would find at `active_at`: the smallest gap within
    /// `dhat` and the first pair (in `near`'s order) whose gap is zero, negative or NaN,
    /// with the fixed flags the pairs were found with. A step starts where the last one
    /// ended, at the last active set's state, so its check takes these.
    near_summary: (f64, Option<usize>),
    near_fixed: Vec<bool>,
    /// The regions of the active pairs (in `active`'s order).
    active_regions: Vec<Closest>,
    /// The broad phase's pairs over the last Newton step's whole line-search segment
    /// (collected by [`Term::max_step`]); every query it covers filters it instead of
    /// hashing the mesh again. It also keeps each listed pair's gap and energy at the
    /// segment's start, which the cap's two sweeps and every trial's energy change need.
    segment: Mutex<Segment>,
    /// The state [`Term::check_start`] last checked and its smallest gap (`None` once
    /// taken), which the step's [`Term::begin_step`] (at the same state) takes instead
    /// of computing it again. The positions' storage is kept from step to step.
    checked_start: Mutex<(Vec<DVec3>, Option<f64>)>,
    /// The places of the active pairs' coupling blocks in the Newton matrix, kept for the
    /// next active set (see [`KeptPlaces`]).
    places: Mutex<KeptPlaces>,
    /// The friction pairs lagged at the step's start (empty without friction).
    friction: Vec<FrictionPair>,
    /// The friction pairs' Hessian blocks (the storage kept from iteration to iteration)
    /// and the places of their coupling blocks on the pattern of the kept revision.
    friction_scatter: Mutex<FrictionScatter>,
    /// The friction pairs' values (energies or changes) and gradients of the last
    /// evaluation, one per pair: storage kept so that an evaluation, several per line
    /// search, does not allocate lists of tens of thousands of entries.
    friction_values: Mutex<(Vec<f64>, Vec<DVec3>)>,
    stats: Arc<SelfContactStats>,
}

/// See [`SelfContactTerm::friction_scatter`].
#[derive(Debug, Default)]
struct FrictionScatter {
    /// The [`HessianPattern::revision`] `places` were found on (`None`: none kept, as
    /// after the pairs are lagged again).
    revision: Option<u64>,
    places: Vec<[PairPlace; 6]>,
    blocks: Vec<PairBlocks>,
}

impl SelfContactTerm {
    /// A term for the cloth `system` with surface `triangles` (indices into the
    /// particles; mollifier thresholds from the edges' lengths at the system's current
    /// positions, taken as rest), checked: the settings (the error names the setting),
    /// every index (the error names the triangle), and the current state (no pair may be
    /// within the thickness; the error names the pair).
    pub fn new(
        system: &SpringSystem,
        triangles: &[[usize; 3]],
        settings: SelfContactSettings,
    ) -> Result<Self, ContactError> {
        settings.validate()?;
        let len = system.len();
        for (t, tri) in triangles.iter().enumerate() {
            if tri.iter().any(|&v| v >= len) {
                return Err(ContactError::BadMesh {
                    item: format!("triangle {t} {tri:?}"),
                    reason: "refers to a particle that does not exist",
                });
            }
            if tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2] {
                return Err(ContactError::BadMesh {
                    item: format!("triangle {t} {tri:?}"),
                    reason: "repeats a vertex",
                });
            }
        }
        let prims = Primitives::new(triangles);
        let x = system.positions();
        // The barrier's reach must be below every edge: a vertex and a triangle at the
        // far end of its shortest edge that does not contain it (there is one unless
        // every triangle there does) are a pair at most that edge apart, so a longer
        // reach puts such pairs in contact from the start whatever the motion (the sheet
        // pushes on itself in its own plane), and a reach beyond the sheet makes every
        // pair active at every iteration.
        let reach = settings.dhat + settings.thickness;
        if let Some((e, length)) = prims
            .edges
            .iter()
            .map(|&[a, b]| ([a, b], (x[a] - x[b]).length()))
            .min_by(|p, q| p.1.total_cmp(&q.1))
            && length <= reach
        {
            return Err(ContactError::BadMesh {
                item: format!(
                    "the shortest edge {e:?} ({length:.3e}, against dhat + thickness = {reach:.3e})"
                ),
                reason: "is not longer than the barrier's reach; make dhat plus the thickness smaller than every edge",
            });
        }
        // Below every edge, `dhat` is also below the mesh's extent: this checks it against
        // the positions' rounding.
        crate::contact::check_contact_distance("dhat", settings.dhat, x)?;
        let root = settings.mollifier_ratio.sqrt();
        let edge_factor = prims
            .edges
            .iter()
            .map(|&[a, b]| root * (x[a] - x[b]).length_squared())
            .collect();
        let term = Self {
            prims,
            edge_factor,
            settings,
            kappa: None,
            active: Vec::new(),
            active_at: Vec::new(),
            cache: Mutex::new(PairCache::default()),
            first_asked: AtomicU8::new(FORM_NONE),
            fell_back: AtomicBool::new(false),
            near: Vec::new(),
            near_values: Vec::new(),
            near_positions: Vec::new(),
            near_list: None,
            near_kappa: f64::NAN,
            near_summary: (f64::INFINITY, None),
            near_fixed: Vec::new(),
            active_regions: Vec::new(),
            segment: Mutex::new(Segment::default()),
            checked_start: Mutex::new((Vec::new(), None)),
            places: Mutex::new(KeptPlaces::default()),
            friction: Vec::new(),
            friction_scatter: Mutex::new(FrictionScatter::default()),
            friction_values: Mutex::new((Vec::new(), Vec::new())),
            stats: Arc::new(SelfContactStats::default()),
        };
        term.check_state(x, system.fixed())?;
        term.publish(f64::INFINITY);
        Ok(term)
    }

    /// The shared statistics.
    #[must_use]
    pub fn stats(&self) -> Arc<SelfContactStats> {
        Arc::clone(&self.stats)
    }

    /// The settings.
    #[must_use]
    pub fn settings(&self) -> &SelfContactSettings {
        &self.settings
    }

    /// The mesh's primitives.
    #[must_use]
    pub fn primitives(&self) -> &Primitives {
        &self.prims
    }

    /// The barrier stiffness (0 before the first step).
    #[must_use]
    pub fn kappa(&self) -> f64 {
        self.kappa.map_or(0.0, |k| k.kappa)
    }

    fn publish(&self, min_gap: f64) {
        let s = &self.stats;
        s.kappa.store(self.kappa().to_bits(), Ordering::Relaxed);
        s.active_pairs
            .store(self.active.len() as u64, Ordering::Relaxed);
        s.min_gap.store(min_gap.to_bits(), Ordering::Relaxed);
    }

    /// A pair's kind and its four particles.
    fn pair(&self, c: Candidate) -> (PairKind, [usize; 4]) {
        c.kind_and_particles(&self.prims)
    }

    fn mollifier_threshold(&self, c: Candidate) -> Option<f64> {
        match c {
            Candidate::PointTriangle { .. } => None,
            // ratio |e_a|^2 |e_b|^2 = (sqrt(ratio) |e_a|^2) (sqrt(ratio) |e_b|^2).
            Candidate::EdgeEdge { a, b } => Some(self.edge_factor[a] * self.edge_factor[b]),
        }
    }

    /// The mollifier of the pair `c` at the positions `p` when it is below 1 (a value that
    /// rounds to 1 takes the unmollified form, as the energy's `m b` does not tell it
    /// from 1): the same answer from the same positions, whichever pass asks.
    fn mollifier_below_one(&self, c: Candidate, p: &[DVec3; 4]) -> Option<Mollifier> {
        self.mollifier_threshold(c)
            .and_then(|eps| Mollifier::below(p, eps))
            .filter(|m| m.value < 1.0)
    }

    /// A pair's gap (distance minus thickness) at `x`.
    fn gap(&self, c: Candidate, x: &[DVec3]) -> f64 {
        self.gap_of(&self.placed(c, x))
    }

    /// The pair `c`'s kind, particles and positions at `x`, gathered once for the several
    /// values a pass computes of it (each of which gathered them again before).
    fn placed(&self, c: Candidate, x: &[DVec3]) -> Placed {
        let (kind, v) = self.pair(c);
        Placed {
            c,
            kind,
            v,
            p: v.map(|i| x[i]),
        }
    }

    /// [`Self::gap`] of a gathered pair.
    fn gap_of(&self, q: &Placed) -> f64 {
        squared_distance(q.kind, &q.p).sqrt() - self.settings.thickness
    }

    /// [`Self::gap`] (the same operations) with the region of the closest points it
    /// found, which the pair's derivatives then need not find again.
    fn gap_and_region_of(&self, q: &Placed) -> (f64, Closest) {
        let closest = q.kind.closest(&q.p);
        let gap = squared_distance_in(&values(&q.p), closest).sqrt() - self.settings.thickness;
        (gap, closest)
    }

    /// The pair's values at `x` as the active set keeps them: its separation and, unless
    /// that shows it beyond `dhat`, its gap and the region of its closest points.
    fn near_value(&self, c: Candidate, x: &[DVec3]) -> NearValue {
        self.near_value_of(&self.placed(c, x))
    }

    /// [`Self::near_value`] of a gathered pair.
    fn near_value_of(&self, q: &Placed) -> NearValue {
        let separation = separation(q.kind, &q.p);
        if self.beyond_dhat_by(separation) {
            NearValue {
                separation,
                ..NearValue::default()
            }
        } else {
            let (gap, closest) = self.gap_and_region_of(q);
            NearValue {
                separation,
                gap,
                closest,
                ..NearValue::default()
            }
        }
    }

    /// The pair's [`separation`] at `x`: a lower bound of its distance at a few dot
    /// products.
    fn separation(&self, c: Candidate, x: &[DVec3]) -> f64 {
        let (kind, v) = self.pair(c);
        separation(kind, &v.map(|i| x[i]))
    }

    /// Whether a pair of that separation has a gap certainly at least `dhat` (see
    /// [`SEPARATION_MARGIN`]): then its energy is zero and it is not active, and its exact
    /// distance, several times the cost, is not needed. Most pairs the broad phase lists
    /// along a long step are such pairs.
    fn beyond_dhat_by(&self, separation: f64) -> bool {
        separation >= self.beyond_dhat_threshold()
    }

    /// The separation from which [`Self::beyond_dhat_by`] holds.
    fn beyond_dhat_threshold(&self) -> f64 {
        (self.settings.dhat + self.settings.thickness) * (1.0 + SEPARATION_MARGIN)
    }

    /// [`Self::beyond_dhat_by`] the pair's separation at `x`.
    fn beyond_dhat(&self, c: Candidate, x: &[DVec3]) -> bool {
        self.beyond_dhat_by(self.separation(c, x))
    }

    /// The broad phase's pairs within `dhat + thickness` at `x` or along `x -> x + dx`:
    /// filtered from the segment's list when it covers the query (the same set, see
    /// [`CandidateCache`]), else found by hashing the mesh.
    fn pairs(&self, x: &[DVec3], dx: Option<&[DVec3]>, fixed: &[bool]) -> Vec<Candidate> {
        self.pairs_placed(x, dx, fixed, None).0
    }

    /// [`Self::pairs`] and, when they were filtered from the segment's list, that list's
    /// id, with their positions in it written to `positions` (`None`: into the segment's
    /// scratch, whose storage is reused; left empty when the mesh was hashed).
    fn pairs_placed(
        &self,
        x: &[DVec3],
        dx: Option<&[DVec3]>,
        fixed: &[bool],
        mut positions: Option<&mut Vec<usize>>,
    ) -> (Vec<Candidate>, Option<u64>) {
        let margin = self.settings.dhat + self.settings.thickness;
        let mut segment = self.segment.lock().unwrap_or_else(PoisonError::into_inner);
        let seg = &mut *segment;
        let covered = match positions.as_deref_mut() {
            Some(p) => seg
                .pairs
                .query_indices_into(&self.prims, x, dx, margin, fixed, p),
            None => seg.query_into_found(&self.prims, x, dx, margin, fixed),
        };
        if covered {
            let list = seg.pairs.list();
            let positions = match positions {
                Some(p) => &*p,
                None => &seg.found,
            };
            return (
                positions.iter().map(|&k| list[k]).collect(),
                Some(seg.list_id),
            );
        }
        drop(segment);
        self.stats.broad_phases.fetch_add(1, Ordering::Relaxed);
        (candidates(&self.prims, x, dx, margin, fixed), None)
    }

    /// Collects the broad phase's pairs over the segment `x -> x + dx` and keeps them
    /// for the queries it covers.
    fn collect_segment(&self, x: &[DVec3], dx: &[DVec3], fixed: &[bool]) {
        let margin = self.settings.dhat + self.settings.thickness;
        let mut segment = self.segment.lock().unwrap_or_else(PoisonError::into_inner);
        if segment
            .pairs
            .covers(&self.prims, x, Some(dx), margin, fixed)
        {
            // A later Newton iteration's segment usually lies inside the last one's
            // region (the steps shrink as Newton converges): its list serves as it is.
            let pairs = std::mem::take(&mut segment.pairs);
            self.reset_from_active_set(&mut segment, pairs, x);
            return;
        }
        // The region is kept wider than the segment by up to the segment's own length
        // (at most `margin`), so the next iterations' segments fall inside it.
        let slack = dx
            .iter()
            .map(|d| d.length())
            .fold(0.0, f64::max)
            .min(margin);
        self.stats.broad_phases.fetch_add(1, Ordering::Relaxed);
        let pairs = CandidateCache::with_slack(&self.prims, x, Some(dx), margin, slack, fixed);
        segment.list_id += 1;
        self.reset_from_active_set(&mut segment, pairs, x);
    }

    /// Resets the segment to `pairs` from `x`, with the separations, gaps and (when
    /// computed with the segment's stiffness) energies the active set has just computed
    /// there, for the pairs both lists hold, so the cap's sweeps and the line search's
    /// energies at `x` do not compute them again: the active set's positions in the list
    /// when it was filtered from it (the usual case: the list serves several Newton
    /// iterations), else a merge (both lists are sorted). The same values, so the same
    /// answers, bit for bit.
    fn reset_from_active_set(&self, seg: &mut Segment, pairs: CandidateCache, x: &[DVec3]) {
        let kappa = self.kappa();
        let at_active = self.active_at.as_slice() == x;
        let seed = Seed {
            positions: &self.near_positions,
            values: &self.near_values,
            energies: self.near_kappa.to_bits() == kappa.to_bits(),
            beyond: self.beyond_dhat_threshold(),
        };
        if at_active && self.near_list == Some(seg.list_id) {
            seg.reset_seeded(pairs, x, kappa, Some(seed));
            return;
        }
        seg.reset(pairs, x, kappa);
        if !at_active {
            return;
        }
        // The merge by chunks of the list on the pool, each chunk starting at its first
        // pair's place in the active set (a lone pass over a wound sheet's list was 1% of
        // its minimizing thread, the other thread idle).
        let (list, near) = (seg.pairs.list(), &self.near);
        spread::for_each_chunk(&mut seg.kept, |first, chunk| {
            let Some(head) = list.get(first) else {
                return;
            };
            let mut j = near.partition_point(|c| c < head);
            for (pair, kept) in list[first..].iter().zip(chunk) {
                while near.get(j).is_some_and(|c| c < pair) {
                    j += 1;
                }
                if near.get(j) == Some(pair) {
                    *kept = seed.kept(&self.near_values[j]);
                    j += 1;
                }
            }
        });
    }

    /// The pairs whose gap may be below `dhat` at `x` (broad phase).
    fn near(&self, x: &[DVec3], fixed: &[bool]) -> Vec<Candidate> {
        self.pairs(x, None, fixed)
    }

    /// The smallest gap at `x` over the pairs within `dhat` (`+inf` when none).
    #[must_use]
    pub fn min_gap(&self, x: &[DVec3], fixed: &[bool]) -> f64 {
        self.gaps_at(x, fixed).0
    }

    /// `Err` naming the first pair (in the broad phase's order) whose gap at `x` is zero
    /// or negative.
    pub fn check_state(&self, x: &[DVec3], fixed: &[bool]) -> Result<(), ContactError> {
        if let Some((pair, _)) = self.gaps_at(x, fixed).1 {
            return Err(ContactError::BadMesh {
                item: pair,
                reason: "are within the thickness of each other (or touching)",
            });
        }
        match self.crossing_at(x, fixed, None) {
            Some(pair) => Err(ContactError::BadMesh {
                item: pair,
                reason: "pass through each other: the mesh crosses itself at the start, \
                         which the barrier cannot undo",
            }),
            None => Ok(()),
        }
    }

    /// The first edge through a triangle sharing none of its vertices at `x` (pairs of
    /// fixed primitives left out, and with `moved` those with no vertex in it), named;
    /// see [`super::crossing`].
    fn crossing_at(&self, x: &[DVec3], fixed: &[bool], moved: Option<&[bool]>) -> Option<String> {
        first_crossing(&self.prims, x, fixed, moved).map(|(e, t)| {
            format!(
                "edge {:?} and triangle {t} {:?}",
                self.prims.edges[e], self.prims.triangles[t]
            )
        })
    }

    /// The smallest gap at `x` over the pairs within `dhat` (`+inf` when none), and the
    /// first pair (in the broad phase's order) whose gap is zero, negative or NaN, named,
    /// with that gap.
    fn gaps_at(&self, x: &[DVec3], fixed: &[bool]) -> (f64, Option<(String, f64)>) {
        let near = self.near(x, fixed);
        let mut gaps = Vec::new();
        spread::fill(&mut gaps, near.len(), 0.0, |i| {
            if self.beyond_dhat(near[i], x) {
                f64::INFINITY
            } else {
                self.gap(near[i], x)
            }
        });
        let touching = gaps
            .iter()
            .position(|g| g.is_nan() || *g <= 0.0)
            .map(|k| (self.pair_name(near[k]), gaps[k]));
        let min = gaps.into_iter().fold(f64::INFINITY, f64::min);
        let min = if min < self.settings.dhat {
            min
        } else {
            f64::INFINITY
        };
        (min, touching)
    }

    /// A pair as an error names it.
    fn pair_name(&self, c: Candidate) -> String {
        match c {
            Candidate::PointTriangle { vertex, triangle } => {
                format!("vertex {vertex} and triangle {triangle}")
            }
            Candidate::EdgeEdge { a, b } => format!(
                "edge {:?} and edge {:?}",
                self.prims.edges[a], self.prims.edges[b]
            ),
        }
    }

    /// A pair's barrier energy at `x` (`+inf` at a gap of zero or below).
    fn pair_energy(&self, kappa: f64, c: Candidate, x: &[DVec3]) -> f64 {
        if self.beyond_dhat(c, x) {
            return 0.0;
        }
        self.pair_energy_at_gap(kappa, c, x, self.gap(c, x))
    }

    /// [`Self::pair_energy`] with the pair's gap at `x` given (as [`Self::gap`] computes
    /// it, so the value is the same).
    fn pair_energy_at_gap(&self, kappa: f64, c: Candidate, x: &[DVec3], gap: f64) -> f64 {
        self.energy_at_gap_of(kappa, &self.placed(c, x), gap)
    }

    /// [`Self::pair_energy_at_gap`] of a gathered pair.
    fn energy_at_gap_of(&self, kappa: f64, q: &Placed, gap: f64) -> f64 {
        if gap.is_nan() || gap <= 0.0 {
            return f64::INFINITY;
        }
        if gap >= self.settings.dhat {
            return 0.0;
        }
        let m = self
            .mollifier_threshold(q.c)
            .map_or(1.0, |eps| mollifier(&q.p, eps));
        kappa * m * barrier(gap, self.settings.dhat)
    }

    /// A pair's energy gradient and Hessian (projected, or exact when `form` asks for
    /// it; not written when `form` is `None`) in the pair's twelve
    /// coordinates, written into `out` (which is marked as holding none when the pair is
    /// beyond `dhat` or not admissible). The gradient, and whether the pair holds
    /// derivatives, do not depend on `form`, bit for bit.
    ///
    /// Pairs take the closed form of [`RegionForm`], mollified edge pairs (nearly
    /// parallel edges) its product with the [`Mollifier`] and the full 12x12 projection;
    /// the degenerate pairs the closed form declines take the dual numbers and the 12x12
    /// projection (or, in the exact form, the dual numbers' Hessian). `region` is the
    /// region of the closest points at `x` when the caller has it (found by the same
    /// rules, so the same). The results are written in place: a pair's derivatives are
    /// over a kilobyte, and the lists of a few ten thousand pairs are refilled at every
    /// Newton iteration.
    fn pair_derivatives(
        &self,
        kappa: f64,
        c: Candidate,
        x: &[DVec3],
        region: Option<Closest>,
        out: &mut PairDerivatives,
    ) {
        let (kind, v) = self.pair(c);
        let p = v.map(|i| x[i]);
        out.kind = kind;
        out.particles = v;
        out.present = false;
        out.closed = None;
        let mollified = self.mollifier_below_one(c, &p);
        let closest = region.unwrap_or_else(|| kind.closest(&p));
        if let Some(present) = self.pair_derivatives_closed(kappa, closest, &p, mollified, out) {
            out.present = present;
            return;
        }
        if let Some(e) = self.pair_energy_dual::<Gradient12>(kappa, c, x) {
            out.gradient = e.gradient;
            out.present = true;
        }
    }

    /// The Hessian in `form` of the pair whose derivatives at `x` are `pair` into `out`
    /// (every entry overwritten when `pair` is present, else left alone): a closed-form
    /// pair's from its span, a mollified pair's in full (the mollifier's curvature
    /// included) from the inputs its gradient kept, the dual numbers' pairs' (the
    /// degenerate pairs the closed form declines) computed again.
    fn pair_hessian(
        &self,
        kappa: f64,
        c: Candidate,
        x: &[DVec3],
        pair: &PairDerivatives,
        form: HessianForm,
        out: &mut PairBlocks,
    ) {
        if let Some(closed) = pair.closed {
            // The span built now from the gradient's inputs at the same state is the one
            // the gradient's pass found (the same function of the same numbers).
            let p = pair.particles.map(|i| x[i]);
            let region = RegionForm::new(&p, closed.closest);
            match closed.mollified {
                None => {
                    if let Some(span) = region.span(closed.first, closed.second) {
                        span.blocks_into(form == HessianForm::Projected, out);
                        return;
                    }
                }
                Some(phi) => {
                    // The mollifier's curvature is outside the distance's span: the full
                    // matrix, projected by the 12x12 decomposition. The mollifier is the
                    // one the gradient's pass found (the same positions).
                    if let Some(mollifier) = self.mollifier_below_one(c, &p) {
                        let h = mollifier.hessian(&region, phi, closed.first, closed.second);
                        if h.iter().flatten().all(|v| v.is_finite()) {
                            *out = PairBlocks::from_matrix(&match form {
                                HessianForm::Exact => h,
                                HessianForm::Projected => project_psd12_pair(&h),
                            });
                            return;
                        }
                    }
                }
            }
        }
        if pair.present
            && let Some(e) = self.pair_energy_dual::<Dual12>(kappa, c, x)
        {
            *out = PairBlocks::from_matrix(&match form {
                HessianForm::Exact => e.hessian,
                HessianForm::Projected => project_psd12_pair(&e.hessian),
            });
        }
    }

    /// The closed-form derivatives of a pair into `out`'s gradient and the inputs of its
    /// Hessian: `Some(true)` when written, `Some(false)` when the pair is beyond `dhat`
    /// or not admissible, `None` when the closed form declines a degenerate pair. With
    /// `E(s) = kappa b(sqrt(s) - xi)`, `E' = kappa b' / (2 d)` and
    /// `E'' = kappa (b'' / (4 s) - b' / (4 s d))`, `d = sqrt(s)`; a mollified edge pair
    /// (`mollified`: its mollifier) has the energy `m E` instead.
    fn pair_derivatives_closed(
        &self,
        kappa: f64,
        closest: Closest,
        p: &[DVec3; 4],
        mollified: Option<Mollifier>,
        out: &mut PairDerivatives,
    ) -> Option<bool> {
        let form = RegionForm::new(p, closest);
        let s = form.value();
        if s.is_nan() || s <= 0.0 {
            return Some(false);
        }
        let d = s.sqrt();
        let (g, dhat) = (d - self.settings.thickness, self.settings.dhat);
        if g.is_nan() || g <= 0.0 || g >= dhat {
            return Some(false);
        }
        let (b1, b2) = (
            barrier_first_derivative(g, dhat),
            barrier_second_derivative(g, dhat),
        );
        let first = kappa * b1 / (2.0 * d);
        let second = kappa * (b2 / (4.0 * s) - b1 / (4.0 * s * d));
        // The closed form declines the pairs whose span is `None` (to the dual numbers,
        // for the gradient too). The span itself is built only when a Hessian is asked
        // for at this iterate, from the inputs kept here: most iterates whose gradient
        // ends the step never ask, and a slot without it is a third of the size. Where
        // the span is not certain from its inputs it is built here to decide.
        // A mollified pair is declined by the same test: its Hessian needs the
        // distance's in full, built from the same factors.
        if !form.spans_certainly(first, second) {
            form.span(first, second)?;
        }
        let (gradient, mollified) = match mollified {
            None => (form.gradient().map(|v| first * v), None),
            Some(m) => {
                let phi = kappa * barrier(g, dhat);
                (m.gradient(&form, phi, first), Some(phi))
            }
        };
        out.closed = Some(ClosedInputs {
            closest,
            first,
            second,
            mollified,
        });
        out.gradient = gradient;
        Some(true)
    }

    /// A pair's energy with its exact derivatives in the pair's twelve coordinates, the
    /// gradient alone ([`Gradient12`]) or with the Hessian ([`Dual12`]), the same bits
    /// for what both hold (`None` when the pair is beyond `dhat` or not admissible).
    fn pair_energy_dual<D: PairDual>(&self, kappa: f64, c: Candidate, x: &[DVec3]) -> Option<D> {
        let (kind, v) = self.pair(c);
        let p = v.map(|i| x[i]);
        let s = D::squared_distance(kind, &p);
        if s.value() <= 0.0 {
            return None;
        }
        let gap = s.sqrt().less(self.settings.thickness);
        let (g, dhat) = (gap.value(), self.settings.dhat);
        if g.is_nan() || g <= 0.0 || g >= dhat {
            return None;
        }
        let b = gap.chain_to(
            barrier(g, dhat),
            barrier_first_derivative(g, dhat),
            barrier_second_derivative(g, dhat),
        );
        let e = match self.mollifier_threshold(c) {
            Some(eps) => D::mollifier(&p, eps) * b,
            None => b,
        };
        Some(e.scaled(kappa))
    }

    /// Calls `f` with the derivatives of every pair with a barrier at `x` and, when `form`
    /// is given, their Hessians in that form (one per pair, in the same order; none when
    /// `None`, for the gradient): the active pairs' kept slots if the active set was
    /// collected at `x` (their Hessians computed first when they do not hold `form`'s),
    /// otherwise computed from the broad phase's pairs. The Hessians are kept apart from
    /// the slots: a slot is then a few cache lines that the gradient pass writes and
    /// reads in one stream, not a twelfth of a page most of which it skips.
    fn with_derivatives(
        &self,
        x: &[DVec3],
        fixed: &[bool],
        form: Option<HessianForm>,
        f: impl FnOnce(&[PairDerivatives], &[PairBlocks]),
    ) {
        let kappa = self.kappa();
        if self.active_at.as_slice() == x {
            let mut cache = self.cache.lock().unwrap_or_else(PoisonError::into_inner);
            if let Some(form) = form
                && cache.form != Some(form)
            {
                // The Hessians are taken out while the pool fills them, so no lock is held
                // across the parallel loop.
                let mut hessians = std::mem::take(&mut cache.hessians);
                let slots = std::mem::take(&mut cache.slots);
                let len = cache.len;
                drop(cache);
                // The storage only grows: every Hessian in use is overwritten whole.
                if hessians.len() < len {
                    hessians.resize(len, PairBlocks::default());
                }
                let active = &self.active;
                spread::for_each(&mut hessians[..len], |i, h| {
                    self.pair_hessian(kappa, active[i], x, &slots[i], form, h);
                });
                cache = self.cache.lock().unwrap_or_else(PoisonError::into_inner);
                cache.slots = slots;
                cache.hessians = hessians;
                cache.form = Some(form);
            }
            let hessians = if form.is_some() {
                &cache.hessians[..cache.len]
            } else {
                &[]
            };
            f(&cache.slots[..cache.len], hessians);
        } else {
            let near = self.near(x, fixed);
            let mut out = vec![PairDerivatives::default(); near.len()];
            spread::for_each(&mut out, |i, slot| {
                self.pair_derivatives(kappa, near[i], x, None, slot);
            });
            let mut hessians = Vec::new();
            if let Some(form) = form {
                hessians.resize(near.len(), PairBlocks::default());
                spread::for_each(&mut hessians, |i, h| {
                    self.pair_hessian(kappa, near[i], x, &out[i], form, h);
                });
            }
            f(&out, &hessians);
        }
    }

    /// Lags the friction of every pair within `dhat` at `x` (the step's start, or a
    /// round's minimizer; see [`super::friction`]), in the pairs' order: the active set's
    /// pairs and regions when it was collected at `x` with these fixed flags (a step
    /// starts where the last one ended; a minimization ends where its last active set
    /// was collected), else the broad phase's. Nothing without friction or stiffness.
    fn lag_friction(&mut self, step: &StepContext<'_>, x: &[DVec3]) {
        let mut friction = std::mem::take(&mut self.friction);
        friction.clear();
        let kappa = self.kappa();
        let fixed = step.system.fixed();
        if self.settings.mu > 0.0 && kappa > 0.0 {
            let near: Vec<(Candidate, Closest)> =
                if self.active_at.as_slice() == x && self.near_fixed.as_slice() == fixed {
                    self.active
                        .iter()
                        .copied()
                        .zip(self.active_regions.iter().copied())
                        .collect()
                } else {
                    let near = self.near(x, fixed);
                    let mut values = Vec::new();
                    spread::fill(&mut values, near.len(), NearValue::default(), |i| {
                        self.near_value(near[i], x)
                    });
                    near.iter()
                        .zip(&values)
                        .filter(|(_, v)| v.gap < self.settings.dhat)
                        .map(|(c, v)| (*c, v.closest))
                        .collect()
                };
            let mut lagged = Vec::new();
            spread::fill(&mut lagged, near.len(), None, |i| {
                self.lag_pair(kappa, near[i].0, near[i].1, step, x)
            });
            friction.extend(lagged.into_iter().flatten());
        }
        self.stats
            .friction_pairs
            .store(friction.len() as u64, Ordering::Relaxed);
        self.friction = friction;
        self.friction_scatter
            .get_mut()
            .unwrap_or_else(PoisonError::into_inner)
            .revision = None;
    }

    /// The friction of the pair `c`, whose closest points at the lag point `x` lie in
    /// `closest`: the barrier's normal force there, `-kappa m b'(gap)`, times `mu`
    /// (`None` when the pair's particles are all fixed or it exerts no force).
    fn lag_pair(
        &self,
        kappa: f64,
        c: Candidate,
        closest: Closest,
        step: &StepContext<'_>,
        x: &[DVec3],
    ) -> Option<FrictionPair> {
        let fixed = step.system.fixed();
        let q = self.placed(c, x);
        if q.v.iter().all(|&i| fixed[i]) {
            return None;
        }
        let (dhat, settings) = (self.settings.dhat, &self.settings);
        let gap = squared_distance_in(&values(&q.p), closest).sqrt() - settings.thickness;
        if !(gap > 0.0 && gap < dhat) {
            return None;
        }
        let m = self
            .mollifier_threshold(c)
            .map_or(1.0, |eps| mollifier(&q.p, eps));
        let lambda = -kappa * m * barrier_first_derivative(gap, dhat);
        FrictionPair::lagged(
            q.kind,
            q.v,
            closest,
            x,
            step.x_ref,
            settings.mu * lambda,
            settings.eps_v * step.h,
        )
    }

    /// The friction pairs' energy at `x`, summed in their order.
    fn friction_energy(&self, x: &[DVec3]) -> f64 {
        self.friction_sum(|pair| pair.energy(x))
    }

    /// `sum_i value(pair i)` over the friction pairs, in their order, each value
    /// computed on the pool into the kept storage.
    fn friction_sum(&self, value: impl Fn(&FrictionPair) -> f64 + Sync + Send) -> f64 {
        let mut kept = self
            .friction_values
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let values = &mut kept.0;
        spread::fill(values, self.friction.len(), 0.0, |i| {
            value(&self.friction[i])
        });
        values.iter().sum()
    }

    /// The friction pairs' energy change from `x` to `x + alpha dx`, summed in their
    /// order.
    fn friction_change(&self, x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64 {
        self.friction_sum(|pair| pair.energy_change(x, dx, alpha))
    }

    /// The largest safe fraction of the step `x -> x + dx` (see [`additive_ccd`]) over
    /// every pair the swept broad phase finds, 1 when none comes close.
    fn ccd_fraction(&self, x: &[DVec3], dx: &[DVec3], fixed: &[bool]) -> f64 {
        let keep = 1.0 - self.settings.toi_fraction;
        let thickness = self.settings.thickness;
        let margin = self.settings.dhat + thickness;
        // The smallest fraction found so far, shared by the sweeps (see
        // `additive_ccd_within`: the minimum over the pairs does not depend on the order
        // they finish in). Fractions are in [0, 1], where the order of an f64's bits is
        // the order of its values, so an integer minimum keeps it. It is written only
        // when a sweep ends below the limit it read (otherwise the minimum cannot
        // change), and sits on a cache line of its own: a locked write per pair kept the
        // line moving between the cores, and the sweeps waited on it most of their time.
        let smallest = SharedMinimum(AtomicU64::new(1.0f64.to_bits()));
        let sweep = |q: &Placed, d: &[DVec3; 4], lp: f64, gap0: f64| {
            smallest.sweep(q, d, lp, gap0, thickness, keep)
        };
        let mut segment = self.segment.lock().unwrap_or_else(PoisonError::into_inner);
        let seg = &mut *segment;
        if seg.query_into_found(&self.prims, x, Some(dx), margin, fixed) {
            // Per found pair its gap at `x` (kept once computed) and its safe fraction,
            // on the pool; the minimum does not depend on the order.
            let at_start = seg.starts_at(x);
            let (found, list, kept) = (&seg.found, seg.pairs.list(), &seg.kept);
            spread::fill(&mut seg.values, found.len(), (0.0, 0.0, 0.0), |i| {
                let (k, c) = (found[i], list[found[i]]);
                // A pair the separation shows clear needs no distance; its gap stays
                // unknown (NaN) unless it was known already. A kept gap comes with its
                // separation (the active set and an earlier sweep keep both).
                let q = self.placed(c, x);
                let sep = if at_start && !kept[k].separation.is_nan() {
                    kept[k].separation
                } else {
                    separation(q.kind, &q.p)
                };
                let d = q.v.map(|i| dx[i]);
                let lp = approach_bound(q.kind, &d);
                if clear_with_bound(sep, lp, thickness, keep) {
                    return (f64::NAN, sep, 1.0);
                }
                let gap0 = if at_start && !kept[k].gap.is_nan() {
                    kept[k].gap
                } else {
                    self.gap_of(&q)
                };
                (gap0, sep, sweep(&q, &d, lp, gap0))
            });
            if at_start {
                let values = &seg.values;
                spread::for_each_at(&mut seg.kept, &seg.found, |i, kept| {
                    let (gap0, sep, _) = values[i];
                    if !gap0.is_nan() {
                        kept.gap = gap0;
                    }
                    if !sep.is_nan() {
                        kept.separation = sep;
                    }
                });
            }
            // The shared minimum is the smallest fraction (and at most 1, where it
            // starts): a sweep that did not write it returned the limit it read, which is
            // at least the final minimum, and a pair shown clear gave 1.
            return f64::from_bits(smallest.0.load(Ordering::Relaxed));
        }
        drop(segment);
        self.stats.broad_phases.fetch_add(1, Ordering::Relaxed);
        let found = candidates(&self.prims, x, Some(dx), margin, fixed);
        self.ccd_fraction_of(&found, x, dx, &smallest)
    }

    /// The smallest safe fraction of the step `x -> x + dx` over the pairs `found`
    /// (at most 1), each pair's sweep stopping at `smallest`, the minimum found so far,
    /// which it lowers.
    fn ccd_fraction_of(
        &self,
        found: &[Candidate],
        x: &[DVec3],
        dx: &[DVec3],
        smallest: &SharedMinimum,
    ) -> f64 {
        let keep = 1.0 - self.settings.toi_fraction;
        let thickness = self.settings.thickness;
        let mut fractions = Vec::new();
        spread::fill(&mut fractions, found.len(), 0.0, |i| {
            let q = self.placed(found[i], x);
            let d = q.v.map(|i| dx[i]);
            let lp = approach_bound(q.kind, &d);
            if clear_with_bound(separation(q.kind, &q.p), lp, thickness, keep) {
                1.0
            } else {
                smallest.sweep(&q, &d, lp, self.gap_of(&q), thickness, keep)
            }
        });
        fractions.into_iter().fold(1.0, f64::min)
    }

    /// [`Term::max_step`] for a move of pinned particles alone (the driver's move of the
    /// pins before a step): only the pairs touching a moving particle are hashed and
    /// swept, since a pair whose particles all stand still keeps its distance and caps
    /// nothing. The segment's list is left as it was: no line search follows along
    /// this move.
    fn pinned_max_step(&self, x: &[DVec3], dx: &[DVec3], reach: f64, fixed: &[bool]) -> f64 {
        let margin = self.settings.dhat + self.settings.thickness;
        let moving: Vec<bool> = dx.iter().map(|d| *d != DVec3::ZERO).collect();
        let fraction = |dx: &[DVec3]| {
            self.stats.broad_phases.fetch_add(1, Ordering::Relaxed);
            let found = candidates_touching(&self.prims, x, Some(dx), margin, fixed, &moving);
            let smallest = SharedMinimum(AtomicU64::new(1.0f64.to_bits()));
            self.ccd_fraction_of(&found, x, dx, &smallest)
        };
        let t = fraction(dx);
        if t < 1.0 || reach <= 1.0 {
            return t;
        }
        let long: Vec<DVec3> = dx.iter().map(|d| LONG_STEP * *d).collect();
        (LONG_STEP * fraction(&long)).max(1.0)
    }
}

/// A pair with its kind, particles and their positions at one state
/// ([`SelfContactTerm::placed`]).
#[derive(Clone, Copy, Debug)]
struct Placed {
    c: Candidate,
    kind: PairKind,
    v: [usize; 4],
    p: [DVec3; 4],
}

/// A pair's values at the state the active set was collected at: its [`separation`],
/// and, unless that shows it beyond `dhat`, its gap and the region of its closest points
/// (else `+inf` and a placeholder region).
#[derive(Clone, Copy, Debug)]
struct NearValue {
    separation: f64,
    gap: f64,
    closest: Closest,
    /// The pair's energy there when a line-search trial computed it (with the stiffness
    /// the trial kept), else NaN.
    energy: f64,
}

impl Default for NearValue {
    fn default() -> Self {
        Self {
            separation: f64::NAN,
            gap: f64::INFINITY,
            closest: Closest::PointPoint([0, 1]),
            energy: f64::NAN,
        }
    }
}

/// The line-search segment's kept pairs ([`CandidateCache`]) and, per kept pair, its gap
/// and its energy at the segment's start `x` (the Newton iterate), taken from the active
/// set collected at `x` when there is one, else filled as they are first asked for: the
/// cap sweeps `x -> x + dx` and `x -> x + 8 dx` from it and every
/// trial's energy change subtracts the energy at it, so without these each pair's
/// distance at `x` was computed two to five times per Newton iteration. A value is the
/// one the same call computes from scratch (the same function of the same numbers), so
/// every answer is unchanged bit for bit.
#[derive(Debug, Default)]
struct Segment {
    pairs: CandidateCache,
    start: Vec<DVec3>,
    /// The barrier stiffness the energies were computed with.
    kappa: f64,
    /// Per listed pair, its values at the start (NaN where not computed yet).
    kept: Vec<Kept>,
    /// Scratch, its storage reused: a query's positions in the list, up to three values
    /// per found pair, and a trial's change of energy per found pair.
    found: Vec<usize>,
    changes: Vec<f64>,
    /// The query `found` answers, when it is valid (see [`Segment::query_into_found`]).
    asked: Asked,
    values: Vec<(f64, f64, f64)>,
    /// The two latest line-search trials on this list (the latest first): the line
    /// search may try a doubled step after the one it accepts.
    trials: [Trial; 2],
    /// Which list `pairs` is: a new list gets a new id, so positions found in an older
    /// one are not taken for positions in it.
    list_id: u64,
}

/// A listed pair's values at the segment's start: its [`separation`], its gap (NaN where
/// not computed, or where the separation showed the pair beyond `dhat`) and its energy
/// (NaN where not computed).
#[derive(Clone, Copy, Debug)]
struct Kept {
    separation: f64,
    gap: f64,
    energy: f64,
}

impl Default for Kept {
    fn default() -> Self {
        Self {
            separation: f64::NAN,
            gap: f64::NAN,
            energy: f64::NAN,
        }
    }
}

/// The values an active set computed at a segment's start, for the pairs at `positions`
/// (ascending) of the segment's list: each pair's separation and gap, and its energy
/// when `energies` (the values' energies were computed with the segment's stiffness).
struct Seed<'a> {
    positions: &'a [usize],
    values: &'a [NearValue],
    energies: bool,
    /// [`SelfContactTerm::beyond_dhat_by`]'s threshold.
    beyond: f64,
}

impl Seed<'_> {
    /// The kept values of a pair whose active-set values are `v`: a gap only where the
    /// active set computed it (not where the separation showed the pair beyond `dhat`),
    /// as the segment would have.
    fn kept(&self, v: &NearValue) -> Kept {
        let beyond = v.separation >= self.beyond;
        Kept {
            separation: v.separation,
            gap: if beyond { f64::NAN } else { v.gap },
            energy: if self.energies { v.energy } else { f64::NAN },
        }
    }
}

/// A line-search trial's state and, per pair its query found (positions in the
/// segment's list, ascending), the pair's values there and its energies at the trial's
/// state and at the segment's start.
#[derive(Debug, Default)]
struct Trial {
    at: Vec<DVec3>,
    /// The stiffness the trial's energies were computed with.
    kappa: f64,
    found: Vec<usize>,
    values: Vec<TrialValue>,
}

/// The query whose answer [`Segment::found`] holds (the storage reused).
#[derive(Debug, Default)]
struct Asked {
    valid: bool,
    margin: f64,
    swept: bool,
    at: Vec<DVec3>,
    sweep: Vec<DVec3>,
    fixed: Vec<bool>,
}

/// [`Trial`]'s values of one pair: its values at the trial's state (with its energy
/// there) and its energy at the segment's start.
#[derive(Clone, Copy, Debug, Default)]
struct TrialValue {
    near: NearValue,
    before: f64,
}

impl Segment {
    /// Keeps `pairs`, collected from `start`, with no values yet; the arrays' storage is
    /// reused.
    fn reset(&mut self, pairs: CandidateCache, start: &[DVec3], kappa: f64) {
        self.reset_seeded(pairs, start, kappa, None);
    }

    /// [`Self::reset`] with the values of `seed`, when given, for the listed pairs at
    /// its positions (ascending) in the list: written in the same pass over the kept
    /// values, on the pool, instead of blanking every value on one thread and then
    /// writing the seed's one by one.
    fn reset_seeded(
        &mut self,
        pairs: CandidateCache,
        start: &[DVec3],
        kappa: f64,
        seed: Option<Seed<'_>>,
    ) {
        let n = pairs.len();
        self.pairs = pairs;
        self.start.clear();
        self.start.extend_from_slice(start);
        self.kappa = kappa;
        // Every value is overwritten below.
        self.kept.truncate(n);
        self.kept.resize(n, Kept::default());
        spread::for_each_chunk(&mut self.kept, |first, chunk| {
            let Some(seed) = &seed else {
                chunk.fill(Kept::default());
                return;
            };
            let mut j = seed.positions.partition_point(|&k| k < first);
            for (k, kept) in (first..).zip(chunk.iter_mut()) {
                *kept = if seed.positions.get(j) == Some(&k) {
                    j += 1;
                    seed.kept(&seed.values[j - 1])
                } else {
                    Kept::default()
                };
            }
        });
        // The trials' positions may refer to the list replaced (and an active set at the
        // new start was collected before it), and so may the last query's answer.
        for t in &mut self.trials {
            t.at.clear();
        }
        self.asked.valid = false;
    }

    /// `found` set to the positions of the kept pairs the query (`x`, `dx`, `margin`,
    /// `fixed`) meets, as [`CandidateCache::query_indices_into`] (false when the list
    /// does not cover the query). The answer of the last query is taken again when this
    /// one is the same: the cap's sweep of the full step and the line search's first
    /// trial ask the same swept boxes (`alpha dx` is `dx` at `alpha = 1`), and so do the
    /// start's admissibility check and its energy change. The same inputs give the same
    /// boxes and so the same answer, bit for bit.
    fn query_into_found(
        &mut self,
        prims: &Primitives,
        x: &[DVec3],
        dx: Option<&[DVec3]>,
        margin: f64,
        fixed: &[bool],
    ) -> bool {
        let a = &self.asked;
        if a.valid
            && a.margin.to_bits() == margin.to_bits()
            && a.swept == dx.is_some()
            && a.at.as_slice() == x
            && dx.is_none_or(|d| a.sweep.as_slice() == d)
            && a.fixed.as_slice() == fixed
        {
            return true;
        }
        let covered = self
            .pairs
            .query_indices_into(prims, x, dx, margin, fixed, &mut self.found);
        let a = &mut self.asked;
        a.valid = covered;
        if covered {
            a.margin = margin;
            a.swept = dx.is_some();
            a.at.clear();
            a.at.extend_from_slice(x);
            a.sweep.clear();
            a.sweep.extend_from_slice(dx.unwrap_or(&[]));
            a.fixed.clear();
            a.fixed.extend_from_slice(fixed);
        }
        covered
    }

    fn starts_at(&self, x: &[DVec3]) -> bool {
        self.start.as_slice() == x
    }

    /// The latest trial made at `x` (its index in `trials`), if any.
    fn trial_at(&self, x: &[DVec3]) -> Option<usize> {
        (0..2).find(|&t| !self.trials[t].at.is_empty() && self.trials[t].at.as_slice() == x)
    }
}

/// Near pairs per task of an active set's selection of its pairs within `dhat`.
const ACTIVE_CHUNK: usize = 4096;

/// The longest multiple of the Newton step the cap looks along when the full step is
/// clear: the line search may lengthen an accepted step, and this lets it up to 8 times.
const LONG_STEP: f64 = 8.0;

impl SelfContactTerm {
    /// The barrier's part of [`Term::energy_change`].
    fn barrier_change(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64 {
        let kappa = self.kappa();
        if kappa == 0.0 {
            return 0.0;
        }
        let moved: Vec<DVec3> = x.iter().zip(dx).map(|(p, d)| *p + alpha * *d).collect();
        let sweep: Vec<DVec3> = dx.iter().map(|d| alpha * *d).collect();
        // Every pair within dhat at either end: the swept boxes contain both ends.
        let fixed = step.system.fixed();
        let margin = self.settings.dhat + self.settings.thickness;
        let mut change = 0.0;
        let mut segment = self.segment.lock().unwrap_or_else(PoisonError::into_inner);
        let seg = &mut *segment;
        if seg.query_into_found(&self.prims, x, Some(&sweep), margin, fixed) {
            // The energy at `x` is the same for every trial of the line search: kept (for
            // the stiffness it was computed with), and computed from the kept gap when
            // there is one, or zero when the kept separation shows the pair beyond `dhat`.
            // Each found pair's two energies on the pool, then the sum in the pairs'
            // order. The pair's values at the trial's state are kept with the trial (the
            // two latest), for the active set at that state if the trial is accepted.
            let at_start = seg.starts_at(x);
            let same_kappa = kappa.to_bits() == seg.kappa.to_bits();
            seg.trials.swap(0, 1);
            let trial = &mut seg.trials[0];
            trial.found.clear();
            trial.found.extend_from_slice(&seg.found);
            let (found, list, kept) = (&seg.found, seg.pairs.list(), &seg.kept);
            spread::fill(&mut trial.values, found.len(), TrialValue::default(), |i| {
                let (k, c) = (found[i], list[found[i]]);
                // The pair's energy at the trial's state from these values is
                // `pair_energy`'s (the same separation test, the same gap).
                let q = self.placed(c, &moved);
                let mut near = self.near_value_of(&q);
                near.energy = if self.beyond_dhat_by(near.separation) {
                    0.0
                } else {
                    self.energy_at_gap_of(kappa, &q, near.gap)
                };
                let kept = &kept[k];
                let before = if at_start && same_kappa && !kept.energy.is_nan() {
                    kept.energy
                } else if at_start && !kept.gap.is_nan() {
                    self.pair_energy_at_gap(kappa, c, x, kept.gap)
                } else if at_start && self.beyond_dhat_by(kept.separation) {
                    0.0
                } else {
                    self.pair_energy(kappa, c, x)
                };
                TrialValue { near, before }
            });
            trial.at = moved;
            trial.kappa = kappa;
            let values = &trial.values;
            if at_start && same_kappa {
                spread::for_each_at(&mut seg.kept, &seg.found, |i, kept| {
                    kept.energy = values[i].before;
                });
            }
            // Each pair's change on the pool (`+inf` where its energy after is, which
            // ends the sum), then the sum in the pairs' order on one thread over those
            // alone: the same additions as over the pairs' values.
            spread::fill(&mut seg.changes, values.len(), 0.0, |i| {
                let (after, before) = (values[i].near.energy, values[i].before);
                if after == f64::INFINITY {
                    f64::INFINITY
                } else {
                    after - before
                }
            });
            for &d in &seg.changes {
                if d == f64::INFINITY {
                    return f64::INFINITY;
                }
                change += d;
            }
            return change;
        }
        drop(segment);
        self.stats.broad_phases.fetch_add(1, Ordering::Relaxed);
        let found = candidates(&self.prims, x, Some(&sweep), margin, fixed);
        let mut values = Vec::new();
        spread::fill(&mut values, found.len(), (0.0, 0.0), |i| {
            (
                self.pair_energy(kappa, found[i], &moved),
                self.pair_energy(kappa, found[i], x),
            )
        });
        for (after, before) in values {
            if after == f64::INFINITY {
                return f64::INFINITY;
            }
            change += after - before;
        }
        change
    }

    /// The barrier's part of [`Term::add_gradient`].
    fn add_barrier_gradient(&self, step: &StepContext<'_>, x: &[DVec3], gradient: &mut [DVec3]) {
        let kappa = self.kappa();
        if kappa == 0.0 {
            return;
        }
        self.with_derivatives(x, step.system.fixed(), None, |pairs, _| {
            for e in pairs.iter().filter(|e| e.present) {
                for (k, &i) in e.particles.iter().enumerate() {
                    gradient[i] += DVec3::new(
                        e.gradient[3 * k],
                        e.gradient[3 * k + 1],
                        e.gradient[3 * k + 2],
                    );
                }
            }
        });
    }

    /// The barrier's part of [`Term::add_hessian`].
    fn add_barrier_hessian(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        curvature: Curvature,
        sink: &mut HessianSink<'_>,
    ) {
        let kappa = self.kappa();
        if kappa == 0.0 {
            return;
        }
        let form = match curvature {
            Curvature::Exact | Curvature::ExactContact(_) if self.settings.exact_hessian => {
                HessianForm::Exact
            }
            _ => HessianForm::Projected,
        };
        let code = match form {
            HessianForm::Exact => FORM_EXACT,
            HessianForm::Projected => FORM_PROJECTED,
        };
        if form == HessianForm::Exact {
            self.stats.exact_hessians.fetch_add(1, Ordering::Relaxed);
        }
        // What the Newton iteration asked for first at its iterate (the state the active
        // set was collected at), to count the fallbacks from the exact form.
        if self.active_at.as_slice() == x {
            let first = match self.first_asked.compare_exchange(
                FORM_NONE,
                code,
                Ordering::Relaxed,
                Ordering::Relaxed,
            ) {
                Ok(_) => code,
                Err(earlier) => earlier,
            };
            if form == HessianForm::Projected
                && first == FORM_EXACT
                && !self.fell_back.swap(true, Ordering::Relaxed)
            {
                self.stats
                    .projected_after_exact
                    .fetch_add(1, Ordering::Relaxed);
            }
        }
        let mut missing = Vec::new();
        self.with_derivatives(x, step.system.fixed(), Some(form), |pairs, hessians| {
            let Some((pattern, values)) = sink.values_mut() else {
                for (e, h) in pairs.iter().zip(hessians).filter(|(e, _)| e.present) {
                    scatter(h, e.kind, e.particles, sink, &mut missing);
                }
                return;
            };
            // The pattern look-ups (six binary searches a pair) on the pool, or taken from
            // the last active set's for the pairs it had; the additions by parts of the
            // matrix, each value's in the pairs' order, so the values are the bits of the
            // sequential scatter.
            let mut kept = self.places.lock().unwrap_or_else(PoisonError::into_inner);
            let listed = (self.active_at.as_slice() == x).then_some(self.active.as_slice());
            let places = kept.places_for(pattern, listed, pairs);
            scatter_in_parts(pattern, values, pairs, hessians, places, &mut missing);
        });
        if !missing.is_empty() {
            self.stats.note_missing(missing.into_iter());
        }
    }
}

/// More pairs within reach than this at the last step, and the step runs on the
/// integrator's pool whatever the system's size (see [`Term::wants_threads`]).
const WANTS_THREADS_PAIRS: usize = 512;

impl Term for SelfContactTerm {
    fn name(&self) -> &'static str {
        "self-contact"
    }

    fn wants_threads(&self) -> bool {
        // A small sheet on a finely meshed obstacle has a few hundred free particles and
        // thousands of pairs: 1.3 to 1.7 times faster on two threads, where the scenes
        // of at most 280 pairs were 5 to 15% slower (docs/bench/contact.md).
        self.stats.active_pairs() > WANTS_THREADS_PAIRS
    }

    fn take_missing_pairs(&mut self) -> Vec<[usize; 2]> {
        self.stats.take_missing_pairs()
    }

    fn check_start(&self, system: &SpringSystem, _time: f64) -> Result<(), StepError> {
        // The cap keeps every gap positive by induction from a start that has them
        // (docs/contact.md); from a state set by hand with a pair within the thickness
        // the barrier is infinite, no trial is accepted, and the step would grind
        // through every split to an unconverged end instead of saying why.
        let (x, fixed) = (system.positions(), system.fixed());
        // A step starts where the last one ended: the last active set was collected at
        // this state, with the same pairs and the same gaps (the same functions of the
        // same numbers), so its answer is this check's.
        let continued = self.active_at.as_slice() == x && self.near_fixed.as_slice() == fixed;
        let (min, touching) = if continued {
            let (min, touching) = self.near_summary;
            let name = |k: usize| (self.pair_name(self.near[k]), self.near_values[k].gap);
            (min, touching.map(name))
        } else {
            self.gaps_at(x, fixed)
        };
        if let Some((pair, gap)) = touching {
            return Err(StepError::SelfContactStart { pair, gap });
        }
        // A state the minimization visited crosses nothing (the cap's induction from a
        // start checked when the term was built, or here); any other start may, and its
        // gaps cannot tell. Only the pairs with a vertex moved since the last such state
        // can have come to cross (a driven move of the pinned particles moves a few),
        // when the fixed particles are the same (a pair of two fixed primitives, never
        // checked, may have one freed).
        if !continued {
            let moved: Option<Vec<bool>> = (self.active_at.len() == x.len()
                && self.near_fixed.as_slice() == fixed)
                .then(|| x.iter().zip(&self.active_at).map(|(a, b)| a != b).collect());
            if let Some(pair) = self.crossing_at(x, fixed, moved.as_deref()) {
                return Err(StepError::SelfContactCrossing { pair });
            }
        }
        let mut checked = self
            .checked_start
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        checked.0.clear();
        checked.0.extend_from_slice(x);
        checked.1 = Some(min);
        Ok(())
    }

    fn begin_step(&mut self, step: &StepContext<'_>) {
        let s = step.system;
        let (x, fixed) = (s.positions(), s.fixed());
        let dhat = self.settings.dhat;
        let settings = self.settings.kappa;
        if self.kappa.is_none() {
            let (sum, count) = s
                .masses()
                .iter()
                .zip(fixed)
                .filter(|(_, f)| !**f)
                .fold((0.0, 0usize), |(acc, n), (m, _)| (acc + m, n + 1));
            let mean = if count > 0 { sum / count as f64 } else { 1.0 };
            let kmin = minimum_kappa(dhat, mean, s.material().gravity.length(), step.h);
            self.kappa = Some(AdaptiveKappa::new(kmin, None, settings));
        }
        // A piece after the first starts where the checked state does not.
        let checked = self
            .checked_start
            .get_mut()
            .unwrap_or_else(PoisonError::into_inner);
        let min = match checked.1.take() {
            Some(min) if checked.0 == x => min,
            _ => self.min_gap(x, fixed),
        };
        if let Some(k) = self.kappa.as_mut() {
            k.update(min, dhat);
        }
        self.publish(min);
        self.lag_friction(step, x);
    }

    fn relag_friction(&mut self, step: &StepContext<'_>, x: &[DVec3]) -> bool {
        self.lag_friction(step, x);
        !self.friction.is_empty()
    }

    fn update_active_set(&mut self, step: &StepContext<'_>, x: &[DVec3]) {
        let fixed = step.system.fixed();
        let dhat = self.settings.dhat;
        let mut min = f64::INFINITY;
        // The lists' storage is reused from iteration to iteration: the derivatives of a
        // few ten thousand pairs are tens of megabytes, and fresh pages cost more to
        // fault in than to fill.
        let mut active = std::mem::take(&mut self.active);
        active.clear();
        let mut positions = std::mem::take(&mut self.near_positions);
        let mut values = std::mem::take(&mut self.near_values);
        let mut regions = std::mem::take(&mut self.active_regions);
        regions.clear();
        // A Newton iterate is usually the state the line search's accepted trial tried,
        // which computed its values there for every pair its query found: the pairs
        // whose boxes met along the trial's step, which hold every pair whose boxes meet
        // at its end (the near pairs' query here). Those are taken as the near pairs: the
        // ones more are farther than `dhat + thickness` (their boxes at `x`, grown by
        // half of that each, do not meet), so not active and not touching, and the
        // active set, its smallest gap and its first touching pair are the ones the
        // query's pairs give, bit for bit; the segment seeded from them gets the values
        // it would compute. The trial's query was on the segment's list (trials are
        // dropped with it) with these fixed flags (the list's).
        let seg = self
            .segment
            .get_mut()
            .unwrap_or_else(PoisonError::into_inner);
        let trial = seg.trial_at(x).filter(|_| seg.pairs.skips(fixed));
        let (near, near_list) = if let Some(t) = trial {
            let trial = &seg.trials[t];
            positions.clear();
            positions.extend_from_slice(&trial.found);
            let list = seg.pairs.list();
            let mut near = std::mem::take(&mut self.near);
            near.clear();
            near.extend(positions.iter().map(|&k| list[k]));
            // Their energies were computed with the trial's stiffness.
            self.near_kappa = trial.kappa;
            let kept = &trial.values;
            spread::fill(&mut values, kept.len(), NearValue::default(), |i| {
                kept[i].near
            });
            (near, Some(seg.list_id))
        } else {
            self.near_kappa = f64::NAN;
            let placed = self.pairs_placed(x, None, fixed, Some(&mut positions));
            let near = &placed.0;
            spread::fill(&mut values, near.len(), NearValue::default(), |i| {
                self.near_value(near[i], x)
            });
            placed
        };
        // The pairs within `dhat` in order, their smallest gap and the first pair at a
        // gap of zero or below (or NaN), by chunks on the pool, joined in order (the
        // minimum does not depend on the order).
        let parts = spread::map_chunks(near.len(), ACTIVE_CHUNK, |range| {
            let (mut pairs, mut closest) = (Vec::new(), Vec::new());
            let (mut min, mut touching) = (f64::INFINITY, None);
            for k in range {
                let v = &values[k];
                if v.gap < dhat {
                    pairs.push(near[k]);
                    closest.push(v.closest);
                    min = min.min(v.gap);
                }
                if touching.is_none() && (v.gap.is_nan() || v.gap <= 0.0) {
                    touching = Some(k);
                }
            }
            (pairs, closest, min, touching)
        });
        let mut touching = None;
        for (pairs, closest, part_min, part_touching) in parts {
            active.extend_from_slice(&pairs);
            regions.extend_from_slice(&closest);
            min = min.min(part_min);
            touching = touching.or(part_touching);
        }
        self.near = near;
        self.near_values = values;
        self.near_positions = positions;
        self.near_list = near_list;
        self.near_summary = (min, touching);
        self.near_fixed.clear();
        self.near_fixed.extend_from_slice(fixed);
        let kappa = self.kappa();
        self.first_asked.store(FORM_NONE, Ordering::Relaxed);
        self.fell_back.store(false, Ordering::Relaxed);
        let mut cache =
            std::mem::take(self.cache.get_mut().unwrap_or_else(PoisonError::into_inner));
        cache.len = 0;
        cache.form = None;
        if kappa > 0.0 {
            // The slots only grow: every one in use is overwritten whole.
            if cache.slots.len() < active.len() {
                cache.slots.resize(active.len(), PairDerivatives::default());
            }
            spread::for_each(&mut cache.slots[..active.len()], |i, slot| {
                self.pair_derivatives(kappa, active[i], x, Some(regions[i]), slot);
            });
            cache.len = active.len();
        }
        *self.cache.get_mut().unwrap_or_else(PoisonError::into_inner) = cache;
        self.active = active;
        self.active_regions = regions;
        self.active_at.clear();
        self.active_at.extend_from_slice(x);
        self.publish(min);
    }

    fn energy(&self, step: &StepContext<'_>, x: &[DVec3]) -> f64 {
        let kappa = self.kappa();
        if kappa == 0.0 {
            return 0.0;
        }
        let near = self.near(x, step.system.fixed());
        let mut energies = Vec::new();
        spread::fill(&mut energies, near.len(), 0.0, |i| {
            self.pair_energy(kappa, near[i], x)
        });
        let barrier: f64 = energies.into_iter().sum();
        if self.friction.is_empty() {
            barrier
        } else {
            barrier + self.friction_energy(x)
        }
    }

    fn energy_change(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], alpha: f64) -> f64 {
        let barrier = self.barrier_change(step, x, dx, alpha);
        if self.friction.is_empty() || barrier == f64::INFINITY {
            barrier
        } else {
            barrier + self.friction_change(x, dx, alpha)
        }
    }

    fn add_gradient(&self, step: &StepContext<'_>, x: &[DVec3], gradient: &mut [DVec3]) {
        self.add_barrier_gradient(step, x, gradient);
        if self.friction.is_empty() {
            return;
        }
        let mut kept = self
            .friction_values
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let pair_gradients = &mut kept.1;
        spread::fill(pair_gradients, self.friction.len(), DVec3::ZERO, |i| {
            self.friction[i].gradient(x)
        });
        for (pair, &g) in self.friction.iter().zip(pair_gradients.iter()) {
            for (&i, &w) in pair.particles.iter().zip(&pair.weights) {
                gradient[i] += w * g;
            }
        }
    }

    fn add_hessian(
        &self,
        step: &StepContext<'_>,
        x: &[DVec3],
        curvature: Curvature,
        sink: &mut HessianSink<'_>,
    ) {
        self.add_barrier_hessian(step, x, curvature, sink);
        if self.friction.is_empty() {
            return;
        }
        // Each pair's `w w^T (x) H`, positive semidefinite as it is (see
        // `super::friction`), scattered as the barrier's pairs are: by parts of the
        // matrix, with the places of the pairs' blocks looked up once per step and
        // pattern (the lagged pairs are the step's), not at every Newton iteration.
        let n = self.friction.len();
        let mut kept = self
            .friction_scatter
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let kept = &mut *kept;
        spread::fill(&mut kept.blocks, n, PairBlocks::default(), |i| {
            let pair = &self.friction[i];
            friction_blocks(&pair.weights, &pair.hessian(x))
        });
        let mut missing = Vec::new();
        if let Some((pattern, values)) = sink.values_mut() {
            if kept.revision != Some(pattern.revision) || kept.places.len() != n {
                let friction = &self.friction;
                spread::fill(&mut kept.places, n, [PairPlace::Skip; 6], |k| {
                    let v = friction[k].particles;
                    PAIR_BLOCKS.map(|(a, b)| PairPlace::find(pattern, v[a], v[b]))
                });
                kept.revision = Some(pattern.revision);
            }
            scatter_in_parts(
                pattern,
                values,
                &self.friction,
                &kept.blocks,
                &kept.places,
                &mut missing,
            );
        } else {
            for (pair, h) in self.friction.iter().zip(&kept.blocks) {
                scatter(h, pair.kind, pair.particles, sink, &mut missing);
            }
        }
        if !missing.is_empty() {
            self.stats.note_missing(missing.into_iter());
        }
    }

    fn gives_exact_contact(&self) -> bool {
        // A pair's exact Hessian differs from its projection (a point-plane or line-line
        // pair has negative eigenvalues wherever the barrier pushes); with no pair active
        // the two matrices are the same.
        self.settings.exact_hessian && self.kappa() > 0.0 && !self.active.is_empty()
    }

    fn max_step(&self, step: &StepContext<'_>, x: &[DVec3], dx: &[DVec3], reach: f64) -> f64 {
        let fixed = step.system.fixed();
        if dx.iter().zip(fixed).all(|(d, &f)| f || *d == DVec3::ZERO) {
            return self.pinned_max_step(x, dx, reach, fixed);
        }
        // One broad phase for the whole segment the line search may try, `x + [0,
        // LONG_STEP] dx`: the cap's two sweeps, every trial's energy change and the next
        // iterate's active set are queries inside it (docs/contact.md, "One broad phase
        // per Newton iteration").
        let long: Vec<DVec3> = dx.iter().map(|d| LONG_STEP * *d).collect();
        self.collect_segment(x, &long, fixed);
        if reach > 1.0 {
            // The longer path first: when it is clear for at least the full step (three
            // caps in four or more on the twist) its answer is the cap, and the step's
            // own sweep, which costs about as much (a sweep's cost follows the pairs
            // listed more than the path's length), is not needed.
            let longer = LONG_STEP * self.ccd_fraction(x, &long, fixed);
            if longer >= 1.0 {
                return longer;
            }
        }
        // Nothing beyond the step itself will be tried (a line search that does not
        // lengthen steps, an admissibility check), or ACCD along the longer path stopped
        // short of the full step: its conservative times may fall short of the step's
        // own, so the step itself is swept.
        self.ccd_fraction(x, dx, fixed).min(1.0)
    }
}

/// The dual numbers a pair's energy is differentiated with
/// ([`SelfContactTerm::pair_energy_dual`]): the same operations on both, so the
/// gradient of [`Gradient12`] is [`Dual12`]'s, bit for bit.
trait PairDual: Scalar {
    fn squared_distance(kind: PairKind, p: &[DVec3; 4]) -> Self;
    fn mollifier(p: &[DVec3; 4], eps_x: f64) -> Self;
    /// `phi(self)` given `phi`, `phi'` and `phi''` there.
    fn chain_to(&self, value: f64, first: f64, second: f64) -> Self;
    /// `self * s` for a constant `s`.
    fn scaled(&self, s: f64) -> Self;
    /// `self - c` for a constant `c` (the derivatives as they are).
    fn less(self, c: f64) -> Self;
}

impl PairDual for Dual12 {
    fn squared_distance(kind: PairKind, p: &[DVec3; 4]) -> Self {
        squared_distance_derivatives(kind, p)
    }
    fn mollifier(p: &[DVec3; 4], eps_x: f64) -> Self {
        mollifier_derivatives(p, eps_x)
    }
    fn chain_to(&self, value: f64, first: f64, second: f64) -> Self {
        self.chain(value, first, second)
    }
    fn scaled(&self, s: f64) -> Self {
        self.scale(s)
    }
    fn less(mut self, c: f64) -> Self {
        self.value -= c;
        self
    }
}

impl PairDual for Gradient12 {
    fn squared_distance(kind: PairKind, p: &[DVec3; 4]) -> Self {
        squared_distance_gradient(kind, p)
    }
    fn mollifier(p: &[DVec3; 4], eps_x: f64) -> Self {
        mollifier_gradient(p, eps_x)
    }
    fn chain_to(&self, value: f64, first: f64, _second: f64) -> Self {
        self.chain(value, first)
    }
    fn scaled(&self, s: f64) -> Self {
        self.scale(s)
    }
    fn less(mut self, c: f64) -> Self {
        self.value -= c;
        self
    }
}

/// Which Hessian of a pair is asked for: its projection onto positive semidefinite
/// matrices, or the exact one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
enum HessianForm {
    #[default]
    Projected,
    Exact,
}

/// An atomic alone on its cache lines (two, for the adjacent-line prefetcher), so the
/// threads reading it do not share a line with anything written.
#[repr(align(128))]
struct SharedMinimum(AtomicU64);

impl SharedMinimum {
    /// The pair's safe fraction of its step `d` up to the minimum so far (see
    /// `additive_ccd_within`), lowering the minimum when it is below it.
    fn sweep(
        &self,
        q: &Placed,
        d: &[DVec3; 4],
        lp: f64,
        gap0: f64,
        thickness: f64,
        keep: f64,
    ) -> f64 {
        let limit = f64::from_bits(self.0.load(Ordering::Relaxed));
        let fraction = additive_ccd_with_bound(q.kind, &q.p, d, lp, thickness, keep, gap0, limit);
        if fraction < limit {
            self.0.fetch_min(fraction.to_bits(), Ordering::Relaxed);
        }
        fraction
    }
}

/// [`SelfContactTerm::first_asked`]'s values.
const FORM_NONE: u8 = 0;
const FORM_PROJECTED: u8 = 1;
const FORM_EXACT: u8 = 2;

/// The active pairs' derivatives at the iterate the active set was collected at: only
/// the first `len` slots and Hessians are this iteration's (the storage is kept from
/// iteration to iteration), the Hessians in `form` (`None`: not computed yet, the
/// gradients only).
#[derive(Debug, Default)]
struct PairCache {
    slots: Vec<PairDerivatives>,
    hessians: Vec<PairBlocks>,
    len: usize,
    form: Option<HessianForm>,
}

/// The coupling block `n` of `h` ([`PAIR_BLOCKS`]' order).
fn coupling(h: &PairBlocks, n: usize) -> DMat3 {
    DMat3::from_cols_array(&h.coupling[n])
}

/// A pair's derivatives at one state (`present` false: the pair has none there).
#[derive(Clone, Debug)]
struct PairDerivatives {
    present: bool,
    kind: PairKind,
    particles: [usize; 4],
    gradient: [f64; 12],
    /// A closed-form pair's region and derivatives of its barrier in the squared
    /// distance (`None` for the dual numbers' pairs and pairs without derivatives), from
    /// which its Hessian is computed when asked for.
    closed: Option<ClosedInputs>,
}

/// What a closed-form pair's Hessian is built from at the state its gradient was:
/// the region of its closest points and `phi'(s)`, `phi''(s)` (see
/// [`RegionForm::span`]), and a mollified pair's `phi(s)`.
#[derive(Clone, Copy, Debug)]
struct ClosedInputs {
    closest: Closest,
    first: f64,
    second: f64,
    /// A mollified edge pair's barrier value `phi(s) = kappa b` (its mollifier is found
    /// again from the positions), `None` for the pairs without a mollifier.
    mollified: Option<f64>,
}

impl Default for PairDerivatives {
    fn default() -> Self {
        Self {
            present: false,
            kind: PairKind::PointTriangle,
            particles: [0; 4],
            gradient: [0.0; 12],
            closed: None,
        }
    }
}

/// The places of the coupling blocks of a list of pairs on a pattern, kept so the next
/// list (the next active set's, mostly the same pairs) looks up only its new pairs: on a
/// resting stack the look-ups (six binary searches in the matrix's structure a pair,
/// each reading a few cache lines of it) cost a fifth of the Newton matrix's assembly.
/// A place is a function of the pair's particles and the pattern alone, so a kept one is
/// the one a look-up would find.
#[derive(Debug, Default)]
struct KeptPlaces {
    /// The pattern's [`HessianPattern::revision`] (0: nothing kept).
    revision: u64,
    /// The pairs (sorted) and, in the same order, their places.
    pairs: Vec<Candidate>,
    places: Vec<[PairPlace; 6]>,
    /// Scratch: the new list's places, and per new pair its index in `pairs` (or
    /// `usize::MAX`).
    next: Vec<[PairPlace; 6]>,
    from: Vec<usize>,
}

impl KeptPlaces {
    /// The places of `slots`' coupling blocks on `pattern` (a pair not present gets
    /// [`PairPlace::Skip`]); `listed`: the pairs the slots are of (sorted), when they are
    /// the active set's, which are then kept for the next call.
    fn places_for(
        &mut self,
        pattern: &HessianPattern,
        listed: Option<&[Candidate]>,
        slots: &[PairDerivatives],
    ) -> &[[PairPlace; 6]] {
        let find = |e: &PairDerivatives| {
            PAIR_BLOCKS.map(|(a, b)| PairPlace::find(pattern, e.particles[a], e.particles[b]))
        };
        let Some(listed) = listed.filter(|l| l.len() == slots.len()) else {
            spread::fill(&mut self.next, slots.len(), [PairPlace::Skip; 6], |k| {
                let e = &slots[k];
                if e.present {
                    find(e)
                } else {
                    [PairPlace::Skip; 6]
                }
            });
            return &self.next;
        };
        let mut from = std::mem::take(&mut self.from);
        from.clear();
        if self.revision == pattern.revision {
            // Both lists are sorted: a merge.
            let old = &self.pairs;
            let mut j = 0;
            from.extend(listed.iter().map(|c| {
                while j < old.len() && old[j] < *c {
                    j += 1;
                }
                if j < old.len() && old[j] == *c {
                    j
                } else {
                    usize::MAX
                }
            }));
        } else {
            from.resize(listed.len(), usize::MAX);
        }
        let old = &self.places;
        // Every pair's places, present or not: a pair kept for a later list may be
        // present there.
        spread::fill(&mut self.next, slots.len(), [PairPlace::Skip; 6], |k| {
            if from[k] == usize::MAX {
                find(&slots[k])
            } else {
                old[from[k]]
            }
        });
        self.from = from;
        std::mem::swap(&mut self.places, &mut self.next);
        self.pairs.clear();
        self.pairs.extend_from_slice(listed);
        self.revision = pattern.revision;
        &self.places
    }
}

/// Which of a pair's six coupling blocks ([`PAIR_BLOCKS`]' order) are added, from
/// whether the pattern has each: all when it has every one, else those within each
/// primitive when it has all of these, else none (see the module documentation; for an
/// exact, indefinite Hessian the partial blocks carry no guarantee, and the matrix may
/// then be refused and the projected blocks asked for).
fn kept_blocks(kind: PairKind, has: [bool; 6]) -> [bool; 6] {
    let group = |k: usize| match kind {
        PairKind::PointTriangle => usize::from(k > 0),
        PairKind::EdgeEdge => usize::from(k > 1),
    };
    if has.iter().all(|&h| h) {
        return [true; 6];
    }
    let within = PAIR_BLOCKS.map(|(a, b)| group(a) == group(b));
    let keep_within = within.iter().zip(has).all(|(&w, h)| !w || h);
    within.map(|w| keep_within && w)
}

/// A pair whose Hessian blocks [`scatter_in_parts`] adds: a barrier pair's derivatives
/// or a friction pair.
trait Scattered {
    /// Whether the pair has blocks to add.
    fn present(&self) -> bool;
    /// Its kind and four particles.
    fn pair(&self) -> (PairKind, [usize; 4]);
}

impl Scattered for PairDerivatives {
    fn present(&self) -> bool {
        self.present
    }

    fn pair(&self) -> (PairKind, [usize; 4]) {
        (self.kind, self.particles)
    }
}

impl Scattered for FrictionPair {
    fn present(&self) -> bool {
        true
    }

    fn pair(&self) -> (PairKind, [usize; 4]) {
        (self.kind, self.particles)
    }
}

/// [`scatter`] of every present pair, in the pairs' order, straight into the values of
/// `pattern`, split into parts of consecutive block columns (one per thread of the
/// caller's pool): each part adds, pair after pair, the blocks that fall in its columns
/// (a diagonal block in its particle's, a coupling block in the lower particle's). Every
/// value gets the same additions in the same order as from the sequential scatter, so
/// the same bits for any number of parts; the parts share no value, so they run side by
/// side. The scatter on one thread was 8% of a resting stack's step.
fn scatter_in_parts<P: Scattered + Sync>(
    pattern: &HessianPattern,
    values: &mut [f64],
    pairs: &[P],
    hessians: &[PairBlocks],
    places: &[[PairPlace; 6]],
    missing: &mut Vec<[usize; 2]>,
) {
    let columns = pattern.free_particles.len();
    let col_ptr = pattern.symbolic.col_ptr();
    let mut missing = Some(missing);
    let n = spread::parts().min(columns.max(1));
    let mut parts = Vec::with_capacity(n);
    let mut rest = values;
    for p in 0..n {
        // Parts of equal width: on a stack of sheets the blocks split about evenly
        // (1.78 / 1.79 ms per part; bounds at quantiles of the blocks' columns were no
        // better balanced and cost their sampling).
        let (first, end) = (columns * p / n, columns * (p + 1) / n);
        let base = col_ptr[3 * first];
        let (part, tail) = std::mem::take(&mut rest).split_at_mut(col_ptr[3 * end] - base);
        // The first part also lists the particle pairs without slots, in the pairs' order.
        parts.push((first..end, base, part, missing.take()));
        rest = tail;
    }
    spread::each(parts, |(columns, base, part, mut missing)| {
        let pairs = pairs.iter().zip(hessians).zip(places);
        for ((e, h), place) in pairs.filter(|((e, _), _)| e.present()) {
            let (kind, particles) = e.pair();
            if let Some(missing) = missing.as_deref_mut() {
                missing.extend(
                    PAIR_BLOCKS
                        .iter()
                        .zip(place)
                        .filter(|&(_, p)| *p == PairPlace::Missing)
                        .map(|(&(a, b), _)| [particles[a], particles[b]]),
                );
            }
            for (k, &i) in particles.iter().enumerate() {
                let f = pattern.free_index[i];
                if columns.contains(&f) {
                    for (slot, v) in pattern.diag_slots[f].iter().zip(h.diagonal[k]) {
                        part[slot - base] += v;
                    }
                }
            }
            let keep = kept_blocks(kind, place.map(|p| p != PairPlace::Missing));
            for (n, p) in place.iter().enumerate() {
                let PairPlace::At { col, k, transposed } = *p else {
                    continue;
                };
                let (col, k) = (col as usize, k as usize);
                if !keep[n] || !columns.contains(&col) {
                    continue;
                }
                let b = &h.coupling[n];
                // The stored block (entry (r, c) at 3 c + r) is the given one, or its
                // transpose.
                for (e, slot) in pattern.off_block_slots_at(col, k).into_iter().enumerate() {
                    let (c, r) = (e / 3, e % 3);
                    part[slot - base] += if transposed {
                        b[3 * r + c]
                    } else {
                        b[3 * c + r]
                    };
                }
            }
        }
    });
}

/// The blocks of a friction pair's Hessian `w w^T (x) h`: block `(k, l)` is
/// `w_k w_l h`.
fn friction_blocks(w: &[f64; 4], h: &DMat3) -> PairBlocks {
    let mut out = PairBlocks::default();
    let entries = h.to_cols_array();
    for (k, d) in out.diagonal.iter_mut().enumerate() {
        let w2 = w[k] * w[k];
        let mut n = 0;
        for c in 0..3 {
            for r in c..3 {
                d[n] = w2 * entries[3 * c + r];
                n += 1;
            }
        }
    }
    for (n, &(a, b)) in PAIR_BLOCKS.iter().enumerate() {
        let wab = w[a] * w[b];
        out.coupling[n] = entries.map(|e| wab * e);
    }
    out
}

/// Adds a pair's Hessian `h` to `sink` (the blocks [`kept_blocks`] keeps, and the
/// diagonal blocks), looking each particle pair up in the sink; particle pairs without
/// slots are pushed to `missing`. [`scatter_in_parts`] is the same additions on a
/// sink's values with the places found beforehand.
fn scatter(
    h: &PairBlocks,
    kind: PairKind,
    v: [usize; 4],
    sink: &mut HessianSink<'_>,
    missing: &mut Vec<[usize; 2]>,
) {
    // Each pattern look-up once (a binary search per pair of particles).
    let has: [bool; 6] = PAIR_BLOCKS.map(|(a, b)| sink.has_pair(v[a], v[b]));
    missing.extend(
        PAIR_BLOCKS
            .iter()
            .zip(has)
            .filter(|&(_, h)| !h)
            .map(|(&(a, b), _)| [v[a], v[b]]),
    );
    for (k, &i) in v.iter().enumerate() {
        sink.add_diagonal(i, SymBlock(h.diagonal[k]));
    }
    let keep = kept_blocks(kind, has);
    for (n, (a, b)) in PAIR_BLOCKS.into_iter().enumerate() {
        if keep[n] {
            // The pattern has the pair (checked above), so this cannot fail.
            let _ = sink.add_pair(v[a], v[b], &coupling(h, n));
        }
    }
}

/// Adds self-contact of the cloth `system` with surface `triangles` to `integrator`, the
/// workspace of any implicit scheme ([`crate::Bdf2::newton_mut`],
/// [`crate::ImplicitMidpoint::newton_mut`]; see [`SelfContactTerm::new`] for the
/// checks), and returns the term's statistics. An integrator that has a self-contact
/// term already refuses a second ([`ContactError::AddedTwice`]).
pub fn enable_self_contact(
    integrator: &mut BackwardEuler,
    system: &SpringSystem,
    triangles: &[[usize; 3]],
    settings: SelfContactSettings,
) -> Result<Arc<SelfContactStats>, ContactError> {
    crate::contact::refuse_second(integrator, "self-contact")?;
    let (term, stats) = self_contact_term(system, triangles, settings)?;
    integrator.add_term(term);
    Ok(stats)
}

/// The self-contact term for `system` with surface `triangles`, checked as
/// [`SelfContactTerm::new`] checks it, ready for an implicit workspace, and its
/// statistics.
pub(crate) fn self_contact_term(
    system: &SpringSystem,
    triangles: &[[usize; 3]],
    settings: SelfContactSettings,
) -> Result<(Box<dyn Term>, Arc<SelfContactStats>), ContactError> {
    let term = SelfContactTerm::new(system, triangles, settings)?;
    let stats = term.stats();
    // Wrapped so the implicit midpoint evaluates it at the end state (the wrapper passes
    // straight through for backward Euler and BDF2).
    Ok((Box::new(AtEndOfStep::new(term)), stats))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::ClothGrid;

    /// The pairs' blocks added by parts of the matrix's columns give the bits of the
    /// sequential scatter through the sink's own look-ups (on values already holding
    /// others, as the springs' are), on one thread and split over pools of two and three:
    /// pairs in both orders of their particles (so some stored blocks are the
    /// transposes), with a pinned particle, with particle pairs the pattern lacks (only
    /// the blocks within each primitive, or only the diagonal ones, are added), and
    /// pairs not present.
    #[test]
    fn blocks_added_by_parts_are_the_sequential_scatters_bit_for_bit() {
        let system = SpringSystem::cloth(&ClothGrid::lab_sized(6, 0.1)).unwrap();
        let n = system.len();
        // Every particle pair (i, j) with i + j not a multiple of 7 has slots.
        let extra: Vec<[usize; 2]> = (0..n)
            .flat_map(|i| (i + 1..n).map(move |j| [i, j]))
            .filter(|[i, j]| (i + j) % 7 != 0)
            .collect();
        let pattern = HessianPattern::with_pairs(&system, &extra);
        // A Weyl sequence picks four distinct particles per pair.
        let mut w = 0.0f64;
        let mut next = |m: usize| {
            w = (w + 0.618_033_988_749_895) % 1.0;
            (w * m as f64) as usize
        };
        let mut pairs = Vec::new();
        let mut hessians = Vec::new();
        for k in 0..400 {
            let mut v = [0usize; 4];
            for s in 0..4 {
                v[s] = loop {
                    let p = next(n);
                    if !v[..s].contains(&p) {
                        break p;
                    }
                };
            }
            pairs.push(PairDerivatives {
                kind: if k % 2 == 0 {
                    PairKind::PointTriangle
                } else {
                    PairKind::EdgeEdge
                },
                particles: v,
                present: k % 11 != 3,
                ..PairDerivatives::default()
            });
            let mut h = PairBlocks::default();
            for (e, x) in h.diagonal.iter_mut().flatten().enumerate() {
                *x = ((k * 97 + e) as f64 * 0.37).sin();
            }
            for (e, x) in h.coupling.iter_mut().flatten().enumerate() {
                *x = ((k * 89 + e) as f64 * 0.53).cos();
            }
            hessians.push(h);
        }
        let places: Vec<[PairPlace; 6]> = pairs
            .iter()
            .map(|e| {
                PAIR_BLOCKS.map(|(a, b)| PairPlace::find(&pattern, e.particles[a], e.particles[b]))
            })
            .collect();
        let start: Vec<f64> = (0..pattern.nnz())
            .map(|k| (k as f64 * 0.11).sin())
            .collect();
        let mut sequential = start.clone();
        let mut missing = Vec::new();
        let mut sink = HessianSink::values(&pattern, &mut sequential);
        for (e, h) in pairs.iter().zip(&hessians).filter(|(e, _)| e.present) {
            scatter(h, e.kind, e.particles, &mut sink, &mut missing);
        }
        assert!(
            !missing.is_empty(),
            "every pair has its slots: the case tests less"
        );
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let parted = || {
            let (mut values, mut missing) = (start.clone(), Vec::new());
            scatter_in_parts(
                &pattern,
                &mut values,
                &pairs,
                &hessians,
                &places,
                &mut missing,
            );
            (bits(&values), missing)
        };
        assert_eq!(parted(), (bits(&sequential), missing.clone()));
        #[cfg(feature = "parallel")]
        for threads in [2, 3] {
            let on_pool = spread::pool(threads).install(|| (spread::parts(), parted()));
            assert_eq!(on_pool, (threads, (bits(&sequential), missing.clone())));
        }
        assert_ne!(bits(&sequential), bits(&start));
    }
}
