//! Global gradient-norm clipping: one norm over every parameter, as PPO implementations do
//! (burn's own clipping works per parameter tensor).

use burn::module::{Module, ModuleVisitor, Param, ParamId};
use burn::optim::GradientsParams;
use burn::tensor::Tensor;

struct Ids(Vec<(ParamId, usize)>);

impl ModuleVisitor for Ids {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        self.0.push((param.id, D));
    }
}

fn with_grad<const D: usize>(grads: &GradientsParams, id: ParamId) -> f64 {
    grads
        .get::<D>(id)
        .map(|g| f64::from(g.square().sum().into_scalar::<f32>()))
        .unwrap_or(0.0)
}

fn scale<const D: usize>(grads: &mut GradientsParams, id: ParamId, factor: f32) {
    if let Some(g) = grads.remove::<D>(id) {
        grads.register::<D>(id, g.mul_scalar(factor));
    }
}

/// Scales all gradients so their joint L2 norm is at most `max_norm`; returns the norm
/// before clipping.
pub fn clip_global_grad_norm<M: Module>(
    module: &M,
    grads: &mut GradientsParams,
    max_norm: f32,
) -> f32 {
    let mut ids = Ids(Vec::new());
    module.visit(&mut ids);
    let mut sq = 0.0;
    for &(id, rank) in &ids.0 {
        sq += match rank {
            1 => with_grad::<1>(grads, id),
            2 => with_grad::<2>(grads, id),
            3 => with_grad::<3>(grads, id),
            _ => 0.0,
        };
    }
    let norm = sq.sqrt() as f32;
    if norm > max_norm && norm.is_finite() {
        let factor = max_norm / (norm + 1e-6);
        for &(id, rank) in &ids.0 {
            match rank {
                1 => scale::<1>(grads, id, factor),
                2 => scale::<2>(grads, id, factor),
                3 => scale::<3>(grads, id, factor),
                _ => {}
            }
        }
    }
    norm
}
