//! The fused update against the burn update: two learners with the same seed, one on each
//! path, given the same batches, must move the weights the same way.

use jsae_nn::DeviceKind;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::Learner;
use crate::fused::HostPolicy;
use crate::policy::PolicyHead;
use crate::{PpoConfig, UpdatePath};

const STEPS: usize = 64;

fn flat(learner: &Learner) -> Vec<f32> {
    let host = HostPolicy::from_policy(learner.policy());
    host.params.slices().concat()
}

/// Two updates of 256 samples on each path (obs normalisation and value clipping on, a
/// smaller last minibatch).
fn compare(head: PolicyHead, tanh_mean: bool) {
    let config = PpoConfig {
        batch_steps: 4 * STEPS,
        epochs: 2,
        // 256 samples: four minibatches of 60 and a last one of 16
        minibatch_size: 60,
        tanh_mean,
        clip_value_loss: true,
        normalize_obs: true,
        ent_coef: 0.01,
        ..PpoConfig::default()
    };
    let x_dim = 5;
    let make = |update| {
        let config = PpoConfig {
            update,
            ..config.clone()
        };
        Learner::new(config, x_dim, head, 0, 7, DeviceKind::Flex)
    };
    let (mut fused, mut burn) = (make(UpdatePath::Fused), make(UpdatePath::Burn));
    let start = flat(&burn);
    assert_eq!(start, flat(&fused));
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    for update in 0..2 {
        for _ in 0..4 {
            let f = crate::synthetic::fragment(x_dim, head, update, STEPS, &mut rng);
            fused.ingest(f.clone()).expect("fused ingests");
            burn.ingest(f).expect("burn ingests");
        }
    }
    assert_eq!((fused.updates(), burn.updates()), (2, 2));
    let (a, b) = (flat(&fused), flat(&burn));
    let moved: f32 = b
        .iter()
        .zip(&start)
        .map(|(x, s)| (x - s) * (x - s))
        .sum::<f32>()
        .sqrt();
    let apart: f32 = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f32>()
        .sqrt();
    assert!(moved > 1e-3, "{head:?}: the weights moved by {moved}");
    assert!(
        apart <= 1e-3 * moved,
        "{head:?} tanh_mean {tanh_mean}: paths {apart} apart after moving {moved}"
    );
    let (sf, sb) = (fused.policy().obs_stats(), burn.policy().obs_stats());
    assert_eq!(sf, sb, "observation statistics");
}

#[test]
fn fused_and_burn_updates_move_the_weights_alike() {
    compare(PolicyHead::Gaussian { dim: 3 }, false);
    compare(PolicyHead::Gaussian { dim: 3 }, true);
    compare(PolicyHead::Categorical { n: 9 }, false);
}
