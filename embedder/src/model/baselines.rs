//! The two baselines' losses (their heads are built with the model, `jsae_agent`). Both keep JSAE's inference side, so actors, the
//! recommender and the plots use them unchanged: phi embeds states, the g-table's rows are
//! what nearest-neighbour f decodes to (discrete actions), and the decoder MLP is f for
//! continuous actions.
//!
//! - **AE**: two auto-encoders, one for states and one for actions, each two layers: the
//!   first is phi (or g), a linear layer and tanh, the second decodes it back to its input.
//!   Losses: the state's reconstruction (cross-entropy per factor, or MSE on normalised
//!   states), reported as the model loss, and the action's (cross-entropy over the actions,
//!   or MSE), reported as the decoder loss. Nothing ties either embedding to the dynamics.
//! - **RA** (Chandak et al. 2019): an inverse model `e = tanh(h(phi(s), phi(s')))` predicts
//!   the embedding of the action that led from s to s', and f maps it back: for discrete
//!   actions a softmax over `-scale * |e - z_a|^2` with one learned point `z_a = tanh(row)`
//!   per action (the g-table), so f's most likely action is the nearest `z_a`, which is the
//!   decode used when acting; for continuous actions the decoder MLP. One loss, `-log f(a|e)`
//!   (or the MSE of f(e) against a), trains h, phi, f and the scale together; it is reported
//!   as the model loss. The policy acts on raw states and outputs e.

use burn::nn::Linear;
use burn::tensor::Tensor;
use jsae_agent::EmbeddingModel;
use jsae_wire::{ActionBatch, StateBatch};

use super::{
    EmbeddingTraining, action_mse, per_factor, state_loss, unreachable_action, wide_softmax,
};

/// AE: (state reconstruction loss, action reconstruction loss).
pub(super) fn autoencoder_losses(
    model: &EmbeddingModel,
    states: &StateBatch,
    actions: &ActionBatch,
) -> (Tensor<1>, Tensor<1>) {
    let (Some(state_decoder), x) = (&model.net().state_decoder, model.embed_states(states)) else {
        panic!("an AE model has a state decoder")
    };
    let state_loss = state_reconstruction_loss(model, x, state_decoder, states);
    let e = model.embed_actions(actions);
    let action_loss = match (actions, &model.net().action_decoder) {
        (ActionBatch::Discrete(a), Some(decoder)) => {
            let bias = decoder.bias.as_ref().map(|b| b.val());
            wide_softmax::linear_cross_entropy(e, decoder.weight.val(), bias, a)
        }
        (ActionBatch::Continuous { .. }, _) => match model.decode(e) {
            Some(pred) => action_mse(model, pred, actions),
            None => unreachable_action(),
        },
        _ => unreachable_action(),
    };
    (state_loss.reshape([1]), action_loss.reshape([1]))
}

/// AE: the state auto-encoder's loss, as `state_loss` of
/// `decoder(x)`; categorical factors' cross-entropies on the host
/// ([`wide_softmax::linear_cross_entropy`] on each factor's columns of the decoder).
fn state_reconstruction_loss(
    model: &EmbeddingModel,
    x: Tensor<2>,
    decoder: &Linear,
    states: &StateBatch,
) -> Tensor<1> {
    let [d, _] = decoder.weight.dims();
    let per_factor = per_factor(model, states, |columns, target| {
        let w = decoder.weight.val().slice([0..d, columns.clone()]);
        let bias = (decoder.bias.as_ref()).map(|b| b.val().narrow(0, columns.start, columns.len()));
        wide_softmax::linear_cross_entropy(x.clone(), w, bias, &target)
    });
    per_factor.unwrap_or_else(|| state_loss(model, decoder.forward(x), states))
}

/// RA: `(-log f(a | h(s, s')) or MSE, 0)`.
pub(super) fn inverse_losses(
    model: &EmbeddingModel,
    states: &StateBatch,
    actions: &ActionBatch,
    next_states: &StateBatch,
) -> (Tensor<1>, Tensor<1>) {
    let e = model.infer_action_embeddings(states, next_states);
    let scored = model
        .action_table()
        .zip(model.net().inverse_log_scale.as_ref());
    let loss = match (actions, scored) {
        (ActionBatch::Discrete(a), Some((z, log_scale))) => {
            wide_softmax::distance_cross_entropy(e, z, log_scale.val(), a)
        }
        (ActionBatch::Continuous { .. }, _) => match model.decode(e) {
            Some(pred) => action_mse(model, pred, actions),
            None => unreachable_action(),
        },
        _ => unreachable_action(),
    };
    (loss.reshape([1]), Tensor::zeros([1], model.device()))
}

/// RA's inverse model: the embedding of the action that led from each s to s',
/// `[batch, d]`.
pub(super) fn infer_action_embeddings(
    model: &EmbeddingModel,
    states: &StateBatch,
    next: &StateBatch,
) -> Tensor<2> {
    let Some(inverse) = &model.net().inverse else {
        panic!("only an RA model has an inverse model")
    };
    let x = Tensor::cat(
        vec![model.embed_states(states), model.embed_states(next)],
        1,
    );
    inverse.forward(x).tanh()
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Device;
    use jsae_settings::EmbeddingConfig;
    use jsae_settings::Representation;
    use jsae_wire::{ActionSpace, StateSpace};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn the_state_decoders_loss_per_factor_equals_the_graphs() {
        let device = Device::flex().autodiff();
        let states = StateSpace::Categorical {
            sizes: vec![5, 7, 3],
        };
        let actions = ActionSpace::Discrete { n: 11 };
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let config = EmbeddingConfig::default();
        let model = EmbeddingModel::new(
            &config,
            Representation::AutoEncoder,
            &states,
            &actions,
            &mut rng,
            &device,
        );
        let batch = StateBatch::Categorical {
            factors: 3,
            data: vec![0, 6, 2, 4, 0, 1, 3, 3, 0, 1, 5, 2],
        };
        let decoder = model
            .net()
            .state_decoder
            .as_ref()
            .expect("an AE has a state decoder");
        let graph = state_loss(&model, decoder.forward(model.embed_states(&batch)), &batch);
        let host = state_reconstruction_loss(&model, model.embed_states(&batch), decoder, &batch);
        let (g, h) = (
            jsae_nn::to_vec(graph.clone()),
            jsae_nn::to_vec(host.clone()),
        );
        assert!((g[0] - h[0]).abs() < 1e-5, "{g:?} against {h:?}");
        let (gg, hg) = (graph.backward(), host.backward());
        let table = model.net().phi_table.as_ref().expect("categorical states");
        for p in [table.val(), decoder.weight.val()] {
            let grad = |g| jsae_nn::to_vec(p.grad(g).expect("a gradient"));
            for (x, y) in grad(&gg).iter().zip(grad(&hg)) {
                assert!((x - y).abs() < 1e-5, "{x} against {y}");
            }
        }
    }
}
