//! A cache hint: asks the processor to start bringing a buffer into its cache before it is
//! read. Used where many small solves run one after another, each on state of its own
//! that was last touched a whole batch ago (see `BodyBatch` in sinew-ik-body): while one
//! solve computes, the next one's state is fetched, instead of each of its first reads
//! waiting for memory. A hint changes no value, so no result depends on it.

/// Asks the processor to bring the memory of `items` into its second-level cache (on
/// x86-64, `prefetcht1` for each 64-byte line; elsewhere nothing). Never reads the items
/// as far as the program is concerned: any slice may be given, and nothing is returned.
#[inline]
pub fn prefetch<T>(items: &[T]) {
    #[cfg(target_arch = "x86_64")]
    {
        let bytes = std::mem::size_of_val(items);
        if bytes == 0 {
            return;
        }
        let start = items.as_ptr().cast::<i8>();
        // Every 64 bytes from the start, and the last byte (whose line the stride may
        // have stepped over when the start is not at a line's start).
        let mut offset = 0;
        while offset < bytes {
            hint_line(start.wrapping_add(offset));
            offset += 64;
        }
        hint_line(start.wrapping_add(bytes - 1));
    }
}

/// One prefetch instruction.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(unsafe_code)]
fn hint_line(address: *const i8) {
    // SAFETY: `_mm_prefetch` is an `unsafe fn` only because it is a `#[target_feature]`
    // function (SSE), and SSE is part of the x86-64 baseline every build targets. The
    // instruction it emits is a hint: it does not read memory as far as the program is
    // concerned, cannot fault for any address, and changes no state but the cache's.
    // `address` is within a live slice in any case.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T1 }>(address);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_prefetch_changes_nothing_and_takes_any_slice() {
        let values: Vec<f64> = (0..1000).map(f64::from).collect();
        prefetch(&values);
        prefetch(&values[3..7]);
        prefetch(&values[..0]);
        prefetch::<()>(&[(); 5]);
        prefetch(&[0u8; 1]);
        assert!(values.iter().enumerate().all(|(i, &v)| v == i as f64));
    }
}
