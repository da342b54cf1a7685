//! The run configuration: every setting of a training run, layered defaults -> file (TOML)
//! -> environment variables and flags (clap), validated whole before anything starts, and
//! saved as `config.toml` next to the results.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{
    Algo, ConfigFile, DeviceKind, EmbeddingConfig, EnvConfig, EnvName, PpoConfig,
    validate_env_config,
};
use jsae_spaces::{ActionSpace, StateSpace};

/// Every setting of a training run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    /// Environment.
    pub env: EnvName,
    /// Algorithm.
    pub algo: Algo,
    /// Seed of everything (environments, initial weights, sampling, minibatch order).
    pub seed: u64,
    /// Env steps of the whole run (all actors, random pre-training steps included).
    pub env_steps: u64,
    /// Actor workers.
    pub actors: usize,
    /// Environments per actor, stepped together with batched inference.
    pub envs_per_actor: usize,
    /// Environments one batch is gathered from, shared among the actors present: each
    /// steps its share of its own (the learner tells it), so the batch stays the same as
    /// actors join and leave. 0: every actor steps all of its environments and the batch is
    /// one rollout of every actor present, growing with them. Unset in a file: the env and
    /// algo's default (64 for an embedded-action gridworld-discrete, else 0). See
    /// [`TrainConfig::shared_batch_envs`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub batch_envs: Option<usize>,
    /// Threads an actor steps its environments on (0: the machine's cores over `actors`, less
    /// one for the learner's update as separate processes, at least one; at most one per
    /// environment). Worth it where a step costs far more than a thread hand-off (MuJoCo).
    pub step_threads: usize,
    /// Steps per environment per rollout fragment.
    pub rollout_len: usize,
    /// Separate processes: rollouts an actor may have out that no newer policy version has
    /// answered yet (1: on-policy like the one-process mode, policy lag 0 with one actor; 2:
    /// the next rollout is collected while the learner updates, lag up to 1, its fragments
    /// kept under PPO's clip). 2 on MuJoCo, where stepping is most of the work: HalfCheetah
    /// PPO 1M as separate processes took 31 s instead of 43 s on 2 cores, and 5 seeds
    /// learned as well (docs/src/performance/scaling.md); 1 elsewhere.
    pub rollouts_per_policy: usize,
    /// Separate processes: the least time an actor waits for a newer policy before it
    /// collects anyway (so a run goes on when another actor that the learner's batch counted
    /// on died); the wait grows to 3 times the slowest recent arrival of a new version.
    pub policy_wait_ms: u64,
    /// burn device.
    pub device: DeviceKind,
    /// Deterministic evaluation episodes at the end.
    pub eval_episodes: usize,
    /// Run directory: `--out` or the default `runs/ENV-ALGO-seedN`, never a setting (not
    /// written to config.toml, so a run's config passed back with another seed does not
    /// write into the old run's directory).
    #[serde(skip)]
    pub out: PathBuf,
    /// Run actor, embedder and learner in this process, in lockstep (deterministic for a
    /// seed), instead of as separate service processes talking gRPC over loopback.
    pub one_process: bool,
    /// A finished run of the same environment and algorithm to warm-start from: the
    /// embedding parts whose shapes match (phi, T, ...; g only with the same action count)
    /// and the policy, where its shape matches (`jsae_run_dir::InitSource`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init_from: Option<PathBuf>,
    /// Environment settings.
    #[serde(default)]
    pub environment: EnvConfig,
    /// Embedding model and trainer settings (JSAE).
    #[serde(default)]
    pub embedding: EmbeddingConfig,
    /// PPO settings.
    #[serde(default)]
    pub ppo: PpoConfig,
    /// Count-based exploration bonus (on for both gridworlds, `bonus = 0.1`; off elsewhere).
    #[serde(default)]
    pub exploration: ExplorationConfig,
}

/// A count-based exploration bonus: the learner sees `r + bonus / sqrt(N(s'))`, where `N`
/// counts all actors' visits to the next state (categorical states by index, real states
/// binned; the actors send the keys, the learner counts). Environment returns, evaluation and
/// the embedder's transitions are unchanged.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ExplorationConfig {
    /// Bonus for a first visit (0 turns it off).
    pub bonus: f64,
    /// Bins per unit length for real-valued states.
    pub bins_per_unit: f64,
}

impl Default for ExplorationConfig {
    fn default() -> Self {
        Self {
            bonus: 0.0,
            bins_per_unit: 40.0,
        }
    }
}

/// Why a configuration was refused.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read config file {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is not valid TOML for this schema.
    #[error("config file {path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A value is out of range.
    #[error("invalid setting: {0}")]
    Invalid(String),
}

/// Merges `overlay` into `base`, table by table.
fn merge(base: &mut toml::Value, overlay: toml::Value) {
    match (base, overlay) {
        (toml::Value::Table(b), toml::Value::Table(o)) => {
            for (k, v) in o {
                match b.get_mut(&k) {
                    Some(existing) => merge(existing, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (b, o) => *b = o,
    }
}

/// `base` with the file's `[section]` laid over it; an error names the dotted key and its
/// line in `text` (the file).
fn overlay<T: Serialize + serde::de::DeserializeOwned>(
    base: &T,
    part: Option<toml::Value>,
    (path, text, section): (&Path, Option<&str>, &str),
) -> Result<T, ConfigError> {
    let Some(part) = part else {
        return Ok(toml::Value::try_from(base)
            .ok()
            .and_then(|v| v.try_into().ok())
            .unwrap_or_else(|| unreachable_roundtrip()));
    };
    let mut value = toml::Value::try_from(base).map_err(|e| ConfigError::Parse {
        path: path.into(),
        message: e.to_string(),
    })?;
    merge(&mut value, part);
    value
        .try_into()
        .map_err(|e: toml::de::Error| ConfigError::Parse {
            path: path.into(),
            message: super::file_errors::section_error(text, section, &e),
        })
}

fn unreachable_roundtrip() -> ! {
    panic!("a default configuration always round-trips through TOML")
}

impl TrainConfig {
    /// The defaults for an environment and algorithm: the common ones, then those of the
    /// action-embedding algorithms, then the environment's own (each with the measurement
    /// that set it).
    pub fn defaults(env: EnvName, algo: Algo) -> Self {
        Self::defaults_for(env, algo, &EnvConfig::default())
    }

    /// As [`TrainConfig::defaults`], for the environment settings `environment` (a gym
    /// environment's defaults follow its spaces).
    pub fn defaults_for(env: EnvName, algo: Algo, environment: &EnvConfig) -> Self {
        let mut c = Self::common_defaults(env, algo);
        // The baselines act in an action-embedding space too, with JSAE's PPO settings.
        if algo.representation().decodes_actions() {
            c.ppo.gae_lambda = 0.97;
            c.ppo.tanh_mean = true;
            c.ppo.ent_coef = 0.05;
        }
        match env {
            EnvName::Gridworld | EnvName::GridworldDiscrete => c.gridworld_defaults(),
            EnvName::Slotmachine => c.slotmachine_defaults(),
            EnvName::Recommender => c.recommender_defaults(),
            EnvName::Gym => c.gym_defaults(&environment.gym),
            _ if env.is_mujoco() => c.mujoco_defaults(),
            _ => {}
        }
        c.environment = environment.clone();
        c
    }

    /// What every environment starts from: one rollout of every actor's 16 environments is a
    /// batch (it grows with the actors), 500k env steps.
    fn common_defaults(env: EnvName, algo: Algo) -> Self {
        Self {
            env,
            algo,
            seed: 1,
            env_steps: 500_000,
            actors: 1,
            envs_per_actor: 16,
            batch_envs: None,
            step_threads: if env.is_mujoco() { 0 } else { 1 },
            rollout_len: 128,
            rollouts_per_policy: if env.is_mujoco() { 2 } else { 1 },
            policy_wait_ms: 3000,
            device: DeviceKind::Flex,
            // recommender returns are sums of a few Bernoulli draws: 20 episodes are too noisy
            eval_episodes: if env == EnvName::Recommender { 200 } else { 20 },
            out: PathBuf::new(),
            one_process: false,
            init_from: None,
            environment: EnvConfig::default(),
            embedding: EmbeddingConfig::default(),
            ppo: PpoConfig::default(),
            exploration: ExplorationConfig::default(),
        }
    }

    /// Defaults, then the file (if any). `env`/`algo` given on the command line pick the
    /// defaults the file is laid over.
    pub fn from_layers(
        env: Option<EnvName>,
        algo: Option<Algo>,
        file: Option<&Path>,
    ) -> Result<Self, ConfigError> {
        Self::from_layers_with(env, algo, file, &[])
    }

    /// As [`TrainConfig::from_layers`], with `sets` (`KEY=VALUE`, `--set`) laid over the
    /// file's settings as if the file held them (so they are read and refused alike).
    pub fn from_layers_with(
        env: Option<EnvName>,
        algo: Option<Algo>,
        file: Option<&Path>,
        sets: &[String],
    ) -> Result<Self, ConfigError> {
        let text = match file {
            None => None,
            Some(path) => {
                Some(
                    std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
                        path: path.into(),
                        source,
                    })?,
                )
            }
        };
        let (file, text) = match sets {
            [] => (file, text),
            _ => (
                Some(Path::new(match file {
                    Some(_) => "the settings file with --set",
                    None => "--set",
                })),
                Some(super::sets::laid_over(
                    text.as_deref().unwrap_or(""),
                    file,
                    sets,
                )?),
            ),
        };
        let parsed: ConfigFile = match (file, &text) {
            (Some(path), Some(text)) => toml::from_str(text).map_err(|e| ConfigError::Parse {
                path: path.into(),
                message: super::file_errors::top_level_error(text, &e),
            })?,
            _ => ConfigFile::default(),
        };
        let env = env.or(parsed.env).unwrap_or(EnvName::GridworldDiscrete);
        let algo = algo.or(parsed.algo).unwrap_or(Algo::Jsae);
        let path = file.unwrap_or(Path::new("<defaults>"));
        let environment = overlay(
            &EnvConfig::default(),
            parsed.environment,
            (path, text.as_deref(), "environment"),
        )?;
        let mut c = Self::defaults_for(env, algo, &environment);
        c.seed = parsed.seed.unwrap_or(c.seed);
        c.env_steps = parsed.env_steps.unwrap_or(c.env_steps);
        c.actors = parsed.actors.unwrap_or(c.actors);
        c.envs_per_actor = parsed.envs_per_actor.unwrap_or(c.envs_per_actor);
        c.batch_envs = parsed.batch_envs.or(c.batch_envs);
        c.step_threads = parsed.step_threads.unwrap_or(c.step_threads);
        c.rollout_len = parsed.rollout_len.unwrap_or(c.rollout_len);
        c.rollouts_per_policy = parsed.rollouts_per_policy.unwrap_or(c.rollouts_per_policy);
        c.policy_wait_ms = parsed.policy_wait_ms.unwrap_or(c.policy_wait_ms);
        c.device = parsed.device.unwrap_or(c.device);
        c.eval_episodes = parsed.eval_episodes.unwrap_or(c.eval_episodes);
        c.one_process = parsed.one_process.unwrap_or(c.one_process);
        c.init_from = parsed.init_from.or(c.init_from);
        let text = text.as_deref();
        let mut ppo = parsed.ppo.map(crate::ppo_recommender::nest_legacy_keys);
        let mut embedding = parsed.embedding;
        crate::embedding_recommender::items_off_in_older_dumps(&mut embedding, &mut ppo);
        c.embedding = overlay(&c.embedding, embedding, (path, text, "embedding"))?;
        c.ppo = overlay(&c.ppo, ppo, (path, text, "ppo"))?;
        c.exploration = overlay(
            &c.exploration,
            parsed.exploration,
            (path, text, "exploration"),
        )?;
        Ok(c)
    }

    /// Seed of the deterministic evaluation episodes at the end of a run.
    pub fn eval_seed(&self) -> u64 {
        self.seed ^ 0xE7A1
    }

    /// The environment's state and action spaces under these settings.
    pub fn spaces(&self) -> (StateSpace, ActionSpace) {
        self.env.spaces(&self.environment)
    }

    /// Whether the run's embedding no longer changes once `env_steps` are done
    /// (`embedding.hold_from`; never without an embedder, without a step budget or unset).
    pub fn embedding_held_at(&self, env_steps: u64) -> bool {
        let Some(share) = self.embedding.hold_from else {
            return false;
        };
        self.algo.representation().needs_embedder()
            && self.env_steps > 0
            && env_steps as f64 >= share * self.env_steps as f64
    }

    /// Checks everything; the reason names the bad setting.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let bad = |m: String| Err(ConfigError::Invalid(m));
        if self.actors == 0
            || self.envs_per_actor == 0
            || self.rollout_len == 0
            || self.rollouts_per_policy == 0
        {
            return bad(
                "actors, envs_per_actor, rollout_len and rollouts_per_policy must be positive"
                    .into(),
            );
        }
        if self.env_steps == 0 {
            return bad("env_steps must be positive".into());
        }
        if self.eval_episodes == 0 {
            return bad("eval_episodes must be positive".into());
        }
        validate_env_config(&self.environment).map_err(ConfigError::Invalid)?;
        if self.env == EnvName::Gym {
            self.environment.gym.check().map_err(ConfigError::Invalid)?;
        }
        let e = &self.exploration;
        if !(e.bonus >= 0.0 && e.bonus.is_finite() && e.bins_per_unit > 0.0) {
            return bad("exploration.bonus must be >= 0 and exploration.bins_per_unit > 0".into());
        }
        self.ppo.validate().map_err(ConfigError::Invalid)?;
        // settings that only the recommender's categorical PPO policy has a use for
        let recommender_ppo = self.env == EnvName::Recommender && self.algo == Algo::Ppo;
        let items = "purchase logs and a categorical policy over their items";
        for (set, key, why) in [
            (
                self.ppo.recommender.next_purchase_coef > 0.0,
                "next_purchase_coef",
                "a categorical policy over the items of the state",
            ),
            (
                self.ppo.recommender.logged_pretrain_epochs > 0,
                "logged_pretrain_epochs",
                items,
            ),
            (self.ppo.recommender.logged_prior, "logged_prior", items),
            (
                self.ppo.recommender.pair_buckets > 0,
                "pair_buckets",
                "a pair of one-hot items in the policy's input",
            ),
        ] {
            if set && !recommender_ppo {
                return bad(format!(
                    "ppo.recommender.{key} is for --env recommender --algo ppo ({why})"
                ));
            }
        }
        crate::embedding_recommender::validate_for_run(self).map_err(ConfigError::Invalid)?;
        if self.algo.representation().needs_embedder() {
            self.embedding.validate().map_err(ConfigError::Invalid)?;
            let budget = self.pretrain_budget();
            if budget as u64 >= self.env_steps {
                return bad(format!(
                    "env_steps ({}) must exceed the pre-training transitions ({budget}: \
                     embedding.pretrain_transitions, or pretrain_per_action x actions)",
                    self.env_steps
                ));
            }
            if self.embedding.replay_capacity < budget {
                return bad(format!(
                    "embedding.replay_capacity ({}) must hold the pre-training transitions \
                     ({budget})",
                    self.embedding.replay_capacity
                ));
            }
        }
        // one round of the run's actors is the learner's batch: past the budget, the run would
        // silently take more steps than asked for in one update
        if self.round_steps() as u64 > self.env_steps {
            return bad(format!(
                "env_steps ({}) is less than one batch: {} environments x rollout_len {} = {} \
                 steps; lower --envs, batch_envs or rollout_len, or raise --env-steps",
                self.env_steps,
                self.actor_envs().iter().sum::<usize>(),
                self.rollout_len,
                self.round_steps()
            ));
        }
        Ok(())
    }

    /// Random transitions the embedder pre-trains on in this run (the embedding settings'
    /// budget for this environment's action space).
    pub fn pretrain_budget(&self) -> usize {
        let (states, actions) = self.spaces();
        self.embedding.pretrain_budget(&states, &actions)
    }

    /// The configuration as TOML (what `config.toml` holds).
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_else(|e| format!("# not serialisable: {e}\n"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_overrides_defaults_and_unknown_keys_are_refused() {
        let dir = std::env::temp_dir().join(format!("jsae-config-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let file = dir.join("run.toml");
        std::fs::write(
            &file,
            "seed = 7\n[ppo]\nepochs = 3\n[environment.gridworld]\nactuators = 4\n",
        )
        .expect("write");
        let c = TrainConfig::from_layers(None, None, Some(&file)).expect("parses");
        assert_eq!(
            (c.seed, c.ppo.epochs, c.environment.gridworld.actuators),
            (7, 3, 4)
        );
        assert_eq!(c.ppo.lr, PpoConfig::default().lr);
        // the saved config reads back as the same configuration
        let saved = dir.join("saved.toml");
        std::fs::write(&saved, c.to_toml()).expect("write");
        let back = TrainConfig::from_layers(None, None, Some(&saved)).expect("round trip");
        assert_eq!(back, c);
        std::fs::write(&file, "[ppo]\nepochz = 3\n").expect("write");
        let err = TrainConfig::from_layers(None, None, Some(&file)).expect_err("typo refused");
        assert!(err.to_string().contains("epochz"), "{err}");
    }

    #[test]
    fn bad_values_are_refused_with_a_reason() {
        let mut c = TrainConfig::defaults(EnvName::Gridworld, Algo::Jsae);
        c.env_steps = 1000;
        assert!(
            c.validate()
                .expect_err("too short")
                .to_string()
                .contains("pretrain")
        );
        for algo in [Algo::Ae, Algo::Ra] {
            TrainConfig::defaults(EnvName::Gridworld, algo)
                .validate()
                .expect("the baselines run");
        }
        // 2^13 actions x 25 transitions each do not fit the default replay buffer.
        let mut c = TrainConfig::defaults(EnvName::GridworldDiscrete, Algo::Jsae);
        c.environment.gridworld.actuators = 13;
        c.env_steps = 1_000_000;
        let reason = c.validate().expect_err("too small a buffer").to_string();
        assert!(
            reason.contains("replay_capacity") && reason.contains("204800"),
            "{reason}"
        );
        c.environment.gridworld.actuators = 12;
        assert_eq!(c.pretrain_budget(), 102_400);
        assert!(c.validate().is_ok());
    }
}
