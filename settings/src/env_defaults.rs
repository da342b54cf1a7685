//! The defaults each environment adds to the common ones ([`TrainConfig::defaults_for`]),
//! each with the measurement that set it.

use jsae_env_spec::{GymConfig, GymSpace};

use crate::{Algo, EnvName, TrainConfig};

impl TrainConfig {
    /// The gridworlds'.
    pub(crate) fn gridworld_defaults(&mut self) {
        let embedded_actions = self.algo.representation().decodes_actions();
        // Random play finds the goal around the solid L in a few % of episodes and the
        // policy learns to avoid walls before it has: without this bonus 2 of 5 seeds
        // found the goal at all in 500k steps; with it every seed tried did.
        self.exploration.bonus = 0.1;
        if self.env == EnvName::Gridworld && embedded_actions {
            // With the continuous state the evaluation's mean action ran into a wall for the
            // whole episode on 3 of 3 seeds at 0.05 (the sampled policy reached the goal in
            // every training episode); at 0.01, 1 of 3 (seeds 2 and 3 solved it).
            self.ppo.ent_coef = 0.01;
        }
        if self.env == EnvName::GridworldDiscrete && embedded_actions {
            // A batch of 64 environments x 128 steps (8,192), shared among the actors present
            // (each has 64 and steps its share): at 500k steps, 512 actions, one actor in one
            // process, seeds 2051-2080, the deterministic evaluation solved 28 of 30 runs
            // against 27 with 32 environments and 22 with 16 (more runs found the goal, and
            // fewer greedy loops; docs/src/experiments/loop-500k-batch.md).
            (self.envs_per_actor, self.batch_envs) = (64, Some(64));
        }
    }

    /// The slotmachine's.
    pub(crate) fn slotmachine_defaults(&mut self) {
        // The next reel position is `position + advance mod 6`: a linear T on the two
        // embeddings cannot express it, and 30 epochs of a tanh T leave it near chance.
        // With these settings the model loss after pre-training is 0.9 nats over the four
        // reels (chance: 7.2) and the policy improves; see docs/src/experiments/slotmachine.md.
        self.embedding.state_dim = 16;
        self.embedding.action_dim = 4;
        self.embedding.transition_hidden = 128;
        self.embedding.pretrain_epochs = 200;
        self.embedding.update_steps = 200;
        self.ppo.gamma = 0.9;
        self.ppo.ent_coef = 0.0;
        // Measured over 5 seeds at 300k steps (results/sweeps/slotmachine-variants.toml):
        // with 25 random transitions per action (102,400, a third of the budget) and an
        // initial std of 1 in E the policy stayed near random (eval 157 against PPO's 282);
        // with 5 (the factored T is fitted from them, 0.97 nats) and 0.3 it reaches
        // 400-470 (docs/src/experiments/slotmachine.md).
        self.embedding.pretrain_per_action = 5;
        self.ppo.init_log_std = -1.2;
    }

    /// The recommender's.
    pub(crate) fn recommender_defaults(&mut self) {
        // 835 items: a random policy recommends each one about 120 times in the
        // pre-training set. Dimensions from the paper's grid ({8,16,32} x {4,8,12}).
        self.env_steps = 300_000;
        self.embedding.state_dim = 16;
        self.embedding.action_dim = 8;
        self.embedding.pretrain_transitions = 100_000;
        if self.algo == Algo::Ppo {
            // Measured at 2M steps (docs/src/experiments/recommender.md): the reward alone
            // leaves PPO at the popular items (1.15 over 5 seeds), the next-purchase loss
            // and a pair feature take it to 6.40; interaction alone does not reach the
            // greedy rule in 2M steps, the logs the model is built from do. A network
            // pre-trained on them stays 0.28 below the rule (5 seeds); the counts as a
            // fixed prior in the logits are at its level, and PPO as a contextual bandit
            // (planning adds 0.07) must move them slowly: at lr 1e-4 seed 1001 fell from
            // 7.99 to 7.77, at 1e-5 7.98 (results/sweeps/recommender-prior.toml).
            self.ppo.hidden = vec![128, 128];
            self.ppo.recommender.logged_prior = true;
            self.ppo.gamma = 0.0;
            self.ppo.lr = 1e-5;
        }
        if self.algo == Algo::Jsae {
            crate::embedding_recommender::jsae_recommender_defaults(self);
        }
    }

    /// HalfCheetah's and Ant's.
    pub(crate) fn mujoco_defaults(&mut self) {
        // CleanRL's ppo_continuous_action where it applies (2048 steps per update, here
        // 16 envs x 128; 32 minibatches of 64; clipped value loss), with observation
        // normalisation in the policy and, for JSAE, in phi.
        self.env_steps = 1_000_000;
        self.ppo.normalize_obs = true;
        self.ppo.minibatch_size = 64;
        self.ppo.clip_value_loss = true;
        self.ppo.ent_coef = 0.0;
        self.embedding.normalize_states = true;
        self.embedding.transition_hidden = 128;
        self.embedding.pretrain_epochs = 20;
        self.embedding.update_every = 50_000;
        (self.embedding.state_dim, self.embedding.action_dim) = match self.env {
            EnvName::Ant => (32, 8),
            _ => (20, 6),
        };
        if self.algo.representation().decodes_actions() {
            // The std is over E, and f stretches E: near g(box) a unit step in E moves
            // the torques by about 3.8 on HalfCheetah and 2.2-2.5 on Ant (measured on the
            // default runs with the example action_box_coverage). These starts are about
            // 1 and 0.8 in torques (PPO starts at 1). With 0.6 in E (2.3 in torques, most
            // samples saturated) JSAE trailed PPO on HalfCheetah, with 0.26 it does not
            // (docs/src/experiments/mujoco.md); Ant at 0.6 learned to fall at once.
            self.ppo.init_log_std = if self.env == EnvName::Ant {
                -1.0
            } else {
                -1.35
            };
        }
    }

    /// A gym environment's: with a box of actions, HalfCheetah's and Ant's (CleanRL's
    /// continuous PPO), so that `gym:HalfCheetah-v5` trains as `half-cheetah` does; with
    /// discrete actions the common defaults (CleanRL's discrete PPO is about them).
    pub(crate) fn gym_defaults(&mut self, gym: &GymConfig) {
        if let Some(GymSpace::Box { shape, .. }) = &gym.action {
            self.rollouts_per_policy = 2;
            self.mujoco_defaults();
            let dim: u32 = shape.iter().product();
            self.embedding.action_dim = dim.clamp(1, 64) as usize;
        }
    }
}
