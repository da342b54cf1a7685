//! A learner resumed from its checkpoint is the learner that wrote it: Adam's moments and
//! step, the reward scaler, the observation normaliser, the counters, the step accounts and
//! the minibatch shuffler and the exploration bonus's visit counts come back equal, and the next update from either gives the same
//! weights, on both update paths. A learner given the weights alone does not.

use jsae_nn::DeviceKind;
use jsae_run_dir::LatestCheckpoint;
use jsae_wire::{PolicySnapshot, RolloutFragment};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::Learner;
use super::credits::StepCredits;
use crate::visits::VisitBonus;
use crate::{PpoConfig, UpdatePath};
use jsae_agent::PolicyHead;

const STEPS: usize = 64;
const X_DIM: usize = 5;
const HEAD: PolicyHead = PolicyHead::Gaussian { dim: 2 };
const ALLOWANCE: u64 = 1_000;

fn flat(learner: &Learner) -> Vec<f32> {
    learner.host_policy().params.slices().concat()
}

fn learner(update: UpdatePath, seed: u64) -> Learner {
    let config = PpoConfig {
        batch_steps: 4 * STEPS,
        epochs: 2,
        minibatch_size: 60,
        normalize_obs: true,
        reward_scaling: true,
        update,
        ..PpoConfig::default()
    };
    let mut l = Learner::new(config, X_DIM, HEAD, 100_000, seed, DeviceKind::Flex);
    l.credits = StepCredits::new(ALLOWANCE);
    l.visits = VisitBonus::new(0.1);
    l
}

/// One update's fragments: two actors with two environments each, their step claims growing
/// round by round (the first round after some random play).
fn round(number: u64, version: u64, rng: &mut ChaCha8Rng) -> Vec<RolloutFragment> {
    let mut fragments = Vec::new();
    for actor in 1..=2u64 {
        for env in 0..2u32 {
            let mut f = crate::synthetic::fragment(X_DIM, HEAD, version, STEPS, rng);
            f.actor_id = actor;
            f.actor_incarnation = 100 + actor;
            f.env_index = env;
            f.actor_env_steps = 300 + (number + 1) * 2 * STEPS as u64;
            for r in &mut f.rewards {
                *r *= 5.0 * actor as f32;
            }
            f.visit_keys = (0..STEPS as u64).map(|t| t % 7 + actor).collect();
            fragments.push(f);
        }
    }
    fragments
}

fn feed(l: &mut Learner, fragments: Vec<RolloutFragment>) {
    for f in fragments {
        l.ingest(f).expect("ingested");
    }
}

fn round_trip(update: UpdatePath) {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut first = learner(update, 7);
    for number in 0..3 {
        let fragments = round(number, first.version(), &mut rng);
        feed(&mut first, fragments);
    }
    assert_eq!(first.updates(), 3);
    let saved = first.checkpoint(41.5).expect("a checkpoint");
    // through the file's bytes, as a restarted process reads them
    let saved = LatestCheckpoint::decode(&saved.encode()).expect("reads back");

    // another seed: whatever matches must come from the checkpoint
    let mut resumed = learner(update, 99);
    assert_eq!(resumed.resume(&saved).expect("resumes"), Some(41.5));
    let adam = first.fused.adam_moments();
    assert_eq!(adam.time > 0, update == UpdatePath::Fused, "{}", adam.time);
    assert_eq!(resumed.fused.adam_moments(), adam);
    let scaler = |l: &Learner| l.reward_scaler.as_ref().map(|s| s.state());
    assert!(scaler(&first).is_some_and(|s| s.stats.count > 100.0));
    assert_eq!(scaler(&resumed), scaler(&first));
    assert!(first.policy().obs_stats().is_some());
    assert_eq!(resumed.policy().obs_stats(), first.policy().obs_stats());
    let counters = |l: &Learner| {
        (
            l.updates(),
            l.version(),
            l.env_steps(),
            l.dropped(),
            l.lag().clone(),
            l.embedding_version(),
            l.credits.clone(),
            l.visits.as_ref().map(VisitBonus::counts),
        )
    };
    assert!(first.visits.as_ref().is_some_and(|v| v.states() == 8));
    assert_eq!(counters(&resumed), counters(&first));
    assert_eq!(first.env_steps(), 2 * 300 + 3 * 4 * STEPS as u64);
    let shuffler = |l: &Learner| (l.rng.get_seed(), l.rng.get_word_pos());
    assert_eq!(shuffler(&resumed), shuffler(&first));
    assert_eq!(flat(&resumed), flat(&first));

    // the weights alone (the old restart) lose the optimiser and the scaler
    let mut weights_only = learner(update, 7);
    weights_only
        .restore(&PolicySnapshot {
            version: saved.version,
            bytes: saved.weights.clone(),
        })
        .expect("loads");

    let next = round(3, first.version(), &mut rng);
    feed(&mut first, next.clone());
    feed(&mut resumed, next.clone());
    feed(&mut weights_only, next);
    assert_eq!(resumed.updates(), 4);
    assert_eq!(flat(&resumed), flat(&first), "the same next update");
    assert_ne!(
        flat(&weights_only),
        flat(&first),
        "the test tells them apart"
    );
}

#[test]
fn a_resumed_fused_learner_updates_as_the_one_that_stopped() {
    round_trip(UpdatePath::Fused);
}

#[test]
fn a_resumed_burn_learner_updates_as_the_one_that_stopped() {
    round_trip(UpdatePath::Burn);
}

#[test]
fn a_damaged_training_state_is_refused_before_anything_changes() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let mut first = learner(UpdatePath::Fused, 7);
    let fragments = round(0, 0, &mut rng);
    feed(&mut first, fragments);
    let mut saved = first.checkpoint(1.0).expect("a checkpoint");
    saved.state.truncate(saved.state.len() - 9);
    let mut other = learner(UpdatePath::Fused, 8);
    let before = flat(&other);
    assert!(other.resume(&saved).is_err());
    assert_eq!((flat(&other), other.version()), (before, 0));
}
