//! What keeps one message from poisoning the policy: the log-probabilities an actor can
//! report lie within the range the wire accepts, and an update that would leave weights
//! that are not finite is undone.

use jsae_nn::DeviceKind;
use jsae_wire::ActionBatch;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::Learner;
use crate::PpoConfig;
use jsae_agent::policy::{LOG_STD_MAX, LOG_STD_MIN, PolicyHead};

fn flat(learner: &Learner) -> Vec<f32> {
    learner.host_policy().params.slices().concat()
}

#[test]
fn every_sampled_log_prob_lies_in_the_behaviour_range() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for (head, init_log_std) in [
        (PolicyHead::Gaussian { dim: 3 }, LOG_STD_MIN),
        (PolicyHead::Gaussian { dim: 3 }, LOG_STD_MAX),
        (PolicyHead::Categorical { n: 1000 }, 0.0),
    ] {
        let config = PpoConfig {
            init_log_std,
            ..PpoConfig::default()
        };
        let learner = Learner::new(config, 4, head, 0, 1, DeviceKind::Flex);
        let (lo, hi) = head.behaviour_logp_range();
        // inputs of every size, so the categorical logits spread far
        let x: Vec<f32> = (0..4 * 4096)
            .map(|i| ((i % 97) as f32 - 48.0) * 1e3)
            .collect();
        let mut actions = match head {
            PolicyHead::Gaussian { dim } => ActionBatch::Continuous {
                dim,
                data: Vec::new(),
            },
            PolicyHead::Categorical { .. } => ActionBatch::Discrete(Vec::new()),
        };
        let mut logp = Vec::new();
        for _ in 0..25 {
            learner.policy().act(
                &x,
                learner.prior(),
                false,
                &mut rng,
                &mut actions,
                &mut logp,
            );
        }
        assert_eq!(logp.len(), 25 * 4096);
        let (min, max) = logp
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &l| {
                (a.min(l), b.max(l))
            });
        assert!(
            lo <= min && max <= hi,
            "{head:?}: [{min}, {max}] outside [{lo}, {hi}]"
        );
    }
}

#[test]
fn an_update_that_ends_in_weights_not_finite_is_undone() {
    let head = PolicyHead::Gaussian { dim: 2 };
    let config = PpoConfig {
        batch_steps: 64,
        // a step size that overflows every weight it touches
        lr: 1e300,
        ..PpoConfig::default()
    };
    let mut learner = Learner::new(config, 3, head, 0, 5, DeviceKind::Flex);
    let before = flat(&learner);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let fragment = crate::synthetic::fragment(3, head, 0, 64, &mut rng);
    let report = match learner.ingest(fragment).expect("ingests") {
        super::Ingested::Updated(report) => report,
        other => panic!("no update: {other:?}"),
    };
    assert_eq!((learner.updates(), learner.updates_refused), (1, 1));
    assert_eq!(
        flat(&learner),
        before,
        "the weights before the update are kept"
    );
    assert_eq!(jsae_nn::non_finite_values(learner.policy().net()), 0);
    // the snapshot published for the version is the kept weights, and it loads
    let mut copy = Learner::new(PpoConfig::default(), 3, head, 0, 6, DeviceKind::Flex);
    copy.restore(&report.snapshot).expect("loads");
    assert_eq!(flat(&copy), before);
}
