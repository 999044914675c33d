//! Writes `scenes/data/table.obj`, a closed box to drape cloth over (a table top), to
//! standard output:
//!
//! ```text
//! cargo run -p sinew-io --example table_obj > scenes/data/table.obj
//! ```
//!
//! The box spans x and z from -0.25 to 0.25 and y from 0.35 to 0.40. Its surface is the
//! boundary of a lattice of spacing 0.05 (11 x 2 x 11 points): every lattice point on the
//! surface is a vertex (listed in the order of `x`, then `y`, then `z`), and every face of
//! the box is a grid of 0.05 x 0.05 quads, wound so that their normals point out of the
//! box (the reader fans each quad into two triangles). Its twelve edges are sharp, which
//! no sphere or capsule collider has.
//!
//! An optional whole number `k` (default 1) divides the spacing: `table_obj 5` writes the
//! same box with faces of 0.01 x 0.01 quads (51 x 6 x 51 lattice points), an obstacle
//! meshed far more finely than the cloth dropped on it, for measuring what that costs
//! (docs/bench/contact.md, "A small cloth on a finely meshed obstacle").

use std::collections::BTreeMap;
use std::fmt::Write;

/// Lattice intervals along x and z, and along y, at the spacing of 0.05.
const INTERVALS_XZ: usize = 10;
const INTERVALS_Y: usize = 1;
const SPACING: f64 = 0.05;
const LOW: [f64; 3] = [-0.25, 0.35, -0.25];

/// A coordinate with six decimals, trailing zeros dropped down to two (`-0.25`, `0.40`,
/// `0.025`).
fn coordinate(v: f64) -> String {
    let mut text = format!("{v:.6}");
    while text.ends_with('0') && text.len() - text.find('.').map_or(0, |d| d) > 3 {
        text.pop();
    }
    text
}

fn main() {
    let k = match std::env::args().nth(1) {
        None => 1,
        Some(arg) => match arg.parse::<usize>() {
            Ok(k) if (1..=50).contains(&k) => k,
            _ => {
                eprintln!(
                    "table_obj: the spacing's divisor must be a whole number from 1 to 50, got {arg:?}"
                );
                std::process::exit(2);
            }
        },
    };
    let spacing = SPACING / k as f64;
    let n = [
        k * INTERVALS_XZ + 1,
        k * INTERVALS_Y + 1,
        k * INTERVALS_XZ + 1,
    ];
    let on_surface = |p: [usize; 3]| (0..3).any(|axis| p[axis] == 0 || p[axis] == n[axis] - 1);
    let mut out = format!(
        "# sinew: a closed box, 0.5 x 0.05 x 0.5, faces tessellated at {} (see crates/io/examples/table_obj.rs)\no table\n",
        coordinate(spacing)
    );
    // OBJ indices from 1, by lattice point.
    let mut index: BTreeMap<[usize; 3], usize> = BTreeMap::new();
    for i in 0..n[0] {
        for j in 0..n[1] {
            for k in 0..n[2] {
                let p = [i, j, k];
                if on_surface(p) {
                    index.insert(p, index.len() + 1);
                    let x = [0, 1, 2].map(|a| coordinate(LOW[a] + spacing * p[a] as f64));
                    let _ = writeln!(out, "v {} {} {}", x[0], x[1], x[2]);
                }
            }
        }
    }
    // Each face: the axis it is normal to, and the side (0 low, 1 high). A quad's corners
    // run from `a` along `u` then `w`, with (u, w, axis) right-handed on the high side,
    // so the high side's quads keep that order and the low side's reverse it.
    for axis in 0..3 {
        let (u, w) = ((axis + 1) % 3, (axis + 2) % 3);
        for side in 0..2 {
            let fixed = side * (n[axis] - 1);
            for s in 0..n[u] - 1 {
                for t in 0..n[w] - 1 {
                    let corner = |ds: usize, dt: usize| {
                        let mut p = [0; 3];
                        p[axis] = fixed;
                        p[u] = s + ds;
                        p[w] = t + dt;
                        index[&p]
                    };
                    let mut quad = [corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)];
                    if side == 0 {
                        quad.reverse();
                    }
                    let _ = writeln!(out, "f {} {} {} {}", quad[0], quad[1], quad[2], quad[3]);
                }
            }
        }
    }
    print!("{out}");
}
