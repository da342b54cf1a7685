//! Adam and global gradient-norm clipping over flat host parameters, with burn's arithmetic:
//! `m = b1 m + (1 - b1) g`, `v = b2 v + (1 - b2) g^2`, and
//! `p -= lr * (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps)` (as
//! `burn::optim::Adam`, no weight decay); clipping as [`crate::clip_global_grad_norm`].

/// Adam's moments for a list of parameter slices (shapes fixed by the first step).
#[derive(Debug, Clone)]
pub struct HostAdam {
    beta_1: f32,
    beta_2: f32,
    epsilon: f32,
    time: i32,
    moment_1: Vec<Vec<f32>>,
    moment_2: Vec<Vec<f32>>,
}

impl HostAdam {
    /// Adam with betas 0.9 / 0.999 and the given epsilon.
    pub fn new(epsilon: f32) -> Self {
        Self {
            beta_1: 0.9,
            beta_2: 0.999,
            epsilon,
            time: 0,
            moment_1: Vec::new(),
            moment_2: Vec::new(),
        }
    }

    /// One step: `params[i] -= lr * adam(grads[i])`. The lists must keep their order and
    /// shapes from step to step (a shape change restarts the moments of that slice).
    pub fn step(&mut self, lr: f32, params: &mut [&mut [f32]], grads: &[&[f32]]) {
        if self.moment_1.len() != params.len() {
            self.moment_1 = params.iter().map(|p| vec![0.0; p.len()]).collect();
            self.moment_2 = self.moment_1.clone();
        }
        self.time += 1;
        let (b1, b2) = (self.beta_1, self.beta_2);
        let bias_1 = 1.0 - b1.powi(self.time);
        let bias_2_sqrt = (1.0 - b2.powi(self.time)).sqrt();
        // burn's form: m * (sqrt(bc2) / bc1) / (sqrt(v) + eps * sqrt(bc2))
        let factor = bias_2_sqrt / bias_1;
        let eps = self.epsilon * bias_2_sqrt;
        for (i, (p, g)) in params.iter_mut().zip(grads).enumerate() {
            let (m, v) = (&mut self.moment_1[i], &mut self.moment_2[i]);
            if m.len() != p.len() {
                *m = vec![0.0; p.len()];
                *v = vec![0.0; p.len()];
            }
            for (((p, &g), m), v) in p
                .iter_mut()
                .zip(g.iter())
                .zip(m.iter_mut())
                .zip(v.iter_mut())
            {
                *m = b1 * *m + (1.0 - b1) * g;
                *v = b2 * *v + (1.0 - b2) * g * g;
                *p -= lr * (*m * factor) / (v.sqrt() + eps);
            }
        }
    }
}

/// Scales all gradients so their joint L2 norm is at most `max_norm`; returns the norm
/// before clipping (a non-finite norm leaves them as they are).
pub fn clip_global_norm(grads: &mut [&mut [f32]], max_norm: f32) -> f32 {
    let sq: f64 = grads
        .iter()
        .map(|g| g.iter().map(|&v| f64::from(v) * f64::from(v)).sum::<f64>())
        .sum();
    let norm = sq.sqrt() as f32;
    if norm > max_norm && norm.is_finite() {
        let factor = max_norm / (norm + 1e-6);
        for g in grads.iter_mut() {
            g.iter_mut().for_each(|v| *v *= factor);
        }
    }
    norm
}

#[cfg(test)]
mod tests {
    //! Against burn's Adam and clipping on the same parameters and gradients.

    use super::*;
    use crate::{BurnDevice, DeviceKind};
    use burn::module::{Module, Param};
    use burn::optim::{AdamConfig, GradientsParams};
    use burn::tensor::Tensor;

    #[derive(Module, Debug)]
    struct Two {
        a: Param<Tensor<1>>,
        b: Param<Tensor<1>>,
    }

    #[test]
    fn adam_steps_and_clipping_equal_burns() {
        let device = DeviceKind::Flex.train_device();
        let a0: Vec<f32> = (0..7).map(|i| (i as f32 * 0.37).sin()).collect();
        let b0: Vec<f32> = (0..3).map(|i| (i as f32 * 1.3).cos()).collect();
        let mut module = Two {
            a: Param::from_tensor(crate::tensor1(a0.clone(), &device)),
            b: Param::from_tensor(crate::tensor1(b0.clone(), &device)),
        };
        let mut optim = AdamConfig::new().with_epsilon(1e-5).init();
        let mut host = HostAdam::new(1e-5);
        let (mut ha, mut hb) = (a0, b0);
        for step in 0..5 {
            // loss = sum(c_a * a^3) + sum(c_b * b^2): gradients 3 c_a a^2 and 2 c_b b
            let scale = 1.0 + step as f32;
            let ca: Vec<f32> = (0..7).map(|i| scale * (i as f32 - 3.0)).collect();
            let cb: Vec<f32> = (0..3).map(|i| scale * (1.0 - i as f32)).collect();
            let loss = (module.a.val().powi_scalar(3) * crate::tensor1(ca.clone(), &device)).sum()
                + (module.b.val().powi_scalar(2) * crate::tensor1(cb.clone(), &device)).sum();
            let mut grads = GradientsParams::from_grads(loss.backward(), &module);
            let burn_norm = crate::clip_global_grad_norm(&module, &mut grads, 1.0);
            module = optim.step(1e-2, module, grads);

            let mut ga: Vec<f32> = ha.iter().zip(&ca).map(|(a, c)| 3.0 * c * a * a).collect();
            let mut gb: Vec<f32> = hb.iter().zip(&cb).map(|(b, c)| 2.0 * c * b).collect();
            let norm = clip_global_norm(&mut [&mut ga, &mut gb], 1.0);
            host.step(1e-2, &mut [&mut ha, &mut hb], &[&ga, &gb]);
            assert!(
                (norm - burn_norm).abs() <= 1e-5 * burn_norm,
                "{norm} vs {burn_norm}"
            );
            for (h, b) in ha.iter().zip(crate::to_vec(module.a.val())) {
                assert!((h - b).abs() < 1e-6, "step {step}: a {h} vs {b}");
            }
            for (h, b) in hb.iter().zip(crate::to_vec(module.b.val())) {
                assert!((h - b).abs() < 1e-6, "step {step}: b {h} vs {b}");
            }
        }
    }
}
