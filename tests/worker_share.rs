//! An actor steps only its share of its environments when the learner shares one batch among
//! the actors present: a rollout then has one fragment per environment stepped, the others
//! wait mid-episode, and a larger share takes them up again where they were.

use jsae_actor::ActorWorker;
use jsae_learner::Learner;
use jsae_nn::DeviceKind;
use jsae_settings::{Algo, EnvName};
use jsae_tests::small_config;

#[test]
fn a_share_steps_the_first_environments_and_the_rest_wait() {
    let out = std::env::temp_dir().join("jsae-worker-share");
    let mut config = small_config(EnvName::GridworldDiscrete, Algo::Ppo, 5, out);
    config.envs_per_actor = 4;
    let mut worker = ActorWorker::new(&config, 0, DeviceKind::Flex).expect("environments");
    let policy = Learner::for_run(&config).snapshot().expect("serialises");
    worker.set_policy(&policy).expect("the run's policy");
    let envs = |w: &mut ActorWorker| -> Vec<u32> {
        w.collect(8).fragments.iter().map(|f| f.env_index).collect()
    };
    assert_eq!(envs(&mut worker), vec![0, 1, 2, 3]);
    assert_eq!(worker.env_steps(), 32);
    assert_eq!(worker.set_active_envs(2), 2);
    let rollout = worker.collect(8);
    assert_eq!(
        rollout
            .fragments
            .iter()
            .map(|f| f.env_index)
            .collect::<Vec<_>>(),
        vec![0, 1]
    );
    assert!(rollout.fragments.iter().all(|f| f.len() == 8));
    assert_eq!(worker.env_steps(), 48, "only the share was stepped");
    // 0 means all, more than it has is all it has
    assert_eq!(worker.set_active_envs(0), 4);
    assert_eq!(worker.set_active_envs(99), 4);
    worker.set_recording(true);
    let rollout = worker.collect(8);
    assert_eq!(worker.env_steps(), 80);
    // the first step of each environment in this rollout: the ones that waited go on from
    // step 8 of their episode, the others from 16 (no episode of 150 steps ended yet)
    let recorded = rollout.recorded.expect("recording");
    assert_eq!(&recorded.env_index[..4], &[0, 1, 2, 3]);
    assert_eq!(&recorded.step[..4], &[16, 16, 8, 8]);
    assert_eq!(&recorded.episode[..4], &[0; 4]);
}
