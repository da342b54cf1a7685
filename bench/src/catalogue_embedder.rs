//! The embedder at catalogue scale, for `jsae bench --catalogue`: minibatch steps of the
//! recommender JSAE's model (its defaults: 64-wide phi and g, minibatches of 4,096, the
//! next-item head, pair rows) on transitions from the generated catalogue's sessions, timed
//! after a warm-up, and the memory the trainer holds. From `embedding.sampled_softmax_from`
//! items the step is the sampled softmax over the tables on the host
//! (`jsae_embedder::TrainingModel`); below it the dense one.

use std::time::Instant;

use jsae_embedder::{EmbedderTrainer, replay::Minibatch};
use jsae_envs::recsys::large_catalogue::LargeCatalogue;
use jsae_settings::{Algo, EnvName, TrainConfig};
use jsae_wire::{ActionBatch, ActionSpace, StateBatch, StateSpace};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Steps timed (after one untimed).
const STEPS: usize = 5;

/// What the embedder's steps measured.
#[derive(Debug, Clone, Copy)]
pub struct EmbedderSteps {
    /// Milliseconds per minibatch step.
    pub step_ms: f64,
    /// Resident memory the trainer added (model, host tables, optimiser), MiB.
    pub mib: f64,
    /// Whether the step was the catalogue-scale (sampled) one.
    pub sampled: bool,
    /// The model loss of the first and the last step (nats).
    pub loss: (f32, f32),
}

/// A minibatch of `rows` transitions from the catalogue's sessions under random play: the
/// state is the last two purchases (or "none"), the action a uniformly random item, the
/// next state the purchase that followed in the session.
fn minibatch(catalogue: &LargeCatalogue, rows: usize, rng: &mut ChaCha8Rng) -> Minibatch {
    let n = catalogue.items() as u32;
    let (mut states, mut actions, mut next) = (Vec::new(), Vec::new(), Vec::new());
    while actions.len() < rows {
        let session = catalogue.session(rng.random_range(0..catalogue.sessions()));
        if session.len() < 2 {
            continue;
        }
        let at = rng.random_range(1..session.len());
        let before = if at >= 2 { session[at - 2] } else { n };
        states.extend([before, session[at - 1]]);
        actions.push(rng.random_range(0..n));
        next.extend([session[at - 1], session[at]]);
    }
    let cat = |data| StateBatch::Categorical { factors: 2, data };
    Minibatch {
        states: cat(states),
        actions: ActionBatch::Discrete(actions),
        next_states: cat(next),
    }
}

/// Times the recommender JSAE embedder's minibatch step on `catalogue`.
pub fn embedder_steps(catalogue: &LargeCatalogue) -> EmbedderSteps {
    let n = catalogue.items();
    let config = TrainConfig::defaults(EnvName::Recommender, Algo::Jsae);
    let states = StateSpace::Categorical {
        sizes: vec![n + 1; 2],
    };
    let actions = ActionSpace::Discrete { n };
    let before = crate::recommender::rss_mib();
    let mut trainer = EmbedderTrainer::new(
        config.embedding.clone(),
        config.algo.representation(),
        &states,
        &actions,
        1,
        config.device,
    );
    let sampled = trainer.model().at_catalogue_scale();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let batch = config.embedding.batch_size;
    let lr = config.embedding.lr;
    let first = trainer.step(&minibatch(catalogue, batch, &mut rng), lr).0;
    let mut last = first;
    let mut seconds = 0.0;
    for _ in 0..STEPS {
        let mb = minibatch(catalogue, batch, &mut rng);
        let t = Instant::now();
        last = trainer.step(&mb, lr).0;
        seconds += t.elapsed().as_secs_f64();
    }
    EmbedderSteps {
        step_ms: seconds * 1e3 / STEPS as f64,
        mib: crate::recommender::rss_mib() - before,
        sampled,
        loss: (first, last),
    }
}
