//! The two questions every pass that may run on the integrator's thread pool asks: is
//! the caller on a pool with another thread to share the work with, and run these two
//! pieces side by side there. Without the `parallel` feature there is no pool, and the
//! pieces run in turn on the calling thread.

/// Whether the caller runs on a rayon pool of more than one thread (never without the
/// `parallel` feature).
#[must_use]
pub(crate) fn shared() -> bool {
    #[cfg(feature = "parallel")]
    return rayon::current_thread_index().is_some() && rayon::current_num_threads() > 1;
    #[cfg(not(feature = "parallel"))]
    false
}

/// `(a(), b())`: side by side on the caller's pool when `parallel` (the calling thread
/// runs `a` and then helps with what `b` spread over the pool), else in turn.
pub(crate) fn join_if<A: Send, B: Send>(
    parallel: bool,
    a: impl FnOnce() -> A + Send,
    b: impl FnOnce() -> B + Send,
) -> (A, B) {
    #[cfg(feature = "parallel")]
    if parallel {
        return rayon::join(a, b);
    }
    let _ = parallel;
    (a(), b())
}
