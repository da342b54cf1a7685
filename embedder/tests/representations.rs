//! The AE and RA baselines learn what they are meant to: the auto-encoders reconstruct states
//! and actions, and RA's inverse model recovers the action that led from s to s' (decoded the
//! way actors decode) far above chance, for discrete and continuous actions. A warm start
//! carries over exactly the parts whose shapes match.

use jsae_action_index::NearestAction;
use jsae_embedder::{EmbedderTrainer, EmbeddingConfig, EmbeddingTraining, replay::Minibatch};
use jsae_nn::{self as nn, DeviceKind};
use jsae_run_dir::InitSource;
use jsae_settings::{Algo, EnvName, Representation, TrainConfig};
use jsae_wire::{ActionBatch, ActionSpace, StateBatch, StateSpace, TransitionBatch};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const SIDE: u32 = 10;
/// 16 moves on a 10x10 grid, each a distinct displacement in {-2, -1, 1, 2}^2; only moves
/// that stay on the grid are drawn, so (s, s') names the action.
const STEPS: [i32; 4] = [-2, -1, 1, 2];

fn grid(n: usize, seed: u64) -> TransitionBatch {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut s, mut a, mut next) = (Vec::new(), Vec::new(), Vec::new());
    while a.len() < n {
        let (x, y) = (rng.random_range(0..SIDE), rng.random_range(0..SIDE));
        let action = rng.random_range(0..16u32);
        let (dx, dy) = (STEPS[action as usize % 4], STEPS[action as usize / 4]);
        let (nx, ny) = (x as i32 + dx, y as i32 + dy);
        if !(0..SIDE as i32).contains(&nx) || !(0..SIDE as i32).contains(&ny) {
            continue;
        }
        s.extend([x, y]);
        a.push(action);
        next.extend([nx as u32, ny as u32]);
    }
    TransitionBatch {
        actor_id: 0,
        states: StateBatch::Categorical {
            factors: 2,
            data: s,
        },
        actions: ActionBatch::Discrete(a),
        rewards: vec![0.0; n],
        next_states: StateBatch::Categorical {
            factors: 2,
            data: next,
        },
        terminated: vec![false; n],
    }
}

/// Real 2-d states, actions in [-1, 1]^2, `s' = s + 0.1 a`.
fn drift(n: usize, seed: u64) -> TransitionBatch {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut s, mut a, mut next) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..n {
        let state = [
            rng.random_range(-1.0f32..1.0),
            rng.random_range(-1.0f32..1.0),
        ];
        let action = [
            rng.random_range(-1.0f32..1.0),
            rng.random_range(-1.0f32..1.0),
        ];
        s.extend(state);
        a.extend(action);
        next.extend([state[0] + 0.1 * action[0], state[1] + 0.1 * action[1]]);
    }
    TransitionBatch {
        actor_id: 0,
        states: StateBatch::Real { dim: 2, data: s },
        actions: ActionBatch::Continuous { dim: 2, data: a },
        rewards: vec![0.0; n],
        next_states: StateBatch::Real { dim: 2, data: next },
        terminated: vec![false; n],
    }
}

fn minibatch(b: &TransitionBatch) -> Minibatch {
    Minibatch {
        states: b.states.clone(),
        actions: b.actions.clone(),
        next_states: b.next_states.clone(),
    }
}

fn continuous() -> ActionSpace {
    ActionSpace::Continuous {
        dim: 2,
        low: vec![-1.0; 2],
        high: vec![1.0; 2],
    }
}

/// A trainer of `representation` pre-trained on `data`; returns it and the (model, decoder)
/// losses on `data` before and after.
fn pretrained(
    representation: Representation,
    states: StateSpace,
    actions: ActionSpace,
    data: &TransitionBatch,
    epochs: usize,
) -> (EmbedderTrainer, (f32, f32), (f32, f32)) {
    let config = EmbeddingConfig {
        pretrain_transitions: data.len(),
        pretrain_per_action: 0,
        pretrain_epochs: epochs,
        batch_size: 128,
        state_dim: 8,
        action_dim: 4,
        ..EmbeddingConfig::default()
    };
    let mut t = EmbedderTrainer::new(
        config,
        representation,
        &states,
        &actions,
        3,
        DeviceKind::Flex,
    );
    let before = t.evaluate(&minibatch(data));
    t.ingest(data).expect("valid transitions");
    let snapshot = t.poll().expect("serialises").expect("pre-trained");
    assert_eq!(snapshot.version, 1);
    let after = t.evaluate(&minibatch(data));
    (t, before, after)
}

#[test]
fn the_auto_encoders_reconstruct_states_and_actions() {
    let data = grid(2048, 1);
    let (t, before, after) = pretrained(
        Representation::AutoEncoder,
        StateSpace::Categorical {
            sizes: vec![SIDE as usize; 2],
        },
        ActionSpace::Discrete { n: 16 },
        &data,
        40,
    );
    // chance: ln 10 per factor, ln 16 per action
    assert!(
        before.0 > 4.0 && after.0 < 0.5 * before.0,
        "{before:?} -> {after:?}"
    );
    assert!(
        before.1 > 2.5 && after.1 < 0.5 * before.1,
        "{before:?} -> {after:?}"
    );
    assert!(t.model().action_table().is_some());

    let data = drift(2048, 2);
    let (_, before, after) = pretrained(
        Representation::AutoEncoder,
        StateSpace::Real { dim: 2 },
        continuous(),
        &data,
        40,
    );
    assert!(after.0 < 0.5 * before.0, "{before:?} -> {after:?}");
    assert!(after.1 < 0.5 * before.1, "{before:?} -> {after:?}");
}

#[test]
fn the_inverse_model_recovers_the_action_far_above_chance() {
    let data = grid(4096, 3);
    let states = StateSpace::Categorical {
        sizes: vec![SIDE as usize; 2],
    };
    let (t, before, after) = pretrained(
        Representation::ActionRepresentation,
        states,
        ActionSpace::Discrete { n: 16 },
        &data,
        60,
    );
    // chance: ln 16 = 2.77 nats
    assert!(after.0 < 0.3 * before.0, "{before:?} -> {after:?}");
    assert_eq!(after.1, 0.0, "RA reports one loss");
    // The action an actor would decode from the inferred embedding: the nearest z_a.
    let held_out = grid(1000, 4);
    let model = t.model();
    let e = nn::to_vec(model.infer_action_embeddings(&held_out.states, &held_out.next_states));
    let table = nn::to_vec(model.action_table().expect("discrete actions"));
    let mut nearest = NearestAction::new(&table, 4);
    let mut decoded = Vec::new();
    nearest.nearest_batch(&e, &mut decoded);
    let ActionBatch::Discrete(truth) = &held_out.actions else {
        unreachable!()
    };
    let hits = decoded.iter().zip(truth).filter(|(a, b)| a == b).count();
    eprintln!("RA: {hits} of 1000 held-out actions decoded right; loss {before:?} -> {after:?}");
    assert!(hits > 700, "{hits} of 1000 decoded right (chance: 62)");

    let data = drift(4096, 5);
    let (t, before, after) = pretrained(
        Representation::ActionRepresentation,
        StateSpace::Real { dim: 2 },
        continuous(),
        &data,
        60,
    );
    // The actions' variance is 1/3: f(e(s, s')) recovers them far better than their mean does.
    eprintln!("RA, continuous: MSE {before:?} -> {after:?}");
    assert!(after.0 < 0.1, "{before:?} -> {after:?}");
    assert!(t.model().action_table().is_none());
}

/// The grid transitions as a gridworld-discrete run with `bins = 10` sees them: one factor
/// of 100 cells.
fn flattened(b: &TransitionBatch) -> TransitionBatch {
    let flat = |s: &StateBatch| match s {
        StateBatch::Categorical { data, .. } => StateBatch::Categorical {
            factors: 1,
            data: data.chunks(2).map(|c| c[0] * SIDE + c[1]).collect(),
        },
        other => other.clone(),
    };
    TransitionBatch {
        states: flat(&b.states),
        next_states: flat(&b.next_states),
        ..b.clone()
    }
}

#[test]
fn a_warm_start_copies_phi_and_t_but_not_g_across_action_counts() {
    // The source run: gridworld-discrete on 10x10 cells with 4 actuators (16 actions).
    let mut config = TrainConfig::defaults(EnvName::GridworldDiscrete, Algo::Jsae);
    config.environment.gridworld.bins = SIDE;
    config.environment.gridworld.actuators = 4;
    let (states, actions) = config.spaces();
    let data = flattened(&grid(1024, 6));
    let (source, _, _) = pretrained(Representation::Jsae, states.clone(), actions, &data, 5);
    config.embedding = source.model().config().clone();
    let init = InitSource {
        dir: "source-run".into(),
        config: config.clone(),
        policy: Vec::new(),
        embedding: Some(source.snapshot().expect("serialises").bytes),
    };
    // The target: 5 actuators (32 actions), the same states and widths.
    let mut target = EmbedderTrainer::new(
        config.embedding.clone(),
        Representation::Jsae,
        &states,
        &ActionSpace::Discrete { n: 32 },
        9,
        DeviceKind::Flex,
    );
    let parts = target.warm_start(&init).expect("warm start");
    assert!(
        parts.contains(&"phi_table") && parts.contains(&"transition"),
        "{parts:?}"
    );
    assert!(!parts.contains(&"g_table"), "{parts:?}");
    let phi = |t: &EmbedderTrainer| nn::to_vec(t.model().embed_states(&data.states));
    assert_eq!(phi(&target), phi(&source));
    // Bytes of another structure are refused with the run's name.
    let broken = InitSource {
        embedding: Some(vec![1, 2, 3]),
        ..init
    };
    let err = target.warm_start(&broken).expect_err("not a snapshot");
    assert!(err.contains("source-run"), "{err}");
}
