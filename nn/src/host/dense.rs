//! The dense product `c = a b` of the host path, on the `gemm` crate's kernels: they are
//! chosen at run time for the CPU (AVX-512 where it has it, AVX2/FMA otherwise), where
//! matrixmultiply (ndarray's own product) stops at AVX2, half the width of this machine's
//! vector units. This module is the crate's only `unsafe`: `gemm` takes raw pointers and
//! strides, which are read here from ndarray views, so every call is in bounds by the
//! views' own guarantees.

#![allow(unsafe_code)]

use ndarray::{ArrayView2, ArrayViewMut2};

/// `c = a b` on the calling thread (`a` is `[m, k]`, `b` is `[k, n]`, `c` is `[m, n]`; any
/// strides, transposed views included).
///
/// # Panics
/// When the shapes do not fit together.
pub fn product(a: ArrayView2<'_, f32>, b: ArrayView2<'_, f32>, mut c: ArrayViewMut2<'_, f32>) {
    let (m, k) = a.dim();
    let n = b.ncols();
    assert!(
        b.nrows() == k && c.dim() == (m, n),
        "product of [{m}, {k}] and {:?} into {:?}",
        b.dim(),
        c.dim()
    );
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        c.fill(0.0);
        return;
    }
    let (a_rs, a_cs) = (a.strides()[0], a.strides()[1]);
    let (b_rs, b_cs) = (b.strides()[0], b.strides()[1]);
    let (c_rs, c_cs) = (c.strides()[0], c.strides()[1]);
    // SAFETY: each pointer is its view's element [0, 0], and every element [i, j] of a view
    // lies at `i * row_stride + j * col_stride` from it inside the view's memory (ndarray's
    // invariant for views, negative strides included); gemm reads `a` over [m, k], `b` over
    // [k, n] and writes `c` over [m, n], exactly the views' shapes checked above. `c` is a
    // unique borrow, so it overlaps neither input, and a mutable view's distinct indices
    // never share memory. With `read_dst` false, `c`'s old values are never read.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            c.as_mut_ptr(),
            c_cs,
            c_rs,
            false,
            a.as_ptr(),
            a_cs,
            a_rs,
            b.as_ptr(),
            b_cs,
            b_rs,
            0.0,
            1.0,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;
    use ndarray::linalg::general_mat_mul;

    fn value(i: usize, j: usize) -> f32 {
        ((i * 13 + j * 7) % 17) as f32 / 17.0 - 0.5
    }

    #[test]
    fn products_equal_ndarrays_for_every_layout() {
        for (m, k, n) in [
            (1, 1, 1),
            (3, 5, 2),
            (64, 17, 6),
            (256, 64, 512),
            (7, 300, 33),
        ] {
            let a = Array2::from_shape_fn((m, k), |(i, j)| value(i, j));
            let b = Array2::from_shape_fn((k, n), |(i, j)| value(i + 2, j));
            let at = Array2::from_shape_fn((k, m), |(i, j)| value(j, i));
            let bt = Array2::from_shape_fn((n, k), |(i, j)| value(j + 2, i));
            let mut expected = Array2::zeros((m, n));
            general_mat_mul(1.0, &a, &b, 0.0, &mut expected);
            // row-major, transposed inputs, and a transposed (column-major) output
            let mut c = Array2::from_elem((m, n), f32::NAN);
            product(a.view(), b.view(), c.view_mut());
            let mut ct = Array2::from_elem((m, n), f32::NAN);
            product(at.t(), bt.t(), ct.view_mut());
            let mut c_col = Array2::from_elem((n, m), f32::NAN);
            product(a.view(), b.view(), c_col.view_mut().reversed_axes());
            for got in [&c, &ct, &c_col.t().to_owned()] {
                let worst = (got - &expected).iter().fold(0.0f32, |w, d| w.max(d.abs()));
                assert!(worst < 1e-4, "{m}x{k}x{n}: off by {worst}");
            }
        }
    }

    #[test]
    fn reversed_views_negative_strides_are_read_in_their_order() {
        let a = Array2::from_shape_fn((5, 7), |(i, j)| value(i, j));
        let b = Array2::from_shape_fn((7, 3), |(i, j)| value(i + 1, j));
        let a_rev = a.slice(ndarray::s![..;-1, ..]);
        let b_rev = b.slice(ndarray::s![.., ..;-1]);
        let mut expected = Array2::zeros((5, 3));
        general_mat_mul(1.0, &a_rev, &b_rev, 0.0, &mut expected);
        let mut c = Array2::from_elem((5, 3), f32::NAN);
        product(a_rev, b_rev, c.view_mut());
        assert!((&c - &expected).iter().all(|d| d.abs() < 1e-5));
    }

    #[test]
    fn an_empty_inner_dimension_gives_zeros() {
        let a = Array2::<f32>::zeros((3, 0));
        let b = Array2::<f32>::zeros((0, 4));
        let mut c = Array2::from_elem((3, 4), 1.0);
        product(a.view(), b.view(), c.view_mut());
        assert!(c.iter().all(|&v| v == 0.0));
    }
}
