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
    /// A linear path from the input straight to the output, added to the last layer's
    /// (a "wide and deep" network: on one-hot inputs a table of one output row per input
    /// entry, which a narrow hidden layer cannot hold). Starts at zero.
    #[serde(default)]
    pub skip: bool,
    /// Input columns past `input` whose weights start at zero (a crossed feature's buckets,
    /// [`crate::SparseRows::crossed`]): the network reads `input + zero_inputs` columns and
    /// starts as the network of the first `input` alone, initialised as that one would be.
    #[serde(default)]
    pub zero_inputs: usize,
    /// With `skip`: the skip path starts as the identity from the `output` input columns from
    /// this one to the outputs (instead of zero), so the network starts by passing that part
    /// of its input through (plus the layers' small output).
    #[serde(default)]
    pub skip_identity: Option<usize>,
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
        let inputs = self.input + self.zero_inputs;
        if let (Some(first), true) = (layers.first_mut(), self.zero_inputs > 0) {
            // zero rows below the first layer's [input, out] weights; biases are zero
            let out = first.weight.val().dims()[1];
            let mut w = crate::to_vec(first.weight.val());
            w.resize(inputs * out, 0.0);
            *first = crate::linear_from_host(w, Some(vec![0.0; out]), inputs, out, device);
        }
        let skip = self.skip.then(|| {
            let mut w = vec![0.0; inputs * self.output];
            if let Some(start) = self.skip_identity {
                for j in (0..self.output).filter(|j| start + j < inputs) {
                    w[(start + j) * self.output + j] = 1.0;
                }
            }
            crate::linear_from_host(w, None, inputs, self.output, device)
        });
        Mlp {
            layers,
            skip,
            activation: Tanh::new(),
        }
    }
}

/// Linear layers with tanh between them.
#[derive(Module, Debug)]
pub struct Mlp {
    layers: Vec<Linear>,
    /// The input-to-output path ([`MlpConfig::skip`]), without a bias.
    skip: Option<Linear>,
    activation: Tanh,
}

impl Mlp {
    /// The linear layers, input first (burn's weights are `[in, out]`).
    pub fn layers(&self) -> &[Linear] {
        &self.layers
    }

    /// The input-to-output path, if the MLP has one.
    pub fn skip(&self) -> Option<&Linear> {
        self.skip.as_ref()
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
        if let (Some(layer), Some(w)) = (self.skip.take(), host.skip.as_ref()) {
            let values: Vec<f32> = w.iter().copied().collect();
            self.skip = Some(Linear {
                weight: layer.weight.map(|old| replaced(old, &values)),
                bias: None,
            });
        }
    }

    /// `[batch, input] -> [batch, output]`.
    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        let wide = self.skip.as_ref().map(|skip| skip.forward(x.clone()));
        let mut x = x;
        let last = self.layers.len().saturating_sub(1);
        for (i, layer) in self.layers.iter().enumerate() {
            x = layer.forward(x);
            if i < last {
                x = self.activation.forward(x);
            }
        }
        match wide {
            Some(wide) => x + wide,
            None => x,
        }
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
