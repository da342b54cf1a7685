//! Warm starts (`--init-from RUN`): the parts of another run's model whose shapes match this
//! one's are copied over. Between action spaces of different sizes that is phi, T (and its
//! hidden layer), the state statistics, RA's inverse model, phi's pair rows and the
//! next-item head; g, f and the AE's action decoder come along only when the action counts
//! are equal.

use burn::module::Param;
use burn::nn::Linear;
use burn::tensor::Tensor;
use jsae_nn::Mlp;

use jsae_agent::EmbeddingModel;

fn same_linear(a: &Option<Linear>, b: &Option<Linear>) -> bool {
    match (a, b) {
        (Some(a), Some(b)) => {
            a.weight.dims() == b.weight.dims()
                && a.bias.as_ref().map(|p| p.dims()) == b.bias.as_ref().map(|p| p.dims())
        }
        _ => false,
    }
}

fn same_table(a: &Option<Param<Tensor<2>>>, b: &Option<Param<Tensor<2>>>) -> bool {
    matches!((a, b), (Some(a), Some(b)) if a.dims() == b.dims())
}

fn same_mlp(a: &Option<Mlp>, b: &Option<Mlp>) -> bool {
    match (a, b) {
        (Some(a), Some(b)) => {
            a.layers().len() == b.layers().len()
                && a.layers()
                    .iter()
                    .zip(b.layers())
                    .all(|(x, y)| x.weight.dims() == y.weight.dims())
        }
        _ => false,
    }
}

/// Copies every part of `source` whose shape matches `model`'s (both of the same
/// representation); returns the names of the parts copied.
pub(super) fn warm_start(model: &mut EmbeddingModel, source: &EmbeddingModel) -> Vec<&'static str> {
    let same_states = model.state_space() == source.state_space();
    let (to, from) = (model.net_mut(), source.net());
    let mut copied = Vec::new();
    macro_rules! take {
        ($field:ident, $same:expr) => {
            if $same(&to.$field, &from.$field) {
                to.$field = from.$field.clone();
                copied.push(stringify!($field));
            }
        };
    }
    take!(phi_table, same_table);
    take!(phi_linear, same_linear);
    take!(g_table, same_table);
    take!(g_linear, same_linear);
    take!(transition_in, same_linear);
    take!(transition, same_linear);
    take!(decoder, same_mlp);
    take!(state_decoder, same_linear);
    take!(action_decoder, same_linear);
    take!(inverse, same_mlp);
    let both =
        |a: &Option<Param<Tensor<1>>>, b: &Option<Param<Tensor<1>>>| a.is_some() && b.is_some();
    take!(inverse_log_scale, both);
    if same_states {
        take!(phi_pair, same_table);
    }
    take!(next_item, same_linear);
    take!(next_item_log_scale, both);
    let same_norm = matches!((&to.state_norm, &from.state_norm), (Some(_), Some(_))) && same_states;
    if same_norm {
        to.state_norm = from.state_norm.clone();
        copied.push("state_norm");
    }
    copied
}
