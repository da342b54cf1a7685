//! A ranking: the `k` best of scored items, for the learned policy and the reference
//! policies alike.

/// Keeps the `k` highest scores under `cmp`, highest first (ties: lower index first); the
/// learned policy's and the reference policies' rankings.
pub(crate) fn best_k<S>(
    all: &mut Vec<(u32, S)>,
    k: usize,
    cmp: impl Fn(&S, &S) -> std::cmp::Ordering,
) {
    let order = |a: &(u32, S), b: &(u32, S)| cmp(&b.1, &a.1).then(a.0.cmp(&b.0));
    let k = k.min(all.len());
    if k == 0 {
        all.clear();
        return;
    }
    all.select_nth_unstable_by(k - 1, order);
    all.truncate(k);
    all.sort_by(order);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn best_k_orders_by_score_then_index() {
        let mut v = vec![(0, 0.1), (1, 0.5), (2, 0.5), (3, 0.9), (4, -1.0)];
        best_k(&mut v, 3, f32::total_cmp);
        assert_eq!(v, vec![(3, 0.9), (1, 0.5), (2, 0.5)]);
    }
}
