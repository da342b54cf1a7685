//! f for discrete actions: the exact nearest neighbour of an embedding among the rows `g(a)`.
//!
//! The table is stored column by column so the distance to every action is one pass of
//! contiguous, auto-vectorised arithmetic per embedding dimension, into a scratch buffer
//! allocated once: a nearest-action lookup allocates nothing (a top-k allocates its
//! distances and the k it returns).

/// Exact nearest-neighbour search over a fixed `[n, d]` table of action embeddings.
#[derive(Debug, Clone)]
pub struct NearestAction {
    /// `columns[j][a]` = component `j` of `g(a)`.
    columns: Vec<Vec<f32>>,
    /// Number of actions.
    n: usize,
    scratch: Vec<f32>,
}

impl NearestAction {
    /// Builds the index from a row-major `[n, d]` table.
    pub fn new(table: &[f32], d: usize) -> Self {
        let n = table.len().checked_div(d).unwrap_or(0);
        let columns = (0..d)
            .map(|j| (0..n).map(|a| table[a * d + j]).collect())
            .collect();
        Self {
            columns,
            n,
            scratch: vec![0.0; n],
        }
    }

    /// Number of actions.
    pub fn len(&self) -> usize {
        self.n
    }

    /// Whether the table is empty.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Embedding width `d`.
    pub fn dim(&self) -> usize {
        self.columns.len()
    }

    /// Component `j` of every action's embedding.
    pub fn column(&self, j: usize) -> &[f32] {
        &self.columns[j]
    }

    /// Squared distances from `e` (`[d]`) to the first `rows` actions, into `dist`.
    fn distances(&self, e: &[f32], rows: usize, dist: &mut Vec<f32>) {
        dist.clear();
        dist.resize(rows.min(self.len()), 0.0);
        for (col, &ej) in self.columns.iter().zip(e) {
            for (acc, &c) in dist.iter_mut().zip(col) {
                let diff = c - ej;
                *acc += diff * diff;
            }
        }
    }

    /// The action whose embedding is closest (Euclidean) to `e` (`[d]`); ties go to the
    /// lowest index.
    pub fn nearest(&mut self, e: &[f32]) -> u32 {
        let mut dist = std::mem::take(&mut self.scratch);
        self.distances(e, usize::MAX, &mut dist);
        let mut best = (f32::INFINITY, 0u32);
        for (a, &v) in dist.iter().enumerate() {
            if v < best.0 {
                best = (v, a as u32);
            }
        }
        self.scratch = dist;
        best.1
    }

    /// Nearest action of every row of `es` (`[batch, d]`), appended to `out`.
    pub fn nearest_batch(&mut self, es: &[f32], out: &mut Vec<u32>) {
        let d = self.dim().max(1);
        for e in es.chunks_exact(d) {
            let a = self.nearest(e);
            out.push(a);
        }
    }

    /// The `k` actions among the first `rows` whose embeddings are closest to `e`, as
    /// `(action, distance)`, closest first (ties: lower index first). This is the one
    /// k-nearest search: recommendations use it.
    pub fn k_nearest(&self, e: &[f32], k: usize, rows: usize) -> Vec<(u32, f32)> {
        let mut dist = Vec::new();
        self.distances(e, rows, &mut dist);
        let order = |a: &(u32, f32), b: &(u32, f32)| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0));
        let k = k.min(dist.len());
        let mut best: Vec<(u32, f32)> = if k == 0 {
            Vec::new()
        } else if k <= SMALL_K {
            // one pass keeping the k best in order: no table-sized buffer besides `dist`
            let mut best = Vec::with_capacity(k + 1);
            for (a, &v) in dist.iter().enumerate() {
                let x = (a as u32, v);
                if best.len() == k && order(&x, &best[k - 1]).is_ge() {
                    continue;
                }
                let at = best.partition_point(|y| order(y, &x).is_lt());
                best.insert(at, x);
                best.truncate(k);
            }
            best
        } else {
            let mut all: Vec<(u32, f32)> = dist
                .iter()
                .enumerate()
                .map(|(a, &v)| (a as u32, v))
                .collect();
            all.select_nth_unstable_by(k - 1, order);
            let mut best = all[..k].to_vec();
            best.sort_by(order);
            best
        };
        best.iter_mut().for_each(|(_, v)| *v = v.sqrt());
        best
    }
}

/// Up to this many neighbours, [`NearestAction::k_nearest`] keeps them in one ordered pass.
const SMALL_K: usize = 64;

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn brute_force(table: &[f32], d: usize, e: &[f32]) -> u32 {
        let mut best = (f32::INFINITY, 0u32);
        for (a, row) in table.chunks_exact(d).enumerate() {
            let dist: f32 = row.iter().zip(e).map(|(r, x)| (r - x) * (r - x)).sum();
            if dist < best.0 {
                best = (dist, a as u32);
            }
        }
        best.1
    }

    #[test]
    fn k_nearest_gives_euclidean_distances_within_the_rows_asked() {
        // rows: (0,0), (3,4), (1,0), (0,0) — the last is outside `rows` = 3
        let index = NearestAction::new(&[0.0, 0.0, 3.0, 4.0, 1.0, 0.0, 0.0, 0.0], 2);
        let got = index.k_nearest(&[0.0, 0.0], 3, 3);
        assert_eq!(got, vec![(0, 0.0), (2, 1.0), (1, 5.0)]);
        let ties = index.k_nearest(&[0.0, 0.0], 2, 4);
        assert_eq!(ties, vec![(0, 0.0), (3, 0.0)]);
    }

    #[test]
    fn lookup_equals_brute_force() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for (n, d) in [(512, 2), (4096, 2), (100, 7), (1, 3)] {
            let table: Vec<f32> = (0..n * d).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mut index = NearestAction::new(&table, d);
            let mut batch = Vec::new();
            let mut want = Vec::new();
            for _ in 0..200 {
                let e: Vec<f32> = (0..d).map(|_| rng.random_range(-1.5..1.5)).collect();
                want.push(brute_force(&table, d, &e));
                batch.extend_from_slice(&e);
            }
            let mut got = Vec::new();
            index.nearest_batch(&batch, &mut got);
            assert_eq!(got, want, "n={n} d={d}");
            let k = index.k_nearest(&batch[..d], 3.min(n), n);
            assert_eq!(k[0].0, want[0]);
            assert!(k.windows(2).all(|w| w[0].1 <= w[1].1));
            let within = index.k_nearest(&batch[..d], n, n / 2);
            assert_eq!(within.len(), n / 2);
            assert!(within.iter().all(|(a, _)| (*a as usize) < n / 2));
        }
    }

    #[test]
    fn k_nearest_equals_a_full_sort_for_every_k() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        // values on a coarse grid, so that distances tie often
        let (n, d) = (500, 2);
        let table: Vec<f32> = (0..n * d).map(|_| rng.random_range(0..6) as f32).collect();
        let index = NearestAction::new(&table, d);
        for k in [1, 10, SMALL_K, SMALL_K + 1, 200, n] {
            let e = [2.5, 1.0];
            let mut want: Vec<(u32, f32)> = table
                .chunks_exact(d)
                .enumerate()
                .map(|(a, r)| (a as u32, (r[0] - e[0]).powi(2) + (r[1] - e[1]).powi(2)))
                .collect();
            want.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
            want.truncate(k);
            want.iter_mut().for_each(|(_, v)| *v = v.sqrt());
            let got = index.k_nearest(&e, k, n);
            assert_eq!(got, want, "k = {k}");
            assert!(
                got.capacity() <= k.max(SMALL_K) + 1,
                "no table-sized buffer kept"
            );
        }
    }
}
