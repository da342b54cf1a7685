//! How a run's rollouts make the learner's batch. Either every actor steps all of its
//! environments and the batch is one rollout of every actor present, so it grows with the
//! actors, or `batch_envs` environments are shared among the actors present,
//! each stepping its share of its own, so the batch and the updates per env step stay one
//! actor's as actors join and leave. The learner applies the same rule to the actors it sees
//! ([`share_envs`]); the one-process driver to the run's own. The batch grows by default;
//! gridworld-discrete with actions in an embedding space shares one batch of 64 environments
//! by default, measured to learn better than one actor's 16 (docs/src/experiments/loop-500k-batch.md).

use super::TrainConfig;

impl TrainConfig {
    /// The environments one batch is gathered from, shared among the actors present; None
    /// when every actor steps all of its own ([`TrainConfig::batch_envs`]).
    pub fn shared_batch_envs(&self) -> Option<usize> {
        self.batch_envs.filter(|&n| n > 0)
    }

    /// The environments each of the run's own `actors` steps in a rollout.
    pub fn actor_envs(&self) -> Vec<usize> {
        let own = vec![self.envs_per_actor; self.actors];
        match self.shared_batch_envs() {
            Some(total) => share_envs(total, &own),
            None => own,
        }
    }

    /// Env steps per rollout round of the run's own actors (the learner's batch).
    pub fn round_steps(&self) -> usize {
        self.actor_envs().iter().sum::<usize>() * self.rollout_len
    }

    /// Env steps each actor plays at random before the first embedding (its share of the
    /// pre-training budget; 0 for a run without an embedder): it then waits for the
    /// embedding. The actor sends no fragment for these steps.
    pub fn random_play_share(&self) -> u64 {
        if !self.algo.representation().needs_embedder() {
            return 0;
        }
        self.pretrain_budget().div_ceil(self.actors.max(1)) as u64
    }

    /// Env steps of random play the learner credits beyond the fragments' own lengths, over
    /// the whole run: the pre-training budget plus one rollout of all environments of every
    /// actor (each actor stops only after the rollout that reaches its share, and may step
    /// more than its share of the batch before the learner has told it); 0 for a run without
    /// an embedder, whose actors play no random steps.
    pub fn random_play_allowance(&self) -> u64 {
        if !self.algo.representation().needs_embedder() {
            return 0;
        }
        (self.pretrain_budget() + self.actors * self.envs_per_actor * self.rollout_len) as u64
    }
}

/// `total` environments shared among actors that have `capacities` of them: as evenly as
/// their capacities allow, a remainder to the first ones, and at least one each (an actor
/// that steps nothing would hold its rounds up), so the shares add up to
/// `max(total, actors)` or all the capacity there is, whichever is less.
pub fn share_envs(total: usize, capacities: &[usize]) -> Vec<usize> {
    let mut shares: Vec<usize> = capacities.iter().map(|&c| c.min(1)).collect();
    let mut left = total.saturating_sub(shares.iter().sum());
    loop {
        let open: Vec<usize> = (0..shares.len())
            .filter(|&i| shares[i] < capacities[i])
            .collect();
        if open.is_empty() || left == 0 {
            return shares;
        }
        let each = (left / open.len()).max(1);
        for i in open {
            let add = each.min(capacities[i] - shares[i]).min(left);
            shares[i] += add;
            left -= add;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Algo, EnvName};

    #[test]
    fn shares_are_even_with_the_remainder_first_and_capped_by_capacity() {
        assert_eq!(share_envs(16, &[16]), vec![16]);
        assert_eq!(share_envs(16, &[16, 16]), vec![8, 8]);
        assert_eq!(share_envs(16, &[16, 16, 16]), vec![6, 5, 5]);
        assert_eq!(share_envs(16, &[16; 4]), vec![4; 4]);
        // an actor started with fewer environments: the others take the rest
        assert_eq!(share_envs(16, &[4, 16]), vec![4, 12]);
        assert_eq!(share_envs(16, &[4, 4]), vec![4, 4]);
        // more actors than environments: one each
        assert_eq!(share_envs(2, &[16; 3]), vec![1, 1, 1]);
        assert_eq!(share_envs(16, &[]), Vec::<usize>::new());
        assert_eq!(share_envs(16, &[16, 0]), vec![16, 0]);
        for n in 1..=9 {
            let s = share_envs(16, &vec![16; n]);
            assert_eq!(s.iter().sum::<usize>(), 16.max(n), "{n}: {s:?}");
            let (lo, hi) = (s.iter().min(), s.iter().max());
            assert!(lo.zip(hi).is_some_and(|(lo, hi)| hi - lo <= 1), "{s:?}");
        }
    }

    #[test]
    fn the_batch_grows_with_the_actors_unless_it_is_shared() {
        let mut c = TrainConfig::defaults(EnvName::HalfCheetah, Algo::Ppo);
        c.actors = 4;
        assert_eq!(c.shared_batch_envs(), None);
        assert_eq!(c.actor_envs(), vec![16; 4]);
        assert_eq!(c.round_steps(), 4 * 16 * 128);
        c.batch_envs = Some(16);
        assert_eq!(c.actor_envs(), vec![4; 4]);
        assert_eq!(c.round_steps(), 16 * 128);
        c.batch_envs = Some(32);
        assert_eq!(c.actor_envs(), vec![8; 4]);
        c.batch_envs = Some(0);
        assert_eq!(c.round_steps(), 4 * 16 * 128);
    }

    #[test]
    fn the_embedded_gridworld_shares_one_batch_of_64_environments_by_default() {
        for algo in [Algo::Jsae, Algo::Ae, Algo::Ra] {
            let mut c = TrainConfig::defaults(EnvName::GridworldDiscrete, algo);
            for (actors, each) in [(1, 64), (2, 32), (4, 16), (3, 22)] {
                c.actors = actors;
                let envs = c.actor_envs();
                assert_eq!(envs.len(), actors);
                assert!(envs.iter().all(|&e| e == each || e == each - 1), "{envs:?}");
                assert_eq!(c.round_steps(), 64 * 128, "{algo:?}, {actors} actors");
            }
        }
        // plain PPO and the continuous state keep the batch that grows
        for (env, algo) in [
            (EnvName::GridworldDiscrete, Algo::Ppo),
            (EnvName::Gridworld, Algo::Jsae),
        ] {
            let c = TrainConfig::defaults(env, algo);
            assert_eq!((c.shared_batch_envs(), c.envs_per_actor), (None, 16));
        }
    }
}
