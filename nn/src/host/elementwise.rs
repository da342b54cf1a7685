//! The MLP pass's per-element loops (bias and tanh, tanh's derivative, bias gradients, the
//! one-hot layer's row sums), compiled for the CPU's widest vector instructions through
//! pulp's run-time dispatch: built for the baseline target they run four lanes at a time,
//! which made them cost more than the products on wide heads. Each loop is the plain one
//! (same operations, same order), so the results are those of the scalar code.

use super::math;

/// Declares a loop as a [`pulp::WithSimd`] operation: the body is inlined whole into pulp's
/// function for the detected instruction set, so it is vectorised for it (a closure would be
/// compiled on its own, for the baseline target).
macro_rules! simd_op {
    ($(#[$doc:meta])* $name:ident<$lt:lifetime> { $($field:ident: $ty:ty),* $(,)? } => $body:block) => {
        $(#[$doc])*
        struct $name<$lt> { $($field: $ty),* }

        impl pulp::WithSimd for $name<'_> {
            type Output = ();

            #[inline(always)]
            fn with_simd<S: pulp::Simd>(self, _: S) {
                let Self { $($field),* } = self;
                $body
            }
        }
    };
}

simd_op! {
    /// Rows of `data` plus `bias`, through tanh when `tanh`.
    AddBias<'a> { data: &'a mut [f32], bias: &'a [f32], tanh: bool } => {
        for row in data.chunks_exact_mut(bias.len().max(1)) {
            if tanh {
                for (z, &b) in row.iter_mut().zip(bias) {
                    *z = math::tanh(*z + b);
                }
            } else {
                for (z, &b) in row.iter_mut().zip(bias) {
                    *z += b;
                }
            }
        }
    }
}

simd_op! {
    /// `g *= 1 - a^2`.
    ThroughTanh<'a> { g: &'a mut [f32], a: &'a [f32] } => {
        for (g, &a) in g.iter_mut().zip(a) {
            *g *= 1.0 - a * a;
        }
    }
}

simd_op! {
    /// `out += row` for each row of `data`, in order.
    ColumnSums<'a> { data: &'a [f32], out: &'a mut [f32] } => {
        let cols = out.len().max(1);
        for row in data.chunks_exact(cols) {
            for (o, &v) in out.iter_mut().zip(row) {
                *o += v;
            }
        }
    }
}

simd_op! {
    /// `out[r] += v_j dense[j]` for the non-zero entries `(j, v_j)` of each sparse row `r`
    /// (`transposed` false), or `out[j] += v_j dense[r]` (`transposed` true: the transposed
    /// product); rows of `width` values.
    SparseProduct<'a> {
        rows: &'a super::SparseRows,
        dense: &'a [f32],
        out: &'a mut [f32],
        width: usize,
        transposed: bool,
    } => {
        for r in 0..rows.nrows() {
            let (index, value) = rows.row(r);
            for (&j, &v) in index.iter().zip(value) {
                let j = j as usize;
                let (o, w) = if transposed {
                    (&mut out[j * width..(j + 1) * width], &dense[r * width..(r + 1) * width])
                } else {
                    (&mut out[r * width..(r + 1) * width], &dense[j * width..(j + 1) * width])
                };
                for (o, &w) in o.iter_mut().zip(w) {
                    *o += v * w;
                }
            }
        }
    }
}

/// Each row of `data` (rows of `bias.len()` values) plus `bias`, through tanh when `tanh`.
pub(super) fn add_bias(data: &mut [f32], bias: &[f32], tanh: bool) {
    pulp::Arch::new().dispatch(AddBias { data, bias, tanh });
}

/// `g *= 1 - a^2` element by element: the gradient through a tanh whose outputs are `a`.
pub(super) fn through_tanh(g: &mut [f32], a: &[f32]) {
    pulp::Arch::new().dispatch(ThroughTanh { g, a });
}

/// `out` = the sum of the rows of `data` (rows of `out.len()` values), added in row order.
pub(super) fn column_sums(data: &[f32], out: &mut [f32]) {
    out.fill(0.0);
    pulp::Arch::new().dispatch(ColumnSums { data, out });
}

/// `out += x w` for sparse rows `x` (`w`: `[x's cols, width]`, `out`: `[x's rows, width]`,
/// both row-major).
pub(super) fn sparse_product(x: &super::SparseRows, w: &[f32], out: &mut [f32], width: usize) {
    pulp::Arch::new().dispatch(SparseProduct {
        rows: x,
        dense: w,
        out,
        width,
        transposed: false,
    });
}

/// `g += x^T d` for sparse rows `x` (`d`: `[x's rows, width]`, `g`: `[x's cols, width]`).
pub(super) fn sparse_outer(x: &super::SparseRows, d: &[f32], g: &mut [f32], width: usize) {
    pulp::Arch::new().dispatch(SparseProduct {
        rows: x,
        dense: d,
        out: g,
        width,
        transposed: true,
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loops_give_the_plain_values() {
        let bias = [0.5, -1.0, 2.0];
        let mut data: Vec<f32> = (0..12).map(|i| i as f32 * 0.1 - 0.4).collect();
        let before = data.clone();
        add_bias(&mut data, &bias, true);
        for (i, (&z, &x)) in data.iter().zip(&before).enumerate() {
            assert!((z - (x + bias[i % 3]).tanh()).abs() < 1e-6);
        }
        let mut plain = before.clone();
        add_bias(&mut plain, &bias, false);
        assert!(
            plain
                .iter()
                .zip(&before)
                .enumerate()
                .all(|(i, (&z, &x))| z == x + bias[i % 3])
        );

        let mut g = vec![2.0; 12];
        through_tanh(&mut g, &before);
        assert!(
            g.iter()
                .zip(&before)
                .all(|(&g, &a)| g == 2.0 * (1.0 - a * a))
        );

        let mut sums = [9.0; 3];
        column_sums(&before, &mut sums);
        for (j, &s) in sums.iter().enumerate() {
            let expected: f32 = (0..4).map(|r| before[r * 3 + j]).sum();
            assert_eq!(s, expected);
        }
    }
}
