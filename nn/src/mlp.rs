//! A tanh multi-layer perceptron with orthogonal initialisation.

use burn::module::Module;
use burn::nn::{Linear, Tanh};
use burn::tensor::{Device, Tensor, TensorData};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::seeded_linear;

/// Shape of an MLP.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MlpConfig {
    /// Input width.
    pub input: usize,
    /// Hidden widths (tanh after each).
    pub hidden: Vec<usize>,
    /// Output width (no activation).
    pub output: usize,
    /// Gain of the output layer's orthogonal initialisation.
    pub output_gain: f32,
}

impl MlpConfig {
    /// Builds the MLP: hidden layers with gain sqrt(2), biases zero.
    pub fn init(&self, rng: &mut ChaCha8Rng, device: &Device) -> Mlp {
        let mut layers = Vec::new();
        let mut width = self.input;
        for &h in &self.hidden {
            layers.push(seeded_linear(width, h, 2f32.sqrt(), true, rng, device));
            width = h;
        }
        layers.push(seeded_linear(
            width,
            self.output,
            self.output_gain,
            true,
            rng,
            device,
        ));
        Mlp {
            layers,
            activation: Tanh::new(),
        }
    }
}

/// Linear layers with tanh between them.
#[derive(Module, Debug)]
pub struct Mlp {
    layers: Vec<Linear>,
    activation: Tanh,
}

impl Mlp {
    /// The linear layers, input first (burn's weights are `[in, out]`).
    pub fn layers(&self) -> &[Linear] {
        &self.layers
    }

    /// Replaces the weights with `host`'s (an MLP of this one's shapes, read in burn's layout
    /// through [`crate::HostMlp::weight`]), keeping each parameter's id and whether it
    /// requires gradients.
    pub fn set_from_host(&mut self, host: &crate::HostMlp) {
        let layers = std::mem::take(&mut self.layers);
        self.layers = layers
            .into_iter()
            .enumerate()
            .map(|(i, layer)| Linear {
                weight: layer
                    .weight
                    .map(|old| replaced(old, &host.weight(i).iter().copied().collect::<Vec<_>>())),
                bias: layer
                    .bias
                    .map(|p| p.map(|old| replaced(old, host.b[i].as_slice().unwrap_or(&[])))),
            })
            .collect();
    }

    /// `[batch, input] -> [batch, output]`.
    pub fn forward(&self, mut x: Tensor<2>) -> Tensor<2> {
        let last = self.layers.len().saturating_sub(1);
        for (i, layer) in self.layers.iter().enumerate() {
            x = layer.forward(x);
            if i < last {
                x = self.activation.forward(x);
            }
        }
        x
    }
}

/// A tensor of `old`'s shape, device and gradient requirement holding `values` (a parameter's
/// new value, for `Param::map`).
pub fn replaced<const D: usize>(old: Tensor<D>, values: &[f32]) -> Tensor<D> {
    let fresh =
        Tensor::<D>::from_data(TensorData::new(values.to_vec(), old.shape()), &old.device());
    if old.is_require_grad() {
        fresh.require_grad()
    } else {
        fresh
    }
}
