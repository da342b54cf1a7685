use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;

/// Rows in clusters, as a trained embedding's are: `n` rows of width `d` around 50 centres.
fn clustered(n: usize, d: usize, seed: u64) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let centres: Vec<f32> = (0..50 * d).map(|_| rng.random_range(-1.0..1.0)).collect();
    (0..n)
        .flat_map(|_| {
            let c = rng.random_range(0..50);
            (0..d)
                .map(|j| centres[c * d + j] + rng.random_range(-0.3..0.3))
                .collect::<Vec<f32>>()
        })
        .collect()
}

#[test]
fn the_approximate_index_reaches_its_recall_against_the_exact_scan() {
    let (n, d) = (5_000, 16);
    let table = clustered(n, d, 3);
    let settings = ApproxSettings {
        threads: 2,
        ..ApproxSettings::default()
    };
    let approx = ApproxNearest::build(&table, d, &settings).expect("builds");
    assert_eq!((approx.len(), approx.dim()), (n, d));
    assert!(approx.recall_at_10() >= 0.95, "{approx:?}");
    // queries it was not calibrated on: recall still near the target
    let exact = NearestAction::new(&table, d);
    let queries = calibration_queries(
        &table,
        d,
        &ApproxSettings {
            seed: 99,
            ..settings
        },
    );
    let mut total = 0.0;
    for q in queries.chunks_exact(d) {
        let got = approx.k_nearest(q, 10, n);
        assert!(got.windows(2).all(|w| w[0].1 <= w[1].1), "nearest first");
        total += recall(&got, &exact.k_nearest(q, 10, n));
    }
    let held_out = total / (queries.len() / d) as f64;
    assert!(held_out >= 0.9, "recall on fresh queries {held_out}");
}

#[test]
fn a_row_is_its_own_nearest_and_distances_are_euclidean() {
    let (n, d) = (2_000, 8);
    let table = clustered(n, d, 4);
    let approx = ApproxNearest::build(&table, d, &ApproxSettings::default()).expect("builds");
    let mut hits = 0;
    for a in (0..n).step_by(37) {
        let got = approx.k_nearest(&table[a * d..(a + 1) * d], 1, n);
        hits += usize::from(got[0].0 as usize == a && got[0].1 < 1e-3);
    }
    assert!(hits >= 50, "{hits} of 55 rows found themselves");
    // far from every row: whatever it returns, the distance is that row's Euclidean one, and
    // no shorter than the exact nearest's
    let e = vec![5.0; d];
    let want = NearestAction::new(&table, d).k_nearest(&e, 1, n)[0].1;
    for (a, dist) in approx.k_nearest(&e, 3, n) {
        let row = &table[a as usize * d..(a as usize + 1) * d];
        let true_dist = row
            .iter()
            .zip(&e)
            .map(|(r, x)| (r - x) * (r - x))
            .sum::<f32>()
            .sqrt();
        assert!(
            (dist - true_dist).abs() < 1e-3 * true_dist.max(1.0),
            "{dist} {true_dist}"
        );
        assert!(dist >= want - 1e-4, "{dist} < the exact {want}");
    }
}

#[test]
fn a_search_within_the_first_rows_returns_only_them() {
    let (n, d) = (3_000, 8);
    let table = clustered(n, d, 5);
    let approx = ApproxNearest::build(&table, d, &ApproxSettings::default()).expect("builds");
    let got = approx.k_nearest(&table[2_500 * d..2_501 * d], 10, 1_000);
    assert_eq!(got.len(), 10);
    assert!(got.iter().all(|(a, _)| *a < 1_000), "{got:?}");
    // most rows within: the plain search's answers
    let got = approx.k_nearest(&table[10 * d..11 * d], 5, 2_900);
    assert_eq!(got.len(), 5);
    assert!(got.iter().all(|(a, _)| *a < 2_900), "{got:?}");
    let mut batch = Vec::new();
    approx.nearest_batch(&table[..4 * d], &mut batch);
    assert_eq!(batch.len(), 4);
    assert!(
        approx.k_nearest(&[0.0; 3], 5, n).is_empty(),
        "a query of another width"
    );
}

#[test]
fn the_index_is_exact_below_its_threshold_and_approximate_from_it() {
    let table = clustered(1_000, 4, 6);
    let small = ActionIndex::build(&table, 4, 5_000, &ApproxSettings::default()).expect("builds");
    assert!(matches!(small, ActionIndex::Exact(_)));
    let never = ActionIndex::build(&table, 4, 0, &ApproxSettings::default()).expect("builds");
    assert!(matches!(never, ActionIndex::Exact(_)));
    let large = ActionIndex::build(&table, 4, 1_000, &ApproxSettings::default()).expect("builds");
    assert!(matches!(large, ActionIndex::Approx(_)));
    assert_eq!((large.len(), large.dim()), (1_000, 4));
}

#[test]
fn a_table_that_is_not_rows_is_refused() {
    for (values, d) in [(10, 3), (0, 4), (8, 0)] {
        let err = ApproxNearest::build(&vec![0.0; values], d, &ApproxSettings::default())
            .expect_err("refused");
        assert!(err.to_string().contains("not rows of width"), "{err}");
    }
}
