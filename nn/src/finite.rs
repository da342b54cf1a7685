//! Whether a module's weights are all finite: a trainer checks it after each update, before
//! weights are published or checkpointed.

use burn::module::{Module, ModuleVisitor, Param};
use burn::tensor::Tensor;

struct NonFinite(usize);

impl ModuleVisitor for NonFinite {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let data = param.val().into_data();
        self.0 += data.iter::<f32>().filter(|v| !v.is_finite()).count();
    }
}

/// How many of the module's parameter values are NaN or infinite.
pub fn non_finite_values<M: Module>(module: &M) -> usize {
    let mut count = NonFinite(0);
    module.visit(&mut count);
    count.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finite_weights_count_none_and_each_nan_or_infinity_counts() {
        let device = burn::tensor::Device::flex();
        let finite = Param::from_tensor(crate::tensor1(vec![1.0, -2.0, 3e38], &device));
        assert_eq!(non_finite_values(&finite), 0);
        let values = vec![1.0, f32::NAN, f32::INFINITY, 0.0, f32::NEG_INFINITY];
        let bad = Param::from_tensor(crate::tensor1(values, &device));
        assert_eq!(non_finite_values(&bad), 3);
    }
}
