//! The count-based exploration bonus (`exploration.bonus`), kept where every actor's steps
//! meet: each fragment carries the key of every step's next state (`visit_keys`), and the
//! learner counts the visits of all actors and adds `bonus / sqrt(n)` to each step's reward
//! before GAE. With counts per actor, as the actors kept them before, a state's count grew N
//! times slower with N actors, so its bonus was sqrt(N) times larger at the same env step and
//! differed from one actor to the next (docs/src/experiments/loop-500k-actors.md).

use std::collections::HashMap;

use jsae_wire::RolloutFragment;

/// The most distinct states counted (some 100 MB of counts). The keys come from the wire, so
/// an actor sending ever new ones must not grow the learner without bound: past the limit a
/// state not counted yet gets a first visit's bonus and is not stored.
pub const MAX_STATES: usize = 1 << 22;

/// Visits per state key, over all actors.
#[derive(Debug, Clone)]
pub struct VisitBonus {
    bonus: f32,
    counts: HashMap<u64, u32>,
    limit: usize,
}

impl VisitBonus {
    /// A bonus of `bonus` for a first visit (None when it is 0: no bonus).
    pub fn new(bonus: f64) -> Option<Self> {
        (bonus > 0.0).then(|| Self {
            bonus: bonus as f32,
            counts: HashMap::new(),
            limit: MAX_STATES,
        })
    }

    /// Counts the fragment's visits, in step order, and adds each step's bonus to its
    /// reward. A fragment without keys (the bonus off at its actor) is left as it is.
    pub fn apply(&mut self, fragment: &mut RolloutFragment) {
        if fragment.visit_keys.len() != fragment.rewards.len() {
            return;
        }
        for (&key, reward) in fragment.visit_keys.iter().zip(&mut fragment.rewards) {
            let n = match self.counts.get(&key).copied() {
                Some(n) => {
                    let n = n.saturating_add(1);
                    self.counts.insert(key, n);
                    n
                }
                None if self.counts.len() < self.limit => {
                    self.counts.insert(key, 1);
                    1
                }
                None => 1,
            };
            *reward += self.bonus / (n as f32).sqrt();
        }
    }

    /// Distinct states visited.
    pub fn states(&self) -> usize {
        self.counts.len()
    }

    /// The counts, for a checkpoint (sorted by key).
    pub fn counts(&self) -> Vec<(u64, u32)> {
        let mut c: Vec<_> = self.counts.iter().map(|(&k, &n)| (k, n)).collect();
        c.sort_unstable();
        c
    }

    /// Counts restored from a checkpoint.
    pub fn restore(&mut self, counts: &[(u64, u32)]) {
        self.counts = counts.iter().copied().collect();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use jsae_wire::ActionBatch;

    fn fragment(actor: u64, keys: Vec<u64>) -> RolloutFragment {
        let n = keys.len();
        RolloutFragment {
            actor_id: actor,
            env_index: 0,
            policy_version: 0,
            embedding_version: 0,
            actor_env_steps: n as u64,
            x_dim: 1,
            x: vec![0.0; n],
            actions: ActionBatch::Discrete(vec![0; n]),
            logp: vec![0.0; n],
            rewards: vec![-0.01; n],
            terminated: vec![false; n],
            truncated: vec![false; n],
            truncated_next_x: Vec::new(),
            last_next_x: vec![0.0],
            episodes: Vec::new(),
            actor_incarnation: 1,
            visit_keys: keys,
        }
    }

    #[test]
    fn two_actors_share_one_count() {
        let mut v = VisitBonus::new(0.1).expect("on");
        let mut a = fragment(0, vec![7, 8]);
        let mut b = fragment(1, vec![7, 7]);
        v.apply(&mut a);
        v.apply(&mut b);
        let close = |x: f32, y: f32| (x - y).abs() < 1e-6;
        assert!(close(a.rewards[0], -0.01 + 0.1) && close(a.rewards[1], -0.01 + 0.1));
        // actor 1's visits of state 7 are its 2nd and 3rd over both actors
        assert!(close(b.rewards[0], -0.01 + 0.1 / 2f32.sqrt()));
        assert!(close(b.rewards[1], -0.01 + 0.1 / 3f32.sqrt()));
        assert_eq!(v.states(), 2);
        assert_eq!(v.counts(), vec![(7, 3), (8, 1)]);
    }

    #[test]
    fn off_or_without_keys_nothing_changes() {
        assert!(VisitBonus::new(0.0).is_none());
        let mut v = VisitBonus::new(0.1).expect("on");
        let mut f = fragment(0, vec![]);
        f.rewards = vec![0.5; 3];
        v.apply(&mut f);
        assert_eq!(f.rewards, vec![0.5; 3]);
        assert_eq!(v.states(), 0);
    }

    #[test]
    fn past_the_limit_new_states_are_not_stored() {
        let mut v = VisitBonus::new(0.1).expect("on");
        v.limit = 2;
        let mut f = fragment(0, vec![1, 2, 3, 3, 1]);
        v.apply(&mut f);
        assert_eq!(v.counts(), vec![(1, 2), (2, 1)]);
        let first = -0.01 + 0.1;
        assert!((f.rewards[2] - first).abs() < 1e-6 && (f.rewards[3] - first).abs() < 1e-6);
        assert!((f.rewards[4] - (-0.01 + 0.1 / 2f32.sqrt())).abs() < 1e-6);
    }

    #[test]
    fn restored_counts_go_on() {
        let mut v = VisitBonus::new(0.1).expect("on");
        v.restore(&[(7, 3)]);
        let mut f = fragment(0, vec![7]);
        v.apply(&mut f);
        assert!((f.rewards[0] - (-0.01 + 0.1 / 2.0)).abs() < 1e-6);
    }
}
