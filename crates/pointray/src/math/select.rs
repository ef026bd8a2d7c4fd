//! Order statistics of values too many to hold, found in passes over them (a cloud prepared out
//! of core: its radii's quantile, its intensities' percentiles).

/// The values at the ranks `ranks` gives for their count (0-based, in `f32::total_cmp`'s order)
/// among those `pass` calls its argument with, in two passes: how many fall in each bucket of
/// their upper 16 bits (as [`order_key`]s), then the values in the ranks' buckets, from which
/// each is selected. Holds the counts and those buckets' values only. `None` where `ranks` gives
/// none, or one past the values.
pub fn select_in_passes<E, const N: usize>(
    ranks: impl FnOnce(usize) -> Option<[usize; N]>,
    mut pass: impl FnMut(&mut dyn FnMut(f32)) -> Result<(), E>,
) -> Result<Option<[f32; N]>, E> {
    let bucket_of = |v: f32| (order_key(v) >> 16) as usize;
    let mut counts = vec![0usize; 1 << 16];
    pass(&mut |v| counts[bucket_of(v)] += 1)?;
    let n = counts.iter().sum();
    let Some(ranks) = ranks(n).filter(|r| r.iter().all(|&rank| rank < n)) else { return Ok(None) };
    // Each rank's bucket, and how many values lie in the buckets below it.
    let place = ranks.map(|rank| {
        let (mut bucket, mut below) = (0, 0);
        while below + counts[bucket] <= rank {
            below += counts[bucket];
            bucket += 1;
        }
        (bucket, below)
    });
    let mut inside: [Vec<f32>; N] = std::array::from_fn(|_| Vec::new());
    pass(&mut |v| {
        for (values, (bucket, _)) in inside.iter_mut().zip(&place) {
            if bucket_of(v) == *bucket {
                values.push(v);
            }
        }
    })?;
    Ok(Some(std::array::from_fn(|k| *inside[k].select_nth_unstable_by(ranks[k] - place[k].1, f32::total_cmp).1)))
}

/// `x`'s bits as an integer in the order of `f32::total_cmp`.
pub fn order_key(x: f32) -> u32 {
    let bits = x.to_bits();
    if bits >> 31 != 0 { !bits } else { bits | 1 << 31 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_selected_in_passes_are_the_sorted_values_at_their_ranks() {
        let values: Vec<f32> = (0..100_003u32).map(|i| ((i * 7_919) % 100_003) as f32 * 1e-3 - 7.0).collect();
        let mut sorted = values.clone();
        sorted.sort_by(f32::total_cmp);
        let each = |f: &mut dyn FnMut(f32)| {
            values.iter().for_each(|&v| f(v));
            Ok::<_, ()>(())
        };
        let ranks = [0, 1_000, 50_001, 100_002];
        assert_eq!(
            select_in_passes(|n| (n == 100_003).then_some(ranks), each).unwrap(),
            Some(ranks.map(|r| sorted[r]))
        );
        assert_eq!(select_in_passes(|n| Some([n]), each).unwrap(), None);
        let signed = [-2.0f32, -0.0, 0.0, 1e-30, 3.0];
        assert!(signed.windows(2).all(|w| order_key(w[0]) < order_key(w[1])));
    }
}
