//! Writes `scenes/data/sheet.obj`, a square cloth of side 1 in the xz plane (y = 0)
//! with 11 x 11 vertices 0.1 apart, to standard output:
//!
//! ```text
//! cargo run -p sinew-io --example sheet_obj > scenes/data/sheet.obj
//! ```
//!
//! Vertex `(i, j)` (OBJ index `11 i + j + 1`) is at `(0.1 i, 0, 0.1 j)`. Cells are
//! quads, except that the cells of the two diagonal bands alternate their split into two
//! triangles, so the file has both quads (the reader triangulates them as fans) and
//! triangles, and the triangulation is not a plain grid.

use std::fmt::Write;

const N: usize = 11;

fn main() {
    let mut out = String::from(
        "# sinew: a 1 x 1 cloth sheet, 11 x 11 vertices (see crates/io/examples/sheet_obj.rs)\no sheet\n",
    );
    for i in 0..N {
        for j in 0..N {
            let _ = writeln!(out, "v {:.1} 0.0 {:.1}", 0.1 * i as f64, 0.1 * j as f64);
        }
    }
    let v = |i: usize, j: usize| N * i + j + 1;
    for i in 0..N - 1 {
        for j in 0..N - 1 {
            let (a, b, c, d) = (v(i, j), v(i, j + 1), v(i + 1, j + 1), v(i + 1, j));
            if i == j || i + j == N - 2 {
                // Split along the other diagonal on the bands, alternating.
                if (i + j) % 2 == 0 {
                    let _ = writeln!(out, "f {a} {b} {d}\nf {b} {c} {d}");
                } else {
                    let _ = writeln!(out, "f {a} {b} {c}\nf {a} {c} {d}");
                }
            } else {
                let _ = writeln!(out, "f {a} {b} {c} {d}");
            }
        }
    }
    print!("{out}");
}
