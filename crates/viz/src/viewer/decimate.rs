//! Choosing which frames a page shows: evenly spaced over the run, first and last
//! always kept, and deterministic.

/// Indices of `count` frames chosen evenly from `0..total`, in increasing order, with
/// the first and the last frame always among them.
///
/// Frame `i` of the choice is `round(i * (total - 1) / (count - 1))` (halves rounded up),
/// so the gaps between chosen frames differ by at most one. With `count >= total` every
/// frame is chosen; with `count == 1` only the first; with `count == 0` or `total == 0`
/// none.
///
/// ```
/// use sinew_viz::viewer::pick_even;
/// assert_eq!(pick_even(10, 4), vec![0, 3, 6, 9]);
/// assert_eq!(pick_even(5, 9), vec![0, 1, 2, 3, 4]);
/// assert_eq!(pick_even(2400, 300).len(), 300);
/// ```
#[must_use]
pub fn pick_even(total: usize, count: usize) -> Vec<usize> {
    if total == 0 || count == 0 {
        return Vec::new();
    }
    if count >= total {
        return (0..total).collect();
    }
    if count == 1 {
        return vec![0];
    }
    // Exact integer arithmetic (u128 cannot overflow here), so the choice does not
    // depend on floating-point rounding.
    let span = (total - 1) as u128;
    let steps = (count - 1) as u128;
    (0..count as u128)
        .map(|i| ((2 * i * span + steps) / (2 * steps)) as usize)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::pick_even;

    #[test]
    fn first_and_last_are_kept_and_the_choice_is_strictly_increasing() {
        for total in 1..60 {
            for count in 1..70 {
                let picked = pick_even(total, count);
                assert_eq!(picked.len(), count.min(total), "{count} of {total}");
                assert_eq!(picked[0], 0);
                if count >= 2 {
                    assert_eq!(*picked.last().unwrap(), total - 1, "{count} of {total}");
                }
                assert!(
                    picked.windows(2).all(|w| w[0] < w[1]),
                    "{count} of {total}: {picked:?}"
                );
            }
        }
    }

    #[test]
    fn gaps_differ_by_at_most_one_and_match_the_ideal_spacing() {
        for (total, count) in [(2400, 300), (1000, 7), (101, 100), (3, 2), (997, 13)] {
            let picked = pick_even(total, count);
            let gaps: Vec<usize> = picked.windows(2).map(|w| w[1] - w[0]).collect();
            let (lo, hi) = (gaps.iter().min().unwrap(), gaps.iter().max().unwrap());
            assert!(hi - lo <= 1, "{count} of {total}: gaps {lo}..{hi}");
            let ideal = (total - 1) as f64 / (count - 1) as f64;
            for (i, &k) in picked.iter().enumerate() {
                assert!(
                    (k as f64 - i as f64 * ideal).abs() <= 0.5,
                    "{count} of {total}, {i}"
                );
            }
        }
    }

    #[test]
    fn empty_requests_choose_nothing() {
        assert!(pick_even(0, 5).is_empty());
        assert!(pick_even(5, 0).is_empty());
        assert_eq!(pick_even(5, 1), vec![0]);
    }
}
