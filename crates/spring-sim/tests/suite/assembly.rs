//! The sparse Newton matrix, assembled through the precomputed slot maps, equals the
//! dense sum of per-spring blocks (`+K` on the diagonal blocks, `-K` off it), the mass
//! term and the damping blocks, with fixed particles removed.

use sinew_math::DVec3;
use sinew_spring_sim::newton_matrix_triplets;
use sinew_spring_sim::*;

#[test]
fn sparse_assembly_equals_the_dense_sum_of_blocks() {
    let mut grid = ClothGrid::lab_sized(4, 0.2).with_damping(0.7);
    grid.fixed = vec![(0, 0), (2, 3)];
    let mut system = SpringSystem::cloth(&grid).unwrap();
    // Move particles so springs are stretched and compressed.
    let positions: Vec<DVec3> = system
        .positions()
        .iter()
        .enumerate()
        .map(|(i, x)| {
            *x + 0.05
                * DVec3::new(
                    (i as f64 * 1.3).sin(),
                    (i as f64 * 0.7).cos(),
                    (i as f64 * 2.1).sin(),
                )
        })
        .collect();
    let velocities = vec![DVec3::ZERO; positions.len()];
    system.set_state(&positions, &velocities).unwrap();
    let h = 0.02;
    let x = system.positions();
    // Free numbering: particles in order, fixed ones skipped.
    let mut free = vec![usize::MAX; system.len()];
    let mut count = 0;
    for (i, f) in system.fixed().iter().enumerate() {
        if !f {
            free[i] = count;
            count += 1;
        }
    }
    let n = 3 * count;
    let mut dense = vec![vec![0.0; n]; n];
    for (i, m) in system.masses().iter().enumerate() {
        if free[i] != usize::MAX {
            for c in 0..3 {
                dense[3 * free[i] + c][3 * free[i] + c] += m / (h * h);
            }
        }
    }
    let c = system.material().damping / h;
    for s in system.springs() {
        let k = spring::hessian_block(
            x[s.a],
            x[s.b],
            s.rest_length,
            s.stiffness,
            spring::Curvature::Clamped,
        ) + spring::outer(spring::damping_direction(x[s.a], x[s.b])) * c;
        for (p, q, sign) in [
            (s.a, s.a, 1.0),
            (s.b, s.b, 1.0),
            (s.a, s.b, -1.0),
            (s.b, s.a, -1.0),
        ] {
            if free[p] == usize::MAX || free[q] == usize::MAX {
                continue;
            }
            for r in 0..3 {
                for cc in 0..3 {
                    dense[3 * free[p] + r][3 * free[q] + cc] += sign * k.col(cc)[r];
                }
            }
        }
    }
    let mut sparse = vec![vec![0.0; n]; n];
    for (r, cc, v) in newton_matrix_triplets(&system, h) {
        assert!(r >= cc, "only the lower triangle is stored");
        sparse[r][cc] += v;
    }
    for r in 0..n {
        for cc in 0..=r {
            let scale = dense[r][r].abs().max(1.0);
            assert!(
                (sparse[r][cc] - dense[r][cc]).abs() <= 1e-12 * scale,
                "entry ({r}, {cc}): {} vs {}",
                sparse[r][cc],
                dense[r][cc]
            );
        }
    }
}
