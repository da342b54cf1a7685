//! The end-of-run evaluation can go back to the embedding the final policy was trained on: a
//! hot swap takes only a newer embedding, `use_embedding` any (the actor's evaluation, when
//! the embedder published a version after the learner's last update).

use jsae_actor::ActorWorker;
use jsae_embedder::EmbedderTrainer;
use jsae_learner::Learner;
use jsae_nn::DeviceKind;
use jsae_settings::{Algo, EnvName};
use jsae_tests::small_config;
use jsae_wire::EmbeddingSnapshot;

#[test]
fn the_evaluation_goes_back_to_an_older_embedding() {
    let out = std::env::temp_dir().join("jsae-evaluation-embedding");
    let config = small_config(EnvName::GridworldDiscrete, Algo::Jsae, 5, out);
    let mut worker = ActorWorker::new(&config, 0, DeviceKind::Flex).expect("environments");
    let (states, actions) = (worker.state_space().clone(), worker.action_space().clone());
    let trainer = EmbedderTrainer::new(
        config.embedding.clone(),
        config.algo.representation(),
        &states,
        &actions,
        1,
        DeviceKind::Flex,
    );
    let first = EmbeddingSnapshot {
        version: 1,
        ..trainer.snapshot().expect("serialises")
    };
    let second = EmbeddingSnapshot {
        version: 2,
        ..first.clone()
    };
    let policy = Learner::for_run(&config).snapshot().expect("serialises");
    worker.set_policy(&policy).expect("the run's policy");
    worker.set_embedding(&second).expect("fits");
    worker.set_embedding(&first).expect("fits");
    assert_eq!(worker.embedding_version(), 2, "a hot swap never goes back");
    worker.use_embedding(&first).expect("fits");
    assert_eq!(worker.embedding_version(), 1);
    assert_eq!(worker.evaluate(1, 7).embedding_version, 1);
}
