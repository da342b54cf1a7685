//! Seeded initialisation computed on the host, so a seed gives the same weights on every
//! device and in every process, whatever else uses burn's global generator.

use burn::module::Param;
use burn::nn::Linear;
use burn::tensor::{Device, Tensor, TensorData};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// A `rows x cols` matrix (row-major) with orthonormal rows or columns, times `gain`
/// (Saxe et al.; what PPO implementations use for their layers).
pub fn orthogonal(rows: usize, cols: usize, gain: f32, rng: &mut ChaCha8Rng) -> Vec<f32> {
    // Orthonormalise the shorter side's vectors with modified Gram-Schmidt.
    let (n, len) = if rows <= cols {
        (rows, cols)
    } else {
        (cols, rows)
    };
    let mut vecs: Vec<Vec<f64>> = (0..n)
        .map(|_| {
            (0..len)
                .map(|_| rng.sample::<f64, _>(StandardNormal))
                .collect()
        })
        .collect();
    for i in 0..n {
        for j in 0..i {
            let dot: f64 = vecs[i].iter().zip(&vecs[j]).map(|(a, b)| a * b).sum();
            let (head, tail) = vecs.split_at_mut(i);
            for (a, b) in tail[0].iter_mut().zip(&head[j]) {
                *a -= dot * b;
            }
        }
        let norm = vecs[i].iter().map(|a| a * a).sum::<f64>().sqrt().max(1e-12);
        vecs[i].iter_mut().for_each(|a| *a /= norm);
    }
    let mut out = vec![0.0f32; rows * cols];
    for r in 0..rows {
        for c in 0..cols {
            let v = if rows <= cols { vecs[r][c] } else { vecs[c][r] };
            out[r * cols + c] = (v as f32) * gain;
        }
    }
    out
}

/// A linear layer from host weights: `weight` is `[d_in, d_out]` row-major.
pub fn linear_from_host(
    weight: Vec<f32>,
    bias: Option<Vec<f32>>,
    d_in: usize,
    d_out: usize,
    device: &Device,
) -> Linear {
    Linear {
        weight: Param::from_tensor(Tensor::from_data(
            TensorData::new(weight, [d_in, d_out]),
            device,
        )),
        bias: bias
            .map(|b| Param::from_tensor(Tensor::from_data(TensorData::new(b, [d_out]), device))),
    }
}

/// A linear layer `[d_in -> d_out]` with orthogonal weights times `gain` and zero bias
/// (or no bias).
pub fn seeded_linear(
    d_in: usize,
    d_out: usize,
    gain: f32,
    bias: bool,
    rng: &mut ChaCha8Rng,
    device: &Device,
) -> Linear {
    let w = orthogonal(d_in, d_out, gain, rng);
    linear_from_host(w, bias.then(|| vec![0.0; d_out]), d_in, d_out, device)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn orthogonal_columns_are_orthonormal_and_seeded() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let (rows, cols) = (10, 4);
        let w = orthogonal(rows, cols, 1.0, &mut rng);
        for a in 0..cols {
            for b in 0..cols {
                let dot: f32 = (0..rows).map(|r| w[r * cols + a] * w[r * cols + b]).sum();
                let want = if a == b { 1.0 } else { 0.0 };
                assert!((dot - want).abs() < 1e-5, "{a},{b}: {dot}");
            }
        }
        let again = orthogonal(rows, cols, 1.0, &mut ChaCha8Rng::seed_from_u64(1));
        assert_eq!(w, again);
    }
}
