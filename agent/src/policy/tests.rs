//! The policy's weights as bytes: what travels with them.

use super::*;
use jsae_nn::{BurnDevice, DeviceKind};
use jsae_wire::ActionBatch;
use rand::SeedableRng;

#[test]
fn observation_statistics_travel_with_the_weights() {
    let device = DeviceKind::Flex.device();
    let config = PpoConfig {
        normalize_obs: true,
        ..PpoConfig::default()
    };
    let head = PolicyHead::Gaussian { dim: 2 };
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut policy = Policy::new(&config, 3, head, &mut rng, &device);
    let x: Vec<f32> = (0..300).map(|i| (i % 7) as f32 * 10.0 + 100.0).collect();
    policy.update_obs_stats(&x);
    let (mean, var, count) = policy.obs_stats().expect("normalises");
    assert!(mean.iter().all(|&m| m > 100.0) && var.iter().all(|&v| v > 100.0));
    assert!((count - 100.0).abs() < 1e-2);

    let bytes = policy.record_bytes().expect("serialises");
    let mut fresh = Policy::new(&config, 3, head, &mut rng, &device);
    assert_ne!(fresh.obs_stats().map(|s| s.0), Some(mean.clone()));
    fresh.load_record(&bytes).expect("loads");
    assert_eq!(fresh.obs_stats().map(|s| (s.0, s.1)), Some((mean, var)));

    let probe = vec![130.0, 110.0, 150.0];
    let act = |p: &Policy| {
        let (mut a, mut lp) = (ActionBatch::empty(&head.action_space()), Vec::new());
        p.act(
            &probe,
            None,
            true,
            &mut ChaCha8Rng::seed_from_u64(0),
            &mut a,
            &mut lp,
        );
        a
    };
    let loaded = {
        let mut p = Policy::new(&config, 3, head, &mut rng, &device);
        p.load_record(&bytes).expect("loads");
        p
    };
    assert_eq!(
        act(&policy),
        act(&loaded),
        "same weights and statistics, same action"
    );
}

#[test]
fn the_mean_starts_at_the_next_item_part_of_the_input() {
    let device = DeviceKind::Flex.device();
    let mut config = PpoConfig {
        tanh_mean: true,
        ..PpoConfig::default()
    };
    config.recommender.mean_at_next_item = true;
    let head = PolicyHead::Gaussian { dim: 3 };
    let policy = Policy::new(&config, 7, head, &mut ChaCha8Rng::seed_from_u64(2), &device);
    // phi's 4 columns, then the head's pre-activation (3)
    let x = [0.9, -0.4, 0.2, 0.7, 1.5, -0.3, 0.05];
    let mean = policy.head_outputs(&x, None);
    for (j, m) in mean.iter().enumerate() {
        let want = f32::tanh(x[4 + j]);
        assert!((m - want).abs() < 0.05, "component {j}: {m} against {want}");
    }
    // and it is a warm start: the path is a parameter like the others
    let plain = Policy::new(
        &PpoConfig::default(),
        7,
        head,
        &mut ChaCha8Rng::seed_from_u64(2),
        &device,
    );
    let far = plain.head_outputs(&x, None);
    assert!(far.iter().all(|m| m.abs() < 0.05), "{far:?}");
}
