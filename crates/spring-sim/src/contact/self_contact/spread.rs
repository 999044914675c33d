//! The self-contact term's per-pair work spread over the integrator's thread pool.
//!
//! Backward Euler runs its whole minimization inside its thread pool when it has one
//! (`NewtonSettings::threads` above 1 and a system above the pool's size), so the term's
//! methods are called from one of the pool's threads. The term then splits its per-pair
//! loops (distances, energies, CCD, derivatives, the kept list's box tests) into fixed
//! chunks of pairs on that pool; called from any other thread (no pool: one thread, a
//! small system, or a caller running the term alone) it runs them in turn on the
//! calling thread.
//!
//! Every spread loop writes one value per pair into its own slot, a function of that
//! pair alone; sums and minimums over the pairs are then taken on one thread in the
//! pairs' order, as the sequential loops take them. So the results are the same bits
//! whatever the number of threads, and the same as the loops before they were spread.

/// Pairs per task: large enough that a task's cost (a few microseconds per pair) hides
/// the hand-off, small enough that two threads end within a small fraction of a loop of
/// a few thousand pairs of each other.
#[cfg(feature = "parallel")]
const CHUNK: usize = 256;

/// Whether the caller runs on a thread pool of more than one thread (see the module
/// documentation).
#[cfg(feature = "parallel")]
use crate::pool::shared as on_pool;

/// Calls `f(i, &mut out[i])` for every `i`, in chunks on the caller's pool when there is
/// one.
pub(crate) fn for_each<T: Send>(out: &mut [T], f: impl Fn(usize, &mut T) + Sync + Send) {
    #[cfg(feature = "parallel")]
    if out.len() > CHUNK && on_pool() {
        use rayon::prelude::*;
        out.par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(c, chunk)| {
                for (i, slot) in chunk.iter_mut().enumerate() {
                    f(c * CHUNK + i, slot);
                }
            });
        return;
    }
    for (i, slot) in out.iter_mut().enumerate() {
        f(i, slot);
    }
}

/// How many parts a pass that splits its output by destination takes: the pool's
/// threads when the caller runs on a pool (see the module documentation), else one.
pub(crate) fn parts() -> usize {
    #[cfg(feature = "parallel")]
    if on_pool() {
        return rayon::current_num_threads();
    }
    1
}

/// Calls `f` on every part, as tasks on the caller's pool when there is one, else in
/// turn on the calling thread.
pub(crate) fn each<T: Send>(parts: Vec<T>, f: impl Fn(T) + Sync + Send) {
    #[cfg(feature = "parallel")]
    if parts.len() > 1 && on_pool() {
        use rayon::prelude::*;
        parts.into_par_iter().for_each(f);
        return;
    }
    parts.into_iter().for_each(f);
}

/// Calls `f(first, chunk)` for consecutive chunks of `out` (`first` the index of the
/// chunk's first element), on the caller's pool when there is one, else once with the
/// whole of `out`: `f` must treat a range alike whether it is given whole or in pieces.
pub(crate) fn for_each_chunk<T: Send>(out: &mut [T], f: impl Fn(usize, &mut [T]) + Sync + Send) {
    #[cfg(feature = "parallel")]
    if out.len() > CHUNK && on_pool() {
        use rayon::prelude::*;
        // Chunks of a few pages: the callers' work per element is a few loads and stores.
        const ELEMENTS: usize = 16 * CHUNK;
        out.par_chunks_mut(ELEMENTS)
            .enumerate()
            .for_each(|(c, chunk)| f(c * ELEMENTS, chunk));
        return;
    }
    f(0, out);
}

/// `out` refilled with `f(i)` for `i` in `0..n` (its storage reused), in chunks on the
/// caller's pool when there is one. Only slots beyond the old length are first set to
/// `blank`: every slot is overwritten, and blanking the whole list on one thread first
/// (megabytes, for the pairs of a large contact) cost as much as a cheap pass itself.
pub(crate) fn fill<T: Send + Clone>(
    out: &mut Vec<T>,
    n: usize,
    blank: T,
    f: impl Fn(usize) -> T + Sync + Send,
) {
    out.truncate(n);
    out.resize(n, blank);
    for_each(out, |i, slot| *slot = f(i));
}

/// The indices `i` in `0..n` for which `keep(i)` holds, ascending, into `out` (cleared
/// first), with the tests in chunks on the caller's pool when there is one.
pub(crate) fn filter_indices(
    n: usize,
    out: &mut Vec<usize>,
    keep: impl Fn(usize) -> bool + Sync + Send,
) {
    out.clear();
    #[cfg(feature = "parallel")]
    if n > CHUNK && on_pool() {
        use rayon::prelude::*;
        let parts: Vec<Vec<usize>> = (0..n.div_ceil(CHUNK))
            .into_par_iter()
            .map(|c| {
                (c * CHUNK..((c + 1) * CHUNK).min(n))
                    .filter(|&i| keep(i))
                    .collect()
            })
            .collect();
        for part in parts {
            out.extend_from_slice(&part);
        }
        return;
    }
    out.extend((0..n).filter(|&i| keep(i)));
}

/// `f(range)` for the consecutive ranges of `chunk` indices covering `0..n`, in the
/// ranges' order: as tasks on the caller's pool when there is one, else the whole range
/// at once (one result). So a caller combining the results must get the same from the
/// pieces of a range as from the range whole.
pub(crate) fn map_chunks<R: Send>(
    n: usize,
    chunk: usize,
    f: impl Fn(std::ops::Range<usize>) -> R + Sync + Send,
) -> Vec<R> {
    #[cfg(feature = "parallel")]
    if n > chunk && on_pool() {
        use rayon::prelude::*;
        return (0..n.div_ceil(chunk))
            .into_par_iter()
            .map(|c| f(c * chunk..((c + 1) * chunk).min(n)))
            .collect();
    }
    let _ = chunk;
    vec![f(0..n)]
}

/// Calls `f(i, &mut out[positions[i]])` for every `i`, `positions` ascending and
/// distinct: the writes of a sparse set of slots, spread over the pool by chunks of
/// `out` (each chunk finds its first position by bisection), else in turn.
pub(crate) fn for_each_at<T: Send>(
    out: &mut [T],
    positions: &[usize],
    f: impl Fn(usize, &mut T) + Sync + Send,
) {
    for_each_chunk(out, |first, chunk| {
        let mut i = positions.partition_point(|&k| k < first);
        while let Some(&k) = positions.get(i)
            && k < first + chunk.len()
        {
            f(i, &mut chunk[k - first]);
            i += 1;
        }
    });
}

/// `out` extended by what `f(range, part)` appends to `part` for the consecutive ranges of
/// `chunk` indices covering `0..n`, in the ranges' order: the ranges as tasks on the
/// caller's pool when there is one (each appends to its own list, joined in order), else
/// the whole range at once. So `f` must append for a range what it appends for its
/// pieces one after another; the result then does not depend on the threads.
pub(crate) fn concat_chunks<T: Send>(
    out: &mut Vec<T>,
    n: usize,
    chunk: usize,
    f: impl Fn(std::ops::Range<usize>, &mut Vec<T>) + Sync + Send,
) {
    #[cfg(feature = "parallel")]
    if n > chunk && on_pool() {
        use rayon::prelude::*;
        let parts: Vec<Vec<T>> = (0..n.div_ceil(chunk))
            .into_par_iter()
            .map(|c| {
                let mut part = Vec::new();
                f(c * chunk..((c + 1) * chunk).min(n), &mut part);
                part
            })
            .collect();
        for mut part in parts {
            out.append(&mut part);
        }
        return;
    }
    let _ = chunk;
    f(0..n, out);
}

/// A pool of `threads` threads for the tests that compare a pass on pools of several
/// sizes with the calling thread's.
#[cfg(all(test, feature = "parallel"))]
pub(crate) fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("a test's thread pool")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sparse writes and the chunks' results are the same on a pool of two or three
    /// threads as on the calling thread: every position written once with its own index,
    /// the others untouched, and the chunks' results joined in order cover `0..n` in
    /// order (positions near the chunks' edges included).
    #[test]
    fn sparse_writes_and_chunk_results_do_not_depend_on_the_threads() {
        let n = 40 * 256 + 17;
        let positions: Vec<usize> = (0..n).filter(|k| k % 7 == 3 || k % 4096 == 0).collect();
        let run = || {
            let mut out = vec![usize::MAX; n];
            for_each_at(&mut out, &positions, |i, slot| *slot = i);
            let parts = map_chunks(n, 1000, |range| {
                range.filter(|k| k % 5 == 1).collect::<Vec<_>>()
            });
            (out, parts.concat())
        };
        let (out, picked) = run();
        for (i, &k) in positions.iter().enumerate() {
            assert_eq!(out[k], i);
        }
        assert_eq!(
            out.iter().filter(|&&v| v != usize::MAX).count(),
            positions.len()
        );
        assert_eq!(picked, (0..n).filter(|k| k % 5 == 1).collect::<Vec<_>>());
        #[cfg(feature = "parallel")]
        for threads in [2, 3] {
            let on = pool(threads).install(|| (on_pool(), run()));
            assert_eq!(on, (true, (out.clone(), picked.clone())));
        }
    }
}
