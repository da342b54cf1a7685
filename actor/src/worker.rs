//! The actor's rollout worker: steps a vector of environments with one batched
//! `phi -> pi_i -> f` inference per step across them, and produces raw transitions for the
//! embedder and embedded rollout fragments for the learner. Weights are swapped in whole
//! between rollouts; before the first embedding exists (JSAE) it acts uniformly at random.

use jsae_agent::greedy::GreedyDecode;
use jsae_agent::{Embedding, Policy};
use jsae_agent::{SwapError, Weights};
use jsae_nn::{BurnDevice, DeviceKind};
use jsae_record::RecordedSteps;
use jsae_wire::{
    ActionBatch, ActionSpace, EmbeddingSnapshot, EpisodeStat, EvalReport, PolicySnapshot,
    RolloutFragment, StateBatch, StateSpace, TransitionBatch,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use jsae_envs::{ActionRef, EnvPool, LocalEnvs, make_env, step_threads};
use jsae_settings::TrainConfig;

mod rollout;

/// Why a snapshot could not be applied.
#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    /// The bytes do not fit the model.
    #[error(transparent)]
    Snapshot(#[from] SwapError),
    /// The environment could not be made (the recommender's data).
    #[error("environment: {0}")]
    Env(#[from] jsae_envs::MakeEnvError),
}

/// What one rollout produced.
#[derive(Debug, Clone)]
pub struct Rollout {
    /// Raw transitions (for the embedder; empty without embeddings).
    pub transitions: TransitionBatch,
    /// One fragment per environment (empty while acting at random).
    pub fragments: Vec<RolloutFragment>,
    /// Where each transition was stepped, when recording (`transitions` then holds every
    /// step, with or without an embedder).
    pub recorded: Option<RecordedSteps>,
}

/// Per-environment episode bookkeeping.
#[derive(Debug, Clone, Copy, Default)]
struct Running {
    ret: f64,
    len: u32,
}

/// One actor: its environments, its copies of the weights, its randomness.
pub struct ActorWorker {
    id: u64,
    config: TrainConfig,
    /// The rollouts' environments, and the evaluation's (number `envs.len()`).
    envs: Box<dyn EnvPool>,
    env_rngs: Vec<ChaCha8Rng>,
    rng: ChaCha8Rng,
    states: StateSpace,
    actions: ActionSpace,
    weights: Weights,
    running: Vec<Running>,
    current: StateBatch,
    env_steps: u64,
    /// This worker's random nonzero number ([`jsae_wire::random_id`]): its fragments' step
    /// claims count within it.
    incarnation: u64,
    greedy: GreedyDecode,
    /// Episodes each environment started before its current one.
    episodes: Vec<u64>,
    recording: bool,
    /// The environments stepped in a rollout, the first ones (the learner's share for this
    /// actor, all by default); the others wait mid-episode. `current` holds their states.
    active: usize,
}

impl std::fmt::Debug for ActorWorker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ActorWorker")
            .field("id", &self.id)
            .field("envs", &self.envs.len())
            .field("policy_version", &self.weights.policy_version())
            .field("embedding_version", &self.embedding_version())
            .field("env_steps", &self.env_steps)
            .finish()
    }
}

fn actor_seed(seed: u64, id: u64, stream: u64) -> u64 {
    seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ id.wrapping_mul(0xBF58_476D_1CE4_E5B9) ^ stream
}

impl ActorWorker {
    /// An actor with `config.envs_per_actor` built-in environments, all reset.
    pub fn new(config: &TrainConfig, id: u64, device: DeviceKind) -> Result<Self, WorkerError> {
        let envs = (0..=config.envs_per_actor)
            .map(|_| make_env(config.env, &config.environment))
            .collect::<Result<_, _>>()?;
        let threads = step_threads(config.step_threads, config.actors, !config.one_process);
        Ok(Self::with_pool(
            config,
            id,
            device,
            Box::new(LocalEnvs::new(envs, threads)),
        ))
    }

    /// An actor stepping `envs` (`config.envs_per_actor` of them, and the evaluation's),
    /// all reset.
    pub fn with_pool(
        config: &TrainConfig,
        id: u64,
        device: DeviceKind,
        mut envs: Box<dyn EnvPool>,
    ) -> Self {
        let mut env_rngs: Vec<ChaCha8Rng> = (0..envs.len())
            .map(|k| ChaCha8Rng::seed_from_u64(actor_seed(config.seed, id, 1000 + k as u64)))
            .collect();
        let states = envs.state_space().clone();
        let actions = envs.action_space().clone();
        let mut current = StateBatch::empty(&states);
        for (i, rng) in env_rngs.iter_mut().enumerate() {
            envs.reset(i, rng);
            envs.push_state(i, &mut current);
        }
        let device = device.device();
        let weights = Weights::new(config, &states, &actions, &device);
        Self {
            id,
            config: config.clone(),
            running: vec![Running::default(); envs.len()],
            envs,
            env_rngs,
            rng: ChaCha8Rng::seed_from_u64(actor_seed(config.seed, id, 1)),
            states,
            actions,
            weights,
            current,
            env_steps: 0,
            incarnation: jsae_wire::random_id(),
            greedy: GreedyDecode::default(),
            episodes: vec![0; config.envs_per_actor],
            recording: false,
            active: config.envs_per_actor,
        }
    }

    /// Steps the first `envs` environments from the next rollout on (at least one, at most
    /// all; 0: all), the others keeping their episodes where they are until a larger share.
    /// Returns the number now stepped.
    pub fn set_active_envs(&mut self, envs: usize) -> usize {
        let all = self.envs.len();
        let envs = if envs == 0 { all } else { envs.clamp(1, all) };
        if envs != self.active {
            self.active = envs;
            self.current = StateBatch::empty(&self.states);
            for i in 0..envs {
                self.envs.push_state(i, &mut self.current);
            }
        }
        envs
    }

    /// The environments a rollout steps ([`ActorWorker::set_active_envs`]).
    pub fn active_envs(&self) -> usize {
        self.active
    }

    /// The actor's id.
    pub fn id(&self) -> u64 {
        self.id
    }

    /// Env steps taken by this actor.
    pub fn env_steps(&self) -> u64 {
        self.env_steps
    }

    /// This worker's incarnation: drawn at random when it was made, carried by its fragments
    /// (the learner counts each incarnation's steps apart, so a restarted actor reusing an id
    /// is counted afresh).
    pub fn incarnation(&self) -> u64 {
        self.incarnation
    }

    /// Why this actor's environments can no longer step (remote workers that will not run
    /// again), if so.
    pub fn env_failure(&self) -> Option<String> {
        self.envs.failure()
    }

    /// The environments' state space.
    pub fn state_space(&self) -> &StateSpace {
        &self.states
    }

    /// The environments' action space.
    pub fn action_space(&self) -> &ActionSpace {
        &self.actions
    }

    /// Version of the embedding in use (0: none yet).
    pub fn embedding_version(&self) -> u64 {
        self.weights.embedding_version()
    }

    /// Version of the policy in use.
    pub fn policy_version(&self) -> Option<u64> {
        self.weights.policy_version()
    }

    /// The policy in use (None before the first policy snapshot).
    pub fn policy(&self) -> Option<&Policy> {
        self.weights.policy().map(|(_, p)| p)
    }

    /// The embedding in use.
    pub fn embedding(&self) -> Option<&Embedding> {
        self.weights.embedding()
    }

    /// Swaps in a new embedding (ignored if not newer).
    pub fn set_embedding(&mut self, snapshot: &EmbeddingSnapshot) -> Result<(), WorkerError> {
        self.weights.set_embedding(snapshot)?;
        Ok(())
    }

    /// Installs `snapshot` even if older than the one in use (the evaluation's embedding).
    pub fn use_embedding(&mut self, snapshot: &EmbeddingSnapshot) -> Result<(), WorkerError> {
        self.weights.load_embedding(snapshot)?;
        Ok(())
    }

    /// How the deterministic evaluation decodes a policy over action embeddings into a
    /// discrete action (default: f of the mean).
    pub fn set_greedy_decode(&mut self, decode: GreedyDecode) {
        self.greedy = decode;
    }

    /// Whether rollouts carry every step for a recording ([`Rollout::recorded`]).
    pub fn set_recording(&mut self, on: bool) {
        self.recording = on;
    }

    /// Swaps in another policy version (the current one is ignored).
    pub fn set_policy(&mut self, snapshot: &PolicySnapshot) -> Result<(), WorkerError> {
        self.weights.set_policy(snapshot)?;
        Ok(())
    }

    /// The visit key of row `i` of `states` for the exploration bonus, which the learner
    /// counts over all actors (`jsae_learner`'s `visits`); None when the bonus is off.
    fn visit_key(&self, states: &StateBatch, i: usize) -> Option<u64> {
        let e = &self.config.exploration;
        if e.bonus <= 0.0 {
            return None;
        }
        let mut key: u64 = 0xcbf2_9ce4_8422_2325;
        let mut mix = |v: u64| key = (key ^ v).wrapping_mul(0x0100_0000_01b3);
        match states {
            StateBatch::Categorical { factors, data } => data[i * factors..(i + 1) * factors]
                .iter()
                .for_each(|&v| mix(u64::from(v))),
            StateBatch::Real { dim, data } => data[i * dim..(i + 1) * dim]
                .iter()
                .for_each(|&v| mix((f64::from(v) * e.bins_per_unit).floor() as i64 as u64)),
        }
        Some(key)
    }

    /// Whether actions come from the policy (else uniformly at random).
    fn acting(&self) -> bool {
        self.weights.ready()
    }

    /// Policy inputs of `states`, `[len, x_dim]`.
    fn policy_inputs(&self, states: &StateBatch, out: &mut Vec<f32>) {
        match self.weights.embedding() {
            Some(e) if self.config.algo.representation().embeds_states() => {
                e.embed_states(states, out)
            }
            _ => states.write_features(&self.states, out),
        }
    }

    fn random_actions(&mut self, n: usize, out: &mut ActionBatch) {
        match (&self.actions, out) {
            (ActionSpace::Discrete { n: count }, ActionBatch::Discrete(v)) => {
                v.extend((0..n).map(|_| self.rng.random_range(0..*count as u32)))
            }
            (ActionSpace::Continuous { low, high, .. }, ActionBatch::Continuous { data, .. }) => {
                for _ in 0..n {
                    for (l, h) in low.iter().zip(high) {
                        data.push(self.rng.random_range(*l..=*h));
                    }
                }
            }
            _ => {}
        }
    }

    /// Maps sampled policy actions to environment actions: f for embeddings, then continuous
    /// actions clipped to the action box (the fragment keeps the unclipped sample, whose
    /// log-probability PPO scores; the embedder gets the action that was executed).
    fn env_actions(&mut self, policy_actions: &ActionBatch, out: &mut ActionBatch) {
        match (self.weights.embedding_mut(), policy_actions) {
            (Some(e), ActionBatch::Continuous { data, .. })
                if self.config.algo.representation().decodes_actions() =>
            {
                e.decode(data, out)
            }
            _ => out.extend_from(policy_actions),
        }
        if let (ActionSpace::Continuous { low, high, .. }, ActionBatch::Continuous { data, .. }) =
            (&self.actions, out)
        {
            let dim = low.len().max(1);
            for row in data.chunks_exact_mut(dim) {
                for ((a, l), h) in row.iter_mut().zip(low).zip(high) {
                    *a = a.clamp(*l, *h);
                }
            }
        }
    }

    /// Runs `episodes` evaluation episodes with the deterministic policy (mean action, then
    /// f) on fresh environments seeded with `seed`, and as many with sampled actions from the
    /// same start states (the policy's own randomness seeded from `seed` too).
    pub fn evaluate(&mut self, episodes: usize, seed: u64) -> EvalReport {
        EvalReport {
            policy_version: self.weights.policy_version().unwrap_or(0),
            embedding_version: self.embedding_version(),
            episodes: self.eval_episodes(episodes, seed, None),
            stochastic: self.eval_episodes(
                episodes,
                seed,
                Some(ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_5a3e)),
            ),
        }
    }

    /// The most likely discrete action ([`jsae_agent::greedy`]) of a policy acting in the
    /// action-embedding space, for the one mean embedding in `policy_action`, when the
    /// worker's greedy decode is the mode; None otherwise (not `greedy`, the mean decode,
    /// continuous actions, a categorical head): then f decodes the mean as in training.
    fn greedy_discrete(&mut self, greedy: bool, policy_action: &ActionBatch) -> Option<u32> {
        let ActionBatch::Continuous { data: mean, .. } = policy_action else {
            return None;
        };
        if !greedy
            || self.greedy == GreedyDecode::Mean
            || self.actions.num_discrete().is_none()
            || !self.config.algo.representation().decodes_actions()
        {
            return None;
        }
        let std: Vec<f32> = self
            .weights
            .acting_policy()
            .log_std_values()
            .iter()
            .map(|l| l.exp())
            .collect();
        jsae_agent::greedy::modal_action(self.weights.embedding_mut()?, mean, &std)
    }

    /// Evaluation episodes: deterministic without `sampling`, else actions drawn with it.
    fn eval_episodes(
        &mut self,
        episodes: usize,
        seed: u64,
        mut sampling: Option<ChaCha8Rng>,
    ) -> Vec<EpisodeStat> {
        let env = self.envs.len();
        let mut env_rng = ChaCha8Rng::seed_from_u64(seed);
        let head_space = self.weights.acting_policy().head().action_space();
        let mut stats = Vec::with_capacity(episodes);
        let (mut state, mut x, mut logp) =
            (StateBatch::empty(&self.states), Vec::new(), Vec::new());
        let mut policy_action = ActionBatch::empty(&head_space);
        let mut env_action = ActionBatch::empty(&self.actions);
        let mut lost = 0;
        while stats.len() < episodes && lost <= episodes {
            self.envs.reset(env, &mut env_rng);
            let mut run = Running::default();
            loop {
                state.clear();
                self.envs.push_state(env, &mut state);
                policy_action.clear();
                env_action.clear();
                self.policy_inputs(&state, &mut x);
                let (deterministic, rng) = match sampling.as_mut() {
                    Some(rng) => (false, rng),
                    None => (true, &mut self.rng),
                };
                self.weights.acting_policy().act(
                    &x,
                    self.weights.prior(),
                    deterministic,
                    rng,
                    &mut policy_action,
                    &mut logp,
                );
                match self.greedy_discrete(sampling.is_none(), &policy_action) {
                    Some(a) => env_action.extend_from(&ActionBatch::Discrete(vec![a])),
                    None => self.env_actions(&policy_action, &mut env_action),
                }
                let step = self.envs.step_one(env, ActionRef::row(&env_action, 0));
                run.ret += step.reward;
                run.len += 1;
                // `RUST_LOG=jsae_actor=trace jsae eval ...`: the episodes step by step (where a
                // greedy policy loops, and where the sampled one goes instead)
                tracing::trace!(
                    episode = stats.len(),
                    step = run.len,
                    state = ?state,
                    action = ?env_action,
                    reward = step.reward,
                    "{} evaluation step",
                    if sampling.is_none() { "deterministic" } else { "sampled" }
                );
                if step.lost {
                    // the environment went away mid-episode: this episode is not counted,
                    // and another starts wherever the pool can
                    tracing::warn!("an evaluation environment was lost; its episode is run again");
                    lost += 1;
                    break;
                }
                if step.terminated || step.truncated {
                    stats.push(EpisodeStat {
                        ret: run.ret,
                        length: run.len,
                        success: self.envs.has_success().then_some(step.success),
                    });
                    break;
                }
            }
        }
        stats
    }
}
