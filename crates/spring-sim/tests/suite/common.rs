//! Set-ups shared by several test modules.

use sinew_spring_sim::{ClothGrid, DVec3};

/// An `n x n` grid of points `origin + s (i u + j w)` and its triangles, indices offset
/// by `offset` (so several sheets share one particle list).
pub fn grid(
    n: usize,
    origin: DVec3,
    u: DVec3,
    w: DVec3,
    s: f64,
    offset: usize,
) -> (Vec<DVec3>, Vec<[usize; 3]>) {
    ClothGrid {
        size: n,
        spacing: s,
        origin,
        ..ClothGrid::lab()
    }
    .sheet(u, w, offset)
}

/// The threads a solver asked for `threads` runs on: those, or the calling thread alone
/// when the crate is built without its `parallel` feature (the thread-count tests then
/// still compare the runs, which must agree all the more).
pub fn expected_threads(threads: usize) -> usize {
    if cfg!(feature = "parallel") {
        threads
    } else {
        1
    }
}
