//! Velocity Verlet's packed substeps ([`super::packed`]) on several threads: the
//! particles cut into contiguous ranges, one [`Part`] per thread, each stepped in its
//! own packed layout.
//!
//! A part holds every spring with an end among its own particles, so each own particle
//! receives all its springs' terms, in the system's order, from its own thread: the same
//! sums as the single-threaded loop, bit for bit, whatever the number of parts. A spring
//! between two parts is computed by both. Between a substep's particle pass and its
//! springs, each part copies the positions and velocities of its halo (the other ends
//! of its cut springs) from the parts that own them; that copy is the only exchange.
//!
//! The design and the measurements are in docs/spring-sim.md ("Velocity Verlet's
//! packed layout on several threads").

use super::packed::{Instance, Packed, Part, Pass};
use crate::model::SpringSystem;
use sinew_math::DVec3;

/// The parts of a system and what ties them together.
#[derive(Clone, Debug, Default)]
pub(super) struct Parts {
    parts: Vec<Packed>,
    /// The first particle of each part's own range, and the system's particle count
    /// last.
    starts: Vec<usize>,
    /// For each part, each halo particle's owner and its local index there, in the
    /// part's halo order.
    halo: Vec<Vec<(usize, usize)>>,
    /// For each of the system's springs in order, the part that reports its energy (the
    /// one owning its first end) and its place in that part's schedule.
    energy_slots: Vec<(usize, usize)>,
    /// Whether the layouts hold the end state of the last step, as stored.
    hold_end: bool,
}

impl Parts {
    /// `count` parts of `system` (at least one, at most one per particle), cut where
    /// the running count of spring ends reaches each part's share, so each part adds
    /// about as many terms.
    pub(super) fn new(system: &SpringSystem, count: usize) -> Self {
        Self::with_instance(system, count, Instance::Detect)
    }

    /// [`Self::new`] with the packed layout's `instance`.
    pub(super) fn with_instance(system: &SpringSystem, count: usize, instance: Instance) -> Self {
        let n = system.len();
        let springs = system.springs();
        let count = count.clamp(1, n.max(1));
        let mut degree = vec![0_usize; n];
        for s in springs {
            degree[s.a] += 1;
            degree[s.b] += 1;
        }
        let total: usize = degree.iter().sum();
        // Part `p` starts at the first particle whose preceding ends reach `p / count`
        // of all ends (and at least one particle after the previous start).
        let mut starts = vec![0];
        let mut before = 0;
        for (i, &d) in degree.iter().enumerate() {
            let p = starts.len();
            if p < count && i > starts[p - 1] && before * count >= p * total {
                starts.push(i);
            }
            before += d;
        }
        while starts.len() < count {
            // Fewer ends than parts: the remaining parts start one particle apart.
            let next = starts[starts.len() - 1] + 1;
            starts.push(next);
        }
        starts.push(n);
        let owner = |i: usize| starts.partition_point(|&s| s <= i) - 1;
        let mut parts = Vec::with_capacity(count);
        let mut halo = Vec::with_capacity(count);
        for p in 0..count {
            let (lo, hi) = (starts[p], starts[p + 1]);
            let mine = |i: usize| (lo..hi).contains(&i);
            let mut halo_of_part: Vec<usize> = Vec::new();
            let mut part_springs = Vec::new();
            for (k, s) in springs.iter().enumerate() {
                if mine(s.a) || mine(s.b) {
                    part_springs.push(k);
                    for end in [s.a, s.b] {
                        if !mine(end) {
                            halo_of_part.push(end);
                        }
                    }
                }
            }
            halo_of_part.sort_unstable();
            halo_of_part.dedup();
            let mut particles: Vec<usize> = (lo..hi).collect();
            particles.extend(&halo_of_part);
            let local_of = |i: usize| {
                if mine(i) {
                    i - lo
                } else {
                    // The halo is sorted.
                    (hi - lo) + halo_of_part.binary_search(&i).expect("an end in the halo")
                }
            };
            let ends = part_springs
                .iter()
                .map(|&k| (local_of(springs[k].a), local_of(springs[k].b)))
                .collect();
            halo.push(
                halo_of_part
                    .iter()
                    .map(|&i| {
                        let q = owner(i);
                        (q, i - starts[q])
                    })
                    .collect(),
            );
            parts.push(Packed::for_part(
                instance,
                Part {
                    particles,
                    own: hi - lo,
                    springs: part_springs,
                    ends,
                },
            ));
        }
        Self {
            parts,
            starts,
            halo,
            energy_slots: Vec::new(),
            hold_end: false,
        }
    }

    /// How many parts.
    #[cfg(test)]
    pub(super) fn len(&self) -> usize {
        self.parts.len()
    }

    /// `substeps` Verlet substeps of `dt` of the state `x`, `v` with minus its forces
    /// `neg_forces` (evaluated first unless `kept`), written back into those buffers;
    /// returns the springs' elastic energy at the end state, summed in the system's
    /// spring order (the same bits as [`SpringSystem::energies`]' spring part).
    ///
    /// The parts run on the threads of the rayon pool the caller installed.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn step(
        &mut self,
        system: &SpringSystem,
        inv_mass: &[f64],
        x: &mut [DVec3],
        v: &mut [DVec3],
        neg_forces: &mut [DVec3],
        kept: bool,
        dt: f64,
        substeps: usize,
    ) -> f64 {
        let c = system.material().damping;
        // Kept forces are those of the end state the parts stored last, which their
        // layouts still hold bit for bit (own particles; the halo is copied before it is
        // read): the state is loaded only when it may differ.
        let load = !(kept && self.hold_end);
        {
            let (x, v, f) = (&*x, &*v, &*neg_forces);
            each(&mut self.parts, |p| {
                p.prepare(system, inv_mass, dt);
                if load {
                    p.load_state(x, v, f);
                }
                if !kept {
                    p.run(c, dt, Pass::Evaluate);
                }
                p.run(c, dt, Pass::Particles { closing: false });
            });
        }
        if self.energy_slots.is_empty() && !system.springs().is_empty() {
            self.energy_slots = self.energy_slots(system);
        }
        for substep in 0..substeps {
            self.exchange();
            let last = substep + 1 == substeps;
            each(&mut self.parts, |p| {
                p.run(c, dt, Pass::Springs { energy: last });
                let next = if last {
                    Pass::CloseKick
                } else {
                    Pass::Particles { closing: true }
                };
                p.run(c, dt, next);
            });
        }
        store(&self.parts, &self.starts, x, v, neg_forces);
        self.hold_end = true;
        self.energy_slots
            .iter()
            .map(|&(p, slot)| self.parts[p].energy(slot))
            .sum()
    }

    /// Copies every halo particle's position and velocity from the part that owns it.
    fn exchange(&mut self) {
        for (p, halo) in self.halo.iter().enumerate() {
            let own = self.starts[p + 1] - self.starts[p];
            for (j, &(q, i)) in halo.iter().enumerate() {
                let state = self.parts[q].particle(i);
                self.parts[p].set_particle(own + j, state);
            }
        }
    }

    /// For each spring of the system, the part that reports its energy and its place in
    /// that part's schedule (built after the first load, which schedules the parts).
    fn energy_slots(&self, system: &SpringSystem) -> Vec<(usize, usize)> {
        let mut slots = vec![(0, 0); system.springs().len()];
        for (p, part) in self.parts.iter().enumerate() {
            let held = part.part().expect("a part");
            let own = self.starts[p]..self.starts[p + 1];
            for (k, slot) in held.springs.iter().zip(part.slots()) {
                if own.contains(&system.springs()[*k].a) {
                    slots[*k] = (p, slot);
                }
            }
        }
        slots
    }
}

/// Each part's own particles into the stepper's buffers, the parts on the installed rayon
/// pool's threads. The parts' own ranges are contiguous (`starts[p]..starts[p + 1]`, and
/// `starts` has one entry more than `parts`), so the buffers are cut in halves with the
/// parts, each half stored by a `rayon::join` branch: no list of the pieces is built per
/// step.
fn store(parts: &[Packed], starts: &[usize], x: &mut [DVec3], v: &mut [DVec3], f: &mut [DVec3]) {
    match parts {
        [] => return,
        [part] => return part.store(x, v, f),
        _ => {}
    }
    let mid = parts.len() / 2;
    let cut = starts[mid] - starts[0];
    let (parts_l, parts_r) = parts.split_at(mid);
    let (x_l, x_r) = x.split_at_mut(cut);
    let (v_l, v_r) = v.split_at_mut(cut);
    let (f_l, f_r) = f.split_at_mut(cut);
    rayon::join(
        || store(parts_l, &starts[..=mid], x_l, v_l, f_l),
        || store(parts_r, &starts[mid..], x_r, v_r, f_r),
    );
}

/// Runs `op` on every item, on the installed rayon pool's threads.
fn each<T: Send>(items: &mut [T], op: impl Fn(&mut T) + Sync + Send) {
    use rayon::prelude::*;
    items.par_iter_mut().for_each(op);
}
