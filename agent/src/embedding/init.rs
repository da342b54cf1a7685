//! How the embedding model's parts are first filled: tables drawn as burn draws a linear
//! layer on one-hots (or zeros, for a template that snapshot bytes replace), linear layers,
//! and g and f for each kind of action space.

use burn::module::Param;
use burn::nn::Linear;
use burn::tensor::{Device, Tensor};
use jsae_nn::{self as nn, Mlp, MlpConfig};
use jsae_settings::{EmbeddingConfig, Representation};
use jsae_wire::ActionSpace;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// How a model's tables (phi's and g's, `rows` wide one-hots) are filled.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Tables {
    /// Drawn: a model to train.
    Drawn,
    /// Zeros: a template that snapshot bytes replace. Its pages are never written, so they
    /// take no memory (a million items' tables are 768 MB).
    Zeros,
}

pub(super) fn uniform_table(
    rows: usize,
    cols: usize,
    tables: Tables,
    rng: &mut ChaCha8Rng,
    device: &Device,
) -> Param<Tensor<2>> {
    if tables == Tables::Zeros {
        // `vec!` of zeros asks the allocator for zeroed memory: fresh pages, never written
        // (`Tensor::zeros` writes every value)
        return Param::from_tensor(nn::tensor2(vec![0.0; rows * cols], rows, cols, device));
    }
    // a linear layer on one-hots of width `rows`: U(-1/sqrt(rows), 1/sqrt(rows))
    let k = 1.0 / (rows as f32).sqrt();
    let values: Vec<f32> = (0..rows * cols).map(|_| rng.random_range(-k..k)).collect();
    Param::from_tensor(nn::tensor2(values, rows, cols, device))
}

/// A linear layer as burn's default initialises one: `U(-1/sqrt(d_in), 1/sqrt(d_in))` weights
/// (and bias).
pub fn uniform_linear(
    d_in: usize,
    d_out: usize,
    bias: bool,
    rng: &mut ChaCha8Rng,
    device: &Device,
) -> Linear {
    let k = 1.0 / (d_in as f32).sqrt();
    let w: Vec<f32> = (0..d_in * d_out).map(|_| rng.random_range(-k..k)).collect();
    let b = bias.then(|| (0..d_out).map(|_| rng.random_range(-k..k)).collect());
    nn::linear_from_host(w, b, d_in, d_out, device)
}

/// g and f: the g-table (discrete actions), or g's linear layer (not RA's, which has no
/// action encoder: its embeddings come from the inverse model) and the decoder MLP.
pub(super) type ActionParts = (Option<Param<Tensor<2>>>, Option<Linear>, Option<Mlp>);

pub(super) fn action_parts(
    config: &EmbeddingConfig,
    representation: Representation,
    actions: &ActionSpace,
    tables: Tables,
    rng: &mut ChaCha8Rng,
    device: &Device,
) -> ActionParts {
    let d = config.action_dim;
    let ra = representation == Representation::ActionRepresentation;
    match actions {
        ActionSpace::Discrete { n } => {
            (Some(uniform_table(*n, d, tables, rng, device)), None, None)
        }
        ActionSpace::Continuous { dim, .. } => {
            // RA has no action encoder: its embeddings come from the inverse model.
            let g = (!ra).then(|| uniform_linear(*dim, d, false, rng, device));
            let hidden = match representation {
                Representation::AutoEncoder => vec![],
                _ => vec![config.decoder_hidden],
            };
            let decoder = MlpConfig {
                input: d,
                hidden,
                output: *dim,
                output_gain: 1.0,
                skip: false,
                zero_inputs: 0,
                skip_identity: None,
            };
            (None, g, Some(decoder.init(rng, device)))
        }
    }
}
