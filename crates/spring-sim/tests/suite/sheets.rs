//! Cloth sheets one above the other: the set-up of the self-contact tests and of the
//! self-contact bench (which includes this file), so the bench's table is measured on the
//! tests' scene.

use sinew_spring_sim::{Bending, ClothGrid, DVec3, Material, MeshCloth};

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

/// Two `n x n` sheets in one particle list: the bottom one flat in the xz plane from the
/// origin with spacing `s`, then the top one from `top` along `u` and `w` with spacing
/// `top_s`.
pub fn stacked(
    n: usize,
    s: f64,
    top: DVec3,
    u: DVec3,
    w: DVec3,
    top_s: f64,
) -> (Vec<DVec3>, Vec<[usize; 3]>) {
    let (mut x, mut t) = grid(n, DVec3::ZERO, DVec3::X, DVec3::Z, s, 0);
    let (xt, tt) = grid(n, top, u, w, top_s, x.len());
    x.extend(xt);
    t.extend(tt);
    (x, t)
}

/// A sheet dropped onto a sheet pinned along its border: the bottom one of spacing `s`,
/// the top one 2 cm up, shifted so no vertex is above a vertex, turned by 0.1 rad about
/// the vertical, of spacing `0.8 s`. The positions, the triangles and the pinned
/// particles.
pub fn dropped(n: usize, s: f64) -> (Vec<DVec3>, Vec<[usize; 3]>, Vec<usize>) {
    let (x, t) = stacked(
        n,
        s,
        DVec3::new(0.03, 0.02, 0.02),
        DVec3::new(0.995, 0.0, 0.0998),
        DVec3::new(-0.0998, 0.0, 0.995),
        0.8 * s,
    );
    let border = (0..n * n)
        .filter(|k| k / n == 0 || k / n == n - 1 || k % n == 0 || k % n == n - 1)
        .collect();
    (x, t, border)
}

/// The sheets' cloth: areal density 0.2, stiffness 500, damping 0.1, gravity 9.81 down,
/// no bending, the particles `fixed` held.
pub fn cloth(fixed: Vec<usize>) -> MeshCloth {
    MeshCloth {
        areal_density: 0.2,
        material: Material {
            stiffness: 500.0,
            damping: 0.1,
            gravity: DVec3::new(0.0, -9.81, 0.0),
        },
        bending: Bending::None,
        fixed,
    }
}
