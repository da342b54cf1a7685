//! Inputs that are mostly zeros (one-hot states): kept as each row's non-zero entries, so
//! the first layer's product is a lookup of weight rows and its gradient touches only those
//! rows. The decision is made once per batch ([`SparseRows::from_dense`]) and a minibatch
//! gathers its rows' entries ([`SparseRows::gather`]) instead of copying wide dense rows.

use ndarray::{Array2, ArrayView2};

use super::elementwise::{sparse_outer, sparse_product};

/// The rows of a `[rows, cols]` matrix as their non-zero entries: row `r` holds
/// `index[start[r]..start[r + 1]]` with `value` alongside.
#[derive(Debug, Clone, PartialEq)]
pub struct SparseRows {
    cols: usize,
    start: Vec<usize>,
    index: Vec<u32>,
    value: Vec<f32>,
}

impl Default for SparseRows {
    fn default() -> Self {
        Self {
            cols: 0,
            start: vec![0],
            index: Vec::new(),
            value: Vec::new(),
        }
    }
}

/// An MLP's input: dense rows, or mostly-zero rows as their non-zero entries.
#[derive(Debug, Clone, Copy)]
pub enum HostInput<'a> {
    /// `[rows, input]`.
    Dense(ArrayView2<'a, f32>),
    /// The same shape, non-zero entries only.
    Sparse(&'a SparseRows),
}

impl HostInput<'_> {
    /// Rows (samples).
    pub fn nrows(&self) -> usize {
        match self {
            Self::Dense(x) => x.nrows(),
            Self::Sparse(x) => x.nrows(),
        }
    }
}

impl SparseRows {
    /// `x`'s non-zero entries, if at most an eighth of `x` is non-zero (below that a dense
    /// product is as cheap).
    pub fn from_dense(x: ArrayView2<'_, f32>) -> Option<Self> {
        Self::scan(x, Some(x.len() / 8), None)
    }

    /// One-hot rows (`x`, `[rows, cols]`) with a crossed feature appended: row `r` also
    /// holds `cross.value` at columns `cols + bucket` for each of `cross`'s buckets of
    /// `(a, b)` ([`PairCross::buckets_of`]), where `a < b` are its last two non-zero columns
    /// (for concatenated one-hots, the last two factors' values: the recommender's item before
    /// the last and its last item). A row with fewer than two non-zero entries gets no crossed
    /// entry. The result is `[rows, cols + cross.buckets]`.
    ///
    /// # Panics
    /// When `cols + cross.buckets` does not fit a `u32`.
    pub fn crossed(x: ArrayView2<'_, f32>, cross: PairCross) -> Self {
        Self::scan(x, None, Some(cross)).expect("columns within u32")
    }

    /// The non-zero entries of `x` (None past `limit` of them), each row followed by its
    /// crossed entries where `cross` is given ([`Self::crossed`]).
    fn scan(
        x: ArrayView2<'_, f32>,
        limit: Option<usize>,
        cross: Option<PairCross>,
    ) -> Option<Self> {
        let cols = x.ncols() + cross.map_or(0, |c| c.buckets);
        if u32::try_from(cols).is_err() {
            return None;
        }
        let mut out = Self {
            cols,
            start: Vec::with_capacity(x.nrows() + 1),
            index: Vec::new(),
            value: Vec::new(),
        };
        out.start.push(0);
        for row in x.rows() {
            let owned;
            let row = match row.to_slice() {
                Some(row) => row,
                None => {
                    owned = row.to_vec();
                    &owned
                }
            };
            let first = out.index.len();
            // runs of zeros are passed over a block at a time (a vectorised test)
            for (b, block) in row.chunks(16).enumerate() {
                let bits = block
                    .iter()
                    .fold(0u32, |acc, v| acc | (v.to_bits() & 0x7fff_ffff));
                if bits == 0 {
                    continue;
                }
                for (j, &v) in block.iter().enumerate() {
                    if v != 0.0 {
                        out.index.push((b * 16 + j) as u32);
                        out.value.push(v);
                    }
                }
            }
            if let (Some(cross), true) = (cross, out.index.len() >= first + 2) {
                let n = out.index.len();
                let (a, b) = (out.index[n - 2], out.index[n - 1]);
                for bucket in cross.buckets_of(a, b) {
                    out.index.push((x.ncols() + bucket) as u32);
                    out.value.push(cross.value);
                }
            }
            if limit.is_some_and(|limit| out.index.len() > limit) {
                return None;
            }
            out.start.push(out.index.len());
        }
        Some(out)
    }

    /// Appends every column index these rows use to `out` (repeats included).
    pub fn columns_into(&self, out: &mut Vec<u32>) {
        out.extend_from_slice(&self.index);
    }

    /// Rows.
    pub fn nrows(&self) -> usize {
        self.start.len() - 1
    }

    /// Columns of the matrix these rows come from.
    pub fn ncols(&self) -> usize {
        self.cols
    }

    /// Row `r`'s column indices and values.
    pub fn row(&self, r: usize) -> (&[u32], &[f32]) {
        let (a, b) = (self.start[r], self.start[r + 1]);
        (&self.index[a..b], &self.value[a..b])
    }

    /// Appends `other`'s rows (of the same width).
    ///
    /// # Panics
    /// When the widths differ.
    pub fn append(&mut self, other: &Self) {
        assert!(
            self.nrows() == 0 || self.cols == other.cols,
            "rows of {} columns appended to rows of {}",
            other.cols,
            self.cols
        );
        self.cols = other.cols;
        let base = self.index.len();
        self.index.extend_from_slice(&other.index);
        self.value.extend_from_slice(&other.value);
        self.start.extend(other.start[1..].iter().map(|s| s + base));
    }

    /// Replaces these rows with rows `rows` of `from`, in that order (buffers reused).
    pub fn gather(&mut self, from: &Self, rows: &[usize]) {
        self.cols = from.cols;
        self.start.clear();
        self.index.clear();
        self.value.clear();
        self.start.push(0);
        for &r in rows {
            let (index, value) = from.row(r);
            self.index.extend_from_slice(index);
            self.value.extend_from_slice(value);
            self.start.push(self.index.len());
        }
    }

    /// `out = x w` (`w` is `[cols, out]`).
    ///
    /// # Panics
    /// When the shapes do not fit together.
    pub(super) fn mul(&self, w: &Array2<f32>, out: &mut Array2<f32>) {
        out.fill(0.0);
        self.mul_add(w, out);
    }

    /// `out += x w` (`w` is `[cols, out]`).
    ///
    /// # Panics
    /// When the shapes do not fit together.
    pub(super) fn mul_add(&self, w: &Array2<f32>, out: &mut Array2<f32>) {
        let width = w.ncols();
        assert!(
            w.nrows() == self.cols && out.dim() == (self.nrows(), width),
            "sparse [{}, {}] times {:?} added to {:?}",
            self.nrows(),
            self.cols,
            w.dim(),
            out.dim()
        );
        match (out.as_slice_mut(), w.as_slice()) {
            (Some(out), Some(w)) => sparse_product(self, w, out, width),
            _ => {
                for (r, mut out_row) in out.rows_mut().into_iter().enumerate() {
                    let (index, value) = self.row(r);
                    for (&j, &v) in index.iter().zip(value) {
                        out_row.scaled_add(v, &w.row(j as usize));
                    }
                }
            }
        }
    }

    /// `g = x^T delta` (`g` is `[cols, delta's cols]`).
    ///
    /// # Panics
    /// When the shapes do not fit together.
    pub(super) fn outer(&self, delta: &Array2<f32>, g: &mut Array2<f32>) {
        g.fill(0.0);
        self.outer_add(delta, g);
    }

    /// `g += x^T delta` (`g` is `[cols, delta's cols]`): only the rows of `g` that `x`'s
    /// non-zero entries pick are touched.
    ///
    /// # Panics
    /// When the shapes do not fit together.
    pub fn outer_add(&self, delta: &Array2<f32>, g: &mut Array2<f32>) {
        let width = delta.ncols();
        assert!(
            delta.nrows() == self.nrows() && g.dim() == (self.cols, width),
            "sparse [{}, {}] transposed times {:?} into {:?}",
            self.nrows(),
            self.cols,
            delta.dim(),
            g.dim()
        );
        match (g.as_slice_mut(), delta.as_slice()) {
            (Some(g), Some(delta)) => sparse_outer(self, delta, g, width),
            _ => {
                for (r, d_row) in delta.rows().into_iter().enumerate() {
                    let (index, value) = self.row(r);
                    for (&j, &v) in index.iter().zip(value) {
                        g.row_mut(j as usize).scaled_add(v, &d_row);
                    }
                }
            }
        }
    }
}

/// A crossed feature of one-hot rows ([`SparseRows::crossed`]): a pair of columns hashed
/// into `hashes` of `buckets` columns, each holding `value`. With two or more hashes two pairs
/// that share one bucket rarely share them all, so the sum of a pair's rows tells it apart
/// where one bucket would be shared ("hash embeddings").
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PairCross {
    /// Columns of the feature.
    pub buckets: usize,
    /// Buckets per pair.
    pub hashes: usize,
    /// The value in each.
    pub value: f32,
}

impl PairCross {
    /// The buckets of the column pair `(a, b)`, one per hash.
    pub fn buckets_of(self, a: u32, b: u32) -> impl Iterator<Item = usize> {
        (0..self.hashes).map(move |k| pair_bucket(a, b, k as u64, self.buckets))
    }
}

/// The bucket in `0..buckets` of the column pair `(a, b)` under hash `k`: a 64-bit mix of the
/// pair and `k` (the finaliser of SplitMix64), reduced modulo `buckets`, so pairs spread
/// evenly whatever their columns' structure. `buckets` must be positive.
pub fn pair_bucket(a: u32, b: u32, k: u64, buckets: usize) -> usize {
    let golden = 0x9e37_79b9_7f4a_7c15u64;
    let mut z = ((u64::from(a) << 32) | u64::from(b)).wrapping_add(golden.wrapping_mul(k + 1));
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^= z >> 31;
    (z % buckets as u64) as usize
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::linalg::general_mat_mul;

    fn value(i: usize, j: usize) -> f32 {
        ((i * 7 + j * 3) % 11) as f32 / 11.0 - 0.5
    }

    /// Two non-zero entries per row of 40.
    fn one_hot(rows: usize) -> Array2<f32> {
        let mut x = Array2::zeros((rows, 40));
        for r in 0..rows {
            x[[r, r * 5]] = 1.0;
            x[[r, 39 - r]] = 0.5;
        }
        x
    }

    #[test]
    fn products_equal_the_dense_ones_and_gathered_rows_are_those_rows() {
        let x = one_hot(6);
        let sparse = SparseRows::from_dense(x.view()).expect("mostly zeros");
        assert_eq!((sparse.nrows(), sparse.ncols()), (6, 40));
        let w = Array2::from_shape_fn((40, 5), |(i, j)| value(i, j));
        let mut dense = Array2::zeros((6, 5));
        general_mat_mul(1.0, &x, &w, 0.0, &mut dense);
        let mut out = Array2::zeros((6, 5));
        sparse.mul(&w, &mut out);
        assert!((&dense - &out).iter().all(|d| d.abs() < 1e-6));

        let delta = Array2::from_shape_fn((6, 5), |(i, j)| value(i, j + 2));
        let mut g_dense = Array2::zeros((40, 5));
        general_mat_mul(1.0, &x.t(), &delta, 0.0, &mut g_dense);
        let mut g = Array2::ones((40, 5));
        sparse.outer(&delta, &mut g);
        assert!((&g_dense - &g).iter().all(|d| d.abs() < 1e-6));

        let mut picked = SparseRows::default();
        picked.gather(&sparse, &[4, 0, 4]);
        let expected =
            ndarray::stack(ndarray::Axis(0), &[x.row(4), x.row(0), x.row(4)]).expect("rows");
        assert_eq!(
            picked,
            SparseRows::from_dense(expected.view()).expect("sparse")
        );
    }

    #[test]
    fn crossed_rows_add_one_entry_for_the_last_two_columns() {
        // rows of two one-hot factors of 5; the last row has one entry only
        let mut x = Array2::zeros((4, 10));
        for (r, (a, b)) in [(0, 5), (0, 9), (4, 5)].into_iter().enumerate() {
            x[[r, a]] = 1.0;
            x[[r, b]] = 1.0;
        }
        x[[3, 7]] = 1.0;
        let cross = PairCross {
            buckets: 16,
            hashes: 2,
            value: 1.0,
        };
        let crossed = SparseRows::crossed(x.view(), cross);
        assert_eq!((crossed.nrows(), crossed.ncols()), (4, 26));
        for (r, (a, b)) in [(0u32, 5u32), (0, 9), (4, 5)].into_iter().enumerate() {
            let h: Vec<u32> = (0..2)
                .map(|k| 10 + pair_bucket(a, b, k, 16) as u32)
                .collect();
            assert_eq!(crossed.row(r), (&[a, b, h[0], h[1]][..], &[1.0; 4][..]));
        }
        assert_eq!(
            crossed.row(3),
            (&[7u32][..], &[1.0][..]),
            "no pair, no crossed entry"
        );
        // without a density limit: a dense row is kept whole
        let dense = Array2::from_elem((1, 3), 1.0);
        let cross = PairCross {
            buckets: 4,
            hashes: 1,
            value: 3.0,
        };
        let crossed = SparseRows::crossed(dense.view(), cross);
        assert_eq!(crossed.row(0).0.len(), 4);
        assert_eq!(crossed.row(0).1[3], 3.0);
    }

    #[test]
    fn pair_buckets_spread_pairs_evenly() {
        let buckets = 4096;
        let mut count = vec![0u32; buckets];
        for a in 0..100 {
            for b in 100..200 {
                count[pair_bucket(a, b, 0, buckets)] += 1;
            }
        }
        // 10,000 pairs in 4,096 buckets: about e^-2.44 = 9% empty if spread at random
        let empty = count.iter().filter(|&&c| c == 0).count() as f64 / buckets as f64;
        assert!((0.05..0.13).contains(&empty), "{empty}");
        // and none far above the mean of 2.44 (the largest of 4,096 Poisson counts: about 10)
        assert!(count.iter().all(|&c| c < 15));
        // two hashes: pairs that share their first bucket almost never share the second
        let shared = (0..100u32)
            .flat_map(|a| (100..200u32).map(move |b| (a, b)))
            .filter(|&(a, b)| pair_bucket(a, b, 0, buckets) == pair_bucket(0, 100, 0, buckets))
            .filter(|&(a, b)| pair_bucket(a, b, 1, buckets) == pair_bucket(0, 100, 1, buckets))
            .count();
        assert_eq!(shared, 1, "only the pair itself");
    }

    #[test]
    fn dense_inputs_stay_dense() {
        let x = Array2::from_shape_fn((4, 8), |(i, j)| value(i, j) + 2.0);
        assert!(SparseRows::from_dense(x.view()).is_none());
    }
}
