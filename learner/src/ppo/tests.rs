//! The fused update against the burn update: two learners with the same seed, one on each
//! path, given the same batches, must move the weights the same way.

use jsae_nn::DeviceKind;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::Learner;
use crate::{PpoConfig, UpdatePath};
use jsae_agent::PolicyHead;
use jsae_settings::RecommenderPpoConfig;

const STEPS: usize = 64;

fn flat(learner: &Learner) -> Vec<f32> {
    let host = learner.host_policy();
    host.params.slices().concat()
}

/// Rewrites `x` (rows of `width`) as one-hot rows.
fn one_hot(x: &mut [f32], width: usize, rng: &mut ChaCha8Rng) {
    for row in x.chunks_mut(width) {
        row.fill(0.0);
        row[rng.random_range(0..width)] = 1.0;
    }
}

/// Two updates of 256 samples on each path (value clipping on, a smaller last minibatch),
/// with obs normalisation on dense inputs, or one-hot inputs as plain PPO reads categorical
/// states (the first layer as a row lookup).
fn compare(head: PolicyHead, tanh_mean: bool, one_hot_inputs: bool) {
    let config = PpoConfig {
        batch_steps: 4 * STEPS,
        epochs: 2,
        // 256 samples: four minibatches of 60 and a last one of 16
        minibatch_size: 60,
        tanh_mean,
        clip_value_loss: true,
        normalize_obs: !one_hot_inputs,
        ent_coef: 0.01,
        ..PpoConfig::default()
    };
    let x_dim = if one_hot_inputs { 40 } else { 5 };
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
            let mut f = crate::synthetic::fragment(x_dim, head, update, STEPS, &mut rng);
            if one_hot_inputs {
                for x in [&mut f.x, &mut f.truncated_next_x, &mut f.last_next_x] {
                    one_hot(x, x_dim, &mut rng);
                }
            }
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
    compare(PolicyHead::Gaussian { dim: 3 }, false, false);
    compare(PolicyHead::Gaussian { dim: 3 }, true, false);
    compare(PolicyHead::Categorical { n: 9 }, false, false);
}

#[test]
fn one_hot_inputs_and_a_wide_head_split_between_threads_move_the_weights_alike() {
    // 60 x 1,200 logits: the softmax rows and the output layer's products are split
    compare(PolicyHead::Categorical { n: 1200 }, false, true);
}

/// Rewrites `x` (rows of two one-hot factors of `size`) with random values of both; the
/// crossed buckets of the rows are added to `buckets`.
fn two_factors(
    x: &mut [f32],
    size: usize,
    pair_buckets: usize,
    buckets: &mut Vec<usize>,
    rng: &mut ChaCha8Rng,
) {
    for row in x.chunks_mut(2 * size) {
        row.fill(0.0);
        let (a, b) = (rng.random_range(0..size), size + rng.random_range(0..size));
        (row[a], row[b]) = (1.0, 1.0);
        buckets.push(jsae_nn::pair_bucket(a as u32, b as u32, 0, pair_buckets));
    }
}

#[test]
fn crossed_pairs_train_only_the_bucket_rows_their_inputs_pick_and_act_as_burns_model() {
    let (size, pair_buckets, n) = (7, 64, 6);
    let x_dim = 2 * size;
    let config = PpoConfig {
        batch_steps: 4 * STEPS,
        epochs: 2,
        minibatch_size: 60,
        recommender: RecommenderPpoConfig {
            pair_buckets,
            pair_scale: 2.0,
            next_purchase_coef: 0.5,
            ..RecommenderPpoConfig::default()
        },
        ..PpoConfig::default()
    };
    let head = PolicyHead::Categorical { n };
    let mut learner = Learner::new(config, x_dim, head, 0, 7, DeviceKind::Flex);
    let start = learner.host_policy();
    assert!(
        start.params.actor.w[0]
            .rows()
            .into_iter()
            .skip(x_dim)
            .all(|r| r.iter().all(|&v| v == 0.0)),
        "the bucket rows start at zero"
    );
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let (mut trained, mut other) = (Vec::new(), Vec::new());
    for _ in 0..4 {
        let mut f = crate::synthetic::fragment(x_dim, head, 0, STEPS, &mut rng);
        two_factors(&mut f.x, size, pair_buckets, &mut trained, &mut rng);
        two_factors(
            &mut f.truncated_next_x,
            size,
            pair_buckets,
            &mut other,
            &mut rng,
        );
        two_factors(&mut f.last_next_x, size, pair_buckets, &mut other, &mut rng);
        learner.ingest(f).expect("ingests");
    }
    assert_eq!(learner.updates(), 1);
    let end = learner.host_policy();
    for (net, w) in [
        ("actor", &end.params.actor.w[0]),
        ("critic", &end.params.critic.w[0]),
    ] {
        for bucket in 0..pair_buckets {
            let row = w.row(x_dim + bucket);
            let moved = row.iter().any(|&v| v != 0.0);
            assert_eq!(
                moved,
                trained.contains(&bucket),
                "{net}: bucket {bucket} moved {moved}"
            );
        }
    }
    let distinct = (0..pair_buckets).filter(|b| trained.contains(b)).count();
    assert!(
        (10..pair_buckets).contains(&distinct),
        "{distinct} buckets trained"
    );

    // acting on the host equals burn's model on the crossed feature written out densely
    let mut x = vec![0.0; 5 * x_dim];
    let mut buckets = Vec::new();
    two_factors(&mut x, size, pair_buckets, &mut buckets, &mut rng);
    let host = learner.policy().head_outputs(&x, None);
    let width = x_dim + pair_buckets;
    let mut dense = vec![0.0; 5 * width];
    for (r, (row, bucket)) in x.chunks(x_dim).zip(&buckets).enumerate() {
        dense[r * width..r * width + x_dim].copy_from_slice(row);
        dense[r * width + x_dim + bucket] = 2.0;
    }
    let (actor, _, _) = learner.policy().parts();
    let device = learner.policy().device().clone();
    let burn = jsae_nn::to_vec(actor.forward(jsae_nn::tensor2(dense, 5, width, &device)));
    assert_eq!(host.len(), burn.len());
    for (h, b) in host.iter().zip(&burn) {
        assert!((h - b).abs() < 1e-5, "host {h}, burn {b}");
    }
}

#[test]
fn ingest_refuses_an_absurd_reward_and_a_claim_that_goes_back_and_credits_no_more_than_delivered() {
    use crate::LearnerError;
    use jsae_wire::ValidationError;
    let head = PolicyHead::Gaussian { dim: 2 };
    let config = PpoConfig {
        batch_steps: 1024,
        ..PpoConfig::default()
    };
    let mut learner = Learner::new(config, 5, head, 0, 7, DeviceKind::Flex);
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let mut f = crate::synthetic::fragment(5, head, 0, 8, &mut rng);
    f.actor_env_steps = 8;
    learner.ingest(f.clone()).expect("a genuine fragment");
    assert_eq!(learner.env_steps(), 8);

    let mut poisoned = f.clone();
    poisoned.actor_env_steps = 16;
    poisoned.rewards[2] = 3e38;
    let refused = learner.ingest(poisoned);
    assert!(
        matches!(
            refused,
            Err(LearnerError::Invalid(ValidationError::Bound {
                index: 2,
                ..
            }))
        ),
        "{refused:?}"
    );
    let mut back = f.clone();
    back.actor_env_steps = 4;
    assert!(matches!(learner.ingest(back), Err(LearnerError::Claim(_))));
    assert_eq!(learner.env_steps(), 8, "neither counted");

    // a claim of 10^12 from a new incarnation of the same id: its own account, its length
    let mut forged = f;
    forged.actor_incarnation = 2;
    forged.actor_env_steps = 1_000_000_000_000;
    learner.ingest(forged).expect("well formed");
    assert_eq!(learner.env_steps(), 16);
}

#[test]
fn a_batch_is_split_into_parts_of_at_least_the_update_size_in_arrival_order() {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let head = PolicyHead::Gaussian { dim: 2 };
    let frags = |lens: &[usize], rng: &mut ChaCha8Rng| {
        lens.iter()
            .enumerate()
            .map(|(i, &n)| {
                let mut f = crate::synthetic::fragment(3, head, 0, n, rng);
                f.env_index = i as u32;
                f
            })
            .collect::<Vec<_>>()
    };
    let sizes = |parts: Vec<Vec<jsae_wire::RolloutFragment>>| -> Vec<Vec<u32>> {
        parts
            .iter()
            .map(|p| p.iter().map(|f| f.env_index).collect())
            .collect()
    };
    let whole = super::split_batch(frags(&[4, 4, 4], &mut rng), None);
    assert_eq!(sizes(whole), [vec![0, 1, 2]]);
    let two = super::split_batch(frags(&[4, 4, 4, 4], &mut rng), Some(8));
    assert_eq!(sizes(two), [vec![0, 1], vec![2, 3]]);
    // 12 steps at 8: no short last part
    let one = super::split_batch(frags(&[4, 4, 4], &mut rng), Some(8));
    assert_eq!(sizes(one), [vec![0, 1, 2]]);
}

#[test]
fn a_batch_of_two_rollouts_updated_in_two_parts_publishes_one_version() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let head = PolicyHead::Gaussian { dim: 2 };
    let config = PpoConfig {
        batch_steps: 4 * STEPS,
        epochs: 2,
        minibatch_size: 64,
        max_update_steps: Some(2 * STEPS),
        ..PpoConfig::default()
    };
    let mut whole = Learner::new(
        PpoConfig {
            max_update_steps: None,
            ..config.clone()
        },
        3,
        head,
        1 << 20,
        1,
        DeviceKind::Flex,
    );
    let mut split = Learner::new(config, 3, head, 1 << 20, 1, DeviceKind::Flex);
    let mut reports = Vec::new();
    for k in 0..4u64 {
        let f = crate::synthetic::fragment(3, head, 0, STEPS, &mut rng);
        let mut f = f;
        f.actor_env_steps = (k + 1) * STEPS as u64;
        whole.ingest(f.clone()).expect("ingests");
        if let super::Ingested::Updated(r) = split.ingest(f).expect("ingests") {
            reports.push(r);
        }
    }
    assert_eq!(reports.len(), 1);
    assert_eq!((split.version(), whole.version()), (1, 1));
    assert_eq!(reports[0].metrics.epochs, 4, "two parts of two epochs");
    assert_ne!(
        flat(&split),
        flat(&whole),
        "two passes move the weights otherwise"
    );
}

/// `ppo.minibatches` cuts a batch into that many minibatches: on a batch of 256, a count of 4
/// is the same update as a `minibatch_size` of 64, on both paths.
#[test]
fn a_count_of_minibatches_is_a_size_of_the_batch_over_the_count() {
    let head = PolicyHead::Gaussian { dim: 2 };
    for update in [UpdatePath::Fused, UpdatePath::Burn] {
        let sized = PpoConfig {
            batch_steps: 4 * STEPS,
            epochs: 2,
            minibatch_size: 64,
            update,
            ..PpoConfig::default()
        };
        let counted = PpoConfig {
            minibatch_size: 7,
            minibatches: Some(4),
            ..sized.clone()
        };
        let weights = |config: PpoConfig| {
            let mut learner = Learner::new(config, 3, head, 1 << 20, 1, DeviceKind::Flex);
            let mut rng = ChaCha8Rng::seed_from_u64(5);
            for _ in 0..4 {
                let f = crate::synthetic::fragment(3, head, 0, STEPS, &mut rng);
                learner.ingest(f).expect("ingests");
            }
            assert_eq!(learner.version(), 1);
            flat(&learner)
        };
        assert_eq!(weights(counted), weights(sized), "{update:?}");
    }
}

/// A policy whose std the entropy bonus holds at its cap (log std 0.5 in E) is held under
/// the falling cap over the run's last quarter, and ends the run at `entropy_log_std_final`.
#[test]
fn the_std_is_held_under_the_falling_entropy_cap() {
    let head = PolicyHead::Gaussian { dim: 2 };
    let config = PpoConfig {
        batch_steps: 4 * STEPS,
        minibatch_size: 64,
        tanh_mean: true,
        ent_coef: 0.05,
        init_log_std: 0.5,
        ..PpoConfig::default()
    };
    let total = 4 * config.batch_steps as u64;
    let mut learner = Learner::new(config, 5, head, total, 7, DeviceKind::Flex);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let (mut ends, mut claimed) = (Vec::new(), 0);
    for update in 0..4 {
        for _ in 0..4 {
            let mut f = crate::synthetic::fragment(5, head, update, STEPS, &mut rng);
            claimed += STEPS as u64;
            f.actor_env_steps = claimed;
            learner.ingest(f).expect("a valid fragment");
        }
        let max = learner
            .policy()
            .log_std_values()
            .into_iter()
            .fold(f32::MIN, f32::max);
        ends.push(max);
    }
    // up to three quarters of the run nothing is held (the bonus keeps the std near 0.5);
    // at the end it is under -1
    assert!(ends[..3].iter().all(|&v| v > 0.3), "{ends:?}");
    assert!(ends[3] <= -1.0, "{ends:?}");
}
