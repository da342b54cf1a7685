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
        let limit = x.len() / 8;
        if u32::try_from(x.ncols()).is_err() {
            return None;
        }
        let mut out = Self {
            cols: x.ncols(),
            start: Vec::with_capacity(x.nrows() + 1),
            index: Vec::new(),
            value: Vec::new(),
        };
        out.start.push(0);
        for row in x.rows() {
            let row = row.to_slice()?;
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
            if out.index.len() > limit {
                return None;
            }
            out.start.push(out.index.len());
        }
        Some(out)
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
    fn dense_inputs_stay_dense() {
        let x = Array2::from_shape_fn((4, 8), |(i, j)| value(i, j) + 2.0);
        assert!(SparseRows::from_dense(x.view()).is_none());
    }
}
