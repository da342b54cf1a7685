//! The learned gridworld action embeddings reflect displacement: an action's nearest
//! neighbours in E cause motions closer to its own than random actions do.

use jsae_actor::ActorWorker;
use jsae_agent::Embedding;
use jsae_embedder::EmbedderTrainer;
use jsae_envs::gridworld::action_motions;
use jsae_nn::{BurnDevice, DeviceKind};
use jsae_settings::EnvName;
use jsae_settings::{Algo, TrainConfig};

/// Mean motion distance from each action to its `k` nearest neighbours in E, and to all
/// other actions.
fn neighbour_vs_random(table: &[f32], d: usize, motions: &[[f64; 2]], k: usize) -> (f64, f64) {
    let n = motions.len();
    let dist_m =
        |a: usize, b: usize| (motions[a][0] - motions[b][0]).hypot(motions[a][1] - motions[b][1]);
    let (mut near, mut all) = (0.0, 0.0);
    for a in 0..n {
        let mut by_e: Vec<(f32, usize)> = (0..n)
            .filter(|&b| b != a)
            .map(|b| {
                let e: f32 = (0..d)
                    .map(|j| (table[a * d + j] - table[b * d + j]).powi(2))
                    .sum();
                (e, b)
            })
            .collect();
        by_e.sort_by(|x, y| x.0.total_cmp(&y.0));
        near += by_e[..k].iter().map(|&(_, b)| dist_m(a, b)).sum::<f64>() / k as f64;
        all += (0..n)
            .filter(|&b| b != a)
            .map(|b| dist_m(a, b))
            .sum::<f64>()
            / (n - 1) as f64;
    }
    (near / n as f64, all / n as f64)
}

/// Pre-trains on uniformly random transitions as the embedder does; returns the 5-NN and the
/// random-pair motion distances of the learned action embeddings.
fn pretrained_structure(config: &TrainConfig) -> (f64, f64) {
    let mut worker = ActorWorker::new(config, 0, DeviceKind::Flex).expect("environments");
    let (states, actions) = (worker.state_space().clone(), worker.action_space().clone());
    let mut trainer = EmbedderTrainer::new(
        config.embedding.clone(),
        config.algo.representation(),
        &states,
        &actions,
        1,
        DeviceKind::Flex,
    );
    let per_env = config.pretrain_budget() / config.envs_per_actor;
    let rollout = worker.collect(per_env);
    assert_eq!(rollout.transitions.len(), config.pretrain_budget());
    assert!(
        rollout.fragments.is_empty(),
        "no policy acts before the first embedding"
    );
    trainer
        .ingest(&rollout.transitions)
        .expect("valid transitions");
    let snapshot = trainer.poll().expect("serialises").expect("pre-trained");
    assert_eq!(snapshot.version, 1);
    let embedding = Embedding::from_snapshot(
        &config.embedding,
        config.algo.representation(),
        &states,
        &actions,
        &snapshot,
        &DeviceKind::Flex.device(),
    )
    .expect("snapshot loads");
    let table = embedding
        .action_table()
        .expect("discrete actions have a table");
    let motions = action_motions(config.environment.gridworld.actuators);
    neighbour_vs_random(&table, embedding.action_dim(), &motions, 5)
}

#[test]
fn pretrained_gridworld_action_embeddings_reflect_displacement() {
    let mut config = TrainConfig::defaults(EnvName::GridworldDiscrete, Algo::Jsae);
    config.envs_per_actor = 16;
    let (near, random) = pretrained_structure(&config);
    eprintln!("5-NN motion distance {near:.3} vs random {random:.3}");
    assert!(
        near < 0.6 * random,
        "no structure: {near:.3} vs {random:.3}"
    );
}

/// Measurement behind the default pre-training size (run with `--ignored --nocapture`):
/// 3,000 random transitions (the public reference code's number) give no structure,
/// 20,000 do.
#[test]
#[ignore = "a measurement (about a minute), not a check"]
fn structure_against_pretraining_size() {
    for (n, epochs) in [(3_000, 100), (20_000, 10), (20_000, 30)] {
        let mut config = TrainConfig::defaults(EnvName::GridworldDiscrete, Algo::Jsae);
        config.envs_per_actor = 20;
        config.embedding.pretrain_transitions = n;
        config.embedding.pretrain_per_action = 0;
        config.embedding.pretrain_epochs = epochs;
        let (near, random) = pretrained_structure(&config);
        eprintln!(
            "{n} transitions, {epochs} epochs: 5-NN motion distance {near:.3} vs random {random:.3}"
        );
    }
}
